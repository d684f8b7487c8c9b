"""``aeromanip export``: a scenario's controller as a self-contained C library.

The directory written holds the generated model (CasADi's C of the SQP's Functions and
of ``symbolic``'s), the compiled SQP loop's sources (``nmpc/backends/sqp``), DAQP's
sources (MIT, its license kept), the controller's step (``c/aeromanip_controller.c``),
its header, a closed-loop example and a Makefile: a C compiler is all it needs.

What can be exported: the weighted strategy on the ``sqp`` or ``sqp-rti`` backend with
the condensed model and DAQP (short horizons: the onboard case), tasks whose parameters
are functions of time. The rest is refused with one line naming what to change.
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
from aeromanip.export import symbolic
from aeromanip.nmpc.backends.sqp import compiled_loop
from aeromanip.nmpc.backends.sqp.compiled_loop import loop_settings
from aeromanip.nmpc.backends.sqp.condensed_qp import CondensedQpModel
from aeromanip.nmpc.backends.sqp.solver import LOOP_CONSTANTS, SqpBackend
from aeromanip.nmpc.controller import Controller
from aeromanip.nmpc.strategies import Weighted

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
    if sc.strategy != "weighted":
        raise ConfigError(
            f"controller.strategy: {sc.strategy!r} cannot be exported to C yet; "
            "'weighted' can (--set controller.strategy=weighted)"
        )
    if sc.backend not in ("sqp", "sqp-rti"):
        raise ConfigError(
            f"controller.backend: {sc.backend!r} cannot be exported to C; 'sqp' and 'sqp-rti' can"
        )
    if sc.problem.model.has_response:
        raise ConfigError(
            "controller.response: rate lags need the measured rates, which the exported "
            "step does not take yet; export without [controller.response]"
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


@dataclass(frozen=True)
class Exportable:
    """The parts of a controller the export writes out."""

    backend: SqpBackend
    model: CondensedQpModel
    daqp: np.ndarray  # the loop's DAQP settings (``compiled_loop.DAQP_SETTINGS``)
    constants: np.ndarray  # the loop's constants (``compiled_loop.CONSTANTS``)


def exportable(ctrl: Controller) -> Exportable:
    """What of ``ctrl``'s only level the export writes, or a ``ConfigError`` naming what
    keeps it from being exported."""
    backend = ctrl.strategy.solvers[0].backend
    if not isinstance(ctrl.strategy, Weighted) or not isinstance(backend, SqpBackend):
        raise ConfigError("controller: only the weighted 'sqp' or 'sqp-rti' can be exported")
    settings = loop_settings(backend.model, backend.opts, LOOP_CONSTANTS)
    if settings is None:
        raise ConfigError(
            "controller.solver_options: the exported loop solves the condensed QP with DAQP "
            "(qpsol = 'daqp', or 'auto' up to condense_max_horizon steps, and DAQP options "
            "it knows)"
        )
    return Exportable(backend, backend.model, *settings)


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


def _config(ex: Exportable, names: dict[str, str]) -> str:
    """``aeromanip_config.h``: the scenario's sizes, constants and Functions."""
    m, qp = ex.model, ex.model.qp
    tr = m.tr
    b = tr.problem.bounds
    dims = {"NX": tr.nx, "N": tr.N, "NU": m.nU, "NC": m.nc, "NP": tr.p.numel(),
            "N_SIZES": len(qp._sizes)}  # fmt: skip
    lines = ["/* generated by aeromanip export: the scenario's sizes and constants */",
             "#ifndef AEROMANIP_CONFIG_H", "#define AEROMANIP_CONFIG_H", "",
             "#include <math.h>", '#include "model_fn.h"', ""]  # fmt: skip
    lines += [f"#define AM_{k} {v}" for k, v in dims.items()]
    lines.append(f"#define AM_SCREEN {_c_double(float(qp.screen))}")
    for key in ("data", "merit", "hess", "prepare", "plan"):
        fn = names.get(key)
        lines.append(f"#define AM_{key.upper()} {fn or '0'}")
        lines.append(f"#define AM_{key.upper()}_WORK {fn + '_work' if fn else '0'}")
    text = "\n".join(lines) + "\n\n"
    text += "".join(_declare(n) for n in names.values())
    hier = np.ascontiguousarray(m.hier_elem_row, dtype=int)
    dims_arr = np.array([m.nU, m.nc, m.nr, m.nh, tr.p.numel()])
    text += _c_array("int", "am_dims", dims_arr)
    text += _c_array("int", "am_hier_row", hier)
    text += _c_array("unsigned char", "am_always", qp.always.astype(int))
    text += _c_array("int", "am_sizes", np.array(qp._sizes))
    text += _c_array("double", "am_daqp", ex.daqp)
    text += _c_array("double", "am_constants", ex.constants)
    text += _c_array("double", "am_opts", ex.backend._loop_opts)
    text += _c_array("int", "am_shift_rows", qp.shift_rows)
    text += _c_array("int", "am_shift_vars", m.shift_vars)
    text += _c_array("double", "am_lbU", m.lbU)
    text += _c_array("double", "am_ubU", m.ubU)
    text += _c_array("double", "am_u_lower", b.u_lower)
    text += _c_array("double", "am_u_upper", b.u_upper)
    return text + "\n#endif\n"


