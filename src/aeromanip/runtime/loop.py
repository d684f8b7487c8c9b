"""The real-time loop: the scenario's controller flying a vehicle through a transport.

``RealtimeFlight.fly(sink)``: wait for the autopilot and the first state; stream hold
setpoints for ``PRE_STREAM_S`` (PX4 takes offboard only after a second of stream); arm
and switch to offboard, each checked; solve the first step from the held state before
the mission clock starts (a cold solve takes several periods' worth of a warm one: the
reference would set off without the vehicle), its plan flown from mission time 0; then
every control period ``dt`` (wall clock):
read the latest state, predict it forward by its age (``Measurement.predicted``), run
``Controller.step`` (its ``latency_s`` predicts on to when the command takes effect) and
hand the plan to the follower, which the streaming thread follows at ``STREAM_HZ``.

Deadlines: a solve longer than ``dt`` is a deadline miss: its plan is dropped (the
previous one keeps flying) and the miss counted; so is a step that starts more than a
period late (it is skipped). Each row logs the state's age, the step's wall time, the
miss and the setpoints streamed over the period before it.

Endings: the mission done, or a signal (Ctrl-C): hold where the vehicle is (platform in
place, arm still) and switch the autopilot to hold (checked). The stream stopped by the
``Streamer`` (``LinkError`` naming why, nothing more streamed): a telemetry fault or
stale telemetry while the link is up: the autopilot is switched to hold (checked; if it
does not take it, its own offboard-loss failsafe acts, the stream being stopped); the
link lost, the vehicle disarmed or out of offboard (a pilot or its failsafe took over):
nothing more commanded.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from aeromanip.experiment.closed_loop import RowMaker, make_controller
from aeromanip.experiment.scenario import Scenario
from aeromanip.interrupts import deferred, raise_if_interrupted
from aeromanip.nmpc.controller import Command
from aeromanip.realtime import setup_frozen
from aeromanip.runtime.follower import GAIN, Plan, PlanFollower
from aeromanip.runtime.measure import Measurement, MissionClock, StateReader
from aeromanip.runtime.streamer import LINK_LOSS_S, STREAM_HZ, Streamer
from aeromanip.runtime.transport import ArmInterface, LinkError, Transport

CONNECT_TIMEOUT_S = 15.0  # [s] wait for the autopilot's heartbeat and first state
PRE_STREAM_S = 1.5  # [s] setpoints streamed before asking for offboard (PX4: > 1 s)
COMMAND_TIMEOUT_S = 3.0  # [s] wait for a COMMAND_ACK
RUNTIME_COLUMNS = ("state_age_ms", "step_ms", "deadline_miss", "setpoints", "setpoint_gap_ms")

Row = dict[str, Any]


@dataclass
class FlightStats:
    """What the runtime measured: steps flown, deadline misses, link loss."""

    steps: int = 0
    deadline_misses: int = 0
    link_lost: bool = False
    link_lost_age_s: float = math.nan
    link_lost_wall: float = math.nan
    start_wall: float = math.nan
    ending: str = ""
    hold_ack: bool = False
    state_ages_ms: list[float] = field(default_factory=list)
    setpoint_rate_hz: float = math.nan
    setpoint_gap_max_ms: float = math.nan

    def summary(self) -> dict[str, Any]:
        """The runtime's keys of ``summary.json``."""
        ages = np.array(self.state_ages_ms) if self.state_ages_ms else np.array([math.nan])
        return {
            "deadline_misses": self.deadline_misses,
            "link_lost": self.link_lost,
            "link_lost_state_age_s": self.link_lost_age_s,
            "link_lost_wall_time": self.link_lost_wall,
            "start_wall_time": self.start_wall,
            "ending": self.ending,
            "hold_accepted": self.hold_ack,
            "state_age_ms_median": float(np.median(ages)),
            "state_age_ms_max": float(np.max(ages)),
            "setpoint_rate_hz": self.setpoint_rate_hz,
            "setpoint_gap_max_ms": self.setpoint_gap_max_ms,
        }


