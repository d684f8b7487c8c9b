"""A stock client flies the SITL: MAVSDK-Python (``mavsdk`` 4, its C++ core in-process)
runs ``mavsdk_square``, an offboard app written as MAVSDK documents it, against
``aeromanip sitl flight`` on 127.0.0.1 (UDP).

Truth: the SITL's truth log (the physics), read after a clean stop (SIGINT). MAVSDK's
telemetry (measured with the physics' 1 mm noise) is compared with it at the vehicle's
time: ``odometry`` by its stamps (the SITL's clock, the truth log's ``t``),
``position_velocity_ned`` (no stamp) by the ODOMETRY of the same measurement; truth rows
at 20 Hz interpolated, ENU -> NED. The square, the return and the body-frame leg are
checked on the truth itself.
Bounded: the app within ``APP_LIMIT_S``, the SITL within ``SITL_MAX_S`` and stopped (or
killed) when the app ends.
"""

import asyncio
import json
import math
import signal
import sys
import time

import numpy as np
import pytest

from aeromanip.experiment.runlog import RunLog
from loopback import free_udp_port, start_sitl

mavsdk = pytest.importorskip("mavsdk")
pytest.importorskip("pymavlink")
pytestmark = pytest.mark.realtime  # flies against the wall clock: the machine to itself

import mavsdk_square  # noqa: E402  (the app: needs mavsdk, checked above)

HOST = "127.0.0.1"
APP_LIMIT_S = 60.0  # [s] the app's whole flight, connection to disarm
SITL_MAX_S = 80.0  # [s] the SITL stops by itself after this, whatever happens
TELEMETRY_TOL_M = 0.01  # [m] MAVSDK's position against the truth
CLI = [sys.executable, "-m", "aeromanip.cli"]


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    root = tmp_path_factory.mktemp("mavsdk")
    port = free_udp_port()
    sitl = start_sitl(root / "sitl", port, SITL_MAX_S)
    began = time.monotonic()
    wall_minus_mono = time.time() - time.monotonic()  # the app stamps with the loop's clock
    try:
        app = mavsdk_square.fly(f"udpin://{HOST}:{port}")
        seen = asyncio.run(asyncio.wait_for(app, APP_LIMIT_S))
        app_s = time.monotonic() - began
        sitl.send_signal(signal.SIGINT)  # a clean stop: the truth log and its summary
        _, stderr = sitl.communicate(timeout=15)
    finally:
        if sitl.poll() is None:
            sitl.kill()
            sitl.communicate(timeout=10)
    return {
        "seen": seen,
        "app_s": app_s,
        "wall_minus_mono": wall_minus_mono,
        "rc": sitl.returncode,
        "stderr": stderr,
        "truth": RunLog.load(root / "sitl"),
        "summary_file": root / "sitl" / "summary.json",
    }


def truth_at(truth: RunLog, wall: np.ndarray, column: str) -> np.ndarray:
    return np.interp(wall, truth.column("wall_time"), truth.column(column))


def phase(flight, name: str) -> float:
    """When the app reached ``name`` [s, wall clock]."""
    return flight["seen"]["phases"][name] + flight["wall_minus_mono"]


def test_the_app_connects_to_a_healthy_armable_vehicle_and_its_parameters(flight):
    seen = flight["seen"]
    assert flight["rc"] == 0, flight["stderr"]
    assert flight["summary_file"].is_file()
    assert all(seen["health"].values()), seen["health"]
    assert seen["phases"]["healthy"] - seen["phases"]["connected"] < 5.0
    assert seen["loss_timeout"] == 0.5 and seen["loss_action"] == 5  # Hold
    assert seen["xy_vel_max"] == 2.0  # set and read back
    # each request answered once: MAVSDK does not ask again (it re-asks what is refused)
    received = json.loads(flight["summary_file"].read_text())["received"]
    requests = {k: n for k, n in received.items() if k.split(":")[-1] in ("512", "520", "410")}
    print(f"requests the SITL read: {requests}; all: {received}")
    assert 1 <= sum(requests.values()) <= 6
    print(f"MAVSDK app: {flight['app_s']:.1f} s, phases "
          + ", ".join(f"{k} {v - seen['phases']['connected']:.2f}"
                      for k, v in seen["phases"].items()))  # fmt: skip


def test_the_modes_and_the_refused_disarm_as_px4_reports_them(flight):
    seen = flight["seen"]
    modes = [m.name for _, m in seen["modes"]]
    changes = [m for i, m in enumerate(modes) if i == 0 or m != modes[i - 1]]
    assert changes == ["HOLD", "OFFBOARD", "HOLD"]
    assert seen["disarm"] == "COMMAND_DENIED"  # in the air: TEMPORARILY_REJECTED
    texts = [t.text for _, t in seen["texts"]]
    assert texts == ["armed: hold", "offboard", "hold (commanded)", "Disarming denied: not landed"]


def seen_legs(flight) -> list[float]:
    """When the app sent each side's setpoint, on the truth log's wall clock [s]."""
    return [t + flight["wall_minus_mono"] for t in flight["seen"]["legs"]]


