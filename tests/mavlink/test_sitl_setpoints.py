"""The SITL flies the setpoints a stock offboard app sends, and refuses bad ones in words.

A pymavlink client (a stand-in for MAVSDK's ``Offboard``: its masks and frames) on
loopback against the SITL autopilot of ``flight`` in physics, in real time: it arms,
streams MAVSDK's ``set_velocity_ned`` (north at 0.5 m/s, mask 2503), switches to
offboard, then sends setpoints with NaN and infinite values. Truth: the SITL's own truth
log (the physics), a physical law (the distance flown at the commanded speed) and the
STATUSTEXT PX4 would send.
"""

import math
import time

import pytest

from aeromanip.experiment.scenario import load_scenarios
from aeromanip.mavlink import frames
from aeromanip.mavlink.protocol import load_mavutil
from aeromanip.mavlink.sitl import SitlAutopilot
from loopback import free_udp_port, sitl_in_thread

pytest.importorskip("pymavlink")
pytestmark = pytest.mark.realtime  # flies against the wall clock: the machine to itself

FLY_S = 4.0  # [s] the SITL's run (real time)
NORTH = 0.5  # [m/s] the commanded speed
VELOCITY_NED_YAW = 2503  # MAVSDK's set_velocity_ned


def fly(client, mav, until, vel, yaw=0.0, texts=None) -> None:
    """Stream setpoints at 20 Hz until the monotonic time ``until``, reading what arrives
    meanwhile (as a client does: the socket's buffer would overflow otherwise); the
    STATUSTEXTs into ``texts``."""
    next_send = 0.0
    while (now := time.monotonic()) < until:
        if now >= next_send:
            client.mav.set_position_target_local_ned_send(
                0, 1, 1, mav.MAV_FRAME_LOCAL_NED, VELOCITY_NED_YAW, 0, 0, 0, *vel, 0, 0, 0, yaw, 0
            )
            next_send = now + 0.05
        msg = client.recv_msg()
        if msg is None:
            time.sleep(0.002)
        elif msg.get_type() == "STATUSTEXT" and texts is not None:
            texts.append(msg.text)


def test_a_stock_velocity_setpoint_flies_and_a_nan_one_is_refused_in_words():
    mavutil = load_mavutil()
    mav = mavutil.mavlink
    port = free_udp_port()
    client = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255)
    sc = load_scenarios("flight", ["duration=5"])[""]
    sitl = SitlAutopilot(sc, f"udpout:127.0.0.1:{port}")
    with sitl_in_thread(sitl, FLY_S) as rows:
        try:
            assert client.wait_heartbeat(timeout=5) is not None
            t0 = time.monotonic()
            client.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)  # arm
            texts: list[str] = []
            heading = frames.yaw_enu_to_ned(float(sc.x0[sc.robot.platform.dofs.index("yaw")]))
            fly(client, mav, t0 + 1.2, (0.0, 0.0, 0.0), heading, texts)
            client.mav.command_long_send(1, 1, 176, 0, 1, 6, 0, 0, 0, 0, 0)  # offboard
            fly(client, mav, t0 + 2.7, (NORTH, 0.0, 0.0), heading, texts)  # keep the heading
            fly(client, mav, t0 + 3.2, (math.nan, math.inf, -math.inf), yaw=math.nan, texts=texts)
        finally:
            client.close()
    # each event said, in order; the bad setpoint refused as PX4's position controller
    # rejects it, said once, not at every message
    assert texts == ["armed: hold", "offboard", "SET_POSITION_TARGET_LOCAL_NED: invalid setpoints"]
    flown = [r for r in rows if r["status"] == "offboard"]
    assert len(flown) >= 10
    # north (ENU y) at the commanded speed for the offboard part, give or take the
    # vehicle's acceleration from rest: at least half the ideal distance, at most all
    north = flown[-1]["y"] - flown[0]["y"]
    span = flown[-1]["t"] - flown[0]["t"]
    assert 0.5 * NORTH * span < north <= NORTH * span + 0.05
    assert abs(flown[-1]["x"] - flown[0]["x"]) < 0.05  # nothing east
    assert all(math.isfinite(r["x"]) and math.isfinite(r["y"]) for r in rows)
