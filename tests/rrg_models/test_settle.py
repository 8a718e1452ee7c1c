"""The grasp-settling model: the affine fit of the settling study, the committed fits, and
the belief moving after a firm goal grasp (agent and estimator alike)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from rrg_estimator.belief import Belief
from rrg_estimator.config import LOW
from rrg_estimator.grid import Grid
from rrg_estimator.tracker import settle_after_grasp
from rrg_models.goal import load_settling
from rrg_models.objects import PAPER_OBJECTS, get_object
from rrg_models.objects.object_model import SETTLING_FILE
from rrg_models.poses import relative_planar
from rrg_sim.physics.settle import fit_affine


def test_fit_affine_recovers_a_known_map_with_its_noise():
    rng = np.random.default_rng(7)
    start = rng.uniform(-1, 1, (400, 3)) * (0.02, 0.02, 0.2)
    A = np.array([[0.5, 0.1, 0.0], [0.0, 0.9, 0.02], [-3.0, 2.0, 0.8]])
    b = np.array([-0.003, 0.001, 0.07])
    after = start @ A.T + b + rng.normal(0, 1, (400, 3)) * (0.001, 0.002, 0.03)
    after[:5, 2] += 2 * np.pi  # a wrapped angle reads as the same small turn
    f = fit_affine(start, after, ignores_theta=False)
    np.testing.assert_allclose(f["A"], A, atol=0.15)
    np.testing.assert_allclose(f["b"], b, atol=0.005)
    np.testing.assert_allclose(f["sigma"], (0.001, 0.002, 0.03), rtol=0.15)
    sym = fit_affine(start, after, ignores_theta=True)  # θ of a symmetric object is left alone
    assert sym["A"][2] == [0.0, 0.0, 1.0] and sym["b"][2] == 0.0 and sym["sigma"][2] == 0.0


@pytest.mark.parametrize("name", PAPER_OBJECTS)
def test_every_object_has_a_committed_settling_fit(name):
    s = load_settling(get_object(name).folder / SETTLING_FILE)
    assert s is not None and "arrived" in s.source
    assert np.all(s.box > 0) and np.all(s.retreated.sigma >= 0)
    assert (get_object(name).settling is None) == (not get_object(name).track_settling)


@pytest.mark.parametrize("name", PAPER_OBJECTS)
def test_every_object_has_a_realistic_settling_study_that_the_realistic_planner_reads(name):
    """The study measured in the realistic world (settle --world realistic) is committed, and
    a profile spec of that world reads it; the nominal world keeps its own."""
    from rrg_models.objects.object_model import settling_file

    obj = get_object(name)
    assert settling_file("realistic") == "settling.realistic.json"
    s = obj.settling_in("realistic")
    assert s is not None and "--world realistic" in s.source and s is not obj.grasp_settling
    assert obj.settling_in("realistic:joint_offset_sigma=0.0025") is s
    assert obj.settling_in("nominal") is obj.grasp_settling


def test_a_missing_realistic_study_falls_back_to_the_nominal_one(tmp_path, monkeypatch):
    import dataclasses

    box = dataclasses.replace(get_object("box"), folder=tmp_path)  # a folder without studies
    assert box.settling_in("realistic") is None is box.grasp_settling


def test_a_firm_goal_grasp_moves_the_belief_and_an_early_contact_does_not():
    obj = get_object("powerdrill")  # its grasp turns a centred drill by about -0.03 rad
    e = np.array([0.62, 0.0, 0.0])
    b = Belief.gaussian(Grid.for_level(LOW, center=e), e, (0.003, 0.003, 0.02))
    after = settle_after_grasp(b, obj, obj.goal_wrt, e, contact=False)
    turn = relative_planar(e, after.mean())[2] - relative_planar(e, b.mean())[2]
    measured = obj.settling.outcome(np.zeros((1, 3)), "retreated")[0][0, 2]
    assert measured < -0.015 and turn == pytest.approx(measured, abs=0.01)
    assert settle_after_grasp(b, obj, obj.goal_wrt, e, contact=True) is b
    assert settle_after_grasp(b, obj, obj.info_wrts[0], e, contact=False) is b


def test_the_estimator_settles_as_measured_in_the_planners_world():
    """In the realistic world a goal grasp's retreat moves the belief as the realistic study
    says, as the planner's goal model expects; the nominal world keeps its own study."""
    from rrg_estimator.tracker import BeliefTracker
    from rrg_estimator.transition import settle

    obj = get_object("powerdrill")
    e = np.array([0.62, 0.0, 0.0])
    b = Belief.gaussian(Grid.for_level(LOW, center=e), e, (0.003, 0.003, 0.02))
    real = settle_after_grasp(b, obj, obj.goal_wrt, e, contact=False, world="realistic")
    expected = settle(b, obj.settling_in("realistic"), e)
    np.testing.assert_allclose(real.weights, expected.weights, atol=1e-12)
    nominal = settle_after_grasp(b, obj, obj.goal_wrt, e, contact=False)
    assert not np.allclose(real.weights, nominal.weights, atol=1e-6)
    tracker = BeliefTracker(obj, b, world="realistic", variable_resolution=False)
    tracker.pending = (obj.goal_wrt, e, False)
    np.testing.assert_allclose(tracker.retreated().weights, expected.weights, atol=1e-12)


