"""The controller benchmark's harness: its answers, not its timings (those are noisy)."""

import json

import numpy as np
import pytest

from aeromanip.bench.controller_speed import bench_controller, format_controller
from aeromanip.cli import main


@pytest.fixture(scope="module")
def short_run():
    return bench_controller(
        ["baseline", "weighted", "hierarchical", "constrained"], duration=20.0, warmup=1
    )


def test_sqp_gives_the_plain_ipopt_closed_loop(short_run):
    v = short_run["variants"]
    assert v["baseline"]["failures"] == v["weighted"]["failures"] == 0
    assert v["weighted"]["closed_loop_cost"] == pytest.approx(
        v["baseline"]["closed_loop_cost"], rel=1e-3
    )
    assert v["weighted"]["ee_rmse_m"] == pytest.approx(v["baseline"]["ee_rmse_m"], rel=1e-2)


def test_shadow_ipopt_agrees_step_by_step(short_run):
    weighted, constrained = (short_run["variants"][n] for n in ("weighted", "constrained"))
    # nominal flight: IPOPT from the same guess gives the same command (1e-4) at every step
    assert weighted["shadow_steps"] == weighted["steps"] == 40
    assert weighted["shadow_ipopt_failures"] == constrained["shadow_ipopt_failures"] == 0
    assert weighted["shadow_other_optimum_steps"] == 0
    # binding bounds make the NLP nonconvex: at some steps the two solvers pick different
    # local optima from the same guess, the SQP's not always the worse one...
    assert constrained["shadow_other_optimum_steps"] <= 0.25 * constrained["steps"]
    assert constrained["shadow_other_optimum_ipopt_cost_higher"] >= 1
    # the hierarchy (both levels, the paper's stage-wise bounds): IPOPT's answer at every step
    hier = short_run["variants"]["hierarchical"]
    assert hier["shadow_steps"] == 40 and hier["shadow_ipopt_failures"] == 0
    assert hier["shadow_other_optimum_steps"] == 0  # every command within 1e-4 of IPOPT's
    # ...but IPOPT restarted at each SQP answer stays there: each is a local optimum
    for r in (weighted, constrained):
        assert r["shadow_certified_max_du"] < 1e-4  # rad/s or m/s
        assert r["shadow_certified_max_rel_cost"] < 1e-5


def test_constrained_variant_binds_the_velocity_bounds_without_violating_them(short_run):
    r = short_run["variants"]["constrained"]
    assert r["failures"] == 0
    assert r["velocity_bound_active_share"] > 0.2
    assert r["max_bound_violation"] <= 1e-6


def test_table_lists_every_variant(short_run):
    table = format_controller(short_run)
    for name in short_run["variants"]:
        assert f"| {name} |" in table
    assert "IPOPT shadow" in table
    assert np.isfinite(short_run["variants"]["weighted"]["speedup_vs_baseline"])


def test_cli_bench_writes_json(tmp_path, capsys):
    out = tmp_path / "bench.json"
    args = ["bench", "controller", "--variant", "rti", "--duration", "2", "--json", str(out)]
    assert main(args) == 0
    data = json.loads(out.read_text())
    assert data["controller"]["variants"]["rti"]["steps"] == 4
    assert "| rti |" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["bench", "--variant", "fastest"], "--variant fastest: unknown"),
        (["bench", "controller", "--duration", "0"], "--duration: must be in (0, 3600] s"),
    ],
)
def test_bad_bench_arguments_are_one_clear_line(args, message, capsys):
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1


