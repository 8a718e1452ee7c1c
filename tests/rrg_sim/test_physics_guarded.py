"""Guarded moves in physics: the hand stops on the first contact, within one control period,
barely moving the object, and the sensor that stops it sits on the side that was hit."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rrg_models.config import SENSOR_NAMES
from rrg_models.objects import get_object
from rrg_models.poses import make_pose
from rrg_models.wrt import WRT
from rrg_sim.physics.world import PhysicsWorld

DOWN = Rotation.from_rotvec([np.pi, 0.0, 0.0])  # hand z = world -z, hand y = world -y


def _sweep(start, end, name: str, above: float | None = None) -> WRT:
    """An info-style WRT: hand pointing down, straight from start to end (object frame) [m],
    optionally entering from ``above`` start (so the way from home clears the object)."""
    points = [start, end] if above is None else [(start[0], start[1], above), start, end]
    return WRT(name, "info", make_pose(np.array(points, dtype=float), DOWN))


# (object, WRT, sensors allowed to stop it): coming down on top of the box lands the
# fingertips; sweeping toward world -y leads with fingers 1 and 2 (hand +y), toward world +y
# with finger 3.
TIPS = {"tip1", "tip2", "tip3", "dist1", "dist2", "dist3"}
FINGERS_1_2 = {"prox1", "prox2", "dist1", "dist2", "tip1", "tip2"}
FINGER_3 = {"prox3", "dist3", "tip3"}
CASES = [
    ("box", _sweep((0.0, 0.0, 0.45), (0.0, 0.0, 0.25), "down_onto_box"), TIPS),
    ("can", _sweep((0.0, 0.18, 0.25), (0.0, -0.18, 0.25), "can_sweep_minus_y"), FINGERS_1_2),
    ("can", _sweep((0.0, -0.18, 0.25), (0.0, 0.18, 0.25), "can_sweep_plus_y"), FINGER_3),
    (
        "box",
        _sweep((0.22, 0.0, 0.27), (-0.22, 0.0, 0.27), "box_sweep_minus_x"),
        FINGERS_1_2 | FINGER_3,
    ),
    (
        "cooler",
        _sweep((0.0, 0.30, 0.40), (0.0, -0.30, 0.40), "cooler_sweep_minus_y", above=0.55),
        FINGERS_1_2,
    ),
    (
        "cooler",
        _sweep((0.0, -0.30, 0.40), (0.0, 0.30, 0.40), "cooler_sweep_plus_y", above=0.55),
        FINGER_3,
    ),
]


@pytest.mark.parametrize("name, wrt, side", CASES, ids=[c[1].name for c in CASES])
def test_guarded_move_stops_on_first_contact(name, wrt, side):
    world = PhysicsWorld(name, seed=3)
    w0 = world.true_object_pose()
    path, timed, stop = world.move_through(wrt.world_poses(w0), guard=True)
    assert stop is not None, "the move must be stopped by a contact"
    assert path.segment[int(np.ceil(timed.index[stop]))] == len(wrt.poses) - 1, (
        "stopped on the last segment"
    )
    fired = world.sensors.fired()
    assert {SENSOR_NAMES[i] for i in np.nonzero(fired)[0]} <= side and fired.any()
    world.hold(0.2)  # the arm comes to rest
    assert np.linalg.norm(world.true_object_pose()[:2] - w0[:2]) < 0.005


def test_guard_reacts_in_the_period_the_signal_crosses():
    """Replaying the stopped move period by period: no sensor fired one period earlier."""
    world = PhysicsWorld("can", seed=0, sensor_noise=0.0)
    wrt = CASES[1][1]
    w0 = world.true_object_pose()
    path, timed, stop = world.move_through(wrt.world_poses(w0), guard=True)
    world.reset()
    world.sensors.tare()
    world._run(timed.ctrl[:stop])  # one period short of the stop, unguarded
    assert not world.sensors.fired().any()
    world._run(timed.ctrl[stop : stop + 1])
    assert world.sensors.fired().any()


@pytest.mark.parametrize("guarded", [True, False], ids=["careful", "firm"])
def test_careful_closing_stops_each_finger_at_its_first_touch(guarded, monkeypatch):
    """The tea box's sweep (an information WRT) stopped by a fingertip: careful closing leaves
    that finger where it stopped and the 80 g box within 1 cm; closing firmly instead (forced
    here) shoves the box on by over 2 cm."""
    world = PhysicsWorld("teabox", seed=3)
    if not guarded:
        monkeypatch.setattr(
            world,
            "close_hand",
            lambda monitor=None, guarded=False: PhysicsWorld.close_hand(
                world, monitor, guarded=False
            ),
        )
    world.reset(np.array([0.6137, 0.0003, -0.0418]))
    w0 = world.true_object_pose()
    sweep = next(w for w in get_object("teabox").wrts() if w.name == "sweep")
    obs = world.execute_wrt(sweep, np.array([0.62, 0.0, 0.0]))
    assert obs.contact and obs.sensors[SENSOR_NAMES.index("tip3")]
    moved = np.linalg.norm(world.true_object_pose()[:2] - w0[:2])
    if guarded:
        assert moved < 0.01
        assert obs.closure[2] == pytest.approx(
            sweep.preclose, abs=0.02
        )  # finger 3 touched first: it stayed
    else:
        assert moved > 0.02


@pytest.mark.parametrize("arm_guard", [True, False], ids=["arm-guard", "no-arm-guard"])
def test_arm_collision_detection_stops_on_unsensed_contacts(arm_guard, monkeypatch):
    """With every hand sensor blind (as on an unsensed part of the hand), the WAM's joint-torque
    collision detection still stops a sweep into the box within 1 cm; without it the hand
    pushes the box on by more than 2 cm."""
    from rrg_sim.physics.sensing import HandSensors

    monkeypatch.setattr(HandSensors, "fired_now", lambda self: None)
    if not arm_guard:
        monkeypatch.setattr(HandSensors, "arm_collision", lambda self, dofs: False)
    world = PhysicsWorld("box", seed=3)
    w0 = world.true_object_pose()
    _, _, stop = world.move_through(CASES[3][1].world_poses(w0), guard=True)
    world.hold(0.2)
    moved = np.linalg.norm(world.true_object_pose()[:2] - w0[:2])
    if arm_guard:
        assert stop is not None and moved < 0.01
    else:
        assert stop is None and moved > 0.02


def test_careful_pinch_reports_every_touch_and_leaves_a_light_box_in_place():
    """The tea box's off-centre pinch (info3) from a seeded offset: the slow careful closing
    moves the 80 g box by under 3 mm and 0.03 rad (at full closing speed finger 3 knocked it
    1.4 cm and 0.18 rad), and every fingertip that stopped its finger is in the observation,
    though the touches of fingers 1 and 3 have eased off by the end of the closing."""
    world = PhysicsWorld("teabox", seed=7)
    e = np.array([0.62, 0.0, 0.0])
    world.reset(np.array([0.611, -0.005, -0.052]))
    w0 = world.true_object_pose()
    obs = world.execute_wrt(get_object("teabox").wrt("info3"), e)
    moved = world.true_object_pose() - w0
    assert np.linalg.norm(moved[:2]) < 0.003 and abs(moved[2]) < 0.03
    assert not obs.contact
    after = world.reading().fired
    tips = [SENSOR_NAMES.index(n) for n in ("tip1", "tip2", "tip3")]
    assert obs.sensors[tips].all()
    assert not after[tips].all()  # what the reading after the closing alone would have said


def test_quiet_checks_agree_with_their_numpy_forms():
    """The compiled per-period checks of sensing.py give the numpy expressions' answers
    (NaN counts as loud), on seeded readings around the thresholds."""
    from rrg_sim.physics.sensing import _any_reaches, _may_fire

    rng = np.random.default_rng(7)
    pads, forces = np.arange(7), np.arange(7, 16).reshape(3, 3)
    for k in range(2000):
        data = rng.normal(0.0, 0.3, 25)
        if k % 97 == 0:
            data[rng.integers(25)] = np.nan
        bias = rng.normal(0.0, 0.1, (3, 6))[:, :3]  # a strided view, as HandSensors holds it
        quiet_pad, quiet_tip2 = 0.3, 0.25
        f = data[forces] - bias
        numpy_quiet = data[pads].max() < quiet_pad and (f * f).sum(axis=1).max() < quiet_tip2
        assert _may_fire(data, pads, forces, bias, quiet_pad, quiet_tip2) == (not numpy_quiet)
        dofs = np.array([0, 2, 4, 6, 8, 10, 12])
        assert _any_reaches(data, dofs, 0.5) == (not np.abs(data[dofs]).max() < 0.5)
