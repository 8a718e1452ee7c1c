"""BarrettHand geometry: symmetry, reach, coupling, closing direction, sensor ids, MuJoCo
agreement."""

from __future__ import annotations

import mujoco
import numpy as np

from rrg_models.config import HAND, N_SENSORS
from rrg_models.hand import (
    body_poses,
    finger_link_poses,
    fingertip_points,
    geom_mjcf,
    hand_geoms,
    hand_geoms_world,
    hand_tree,
)

MIRROR_X = np.diag([-1.0, 1.0, 1.0])


def test_fingers_1_and_2_mirror_each_other_across_x():
    rng = np.random.default_rng(0)
    for spread in rng.uniform(*HAND.spread_range, size=5):
        prox = np.full(3, rng.uniform(*HAND.proximal_range))
        poses = finger_link_poses(spread, prox)
        p1, p2 = poses[0, :, :3, 3], poses[1, :, :3, 3]
        np.testing.assert_allclose(p2, p1 @ MIRROR_X, atol=1e-12)


def test_straight_fingertip_reach_along_z():
    tips = fingertip_points(0.0, np.zeros(3))
    reach = HAND.knuckle_z + HAND.proximal_length + HAND.distal_length
    np.testing.assert_allclose(tips[:, 2], reach, atol=1e-12)
    assert abs(reach - (0.0754 + 0.07 + 0.057)) < 1e-12
    np.testing.assert_allclose(
        tips[:, :2], [[0.025, 0.05], [-0.025, 0.05], [0.0, -0.05]], atol=1e-12
    )


def test_spread_pi_over_2_puts_fingers_1_2_on_plus_minus_x():
    tips = fingertip_points(np.pi / 2, np.zeros(3))
    np.testing.assert_allclose(
        tips[0, :2], [HAND.spread_axis_x + HAND.knuckle_radius, 0.0], atol=1e-12
    )
    np.testing.assert_allclose(
        tips[1, :2], [-HAND.spread_axis_x - HAND.knuckle_radius, 0.0], atol=1e-12
    )


def test_distal_is_coupled_to_proximal():
    prox = np.array([0.3, 0.9, 1.5])
    poses = finger_link_poses(0.0, prox)
    for k in range(3):
        R_rel = poses[k, 0, :3, :3].T @ poses[k, 1, :3, :3]
        angle = np.arctan2(R_rel[2, 1], R_rel[1, 1])  # rotation about local x
        assert abs(angle - HAND.distal_coupling * prox[k]) < 1e-12


def test_closing_moves_fingertips_inward():
    """Each tip moves against its finger's outward radial direction (base frame +y) as it closes."""
    for spread in (0.0, np.pi / 3, np.pi / 2):
        outward = body_poses(spread, np.zeros(3))
        out_dirs = np.stack([outward[f"f{i}_base"][:3, 1] for i in (1, 2, 3)])
        radial = [
            np.einsum("fk,fk->f", fingertip_points(spread, np.full(3, a)), out_dirs)
            for a in np.linspace(0.0, 1.2, 7)
        ]
        assert np.all(np.diff(radial, axis=0) < 0)


def test_batched_kinematics_match_single_calls():
    rng = np.random.default_rng(1)
    prox = rng.uniform(0, 2, size=(4, 2, 3))
    batch = finger_link_poses(0.7, prox)
    assert batch.shape == (4, 2, 3, 3, 4, 4)
    np.testing.assert_allclose(batch[2, 1], finger_link_poses(0.7, prox[2, 1]), atol=1e-14)


def test_sensor_ids_cover_all_ten_sensors_once():
    ids = [g.sensor for _, g in hand_geoms() if g.sensor >= 0]
    assert sorted(ids) == list(range(N_SENSORS))


def test_world_geoms_follow_the_hand_pose():
    T = np.eye(4)
    T[:3, 3] = [0.5, 0.1, 0.4]
    local = {g.name: P for g, P in hand_geoms_world(np.eye(4), 0.2, np.full(3, 0.5))}
    for g, P in hand_geoms_world(T, 0.2, np.full(3, 0.5)):
        np.testing.assert_allclose(P, T @ local[g.name], atol=1e-14)


def _articulated_mjcf() -> str:
    """The tree as an MJCF with hinge joints (what the physics simulator builds)."""
    f = lambda v: " ".join(f"{x:.6g}" for x in v)
    children: dict[str | None, list] = {}
    for b in hand_tree():
        children.setdefault(b.parent, []).append(b)

    def body(b) -> str:
        mass = "" if b.geoms else '<inertial pos="0 0 0" mass="0.01" diaginertia="1e-6 1e-6 1e-6"/>'
        joint = (
            ""
            if b.joint is None
            else (f'<joint name="{b.joint.name}" type="hinge" axis="{f(b.joint.axis)}"/>')
        )
        inner = "".join(geom_mjcf(g) for g in b.geoms) + "".join(
            body(c) for c in children.get(b.name, [])
        )
        return (
            f'<body name="{b.name}" pos="{f(b.pos)}" quat="{f(b.quat)}">{mass}{joint}{inner}</body>'
        )

    return f"<mujoco><worldbody>{body(children[None][0])}</worldbody></mujoco>"


def test_tree_agrees_with_mujoco_forward_kinematics():
    model = mujoco.MjModel.from_xml_string(_articulated_mjcf())
    data = mujoco.MjData(model)
    spread, prox = 0.8, np.array([0.4, 1.1, 2.0])
    for name in ("f1_spread", "f2_spread"):
        data.joint(name).qpos = spread
    for k in range(3):
        data.joint(f"f{k + 1}_prox").qpos = prox[k]
        data.joint(f"f{k + 1}_dist").qpos = HAND.distal_coupling * prox[k]
    mujoco.mj_kinematics(model, data)
    for name, T in body_poses(spread, prox).items():
        np.testing.assert_allclose(data.body(name).xpos, T[:3, 3], atol=1e-9)
        np.testing.assert_allclose(data.body(name).xmat.reshape(3, 3), T[:3, :3], atol=1e-9)
