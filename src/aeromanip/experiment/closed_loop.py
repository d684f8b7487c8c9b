"""The closed loop of a scenario: controller and simulator, step by step, one log row each.

``fly`` hands every row to a sink as it is made (the runner streams them to disk, so a run
keeps what it flew and its memory stays flat); ``simulate`` collects them into a
``RunLog`` for use from Python. Between steps the loop checks for a stop signal that C
code may have swallowed (``aeromanip.interrupts``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import casadi as ca
import numpy as np

from aeromanip.experiment.progress import Progress
from aeromanip.experiment.runlog import RunLog, contract_columns
from aeromanip.experiment.scenario import Scenario
from aeromanip.interrupts import deferred, raise_if_interrupted
from aeromanip.nmpc.constraints import Clearance
from aeromanip.nmpc.controller import Command, Controller
from aeromanip.nmpc.strategies import STRATEGIES
from aeromanip.realtime import setup_frozen
from aeromanip.robot.spec import PLATFORM_DOFS
from aeromanip.sim.base import SIMULATORS, Simulator
from aeromanip.sim.contact import PROBE_RADIUS, read_surfaces

Row = dict[str, Any]


def make_simulator(sc: Scenario) -> Simulator:
    """The scenario's simulator (``sim``: a registered name or ``package.module:Class``)."""
    cls = SIMULATORS.get(sc.sim, "sim")
    return cls.from_options(sc.robot, sc.sim_options)


def make_controller(sc: Scenario) -> Controller:
    """The scenario's controller."""
    return Controller(
        sc.problem,
        sc.strategy,
        sc.backend,
        sc.solver_options,
        hierarchy=sc.hierarchy or None,
        time_budget_s=sc.time_budget_s,
        latency_s=sc.latency_s,
    )


def log_columns(sc: Scenario, sim: Simulator) -> list[str]:
    """Every column a run of ``sc`` on ``sim`` logs, in order (the contract's first)."""
    cols = [*contract_columns(sc.robot.n_joints), "iterations", "message"]
    cols += [f"clear_{p}" for p in clearance_points(sc)]
    cols += [f"cost_{e.name}" for e in sc.problem.entries]
    cols += list(sc.problem.observations(0.0))
    if STRATEGIES.get(sc.strategy).by_level:  # per level: optimum, gain, loss
        for lvl in sc.problem.levels:
            cols += [f"level{lvl}_{k}" for k in ("cost", "objective", "gain", "loss")]
    return cols + [k for k in sim.extras() if k not in cols]


def run_meta(sc: Scenario) -> dict[str, Any]:
    """``meta.json``: what the plots and metrics need to read the log alone."""
    meta: dict[str, Any] = {
        "scenario": sc.name,
        "state_names": list(sc.robot.state_names),
        # the true limits (the NMPC may plan with tightened ones)
        "bounds": sc.limits.as_dict(),
        "strategy": sc.strategy,
        "backend": sc.backend,
        "dt": sc.problem.dt,
        "horizon": sc.problem.horizon,
        "sim": sc.sim,
    }
    if sc.clearance is not None:
        meta["clearance_min"] = sc.clearance.d_min
        meta["clearance_planned"] = min(
            c.d_min for c in sc.problem.constraints if isinstance(c, Clearance)
        )
    surfaces = sc.sim_options.get("surfaces") if sc.sim == "physics" else None
    if surfaces:  # the contact metrics' tangents; the replay's and the MCAP's surfaces
        checked = read_surfaces(surfaces)  # checked when built
        meta["surface_normals"] = [list(s.normal) for s in checked]
        meta["surfaces"] = [
            {"point": list(s.point), "normal": list(s.normal), "size": list(s.size),
             "thickness": s.thickness, "tangents": [list(t) for t in s.tangents()]}
            for s in checked
        ]  # fmt: skip
        meta["probe_radius"] = float(sc.sim_options.get("probe_radius", PROBE_RADIUS))
    if (markers := sc.reference.markers()) is not None:
        meta["waypoints"] = np.asarray(markers).tolist()
    return meta


def clearance_points(sc: Scenario) -> list[str]:
    """The arm points whose depth below the base is logged (``clear_<point>``)."""
    kin = sc.problem.kin
    if sc.clearance is not None and sc.clearance.points is not None:
        return list(sc.clearance.points)
    return kin.default_clearance_points()


def _log_function(sc: Scenario) -> ca.Function:
    """EE position, arm CoG (body xy), D, the exact rho (no regularisation: that is for
    the cost only) and each clearance point's depth below the base, of a state."""
    kin = sc.problem.kin
    x = kin.symbols()[0]
    tracked = sc.tracked if len(sc.tracked) <= kin.n_joints else sc.tracked[: kin.n_joints]
    outs = [
        kin.ee_position(x),
        kin.cog_body(x)[:2],
        kin.manipulability(tracked)(x),
        kin.condition_number(tracked, delta=0.0)(x),
        kin.clearance(clearance_points(sc))(x),
    ]
    return ca.Function("log", [x], outs)


