"""The whole simulated graph, end to end, as ``rrg-launch`` runs it: each node in its own process,
a robust grasp of the box at low uncertainty judged a success by the simulator, a bag that
rosbags and Foxglove's readers decode completely, ``rrg-bag plot`` and ``summary`` on it; and
Ctrl-C in the middle of a grasp still leaves a finalized bag."""

from __future__ import annotations

import json
import signal
import subprocess
import sys

import numpy as np
import pytest
import yaml
from bag_frames import check_frames
from ros_testing import ROOT, ArmWatch, RosClient, ros_env
from rosbags.highlevel import AnyReader

from rrg_bags.bag_cli import bag_info
from rrg_bags.bag_cli import main as bag_cli
from rrg_common.ros.msg_conversions import ARM_JOINT_NAMES
from rrg_models import wam

NODE_MODULES = ROOT / ".cache" / "npm" / "node_modules"
LAUNCH = [sys.executable, "-m", "rrg_bringup.launch"]
JOINTS = "/rrg/joint_states"
#: Every topic the graph publishes during a grasp (the recorder must have them all).
GRAPH_TOPICS = {
    "/rrg/joint_states",
    "/rrg/fingertip1/wrench",
    "/rrg/fingertip2/wrench",
    "/rrg/fingertip3/wrench",
    "/rrg/contact_pads",
    "/rrg/eval/object_pose",
    "/rrg/eval/grasp_outcome",
    "/rrg/observation",
    "/rrg/belief",
    "/rrg/belief_markers",
    "/rrg/grasp_step",
    "/rosout",
    "/tf",
    "/tf_static",
    "/robot_description",
    "/diagnostics",
}
#: The status each node of the graph reports on /diagnostics once a second.
NODE_STATUSES = {
    "sim: status",
    "executor: status",
    "estimator: status",
    "planner: status",
    "rrg_bag_recorder: status",
}


def launch_args(tmp_path, name: str, domain_id: int, *extra: str) -> list[str]:
    return [
        *LAUNCH,
        "--grasp",
        "box",
        "--level",
        "low",
        "--levels",
        "low",
        "--domain-id",
        str(domain_id),
        "--bags",
        str(tmp_path),
        "--bag-name",
        name,
        "--log-dir",
        str(tmp_path / f"{name}_logs"),
        *extra,
    ]


@pytest.fixture(scope="module")
def grasp_run(tmp_path_factory, ros_domain):
    """One launcher run: returns (its JSON outcome, the bag folder, its stdout)."""
    tmp = tmp_path_factory.mktemp("graph")
    out = subprocess.run(
        launch_args(tmp, "e2e", ros_domain, "--seed", "4", "--json"),
        env=ros_env(ros_domain),
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stdout + out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1]), tmp / "e2e", out.stdout


@pytest.mark.slow  # the launcher's node processes
def test_robust_grasp_of_the_box_succeeds_as_judged_by_the_simulator(grasp_run):
    outcome, _, stdout = grasp_run
    assert outcome["error"] == ""
    assert outcome["success"], outcome["judge"]
    assert outcome["judge"].startswith("SUCCESS") and "held True" in outcome["judge"]
    assert outcome["actions"] and outcome["actions"][-1] == "goal"
    assert outcome["planner_success"] and outcome["p_goal"] > 0.9
    assert "step 1:" in stdout and "finalized" in stdout


@pytest.mark.slow  # the launcher's node processes
def test_bag_records_every_topic_and_rosbags_decodes_every_message(grasp_run):
    outcome, bag, _ = grasp_run
    assert sorted(p.name for p in bag.iterdir()) == ["e2e_0.mcap", "metadata.yaml"]
    info = bag_info(bag)
    assert info.finalized and info.profile == "ros2"
    counts = {t.name: t.count for t in info.topics}
    assert GRAPH_TOPICS <= set(counts), GRAPH_TOPICS - set(counts)
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["message_count"] == info.message_count
    decoded: dict[str, list] = {}
    with AnyReader([bag]) as reader:
        for conn, _, raw in reader.messages():
            decoded.setdefault(conn.topic, []).append(reader.deserialize(raw, conn.msgtype))
    assert {t: len(m) for t, m in decoded.items()} == {t: n for t, n in counts.items() if n}
    assert [o.wrt_name for o in decoded["/rrg/observation"]] == outcome["actions"]
    retreats = len(outcome["actions"]) - 1  # the hand retreats after every action but the last
    assert len(decoded.get("/rrg/retreated", [])) == retreats
    # the reset's belief, then one per action and one per retreat
    assert len(decoded["/rrg/belief"]) == 1 + len(outcome["actions"]) + retreats
    assert decoded["/rrg/belief"][-1].weights.size == 31 * 31 * 25
    assert decoded["/rrg/eval/grasp_outcome"][-1].message.startswith("SUCCESS")
    assert decoded["/rrg/joint_states"][-1].name[:7] == [f"wam_j{i}" for i in range(1, 8)]


