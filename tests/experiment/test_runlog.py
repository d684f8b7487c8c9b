"""RunLog: exact CSV round trip, metrics against hand-computed numpy, motion share."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.experiment.runlog import (
    RunLog,
    contract_columns,
    load,
    motion_share,
    read_summary,
    write_summary,
)

CONTRACT_KEYS = (
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
)


def synthetic_log(n: int = 50, n_joints: int = 2, seed: int = 0) -> RunLog:
    """A log with every contract column plus roll/pitch/arm_torque/iterations and an extra."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.1
    cols: dict[str, np.ndarray] = {"t": t}
    for name in contract_columns(n_joints):
        if name not in ("t", "status"):
            cols[name] = rng.normal(size=n) * 0.3
    cols["cond"] = 1.0 + rng.random(n) * 5
    cols["solve_ms"] = 1.0 + rng.random(n) * 20
    status = np.array(["ok"] * n, dtype=object)
    status[[3, 7, 8]] = ["fallback", "failed", "fallback"]
    cols["status"] = status.astype(str)
    cols["roll"] = rng.normal(size=n) * 0.05
    cols["pitch"] = rng.normal(size=n) * 0.05
    cols["arm_torque"] = rng.random(n)
    cols["iterations"] = rng.integers(1, 30, size=n).astype(float)
    cols["my_extra"] = rng.normal(size=n) / 3.0
    meta = {
        "bounds": {"q1": [-1.0, 1.0], "u_y": [-0.5, 0.5]},
        "state_names": ["y", "z", "q1"],
        "waypoints": [[0.0, 0.1, 0.2]],
        "scenario": "synthetic",
    }
    return RunLog(cols, meta)


def test_basic_api():
    log = synthetic_log(n=10, n_joints=3)
    assert len(log) == 10
    assert log.n_joints == 3
    assert log.missing_columns() == []
    assert log.column("status").dtype.kind == "U"
    assert "my_extra" in log
    with pytest.raises(ConfigError, match="no column 'nope'"):
        log.column("nope")
    with pytest.raises(ConfigError, match=r"log\.b: has 2 rows, expected 3"):
        RunLog({"a": [1, 2, 3], "b": [1, 2]})


def test_from_rows_fills_missing():
    log = RunLog.from_rows(
        [
            {"t": 0.0, "q1": 0.5, "status": "ok"},
            {"t": 0.1, "q1": 0.6, "status": "failed", "extra": 2.0},
        ]
    )
    assert log.names == ["t", "q1", "status", "extra"]
    assert math.isnan(log.column("extra")[0])
    assert log.column("extra")[1] == 2.0
    assert list(log.column("status")) == ["ok", "failed"]
    assert log.n_joints == 1


def test_save_load_round_trip_exact(tmp_path):
    log = synthetic_log()
    log.columns["x"][4] = math.nan
    log.columns["y"][5] = 1e-300
    log.columns["z"][6] = 0.1 + 0.2
    log.save(tmp_path / "run")
    header = (tmp_path / "run" / "log.csv").read_text().splitlines()[0].split(",")
    assert header == log.names
    back = load(tmp_path / "run")
    assert back.names == log.names
    for name in log.names:
        a, b = log.column(name), back.column(name)
        assert a.dtype.kind == b.dtype.kind, name
        if a.dtype.kind == "f":
            assert np.array_equal(a, b, equal_nan=True), name
        else:
            assert np.array_equal(a, b), name
    assert back.meta == log.meta
    also = RunLog.load(tmp_path / "run" / "log.csv")
    assert len(also) == len(log)


def test_load_errors(tmp_path):
    with pytest.raises(ConfigError, match="cannot read run log"):
        RunLog.load(tmp_path)
    (tmp_path / "log.csv").write_text("t,x\n0,1\n1\n")
    with pytest.raises(ConfigError, match="line 3: 1 fields, header has 2"):
        RunLog.load(tmp_path)


def test_summary_against_numpy():
    log = synthetic_log()
    s = log.summary()
    for k in CONTRACT_KEYS:
        assert k in s
    c = log.columns
    err = np.sqrt(
        (c["ee_x"] - c["ref_x"]) ** 2
        + (c["ee_y"] - c["ref_y"]) ** 2
        + (c["ee_z"] - c["ref_z"]) ** 2
    )
    assert s["ee_rmse_m"] == pytest.approx(np.sqrt(np.mean(err**2)))
    assert s["ee_max_err_m"] == pytest.approx(err.max())
    assert s["cog_xy_mean_m"] == pytest.approx(np.mean(np.hypot(c["cog_bx"], c["cog_by"])))
    assert s["cond_mean"] == pytest.approx(c["cond"].mean())
    assert s["min_clearance_m"] == pytest.approx(c["clearance"].min())
    assert s["solve_ms_median"] == pytest.approx(np.median(c["solve_ms"]))
    assert s["solve_ms_p95"] == pytest.approx(np.percentile(c["solve_ms"], 95))
    assert s["solve_ms_max"] == pytest.approx(c["solve_ms"].max())
    assert s["steps"] == 50
    assert s["solver_failures"] == 3
    rp = np.degrees(np.hypot(c["roll"], c["pitch"]))
    assert s["roll_pitch_mean_deg"] == pytest.approx(rp.mean())
    assert s["arm_torque_mean_nm"] == pytest.approx(c["arm_torque"].mean())
    assert s["iterations_mean"] == pytest.approx(c["iterations"].mean())


