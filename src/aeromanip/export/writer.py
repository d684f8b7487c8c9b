"""``aeromanip export``: a scenario's controller as a self-contained C library.

The directory written holds the generated model (CasADi's C of the SQP's Functions and
of ``nmpc.backends.sqp.step_functions``), the compiled SQP loop's and the controller
step's sources with DAQP's (``nmpc/backends/sqp``; DAQP's MIT license kept), the public
API over the step (``c/aeromanip_controller.c``) with its header and generated
configuration, a closed-loop example and a Makefile: a C compiler is all it needs.

What can be exported: the weighted strategy or the strict hierarchy (every level a loop
of its own, each lower level's rows pinned to the higher levels' answers) on the ``sqp``
or ``sqp-rti`` backend with the condensed model and DAQP (short horizons: the onboard
case), tasks whose parameters are functions of time. The rest is refused with one line
naming what to change.
"""

from __future__ import annotations

import math
import shutil
from dataclasses import dataclass
from importlib.metadata import version
from pathlib import Path

import casadi as ca
import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.experiment.scenario import Scenario
from aeromanip.nmpc.backends.sqp import compiled_loop, step_functions
from aeromanip.nmpc.backends.sqp.compiled_step import LevelParts, StepParts, step_parts
from aeromanip.nmpc.controller import Controller
from aeromanip.nmpc.strategies import MODE
from aeromanip.nmpc.transcription import Transcription

HERE = Path(__file__).parent / "c"
#: the generated C file of every Function (and its header)
MODEL_FILE = "aeromanip_model"
#: the C files written next to the generated ones, from ``nmpc/backends/sqp``
LOOP_FILES = (*compiled_loop.SOURCES, *compiled_loop.HEADERS)


@dataclass(frozen=True)
class ExportRequest:
    """What to export: the controller and the scenario it flies."""

    controller: Controller
    scenario: str
    command: str  # the command line that wrote it (in the header)
    x0: np.ndarray  # the scenario's initial state (the example's)
    duration_s: float  # the scenario's duration (the example's)


def check_scenario(sc: Scenario) -> None:
    """Refuse, before anything is built, a scenario whose controller cannot be exported
    (``ConfigError``: one line naming the key)."""
    if sc.strategy not in ("weighted", "hierarchical"):
        raise ConfigError(
            f"controller.strategy: {sc.strategy!r} cannot be exported to C; "
            "'weighted' and 'hierarchical' can"
        )
    mode = sc.hierarchy.get("mode", MODE) if sc.strategy == "hierarchical" else MODE
    if mode != "strict":
        raise ConfigError(
            f"controller.hierarchy.mode: {mode!r} cannot be exported to C; 'strict' can"
        )
    if sc.backend not in ("sqp", "sqp-rti"):
        raise ConfigError(
            f"controller.backend: {sc.backend!r} cannot be exported to C; 'sqp' and 'sqp-rti' can"
        )
    if sc.time_budget_s is not None:
        raise ConfigError("controller.time_budget: not exported (bound the step by max_iter)")
    for method in ("observe", "force_feedforward"):  # what the C step does not compute
        users = [t.name for t in sc.problem.overriding(method)]
        if users:
            raise ConfigError(f"tasks.{users[0]}: uses measurements; cannot be exported to C")
    t = ca.SX.sym("t")
    for e in sc.problem.entries:
        e.task.param_expression(t)


def exportable(ctrl: Controller) -> StepParts:
    """What of ``ctrl``'s levels the export writes, or a ``ConfigError`` naming what
    keeps it from being exported."""
    return step_parts(ctrl.strategy)


def _c_array(ctype: str, name: str, values: np.ndarray) -> str:
    """A static C array (one element more than the values: C has no empty arrays)."""
    flat = np.asarray(values).ravel()
    if ctype == "double":
        items = [_c_double(float(v)) for v in flat]
    else:
        items = [str(int(v)) for v in flat]
    body = ", ".join([*items, "0"])
    return f"static const {ctype} {name}[{flat.size + 1}] = {{{body}}};\n"


def _c_double(v: float) -> str:
    """A float as C source text (``NAN``, ``INFINITY`` from ``math.h``)."""
    if math.isnan(v):
        return "NAN"
    if math.isinf(v):
        return "INFINITY" if v > 0 else "-INFINITY"
    return repr(v)


