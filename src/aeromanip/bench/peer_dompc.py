"""do-mpc as a peer: the ``flight`` problem set up as a do-mpc user would, timed beside ours.

The problem is the ``flight`` scenario's (x8-3dof, N = 10, dt = 0.5 s, kinematic loop)
with the weighted strategy: ``do_mpc.model.Model`` (discrete, ``x+ = x + dt u``), the
reference as a time-varying parameter, the tracking, CoG and posture terms in
``lterm`` / ``mterm``, the control rate through ``set_rterm``, the joint, velocity and
platform-box bounds (terminal bounds on), the self-collision clearance as a nonlinear
constraint, IPOPT at the ``sqp`` backend's KKT tolerance.

Two things do-mpc cannot say as aeromanip does, and how they are said here:

* ``mterm`` sees ``x_N`` only, not ``u_{N-1}``: the terminal control cost
  ``||u_{N-1}||^2_{W_s}`` goes into ``lterm`` times a time-varying flag, 1 at stage N-1;
* do-mpc evaluates nonlinear constraints at ``x_0 .. x_{N-1}`` (not at ``x_N``; ``x_0``
  is fixed): the clearance is written on the next state ``x_k + dt u_k`` = ``x_{k+1}``,
  so it holds on every predicted state ``x_1 .. x_N``, as aeromanip's rows.

``equivalence`` evaluates both objectives at one trajectory (they must agree to
``EQUIV_RTOL``); ``bench_peer`` flies do-mpc and aeromanip's weighted ``sqp``,
hierarchical ``sqp`` and ``sqp-rti`` in one process and reports the median ratios.
"""

from __future__ import annotations

import time
import warnings
from typing import Any

import casadi as ca
import numpy as np

from aeromanip.bench.controller_speed import (
    bench_scenario,
    closed_loop_score,
    closed_loop_steps,
    machine,
    run_variant,
)
from aeromanip.errors import ConfigError
from aeromanip.experiment.scenario import Scenario
from aeromanip.nmpc.backends.codegen import limit_blas_threads
from aeromanip.nmpc.backends.sqp.solver import DEFAULTS as SQP_DEFAULTS
from aeromanip.nmpc.problem import Problem
from aeromanip.nmpc.transcription import Transcription

MISSING = "do-mpc is not installed (the peer benchmark): pip install -e '.[bench]'"
TOL = SQP_DEFAULTS["tol"]  # IPOPT's tol: the sqp backend's KKT tolerance (1e-6)
DEFAULT_TOL = 1e-8  # IPOPT's default tol (an information row)
EQUIV_RTOL = 1e-9  # the two objectives at one trajectory: largest relative difference
TASKS = ("tracking", "cog", "posture", "control_rate")  # the terms expressed here
# row: (strategy, backend, target: do-mpc's median over the row's at least this)
ROWS: dict[str, tuple[str, str, float]] = {
    "weighted": ("weighted", "sqp", 25.0),
    "hierarchical": ("hierarchical", "sqp", 12.0),
    "rti": ("weighted", "sqp-rti", 60.0),
}