def _functions(ex: Exportable, ctrl: Controller) -> tuple[list[ca.Function], dict[str, str]]:
    """Every Function the export generates, and the loop's and the step's names for them."""
    m, tr = ex.model, ex.model.tr
    data, merit = m.sources[0], m.sources[1]
    hess = m.sources[4] if len(m.sources) > 4 else None
    prepare = symbolic.prepare_function(m, ctrl.latency_s, tr.lbg, tr.ubg, "aeromanip_prepare")
    plan = symbolic.plan_function(tr, "aeromanip_plan")
    fs = [data, merit, prepare, plan, symbolic.ee_function(tr, "aeromanip_ee"),
          symbolic.reference_function(tr, "aeromanip_reference")]  # fmt: skip
    names = {"data": data.name(), "merit": merit.name(), "prepare": prepare.name(),
             "plan": plan.name()}  # fmt: skip
    if hess is not None:
        fs.append(hess)
        names["hess"] = hess.name()
    return fs, names


def _fill(template: str, values: dict[str, str]) -> str:
    for key, value in values.items():
        template = template.replace(f"@{key}@", value)
    return template


def export_controller(req: ExportRequest, out: Path) -> list[Path]:
    """Write the export of ``req`` into ``out`` (created); the files written."""
    ctrl = req.controller
    ex = exportable(ctrl)
    fs, names = _functions(ex, ctrl)  # refuses tasks without expressions before writing
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
    (src / "aeromanip_config.h").write_text(_config(ex, names))
    tr = ex.model.tr
    values = {
        "SCENARIO": req.scenario, "VERSION": version("aeromanip"), "COMMAND": req.command,
        "STATE_NAMES": ", ".join(tr.problem.robot.state_names), "NX": str(tr.nx),
        "N": str(tr.N), "DT": repr(float(tr.problem.dt)),
        "STRATEGY": "weighted", "BACKEND": "RTI" if ex.backend.opts["rti"] else "SQP",
        "STEPS": str(max(1, round(req.duration_s / tr.problem.dt))),
        "X0": ", ".join(repr(float(v)) for v in req.x0),
    }  # fmt: skip
    for name, where in (("aeromanip_controller.h", inc), ("example.c", example),
                        ("Makefile", out), ("README.md", out)):  # fmt: skip
        (where / name).write_text(_fill((HERE / f"{name}.in").read_text(), values))
    shutil.copytree(HERE / "third_party", out / "third_party", dirs_exist_ok=True)
    return sorted(p for p in out.rglob("*") if p.is_file())
