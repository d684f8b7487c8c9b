"""The bridge's bytes against PX4's rules (PX4-Autopilot at commit 161b530; the table with
every rule and its source line is ``docs/mavlink/bridge-vs-px4.md``).

``aeromanip fly`` flies a short mission against a PX4 stand-in on 127.0.0.1
(``px4_fake``) whose system id is 7 (``MAV_SYS_ID`` = 7: nothing may assume 1); the
stand-in records every datagram. Each message is unpacked here from its raw MAVLink 2
bytes with ``struct`` (the wire layout of the MAVLink XML, not pymavlink's decoder and
not the bridge's constants) and read by a re-statement of PX4's code, written from the
cited source. Smaller tests drive the transport alone against the stand-in.
"""

import math
import struct
import time

import numpy as np
import pytest

pytest.importorskip("pymavlink")

from aeromanip.cli import main
from aeromanip.errors import ExitCode
from aeromanip.experiment.scenario import load_scenarios
from aeromanip.mavlink.bridge import MavlinkTransport
from aeromanip.runtime.follower import GAIN
from aeromanip.runtime.transport import LinkError
from loopback import free_udp_port
from px4_fake import FakePx4

pytestmark = pytest.mark.realtime  # flies against the wall clock

PX4_SYSID, PX4_COMPID = 7, 1
COM_OF_LOSS_T = 1.0  # [s] PX4's default (commander_params.c L318-329)
HEARTBEAT_TIMEOUT_S = 2.5  # [s] msg/TelemetryStatus.msg L38 (HEARTBEAT_TIMEOUT_US)
DRIFT_NED = (0.2, 0.0, 0.0)  # [m] the stand-in moves this far from where the bridge holds
DRIFT_YAW = 0.1  # [rad] and turns this much (NED: clockwise)

# MAVLink common.xml POSITION_TARGET_TYPEMASK bits
X, Y, Z, VX, VY, VZ, AX, AY, AZ, FORCE, YAW, YAW_RATE = (1 << i for i in range(12))
# px4_custom_mode.h L44-55 (main modes count from MANUAL = 1), L58-61 (AUTO sub modes)
MAIN = {"MANUAL": 1, "ALTCTL": 2, "POSCTL": 3, "AUTO": 4, "ACRO": 5, "OFFBOARD": 6}
AUTO_LOITER = 3
CMD_ARM, CMD_SET_MODE, CMD_SET_ACTUATOR, CMD_SET_MESSAGE_INTERVAL = 400, 176, 187, 511


def unpack(raw: bytes) -> tuple[int, int, int, bytes]:
    """A MAVLink 2 frame: source system, source component, message id, payload (with
    the trailing zeros MAVLink 2 cuts off put back)."""
    assert raw[0] == 0xFD, "MAVLink 2 framing"
    n = raw[1]
    msgid = raw[7] | raw[8] << 8 | raw[9] << 16
    return raw[5], raw[6], msgid, raw[10 : 10 + n] + bytes(64)


def setpoint_fields(raw: bytes) -> dict:
    """SET_POSITION_TARGET_LOCAL_NED (#84), by its wire layout."""
    sysid, compid, msgid, p = unpack(raw)
    assert msgid == 84
    f = struct.unpack_from("<I11fHBBB", p)
    return dict(
        src=(sysid, compid), time_boot_ms=f[0], pos=f[1:4], vel=f[4:7], acc=f[7:10],
        yaw=f[10], yaw_rate=f[11], mask=f[12], target=(f[13], f[14]), frame=f[15],
    )  # fmt: skip


def command_fields(raw: bytes) -> dict:
    """COMMAND_LONG (#76), by its wire layout."""
    sysid, compid, msgid, p = unpack(raw)
    assert msgid == 76
    f = struct.unpack_from("<7fHBBB", p)
    return dict(src=(sysid, compid), params=f[:7], command=f[7], target=(f[8], f[9]), conf=f[10])


def heartbeat_fields(raw: bytes) -> dict:
    """HEARTBEAT (#0), by its wire layout."""
    sysid, compid, msgid, p = unpack(raw)
    assert msgid == 0
    _, kind, autopilot, base, _, _ = struct.unpack_from("<IBBBBB", p)
    return dict(src=(sysid, compid), type=kind, autopilot=autopilot, base_mode=base)


