"""The paper's figures drawn from run logs alone (any saved run can be re-plotted).

Uses ``matplotlib.figure.Figure`` directly (no pyplot, no GUI backend). Each function
writes PNG(s) into ``out_dir`` (created) and returns their paths. Meta keys used (all
optional): ``bounds``, ``state_names``, ``waypoints``, ``scenario`` (see ``runlog``).

Single run: ``plot_tracking`` (Figs. 2, 7), ``plot_commands`` (Fig. 3), ``plot_joints``
(Fig. 8), ``plot_platform`` (Fig. 9), ``plot_cog``, ``plot_solve_time``; ``plot_run``
draws all that apply. Several variants: ``plot_condition`` (Fig. 4), ``plot_paths_3d``
(Figs. 5-6), ``plot_errors``; ``plot_comparison`` draws those.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from aeromanip.runlog import RunLog, bound_pair

DPI = 120
PLATFORM = ("x", "y", "z", "yaw")
_LEGEND: dict[str, Any] = {"loc": "upper right", "fontsize": "small", "framealpha": 0.8}


def _unit(name: str, rate: bool = False) -> str:
    """SI unit of a state DoF (``rate``: of its derivative)."""
    base = "m" if name in ("x", "y", "z") else "rad"
    return f"{base}/s" if rate else base


def _title(log: RunLog, what: str) -> str:
    scen = log.meta.get("scenario")
    return f"{scen}: {what}" if scen else what


def _save(fig: Figure, out_dir: str | Path, name: str) -> Path:
    d = Path(out_dir)
    d.mkdir(parents=True, exist_ok=True)
    path = d / name
    fig.savefig(path, dpi=DPI)
    return path


def _margins(
    fig: Figure,
    nrows: int = 1,
    ncols: int = 1,
    *,
    left: float = 0.9,
    right: float = 0.25,
    top: float = 0.6,
    bottom: float = 0.55,
    hgap: float = 0.3,
    wgap: float = 1.0,
) -> None:
    """Fixed margins and gaps in inches (cheaper and steadier than a layout engine)."""
    w, h = fig.get_size_inches()
    ax_w = (w - left - right - wgap * (ncols - 1)) / ncols
    ax_h = (h - top - bottom - hgap * (nrows - 1)) / nrows
    fig.subplots_adjust(
        left=left / w,
        right=1 - right / w,
        top=1 - top / h,
        bottom=bottom / h,
        wspace=wgap / ax_w,
        hspace=hgap / ax_h,
    )


def _grid(
    n: int, width: float = 9.0, row_h: float = 2.2, max_rows: int = 4
) -> tuple[Figure, list[Axes]]:
    """A figure with ``n`` time-series axes sharing x (two columns beyond ``max_rows``)."""
    ncols = 1 if n <= max_rows else 2
    nrows = math.ceil(n / ncols)
    fig = Figure(figsize=(width if ncols == 1 else width * 1.6, 1.15 + row_h * nrows))
    axes = fig.subplots(nrows, ncols, sharex=True, squeeze=False).ravel().tolist()
    _margins(fig, nrows, ncols, hgap=0.3 if n <= max_rows else 0.45)
    for ax in axes[n:]:
        ax.set_visible(False)
    for i, ax in enumerate(axes[:n]):
        if i + ncols >= n:  # nothing visible below: this axes shows the time axis
            ax.xaxis.set_tick_params(labelbottom=True)
            ax.set_xlabel("t [s]")
    return fig, axes[:n]


def _bounds_of(log: RunLog, bounds: Mapping[str, Any] | None = None) -> Mapping[str, Any]:
    return bounds if bounds is not None else (log.meta.get("bounds") or {})


def _bound_lines(ax: Axes, bounds: Mapping[str, Any], key: str) -> None:
    """Dashed horizontal lines at the finite sides of ``bounds[key]``."""
    if bounds.get(key) is None:
        return
    label = "bounds"
    for v in bound_pair(bounds[key], key):
        if math.isfinite(v):
            ax.axhline(v, color="0.3", ls="--", lw=1.0, label=label)
            label = "_nolegend_"


def _finish(ax: Axes, ylabel: str, legend: bool = True) -> None:
    ax.set_ylabel(ylabel)
    ax.grid(True, alpha=0.4)
    if legend and ax.get_legend_handles_labels()[0]:
        ax.legend(**_LEGEND)


def _active(col: np.ndarray) -> bool:
    return bool(col.size) and bool(np.any(np.nan_to_num(col) != 0.0))


def plot_tracking(log: RunLog, out_dir: str | Path, name: str = "ee_tracking.png") -> list[Path]:
    """EE position vs reference per world axis, plus the error norm [m] (Figs. 2 and 7)."""
    t = log.column("t")
    fig, axes = _grid(4)
    for ax, c in zip(axes[:3], "xyz", strict=True):
        ax.plot(t, log.column(f"ref_{c}"), "r--", lw=1.2, label="reference")
        ax.plot(t, log.column(f"ee_{c}"), "b-", lw=1.2, label="end effector")
        _finish(ax, f"{c}_e [m]")
    err = log.ee_error()
    rmse = float(np.sqrt(np.nanmean(err**2))) if err.size else math.nan
    axes[3].plot(t, err, "k-", lw=1.0, label=f"|ee - ref| (RMSE {rmse * 1000:.1f} mm)")
    _finish(axes[3], "error [m]")
    fig.suptitle(_title(log, "end-effector tracking (world frame)"))
    return [_save(fig, out_dir, name)]


def _command_dofs(log: RunLog) -> list[str]:
    names = log.meta.get("state_names")
    if names:
        return [n for n in names if f"u_{n}" in log]
    dofs = [n for n in PLATFORM if f"u_{n}" in log and _active(log.column(f"u_{n}"))]
    return dofs + [f"q{i}" for i in range(1, log.n_joints + 1) if f"u_q{i}" in log]


def plot_commands(
    log: RunLog,
    out_dir: str | Path,
    bounds: Mapping[str, Any] | None = None,
    name: str = "commands.png",
) -> list[Path]:
    """Velocity commands per active DoF with dashed ``u_<dof>`` bounds (Fig. 3)."""
    dofs = _command_dofs(log)
    if not dofs:
        return []
    b = _bounds_of(log, bounds)
    t = log.column("t")
    fig, axes = _grid(len(dofs))
    for ax, dof in zip(axes, dofs, strict=True):
        color = "C0" if dof in PLATFORM else "C1"
        ax.step(t, log.column(f"u_{dof}"), where="post", color=color, lw=1.2, label=f"u_{dof}")
        _bound_lines(ax, b, f"u_{dof}")
        _finish(ax, f"u_{dof} [{_unit(dof, rate=True)}]")
    fig.suptitle(_title(log, "NMPC commands (platform: blue, arm joints: orange)"))
    return [_save(fig, out_dir, name)]


def _series_plot(
    log: RunLog, dofs: list[str], out_dir: str | Path, name: str, title: str
) -> list[Path]:
    b = _bounds_of(log)
    t = log.column("t")
    fig, axes = _grid(len(dofs))
    for ax, dof in zip(axes, dofs, strict=True):
        ax.plot(t, log.column(dof), "b-", lw=1.2, label=dof)
        _bound_lines(ax, b, dof)
        _finish(ax, f"{dof} [{_unit(dof)}]")
    fig.suptitle(_title(log, title))
    return [_save(fig, out_dir, name)]


def plot_joints(log: RunLog, out_dir: str | Path, name: str = "joints.png") -> list[Path]:
    """Joint positions q1..qn [rad] with dashed lower/upper bounds (Fig. 8)."""
    dofs = [f"q{i}" for i in range(1, log.n_joints + 1)]
    if not dofs:
        return []
    return _series_plot(log, dofs, out_dir, name, "arm joint positions")


def plot_platform(log: RunLog, out_dir: str | Path, name: str = "platform.png") -> list[Path]:
    """Platform x, y, z [m] (and yaw [rad] when active) with dashed bounds (Fig. 9)."""
    active = log.meta.get("state_names") or []
    dofs = [d for d in ("x", "y", "z") if d in log]
    if "yaw" in log and ("yaw" in active or _active(log.column("yaw"))):
        dofs.append("yaw")
    if not dofs:
        return []
    return _series_plot(log, dofs, out_dir, name, "platform position (world frame)")


def plot_cog(log: RunLog, out_dir: str | Path, name: str = "cog_offset.png") -> list[Path]:
    """Arm CoG offset in the body xy plane [m]; roll/pitch [deg] when logged."""
    if "cog_bx" not in log or "cog_by" not in log:
        return []
    tilt = "roll" in log and "pitch" in log
    t = log.column("t")
    fig, axes = _grid(2 if tilt else 1, row_h=2.6)
    bx, by = log.column("cog_bx"), log.column("cog_by")
    axes[0].plot(t, bx, lw=1.0, label="cog_bx")
    axes[0].plot(t, by, lw=1.0, label="cog_by")
    axes[0].plot(t, np.hypot(bx, by), "k-", lw=1.4, label="|cog_xy|")
    _finish(axes[0], "arm CoG offset [m]")
    if tilt:
        axes[1].plot(t, np.degrees(log.column("roll")), lw=1.0, label="roll")
        axes[1].plot(t, np.degrees(log.column("pitch")), lw=1.0, label="pitch")
        _finish(axes[1], "tilt [deg]")
    fig.suptitle(_title(log, "arm CoG offset from the body z axis"))
    return [_save(fig, out_dir, name)]


def plot_solve_time(log: RunLog, out_dir: str | Path, name: str = "solve_time.png") -> list[Path]:
    """NMPC solve time per step [ms], non-"ok" steps marked, vs the control period."""
    if "solve_ms" not in log or len(log) == 0:
        return []
    t, ms = log.column("t"), log.column("solve_ms")
    fig, axes = _grid(1, row_h=3.0)
    ax = axes[0]
    ax.plot(t, ms, "b.-", lw=0.8, ms=3, label="solve time")
    ax.axhline(float(np.nanmedian(ms)), color="g", ls=":", label="median")
    if t.size > 1:
        period_ms = float(np.median(np.diff(t))) * 1000.0
        ax.axhline(period_ms, color="r", ls="--", label=f"control period ({period_ms:.0f} ms)")
    if "status" in log:
        bad = log.column("status") != "ok"
        if np.any(bad):
            ax.plot(t[bad], ms[bad], "rx", ms=7, label="status != ok")
    _finish(ax, "solve time [ms]")
    fig.suptitle(_title(log, "NMPC solve time per control step"))
    return [_save(fig, out_dir, name)]


def plot_run(log: RunLog, out_dir: str | Path) -> list[Path]:
    """Every single-run figure whose columns exist, into ``out_dir``."""
    paths: list[Path] = []
    if all(f"{p}_{c}" in log for p in ("ee", "ref") for c in "xyz"):
        paths += plot_tracking(log, out_dir)
    paths += plot_commands(log, out_dir)
    paths += plot_joints(log, out_dir)
    paths += plot_platform(log, out_dir)
    paths += plot_cog(log, out_dir)
    paths += plot_solve_time(log, out_dir)
    return paths


def plot_condition(
    logs: Mapping[str, RunLog], out_dir: str | Path, name: str = "condition.png"
) -> list[Path]:
    """Condition number of J_eq J_eq^T over time, one line per variant (Fig. 4)."""
    logs = {k: v for k, v in logs.items() if "cond" in v and len(v)}
    if not logs:
        return []
    fig = Figure(figsize=(9, 4))
    ax = fig.add_subplot()
    _margins(fig, top=0.45)
    finite = []
    for label, log in logs.items():
        c = log.column("cond")
        ax.plot(log.column("t"), c, lw=1.3, label=label)
        finite.append(c[np.isfinite(c) & (c > 0)])
    vals = np.concatenate(finite)
    if vals.size and vals.max() / vals.min() > 50:
        ax.set_yscale("log")
    ax.set_xlabel("t [s]")
    _finish(ax, "condition number rho [-]")
    ax.set_title("condition number of J_eq J_eq^T per variant")
    return [_save(fig, out_dir, name)]


def _xyz(log: RunLog, prefix: str) -> np.ndarray | None:
    names = [f"{prefix}{c}" for c in "xyz"]
    if not all(n in log for n in names):
        return None
    return np.stack([log.column(n) for n in names], axis=1)


def plot_paths_3d(
    logs: Mapping[str, RunLog], out_dir: str | Path, name: str = "paths_3d.png"
) -> list[Path]:
    """3D paths of EE, platform and reference with waypoints, one panel per variant (Figs. 5-6)."""
    logs = {k: v for k, v in logs.items() if _xyz(v, "ee_") is not None and len(v)}
    if not logs:
        return []
    paths = {k: (_xyz(v, "ee_"), _xyz(v, ""), _xyz(v, "ref_")) for k, v in logs.items()}
    pts = np.concatenate([p for trio in paths.values() for p in trio if p is not None])
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    mid = (pts.max(axis=0) + pts.min(axis=0)) / 2 if pts.size else np.zeros(3)
    half = max(float(np.max(pts.max(axis=0) - pts.min(axis=0))) / 2 if pts.size else 0.0, 0.1)
    n = len(logs)
    fig = Figure(figsize=(5.4 * n, 5.8))
    fig.subplots_adjust(left=0.0, right=0.95, bottom=0.07, top=0.9, wspace=0.1)
    for i, (label, log) in enumerate(logs.items()):
        ax = fig.add_subplot(1, n, i + 1, projection="3d")
        ee, base, ref = paths[label]
        if ref is not None:
            ax.plot(*ref.T, "r--", lw=1.0, label="reference")
        ax.plot(*ee.T, "b-", lw=1.5, label="end effector")
        if base is not None:
            ax.plot(*base.T, "k-", lw=1.5, label="platform")
            ax.scatter(*base[0], color="k", marker="o", s=20)
        ax.scatter(*ee[0], color="b", marker="o", s=20, label="start")
        wps = log.meta.get("waypoints")
        if wps:
            w = np.asarray(wps, dtype=float).reshape(-1, 3)
            ax.scatter(*w.T, color="r", marker="*", s=80, depthshade=False, label="waypoints")
        for setter, m in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), mid, strict=True):
            setter(m - half, m + half)
        ax.set_box_aspect((1, 1, 1))
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_zlabel("z [m]")
        ax.set_title(label)
        ax.legend(loc="upper left", fontsize="small")
    fig.suptitle("end-effector and platform paths (world frame)")
    return [_save(fig, out_dir, name)]


def plot_errors(
    logs: Mapping[str, RunLog], out_dir: str | Path, name: str = "comparison_errors.png"
) -> list[Path]:
    """Tracking error |ee - ref| [m] and arm CoG offset |cog_xy| [m] per variant."""
    logs = {k: v for k, v in logs.items() if len(v)}
    if not logs:
        return []
    fig, axes = _grid(2, row_h=2.8)
    for label, log in logs.items():
        t = log.column("t")
        if all(f"{p}_{c}" in log for p in ("ee", "ref") for c in "xyz"):
            err = log.ee_error()
            rmse = float(np.sqrt(np.nanmean(err**2)))
            axes[0].plot(t, err, lw=1.2, label=f"{label} (RMSE {rmse * 1000:.1f} mm)")
        if "cog_bx" in log and "cog_by" in log:
            cog = np.hypot(log.column("cog_bx"), log.column("cog_by"))
            axes[1].plot(t, cog, lw=1.2, label=f"{label} (mean {np.nanmean(cog) * 1000:.1f} mm)")
    _finish(axes[0], "|ee - ref| [m]")
    _finish(axes[1], "|cog_xy| [m]")
    fig.suptitle("tracking error and arm CoG offset per variant")
    return [_save(fig, out_dir, name)]


def plot_comparison(logs: Mapping[str, RunLog], out_dir: str | Path) -> list[Path]:
    """Condition-number comparison, 3D paths and error/CoG comparison of several variants."""
    return plot_condition(logs, out_dir) + plot_paths_3d(logs, out_dir) + plot_errors(logs, out_dir)