@pytest.mark.slow  # the launcher's node processes
def test_the_bag_holds_every_nodes_health_from_diagnostics(grasp_run):
    """/diagnostics holds the status of every node of the graph, decoded by rosbags: each OK
    at some point (the planner once the executor and the estimator were up), and what each
    knows of the grasp: the planner's steps, the estimator's tables and update latency, the
    executor's executions, the recorder's bag."""
    outcome, bag, _ = grasp_run
    statuses: dict[str, list] = {}
    with AnyReader([bag]) as reader:
        conns = [c for c in reader.connections if c.topic == "/diagnostics"]
        for conn, _, raw in reader.messages(connections=conns):
            assert conn.msgtype == "diagnostic_msgs/msg/DiagnosticArray"
            for st in reader.deserialize(raw, conn.msgtype).status:
                statuses.setdefault(st.name, []).append(st)
    assert NODE_STATUSES <= set(statuses), set(statuses)
    values = lambda name: [{v.key: v.value for v in st.values} for st in statuses[name]]
    for name in NODE_STATUSES:
        assert any(st.level == 0 for st in statuses[name]), statuses[name][-1]  # OK
    ok = [
        v for st, v in zip(statuses["planner: status"], values("planner: status")) if not st.level
    ]
    assert ok and ok[-1]["peer executor"] == ok[-1]["peer estimator"] == "up"
    # each node also reports at once after its events (force_update), so even a one-action
    # grasp's bag has the status after each
    actions = outcome["actions"]
    steps = [v["last step"].split(" (")[0] for v in values("planner: status")]
    assert f"box step {len(actions)}: {actions[-1]}" in steps, steps
    assert "tables box/low" in values("planner: status")[-1]
    estimator = values("estimator: status")
    assert max(int(v["updates"]) for v in estimator) == len(actions)
    assert estimator[-1]["belief"] == "box" and "tables box/low" in estimator[-1]
    assert float(estimator[-1]["last update latency [ms]"]) > 0.0
    executor = values("executor: status")
    assert max(int(v["executions"]) for v in executor) == len(actions)
    assert executor[-1]["last execution result"] == "ok"
    assert float(executor[-1]["last execution duration [s]"]) > 0.0
    recorder = values("rrg_bag_recorder: status")[-1]
    assert recorder["bag"].endswith("e2e_0.mcap") and int(recorder["messages written"]) > 0
    assert recorder["messages dropped"] == "0"
    assert any(float(v["simulated time since reset [s]"]) > 0.0 for v in values("sim: status"))


@pytest.mark.slow  # the launcher's node processes
def test_the_bags_frames_put_the_fingertips_where_the_models_do(grasp_run):
    """bag_frames.check_frames: the bag's tf frames put the palm and the fingertips where the
    models do at the recorded joint states (within 1e-6 m)."""
    _, bag, _ = grasp_run
    checked, states = check_frames(bag)
    assert checked >= 0.9 * states and states >= 20, (checked, states)


