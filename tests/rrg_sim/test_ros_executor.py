"""The sim node and the executor node as separate processes: ExecuteWrt over ROS runs the same
executor core as the physics world in-process (same observation, noiseless sensors), publishes
its observation, and every bad request to ExecuteWrt, GuardedMove, HandCommand and ResetSim
gets its error code and a message while the nodes keep serving."""

from __future__ import annotations

import numpy as np
import pytest
from builtin_interfaces.msg import Duration
from rclpy.action import ActionClient
from ros_testing import RosClient, node_processes, ros_env
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from rrg_common.ros.msg_conversions import ARM_JOINT_NAMES, observation_from_msg, planar_to_msg
from rrg_models import wam
from rrg_msgs.action import ExecuteWrt, GuardedMove
from rrg_msgs.msg import Observation as ObservationMsg
from rrg_msgs.msg import Retreated
from rrg_msgs.srv import HandCommand, ResetSim, Retreat
from rrg_sim.physics.judge import judge_grasp
from rrg_sim.physics.world import PhysicsWorld

pytestmark = pytest.mark.slow  # node processes

TRUE_POSE = np.array([0.625, 0.004, 0.05])


@pytest.fixture(scope="module")
def graph(tmp_path_factory, ros_domain):
    env = ros_env(ros_domain)
    specs = [
        ("rrg_sim.ros.sim_node", {"object_name": "box", "sensor_noise": 0.0}),
        ("rrg_sim.executor.executor_node", {}),
    ]
    with node_processes(specs, env, tmp_path_factory.mktemp("logs")) as procs:
        client = RosClient(env)
        n = client.node
        c = {
            "reset": n.create_client(ResetSim, "/rrg/reset_sim"),
            "hand": n.create_client(HandCommand, "/rrg/hand_command"),
            "retreat": n.create_client(Retreat, "/rrg/retreat"),
            "judge": n.create_client(Trigger, "/rrg/eval/judge_grasp"),
        }
        client.wait_for_services(c.values(), procs, timeout_s=60.0)
        c["execute"] = ActionClient(n, ExecuteWrt, "/rrg/execute_wrt")
        c["move"] = ActionClient(n, GuardedMove, "/rrg/guarded_move")
        assert c["execute"].wait_for_server(timeout_sec=30.0) and c["move"].wait_for_server(
            timeout_sec=30.0
        )
        observations, retreats = [], []
        n.create_subscription(ObservationMsg, "/rrg/observation", observations.append, 10)
        n.create_subscription(Retreated, "/rrg/retreated", retreats.append, 10)
        c["retreats"] = retreats
        yield client, c, observations
        client.close()


def run_action(client: RosClient, action: ActionClient, goal, timeout_s: float = 120.0):
    handle = client.result(action.send_goal_async(goal), 10.0)
    assert handle.accepted
    return client.result(handle.get_result_async(), timeout_s).result


def reset(client: RosClient, c, pose=TRUE_POSE, name: str = "box") -> ResetSim.Response:
    return client.call(c["reset"], ResetSim.Request(object_name=name, pose=planar_to_msg(pose)))


def test_execute_wrt_over_ros_matches_the_in_process_execution(graph):
    """goal (left closed), retreat, sweep (stops on a contact) over ROS and in-process, noiseless:
    the same observations (the hand pose differs by the WAM model's FK vs MuJoCo, < 1 mm)."""
    client, c, observations = graph
    assert reset(client, c).error_code == ResetSim.Response.NONE
    world = PhysicsWorld("box", sensor_noise=0.0)
    world.reset(TRUE_POSE)
    for name, e in [("goal", np.array([0.62, 0.0, 0.0])), ("sweep", np.array([0.61, 0.01, 0.0]))]:
        res = run_action(
            client,
            c["execute"],
            ExecuteWrt.Goal(object_name="box", wrt_name=name, estimate=planar_to_msg(e)),
        )
        assert res.error_code == ExecuteWrt.Result.NONE, res.error_msg
        assert client.spin_until(
            lambda name=name: observations and observations[-1].wrt_name == name, 10.0
        )
        assert observations[-1].header.stamp == res.observation.header.stamp
        ros = observation_from_msg(res.observation)
        local = world.execute_wrt(world.obj.wrt(name), e)
        assert ros.contact == local.contact and (name == "goal" or ros.contact)
        np.testing.assert_array_equal(ros.sensors, local.sensors)
        np.testing.assert_allclose(ros.closure, local.closure, atol=1e-3)
        assert ros.progress == pytest.approx(local.progress, abs=1e-4)
        np.testing.assert_allclose(ros.motion_dir, local.motion_dir, atol=1e-3)
        np.testing.assert_allclose(ros.hand_pose[:3, 3], local.hand_pose[:3, 3], atol=1e-3)
        # every fingertip's contact point (NaN rows: no contact on that tip, on both sides);
        # the goal grasp closes on the box, the sweep touches it with no fingertip
        assert np.isfinite(local.tip_points).any() == (name == "goal")
        np.testing.assert_allclose(
            ros.tip_points, local.tip_points, atol=1e-3, equal_nan=True, err_msg=name
        )
        if name == "goal":
            assert client.call(c["retreat"], Retreat.Request()).error_code == Retreat.Response.NONE
            world.retreat()

    judged = client.call(c["judge"], Trigger.Request())  # the sweep is no goal grasp
    assert not judged.success and "not a goal grasp" in judged.message


