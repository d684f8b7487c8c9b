"""The run log: one row per control step, saved as ``log.csv``, and its metrics.

A ``RunLog`` holds numpy columns (float64, except the text column ``status``) and a
JSON-able ``meta`` dict. Meta keys read by the metrics and plots (all optional):
``bounds`` ({column: [lo, hi]}, ``None`` for an open side), ``state_names`` (active
NMPC DoFs, e.g. ``["y", "z", "q1", "q2"]``), ``waypoints`` ([[x, y, z], ...]),
``scenario`` (a title). ``save`` writes ``log.csv`` (the DESIGN.md contract) and
``meta.json``; ``load`` reads both back exactly.
"""

from __future__ import annotations

import csv
import io
import json
import math
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.experiment.contact_metrics import force_metrics

LOG_FILE = "log.csv"
META_FILE = "meta.json"
SUMMARY_FILE = "summary.json"
TEXT_COLUMNS: frozenset[str] = frozenset({"status", "message"})
CLEARANCE_ACTIVE = 1e-3  # [m] a point this close to its planned depth binds the constraint
"""Columns always stored as text."""

_JOINT = re.compile(r"q([1-9][0-9]*)")


def contract_columns(n_joints: int) -> list[str]:
    """The columns every ``log.csv`` must hold (DESIGN.md), in their canonical order."""
    q = [f"q{i}" for i in range(1, n_joints + 1)]
    return [
        "t",
        "x",
        "y",
        "z",
        "yaw",
        *q,
        "u_x",
        "u_y",
        "u_z",
        "u_yaw",
        *(f"u_{n}" for n in q),
        "ee_x",
        "ee_y",
        "ee_z",
        "ref_x",
        "ref_y",
        "ref_z",
        "cog_bx",
        "cog_by",
        "manip",
        "cond",
        "clearance",
        "solve_ms",
        "status",
    ]


