"""What a ground station sees of the SITL, checked against PX4's rules (the citations in
``sitl_telemetry`` and ``sitl_commands``): the messages and their rates, a healthy and
armable vehicle, commands answered by COMMAND_LONG and COMMAND_INT alike with ACKs to the
sender, requests answered, what it cannot do refused in words.

A pymavlink client (sysid 255, compid 190 as QGroundControl) on loopback against the SITL
of ``flight`` in physics, in real time (one SITL, about 10 s).
"""

import math
import threading
import time
from collections import Counter
from itertools import pairwise

import pytest

from aeromanip.experiment.scenario import load_scenarios
from aeromanip.mavlink.protocol import load_mavutil
from aeromanip.mavlink.sitl import SitlAutopilot
from aeromanip.mavlink.sitl_telemetry import (
    EARTH_RADIUS_M,
    HOME_ALT_M,
    HOME_LAT_DEG,
    HOME_LON_DEG,
)
from loopback import free_udp_port

pytest.importorskip("pymavlink")
pytestmark = pytest.mark.realtime  # flies against the wall clock: the machine to itself

# [s] the SITL's longest run (real time; the tests take ~30 s alone, longer on a loaded
# machine, where at 40 s it stopped before the last two); stopped when the tests are done
RUN_S = 90.0
ME = (255, 190)  # the client's system and component
SETTLE_S = 0.3  # [s] the shortest wait after a command: what is sent with the answer
ANSWER_WAIT_S = 3.0  # [s] the longest wait for its answer (a fully loaded machine)
UNKNOWN_COMMAND = 31000  # a MAV_CMD no autopilot knows: answered UNSUPPORTED
GET_MESSAGE_INTERVAL = 510  # MAV_CMD: answered by MESSAGE_INTERVAL, no COMMAND_ACK
RATE_WINDOW_S = 4.0  # [s] messages counted over this
PX4_RATES = {  # [Hz] PX4's ground-station link, and the SITL's state rate
    "HEARTBEAT": 1.0,
    "SYS_STATUS": 1.0,
    "EXTENDED_SYS_STATE": 1.0,
    "HOME_POSITION": 0.5,
    "GLOBAL_POSITION_INT": 5.0,
    "SYSTEM_TIME": 1.0,
    "LOCAL_POSITION_NED": 50.0,
    "ATTITUDE": 50.0,
}
CAPABILITIES = ("MAVLINK2", "COMMAND_INT", "PARAM_FLOAT", "PARAM_ENCODE_BYTEWISE",
                "MISSION_INT", "SET_POSITION_TARGET_LOCAL_NED")  # fmt: skip
ACCEPTED, TEMPORARILY_REJECTED, DENIED, UNSUPPORTED, FAILED = range(5)


STAMPED = (  # streams with a time stamp: (name, its field, the field's unit [s])
    ("LOCAL_POSITION_NED", "time_boot_ms", 1e-3),
    ("ATTITUDE", "time_boot_ms", 1e-3),
    ("GLOBAL_POSITION_INT", "time_boot_ms", 1e-3),
    ("SYSTEM_TIME", "time_boot_ms", 1e-3),
    ("HOME_POSITION", "time_usec", 1e-6),
)


def sitl_span(msgs: list, stamp: str, unit: float) -> float:
    """The SITL time [s] that ``msgs`` (a 50 Hz stream) cover, one period included."""
    return unit * (getattr(msgs[-1], stamp) - getattr(msgs[0], stamp)) + 0.02


def mean_period(stamps: list[int], measured_every: int) -> float:
    """The mean period of a stream's stamps, each the time of the measurement it carries:
    every period a whole number of measurement periods (50 Hz: ``measured_every`` in the
    stamps' unit), so a 20 Hz stream's periods are 40 and 60 ms."""
    assert all((b - a) > 0 and (b - a) % measured_every == 0 for a, b in pairwise(stamps))
    return (stamps[-1] - stamps[0]) / (len(stamps) - 1)


class ServingDoneError(Exception):
    """Stops the SITL's thread."""


