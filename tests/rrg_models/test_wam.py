"""WAM kinematics: FK, analytic IK with redundancy resolution, table clearance, feasibility maps."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rrg_models import wam, wam_feasibility
from rrg_models.config import HAND, WAM, WORLD
from rrg_models.poses import home_pose, interpolate_poses, make_pose, planar_pose
from rrg_models.wam_feasibility import FeasibilityMap, PolarGrid

WRIST_TO_HAND = WAM.dh[6][2] + WAM.hand_mount  # m
DOWN = Rotation.from_rotvec([np.pi, 0.0, 0.0])  # hand z = world -z


def hand_at_palm(palm, approach, finger_axis) -> np.ndarray:
    """Hand pose whose palm surface centre is at ``palm`` [m], approaching along ``approach``,
    with hand x along ``finger_axis`` (both unit vectors in world)."""
    z, x = np.asarray(approach, float), np.asarray(finger_axis, float)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    T[:3, 3] = np.asarray(palm, float) - HAND.palm_surface_z * z
    return T


def random_clear_configurations(n: int, seed: int) -> np.ndarray:
    """n random in-limit joint vectors whose elbow and wrist centre clear the table."""
    rng = np.random.default_rng(seed)
    q = rng.uniform(wam.LOWER, wam.UPPER, (3 * n, 7))
    return q[wam.arm_clear_of_table(q)][:n]


def test_dh_transform_is_rz_tz_tx_rx():
    alpha, a, d, theta = 0.3, 0.05, 0.2, -1.1
    Rz = make_pose([0, 0, 0], Rotation.from_rotvec([0, 0, theta]))
    Tz = make_pose([0, 0, d])
    Tx = make_pose([a, 0, 0])
    Rx = make_pose([0, 0, 0], Rotation.from_rotvec([alpha, 0, 0]))
    np.testing.assert_allclose(wam.dh_transform(alpha, a, d, theta), Rz @ Tz @ Tx @ Rx, atol=1e-12)


def test_fk_hand_computed_cases():
    top = WAM.base_height + WAM.dh[2][2] + WAM.dh[4][2]  # upright arm: wrist centre height
    # q = 0: the arm points straight up; the hand is turned by the mount's yaw (π) about z.
    T0 = wam.fk(np.zeros(7))
    np.testing.assert_allclose(T0[:3, 3], [0, 0, top + WRIST_TO_HAND], atol=1e-12)
    np.testing.assert_allclose(T0[:3, :3], np.diag([-1.0, -1.0, 1.0]), atol=1e-12)
    # J2 = π/2: the straight arm points forward along +x at shoulder height.
    T1 = wam.fk(np.array([0, np.pi / 2, 0, 0, 0, 0, 0]))
    np.testing.assert_allclose(
        T1[:3, 3], [WAM.dh[2][2] + WAM.dh[4][2] + WRIST_TO_HAND, 0, WAM.base_height], atol=1e-12
    )
    np.testing.assert_allclose(T1[:3, 2], [1, 0, 0], atol=1e-12)
    # J4 = π/2: upper arm up to the elbow (0.045 m offsets), forearm horizontal along +x.
    frames = wam.fk_frames(np.array([0, 0, 0, np.pi / 2, 0, 0, 0]))
    elbow_z = WAM.base_height + WAM.dh[2][2] + 0.045
    np.testing.assert_allclose(frames[5, :3, 3], [0.045 + WAM.dh[4][2], 0, elbow_z], atol=1e-12)
    np.testing.assert_allclose(
        frames[8, :3, 3], [0.045 + WAM.dh[4][2] + WRIST_TO_HAND, 0, elbow_z], atol=1e-12
    )
    np.testing.assert_allclose(frames[8], wam.fk(np.array([0, 0, 0, np.pi / 2, 0, 0, 0])))


def test_fk_is_vectorized_over_leading_axes():
    q = random_clear_configurations(12, seed=1).reshape(3, 4, 7)
    T = wam.fk(q)
    assert T.shape == (3, 4, 4, 4)
    np.testing.assert_allclose(T[2, 1], wam.fk(q[2, 1]), atol=1e-14)
    frames = wam.fk_frames(q)
    assert frames.shape == (3, 4, 9, 4, 4)
    # Frame i-1's z is joint i's axis: turning joint 7 spins the hand about frame 6's z.
    q2 = q.copy()
    q2[..., 6] += 0.3
    np.testing.assert_allclose(wam.fk(q2)[..., :3, 2], T[..., :3, 2], atol=1e-12)
    np.testing.assert_allclose(frames[..., 6, :3, 2], T[..., :3, 2], atol=1e-12)


def test_home_q_reaches_home_pose():
    np.testing.assert_allclose(wam.fk(wam.HOME_Q), home_pose(), atol=1e-9)
    assert wam.within_limits(wam.HOME_Q) and wam.arm_clear_of_table(wam.HOME_Q)
    assert wam.HOME_Q[0] == pytest.approx(0.0, abs=1e-9) and wam.HOME_Q[2] == pytest.approx(
        0.0, abs=1e-9
    )


def test_ik_round_trip_on_random_reachable_poses():
    q_true = random_clear_configurations(400, seed=2)
    T = wam.fk(q_true)
    q, ok = wam.ik_batch(T)
    assert ok.mean() >= 0.99  # the J3 sweep may miss a pose whose solutions need a narrow J3 window
    assert ok.sum() >= 200
    T_back = wam.fk(q[ok])
    assert np.abs(T_back[:, :3, 3] - T[ok, :3, 3]).max() < 1e-3
    rot_err = (
        Rotation.from_matrix(T_back[:, :3, :3]).inv() * Rotation.from_matrix(T[ok, :3, :3])
    ).magnitude()
    assert rot_err.max() < 0.01
    assert wam.within_limits(q[ok]).all() and wam.arm_clear_of_table(q[ok]).all()
    assert np.isnan(q[~ok]).all()
    # Seeded with the true posture (its J3 is then among the samples) every pose is solved.
    q_seeded, ok_seeded = wam.ik_batch(T, q_true)
    assert ok_seeded.all()
    np.testing.assert_allclose(q_seeded, q_true, atol=1e-6)


def test_ik_batch_agrees_with_ik():
    q_true = random_clear_configurations(30, seed=3)
    T = wam.fk(q_true)
    seed = np.random.default_rng(4).uniform(wam.LOWER, wam.UPPER, 7)
    q_batch, ok_batch = wam.ik_batch(T, seed)
    for i in range(len(T)):
        q_one, ok_one = wam.ik(T[i], seed)
        assert ok_one == ok_batch[i]
        np.testing.assert_allclose(q_one, q_batch[i], atol=1e-12)


def test_redundancy_resolution_prefers_the_seed():
    """The chosen solution is the nearest (in joint space) of all usable sampled solutions."""
    T = wam.fk(random_clear_configurations(20, seed=5))
    pref = np.random.default_rng(6).uniform(wam.LOWER, wam.UPPER, (20, 7))
    q, ok = wam.ik_batch(T, pref)
    sol = wam.ik_solutions(T, pref)
    Q = sol.angles().reshape(7, -1, 20)
    usable = sol.usable().reshape(-1, 20)
    for i in np.nonzero(ok)[0]:
        cands = Q[:, usable[:, i], i].T
        assert (
            np.sum((q[i] - pref[i]) ** 2) <= np.min(np.sum((cands - pref[i]) ** 2, axis=1)) + 1e-12
        )


def test_ik_path_is_continuous():
    grasp = planar_pose([0.62, 0.05, 0.4]) @ make_pose([0, 0, 0.18 - HAND.palm_surface_z], DOWN)
    Ts = interpolate_poses(home_pose(), grasp, 25)
    qs, ok = wam.ik_path(Ts, wam.HOME_Q)
    assert ok.all()
    steps = np.abs(np.diff(np.vstack([wam.HOME_Q, qs]), axis=0))
    assert steps.max() < 0.25  # rad between neighbouring via-points ~2 cm / 0.02 rad apart
    np.testing.assert_allclose(qs[:, 2], wam.HOME_Q[2], atol=1e-12)  # J3 held where it works
    np.testing.assert_allclose(wam.fk(qs), Ts, atol=1e-9)


def test_far_pose_is_infeasible():
    T = make_pose([2.0, 0.0, 0.3], DOWN)
    q, ok = wam.ik(T)
    assert not ok and np.isnan(q).all()
    assert not wam.feasible_path(np.stack([home_pose(), T]))


def test_top_down_grasps_at_the_nominal_pose_are_feasible():
    x, y, _ = WORLD.nominal_pose
    for palm_z in (0.15, 0.20, 0.25):
        for yaw in np.linspace(-np.pi, np.pi, 12, endpoint=False):
            grasp = planar_pose([x, y, yaw]) @ make_pose([0, 0, palm_z - HAND.palm_surface_z], DOWN)
            approach = grasp.copy()
            approach[2, 3] += 0.15
            assert wam.feasible_path(np.stack([approach, grasp])), (palm_z, yaw)


@pytest.mark.parametrize("approach", [(0, 1, 0), (0, -1, 0), (1, 0, 0)])
@pytest.mark.parametrize("fingers_vertical", [True, False])
def test_side_grasps_at_palm_height_10cm_are_feasible(approach, fingers_vertical):
    """Hand z horizontal, palm 10 cm above the table, pre-grasp 10 cm back along the approach.
    Along ±y around the nominal pose. Along +x the wrist centre lies 0.2 m behind the palm and
    J6's ±π/2 rules out radially outward approaches close to the base (at y = 0 the palm needs
    x ≥ 0.66 m), so those objects sit 12-22 cm beyond the nominal pose."""
    a = np.asarray(approach, float)
    finger_axis = (0, 0, 1) if fingers_vertical else np.cross((0, 0, 1), a)
    centres = (
        [(0.84, 0.0), (0.76, 0.10), (0.76, -0.10)]
        if a[0] > 0
        else [(0.62, 0.0), (0.57, 0.05), (0.57, -0.05), (0.62, 0.05), (0.62, -0.05)]
    )
    for cx, cy in centres:
        palm = np.array([cx, cy, 0.10]) - 0.06 * a  # a 12 cm wide object
        Ts = np.stack([hand_at_palm(palm - d * a, a, finger_axis) for d in (0.10, 0.0)])
        assert wam.feasible_path(Ts), (cx, cy)


def test_table_clearance():
    low_elbow = np.array(
        [0.0, 1.985, 0.0, np.pi / 2, 0.0, 0.0, 0.0]
    )  # elbow 6.5 cm above the table
    points = wam.arm_points(low_elbow)
    assert points[1, 2] < wam.CLEARANCE_Z and WORLD.table_x[0] < points[1, 0] < WORLD.table_x[1]
    assert not wam.arm_clear_of_table(low_elbow)
    behind = low_elbow + np.array(
        [2.5, 0, 0, 0, 0, 0, 0]
    )  # same posture turned away from the table
    assert wam.arm_clear_of_table(behind)
    below = np.array(
        [
            [[0.5, 0.0, -0.05], [0.5, 0.0, 0.3], [0.6, 0.0, 0.3]],  # elbow below the table
            [[0.1, 0.0, -0.05], [0.5, 0.0, 0.3], [0.6, 0.0, 0.3]],
        ]
    )  # ... but beside it
    np.testing.assert_array_equal(wam.points_clear_of_table(below), [False, True])
    # A horizontal hand with its wrist centre 5 cm above the table: solutions within the joint
    # limits exist, but IK and feasibility reject them all.
    T = hand_at_palm([0.55, 0.0, 0.05], (0, 1, 0), (0, 0, 1))
    sol = wam.ik_solutions(T[None])
    assert sol.valid.any() and not sol.usable().any()
    assert not wam.ik(T)[1] and not wam.feasible_path(T[None])


def test_ik_solutions_points_match_fk():
    T = wam.fk(random_clear_configurations(40, seed=7))
    sol = wam.ik_solutions(T)
    index = np.nonzero(sol.valid)
    q = sol.angles()[(slice(None),) + index].T
    np.testing.assert_allclose(wam.fk(q), T[index[-1]], atol=1e-9)
    points = wam.arm_points(q)
    np.testing.assert_allclose(
        points[:, :2],
        np.moveaxis(sol.elbows[(slice(None), slice(None)) + index[1:]], -1, 0),
        atol=1e-9,
    )
    np.testing.assert_allclose(points[:, 2], sol.wrist[:, index[-1]].T, atol=1e-9)
    assert wam.within_limits(q).all()


@pytest.fixture
def tmp_cache(tmp_path, monkeypatch):
    monkeypatch.setattr(wam_feasibility, "CACHE_DIR", tmp_path)
    return tmp_path


@pytest.fixture
def waypoint_builds(monkeypatch):
    """Counts the waypoint maps FeasibilityMap builds; while ``forbidden``, building raises."""

    class Builds:
        count = 0
        forbidden = False

    build = wam_feasibility._waypoint_feasibility

    def counted(pose, grid):
        if Builds.forbidden:
            raise AssertionError("the map was built, not loaded from the cache")
        Builds.count += 1
        return build(pose, grid)

    monkeypatch.setattr(wam_feasibility, "_waypoint_feasibility", counted)
    return Builds


def top_down_wrt() -> np.ndarray:
    return np.stack([make_pose([0, 0, h - HAND.palm_surface_z], DOWN) for h in (0.35, 0.25, 0.18)])


def test_feasibility_map_matches_exact_feasibility(tmp_cache, waypoint_builds):
    poses = top_down_wrt()
    fmap = FeasibilityMap(poses)
    grid = fmap.grid
    assert waypoint_builds.count == 3  # one map per waypoint, none cached yet
    assert 0.3 < fmap.feasible.mean() < 1.0
    rng = np.random.default_rng(8)
    r, phi, psi = grid.axes()
    i = rng.integers(0, [grid.nr, grid.nphi, grid.npsi], (300, 3))
    e = np.stack(
        [
            r[i[:, 0]] * np.cos(phi[i[:, 1]]),
            r[i[:, 0]] * np.sin(phi[i[:, 1]]),
            phi[i[:, 1]] + psi[i[:, 2]],
        ],
        axis=1,
    )
    exact = wam.feasible_paths(planar_pose(e)[:, None] @ poses)
    assert 0.2 < exact.mean() < 1.0
    assert (fmap.lookup(e) == exact).mean() >= 0.99
    # The nominal pose is feasible; off the grid the lookup falls back to the exact test.
    assert fmap.lookup(np.array(WORLD.nominal_pose))
    off = np.array([[1.6, 0.0, 0.0], [0.2, 0.6, 1.0]])
    np.testing.assert_array_equal(
        fmap.lookup(off), wam.feasible_paths(planar_pose(off)[:, None] @ poses)
    )
    assert not fmap.lookup(off[0])


def test_feasibility_map_cache(tmp_cache, waypoint_builds):
    poses = top_down_wrt()[1:]
    built = FeasibilityMap(poses)
    assert waypoint_builds.count == 2
    assert len(list(tmp_cache.glob("*.npz"))) == 1
    waypoint_builds.forbidden = True
    loaded = FeasibilityMap(poses)  # from the cache (building would raise)
    np.testing.assert_array_equal(loaded.feasible, built.feasible)
    waypoint_builds.forbidden = False
    FeasibilityMap(poses, grid=PolarGrid.covering(half_extent=0.1))  # another grid: built
    assert waypoint_builds.count == 4 and len(list(tmp_cache.glob("*.npz"))) == 2


def test_ik_batch_solves_most_random_clear_configurations():
    """(Its speed, and the map's build time: ``rrg-bench plan``.)"""
    T = wam.fk(random_clear_configurations(2000, seed=9))
    _, ok = wam.ik_batch(T)
    assert ok.mean() > 0.9
