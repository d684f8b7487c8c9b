"""The software-in-the-loop autopilot: the scenario's robot in the MuJoCo physics (its
PX4-like inner loop taking velocity + yaw-rate setpoints, ``physics.setpoint =
"velocity"``), flown in real time behind the MAVLink subset of ``protocol``.

Every ``tick`` (the physics' outer-loop period, 10 ms by default) it reads what arrived
(setpoints, ``COMMAND_LONG``: arm, mode, actuators; each answered by a ``COMMAND_ACK``),
reads ``SET_POSITION_TARGET_LOCAL_NED`` as PX4 does (``setpoints``: every mask and frame
PX4 takes; a refused one is a STATUSTEXT with PX4's words) and flies the last accepted
one through its position and yaw loops,
lets ``Vehicle`` decide what to fly and advances the physics by the tick. It sends
``LOCAL_POSITION_NED`` + ``ATTITUDE`` + the joints (``NAMED_VALUE_FLOAT``) at ``state_hz``
(with the physics' measurement noise: ``[physics] noise``), a ``HEARTBEAT`` at
``HEARTBEAT_HZ`` and at every mode change, and hands a truth row (the contract columns
from the true state plus roll, pitch, motors, velocity, mode) to its sink at ``TRUTH_HZ``.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from aeromanip.experiment.closed_loop import RowMaker, log_columns
from aeromanip.experiment.scenario import Scenario
from aeromanip.interrupts import raise_if_interrupted
from aeromanip.mavlink import frames, setpoints
from aeromanip.mavlink.arm import MAV_CMD_DO_SET_ACTUATOR, actuator_to_joint, joint_name
from aeromanip.mavlink.protocol import (
    MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
    MAV_MODE_FLAG_SAFETY_ARMED,
    MODES,
    custom_mode,
    load_mavutil,
    open_link,
)
from aeromanip.mavlink.vehicle import DENIED, Event, Vehicle
from aeromanip.nmpc.controller import Command
from aeromanip.sim.mjcf import FREE_JOINT
from aeromanip.sim.physics import PhysicsSimulator

STATE_HZ = 50.0  # [Hz] state messages
HEARTBEAT_HZ = 2.0  # [Hz]
TRUTH_HZ = 20.0  # [Hz] truth-log rows
MAV_CMD_COMPONENT_ARM_DISARM = 400
MAV_CMD_DO_SET_MODE = 176
SYSTEM_ID = 1  # this vehicle's MAVLink system id (component 1: the autopilot)
REFUSAL_EVERY_S = 1.0  # [s] a refusal's reason is said at most this often
TRUTH_COLUMNS = ("wall_time", "t_mission", "vx", "vy", "vz", "speed", "armed")

Row = dict[str, Any]


class SitlAutopilot:
    """The SITL vehicle of scenario ``sc`` on link ``url`` (module docstring)."""

    def __init__(self, sc: Scenario, url: str, state_hz: float = STATE_HZ) -> None:
        self.conn = open_link(url, SYSTEM_ID, 1)  # first: a link that cannot open costs nothing
        self.m = load_mavutil().mavlink
        self.sc = sc
        # PX4-like: velocity + yaw-rate set-points; the arm's targets are angles (ramps)
        options = {**sc.physics, "setpoint": "velocity", "joint_setpoint": "ramp"}
        self.sim = PhysicsSimulator.from_options(sc.robot, options)
        self.sim.reset(sc.x0)
        self.tick = 1.0 / self.sim.outer_rate_hz
        self.vehicle = Vehicle(sc.robot, sc.x0)
        self.maker = RowMaker(sc)
        self.every = {
            "state": max(1, round(1.0 / (state_hz * self.tick))),
            "heartbeat": max(1, round(1.0 / (HEARTBEAT_HZ * self.tick))),
            "truth": max(1, round(1.0 / (TRUTH_HZ * self.tick))),
        }
        fv = self.sim.model.jnt_dofadr[self.sim.model.joint(FREE_JOINT).id]
        self._vel = self.sim.data.qvel[fv : fv + 3]  # world frame
        self._omega = self.sim.data.qvel[fv + 3 : fv + 6]  # body frame
        self.t = 0.0
        self.overruns = 0
        self._u = np.zeros(sc.robot.nx)
        self._events_seen = 0
        self._setpoint: setpoints.Setpoint | None = None  # the last one accepted
        self._refused: dict[str, float] = {}  # reason -> when it was last said [s]

    def run(self, sink: Callable[[Row], None], max_time_s: float | None = None) -> None:
        """Fly in real time until ``max_time_s`` [s] (or a signal: ``RunInterrupted``)."""
        start = time.monotonic()
        k = 0
        while max_time_s is None or self.t < max_time_s:
            raise_if_interrupted()
            self._receive()
            self._step()
            k += 1
            if k % self.every["state"] == 0:
                self._send_state()
            if k % self.every["heartbeat"] == 0:
                self._heartbeat()
            if k % self.every["truth"] == 0:
                sink(self._truth_row())
            self._announce()
            left = start + k * self.tick - time.monotonic()
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
            if kind == "SET_POSITION_TARGET_LOCAL_NED":
                self._on_setpoint(msg)
            elif kind == "COMMAND_LONG":
                self._on_command(msg)

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
        return frames.ned_to_enu(v), frames.yaw_rate_ned_to_enu(rate)

    def _refuse(self, reason: str, severity: int | None = None) -> None:
        """Say why a message is ignored: a STATUSTEXT (critical unless ``severity``; and
        the SITL's stderr), once a second per reason at most."""
        if self.t - self._refused.get(reason, -math.inf) < REFUSAL_EVERY_S:
            return
        self._refused[reason] = self.t
        level = self.m.MAV_SEVERITY_CRITICAL if severity is None else severity
        self.conn.mav.statustext_send(level, reason.encode()[:50])
        self.vehicle.events.append(Event(self.t, f"refused: {reason}"))

    def _on_command(self, msg: Any) -> None:
        v, x, cmd = self.vehicle, self.sim.true_state(), int(msg.command)
        result = self.m.MAV_RESULT_UNSUPPORTED
        if cmd == MAV_CMD_COMPONENT_ARM_DISARM:
            result = v.arm(self.t, msg.param1 > 0.5, x)
        elif cmd == MAV_CMD_DO_SET_MODE:
            result = DENIED
            if int(msg.param1) & MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
                wanted = (int(msg.param2), int(msg.param3))
                for name, (main, sub) in MODES.items():
                    if wanted[0] == main and (sub == 0 or wanted[1] == sub):
                        result = v.set_mode(self.t, name, x)
        elif cmd == MAV_CMD_DO_SET_ACTUATOR:
            result = self._on_actuators(msg)
        self.conn.mav.command_ack_send(cmd, result)

    def _on_actuators(self, msg: Any) -> int:
        """Joint targets from a ``DO_SET_ACTUATOR`` (``arm.py``); NaN keeps a joint's."""
        base = 6 * int(msg.param7)
        q = self.vehicle.q_target.copy()
        params = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6)
        for j, value in enumerate(params):
            i = base + j
            if i < len(q) and math.isfinite(value):
                joint = self.sc.robot.joints[i]
                q[i] = actuator_to_joint(value, joint.lower, joint.upper)
        self.vehicle.on_joints(self.t, q)
        return self.m.MAV_RESULT_ACCEPTED

    def _send_state(self) -> None:
        ms = int(1e3 * self.t) & 0xFFFFFFFF
        x = self.sim.state()  # with the measurement noise
        spec = self.sc.robot
        pose = {"x": 0.0, "y": 0.0, "z": 0.0, "yaw": 0.0} | dict(
            zip(spec.platform.dofs, x[: spec.n_platform].tolist(), strict=True)
        )
        north, east, down = frames.enu_to_ned((pose["x"], pose["y"], pose["z"]))
        vn, ve, vd = frames.enu_to_ned(self._vel.tolist())
        self.conn.mav.local_position_ned_send(ms, north, east, down, vn, ve, vd)
        extras = self.sim.extras()
        roll, pitch, yaw = frames.attitude_enu_to_ned(extras["roll"], extras["pitch"], pose["yaw"])
        p, q, r = frames.flu_to_frd(self._omega.tolist())
        self.conn.mav.attitude_send(ms, roll, pitch, yaw, p, q, r)
        for i, value in enumerate(x[spec.n_platform :].tolist()):
            self.conn.mav.named_value_float_send(ms, joint_name(i).encode(), value)

    def _heartbeat(self) -> None:
        v = self.vehicle
        mav_type = self.m.MAV_TYPE_OCTOROTOR if self.sim.rotors == 8 else self.m.MAV_TYPE_QUADROTOR
        base = MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (MAV_MODE_FLAG_SAFETY_ARMED if v.armed else 0)
        status = self.m.MAV_STATE_ACTIVE if v.armed else self.m.MAV_STATE_STANDBY
        self.conn.mav.heartbeat_send(
            mav_type, self.m.MAV_AUTOPILOT_PX4, base, custom_mode(v.mode), status
        )

    def _announce(self) -> None:
        """Print the vehicle's new events (and send a heartbeat at once on a change)."""
        events = self.vehicle.events
        if len(events) == self._events_seen:
            return
        for e in events[self._events_seen :]:
            print(f"sitl: t={e.t:.2f} s: {e.text}", file=sys.stderr, flush=True)
        self._events_seen = len(events)
        self._heartbeat()

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