class Gcs:
    """A ground station: every message kept with its arrival time."""

    def __init__(self, port: int) -> None:
        mavutil = load_mavutil()
        self.m = mavutil.mavlink
        self.conn = mavutil.mavlink_connection(
            f"udpin:127.0.0.1:{port}", source_system=ME[0], source_component=ME[1]
        )
        self.log: list[tuple[float, object]] = []

    def pump(self, seconds: float, until=lambda: False) -> None:
        """Keep what arrives for ``seconds``, or until ``until()`` holds."""
        end = time.monotonic() + seconds
        while time.monotonic() < end and not until():
            msg = self.conn.recv_msg()
            if msg is None:
                time.sleep(0.001)
            else:
                self.log.append((time.monotonic(), msg))

    def since(self, t0: float, kind: str) -> list:
        return [m for t, m in self.log if t >= t0 and m.get_type() == kind]

    def send(self, command: int, params: tuple, as_int: bool, target: tuple) -> float:
        """Send a command (COMMAND_LONG or COMMAND_INT); when it was sent."""
        t0 = time.monotonic()
        p = [*params, *[0.0] * (7 - len(params))]
        if as_int:
            self.conn.mav.command_int_send(*target, 0, command, 0, 0, *p[:4], int(p[4]),
                                           int(p[5]), p[6])  # fmt: skip
        else:
            self.conn.mav.command_long_send(*target, command, 0, *p)
        return t0

    def ack(self, command: int, *params: float, as_int: bool = False, target=(1, 1)):
        """Send a command (COMMAND_LONG or COMMAND_INT), return (its ACK or None, t0)."""
        t0 = self.send(command, params, as_int, target)

        def acks() -> list:
            return [a for a in self.since(t0, "COMMAND_ACK") if a.command == command]

        def answered() -> bool:  # GET_MESSAGE_INTERVAL is answered by its reply alone
            reply = command == GET_MESSAGE_INTERVAL and self.since(t0, "MESSAGE_INTERVAL")
            return bool(acks() or reply)

        self.pump(SETTLE_S)  # what comes with the answer arrives too
        self.pump(ANSWER_WAIT_S - SETTLE_S, until=answered)  # a loaded machine answers late
        return (acks()[0] if acks() else None), t0

    def unanswered(self, command: int, *params: float, as_int: bool, target: tuple) -> bool:
        """Send a command that must go unanswered, then one that is answered (an unknown
        command, to us): the SITL reads in order, so its answer to the second proves the
        first got none."""
        t0 = self.send(command, params, as_int, target)
        fence, _ = self.ack(UNKNOWN_COMMAND)
        assert fence is not None and fence.result == UNSUPPORTED, "the fence got no answer"
        return not [a for a in self.since(t0, "COMMAND_ACK") if a.command == command]

    def texts(self, t0: float) -> list[str]:
        """The STATUSTEXTs since ``t0``, chunks (same non-zero id) joined."""
        out: list[str] = []
        last_id = 0
        for m in self.since(t0, "STATUSTEXT"):
            if m.id and m.id == last_id and m.chunk_seq > 0:
                out[-1] += m.text
            else:
                out.append(m.text)
            last_id = m.id
        return out


@pytest.fixture(scope="module")
def gcs():
    port = free_udp_port()
    client = Gcs(port)
    sc = load_scenarios("flight", ["duration=5"])[""]
    sitl = SitlAutopilot(sc, f"udpout:127.0.0.1:{port}")
    failures, done = [], threading.Event()

    def sink(row: dict) -> None:
        if done.is_set():
            raise ServingDoneError

    def serve() -> None:
        try:
            sitl.run(sink, max_time_s=RUN_S)
        except ServingDoneError:
            pass
        except BaseException as e:  # reported by the test
            failures.append(e)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        assert client.conn.wait_heartbeat(timeout=5) is not None
        client.conn.mav.heartbeat_send(6, 8, 0, 0, 4)  # a GCS heartbeat: our address
        yield client
    finally:
        done.set()
        thread.join(timeout=RUN_S + 5)
        client.conn.close()
        sitl.close()
    assert not failures and not thread.is_alive()