def import_dompc() -> Any:
    """``do_mpc`` (its optional-feature warnings silenced), or a ``ConfigError``."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            import do_mpc
    except ImportError:
        raise ConfigError(MISSING) from None
    return do_mpc


def _check(problem: Problem) -> None:
    """Refuse problems whose terms this peer does not express identically."""
    names = [type(e.task).__name__ for e in problem.entries]
    kinds = {"EndEffectorTracking", "CogAlignment", "Posture", "ControlRate"}
    if set(names) - kinds or len(names) != len(set(names)):
        raise ConfigError(f"do-mpc peer: tasks {names}: only one each of {TASKS}")
    if problem.model.nz != 2 * problem.kin.nx or problem.bounds.accel_limits is not None:
        raise ConfigError("do-mpc peer: rate responses and command-rate bounds not expressed")
    if [type(c).__name__ for c in problem.constraints] not in ([], ["Clearance"]):
        raise ConfigError("do-mpc peer: path constraints other than the clearance")


def _state_cost(problem: Problem, x: ca.SX, ref: ca.SX, terminal: bool) -> ca.SX:
    """Tracking + CoG + posture: ``sum W ||r(x)||^2`` (terminal: the weights ``W_s``)."""
    kin, names, cost = problem.kin, problem.robot.state_names, ca.SX(0)
    for e in problem.entries:
        w, task = ca.DM(e.terminal_weight if terminal else e.weight), e.task
        kind = type(task).__name__
        if kind == "EndEffectorTracking":
            if task.orientation is not None:
                raise ConfigError("do-mpc peer: orientation tracking not expressed")
            r = (kin.ee_position(x) - ref)[task.rows]
        elif kind == "CogAlignment":
            r = kin.cog_body(x)[:2] - task.target
        elif kind == "Posture":
            r = ca.vertcat(*[x[names.index(d)] for d in task.dofs]) - ca.DM(task.target)
        else:
            continue
        cost += ca.dot(w, r**2)
    return cost


def build_mpc(problem: Problem, clearance: float | None, tol: float = TOL) -> Any:
    """The do-mpc MPC of ``problem`` (weighted strategy); ``clearance``: the planned
    minimum distance [m] (``None``: no clearance constraint)."""
    do_mpc = import_dompc()
    _check(problem)
    nx, dt, N, b = problem.kin.nx, problem.dt, problem.horizon, problem.bounds
    model = do_mpc.model.Model("discrete", "SX")
    x = model.set_variable("_x", "x", (nx, 1))
    u = model.set_variable("_u", "u", (nx, 1))
    ref = model.set_variable("_tvp", "ref", (3, 1))
    last = model.set_variable("_tvp", "last")  # 1 at stage N-1: the terminal control cost
    model.set_rhs("x", x + dt * u)
    model.setup()
    mpc = do_mpc.controller.MPC(model)
    mpc.settings.n_horizon, mpc.settings.t_step = N, dt
    mpc.settings.use_terminal_bounds = True
    mpc.settings.nlpsol_opts = {
        "ipopt.tol": tol,
        "ipopt.print_level": 0,
        "ipopt.sb": "yes",
        "print_time": 0,
        "record_time": True,  # IPOPT's own wall time in solver_stats
    }
    rate = next(e for e in problem.entries if type(e.task).__name__ == "ControlRate")
    lterm = _state_cost(problem, x, ref, False) + last * ca.dot(ca.DM(rate.terminal_weight), u**2)
    mpc.set_objective(lterm=lterm, mterm=_state_cost(problem, x, ref, True))
    mpc.set_rterm(u=rate.weight)
    for side, xb, ub in (("lower", b.x_lower, b.u_lower), ("upper", b.x_upper, b.u_upper)):
        mpc.bounds[side, "_x", "x"] = xb
        mpc.bounds[side, "_u", "u"] = ub
        mpc.terminal_bounds[side, "x"] = xb
    if clearance is not None:  # on x_{k+1} = x_k + dt u_k (see module doc)
        mpc.set_nl_cons("clearance", -problem.kin.clearance()(x + dt * u), ub=-clearance)
    mpc.set_tvp_fun(_tvp_fun(mpc, problem))
    with warnings.catch_warnings():  # do-mpc calls numpy on CasADi values (FutureWarning)
        warnings.simplefilter("ignore", FutureWarning)
        mpc.setup()
    return mpc


def _tvp_fun(mpc: Any, problem: Problem) -> Any:
    """do-mpc's time-varying parameters at time ``t`` [s]: the reference per stage."""
    tvp, N = mpc.get_tvp_template(), problem.horizon

    def tvp_fun(t: float) -> Any:
        P = problem.stage_params(t)
        for k in range(N + 1):
            tvp["_tvp", k, "ref"] = P[k, :3]
            tvp["_tvp", k, "last"] = float(k == N - 1)
        return tvp

    return tvp_fun


def planned_clearance(sc: Scenario) -> float | None:
    """The minimum clearance [m] aeromanip's rows require (``d_min`` + margin)."""
    if sc.clearance is None:
        return None
    path = Transcription(sc.problem, sc.problem.entries).stage_model.path
    if np.any(np.isfinite(path.upper)) or np.ptp(path.lower) > 0:
        raise ConfigError("do-mpc peer: the clearance rows are not one lower bound")
    return float(path.lower[0])


