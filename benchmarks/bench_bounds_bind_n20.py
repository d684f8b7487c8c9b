"""The SQP where velocity bounds bind at N = 20, against IPOPT, in one process.

The flight at N = 20 (dt = 0.25 s) with its reference 25x faster (the stress bench's
`fast`): velocity bounds bind in about a third of the steps. Per strategy (weighted;
hierarchical, strict) and QP model, the closed loop on the kinematic simulator: step
median and p95 [ms], SQP iterations per step, and the closed-loop cost against IPOPT's.
The condensed model (``qpsol = "daqp"``, the compiled loop) is built once into the
compile cache (about 2 and 5 minutes at N = 20, 1.7 GiB in the compiler); the sparse
one (``"riccati"``, the default beyond ``condense_max_horizon``, or ``"hpipm"``) in
seconds. ``--qp`` keeps the rows of the QP solvers named (``ipopt`` for IPOPT's).

    python benchmarks/bench_bounds_bind_n20.py [--qp ipopt,riccati,hpipm] [out.json]
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np

from aeromanip.bench.controller_speed import closed_loop_score, machine
from aeromanip.experiment.scenario import load_scenarios
from aeromanip.nmpc.backends.codegen import limit_blas_threads
from aeromanip.nmpc.controller import Controller

SETS = [
    "sim=kinematic",
    "controller.horizon=20",
    "controller.dt=0.25",
    "controller.weights_dt=0.5",
    "reference.frequency=[0.3125, 0.2275, 0.1675]",  # the flight's, 25x faster
    "duration=15",
]
ROWS = [  # (strategy, backend, solver options)
    ("weighted", "ipopt", None),
    ("weighted", "sqp", {"qpsol": "daqp"}),
    ("weighted", "sqp", {"qpsol": "riccati"}),
    ("weighted", "sqp", {"qpsol": "hpipm"}),
    ("hierarchical", "ipopt", None),
    ("hierarchical", "sqp", {"qpsol": "daqp"}),
    ("hierarchical", "sqp", {"qpsol": "riccati"}),
    ("hierarchical", "sqp", {"qpsol": "hpipm"}),
]


def closed_loop(strategy: str, backend: str, options: dict | None) -> dict:
    """One row: the 60-step closed loop (after one warm-up loop, controller reset)."""
    sc = load_scenarios("flight", [*SETS, f"controller.strategy={strategy}"])[""]
    pb = sc.problem
    hierarchy = sc.hierarchy if strategy == "hierarchical" else None
    ctrl = Controller(pb, strategy, backend, options, hierarchy=hierarchy)
    limit_blas_threads(1)
    for _pass in ("warm-up", "timed"):  # the second loop is the one reported
        ctrl.reset()
        x, X, U, ts, its = sc.x0.copy(), [], [], [], []
        for k in range(sc.steps):
            t0 = time.perf_counter()
            cmd = ctrl.step(x, k * pb.dt)
            ts.append(time.perf_counter() - t0)
            X.append(x)
            U.append(cmd.u)
            its.append(cmd.iterations)
            x = x + pb.dt * cmd.u
    ms = 1e3 * np.array(ts)
    return {
        "strategy": strategy,
        "backend": backend,
        "qpsol": (options or {}).get("qpsol", "-"),
        "median_ms": float(np.median(ms)),
        "p95_ms": float(np.percentile(ms, 95)),
        "iterations_mean": float(np.mean(its)),
        **closed_loop_score(sc, np.array(X), np.array(U)),
    }


def _qp_name(row: tuple) -> str:
    return (row[2] or {}).get("qpsol", row[1])


def main(argv: list[str]) -> int:
    keep = None
    if argv[:1] == ["--qp"]:
        keep, argv = set(argv[1].split(",")), argv[2:]
    rows = [closed_loop(*row) for row in ROWS if keep is None or _qp_name(row) in keep]
    ipopt = {r["strategy"]: r for r in rows if r["backend"] == "ipopt"}
    print("| strategy | backend | QP | median ms | p95 ms | iters | cost | x IPOPT's cost |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        ratio = r["closed_loop_cost"] / ipopt[r["strategy"]]["closed_loop_cost"]
        print(
            f"| {r['strategy']} | {r['backend']} | {r['qpsol']} | {r['median_ms']:.1f} "
            f"| {r['p95_ms']:.1f} | {r['iterations_mean']:.1f} | {r['closed_loop_cost']:.5f} "
            f"| {ratio:.4f} |"
        )
    if argv:
        with open(argv[0], "w") as fh:
            json.dump({"machine": machine(), "rows": rows}, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