def test_the_streams_come_at_px4s_rates_and_say_a_healthy_armable_px4(gcs):
    t0 = time.monotonic()
    gcs.pump(RATE_WINDOW_S)
    counts = Counter(m.get_type() for t, m in gcs.log if t >= t0)
    # the SITL's clock (its messages' stamps): it lags the wall clock on a loaded machine
    span = sitl_span(gcs.since(t0, "LOCAL_POSITION_NED"), "time_boot_ms", 1e-3)
    print(f"rates [Hz] over {span:.2f} s of SITL time: "
          + ", ".join(f"{k} {n / span:.3g}" for k, n in sorted(counts.items())))  # fmt: skip
    for kind, hz in PX4_RATES.items():
        assert abs(counts[kind] - hz * span) <= 1.5, (kind, counts[kind], span)
    for kind, stamp, unit in STAMPED:  # each period exact, in SITL time
        msgs = gcs.since(t0, kind)
        periods = {round(getattr(b, stamp) - getattr(a, stamp)) for a, b in pairwise(msgs)}
        assert periods == {round(1 / (PX4_RATES[kind] * unit))}, (kind, periods)
    beat = gcs.since(t0, "HEARTBEAT")[-1]
    # flight's platform is an octocopter (its 8 rotors in the physics)
    assert (beat.type, beat.autopilot) == (gcs.m.MAV_TYPE_OCTOROTOR, gcs.m.MAV_AUTOPILOT_PX4)
    assert beat.base_mode == 29 and beat.custom_mode == 0x03040000  # Hold, disarmed
    assert beat.system_status == gcs.m.MAV_STATE_STANDBY
    status = gcs.since(t0, "SYS_STATUS")[-1]
    gps = gcs.m.MAV_SYS_STATUS_SENSOR_GPS
    prearm = gcs.m.MAV_SYS_STATUS_PREARM_CHECK
    assert status.onboard_control_sensors_present & gps
    assert status.onboard_control_sensors_health & (gps | prearm) == gps | prearm
    assert gcs.since(t0, "EXTENDED_SYS_STATE")[-1].landed_state == 1  # on the ground
    # home and global position: the fixed origin plus the local NED position, checked by
    # the great-circle distance (haversine) and the altitudes
    home = gcs.since(t0, "HOME_POSITION")[-1]
    glob = gcs.since(t0, "GLOBAL_POSITION_INT")[-1]
    local = gcs.since(t0, "LOCAL_POSITION_NED")[-1]
    origin = (math.radians(HOME_LAT_DEG), math.radians(HOME_LON_DEG))
    here = (math.radians(glob.lat * 1e-7), math.radians(glob.lon * 1e-7))
    h = (
        math.sin((here[0] - origin[0]) / 2) ** 2
        + math.cos(origin[0]) * math.cos(here[0]) * math.sin((here[1] - origin[1]) / 2) ** 2
    )
    distance = 2 * EARTH_RADIUS_M * math.asin(math.sqrt(h))
    assert abs(distance - math.hypot(local.x, local.y)) < 0.02  # degE7 ~ 1.1 cm
    assert abs(glob.alt - 1e3 * (HOME_ALT_M - local.z)) < 10  # [mm] with the noise
    assert abs(home.altitude - 1e3 * (HOME_ALT_M - home.z)) <= 1
    assert abs(glob.relative_alt - 1e3 * (home.z - local.z)) < 10


def test_requests_are_answered_with_the_message_then_an_ack_to_the_sender(gcs):
    for as_int in (False, True):
        ack, t0 = gcs.ack(512, 148, as_int=as_int)  # REQUEST_MESSAGE AUTOPILOT_VERSION
        assert ack.result == ACCEPTED and (ack.target_system, ack.target_component) == ME
        (version,) = gcs.since(t0, "AUTOPILOT_VERSION")
        cap = {n: getattr(gcs.m, f"MAV_PROTOCOL_CAPABILITY_{n}") for n in CAPABILITIES}
        assert version.capabilities == sum(cap.values())  # only what it does
    ack, t0 = gcs.ack(520, 1)  # the older REQUEST_AUTOPILOT_CAPABILITIES
    assert ack.result == ACCEPTED and len(gcs.since(t0, "AUTOPILOT_VERSION")) == 1
    ack, t0 = gcs.ack(410)  # GET_HOME_POSITION
    assert ack.result == ACCEPTED and gcs.since(t0, "HOME_POSITION")
    ack, _ = gcs.ack(512, 147)  # BATTERY_STATUS: not something it can send
    assert ack.result == DENIED
    ack, t0 = gcs.ack(512, 244, 33)  # MESSAGE_INTERVAL of GLOBAL_POSITION_INT
    assert ack.result == ACCEPTED
    assert [m.interval_us for m in gcs.since(t0, "MESSAGE_INTERVAL")] == [200_000]