def ned_truth(truth: RunLog, at: np.ndarray, clock: str) -> np.ndarray:
    """The true position (NED) at times ``at`` of the truth log's ``clock`` column."""
    x, y, z = (np.interp(at, truth.column(clock), truth.column(c)) for c in ("x", "y", "z"))
    return np.column_stack([y, x, -z])  # ENU -> NED: north = y, east = x, down = -z


def test_mavsdk_odometry_is_the_truth_within_1_cm_at_the_vehicles_time(flight):
    truth = flight["truth"]
    stamped = [(o.time_usec * 1e-6, o.position_body) for _, o in flight["seen"]["odometry"]]
    t = np.array([s for s, _ in stamped])
    inside = (t >= truth.column("t")[0]) & (t <= truth.column("t")[-1])
    ned = np.array([(p.x_m, p.y_m, p.z_m) for _, p in stamped])[inside]
    error = np.linalg.norm(ned - ned_truth(truth, t[inside], "t"), axis=1)
    print(f"MAVSDK odometry vs truth: {len(error)} samples, max {1e3 * error.max():.2f} mm, "
          f"RMS {1e3 * math.sqrt(np.mean(error**2)):.2f} mm")  # fmt: skip
    assert len(error) >= 50 * 15  # 50 Hz over the whole flight
    assert error.max() < TELEMETRY_TOL_M


def test_mavsdk_position_ned_is_the_truth_within_1_cm_at_the_vehicles_time(flight):
    """``position_velocity_ned`` carries no time stamp: each sample is the measurement an
    ODOMETRY carried too (the same float32 position, bit for bit), which gives its time."""
    truth = flight["truth"]
    stamp = {
        (o.position_body.x_m, o.position_body.y_m, o.position_body.z_m): o.time_usec * 1e-6
        for _, o in flight["seen"]["odometry"]
    }
    samples = [(t, (p.position.north_m, p.position.east_m, p.position.down_m))
               for t, p in flight["seen"]["positions"]]  # fmt: skip
    matched = [(seen_at, stamp[ned], ned) for seen_at, ned in samples if ned in stamp]
    assert len(matched) >= 0.95 * len(samples) >= 50 * 15
    t = np.array([m[1] for m in matched])
    ned = np.array([m[2] for m in matched])
    error = np.linalg.norm(ned - ned_truth(truth, t, "t"), axis=1)
    # how old each was when the app saw it: the truth log's wall clock at that time
    age = np.array([m[0] for m in matched]) + flight["wall_minus_mono"] - np.interp(
        t, truth.column("t"), truth.column("wall_time"))  # fmt: skip
    print(f"MAVSDK position NED vs truth: {len(error)} of {len(samples)} samples stamped, "
          f"max {1e3 * error.max():.2f} mm; seen {1e3 * np.median(age):.1f} ms (median), "
          f"{1e3 * age.max():.0f} ms (max) after the SITL sent it")  # fmt: skip
    assert error.max() < TELEMETRY_TOL_M


def test_the_square_the_return_and_the_body_leg_are_flown(flight):
    truth = flight["truth"]
    start = np.array(flight["seen"]["start"])  # NED, where offboard began
    # the square: 0.5 m/s for 2 s each side, north, east, south, west
    t_sq = np.linspace(phase(flight, "offboard"), phase(flight, "square_done"), 200)
    north = truth_at(truth, t_sq, "y") - start[0]
    east = truth_at(truth, t_sq, "x") - start[1]
    assert np.ptp(north) == pytest.approx(1.0, abs=0.1)
    assert np.ptp(east) == pytest.approx(1.0, abs=0.1)
    assert north.min() > -0.05 and east.min() > -0.05  # north and east of the start
    # closed, give or take the lag: each side as long as the app flew it (2 s, or more
    # where a loaded machine woke the app late)
    sent = np.array([*seen_legs(flight), phase(flight, "square_done")])
    end = np.diff(sent) @ np.array(mavsdk_square.SQUARE)  # [m] north, east
    assert abs(north[-1] - end[0]) < 0.15 and abs(east[-1] - end[1]) < 0.15, end
    # set_position_ned: back at the start after 4 s
    t_back = np.array([phase(flight, "position_done")])
    back = np.array([truth_at(truth, t_back, c)[0] for c in ("y", "x")])
    down = -truth_at(truth, t_back, "z")[0]
    assert np.linalg.norm(back - start[:2]) < 0.05 and abs(down - start[2]) < 0.05
    # set_velocity_body forward 0.3 m/s: along the heading (NED yaw from the truth)
    t_body = phase(flight, "body_done") - 0.2
    yaw_ned = math.pi / 2 - truth_at(truth, np.array([t_body]), "yaw")[0]
    v = np.array([truth_at(truth, np.array([t_body]), c)[0] for c in ("vy", "vx")])
    assert np.dot(v, (math.cos(yaw_ned), math.sin(yaw_ned))) == pytest.approx(0.3, abs=0.05)
    # held at the end
    t_held = np.array([phase(flight, "held")])
    assert truth_at(truth, t_held, "speed")[0] < 0.1
