"""The realistic world profile: each of its parameters has the effect it claims in MuJoCo, and
the nominal profile draws nothing."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from scipy import stats

from rrg_models import wam
from rrg_models.config import PHYSICS, SENSING, WORLD
from rrg_sim.config import NOMINAL, REALISTIC, WORLD_PROFILES
from rrg_sim.physics.realism import draw_conditions
from rrg_sim.physics.world import PhysicsWorld

SEEDS = range(40)


@pytest.fixture(scope="module")
def box_world() -> PhysicsWorld:
    return PhysicsWorld("box", profile="realistic")


def _binomial_ok(k: int, n: int, p: float) -> bool:
    """k of n is consistent with rate p (two-sided exact test at 1e-3)."""
    return stats.binomtest(k, n, p).pvalue > 1e-3


def test_the_nominal_profile_draws_nothing_and_both_profiles_are_named():
    assert set(WORLD_PROFILES) == {"nominal", "realistic"}
    c = draw_conditions(NOMINAL, np.random.default_rng(0))
    assert not c.joint_offset.any() and c.table_dz == 0.0 and c.friction is None
    w = PhysicsWorld("box")
    np.testing.assert_allclose(w.hand_pose(), w.true_hand_pose(), atol=1e-12)
    np.testing.assert_allclose(w.hand_pose_error(), 0.0, atol=1e-12)


def test_joint_offsets_are_drawn_per_trial_and_move_the_palm_by_their_amount(box_world):
    """The encoders read q_true + offset: the servos bring the readings to their targets, so
    the true palm sits at the forward kinematics of q_true, off the measured palm by the
    configured calibration error (≈ 0.88 mm per mrad of σ, config.REALISTIC's note)."""
    offsets, errors = [], []
    for seed in SEEDS:
        box_world.reseed(seed)
        box_world.reset()
        c = box_world.conditions
        offsets.append(c.joint_offset)
        np.testing.assert_allclose(box_world.arm_q(), wam.HOME_Q, atol=1e-4)  # reads home
        q_true = box_world.data.qpos[box_world._arm_q]
        np.testing.assert_allclose(q_true, wam.HOME_Q - c.joint_offset, atol=1e-9)
        expected = wam.fk(q_true)
        expected[2, 3] -= c.table_dz  # the robot's base stands dz lower (the table test)
        np.testing.assert_allclose(box_world.true_hand_pose(), expected, atol=1e-9)
        errors.append(
            np.linalg.norm(box_world.true_hand_pose()[:3, 3] - box_world.hand_pose()[:3, 3])
        )
    offsets = np.array(offsets)
    assert np.std(offsets) == pytest.approx(REALISTIC.joint_offset_sigma, rel=0.2)
    # the same seed draws the same offsets; another seed others
    box_world.reseed(3)
    np.testing.assert_array_equal(box_world.conditions.joint_offset, offsets[3])
    assert not np.allclose(offsets[3], offsets[4])
    mean_mm = 1000 * np.mean(errors)
    assert 0.5 * 8.8 < mean_mm < 1.5 * 8.8, mean_mm


def test_the_servos_hold_the_offset_arm_where_it_reads_its_target(box_world):
    """After a move and a hold, the arm reads its commanded target (the servo closes its loop
    on the offset encoders), so the offset stays invisible to the robot."""
    box_world.reseed(5)
    box_world.reset()
    target = wam.HOME_Q + np.array([0.05, -0.05, 0.0, 0.05, 0.0, 0.05, 0.0])
    box_world.follow(np.vstack([box_world.arm_q(), target]), np.array([0.0, 1.0]))
    box_world.hold(1.0)
    np.testing.assert_allclose(box_world.arm_q(), target, atol=2e-3)


def test_joint_readings_are_quantized_to_the_encoder_resolution(box_world):
    box_world.reseed(1)
    box_world.reset()
    res = np.asarray(REALISTIC.joint_resolution)
    q = box_world.arm_q()
    np.testing.assert_allclose(q / res, np.round(q / res), atol=1e-6)
    assert np.all(res < 1e-4) and np.all(res > 1e-6)


def test_the_arm_servos_saturate_at_the_torque_limits(box_world):
    limit = np.asarray(REALISTIC.arm_torque_limit)
    box_world.reseed(0)
    box_world.reset()
    box_world.data.ctrl[:7] = box_world.arm_q() + 1.0  # a large step: the PD asks for more
    mujoco.mj_step(box_world.model, box_world.data)
    force = box_world.data.actuator_force[:7]
    np.testing.assert_allclose(np.abs(force), limit, rtol=1e-9)
    box_world.reset()


def test_the_table_stands_higher_or_lower_relative_to_the_robot(box_world):
    """The object rests on the table, which the trial's draw puts dz higher relative to the
    robot than modelled: the palm truly stands dz lower than it measures."""
    dz = []
    for seed in SEEDS:
        box_world.reseed(seed)
        box_world.reset(np.array(WORLD.nominal_pose))
        c = box_world.conditions
        dz.append(c.table_dz)
        error = box_world.true_hand_pose()[:3, 3] - box_world.hand_pose()[:3, 3]
        # the palm's error: the joint offsets' part plus -dz in height
        q_true = box_world.data.qpos[box_world._arm_q]
        np.testing.assert_allclose(
            error[2], (wam.fk(q_true) - box_world.hand_pose())[2, 3] - c.table_dz, atol=1e-9
        )
        assert box_world.object_height() == pytest.approx(0.0, abs=5e-4)
    assert np.std(dz) == pytest.approx(REALISTIC.table_height_sigma, rel=0.3)


def test_friction_draws_decide_when_a_pushed_object_slides(box_world):
    """A horizontal push below μ m g leaves the object at rest, one above it slides it: μ is the
    trial's draw, within the profile's range."""
    m = box_world.model
    body = box_world._obj_body
    mass = float(m.body_subtreemass[body])
    g = -m.opt.gravity[2]
    mus = []
    for seed in (2, 9):
        box_world.reseed(seed)
        mu = box_world.conditions.friction
        mus.append(mu)
        lo, hi = REALISTIC.friction_range
        assert lo <= mu <= hi
        for factor, slides in ((0.7, False), (1.3, True)):
            box_world.reset(np.array(WORLD.nominal_pose))
            y0 = box_world.true_object_pose()[1]
            # along the box's 20 cm length (world y at θ 0): it slides before it tips
            box_world.data.xfrc_applied[body, 1] = factor * mu * mass * g
            box_world.hold(0.3)
            box_world.data.xfrc_applied[body] = 0.0
            moved = box_world.true_object_pose()[1] - y0
            assert (moved > 0.005) == slides, (seed, factor, moved)
    assert mus[0] != mus[1]


def test_the_centre_of_mass_moves_by_the_drawn_offset(box_world):
    lo, hi = REALISTIC.com_offset_range
    base = PhysicsWorld("box").model.body_ipos[box_world._obj_body]
    for seed in SEEDS:
        box_world.reseed(seed)
        off = box_world.model.body_ipos[box_world._obj_body] - base
        np.testing.assert_allclose(off, box_world.conditions.com_offset, atol=1e-12)
        assert lo <= np.linalg.norm(off) <= hi and off[2] == 0.0


def test_pads_miss_at_the_configured_rate_and_a_dead_pad_stays_silent(box_world, monkeypatch):
    sensors = box_world.sensors
    dead = 0
    n = 0
    for seed in range(300):
        box_world.reseed(seed)
        sensors.tare()
        dead += int(sensors.dead.sum())
        n += 7
    assert _binomial_ok(dead, n, REALISTIC.pad_miss)
    # Press the palm pad hard: it fires, unless this guarded move drew it dead.
    box_world.reseed(0)
    box_world.reset()
    pads = np.zeros(7)
    pads[0] = 10 * SENSING.pad_force_threshold
    sensors.dead[:] = False
    sensors._pad_sample_at = -1
    assert sensors._pads(pads)[0]
    sensors.dead[0] = True
    sensors._pad_sample_at = -1
    assert not sensors._pads(pads)[0]
    # The observation's readings see the same pads as the guard: the dead palm pad is silent.
    monkeypatch.setattr(sensors, "read", lambda: (pads, np.zeros((3, 6))))
    sensors._pad_sample_at = -1
    assert not box_world.reading().fired[0] and not sensors.fired()[0]
    sensors.dead[0] = False
    sensors._pad_sample_at = -1
    assert box_world.reading().fired[0]


def test_pads_fire_falsely_at_the_configured_rate_for_one_sample(box_world):
    sensors = box_world.sensors
    box_world.reseed(0)
    box_world.reset()
    fired = 0
    trials = 400
    for _ in range(trials):
        sensors.schedule_false_alarms(500)
        fired += int((sensors.false_alarm_at >= 0).sum())
    assert _binomial_ok(fired, 7 * trials, REALISTIC.pad_false_alarm)
    # A scheduled false alarm fires its pad, with nothing touching, during one pad sample.
    period = sensors.pad_period
    sensors.false_alarm_at[:] = -1
    sensors.false_alarm_at[3] = 3 * period + 2
    seen = []
    for k in range(6 * period):
        box_world.data.time = k * PHYSICS.timestep
        seen.append(bool(sensors._pads(np.zeros(7))[3]))
    assert seen == [3 * period <= k < 4 * period for k in range(6 * period)]
    sensors.restart()


def test_pads_are_sampled_at_the_profile_rate(box_world):
    """A pad reading changes only at pad-sample instants (50 Hz: every 10th control period)."""
    sensors = box_world.sensors
    box_world.reseed(0)
    box_world.reset()
    sensors.dead[:] = False
    period = sensors.pad_period
    assert period == round(REALISTIC.pad_period / PHYSICS.timestep) == 10
    touch = np.zeros(7)
    states = []
    for k in range(40):
        box_world.data.time = k * PHYSICS.timestep
        touch[1] = 1.0 if k >= 13 else 0.0  # contact from period 13 on
        states.append(bool(sensors._pads(touch)[1]))
    assert states == [k >= 20 for k in range(40)]  # seen at the next sample, period 20
    sensors.restart()


def test_nano17_noise_is_atis_resolution():
    """With nothing touching, each Nano17 axis reads noise of σ = ATI's resolution."""
    w = PhysicsWorld("box", seed=0, profile="realistic")
    w.sensors.tare()
    forces, torques = [], []
    for _ in range(3000):
        _, wrench = w.sensors.read()
        forces.append(wrench[:, :3])
        torques.append(wrench[:, 3:])
    assert np.std(forces) == pytest.approx(REALISTIC.nano17_force_noise, rel=0.05)
    assert np.std(torques) == pytest.approx(REALISTIC.nano17_torque_noise, rel=0.05)


@pytest.mark.parametrize("confirm", [True, False], ids=["confirmed", "unconfirmed"])
def test_a_false_pad_alarm_stops_a_guarded_move_only_without_confirmation(confirm):
    """Every pad fires falsely once, for one 50 Hz sample, during a guarded move through free
    space: confirmed stops ride through all seven alarms, unconfirmed ones stop at the first."""
    import dataclasses

    from rrg_models.poses import raised

    alarms = dataclasses.replace(NOMINAL, name="alarms", pad_period=0.02, pad_false_alarm=1.0)
    world = PhysicsWorld("box", seed=1, profile=alarms, confirm_stops=confirm)
    down = raised(world.hand_pose(), -0.15)[None]  # 15 cm down, still 40 cm above the table
    _, _, stop = world.move_through(down, guard=True)
    assert (stop is None) == confirm


@pytest.mark.parametrize("case", range(6))
def test_confirmation_does_not_delay_a_stop_on_a_real_contact(case):
    """The guarded-move cases of test_physics_guarded, with the pads at 50 Hz: each stops on a
    real contact in the same control period with and without confirmation (a Nano17 or the
    collision detection agrees at once, or the pad holds for the next sample)."""
    import dataclasses

    from test_physics_guarded import CASES

    name, wrt, _ = CASES[case]
    slow_pads = dataclasses.replace(NOMINAL, name="slow-pads", pad_period=0.02)
    stops = []
    for confirm in (False, True):
        world = PhysicsWorld(name, seed=3, profile=slow_pads, confirm_stops=confirm)
        _, _, stop = world.move_through(wrt.world_poses(world.true_object_pose()), guard=True)
        stops.append(stop)
        assert world.unconfirmed_stops == 0
    assert stops[0] is not None and stops[0] == stops[1]


def test_a_world_profile_spec_sets_the_numbers_whose_sensitivity_is_shown():
    from rrg_sim.config import world_profile

    assert world_profile("realistic") is REALISTIC and world_profile("nominal") is NOMINAL
    p = world_profile("realistic:joint_offset_sigma=0.0025,pad_false_alarm=0.01")
    assert p.name == "realistic:joint_offset_sigma=0.0025,pad_false_alarm=0.01"
    assert p.joint_offset_sigma == 0.0025 and p.pad_false_alarm == 0.01
    assert p.pad_miss == REALISTIC.pad_miss and p.friction_range == REALISTIC.friction_range
    for bad, why in (
        ("wobbly", "unknown world profile"),
        ("realistic:friction_range=1", "is not one of"),
        ("realistic:pad_miss=lots", "needs a number"),
        ("realistic:pad_miss=-1", ">= 0"),
    ):
        with pytest.raises(ValueError, match=why):
            world_profile(bad)
