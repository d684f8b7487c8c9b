"""UAM kinematics as CasADi Functions of the NMPC state ``x = [platform DoFs, q1..qn]``.

The platform pose is ``world_T_body = Trans(x, y, z) Rz(yaw)`` (roll and pitch are left to
the inner loop, paper Sec. III-C); inactive DoFs take their fixed values. Every Function
takes the state as a column vector and can be called numerically (``DM``/NumPy) or on
symbols (it is then inlined into the caller's expression graph).
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import cached_property

import casadi as ca

from aeromanip.errors import ConfigError
from aeromanip.robot.spec import PLATFORM_DOFS, RobotSpec
from aeromanip.robot.spectral import KINK, condition_number

AXES = {"x": 0, "y": 1, "z": 2}


def rot_x(a: ca.SX | float) -> ca.SX:
    """Rotation about x by ``a`` [rad]."""
    c, s = ca.cos(a), ca.sin(a)
    return ca.vertcat(ca.horzcat(1, 0, 0), ca.horzcat(0, c, -s), ca.horzcat(0, s, c))


def rot_y(a: ca.SX | float) -> ca.SX:
    """Rotation about y by ``a`` [rad]."""
    c, s = ca.cos(a), ca.sin(a)
    return ca.vertcat(ca.horzcat(c, 0, s), ca.horzcat(0, 1, 0), ca.horzcat(-s, 0, c))


def rot_z(a: ca.SX | float) -> ca.SX:
    """Rotation about z by ``a`` [rad]."""
    c, s = ca.cos(a), ca.sin(a)
    return ca.vertcat(ca.horzcat(c, -s, 0), ca.horzcat(s, c, 0), ca.horzcat(0, 0, 1))


def rot_rpy(rpy: Sequence[float]) -> ca.SX:
    """URDF fixed-axis roll-pitch-yaw: ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    return rot_z(rpy[2]) @ rot_y(rpy[1]) @ rot_x(rpy[0])


def rot_axis(axis: Sequence[float], a: ca.SX) -> ca.SX:
    """Rotation by ``a`` [rad] about the unit ``axis`` (Rodrigues)."""
    k = ca.DM(list(axis))
    K = ca.skew(k)
    return ca.DM.eye(3) + ca.sin(a) * K + (1 - ca.cos(a)) * (K @ K)


