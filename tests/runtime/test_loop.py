"""The real-time loop against an in-memory autopilot (no link, no physics): a vehicle
that holds still where the scenario starts, and records every setpoint it is sent.

The reference sets off at mission time 0, so the vehicle must be flying a plan from
then on: a cold first solve (hundreds of ms) made after the clock started held it still
meanwhile, and the flight over MAVLink tracked 1.8x worse than in physics over its
first 5 s (tests/mavlink/test_fly_against_sitl.py).
"""

import errno
import json
import os
import threading
import time

import numpy as np

from aeromanip.experiment.scenario import load_scenarios
from aeromanip.runtime.loop import RealtimeFlight
from aeromanip.runtime.transport import ArmInterface, Setpoint, Transport, VehicleState


class StillVehicle(Transport, ArmInterface):
    """An autopilot and arm at the scenario's initial state, taking every command."""

    def __init__(self, x0: np.ndarray) -> None:
        self.x0 = x0
        self.setpoints: list[tuple[float, Setpoint]] = []  # (monotonic time, setpoint)
        self.modes: list[str] = []
        self._lock = threading.Lock()

    def connect(self, timeout_s: float) -> None:
        pass

    def state(self) -> VehicleState:
        x, y, z, yaw = self.x0[:4]
        return VehicleState(time.monotonic(), (x, y, z), (0.0, 0.0, 0.0), 0.0, 0.0, yaw, 0.0)

    def send(self, setpoint) -> None:
        if isinstance(setpoint, Setpoint):
            with self._lock:
                self.setpoints.append((time.monotonic(), setpoint))

    def arm(self, timeout_s: float) -> None:
        self.modes.append("armed")

    def set_mode(self, mode: str, timeout_s: float) -> None:
        self.modes.append(mode)

    def mode(self) -> str:
        return self.modes[-1]

    def close(self) -> None:
        pass

    def joints(self):
        return tuple(self.x0[4:]), time.monotonic()


def test_the_first_plan_flies_from_mission_time_zero():
    sc = next(iter(load_scenarios("flight", ["duration=1.0"]).values()))  # 2 steps at 2 Hz
    vehicle = StillVehicle(np.array(sc.x0))
    flight = RealtimeFlight(sc, vehicle, vehicle)
    calls = []
    step = flight.ctrl.step
    flight.ctrl.step = lambda x, t, r=None, **kw: (
        calls.append((t, flight.clock.t0)) or step(x, t, r, **kw)
    )
    rows = []
    stats = flight.fly(rows.append)

    assert stats.ending == "completed" and stats.steps == 2 and stats.deadline_misses == 0
    assert rows[0]["t"] == 0.0 and rows[1]["t"] >= 0.5
    # step 0 solved before the clock started, step 1 at about 0.5 s after it
    assert calls[0] == (0.0, None) and calls[1][1] is not None
    assert vehicle.modes[:2] == ["armed", "offboard"] and vehicle.modes[-1] == "hold"
    t0 = flight.clock.t0
    flown = [(w - t0, s) for w, s in vehicle.setpoints if t0 <= w < t0 + 0.5]
    assert len(flown) >= 20  # 50 Hz over step 0's period
    # every setpoint from the start on flies the plan: the reference moves at
    # 2 pi A f = 5.5 cm/s in x at t = 0, the vehicle sits still, so the setpoint is the
    # plan's command plus the position feedback, never the hold's zero
    vx = np.array([s.velocity[0] for _, s in flown])
    assert np.all(vx > 0.01), vx[:10]
    held = [s for w, s in vehicle.setpoints if w < t0]
    assert held and all(s.velocity == (0.0, 0.0, 0.0) for s in held)


class RefusingStream:
    """A log stream whose third write (the header, a row, then this) writes half of its
    text and fails as a full disk does."""

    def __init__(self, f) -> None:
        self.f, self.writes = f, 0

    def write(self, text: str) -> int:
        self.writes += 1
        if self.writes >= 3:
            self.f.write(text[: len(text) // 2])
            self.f.flush()
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return self.f.write(text)

    def __getattr__(self, name: str):
        return getattr(self.f, name)


def test_a_refused_write_stops_the_flight_holding_and_keeps_the_rows(tmp_path, monkeypatch):
    import aeromanip.experiment.logwriter as logwriter
    from aeromanip.experiment.runlog import RunLog
    from aeromanip.runtime.session import fly_session

    real_open = logwriter.open_stream
    monkeypatch.setattr(logwriter, "open_stream", lambda p: RefusingStream(real_open(p)))
    sc = next(iter(load_scenarios("flight", ["duration=2.0"]).values()))  # 4 steps at 2 Hz
    vehicle = StillVehicle(np.array(sc.x0))
    result = fly_session(RealtimeFlight(sc, vehicle, vehicle), tmp_path / "out", "memory")

    assert isinstance(result.io_error, OSError) and result.io_error.errno == errno.ENOSPC
    assert vehicle.modes[-1] == "hold"  # the mission stopped, the vehicle holding
    assert result.out_dir == (tmp_path / "out").absolute()
    log = RunLog.load(result.out_dir)
    assert len(log) == 1 == result.summary["steps"]  # the row written; the cut one dropped
    assert "ENOSPC" in result.summary["stopped_by"]
    assert json.loads((result.out_dir / "summary.json").read_text())["steps"] == 1


class TiltedSensingVehicle(StillVehicle):
    """The still vehicle rolled and pitched a little, its arm carrying a wrist sensor."""

    ROLL, PITCH, WRENCH = 0.02, -0.03, (-1.5, 0.1, 0.2, 0.0, 0.01, 0.0)

    def state(self) -> VehicleState:
        x, y, z, yaw = self.x0[:4]
        return VehicleState(
            time.monotonic(), (x, y, z), (0.0, 0.0, 0.0), self.ROLL, self.PITCH, yaw, 0.0
        )

    def wrench(self):
        return self.WRENCH


def test_the_controller_receives_the_attitude_and_the_wrist_wrench_with_the_state():
    """What the contact tasks need on a vehicle: every step gets the platform's roll and
    pitch from the autopilot's state and the arm interface's wrench reading, as the
    physics simulator hands them; an arm without a sensor gives ``None``."""
    sc = next(iter(load_scenarios("flight", ["duration=1.0"]).values()))
    for vehicle, wrench in (
        (TiltedSensingVehicle(np.array(sc.x0)), TiltedSensingVehicle.WRENCH),
        (StillVehicle(np.array(sc.x0)), None),
    ):
        flight = RealtimeFlight(sc, vehicle, vehicle)
        seen = []

        def recorded(x, t, r=None, step=flight.ctrl.step, seen=seen, **kw):
            seen.append(kw)
            return step(x, t, r, **kw)

        flight.ctrl.step = recorded
        assert flight.fly(lambda row: None).steps == 2 and len(seen) == 2
        for kw in seen:
            if wrench is None:
                assert kw["wrench"] is None and kw["attitude"] == (0.0, 0.0)
            else:
                np.testing.assert_array_equal(kw["wrench"], wrench)
                assert kw["attitude"] == (vehicle.ROLL, vehicle.PITCH)
