"""A whole controller step in compiled C: one call per control step (``controller_step.c``).

What ``Controller.step`` does for the weighted or strict hierarchical strategy on the
``sqp`` or ``sqp-rti`` backend with the condensed model and DAQP: the solve's
parameters, the guess, each level's row bounds and pinned rows, the SQP loop, the plan
and the fallback. ``aeromanip export`` writes the same step with a generated
configuration; here it is configured at run time (``AmConfig``) from the controller's
own compiled model (its codegen libraries, called through their symbols), with four
Functions of its own per level compiled beside them (parameters, plan, row bounds and
task costs, ``step_functions``). The C code is the compiled loop's library.

``StepParts`` is what of a controller the step (and the export) needs, or a
``ConfigError`` naming what keeps it from being compiled.
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.nmpc.backends.codegen import Buffered, compiled_all, library_of
from aeromanip.nmpc.backends.sqp import step_functions
from aeromanip.nmpc.backends.sqp.compiled_loop import STATUS, loop_library, loop_settings
from aeromanip.nmpc.backends.sqp.condensed_qp import CondensedQpModel
from aeromanip.nmpc.backends.sqp.dense_qp import failure_text
from aeromanip.nmpc.backends.sqp.solver import LOOP_CONSTANTS, SEED_FLOOR, SqpBackend
from aeromanip.nmpc.backends.sqp.step_structs import (
    DOUBLES,
    POINTER,
    STEP_STATUS,
    AmConfig,
    AmLevel,
    AmLevelState,
    AmOutput,
    AmState,
)
from aeromanip.nmpc.strategies import Hierarchical, Strategy, Weighted


@dataclass(frozen=True)
class LevelParts:
    """One priority level (the weighted strategy: its only one) as the step runs it."""

    backend: Any  # its SqpBackend
    model: CondensedQpModel
    lbg: np.ndarray  # the level's NLP row bounds, rows no decision moves left free
    ubg: np.ndarray
    pins: np.ndarray  # (n, 2): the condensed row pinned, the higher level it is pinned to


@dataclass(frozen=True)
class StepParts:
    """What of a controller's strategy the compiled step (and the export) runs."""

    levels: list[LevelParts]
    daqp: np.ndarray  # the loop's DAQP settings (``compiled_loop.DAQP_SETTINGS``)
    constants: np.ndarray  # the loop's constants (``compiled_loop.CONSTANTS``)
    loop_opts: np.ndarray  # the loop's options (``SqpBackend._loop_opts``)
    rti: bool
    hierarchical: bool


def _level_parts(backend: Any) -> LevelParts:
    """A level's model, its row bounds and the rows the higher levels' answers pin
    (``Transcription.strict_pins``: a higher level's residual rows held at their values
    there, the rows no decision moves left free)."""
    model, tr = backend.model, backend.tr
    lbg, ubg = tr.lbg.copy(), tr.ubg.copy()
    row_of = {r: i for i, r in enumerate(model.keep)}
    pins = []
    for j in range(len(tr.hier_rows)):
        pinned, free = tr.strict_pins(j)
        pins += [(row_of[int(r)], j) for r in pinned]
        lbg[free], ubg[free] = -np.inf, np.inf
    return LevelParts(backend, model, lbg, ubg, np.array(pins, dtype=int).reshape(-1, 2))