def test_message_intervals_are_set_as_px4_sets_them(gcs):
    ack, _ = gcs.ack(511, 33, 50_000, as_int=True)  # GLOBAL_POSITION_INT at 20 Hz
    assert ack.result == ACCEPTED
    t0 = time.monotonic()
    gcs.pump(1.0)
    stamps = [m.time_boot_ms for m in gcs.since(t0, "GLOBAL_POSITION_INT")]
    assert len(stamps) >= 10 and mean_period(stamps, 20) == pytest.approx(50, abs=1)  # [ms]
    assert gcs.ack(511, 33, -1)[0].result == ACCEPTED  # stop
    t0 = time.monotonic()
    gcs.pump(0.5)
    assert gcs.since(t0, "GLOBAL_POSITION_INT") == []
    assert gcs.ack(511, 33, 0)[0].result == ACCEPTED  # back to the default (5 Hz)
    assert gcs.ack(511, 0, 100_000)[0].result == FAILED  # HEARTBEAT is fixed
    assert gcs.ack(511, 33, 100_000, 1)[0].result == FAILED  # param3 set
    assert gcs.ack(511, 147, 100_000)[0].result == FAILED  # not a stream
    ack, t0 = gcs.ack(510, 32)  # GET_MESSAGE_INTERVAL: the reply, no ACK
    assert ack is None
    assert [m.interval_us for m in gcs.since(t0, "MESSAGE_INTERVAL")] == [20_000]
    _, t0 = gcs.ack(510, 331)  # ODOMETRY: an onboard link's, off here until asked
    assert [m.interval_us for m in gcs.since(t0, "MESSAGE_INTERVAL")] == [-1]
    assert gcs.ack(511, 331, 0)[0].result == ACCEPTED  # its default: 30 Hz asked
    t0 = time.monotonic()
    gcs.pump(1.0)
    stamps = [m.time_usec for m in gcs.since(t0, "ODOMETRY")]
    # 30 Hz is no whole number of 10 ms ticks: every 3 ticks (33.3 Hz)
    assert len(stamps) >= 15 and mean_period(stamps, 20_000) == pytest.approx(
        30_000, abs=1e3
    )  # [us]
    assert gcs.ack(511, 331, -1)[0].result == ACCEPTED


def test_commands_long_and_int_alike_and_what_it_cannot_do_refused_in_words(gcs):
    for as_int in (False, True):
        ack, _ = gcs.ack(UNKNOWN_COMMAND, 1, as_int=as_int)  # a command it does not know
        assert ack.result == UNSUPPORTED and (ack.target_system, ack.target_component) == ME
        assert gcs.unanswered(400, 1, target=(7, 1), as_int=as_int)  # not for it
        assert gcs.unanswered(400, 1, target=(0, 1), as_int=as_int)  # PX4: no broadcast
    ack, t0 = gcs.ack(400, 7)
    assert ack.result == UNSUPPORTED
    assert gcs.texts(t0) == ["Unsupported ARM_DISARM param: 7.000"]
    ack, t0 = gcs.ack(400, 1, as_int=True)  # arm by COMMAND_INT
    assert ack.result == ACCEPTED
    gcs.pump(0.2)
    assert gcs.texts(t0) == ["armed: hold"]
    beat = gcs.since(t0, "HEARTBEAT")[0]  # sent at once on the change
    assert beat.base_mode == 157 and beat.system_status == gcs.m.MAV_STATE_ACTIVE
    ack, t0 = gcs.ack(400, 0)
    assert ack.result == TEMPORARILY_REJECTED
    assert gcs.texts(t0) == ["Disarming denied: not landed"]
    ack, t0 = gcs.ack(21)  # NAV_LAND
    assert ack.result == TEMPORARILY_REJECTED
    assert gcs.texts(t0) == ["Switching to Land is currently not available"]
    ack, t0 = gcs.ack(176, 1, 3)  # DO_SET_MODE Position
    assert ack.result == TEMPORARILY_REJECTED
    assert gcs.texts(t0) == ["Switching to Position is currently not available"]
    t0 = time.monotonic()  # the SET_MODE message: Offboard without a setpoint stream
    gcs.conn.mav.set_mode_send(1, 1, 6 << 16)
    gcs.pump(0.3)
    assert [a.result for a in gcs.since(t0, "COMMAND_ACK")] == [TEMPORARILY_REJECTED]
    assert gcs.texts(t0) == ["offboard refused: no setpoint stream"]
    ack, _ = gcs.ack(176, 1, 4, 3, as_int=True)  # Hold by COMMAND_INT
    assert ack.result == ACCEPTED
    assert gcs.ack(400, 1, 0, 0, 0, 2**31 - 1, 2**31 - 1)[0].result == DENIED  # malformed


def test_pings_timesync_and_unsupported_messages(gcs):
    t0 = time.monotonic()
    gcs.conn.mav.ping_send(123456, 7, 0, 0)
    gcs.conn.mav.timesync_send(0, 987654321)
    gcs.conn.mav.request_data_stream_send(1, 1, 0, 10, 1)
    gcs.conn.mav.set_attitude_target_send(0, 1, 1, 7, (1, 0, 0, 0), 0, 0, 0, 0.5)
    gcs.pump(0.3)
    (ping,) = gcs.since(t0, "PING")
    assert (ping.time_usec, ping.seq, ping.target_system, ping.target_component) == (
        123456, 7, *ME)  # fmt: skip
    (sync,) = gcs.since(t0, "TIMESYNC")
    assert sync.ts1 == 987654321 and sync.tc1 > 0
    assert gcs.texts(t0) == [
        "REQUEST_DATA_STREAM unsupported: use SET_MESSAGE_INTERVAL",
        "SET_ATTITUDE_TARGET unsupported",
    ]
