"""The MuJoCo robot and scenes: agreement with the core's kinematics and hand model, mass
properties, couplings, sensors, generated assets, and a menagerie-style smoke test."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from rrg_models import wam
from rrg_models.config import HAND, PHYSICS, WAM_LINKS
from rrg_models.description.mjcf_robot import (
    ARM_JOINTS,
    PAD_TOUCH,
    PALM_BODY,
    ROBOT_FILE,
    TIP_FORCE,
    TIP_TORQUE,
    robot_xml,
)
from rrg_models.hand import body_poses
from rrg_models.hand_sensing import TIP_RADIUS, TIP_Z0, TIP_Z1, contact_from_wrench
from rrg_models.objects import PAPER_OBJECTS
from rrg_sim.physics.scene import ASSETS_DIR, asset_files, build_model


@pytest.fixture(scope="module")
def robot():
    model = mujoco.MjModel.from_xml_string(robot_xml())
    return model, mujoco.MjData(model)


def _qadr(model, joint: str) -> int:
    return int(model.jnt_qposadr[model.joint(joint).id])


def test_hand_site_pose_matches_wam_fk(robot):
    model, data = robot
    rng = np.random.default_rng(0)
    palm = model.body(PALM_BODY).id
    adr = [_qadr(model, j) for j in ARM_JOINTS]
    for q in rng.uniform(wam.LOWER, wam.UPPER, size=(50, 7)):
        data.qpos[adr] = q
        mujoco.mj_kinematics(model, data)
        T = wam.fk(q)
        assert np.linalg.norm(data.xpos[palm] - T[:3, 3]) < 1e-3
        np.testing.assert_allclose(data.xmat[palm].reshape(3, 3), T[:3, :3], atol=1e-6)


def test_hand_bodies_match_hand_model(robot):
    """Finger link poses in the hand frame equal rrg_models.hand's at a random spread/closure."""
    model, data = robot
    mujoco.mj_resetData(model, data)
    spread, prox = 0.7, np.array([0.4, 0.9, 1.3])
    data.qpos[_qadr(model, "bh/f1_spread")] = data.qpos[_qadr(model, "bh/f2_spread")] = spread
    for i in range(3):
        data.qpos[_qadr(model, f"bh/f{i + 1}_prox")] = prox[i]
        data.qpos[_qadr(model, f"bh/f{i + 1}_dist")] = HAND.distal_coupling * prox[i]
    mujoco.mj_kinematics(model, data)
    palm = model.body(PALM_BODY).id
    R0, p0 = data.xmat[palm].reshape(3, 3), data.xpos[palm]
    for name, T in body_poses(spread, prox).items():
        b = model.body(f"bh/{name}").id
        np.testing.assert_allclose(R0.T @ (data.xpos[b] - p0), T[:3, 3], atol=1e-9)


def test_arm_mass_is_barretts(robot):
    model, _ = robot
    arm = sum(model.body_mass[model.body(f"wam/link{i}").id] for i in range(1, 8))
    assert arm == pytest.approx(sum(link.mass for link in WAM_LINKS))
    hand = sum(
        model.body_mass[b] for b in range(model.nbody) if model.body(b).name.startswith("bh/")
    )
    assert 1.0 < hand < 1.3  # BH8-282: 1.18 kg


def test_gravity_compensated_arm_holds_home(robot):
    model, data = robot
    mujoco.mj_resetData(model, data)
    adr = [_qadr(model, j) for j in ARM_JOINTS]
    data.qpos[adr] = wam.HOME_Q
    data.ctrl[:7] = wam.HOME_Q
    mujoco.mj_step(model, data, nstep=500)
    np.testing.assert_allclose(data.qpos[adr], wam.HOME_Q, atol=2e-3)
    assert np.linalg.norm(wam.fk(data.qpos[adr])[:3, 3] - wam.fk(wam.HOME_Q)[:3, 3]) < 1e-3


def test_spread_and_distal_couplings(robot):
    model, data = robot
    mujoco.mj_resetData(model, data)
    adr = [_qadr(model, j) for j in ARM_JOINTS]
    data.qpos[adr] = data.ctrl[:7] = wam.HOME_Q
    data.ctrl[7] = 1.0  # spread
    data.ctrl[8:11] = [0.5, 1.0, 1.5]
    mujoco.mj_step(model, data, nstep=750)
    q = lambda j: data.qpos[_qadr(model, j)]
    assert q("bh/f1_spread") == pytest.approx(1.0, abs=0.02)
    assert q("bh/f2_spread") == pytest.approx(q("bh/f1_spread"), abs=2e-3)
    for i, target in enumerate((0.5, 1.0, 1.5), start=1):
        assert q(f"bh/f{i}_prox") == pytest.approx(target, abs=0.03)
        assert q(f"bh/f{i}_dist") == pytest.approx(
            HAND.distal_coupling * q(f"bh/f{i}_prox"), abs=5e-3
        )


def test_sensors_are_named_and_sized(robot):
    model, _ = robot
    assert all(model.sensor(n).dim[0] == 1 for n in PAD_TOUCH)
    assert all(model.sensor(n).dim[0] == 3 for n in TIP_FORCE + TIP_TORQUE)
    assert len(PAD_TOUCH) == 7