class DompcPeer:
    """do-mpc's MPC as the closed loop needs it: ``step(x, t) -> (u, iterations, ok)``."""

    def __init__(self, sc: Scenario, tol: float = TOL) -> None:
        self.sc = sc
        self.mpc = build_mpc(sc.problem, planned_clearance(sc), tol)
        self.solver_s: list[float] = []  # IPOPT's own wall time per step [s]
        self.reset()

    def reset(self, x0: np.ndarray | None = None) -> None:
        """Start afresh at ``x0`` (default the scenario's), at rest, from a constant guess."""
        self.mpc.reset_history()
        self.mpc.x0 = self.sc.x0 if x0 is None else x0
        self.mpc.u0 = np.zeros(self.sc.problem.kin.nx)
        self.mpc.set_initial_guess()
        self.mpc.flags["initial_run"] = False  # no multipliers from an earlier run
        self.solver_s = []

    def step(self, x: np.ndarray, t: float) -> tuple[np.ndarray, int, bool]:
        """``make_step`` at time ``t`` [s]; the first command [state units/s]."""
        self.mpc.t0 = t
        u = self.mpc.make_step(x).ravel()
        st = self.mpc.solver_stats
        self.solver_s.append(float(st["t_wall_total"]))
        return u, int(st["iter_count"]), bool(st["success"])


def equivalence(sc: Scenario, seed: int = 0, t: float = 3.0) -> dict[str, float]:
    """Both objectives at one trajectory: from the scenario's start, random commands
    within the bounds, the states rolled out; a random previous command."""
    pb, mpc = sc.problem, build_mpc(sc.problem, planned_clearance(sc))
    rng, N, nx, b = np.random.default_rng(seed), pb.horizon, pb.kin.nx, pb.bounds
    U = rng.uniform(b.u_lower, b.u_upper, (N, nx))
    u_prev = rng.uniform(b.u_lower, b.u_upper)
    X = sc.x0 + pb.dt * np.vstack([np.zeros(nx), np.cumsum(U, 0)])
    tr = Transcription(pb, pb.entries)
    p = tr.parameters(X[0], u_prev, pb.stage_params(t))
    w = tr.pack(X, U, u_prev)
    f_ours = float(ca.Function("f", [tr.w, tr.p], [tr.f])(w, p))
    costs = float(tr.costs(w, p).sum())
    ox, op = mpc.opt_x(0), mpc.opt_p(0)
    for k in range(N + 1):
        ox["_x", k, 0, -1] = X[k]
    for k in range(N):
        ox["_u", k, 0] = U[k]
    op["_x0"], op["_u_prev"] = X[0], u_prev
    op["_tvp"] = mpc.tvp_fun(t)["_tvp"]
    f_dompc = float(ca.Function("f", [mpc.nlp["x"], mpc.nlp["p"]], [mpc.nlp["f"]])(ox, op))
    rel = abs(f_dompc - f_ours) / abs(f_ours)
    return {
        "f_aeromanip": f_ours,
        "costs_aeromanip": costs,
        "f_dompc": f_dompc,
        "rel_diff": rel,
        "rel_diff_costs": abs(f_dompc - costs) / abs(costs),
    }


def _fly_dompc(duration: float, warmup: int, tol: float = TOL) -> dict[str, Any]:
    """do-mpc's closed loop of the flight (IPOPT's ``tol``): timing [ms] (and IPOPT's
    share), iterations, failures, score."""
    sc = bench_scenario("flight", duration)
    peer = DompcPeer(sc, tol)
    for k in range(warmup):
        peer.step(sc.x0, k * sc.problem.dt)
    peer.reset()
    X, U, ts, its, fails = closed_loop_steps(sc, peer.step, None)
    ms = 1e3 * np.array(ts)
    return {
        "backend": f"do-mpc + ipopt (tol {tol:g})",
        "ipopt_median_ms": float(np.median(1e3 * np.array(peer.solver_s))),
        "steps": len(ms),
        "median_ms": float(np.median(ms)),
        "p95_ms": float(np.percentile(ms, 95)),
        "max_ms": float(ms.max()),
        "iterations_mean": float(np.mean(its)),
        "failures": int(fails),
        **closed_loop_score(sc, X, U),
        "commands": U.tolist(),
    }