def test_the_horizon_probe_flies_its_case_and_reports_its_costs():
    """``bench horizon``'s probe, in this process (warm cache: the flight's own N = 10
    problem): every timed step solved, and its costs reported where the table reads them."""
    from aeromanip.bench.horizon import STEPS, format_horizon, probe

    row = probe(10, "sqp", "weighted")
    assert row["ok_steps"] == row["steps"] == STEPS
    assert row["build_s"] > 0 and row["rss_mib"] > 50  # Python + CasADi alone take more
    assert 0 < row["step_ms_median"] <= row["step_ms_p95"]
    table = format_horizon([row, {"horizon": 100, "backend": "sqp", "strategy": "weighted",
                                  "error": "killed"}])  # fmt: skip
    assert "failed: killed" in table.splitlines()[-1]
    assert f"{STEPS}/{STEPS}" in table.splitlines()[1]


def test_stress_cases_reach_ipopts_closed_loop_without_partial_steps():
    """With the clearance binding from rest, the seeded sqp loops end where
    IPOPT's do (they stopped at a local optimum 4x costlier before), RTI too; with the
    velocity bounds binding, the hierarchy's second level is solved at every step."""
    from aeromanip.bench.controller_speed import run_variant
    from aeromanip.bench.stress import RTI_COST, SQP_COST, bench_stress, format_stress

    r = bench_stress(["clearance"], duration=5.0, warmup=1)
    c = r["cases"]["clearance"]
    ratios = c["targets"]["cost_ratio"]
    assert ratios["weighted"] <= SQP_COST and ratios["hierarchical"] <= SQP_COST
    assert ratios["rti"] <= RTI_COST
    assert all(row["failures"] == 0 for row in c["rows"].values())
    assert "| clearance | hierarchical | sqp |" in format_stress(r)
    fast = run_variant("fast", "hierarchical", "sqp", duration=10.0, warmup=1)
    assert fast["partial_steps"] == fast["failures"] == 0
    assert fast["velocity_bound_active_share"] > 0.1


def test_unknown_stress_case_is_one_clear_line():
    from aeromanip.bench.stress import bench_stress
    from aeromanip.errors import ConfigError

    with pytest.raises(ConfigError, match="stress case 'windy': unknown"):
        bench_stress(["windy"])


def test_profile_attributes_each_compiled_call_to_its_part():
    """RTI runs no line search (no merit calls) and one QP a step; the converged SQP
    evaluates the merit; the Python rest is what the timed calls leave of the step."""
    from aeromanip.bench import profile
    from aeromanip.nmpc.backends.codegen import Buffered
    from aeromanip.nmpc.backends.nlpsol import NlpBackend

    init, solve = Buffered.__init__, NlpBackend.solve
    rows = profile.bench_profile(["rti", "weighted"], duration=10.0)
    assert Buffered.__init__ is init and NlpBackend.solve is solve  # the timing is undone
    rti, weighted = rows
    for r in rows:
        assert r["steps"] == 20
        parts = r["parts_ms"]
        assert parts["QP solver (DAQP)"] > 0 and parts["model: linearisation"] > 0
        assert 0 < parts[profile.PYTHON] < r["mean_ms"]
        assert sum(parts.values()) == pytest.approx(r["mean_ms"])
        assert all(0 < share < 1 for _, share in r["python_top"])
    assert rti["parts_ms"][profile.SEED] > 0  # the first step starts cold: IPOPT seeds it
    assert "model: merit (line search)" not in rti["parts_ms"]
    assert weighted["parts_ms"]["model: merit (line search)"] > 0
    assert "| QP solver (DAQP) [ms] |" in profile.format_profile(rows)


def test_the_contact_variant_gives_ipopts_closed_loop():
    """The contact task's bench (the force and surface tasks, the approach bound): the
    SQP's commands are IPOPT's, converged tightly, along the first 3 s."""
    res = bench_controller(["contact-ipopt", "contact"], duration=3.0, warmup=1)["variants"]
    sqp = res["contact"]
    assert sqp["steps"] == 30 and sqp["failures"] == res["contact-ipopt"]["failures"] == 0
    assert sqp["vs"] == "contact-ipopt" and sqp["max_command_diff"] < 1e-4
    assert sqp["cost_ratio"] == pytest.approx(1.0, abs=1e-6)
