"""The hand's sensing logic shared by the simulator and the hardware bridge
(rrg_models.hand_sensing), and the bridge's hand state and trip logic
(rrg_hw_bridge.contact_guard)."""

from __future__ import annotations

import numpy as np
import pytest

from rrg_hw_bridge.contact_guard import (
    ContactGuard,
    HandState,
    StopSensing,
    derived_pads,
    path_index,
)
from rrg_models.config import HAND, PHYSICS, SENSING
from rrg_models.hand_sensing import (
    CLOSE_START_TIME,
    FingerClosing,
    fired_sensors,
    hand_tip_poses,
    reading_from_joints,
    tip_contacts,
)
from rrg_sim.physics.world import PhysicsWorld


def test_fired_sensors_thresholds():
    pads = np.zeros(7)
    tips = np.zeros((3, 6))
    assert not fired_sensors(pads, tips).any()
    pads[2] = SENSING.pad_force_threshold * 1.01
    tips[1, :3] = [0.0, SENSING.tip_force_threshold * 0.99, 0.0]
    tips[2, :3] = [SENSING.tip_force_threshold * 0.8, SENSING.tip_force_threshold * 0.8, 0.0]
    fired = fired_sensors(pads, tips)
    assert fired.tolist() == [False, False, True] + [False] * 5 + [False, True]


def test_hand_kinematics_put_the_sensors_where_mujoco_does():
    world = PhysicsWorld("box", seed=0)
    world.place_object([1.1, 0.6, 0.0])  # out of the hand's way
    world.move_hand(0.7, np.array([0.5, 0.9, 1.3]))
    spread, proximal = world.hand_angles()
    d, m = world.data, world.model
    palm = m.body("bh/palm").id
    R_palm, p_palm = d.xmat[palm].reshape(3, 3), d.xpos[palm]
    poses = hand_tip_poses(spread, proximal)
    for i in range(3):
        tip = m.body(f"bh/f{i + 1}_tip").id
        R = R_palm.T @ d.xmat[tip].reshape(3, 3)
        p = R_palm.T @ (d.xpos[tip] - p_palm)
        assert np.abs(poses[i, :3, 3] - p).max() < 2e-3  # m: the distal coupling is soft
        assert np.abs(poses[i, :3, :3] - R).max() < 2e-2


def test_reading_locates_a_fingertip_contact_in_the_hand_frame():
    spread, proximal = 0.3, np.array([0.8, 0.8, 0.8])
    poses = hand_tip_poses(spread, proximal)
    tips = np.zeros((3, 6))
    contact = np.array([0.0, -0.008, 0.02])  # on finger 2's tip, its own frame [m]
    force = np.array([0.0, 1.0, 0.0])  # pushing into the tip [N]
    tips[1] = np.r_[force, np.cross(contact, force)]
    reading = reading_from_joints(np.zeros(7), tips, spread, proximal)
    assert reading.fired.tolist() == [False] * 8 + [True, False]
    assert np.isnan(reading.tip_points[[0, 2]]).all()
    expected = poses[1, :3, :3] @ contact + poses[1, :3, 3]
    assert np.linalg.norm(reading.tip_points[1] - expected) < 2e-3
    points, normals = tip_contacts(tips, reading.fired, poses)
    np.testing.assert_allclose(points, reading.tip_points)
    assert np.isclose(np.linalg.norm(normals[1]), 1.0)


def test_finger_closing_stalls_after_the_start_time_and_stops_on_own_contact():
    dt = PHYSICS.timestep
    careless = FingerClosing(guarded=False)
    assert careless.speed == HAND.close_speed
    still = np.zeros(3)
    # Slow from the start, but nothing stops before CLOSE_START_TIME.
    for _ in range(int(round(CLOSE_START_TIME / dt))):
        assert not careless.update(dt, still).any()
    stopped = [careless.update(dt, np.array([0.0, 1.0, 1.0])) for _ in range(20)]
    assert stopped[0].tolist() == [True, False, False]  # still long enough already
    assert not careless.done
    careful = FingerClosing(guarded=True)
    assert careful.speed == HAND.careful_close_speed and careful.timeout > careless.timeout
    fired = np.zeros(10, bool)
    fired[9] = True  # finger 3's Nano17
    new = careful.update(dt, np.ones(3), fired)
    assert new.tolist() == [False, False, True]
    assert careful.touched[9] and not careless.touched.any()
    # An unguarded closing records the touch but does not stop on it.
    assert not FingerClosing(guarded=False).update(dt, np.ones(3), fired).any()


