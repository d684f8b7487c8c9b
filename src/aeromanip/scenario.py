"""Scenarios: one TOML file describes a whole closed-loop run (and its variants).

Layout (see the built-in files in ``aeromanip/scenarios/`` for documented examples)::

    extends = "flight" | "other.toml"   (start from that scenario, override key by key)
    name, description, duration [s], initial_state [nx], sim ("kinematic" | "physics")
    robot = "x8-3dof"  |  robot = "path/robot.toml"  |  [robot] ... (inline robot table)
    [controller]  strategy, backend, horizon, dt, time_budget, [hierarchy], [solver_options]
    [bounds]      joints, velocity (bools), platform_box = { z = [lo, hi], ... },
                  platform_margin [m], joint_margin [rad] (the NMPC plans inside the
                  box and joint limits shrunk by them)
    [clearance]   d_min, points, margin [m] (planned at d_min + margin; omit the table
                  for no self-collision constraint)
    [reference]   kind = "sinusoids" | "waypoints" | "lissajous" | "csv" | "constant" ...
    [tasks.NAME]  kind (default NAME), weight, terminal_weight, level | regularizer = true,
                  and the task's own options (tracked, target_xy, eps, delta, kink)
    [physics]     options of the physics simulator
    [variants.NAME]  overrides merged into the scenario, e.g. ``tasks.cond.weight = 0.0``

Every value read is recorded (defaults included) so that ``resolved`` written as TOML
reproduces the run exactly.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from aeromanip.config import (
    Table,
    apply_override,
    builtin_descriptions,
    load_toml,
    parse_override,
    resolve_toml,
)
from aeromanip.constraints import Bounds, Clearance
from aeromanip.errors import ConfigError
from aeromanip.ocp import MODES, Problem
from aeromanip.references import Reference, reference_from_table
from aeromanip.robot.loader import robot_from_table
from aeromanip.robot.spec import RobotSpec
from aeromanip.solvers import BACKENDS
from aeromanip.tasks import (
    CogAlignment,
    CogVelocity,
    ConditionNumber,
    ControlRate,
    EndEffectorTracking,
    Manipulability,
    Task,
)

TASK_KINDS = ("tracking", "cog", "cog_velocity", "manipulability", "condition", "control_rate")


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
    duration: float
    x0: np.ndarray
    sim: str
    physics: dict[str, Any]
    tracked: str
    clearance: Clearance | None
    limits: Bounds
    resolved: dict[str, Any] = field(default_factory=dict)

    @property
    def steps(self) -> int:
        """Control steps in the run."""
        return round(self.duration / self.problem.dt)


def builtin_scenarios() -> dict[str, str]:
    """Built-in scenario names mapped to their one-line description."""
    return builtin_descriptions("aeromanip.scenarios")


def scenario_source(name_or_path: str | Path, _seen: tuple[Path, ...] = ()) -> tuple[
    dict[str, Any], Path
]:
    """The raw TOML table of a built-in scenario name or a file, and its directory.

    A scenario may start from another: ``extends = "flight"`` (a built-in name or a file,
    relative to this one) takes that scenario's table and overrides it key by key.
    """
    path = resolve_toml(name_or_path, "aeromanip.scenarios", "scenario")
    data = load_toml(path)
    base = data.pop("extends", None)
    if base is None:
        return data, path.parent
    if not isinstance(base, str):
        raise ConfigError(f"{path}: extends: expected a scenario name or file, got {base!r}")
    if path in _seen:
        raise ConfigError(f"{path}: extends: a cycle ({' -> '.join(map(str, _seen))})")
    target = path.parent / base if base.endswith(".toml") else base
    parent, parent_dir = scenario_source(target, (*_seen, path))
    parent.pop("variants", None)  # variants are a scenario's own
    _anchor_paths(parent, parent_dir)  # its files stay where it names them
    return _merge(parent, data), path.parent


def _anchor_paths(data: dict[str, Any], base_dir: Path) -> None:
    """Make the relative file names of a scenario table absolute against ``base_dir``:
    ``robot`` (a TOML file), ``robot.arm.urdf`` and ``reference.file``."""

    def anchor(table: Any, key: str, suffixes: tuple[str, ...] = ()) -> None:
        v = table.get(key) if isinstance(table, dict) else None
        if isinstance(v, str) and (not suffixes or v.endswith(suffixes)):
            p = Path(v)
            if not p.is_absolute():
                table[key] = str(base_dir / p)

    anchor(data, "robot", (".toml",))
    robot = data.get("robot")
    if isinstance(robot, dict):
        anchor(robot.get("arm"), "urdf")
    anchor(data.get("reference"), "file")


def _merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = copy.deepcopy(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def expand_variants(
    data: dict[str, Any], overrides: list[str] = (), only: str | None = None
) -> dict[str, dict[str, Any]]:
    """Apply ``--set`` overrides, then split into variants: {variant name or "": data}."""
    data = copy.deepcopy(data)
    controller = data.get("controller")
    if isinstance(controller, dict):  # free-form: --set controller.solver_options.KEY=...
        controller.setdefault("solver_options", {})
    for text in overrides:
        path, value = parse_override(text)
        apply_override(data, path, value, f"--set {text}")
    variants = data.pop("variants", {})
    if not isinstance(variants, dict):
        raise ConfigError("variants: must be a table of named variants")
    if not variants:
        if only:
            raise ConfigError(f"--variant {only}: the scenario has no variants")
        return {"": data}
    if only is not None:
        if only not in variants:
            raise ConfigError(f"--variant {only}: unknown variant (have: {', '.join(variants)})")
        variants = {only: variants[only]}
    out = {}
    for name, over in variants.items():
        if not isinstance(over, dict):
            raise ConfigError(f"variants.{name}: must be a table of overrides")
        out[name] = _merge(data, over)
    return out


def _robot(t: Table, base_dir: Path) -> RobotSpec:
    raw = t.data.get("robot")
    if isinstance(raw, str):  # a built-in name or a robot TOML file: inlined when resolved
        p = Path(raw)
        path = resolve_toml(
            base_dir / p if p.suffix == ".toml" else raw, "aeromanip.robots", "robot"
        )
        return robot_from_table(
            t.sub("robot", load_toml(path)), base_dir=path.parent, source=path
        )
    return robot_from_table(t.table("robot"), base_dir=base_dir)


def _task(kind: str, tt: Table, reference: Reference) -> Task:
    if kind == "tracking":
        return EndEffectorTracking(reference, tracked=tt.str("tracked", "xyz"))
    if kind == "cog":
        return CogAlignment(tt.floats("target_xy", [0.0, 0.0], size=2))  # type: ignore[arg-type]
    if kind == "cog_velocity":
        return CogVelocity()
    if kind == "manipulability":
        return Manipulability(tt.str("tracked", "xyz"), eps=tt.float("eps", 1e-9))
    if kind == "condition":
        return ConditionNumber(
            tt.str("tracked", "xyz"), delta=tt.float("delta", 1e-9), kink=tt.float("kink", 1e-4)
        )
    return ControlRate()


def _weight(tt: Table, key: str, default: Any) -> Any:
    if isinstance(tt.data.get(key), dict):
        wt = tt.table(key)
        return {k: wt.float(k) for k in wt.data}
    v = tt.raw(key, default)
    if isinstance(v, list):
        return list(tt.floats(key))
    return tt.float(key) if key in tt.data else v


def build_scenario(data: dict[str, Any], base_dir: Path, variant: str = "") -> Scenario:
    """Build a ``Scenario`` from one variant's table; errors name the key path."""
    t = Table(data)
    name = t.str("name")
    description = t.str("description", "")
    robot = _robot(t, base_dir)
    ct = t.table("controller")
    horizon, dt = ct.int("horizon", minimum=1), ct.float("dt")
    strategy = ct.str("strategy", "weighted", choices=("weighted", "hierarchical"))
    backend = ct.str("backend", "ipopt", choices=BACKENDS)
    budget = ct.raw("time_budget", None)
    budget = None if budget is None else ct.float("time_budget")
    hierarchy = {}
    if strategy == "hierarchical" or ct.has("hierarchy"):
        ht = ct.table("hierarchy", {})
        hierarchy = {
            "mode": ht.str("mode", "stagewise", choices=MODES),
            "rel_tol": ht.float("rel_tol", 1e-3),
            "abs_tol": ht.float("abs_tol", 1e-6),
        }
        ht.done()
        if strategy != "hierarchical":
            hierarchy = {}  # a weighted variant of a hierarchical scenario: not used
    solver_options = dict(ct.table("solver_options", {}).data)
    ct.resolved["solver_options"] = solver_options
    ct.done()

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
    flags = {"joint_limits": bt.bool("joints", True), "velocity_limits": bt.bool("velocity", True)}
    limits = Bounds.from_robot(robot, platform_box=box, **flags)
    # constraint tightening: the NMPC plans inside bounds shrunk by the margins, so that the
    # real robot, lagging its references a little (physics), stays inside the true ones
    shrink = {d: margins["platform_margin"] for d in box}
    if flags["joint_limits"]:
        shrink.update({f"q{i + 1}": margins["joint_margin"] for i in range(robot.n_joints)})
    bounds = limits.tightened(shrink)
    bt.done()
    problem = Problem(robot, horizon, dt, bounds)

    reference = reference_from_table(t.table("reference"), base_dir=base_dir)
    tracked = "xyz"
    tasks_t = t.table("tasks")
    if not tasks_t.data:
        raise ConfigError("tasks: the scenario needs at least one task")
    for task_name in tasks_t.data:
        tt = tasks_t.table(task_name)
        kind = tt.str("kind", task_name if task_name in TASK_KINDS else "", choices=TASK_KINDS)
        regularizer = tt.bool("regularizer", False)
        level = None if regularizer else tt.int("level", 0, minimum=0)
        weight = _weight(tt, "weight", 1.0)
        terminal = _weight(tt, "terminal_weight", None)
        task = _task(kind, tt, reference)
        if kind == "tracking":
            tracked = task.tracked  # type: ignore[attr-defined]
        tt.done()
        problem.add_task(task, weight, terminal, level, name=task_name)
    tasks_t.done()

    clearance = None
    if t.has("clearance"):
        cl = t.table("clearance")
        points = cl.raw("points", None)
        if points is not None and (
            not isinstance(points, list) or not all(isinstance(p, str) for p in points)
        ):
            raise ConfigError(f"{cl.key('points')}: expected an array of point names")
        clearance = Clearance(cl.float("d_min", 0.1), points)
        margin = cl.float("margin", 0.0)
        if margin < 0.0:
            raise ConfigError(f"{cl.key('margin')}: must be >= 0 m, got {margin}")
        cl.done()
        # the NMPC keeps margin more than d_min: a real arm lags its plan a little
        problem.add_constraint(Clearance(clearance.d_min + margin, points))

    x0 = np.array(t.floats("initial_state", size=robot.nx))
    if bounds.violation(x0) > 0:
        raise ConfigError(f"initial_state: outside the state bounds by {bounds.violation(x0):.3g}")
    sim = t.str("sim", "kinematic", choices=("kinematic", "physics"))
    physics = dict(t.table("physics", {}).data)
    t.resolved["physics"] = physics
    duration = t.float("duration")
    if duration < dt:
        raise ConfigError(f"duration: must be at least one control period ({dt} s)")
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
        strategy=strategy,
        backend=backend,
        solver_options=solver_options,
        hierarchy=hierarchy,
        time_budget_s=budget,
        duration=duration,
        x0=x0,
        sim=sim,
        physics=physics,
        tracked=tracked,
        clearance=clearance,
        limits=limits,
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
