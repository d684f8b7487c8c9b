"""Scenarios: one TOML file describes a whole closed-loop run (and its variants).

Layout (see the built-in files in ``aeromanip/scenarios/`` for documented examples)::

    extends = "flight" | "other.toml"   (start from that scenario, override key by key)
    name, description, duration [s], initial_state [nx],
    sim ("kinematic" | "physics" | "package.module:Class")
    robot = "x8-3dof"  |  robot = "path/robot.toml"  |  [robot] ... (inline robot table)
    [controller]  strategy, backend (a name or "package.module:Class"), horizon, dt,
                  time_budget, latency [s] (command delay, compensated by prediction),
                  weights_dt [s] (the period the weights were tuned at: rescaled to dt),
                  [hierarchy], [solver_options],
                  [response] (per DoF name or "default": rate time constants [s])
    [bounds]      joints, velocity (bools), platform_box = { z = [lo, hi], ... },
                  platform_margin [m], joint_margin [rad] (the NMPC plans inside the
                  box and joint limits shrunk by them), margin_ramp [s] (the shrinking
                  grows from 0 at the measured state to the margins over this time of
                  the horizon; 0: at once), acceleration = { x = a, ..., default = a }
                  [m/s^2, rad/s^2] (command-rate bounds)
    [clearance]   d_min, points, margin [m] (planned at d_min + margin; omit the table
                  for no self-collision constraint)
    [reference]   kind = "sinusoids" | "waypoints" | "lissajous" | "csv" | "constant" |
                  "package.module:Class" (a Reference of your own), and its keys
    [tasks.NAME]  kind (default NAME; or "package.module:Class"), weight, terminal_weight,
                  level | regularizer = true, and the task's own options (tracked,
                  target_xy, eps, delta, kink: see each task's ``from_table``)
    [physics]     options of the physics simulator (any simulator names its own
                  table: ``Simulator.options_table``)
    [variants.NAME]  overrides merged into the scenario, e.g. ``tasks.cond.weight = 0.0``

Every value read is recorded (defaults included) so that ``resolved`` written as TOML
reproduces the run exactly.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from aeromanip.config import Table, load_toml, resolve_toml
from aeromanip.errors import ConfigError
from aeromanip.experiment.sources import builtin_scenarios, expand_variants, scenario_source
from aeromanip.nmpc.approach import APPROACH_GAIN, RELEASE, ApproachSpeed
from aeromanip.nmpc.backends import BACKENDS
from aeromanip.nmpc.constraints import D_MIN, Bounds, Clearance
from aeromanip.nmpc.model import MAX_TAU
from aeromanip.nmpc.problem import Problem
from aeromanip.nmpc.strategies import (
    ABS_TOL,
    MAX_ABS_TOL,
    MAX_REL_TOL,
    MODE,
    REL_TOL,
    STRATEGIES,
)
from aeromanip.nmpc.transcription import MODES
from aeromanip.references import Reference, reference_from_table
from aeromanip.robot.loader import robot_from_table
from aeromanip.robot.spec import RobotSpec
from aeromanip.sim.base import SIMULATORS
from aeromanip.sim.contact import PROBE_RADIUS, read_probe_radius, read_surfaces
from aeromanip.tasks import TASKS, EndEffectorTracking, SurfaceTask
from aeromanip.tasks.contact import Plane

__all__ = ["Scenario", "build_scenario", "builtin_scenarios", "load_scenarios"]

MIN_DT = 1e-3  # [s] the fastest control period (1 kHz)
MAX_DT = 60.0  # [s]
MAX_HORIZON = 500  # steps (the NLP grows with it: N = 100 covers 5 s at 20 Hz)
MAX_DURATION = 1e6  # [s] about 11.6 days
MAX_STEPS = 10_000_000  # control steps in one run
MAX_FAILURE_RATIO = 0.05  # a run with more failed steps than this share did not fly
MAX_BOUND_VIOLATION = 0.02  # [m, rad] a run whose state left a bound by more did not fly
MAX_MARGIN_RAMP_S = 60.0  # [s] bounds.margin_ramp


@dataclass
class Scenario:
    """A resolved scenario: everything needed to build and run the closed loop."""

    name: str
    description: str
    robot: RobotSpec
    problem: Problem
    reference: Reference
    strategy: str
    backend: str
    solver_options: dict[str, Any]
    hierarchy: dict[str, Any]
    time_budget_s: float | None
    latency_s: float
    duration: float
    x0: np.ndarray
    sim: str
    physics: dict[str, Any]
    tracked: str
    clearance: Clearance | None
    limits: Bounds
    max_failure_ratio: float = MAX_FAILURE_RATIO
    max_bound_violation: float = MAX_BOUND_VIOLATION
    resolved: dict[str, Any] = field(default_factory=dict)
    #: the simulator's options: the table its ``options_table`` names (``[physics]``...)
    sim_options: dict[str, Any] = field(default_factory=dict)

    @property
    def steps(self) -> int:
        """Control steps in the run."""
        return round(self.duration / self.problem.dt)


@dataclass
class ControllerSettings:
    """The ``[controller]`` table, read."""

    horizon: int
    dt: float
    strategy: str
    backend: str
    time_budget_s: float | None
    latency_s: float
    weights_dt: float | None
    response_tau: np.ndarray | None
    hierarchy: dict[str, Any]
    solver_options: dict[str, Any]


def _robot(t: Table, base_dir: Path) -> RobotSpec:
    raw = t.data.get("robot")
    if isinstance(raw, str):  # a built-in name or a robot TOML file: inlined when resolved
        p = Path(raw)
        path = resolve_toml(
            base_dir / p if p.suffix == ".toml" else raw, "aeromanip.robots", "robot"
        )
        return robot_from_table(t.sub("robot", load_toml(path)), base_dir=path.parent, source=path)
    return robot_from_table(t.table("robot"), base_dir=base_dir)


def per_dof(
    table: Table, names: tuple[str, ...], default: float, minimum: float, maximum: float
) -> np.ndarray:
    """A table of values keyed by state name (``default`` for the others, or the table's
    own ``default`` key), each checked within ``[minimum, maximum]``."""
    unknown = set(table.data) - set(names) - {"default"}
    if unknown:
        key = table.key(sorted(unknown)[0])
        raise ConfigError(f"{key}: unknown DoF (use {list(names)} or 'default')")
    fallback = table.float("default", default, finite=False, minimum=minimum, maximum=maximum)
    return np.array(
        [
            table.float(n, fallback, finite=False, minimum=minimum, maximum=maximum)
            if n in table.data
            else fallback
            for n in names
        ]
    )


def _controller(t: Table, robot: RobotSpec) -> ControllerSettings:
    ct = t.table("controller")
    horizon = ct.int("horizon", minimum=1, maximum=MAX_HORIZON)
    dt = ct.float("dt", minimum=MIN_DT, maximum=MAX_DT)
    strategy = ct.str("strategy", "weighted")
    by_level = STRATEGIES.get(strategy, ct.key("strategy")).by_level  # known, or loads
    backend = ct.str("backend", "ipopt")
    backend_cls = BACKENDS.get(backend, ct.key("backend"))  # known, or a class that loads
    budget = ct.raw("time_budget", None)
    budget = None if budget is None else ct.float("time_budget", positive=True)
    latency = ct.float("latency", 0.0, minimum=0.0)
    if latency >= dt:
        raise ConfigError(f"{ct.key('latency')}: must be below dt = {dt:g} s, got {latency:g}")
    weights_dt = ct.raw("weights_dt", None)
    if weights_dt is not None:
        weights_dt = ct.float("weights_dt", minimum=MIN_DT, maximum=MAX_DT)
    tau = None
    if ct.has("response"):
        tau = per_dof(ct.table("response"), robot.state_names, 0.0, 0.0, MAX_TAU)
    hierarchy = {}
    if by_level or ct.has("hierarchy"):
        ht = ct.table("hierarchy", {})
        hierarchy = {
            "mode": ht.str("mode", MODE, choices=MODES),
            "rel_tol": ht.float("rel_tol", REL_TOL, minimum=0.0, maximum=MAX_REL_TOL),
            "abs_tol": ht.float("abs_tol", ABS_TOL, minimum=0.0, maximum=MAX_ABS_TOL),
        }
        if ht.has("regularizer_scale"):  # default: Hierarchical's, by mode
            scale = ht.float("regularizer_scale", positive=True, maximum=1.0)
            hierarchy["regularizer_scale"] = scale
        ht.done()
        if not by_level:
            hierarchy = {}  # a weighted variant of a hierarchical scenario: not used
    solver_options = dict(ct.table("solver_options", {}).data)
    backend_cls.check_options(solver_options, horizon)  # before anything is built
    ct.resolved["solver_options"] = solver_options
    ct.done()
    return ControllerSettings(
        horizon, dt, strategy, backend, budget, latency, weights_dt, tau, hierarchy, solver_options
    )


def _bounds(t: Table, robot: RobotSpec) -> tuple[Bounds, Bounds]:
    """The true limits and the (tightened) bounds the NMPC plans with."""
    bt = t.table("bounds", {})
    box_t = bt.table("platform_box", {})
    box = {k: box_t.floats(k, size=2, finite=False) for k in box_t.data}
    margins = {
        "platform_margin": bt.float("platform_margin", 0.0),
        "joint_margin": bt.float("joint_margin", 0.0),
    }
    for key, m in margins.items():
        if m < 0:
            raise ConfigError(f"{bt.key(key)}: must be >= 0, got {m}")
    ramp = bt.float("margin_ramp", Bounds.margin_ramp, minimum=0.0, maximum=MAX_MARGIN_RAMP_S)
    flags = {"joint_limits": bt.bool("joints", True), "velocity_limits": bt.bool("velocity", True)}
    limits = Bounds.from_robot(robot, platform_box=box, **flags)
    if bt.has("acceleration"):
        at = bt.table("acceleration")
        accel = per_dof(at, robot.state_names, np.inf, 0.0, np.inf)
        if np.any(accel <= 0):
            raise ConfigError(f"{at.key(robot.state_names[int(np.argmin(accel))])}: must be > 0")
        limits = limits.with_accel(accel)
    # constraint tightening: the NMPC plans inside bounds shrunk by the margins, so that the
    # real robot, lagging its references a little (physics), stays inside the true ones
    shrink = {d: margins["platform_margin"] for d in box}
    if flags["joint_limits"]:
        shrink.update({f"q{i + 1}": margins["joint_margin"] for i in range(robot.n_joints)})
    bt.done()
    for dof, m in shrink.items():  # a margin may not close a bound: say which key
        i = limits.names.index(dof)
        lo, hi = limits.x_lower[i], limits.x_upper[i]
        if lo + m > hi - m:
            key = bt.key("joint_margin" if dof.startswith("q") else "platform_margin")
            raise ConfigError(
                f"{key}: {m:g} closes the bounds of {dof} [{lo:.4g}, {hi:.4g}] "
                f"(at most {(hi - lo) / 2:.4g})"
            )
    return limits, limits.tightened(shrink, ramp)


def _weight(tt: Table, key: str, default: Any) -> Any:
    if isinstance(tt.data.get(key), dict):
        wt = tt.table(key)
        return {k: wt.float(k) for k in wt.data}
    v = tt.raw(key, default)
    if isinstance(v, list):
        return list(tt.floats(key))
    return tt.float(key) if key in tt.data else v


def _scenario_surfaces(t: Table) -> tuple[list[Plane], float]:
    """The (point, normal) of each ``[[physics.surfaces]]`` entry (checked) and the probe's
    radius [m], for tasks on a surface (read again with the simulator's options)."""
    physics = t.data.get("physics", {})
    if not isinstance(physics, dict):
        return [], PROBE_RADIUS
    surfaces = read_surfaces(physics.get("surfaces", []))
    radius = read_probe_radius(physics.get("probe_radius", PROBE_RADIUS))
    return [(s.point, s.normal) for s in surfaces], radius


def _tasks(t: Table, problem: Problem, reference: Reference) -> str:
    """Add the ``[tasks.NAME]`` tables to ``problem``; return the tracked coordinates."""
    tracked = "xyz"
    planes: tuple[list[Plane], float] | None = None
    tasks_t = t.table("tasks")
    if not tasks_t.data:
        raise ConfigError("tasks: the scenario needs at least one task")
    for task_name in tasks_t.data:
        tt = tasks_t.table(task_name)
        kind = tt.str("kind", task_name if task_name in TASKS else "")
        cls = TASKS.get(kind, tt.key("kind"))
        regularizer = tt.bool("regularizer", False)
        level = None if regularizer else tt.int("level", 0, minimum=0)
        weight = _weight(tt, "weight", 1.0)
        terminal = _weight(tt, "terminal_weight", None)
        task = cls.from_table(tt, reference)
        if isinstance(task, EndEffectorTracking):
            tracked = task.tracked
        if isinstance(task, SurfaceTask):
            planes = planes or _scenario_surfaces(t)
            try:
                task.use_scenario(*planes)
            except ConfigError as e:
                raise ConfigError(f"tasks.{task_name}: {e}") from None
        tt.done()
        problem.add_task(task, weight, terminal, level, name=task_name)
    tasks_t.done()
    return tracked


def _clearance(t: Table, problem: Problem) -> Clearance | None:
    """The ``[clearance]`` table: the true constraint; the NMPC plans ``margin`` inside it."""
    if not t.has("clearance"):
        return None
    cl = t.table("clearance")
    points = cl.raw("points", None)
    if points is not None and (
        not isinstance(points, list) or not points or not all(isinstance(p, str) for p in points)
    ):
        raise ConfigError(f"{cl.key('points')}: expected a non-empty array of point names")
    clearance = Clearance(cl.float("d_min", D_MIN), points)
    problem.kin.clearance(points)  # unknown point names fail here, naming the key
    margin = cl.float("margin", 0.0, minimum=0.0)
    cl.done()
    # the NMPC keeps margin more than d_min: a real arm lags its plan a little
    problem.add_constraint(Clearance(clearance.d_min + margin, points))
    return clearance


def _approach(t: Table, problem: Problem) -> None:
    """The ``[approach]`` table: a bounded approach speed near a surface (``nmpc.approach``)."""
    if not t.has("approach"):
        return
    at = t.table("approach")
    planes, radius = _scenario_surfaces(t)
    index = at.int("surface", 0, minimum=0)
    if index >= len(planes):
        raise ConfigError(
            f"{at.key('surface')}: {index}, but the scenario has {len(planes)} "
            "[[physics.surfaces]] (indices from 0)"
        )
    speed, distance = at.float("speed"), at.float("distance")
    gain, release = at.float("gain", APPROACH_GAIN), at.float("release", RELEASE)
    at.done()
    problem.add_constraint(ApproachSpeed(*planes[index], speed, distance, gain, radius, release))


def _initial_state(
    t: Table, problem: Problem, bounds: Bounds, clearance: Clearance | None
) -> np.ndarray:
    """``initial_state``: inside the state bounds and the clearance constraint."""
    x0 = np.array(t.floats("initial_state", size=problem.robot.nx))
    if bounds.violation(x0) > 0:
        raise ConfigError(f"initial_state: outside the state bounds by {bounds.violation(x0):.3g}")
    if clearance is not None:
        depth = float(np.min(np.asarray(problem.kin.clearance(clearance.points)(x0))))
        if depth < clearance.d_min:
            raise ConfigError(
                f"initial_state: an arm point is {depth:.4g} m below the base, "
                f"clearance.d_min is {clearance.d_min:g} m"
            )
    return x0


def _simulation(
    t: Table, robot: RobotSpec, cs: ControllerSettings
) -> tuple[str, dict[str, Any], dict[str, Any]]:
    """The simulator's name, the ``[physics]`` options (read even when not used: the
    SITL autopilot flies the physics simulator) and the simulator's own options (the
    table its ``options_table`` names; none if it names none); the control period and
    the latency are whole numbers of the simulator's steps."""
    sim = t.str("sim", "kinematic")
    cls = SIMULATORS.get(sim, t.key("sim"))
    physics = dict(t.table("physics", {}).data)
    t.resolved["physics"] = physics
    table = cls.options_table
    if table is None:
        options: dict[str, Any] = {}
    elif table == "physics":
        options = physics
    else:
        options = dict(t.table(table, {}).data)
        t.resolved[table] = options
    if table is not None:  # checked now, built when the run starts
        cls.check_options(options)
    h = cls.time_step(options)
    for key, value in (("dt", cs.dt), ("latency", cs.latency_s)):
        if h is not None and abs(value / h - round(value / h)) > 1e-6:
            raise ConfigError(
                f"controller.{key}: {value:g} s is not a whole number of the {sim} "
                f"simulator's steps ({h:g} s)"
            )
    return sim, physics, options


def build_scenario(data: dict[str, Any], base_dir: Path, variant: str = "") -> Scenario:
    """Build a ``Scenario`` from one variant's table; errors name the key path."""
    t = Table(data)
    name, description = t.str("name"), t.str("description", "")
    if not name or "/" in name or name in (".", ".."):
        raise ConfigError(f"name: {name!r} must be a non-empty name without '/' (a directory)")
    robot = _robot(t, base_dir)
    cs = _controller(t, robot)
    limits, bounds = _bounds(t, robot)
    problem = Problem(robot, cs.horizon, cs.dt, bounds, cs.response_tau, cs.weights_dt)
    reference = reference_from_table(t.table("reference"), base_dir=base_dir)
    tracked = _tasks(t, problem, reference)
    clearance = _clearance(t, problem)
    _approach(t, problem)
    x0 = _initial_state(t, problem, bounds, clearance)
    sim, physics, sim_options = _simulation(t, robot, cs)
    duration = t.float("duration", minimum=cs.dt, maximum=MAX_DURATION)
    if duration / cs.dt > MAX_STEPS:
        raise ConfigError(
            f"duration: {duration:g} s at controller.dt = {cs.dt:g} s is "
            f"{duration / cs.dt:.3g} steps; at most {MAX_STEPS:g} in one run"
        )
    max_failure_ratio = t.float("max_failure_ratio", MAX_FAILURE_RATIO, minimum=0.0, maximum=1.0)
    max_bound_violation = t.float("max_bound_violation", MAX_BOUND_VIOLATION, minimum=0.0)
    t.done()
    resolved = dict(t.resolved)
    if variant:
        resolved["name"] = f"{name}/{variant}"
    return Scenario(
        name=resolved["name"],
        description=description,
        robot=robot,
        problem=problem,
        reference=reference,
        strategy=cs.strategy,
        backend=cs.backend,
        solver_options=cs.solver_options,
        hierarchy=cs.hierarchy,
        time_budget_s=cs.time_budget_s,
        latency_s=cs.latency_s,
        duration=duration,
        x0=x0,
        sim=sim,
        physics=physics,
        sim_options=sim_options,
        tracked=tracked,
        clearance=clearance,
        limits=limits,
        max_failure_ratio=max_failure_ratio,
        max_bound_violation=max_bound_violation,
        resolved=resolved,
    )


def load_scenarios(
    name_or_path: str | Path, overrides: list[str] = (), only: str | None = None
) -> dict[str, Scenario]:
    """Every variant of a scenario, built: {variant name ("" if none): Scenario}."""
    data, base_dir = scenario_source(name_or_path)
    return {
        v: build_scenario(d, base_dir, v) for v, d in expand_variants(data, overrides, only).items()
    }