class RunLog:
    """Per-control-step columns (dict of equal-length arrays) plus run metadata."""

    def __init__(
        self,
        columns: Mapping[str, Sequence[Any] | np.ndarray],
        meta: Mapping[str, Any] | None = None,
    ) -> None:
        cols: dict[str, np.ndarray] = {}
        n: int | None = None
        for name, values in columns.items():
            arr = np.asarray(values)
            if arr.ndim != 1:
                raise ConfigError(f"log.{name}: expected a 1-D column, got shape {arr.shape}")
            if name in TEXT_COLUMNS or arr.dtype.kind in "USO":
                arr = arr.astype(str)
            else:
                arr = arr.astype(float)
            if n is None:
                n = arr.size
            elif arr.size != n:
                raise ConfigError(f"log.{name}: has {arr.size} rows, expected {n}")
            cols[name] = arr
        self.columns = cols
        self.meta: dict[str, Any] = dict(meta or {})

    @classmethod
    def from_rows(
        cls, rows: Sequence[Mapping[str, Any]], meta: Mapping[str, Any] | None = None
    ) -> RunLog:
        """Build from a list of row dicts; a key missing in a row is NaN (or "" for text)."""
        names: dict[str, None] = {}
        for row in rows:
            names.update(dict.fromkeys(row))
        text = {
            n for n in names if n in TEXT_COLUMNS or any(isinstance(r.get(n), str) for r in rows)
        }
        cols = {n: [r.get(n, "" if n in text else math.nan) for r in rows] for n in names}
        return cls(
            {n: np.array(v, dtype=str if n in text else float) for n, v in cols.items()}, meta
        )

    def __len__(self) -> int:
        return next(iter(self.columns.values())).size if self.columns else 0

    def __contains__(self, name: object) -> bool:
        return name in self.columns

    @property
    def names(self) -> list[str]:
        """Column names in order."""
        return list(self.columns)

    def column(self, name: str) -> np.ndarray:
        """One column; a missing name raises ``ConfigError`` listing what exists."""
        try:
            return self.columns[name]
        except KeyError:
            raise ConfigError(f"log: no column {name!r} (have {self.names})") from None

    @property
    def n_joints(self) -> int:
        """Number of arm joints: the length of the run q1, q2, ... of columns."""
        n = 0
        while f"q{n + 1}" in self.columns:
            n += 1
        return n

    def missing_columns(self) -> list[str]:
        """Contract columns (DESIGN.md) that this log lacks."""
        return [c for c in contract_columns(self.n_joints) if c not in self.columns]

    def window(self, t0: float, t1: float) -> RunLog:
        """The rows with ``t0 <= t <= t1`` [s] (same meta)."""
        t = self.column("t")
        keep = (t >= t0) & (t <= t1)
        return RunLog({n: c[keep] for n, c in self.columns.items()}, self.meta)

    # ------------------------------------------------------------------ files
    def save(self, out_dir: str | Path) -> Path:
        """Write ``log.csv`` (exact float repr) and ``meta.json`` into ``out_dir``."""
        d = Path(out_dir)
        d.mkdir(parents=True, exist_ok=True)
        texts = []
        for col in self.columns.values():
            if col.dtype.kind == "U":
                texts.append(col.tolist())
            else:
                texts.append([repr(v) for v in col.tolist()])
        path = d / LOG_FILE
        with path.open("w", newline="") as f:
            w = csv.writer(f, lineterminator="\n")
            w.writerow(self.names)
            w.writerows(zip(*texts, strict=True))
        (d / META_FILE).write_text(json.dumps(jsonable(self.meta), indent=2) + "\n")
        return path

    @classmethod
    def load(cls, path: str | Path, require_rows: bool = False) -> RunLog:
        """Read a run directory (or its ``log.csv``) written by ``save`` or streamed by
        ``LogWriter`` (a last line cut short by a crash is dropped). A log without rows
        is an error with ``require_rows``; so is a malformed ``meta.json``."""
        p = Path(path)
        d, f = (p.parent, p) if p.suffix == ".csv" else (p, p / LOG_FILE)
        try:
            with f.open(newline="") as fh:
                text = fh.read()
            rows = list(csv.reader(io.StringIO(text, newline="")))
        except (OSError, UnicodeDecodeError, csv.Error) as e:
            raise ConfigError(
                f"{f}: cannot read run log: {getattr(e, 'strerror', None) or e}"
            ) from None
        if not rows:
            raise ConfigError(f"{f}: empty run log (no header)")
        header, body = rows[0], rows[1:]
        if body and not text.endswith("\n"):  # the last row of a run cut short
            body = body[:-1]
        for i, r in enumerate(body):
            if len(r) != len(header):
                raise ConfigError(f"{f}: line {i + 2}: {len(r)} fields, header has {len(header)}")
        if require_rows and not body:
            raise ConfigError(f"{f}: the run log has no rows (the run flew no step)")
        cols = {name: _parse_column(name, [r[j] for r in body], f) for j, name in enumerate(header)}
        return cls(cols, _load_meta(d / META_FILE))

    # ---------------------------------------------------------------- metrics
    def summary(self) -> dict[str, Any]:
        """Run metrics (DESIGN.md contract keys plus extras); NaN when a column is absent.

        Units: m, ms, deg, N m. ``max_bound_violation`` is the largest amount by which
        any column named in ``meta["bounds"]`` leaves its bound (0 when none does).
        """
        s: dict[str, Any] = {"steps": len(self)}
        err = self._ee_error()
        s["ee_rmse_m"] = _nan_or(err, lambda e: float(np.sqrt(np.nanmean(e**2))))
        s["ee_max_err_m"] = _nan_or(err, lambda e: float(np.nanmax(e)))
        cog = self._norm(("cog_bx", "cog_by"))
        s["cog_xy_mean_m"] = _nan_or(cog, lambda c: float(np.nanmean(c)))
        s["cond_mean"] = _nan_or(self.columns.get("cond"), lambda c: float(np.nanmean(c)))
        s["min_clearance_m"] = _nan_or(self.columns.get("clearance"), lambda c: float(np.nanmin(c)))
        viol, where = self.bound_violation()
        s["max_bound_violation"] = viol
        s["max_bound_violation_column"] = where
        ms = self.columns.get("solve_ms")
        s["solve_ms_median"] = _nan_or(ms, lambda m: float(np.nanmedian(m)))
        s["solve_ms_p95"] = _nan_or(ms, lambda m: float(np.nanpercentile(m, 95)))
        s["solve_ms_max"] = _nan_or(ms, lambda m: float(np.nanmax(m)))
        status = self.columns.get("status")
        s["solver_failures"] = int(np.sum(status != "ok")) if status is not None else 0
        names, counts = np.unique(status, return_counts=True) if status is not None else ([], [])
        s["steps_by_status"] = {str(n): int(c) for n, c in zip(names, counts, strict=True)}
        if "roll" in self.columns and "pitch" in self.columns:
            rp = np.degrees(self._norm(("roll", "pitch")))
            s["roll_pitch_mean_deg"] = _nan_or(rp, lambda a: float(np.nanmean(a)))
            s["roll_pitch_max_deg"] = _nan_or(rp, lambda a: float(np.nanmax(a)))
        if "rotor_spread" in self.columns:  # differential thrust: spent on moments [N]
            s["rotor_spread_mean_n"] = _nan_or(
                self.columns["rotor_spread"], lambda a: float(np.nanmean(a))
            )
        if "arm_torque" in self.columns:
            s["arm_torque_mean_nm"] = _nan_or(
                self.columns["arm_torque"], lambda a: float(np.nanmean(a))
            )
        s.update(self._level_losses())
        s.update(self._clearance_use())
        s.update(self._contact())
        if "iterations" in self.columns:
            s["iterations_mean"] = _nan_or(
                self.columns["iterations"], lambda a: float(np.nanmean(a))
            )
        return s

    def _contact(self) -> dict[str, Any]:
        """With surfaces (a ``contact`` column): the share of rows in contact and the
        largest normal force [N], and with a set force the force regulation's metrics
        (``contact_metrics``); nothing otherwise."""
        if "contact" not in self.columns or "f_n" not in self.columns or len(self) == 0:
            return {}
        return {
            "contact_share": float(np.nanmean(self.columns["contact"])),
            "f_n_max_n": float(np.nanmax(self.columns["f_n"])),
            **force_metrics(self.columns, (self.meta.get("surface_normals") or [None])[0]),
        }

    def _level_losses(self) -> dict[str, Any]:
        """Per hierarchy level: how much of its optimal cost the lower levels took, per
        step (``loss``; relative to the optimum: ``loss_rel``), mean and max."""
        out: dict[str, Any] = {}
        for name in self.columns:
            m = re.fullmatch(r"level(\d+)_loss", name)
            if not m:
                continue
            loss = self.columns[name]
            cost = self.columns.get(f"level{m[1]}_cost", np.full(loss.shape, np.nan))
            rel = loss / np.maximum(np.abs(cost), 1e-12)
            out[m[1]] = {
                "loss_mean": _nan_or(loss, lambda a: float(np.nanmean(a))),
                "loss_max": _nan_or(loss, lambda a: float(np.nanmax(a))),
                "loss_rel_mean": _nan_or(rel, lambda a: float(np.nanmean(a))),
                "cost_mean": _nan_or(cost, lambda a: float(np.nanmean(a))),
            }
        return {"levels": out} if out else {}

    def _clearance_use(self) -> dict[str, Any]:
        """Each point's smallest depth below the base [m] and the share of steps at which
        the self-collision constraint binds (within ``CLEARANCE_ACTIVE`` of the planned
        depth ``meta["clearance_planned"]``)."""
        points = {n[6:]: c for n, c in self.columns.items() if n.startswith("clear_")}
        out: dict[str, Any] = {}
        if points:
            out["min_clearance_by_point_m"] = {
                p: _nan_or(c, lambda a: float(np.nanmin(a))) for p, c in points.items()
            }
        planned = self.meta.get("clearance_planned")
        if planned is not None and "clearance" in self.columns and len(self):
            near = self.columns["clearance"] <= float(planned) + CLEARANCE_ACTIVE
            out["clearance_active_share"] = float(np.mean(near))
        return out

    def bound_violation(self) -> tuple[float, str | None]:
        """Largest excursion beyond ``meta["bounds"]`` [column units] and its column."""
        worst, where = 0.0, None
        for name, bound in (self.meta.get("bounds") or {}).items():
            col = self.columns.get(name)
            if col is None or col.dtype.kind != "f" or col.size == 0:
                continue
            lo, hi = bound_pair(bound, name)
            over = np.maximum(np.nan_to_num(lo - col, nan=0.0), np.nan_to_num(col - hi, nan=0.0))
            v = float(np.max(over))
            if v > worst:
                worst, where = v, name
        return worst, where

    def ee_error(self) -> np.ndarray:
        """||ee - ref|| [m] per step."""
        err = self._ee_error()
        if err is None:
            raise ConfigError("log: needs columns ee_x..ee_z and ref_x..ref_z")
        return err

    def _ee_error(self) -> np.ndarray | None:
        names = ("ee_x", "ee_y", "ee_z", "ref_x", "ref_y", "ref_z")
        if not all(n in self.columns for n in names) or len(self) == 0:
            return None
        ee = np.stack([self.columns[n] for n in names[:3]], axis=1)
        ref = np.stack([self.columns[n] for n in names[3:]], axis=1)
        return np.linalg.norm(ee - ref, axis=1)

    def _norm(self, names: tuple[str, ...]) -> np.ndarray | None:
        if not all(n in self.columns for n in names) or len(self) == 0:
            return None
        return np.sqrt(sum(self.columns[n] ** 2 for n in names))