def test_goal_grasp_is_left_closed_for_the_judge(graph):
    client, c, _ = graph
    assert reset(client, c).error_code == ResetSim.Response.NONE
    e = np.array([0.62, 0.0, 0.0])
    res = run_action(
        client,
        c["execute"],
        ExecuteWrt.Goal(object_name="box", wrt_name="goal", estimate=planar_to_msg(e)),
    )
    assert res.error_code == ExecuteWrt.Result.NONE, res.error_msg
    judged = client.call(c["judge"], Trigger.Request(), timeout_s=60.0)
    world = PhysicsWorld("box", sensor_noise=0.0)
    world.reset(TRUE_POSE)
    world.execute_wrt(world.obj.goal_wrt, e)
    ok, _ = judge_grasp(world, world.obj, e)
    assert judged.success == ok and judged.success, judged.message


def arm_q(client: RosClient, c) -> np.ndarray:
    """The arm's joint angles [rad], read from the hand command's joint state (opening the hand)."""
    hand = client.call(c["hand"], HandCommand.Request(mode=HandCommand.Request.MODE_OPEN))
    return np.array(
        [hand.joint_state.position[hand.joint_state.name.index(n)] for n in ARM_JOINT_NAMES]
    )


def test_an_info_wrt_stays_where_it_stopped_until_the_retreat_it_announces(graph):
    client, c, _ = graph
    assert reset(client, c).error_code == ResetSim.Response.NONE
    res = run_action(
        client,
        c["execute"],
        ExecuteWrt.Goal(object_name="box", wrt_name="info1", estimate=planar_to_msg(TRUE_POSE)),
    )
    assert res.error_code == ExecuteWrt.Result.NONE, res.error_msg
    assert np.abs(arm_q(client, c) - wam.HOME_Q).max() > 0.1  # still at the box
    c["retreats"].clear()
    answer = client.call(c["retreat"], Retreat.Request())
    assert answer.error_code == Retreat.Response.NONE, answer.error_msg
    assert client.spin_until(lambda: len(c["retreats"]) == 1, 10.0)
    event = c["retreats"][0]
    assert (event.header.stamp, event.observation_stamp) == (
        answer.header.stamp,
        res.observation.header.stamp,
    )
    assert (event.object_name, event.wrt_name) == ("box", "info1")
    np.testing.assert_allclose(arm_q(client, c), wam.HOME_Q, atol=0.02)
    again = client.call(
        c["retreat"], Retreat.Request()
    )  # nothing pending: announced, nothing moves
    assert again.error_code == Retreat.Response.NONE
    assert client.spin_until(lambda: len(c["retreats"]) == 2, 10.0)
    assert c["retreats"][1].wrt_name == "" and c["retreats"][1].header.stamp == again.header.stamp


BAD_EXECUTIONS = {
    "unknown object": (dict(object_name="teapot"), ExecuteWrt.Result.UNKNOWN_OBJECT),
    "unknown WRT": (dict(wrt_name="wave"), ExecuteWrt.Result.UNKNOWN_WRT),
    "unreachable estimate": (
        dict(estimate=planar_to_msg([2.5, 1.5, 0.0])),
        ExecuteWrt.Result.INFEASIBLE,
    ),
    "NaN estimate": (
        dict(estimate=planar_to_msg([np.nan, 0.0, 0.0])),
        ExecuteWrt.Result.INFEASIBLE,
    ),
}