def step_parts(strategy: Strategy) -> StepParts:
    """What of ``strategy``'s levels the step runs, or a ``ConfigError`` naming what keeps
    it from being compiled (or exported)."""
    backends = [st.backend for st in strategy.solvers]
    strict = isinstance(strategy, Hierarchical) and strategy.mode == "strict"
    if not (isinstance(strategy, Weighted) or strict) or not all(
        isinstance(b, SqpBackend) for b in backends
    ):
        raise ConfigError(
            "controller: only the weighted or strict hierarchical 'sqp' or 'sqp-rti' can be "
            "compiled whole"
        )
    settings = [loop_settings(b.model, b.opts, LOOP_CONSTANTS) for b in backends]
    if any(s is None for s in settings):
        raise ConfigError(
            "controller.solver_options: the compiled step solves the condensed QP with DAQP "
            "(qpsol = 'daqp', or 'auto' up to condense_max_horizon steps, and DAQP options "
            "it knows)"
        )
    daqp, constants = settings[0]  # type: ignore[misc]
    first = backends[0]
    for b, (d, k) in zip(backends, settings, strict=True):  # type: ignore[misc]
        same = np.array_equal(b._loop_opts, first._loop_opts) and b.opts["rti"] == first.opts["rti"]
        if not (same and np.array_equal(d, daqp, equal_nan=True) and np.array_equal(k, constants)):
            raise ConfigError("controller.solver_options: the levels' solver options differ")
    return StepParts([_level_parts(b) for b in backends], daqp, constants, first._loop_opts,
                     bool(first.opts["rti"]), strict)  # fmt: skip


def _symbols(f: ca.Function) -> tuple[ctypes.CDLL, int, int] | None:
    """The compiled library of ``f`` and the addresses of ``f`` and its work function
    (``None``: ``f`` is not compiled)."""
    path = library_of(f)
    if path is None:
        return None
    so = ctypes.CDLL(str(path))
    addresses = [
        ctypes.cast(getattr(so, n), ctypes.c_void_p).value for n in (f.name(), f.name() + "_work")
    ]
    return so, addresses[0], addresses[1]


def _declare(lib: ctypes.CDLL) -> None:
    lib.am_new.restype = POINTER
    lib.am_new.argtypes = [ctypes.POINTER(AmConfig)]
    lib.am_free.argtypes = [POINTER]
    lib.am_free.restype = None
    lib.am_reset.argtypes = [POINTER, POINTER]
    lib.am_reset.restype = None
    lib.am_discard.argtypes = [POINTER]
    lib.am_discard.restype = None
    lib.am_step.argtypes = [POINTER, POINTER, POINTER, ctypes.c_double, ctypes.POINTER(AmOutput)]
    lib.am_step.restype = ctypes.c_int
    lib.am_state.argtypes = [POINTER]
    lib.am_state.restype = ctypes.POINTER(AmState)
    lib.am_level_state.argtypes = [POINTER, ctypes.c_int]
    lib.am_level_state.restype = ctypes.POINTER(AmLevelState)


def step_functions_of(parts: StepParts, latency_s: float) -> dict[str, Any]:
    """The step's own Functions: ``parameters``, ``plan``, and per level ``bounds`` and
    ``costs`` (every task's cost over the horizon at a level's commands, for the
    reports), named after what they compute."""
    tr = parts.levels[0].model.tr
    return {
        "parameters": step_functions.parameters_function(tr, latency_s, "aeromanip_step_p"),
        "plan": step_functions.plan_function(tr, "aeromanip_step_plan"),
        "bounds": [
            step_functions.bounds_function(lv.model, lv.lbg, lv.ubg, f"aeromanip_step_b{i}")
            for i, lv in enumerate(parts.levels)
        ],
        "costs": [
            step_functions.costs_function(lv.model, f"aeromanip_step_c{i}")
            for i, lv in enumerate(parts.levels)
        ],
    }


def compilable(strategy: Strategy, problem: Any, time_budget_s: float | None) -> StepParts | None:
    """``step_parts`` where the compiled step gives what ``Controller.step`` gives (every
    level on the compiled loop, no time budget, no task that measures or whose
    parameters are not a function of time), else ``None``."""
    try:
        parts = step_parts(strategy)
    except ConfigError:
        return None
    if time_budget_s is not None or any(lv.backend.loop is None for lv in parts.levels):
        return None
    if problem.overriding("observe") or problem.overriding("force_feedforward"):
        return None
    t = ca.SX.sym("t")
    try:
        for e in problem.entries:
            e.task.param_expression(t)
    except ConfigError:
        return None
    return parts


Symbol = tuple[ctypes.CDLL, int, int]  # a compiled Function: its library, f, f_work