def load(path: str | Path) -> RunLog:
    """Read a run directory (or its ``log.csv``); same as ``RunLog.load``."""
    return RunLog.load(path)


def motion_share(
    log: RunLog, t0: float, t1: float, direction: Sequence[float] = (0.0, 1.0, 0.0)
) -> dict[str, float]:
    """How much of the end-effector motion along ``direction`` the platform vs the arm carry.

    Over the rows with ``t0 <= t <= t1`` [s], for each step k (forward differences,
    dt = t[k+1] - t[k]): v_ee = d(ee)/dt, v_platform = d(x, y, z)/dt (the platform's
    actual translational velocity; equal to the command u_x, u_y, u_z in the ideal
    kinematic loop, and the true motion under full physics) and v_arm = v_ee -
    v_platform (arm-induced EE velocity, including yaw-induced motion). With ``e`` the
    unit ``direction`` of the reference motion:

        P = sum_k |v_platform . e| dt,  A = sum_k |v_arm . e| dt        [m]
        platform share = P / (P + A),   arm share = A / (P + A)

    Returns ``{"platform", "arm", "platform_m", "arm_m"}``; shares are NaN when nothing
    moves along ``e``.
    """
    e = np.asarray(direction, dtype=float).reshape(-1)
    if e.shape != (3,) or not np.all(np.isfinite(e)) or np.linalg.norm(e) < 1e-12:
        raise ConfigError(
            f"motion_share.direction: expected a non-zero 3-vector, got {direction!r}"
        )
    e = e / np.linalg.norm(e)
    w = log.window(t0, t1)
    nan = {"platform": math.nan, "arm": math.nan, "platform_m": 0.0, "arm_m": 0.0}
    if len(w) < 2:
        return nan
    ee = np.stack([w.column(n) for n in ("ee_x", "ee_y", "ee_z")], axis=1)
    base = np.stack([w.column(n) for n in ("x", "y", "z")], axis=1)
    d_ee = np.diff(ee, axis=0) @ e  # = v . e dt
    d_pl = np.diff(base, axis=0) @ e
    P = float(np.sum(np.abs(d_pl)))
    A = float(np.sum(np.abs(d_ee - d_pl)))
    if P + A <= 0.0:
        return nan
    return {"platform": P / (P + A), "arm": A / (P + A), "platform_m": P, "arm_m": A}