def test_bound_violation():
    log = synthetic_log()
    c = log.columns
    expected = max(
        max(0.0, (c["q1"] - 1.0).max(), (-1.0 - c["q1"]).max()),
        max(0.0, (c["u_y"] - 0.5).max(), (-0.5 - c["u_y"]).max()),
    )
    s = log.summary()
    assert s["max_bound_violation"] == pytest.approx(expected)
    assert expected > 0

    t = np.arange(5.0)
    inside = RunLog({"t": t, "q1": [0.0, 0.5, 0.9, -0.9, 0.0]}, {"bounds": {"q1": [-1, 1]}})
    assert inside.summary()["max_bound_violation"] == 0.0
    assert inside.summary()["max_bound_violation_column"] is None
    out = RunLog(
        {"t": t, "q1": [0.0, 1.25, 0.9, -1.1, 0.0], "z": [3.0] * 5},
        {"bounds": {"q1": [-1, 1], "z": [None, 2.5], "absent": [0, 1]}},
    )
    s = out.summary()
    assert s["max_bound_violation"] == pytest.approx(0.5)
    assert s["max_bound_violation_column"] == "z"
    with pytest.raises(ConfigError, match=r"meta\.bounds\.q1"):
        RunLog({"q1": [0.0]}, {"bounds": {"q1": [1.0]}}).summary()


def test_summary_missing_columns_are_nan():
    s = RunLog({"t": [0.0, 0.1]}).summary()
    assert s["steps"] == 2
    assert math.isnan(s["ee_rmse_m"]) and math.isnan(s["cond_mean"])
    assert s["solver_failures"] == 0
    assert "roll_pitch_mean_deg" not in s


def test_write_and_read_summary(tmp_path):
    s = synthetic_log().summary()
    s["cond_mean"] = math.nan
    s["weird"] = np.float64(math.inf)
    path = write_summary(tmp_path, s)
    text = path.read_text()
    data = json.loads(text)  # strict JSON: no NaN/Infinity tokens
    assert "NaN" not in text and "Infinity" not in text
    assert data["cond_mean"] is None and data["weird"] is None
    assert data["steps"] == 50
    back = read_summary(tmp_path)
    assert math.isnan(back["cond_mean"])
    assert back["ee_rmse_m"] == s["ee_rmse_m"]


def _motion_log(platform_y: np.ndarray, ee_y: np.ndarray) -> RunLog:
    n = platform_y.size
    z = np.zeros(n)
    return RunLog(
        {
            "t": np.arange(n) * 0.05,
            "x": z,
            "y": platform_y,
            "z": z + 1.0,
            "ee_x": z,
            "ee_y": ee_y,
            "ee_z": z + 0.5,
        }
    )


def test_motion_share_platform_only_and_arm_only():
    t = np.arange(200) * 0.05
    wave = 0.3 * np.sin(2 * np.pi * 0.2 * t)
    plat = motion_share(_motion_log(wave, wave + 0.1), 0.0, 10.0, (0, 1, 0))
    assert plat["platform"] == pytest.approx(1.0)
    assert plat["arm"] == pytest.approx(0.0)
    arm = motion_share(_motion_log(np.zeros_like(t), wave), 0.0, 10.0, (0, 1, 0))
    assert arm["platform"] == pytest.approx(0.0)
    assert arm["arm"] == pytest.approx(1.0)


def test_motion_share_mixed_window_and_direction():
    t = np.arange(200) * 0.05
    plat_y = np.where(t < 5.0, 0.0, 0.1 * (t - 5.0))  # platform moves only after 5 s
    ee_y = 0.05 * t + plat_y  # the arm drifts at 5 cm/s throughout
    log = _motion_log(plat_y, ee_y)
    first = motion_share(log, 0.0, 4.9)
    assert first["platform"] == pytest.approx(0.0)
    second = motion_share(log, 4.99, 9.96)
    assert second["platform"] == pytest.approx(2.0 / 3.0)
    in_window = (t >= 4.99) & (t <= 9.96)
    assert second["platform_m"] == pytest.approx(np.ptp(plat_y[in_window]))
    assert second["arm_m"] == pytest.approx(np.ptp(plat_y[in_window]) / 2.0)
    # motion along y is invisible along x: nothing to share
    assert math.isnan(motion_share(log, 0.0, 10.0, (1, 0, 0))["platform"])
    with pytest.raises(ConfigError, match="direction"):
        motion_share(log, 0.0, 1.0, (0, 0, 0))
