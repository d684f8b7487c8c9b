"""The paper's case studies end to end (shortened where the claim allows), run outputs."""

from importlib import resources

import numpy as np
import pytest

from aeromanip.experiment.runlog import RunLog, motion_share, read_summary
from aeromanip.experiment.runner import run_scenarios
from aeromanip.experiment.scenario import builtin_scenarios, load_scenarios

PLANAR_SHORT = [
    "duration=45",
    "reference.phases=[{duration=20.0, amplitude=0.08, frequency=0.1},"
    " {duration=25.0, amplitude=1.0, frequency=0.04}]",
]


@pytest.fixture(scope="module")
def planar(tmp_path_factory):
    out = tmp_path_factory.mktemp("planar")
    run_scenarios(load_scenarios("planar", PLANAR_SHORT), out, progress=False)
    return out


@pytest.fixture(scope="module")
def waypoints(tmp_path_factory):
    out = tmp_path_factory.mktemp("waypoints")
    run_scenarios(load_scenarios("waypoints"), out, progress=False)
    return out


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    out = tmp_path_factory.mktemp("flight")
    run_scenarios(load_scenarios("flight", ["duration=90", "sim='kinematic'"]), out, progress=False)
    return out


def test_builtin_scenarios_are_listed():
    assert {"planar", "waypoints", "waypoints-unbounded", "flight"} <= set(builtin_scenarios())


def test_planar_small_phase_by_arm_big_phase_by_platform(planar):
    """Sec. VI-A / Fig. 3: the small sinusoid mostly by the arm, the big one by the platform."""
    log = RunLog.load(planar / "cond-default")
    small = motion_share(log, 0.0, 20.0, (0, 1, 0))
    big = motion_share(log, 20.0, 45.0, (0, 1, 0))
    assert small["arm"] > 0.5, small
    assert big["platform"] > 0.5, big
    s = read_summary(planar / "cond-default" / "summary.json")
    # the summary carries the same shares, per reference phase
    assert [p["t0_s"] for p in s["phases"]] == [0.0, 20.0]
    assert s["phases"][0]["arm_share"] == pytest.approx(small["arm"])
    assert s["phases"][1]["platform_share"] == pytest.approx(big["platform"])
    assert s["ee_rmse_m"] < 0.01 and s["solver_failures"] == 0
    assert s["min_clearance_m"] >= 0.1 - 1e-6


def test_planar_condition_number_falls_with_its_weight(planar):
    """Fig. 4: mean rho decreases from cond-off to cond-default to cond-high."""
    rho = [
        read_summary(planar / v / "summary.json")["cond_mean"]
        for v in ("cond-off", "cond-default", "cond-high")
    ]
    assert rho[0] > rho[1] > rho[2], rho


def test_waypoints_hierarchy_keeps_tracking_and_aligns_cog(waypoints):
    """Fig. 5 with a strict hierarchy: the tracking of tracking-only (within 5 % or
    0.02 mm RMS), a mean arm-CoG offset at least 10x smaller, level 0 at its optimum."""
    only = read_summary(waypoints / "tracking-only" / "summary.json")
    hier = read_summary(waypoints / "hierarchical" / "summary.json")
    assert hier["ee_rmse_m"] <= max(1.05 * only["ee_rmse_m"], only["ee_rmse_m"] + 2e-5)
    assert hier["cog_xy_mean_m"] <= 0.1 * only["cog_xy_mean_m"]
    assert hier["levels"]["0"]["loss_rel_mean"] < 1e-6  # what level 1 took from level 0
    # the end effector passes through every waypoint
    for v in ("tracking-only", "hierarchical"):
        log = RunLog.load(waypoints / v)
        ee = np.column_stack([log.column(c) for c in ("ee_x", "ee_y", "ee_z")])
        for p in log.meta["waypoints"]:
            assert np.min(np.linalg.norm(ee - np.asarray(p), axis=1)) < 0.01


def test_waypoints_come_to_rest_once_the_reference_holds_still(waypoints):
    """The terminal control cost W_s (eq. 4): every plan ends at rest, so once the
    reference holds still (from 24 s) every DoF's rate dies out: below 0.01 [m/s, rad/s]
    from 10 s later on, in both variants."""
    for v in ("tracking-only", "hierarchical"):
        log = RunLog.load(waypoints / v)
        late = log.column("t") >= 34.0
        assert late.sum() >= 10
        for dof in ("x", "y", "z", "yaw", "q1", "q2", "q3"):
            assert np.abs(log.column(f"u_{dof}")[late]).max() < 0.01, (v, dof)