def px4_reads_local_ned(sp: dict, vehicle_yaw: float = 0.0) -> dict | str:
    """What PX4 makes of a SET_POSITION_TARGET_LOCAL_NED: ``mavlink_receiver.cpp``
    ``handle_message_set_position_target_local_ned``, L1029-1146 at 161b530, restated:
    the target check (L1035-1037), LOCAL_NED field by field (L1043-1054), BODY_NED
    (L1056-1100), any other frame refused (L1102-1107), yaw / yaw rate (L1110-1111), the
    control flags from which vectors are not all NaN (L1114-1117), FORCE refused
    (L1119-1124), nothing set refused (L1140-1144)."""
    nan = math.nan
    if sp["target"][0] not in (PX4_SYSID, 0) or sp["target"][1] not in (PX4_COMPID, 0):
        return "not for this vehicle (dropped)"
    m = sp["mask"]
    if sp["frame"] == 1:  # MAV_FRAME_LOCAL_NED
        pos = [nan if m & b else v for b, v in zip((X, Y, Z), sp["pos"], strict=True)]
        vel = [nan if m & b else v for b, v in zip((VX, VY, VZ), sp["vel"], strict=True)]
        acc = [nan if m & b else v for b, v in zip((AX, AY, AZ), sp["acc"], strict=True)]
    elif sp["frame"] == 8:  # MAV_FRAME_BODY_NED
        c, s = math.cos(vehicle_yaw), math.sin(vehicle_yaw)
        bx, by, bz = sp["vel"]
        vel = [nan] * 3 if m & (VX | VY | VZ) else [c * bx - s * by, s * bx + c * by, bz]
        acc = [nan] * 3 if m & (AX | AY | AZ) else list(sp["acc"])  # (rotated by R)
        pos = [nan] * 3
    else:
        return f"coordinate frame {sp['frame']} unsupported"
    yaw = nan if m & YAW else sp["yaw"]
    yawspeed = nan if m & YAW_RATE else sp["yaw_rate"]
    ocm = tuple(not all(math.isnan(v) for v in vec) for vec in (pos, vel, acc))
    if ocm[2] and m & FORCE:
        return "force not supported"
    if not any(ocm):
        return "invalid"
    return dict(ocm=ocm, pos=pos, vel=vel, acc=acc, yaw=yaw, yawspeed=yawspeed)


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    """One short mission (two steps) flown against the stand-in; what it received."""
    sc = next(iter(load_scenarios("flight", ["duration=1.0"]).values()))
    x0 = np.array(sc.x0)
    ned = (float(x0[1]), float(x0[0]), -float(x0[2]))
    yaw0 = math.remainder(math.pi / 2 - float(x0[3]), 2 * math.pi)
    drift = {"t": None}

    def mutate(kind, f, since):  # 0.3 s after the first setpoint, moved and turned
        sps = fake.of_type("SET_POSITION_TARGET_LOCAL_NED")
        if sps and drift["t"] is None and time.monotonic() > sps[0].t + 0.3:
            drift["t"] = time.monotonic()
        if drift["t"] is None:
            return f
        if kind == "LOCAL_POSITION_NED":
            return {**f, **{k: f[k] + d for k, d in zip("xyz", DRIFT_NED, strict=True)}}
        return {**f, "yaw": math.remainder(f["yaw"] + DRIFT_YAW, 2 * math.pi)}

    out = tmp_path_factory.mktemp("capture") / "run"
    port = free_udp_port()
    fake = FakePx4(port, ned, yaw0, tuple(x0[4:]), mutate=mutate, sysid=PX4_SYSID)
    argv = ["fly", "flight", "--link", f"udpin:127.0.0.1:{port}", "--out", str(out)]
    with fake:
        rc = main([*argv, "--set", "duration=1.0"])
    return {"rc": rc, "fake": fake, "drift_t": drift["t"], "limits": sc.robot.joints}


