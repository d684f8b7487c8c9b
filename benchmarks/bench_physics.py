"""Cost of one physics step of ``PhysicsSimulator`` (inner loop + MuJoCo + bookkeeping).

For each robot (planar-2dof, x8-3dof) and case (``hover``: hold the initial state;
``moving``: platform and joints following slow sinusoids, with a yaw ramp on the x8), the
simulator is advanced by whole control periods; each period's wall time divided by its number
of physics steps is one sample. Printed: median and p95 of these per-step samples [us], and
simulated seconds per wall-clock second over all timed periods. For reference, the cost of a
bare ``mujoco.mj_step`` of the same model (no controller) is printed as the floor.

Run: ``python benchmarks/bench_physics.py [--periods 100] [--dt 0.1] [--json out.json]
[--option outer_rate_hz=500 ...]`` (``--option`` passes ``[physics]`` options through
``PhysicsSimulator.from_options``; the default options are the project's defaults).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from typing import Any

import mujoco
import numpy as np

from aeromanip.robot.loader import load_robot
from aeromanip.sim.physics import PhysicsSimulator

X0 = {
    "planar-2dof": [0.0, 1.0, 0.3, 0.5],
    "x8-3dof": [0.0, 0.0, 1.0, 0.0, 0.0, 0.4, -0.6],
}


def _command(spec: Any, t: float) -> np.ndarray:
    """Rates of the ``moving`` case at time ``t`` [s]: small sinusoids, a slow yaw ramp."""
    u = np.zeros(spec.nx)
    for i, dof in enumerate(spec.platform.dofs):
        if dof == "yaw":
            u[i] = 0.3
        else:
            u[i] = 0.2 * math.cos(0.6 * t + i)
    u[spec.n_platform :] = 0.3 * np.cos(0.5 * t + np.arange(spec.n_joints))
    return u


def bench_case(
    robot: str, case: str, periods: int, dt: float, options: dict[str, Any]
) -> dict[str, float]:
    """Per-physics-step timing of ``periods`` control periods of ``dt`` [s] (after warm-up)."""
    spec = load_robot(robot)
    sim = PhysicsSimulator.from_options(spec, options)
    x = np.array(X0[robot], dtype=float)
    sim.reset(x)
    steps = round(dt * sim.rate_hz)
    samples = np.empty(periods)
    warmup = 5
    for k in range(warmup + periods):
        u = _command(spec, k * dt) if case == "moving" else np.zeros(spec.nx)
        plan = np.tile(x, (2, 1))
        t0 = time.perf_counter()
        sim.advance(u, plan, dt)
        elapsed = time.perf_counter() - t0
        if k >= warmup:
            samples[k - warmup] = elapsed / steps
        x = x + dt * u  # nominal plan: ramps continue along the commanded path
    drift = float(np.linalg.norm(sim.true_state()[: spec.n_platform] - x[: spec.n_platform]))
    return {
        "robot": robot,
        "case": case,
        "steps_per_period": steps,
        "median_us": float(np.median(samples) * 1e6),
        "p95_us": float(np.percentile(samples, 95) * 1e6),
        "realtime_factor": float(1.0 / (samples.mean() * sim.rate_hz)),
        "platform_error_m": drift,
    }


def bench_mj_step(robot: str, repeat: int = 20000) -> float:
    """Median cost of a bare ``mj_step`` of the robot's model [us] (blocks of 100 steps)."""
    sim = PhysicsSimulator(load_robot(robot))
    m, d = sim.model, sim.data
    ts = []
    for _ in range(repeat // 100):
        t0 = time.perf_counter()
        for _ in range(100):
            mujoco.mj_step(m, d)
        ts.append((time.perf_counter() - t0) / 100)
    return float(np.median(ts) * 1e6)


def _parse_option(text: str) -> tuple[str, Any]:
    key, _, value = text.partition("=")
    number = float(value)
    return key, int(number) if number.is_integer() and key in ("rotors", "seed") else number


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--periods", type=int, default=100, help="timed control periods")
    parser.add_argument("--dt", type=float, default=0.1, help="control period [s]")
    parser.add_argument("--option", action="append", default=[], help="physics KEY=VALUE")
    parser.add_argument("--json", help="write the results to this file")
    args = parser.parse_args()
    options = dict(_parse_option(o) for o in args.option)
    results = []
    print(f"options {options or 'defaults'}, control period {args.dt} s")
    print(f"{'robot':<12} {'case':<7} {'median us':>9} {'p95 us':>8} {'sim s/wall s':>12}")
    for robot in X0:
        for case in ("hover", "moving"):
            r = bench_case(robot, case, args.periods, args.dt, options)
            results.append(r)
            print(
                f"{robot:<12} {case:<7} {r['median_us']:9.1f} {r['p95_us']:8.1f} "
                f"{r['realtime_factor']:12.1f}"
            )
        floor = bench_mj_step(robot)
        results.append({"robot": robot, "case": "mj_step only", "median_us": floor})
        print(f"{robot:<12} bare mj_step (floor): {floor:.1f} us")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=2)


if __name__ == "__main__":
    main()
