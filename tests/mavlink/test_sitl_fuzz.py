"""Nothing a client sends crashes the SITL or its truth log: a hypothesis fuzz of
malformed MAVLink (random bytes, cut frames, bad checksums, unknown message ids) and of
well-formed messages with hostile fields (NaN, infinities, huge values, any mask and
frame, any command and params, parameter sets with bad names and types) sent to
``aeromanip sitl`` over loopback UDP.

Afterwards the SITL must be alive and answer (a HEARTBEAT, a PARAM_VALUE), stop cleanly
on SIGINT (exit 0) and leave its truth log whole: every row complete, the summary
written. Bounded: ``EXAMPLES`` datagrams, each send under a watchdog, the SITL's own
``--max-time``.
"""

import json
import math
import signal
import socket
import subprocess
import sys
import time

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aeromanip.experiment.runlog import RunLog
from aeromanip.mavlink.protocol import load_mavutil
from fuzzing import FUZZ, watchdog

pytest.importorskip("pymavlink")
pytestmark = pytest.mark.realtime  # a real-time SITL: the machine to itself

HOST = "127.0.0.1"
EXAMPLES = 400  # datagrams sent (>= 300)
SITL_MAX_S = 90.0  # [s] the SITL stops by itself after this
GOOD_EVERY = 8  # examples per good setpoint (~20 Hz)
SEND_LIMIT_S = 2.0  # [s] the watchdog on each example
CLI = [sys.executable, "-m", "aeromanip.cli"]

m = load_mavutil().mavlink
enc = m.MAVLink(None, srcSystem=255, srcComponent=190)

floats = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True, width=32),
    st.sampled_from([math.nan, math.inf, -math.inf, 1e38, -1e38, 0.0, 1.0, 2.0**31]),
)
u8, u16 = st.integers(0, 255), st.integers(0, 65535)
i32 = st.integers(-(2**31), 2**31 - 1)
target = st.sampled_from([(1, 1), (1, 0), (0, 0), (2, 1), (1, 7)])
name16 = st.one_of(
    st.sampled_from([b"COM_OF_LOSS_T", b"COM_OBL_RC_ACT", b"MPC_XY_VEL_MAX", b"MC_YAWRATE_MAX"]),
    st.binary(max_size=16),
)


def packed(build) -> bytes:
    return build().pack(enc)


messages = st.one_of(
    st.builds(lambda t, mask, frame, v, yaw: packed(
        lambda: enc.set_position_target_local_ned_encode(0, *t, frame, mask, *v, *yaw)),
        target, u16, st.sampled_from([1, 8, 7, 9, 12, 0, 255]), st.lists(floats, min_size=9,
        max_size=9), st.lists(floats, min_size=2, max_size=2)),
    st.builds(lambda t, cmd, p: packed(lambda: enc.command_long_encode(*t, cmd, 0, *p)),
              target, st.one_of(u16, st.sampled_from([400, 176, 187, 511, 512, 510, 21])),
              st.lists(floats, min_size=7, max_size=7)),
    st.builds(lambda t, cmd, p, x, y, z: packed(lambda: enc.command_int_encode(
        *t, 0, cmd, 0, 0, *p, x, y, z)), target, st.one_of(u16, st.sampled_from([400, 176, 512])),
        st.lists(floats, min_size=4, max_size=4), i32, i32, floats),
    st.builds(lambda t, name, value, kind: packed(lambda: enc.param_set_encode(
        *t, name, value, kind)), target, name16, floats, u8),
    st.builds(lambda t, name, index: packed(lambda: enc.param_request_read_encode(
        *t, name, index)), target, name16, st.integers(-32768, 32767)),
    st.builds(lambda t, n, kind: packed(lambda: enc.mission_count_encode(*t, n, kind)),
              target, u16, u8),
    st.builds(lambda base, custom: packed(lambda: enc.set_mode_encode(1, base, custom)),
              u8, st.integers(0, 2**32 - 1)),
    st.builds(lambda mask, q, rates, thrust: packed(lambda: enc.set_attitude_target_encode(
        0, 1, 1, mask, q, *rates, thrust)), u8, st.lists(floats, min_size=4, max_size=4),
        st.lists(floats, min_size=3, max_size=3), floats),
    st.builds(lambda tc1, ts1: packed(lambda: enc.timesync_encode(tc1, ts1)),
              st.integers(-(2**63), 2**63 - 1), st.integers(-(2**63), 2**63 - 1)),
)  # fmt: skip


@st.composite
def damaged(draw) -> bytes:
    """A message cut short, a byte flipped (a bad checksum), or its id changed."""
    frame = draw(messages)
    how = draw(st.sampled_from(["cut", "flip", "msgid"]))
    if how == "cut":
        return frame[: draw(st.integers(0, len(frame) - 1))]
    out = bytearray(frame)
    if how == "flip":
        i = draw(st.integers(0, len(out) - 1))
        out[i] ^= draw(st.integers(1, 255))
    else:  # MAVLink 2: msgid in bytes 7..9 (an id no dialect knows, or another's)
        out[7:10] = draw(st.integers(0, 2**24 - 1)).to_bytes(3, "little")
    return bytes(out)


