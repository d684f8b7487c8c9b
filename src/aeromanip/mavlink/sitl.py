"""The software-in-the-loop autopilot: the scenario's robot in the MuJoCo physics (its
PX4-like inner loop taking velocity + yaw-rate setpoints, ``physics.setpoint =
"velocity"``), flown in real time behind PX4's MAVLink, as far as an offboard app and a
ground station touch it.

Every ``tick`` (the physics' outer-loop period, 10 ms by default) it reads what arrived:
``SET_POSITION_TARGET_LOCAL_NED`` read as PX4 does (``setpoints``; a refused one is a
STATUSTEXT with PX4's words), ``COMMAND_LONG`` / ``COMMAND_INT`` and ``SET_MODE``
(``sitl_commands``: each answered by a ``COMMAND_ACK`` to its sender), ``PING`` and
``TIMESYNC`` (answered), the setpoint kinds it cannot fly (refused in words). It flies the
last accepted setpoint through its position and yaw loops, lets ``Vehicle`` decide what
to fly and advances the physics by the tick. It streams what PX4 streams
(``sitl_telemetry``: HEARTBEAT, SYS_STATUS, HOME_POSITION, GLOBAL_POSITION_INT, .., and
``LOCAL_POSITION_NED`` + ``ATTITUDE`` + the joints at ``state_hz``, measured with the
physics' noise), says each event in a STATUSTEXT, and hands a truth row (the contract
columns from the true state plus roll, pitch, motors, velocity, mode) to its sink at
``TRUTH_HZ``.
"""

from __future__ import annotations

import math
import struct
import sys
import time
from collections import Counter
from collections.abc import Callable
from typing import Any

import numpy as np

from aeromanip.experiment.closed_loop import RowMaker, log_columns
from aeromanip.experiment.scenario import Scenario
from aeromanip.interrupts import raise_if_interrupted
from aeromanip.mavlink import frames, setpoints
from aeromanip.mavlink.protocol import load_mavutil, open_link
from aeromanip.mavlink.sitl_commands import (
    MAV_CMD_DO_SET_MODE,
    SEVERITY_CRITICAL,
    SEVERITY_INFO,
    SEVERITY_WARNING,
    Commands,
    from_int,
    from_long,
)
from aeromanip.mavlink.sitl_params import Parameters
from aeromanip.mavlink.sitl_telemetry import Measurement, Status, StatusTexts, Telemetry
from aeromanip.mavlink.vehicle import Event, Vehicle
from aeromanip.nmpc.controller import Command
from aeromanip.robot.spec import RobotSpec
from aeromanip.sim.mjcf import FREE_JOINT
from aeromanip.sim.physics import PhysicsSimulator

STATE_HZ = 50.0  # [Hz] state messages
TRUTH_HZ = 20.0  # [Hz] truth-log rows
SYSTEM_ID = 1  # this vehicle's MAVLink system id (component 1: the autopilot)
TRUTH_COLUMNS = ("wall_time", "t_mission", "vx", "vy", "vz", "speed", "armed")
SAID = "said: "  # an event that was a STATUSTEXT of the SITL's own
LOAD_SMOOTHING = 0.05  # the share of a new tick in the reported load
#: setpoint messages PX4 takes and this SITL cannot fly (refused in words, no offboard signal)
UNFLOWN = ("SET_ATTITUDE_TARGET", "SET_POSITION_TARGET_GLOBAL_INT", "SET_ACTUATOR_CONTROL_TARGET")

Row = dict[str, Any]


