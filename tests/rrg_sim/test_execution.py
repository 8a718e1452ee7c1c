"""The executor core's timing and retreat rules (rrg_sim.executor.wrt_executor,
physics.trajectory): the guarded move's via-point times, the servo targets that follow them,
and a retreat that is dropped when the arm has moved since the WRT ended."""

from __future__ import annotations

import numpy as np
import pytest

from rrg_models import wam
from rrg_models.config import PHYSICS
from rrg_models.trajectory import (
    SETTLE_TIME,
    InfeasiblePath,
    plan_path,
    sample_times,
    servo_targets,
)
from rrg_sim.executor.robot_errors import ForceCeilingStop, StaleDataStop
from rrg_sim.physics.judge import judge_grasp
from rrg_sim.physics.world import PhysicsWorld


def two_segment_path():
    T1 = wam.fk(wam.HOME_Q)
    T1[0, 3] += 0.10
    T2 = T1.copy()
    T2[2, 3] -= 0.08
    return plan_path(np.stack([T1, T2]), wam.HOME_Q)


def test_sample_times_rest_at_every_waypoint():
    path = two_segment_path()
    t = sample_times(path)
    assert t[0] == 0.0 and np.all(np.diff(t) > 0.0)
    steps = np.diff(t)
    corner = int(np.nonzero(path.segment == 0)[0][-1])  # the last sample of segment 0
    middle = steps[corner // 2]
    assert steps[corner - 1] > 1.5 * middle and steps[corner] > 1.5 * middle  # slow in, slow out
    cruise = (
        np.linalg.norm(path.poses[corner // 2 + 1, :3, 3] - path.poses[corner // 2, :3, 3]) / middle
    )
    assert abs(cruise - PHYSICS.move_speed) < 0.01  # m/s between the ramps
    fast = sample_times(path, {0: (2 * PHYSICS.move_speed, PHYSICS.turn_speed)})
    assert fast[corner] < t[corner] and np.isclose(fast[-1] - fast[corner], t[-1] - t[corner])


def test_servo_targets_pass_the_via_points_at_their_times():
    path = two_segment_path()
    t = sample_times(path)
    ctrl, index = servo_targets(path.q, t)
    dt = PHYSICS.timestep
    settle = int(round(SETTLE_TIME / dt))
    assert len(ctrl) == len(index) == int(np.ceil(t[-1] / dt)) + 1 + settle
    assert (
        index[0] == 0.0 and np.all(np.diff(index) >= 0.0) and np.all(index[-settle:] == len(t) - 1)
    )
    reached = (
        np.searchsorted(index, np.arange(len(t)) - 1e-9) * dt
    )  # first period commanding each via-point
    assert np.abs(reached - t).max() <= dt + 1e-9
    np.testing.assert_allclose(ctrl[-1], path.q[-1], atol=1e-6)  # at rest on the last via-point


def test_retreat_is_dropped_when_the_arm_has_moved():
    world = PhysicsWorld("box", sensor_noise=0.0)
    e = world.true_object_pose()
    world.execute_wrt(world.obj.goal_wrt, e)
    ok, _ = judge_grasp(world, world.obj, e)  # lifts the object: the arm leaves the grasp pose
    assert ok
    lifted = world.arm_q()
    world.retreat()
    np.testing.assert_allclose(world.arm_q(), lifted, atol=1e-3)
    assert world.executor.last is None
    world.reset()
    world.execute_wrt(world.obj.goal_wrt, e)
    world.retreat()  # from where the WRT left it: back home
    np.testing.assert_allclose(world.arm_q(), wam.HOME_Q, atol=0.05)  # servo lag [rad]


def test_a_reorientation_the_arm_cannot_finish_is_refused_before_anything_moves():
    """The giant teacup's ccw reorientation at θ = 2.4 rad: τ(e) itself is reachable, but the
    lift-turn-put-down after the grasp is not. It must be refused up front (the agent is told
    nothing moved), not half way with the cup already turned."""
    world = PhysicsWorld("giant_teacup", sensor_noise=0.0)
    e = np.array([0.54, 0.0, 2.4])
    world.reset(e)
    wrt = world.obj.wrt("reorient_ccw")
    plan_path(
        wrt.world_poses(e), world.arm_q(), rigid_from=1, reconfigure=True
    )  # the approach alone is fine
    w0, q0 = world.true_object_pose(), world.arm_q()
    with pytest.raises(InfeasiblePath):
        world.execute_wrt(wrt, e)
    np.testing.assert_allclose(world.true_object_pose(), w0, atol=1e-4)
    np.testing.assert_allclose(world.arm_q(), q0, atol=1e-3)


def test_the_transit_to_a_side_grasp_passes_above_the_object():
    """The pitcher turned 0.44 rad: the straight line from home to its goal grasp's approach
    pose brushed it with finger 3 (a contact at progress 0 no table predicts). Through the
    pose above the approach pose the hand arrives without touching anything."""
    from rrg_sim.executor.wrt_executor import transit_via

    world = PhysicsWorld("brita_pitcher", seed=1)
    w = np.array([0.62, 0.0, 0.444])
    world.reset(w)
    first = world.obj.goal_wrt.world_poses(w)[0]
    assert transit_via(first)[2, 3] == PHYSICS.transit_height
    high = first.copy()
    high[2, 3] = PHYSICS.transit_height + 0.1
    assert transit_via(high) is None  # a WRT that starts high (a top-down grasp) goes straight
    obs = world.execute_wrt(world.obj.goal_wrt, w)
    assert not obs.contact and obs.progress > 0.3


def test_a_goal_grasp_ends_where_the_arm_can_lift_it():
    """The can's top grasp at (0.66, 0.02): the least-motion chain down from the raised transit
    ended with J5 at 1.16 rad, 0.09 from its limit, from where lifting the can 10 cm needs J5
    past the limit (the judge found the grasp good and could not lift it). The chain is now
    chosen through the lift too; the judged grasp lifts and holds."""
    world = PhysicsWorld("can", seed=1)
    e = np.array([0.66, 0.02, 0.0])
    world.reset(e)
    obs = world.execute_wrt(world.obj.goal_wrt, e)
    ok, info = judge_grasp(world, world.obj, e, obs)
    assert info["lift_feasible"] and info["held"] and ok


def test_planned_paths_keep_clear_of_the_joint_limits_where_they_can():
    """A path that passes J5 exactly at its 1.25 rad limit lets the servo's overshoot press the
    limit stop, and the collision detection reads a contact at progress 0. Paths keep
    LIMIT_MARGIN inside the limits when some chain does, and still pass through the margin
    when none does (the cooler's grasp at x = 0.75 touches J6's limit)."""
    from rrg_models.objects import get_object
    from rrg_models.trajectory import LIMIT_MARGIN
    from rrg_sim.executor.wrt_executor import wrt_path

    def plan(name, e):
        return wrt_path(get_object(name).goal_wrt, np.array(e), wam.HOME_Q)

    def clearance(path):
        return float(np.minimum(path.q - wam.LOWER, wam.UPPER - path.q).min())

    assert clearance(plan("can", [0.66, 0.02, 0.0])) >= LIMIT_MARGIN
    assert 0.0 <= clearance(plan("cooler", [0.752, 0.063, 0.388])) < LIMIT_MARGIN


def test_a_retreat_whose_turned_approach_is_out_of_reach_backs_out_and_goes_home():
    """After the pitcher's reorient_cw at (0.77, 0.01, 0.8) the approach turned with the object
    has no continuous IK chain from where the arm put it down (a run would end with an
    InfeasiblePath). The hand opens, backs out along its approach axis and rises instead, and
    the arm goes home, leaving the pitcher where it was put down (in MuJoCo, rising with the
    fingers around its handle dragged it 8 cm and turned it 1.3 rad)."""
    world = PhysicsWorld("brita_pitcher", seed=1)
    e = np.array([0.77, 0.01, 0.8])
    world.reset(np.array([0.787, 0.0007, 0.702]))
    wrt = next(w for w in world.obj.wrts() if w.name == "reorient_cw")
    world.execute_wrt(wrt, e)
    last = world.executor.last
    assert not np.allclose(last.moved, np.eye(4))  # the grasp held: the pitcher was turned
    back = last.turned_approach()
    with pytest.raises(InfeasiblePath):
        plan_path(back, world.arm_q(), rigid_from=len(back))
    put_down = world.true_object_pose()
    world.retreat()
    np.testing.assert_allclose(world.arm_q(), wam.HOME_Q, atol=0.05)  # servo lag [rad]
    moved = world.true_object_pose() - put_down
    assert np.abs(moved[:2]).max() < 0.005 and abs(moved[2]) < 0.02, moved  # [m], [rad]


def test_the_open_hand_at_home_is_clear_of_the_tallest_object_below_it():
    """Every WRT starts from home, and the tables assume the way to its first pose is free.
    With home 45 cm over the table the fingertips hung at the cooler's 28 cm handle: at high
    uncertainty 20 of 100 drawn cooler poses stopped the first sweep in free space (MuJoCo)."""
    world = PhysicsWorld("cooler", sensor_noise=0.0)
    home = world.hand_pose()[:3, 3]
    for theta in (0.0, np.pi / 2):
        world.reset([home[0], home[1], theta])  # the cooler right below the hand
        for wrt in world.obj.wrts():
            world.move_hand(wrt.spread, wrt.preclose)
            assert not world.reading().fired.any(), (theta, wrt.name)


def test_a_feasibility_map_over_the_executed_path_agrees_with_the_executor():
    """The pitcher's goal grasp starts 33 cm back from the handle, near the WAM's base: at
    θ ≈ -0.4 its two waypoints are reachable but the descent from the transit to the first is
    not, and a map over the waypoints alone said feasible where the executor found no IK
    chain (23 of 200 poses drawn at high uncertainty; agents then replanned until they gave
    up). The map over ``executed_poses`` checks that descent and the lift. Near that pose it
    is wrong at least 4× less often (it does not check joint continuity: 11 → 2 of 40)."""
    from rrg_models.objects import get_object
    from rrg_models.wam_feasibility import FeasibilityMap
    from rrg_sim.executor.wrt_executor import executed_poses, wrt_path

    wrt = get_object("brita_pitcher").goal_wrt
    old, new = FeasibilityMap(wrt.poses), FeasibilityMap(executed_poses(wrt))
    e = np.array([0.685, 0.047, -0.368])
    assert old.lookup(e) and not new.lookup(e)
    with pytest.raises(InfeasiblePath):
        wrt_path(wrt, e, wam.HOME_Q)
    rng = np.random.default_rng(3)
    poses = np.array([0.62, 0.0, -0.4]) + rng.normal(size=(40, 3)) * [0.03, 0.03, 0.15]

    def chain(e) -> bool:
        try:
            wrt_path(wrt, e, wam.HOME_Q)
            return True
        except InfeasiblePath:
            return False

    has_chain = np.array([chain(e) for e in poses])
    wrong_old = int(np.sum(old.lookup(poses) & ~has_chain))
    wrong_new = int(np.sum(new.lookup(poses) & ~has_chain))
    print(
        f"feasible by the map but no chain, of {len(poses)}: waypoints {wrong_old}, "
        f"executed path {wrong_new}"
    )
    assert wrong_old >= 10 and 4 * wrong_new <= wrong_old


def test_a_path_starts_from_a_joint_pressed_just_past_its_limit():
    """A bowl grasp measured in MuJoCo ended with J7 at -3.002 rad, 2 mrad past its limit,
    pressed there by the contact. No IK solution, so no chain, starts there, and the judge could
    not lift a good grasp: the plan starts from the nearest configuration within the limits."""
    q = np.array([0.71, 1.567, -1.538, 2.237, -1.553, -1.544, -3.002])
    assert q[6] < wam.LOWER[6]
    up = wam.fk(q)
    up[2, 3] += PHYSICS.lift_height
    path = plan_path(up[None], q, rigid_from=1)
    assert np.all(path.q >= wam.LOWER) and np.all(path.q <= wam.UPPER)
    assert np.abs(wam.fk(path.q[-1])[:3, 3] - up[:3, 3]).max() < 1e-3


def test_a_lift_the_least_motion_chain_cannot_reach_starts_where_the_arm_is():
    """A can grasp near J2's limit measured in MuJoCo ended at q below. The least-motion chain
    up from there starts at another elbow swivel that no swivel in place reaches, and the judge
    could not lift a good grasp: the plan falls back to the least-motion chain that starts at q
    itself."""
    q = np.array([-1.127, 1.966, 1.36, 2.122, -2.16, 0.151, 1.709])
    up = wam.fk(q)
    up[2, 3] += PHYSICS.lift_height
    path = plan_path(up[None], q, rigid_from=1)
    assert np.allclose(path.q[0], q, atol=1e-6)
    assert np.abs(wam.fk(path.q[-1])[:3, 3] - up[:3, 3]).max() < 1e-3


class HandOnly:
    """A robot whose hand stands at the given angles [rad], recording the hand commands."""

    def __init__(self, proximal):
        self.proximal = np.asarray(proximal, dtype=float)
        self.sent: list[tuple[float, np.ndarray]] = []

    def hand_angles(self) -> tuple[float, np.ndarray]:
        return 0.3, self.proximal

    def move_hand(self, spread, proximal) -> None:
        self.sent.append((spread, np.broadcast_to(proximal, 3).copy()))


def test_an_opening_never_closes_a_finger():
    """The hand opens to the preshape without moving a finger that is already more open (one
    the object pushed past its open stop would otherwise press on it as the hand withdraws)."""
    from rrg_sim.executor.wrt_executor import WrtExecutor

    robot = HandOnly([0.9, 0.1, -0.0014])
    WrtExecutor(robot)._open(0.2)
    [(spread, proximal)] = robot.sent
    assert spread == 0.3
    np.testing.assert_array_equal(proximal, [0.2, 0.1, -0.0014])


class ArmOnly:
    """A robot whose arm stands at q (7,) [rad], recording the joint paths it is sent."""

    def __init__(self, q):
        self.q = np.asarray(q, dtype=float)
        self.sent: list[np.ndarray] = []

    def arm_q(self) -> np.ndarray:
        return self.q.copy()

    def hand_pose(self) -> np.ndarray:
        return wam.fk(self.q)

    def follow(self, q, t, guard=False):
        self.sent.append(np.asarray(q, dtype=float))


#: A top-down tape roll grasp near the WAM's base measured in MuJoCo (the realistic world): its
#: plan ended at LIFT_PLANNED, the arm stopped at LIFT_ACTUAL, 10 mrad away at J7. Lifted
#: straight up from there the wrist passes by its singularity (J6 crosses 0), and from
#: LIFT_ACTUAL only a wrist flip continues the lift; the judge's fresh plan failed a grasp
#: that held.
LIFT_ACTUAL = np.array([-0.041, 0.923, -0.003, 2.386, -0.017, -0.165, 1.533])
LIFT_PLANNED = LIFT_ACTUAL + np.array([0.0, 0.0, 0.0, 0.0, 0.002, 0.0, 0.01])


def test_a_goal_grasp_is_lifted_along_the_lift_its_plan_chose():
    """WrtExecutor.lift follows the chain plan_path chose through the grasp's ``then`` lift
    when the hand stands within LIFT_START_TOLERANCE of the planned end (the joints within
    RETREAT_TOLERANCE), and plans a fresh lift otherwise: here the fresh plan has no chain, the
    planned one lifts."""
    from rrg_models.objects import get_object
    from rrg_models.poses import raised
    from rrg_sim.executor.wrt_executor import (
        LIFT_START_TOLERANCE,
        RETREAT_TOLERANCE,
        Execution,
        WrtExecutor,
    )

    top = wam.fk(LIFT_PLANNED)
    planned = plan_path(top[None], LIFT_PLANNED, then=raised(top, PHYSICS.lift_height)[None])
    assert planned.after is not None and np.abs(planned.q[-1] - LIFT_PLANNED).max() < 1e-6
    with pytest.raises(InfeasiblePath):
        plan_path(raised(wam.fk(LIFT_ACTUAL), PHYSICS.lift_height)[None], LIFT_ACTUAL, 1)
    assert np.abs(LIFT_ACTUAL - LIFT_PLANNED).max() <= RETREAT_TOLERANCE

    goal = get_object("taperoll").goal_wrt
    robot = ArmOnly(LIFT_ACTUAL)
    executor = WrtExecutor(robot)
    executor.last = Execution(
        goal, np.zeros(3), planned, None, LIFT_ACTUAL, lift=planned.then_path()
    )
    executor.lift()
    [q] = robot.sent
    np.testing.assert_array_equal(q[0], LIFT_ACTUAL)
    np.testing.assert_array_equal(q[1:], planned.after.q)
    rise = wam.fk(q[-1])[2, 3] - wam.fk(LIFT_ACTUAL)[2, 3]
    assert rise == pytest.approx(PHYSICS.lift_height, abs=2e-3)

    # Without the plan's lift (no WRT ran) the lift is planned from where the arm is ...
    executor.last = None
    with pytest.raises(InfeasiblePath):
        executor.lift()
    assert len(robot.sent) == 1
    # ... and so it is for a hand that stands off the planned end (J4 alone 10 mrad off: the
    # hand 4 mm)
    short = LIFT_PLANNED + np.array([0.0, 0.0, 0.0, -0.01, 0.0, 0.0, 0.0])
    gap = np.linalg.norm(wam.fk(short)[:3, 3] - top[:3, 3])
    assert LIFT_START_TOLERANCE < gap and np.abs(short - LIFT_PLANNED).max() <= RETREAT_TOLERANCE
    robot.q = short
    executor.last = Execution(goal, np.zeros(3), planned, None, short, lift=planned.then_path())
    executor.lift()
    assert np.abs(robot.sent[-1][0] - short).max() < 1e-6
    assert not np.array_equal(robot.sent[-1][1:], planned.after.q)
    robot.q, executor.last = LIFT_PLANNED, None
    executor.lift()
    assert np.abs(robot.sent[-1][0] - LIFT_PLANNED).max() < 1e-6


@pytest.mark.parametrize(
    "stop",
    [
        ForceCeilingStop("guarded_move failed (108): fingertip 2: force 20.1 N"),
        StaleDataStop("guarded_move failed (109): no fresh data from pads within 150 ms"),
    ],
)
def test_a_retreat_stopped_by_the_safety_layer_withdraws_and_goes_home(stop, monkeypatch):
    """The hardware bridge stops and holds any arm move whose fingertip load passes its ceiling
    (GuardedMove FORCE_LIMIT: an opened finger catching on the object as it leaves) or whose
    data went stale (STALE_DATA). The retreat opens the hand, backs out, rises and goes home
    from where the retrace was stopped."""
    from rrg_sim.executor import wrt_executor

    monkeypatch.setattr(wrt_executor, "WITHDRAW_PAUSE_S", 0.0)
    world = PhysicsWorld("box", sensor_noise=0.0)
    e = world.true_object_pose()
    world.execute_wrt(world.obj.goal_wrt, e)
    follow, stops = world.follow, []

    def stopped_once(q, t, guard):
        if not stops:  # the retrace: the arm moves a few via-points, then the layer holds it
            stops.append(len(q))
            follow(q[:4], t[:4], guard)
            raise stop
        return follow(q, t, guard)

    world.follow = stopped_once
    world.retreat()
    assert stops and stops[0] > 4
    np.testing.assert_allclose(world.arm_q(), wam.HOME_Q, atol=0.05)  # servo lag [rad]
    np.testing.assert_allclose(world.hand_angles()[1], 0.0, atol=0.02)  # open [rad]
    assert world.executor.last is None


def test_a_wrt_stopped_for_stale_data_brings_the_hand_home_and_says_so(monkeypatch):
    """The bridge stops a guarded move whose data went stale (GuardedMove STALE_DATA: pads
    150 ms late on a loaded host). The execution withdraws the hand and goes home, tried again
    while the data is still stale, and raises ExecutionStopped: nothing was observed, and the
    same WRT runs again afterwards."""
    from rrg_sim.executor import wrt_executor
    from rrg_sim.executor.robot_errors import ExecutionStopped

    monkeypatch.setattr(wrt_executor, "WITHDRAW_PAUSE_S", 0.0)
    world = PhysicsWorld("box", sensor_noise=0.0)
    e = world.true_object_pose()
    follow, stops = world.follow, []

    def stale(q, t, guard):
        if len(stops) < 2:  # the approach, then the first try at withdrawing
            stops.append(guard)
            follow(q[: len(q) // 2], t[: len(t) // 2], guard)
            raise StaleDataStop("guarded_move failed (109): no fresh data from pads within 150 ms")
        return follow(q, t, guard)

    world.follow = stale
    with pytest.raises(ExecutionStopped, match="box|goal"):
        world.execute_wrt(world.obj.goal_wrt, e)
    assert stops == [True, False]  # the approach, then a withdrawal that was stopped too
    np.testing.assert_allclose(world.arm_q(), wam.HOME_Q, atol=0.05)  # servo lag [rad]
    np.testing.assert_allclose(world.hand_angles()[1], 0.0, atol=0.02)  # open [rad]
    assert world.executor.last is None
    obs = world.execute_wrt(world.obj.goal_wrt, e)
    assert obs.sensors.any()


def test_a_retreat_stopped_by_anything_else_fails():
    """Only the ceiling's hold is worked around: any other failure of the retrace is the
    caller's (the executor node answers it as MOTION_FAILED or ROBOT_FAULT)."""
    from rrg_sim.executor.robot_errors import MotionFailed

    world = PhysicsWorld("box", sensor_noise=0.0)
    world.execute_wrt(world.obj.goal_wrt, world.true_object_pose())

    def refused(q, t, guard):
        raise MotionFailed("guarded_move failed (107): outside the workspace")

    world.follow = refused
    with pytest.raises(MotionFailed, match="107"):
        world.retreat()