def sent(flight, kind):
    return [r for r in flight["fake"].received if r.msg.get_type() == kind]


def commands(flight, command):
    out = []
    for r in sent(flight, "COMMAND_LONG"):
        c = command_fields(r.raw)
        if c["command"] == command:
            out.append((r.t, c))
    return out


def offboard_request_t(flight) -> float:
    return next(t for t, c in commands(flight, CMD_SET_MODE) if round(c["params"][1]) == 6)


def test_the_mission_flew_to_its_end(flight):
    # the stand-in does not move, so the tracking is poor: flown, not necessarily well
    assert flight["rc"] in (ExitCode.OK, ExitCode.DID_NOT_FLY)


def test_heartbeat_is_an_onboard_controller_of_the_vehicles_system(flight):
    connected = sent(flight, "COMMAND_LONG")[0].t  # the bridge heard the autopilot
    beats = [(r.t, heartbeat_fields(r.raw)) for r in sent(flight, "HEARTBEAT")]
    assert len(beats) >= 3
    for t, h in beats:
        if t < connected:  # before: whom to be is not known yet
            continue
        # mavlink_receiver.cpp L2147-2164: counted as the onboard controller (for
        # COM_OBC_LOSS_T, Commander.cpp L2890-2898) only from PX4's own system id
        assert h["src"][0] == PX4_SYSID and h["type"] == 18  # MAV_TYPE_ONBOARD_CONTROLLER
        assert h["autopilot"] == 8  # MAV_AUTOPILOT_INVALID: not an autopilot
    gaps = np.diff([t for t, _ in beats])
    assert gaps.max() < HEARTBEAT_TIMEOUT_S and 0.8 < np.median(gaps) < 1.2  # 1 Hz


def test_setpoints_are_velocity_and_yaw_rate_as_px4_reads_them(flight):
    sps = [setpoint_fields(r.raw) for r in sent(flight, "SET_POSITION_TARGET_LOCAL_NED")]
    assert len(sps) > 50
    for sp in sps:
        got = px4_reads_local_ned(sp)
        assert isinstance(got, dict), got  # accepted: an offboard signal
        # velocity control only (control_mode.cpp: position > velocity > acceleration)
        assert got["ocm"] == (False, True, False)
        assert all(math.isfinite(v) for v in got["vel"])  # every axis set (_inputValid)
        assert math.isnan(got["yaw"]) and math.isfinite(got["yawspeed"])  # yaw rate flown


def test_setpoints_are_ned_metres_per_second(flight):
    """The stand-in moved 0.2 m north of where the bridge holds it and turned 0.1 rad
    clockwise: the bridge must send it back south and turn it back anticlockwise (NED:
    negative yaw rate), at the hold's P gain (m/s per m)."""
    start, switch = flight["drift_t"] + 0.2, offboard_request_t(flight)
    sps = [
        setpoint_fields(r.raw)
        for r in sent(flight, "SET_POSITION_TARGET_LOCAL_NED")
        if start < r.t < switch
    ]
    assert len(sps) >= 10
    for sp in sps:
        v = np.array(sp["vel"])
        back = -np.array(DRIFT_NED) / np.linalg.norm(DRIFT_NED)
        assert np.dot(v, back) > 0.98 * np.linalg.norm(v)  # towards the hold point
        assert np.linalg.norm(v) == pytest.approx(GAIN * 0.2, rel=0.2)  # m/s
        assert sp["yaw_rate"] == pytest.approx(-GAIN * DRIFT_YAW, rel=0.2)  # rad/s


def test_offboard_handshake_and_stream(flight):
    times = [r.t for r in sent(flight, "SET_POSITION_TARGET_LOCAL_NED")]
    switch = offboard_request_t(flight)
    before = [t for t in times if t < switch]
    # PX4 takes offboard when the last setpoint is younger than COM_OF_LOSS_T
    # (offboardCheck.cpp L46-51); its docs ask for a stream > 2 Hz for over a second
    assert switch - before[-1] < 0.1 and switch - before[0] >= 1.0
    assert len(before) >= 2 * (switch - before[0])
    arm = commands(flight, CMD_ARM)[0][0]
    assert before[0] < arm < switch  # armed while streaming, before offboard
    # from the first setpoint to the last: never a gap near the loss timeout
    gaps = np.diff(times)
    assert gaps.max() < 0.5 * COM_OF_LOSS_T and len(times) / (times[-1] - times[0]) >= 20


