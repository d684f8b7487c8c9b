"""A tabulated reference read from a CSV file."""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from pathlib import Path

import casadi as ca
import numpy as np

from aeromanip.config import Table
from aeromanip.errors import ConfigError
from aeromanip.references.base import REFERENCES, Reference, as_times


@REFERENCES.register("csv")
class Csv(Reference):
    """A tabulated reference from a CSV file with header columns ``t, x, y, z``.

    Times [s] must be strictly increasing; positions [m] are linearly interpolated and
    the first/last rows held outside the table. Extra columns are ignored.
    """

    def __init__(self, path: str | Path, *, name: str = "reference") -> None:
        p = Path(path)
        self.path = p
        try:
            with p.open(newline="") as f:
                rows = list(csv.reader(f))
        except OSError as e:
            raise ConfigError(f"{name}.file: cannot read {str(p)!r}: {e.strerror}") from None
        if not rows:
            raise ConfigError(f"{name}.file: {p}: empty file (a header t,x,y,z is required)")
        header = [h.strip() for h in rows[0]]
        cols = {}
        for c in ("t", "x", "y", "z"):
            if c not in header:
                raise ConfigError(f"{name}.file: {p}: missing column {c!r} in header {header}")
            cols[c] = header.index(c)
        data = np.empty((len(rows) - 1, 4))
        for r, row in enumerate(rows[1:]):
            line = r + 2
            for j, c in enumerate(("t", "x", "y", "z")):
                try:
                    v = float(row[cols[c]])
                except (IndexError, ValueError):
                    cell = row[cols[c]] if cols[c] < len(row) else "<missing>"
                    raise ConfigError(
                        f"{name}.file: {p}: line {line}, column {c!r}: not a number: {cell!r}"
                    ) from None
                if not math.isfinite(v):
                    raise ConfigError(
                        f"{name}.file: {p}: line {line}, column {c!r}: must be finite, got {v!r}"
                    )
                data[r, j] = v
        if data.shape[0] == 0:
            raise ConfigError(f"{name}.file: {p}: no data rows")
        bad = np.nonzero(np.diff(data[:, 0]) <= 0)[0]
        if bad.size:
            line = int(bad[0]) + 3
            raise ConfigError(
                f"{name}.file: {p}: line {line}: t must be strictly increasing, "
                f"got {data[bad[0], 0]!r} then {data[bad[0] + 1, 0]!r}"
            )
        self.t = data[:, 0]
        self.xyz = data[:, 1:]
        self.duration = float(max(self.t[-1], 0.0))

    def sample(self, times: np.ndarray | Sequence[float]) -> np.ndarray:
        """Reference positions [m] at ``times`` [s], shape (len(times), 3)."""
        t = as_times(times)
        return np.stack([np.interp(t, self.t, self.xyz[:, j]) for j in range(3)], axis=1)

    def expression(self, t: ca.SX) -> ca.SX:
        """``sample`` at one time ``t`` [s] as a CasADi expression (3,): CasADi's linear
        interpolant, held outside the table."""
        if self.t.size == 1:
            return ca.SX(ca.DM(self.xyz[0]))
        held = ca.fmin(ca.fmax(t, self.t[0]), self.t[-1])
        cols = [
            ca.interpolant(f"reference_{'xyz'[j]}", "linear", [self.t], self.xyz[:, j])(held)
            for j in range(3)
        ]
        return ca.vertcat(*cols)

    @classmethod
    def from_table(cls, table: Table, base_dir: Path | None = None) -> Csv:
        """Key: ``file`` (relative to ``base_dir``, default the working directory)."""
        file = Path(table.str("file"))
        if not file.is_absolute() and base_dir is not None:
            file = base_dir / file
        return cls(file, name=table.path or "reference")