def _declare(name: str) -> str:
    return (
        f"int {name}(const double** arg, double** res, casadi_int* iw, double* w, int mem);\n"
        f"int {name}_work(casadi_int* sz_arg, casadi_int* sz_res, casadi_int* sz_iw, "
        "casadi_int* sz_w);\n"
    )


def _level_arrays(i: int, lv: LevelParts) -> str:
    """Level ``i``'s constant arrays."""
    m, qp = lv.model, lv.model.qp
    dims = np.array([m.nU, m.nc, m.nr, m.nh, m.tr.p.numel()])
    return "".join(
        [_c_array("int", f"am_dims_{i}", dims),
         _c_array("int", f"am_hier_row_{i}", np.ascontiguousarray(m.hier_elem_row)),
         _c_array("unsigned char", f"am_always_{i}", qp.always.astype(int)),
         _c_array("int", f"am_sizes_{i}", np.array(qp._sizes)),
         _c_array("int", f"am_shift_rows_{i}", qp.shift_rows),
         _c_array("int", f"am_pins_{i}", lv.pins)]
    )  # fmt: skip


def _level_entry(i: int, lv: LevelParts, names: list[str]) -> str:
    """Level ``i``'s row of ``am_levels``; ``names``: its data, merit, hess (or ""),
    bounds Functions."""
    qp = lv.model.qp
    fns = [n or "0" for n in names]
    works = [f"{n}_work" if n else "0" for n in names]
    return (
        f"  {{am_dims_{i}, am_hier_row_{i}, am_always_{i}, am_sizes_{i}, {len(qp._sizes)}, "
        f"{_c_double(float(qp.screen))}, am_shift_rows_{i}, am_pins_{i}, {len(lv.pins)},\n"
        f"   {', '.join(fns)},\n   {', '.join(works)}}},\n"
    )


def _config(ex: StepParts, names: dict[str, str], level_names: list[list[str]]) -> str:
    """``aeromanip_config.h``: the scenario's controller (``am_config``, an ``AmConfig``
    of ``controller_step.h``), its constants and the Functions it calls."""
    first = ex.levels[0].model
    tr = first.tr
    b = tr.problem.bounds
    lines = ["/* generated by aeromanip export: the scenario's controller */",
             "#ifndef AEROMANIP_CONFIG_H", "#define AEROMANIP_CONFIG_H", "",
             "#include <math.h>", '#include "controller_step.h"', ""]  # fmt: skip
    text = "\n".join(lines) + "\n"
    declared = [*names.values(), *(n for level in level_names for n in level if n)]
    text += "".join(_declare(n) for n in declared) + "\n"
    text += _c_array("double", "am_daqp", ex.daqp)
    text += _c_array("double", "am_constants", ex.constants)
    text += _c_array("double", "am_opts", ex.loop_opts)
    text += _c_array("int", "am_shift_vars", first.shift_vars)
    text += _c_array("double", "am_lbU", first.lbU)
    text += _c_array("double", "am_ubU", first.ubU)
    text += _c_array("double", "am_u_lower", b.u_lower)
    text += _c_array("double", "am_u_upper", b.u_upper)
    text += "".join(_level_arrays(i, lv) for i, lv in enumerate(ex.levels))
    text += f"\nstatic const AmLevel am_levels[{len(ex.levels)}] = {{\n"
    text += "".join(
        _level_entry(i, lv, ns) for i, (lv, ns) in enumerate(zip(ex.levels, level_names,
                                                                   strict=True))
    )  # fmt: skip
    sizes = f"{tr.nx}, {tr.N}, {first.nU}, {tr.p.numel()}, {len(ex.levels)}"
    par, plan = names["parameters"], names["plan"]
    text += (
        "};\n\nstatic const AmConfig am_config = {\n"
        f"  {sizes}, am_levels, am_daqp, am_constants, am_opts, am_shift_vars,\n"
        "  am_lbU, am_ubU, am_u_lower, am_u_upper,\n"
        f"  {par}, {plan}, {par}_work, {plan}_work, 0, 0.0, 0.0}};\n"
    )
    return text + "\n#endif\n"


