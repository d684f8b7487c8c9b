"""The closed loop: controller and simulator, step by step, into a ``RunLog``; run outputs.

A run directory holds (DESIGN.md contract): ``config.toml`` (the resolved scenario),
``robot.urdf``, ``log.csv`` (+ ``meta.json``), ``summary.json`` and ``figures/*.png``;
physics runs also ``robot.xml``, the MJCF model flown.
A scenario with variants writes one such directory per variant plus comparison figures.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np
import tomli_w

from aeromanip.experiment.plots import plot_comparison, plot_run
from aeromanip.experiment.runlog import RunLog, motion_share, write_summary
from aeromanip.experiment.scenario import Scenario
from aeromanip.nmpc.controller import Controller
from aeromanip.references import SinusoidPhases, Waypoints
from aeromanip.robot.spec import PLATFORM_DOFS
from aeromanip.robot.urdf_export import robot_to_urdf
from aeromanip.sim.base import SIMULATORS, Simulator


def make_simulator(sc: Scenario) -> Simulator:
    """The scenario's simulator (``sim``: a registered name or ``package.module:Class``)."""
    cls = SIMULATORS.get(sc.sim, "sim")
    options = sc.physics if cls.options_table == "physics" else {}
    return cls.from_options(sc.robot, options)


def make_controller(sc: Scenario) -> Controller:
    """The scenario's controller."""
    return Controller(
        sc.problem,
        sc.strategy,
        sc.backend,
        sc.solver_options,
        hierarchy=sc.hierarchy or None,
        time_budget_s=sc.time_budget_s,
    )


def _log_function(sc: Scenario) -> ca.Function:
    kin = sc.problem.kin
    x = kin.symbols()[0]
    tracked = sc.tracked if len(sc.tracked) <= kin.n_joints else sc.tracked[: kin.n_joints]
    clearance = sc.clearance.points if sc.clearance is not None else None
    outs = [
        kin.ee_position(x),
        kin.cog_body(x)[:2],
        kin.manipulability(tracked)(x),
        kin.condition_number(tracked)(x),
        ca.mmin(kin.clearance(clearance)(x)),
    ]
    return ca.Function("log", [x], outs)


class Progress:
    """A one-line progress bar on a terminal, shown once a run lasts over ``after`` seconds."""

    def __init__(self, total: int, label: str, after: float = 2.0) -> None:
        self.total, self.label, self.after = total, label, after
        self.t0 = time.perf_counter()
        self.last = 0.0
        self.enabled = sys.stderr.isatty()

    def update(self, done: int) -> None:
        """Redraw (at most 10 times a second)."""
        now = time.perf_counter() - self.t0
        if not self.enabled or now < self.after or now - self.last < 0.1:
            return
        self.last = now
        frac = done / self.total
        eta = now / max(frac, 1e-9) - now
        bar = "#" * int(30 * frac)
        sys.stderr.write(f"\r{self.label} [{bar:<30}] {100 * frac:5.1f}%  eta {eta:5.0f} s ")
        sys.stderr.flush()

    def close(self) -> None:
        """Clear the line."""
        if self.enabled and time.perf_counter() - self.t0 >= self.after:
            sys.stderr.write("\r" + " " * 79 + "\r")
            sys.stderr.flush()


def simulate(
    sc: Scenario, progress: bool = True, on_step: Callable[[int, dict], None] | None = None
) -> RunLog:
    """Run the closed loop of ``sc`` and return its log."""
    ctrl, sim = make_controller(sc), make_simulator(sc)
    spec, dt = sc.robot, sc.problem.dt
    log_f = _log_function(sc)
    names = spec.state_names
    platform = {d: float(spec.platform.fixed.get(d, 0.0)) for d in PLATFORM_DOFS}
    sim.reset(sc.x0)
    bar = Progress(sc.steps, sc.name) if progress else None
    rows = []
    for k in range(sc.steps):
        t = k * dt
        measured = sim.state()
        cmd = ctrl.step(measured, t)
        x = sim.true_state()
        ee, cog, manip, cond, clear = (np.asarray(v).ravel() for v in log_f(x))
        physical_ee = sim.ee_position()
        if physical_ee is not None:
            ee = np.asarray(physical_ee, dtype=float)
        ref = sc.reference.position(t)
        row: dict[str, Any] = {"t": t}
        for d in PLATFORM_DOFS:
            row[d] = x[names.index(d)] if d in names else platform[d]
        row.update({f"q{i + 1}": x[spec.n_platform + i] for i in range(spec.n_joints)})
        for d in PLATFORM_DOFS:
            row[f"u_{d}"] = cmd.u[names.index(d)] if d in names else 0.0
        row.update({f"u_q{i + 1}": cmd.u[spec.n_platform + i] for i in range(spec.n_joints)})
        row.update(
            {
                "ee_x": ee[0],
                "ee_y": ee[1],
                "ee_z": ee[2],
                "ref_x": ref[0],
                "ref_y": ref[1],
                "ref_z": ref[2],
                "cog_bx": cog[0],
                "cog_by": cog[1],
                "manip": manip[0],
                "cond": cond[0],
                "clearance": clear[0],
                "solve_ms": 1e3 * cmd.solve_time_s,
                "iterations": cmd.iterations,
                "status": cmd.status,
            }
        )
        row.update({f"cost_{n}": c for n, c in cmd.task_costs.items()})
        if sc.strategy == "hierarchical":  # per level: optimal cost, what optimising it gained
            for lv in cmd.levels:
                row[f"level{lv.level}_cost"] = lv.cost
                row[f"level{lv.level}_gain"] = lv.gain
        now = {k: v for k, v in sim.extras().items() if k in sim.instant_extras}
        sim.advance(cmd.u, cmd.plan_x, dt)
        row.update(sim.extras())  # means over the period this row's command flew
        row.update(now)  # values at this row's time, as the state
        rows.append(row)
        if on_step is not None:
            on_step(k, row)
        if bar is not None:
            bar.update(k + 1)
    if bar is not None:
        bar.close()
    return RunLog.from_rows(rows, meta=_meta(sc))