def test_hand_state_tares_and_derives_pads():
    state = HandState(derive_pads=True)
    state.set_tip(0, np.array([0.0, 0.0, 0.3, 0.0, 0.0, 0.0]))  # the fingertip's own weight
    state.tare()
    tips = state.set_tip(0, np.array([0.0, 0.0, 1.3, 0.0, 0.0, 0.0]))
    np.testing.assert_allclose(tips[0, :3], [0.0, 0.0, 1.0])
    pads = state.pads()
    assert pads[4] == pytest.approx(1.0) and pads[[0, 1, 2, 3, 5, 6]].sum() == 0.0
    np.testing.assert_allclose(derived_pads(tips), pads)
    assert state.fired()[[4, 7]].all()
    topic = HandState(derive_pads=False)
    topic.set_pads(np.r_[0.5, np.zeros(6)])
    assert topic.fired().tolist() == [True] + [False] * 9


def test_contact_guard_trips_on_sensors_and_effort_change():
    guard = ContactGuard(tip_force_threshold=2.0, pad_force_threshold=1.0, effort_threshold=1.5)
    tips = np.zeros((3, 6))
    tips[0, 2] = 1.9
    assert guard.check_sensors(np.zeros(7), tips) is None
    tips[0, 2] = 2.1
    trip = guard.check_sensors(np.zeros(7), tips)
    assert trip.sensors[7] and trip.describe(("a",) * 7 + ("tip1", "tip2", "tip3")) == (
        "contact on tip1"
    )
    effort0 = np.array([5.0, -30.0, 2.0, 10.0, 0.5, 0.2, 0.0])
    guard.start(effort0)
    assert guard.check_effort(effort0 + 1.4) is None
    trip = guard.check_effort(effort0 + np.r_[0, 0, 0, -1.6, 0, 0, 0])
    assert trip.effort_joint == 3 and trip.effort_change_nm == pytest.approx(1.6)
    off = ContactGuard(effort_threshold=0.0)
    off.start(effort0)
    assert off.check_effort(effort0 + 10.0) is None


def test_stop_confirmation_waits_for_a_second_pad_sample():
    """A lone pad in one sample is rejected, in two samples running it stops the move; a
    Nano17 or the collision detection stops it at once, also while a pad is pending; with
    confirmation off a lone pad stops it at once."""
    from rrg_models.hand_sensing import StopConfirmation

    pad, tip = np.zeros(10, bool), np.zeros(10, bool)
    pad[2], tip[8] = True, True
    c = StopConfirmation()
    assert not c.update(pad, False, 0) and not c.update(pad, False, 0)  # the same held sample
    assert not c.update(None, False, 5) and c.rejected == 1  # the next sample is quiet
    assert not c.update(pad, False, 10) and c.update(pad, False, 15)  # two samples running
    c = StopConfirmation()
    assert not c.update(pad, False, 0) and c.update(tip, False, 0)  # a Nano17 agrees
    assert StopConfirmation().update(None, True, 0)  # the collision detection
    assert StopConfirmation().update(tip, False, 0)
    assert StopConfirmation(confirm=False).update(pad, False, 0)


def test_contact_guard_confirms_a_lone_pad_on_the_next_pad_sample():
    """The bridge's guard: a pad over its threshold trips only when the next pad message still
    has one; a one-message false alarm does not; fingertip messages between pad messages are
    not pad samples (pads from a topic), but are (pads derived from the fingertips)."""
    guard = ContactGuard()
    pads, quiet, tips = np.r_[0.5, np.zeros(6)], np.zeros(7), np.zeros((3, 6))
    assert guard.check_sensors(pads, tips, True) is None
    assert guard.check_sensors(pads, tips, False) is None  # a fingertip sample: the same pads
    assert guard.check_sensors(quiet, tips, True) is None  # the false alarm is gone
    assert guard.confirmation.rejected == 1
    assert guard.check_sensors(pads, tips, True) is None
    trip = guard.check_sensors(pads, tips, True)
    assert trip is not None and trip.sensors[0]
    assert ContactGuard(confirm_stops=False).check_sensors(pads, tips, True) is not None


