"""The exported C controller (``aeromanip export``) against the Python controller: the
same commands, statuses and iterations on the same recorded states, through solves,
cold retries, fallbacks and stops; bad input refused; the example flies the scenario.

The exports are built with ``-O0``: the tests are about answers, and the generated model
compiles in seconds so (timings are ``aeromanip bench``'s and the example's). The Python
controller runs its NumPy loop with CasADi's DAQP (codegen off): a second
implementation of everything the C step does.
"""

from __future__ import annotations

import ctypes
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from aeromanip.cli import main
from aeromanip.errors import StateError
from aeromanip.experiment.closed_loop import make_controller
from aeromanip.experiment.scenario import load_scenarios

BUILD_TIMEOUT_S = 300
EXPORTS = {
    "flight": ("flight", ["controller.strategy=weighted", "controller.solver_options.seed=none"]),
    # four SQP iterations: where the reference jumps ahead, solves fail, are retried
    # cold, fall back on the last plan and stop once it has flown out; with latency
    "flight, 4 iterations": ("flight", ["controller.strategy=weighted",
                                        "controller.solver_options.seed=none",
                                        "controller.solver_options.max_iter=4",
                                        "controller.latency=0.1"]),
    "planar RTI": ("planar", ["controller.backend=sqp-rti", "controller.horizon=10",
                              "controller.solver_options.seed=none"]),
    "hierarchical flight": ("flight", ["controller.solver_options.seed=none"]),
    # four SQP iterations and four DAQP iterations per QP: the second level's QPs fail
    # where the first level's do not (partial steps), besides retries, fallbacks, stops
    "hierarchical flight, 4 iterations": ("flight", [
        "controller.solver_options.seed=none", "controller.solver_options.max_iter=4",
        "controller.solver_options.qpsol_options.daqp.iter_limit=4", "controller.latency=0.1"]),
    # a bounded step: at most 5 QPs a level (corrections counted), the last iterate the
    # answer where its rows hold, shifted Hessians, no cold retry
    "hierarchical flight, bounded": ("flight", [
        "controller.solver_options.seed=none", "controller.solver_options.max_iter=5",
        "controller.solver_options.accept_at_max_iter=true"]),
    # rate lags (the platform's) at 10 Hz with latency: the measured rates start the plan
    "rate lags": ("waypoints-rates", ["controller.horizon=10",
                                      "controller.solver_options.seed=none",
                                      "controller.solver_options.qpsol=daqp"]),
}  # fmt: skip
VARIANTS = {"planar": "cond-default", "waypoints-rates": "10hz"}


def _export(name: str, root: Path) -> tuple[Path, object]:
    scenario, sets = EXPORTS[name]
    variant = VARIANTS.get(scenario)
    out = root / re.sub(r"\W+", "-", name)
    args = ["export", scenario, "--out", str(out)] + (["--variant", variant] if variant else [])
    for s in sets:
        args += ["--set", s]
    assert main(args) == 0
    make = ["make", "-C", str(out), "-j2", "CFLAGS=-O0", "all", "shared"]
    subprocess.run(make, check=True, capture_output=True, timeout=BUILD_TIMEOUT_S)
    sc = next(iter(load_scenarios(scenario, sets, variant).values()))
    return out, sc


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    root = tmp_path_factory.mktemp("exports")
    return {name: _export(name, root) for name in EXPORTS}