class RealtimeFlight:
    """The scenario ``sc`` flown in real time over ``transport`` and ``arm``."""

    def __init__(
        self,
        sc: Scenario,
        transport: Transport,
        arm: ArmInterface,
        stream_hz: float = STREAM_HZ,
        loss_s: float = LINK_LOSS_S,
        gain: float = GAIN,
    ) -> None:
        self.sc, self.transport, self.arm = sc, transport, arm
        self.ctrl = make_controller(sc)
        self.maker = RowMaker(sc)
        self.follower = PlanFollower(sc.robot, gain)
        self.reader = StateReader(sc.robot, transport, arm)
        self.clock = MissionClock()
        self.streamer = Streamer(
            transport, arm, self.follower, self.reader, self.clock, stream_hz, loss_s
        )
        self.stats = FlightStats()

    def fly(self, sink: Callable[[Row], None]) -> FlightStats:
        """Fly the mission, handing a row per step to ``sink``; ``LinkError`` if the link
        is lost or the autopilot refuses, ``RunInterrupted`` on a signal, ``OSError`` if a
        row cannot be written, any other error of the step raised as it is (the vehicle
        left holding in all but the first)."""
        self.transport.connect(CONNECT_TIMEOUT_S)
        m = self._first_state()
        self.follower.hold(m.x)
        self.streamer.start()
        try:
            with setup_frozen():  # no full garbage collection inside a step
                self._sleep_until(time.monotonic() + PRE_STREAM_S)
                self.transport.arm(COMMAND_TIMEOUT_S)
                self.transport.set_mode("offboard", COMMAND_TIMEOUT_S)
                self.streamer.flying.set()
                self._first_step(sink)
                self._steps(sink)
            self.stats.ending = "completed"
            self._hold()
        except LinkError:
            if self.streamer.lost.is_set():
                raise self._stopped() from None
            raise
        except KeyboardInterrupt:
            self.stats.ending = "interrupted"
            self._hold()
            raise
        except OSError:  # the log cannot be written: stop the mission, the vehicle holding
            self.stats.ending = "write refused"
            self._hold()
            raise
        except Exception:  # a fault it cannot fly on (a bug too): the vehicle holding first
            self.stats.ending = "fault"
            if self.streamer.flying.is_set():
                self._hold()
            raise
        finally:
            self._stream_stats()
            self.streamer.stop()
        return self.stats

    def _first_state(self) -> Measurement:
        end = time.monotonic() + CONNECT_TIMEOUT_S
        while (m := self.reader.read()) is None:
            if (fault := self.transport.fault()) is not None:
                self.stats.ending = "telemetry fault"
                raise LinkError(f"telemetry fault: {fault}; nothing commanded")
            if time.monotonic() > end:
                raise LinkError(f"no vehicle state and joints within {CONNECT_TIMEOUT_S:g} s")
            time.sleep(0.01)
        return m

    def _sleep_until(self, deadline: float) -> None:
        """Wait until ``deadline`` [s, monotonic], raising on link loss or a signal."""
        while True:
            if self.streamer.lost.is_set():
                raise LinkError("the setpoint stream stopped")  # fly() says why
            raise_if_interrupted()
            left = deadline - time.monotonic()
            if left <= 0:
                return
            self.streamer.lost.wait(min(left, 0.05))

    def _stopped(self) -> LinkError:
        """The stream stopped by itself: record why; after a telemetry fault or stale
        telemetry in offboard, switch the autopilot to hold; the error to raise."""
        s, why = self.stats, self.streamer.stop_reason
        kind, text = (why.kind, why.text) if why is not None else ("link lost", "link lost")
        s.ending, s.link_lost = kind, kind == "link lost"
        s.link_lost_age_s, s.link_lost_wall = self.streamer.lost_age, self.streamer.lost_wall
        if kind in ("telemetry fault", "telemetry stale") and self.streamer.flying.is_set():
            with deferred():
                try:
                    self.transport.set_mode("hold", COMMAND_TIMEOUT_S)
                    s.hold_ack = True
                    text += "; setpoints stopped, hold commanded and confirmed"
                except LinkError as e:
                    text += f"; setpoints stopped, hold not confirmed ({e}): the autopilot's "
                    text += "offboard-loss failsafe acts"
        elif kind in ("telemetry fault", "telemetry stale"):
            text += "; setpoints stopped, nothing commanded (not in offboard yet)"
        return LinkError(text)

    def _read(self) -> Measurement:
        if (m := self.reader.read()) is None:
            raise LinkError("no vehicle state")
        return m

    def _solve(self, m: Measurement, now: float, t: float) -> tuple[Command, np.ndarray, float]:
        """``Controller.step`` at mission time ``t`` [s] from ``m`` predicted to ``now``
        [s, monotonic]: the command, the state it started from, the step's wall time [s]."""
        x = m.predicted(now)
        rates = m.rates if self.ctrl.problem.model.has_response else None
        c0 = time.perf_counter()
        with deferred():
            cmd = self.ctrl.step(x, t, rates, wrench=m.wrench, attitude=m.attitude)
        return cmd, x, time.perf_counter() - c0

    def _first_step(self, sink: Callable[[Row], None]) -> None:
        """Step 0, solved before the clock starts from the state of the vehicle holding
        still: its plan flies from mission time 0 on; no deadline applies to it."""
        m = self._read()
        now = time.monotonic()
        cmd, x, step_s = self._solve(m, now, 0.0)
        self._sleep_until(now)  # raises if the link was lost or a signal came meanwhile
        self.clock.start()
        self.stats.start_wall = time.time()
        self._fly(cmd, 0.0)
        self._log(sink, 0.0, cmd, x, 1e3 * m.age(now), step_s, False, (0, math.nan))

    def _steps(self, sink: Callable[[Row], None]) -> None:
        """Steps 1 on, each at its period's start (wall clock)."""
        dt = self.sc.problem.dt
        k, last = 1, self.clock.at(0.0)
        while k < self.sc.steps:
            self._sleep_until(self.clock.at(k * dt))
            now = time.monotonic()
            if now - self.clock.at(k * dt) > dt:  # a whole period late: skip, count it
                self.stats.deadline_misses += 1
                k = math.floor((now - self.clock.at(0.0)) / dt) + 1
                continue
            m, t = self._read(), self.clock.now()
            cmd, x, step_s = self._solve(m, now, t)
            miss = step_s > dt
            if miss:  # too late: the previous plan flies on, the controller forgets this one
                self.stats.deadline_misses += 1
                self.ctrl.discard()
            else:
                self._fly(cmd, t)
            stream = self.streamer.rate_between(last, now)
            self._log(sink, t, cmd, x, 1e3 * m.age(now), step_s, miss, stream)
            last, k = now, k + 1

    def _fly(self, cmd: Command, t: float) -> None:
        """Hand ``cmd``'s plan, solved at mission time ``t`` [s], to the follower."""
        dt = self.sc.problem.dt
        self.follower.follow(Plan(t + self.ctrl.latency_s, cmd.plan_x, cmd.plan_u, dt))

    def _log(
        self,
        sink: Callable[[Row], None],
        t: float,
        cmd: Command,
        x: np.ndarray,
        age_ms: float,
        step_s: float,
        miss: bool,
        stream: tuple[int, float],
    ) -> None:
        """Hand the step's row, with the runtime's columns, to ``sink``; count the step.
        ``stream``: the setpoints sent since the last step and their largest gap [s]."""
        row = self.maker.row(t, x, None, cmd)
        self.stats.state_ages_ms.append(age_ms)
        count, gap = stream
        row.update(
            state_age_ms=age_ms,
            step_ms=1e3 * step_s,
            deadline_miss=float(miss),
            setpoints=count,
            setpoint_gap_ms=1e3 * gap,
        )
        sink(row)
        self.stats.steps += 1

    def _hold(self) -> None:
        """Hold where the vehicle is, arm still, and switch the autopilot to hold."""
        self.streamer.flying.clear()  # leaving offboard is now ours
        with deferred():
            m = self.reader.read()
            if m is not None:
                self.follower.hold(m.x)
            try:
                self.transport.set_mode("hold", COMMAND_TIMEOUT_S)
                self.stats.hold_ack = True
            except LinkError as e:
                print(f"aeromanip: hold not confirmed: {e}", file=sys.stderr)

    def _stream_stats(self) -> None:
        sent = self.streamer.sent
        if self.clock.t0 is None or len(sent) < 2:
            return
        flown = [s for s in sent if s >= self.clock.t0]
        if len(flown) >= 2:
            self.stats.setpoint_rate_hz = (len(flown) - 1) / (flown[-1] - flown[0])
            gaps = np.diff(flown)
            self.stats.setpoint_gap_max_ms = 1e3 * float(gaps.max())