def test_unbounded_tracking_alone_lifts_the_arm_to_the_platform(tmp_path):
    """Fig. 6: without motion bounds, tracking alone brings platform and end effector to
    similar heights (the arm stretched, above the self-collision depth); the hierarchy
    keeps the arm below the platform and its CoG aligned. Both track the waypoints."""
    run_scenarios(load_scenarios("waypoints-unbounded"), tmp_path, progress=False, figures=False)
    only = RunLog.load(tmp_path / "tracking-only")
    hier = RunLog.load(tmp_path / "hierarchical")
    s_only = read_summary(tmp_path / "tracking-only" / "summary.json")
    s_hier = read_summary(tmp_path / "hierarchical" / "summary.json")
    assert s_only["ee_rmse_m"] < 0.005 and s_hier["ee_rmse_m"] < 0.005
    assert s_only["min_clearance_m"] < 0.0  # the end effector above the base
    assert s_hier["min_clearance_m"] >= 0.1
    assert np.min(hier.column("z") - hier.column("ee_z")) > 0.3
    assert s_hier["cog_xy_mean_m"] <= 0.5 * s_only["cog_xy_mean_m"]
    # no joint spins: every plan ends at rest (terminal control cost), no rate aliases
    for log in (only, hier):
        rates = np.column_stack([log.column(f"u_q{i}") for i in (1, 2, 3)])
        assert np.abs(rates).max() < 1.5  # rad/s


def test_flight_respects_joint_clearance_and_platform_bounds(flight):
    """Figs. 8-9: joints within bounds, clearance >= 0.1 m, the platform in its box."""
    s = read_summary(flight / "summary.json")
    log = RunLog.load(flight)
    assert s["solver_failures"] == 0
    assert s["max_bound_violation"] <= 1e-6
    assert s["min_clearance_m"] >= 0.1 - 1e-6
    box = {"x": (-0.6, 0.6), "y": (-0.6, 0.6), "z": (0.8, 1.5)}
    for dof, (lo, hi) in box.items():
        assert lo - 1e-6 <= log.column(dof).min() and log.column(dof).max() <= hi + 1e-6
    for i, (lo, hi) in enumerate([(-1.57, 1.57), (-1.6, 1.6), (-2.2, 2.2)]):
        q = log.column(f"q{i + 1}")
        assert lo - 1e-6 <= q.min() and q.max() <= hi + 1e-6
    # the reference leaves the box: the NMPC's box (tightened by platform_margin = 0.01 m)
    # is active at some point
    assert max(log.column("x").max(), log.column("y").max()) == pytest.approx(0.59, abs=1e-4)


def test_run_directory_follows_the_contract(flight):
    for name in ("config.toml", "robot.urdf", "log.csv", "summary.json"):
        assert (flight / name).stat().st_size > 0, name
    log = RunLog.load(flight)
    assert log.missing_columns() == []
    summary = read_summary(flight / "summary.json")
    for key in (
        "ee_rmse_m",
        "ee_max_err_m",
        "cog_xy_mean_m",
        "cond_mean",
        "min_clearance_m",
        "max_bound_violation",
        "solve_ms_median",
        "solve_ms_p95",
        "solve_ms_max",
        "steps",
        "solver_failures",
    ):
        assert key in summary, key
    assert summary["steps"] == 180


def _pngs(d):
    return sorted(p.name for p in (d / "figures").glob("*.png"))


def test_every_figure_is_produced_and_replotting_reproduces_them(planar, tmp_path):
    from aeromanip.cli import main

    expected_single = {
        "ee_tracking.png",
        "commands.png",
        "joints.png",
        "platform.png",
        "cog_offset.png",
        "solve_time.png",
    }
    for v in ("cond-off", "cond-default", "cond-high"):
        assert expected_single <= set(_pngs(planar / v))
    assert {"condition.png", "paths_3d.png", "comparison_errors.png"} <= set(_pngs(planar))
    for png in planar.rglob("*.png"):
        data = png.read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000, png
    # re-plot a copy of the saved run from its files alone
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(planar, copy, ignore=shutil.ignore_patterns("figures"))
    assert main(["plot", str(copy)]) == 0
    assert _pngs(copy) == _pngs(planar)
    for v in ("cond-off", "cond-default", "cond-high"):
        assert _pngs(copy / v) == _pngs(planar / v)


