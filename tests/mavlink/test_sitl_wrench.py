"""The wrist force/torque sensor over MAVLink: the SITL autopilot of a contact scenario
streams its physics' sensor reading (``NAMED_VALUE_FLOAT`` ``wrist_*``), and the arm
interface of ``aeromanip fly`` hands it to the controller once every component has come.
Truth: the scenario's sensor noise law and a physical law (armed, the vehicle holds at its
start, the probe off the wall: the sensor feels the probe's weight alone), and the SITL's
own truth log."""

from types import SimpleNamespace

import numpy as np
import pytest

from aeromanip.experiment.scenario import load_scenarios
from aeromanip.mavlink.arm import WRENCH_NAMES, MavlinkActuatorArm
from aeromanip.mavlink.protocol import load_mavutil
from aeromanip.mavlink.sitl import SitlAutopilot
from loopback import free_udp_port, sitl_in_thread

pytest.importorskip("pymavlink")

FLY_S = 3.0  # [s] the SITL's run (real time)


class Handlers:
    """A transport stand-in: the arm registers its message handler here."""

    def __init__(self) -> None:
        self.handlers = {}

    def add_handler(self, name, fn) -> None:
        self.handlers[name] = fn


def _value(name: str, value: float) -> SimpleNamespace:
    return SimpleNamespace(name=name, value=value)


def test_the_arm_hands_on_the_wrench_once_every_component_has_come():
    sc = load_scenarios("contact-wall", ["duration=5"], "cog")["cog"]
    transport = Handlers()
    arm = MavlinkActuatorArm(transport, sc.robot)
    on_value = transport.handlers["NAMED_VALUE_FLOAT"]
    reading = [0.5, -1.0, 2.0, 0.01, -0.02, 0.03]
    for name, v in zip(WRENCH_NAMES[:-1], reading, strict=False):
        on_value(_value(name, v))
        assert arm.wrench() is None
    on_value(_value(WRENCH_NAMES[-1], reading[-1]))
    assert arm.wrench() == tuple(reading)
    assert arm.joints() is None  # the joints' feedback is its own
    on_value(_value("wrist_fz", 2.5))  # the latest value of each component
    assert arm.wrench()[2] == 2.5


@pytest.mark.realtime  # flies against the wall clock: the machine to itself
def test_the_sitl_streams_its_wrist_sensor_with_the_scenarios_noise():
    mavutil = load_mavutil()
    port = free_udp_port()
    client = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255)
    sc = load_scenarios("contact-wall", ["duration=5"], "cog")["cog"]
    sitl = SitlAutopilot(sc, f"udpout:127.0.0.1:{port}")
    transport = Handlers()
    arm = MavlinkActuatorArm(transport, sc.robot)
    received = {name: [] for name in WRENCH_NAMES}
    with sitl_in_thread(sitl, FLY_S) as rows:
        try:
            assert client.wait_heartbeat(timeout=5) is not None
            client.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)  # arm: it holds
            while len(received["wrist_tz"]) < 60:
                msg = client.recv_match(type="NAMED_VALUE_FLOAT", blocking=True, timeout=2)
                assert msg is not None, "no NAMED_VALUE_FLOAT within 2 s"
                name = str(msg.name).rstrip("\x00")
                transport.handlers["NAMED_VALUE_FLOAT"](msg)
                if name in received:
                    received[name].append(msg.value)
        finally:
            client.close()
    assert all(r["f_n"] == 0.0 for r in rows)  # the probe is off the wall
    noise = sc.sim_options["noise"]
    contact = sitl.sim.contact  # the probe beyond the sensor: its weight is all it feels
    weight = contact.model.body_subtreemass[contact.model.site_bodyid[contact.site]] * 9.81
    expected_force = {"wrist_fx": 0.0, "wrist_fy": 0.0, "wrist_fz": -weight}  # world, up +z
    for name, values in received.items():
        v = np.unique(np.array(values))  # one draw per SITL step, sent more than once
        std = noise["force"] if "_f" in name else noise["torque"]
        assert v.size >= 10 and np.all(np.isfinite(v)), name
        assert 0.5 * std < np.std(v) < 2.0 * std, name  # the noise law
        if name in expected_force:  # hovering level: the weight, give or take 2 deg of tilt
            tolerance = 4.0 * std / np.sqrt(v.size) + 0.05 * weight
            assert abs(np.mean(v) - expected_force[name]) < tolerance, name
    assert arm.wrench() is not None
