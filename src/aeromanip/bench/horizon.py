"""How build time, build memory and step time grow with the horizon (``aeromanip bench
horizon``).

The flight problem with a 5 s horizon at ``N`` steps (``dt = 5 / N``), each case built
from a cold compile cache in a fresh process, so that its peak memory (``ru_maxrss`` of
the process and of its largest child, the C compiler) and build time are its own; then
``STEPS`` closed-loop steps on the kinematic simulator give the step time.
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from typing import Any

import numpy as np

HORIZONS = (10, 20, 50, 100)
CASES = (  # (backend, strategy)
    ("sqp", "weighted"),
    ("sqp", "hierarchical"),
    ("sqp-rti", "hierarchical"),
    ("ipopt", "weighted"),
    ("ipopt", "hierarchical"),
)
HORIZON_S = 5.0  # [s] the prediction horizon of every case
STEPS = 30  # closed-loop steps timed per case (after WARMUP)
WARMUP = 3
PROBE_TIMEOUT_S = 3600.0


def probe(horizon: int, backend: str, strategy: str) -> dict[str, Any]:
    """Build and time one case in this process (run by ``main`` in a fresh one)."""
    from aeromanip.experiment.closed_loop import make_controller, make_simulator
    from aeromanip.experiment.scenario import load_scenarios

    dt = HORIZON_S / horizon
    sets = [
        "sim='kinematic'",
        f"controller.dt={dt}",
        f"controller.horizon={horizon}",
        "controller.weights_dt=0.5",  # the flight's weights, whatever the period
        f"controller.backend='{backend}'",
        f"controller.strategy='{strategy}'",
        f"duration={dt * (STEPS + WARMUP)}",
    ]
    sc = load_scenarios("flight", sets)[""]
    t0 = time.perf_counter()
    ctrl = make_controller(sc)
    build_s = time.perf_counter() - t0
    sim = make_simulator(sc)
    sim.reset(sc.x0)
    times, statuses = [], []
    for k in range(STEPS + WARMUP):
        t1 = time.perf_counter()
        cmd = ctrl.step(sim.state(), k * dt)
        if k >= WARMUP:
            times.append(time.perf_counter() - t1)
            statuses.append(cmd.status)
        sim.advance(cmd.u, cmd.plan_x, dt)
    mib = 1.0 / 1024.0  # ru_maxrss is in KiB on Linux
    return {
        "horizon": horizon,
        "backend": backend,
        "strategy": strategy,
        "build_s": build_s,
        "rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * mib,
        "compiler_rss_mib": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * mib,
        "step_ms_median": 1e3 * float(np.median(times)),
        "step_ms_p95": 1e3 * float(np.percentile(times, 95)),
        "ok_steps": statuses.count("ok"),
        "steps": len(statuses),
    }


def run_probe(horizon: int, backend: str, strategy: str) -> dict[str, Any]:
    """``probe`` in a fresh process with an empty compile cache (a cold build)."""
    with tempfile.TemporaryDirectory(prefix="aeromanip-bench-") as cache:
        env = {**os.environ, "AEROMANIP_CACHE": cache, "AEROMANIP_CODEGEN": "1"}
        cmd = [sys.executable, "-m", "aeromanip.bench.horizon", str(horizon), backend, strategy]
        done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=PROBE_TIMEOUT_S)
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["?"])[-1]
        return {"horizon": horizon, "backend": backend, "strategy": strategy, "error": last}
    return json.loads(done.stdout.strip().splitlines()[-1])


def bench_horizon(
    horizons: tuple[int, ...] = HORIZONS, cases: tuple[tuple[str, str], ...] = CASES
) -> list[dict[str, Any]]:
    """Every case at every horizon (each in its own process, one after the other)."""
    return [run_probe(n, b, s) for n in horizons for b, s in cases]


def format_horizon(rows: list[dict[str, Any]]) -> str:
    """The table: one line per case."""
    head = (
        f"{'N':>4} {'backend':<8}{'strategy':<14}{'build s':>9}{'build MiB':>11}"
        f"{'gcc MiB':>9}{'step ms':>9}{'p95 ms':>8}{'ok':>7}"
    )
    lines = [head]
    for r in rows:
        lead = f"{r['horizon']:>4} {r['backend']:<8}{r['strategy']:<14}"
        if "error" in r:
            lines.append(f"{lead}failed: {r['error']}")
            continue
        lines.append(
            f"{lead}{r['build_s']:>9.1f}{r['rss_mib']:>11.0f}{r['compiler_rss_mib']:>9.0f}"
            f"{r['step_ms_median']:>9.1f}{r['step_ms_p95']:>8.1f}"
            f"{r['ok_steps']:>4}/{r['steps']:<2}"
        )
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    """``python -m aeromanip.bench.horizon N BACKEND STRATEGY``: one probe, JSON out."""
    from aeromanip.nmpc.backends.codegen import limit_blas_threads

    limit_blas_threads(1)
    print(json.dumps(probe(int(argv[0]), argv[1], argv[2])))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