@pytest.mark.parametrize("case", list(BAD_EXECUTIONS))
def test_execute_wrt_rejects_bad_goals(graph, case):
    client, c, _ = graph
    fields, code = BAD_EXECUTIONS[case]
    goal = ExecuteWrt.Goal(object_name="box", wrt_name="goal", estimate=planar_to_msg(TRUE_POSE))
    for k, v in fields.items():
        setattr(goal, k, v)
    res = run_action(client, c["execute"], goal)
    assert res.error_code == code and res.error_msg, res.error_msg


def trajectory(q: np.ndarray, names=ARM_JOINT_NAMES, seconds: float = 1.0) -> JointTrajectory:
    return JointTrajectory(
        joint_names=list(names),
        points=[
            JointTrajectoryPoint(
                positions=qk.tolist(), time_from_start=Duration(sec=int(seconds * (k + 1)))
            )
            for k, qk in enumerate(q)
        ],
    )


def test_guarded_move_runs_timed_via_points_and_rejects_bad_ones(graph):
    client, c, _ = graph
    assert reset(client, c).error_code == ResetSim.Response.NONE
    target = wam.HOME_Q + np.array([0.1, 0.0, 0.0, -0.1, 0.0, 0.0, 0.0])
    ok = run_action(
        client,
        c["move"],
        GuardedMove.Goal(trajectory=trajectory(target[None]), stop_on_contact=True),
    )
    assert (
        ok.error_code == GuardedMove.Result.NONE
        and not ok.stopped_on_contact
        and ok.path_fraction == 1.0
    )
    q = np.array(
        [ok.final_joint_state.position[ok.final_joint_state.name.index(n)] for n in ARM_JOINT_NAMES]
    )
    np.testing.assert_allclose(q, target, atol=0.01)
    R = GuardedMove.Result
    bad = {
        R.INVALID_TRAJECTORY: [
            trajectory(target[None], names=["j1"] * 7),
            trajectory(np.zeros((0, 7))),
            trajectory(np.full((1, 7), np.nan)),
        ],
        R.JOINT_LIMITS: [trajectory((wam.HOME_Q + np.array([0, 0, 0, 0, 0, 0, 9.0]))[None])],
    }
    for code, trajs in bad.items():
        for traj in trajs:
            res = run_action(client, c["move"], GuardedMove.Goal(trajectory=traj))
            assert res.error_code == code and res.error_msg, res.error_msg


def test_hand_command_and_reset_sim_reject_bad_requests(graph):
    client, c, _ = graph
    H = HandCommand
    for req, code in [
        (H.Request(mode=7), H.Response.INVALID_MODE),
        (H.Request(mode=H.Request.MODE_OPEN, spread=4.0), H.Response.OUT_OF_RANGE),
        (
            H.Request(mode=H.Request.MODE_POSITION, proximal=[0.1, 3.0, 0.1]),
            H.Response.OUT_OF_RANGE,
        ),
    ]:
        resp = client.call(c["hand"], req)
        assert resp.error_code == code and resp.error_msg
    closed = client.call(c["hand"], H.Request(mode=H.Request.MODE_CLOSE, spread=0.0))
    assert closed.error_code == H.Response.NONE
    proximal = [
        closed.joint_state.position[closed.joint_state.name.index(f"bh_f{i}_prox")]
        for i in (1, 2, 3)
    ]
    assert min(proximal) > 1.0  # nothing in the way: the fingers closed far
    assert reset(client, c, name="teapot").error_code == ResetSim.Response.UNKNOWN_OBJECT
    assert reset(client, c, pose=[3.0, 0.0, 0.0]).error_code == ResetSim.Response.INVALID_POSE
    assert reset(client, c, pose=[np.nan, 0.0, 0.0]).error_code == ResetSim.Response.INVALID_POSE
    assert reset(client, c, name="can", pose=[0.6, 0.05, 0.0]).error_code == ResetSim.Response.NONE
    assert reset(client, c).error_code == ResetSim.Response.NONE


OPEN_FINGERS = (1.0, 1.0, 1.0)