def test_path_index_projects_a_measured_configuration():
    q = np.zeros((4, 7))
    q[:, 0] = [0.0, 0.1, 0.2, 0.4]
    probe = np.zeros(7)
    probe[0] = 0.3
    assert path_index(q, probe) == pytest.approx(2.5)
    probe[0], probe[1] = 0.05, 0.01  # off the path: the nearest point
    assert path_index(q, probe) == pytest.approx(0.5)
    probe[0] = 1.0
    assert path_index(q, probe) == pytest.approx(3.0)


def test_velocity_estimate_follows_a_ramp_and_settles_at_rest():
    from rrg_hw_bridge.contact_guard import VelocityEstimate

    est = VelocityEstimate(2, tau_s=0.01)
    dt = 0.002  # a 500 Hz driver
    for k in range(100):  # 0.2 s at 0.5 rad/s on joint 0
        v = est.update(np.array([0.5 * k * dt, 1.0]), k * dt)
    assert v[0] == pytest.approx(0.5, rel=1e-3) and v[1] == 0.0
    for k in range(100, 150):  # stopped
        v = est.update(np.array([0.5 * 99 * dt, 1.0]), k * dt)
    assert abs(v[0]) < PHYSICS.stall_speed


def test_the_ceilings_loads_are_untared_so_a_tare_under_load_neither_hides_nor_fakes_one():
    """A guarded move tared while a fingertip carried 15 N: its contact detection sees the
    change, the force ceiling the load itself (a tared 30 N would read 15 N, and the load's
    release -15 N)."""
    from rrg_hw_bridge.safety import ForceCeiling

    hand = HandState(derive_pads=False)
    hand.set_tip(0, np.array([0.0, 0.0, 15.0, 0.0, 0.0, 0.0]))
    hand.tare()
    ceiling = ForceCeiling(20.0, 0.2)
    hand.set_tip(0, np.array([0.0, 0.0, 30.0, 0.0, 0.0, 0.0]))
    assert ceiling.check(hand.tips()) is None  # what the old check saw: 15 N
    assert ceiling.check(hand.loads()) is not None  # the load: 30 N
    hand.set_tip(0, np.zeros(6))  # released
    assert ceiling.check(hand.loads()) is None
    assert hand.tips()[0, 2] == -15.0


def test_a_contact_that_fires_while_the_arm_stops_belongs_to_the_stops_reading():
    """A fingertip that touched while the arm decelerated after a trip, and bounced off before
    it was at rest, is in the move's reading with its contact point from its strongest load;
    a fingertip firing at the hold reads its load there; the reading without the stop is the
    hand's now."""
    hand = HandState(derive_pads=False)
    hand.set_hand_joints(0.0, np.full(3, 0.8))
    guard, stop = ContactGuard(), StopSensing()
    touch = np.array([0.4, 0.3, 2.9, 0.002, -0.01, 0.0])  # N, N m: tip 2 in the deceleration
    for load in (0.4 * touch, touch, 0.5 * touch):
        hand.set_tip(1, load)
        stop.add(guard.fired(hand.pads(), hand.tips()), hand.tips())
    hand.set_tip(1, np.zeros(6))  # bounced off
    hand.set_tip(2, touch)  # tip 3 pressed at the hold
    now, held = hand.reading(), hand.reading(stop)
    assert not now.fired[8] and np.isnan(now.tip_points[1]).all()
    assert held.fired[8] and held.fired[9] and not held.fired[7]
    at_peak = HandState(derive_pads=False)
    at_peak.set_hand_joints(0.0, np.full(3, 0.8))
    at_peak.set_tip(1, touch)
    np.testing.assert_allclose(held.tip_points[1], at_peak.reading().tip_points[1])
    np.testing.assert_allclose(held.tip_points[2], now.tip_points[2])
    np.testing.assert_array_equal(hand.tips(stop)[1], touch)
    np.testing.assert_array_equal(hand.tips(stop)[2], hand.tips()[2])
    assert not StopSensing().fired.any()
