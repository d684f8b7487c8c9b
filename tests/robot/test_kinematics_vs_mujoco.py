"""Our CasADi kinematics against MuJoCo's, on the robot exported as URDF.

The export with ``platform_joints=True`` gives one MuJoCo joint per NMPC state entry, so
``qpos`` is the NMPC state and MuJoCo's forward kinematics and Jacobians are an
independent implementation of the same quantities.
"""

from pathlib import Path

import mujoco
import numpy as np
import pytest

from aeromanip.robot.kinematics import Kinematics
from aeromanip.robot.loader import load_robot
from aeromanip.robot.urdf_export import robot_to_urdf

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "robots" / "urdf-arm.toml"
ROBOTS = ["planar-2dof", "x8-3dof", str(EXAMPLE)]


def random_states(spec, n, seed):
    rng = np.random.default_rng(seed)
    lo = np.array([-3.0] * spec.n_platform + [max(j.lower, -np.pi) for j in spec.joints])
    hi = np.array([3.0] * spec.n_platform + [min(j.upper, np.pi) for j in spec.joints])
    return rng.uniform(lo, hi, size=(n, spec.nx))


@pytest.fixture(scope="module", params=ROBOTS, ids=["planar-2dof", "x8-3dof", "urdf-arm"])
def pair(request):
    spec = load_robot(request.param)
    model = mujoco.MjModel.from_xml_string(
        robot_to_urdf(spec, platform_joints=True, mujoco_compiler=True)
    )
    assert model.nq == model.nv == spec.nx
    return spec, Kinematics(spec), model


def body(model, name):
    return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)


def test_forward_kinematics_cog_and_jacobian_match_mujoco(pair):
    spec, kin, model = pair
    data = mujoco.MjData(model)
    ee, base = body(model, spec.ee_link), body(model, spec.base_link)
    links = [body(model, j.link_name) for j in spec.joints]
    hinge = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, j.name) for j in spec.joints]
    masses = np.array([j.link.mass for j in spec.joints])
    for x in random_states(spec, 100, seed=11):
        data.qpos[:] = x
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        # end-effector pose
        np.testing.assert_allclose(np.asarray(kin.ee_position(x)).ravel(), data.xpos[ee], atol=1e-9)
        np.testing.assert_allclose(
            np.asarray(kin.ee_rotation(x)), data.xmat[ee].reshape(3, 3), atol=1e-9
        )
        # every joint origin
        np.testing.assert_allclose(
            np.asarray(kin.joint_positions(x)).T, data.xanchor[hinge], atol=1e-9
        )
        # arm CoG in the body frame: mass-weighted link CoMs, moved into the base frame
        com_world = masses @ data.xipos[links] / masses.sum()
        R_wb = data.xmat[base].reshape(3, 3)
        cog_body = R_wb.T @ (com_world - data.xpos[base])
        np.testing.assert_allclose(np.asarray(kin.cog_body(x)).ravel(), cog_body, atol=1e-9)
        # EE Jacobian w.r.t. the state (qvel = dx/dt for slide/hinge joints)
        jacp = np.zeros((3, model.nv))
        mujoco.mj_jac(model, data, jacp, None, data.xpos[ee], ee)
        np.testing.assert_allclose(np.asarray(kin.ee_jacobian(x)), jacp, atol=1e-9)


def test_clearance_matches_mujoco_depth_below_base(pair):
    spec, kin, model = pair
    data = mujoco.MjData(model)
    base = body(model, spec.base_link)
    hinge = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, j.name) for j in spec.joints]
    ee = body(model, spec.ee_link)
    f = kin.clearance()
    for x in random_states(spec, 30, seed=12):
        data.qpos[:] = x
        mujoco.mj_kinematics(model, data)
        R_wb = data.xmat[base].reshape(3, 3)
        pts = np.vstack([data.xanchor[hinge[1:]], data.xpos[ee]])
        depth = -(pts - data.xpos[base]) @ R_wb[:, 2]
        np.testing.assert_allclose(np.asarray(f(x)).ravel(), depth, atol=1e-9)
