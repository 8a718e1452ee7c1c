"""The emulated hardware drivers: the ROS-free core (trajectory tracking as the simulator's, cancel
holds, velocity closing stalls and brakes, faults) and the fake_hw node behind real protocols
(FollowJointTrajectory, the BarrettHand services, three Net F/T boxes over RDT, run-time fault
parameters, the simulation-only reset)."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from fake_hw_testing import BOX_POSE, HOSTS, free_udp_port

from rrg_fake_hw.emulated_robot import (
    JOINT_LIMIT_GLITCH,
    PREEMPTED_MESSAGE,
    EmulatedRobot,
    GoalState,
)
from rrg_models import wam
from rrg_models.config import HAND, PHYSICS, SENSING
from rrg_sim.physics.world import PhysicsWorld

GOAL_ESTIMATE = np.array([0.62, 0.0, 0.0])
#: An arm target near home, reached in TARGET_TIME [s].
TARGET = wam.HOME_Q + np.array([0.15, -0.1, 0.1, 0.2, 0.0, 0.1, 0.0])
TARGET_TIME = 1.0


@pytest.fixture
def robot() -> EmulatedRobot:
    r = EmulatedRobot("box", seed=0, sensor_noise=0.0)
    r.reset("box", BOX_POSE)
    return r


def grasped(r: EmulatedRobot) -> None:
    """The hand around the box at its goal grasp (the world's own WRT execution), then opened."""
    with r.exclusive() as world:
        world.execute_wrt(world.obj.goal_wrt, GOAL_ESTIMATE)
    r.open_grasp()
    r.advance(1.2)


# ---------------------------------------------------------------------- core, no ROS
@pytest.mark.slow
def test_trajectory_tracking_is_the_simulators_follow(robot):
    """Via-points after t = 0 start from the measured configuration and are tracked period by
    period exactly as PhysicsWorld.follow tracks them; the goal succeeds at the last one."""
    world = PhysicsWorld("box", seed=0, sensor_noise=0.0)
    world.reset(BOX_POSE)
    q = np.array([(wam.HOME_Q + TARGET) / 2, TARGET])
    t = np.array([0.5, TARGET_TIME])
    goal = robot.follow(q, t)
    assert robot.goal_status(goal).state is GoalState.ACTIVE
    world.follow(np.vstack([world.arm_q(), q]), np.r_[0.0, t])
    while robot.goal_status(goal).state is GoalState.ACTIVE:
        robot.advance(PHYSICS.timestep)
    assert robot.world.sim_time == pytest.approx(world.sim_time)
    np.testing.assert_allclose(robot.world.arm_q(), world.arm_q(), atol=1e-9)
    assert robot.goal_status(goal).state is GoalState.SUCCEEDED
    np.testing.assert_allclose(robot.snapshot().arm_q, TARGET, atol=0.01)  # servo lag
    assert [e.name for e in robot.events()] == ["goal_accepted", "goal_finished"]
    with pytest.raises(ValueError):
        robot.follow(q[::-1], t[::-1])  # times must increase


@pytest.mark.slow
def test_a_cancel_holds_the_arm_where_it_is_and_a_new_goal_preempts(robot):
    first = robot.follow(TARGET[None], [TARGET_TIME])
    second = robot.follow(TARGET[None], [TARGET_TIME])
    assert robot.goal_status(first).state is GoalState.PREEMPTED
    robot.advance(0.4)
    moving = np.abs(robot.snapshot().arm_qd).max()
    assert moving > 0.1
    assert robot.cancel(second)
    assert robot.goal_status(second).state is GoalState.CANCELED
    q_cancel = robot.world.arm_q()
    robot.advance(0.5)
    # the servos stopped it (in ~ 40 ms, as the simulator's stop) within what it travels in
    # 40 ms, and it stays there
    assert np.abs(robot.world.arm_q() - q_cancel).max() < 0.04 * moving
    assert np.abs(robot.snapshot().arm_qd).max() < 0.01
    names = [e.name for e in robot.events()]
    assert names[-2:] == ["cancel_received", "goal_finished"]
    cancel, finish = robot.events()[-2:]
    assert cancel.time_s <= finish.time_s and finish.details["state"] == "canceled"
    assert not robot.cancel(second)  # no longer running


@pytest.mark.slow
def test_velocity_closing_stalls_on_the_object_and_zero_velocity_brakes(robot):
    grasped(robot)
    assert np.abs(robot.snapshot().proximal).max() < 0.01
    robot.finger_velocities([1.0, 1.0, 1.0])  # rad/s
    robot.advance(0.5)
    s = robot.snapshot()
    loads = np.linalg.norm(s.tip_loads[:, :3], axis=1)
    assert np.all(s.proximal < 0.3)  # a free finger would be at 0.5 rad
    assert np.all(np.abs(s.proximal_velocity) < 0.1)  # stalled
    assert np.all(loads > SENSING.tip_force_threshold)
    robot.finger_velocities([0.0, 0.0, 0.0])
    assert robot.braked.all()
    robot.advance(0.1)
    held = robot.snapshot().proximal
    robot.advance(0.3)
    s = robot.snapshot()  # the worm drive keeps the squeeze: the fingers barely creep
    np.testing.assert_allclose(s.proximal, held, atol=0.01)
    assert np.all(np.linalg.norm(s.tip_loads[:, :3], axis=1) > SENSING.tip_force_threshold)
    robot.finger_velocities([-1.0, 0.0, 0.0])  # a move releases only that finger's brake
    assert robot.braked.tolist() == [False, True, True]
    robot.advance(0.3)
    assert robot.snapshot().proximal[0] < held[0] - 0.1


@pytest.mark.slow
def test_hand_position_moves_ramp_and_a_stuck_finger_ignores_commands(robot):
    robot.move_spread(1.0)
    robot.move_fingers([1.0, 1.0, 1.0])
    robot.advance(0.1)
    s = robot.snapshot()
    assert np.all(s.proximal <= HAND.close_speed * 0.1 + 1e-3)  # ramped at the hand's speed
    robot.advance(0.9)
    s = robot.snapshot()
    np.testing.assert_allclose(s.spread, [1.0, 1.0], atol=0.02)
    np.testing.assert_allclose(s.proximal, 1.0, atol=0.02)
    np.testing.assert_allclose(s.distal, HAND.distal_coupling, atol=0.03)
    robot.set_stuck_finger(1)
    robot.open_grasp()
    robot.finger_velocities([-1.0, -1.0, -1.0])  # rad/s, from 1 rad
    robot.advance(1.3)
    s = robot.snapshot()
    assert s.proximal[1] == pytest.approx(1.0, abs=0.02)
    np.testing.assert_allclose(s.proximal[[0, 2]], 0.0, atol=0.02)
    with pytest.raises(ValueError):
        robot.move_fingers([3.0, 0.0, 0.0])  # beyond HAND.proximal_range
    with pytest.raises(ValueError):
        robot.move_spread(-0.5)


def test_joint_limit_fault_and_extra_force(robot):
    q = robot.snapshot().arm_q
    robot.set_joint_limit_fault(True)
    glitch = robot.snapshot().arm_q
    assert glitch[3] == pytest.approx(wam.UPPER[3] + JOINT_LIMIT_GLITCH)
    assert not wam.within_limits(glitch)
    np.testing.assert_array_equal(np.delete(glitch, 3), np.delete(q, 3))
    np.testing.assert_array_equal(robot.world.arm_q(), q)  # the arm itself did not move
    robot.set_joint_limit_fault(False)
    np.testing.assert_array_equal(robot.snapshot().arm_q, q)

    loads = np.array([robot.tip_load(i) for i in range(3)])
    robot.set_extra_force(5.0)  # N
    extra = np.array([robot.tip_load(i) for i in range(3)])
    np.testing.assert_allclose(
        extra - loads, np.r_[[0, 0, 5.0, 0, 0, 0], np.zeros(12)].reshape(3, 6)
    )
    np.testing.assert_array_equal(robot.snapshot().tip_loads, extra)


def test_readings_are_noisy_where_the_drivers_are_and_the_loads_never():
    noisy = EmulatedRobot("box", seed=3, sensor_noise=1.0)
    a, b = noisy.snapshot(), noisy.snapshot()
    assert np.std(a.arm_effort - b.arm_effort) > 0.3 * PHYSICS.arm_torque_noise
    assert np.std(a.pads - b.pads) > 0.3 * PHYSICS.pad_force_noise
    np.testing.assert_array_equal(a.tip_loads, b.tip_loads)
    again = EmulatedRobot("box", seed=3, sensor_noise=1.0).snapshot()
    np.testing.assert_array_equal(again.arm_effort, a.arm_effort)  # seeded


@pytest.mark.slow
def test_the_thread_steps_the_world_in_real_time(robot):
    with robot:
        assert robot.running
        with pytest.raises(RuntimeError):
            robot.advance(0.1)
        goal = robot.follow(TARGET[None], [0.2])
        deadline = time.monotonic() + 5.0
        while robot.goal_status(goal).state is GoalState.ACTIVE and time.monotonic() < deadline:
            time.sleep(0.01)
    assert robot.goal_status(goal).state is GoalState.SUCCEEDED
    t = robot.world.sim_time
    assert robot.timing.steps > 0
    robot.advance(0.1)  # stopped: stepping by hand again
    assert robot.world.sim_time == pytest.approx(t + 0.1)


# ---------------------------------------------------------------------- the node over ROS
DRIVER_ARM = tuple(f"wam_j{i}_joint" for i in range(1, 8))


@pytest.fixture(scope="module")
def fake_hw(tmp_path_factory, ros_domain):
    from bhand_srvs.srv import FingerPosition, FingerVelocity, GraspPosition, SpreadPosition
    from control_msgs.action import FollowJointTrajectory
    from diagnostic_msgs.msg import DiagnosticStatus
    from geometry_msgs.msg import PoseStamped
    from rcl_interfaces.srv import SetParameters
    from rclpy.action import ActionClient
    from ros_testing import RosClient, node_processes, ros_env
    from sensor_msgs.msg import JointState
    from std_srvs.srv import Trigger
    from wam_msgs.msg import TactilePressureArray

    from rrg_msgs.srv import ResetSim

    env = ros_env(ros_domain)
    port = free_udp_port(HOSTS)
    params = {"object_name": "box", "sensor_noise": 0.0, "rdt_port": port}
    with node_processes(
        [("rrg_fake_hw.fake_hw_node", params)], env, tmp_path_factory.mktemp("logs")
    ) as procs:
        client = RosClient(env)
        n = client.node
        c = {
            "fingers": n.create_client(FingerPosition, "/bhand/moveToFingerPositions"),
            "spread": n.create_client(SpreadPosition, "/bhand/moveToSpreadPosition"),
            "velocity": n.create_client(FingerVelocity, "/bhand/moveToFingerVelocities"),
            "grasp": n.create_client(GraspPosition, "/bhand/moveToGraspPosition"),
            "open": n.create_client(Trigger, "/bhand/openGrasp"),
            "close": n.create_client(Trigger, "/bhand/closeGrasp"),
            "idle": n.create_client(Trigger, "/bhand/idle"),
            "reset": n.create_client(ResetSim, "/rrg/reset_sim"),
            "params": n.create_client(SetParameters, "/fake_hw/set_parameters"),
        }
        client.wait_for_services(c.values(), procs, timeout_s=60.0)
        c["arm"] = ActionClient(n, FollowJointTrajectory, "/arm_controller/follow_joint_trajectory")
        assert c["arm"].wait_for_server(timeout_sec=30.0)
        seen: dict[str, list] = {"joints": [], "pads": [], "events": [], "truth": []}

        def keep(key: str, limit: int = 200):
            def store(msg) -> None:
                seen[key].append(msg)
                del seen[key][:-limit]

            return store

        n.create_subscription(JointState, "/joint_states", keep("joints"), 10)
        n.create_subscription(TactilePressureArray, "/bhand/tactile_states", keep("pads"), 10)
        n.create_subscription(DiagnosticStatus, "/fake_hw/events", keep("events", 1000), 100)
        n.create_subscription(PoseStamped, "/rrg/eval/object_pose", keep("truth"), 10)
        assert client.spin_until(lambda: seen["joints"] and seen["pads"], 10.0)
        yield client, c, seen, port
        client.close()


def latest(seen, names) -> np.ndarray:
    js = seen["joints"][-1]
    return np.array([js.position[js.name.index(n)] for n in names])


def fresh(client, seen, seconds: float = 0.1) -> None:
    """Let ``seconds`` of new messages arrive."""
    seen["joints"].clear()
    end = time.monotonic() + seconds
    client.spin_until(lambda: time.monotonic() > end and seen["joints"], seconds + 5.0)


def arm_goal(q: np.ndarray, seconds: float, names=DRIVER_ARM):
    from builtin_interfaces.msg import Duration
    from control_msgs.action import FollowJointTrajectory
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

    order = [DRIVER_ARM.index(n) if n in DRIVER_ARM else i for i, n in enumerate(names)]
    sec = int(seconds)
    return FollowJointTrajectory.Goal(
        trajectory=JointTrajectory(
            joint_names=list(names),
            points=[
                JointTrajectoryPoint(
                    positions=np.asarray(q, dtype=float)[order].tolist(),
                    time_from_start=Duration(sec=sec, nanosec=int(round((seconds - sec) * 1e9))),
                )
            ],
        )
    )


def reset(client, c, pose=BOX_POSE):
    from rrg_common.ros.msg_conversions import planar_to_msg
    from rrg_msgs.srv import ResetSim

    return client.call(c["reset"], ResetSim.Request(object_name="box", pose=planar_to_msg(pose)))


def set_param(client, c, name: str, value):
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter

    req = SetParameters.Request(parameters=[Parameter(name, value=value).to_parameter_msg()])
    return client.call(c["params"], req).results[0]


@pytest.mark.slow
def test_follow_joint_trajectory_moves_the_arm_and_a_cancel_holds_it(fake_hw):
    from action_msgs.msg import GoalStatus
    from control_msgs.action import FollowJointTrajectory

    client, c, seen, _ = fake_hw
    assert reset(client, c).error_code == 0
    R = FollowJointTrajectory.Result
    shuffled = DRIVER_ARM[::-1]  # any joint order
    handle = client.result(c["arm"].send_goal_async(arm_goal(TARGET, TARGET_TIME, shuffled)))
    assert handle.accepted
    res = client.result(handle.get_result_async(), 10.0)
    assert res.status == GoalStatus.STATUS_SUCCEEDED and res.result.error_code == R.SUCCESSFUL
    fresh(client, seen)
    np.testing.assert_allclose(latest(seen, DRIVER_ARM), TARGET, atol=3e-3)

    handle = client.result(c["arm"].send_goal_async(arm_goal(wam.HOME_Q, 2.0)))
    assert handle.accepted
    fresh(client, seen, 0.4)
    client.result(handle.cancel_goal_async())
    res = client.result(handle.get_result_async(), 10.0)
    assert res.status == GoalStatus.STATUS_CANCELED
    fresh(client, seen, 0.1)  # stopping takes the servos ~ 40 ms
    q_stop = latest(seen, DRIVER_ARM)
    assert np.abs(q_stop - TARGET).max() > 0.02 and np.abs(q_stop - wam.HOME_Q).max() > 0.02
    fresh(client, seen, 0.3)
    np.testing.assert_allclose(latest(seen, DRIVER_ARM), q_stop, atol=5e-3)
    names = [e.name for e in seen["events"]]
    assert names[-3:] == ["goal_accepted", "cancel_received", "goal_finished"]
    times = [float(dict((v.key, v.value) for v in e.values)["time"]) for e in seen["events"][-3:]]
    assert times == sorted(times)

    first = client.result(c["arm"].send_goal_async(arm_goal(TARGET, 1.0)))
    second = client.result(c["arm"].send_goal_async(arm_goal(TARGET, 0.5)))
    preempted = client.result(first.get_result_async(), 10.0)
    assert preempted.status == GoalStatus.STATUS_CANCELED
    assert preempted.result.error_string == PREEMPTED_MESSAGE
    done = client.result(second.get_result_async(), 10.0)
    assert done.status == GoalStatus.STATUS_SUCCEEDED

    wrong = list(DRIVER_ARM[:6]) + ["bhand_j11_joint"]
    bad = client.result(c["arm"].send_goal_async(arm_goal(TARGET, 1.0, wrong)))
    assert not bad.accepted
    nan = client.result(c["arm"].send_goal_async(arm_goal(np.full(7, np.nan), 1.0)))
    assert not nan.accepted


@pytest.mark.slow
def test_bhand_services_move_the_hand(fake_hw):
    from bhand_srvs.srv import FingerPosition, FingerVelocity, GraspPosition, SpreadPosition
    from std_srvs.srv import Trigger

    client, c, seen, _ = fake_hw
    assert reset(client, c).error_code == 0
    prox = ("bhand_j12_joint", "bhand_j22_joint", "bhand_j32_joint")
    spread = ("bhand_j11_joint", "bhand_j21_joint")
    assert client.call(c["spread"], SpreadPosition.Request(position=0.6)).response
    assert client.call(c["fingers"], FingerPosition.Request(position=[0.8, 0.9, 1.0])).response
    fresh(client, seen, 0.8)
    np.testing.assert_allclose(latest(seen, spread), 0.6, atol=0.02)
    np.testing.assert_allclose(latest(seen, prox), [0.8, 0.9, 1.0], atol=0.02)
    assert not client.call(c["fingers"], FingerPosition.Request(position=[3.0, 0.0, 0.0])).response
    assert not client.call(c["fingers"], FingerPosition.Request(position=[0.1])).response
    assert client.call(c["velocity"], FingerVelocity.Request(velocity=[-1.0, 0.0, 0.0])).response
    fresh(client, seen, 1.0)  # 0.8 rad at 1 rad/s
    q = latest(seen, prox)
    assert q[0] < 0.05 and q[1:] == pytest.approx([0.9, 1.0], abs=0.02)
    assert client.call(c["grasp"], GraspPosition.Request(position=0.5)).response
    fresh(client, seen, 0.5)
    np.testing.assert_allclose(latest(seen, prox), 0.5, atol=0.02)
    assert client.call(c["close"], Trigger.Request()).success
    fresh(client, seen, 0.3)
    assert client.call(c["idle"], Trigger.Request()).success
    fresh(client, seen, 0.1)
    q = latest(seen, prox)
    fresh(client, seen, 0.3)
    np.testing.assert_allclose(latest(seen, prox), q, atol=0.02)  # idle: stopped
    assert client.call(c["open"], Trigger.Request()).success
    fresh(client, seen, 1.2)
    np.testing.assert_allclose(latest(seen, prox), 0.0, atol=0.02)
    pucks = seen["pads"][-1].tactile_pressures  # Barrett's layout: 4 pucks of 24 cells
    assert [len(p.pressure) for p in pucks] == [24] * 4
    assert not np.any([p.pressure for p in pucks])  # the open hand touches nothing


@pytest.mark.slow
def test_rdt_boxes_stream_and_the_fault_parameters_take_effect(fake_hw):
    from rrg_hw_bridge.rdt import RdtClient

    client, c, seen, port = fake_hw
    assert reset(client, c).error_code == 0
    samples = [[] for _ in HOSTS]
    lock = threading.Lock()

    def on_sample(i):
        def store(s) -> None:
            with lock:
                samples[i].append(s)

        return store

    clients = [RdtClient(h, port, on_sample=on_sample(i)) for i, h in enumerate(HOSTS)]

    def collect(seconds: float) -> list[list]:
        with lock:
            for s in samples:
                s.clear()
        end = time.monotonic() + seconds
        client.spin_until(lambda: time.monotonic() > end, seconds + 1.0)
        with lock:
            return [list(s) for s in samples]

    for rc in clients:
        rc.start()
    try:
        got = collect(0.3)
        for s in got:
            assert len(s) > 100 and all(x.status == 0 for x in s)  # ~1 kHz
        base = np.mean([x.wrench for x in got[0]], axis=0)
        assert np.all(np.isfinite(base))

        assert set_param(client, c, "bench.crossing_threshold", 2.0).successful  # N
        assert set_param(client, c, "fault.extra_force", 5.0).successful
        collect(0.05)  # records the boxes sent before the fault, still in the sockets
        got = collect(0.2)
        np.testing.assert_allclose(
            np.mean([x.wrench for x in got[0]], axis=0) - base, [0, 0, 5.0, 0, 0, 0], atol=0.05
        )
        crossings = lambda: [e for e in seen["events"] if e.name == "first_crossing"]
        assert client.spin_until(crossings, 5.0)
        values = {v.key: v.value for v in crossings()[0].values}
        assert values["box"] == "0" and float(values["time"]) <= time.monotonic()
        assert set_param(client, c, "bench.crossing_threshold", 0.0).successful
        assert set_param(client, c, "fault.extra_force", 0.0).successful

        assert set_param(client, c, "fault.silent_box", 1).successful
        collect(0.05)
        got = collect(0.2)
        assert len(got[1]) == 0 and len(got[0]) > 50 and len(got[2]) > 50
        assert set_param(client, c, "fault.silent_box", -1).successful
        assert set_param(client, c, "fault.status_word", 0x20000).successful
        collect(0.05)
        assert all(x.status == 0x20000 for x in collect(0.1)[2])
        assert set_param(client, c, "fault.status_word", 0).successful
    finally:
        for rc in clients:
            rc.stop()

    assert set_param(client, c, "fault.joint_limit", True).successful
    fresh(client, seen)
    assert latest(seen, ["wam_j4_joint"])[0] > wam.UPPER[3]
    assert set_param(client, c, "fault.joint_limit", False).successful
    assert not set_param(client, c, "fault.stuck_finger", 7).successful  # out of range
    assert not set_param(client, c, "fault.drop_probability", "often").successful


@pytest.mark.slow
def test_reset_sim_places_the_object_and_homes_the_arm(fake_hw):
    from rrg_msgs.srv import ResetSim

    client, c, seen, _ = fake_hw
    pose = np.array([0.6, -0.05, 0.3])
    assert reset(client, c, pose).error_code == ResetSim.Response.NONE
    assert reset(client, c, [5.0, 0.0, 0.0]).error_code == ResetSim.Response.INVALID_POSE
    seen["truth"].clear()
    fresh(client, seen, 0.1)
    assert client.spin_until(lambda: seen["truth"], 5.0)
    p = seen["truth"][-1].pose.position
    np.testing.assert_allclose([p.x, p.y], pose[:2], atol=0.01)
    np.testing.assert_allclose(latest(seen, DRIVER_ARM), wam.HOME_Q, atol=2e-3)