@pytest.mark.slow  # the launcher's node processes
def test_foxglove_readers_decode_the_graph_bag(grasp_run):
    _, bag, _ = grasp_run
    out = subprocess.run(
        [
            "node",
            str(ROOT / "tests" / "foxglove_bag_reader.cjs"),
            str(NODE_MODULES),
            str(bag / "e2e_0.mcap"),
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0, out.stderr
    topics = json.loads(out.stdout)[
        "topics"
    ]  # (CDR's end padding counts as trailing bytes there: benign)
    assert {t: v["count"] for t, v in topics.items()} == {
        t.name: t.count for t in bag_info(bag).topics
    }
    assert GRAPH_TOPICS <= set(topics)


@pytest.mark.slow  # the launcher's node processes
def test_bag_plot_and_summary(grasp_run, capsys):
    outcome, bag, _ = grasp_run
    out = bag.with_name("plots")
    assert bag_cli(["plot", str(bag), "--out", str(out)]) == 0
    pngs = sorted(out.glob("*.png"))
    assert len(pngs) == len(outcome["actions"]) + 2  # a PNG per belief, and the overview
    assert all(p.read_bytes()[:4] == b"\x89PNG" for p in pngs)
    assert bag_cli(["summary", str(bag)]) == 0
    text = capsys.readouterr().out
    for k, name in enumerate(outcome["actions"], 1):
        assert f"step {k}: {name}" in text
    assert "Simulator: SUCCESS" in text and "Planner:   success = True" in text


@pytest.mark.slow  # the launcher's node processes
def test_ctrl_c_mid_grasp_leaves_a_finalized_bag(tmp_path, ros_domain):
    """SIGINT while the first WRT executes (the simulator paced at real time to make the grasp
    last): the launcher cancels the grasp, stops the nodes and the recorder in order."""
    env = ros_env(ros_domain)
    watcher = RosClient(env, "ctrl_c_watcher")
    arm_left_home = ArmWatch(watcher).left_home

    proc = subprocess.Popen(
        launch_args(tmp_path, "interrupted", ros_domain, "--real-time-factor", "1"),
        env=env,
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    lines = []
    try:
        for line in proc.stdout:  # until the first action is under way
            lines.append(line)
            if "step 1:" in line:
                break
        assert lines and "step 1:" in lines[-1], "".join(lines)
        # inside the WRT's guarded moves: the arm has left home
        assert watcher.spin_until(arm_left_home, 60.0), "the arm did not move"
        proc.send_signal(signal.SIGINT)
        rest, _ = proc.communicate(timeout=60)
    except BaseException:
        proc.kill()
        raise
    finally:
        watcher.close()
    text = "".join(lines) + rest
    assert proc.returncode == 1, text  # interrupted grasp
    assert (
        "interrupted: stopping the graph" in text
        and "finalized" in text
        and "NOT finalized" not in text
    )
    bag = tmp_path / "interrupted"
    info = bag_info(bag)
    assert info.finalized and info.message_count > 0
    assert (bag / "metadata.yaml").is_file()
    with AnyReader([bag]) as reader:
        assert sum(1 for _ in reader.messages()) == info.message_count


@pytest.mark.parametrize(
    "args, message",
    [
        (["--fake-hw"], "--fake-hw and --hw-param need --mode hw"),
        (["--hw-param", "dry_run:=true"], "--fake-hw and --hw-param need --mode hw"),
        (["--mode", "hw", "--hw-param", "dry_run"], "expected NAME:=VALUE"),
    ],
)
def test_hw_options_are_checked(args, message):
    out = subprocess.run([*LAUNCH, *args], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert out.returncode == 2
    assert message in out.stderr


def test_the_launcher_tells_the_belief_which_pads_the_bridge_cannot_read(tmp_path):
    """The bridge's pad_source, from --hw-param or its parameters file, gives the pads the
    estimator and the planner leave out."""
    from rrg_bringup.graph import bridge_pad_source
    from rrg_bringup.supervisor import LaunchError
    from rrg_hw_bridge.contact_guard import DERIVED_PADS_UNSENSED, UNSENSED_PADS

    params = tmp_path / "bridge.yaml"
    params.write_text("/**:\n  ros__parameters:\n    pad_source: derived\n")
    # by default the bridge reads Barrett's tactile pucks, which have no proximal pads
    assert UNSENSED_PADS[bridge_pad_source({}, None)] == ("prox1", "prox2", "prox3")
    assert UNSENSED_PADS["topic"] == ()
    assert UNSENSED_PADS[bridge_pad_source({}, params)] == DERIVED_PADS_UNSENSED
    assert bridge_pad_source({"pad_source": "topic"}, params) == "topic"  # the CLI wins
    with pytest.raises(LaunchError, match="pad_source"):
        bridge_pad_source({"pad_source": "gloves"}, None)


def test_an_unknown_world_profile_is_a_usage_error():
    out = subprocess.run(
        [*LAUNCH, "--world", "perfect"], capture_output=True, text=True, timeout=60, cwd=ROOT
    )
    assert out.returncode == 2 and "--world" in out.stderr and "realistic" in out.stderr


@pytest.mark.slow  # the launcher's node processes
def test_the_graph_runs_a_judged_grasp_in_the_realistic_world(tmp_path, ros_domain):
    """--world realistic reaches the simulator node, the estimator and the planner: the grasp
    runs and is judged by the test with required contacts, the joint states the simulator
    publishes are the encoders' readings, which start at home whatever the trial's joint
    offsets, and every goal grasp has its check on record, with the belief's posture frame."""
    args = launch_args(tmp_path, "realistic", ros_domain, "--world", "realistic", "--json")
    out = subprocess.run(
        args, env=ros_env(ros_domain), cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert out.returncode == 0, out.stdout + out.stderr
    outcome = json.loads(out.stdout.strip().splitlines()[-1])
    assert outcome["error"] == "" and outcome["judge"].startswith(("SUCCESS", "FAILURE"))
    assert "required contacts" in outcome["judge"] and "strict" in outcome["judge"]
    with AnyReader([tmp_path / "realistic"]) as reader:
        conns = [c for c in reader.connections if c.topic == "/rrg/joint_states"]
        first = next(reader.messages(connections=conns))
        msg = reader.deserialize(first[2], first[0].msgtype)
        conns = [c for c in reader.connections if c.topic == "/rrg/grasp_step"]
        steps = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(conns)]
        conns = [c for c in reader.connections if c.topic == "/rrg/observation"]
        observed = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(conns)]
    # every goal grasp began with a table touch (the executor's world_profile), and only those
    goal_heights = [o.table_height for o in observed if o.wrt_name == "goal"]
    assert goal_heights and all(abs(h) < 0.02 for h in goal_heights)
    assert all(np.isnan(o.table_height) for o in observed if o.wrt_name.startswith("info"))
    arm = [msg.position[list(msg.name).index(n)] for n in ARM_JOINT_NAMES]
    assert arm == pytest.approx(wam.HOME_Q, abs=1e-4)  # the encoders read home
    goals = [s.step for s in steps if s.event == 0 and s.wrt_kind == "goal"]  # EVENT_DECISION
    checks = [s for s in steps if s.event == 5]  # EVENT_GOAL_CHECKED
    assert goals and [c.step for c in checks] == goals
    last = checks[-1]
    assert last.p_goal == (0.0 if last.mismatches else last.p_goal_belief)
    # the box's WRTs all share the goal's posture frame, and a goal grasp leaves the belief's
    # frame as it was: the prior's, unless an information grasp ran first
    read = any(s.event == 0 and s.wrt_kind != "goal" and s.step < last.step for s in steps)
    assert last.posture_frame == ("goal" if read else "")


@pytest.mark.slow  # the launcher's node processes and an in-process MuJoCo run
def test_without_sensor_noise_the_graph_takes_the_in_process_agents_actions(tmp_path, ros_domain):
    """The closed loop is one piece of code: over ROS (executor and estimator nodes) and
    in-process (MuJoCo environment and BeliefTracker) it decides, executes, updates and retreats
    alike, so a noiseless grasp of several actions, retreats and a settling takes the same
    actions to the same P(goal)."""

    from rrg_experiments.physics_env import PhysicsEnvironment
    from rrg_models.config import WORLD
    from rrg_planner.agent import RobustGraspAgent
    from rrg_planner.closed_loop import run_in_process
    from rrg_planner.planning_model import PlanningModel
    from rrg_sim.physics.world import PhysicsWorld

    true = [0.72205, -0.12778, 0.21892]  # box, high uncertainty: five actions
    args = [*LAUNCH, "--grasp", "box", "--level", "high", "--sensor-noise", "0", "--no-bag"]
    args += ["--true-pose", *map(str, true), "--domain-id", str(ros_domain), "--json"]
    args += ["--log-dir", str(tmp_path / "logs")]
    out = subprocess.run(
        args, env=ros_env(ros_domain), cwd=ROOT, capture_output=True, text=True, timeout=600
    )
    assert out.returncode == 0, out.stdout + out.stderr
    graph = json.loads(out.stdout.strip().splitlines()[-1])

    env = PhysicsEnvironment(PhysicsWorld("box", sensor_noise=0.0))
    env.reset(np.array(true), seed=0)
    model = PlanningModel("box", levels=("high", "mid", "low"), workers=1, progress=False)
    local = run_in_process(RobustGraspAgent(model), env, "high", WORLD.nominal_pose)

    assert len(local.steps) > 2 and graph["error"] == ""
    assert graph["actions"] == [s.wrt for s in local.steps]
    assert graph["p_goal"] == pytest.approx(local.p_goal, rel=1e-6)
    assert graph["success"] == local.success