def write_summary(out_dir: str | Path, summary: Mapping[str, Any]) -> Path:
    """Write ``summary.json`` (indent 2; NaN and inf as null) into ``out_dir``."""
    d = Path(out_dir)
    d.mkdir(parents=True, exist_ok=True)
    path = d / SUMMARY_FILE
    path.write_text(json.dumps(jsonable(dict(summary)), indent=2) + "\n")
    return path


def read_summary(path: str | Path) -> dict[str, Any]:
    """Read ``summary.json`` from a run directory (or the file itself); null becomes NaN."""
    p = Path(path)
    f = p if p.suffix == ".json" else p / SUMMARY_FILE
    try:
        data = json.loads(f.read_text())
    except OSError as e:
        raise ConfigError(f"{f}: cannot read summary: {e.strerror}") from None
    return {k: math.nan if v is None else v for k, v in data.items()}


def _load_meta(path: Path) -> dict[str, Any]:
    """``meta.json`` (empty if absent); malformed is a ``ConfigError``."""
    if not path.exists():
        return {}
    try:
        meta = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise ConfigError(f"{path}: cannot read run metadata: {e}") from None
    if not isinstance(meta, dict):
        raise ConfigError(f"{path}: run metadata must be a JSON object")
    bounds = meta.get("bounds") or {}
    if not isinstance(bounds, dict):
        raise ConfigError(f"{path}: bounds: expected an object of [lower, upper] pairs")
    for name, bound in bounds.items():  # checked here, before anything is drawn from it
        bound_pair(bound, name)
    _check_meta_types(meta, path)
    return meta