def test_the_estimator_settles_a_firm_goal_grasp_when_the_hand_retreats():
    """BeliefTracker: the belief that follows a goal grasp is the one that judged it; the
    settling is applied when the hand retreats, or, when no retreat was reported, before the
    next observation's update."""
    from rrg_estimator.tracker import BeliefTracker, wrt_posterior
    from rrg_sim.geometric_sim import GeometricSimulator

    mean = np.array([0.62, 0.0, 0.0])
    tracker = BeliefTracker.gaussian(
        "powerdrill", mean, LOW.sigma, level=LOW, variable_resolution=False
    )
    obj, goal, info = tracker.obj, tracker.obj.goal_wrt, tracker.obj.info_wrts[0]
    grasped = GeometricSimulator(obj, goal).simulate(mean, mean)
    assert not grasped.contact
    after_goal = tracker.update(goal.name, mean, grasped)
    assert after_goal is tracker.belief
    settled = settle_after_grasp(after_goal, obj, goal, mean, contact=False)
    np.testing.assert_allclose(tracker.retreated().weights, settled.weights, atol=1e-12)
    assert tracker.retreated() is tracker.belief  # nothing more to apply
    sensed = GeometricSimulator(obj, info).simulate(mean, mean)
    table = tracker.tables.table(info.name, tracker.belief.grid)
    expected = wrt_posterior(settled, table, info, mean, sensed)
    np.testing.assert_allclose(
        tracker.update(info.name, mean, sensed).weights, expected.weights, atol=1e-12
    )
    unsettled = wrt_posterior(after_goal, table, info, mean, sensed)
    assert np.abs(unsettled.weights - expected.weights).sum() > 0.05  # the settling mattered
    # An update the core refuses keeps the belief and the pending retreat.
    refused = BeliefTracker.gaussian(
        "powerdrill", mean, LOW.sigma, level=LOW, variable_resolution=False
    )
    before = refused.update(goal.name, mean, grasped)
    pushed = GeometricSimulator(obj, info).simulate(mean, mean)
    pushed = dataclasses.replace(pushed, contact=True, motion_dir=np.full(3, np.nan))
    with pytest.raises(ValueError, match="motion direction"):
        refused.update(info.name, mean, pushed)
    assert refused.belief is before
    np.testing.assert_allclose(refused.retreated().weights, settled.weights, atol=1e-12)
    # Without a reported retreat, the next update applies it first.
    lazy = BeliefTracker.gaussian(
        "powerdrill", mean, LOW.sigma, level=LOW, variable_resolution=False
    )
    lazy.update(goal.name, mean, grasped)
    np.testing.assert_allclose(
        lazy.update(info.name, mean, sensed).weights, expected.weights, atol=1e-12
    )


def test_the_outcome_corrects_the_affine_map_where_the_samples_say_so():
    """A closing that turns the object by +0.1 rad for Δθ < 0 and not at all otherwise: the
    affine fit averages the two; the kernel-corrected outcome follows each side, and is the
    affine map where there are no samples."""
    from rrg_models.goal import AffineSettle, Settling

    rng = np.random.default_rng(3)
    start = rng.uniform(-1, 1, (600, 3)) * (0.02, 0.02, 0.25)
    closed = (
        start + np.where(start[:, 2:] < 0, 0.1, 0.0) * [0, 0, 1] + rng.normal(0, 0.002, (600, 3))
    )
    f = fit_affine(start, closed, ignores_theta=False)
    fit = AffineSettle(np.array(f["A"]), np.array(f["b"]), np.array(f["sigma"]))
    box, bandwidth = np.array([0.02, 0.02, 0.25]), np.array([0.005, 0.005, 0.03])
    s = Settling(
        box, fit, fit, "test", start=start, samples={"closed": closed}, bandwidth=bandwidth
    )
    q = np.array([[0.0, 0.0, -0.15], [0.0, 0.0, 0.15]])
    mean, sigma = s.outcome(q, "closed")
    np.testing.assert_allclose(mean[:, 2], [-0.05, 0.15], atol=0.02)
    assert np.all(sigma[:, 2] < 0.5 * fit.sigma[2])  # sharper than the affine residual
    for bare in (
        Settling(box, fit, fit, "test", bandwidth=bandwidth),
        s,
    ):  # no samples of this stage
        mean, sigma = bare.outcome(q, "retreated" if bare is s else "closed")
        np.testing.assert_allclose(mean, fit.apply(q), atol=1e-12)
        np.testing.assert_allclose(sigma, np.broadcast_to(fit.sigma, (2, 3)))


