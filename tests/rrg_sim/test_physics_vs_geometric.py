"""Physics observations agree with the geometric simulator's predictions on the same pose.

The geometric simulator assumes the object never moves, so agreement is checked over the
executions that left the object still (rrg_sim.physics.agreement.STILL). Over the whole
catalogue (goal + info WRTs, Δ = 0 and 11 seeded estimate errors of σ = 1.5 cm, 1.5 cm,
0.1 rad: ``python -m rrg_sim.physics.agreement --offsets 12``) 519 of 611
executions left the object still (the rest mostly pushed it while closing or sweeping), and
on those physics measured: contact flag agreement 0.99, |Δprogress| ≤ 1.6 mm, fired-sensor
Hamming distance 0/1/2 in 86/10/3 % of runs, P(fire | predicted) 0.99, P(fire | not
predicted) 0.02, |Δclosure| mean 0.013 rad (90 %: 0.022 rad), Nano17 contact point distance
median 1.0 mm (90 %: 4.1 mm). A firm goal grasp is the exception: it pulls the object as it
closes (last test).
"""

from __future__ import annotations

import numpy as np
import pytest

from rrg_models.config import WORLD
from rrg_models.poses import compose_planar
from rrg_sim.geometric_sim import GeometricSimulator
from rrg_sim.physics.agreement import agreement_stats, measure
from rrg_sim.physics.world import PhysicsWorld

#: Tolerances: about twice what the ``stats`` fixture below measures (6 objects, goal + info
#: WRTs, Δ = 0 and 1 seeded estimate error, seed 5: deterministic), the measured value in each
#: comment. A lower bound on a fraction doubles the measured shortfall from 1.
MIN_STILL_FRACTION = 0.74  # 54 of 62 runs left the object still: 0.871 (8 moved it)
MIN_CONTACT_AGREEMENT = 0.98  # 1.0 (54 of 54); no disagreement to double: one allowed (53/54)
MAX_PROGRESS_ERROR = 0.0009  # m; max |Δprogress| 0.00045
MIN_HAMMING_LE_2 = 0.96  # runs with at most 2 sensor flags different: 53/54 = 0.981
MIN_P_DETECT = 0.987  # P(fire | predicted) 0.9935 (1 of 154 predicted contacts missed)
MAX_P_FALSE_ALARM = 0.073  # P(fire | not predicted) 0.0363
MAX_CLOSURE_MEAN, MAX_CLOSURE_P90 = 0.027, 0.078  # rad; |Δclosure| mean 0.0134, 90 %: 0.0389
#: m; Nano17 contact point distance median 0.00099, 90 %: 0.0062
MAX_TIP_MEDIAN, MAX_TIP_P90 = 0.002, 0.0125
#: The firm goal grasp (last test): physics' finger-1 closures 8 mm apart differ by 0.032 rad.
MAX_FIRM_GRASP_CLOSURE_CHANGE = 0.065  # rad


@pytest.fixture(scope="module")
def stats():
    diffs = measure(
        names=("cooler", "cup", "teabox", "box", "wooden_bowl", "giant_teacup"), offsets=2, seed=5
    )
    return agreement_stats(diffs)


@pytest.mark.slow  # (its fixture: a MuJoCo campaign)
def test_enough_executions_leave_the_object_still(stats):
    assert stats["still"] >= MIN_STILL_FRACTION * stats["runs"]


@pytest.mark.slow
def test_contact_flag_and_progress_agree(stats):
    assert stats["contact_agreement"] >= MIN_CONTACT_AGREEMENT
    assert stats["progress_abs_max"] <= MAX_PROGRESS_ERROR


@pytest.mark.slow
def test_fired_sensors_agree(stats):
    hist = np.asarray(stats["hamming_hist"])
    assert hist[:3].sum() >= MIN_HAMMING_LE_2 * hist.sum()
    assert stats["p_detect"] >= MIN_P_DETECT and stats["p_false_alarm"] <= MAX_P_FALSE_ALARM


@pytest.mark.slow
def test_closure_and_fingertip_contacts_agree(stats):
    assert (
        stats["closure_abs_mean"] <= MAX_CLOSURE_MEAN
        and stats["closure_abs_p90"] <= MAX_CLOSURE_P90
    )
    assert stats["tip_dist_median"] <= MAX_TIP_MEDIAN and stats["tip_dist_p90"] <= MAX_TIP_P90


def test_a_firm_goal_grasp_pulls_the_object_so_its_closures_are_not_geometric():
    """Why goal WRTs have closure_informative False (wrt_generation.line_grasp_wrt): closing
    on the pitcher's handle bar 8 mm nearer or farther, the geometric model (nothing moves)
    predicts finger 1 closing 0.3 rad differently, but the fingers pull the bar into the palm
    and physics reads about the same angle both times. The info grasps keep theirs."""
    world = PhysicsWorld("brita_pitcher", seed=0)
    wrt = world.obj.goal_wrt
    assert not wrt.closure_informative and all(w.closure_informative for w in world.obj.info_wrts)
    geo = GeometricSimulator(world.obj, wrt)
    w = np.asarray(WORLD.nominal_pose, dtype=float)
    physics, predicted = [], []
    for dx in (-0.008, 0.008):
        e = compose_planar(w, (dx, 0.0, 0.0))
        world.reset(w)
        physics.append(world.execute_wrt(wrt, e).closure[0])
        predicted.append(geo.simulate(w, e).closure[0])
    assert abs(predicted[1] - predicted[0]) > 0.2
    assert abs(physics[1] - physics[0]) < MAX_FIRM_GRASP_CLOSURE_CHANGE