class Exported:
    """The exported library through ctypes."""

    def __init__(self, directory: Path, nx: int, N: int) -> None:
        class Output(ctypes.Structure):
            _fields_ = [
                ("u", ctypes.c_double * nx),
                ("plan_x", ctypes.c_double * ((N + 1) * nx)),
                ("plan_u", ctypes.c_double * (N * nx)),
                ("status", ctypes.c_int),
                ("solver_status", ctypes.c_int),
                ("iterations", ctypes.c_int),
                ("levels", ctypes.c_int),
                ("cost", ctypes.c_double),
            ]

        self.lib = ctypes.CDLL(str(directory / "libaeromanip_controller.so"))
        self.lib.aeromanip_init.restype = ctypes.c_void_p
        self.lib.aeromanip_step.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_double,
                                            ctypes.POINTER(Output)]  # fmt: skip
        self.lib.aeromanip_step_rates.argtypes = [ctypes.c_void_p, ctypes.c_void_p,
                                                  ctypes.c_void_p, ctypes.c_double,
                                                  ctypes.POINTER(Output)]  # fmt: skip
        self.lib.aeromanip_free.argtypes = [ctypes.c_void_p]
        self.lib.aeromanip_discard.argtypes = [ctypes.c_void_p]
        self.handle = self.lib.aeromanip_init()
        assert self.handle
        self.out = Output()

    def step(self, x: np.ndarray, t: float, rates: np.ndarray | None = None) -> int:
        x = np.ascontiguousarray(x, dtype=float)
        if rates is None:
            return self.lib.aeromanip_step(self.handle, x.ctypes.data, t, ctypes.byref(self.out))
        r = np.ascontiguousarray(rates, dtype=float)
        return self.lib.aeromanip_step_rates(self.handle, x.ctypes.data, r.ctypes.data, t,
                                             ctypes.byref(self.out))  # fmt: skip

    def discard(self) -> None:
        self.lib.aeromanip_discard(self.handle)

    def close(self) -> None:
        self.lib.aeromanip_free(self.handle)


STATUS = {0: "ok", 1: "fallback", 2: "stopped", 4: "partial"}


