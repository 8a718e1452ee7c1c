"""Judging a grasp in physics (algorithm §2, "Judging").

After a goal WRT has closed the hand, the grasp succeeds iff

* the object's true pose relative to the executed goal, Δ = relative_planar(e_used, w_true)
  taken before lifting, lies inside the object's goal region (its tolerances); where the
  profile's calibration error puts the hand elsewhere than the robot measures, e_used is
  first moved with the hand (PhysicsWorld.hand_pose_error), so Δ is relative to the hand,
* at least ``goal.min_fingers`` fingers truly touch the object once the hand has closed
  (MuJoCo's contacts over TOUCH_WINDOW before the lift, not the sensors: a pad that missed
  does not fail a grasp, a pad that fired falsely does not make one), the hand touches each
  of ``goal.required_contacts`` (the object parts, e.g. the drill's trigger, that the
  fingers must reach) in that window, and
* the object stays in the hand while the arm lifts it PHYSICS.lift_height and holds it
  PHYSICS.hold_time: still touching the hand and risen by at least HELD_FRACTION of the lift.
  The robot lifts as its executor does (WrtExecutor.lift: along the lift the goal grasp's
  plan chose, when the hand stands where that plan ends).

The judge judges the truth only. What the robot's own sensors said of the grasp (the
observation's fingers, ``info["sensed_fingers"]``) is the robot's business: its verification
(rrg_models.goal.goal_grasp_mismatches) may reject a grasp before it is ever judged.

The strict test (``info["strict_success"]``) also asks the offset where a finger first
touched the object, before the closing pulled it into the hand, to lie in the goal region's
tolerances about the estimate itself (a region's centre is where the closing leaves the object).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from rrg_models.config import PHYSICS
from rrg_models.objects import ObjectModel
from rrg_models.observation import Observation, fingers_in_contact
from rrg_models.poses import compose_planar, invert, relative_planar
from rrg_models.trajectory import InfeasiblePath
from rrg_sim.physics.world import PhysicsWorld

#: The object counts as lifted when it rose at least this fraction of the lift (chosen: a
#: grasp that lets it slide half-way out has failed).
HELD_FRACTION = 0.5

#: The closed hand is held this long [s] before the lift, and a finger touches what it touches
#: at any period of it (chosen: 25 control periods; contacts of a finger closed on the object
#: come and go between periods).
TOUCH_WINDOW = 0.05


def _object_in_hand_frame(world: PhysicsWorld) -> np.ndarray:
    return invert(world.true_hand_pose()) @ world.object_pose()


def judge_grasp(
    world: PhysicsWorld,
    obj: ObjectModel,
    e_used,
    observation: Observation | None = None,
    goal: str | None = None,
) -> tuple[bool, dict]:
    """Lift and hold the grasp the last goal WRT left in ``world``; returns (success, info).
    ``observation``: that WRT's observation (default: the last one the world's own executor
    made; the simulator node passes the one the executor node published). ``goal``: which of
    the object's goal grasps ran, judged against its own region (default: the one the world's
    own executor ran last, else "goal").

    info: goal (the goal grasp judged), delta (Δ), in_region, touch_delta (Δ where a finger
    first touched), touch_in_region, strict_success, fingers (truly touching the object),
    sensed_fingers (with a sensor fired in the observation), fingers_ok (at least the
    goal's, truly), required_ok, required (each required contact made), touching (finger →
    object parts touched before the lift), held, lift_feasible, lift_dz [m], slip [m]
    (object displacement in the hand frame during lift and hold), early_contact, w_true
    (object pose before lifting), hand_error (the planar calibration error at the grasp,
    PhysicsWorld.hand_pose_error).
    """
    obs = world.last_observation if observation is None else observation
    if obs is None:
        raise RuntimeError("judge_grasp needs a WRT execution first")
    if goal is None:
        last = world.executor.last
        goal = last.wrt.name if last is not None and last.wrt.kind == "goal" else "goal"
    region = obj.goal_region(goal)
    touching = world.touching_while_held(TOUCH_WINDOW)
    w_true = world.true_object_pose()
    hand_error = world.hand_pose_error()
    e_hand = compose_planar(hand_error, np.asarray(e_used, dtype=float))
    delta = relative_planar(e_hand, w_true)
    in_region = bool(region.contains(delta))
    fingers = sum(1 for f in (1, 2, 3) if touching.get(f))
    required = {rc.name: rc.met(touching) for rc in region.required_contacts}
    required_ok = all(required.values())
    touch_pose = (
        world.true_object_pose() if world.first_touch_pose is None else world.first_touch_pose
    )
    touch_delta = relative_planar(e_hand, touch_pose)
    touch_in_region = bool(replace(region, centre=(0.0, 0.0, 0.0)).contains(touch_delta))
    z0, grip0 = world.object_height(), _object_in_hand_frame(world)
    try:
        world.executor.lift()
        lift_feasible = True
    except InfeasiblePath:  # the arm cannot lift from this grasp: it cannot be held either
        lift_feasible = False
    world.hold(PHYSICS.hold_time)
    lift_dz = world.object_height() - z0
    held = (
        lift_feasible and world.object_in_hand() and lift_dz >= HELD_FRACTION * PHYSICS.lift_height
    )
    slip = float(np.linalg.norm(_object_in_hand_frame(world)[:3, 3] - grip0[:3, 3]))
    fingers_ok = fingers >= region.min_fingers
    success = held and in_region and fingers_ok and required_ok
    info = dict(
        goal=goal,
        delta=delta.tolist(),
        in_region=in_region,
        touch_delta=touch_delta.tolist(),
        touch_in_region=touch_in_region,
        strict_success=success and touch_in_region,
        fingers=fingers,
        sensed_fingers=int(fingers_in_contact(obs.sensors)),
        fingers_ok=fingers_ok,
        required_ok=required_ok,
        required=required,
        touching={str(k): sorted(v) for k, v in sorted(touching.items())},
        held=held,
        lift_feasible=lift_feasible,
        lift_dz=lift_dz,
        slip=slip,
        early_contact=obs.contact,
        w_true=w_true.tolist(),
        hand_error=hand_error.tolist(),
    )
    return success, info