def test_arm_command_as_px4s_commander_reads_it(flight):
    (_, c), *more = commands(flight, CMD_ARM)
    assert more == []  # answered at once: sent once
    p = c["params"]
    # evaluate_target_ok (mavlink_receiver.cpp L449-455): own system, own or all components
    assert c["target"][0] == PX4_SYSID and c["target"][1] in (PX4_COMPID, 0)
    assert round(p[0]) == 1  # Commander.cpp L985: lroundf(param1): ARM
    assert round(p[1]) != 21196  # L995: not forced (the checks run)
    int32_max = float(2**31 - 1)  # mavlink_receiver.cpp L470-482: param5/6 = INT32_MAX denied
    assert not (math.isclose(p[4], int32_max) and math.isclose(p[5], int32_max))
    assert c["conf"] == 0


def test_mode_commands_name_offboard_then_hold(flight):
    modes = [c for _, c in commands(flight, CMD_SET_MODE)]
    for c in modes:
        assert c["target"] == (PX4_SYSID, PX4_COMPID) or c["target"] == (PX4_SYSID, 0)
        assert int(c["params"][0]) & 1  # CUSTOM_MODE_ENABLED (Commander.cpp L842)
    # uint8 casts of param2, param3 (Commander.cpp L834-836): OFFBOARD (L917-918), then
    # AUTO with sub mode LOITER = Hold (L866-869) at the end
    named = [(int(c["params"][1]), int(c["params"][2])) for c in modes]
    assert named == [(MAIN["OFFBOARD"], 0), (MAIN["AUTO"], AUTO_LOITER)]


def test_telemetry_rates_asked_as_px4_accepts(flight):
    asked = {}
    for _, c in commands(flight, CMD_SET_MESSAGE_INTERVAL):
        p = c["params"]
        msg_id = int(p[0] + 0.5)  # mavlink_receiver.cpp L583
        # set_message_interval, L2239-2281: not HEARTBEAT; param3, param4, param7 unset
        # (NaN) or 0; an interval > 0 is a rate of 1e6 / interval
        assert msg_id != 0
        assert all(not math.isfinite(p[i]) or int(p[i] + 0.5) == 0 for i in (2, 3, 6))
        assert p[1] > 0
        asked[msg_id] = 1e6 / p[1]
    # LOCAL_POSITION_NED (32) and ATTITUDE (30), fast enough for a 0.5 s staleness check
    assert set(asked) == {30, 32} and min(asked.values()) >= 20.0
    arm = commands(flight, CMD_ARM)[0][0]
    assert max(t for t, _ in commands(flight, CMD_SET_MESSAGE_INTERVAL)) < arm


def test_actuator_commands_as_px4s_actuator_set_reads_them(flight):
    """FunctionActuatorSet.hpp L55-76: only set index int(param7 + 0.5) == 0 is read;
    a finite param i sets output "Peripheral via Actuator Set i", a NaN keeps it."""
    joints = flight["limits"]
    held = flight["fake"].joints
    switch = offboard_request_t(flight)  # before it, the arm held where it is
    cmds = [c for t, c in commands(flight, CMD_SET_ACTUATOR) if t < switch]
    assert len(cmds) > 50
    for c in cmds:
        p = c["params"]
        assert int(p[6] + 0.5) == 0 and c["target"][0] == PX4_SYSID
        assert all(math.isnan(v) for v in p[len(joints) : 6])  # the unused outputs kept
        for value, j, q in zip(p, joints, held, strict=False):
            assert -1.0 <= value <= 1.0
            # the value spans the joint's range: -1 at its lower limit, +1 at its upper
            assert j.lower + 0.5 * (value + 1.0) * (j.upper - j.lower) == pytest.approx(q, abs=1e-5)


