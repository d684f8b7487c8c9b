"""``sitl_commands`` without a link: COMMAND_INT read as PX4 reads it, and actuator values
outside an output's range [-1, 1] held at its ends (a hostile value cannot send a joint's
servo past its limits)."""

import math
import socket
from types import SimpleNamespace

import pytest

from aeromanip.experiment.scenario import load_scenarios
from aeromanip.mavlink.sitl import SitlAutopilot
from aeromanip.mavlink.sitl_commands import INT32_MAX, NAN_AS_INT, Request, from_int, from_long

pytest.importorskip("pymavlink")


def command_int(x: int, y: int, **kw) -> SimpleNamespace:
    fields = dict(command=400, param1=1.0, param2=0.0, param3=0.0, param4=0.0, x=x, y=y,
                  z=5.0, target_system=1, target_component=1)  # fmt: skip
    msg = SimpleNamespace(**(fields | kw))
    msg.get_srcSystem, msg.get_srcComponent = (lambda: 255), (lambda: 190)
    return msg


def test_command_int_positions_are_degrees_and_int32_max_is_unset():
    req = from_int(command_int(473977420, 85455940))
    assert req.params[4:] == pytest.approx((47.397742, 8.545594, 5.0))
    assert req.sender == (255, 190) and not req.malformed
    unset = from_int(command_int(INT32_MAX, INT32_MAX))
    assert math.isnan(unset.params[4]) and math.isnan(unset.params[5])
    assert from_int(command_int(NAN_AS_INT, NAN_AS_INT)).malformed  # PX4: DENIED


def test_command_long_with_int32_max_in_params_5_and_6_is_malformed():
    msg = command_int(0, 0)
    for i, value in enumerate((1.0, 0, 0, 0, float(INT32_MAX), float(INT32_MAX), 0), start=1):
        setattr(msg, f"param{i}", value)
    assert from_long(msg).malformed
    msg.param6 = 1e9
    assert not from_long(msg).malformed


def test_actuator_values_beyond_the_output_range_hold_the_joint_at_its_limit():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    sc = load_scenarios("flight", ["duration=5"])[""]
    sitl = SitlAutopilot(sc, f"udpout:127.0.0.1:{port}")
    try:
        before = sitl.vehicle.q_target.copy()
        params = (1e38, -math.inf, math.nan, 0.0, 0.0, 0.0, 0.0)
        assert sitl.commands.handle(Request(187, params, (255, 190), (1, 1))) == 0
        joints = sc.robot.joints
        assert sitl.vehicle.q_target[0] == joints[0].upper
        assert sitl.vehicle.q_target[1] == before[1]  # not finite: kept
        assert sitl.vehicle.q_target[2] == before[2]
        bad_group = (0.0,) * 6 + (math.nan,)
        assert sitl.commands.handle(Request(187, bad_group, (255, 190), (1, 1))) == 2  # DENIED
    finally:
        sitl.close()
