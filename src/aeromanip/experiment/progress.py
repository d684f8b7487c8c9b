"""A one-line progress bar on a terminal (standard error), for runs longer than a moment."""

from __future__ import annotations

import sys
import time

SHOW_AFTER_S = 2.0  # [s] a run shorter than this shows no bar
REDRAW_S = 0.1  # [s] at most this often


class Progress:
    """Shown once a run lasts over ``after`` seconds, and only on a terminal."""

    def __init__(self, total: int, label: str, after: float = SHOW_AFTER_S) -> None:
        self.total, self.label, self.after = total, label, after
        self.t0 = time.perf_counter()
        self.last = 0.0
        self.enabled = sys.stderr.isatty()

    def update(self, done: int) -> None:
        """Redraw (at most every ``REDRAW_S``)."""
        now = time.perf_counter() - self.t0
        if not self.enabled or now < self.after or now - self.last < REDRAW_S:
            return
        self.last = now
        frac = done / max(self.total, 1)
        eta = now / max(frac, 1e-9) - now
        bar = "#" * int(30 * frac)
        sys.stderr.write(f"\r{self.label} [{bar:<30}] {100 * frac:5.1f}%  eta {eta:5.0f} s ")
        sys.stderr.flush()

    def close(self) -> None:
        """Clear the line."""
        if self.enabled and time.perf_counter() - self.t0 >= self.after:
            sys.stderr.write("\r" + " " * 79 + "\r")
            sys.stderr.flush()
