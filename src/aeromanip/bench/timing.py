"""Timing helpers: repeat a call after warm-up and report robust statistics."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np


def time_call(fn: Callable[[], object], repeat: int, warmup: int = 50) -> dict[str, float]:
    """Median, p95 and max of ``repeat`` timed calls [microseconds] after ``warmup`` calls."""
    for _ in range(warmup):
        fn()
    ts = np.empty(repeat)
    for i in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts[i] = time.perf_counter() - t0
    ts *= 1e6
    return {
        "median_us": float(np.median(ts)),
        "p95_us": float(np.percentile(ts, 95)),
        "max_us": float(ts.max()),
        "calls": int(repeat),
    }
