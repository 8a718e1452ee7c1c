"""The robot's URDF against the project's own models: MuJoCo's URDF parser (a parser of its own,
apart from its MJCF one) compiles it, and its forward kinematics must equal rrg_models.wam's and
rrg_models.hand's; its bodies, masses and inertias must equal the MJCF robot's."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import mujoco
import numpy as np
import pytest

from rrg_common.ros.msg_conversions import ARM_JOINT_NAMES, PROXIMAL_JOINT_NAMES, SPREAD_JOINT_NAME
from rrg_models import wam
from rrg_models.description.mjcf_robot import robot_xml
from rrg_models.description.urdf_robot import PALM_LINK, robot_urdf, ros_name
from rrg_models.hand import FINGERS, body_poses, joint_angles

#: MuJoCo's URDF extension: keep the bodies of fixed joints (the palm, the fingertips) apart.
KEEP_FIXED = '<mujoco><compiler fusestatic="false" discardvisual="false"/></mujoco>'


@pytest.fixture(scope="module")
def urdf_model() -> mujoco.MjModel:
    text = robot_urdf()
    head = '<robot name="wam_barretthand">'
    assert text.startswith(head)
    return mujoco.MjModel.from_xml_string(text.replace(head, head + KEEP_FIXED, 1))


def pose(m: mujoco.MjModel, d: mujoco.MjData, body: str) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = d.xmat[m.body(body).id].reshape(3, 3), d.xpos[m.body(body).id]
    return T


def test_the_urdf_palm_is_where_the_wam_model_puts_the_hand(urdf_model):
    """1,000 random arm configurations within the limits: the palm link's pose equals
    rrg_models.wam.fk's hand frame to 1e-9 m and 1e-9 in each rotation entry."""
    m, d = urdf_model, mujoco.MjData(urdf_model)
    arm = [m.joint(n).qposadr[0] for n in ARM_JOINT_NAMES]
    rng = np.random.default_rng(39)
    worst = 0.0
    for q in rng.uniform(wam.LOWER, wam.UPPER, (1000, 7)):
        d.qpos[:] = 0.0
        d.qpos[arm] = q
        mujoco.mj_kinematics(m, d)
        worst = max(worst, float(np.abs(pose(m, d, PALM_LINK) - wam.fk(q)).max()))
    assert worst < 1e-9, worst


def test_the_urdf_fingers_are_where_the_hand_model_puts_them(urdf_model):
    """200 random hand configurations (distal joints at their coupling): every hand link's pose
    in the palm's frame equals rrg_models.hand.body_poses to 1e-9."""
    m, d = urdf_model, mujoco.MjData(urdf_model)
    rng = np.random.default_rng(40)
    for _ in range(200):
        spread, proximal = rng.uniform(0.0, np.pi), rng.uniform(0.0, 2.44, 3)
        d.qpos[:] = 0.0
        for joint, angle in joint_angles(spread, proximal).items():
            d.qpos[m.joint(ros_name(f"bh/{joint}")).qposadr[0]] = angle
        mujoco.mj_kinematics(m, d)
        palm_inv = np.linalg.inv(pose(m, d, PALM_LINK))
        for body, T in body_poses(spread, proximal).items():
            np.testing.assert_allclose(
                palm_inv @ pose(m, d, ros_name(f"bh/{body}")), T, atol=1e-9, err_msg=body
            )


def test_the_urdf_and_the_mjcf_are_one_robot(urdf_model):
    """Same bodies (the URDF's root ``world`` is MuJoCo's world body), masses, inertias and
    joint ranges as the MJCF robot, and every body at the same pose in random configurations
    (the MJCF's numbers carry 9 significant digits)."""
    u, j = urdf_model, mujoco.MjModel.from_xml_string(robot_xml())
    bodies = [j.body(i).name for i in range(1, j.nbody)]
    assert sorted(ros_name(b) for b in bodies) == sorted(u.body(i).name for i in range(1, u.nbody))
    for b in bodies:
        ub, jb = u.body(ros_name(b)), j.body(b)
        np.testing.assert_allclose(ub.mass, jb.mass, rtol=1e-9, err_msg=b)
        np.testing.assert_allclose(np.sort(ub.inertia), np.sort(jb.inertia), rtol=1e-6, err_msg=b)
    joints = [j.joint(i).name for i in range(j.njnt)]
    assert sorted(ros_name(n) for n in joints) == sorted(u.joint(i).name for i in range(u.njnt))
    for n in joints:
        np.testing.assert_allclose(u.joint(ros_name(n)).range, j.joint(n).range, atol=1e-9)
    du, dj = mujoco.MjData(u), mujoco.MjData(j)
    rng = np.random.default_rng(41)
    for _ in range(50):
        for n in joints:
            lo, hi = j.joint(n).range
            dj.qpos[j.joint(n).qposadr[0]] = du.qpos[u.joint(ros_name(n)).qposadr[0]] = rng.uniform(
                lo, hi
            )
        mujoco.mj_kinematics(u, du)
        mujoco.mj_kinematics(j, dj)
        for b in bodies:
            np.testing.assert_allclose(pose(u, du, ros_name(b)), pose(j, dj, b), atol=1e-6)


def test_the_urdf_names_the_joints_as_the_joint_states_do():
    """The joint states the simulator and the bridge publish name URDF joints; finger 2's
    spread and the distal joints mimic their drivers; every movable joint has its limits."""
    robot = ET.fromstring(robot_urdf())
    joints = {j.get("name"): j for j in robot.iter("joint")}
    assert {*ARM_JOINT_NAMES, SPREAD_JOINT_NAME, *PROXIMAL_JOINT_NAMES} <= set(joints)
    mimics = {
        n: j.find("mimic").get("joint") for n, j in joints.items() if j.find("mimic") is not None
    }
    assert mimics == {
        "bh_f2_spread": SPREAD_JOINT_NAME,
        **{f"bh_f{i}_dist": f"bh_f{i}_prox" for i in FINGERS},
    }
    for name, j in joints.items():
        if j.get("type") == "revolute":
            limit = j.find("limit")
            assert float(limit.get("effort")) > 0 and float(limit.get("velocity")) > 0, name
    links = {link.get("name") for link in robot.iter("link")}
    assert {"world", PALM_LINK, "bh_f1_tip", "bh_f2_tip", "bh_f3_tip"} <= links