@pytest.mark.parametrize(
    "point, normal",
    [
        ((TIP_RADIUS, 0.0, (TIP_Z0 + TIP_Z1) / 2), (-1.0, 0.0, 0.0)),  # side of the cylinder
        ((0.0, -TIP_RADIUS, TIP_Z0 + 0.001), (0.0, 1.0, 0.0)),
        ((0.0, 0.0, TIP_Z1 + TIP_RADIUS), (0.0, 0.0, -1.0)),  # apex of the cap
        (
            (TIP_RADIUS * np.sqrt(0.5), 0.0, TIP_Z1 + TIP_RADIUS * np.sqrt(0.5)),
            (-np.sqrt(0.5), 0.0, -np.sqrt(0.5)),
        ),
    ],
)
def test_nano17_contact_point_from_wrench(point, normal):
    """A force pressing into the tip at a surface point is located there from (F, p × F)."""
    rng = np.random.default_rng(1)
    point, normal = np.asarray(point), np.asarray(normal)
    for _ in range(5):
        tangent = np.cross(normal, rng.normal(size=3))
        force = 3.0 * normal + 0.5 * tangent  # inside the friction cone
        p, n = contact_from_wrench(force, np.cross(point, force))
        np.testing.assert_allclose(p, point, atol=1e-9)
        np.testing.assert_allclose(n, normal, atol=1e-9)


#: Largest distance [m] of a committed hull vertex outside the hull built here, and back. The
#: object meshes' vertices carry the last bits of numpy's trigonometry, which differ between
#: CPUs (measured: -6.9e-18 where another machine gives 0), and Qhull then keeps another of
#: two coplanar points; the solid is the same.
HULL_TOLERANCE_M = 1e-9


def _outside(points: np.ndarray, hull_points: np.ndarray) -> float:
    """Largest distance [m] of ``points`` outside the convex hull of ``hull_points``."""
    from scipy.spatial import ConvexHull

    eq = ConvexHull(hull_points).equations  # n·x + d ≤ 0 inside, n unit
    return float(np.max(points @ eq[:, :3].T + eq[:, 3]))


def test_generated_assets_are_up_to_date():
    """rrg_sim/assets/ holds what the code builds (regenerate: python -m rrg_sim.physics.scene):
    the same MJCF text, but for the object's hull, which must be the same solid."""
    import xml.etree.ElementTree as ET

    for name, text in asset_files().items():
        committed, built = ET.fromstring((ASSETS_DIR / name).read_text()), ET.fromstring(text)
        hulls = []
        for root in (committed, built):
            mesh = root.find("asset/mesh[@name='object_hull']")
            if mesh is not None:
                hulls.append(np.array(mesh.attrib.pop("vertex").split(), float).reshape(-1, 3))
        assert ET.tostring(committed) == ET.tostring(built), f"{name} is stale"
        if hulls:
            a, b = hulls
            assert _outside(a, b) <= HULL_TOLERANCE_M, f"{name}: the hull is stale"
            assert _outside(b, a) <= HULL_TOLERANCE_M, f"{name}: the hull is stale"


def _smoke(model: mujoco.MjModel, seed: int) -> mujoco.MjData:
    """1 s under random controls (menagerie's model test): no warnings, finite state."""
    data = mujoco.MjData(model)
    rng = np.random.default_rng(seed)
    arm = [_qadr(model, j) for j in ARM_JOINTS]
    data.qpos[arm] = wam.HOME_Q
    mujoco.mj_forward(model, data)
    low = np.where(model.actuator_ctrllimited, model.actuator_ctrlrange[:, 0], -np.inf)
    high = np.where(model.actuator_ctrllimited, model.actuator_ctrlrange[:, 1], np.inf)
    low[:7], high[:7] = (
        wam.HOME_Q - 0.3,
        wam.HOME_Q + 0.3,
    )  # arm servos: around home, above the table
    for _ in range(10):
        data.ctrl[:] = rng.uniform(low, high)
        mujoco.mj_step(model, data, nstep=int(0.1 / PHYSICS.timestep))
    assert all(w.number == 0 for w in data.warning), [w.number for w in data.warning]
    assert np.isfinite(data.qpos).all() and np.isfinite(data.qvel).all()
    return data


def test_robot_alone_smoke():
    _smoke(mujoco.MjModel.from_xml_string(robot_xml()), seed=0)


@pytest.mark.parametrize("name", PAPER_OBJECTS)
def test_object_scene_smoke(name):
    model = build_model(name)
    assert model.opt.timestep == PHYSICS.timestep
    data = _smoke(model, seed=1)
    assert data.time == pytest.approx(1.0)


def test_robot_file_is_included_by_scene():
    assert f'<include file="{ROBOT_FILE}" />' in asset_files()["scene.xml"]


def test_worlds_by_object_makes_each_world_once_and_keeps_its_noise_going():
    """A switch back to an object returns its world (no new MuJoCo model or data), placed anew
    by reset, and the world's noise continues rather than restarting from the seed."""
    from rrg_sim.physics.world import WorldsByObject

    worlds = WorldsByObject(seed=3, sensor_noise=1.0)
    box = worlds("box")
    first = box.rng.random()
    can = worlds("can")
    assert can is not box and can.obj.name == "can" and box.obj.name == "box"
    again = worlds("box")
    assert again is box and again.model is box.model and again.data is box.data
    assert again.rng.random() != first  # the stream went on
    again.reset(np.array([0.6, 0.02, 0.1]))
    assert np.allclose(again.true_object_pose(), [0.6, 0.02, 0.1], atol=0.01)
