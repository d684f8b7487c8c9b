"""How long a controller step takes, and what it buys: the ``flight`` problem closed loop.

Every variant runs the same closed loop (``flight``: x8-3dof, N = 10, dt = 0.5 s, the
ideal kinematic inner loop ``x <- x + dt u``) in this one process, one after the other.
For each: the per-step wall time of ``Controller.step`` (Python included) after a few
warm-up steps (then the controller is reset), the solver iterations, failures, the
end-effector tracking RMSE, the closed-loop cost (every task's weighted stage cost along
the executed trajectory, so that all variants are scored alike) and the largest bound
violation. Variants whose answer should equal a reference report the largest difference
of their applied commands from it.

* ``baseline``: the formulation most users write first: CasADi ``nlpsol`` + IPOPT with
  default options, solved from scratch (no warm start) at every step.
* ``weighted``: the weighted strategy; ``hierarchical``: 2 levels (tracking, then CoG),
  strict (the tracking residuals pinned at their optimum, see ``strategies``);
  ``stagewise``: the same hierarchy in the paper's literal, relaxed form (stage costs
  bounded by the optimum plus a tolerance);
  ``constrained``: weighted, with a reference 25x faster so that velocity bounds bind;
  ``rti``: weighted, one SQP iteration per step; ``*-python-loop``: the SQP's loop in
  Python instead of compiled C (``compiled_loop``); ``*-python-step``: the step in
  Python around the compiled loop (``compiled_step``). Each with the ``sqp`` backend and, as
  the reference answer, with IPOPT warm-started and converged tightly (``-ipopt``,
  ``tol = 1e-10``: at its default tolerance IPOPT's own answer moves by ~3e-4 rad/s).
* ``contact``: the ``contact-wall`` problem (its ``cog`` variant: the force task with its
  rest-point estimate as a parameter, the surface-tangential task, the approach-speed
  bound; 10 Hz, N = 10) in the ideal loop, where the spring model is the contact.
"""

from __future__ import annotations

import os
import platform
import time
from collections.abc import Callable, Sequence
from typing import Any

import casadi as ca
import numpy as np

from aeromanip.bench.shadow import REF_OPTIONS, IpoptHierarchyShadow, IpoptShadow
from aeromanip.experiment.scenario import Scenario, load_scenarios
from aeromanip.nmpc.backends.codegen import limit_blas_threads
from aeromanip.nmpc.controller import Controller
from aeromanip.nmpc.problem import Problem
from aeromanip.nmpc.strategies import Weighted
from aeromanip.nmpc.transcription import Transcription

FAST = 25.0  # reference speed-up of the constrained variant: velocity bounds bind
PYTHON_LOOP = {"compiled_loop": False}  # the SQP's loop in Python
PYTHON_STEP = {"compiled_step": False}  # the step in Python around the compiled loop


# name: (scenario kind, strategy ("stagewise": hierarchical, mode "stagewise"), backend,
#        solver options, the variant it should equal)
VARIANTS: dict[str, tuple[str, str, str, dict | None, str | None]] = {
    "baseline": ("flight", "weighted", "plain-ipopt", None, None),
    "weighted-ipopt": ("flight", "weighted", "ipopt", REF_OPTIONS, None),
    "weighted": ("flight", "weighted", "sqp", None, "weighted-ipopt"),
    "rti": ("flight", "weighted", "sqp-rti", None, "weighted"),
    "hierarchical-ipopt": ("flight", "hierarchical", "ipopt", REF_OPTIONS, None),
    "hierarchical": ("flight", "hierarchical", "sqp", None, "hierarchical-ipopt"),
    "stagewise-ipopt": ("flight", "stagewise", "ipopt", REF_OPTIONS, None),
    "stagewise": ("flight", "stagewise", "sqp", None, "stagewise-ipopt"),
    "constrained-ipopt": ("fast", "weighted", "ipopt", REF_OPTIONS, None),
    "constrained": ("fast", "weighted", "sqp", None, "constrained-ipopt"),
    # the SQP's loop in Python (where it is compiled by default): the same answers
    "weighted-python-loop": ("flight", "weighted", "sqp", PYTHON_LOOP, "weighted"),
    "rti-python-loop": ("flight", "weighted", "sqp-rti", PYTHON_LOOP, "rti"),
    "hierarchical-python-loop": ("flight", "hierarchical", "sqp", PYTHON_LOOP, "hierarchical"),
    # the step in Python around the compiled loop (where the whole step is compiled)
    "weighted-python-step": ("flight", "weighted", "sqp", PYTHON_STEP, "weighted"),
    "rti-python-step": ("flight", "weighted", "sqp-rti", PYTHON_STEP, "rti"),
    "hierarchical-python-step": ("flight", "hierarchical", "sqp", PYTHON_STEP, "hierarchical"),
    # contact inspection (contact-wall, cog): the force and surface tasks, the approach bound
    "contact-ipopt": ("contact", "weighted", "ipopt", REF_OPTIONS, None),
    "contact": ("contact", "weighted", "sqp", None, "contact-ipopt"),
}