def _functions(
    ex: StepParts, ctrl: Controller
) -> tuple[list[ca.Function], dict[str, str], list[list[str]]]:
    """Every Function the export generates; the step's names for its own (parameters,
    plan) and each level's data, merit, exact Hessian ("" if none) and bounds."""
    tr = ex.levels[0].model.tr
    parameters = step_functions.parameters_function(tr, ctrl.latency_s, "aeromanip_parameters")
    plan = step_functions.plan_function(tr, "aeromanip_plan")
    fs = [parameters, plan, step_functions.ee_function(tr, "aeromanip_ee"),
          step_functions.reference_function(tr, "aeromanip_reference")]  # fmt: skip
    names = {"parameters": parameters.name(), "plan": plan.name()}
    level_names = []
    for i, lv in enumerate(ex.levels):
        m = lv.model
        own = [_renamed(m.sources[0], f"aeromanip_data_{i}"),
               _renamed(m.sources[1], f"aeromanip_merit_{i}"),
               _renamed(m.sources[4], f"aeromanip_hessian_{i}") if len(m.sources) > 4 else None,
               step_functions.bounds_function(m, lv.lbg, lv.ubg,
                                              f"aeromanip_bounds_{i}")]  # fmt: skip
        fs += [f for f in own if f is not None]
        level_names.append([f.name() if f is not None else "" for f in own])
    return fs, names, level_names


def _renamed(f: ca.Function, name: str) -> ca.Function:
    """The expression Function ``f`` under ``name`` (the levels' model Functions share
    names: one C file holds them all)."""
    args = f.sx_in()
    return ca.Function(name, args, f.call(args), f.name_in(), f.name_out())


def _lagged_text(tr: Transcription) -> str:
    """Which DoFs' rates lag, as the header says it."""
    names = [tr.problem.robot.state_names[i] for i in tr.model.lagged]
    return f"here {', '.join(names)}" if names else "none here: the rates are not used"


def _strategy_text(ex: StepParts) -> str:
    """The strategy, as the header says it."""
    return f"strict hierarchical ({len(ex.levels)} levels)" if ex.hierarchical else "weighted"


def _fill(template: str, values: dict[str, str]) -> str:
    for key, value in values.items():
        template = template.replace(f"@{key}@", value)
    return template


def export_controller(req: ExportRequest, out: Path) -> list[Path]:
    """Write the export of ``req`` into ``out`` (created); the files written."""
    ctrl = req.controller
    ex = exportable(ctrl)
    fs, names, level_names = _functions(ex, ctrl)  # refuses what it cannot write first
    src, inc, example = out / "src", out / "include", out / "example"
    for d in (src, inc, example):
        d.mkdir(parents=True, exist_ok=True)
    cg = ca.CodeGenerator(f"{MODEL_FILE}.c", {"with_header": True})
    for f in fs:
        cg.add(f)
    cg.generate(f"{src}/")
    for name in LOOP_FILES:
        shutil.copyfile(compiled_loop.HERE / name, src / name)
    shutil.copyfile(HERE / "aeromanip_controller.c", src / "aeromanip_controller.c")
    (src / "aeromanip_config.h").write_text(_config(ex, names, level_names))
    tr = ex.levels[0].model.tr
    values = {
        "SCENARIO": req.scenario, "VERSION": version("aeromanip"), "COMMAND": req.command,
        "STATE_NAMES": ", ".join(tr.problem.robot.state_names), "NX": str(tr.nx),
        "LAGGED": _lagged_text(tr),
        "N": str(tr.N), "DT": repr(float(tr.problem.dt)),
        "STRATEGY": _strategy_text(ex), "LEVELS": str(len(ex.levels)),
        "BACKEND": "RTI" if ex.rti else "SQP",
        "STEPS": str(max(1, round(req.duration_s / tr.problem.dt))),
        "X0": ", ".join(repr(float(v)) for v in req.x0),
    }  # fmt: skip
    for name, where in (("aeromanip_controller.h", inc), ("example.c", example),
                        ("Makefile", out), ("README.md", out)):  # fmt: skip
        (where / name).write_text(_fill((HERE / f"{name}.in").read_text(), values))
    third_party = compiled_loop.HERE / compiled_loop.THIRD_PARTY
    shutil.copytree(third_party, out / compiled_loop.THIRD_PARTY, dirs_exist_ok=True)
    return sorted(p for p in out.rglob("*") if p.is_file())