@pytest.fixture
def link():
    """A transport and a stand-in (system 7) made with ``fake_kw``."""
    made = []

    def make(**fake_kw):
        port = free_udp_port()
        t = MavlinkTransport(f"udpin:127.0.0.1:{port}")
        fake = FakePx4(port, sysid=PX4_SYSID, **fake_kw).__enter__()
        made.append((t, fake))
        t.connect(5.0)
        return t, fake

    yield make
    for t, fake in made:
        t.close()
        fake.__exit__(None, None, None)


def test_an_unanswered_command_is_resent_with_its_confirmation_counting(link):
    t, fake = link(acks={CMD_ARM: None})
    with pytest.raises(LinkError, match="no COMMAND_ACK for command 400"):
        t.arm(1.2)
    arms = [command_fields(r.raw) for r in fake.of_type("COMMAND_LONG")]
    arms = [c for c in arms if c["command"] == CMD_ARM]
    assert [c["conf"] for c in arms] == list(range(len(arms))) and len(arms) >= 3


def test_a_mode_acked_but_not_taken_is_not_flown(link):
    """PX4 at 161b530 acks DO_SET_MODE ACCEPTED in the receiver (mavlink_receiver.cpp
    L616-617) before its commander decides: only the heartbeat says the mode changed."""
    t, _ = link(modes_taken=False)
    t0 = time.monotonic()
    with pytest.raises(LinkError, match="accepted, but the autopilot's heartbeat still says"):
        t.set_mode("offboard", 3.0)
    assert time.monotonic() - t0 < 3.5


def test_acks_addressed_to_another_client_are_not_ours(link):
    t, _ = link(ack_to=(42, 190))  # a ground station's ack (mavlink_receiver.cpp L121-133)
    with pytest.raises(LinkError, match="no COMMAND_ACK"):
        t.arm(1.0)


def test_heartbeats_of_another_component_do_not_change_armed_or_mode(link):
    t, fake = link()
    t.arm(3.0)
    assert t.is_armed()
    fake.conn.mav.srcComponent = 100  # a camera of the same system: base_mode 0
    fake.conn.mav.heartbeat_send(30, 8, 0, 0, 0)
    fake.conn.mav.srcComponent = PX4_COMPID
    time.sleep(0.3)
    assert t.is_armed() and t.mode() == "hold"


def test_a_refused_arm_is_one_line_with_the_autopilots_reason(tmp_path, capsys):
    """Commander.cpp L1009-1011: refused -> TEMPORARILY_REJECTED, after a critical
    STATUSTEXT "Arming denied: ..." (L644-651)."""
    sc = next(iter(load_scenarios("flight", ["duration=1.0"]).values()))
    x0 = np.array(sc.x0)
    port = free_udp_port()
    why = "Arming denied: Resolve system health failures first\t"
    fake = FakePx4(port, joints=tuple(x0[4:]), acks={CMD_ARM: 1}, reject_text=why)
    with fake:
        rc = main(["fly", "flight", "--link", f"udpin:127.0.0.1:{port}", "--out",
                   str(tmp_path / "run"), "--set", "duration=1.0"])  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == ExitCode.LINK and len(err) == 1, err
    assert "arm: the autopilot answered MAV_RESULT_TEMPORARILY_REJECTED" in err[0]
    assert "(it said: Arming denied: Resolve system health failures first)" in err[0]
    assert not any(
        command_fields(r.raw)["command"] == CMD_SET_MODE for r in fake.of_type("COMMAND_LONG")
    )


@pytest.mark.parametrize(
    "main_mode, sub_mode, name",
    [(6, 0, "offboard"), (4, 3, "hold"), (4, 4, "other"), (4, 0, "other"), (3, 0, "other")],
)
def test_the_heartbeats_custom_mode_read_as_px4_packs_it(main_mode, sub_mode, name):
    """``union px4_custom_mode`` (px4_custom_mode.h L85-90): a reserved uint16, then the
    main mode and the sub mode bytes, little-endian in the HEARTBEAT's ``custom_mode``."""
    from aeromanip.mavlink.protocol import mode_name

    (custom,) = struct.unpack("<I", struct.pack("<HBB", 0, main_mode, sub_mode))
    assert mode_name(custom) == name
