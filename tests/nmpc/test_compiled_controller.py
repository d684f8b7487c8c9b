"""The controller step compiled whole (``nmpc.compiled_controller``) against the Python
path (``solver_options.compiled_step = false``: the strategy level by level, the compiled
loop per solve, NumPy around it): the same commands, plans, statuses, iterations, level
reports and task costs, step by step, through IPOPT seeds (taken by Python), cold
retries, fallbacks, stops, partial steps, discards and resets."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.experiment.closed_loop import make_controller
from aeromanip.experiment.scenario import load_scenarios
from aeromanip.nmpc.backends.sqp.compiled_step import step_parts

pytestmark = pytest.mark.codegen  # the step is compiled code

FOUR = ["controller.solver_options.max_iter=4", "controller.latency=0.1"]
CASES = {
    # name: scenario, variant, settings, steps, the clock's jump every 10 steps [s]
    "weighted, seeded": ("flight", None, ["controller.strategy=weighted"], 60, 0.0),
    # four iterations, the reference jumping ahead: failed solves, cold retries, fallbacks
    # and stops, all in C
    "weighted, 4 iterations": ("flight", None, ["controller.strategy=weighted",
                                                "controller.solver_options.seed=none", *FOUR],
                               80, 25.0),
    # the same with DAQP held to 4 iterations a QP: partial steps too
    "hierarchical, 4 iterations": ("flight", None, [
        "controller.solver_options.seed=none", *FOUR,
        "controller.solver_options.qpsol_options.daqp.iter_limit=4"], 80, 5.0),
    # four QPs a level, the last iterate the answer where its rows hold: no cold retry
    "hierarchical, bounded": ("flight", None, [
        "controller.solver_options.seed=none", *FOUR,
        "controller.solver_options.accept_at_max_iter=true"], 80, 25.0),
    # seeded: every failed warm solve is Python's (IPOPT), the steps around it C's
    "hierarchical, seeded, 4 iterations": ("flight", None, [
        *FOUR, "controller.solver_options.qpsol_options.daqp.iter_limit=4"], 60, 5.0),
    "real-time iteration": ("planar", "cond-default", ["controller.backend=sqp-rti",
                                                       "controller.horizon=10"], 60, 0.0),
    # the platform's rate lags at 10 Hz with latency: the measured rates start the plan
    # (a short horizon: the model builds in seconds)
    "rate lags": ("flight-rates", "10hz", ["controller.horizon=5",
                                           "controller.solver_options.qpsol=daqp",
                                           "controller.strategy=weighted",
                                           "controller.backend=sqp-rti"], 60, 0.0),
}  # fmt: skip
OFF = "controller.solver_options.compiled_step=false"


def _pair(name: str):
    scenario, variant, sets, steps, jump = CASES[name]
    sc = next(iter(load_scenarios(scenario, sets, variant).values()))
    python = make_controller(next(iter(load_scenarios(scenario, [*sets, OFF], variant).values())))
    return sc, make_controller(sc), python, steps, jump


def _close(a: float, b: float, rtol: float, atol: float) -> bool:
    return (math.isnan(a) and math.isnan(b)) or abs(a - b) <= atol + rtol * abs(b)


def _same(cmd_c, cmd_py, in_c: bool, step: int) -> None:
    """One step's commands alike. A step the compiled controller left to Python (an IPOPT
    seed) starts IPOPT from a guess whose states are rolled out from the generated
    parameters (equal to NumPy's to the last bits): its answer agrees to IPOPT's
    tolerance, so its costs are compared to 1e-6; a compiled step's to 1e-9."""
    assert (cmd_c.status, cmd_c.iterations, cmd_c.message) == (
        cmd_py.status, cmd_py.iterations, cmd_py.message), f"step {step}"  # fmt: skip
    np.testing.assert_allclose(cmd_c.u, cmd_py.u, rtol=0, atol=1e-8, err_msg=f"step {step}")
    np.testing.assert_allclose(cmd_c.plan_x, cmd_py.plan_x, rtol=0, atol=1e-8)
    np.testing.assert_allclose(cmd_c.plan_u, cmd_py.plan_u, rtol=0, atol=1e-8)
    rtol, atol = (1e-9, 1e-12) if in_c else (1e-6, 1e-6)
    for key, value in cmd_py.task_costs.items():
        assert _close(cmd_c.task_costs[key], value, rtol, atol), (step, key)
    assert len(cmd_c.levels) == len(cmd_py.levels), f"step {step}"
    for lc, lp in zip(cmd_c.levels, cmd_py.levels, strict=True):
        assert (lc.level, lc.success, lc.status, lc.iterations) == (
            lp.level, lp.success, lp.status, lp.iterations), f"step {step}"  # fmt: skip
        for field in ("cost", "gain", "objective", "loss"):
            got, want = getattr(lc, field), getattr(lp, field)
            # a gain or a loss is a difference of costs: as exact as the costs it takes
            scale = abs(lp.cost) if field in ("gain", "loss") and math.isfinite(lp.cost) else 0.0
            assert _close(got, want, rtol, max(atol, rtol * scale)), (
                step, lc.level, field, got, want)  # fmt: skip


@pytest.mark.parametrize("name", list(CASES))
def test_the_compiled_step_gives_the_python_paths_commands_and_reports(name):
    sc, compiled, python, steps, jump = _pair(name)
    assert compiled.compiled_step and not python.compiled_step
    rng = np.random.default_rng(5)
    x, dt, seen, in_c, handed = sc.x0.copy(), sc.problem.dt, set(), 0, 0
    lagged = sc.problem.model.has_response
    rates = np.zeros_like(x) if lagged else None
    tau = sc.problem.model.tau
    lag = np.where(tau > 0, np.exp(-dt / np.where(tau > 0, tau, 1.0)), 0.0)
    for k in range(steps):
        t = k * dt + jump * (k // 10)
        cmd_c = compiled.step(x, t, rates=rates)
        cmd_py = python.step(x, t, rates=rates)
        in_c += compiled._in_c.last_in_c
        # a step C left to Python after solving in it: Python took those solves over
        handed += any(ls.tried.valid for ls, _ in compiled._in_c.step_c.levels)
        _same(cmd_c, cmd_py, compiled._in_c.last_in_c, k)
        seen.add(cmd_py.status)
        if k % 9 == 4:  # a command that came too late, twice: the old plan flies on
            for ctrl in (compiled, python):
                ctrl.discard()
                ctrl.discard()
            np.testing.assert_allclose(compiled.u_prev, python.u_prev, rtol=0, atol=1e-8)
        if k == steps // 2:
            compiled.reset(cmd_py.u)
            python.reset(cmd_py.u)
        if lagged:
            rates = cmd_py.u + lag * (rates - cmd_py.u) + rng.normal(0.0, 3e-3, x.size)
        x = x + dt * (cmd_py.u if rates is None else rates) + rng.normal(0.0, 3e-3, x.size)
    if "seeded" in name:  # both paths taken, in turn: the first step is always a seed
        assert steps - in_c >= 1 and in_c >= steps // 3, in_c
    if name == "hierarchical, seeded, 4 iterations":  # warm solves failed in C
        assert handed >= 3, handed
    else:  # only the first step after a reset is Python's (nothing to start warm from)
        assert in_c >= steps - 2, in_c
    if "4 iterations" in name and "seeded" not in name:
        assert {"fallback", "stopped"} <= seen, seen
    if name == "hierarchical, 4 iterations":
        assert "partial" in seen, seen


@pytest.mark.parametrize(
    "sets", [[OFF], ["controller.time_budget=0.5"]], ids=["switched off", "time budget"]
)
def test_where_the_step_cannot_be_compiled_whole_python_takes_it(sets):
    sc = next(iter(load_scenarios("flight", sets, None).values()))
    ctrl = make_controller(sc)
    assert not ctrl.compiled_step
    assert ctrl.step(sc.x0, 0.0).status == "ok"


@pytest.mark.parametrize(
    "sets",
    [["controller.horizon=20"], ["controller.hierarchy.mode=total"],
     ["controller.backend=ipopt"]],
    ids=["sparse model", "relaxed hierarchy", "ipopt"],
)  # fmt: skip
def test_what_the_step_cannot_run_is_refused_in_one_line(sets, monkeypatch):
    """Checked before anything is compiled (the model in-process here)."""
    monkeypatch.setenv("AEROMANIP_CODEGEN", "0")
    sc = next(iter(load_scenarios("flight", sets, None).values()))
    ctrl = make_controller(sc)
    with pytest.raises(ConfigError) as err:
        step_parts(ctrl.strategy)
    assert "\n" not in str(err.value) and str(err.value).startswith("controller")
    assert not ctrl.compiled_step