class PlainIpopt:
    """The baseline: the same NLP through ``nlpsol`` + IPOPT, default options, cold start.

    It offers the one method the loop needs, ``step(x, t) -> (u, iterations, ok)``.
    """

    def __init__(self, problem: Problem) -> None:
        self.problem = problem
        self.tr = Transcription(problem, problem.entries)
        nlp = {"x": self.tr.w, "p": self.tr.p, "f": self.tr.f, "g": self.tr.g}
        opts = {"print_time": False, "ipopt.print_level": 0, "ipopt.sb": "yes"}
        self.solver = ca.nlpsol("baseline", "ipopt", nlp, opts)
        self.u_prev = np.zeros(problem.kin.nx)

    def reset(self) -> None:
        """Forget the applied command."""
        self.u_prev = np.zeros(self.problem.kin.nx)

    def step(self, x: np.ndarray, t: float) -> tuple[np.ndarray, int, bool]:
        """Solve from the constant-state guess; return the first command."""
        tr, N = self.tr, self.problem.horizon
        p = tr.parameters(x, self.u_prev, self.problem.stage_params(t))
        lbw, ubw = tr.variable_bounds(p)
        w0 = tr.pack(np.repeat(x[None], N + 1, 0), np.zeros((N, x.size)), self.u_prev)
        out = self.solver(x0=w0, p=p, lbx=lbw, ubx=ubw, lbg=tr.lbg, ubg=tr.ubg)
        st = self.solver.stats()
        u = tr.unpack(np.asarray(out["x"]).ravel())[1][0]
        if not st["success"]:
            u = np.zeros_like(u)
        self.u_prev = u
        return u, int(st["iter_count"]), bool(st["success"])


#: the closed loops' problems: kind -> (built-in scenario, overrides)
KINDS: dict[str, tuple[str, list[str]]] = {
    "flight": ("flight", []),
    "fast": ("flight", []),  # the reference FAST times faster (``bench_scenario``)
    # far from the reference (the EE 0.9 m away), the platform at its box's corner and
    # turned, every joint within 0.1 rad of a limit
    "far": ("flight", ["initial_state=[0.5, -0.5, 1.4, 1.2, 1.47, -1.5, 2.1]"]),
    "clearance": ("clearance", []),  # the reference rises to the base: eq. 17 binds
    # press a wall and slide on it (the contact spring in the ideal loop: no sensor)
    "contact": ("contact-wall", []),
}
#: the variant of a scenario that has several
KIND_VARIANT = {"contact": "cog"}


def bench_scenario(kind: str, duration: float) -> Scenario:
    name, extra = KINDS[kind]
    sets = [f"duration={duration}", "sim=kinematic", *extra]
    variant = KIND_VARIANT.get(kind)
    sc = load_scenarios(name, sets, only=variant)[variant or ""]
    if kind == "fast":  # the flight's Lissajous frequencies [Hz], FAST times higher
        freq = sc.resolved["reference"]["frequency"]
        fast = f"reference.frequency={[FAST * f for f in freq]}"
        sc = load_scenarios(name, [*sets, fast])[""]
    return sc


def _stepper(
    sc: Scenario, strategy: str, backend: str, options: dict | None
) -> tuple[Any, Callable]:
    if backend == "plain-ipopt":
        ctrl = PlainIpopt(sc.problem)
        return ctrl, ctrl.step

    hierarchy = None
    if strategy in ("hierarchical", "stagewise"):
        hierarchy = dict(sc.hierarchy, mode="stagewise" if strategy == "stagewise" else "strict")
        strategy = "hierarchical"
    ctrl = Controller(sc.problem, strategy, backend, options, hierarchy=hierarchy)

    def step(x: np.ndarray, t: float) -> tuple[np.ndarray, int, bool]:
        cmd = ctrl.step(x, t)
        step.last = cmd  # type: ignore[attr-defined]  # for the IPOPT shadow
        step.partial += cmd.status == "partial"  # type: ignore[attr-defined]
        return cmd.u, cmd.iterations, cmd.status == "ok"

    step.partial = 0  # type: ignore[attr-defined]  # steps with a lower level unsolved
    return ctrl, step


