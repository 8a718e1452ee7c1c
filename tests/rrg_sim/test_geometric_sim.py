"""Geometric simulator: head-on contacts hit the right sensors, culling is exact, table, no
contact."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rrg_estimator.obs_tables import ARRAY_FIELDS
from rrg_models.config import GEOMSIM, HAND, SENSOR_NAMES
from rrg_models.objects import Primitive, get_object
from rrg_models.poses import make_pose
from rrg_models.wrt import WRT
from rrg_sim.geometric_sim import GeometricSimulator

DOWN = Rotation.from_rotvec([np.pi, 0.0, 0.0])  # hand z = world -z
FORWARD = Rotation.from_rotvec([0.0, np.pi / 2, 0.0])  # hand z = world +x
TIP_REACH = HAND.knuckle_z + HAND.proximal_length + HAND.distal_length
STEP_TOL = GEOMSIM.path_step / 2**GEOMSIM.refine_iters + 1e-6


@dataclass(frozen=True)
class Obj:
    name: str
    parts: tuple[Primitive, ...]


BOX = Obj("box", (Primitive("box", (0.1, 0.05, 0.075), (0.0, 0.0, 0.075)),))  # 20 x 10 x 15 cm
PEG = Obj(
    "peg", (Primitive("box", (0.02, 0.02, 0.1), (0.0, 0.0, 0.1)),)
)  # fits between the fingers


def top_down(z_end: float, spread: float = 0.0, preclose: float = 0.0) -> WRT:
    return WRT(
        "top_down",
        "goal",
        make_pose(np.array([[0.0, 0.0, 0.5], [0.0, 0.0, z_end]]), DOWN),
        spread=spread,
        preclose=preclose,
    )


def side_approach() -> WRT:
    """Horizontal approach along +x at mid height of BOX, palm facing it."""
    return WRT(
        "side",
        "info",
        make_pose(np.array([[-0.45, 0.0, 0.075], [-0.2, 0.0, 0.075]]), FORWARD),
        spread=0.0,
        preclose=0.3,
    )


def names(sensors: np.ndarray) -> set[str]:
    return {SENSOR_NAMES[i] for i in np.flatnonzero(sensors)}


class BruteForce(GeometricSimulator):
    """The same simulator without culling: every sample and closing angle is tested."""

    def _sweep_candidates(self, framed, w, start=None, limit=None):
        return np.ones((len(w), self.path.n_coarse), bool), np.full(len(w), self.path.n_coarse)

    def _closing_candidates(self, T_stop, w, start=None, limit=None):
        n_a = self._link_shape[0]
        return np.ones((len(w), n_a, 3), bool), np.full((len(w), 3), n_a)


def test_top_down_descent_stops_on_the_fingertips():
    sim = GeometricSimulator(BOX, top_down(0.235))
    o = sim.simulate_relative((0.0, 0.0, 0.0))
    assert o.contact
    assert names(o.sensors) == {"tip1", "tip2", "tip3"}
    # The straight fingertips' apexes reach the box top (z = 0.15).
    assert o.progress == pytest.approx(0.5 - 0.15 - TIP_REACH, abs=STEP_TOL)
    np.testing.assert_allclose(o.motion_dir, [0.0, 0.0, -1.0], atol=1e-9)
    # Contact normals: the box's outward normal (+z world) = -z of the downward hand.
    np.testing.assert_allclose(o.tip_normals, np.tile([0.0, 0.0, -1.0], (3, 1)), atol=1e-6)
    np.testing.assert_allclose(o.tip_points[:, 2], TIP_REACH, atol=2e-3)
    np.testing.assert_allclose(o.closure, 0.0)  # fingers already touching: they cannot close


def test_palm_first_descent_stops_on_the_palm_pad_and_fingertips_close_on_the_sides():
    sim = GeometricSimulator(PEG, top_down(0.2, spread=np.pi / 2))
    o = sim.simulate_relative((0.0, 0.0, 0.0))
    assert o.contact
    assert names(o.sensors) == {"palm", "tip1", "tip2", "tip3"}
    assert o.progress == pytest.approx(0.5 - 0.2 - HAND.palm_surface_z, abs=STEP_TOL)
    assert np.all(o.closure < 0.6)  # each finger stopped early on the peg
    # Fingers 1, 2 on ±x touch the ±x faces, finger 3 (hand -y = world +y) the +y face;
    # normals are the faces' outward normals in the hand frame (x = x, y = -y, z = -z).
    np.testing.assert_allclose(o.tip_normals, [[1, 0, 0], [-1, 0, 0], [0, -1, 0]], atol=1e-6)
    np.testing.assert_allclose(np.abs(o.tip_points[[0, 1], 0]), 0.02, atol=1e-3)
    np.testing.assert_allclose(o.tip_points[2, 1], -0.02, atol=1e-3)


def test_side_approach_hits_the_near_face_with_the_fingertips():
    sim = GeometricSimulator(BOX, side_approach())
    o = sim.simulate_relative((0.0, 0.0, 0.0))
    assert o.contact and names(o.sensors) & {"tip1", "tip2", "tip3"}
    np.testing.assert_allclose(o.motion_dir, [1.0, 0.0, 0.0], atol=1e-9)
    tip_x = (
        o.hand_pose[:3, :3] @ o.tip_points[np.flatnonzero(~np.isnan(o.tip_points[:, 0]))].T
        + o.hand_pose[:3, 3:4]
    )
    np.testing.assert_allclose(tip_x[0], -0.1, atol=2e-3)  # on the box's -x face


def test_far_object_gives_no_contact_and_fully_closed_fingers():
    wrt = top_down(0.235)
    sim = GeometricSimulator(BOX, wrt)
    o = sim.simulate_relative((0.6, 0.0, 0.0))
    assert not o.contact and not o.sensors.any()
    assert o.progress == pytest.approx(sim.path.length)
    np.testing.assert_allclose(o.hand_pose, wrt.poses[-1], atol=1e-12)
    np.testing.assert_allclose(o.closure, GEOMSIM.close_max)
    assert np.isnan(o.tip_points).all()


def test_descent_onto_the_table_stops_on_it():
    sim = GeometricSimulator(BOX, top_down(0.1))
    o = sim.simulate_relative((0.6, 0.0, 0.0))
    assert o.contact and names(o.sensors) == {"tip1", "tip2", "tip3"}
    assert o.progress == pytest.approx(0.5 - TIP_REACH, abs=STEP_TOL)
    np.testing.assert_allclose(o.tip_normals, np.tile([0.0, 0.0, -1.0], (3, 1)), atol=1e-6)


@pytest.mark.parametrize(
    "wrt", [top_down(0.235, preclose=0.2), side_approach()], ids=["top_down", "side"]
)
def test_culling_never_changes_the_result(wrt):
    rng = np.random.default_rng(7)
    deltas = np.column_stack(
        [rng.uniform(-0.15, 0.15, 150), rng.uniform(-0.15, 0.15, 150), rng.uniform(-1.2, 1.2, 150)]
    )
    fast, brute = (
        GeometricSimulator(BOX, wrt).simulate_batch(deltas),
        BruteForce(BOX, wrt).simulate_batch(deltas),
    )
    assert 0.2 < fast.contact.mean() < 0.95  # a mix of outcomes
    for field in (
        "contact",
        "sensors",
        "progress",
        "closure",
        "tip_points",
        "tip_normals",
        "motion_dir",
    ):
        np.testing.assert_allclose(
            getattr(fast, field), getattr(brute, field), atol=1e-6, err_msg=field
        )


@pytest.mark.parametrize("name", ["cup", "powerdrill"])
def test_culling_is_exact_on_catalogue_composites(name):
    obj = get_object(name)
    rng = np.random.default_rng(11)
    deltas = np.column_stack(
        [rng.uniform(-0.1, 0.1, 80), rng.uniform(-0.1, 0.1, 80), rng.uniform(-1.2, 1.2, 80)]
    )
    fast = GeometricSimulator(obj, obj.goal_wrt).simulate_batch(deltas)
    brute = BruteForce(obj, obj.goal_wrt).simulate_batch(deltas)
    assert fast.contact.any()
    for field in ("contact", "sensors", "progress", "closure", "tip_points", "tip_normals"):
        np.testing.assert_allclose(
            getattr(fast, field), getattr(brute, field), atol=1e-6, err_msg=field
        )


def test_world_simulation_of_a_shifted_pair_matches_the_relative_one():
    sim = GeometricSimulator(BOX, side_approach())
    e = np.array([0.6, -0.1, 0.7])
    c, s = np.cos(e[2]), np.sin(e[2])
    delta = np.array([0.02, -0.03, 0.2])
    w = np.array(
        [e[0] + c * delta[0] - s * delta[1], e[1] + s * delta[0] + c * delta[1], e[2] + delta[2]]
    )
    rel, world = sim.simulate_relative(delta), sim.simulate(w, e)
    assert rel.contact == world.contact and (rel.sensors == world.sensors).all()
    assert world.progress == pytest.approx(rel.progress, abs=1e-6)
    Te = make_pose([e[0], e[1], 0.0], Rotation.from_rotvec([0.0, 0.0, e[2]]))
    np.testing.assert_allclose(world.hand_pose, Te @ rel.hand_pose, atol=1e-6)
    np.testing.assert_allclose(world.motion_dir, Te[:3, :3] @ rel.motion_dir, atol=1e-6)


@pytest.mark.parametrize("kind", ["goal", "info"])
def test_a_grasp_stopped_in_its_last_centimetre_has_arrived(kind):
    """A goal (or reorientation) grasp whose fingertips touch 1 cm before its end has arrived:
    no early contact, as execution reports it (config.GEOMSIM.grasp_arrival_tolerance); the
    same stop ends an information WRT early. The sensors that stopped it fire either way."""
    z_end = 0.15 + TIP_REACH - 0.01
    wrt = top_down(z_end)
    sim = GeometricSimulator(
        BOX, WRT(wrt.name, kind, wrt.poses, spread=wrt.spread, preclose=wrt.preclose)
    )
    o = sim.simulate_relative((0.0, 0.0, 0.0))
    assert o.contact == (kind == "info")
    assert o.progress == pytest.approx(sim.path.length - 0.01, abs=STEP_TOL)
    assert names(o.sensors) == {"tip1", "tip2", "tip3"}


def assert_same_arrays(a, b) -> None:
    """Every field of two ObservationArrays equal bit for bit (NaN where NaN)."""
    for field in ARRAY_FIELDS:
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=field)


@pytest.mark.parametrize(
    ("name", "wrt_names"),
    [
        ("powerdrill", ("goal", "info1", "sweep")),
        ("cup", ("goal", "reorient_ccw")),
        ("giant_teacup", ("info_handle",)),
        ("can", ("goal_probe",)),
    ],
)
def test_the_fast_batch_equals_the_per_sample_reference_bit_for_bit(name, wrt_names):
    """Box culling, the scans that stop early and the samples kept out of the MuJoCo loops
    change no bit of any field, against the sphere-culled per-sample loop (2000 seeded offsets
    over the high grid's span per WRT)."""
    obj = get_object(name)
    rng = np.random.default_rng(40)
    deltas = np.column_stack(
        [
            rng.uniform(-0.2, 0.2, 2000),
            rng.uniform(-0.2, 0.2, 2000),
            rng.uniform(-np.pi / 2, np.pi / 2, 2000),
        ]
    )
    for wrt_name in wrt_names:
        sim = GeometricSimulator(obj, obj.wrt(wrt_name))
        fast, reference = sim.simulate_batch(deltas), sim.simulate_batch_reference(deltas)
        assert 0.05 < fast.contact.mean() < 0.95 or fast.closure.std() > 0.1  # varied outcomes
        assert_same_arrays(fast, reference)


def test_a_scan_stopped_early_is_resumed_when_its_candidates_are_free():
    """With one candidate per scan, free first candidates make the loops scan on; the result
    is still the reference's."""
    obj = get_object("powerdrill")
    rng = np.random.default_rng(5)
    deltas = np.column_stack(
        [rng.uniform(-0.1, 0.1, 400), rng.uniform(-0.1, 0.1, 400), rng.uniform(-1, 1, 400)]
    )
    sim = GeometricSimulator(obj, obj.goal_wrt)
    full, resume = sim._sweep_candidates(sim._relative, deltas, limit=1)
    assert (resume < sim.path.n_coarse).any()  # some scans did stop early
    assert (full.sum(axis=1) <= 1).all()

    class OneCandidate(GeometricSimulator):
        def _sweep_candidates(self, framed, w, start=None, limit=1):
            return super()._sweep_candidates(
                framed, w, start, min(limit, 1) if start is None else limit
            )

        def _closing_candidates(self, T_stop, w, start=None, limit=1):
            return super()._closing_candidates(
                T_stop, w, start, min(limit, 1) if start is None else limit
            )

    assert_same_arrays(
        OneCandidate(obj, obj.goal_wrt).simulate_batch(deltas), sim.simulate_batch_reference(deltas)
    )


def test_box_culling_is_tighter_than_the_sphere_culling_and_covers_every_touch():
    """Every coarse sample the brute-force sweep finds touching is a candidate, and the box
    test flags fewer samples than the sphere covers do."""
    obj = get_object("powerdrill")
    rng = np.random.default_rng(9)
    deltas = np.column_stack(
        [rng.uniform(-0.1, 0.1, 300), rng.uniform(-0.1, 0.1, 300), rng.uniform(-1, 1, 300)]
    )
    sim = GeometricSimulator(obj, obj.goal_wrt)
    boxes, _ = sim._sweep_candidates(sim._relative, deltas, limit=sim.path.n_coarse)
    spheres = sim._sweep_candidates_spheres(sim._relative, deltas)
    assert boxes.sum() < 0.8 * spheres.sum()
    q = sim._relative.palm_qpos
    for i in range(0, len(deltas), 10):  # MuJoCo at every coarse sample of 30 offsets
        sim._set_object(deltas[i])
        sim._set_fingers([0, 0, 0])
        for c in range(sim.path.n_coarse):
            sim._qpos[sim._palm_adr : sim._palm_adr + 7] = q[c * 2**GEOMSIM.refine_iters]
            if sim._collide():
                assert boxes[i, c], (i, c)


def test_a_zero_hand_offset_is_the_nominal_batch_and_a_raised_hand_stops_later():
    sim = GeometricSimulator(BOX, top_down(0.235))
    deltas = np.array([[0.0, 0.0, 0.0], [0.01, -0.01, 0.3], [0.6, 0.0, 0.0]])
    nominal = sim.simulate_batch(deltas)
    assert_same_arrays(sim.simulate_batch_offset(deltas, (0.0, 0.0, 0.0)), nominal)
    up = sim.simulate_batch_offset(deltas, (0.0, 0.0, 0.01))  # the hand truly 1 cm higher
    assert up.contact[0] and nominal.contact[0]
    assert up.progress[0] == pytest.approx(nominal.progress[0] + 0.01, abs=STEP_TOL)
    # Stop poses as the robot measures them: on the nominal path, 1 cm further along it.
    np.testing.assert_allclose(up.stop_pose[0, :3, :3], nominal.stop_pose[0, :3, :3], atol=1e-6)
    assert up.stop_pose[0, 2, 3] == pytest.approx(nominal.stop_pose[0, 2, 3] - 0.01, abs=STEP_TOL)
    assert not up.contact[2]
    np.testing.assert_allclose(up.stop_pose[2], nominal.stop_pose[2], atol=1e-6)
