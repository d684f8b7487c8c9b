"""``aeromanip fly`` against a vehicle that goes wrong mid-flight (a PX4 stand-in on
127.0.0.1, ``px4_fake``; each flight a few seconds, every wait bounded).

What the vehicle does, about 2.5 s into offboard, and what ``fly`` must do (PX4's rules
for it: ``docs/mavlink/bridge-vs-px4.md``):

- telemetry it cannot fly on (a value not finite or out of range), or no position or
  attitude for 0.5 s while the link is up (one message stopped, or time going back: an
  autopilot that rebooted or sent an absurd time): stop the setpoints at once and switch
  the autopilot to Hold (a ``DO_SET_MODE`` AUTO / LOITER), checked by its heartbeat;
- the vehicle leaves offboard or disarms (a pilot, a kill switch, its own failsafe):
  stop the setpoints, command nothing.

Each ends with one line on stderr naming the cause, exit 4 (``ExitCode.LINK``), and a
run directory whose log holds every step flown and whose summary says what happened.
"""

import json
import math
import time

import numpy as np
import pytest

pytest.importorskip("pymavlink")

from aeromanip.cli import main
from aeromanip.errors import ExitCode
from aeromanip.experiment.runlog import RunLog
from aeromanip.experiment.scenario import load_scenarios
from loopback import free_udp_port
from px4_fake import AUTO, INF, LOITER, FakePx4

pytestmark = pytest.mark.realtime  # flies against the wall clock

FAULT_AFTER_S = 2.5  # [s] after the fake entered offboard
DURATION_S = 6.0  # [s] the mission: longer than it takes to go wrong
STOP_WITHIN_S = 0.1  # [s] the setpoints stop this soon after the vehicle says so
LOSS_S = 0.5  # [s] the bridge's stated telemetry timeout (LINK_LOSS_S)


class Once:
    """A ``mutate``: from ``FAULT_AFTER_S`` on, ``change(kind, fields)``; remembers when
    it first changed something (``t``)."""

    def __init__(self, change):
        self.change, self.t = change, None

    def __call__(self, kind, fields, since):
        if since is None or since < FAULT_AFTER_S:
            return fields
        out = self.change(kind, dict(fields))
        if out != fields and self.t is None:
            self.t = time.monotonic()
        return out


def set_field(kind, name, value):
    return lambda k, f: {**f, name: value} if k == kind else f


def stop(kind):
    return lambda k, f: None if k == kind else f


class BackInTime:
    """One message with an absurd ``time_boot_ms`` (the largest), then the true ones."""

    def __init__(self):
        self.sent = False

    def __call__(self, kind, f):
        if kind != "LOCAL_POSITION_NED":
            return f
        if not self.sent:
            self.sent = True
            return {**f, "time_boot_ms": 2**32 - 1}
        return {**f, "time_boot_ms": f["time_boot_ms"] + 1}  # differs: marks the fault's time


def leave_offboard(v):
    v.main, v.sub = 3, 0  # POSCTL: a pilot took over
    v.event_t = time.monotonic()
    v.heartbeat()


def disarm(v):
    v.armed = False  # a kill switch
    v.event_t = time.monotonic()
    v.heartbeat()


CASES = {  # name -> (mutate, action, ending, words in the line, hold commanded)
    "nan position": (Once(set_field("LOCAL_POSITION_NED", "x", math.nan)), None,
                     "telemetry fault", "LOCAL_POSITION_NED.x = nan (not finite)", True),
    "inf attitude": (Once(set_field("ATTITUDE", "roll", INF)), None,
                     "telemetry fault", "ATTITUDE.roll = inf (not finite)", True),
    "position out of range": (Once(set_field("LOCAL_POSITION_NED", "z", -1e6)), None,
                              "telemetry fault", "LOCAL_POSITION_NED.z = -1e+06 m (allowed", True),
    "attitude stale": (Once(stop("ATTITUDE")), None,
                       "telemetry stale", "no ATTITUDE for 0.5", True),
    "absurd timestamp": (Once(BackInTime()), None, "telemetry stale",
                         "LOCAL_POSITION_NED.time_boot_ms went back from 4294967295", True),
    "left offboard": (None, leave_offboard, "left offboard", "left offboard (now other)", False),
    "disarmed": (None, disarm, "disarmed", "disarmed in flight", False),
}  # fmt: skip


@pytest.fixture(scope="module")
def x0():
    sc = next(iter(load_scenarios("flight", [f"duration={DURATION_S:g}"]).values()))
    return np.array(sc.x0)


def fly_against(fake_kw, x0, out, capsys):
    port = free_udp_port()
    ned = (float(x0[1]), float(x0[0]), -float(x0[2]))  # ENU -> NED
    yaw = math.remainder(math.pi / 2 - float(x0[3]), 2 * math.pi)
    argv = ["fly", "flight", "--link", f"udpin:127.0.0.1:{port}", "--out", str(out)]
    t0 = time.monotonic()
    with FakePx4(port, ned=ned, yaw_ned=yaw, joints=tuple(x0[4:]), **fake_kw) as v:
        rc = main([*argv, "--set", f"duration={DURATION_S:g}"])
    assert time.monotonic() - t0 < 60
    return rc, v, capsys.readouterr()