def bench_peer(duration: float = 60.0, warmup: int = 3) -> dict[str, Any]:
    """The equivalence check (must hold, else ``ConfigError``), then do-mpc and the
    ``ROWS`` flown on the flight for ``duration`` [s] each, in this process."""
    t0 = time.perf_counter()
    eq = equivalence(bench_scenario("flight", duration))
    if not eq["rel_diff"] <= EQUIV_RTOL:
        raise ConfigError(f"do-mpc peer: objectives differ by {eq['rel_diff']:.1e} (relative)")
    limit_blas_threads(1)
    rows = {"do-mpc": _fly_dompc(duration, warmup)}
    # for information: IPOPT's default tol, what a do-mpc user gets unless they set it
    default = _fly_dompc(duration, warmup, DEFAULT_TOL)
    default.pop("commands")
    commands = {}
    for name, (strategy, backend, _) in ROWS.items():
        rows[name] = run_variant("flight", strategy, backend, None, duration, warmup)
        commands[name] = rows[name].pop("commands")
    rows["do-mpc-default-tol"] = default
    ref, U_ref = rows["do-mpc"]["median_ms"], np.array(rows["do-mpc"].pop("commands"))
    for name, r in rows.items():
        r["speedup_vs_dompc"] = ref / r["median_ms"]
        r["cost_vs_dompc"] = r["closed_loop_cost"] / rows["do-mpc"]["closed_loop_cost"]
        if name == "weighted":  # the same NLP: the same commands, to the tolerances
            U = np.array(commands[name])
            r["max_command_diff_vs_dompc"] = float(np.abs(U - U_ref).max())
        if name in ROWS:
            r["target"] = ROWS[name][2]
            r["target_met"] = r["speedup_vs_dompc"] >= ROWS[name][2]
    return {
        "machine": {**machine(), "do_mpc": import_dompc().__version__},
        "duration_s": duration,
        "ipopt_tol": TOL,
        "equivalence": eq,
        "rows": rows,
        "wall_s": time.perf_counter() - t0,
    }


def format_peer(result: dict[str, Any]) -> str:
    """The results as Markdown: the equivalence figure and the side-by-side table."""
    eq = result["equivalence"]
    lines = [
        f"objectives at one trajectory: aeromanip {eq['f_aeromanip']:.12g}, do-mpc "
        f"{eq['f_dompc']:.12g}, relative difference {eq['rel_diff']:.1e}",
        "",
        "| row | backend | median ms | p95 ms | max ms | iters | fails | cost "
        "| x do-mpc's cost | x do-mpc (median) | target |",
        "|" + "---|" * 11,
    ]
    for name, r in result["rows"].items():
        target = (
            f">= {r['target']:g}x: {'yes' if r['target_met'] else 'NO'}" if "target" in r else "-"
        )
        lines.append(
            f"| {name} | {r['backend']} | {r['median_ms']:.2f} | {r['p95_ms']:.2f} "
            f"| {r['max_ms']:.2f} | {r['iterations_mean']:.1f} | {r['failures']} "
            f"| {r['closed_loop_cost']:.5f} | {r['cost_vs_dompc']:.4f} "
            f"| {r['speedup_vs_dompc']:.1f} | {target} |"
        )
    ipopt = result["rows"]["do-mpc"]["ipopt_median_ms"]
    lines += ["", f"do-mpc step: IPOPT's own wall time, median {ipopt:.2f} ms"]
    du = result["rows"].get("weighted", {}).get("max_command_diff_vs_dompc")
    if du is not None:
        lines += ["", f"weighted sqp vs do-mpc, largest command difference: {du:.1e}"]
    m = result["machine"]
    lines += [
        "",
        f"Machine: {m['cpu']}, {m['cores']} cores; do-mpc {m['do_mpc']}, CasADi {m['casadi']}; "
        f"load average at start {m['load_average_at_start']}; IPOPT tol {result['ipopt_tol']:g}; "
        f"{result['duration_s']:g} s closed loop per row.",
    ]
    return "\n".join(lines)
