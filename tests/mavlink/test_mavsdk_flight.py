"""A stock client flies the SITL: MAVSDK-Python (``mavsdk`` 4, its C++ core in-process)
runs ``mavsdk_square``, an offboard app written as MAVSDK documents it, against
``aeromanip sitl flight`` on 127.0.0.1 (UDP).

Truth: the SITL's truth log (the physics), read after a clean stop (SIGINT). MAVSDK's
telemetry (``position_velocity_ned``, measured with the physics' 1 mm noise) is compared
with it at the same wall-clock times (truth rows at 20 Hz interpolated; ENU -> NED);
the square, the return and the body-frame leg are checked on the truth itself.
Bounded: the app within ``APP_LIMIT_S``, the SITL within ``SITL_MAX_S`` and stopped (or
killed) when the app ends.
"""

import asyncio
import math
import signal
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from aeromanip.experiment.runlog import RunLog

mavsdk = pytest.importorskip("mavsdk")
pytest.importorskip("pymavlink")
pytestmark = pytest.mark.realtime  # flies against the wall clock: the machine to itself

import mavsdk_square  # noqa: E402  (the app: needs mavsdk, checked above)

HOST = "127.0.0.1"
APP_LIMIT_S = 60.0  # [s] the app's whole flight, connection to disarm
SITL_MAX_S = 80.0  # [s] the SITL stops by itself after this, whatever happens
TELEMETRY_TOL_M = 0.01  # [m] MAVSDK's position against the truth
CLI = [sys.executable, "-m", "aeromanip.cli"]


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((HOST, 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    root = tmp_path_factory.mktemp("mavsdk")
    port = free_udp_port()
    sitl = subprocess.Popen(
        [*CLI, "sitl", "flight", "--link", f"udpout:{HOST}:{port}", "--out", str(root / "sitl"),
         "--max-time", str(SITL_MAX_S)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
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


def test_mavsdk_telemetry_is_the_truth_within_1_cm(flight):
    truth = flight["truth"]
    samples = [(t, p.position) for t, p in flight["seen"]["positions"]]
    wall = np.array([t for t, _ in samples]) + flight["wall_minus_mono"]
    inside = (wall > truth.column("wall_time")[0]) & (wall < truth.column("wall_time")[-1])
    wall = wall[inside]
    ned = np.array([(p.north_m, p.east_m, p.down_m) for _, p in samples])[inside]
    armed = truth_at(truth, wall, "armed") > 0.5
    assert armed.sum() >= 50 * 15  # 50 Hz over the whole flight
    # truth ENU -> NED: north = y, east = x, down = -z
    expected = np.column_stack(
        [truth_at(truth, wall, "y"), truth_at(truth, wall, "x"), -truth_at(truth, wall, "z")]
    )
    error = np.linalg.norm(ned - expected, axis=1)
    print(f"MAVSDK vs truth: {len(error)} samples, max {1e3 * error.max():.2f} mm, "
          f"RMS {1e3 * math.sqrt(np.mean(error**2)):.2f} mm")  # fmt: skip
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
    assert abs(north[-1]) < 0.15 and abs(east[-1]) < 0.15  # closed, give or take the lag
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