@pytest.mark.parametrize("case", list(CASES))
def test_a_vehicle_going_wrong_stops_the_flight_cleanly(case, x0, tmp_path, capsys):
    mutate, action, ending, words, hold = CASES[case]
    kw = {"mutate": mutate} if mutate else {"at": [(FAULT_AFTER_S, action)]}
    rc, v, out = fly_against(kw, x0, tmp_path / "run", capsys)

    assert rc == ExitCode.LINK, out.err
    lines = out.err.strip().splitlines()
    assert len(lines) == 1 and words in lines[0], out.err  # one line, naming the cause
    assert "Traceback" not in out.err
    s = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert s["ending"] == ending and words in s["error"] and not s["link_lost"]
    log = RunLog.load(tmp_path / "run", require_rows=True)  # intact, every row whole
    assert log.missing_columns() == [] and len(log) == s["steps"] >= 2

    went_wrong = mutate.t if mutate else v.event_t
    assert went_wrong is not None
    setpoints = [r.t for r in v.of_type("SET_POSITION_TARGET_LOCAL_NED")]
    stale = case in ("attitude stale", "absurd timestamp")
    # faults and mode changes: at once; stale telemetry: when it is LOSS_S old
    assert setpoints[-1] - went_wrong <= (LOSS_S if stale else 0.0) + STOP_WITHIN_S
    modes_after = [
        (round(r.msg.param2), round(r.msg.param3))
        for r in v.of_type("COMMAND_LONG")
        if r.msg.command == 176 and r.t > went_wrong
    ]
    if hold:  # PX4's Hold: AUTO (4) / LOITER (3), taken (the fake's heartbeat shows it)
        assert modes_after == [(AUTO, LOITER)] and s["hold_accepted"]
        assert (v.main, v.sub) == (AUTO, LOITER)
        assert "hold commanded and confirmed" in lines[0]
    else:  # a pilot or the autopilot took over: nothing commanded
        assert modes_after == [] and not s["hold_accepted"]
        assert not any(r.msg.command == 400 for r in v.of_type("COMMAND_LONG") if r.t > went_wrong)


def test_telemetry_bad_from_the_start_commands_nothing(x0, tmp_path, capsys):
    def nan_always(kind, fields, since):
        return {**fields, "roll": math.nan} if kind == "ATTITUDE" else fields

    rc, v, out = fly_against({"mutate": nan_always}, x0, tmp_path / "run", capsys)
    assert rc == ExitCode.LINK, out.err
    lines = out.err.strip().splitlines()
    assert len(lines) == 1 and "ATTITUDE.roll = nan (not finite); nothing commanded" in lines[0]
    s = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert s["ending"] == "telemetry fault" and s["steps"] == 0
    assert v.of_type("SET_POSITION_TARGET_LOCAL_NED") == []
    assert {r.msg.command for r in v.of_type("COMMAND_LONG")} <= {511}  # rates asked only
    assert not v.armed


def test_a_controller_fault_mid_flight_holds_the_vehicle_and_keeps_the_run(
    x0, tmp_path, capsys, monkeypatch
):
    """The controller raises (a state it cannot fly on) at its third step: the vehicle is
    held and commanded to Hold, one line, exit 3, the rows flown kept with the cause."""
    from aeromanip.errors import StateError
    from aeromanip.nmpc.controller import Controller

    step, calls, raised = Controller.step, [], []

    def faulty(self, *args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            raised.append(time.monotonic())
            raise StateError("x: injected fault")
        return step(self, *args, **kwargs)

    monkeypatch.setattr(Controller, "step", faulty)
    rc, v, out = fly_against({}, x0, tmp_path / "run", capsys)
    assert rc == ExitCode.DID_NOT_FLY, out.err
    lines = out.err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in out.err, out.err
    assert "the flight stopped (vehicle holding): x: injected fault; 2 steps kept" in lines[0]
    s = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert s["ending"] == "fault" and s["stopped_by"] == "x: injected fault" and s["hold_accepted"]
    assert len(RunLog.load(tmp_path / "run", require_rows=True)) == s["steps"] == 2
    modes_after = [
        (round(r.msg.param2), round(r.msg.param3))
        for r in v.of_type("COMMAND_LONG")
        if r.msg.command == 176 and r.t > raised[0]
    ]
    assert modes_after == [(AUTO, LOITER)] and (v.main, v.sub) == (AUTO, LOITER)
    # until Hold is taken, the setpoints hold one point (as after Ctrl-C)
    since = raised[0] + STOP_WITHIN_S  # one in flight meanwhile may still follow the plan
    held = [r.msg for r in v.of_type("SET_POSITION_TARGET_LOCAL_NED") if r.t > since]
    assert not held or np.ptp([[m.x, m.y, m.z] for m in held], axis=0).max() < 1e-6
