"""Where a controller step's time goes: compiled code, the QP solver, Python and NumPy.

The bench's closed loop (``bench.controller_speed``: the flight problem, ideal inner
loop) is run for one variant with every ``Buffered`` Function call timed by its name:
the QP solver (DAQP or HPIPM through CasADi), the compiled controller step (the whole
step in C: parameters, bounds, every level's SQP loop, plan), the compiled SQP loop (the
whole solve in C where the step is Python's: its model calls and QPs are inside it),
the model's compiled Functions (linearisation, merit, Hessian, multipliers, logged
costs), and the IPOPT solve that seeds the SQP on a cold start (the first step). The
rest of the step is Python and NumPy (input checks, reports; where the step is Python's:
the SQP loop, the QP's row screening, reference sampling, bounds, warm start). A second pass under
``cProfile`` names the Python functions that take most of that rest (their own time,
profiler overhead included, as shares).
"""

from __future__ import annotations

import contextlib
import cProfile
import pstats
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from aeromanip.bench.controller_speed import VARIANTS, _stepper, bench_scenario
from aeromanip.nmpc.backends import codegen
from aeromanip.nmpc.backends.codegen import limit_blas_threads
from aeromanip.nmpc.backends.nlpsol import NlpBackend
from aeromanip.nmpc.backends.sqp.compiled_loop import CompiledLoop
from aeromanip.nmpc.backends.sqp.compiled_step import CompiledStep

PROFILED = ("weighted", "rti", "hierarchical")  # the variants `aeromanip bench profile` runs
# part of a Function's name -> category (first match; the rest is "other compiled")
CATEGORIES = (
    ("aeromanip_qp", "QP solver (DAQP)"),
    ("hpipm", "QP solver (HPIPM)"),
    ("merit", "model: merit (line search)"),
    ("hess", "model: exact Hessian"),
    ("lagw", "model: multipliers"),
    ("stage_costs", "logged stage costs"),
    ("aeromanip_step_c", "logged stage costs"),
    ("aeromanip_sqp_data", "model: linearisation"),
    ("aeromanip_ms_", "model: linearisation"),
)
PYTHON = "Python and NumPy"
SEED = "IPOPT seed (cold start, Python included)"
COMPILED_LOOP = "compiled SQP loop (model, DAQP, line search: C)"
COMPILED_STEP = "compiled step (parameters, bounds, every level's SQP loop, plan: C)"
TOP_PYTHON = 8  # Python functions listed per variant


def _category(name: str) -> str:
    return next((c for part, c in CATEGORIES if part in name), "other compiled")


def _timed(method: Callable, acc: dict[str, float], category: str) -> Callable:
    """``method`` adding its run time [s] to ``acc[category]``."""

    def timed(*args: Any, **kwargs: Any) -> Any:
        t0 = time.perf_counter()
        try:
            return method(*args, **kwargs)
        finally:
            acc[category] += time.perf_counter() - t0

    return timed


@contextlib.contextmanager
def timed_functions(acc: dict[str, float]) -> Iterator[None]:
    """While inside, every new ``Buffered`` adds its run time [s] to ``acc[category]``,
    every ``NlpBackend`` solve (the SQP's IPOPT seed) to ``acc[SEED]``, every call of
    the compiled SQP loop to ``acc[COMPILED_LOOP]`` and of the compiled controller step
    to ``acc[COMPILED_STEP]``."""
    original, nlp_solve, loop_solve, step_run = (
        codegen.Buffered.__init__,
        NlpBackend.solve,
        CompiledLoop.solve,
        CompiledStep.run,
    )

    def init(self: codegen.Buffered, f: Any) -> None:
        original(self, f)
        self.run = _timed(self.run, acc, _category(f.name()))

    codegen.Buffered.__init__ = init  # type: ignore[method-assign]
    NlpBackend.solve = _timed(nlp_solve, acc, SEED)  # type: ignore[method-assign]
    CompiledLoop.solve = _timed(loop_solve, acc, COMPILED_LOOP)  # type: ignore[method-assign]
    CompiledStep.run = _timed(step_run, acc, COMPILED_STEP)  # type: ignore[method-assign]
    try:
        yield
    finally:
        codegen.Buffered.__init__ = original  # type: ignore[method-assign]
        NlpBackend.solve = nlp_solve  # type: ignore[method-assign]
        CompiledLoop.solve = loop_solve  # type: ignore[method-assign]
        CompiledStep.run = step_run  # type: ignore[method-assign]