def run_variant(
    kind: str,
    strategy: str,
    backend: str,
    options: dict | None = None,
    duration: float = 60.0,
    warmup: int = 3,
    shadowed: bool = False,
) -> dict[str, Any]:
    """Closed loop of one variant: timing [ms], iterations, tracking and cost; with
    ``shadowed`` (a converged backend) also the IPOPT shadow's summary."""
    sc = bench_scenario(kind, duration)
    ctrl, step = _stepper(sc, strategy, backend, options)
    x = sc.x0.copy()
    for k in range(warmup):  # compile, load, fill caches; then start afresh
        step(x, k * sc.problem.dt)
    ctrl.reset()
    if hasattr(step, "partial"):
        step.partial = 0
    shadow = None
    if shadowed:
        weighted = isinstance(ctrl.strategy, Weighted)
        shadow = IpoptShadow(ctrl) if weighted else IpoptHierarchyShadow(ctrl)
    X, U, ts, its, fails = closed_loop_steps(sc, step, shadow)
    ms = 1e3 * np.array(ts)
    return {
        "scenario": sc.name + (f" (reference x{FAST:g})" if kind == "fast" else ""),
        "strategy": strategy,
        "backend": backend,
        "options": options or {},
        "steps": len(ms),
        "median_ms": float(np.median(ms)),
        "p95_ms": float(np.percentile(ms, 95)),
        "max_ms": float(ms.max()),
        "iterations_mean": float(np.mean(its)),
        "iterations_max": int(np.max(its)),
        "failures": int(fails),
        "partial_steps": int(getattr(step, "partial", 0)),
        **closed_loop_score(sc, X, U),
        "commands": U.tolist(),
        **(shadow.summary() if shadow else {}),
    }


def closed_loop_steps(
    sc: Scenario, step: Callable, shadow: IpoptShadow | IpoptHierarchyShadow | None
) -> tuple[np.ndarray, np.ndarray, list[float], list[int], int]:
    """The ideal loop ``x <- x + dt u``: states, commands, step times [s], iterations and
    failures; the shadow (if any) solves outside the timed region."""
    dt, x = sc.problem.dt, sc.x0.copy()
    xs, us, ts, its, fails = [], [], [], [], 0
    for k in range(sc.steps):
        seen = shadow.before(x, k * dt) if shadow else None
        t0 = time.perf_counter()
        u, it, ok = step(x, k * dt)
        ts.append(time.perf_counter() - t0)
        if shadow and seen is not None:
            shadow.after(*seen, step.last)  # type: ignore[attr-defined]
        xs.append(x)
        us.append(u)
        its.append(it)
        fails += not ok
        x = x + dt * u
    return np.array(xs), np.array(us), ts, its, fails


def closed_loop_score(sc: Scenario, X: np.ndarray, U: np.ndarray) -> dict[str, float]:
    """Tracking RMSE, the closed-loop cost (every task's weighted stage cost along the
    flown trajectory), the largest bound violation and the share of steps at a
    velocity bound."""
    pb, b = sc.problem, sc.problem.bounds
    times = pb.dt * np.arange(len(X))
    ee = np.array([np.asarray(pb.kin.ee_position(xk)).ravel() for xk in X])
    err = np.linalg.norm(ee - np.asarray(sc.reference.sample(times)), axis=1)
    tr = Transcription(pb, pb.entries)
    P = np.vstack([pb.stage_params(t)[0] for t in times])
    V = np.vstack([np.zeros(pb.kin.nx), U[:-1]])
    cost = sum(
        float(np.asarray(tr.stage_model.cost(np.concatenate([X[k], V[k]]), U[k], P[k])[3]).sum())
        for k in range(len(X))
    )
    clear = pb.kin.clearance()
    d_min = sc.clearance.d_min if sc.clearance is not None else -np.inf
    viol = max(
        float(np.max(b.x_lower - X)),
        float(np.max(X - b.x_upper)),
        float(np.max(b.u_lower - U)),
        float(np.max(U - b.u_upper)),
        max(float(d_min - np.min(np.asarray(clear(xk)))) for xk in X),
        0.0,
    )
    active = np.any(np.isclose(U, b.u_lower, atol=1e-5) | np.isclose(U, b.u_upper, atol=1e-5), 1)
    return {
        "ee_rmse_m": float(np.sqrt(np.mean(err**2))),
        "closed_loop_cost": cost,
        "max_bound_violation": viol,
        "velocity_bound_active_share": float(np.mean(active)),
    }