@pytest.mark.parametrize(
    "target, answers, sent, raised, fingers",
    [
        (0.2, ["stopped", "ok"], 2, None, OPEN_FINGERS),  # an opening stopped once: again
        (0.2, ["stopped", "stopped", "ok"], 3, None, OPEN_FINGERS),  # by one finger, another
        (0.2, ["stopped"] * 4, 4, "HandStopped", OPEN_FINGERS),  # stopped every time: for good
        (0.2, ["stopped", "refused"], 2, "MotionFailed", OPEN_FINGERS),  # a retry refused
        (0.2, ["refused"], 1, "MotionFailed", OPEN_FINGERS),  # refused (E-stop, stale data)
        (1.5, ["stopped"], 1, "HandStopped", OPEN_FINGERS),  # a closing is never sent again
        # a finger the object pushed just past its open stop still opens to it
        (0.0, ["stopped", "ok"], 2, None, (0.175, 0.175, -0.0014)),
    ],
)
def test_an_opening_the_safety_layer_stopped_is_tried_again(
    monkeypatch, target, answers, sent, raised, fingers
):
    """The robot client's policy on the bridge's answers to a hand position command, with the
    fingers at the given angles [rad]: an opening that was stopped midway is sent again, up to
    OPEN_RETRIES times; a refusal, a closing, or the last stop is the caller's."""
    from rrg_common.ros.msg_conversions import PROXIMAL_JOINT_NAMES, SPREAD_JOINT_NAME
    from rrg_sim.executor import robot_client

    monkeypatch.setattr(robot_client, "OPEN_RETRY_PAUSE_S", 0.0)
    robot = object.__new__(robot_client.RosRobot)
    robot._joints = {SPREAD_JOINT_NAME: 0.0, **dict(zip(PROXIMAL_JOINT_NAMES, fingers))}
    robot.node = rclpy_logger_stub()
    calls = []

    def hand(mode, spread, proximal):
        answer = answers[len(calls)]
        calls.append(proximal)
        if answer == "stopped":
            raise robot_client.HandStopped("hand_command failed (206): force ceiling")
        if answer == "refused":
            raise robot_client.MotionFailed("hand_command failed (204): E-stop latched")

    robot._hand = hand
    if raised is None:
        robot.move_hand(0.0, target)
    else:
        with pytest.raises(getattr(robot_client, raised)) as info:
            robot.move_hand(0.0, target)
        assert type(info.value).__name__ == raised
    assert len(calls) == sent


@pytest.mark.parametrize(
    "guard, code, on_contact, stop",
    [
        (True, "NONE", True, 1.0),  # a guarded move stopped halfway along 3 via-points
        (True, "FORCE_LIMIT", True, 1.0),  # its first contact spiked over the ceiling
        (False, "FORCE_LIMIT", False, "MotionFailed"),  # an unguarded move struck something
        (True, "FORCE_LIMIT", False, "MotionFailed"),  # the ceiling, but no contact trip
        (True, "STALE_DATA", False, "MotionFailed"),
    ],
)
def test_a_guarded_move_the_force_ceiling_stopped_on_contact_is_its_stop(
    guard, code, on_contact, stop
):
    """The robot client's policy on the bridge's guarded-move results: a guarded move that
    the force ceiling stopped at its contact stopped where it touched; any other error is
    the caller's."""
    from types import SimpleNamespace

    from rrg_msgs.action import GuardedMove
    from rrg_sim.executor import robot_client

    R = GuardedMove.Result
    res = R(error_code=getattr(R, code), stopped_on_contact=on_contact, path_fraction=0.5)
    robot = object.__new__(robot_client.RosRobot)
    robot.node = rclpy_logger_stub()
    robot.unconfirmed_stops = 0
    robot.move_client = SimpleNamespace(send_goal_async=lambda goal: "sent")
    handle = SimpleNamespace(accepted=True, get_result_async=lambda: "result")
    robot._wait = lambda future, what: handle if future == "sent" else SimpleNamespace(result=res)
    robot._sensed = lambda joint_state, sensors, tip_contacts: None
    q, t = np.zeros((3, 7)), np.array([0.0, 1.0, 2.0])
    if isinstance(stop, str):
        with pytest.raises(robot_client.MotionFailed, match=f"({getattr(R, code)})"):
            robot.follow(q, t, guard)
    else:
        assert robot.follow(q, t, guard) == pytest.approx(stop)


def rclpy_logger_stub():
    """A stand-in for the node: only its logger is used."""
    import logging
    from types import SimpleNamespace

    return SimpleNamespace(get_logger=lambda: logging.getLogger("robot_client_test"))
