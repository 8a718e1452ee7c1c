"""The judge's failure paths, in MuJoCo physics: every success rate rests on them. Each case
is a real grasp that must be judged a failure for its own reason, and the strict test's
first-touch offset."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from rrg_models.config import PHYSICS, WORLD
from rrg_models.goal import RequiredContact
from rrg_models.poses import compose_planar
from rrg_sim.physics import judge
from rrg_sim.physics.judge import judge_grasp
from rrg_sim.physics.world import PhysicsWorld

pytestmark = pytest.mark.slow  # MuJoCo grasps

E = np.asarray(WORLD.nominal_pose, dtype=float)


def _grasp(name: str, delta) -> tuple[PhysicsWorld, object]:
    """The goal WRT run at the nominal estimate with the object at offset delta, noiseless."""
    world = PhysicsWorld(name, sensor_noise=0.0)
    world.reset(compose_planar(E, np.asarray(delta, dtype=float)))
    obs = world.execute_wrt(world.obj.goal_wrt, E)
    return world, obs


def test_a_grasp_in_its_region_that_slips_out_during_the_lift_fails():
    """The can enveloped by all three fingers, inside its goal region, slides
    out of the hand: not held, so not a success (MuJoCo: so do its neighbours 3 mm away)."""
    world, obs = _grasp("can", (-0.010, -0.0095, 0.0))
    ok, info = judge_grasp(world, world.obj, E)
    assert info["in_region"] and info["fingers"] == 3 and info["lift_feasible"]
    assert not info["held"] and info["lift_dz"] < judge.HELD_FRACTION * PHYSICS.lift_height
    assert not ok and not info["strict_success"]


def test_an_object_touched_by_one_fingertip_is_not_held():
    """The tea box met off-centre by one finger: one finger in contact, it is not lifted."""
    world, obs = _grasp("teabox", (0.011, -0.018, -0.367))
    ok, info = judge_grasp(world, world.obj, E)
    assert info["fingers"] == 1 and info["fingers"] < world.obj.goal.min_fingers
    assert not info["held"] and not ok


def test_the_judge_counts_the_fingers_that_truly_touch_not_the_sensed_ones():
    """A centred box grasp holds with three fingers on the box. Judged on an observation in
    which finger 3's sensors stayed silent (a missed pad), it still succeeds: the judge counts
    MuJoCo's contacts; the observation's two fingers are reported as sensed_fingers only."""
    world, obs = _grasp("box", (0.0, 0.0, 0.0))
    silent = obs.sensors.copy()
    silent[[3, 6, 9]] = False  # finger 3: proximal and distal pads, Nano17
    ok, info = judge_grasp(world, world.obj, E, dataclasses.replace(obs, sensors=silent))
    assert info["held"] and info["in_region"] and info["fingers"] == 3
    assert info["sensed_fingers"] == 2 and info["fingers_ok"] and ok


def test_too_few_fingers_truly_touching_fail_a_grasp_the_sensors_call_whole():
    """The tea box met off-centre by one finger, judged on an observation in which every
    finger's sensors fired (false alarms): one finger truly touches, so it fails."""
    world, obs = _grasp("teabox", (0.011, -0.018, -0.367))
    loud = obs.sensors.copy()
    loud[1:] = True
    ok, info = judge_grasp(world, world.obj, E, dataclasses.replace(obs, sensors=loud))
    assert info["sensed_fingers"] == 3 and info["fingers"] == 1 and not info["fingers_ok"]
    assert not ok


def test_a_missing_required_contact_fails_a_grasp_that_holds():
    """The drill's grasp presses the trigger; the same grasp asked to touch the chuck, which
    it does not reach, holds the drill and still fails."""
    world, obs = _grasp("powerdrill", (0.0, 0.0, 0.0))
    ok, info = judge_grasp(world, world.obj, E)
    assert info["required"] == {"trigger": True} and ok
    world, obs = _grasp("powerdrill", (0.0, 0.0, 0.0))
    chuck = dataclasses.replace(world.obj.goal, required_contacts=(RequiredContact("chuck", (3,)),))
    ok, info = judge_grasp(world, dataclasses.replace(world.obj, goal=chuck), E)
    assert info["held"] and info["in_region"] and info["required"] == {"chuck": False}
    assert not ok


def test_a_lift_that_cannot_be_planned_fails(monkeypatch):
    """A lift beyond the WAM's reach (1.5 m) has no IK path: the grasp cannot be held. (The
    grasp's own plan chose its lift to 10 cm; without it the executor plans one.)"""
    from rrg_sim.executor import wrt_executor

    world, obs = _grasp("box", (0.0, 0.0, 0.0))
    world.executor.last.lift = None
    far = dataclasses.replace(PHYSICS, lift_height=1.5)
    monkeypatch.setattr(judge, "PHYSICS", far)
    monkeypatch.setattr(wrt_executor, "PHYSICS", far)
    ok, info = judge_grasp(world, world.obj, E)
    assert not info["lift_feasible"] and not info["held"] and not ok


def test_the_strict_test_judges_the_offset_where_a_finger_first_touched():
    """The cup's closing pulls it toward the hand: a start 1.6 cm off along the closing
    direction ends inside the 1 cm region (a success) but first touched outside it (strict
    failure); a centred grasp passes both."""
    world, obs = _grasp("cup", (0.0, 0.0, 0.0))
    ok, info = judge_grasp(world, world.obj, E)
    assert ok and info["strict_success"] and info["touch_in_region"]
    pulled = []
    for dy in (-0.016, 0.016, -0.014, 0.014):
        world, obs = _grasp("cup", (0.0, dy, 0.0))
        ok, info = judge_grasp(world, world.obj, E)
        pulled.append((ok, info["touch_in_region"], info["strict_success"]))
    assert any(ok and not touch and not strict for ok, touch, strict in pulled), pulled


def test_the_strict_test_asks_the_first_touch_about_the_estimate_not_the_regions_centre():
    """An onboarded goal region is centred where the closing leaves the object; the first
    touch, before any closing, is judged against the tolerances about the estimate itself."""
    from dataclasses import replace

    world, obs = _grasp("cup", (0.0, 0.0, 0.0))
    shifted = replace(world.obj, goal=replace(world.obj.goal, centre=(0.0, 0.02, 0.0)))
    ok, info = judge_grasp(world, shifted, E)
    assert not ok and not info["in_region"] and info["touch_in_region"]
