"""The paper's figures drawn from run logs alone (any saved run can be re-plotted).

Uses ``matplotlib.figure.Figure`` directly (no pyplot, no GUI backend). Each function
writes PNG(s) into ``out_dir`` (created) and returns their paths. Meta keys used (all
optional): ``bounds``, ``state_names``, ``waypoints``, ``scenario`` (see ``runlog``).
Layout helpers (margins, one legend per figure under its title) live in ``plot_style``.

Single run: ``plot_tracking`` (Figs. 2, 7), ``plot_commands`` (Fig. 3), ``plot_joints``
(Fig. 8), ``plot_platform`` (Fig. 9), ``plot_cog``, ``plot_clearance`` (eq. 17 against
``d_min``), ``plot_attitude`` (physics runs),
``plot_solve_time``; ``plot_run`` draws all that apply. Several variants: ``plot_condition``
(Fig. 4), ``plot_paths_3d`` (Figs. 5-6), ``plot_errors``; ``plot_comparison`` draws those.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from aeromanip.errors import ConfigError
from aeromanip.experiment.contact_plots import plot_contact
from aeromanip.experiment.plot_style import (
    active,
    bound_lines,
    finish,
    grid,
    margins,
    save,
    title_and_legend,
    unit,
)
from aeromanip.experiment.runlog import RunLog

PLATFORM = ("x", "y", "z", "yaw")
REF_STYLE: dict[str, Any] = {"color": "r", "ls": "--", "lw": 1.2, "label": "reference"}
START_STYLE: dict[str, Any] = {"marker": "o", "ms": 7, "mfc": "limegreen", "mec": "k", "ls": ""}


def _title(log: RunLog, what: str) -> str:
    scen = str(log.meta.get("scenario") or "").replace("$", r"\$")  # no mathtext
    return f"{scen}: {what}" if scen else what


def _bounds_of(log: RunLog, bounds: Mapping[str, Any] | None = None) -> Mapping[str, Any]:
    return bounds if bounds is not None else (log.meta.get("bounds") or {})


def _shown(log: RunLog, name: str) -> bool:
    """A logged column worth a panel: an active NMPC DoF (``state_names``) or not all zero."""
    return name in log and (name in (log.meta.get("state_names") or []) or active(log.column(name)))


def _tracked_axes(log: RunLog) -> list[str]:
    """World axes whose reference or EE position is not constantly zero (planar: y, z)."""
    axes = [c for c in "xyz" if active(log.column(f"ref_{c}")) or active(log.column(f"ee_{c}"))]
    return axes or list("xyz")


def plot_tracking(log: RunLog, out_dir: str | Path, name: str = "ee_tracking.png") -> list[Path]:
    """EE position vs reference per used world axis [m], plus the error norm [mm] (Figs. 2, 7).

    Axes whose reference and EE position are both constantly zero are left out (the planar
    robot moves in the y-z plane; the paper's Fig. 2 likewise omits its null axis).
    """
    t = log.column("t")
    coords = _tracked_axes(log)
    fig, axes = grid(len(coords) + 1)
    for ax, c in zip(axes, coords, strict=False):
        ax.plot(t, log.column(f"ee_{c}"), "b-", lw=1.4, label="end effector")
        ax.plot(t, log.column(f"ref_{c}"), **REF_STYLE)  # on top: visible where they coincide
        finish(ax, f"{c}_e [m]")
    err = log.ee_error()
    rmse = float(np.sqrt(np.nanmean(err**2))) if err.size else math.nan
    axes[-1].plot(t, err * 1000, "k-", lw=1.0, label=f"|ee - ref| (RMSE {rmse * 1000:.1f} mm)")
    finish(axes[-1], "error [mm]")
    title_and_legend(fig, axes, _title(log, "end-effector tracking (world frame)"))
    return [save(fig, out_dir, name)]


def _command_dofs(log: RunLog) -> list[str]:
    names = log.meta.get("state_names")
    if names:
        return [n for n in names if f"u_{n}" in log]
    dofs = [n for n in PLATFORM if f"u_{n}" in log and active(log.column(f"u_{n}"))]
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
    fig, axes = grid(len(dofs))
    for ax, dof in zip(axes, dofs, strict=True):
        plat = dof in PLATFORM
        label = "platform velocity command" if plat else "arm joint velocity command"
        ax.step(
            t,
            log.column(f"u_{dof}"),
            where="post",
            color="C0" if plat else "C1",
            lw=1.2,
            label=label,
        )
        bound_lines(ax, b, f"u_{dof}")
        finish(ax, f"u_{dof} [{unit(dof, rate=True)}]")
    title_and_legend(fig, axes, _title(log, "NMPC velocity commands"))
    return [save(fig, out_dir, name)]


def _series_plot(
    log: RunLog, dofs: list[str], out_dir: str | Path, name: str, title: str, what: str
) -> list[Path]:
    b = _bounds_of(log)
    t = log.column("t")
    fig, axes = grid(len(dofs))
    for ax, dof in zip(axes, dofs, strict=True):
        ax.plot(t, log.column(dof), "b-", lw=1.2, label=what)
        bound_lines(ax, b, dof)
        finish(ax, f"{dof} [{unit(dof)}]")
    title_and_legend(fig, axes, _title(log, title))
    return [save(fig, out_dir, name)]


def plot_joints(log: RunLog, out_dir: str | Path, name: str = "joints.png") -> list[Path]:
    """Joint positions q1..qn [rad] with dashed lower/upper bounds (Fig. 8)."""
    dofs = [f"q{i}" for i in range(1, log.n_joints + 1)]
    if not dofs:
        return []
    return _series_plot(log, dofs, out_dir, name, "arm joint positions", "joint position")


def plot_platform(log: RunLog, out_dir: str | Path, name: str = "platform.png") -> list[Path]:
    """Platform x, y, z [m] and yaw [rad] that are active or move, with dashed bounds (Fig. 9)."""
    dofs = [d for d in PLATFORM if _shown(log, d)]
    if not any(d in dofs for d in "xyz"):  # a platform at the origin: still show x, y, z
        dofs = [d for d in "xyz" if d in log] + dofs
    if not dofs:
        return []
    return _series_plot(
        log, dofs, out_dir, name, "platform position (world frame)", "platform position"
    )


def plot_cog(log: RunLog, out_dir: str | Path, name: str = "cog_offset.png") -> list[Path]:
    """Arm CoG offset in the body xy plane [m] (components that are not all zero, and norm)."""
    if "cog_bx" not in log or "cog_by" not in log:
        return []
    t = log.column("t")
    fig, axes = grid(1, row_h=2.6)
    bx, by = log.column("cog_bx"), log.column("cog_by")
    for col, c, color in ((bx, "cog_bx", "C0"), (by, "cog_by", "C1")):
        if active(col):
            axes[0].plot(t, col, color=color, lw=1.0, label=f"{c} (body {c[-1]})")
    axes[0].plot(t, np.hypot(bx, by), "k-", lw=1.4, label="|cog_xy|")
    finish(axes[0], "arm CoG offset [m]")
    title_and_legend(fig, axes, _title(log, "arm CoG offset from the body z axis"))
    return [save(fig, out_dir, name)]


def _motor_columns(log: RunLog) -> list[str]:
    """``motor_1``, ``motor_2``, ... up to the first one missing."""
    n = 0
    while f"motor_{n + 1}" in log:
        n += 1
    return [f"motor_{i}" for i in range(1, n + 1)]


def plot_attitude(log: RunLog, out_dir: str | Path, name: str = "attitude.png") -> list[Path]:
    """Physics runs: roll/pitch [deg], arm torque on the base [N m], motor thrusts [N].

    One panel per group of columns present; nothing is written for a log without any
    (kinematic simulation).
    """
    tilt = "roll" in log and "pitch" in log
    motors = _motor_columns(log)
    panels = int(tilt) + int("arm_torque" in log) + int(bool(motors))
    if not panels:
        return []
    t = log.column("t")
    fig, axes = grid(panels, row_h=2.4)
    it = iter(axes)
    if tilt:
        ax = next(it)
        ax.plot(t, np.degrees(log.column("roll")), color="C0", lw=1.0, label="roll")
        ax.plot(t, np.degrees(log.column("pitch")), color="C1", lw=1.0, label="pitch")
        finish(ax, "tilt [deg]")
    if "arm_torque" in log:
        ax = next(it)
        ax.plot(t, log.column("arm_torque"), "k-", lw=1.2, label="arm torque")
        finish(ax, "arm torque [N m]")
    if motors:
        ax = next(it)
        for i, m in enumerate(motors):
            ax.plot(t, log.column(m), color=f"C{(i + 2) % 10}", lw=1.0, label=m.replace("_", " "))
        finish(ax, "motor thrust [N]")
    title_and_legend(fig, axes, _title(log, "platform attitude and arm load (physics)"))
    return [save(fig, out_dir, name)]


def plot_solve_time(log: RunLog, out_dir: str | Path, name: str = "solve_time.png") -> list[Path]:
    """NMPC solve time per step [ms], non-"ok" steps marked, vs the control period."""
    if "solve_ms" not in log or len(log) == 0:
        return []
    t, ms = log.column("t"), log.column("solve_ms")
    fig, axes = grid(1, row_h=3.0)
    ax = axes[0]
    ax.plot(t, ms, "b.-", lw=0.8, ms=3, label="solve time")
    median = float(np.nanmedian(ms))
    ax.axhline(median, color="g", ls=":", label=f"median ({median:.1f} ms)")
    if t.size > 1:
        period_ms = float(np.median(np.diff(t))) * 1000.0
        ax.axhline(period_ms, color="r", ls="--", label=f"control period ({period_ms:.0f} ms)")
    if "status" in log:
        bad = log.column("status") != "ok"
        if np.any(bad):
            ax.plot(t[bad], ms[bad], "rx", ms=7, label="status != ok")
    finish(ax, "solve time [ms]")
    title_and_legend(fig, axes, _title(log, "NMPC solve time per control step"))
    return [save(fig, out_dir, name)]


def plot_clearance(log: RunLog, out_dir: str | Path, name: str = "clearance.png") -> list[Path]:
    """Each constrained arm point's depth below the base [m] against ``d_min`` (dashed;
    the counterpart of Fig. 8's bounds for the self-collision constraint, eq. 17)."""
    points = [n for n in log.names if n.startswith("clear_")]
    if not points:
        return []
    t = log.column("t")
    fig, axes = grid(1, row_h=3.0)
    ax = axes[0]
    for i, col in enumerate(points):
        ax.plot(t, log.column(col), color=f"C{i}", lw=1.2, label=col[6:])
    d_min = log.meta.get("clearance_min")
    if d_min is not None:
        ax.axhline(float(d_min), color="r", ls="--", lw=1.0, label=f"d_min ({float(d_min):g} m)")
    planned = log.meta.get("clearance_planned")
    if planned is not None and d_min is not None and float(planned) > float(d_min):
        ax.axhline(float(planned), color="r", ls=":", lw=1.0, label="planned limit")
    finish(ax, "depth below the base [m]")
    title_and_legend(fig, axes, _title(log, "self-collision clearance of the arm points"))
    return [save(fig, out_dir, name)]


def plot_run(log: RunLog, out_dir: str | Path) -> list[Path]:
    """Every single-run figure whose columns exist, into ``out_dir``."""
    draws: list[Any] = []
    if all(f"{p}_{c}" in log for p in ("ee", "ref") for c in "xyz"):
        draws.append(plot_tracking)
    draws += [plot_commands, plot_joints, plot_platform, plot_cog, plot_clearance]
    draws += [plot_attitude, plot_contact, plot_solve_time]
    paths: list[Path] = []
    for draw in draws:
        paths += _drawn(draw, log, out_dir)
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
    margins(fig)
    finite = []
    for label, log in logs.items():
        c = log.column("cond")
        ax.plot(log.column("t"), c, lw=1.3, label=label)
        finite.append(c[np.isfinite(c) & (c > 0)])
    vals = np.concatenate(finite)
    if vals.size and vals.max() / vals.min() > 50:
        ax.set_yscale("log")
    ax.set_xlabel("t [s]")
    finish(ax, "condition number rho [-]")
    title_and_legend(fig, [ax], "condition number of J_eq J_eq^T per variant")
    return [save(fig, out_dir, name)]


def _xyz(log: RunLog, prefix: str) -> np.ndarray | None:
    names = [f"{prefix}{c}" for c in "xyz"]
    if not all(n in log for n in names):
        return None
    return np.stack([log.column(n) for n in names], axis=1)


def _inner_ticks(lo: float, hi: float) -> np.ndarray:
    """About four round ticks strictly inside [lo, hi] (5 % clear of both ends)."""
    ticks = MaxNLocator(5).tick_values(lo, hi)
    pad = 0.05 * (hi - lo)
    return ticks[(ticks >= lo + pad) & (ticks <= hi - pad)]


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
    flat_x = bool(pts.size) and float(np.ptp(pts[:, 0])) < 1e-9
    n = len(logs)
    fig = Figure(figsize=(5.4 * n, 5.8))
    fig.subplots_adjust(left=0.0, right=0.95, bottom=0.07, top=1 - 0.85 / 5.8, wspace=0.1)
    axes = []
    for i, (label, log) in enumerate(logs.items()):
        # drawing order, not depth, decides what is on top (reference over EE, starts last)
        ax = fig.add_subplot(1, n, i + 1, projection="3d", computed_zorder=False)
        axes.append(ax)
        ee, base, ref = paths[label]
        ax.plot(*ee.T, "b-", lw=1.5, label="end effector")
        if ref is not None:
            ax.plot(*ref.T, **REF_STYLE)  # on top: visible where the EE tracks it
        if base is not None:
            ax.plot(*base.T, "k-", lw=1.5, label="platform")
        wps = log.meta.get("waypoints")
        if wps:
            w = np.asarray(wps, dtype=float).reshape(-1, 3)
            ax.plot(*w.T, "r*", ms=12, mec="darkred", label="waypoints")
        for p in (ee, base):  # plot markers: no depth shading, so legend and marker agree
            if p is not None:
                ax.plot(*p[:1].T, **START_STYLE, label="start")
        for setter, m in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), mid, strict=True):
            setter(m - half, m + half)
        ax.set_box_aspect((1, 1, 1))
        for setter, m in zip((ax.set_xticks, ax.set_yticks, ax.set_zticks), mid, strict=True):
            setter(_inner_ticks(m - half, m + half))  # none at the corners: no label collisions
        if flat_x:  # planar robot (y-z plane): look at that plane nearly face on
            ax.view_init(elev=15, azim=-20)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_zlabel("z [m]")
        ax.set_title(label)
    title_and_legend(fig, axes, "end-effector and platform paths (world frame)")
    return [save(fig, out_dir, name)]


