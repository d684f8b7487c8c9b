"""How long kinematics take: EE position + arm CoG + both Jacobians for one state.

Three ways of calling the same CasADi Function, measured side by side:

* ``python``: ``f(x)`` from Python (converts inputs/outputs to ``DM``; what a script does);
* ``buffer``: CasADi's zero-copy buffer interface on preallocated NumPy arrays (what a
  real-time loop in Python should do);
* ``batch``: ``f.map(n)`` over many states in one call, per state.
"""

from __future__ import annotations

import numpy as np

from aeromanip.bench.timing import time_call
from aeromanip.errors import AeromanipError
from aeromanip.robot.kinematics import Kinematics
from aeromanip.robot.loader import load_robot


def bench_kinematics(robot: str = "x8-3dof", repeat: int = 5000, batch: int = 1000) -> dict:
    """Per-state evaluation times [us] of ``Kinematics.summary`` for ``robot``."""
    kin = Kinematics(load_robot(robot))
    f = kin.summary
    rng = np.random.default_rng(0)
    x = rng.uniform(-1, 1, kin.nx)
    python = time_call(lambda: f(x), repeat)

    buf, evaluate = f.buffer()
    x_buf = np.array(x)
    outs = [np.zeros(f.nnz_out(i)) for i in range(f.n_out())]
    buf.set_arg(0, memoryview(x_buf))
    for i, o in enumerate(outs):
        buf.set_res(i, memoryview(o))
    evaluate()
    expected = np.concatenate([np.asarray(v.nonzeros()) for v in f(x)])
    if not np.allclose(np.concatenate(outs), expected, rtol=0, atol=1e-14):
        raise AeromanipError("bench: the buffer evaluation disagrees with the Function call")
    buffered = time_call(evaluate, repeat * 4)

    fmap = f.map(batch)
    X = rng.uniform(-1, 1, (kin.nx, batch))
    per_batch = time_call(lambda: fmap(X), max(20, repeat // 250), warmup=3)
    batched = {k: v / batch for k, v in per_batch.items() if k != "calls"}
    return {
        "robot": robot,
        "outputs": "ee_position, cog_body, ee_jacobian, cog_jacobian",
        "instructions": int(f.n_instructions()),
        "python": python,
        "buffer": buffered,
        "batch_per_state": batched,
    }


def format_kinematics(result: dict) -> str:
    """A small table of ``bench_kinematics`` results."""
    lines = [
        f"kinematics of {result['robot']} ({result['outputs']}), "
        f"{result['instructions']} instructions",
        f"{'call':<18}{'median us':>12}{'p95 us':>12}",
    ]
    for key in ("python", "buffer", "batch_per_state"):
        r = result[key]
        lines.append(f"{key:<18}{r['median_us']:>12.2f}{r['p95_us']:>12.2f}")
    return "\n".join(lines)