class RowMaker:
    """Builds a log row from the true state, the command and the simulator's extras."""

    def __init__(self, sc: Scenario) -> None:
        self.sc = sc
        self.by_level = STRATEGIES.get(sc.strategy).by_level  # per-level columns
        self.log_f = _log_function(sc)
        spec = sc.robot
        names = spec.state_names
        fixed = {d: float(spec.platform.fixed.get(d, 0.0)) for d in PLATFORM_DOFS}
        #: per platform DoF: its index in the state, or its fixed value
        self.platform = [
            (d, names.index(d) if d in names else None, fixed[d]) for d in PLATFORM_DOFS
        ]
        self.joints = [(i + 1, spec.n_platform + i) for i in range(spec.n_joints)]
        self.points = [f"clear_{p}" for p in clearance_points(sc)]

    def row(self, t: float, x: np.ndarray, ee: np.ndarray | None, cmd: Command) -> Row:
        """The row of time ``t`` [s]: state ``x``, the physical EE (if the simulator has
        one) and the command decided at ``t``."""
        e, cog, manip, cond, clear = (np.asarray(v).ravel() for v in self.log_f(x))
        ee = e if ee is None else np.asarray(ee, dtype=float)
        ref = self.sc.reference.position(t)
        row: Row = {"t": t}
        row.update({d: (x[i] if i is not None else v) for d, i, v in self.platform})
        row.update({f"q{j}": x[i] for j, i in self.joints})
        row.update({f"u_{d}": (cmd.u[i] if i is not None else 0.0) for d, i, _ in self.platform})
        row.update({f"u_q{j}": cmd.u[i] for j, i in self.joints})
        row.update(ee_x=ee[0], ee_y=ee[1], ee_z=ee[2], ref_x=ref[0], ref_y=ref[1], ref_z=ref[2])
        row.update(cog_bx=cog[0], cog_by=cog[1], manip=manip[0], cond=cond[0])
        row.update(zip(self.points, clear, strict=True), clearance=float(np.min(clear)))
        row.update(
            solve_ms=1e3 * cmd.solve_time_s,
            status=cmd.status,
            iterations=cmd.iterations,
            message=cmd.message,
        )
        row.update({f"cost_{n}": c for n, c in cmd.task_costs.items()})
        row.update(cmd.observations)
        if self.by_level:
            for lv in cmd.levels:
                for key in ("cost", "objective", "gain", "loss"):
                    row[f"level{lv.level}_{key}"] = getattr(lv, key)
        return row


def fly(
    sc: Scenario,
    sink: Callable[[Row], None],
    *,
    progress: bool = True,
    ctrl: Controller | None = None,
    sim: Simulator | None = None,
) -> int:
    """Fly the closed loop of ``sc``, handing each row to ``sink``; return the steps flown.

    With a latency (``Controller.latency_s``) the command decided at ``t`` takes effect
    at ``t + latency``: the previous one flies until then, continuing its ramp (and the
    simulator's period means cover the new command's part of the period). A signal stops
    the loop between steps with ``RunInterrupted`` (rows already handed over are the
    run's record). ``ctrl`` and ``sim`` default to the scenario's.
    """
    ctrl = ctrl or make_controller(sc)
    sim = sim or make_simulator(sc)
    dt, maker, lag = sc.problem.dt, RowMaker(sc), ctrl.latency_s
    measure_rates = ctrl.problem.model.has_response
    sim.reset(sc.x0)
    held_u, held_start = np.zeros(sc.robot.nx), np.asarray(sc.x0, dtype=float)
    bar = Progress(sc.steps, sc.name) if progress else None
    with setup_frozen():  # no full garbage collection inside a step
        try:
            for k in range(sc.steps):
                raise_if_interrupted()
                t = k * dt
                # a signal is raised between steps, never inside CasADi's or MuJoCo's C calls
                # (one landing in a conversion of their results surfaced as a SystemError)
                with deferred():
                    rates = sim.rates() if measure_rates else None
                    measured = (sim.measured_wrench(), sim.measured_attitude())
                    cmd = ctrl.step(sim.state(), t, rates, *measured)
                    row = maker.row(t, sim.true_state(), sim.ee_position(), cmd)
                    now = {n: v for n, v in sim.extras().items() if n in sim.instant_extras}
                    if lag > 0:
                        sim.advance(held_u, held_start, lag)
                    if cmd.force_ff is not None:  # from now on (the previous one flew the lag)
                        sim.set_force_feedforward(cmd.force_ff)
                    sim.advance(cmd.u, cmd.plan_x, dt - lag)
                    held_u, held_start = cmd.u, cmd.plan_x[0] + (dt - lag) * cmd.u
                    row.update(sim.extras())  # means over the period this row's command flew
                    row.update(now)  # values at this row's time, as the state
                    sink(row)  # a step flown is a row kept
                if bar is not None:
                    bar.update(k + 1)
        finally:
            if bar is not None:
                bar.close()
    return sc.steps


def simulate(sc: Scenario, progress: bool = False) -> RunLog:
    """Run the closed loop of ``sc`` in memory and return its log."""
    rows: list[Row] = []
    fly(sc, rows.append, progress=progress)
    return RunLog.from_rows(rows, meta=run_meta(sc))