def test_the_goal_weights_follow_the_drill_grasps_measured_turn_and_hold():
    """The drill's closing turns it by about -0.03 rad near the centre (the committed study):
    a drill turned +0.1 rad from the estimate is likelier to end in the goal region than one
    turned -0.1 rad, though both start inside its ±10° region; the weights also carry the
    measured chance that the grasp presses the trigger and holds; beyond the studied box
    nothing moves."""
    from rrg_models.goal import goal_holds, goal_weights

    obj = get_object("powerdrill")
    delta = np.array([[0.0, 0.0, 0.1], [0.0, 0.0, -0.1], [0.0, 0.0, 0.0], [0.03, 0.0, 0.0]])
    contact = np.zeros(4, dtype=bool)
    sensors = np.zeros((4, 10), dtype=bool)
    sensors[:, 4:7] = True  # the three fingertips
    p = goal_weights(obj.goal, delta, contact, sensors, settling=obj.grasp_settling)
    hold = obj.settling.hold_probability(delta[:3])
    assert goal_holds(obj.goal, delta[:2], contact[:2], sensors[:2]).all()
    assert p[0] > p[1] + 0.05 and p[2] > 0.9 and p[3] == 0.0
    assert np.all(p[:3] <= hold + 1e-12) and np.all((hold > 0.5) & (hold < 1.0))
    assert (
        goal_weights(obj.goal, delta, ~contact, sensors, settling=obj.grasp_settling).max() == 0.0
    )  # an early contact never grasps


def test_the_hold_probability_is_the_local_share_of_study_grasps_that_held():
    """Settling.hold_probability: where every nearby sample held it is near 1, where none
    did near 0, and half-way between in between."""
    from rrg_models.goal import Settling

    fit = load_settling(get_object("powerdrill").folder / SETTLING_FILE).closed
    start = np.array([[x, 0.0, 0.0] for x in np.linspace(-0.02, 0.02, 41)])
    held = (start[:, 0] < 0.0).astype(float)  # held left of centre only
    s = Settling(
        np.array([0.02, 0.02, 0.2]),
        fit,
        fit,
        "test",
        start=start,
        held=held,
        bandwidth=np.array([0.002, np.inf, np.inf]),
    )
    p = s.hold_probability(np.array([[-0.015, 0.0, 0.0], [0.0, 0.0, 0.0], [0.015, 0.0, 0.0]]))
    assert p[0] > 0.99 and 0.3 < p[1] < 0.7 and p[2] < 0.01


def test_a_coarse_grid_points_goal_weight_is_the_regions_average_over_its_cell():
    """On the high-uncertainty grid a point stands for its cell: the teacup's point -0.1 rad
    off the estimate (where its closing leaves it best placed, but the cell reaches 0.15 rad
    off, outside the 8° region) and the centre count less, and no cell reaches 0.9."""
    from rrg_models.goal import goal_weights

    obj = get_object("giant_teacup")
    delta = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -0.1], [0.02, 0.0, 0.0]])
    contact = np.zeros(3, dtype=bool)
    sensors = np.zeros((3, 10), dtype=bool)
    sensors[:, 4:7] = True  # the three fingertips
    point = goal_weights(obj.goal, delta, contact, sensors, settling=obj.grasp_settling)
    cell = goal_weights(
        obj.goal, delta, contact, sensors, cell=(0.01, 0.01, 0.1), settling=obj.grasp_settling
    )
    fine = goal_weights(
        obj.goal, delta, contact, sensors, cell=(0.002, 0.002, 0.013), settling=obj.grasp_settling
    )
    assert point[1] > 0.7 and cell[0] < point[0] and cell[1] < point[1] and cell.max() < 0.9
    assert np.allclose(fine, point, atol=0.05)  # the low grid's cells are small
    assert cell[2] < 0.05 and point[2] < 0.05  # 2 cm off: out, cell or not