#: a good setpoint (north 0.2 m/s, the heading held), sent before every GOOD_EVERY-th
#: example: the vehicle stays in offboard and flies while the hostile ones arrive (and
#: each hostile one that is taken flies for a few ticks)
SETPOINT = packed(lambda: enc.set_position_target_local_ned_encode(
    0, 1, 1, 1, 0b110111000111, 0, 0, 0, 0.2, 0, 0, 0, 0, 0, 0, 0))  # fmt: skip

#: setpoints the SITL reads (its frames and address, MAVSDK's masks or any) with hostile
#: values: the ones that fly
flown = st.builds(
    lambda mask, frame, v, yaw: packed(
        lambda: enc.set_position_target_local_ned_encode(0, 1, 1, frame, mask, *v, *yaw)),
    st.one_of(st.sampled_from([0, 2503, 1479, 2552, 3135, 2048, 2496, 2503 | 512]), u16),
    st.sampled_from([1, 8]), st.lists(floats, min_size=9, max_size=9),
    st.lists(floats, min_size=2, max_size=2),
)  # fmt: skip

datagrams = st.one_of(
    st.binary(min_size=1, max_size=280),  # noise
    damaged(),
    messages,
    messages,
    flown,
    flown,
)


@pytest.fixture(scope="module")
def sitl(tmp_path_factory):
    root = tmp_path_factory.mktemp("fuzz")
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind((HOST, 0))
    sock.settimeout(5.0)
    errors = (root / "stderr.txt").open("w")
    proc = subprocess.Popen(
        [*CLI, "sitl", "flight", "--link", f"udpout:{HOST}:{sock.getsockname()[1]}",
         "--out", str(root / "sitl"), "--max-time", str(SITL_MAX_S)],
        stdout=subprocess.DEVNULL, stderr=errors,
    )  # fmt: skip
    try:
        _, peer = sock.recvfrom(4096)  # its first message: its address
        sock.settimeout(0.0)
        sock.sendto(packed(lambda: enc.command_long_encode(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)),
                    peer)  # arm  # fmt: skip
        end = time.monotonic() + 1.3
        while time.monotonic() < end:  # a setpoint stream, then offboard: flying
            sock.sendto(SETPOINT, peer)
            drain(sock)
            time.sleep(0.05)
        sock.sendto(packed(lambda: enc.command_long_encode(1, 1, 176, 0, 1, 6, 0, 0, 0, 0, 0)),
                    peer)  # fmt: skip
        yield {"proc": proc, "sock": sock, "peer": peer, "root": root, "sent": []}
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=10)
        sock.close()
        errors.close()


def drain(sock: socket.socket) -> list[bytes]:
    out = []
    while True:
        try:
            out.append(sock.recv(65536))
        except (BlockingIOError, InterruptedError):
            return out


@settings(FUZZ, max_examples=EXAMPLES)
@given(datagram=datagrams)
def test_hostile_datagrams_are_survived(sitl, datagram):
    with watchdog(SEND_LIMIT_S):
        if len(sitl["sent"]) % GOOD_EVERY == 0:  # keep the vehicle in offboard
            sitl["sock"].sendto(SETPOINT, sitl["peer"])
        sitl["sock"].sendto(datagram, sitl["peer"])
        sitl["sent"].append(len(datagram))
        drain(sitl["sock"])
        time.sleep(0.005)  # about one per SITL tick
    assert sitl["proc"].poll() is None


def test_the_sitl_answers_after_the_fuzz_and_its_log_is_whole(sitl):
    proc, sock, peer = sitl["proc"], sitl["sock"], sitl["peer"]
    assert len(sitl["sent"]) >= 300
    assert proc.poll() is None  # alive
    parser = m.MAVLink(None)
    kinds: set[str] = set()
    end = time.monotonic() + 3.0
    while time.monotonic() < end and not {"HEARTBEAT", "PARAM_VALUE"} <= kinds:
        sock.sendto(packed(lambda: enc.param_request_read_encode(1, 1, b"COM_OF_LOSS_T", -1)),
                    peer)  # fmt: skip
        time.sleep(0.2)
        for data in drain(sock):
            for msg in parser.parse_buffer(data) or []:
                kinds.add(msg.get_type())
    assert {"HEARTBEAT", "PARAM_VALUE"} <= kinds
    proc.send_signal(signal.SIGINT)
    assert proc.wait(timeout=15) == 0
    print(f"fuzz: {len(sitl['sent'])} datagrams, {sum(sitl['sent'])} bytes; SITL alive")
    out = sitl["root"] / "sitl"
    assert (out / "summary.json").is_file() and not list(sitl["root"].glob("sitl.partial-*"))
    log = RunLog.load(out, require_rows=True)
    assert log.missing_columns() == []
    t = log.column("t")
    assert len(t) >= 20 and all(math.isfinite(v) for v in t)
    events = json.loads((out / "summary.json").read_text())["events"]
    assert any(e["text"] == "offboard" for e in events)  # the fuzz met a flying vehicle
    lines = (out / "log.csv").read_text().splitlines()
    width = len(lines[0].split(","))
    assert all(len(line.split(",")) == width for line in lines)  # no cut row