class SitlAutopilot:
    """The SITL vehicle of scenario ``sc`` on link ``url`` (module docstring)."""

    def __init__(self, sc: Scenario, url: str, state_hz: float = STATE_HZ) -> None:
        self.conn = open_link(url, SYSTEM_ID, 1)  # first: a link that cannot open costs nothing
        self.m = load_mavutil().mavlink
        self.sc = sc
        self.system_id = SYSTEM_ID
        # PX4-like: velocity + yaw-rate set-points; the arm's targets are angles (ramps)
        options = {**sc.physics, "setpoint": "velocity", "joint_setpoint": "ramp"}
        self.sim = PhysicsSimulator.from_options(sc.robot, options)
        self.sim.reset(sc.x0)
        self.tick = 1.0 / self.sim.outer_rate_hz
        self.params = Parameters(self.conn, SYSTEM_ID, self.say)
        self.vehicle = ParamVehicle(sc.robot, sc.x0, self.params)
        self.maker = RowMaker(sc)
        self.every = {
            "state": max(1, round(1.0 / (state_hz * self.tick))),
            "truth": max(1, round(1.0 / (TRUTH_HZ * self.tick))),
        }
        fv = self.sim.model.jnt_dofadr[self.sim.model.joint(FREE_JOINT).id]
        self._vel = self.sim.data.qvel[fv : fv + 3]  # world frame
        self._omega = self.sim.data.qvel[fv + 3 : fv + 6]  # body frame
        self.t = 0.0
        self.overruns = 0
        self.load = 0.0  # the share of a tick spent working (smoothed)
        self._u = np.zeros(sc.robot.nx)
        self._events_seen = 0
        self._setpoint: setpoints.Setpoint | None = None  # the last one accepted
        mav_type = self.m.MAV_TYPE_OCTOROTOR if self.sim.rotors == 8 else self.m.MAV_TYPE_QUADROTOR
        self._meas = self._measurement(self.sim.true_state())
        self.telemetry = Telemetry(
            self.conn, self.m, self.tick, state_hz, mav_type, self._meas.position
        )
        self.texts = StatusTexts(self.conn)
        self.commands = Commands(self)
        self.received: Counter[str] = Counter()  # message types (commands by id) read
        self._handlers: dict[str, Callable[[Any], None]] = (
            {
                "SET_POSITION_TARGET_LOCAL_NED": self._on_setpoint,
                "COMMAND_LONG": lambda msg: self.commands.handle(from_long(msg)),
                "COMMAND_INT": lambda msg: self.commands.handle(from_int(msg)),
                "SET_MODE": self._on_set_mode,
                "PING": self._on_ping,
                "TIMESYNC": self._on_timesync,
                "REQUEST_DATA_STREAM": lambda msg: self.say(
                    "REQUEST_DATA_STREAM unsupported: use SET_MESSAGE_INTERVAL", SEVERITY_WARNING
                ),
            }
            | {kind: self._on_unflown for kind in UNFLOWN}
            | self.params.handlers()
        )

    def run(self, sink: Callable[[Row], None], max_time_s: float | None = None) -> None:
        """Fly in real time until ``max_time_s`` [s] (or a signal: ``RunInterrupted``)."""
        start = time.monotonic()
        k = 0
        while max_time_s is None or self.t < max_time_s:
            raise_if_interrupted()
            began = time.monotonic()
            self._receive()
            self._step()
            k += 1
            if k % self.every["state"] == 0:  # a measurement (the physics' noise)
                self._meas = self._measurement(self.sim.state())
            self.telemetry.stream(k, self._meas, self._status())
            if k % self.every["truth"] == 0:
                sink(self._truth_row())
            self._announce()
            now = time.monotonic()
            self.load += LOAD_SMOOTHING * ((now - began) / self.tick - self.load)
            left = start + k * self.tick - now
            if left > 0:
                time.sleep(left)
            elif left < -0.1:  # fell behind: do not race to catch up
                self.overruns += 1
                start -= left

    def _step(self) -> None:
        if self._setpoint is not None and self.vehicle.mode == "offboard":
            self.vehicle.steer(*self._flown(self._setpoint))  # its loops, at every tick
        x = self.sim.true_state()
        speed = math.sqrt(sum(v * v for v in self._vel.tolist()))
        u, q0 = self.vehicle.command(self.t, x, speed)
        self._u = u
        if self.vehicle.armed:
            self.sim.advance(u, q0, self.tick)
        self.t += self.tick

    def _receive(self) -> None:
        while (msg := self.conn.recv_msg()) is not None:
            kind = msg.get_type()
            self.received[f"{kind}:{msg.command}" if kind.startswith("COMMAND_") else kind] += 1
            handler = self._handlers.get(kind)
            if handler is None:
                continue  # not for an autopilot (PX4 ignores it too), or not MAVLink
            try:
                handler(msg)
            except (ArithmeticError, ValueError, TypeError, struct.error) as e:
                # a field no check foresaw: the message is refused, the vehicle flies on
                self.say(f"{msg.get_type()} refused: {type(e).__name__}", SEVERITY_CRITICAL)

    def _on_setpoint(self, msg: Any) -> None:
        """A ``SET_POSITION_TARGET_LOCAL_NED``, read as PX4 does (``setpoints``): kept and
        flown from now on, or refused with a STATUSTEXT and ignored (not an offboard
        signal: the last accepted setpoint flies on until the offboard loss timeout)."""
        if msg.target_system not in (0, SYSTEM_ID) or msg.target_component not in (0, 1):
            return  # not for this vehicle (PX4 drops it too)
        extras = self.sim.extras()
        _, _, yaw = self._pose_ned()
        roll, pitch, _ = frames.attitude_enu_to_ned(extras["roll"], extras["pitch"], 0.0)
        sp = setpoints.from_local_ned(msg, (roll, pitch, yaw))
        if isinstance(sp, str):
            severity = self.m.MAV_SEVERITY_WARNING if sp == setpoints.INVALID else None
            self._refuse(sp, severity)
            return
        self._setpoint = sp
        velocity, rate = self._flown(sp)
        self.vehicle.on_setpoint(self.t, velocity, rate, int(msg.time_boot_ms) & 0xFFFFFFFF)

    def _pose_ned(self) -> tuple[setpoints.Vec3, setpoints.Vec3, float]:
        """The vehicle's true position [m], velocity [m/s] and yaw [rad], NED."""
        x, spec = self.sim.true_state(), self.sc.robot
        pose = {"x": 0.0, "y": 0.0, "z": 0.0, "yaw": 0.0} | dict(
            zip(spec.platform.dofs, x[: spec.n_platform].tolist(), strict=True)
        )
        position = frames.enu_to_ned((pose["x"], pose["y"], pose["z"]))
        return position, frames.enu_to_ned(self._vel.tolist()), frames.yaw_enu_to_ned(pose["yaw"])

    def _flown(self, sp: setpoints.Setpoint) -> tuple[tuple[float, float, float], float]:
        """The velocity [m/s, ENU] and yaw rate [rad/s, ENU] that fly ``sp`` now."""
        position, velocity, yaw = self._pose_ned()
        v, rate = setpoints.velocity_and_yaw_rate(sp, position, velocity, yaw, self.tick)
        v, rate = self._limited(v, rate)
        return frames.ned_to_enu(v), frames.yaw_rate_ned_to_enu(rate)

    def _limited(self, v: setpoints.Vec3, rate: float) -> tuple[setpoints.Vec3, float]:
        """Velocity [m/s, NED] and yaw rate [rad/s] within the parameters' limits (PX4
        ``PositionControl.cpp`` L133-137: PX4 lets the position loop's share go first,
        here the horizontal sum is scaled)."""
        p = self.params
        horizontal, limit = math.hypot(v[0], v[1]), p["MPC_XY_VEL_MAX"]
        scale = limit / horizontal if horizontal > limit else 1.0
        down = min(max(v[2], -p["MPC_Z_VEL_MAX_UP"]), p["MPC_Z_VEL_MAX_DN"])
        most = math.radians(p["MC_YAWRATE_MAX"])
        return (scale * v[0], scale * v[1], down), min(max(rate, -most), most)

    def _refuse(self, reason: str, severity: int | None = None) -> None:
        """Say why a message is ignored (critical unless ``severity``)."""
        self.say(reason, SEVERITY_CRITICAL if severity is None else severity)

    def say(self, text: str, severity: int) -> None:
        """A STATUSTEXT (``MAV_SEVERITY``), the same text once a second at most; also an
        event (the SITL's stderr and its summary)."""
        if self.texts.say(self.t, text, severity):
            self.vehicle.events.append(Event(self.t, f"{SAID}{text}"))

    def _on_set_mode(self, msg: Any) -> None:
        """The legacy ``SET_MODE``: PX4 turns it into ``DO_SET_MODE`` (``mavlink_receiver.
        cpp`` L924-950); answered with that command's ACK."""
        if int(msg.target_system) != self.system_id:
            return
        custom = int(msg.custom_mode)
        main, sub = (custom >> 16) & 0xFF, (custom >> 24) & 0xFF
        result = self.commands.set_mode(float(msg.base_mode), float(main), float(sub))
        sender = (msg.get_srcSystem(), msg.get_srcComponent())
        self.conn.mav.command_ack_send(MAV_CMD_DO_SET_MODE, result, 0, 0, *sender)

    def _on_ping(self, msg: Any) -> None:
        """A PING request (target 0/0) echoed to its sender (PX4 L1723-1734)."""
        if msg.target_system == 0 and msg.target_component == 0:
            sender = (msg.get_srcSystem(), msg.get_srcComponent())
            self.conn.mav.ping_send(int(msg.time_usec), int(msg.seq), *sender)

    def _on_timesync(self, msg: Any) -> None:
        """A TIMESYNC request (tc1 = 0): tc1 our clock [ns], ts1 echoed
        (``mavlink_timesync.cpp`` L62-73)."""
        if int(msg.tc1) == 0:
            self.conn.mav.timesync_send(time.monotonic_ns(), int(msg.ts1))

    def _on_unflown(self, msg: Any) -> None:
        """A setpoint kind PX4 flies and this SITL cannot: refused (no offboard signal)."""
        self._refuse(f"{msg.get_type()} unsupported")

    def _measurement(self, x: np.ndarray) -> Measurement:
        """What the estimator reports of the NMPC state ``x`` (NED, FRD)."""
        spec = self.sc.robot
        pose = {"x": 0.0, "y": 0.0, "z": 0.0, "yaw": 0.0} | dict(
            zip(spec.platform.dofs, x[: spec.n_platform].tolist(), strict=True)
        )
        extras = self.sim.extras()
        wrench = self.sim.measured_wrench()
        return Measurement(
            t=self.t,
            position=frames.enu_to_ned((pose["x"], pose["y"], pose["z"])),
            velocity=frames.enu_to_ned(self._vel.tolist()),
            attitude=frames.attitude_enu_to_ned(extras["roll"], extras["pitch"], pose["yaw"]),
            rates=frames.flu_to_frd(self._omega.tolist()),
            joints=tuple(x[spec.n_platform :].tolist()),
            wrench=None if wrench is None else tuple(float(v) for v in wrench),
        )

    def _status(self) -> Status:
        return Status(self.vehicle.armed, self.vehicle.mode, self.load)

    def send_now(self, name: str) -> None:
        """Send message ``name`` now, from the last measurement (``REQUEST_MESSAGE``)."""
        self.telemetry.send(name, self._meas, self._status())

    def _announce(self) -> None:
        """Say the vehicle's new events (stderr, STATUSTEXT) and send a heartbeat at once
        on a change."""
        events = self.vehicle.events
        if len(events) == self._events_seen:
            return
        new = events[self._events_seen :]
        self._events_seen = len(events)
        for e in new:
            print(f"sitl: t={e.t:.2f} s: {e.text.removeprefix(SAID)}", file=sys.stderr, flush=True)
            if not e.text.startswith(SAID):  # the vehicle's own: say it too
                self.texts.say(self.t, e.text, _severity(e.text))
        if any(not e.text.startswith(SAID) for e in new):
            self.send_now("HEARTBEAT")

    def _truth_row(self) -> Row:
        v = self.vehicle
        x = self.sim.true_state()
        cmd = Command(self._u, x[None, :], np.zeros((1, len(x))), {}, v.mode, "", 0, math.nan)
        row = self.maker.row(self.t, x, self.sim.ee_position(), cmd)
        t_mission = v.mission_t(self.t)
        ref = (
            self.sc.reference.position(t_mission)
            if math.isfinite(t_mission) and t_mission <= self.sc.duration
            else (math.nan,) * 3
        )
        row.update(ref_x=ref[0], ref_y=ref[1], ref_z=ref[2])
        row.update(self.sim.extras())
        vel = self._vel.tolist()
        row.update(
            wall_time=time.time(),
            t_mission=t_mission,
            vx=vel[0],
            vy=vel[1],
            vz=vel[2],
            speed=math.sqrt(sum(c * c for c in vel)),
            armed=float(v.armed),
        )
        return row

    def columns(self) -> list[str]:
        """The truth log's columns: a physics run log's plus ``TRUTH_COLUMNS``."""
        cols = log_columns(self.sc, self.sim)
        return cols + [c for c in TRUTH_COLUMNS if c not in cols]

    def close(self) -> None:
        """Release the link."""
        self.conn.close()


class ParamVehicle(Vehicle):
    """``Vehicle`` whose offboard-loss timeout is the parameter ``COM_OF_LOSS_T``."""

    def __init__(self, spec: RobotSpec, x0: np.ndarray, params: Parameters) -> None:
        super().__init__(spec, x0)
        self.params = params

    def loss_s(self) -> float:
        """The offboard-loss timeout now [s]."""
        return self.params["COM_OF_LOSS_T"]


def _severity(event: str) -> int:
    """The STATUSTEXT severity of a vehicle event: failsafes and refusals as PX4 says
    them (critical), the rest informational."""
    if event.startswith("failsafe"):
        return SEVERITY_WARNING
    return SEVERITY_CRITICAL if "refused" in event else SEVERITY_INFO
