"""The exported C controller (``aeromanip export``) against the Python controller.

The 13-minute ``flight`` (1560 steps at 2 Hz, N = 10) on the kinematic model, weighted
and as the strict hierarchy of two levels, each with the SQP and the real-time
iteration, and the SQP with a bounded step (``accept_at_max_iter``: at most 3 QPs,
weighted; 5 a level, hierarchical): per row, the C example's step median and worst
case over the whole flight (built with ``-O3 -funroll-loops``, as the export's Makefile
does; the flight flown ``REPEATS`` times: the first flight's median and worst, and the
worst of each step's fastest time over the flights, the step's own work without what
other processes of a shared machine took from it), then the
Python controller's step on the same flight in this process (its compiled loop), the
library's code size and static memory (``size``: text; data + bss) and the step's
worst-case stack (GCC's call graph, ``-fcallgraph-info=su``: the deepest chain of frames
from ``aeromanip_step``, the generated model's functions at the indirect calls).

    python benchmarks/bench_export.py [out.json]
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from aeromanip.bench.controller_speed import machine
from aeromanip.cli import main as aeromanip
from aeromanip.experiment.closed_loop import make_controller
from aeromanip.experiment.scenario import load_scenarios

SEED = "controller.solver_options.seed=none"  # the export has no IPOPT seed
BASE = ["controller.strategy=weighted", SEED]
RTI = "controller.backend=sqp-rti"
ACCEPT = "controller.solver_options.accept_at_max_iter=true"
ROWS = {"weighted sqp": BASE, "weighted sqp-rti": [*BASE, RTI],
        "hierarchical sqp": [SEED], "hierarchical sqp-rti": [SEED, RTI],
        "weighted sqp, 3 QPs": [*BASE, "controller.solver_options.max_iter=3", ACCEPT],
        "hierarchical sqp, 5 QPs a level": [SEED, "controller.solver_options.max_iter=5",
                                            ACCEPT]}  # fmt: skip
REPEATS = 3  # flights of the C example per row
CFLAGS = "-O3 -funroll-loops"  # the Makefile's default


def build(sets: list[str], out: Path) -> None:
    """Export ``flight`` with ``sets`` into ``out`` and build it (call-graph info on)."""
    args = ["export", "flight", "--out", str(out)]
    for s in sets:
        args += ["--set", s]
    assert aeromanip(args) == 0
    flags = f"CFLAGS={CFLAGS} -fcallgraph-info=su"
    subprocess.run(["make", "-C", str(out), "-j2", flags], check=True, capture_output=True)


def c_steps(out: Path) -> dict:
    """The example's summary (its first flight): step median and worst case [ms], EE
    RMSE [mm]; and over ``REPEATS`` flights, the worst of each step's fastest [ms]."""
    runs = [subprocess.run([str(out / "example" / "example")], capture_output=True,
                           text=True, check=True).stdout.strip().splitlines()
            for _ in range(REPEATS)]  # fmt: skip
    last = runs[0][-1]
    median, worst = (float(v) for v in re.findall(r"([0-9.]+) us", last))
    rmse = float(re.search(r"EE RMSE ([0-9.]+) mm", last).group(1))
    # the per-step rows (step,t_s,solve_us,status,iterations) between header and summary
    fastest = np.min([[float(row.split(",")[2]) for row in r[1:-1]] for r in runs], axis=0)
    return {"c_median_ms": median / 1e3, "c_worst_ms": worst / 1e3, "c_ee_rmse_mm": rmse,
            "c_own_worst_ms": float(fastest.max()) / 1e3,
            "c_own_median_ms": float(np.median(fastest)) / 1e3,
            "c_failed": int(re.search(r"failed (\d+)", last).group(1)),
            "c_partial": int(re.search(r"partial (\d+)", last).group(1))}  # fmt: skip


def python_steps(sets: list[str]) -> dict:
    """The Python controller's step over the same flight [ms]."""
    sc = load_scenarios("flight", [*sets, "sim=kinematic"])[""]
    ctrl = make_controller(sc)
    x, dt, times = sc.x0.copy(), sc.problem.dt, []
    for k in range(sc.steps):
        t0 = time.perf_counter()
        cmd = ctrl.step(x, k * dt)
        times.append(time.perf_counter() - t0)
        x = x + dt * cmd.u
    ms = 1e3 * np.array(times)
    return {"python_median_ms": float(np.median(ms)), "python_worst_ms": float(ms.max())}


def memory(out: Path) -> dict:
    """Code size and static memory [bytes] of the library (``size``)."""
    run = subprocess.run(["size", "-t", str(out / "libaeromanip_controller.a")],
                         capture_output=True, text=True, check=True)  # fmt: skip
    text, data, bss = (int(v) for v in run.stdout.strip().splitlines()[-1].split()[:3])
    return {"code_bytes": text, "static_bytes": data + bss, "stack_bytes": stack(out)}


def stack(out: Path) -> int:
    """The deepest chain of stack frames [bytes] from ``aeromanip_step`` (GCC's call graph;
    ``fn_call``'s indirect call goes to the largest generated function)."""
    frames: dict[str, int] = {}
    calls: dict[str, set[str]] = {}
    for ci in out.rglob("*.ci"):
        text = ci.read_text()
        for title, label in re.findall(r'node: \{ title: "([^"]+)" label: "([^"]+)"', text):
            size = re.search(r"\\n(\d+) bytes", label)
            if size:
                frames[title.split(":")[-1]] = int(size.group(1))
        for a, b in re.findall(r'edge: \{ sourcename: "([^"]+)" targetname: "([^"]+)"', text):
            calls.setdefault(a.split(":")[-1], set()).add(b.split(":")[-1])
    prefixes = ("aeromanip_data_", "aeromanip_merit_", "aeromanip_hessian_", "aeromanip_bounds_",
                "aeromanip_model_f", "aeromanip_parameters", "aeromanip_plan")  # fmt: skip
    generated = {f for f in frames if f.startswith(prefixes)}
    calls.setdefault("fn_call", set()).update(generated)

    def deepest(fn: str, seen: frozenset[str]) -> int:
        below = [deepest(c, seen | {fn}) for c in calls.get(fn, ()) if c not in seen]
        return frames.get(fn, 0) + max(below, default=0)

    return deepest("aeromanip_step", frozenset())


def main() -> None:
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, sets in ROWS.items():
            out = Path(tmp) / name.replace(" ", "-")
            build(sets, out)
            rows[name] = {**c_steps(out), **python_steps(sets), **memory(out)}
            r = rows[name]
            print(f"{name:20s} C {r['c_median_ms']:.3f} / {r['c_worst_ms']:.3f} ms "
                  f"(own worst {r['c_own_worst_ms']:.3f} ms, "
                  f"{r['c_own_worst_ms'] / r['c_own_median_ms']:.1f}x its median), "
                  f"partial {r['c_partial']}, "
                  f"Python {r['python_median_ms']:.3f} / {r['python_worst_ms']:.3f} ms "
                  f"(median / worst), EE RMSE {r['c_ee_rmse_mm']:.3f} mm, "
                  f"code {r['code_bytes'] / 1024:.0f} KiB, static {r['static_bytes']} B, "
                  f"stack {r['stack_bytes']} B")  # fmt: skip
    if len(sys.argv) > 1:
        Path(sys.argv[1]).write_text(json.dumps({"machine": machine(), "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