class Kinematics:
    """Forward kinematics, arm CoG, Jacobians, manipulability and clearance of a ``RobotSpec``.

    Attributes (``casadi.Function``, input ``x`` of size ``spec.nx``):
        ee_position: end-effector position, world frame [m] (3x1).
        ee_rotation: end-effector orientation, world frame (3x3).
        ee_position_body: end-effector position, body frame [m] (3x1).
        joint_positions: world position of every joint origin [m] (3 x n_joints).
        joint_positions_body: the same in the body frame (3 x n_joints).
        cog_body: arm CoG in the body frame [m] (3x1), paper eq. 10.
        cog_jacobian: d cog_body / d q (3 x n_joints), paper eq. 12.
        ee_jacobian: d ee_position / d x (3 x nx), world frame.
    """

    def __init__(self, spec: RobotSpec) -> None:
        self.spec = spec
        self.nx = spec.nx
        self.n_platform = spec.n_platform
        self.n_joints = spec.n_joints
        x = ca.SX.sym("x", self.nx)
        self._x = x
        pose = {}
        for dof in PLATFORM_DOFS:
            if dof in spec.platform.dofs:
                pose[dof] = x[spec.platform.dofs.index(dof)]
            else:
                pose[dof] = float(spec.platform.fixed.get(dof, 0.0))
        q = x[self.n_platform :]
        self._q = q
        self._R_wb = rot_z(pose["yaw"])
        self._p_wb = ca.vertcat(pose["x"], pose["y"], pose["z"])

        R = rot_rpy(spec.mount_rpy)
        p = ca.DM(list(spec.mount_xyz))
        origins, coms = [], []
        for i, j in enumerate(spec.joints):
            p = p + R @ ca.DM(list(j.xyz))
            R = R @ rot_rpy(j.rpy)
            origins.append(p)
            R = R @ rot_axis(j.axis, q[i])
            coms.append(p + R @ ca.DM(list(j.link.com)))
        self._ee_body = p + R @ ca.DM(list(spec.ee_xyz))
        self._R_ee_body = R @ rot_rpy(spec.ee_rpy)
        self._origins_body = ca.horzcat(*origins)
        masses = [j.link.mass for j in spec.joints]
        self._cog_body = sum((m * c for m, c in zip(masses, coms, strict=True)), ca.DM.zeros(3))
        self._cog_body = self._cog_body / sum(masses)

        ee_world = self._to_world(self._ee_body)
        self.ee_position = ca.Function("ee_position", [x], [ee_world], ["x"], ["p"])
        self.ee_rotation = ca.Function(
            "ee_rotation", [x], [self._R_wb @ self._R_ee_body], ["x"], ["R"]
        )
        self.ee_position_body = ca.Function("ee_position_body", [x], [self._ee_body], ["x"], ["p"])
        self.joint_positions_body = ca.Function(
            "joint_positions_body", [x], [self._origins_body], ["x"], ["P"]
        )
        self.joint_positions = ca.Function(
            "joint_positions", [x], [self._to_world(self._origins_body)], ["x"], ["P"]
        )
        self.cog_body = ca.Function("cog_body", [x], [self._cog_body], ["x"], ["c"])
        self.cog_jacobian = ca.Function(
            "cog_jacobian", [x], [ca.jacobian(self._cog_body, q)], ["x"], ["J"]
        )
        self._J_ee = ca.jacobian(ee_world, x)
        self.ee_jacobian = ca.Function("ee_jacobian", [x], [self._J_ee], ["x"], ["J"])

    def _to_world(self, p_body: ca.SX) -> ca.SX:
        return self._R_wb @ p_body + ca.repmat(self._p_wb, 1, p_body.shape[1])

    @staticmethod
    def tracked_rows(tracked: Sequence[str] | str) -> list[int]:
        """Row indices of tracked coordinates, e.g. ``"yz"`` -> ``[1, 2]``."""
        rows = []
        for c in tracked:
            if c not in AXES:
                raise ConfigError(f"tracked: unknown coordinate {c!r} (use x, y, z)")
            rows.append(AXES[c])
        if len(set(rows)) != len(rows) or not rows:
            raise ConfigError(
                f"tracked: coordinates must be distinct and non-empty, got {tracked!r}"
            )
        return rows

    def jeq(self, tracked: Sequence[str] | str = "xyz") -> ca.Function:
        """``J_eq``: rows of the EE position Jacobian for ``tracked``, arm-joint columns."""
        rows = self.tracked_rows(tracked)
        J = self._J_ee[rows, self.n_platform :]
        return ca.Function("jeq", [self._x], [J], ["x"], ["J"])

    def manipulability(self, tracked: Sequence[str] | str = "xyz") -> ca.Function:
        """``D = det(J_eq J_eq^T)`` (paper eq. 14) [m^(2m) for m tracked coordinates]."""
        J = self.jeq(tracked)(self._x)
        self._check_square(J)
        return ca.Function("manipulability", [self._x], [ca.det(J @ J.T)], ["x"], ["D"])

    def condition_number(
        self, tracked: Sequence[str] | str = "xyz", delta: float = 1e-9, kink: float = KINK
    ) -> ca.Function:
        """``rho`` of ``J_eq J_eq^T`` (eq. 16), regularised by ``delta``, ``kink`` (spectral)."""
        J = self.jeq(tracked)(self._x)
        self._check_square(J)
        return ca.Function(
            "condition_number", [self._x], [condition_number(J @ J.T, delta, kink)], ["x"], ["rho"]
        )

    def _check_square(self, J: ca.SX) -> None:
        if J.shape[0] > J.shape[1]:
            raise ConfigError(
                f"tracked: {J.shape[0]} tracked coordinates but only {J.shape[1]} arm joints: "
                "J_eq J_eq^T is always singular; track fewer coordinates"
            )

    def point_names(self) -> list[str]:
        """Names of the arm points usable in clearance: ``joint1..jointN`` and ``ee``."""
        return [f"joint{i + 1}" for i in range(self.n_joints)] + ["ee"]

    def default_clearance_points(self) -> list[str]:
        """Every joint origin after the first, and the end effector (DESIGN.md)."""
        return self.point_names()[1:]

    def clearance(self, points: Sequence[str] | None = None) -> ca.Function:
        """Depth of each point below the base, ``-z_body`` [m] (paper eq. 17)."""
        points = list(self.default_clearance_points() if points is None else points)
        names = self.point_names()
        depths = []
        for name in points:
            if name not in names:
                raise ConfigError(f"clearance.points: unknown point {name!r} (use {names})")
            if name == "ee":
                depths.append(-self._ee_body[2])
            else:
                depths.append(-self._origins_body[2, names.index(name)])
        return ca.Function("clearance", [self._x], [ca.vertcat(*depths)], ["x"], ["d"])

    @cached_property
    def summary(self) -> ca.Function:
        """EE position, arm CoG and both Jacobians in one call (for speed-critical users)."""
        out = [self.ee_position(self._x), self.cog_body(self._x), self._J_ee]
        out.append(self.cog_jacobian(self._x))
        return ca.Function("kinematics", [self._x], out, ["x"], ["ee", "cog", "J_ee", "J_cog"])

    def symbols(self) -> tuple[ca.SX, ca.SX]:
        """The state symbol ``x`` and its joint part ``q`` used to build every Function."""
        return self._x, self._q