def _meta(sc: Scenario) -> dict[str, Any]:
    bounds = sc.limits.as_dict()  # the true limits (the NMPC may plan with tightened ones)
    meta: dict[str, Any] = {
        "scenario": sc.name,
        "state_names": list(sc.robot.state_names),
        "bounds": bounds,
        "strategy": sc.strategy,
        "backend": sc.backend,
        "dt": sc.problem.dt,
        "horizon": sc.problem.horizon,
        "sim": sc.sim,
    }
    if sc.clearance is not None:
        meta["clearance_min"] = sc.clearance.d_min
    if isinstance(sc.reference, Waypoints):
        meta["waypoints"] = np.asarray(sc.reference.points).tolist()
    return meta


def write_run(sc: Scenario, log: RunLog, out_dir: Path, figures: bool = True) -> dict[str, Any]:
    """Write the run directory; return its summary."""
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "config.toml").write_text(tomli_w.dumps(_toml_safe(sc.resolved)))
    (out_dir / "robot.urdf").write_text(robot_to_urdf(sc.robot))
    if sc.sim == "physics":  # the model flown: python -m mujoco.viewer --mjcf=robot.xml
        (out_dir / "robot.xml").write_text(make_simulator(sc).to_xml())
    log.save(out_dir)
    summary = log.summary()
    if isinstance(sc.reference, SinusoidPhases):  # who carries each phase (Fig. 3's claim)
        ref = sc.reference
        ends = [*ref.phase_starts[1:], ref.duration]
        summary["phases"] = [
            {"t0_s": float(t0), "t1_s": float(t1)}
            | {
                f"{k}_share": v
                for k, v in motion_share(log, t0, t1, ref.direction).items()
                if k in ("arm", "platform")
            }
            for t0, t1 in zip(ref.phase_starts, ends, strict=True)
        ]
    summary.update(
        {
            "scenario": sc.name,
            "strategy": sc.strategy,
            "backend": sc.backend,
            "sim": sc.sim,
            "duration_s": sc.duration,
        }
    )
    write_summary(out_dir, summary)
    if figures:
        plot_run(log, out_dir / "figures")
    return summary


def _toml_safe(v: Any) -> Any:
    """Drop ``None`` values (TOML has no null); everything else tomli_w writes as is."""
    if isinstance(v, dict):
        return {k: _toml_safe(x) for k, x in v.items() if x is not None}
    if isinstance(v, list | tuple):
        return [_toml_safe(x) for x in v]
    return v


def run_scenarios(
    scenarios: dict[str, Scenario], out_dir: Path, progress: bool = True, figures: bool = True
) -> dict[str, dict[str, Any]]:
    """Run every variant into ``out_dir`` (``out_dir/<variant>`` when there are several)."""
    summaries, logs = {}, {}
    for variant, sc in scenarios.items():
        d = out_dir / variant if variant else out_dir
        log = simulate(sc, progress=progress)
        summaries[variant] = write_run(sc, log, d, figures)
        summaries[variant]["out_dir"] = str(d)
        logs[variant or sc.name] = log
    if len(logs) > 1:  # every variant's summary side by side
        write_summary(
            out_dir,
            {v: {k: x for k, x in s.items() if k != "out_dir"} for v, s in summaries.items()},
        )
        if figures:
            plot_comparison(logs, out_dir / "figures")
    return summaries