def _check_meta_types(meta: dict[str, Any], path: Path) -> None:
    """The meta keys the plots read, of the types they need."""
    names = meta.get("state_names")
    if names is not None and not (
        isinstance(names, list) and all(isinstance(n, str) for n in names)
    ):
        raise ConfigError(f"{path}: state_names: expected an array of names, got {names!r:.60}")
    for key in ("clearance_min", "clearance_planned", "dt"):
        v = meta.get(key)
        if v is not None and (isinstance(v, bool) or not isinstance(v, int | float)):
            raise ConfigError(f"{path}: {key}: expected a number, got {v!r:.60}")
    points = meta.get("waypoints")
    if points is not None:
        ok = isinstance(points, list) and all(
            isinstance(p, list) and len(p) == 3 and all(isinstance(c, int | float) for c in p)
            for p in points
        )
        if not ok:
            raise ConfigError(
                f"{path}: waypoints: expected an array of [x, y, z], got {points!r:.60}"
            )
    if "scenario" in meta and not isinstance(meta["scenario"], str):
        raise ConfigError(f"{path}: scenario: expected a name, got {meta['scenario']!r:.60}")


def _nan_or(values: np.ndarray | None, fn: Any) -> float:
    if values is None or values.size == 0 or np.all(np.isnan(values)):
        return math.nan
    return fn(values)


def bound_pair(bound: Any, name: str) -> tuple[float, float]:
    """``meta["bounds"][name]`` as (lower, upper); ``None`` means an open side (+-inf)."""
    ok = isinstance(bound, Sequence) and not isinstance(bound, str) and len(bound) == 2
    try:
        if ok:
            lo = -math.inf if bound[0] is None else float(bound[0])
            hi = math.inf if bound[1] is None else float(bound[1])
            return lo, hi
    except (TypeError, ValueError):
        pass
    raise ConfigError(f"meta.bounds.{name}: expected [lower, upper], got {bound!r}")


def _parse_column(name: str, values: list[str], where: Path | None = None) -> np.ndarray:
    """A column read back: text for ``TEXT_COLUMNS``, numbers for every other one (a cell
    that is not one is a ``ConfigError`` naming its line and column)."""
    if name in TEXT_COLUMNS:
        return np.array(values, dtype=str)
    out = np.empty(len(values))
    for i, v in enumerate(values):
        try:
            out[i] = float(v)
        except ValueError:
            raise ConfigError(
                f"{where or 'log'}: line {i + 2}, column {name!r}: not a number: {v[:40]!r}"
            ) from None
    return out


def jsonable(v: Any) -> Any:
    """Convert numpy values to plain Python, non-finite floats to None (strict JSON)."""
    if isinstance(v, Mapping):
        return {str(k): jsonable(x) for k, x in v.items()}
    if isinstance(v, np.ndarray):
        return jsonable(v.tolist())
    if isinstance(v, list | tuple):
        return [jsonable(x) for x in v]
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, Path):
        return str(v)
    return v