def test_config_toml_reproduces_the_run(tmp_path):
    first = tmp_path / "first"
    run_scenarios(load_scenarios("flight", ["duration=10"]), first, progress=False, figures=False)
    again = tmp_path / "again"
    run_scenarios(load_scenarios(first / "config.toml"), again, progress=False, figures=False)
    a, b = RunLog.load(first), RunLog.load(again)
    for col in ("x", "y", "z", "q1", "q2", "q3", "u_x", "ee_x", "ref_x"):
        np.testing.assert_array_equal(a.column(col), b.column(col))


def test_a_scenario_extends_another_key_by_key(tmp_path):
    mine = tmp_path / "mine.toml"
    mine.write_text(
        'extends = "flight"\nname = "mine"\nduration = 12.0\n[controller]\nhorizon = 6\n'
    )
    sc = load_scenarios(mine)[""]
    flight = load_scenarios("flight")[""]
    assert (sc.name, sc.duration, sc.problem.horizon) == ("mine", 12.0, 6)
    assert sc.problem.dt == flight.problem.dt and sc.strategy == flight.strategy
    np.testing.assert_array_equal(sc.problem.bounds.x_upper, flight.problem.bounds.x_upper)
    # a parent's relative files are found next to the parent, not next to the child
    parent_dir, child_dir = tmp_path / "p", tmp_path / "c"
    parent_dir.mkdir()
    child_dir.mkdir()
    robot_toml = resources.files("aeromanip") / "robots" / "x8-3dof.toml"
    (parent_dir / "myrobot.toml").write_text(robot_toml.read_text())
    (parent_dir / "parent.toml").write_text(
        'extends = "flight"\nname = "parent"\nrobot = "myrobot.toml"\n'
    )
    (child_dir / "child.toml").write_text(
        'extends = "../p/parent.toml"\nname = "child"\nduration = 3.0\n'
    )
    child = load_scenarios(child_dir / "child.toml")[""]
    assert child.robot.name == flight.robot.name and child.duration == 3.0
    # a cycle is a clear error, not a recursion
    (tmp_path / "a.toml").write_text('extends = "b.toml"\n')
    (tmp_path / "b.toml").write_text('extends = "a.toml"\n')
    from aeromanip.errors import ConfigError

    with pytest.raises(ConfigError, match="extends: a cycle"):
        load_scenarios(tmp_path / "a.toml")


def test_clearance_margin_plans_inside_the_true_limit():
    from aeromanip.errors import ConfigError
    from aeromanip.nmpc.constraints import Clearance

    sc = load_scenarios("flight")[""]
    planned = [c for c in sc.problem.constraints if isinstance(c, Clearance)]
    assert sc.clearance.d_min == 0.1  # what runs are judged against
    assert [c.d_min for c in planned] == [pytest.approx(0.105)]  # what the NMPC keeps
    with pytest.raises(ConfigError, match=r"clearance\.margin: must be >= 0, got -0\.01"):
        load_scenarios("flight", ["clearance.margin=-0.01"])


def test_clearance_binds_in_3d_and_holds(tmp_path):
    """eq. 17 pressed: the self-collision constraint binds for a real share of the
    flight, and no arm point ever comes above d_min below the base."""
    run_scenarios(load_scenarios("clearance", ["duration=60"]), tmp_path, progress=False)
    s = read_summary(tmp_path / "summary.json")
    log = RunLog.load(tmp_path)
    d_min, planned = log.meta["clearance_min"], log.meta["clearance_planned"]
    assert planned == pytest.approx(d_min + 0.005)
    assert s["min_clearance_m"] >= d_min - 1e-9  # never violated ...
    assert s["min_clearance_m"] <= planned + 1e-6  # ... and touched
    assert s["clearance_active_share"] >= 0.15
    for p, depth in s["min_clearance_by_point_m"].items():
        assert depth >= d_min - 1e-9, p
    assert (tmp_path / "figures" / "clearance.png").stat().st_size > 0


def test_set_wins_over_a_variants_own_value():
    """``--set KEY=VALUE`` is the last word, also where a variant sets the key itself."""
    plain = load_scenarios("flight-rates")
    assert [plain[v].latency_s for v in ("2hz", "10hz", "20hz")] == [0.0, 0.02, 0.01]
    forced = load_scenarios("flight-rates", ["controller.latency=0.0", "duration=7"])
    assert all(sc.latency_s == 0.0 and sc.duration == 7.0 for sc in forced.values())