def machine() -> dict[str, Any]:
    """What the numbers were measured on."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            names = [ln.split(":", 1)[1].strip() for ln in fh if ln.startswith("model name")]
        cpu = names[0] if names else cpu
    except OSError:
        pass
    load = os.getloadavg() if hasattr(os, "getloadavg") else (np.nan,) * 3
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "casadi": ca.__version__,
        "numpy": np.__version__,
        "load_average_at_start": [round(v, 2) for v in load],
    }


def bench_controller(
    variants: Sequence[str] | None = None, duration: float = 60.0, warmup: int = 3
) -> dict[str, Any]:
    """Run the variants (default: all of ``VARIANTS``) in this process; see module doc."""
    names = list(variants or VARIANTS)
    limit_blas_threads(1)  # as the sqp backend does: the same conditions for every variant
    out: dict[str, Any] = {"machine": machine(), "duration_s": duration, "variants": {}}
    res = out["variants"]
    for name in names:
        kind, strategy, backend, options, _ = VARIANTS[name]
        shadowed = backend == "sqp"
        res[name] = run_variant(kind, strategy, backend, options, duration, warmup, shadowed)
    for name in names:
        ref = VARIANTS[name][4]
        if ref in res:
            a, b = np.array(res[name]["commands"]), np.array(res[ref]["commands"])
            res[name]["vs"] = ref
            res[name]["max_command_diff"] = float(np.abs(a - b).max())
            res[name]["cost_ratio"] = res[name]["closed_loop_cost"] / res[ref]["closed_loop_cost"]
    if "baseline" in res:
        for r in res.values():
            r["speedup_vs_baseline"] = res["baseline"]["median_ms"] / r["median_ms"]
    for r in res.values():
        r.pop("commands")
    return out


def format_controller(result: dict[str, Any]) -> str:
    """The results as a Markdown table."""
    head = (
        "| variant | backend | median ms | p95 ms | max ms | iters | fails | x baseline "
        "| EE RMSE m | cost | vs ref: max du, cost ratio | bound viol | vel. bound active |"
    )
    lines = [head, "|" + "---|" * 13]
    for name, r in result["variants"].items():
        vs = f"{r['max_command_diff']:.1e}, {r['cost_ratio']:.4f} ({r['vs']})" if "vs" in r else "-"
        lines.append(
            f"| {name} | {r['backend']} | {r['median_ms']:.2f} | {r['p95_ms']:.2f} "
            f"| {r['max_ms']:.2f} | {r['iterations_mean']:.1f} | {r['failures']} "
            f"| {r.get('speedup_vs_baseline', float('nan')):.1f} | {r['ee_rmse_m']:.5f} "
            f"| {r['closed_loop_cost']:.5f} | {vs} | {r['max_bound_violation']:.1e} "
            f"| {100 * r['velocity_bound_active_share']:.0f}% |"
        )
    shadowed = {n: r for n, r in result["variants"].items() if "shadow_steps" in r}
    if shadowed:
        lines += [
            "",
            "IPOPT shadow (the same inputs at every step; du: largest command difference; "
            "IPOPT's cost higher: by the levels in order for a hierarchy):",
            "",
            "| variant | steps | same guess: max du | other optimum (IPOPT's cost higher) "
            "| IPOPT restarted at the answer: max du, max rel. cost change |",
            "|" + "---|" * 5,
        ]
        for name, r in shadowed.items():
            restart = (
                f"{r['shadow_certified_max_du']:.1e}, {r['shadow_certified_max_rel_cost']:.1e}"
                if "shadow_certified_max_du" in r
                else "- (hierarchy: not restarted)"
            )
            lines.append(
                f"| {name} | {r['shadow_steps']} | {r['shadow_same_guess_max_du']:.1e} "
                f"| {r['shadow_other_optimum_steps']} "
                f"({r['shadow_other_optimum_ipopt_cost_higher']}) | {restart} |"
            )
    m = result["machine"]
    lines.append("")
    lines.append(
        f"Machine: {m['cpu']}, {m['cores']} cores, {m['platform']}; Python {m['python']}, "
        f"CasADi {m['casadi']}; load average at start {m['load_average_at_start']}. "
        f"Closed loop of {result['duration_s']:g} s per variant."
    )
    return "\n".join(lines)
