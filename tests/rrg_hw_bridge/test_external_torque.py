"""The arm's external torque from its motors' torques (rrg_hw_bridge.external_torque), on the
emulated WAM, whose controller reports the torques a real one does: gravity and motion included,
with their noise. Free motion never trips the effort guard; a contact of the configured size
does, and without the observer the arm's own motion would."""

from __future__ import annotations

import numpy as np
import pytest

from rrg_fake_hw.emulated_robot import EmulatedRobot
from rrg_hw_bridge.contact_guard import ContactGuard
from rrg_hw_bridge.external_torque import ExternalTorqueObserver
from rrg_models import wam
from rrg_models.config import PHYSICS, SENSING

BOX_POSE = np.array([0.625, 0.004, 0.05])
#: A configuration near home, 0.15-0.2 rad away on four joints.
AWAY = wam.HOME_Q + np.array([0.15, -0.1, 0.1, 0.2, 0.0, 0.1, 0.0])
#: Free motions (seconds, target): fast (about 0.2 rad/s, up to 6 rad/s² at the ends) and slow.
MOTIONS = ((1.0, AWAY), (1.0, wam.HOME_Q), (3.0, AWAY), (3.0, wam.HOME_Q))
THRESHOLD = SENSING.arm_torque_threshold  # N m


def hand_state(s) -> tuple[np.ndarray, np.ndarray]:
    return np.r_[s.spread, s.proximal, s.distal], np.r_[
        s.spread_velocity, s.proximal_velocity, s.distal_velocity
    ]


def run(robot: EmulatedRobot, observer: ExternalTorqueObserver, seconds: float, t0: float):
    """Step the robot ``seconds``, feeding every joint state to the observer; returns the
    estimates (N,7) [N m], the raw motor torques (N,7) [N m] and the time after."""
    estimates, raw, t = [], [], t0
    for _ in range(int(round(seconds / PHYSICS.timestep))):
        robot.advance(PHYSICS.timestep)
        t += PHYSICS.timestep
        s = robot.snapshot(pads=False)
        estimates.append(observer.update(t, s.arm_q, s.arm_qd, s.arm_effort, *hand_state(s)))
        raw.append(s.arm_effort)
    return np.array(estimates), np.array(raw), t


def first_trip(efforts: np.ndarray, baseline: np.ndarray) -> int | None:
    """Index of the first sample at which a ContactGuard with the default threshold trips."""
    guard = ContactGuard(effort_threshold=THRESHOLD)
    guard.start(baseline)
    for k, e in enumerate(efforts):
        if guard.check_effort(e) is not None:
            return k
    return None


@pytest.fixture
def robot() -> EmulatedRobot:
    r = EmulatedRobot("box", seed=7, sensor_noise=1.0)
    r.reset("box", BOX_POSE)
    r.advance(0.3)
    return r


def test_free_motion_never_trips_the_guard_but_would_without_the_observer(robot):
    observer = ExternalTorqueObserver()
    estimates, raw, t = run(robot, observer, 0.1, 0.0)
    base, raw_base = estimates[-25:].mean(axis=0), raw[-25:].mean(axis=0)
    for seconds, target in MOTIONS:
        robot.follow(target[None], [seconds])
        est, torques, t = run(robot, observer, seconds + 0.4, t)
        assert np.abs(est - base).max() < THRESHOLD / 2, np.abs(est - base).max(axis=0)
        assert first_trip(est, base) is None
        # the motors' torques themselves change by far more than the threshold
        assert first_trip(torques, raw_base) is not None
        assert np.abs(torques - raw_base).max() > 3 * THRESHOLD


@pytest.mark.parametrize("size, trips", [(2.0, True), (0.5, False)])
def test_a_contact_of_the_configured_size_trips_the_guard(robot, size, trips):
    """A push on the palm whose largest joint torque is ``size`` × the threshold, during a
    slow move: the estimate follows the true torque, and the guard trips when size > 1."""
    observer = ExternalTorqueObserver()
    estimates, _, t = run(robot, observer, 0.1, 0.0)
    base = estimates[-25:].mean(axis=0)
    robot.follow(AWAY[None], [3.0])
    est, _, t = run(robot, observer, 0.5, t)
    robot.set_palm_push(1.0)
    per_newton = np.abs(robot.palm_push_torque()).max()  # N m per N, here
    robot.set_palm_push(size * THRESHOLD / per_newton)
    est, _, t = run(robot, observer, 0.5, t)
    truth = robot.palm_push_torque()  # the arm moved on meanwhile
    assert np.abs(truth).max() == pytest.approx(size * THRESHOLD, rel=0.15)
    np.testing.assert_allclose(est[-25:].mean(axis=0), truth, atol=0.1)
    k = first_trip(est, base)
    if trips:
        assert k is not None and k * PHYSICS.timestep < 0.05  # within 50 ms of the push
    else:
        assert k is None


def test_lost_joint_states_are_skipped_and_a_long_silence_restarts_the_observer(robot):
    """Joint states lost at the start of a fast motion (the torque between their neighbours
    unknown) leave the estimate where it was: the interval is skipped; with the interval used,
    the same loss shows up as torque several times the noise. After a silence longer than
    max_gap_s the estimate starts again from zero."""
    kept, used = ExternalTorqueObserver(), ExternalTorqueObserver(gap_factor=np.inf)
    t, peaks = 0.0, {"kept": 0.0, "used": 0.0}
    _, _, t = run(robot, kept, 0.1, t)
    robot.follow(AWAY[None], [0.3])  # 0.3 rad in 0.3 s: up to 20 rad/s² at the start
    for k in range(300):
        robot.advance(PHYSICS.timestep)
        t += PHYSICS.timestep
        if k % 50 < 9:  # 18 ms lost every 100 ms from the start on, as seen on a loaded host
            continue
        s = robot.snapshot(pads=False)
        args = (t, s.arm_q, s.arm_qd, s.arm_effort, *hand_state(s))
        peaks["kept"] = max(peaks["kept"], np.abs(kept.update(*args)).max())
        peaks["used"] = max(peaks["used"], np.abs(used.update(*args)).max())
    assert kept.gaps >= 6
    assert peaks["kept"] < THRESHOLD / 2, peaks
    assert peaks["used"] > 3 * peaks["kept"], peaks
    robot.set_palm_push(10.0)
    est, _, t = run(robot, kept, 0.3, t)
    assert np.abs(est[-1]).max() > 2.0
    s = robot.snapshot(pads=False)
    again = kept.update(t + 0.5, s.arm_q, s.arm_qd, s.arm_effort, *hand_state(s))
    np.testing.assert_array_equal(again, np.zeros(7))