def _lockstep(
    directory: Path,
    sc,
    steps: int,
    noise: float,
    jump_s: float = 0.0,
    lags: bool = False,
    discards: bool = False,
) -> dict:
    """Fly the Python controller on its kinematic model (the state disturbed by
    ``noise`` [m, rad] per step, the clock jumping ``jump_s`` ahead every 10 steps; with
    ``lags`` the rates follow the commands through the model's first-order lags and are
    measured; with ``discards`` every 7th command, twice, is discarded as too late by
    both) and hand each state to the C controller too; the statuses seen."""
    ctrl = make_controller(sc)
    c = Exported(directory, ctrl.nx, sc.problem.horizon)
    rng = np.random.default_rng(11)
    x, dt, seen = sc.x0.copy(), sc.problem.dt, {}
    tau = sc.problem.model.tau
    lag = np.where(tau > 0, np.exp(-dt / np.where(tau > 0, tau, 1.0)), 0.0)
    rates = np.zeros_like(x) if lags else None
    try:
        for k in range(steps):
            t = k * dt + jump_s * (k // 10)
            cmd = ctrl.step(x, t, rates=rates)
            status = c.step(x, t, rates)
            assert STATUS[status] == cmd.status, f"step {k}"
            assert c.out.iterations == cmd.iterations, f"step {k}"
            solved = sum(level.success for level in cmd.levels)
            assert c.out.levels == (solved if cmd.status in ("ok", "partial") else 0)
            np.testing.assert_allclose(np.array(c.out.u), cmd.u, rtol=0, atol=1e-8)
            np.testing.assert_allclose(
                np.array(c.out.plan_x).reshape(-1, ctrl.nx), cmd.plan_x, rtol=0, atol=1e-8
            )
            seen[cmd.status] = seen.get(cmd.status, 0) + 1
            if discards and k % 7 == 3:
                for _ in range(2):
                    ctrl.discard()
                    c.discard()
                seen["discarded"] = seen.get("discarded", 0) + 1
            u = ctrl.u_prev  # what flies: the command, or after discards the old plan's
            if lags:
                rates = u + lag * (rates - u) + rng.normal(0.0, noise, x.size)
            x = x + dt * (u if rates is None else rates) + rng.normal(0.0, noise, x.size)
    finally:
        c.close()
    return seen


def test_the_weighted_sqp_gives_the_python_controllers_commands(built):
    directory, sc = built["flight"]
    seen = _lockstep(directory, sc, 60, 0.003)
    assert seen == {"ok": 60}


def test_cold_retries_fallbacks_and_stops_are_the_python_controllers(built):
    directory, sc = built["flight, 4 iterations"]
    seen = _lockstep(directory, sc, 60, 0.003, jump_s=25.0)
    assert seen["ok"] > 20 and seen["fallback"] > 3 and seen["stopped"] > 3  # every path


def test_the_real_time_iteration_gives_the_python_controllers_commands(built):
    directory, sc = built["planar RTI"]
    assert _lockstep(directory, sc, 80, 0.002) == {"ok": 80}


def test_the_strict_hierarchy_gives_the_python_controllers_commands(built):
    directory, sc = built["hierarchical flight"]
    assert sc.strategy == "hierarchical" and len(sc.problem.levels) == 2
    assert _lockstep(directory, sc, 60, 0.003) == {"ok": 60}


def test_a_hierarchys_partial_steps_are_the_python_controllers(built):
    directory, sc = built["hierarchical flight, 4 iterations"]
    seen = _lockstep(directory, sc, 60, 0.003, jump_s=5.0)
    assert seen["ok"] > 20 and seen["partial"] > 2  # the second level failed, not the first
    assert seen["fallback"] > 3 and seen["stopped"] > 3


def test_a_bounded_hierarchys_steps_are_the_python_controllers(built):
    directory, sc = built["hierarchical flight, bounded"]
    seen = _lockstep(directory, sc, 60, 0.003, jump_s=25.0)  # the reference jumps far
    assert seen["ok"] > 20 and seen["partial"] > 2 and set(seen) == {"ok", "partial"}, seen


def test_rate_lags_start_from_the_measured_rates_as_in_python(built):
    directory, sc = built["rate lags"]
    assert sc.problem.model.has_response and sc.latency_s > 0
    assert _lockstep(directory, sc, 60, 0.002, lags=True) == {"ok": 60}


def test_discarded_commands_let_the_last_plan_fly_on_as_in_python(built):
    directory, sc = built["hierarchical flight, 4 iterations"]
    seen = _lockstep(directory, sc, 60, 0.003, jump_s=5.0, discards=True)
    assert seen["discarded"] >= 8 and seen["ok"] > 10 and seen["fallback"] > 2


def test_a_state_that_is_not_finite_is_refused_and_changes_nothing(built):
    directory, sc = built["flight"]
    ctrl, nx = make_controller(sc), sc.problem.kin.nx
    c = Exported(directory, nx, sc.problem.horizon)
    try:
        x = sc.x0.copy()
        for k, bad in enumerate([None, np.nan, None, np.inf, None]):
            if bad is not None:
                x_bad = x.copy()
                x_bad[2] = bad
                assert c.step(x_bad, k * 0.5) == 3  # AEROMANIP_BAD_INPUT
                with pytest.raises(StateError):
                    ctrl.step(x_bad, k * 0.5)
                continue
            cmd = ctrl.step(x, k * 0.5)
            assert c.step(x, k * 0.5) == 0
            np.testing.assert_allclose(np.array(c.out.u), cmd.u, rtol=0, atol=1e-8)
            x = x + 0.5 * cmd.u
    finally:
        c.close()


def test_the_example_flies_the_scenario_with_the_python_controllers_error(built):
    directory, sc = built["flight"]
    steps = 40
    run = subprocess.run([str(directory / "example" / "example"), str(steps)],
                         capture_output=True, text=True, timeout=60)  # fmt: skip
    assert run.returncode == 0, run.stderr
    lines = run.stdout.strip().splitlines()
    assert len(lines) == steps + 2  # header, one per step, summary
    rmse_mm = float(re.search(r"EE RMSE ([0-9.]+) mm", lines[-1]).group(1))
    ctrl, x, sq = make_controller(sc), sc.x0.copy(), 0.0
    for k in range(steps):
        t = k * sc.problem.dt
        sq += np.sum((sc.problem.ee_of(x) - sc.reference.position(t)) ** 2)
        x = x + sc.problem.dt * ctrl.step(x, t).u
    assert rmse_mm == pytest.approx(1e3 * np.sqrt(sq / steps), abs=2e-6)
    assert "failed 0" in lines[-1]


@pytest.mark.parametrize(
    "args, key",
    [
        (["flight", "--set", "controller.hierarchy.mode=stagewise"],
         "controller.hierarchy.mode: 'stagewise'"),
        (["contact-wall", "--variant", "cog"], "controller.backend: 'ipopt'"),
        (["contact-wall", "--variant", "cog", "--set", "controller.backend=sqp"], "tasks.force"),
        (["flight", "--set", "controller.strategy=weighted", "--set", "controller.horizon=20"],
         "controller.solver_options"),
        (["waypoints-rates", "--variant", "10hz"], "controller.solver_options"),
    ],
)  # fmt: skip
def test_what_cannot_be_exported_is_refused_in_one_line_before_writing(args, key, tmp_path,
                                                                       capsys):  # fmt: skip
    out = tmp_path / "export"
    assert main(["export", *args, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and key in err
    assert not out.exists()


COUNTING_HARNESS = r"""
#include <stdio.h>
#include <stdlib.h>
#include "aeromanip_controller.h"
void* __real_malloc(size_t n);
void* __real_calloc(size_t n, size_t k);
void* __real_realloc(void* p, size_t n);
static long counted = 0;
void* __wrap_malloc(size_t n) { ++counted; return __real_malloc(n); }
void* __wrap_calloc(size_t n, size_t k) { ++counted; return __real_calloc(n, k); }
void* __wrap_realloc(void* p, size_t n) { ++counted; return __real_realloc(p, n); }
int main(int argc, char** argv) {
  double x[AEROMANIP_NX];
  for (int i = 0; i < AEROMANIP_NX && i + 1 < argc; ++i) x[i] = atof(argv[i + 1]);
  aeromanip_controller* c = aeromanip_init();
  long in_init = counted, solved = 0;
  aeromanip_output out;
  for (int k = 0; k < 40; ++k) {
    solved += aeromanip_step(c, x, k * AEROMANIP_DT, &out) == AEROMANIP_OK;
    for (int i = 0; i < AEROMANIP_NX; ++i) x[i] += AEROMANIP_DT * out.u[i];
  }
  printf("%ld %ld %ld\n", in_init, counted - in_init, solved);
  aeromanip_free(c);
  return 0;
}
"""


@pytest.mark.parametrize("name", ["flight", "hierarchical flight"])
def test_a_step_allocates_no_memory(built, tmp_path, name):
    directory, sc = built[name]
    src, exe = tmp_path / "count.c", tmp_path / "count"
    src.write_text(COUNTING_HARNESS)
    wrap = "-Wl,--wrap=malloc,--wrap=calloc,--wrap=realloc"
    subprocess.run(["cc", "-O0", f"-I{directory / 'include'}", str(src),
                    str(directory / "libaeromanip_controller.a"), "-lm", wrap, "-o", str(exe)],
                   check=True, capture_output=True, timeout=60)  # fmt: skip
    run = subprocess.run([str(exe), *map(repr, sc.x0)], capture_output=True, text=True,
                         check=True, timeout=60)  # fmt: skip
    in_init, in_steps, solved = map(int, run.stdout.split())
    assert in_init > 10  # the counter sees the library's allocations
    assert solved == 40 and in_steps == 0


AARCH64_CC = "aarch64-linux-gnu-gcc"  # Debian's gcc-aarch64-linux-gnu (tools/install-cross)
EM_AARCH64 = 183  # the ELF header's e_machine for aarch64


@pytest.mark.skipif(shutil.which(AARCH64_CC) is None, reason=f"{AARCH64_CC} not installed")
def test_the_export_cross_compiles_for_aarch64(built, tmp_path):
    directory, _ = built["flight"]
    cross = tmp_path / "cross"
    shutil.copytree(directory, cross)
    subprocess.run(["make", "-C", str(cross), "clean"], check=True, capture_output=True)
    make = ["make", "-C", str(cross), "-j2", f"CC={AARCH64_CC}", "AR=aarch64-linux-gnu-ar",
            "CFLAGS=-O0"]  # fmt: skip
    subprocess.run(make, check=True, capture_output=True, timeout=BUILD_TIMEOUT_S)
    header = (cross / "example" / "example").read_bytes()[:20]
    assert header[:4] == b"\x7fELF" and int.from_bytes(header[18:20], "little") == EM_AARCH64


def test_export_build_makes_and_flies_the_example(tmp_path, capsys):
    out = tmp_path / "planar"
    args = ["export", "planar", "--variant", "cond-default", "--out", str(out), "--build"]
    for s in EXPORTS["planar RTI"][1]:
        args += ["--set", s]
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert re.search(r"example: steps 800, failed 0, partial 0, solve median [0-9.]+ us", printed)
    assert (out / "libaeromanip_controller.a").is_file()