def _loop(sc: Any, step: Any) -> list[float]:
    """The ideal closed loop; step times [s]."""
    dt, x, ts = sc.problem.dt, sc.x0.copy(), []
    for k in range(sc.steps):
        t0 = time.perf_counter()
        u, _, _ = step(x, k * dt)
        ts.append(time.perf_counter() - t0)
        x = x + dt * u
    return ts


def profile_variant(name: str, duration: float = 120.0, warmup: int = 3) -> dict[str, Any]:
    """One variant's step broken down: mean time per step [ms] per category, the step's
    median and mean [ms], and the Python functions with the most own time."""
    kind, strategy, backend, options, _ = VARIANTS[name]
    sc = bench_scenario(kind, duration)
    acc: dict[str, float] = defaultdict(float)
    with timed_functions(acc):
        ctrl, step = _stepper(sc, strategy, backend, options)
        for k in range(warmup):
            step(sc.x0.copy(), k * sc.problem.dt)
        ctrl.reset()
        acc.clear()
        ts = _loop(sc, step)
        n = len(ts)
        parts = {c: 1e3 * v / n for c, v in sorted(acc.items(), key=lambda kv: -kv[1])}
        parts[PYTHON] = 1e3 * float(np.mean(ts)) - sum(parts.values())
        ctrl.reset()
        prof = cProfile.Profile()
        prof.enable()
        _loop(sc, step)
        prof.disable()
    return {
        "variant": name,
        "steps": n,
        "median_ms": 1e3 * float(np.median(ts)),
        "mean_ms": 1e3 * float(np.mean(ts)),
        "parts_ms": parts,
        "python_top": _python_top(prof),
    }


def _python_top(prof: cProfile.Profile) -> list[tuple[str, float]]:
    """The package's functions by own time, as shares of all profiled time."""
    stats = pstats.Stats(prof).stats  # type: ignore[attr-defined]
    total = sum(v[2] for v in stats.values())
    ours = [
        (f"{path.split('aeromanip/')[-1]}:{func}", v[2] / total)
        for (path, _, func), v in stats.items()
        if "aeromanip/" in path and "bench/" not in path
    ]
    return sorted(ours, key=lambda r: -r[1])[:TOP_PYTHON]


def bench_profile(variants: list[str] | None = None, duration: float = 120.0) -> list[dict]:
    """``profile_variant`` for each of ``variants`` (default ``PROFILED``)."""
    limit_blas_threads(1)
    return [profile_variant(v, duration) for v in (variants or PROFILED)]


def format_profile(rows: list[dict]) -> str:
    """Markdown: one table of the parts, then each variant's Python functions."""
    cats = list(dict.fromkeys(c for r in rows for c in r["parts_ms"]))
    head = "| part | " + " | ".join(r["variant"] for r in rows) + " |"
    lines = [head, "|---" * (len(rows) + 1) + "|"]
    for c in cats:
        cells = []
        for r in rows:
            v = r["parts_ms"].get(c)
            cells.append("-" if v is None else f"{v:.3f} ({100 * v / r['mean_ms']:.0f} %)")
        lines.append(f"| {c} [ms] | " + " | ".join(cells) + " |")
    for label, key in (("**step, mean**", "mean_ms"), ("step, median", "median_ms")):
        lines.append(f"| {label} [ms] | " + " | ".join(f"{r[key]:.3f}" for r in rows) + " |")
    for r in rows:
        top = ", ".join(f"`{f}` {100 * s:.0f} %" for f, s in r["python_top"])
        lines.append(f"\n{r['variant']}: most own time under cProfile: {top}")
    return "\n".join(lines)