class CompiledStep:
    """The compiled step of one controller (module docstring); ``build`` says ``None``
    where it cannot be built.

    The C controller keeps its memory: ``state`` and ``levels`` (each level's state and
    NumPy views of its arrays) may be read and written between steps."""

    def __init__(
        self,
        lib: ctypes.CDLL,
        parts: StepParts,
        level_symbols: list[list[Symbol | None]],
        ends: list[Symbol],
        costs: list[Buffered],
        seed_ratio: float | None,
    ) -> None:
        self.lib, self.parts, self.costs = lib, parts, costs
        self._keep: list[Any] = [level_symbols, ends]  # what the C controller points into
        levels = (AmLevel * len(parts.levels))()
        for i, (lv, sym) in enumerate(zip(parts.levels, level_symbols, strict=True)):
            levels[i] = self._level(lv, sym)
        tr, first = parts.levels[0].model.tr, parts.levels[0].model
        b = tr.problem.bounds
        arrays = [parts.daqp, parts.constants, parts.loop_opts.astype(float),
                  np.asarray(first.shift_vars, dtype=np.intc), first.lbU, first.ubU,
                  b.u_lower, b.u_upper]  # fmt: skip
        (_, par, par_work), (_, plan, plan_work) = ends
        self.config = AmConfig(
            tr.nx, tr.N, first.nU, tr.p.numel(), len(parts.levels), levels,
            *(self._array(a) for a in arrays), par, plan, par_work, plan_work,
            int(seed_ratio is not None), seed_ratio or 0.0, SEED_FLOOR,
        )  # fmt: skip
        self._keep.append(levels)
        self.handle = lib.am_new(ctypes.byref(self.config))
        if not self.handle:
            raise MemoryError("the compiled controller step could not allocate its buffers")
        self._views(tr.nx, tr.N, first.nU, tr.p.numel())

    @classmethod
    def build(
        cls, parts: StepParts, latency_s: float, seed_ratio: float | None
    ) -> CompiledStep | None:
        """The step of ``parts`` (``compilable``) with ``latency_s`` [s]; ``seed_ratio``
        (``None``: no seeds) as ``SqpBackend``'s: a step it would seed is left to the
        host (``AM_HOST``). ``None`` if its library or Functions cannot be built."""
        lib = loop_library()
        if lib is None:
            return None
        _declare(lib)
        fns = step_functions_of(parts, latency_s)
        own = [fns["parameters"], fns["plan"], *fns["costs"]]
        costs = compiled_all(own + fns["bounds"])[2 : 2 + len(fns["costs"])]
        level_symbols = []
        for lv, bounds in zip(parts.levels, fns["bounds"], strict=True):
            srcs = lv.model.sources
            level_symbols.append([_symbols(f) for f in (srcs[0], srcs[1], bounds)])
            level_symbols[-1].insert(2, _symbols(srcs[4]) if len(srcs) > 4 else None)
        ends = [_symbols(fns["parameters"]), _symbols(fns["plan"])]
        missing = [s is None for s in ends] + [
            sym[k] is None for sym in level_symbols for k in (0, 1, 3)
        ]  # fmt: skip
        if any(missing) or any(library_of(f) is None for f in fns["costs"]):
            return None
        return cls(lib, parts, level_symbols, ends, [Buffered(f) for f in costs], seed_ratio)  # type: ignore[arg-type]

    def __del__(self) -> None:
        handle = getattr(self, "handle", None)
        if handle:
            self.lib.am_free(handle)
            self.handle = None

    def _array(self, a: np.ndarray) -> int:
        """``a`` kept alive, contiguous, as an address."""
        a = np.ascontiguousarray(a)
        self._keep.append(a)
        return a.ctypes.data

    def _level(self, lv: LevelParts, sym: list[Symbol | None]) -> AmLevel:
        m, qp = lv.model, lv.model.qp
        ints = [
            np.array([m.nU, m.nc, m.nr, m.nh, m.tr.p.numel()], dtype=np.intc),
            np.asarray(m.hier_elem_row, dtype=np.intc), np.asarray(qp.always, dtype=np.uint8),
            np.asarray(qp._sizes, dtype=np.intc), np.asarray(qp.shift_rows, dtype=np.intc),
            np.asarray(lv.pins, dtype=np.intc),
        ]  # fmt: skip
        dims, hier, always, sizes, shift_rows, pins = (self._array(v) for v in ints)
        fns = [s[1] if s else None for s in sym]
        works = [s[2] if s else None for s in sym]
        return AmLevel(dims, hier, always, sizes, len(qp._sizes), float(qp.screen), shift_rows,
                       pins, len(lv.pins), *fns, *works)  # fmt: skip

    def _views(self, nx: int, N: int, nU: int, n_p: int) -> None:
        """NumPy views of the C controller's memory, and the output's buffers."""
        view = np.ctypeslib.as_array
        st = self.lib.am_state(self.handle).contents
        self.state = st
        self.u_prev, self.p = view(st.u_prev, (nx,)), view(st.p, (n_p,))
        self.first = view(st.first, (nU,))
        self.plan_x, self.plan_u = view(st.plan_x, ((N + 1) * nx,)), view(st.plan_u, (N * nx,))
        self.levels: list[tuple[AmLevelState, dict[str, np.ndarray]]] = []
        for i, lv in enumerate(self.parts.levels):
            ls = self.lib.am_level_state(self.handle, i).contents
            nc = lv.model.nc
            arrays = {"U": view(ls.U, (nU,)), "lam_c": view(ls.lam_c, (nc,)),
                      "lam_u": view(ls.lam_u, (nU,)), "memory": view(ls.memory, (nc,)),
                      "lbc": view(ls.lbc, (nc,)), "ubc": view(ls.ubc, (nc,)),
                      "tried_U": view(ls.tried.U, (nU,)),
                      "tried_lam_c": view(ls.tried.lam_c, (nc,)),
                      "tried_lam_u": view(ls.tried.lam_u, (nU,)),
                      "tried_memory": view(ls.tried.memory, (nc,))}  # fmt: skip
            self.levels.append((ls, arrays))
        self.u, self.out_x, self.out_u = np.zeros(nx), np.zeros((N + 1, nx)), np.zeros((N, nx))
        bufs = (a.ctypes.data_as(DOUBLES) for a in (self.u, self.out_x, self.out_u))
        self.out = AmOutput(*bufs)
        self._out_ref = ctypes.byref(self.out)

    def run(self, x: np.ndarray, rates: np.ndarray | None, t: float) -> str:
        """One step from the state ``x`` at ``t`` [s] (``rates``: measured, or ``None``);
        the outcome's word (``STEP_STATUS``); the command and plan are in ``u``,
        ``out_x``, ``out_u``, the figures in ``out`` and ``levels``."""
        r = None if rates is None else rates.ctypes.data
        code = self.lib.am_step(self.handle, x.ctypes.data, r, float(t), self._out_ref)
        return STEP_STATUS[code]

    def reset(self, u_prev: np.ndarray) -> None:
        """``am_reset``: no plan, no warm start, ``u_prev`` in flight."""
        self.lib.am_reset(self.handle, np.ascontiguousarray(u_prev, dtype=float).ctypes.data)

    def discard(self) -> None:
        """``am_discard`` (``Controller.discard``)."""
        self.lib.am_discard(self.handle)

    def level_status(self, i: int, tried: bool = False) -> str:
        """Level ``i``'s last solve (``tried``: its solve in the last step left to the
        host) as the Python loop words it (``SqpBackend``)."""
        ls = self.levels[i][0]
        st = ls.tried if tried else ls
        word = STATUS.get(st.status, f"unknown status {st.status}")
        if word == "QP failed":
            flag = st.qp_exitflag
            why = failure_text("daqp", flag, flag == 1, bool(st.qp_finite), st.qp_excess)
            word = f"QP failed: {why}"
        return word