def plot_errors(
    logs: Mapping[str, RunLog], out_dir: str | Path, name: str = "comparison_errors.png"
) -> list[Path]:
    """Tracking error |ee - ref| [mm] and arm CoG offset |cog_xy| [m] per variant."""
    logs = {k: v for k, v in logs.items() if len(v)}
    if not logs:
        return []
    fig, axes = grid(2, row_h=2.8)
    for i, (label, log) in enumerate(logs.items()):
        t, color, stats = log.column("t"), f"C{i % 10}", []
        if all(f"{p}_{c}" in log for p in ("ee", "ref") for c in "xyz"):
            err = log.ee_error()
            stats.append(f"RMSE {np.sqrt(np.nanmean(err**2)) * 1000:.1f} mm")
            axes[0].plot(t, err * 1000, color=color, lw=1.2)
        if "cog_bx" in log and "cog_by" in log:
            cog = np.hypot(log.column("cog_bx"), log.column("cog_by"))
            stats.append(f"mean CoG {np.nanmean(cog) * 1000:.1f} mm")
            axes[1].plot(t, cog, color=color, lw=1.2)
        text = f"{label} ({', '.join(stats)})" if stats else label
        axes[0].plot([], [], color=color, lw=1.2, label=text)
    finish(axes[0], "|ee - ref| [mm]")
    finish(axes[1], "|cog_xy| [m]")
    title_and_legend(fig, axes, "tracking error and arm CoG offset per variant")
    return [save(fig, out_dir, name)]


def plot_comparison(logs: Mapping[str, RunLog], out_dir: str | Path) -> list[Path]:
    """Condition-number comparison, 3D paths and error/CoG comparison of several variants."""
    paths: list[Path] = []
    for draw in (plot_condition, plot_paths_3d, plot_errors):
        paths += _drawn(draw, logs, out_dir)
    return paths


def _drawn(draw: Any, data: Any, out_dir: str | Path) -> list[Path]:
    """``draw(data, out_dir)``; data it cannot draw (values beyond what Matplotlib can
    scale, a ``figures`` path that is a file) is one ``ConfigError`` naming the figure."""
    try:
        with warnings.catch_warnings():  # an overflow is an error here, not stderr noise
            warnings.simplefilter("error", RuntimeWarning)
            return draw(data, out_dir)
    except (ValueError, OverflowError, FloatingPointError, RuntimeError, OSError, Warning) as e:
        first = (str(e).strip().splitlines() or [type(e).__name__])[0]
        raise ConfigError(f"{out_dir}: cannot draw {draw.__name__[5:]}: {first}") from None
