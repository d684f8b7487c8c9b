"""The SITL's parameters change its flight as their PX4 namesakes do: ``MPC_XY_VEL_MAX``
caps the velocity flown (truth: the physics' speed), ``COM_OF_LOSS_T`` is the time from
the last setpoint to the failsafe hold, ``MC_YAWRATE_MAX`` caps the yaw rate.

A pymavlink client on loopback against the SITL of ``flight`` in physics, in real time.
"""

import math
import time

import pytest

from aeromanip.experiment.scenario import load_scenarios
from aeromanip.mavlink.protocol import load_mavutil
from aeromanip.mavlink.sitl import SitlAutopilot
from aeromanip.mavlink.sitl_params import REAL32
from loopback import free_udp_port, sitl_in_thread

pytest.importorskip("pymavlink")

FLY_S = 7.5  # [s] the SITL's run (real time)
CAP = 0.2  # [m/s] MPC_XY_VEL_MAX set by the client
LOSS_T = 1.5  # [s] COM_OF_LOSS_T set by the client
VELOCITY_NED_YAW = 2503  # MAVSDK's set_velocity_ned


def stream(client, until: float, north: float, got: list) -> None:
    """Setpoints north at 20 Hz until the monotonic time ``until``; what arrives into
    ``got``."""
    next_send = 0.0
    while (now := time.monotonic()) < until:
        if north is not None and now >= next_send:
            client.mav.set_position_target_local_ned_send(
                0, 1, 1, 1, VELOCITY_NED_YAW, 0, 0, 0, north, 0, 0, 0, 0, 0, math.nan, 0
            )
            next_send = now + 0.05
        msg = client.recv_msg()
        if msg is None:
            time.sleep(0.002)
        else:
            got.append(msg)


@pytest.mark.realtime  # flies against the wall clock: the machine to itself
def test_the_velocity_cap_and_the_loss_timeout_fly_as_set():
    mavutil = load_mavutil()
    port = free_udp_port()
    client = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255)
    sc = load_scenarios("flight", ["duration=5"])[""]
    sitl = SitlAutopilot(sc, f"udpout:127.0.0.1:{port}")
    got: list = []
    with sitl_in_thread(sitl, FLY_S) as rows:
        try:
            assert client.wait_heartbeat(timeout=5) is not None
            t0 = time.monotonic()
            client.mav.param_set_send(1, 1, b"MPC_XY_VEL_MAX", CAP, REAL32)
            client.mav.param_set_send(1, 1, b"COM_OF_LOSS_T", LOSS_T, REAL32)
            client.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)  # arm
            stream(client, t0 + 1.2, 1.0, got)
            client.mav.command_long_send(1, 1, 176, 0, 1, 6, 0, 0, 0, 0, 0)  # offboard
            stream(client, t0 + 4.0, 1.0, got)  # 1 m/s asked
            stream(client, t0 + 6.5, None, got)  # silence: the failsafe after LOSS_T
        finally:
            client.close()
    echoes = {m.param_id: m.param_value for m in got if m.get_type() == "PARAM_VALUE"}
    assert echoes == {"MPC_XY_VEL_MAX": pytest.approx(CAP), "COM_OF_LOSS_T": LOSS_T}
    flown = [r for r in rows if r["status"] == "offboard"]
    assert len(flown) >= 30
    speeds = [math.hypot(r["vx"], r["vy"]) for r in flown]
    assert max(speeds) <= 1.1 * CAP  # capped (the velocity loop's overshoot aside)
    assert sum(speeds[-10:]) / 10 > 0.8 * CAP  # and flying at the cap, not slower
    (failsafe,) = [e for e in sitl.vehicle.events if e.text.startswith("failsafe")]
    assert failsafe.t - sitl.vehicle.last_sp == pytest.approx(LOSS_T, abs=2 * sitl.tick)
    assert "1.5 s" in failsafe.text


def test_the_yaw_rate_and_climb_limits_bound_what_is_flown():
    port = free_udp_port()
    sc = load_scenarios("flight", ["duration=5"])[""]
    sitl = SitlAutopilot(sc, f"udpout:127.0.0.1:{port}")
    try:
        sitl.params.values["MC_YAWRATE_MAX"] = 30.0  # [deg/s]
        v, rate = sitl._limited((3.0, 4.0, -10.0), -2.0)  # 5 m/s; climbing 10 m/s
        assert rate == pytest.approx(-math.radians(30.0))
        assert v == pytest.approx((3.0, 4.0, -3.0))  # MPC_Z_VEL_MAX_UP 3 m/s
        sitl.params.values["MPC_XY_VEL_MAX"] = 1.0
        v, _ = sitl._limited((3.0, 4.0, 9.0), 0.0)
        assert v == pytest.approx((0.6, 0.8, 1.5))  # the direction kept; down 1.5 m/s
    finally:
        sitl.close()
