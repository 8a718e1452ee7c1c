"""End to end through the hardware bridge: ``rrg-launch --mode hw --fake-hw`` runs a robust
grasp of the drill on the emulated drivers, the MuJoCo judge scores it, and its bag opens in
both readers; a pad dropout in the middle of a guarded move is withdrawn from and the grasp
goes on. A module of its own, so no other graph shares the machine while it runs."""

from __future__ import annotations

import json
import signal
import subprocess
import time

import pytest
from ros_testing import ROOT, exclusive_domain_id, network_namespace, ros_env
from rosbags.highlevel import AnyReader

from rrg_bags.bag_cli import bag_info

NODE_MODULES = ROOT / ".cache" / "npm" / "node_modules"
#: The bridge's parameters file (a lab's would name its drivers and limits).
HW_PARAMS = """/**:
  ros__parameters:
    watchdog_timeout: 0.15
    confirm_stops: true
    pad_source: tactile
"""
#: Longest run of the launcher [s] (a grasp takes ~ 1.5 min in real time).
E2E_TIMEOUT_S = 600

pytestmark = pytest.mark.slow


def test_a_robust_grasp_runs_end_to_end_through_the_bridge(tmp_path):
    """rrg-launch in hw mode on the emulated drivers, in a DDS domain of its own, the bridge's
    parameters from a file, discovering its peers beyond loopback (SUBNET) inside a network
    namespace of its own (on this host's network where none can be made)."""
    logs = tmp_path / "logs"
    params = tmp_path / "bridge.yaml"
    params.write_text(HW_PARAMS)
    netns = network_namespace(tmp_path)
    print("in a network namespace" if netns else "no network namespace: on this host's network")
    with exclusive_domain_id() as domain_id:
        proc = subprocess.Popen(
            [
                *(netns or []),
                str(ROOT / ".venv" / "bin" / "rrg-launch"),
                *("--mode", "hw", "--fake-hw", "--grasp", "powerdrill", "--level", "high"),
                *("--seed", "0", "--json", "--domain-id", str(domain_id)),
                *("--bags", str(tmp_path), "--bag-name", "hw", "--log-dir", str(logs)),
                *("--hw-params", str(params), "--discovery-range", "SUBNET"),
            ],
            env=ros_env(domain_id),
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            stdout, stderr = proc.communicate(timeout=E2E_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            # Ctrl-C: the launcher stops its children (each in its own session) in order
            proc.send_signal(signal.SIGINT)
            stdout, stderr = proc.communicate(timeout=60)
            pytest.fail(f"rrg-launch took over {E2E_TIMEOUT_S} s: {stdout[-3000:]}")
    assert proc.returncode == 0, stdout[-3000:] + stderr[-3000:]
    outcome = json.loads(stdout.strip().splitlines()[-1])
    print(f"actions {outcome['actions']}: {outcome['judge']}")
    assert outcome["error"] == "", outcome["error"]
    assert outcome["actions"], outcome
    assert outcome["judge"].startswith(("SUCCESS", "FAILURE")), outcome["judge"]
    assert outcome["success"] == outcome["judge"].startswith("SUCCESS")

    bag = tmp_path / "hw"
    info = bag_info(bag)
    assert info.finalized and info.profile == "ros2" and info.message_count > 0
    counts = {t.name: t.count for t in info.topics if t.count}
    assert {"/rrg/joint_states", "/rrg/fingertip1/wrench", "/rrg/observation"} <= set(counts)
    decoded: dict[str, int] = {}
    with AnyReader([bag]) as reader:
        for conn, _, raw in reader.messages():
            reader.deserialize(raw, conn.msgtype)
            decoded[conn.topic] = decoded.get(conn.topic, 0) + 1
    assert decoded == counts
    fox = subprocess.run(
        ["node", str(ROOT / "tests" / "foxglove_bag_reader.cjs"), str(NODE_MODULES)]
        + [str(bag / "hw_0.mcap")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert fox.returncode == 0, fox.stderr
    topics = json.loads(fox.stdout)["topics"]
    assert {t: v["count"] for t, v in topics.items() if v["count"]} == counts

    texts = {p.name: p.read_text() for p in logs.glob("*.log")}
    assert {"fake_hw.log", "hw_bridge.log"} <= set(texts)
    assert "watchdog 150 ms" in texts["hw_bridge.log"]  # from the parameters file
    # the pads as Barrett's hand publishes them: its tactile pucks, no proximal pads
    assert "pads from Barrett's tactile pucks on /bhand/tactile_states" in texts["hw_bridge.log"]
    assert "discovery range SUBNET" in stdout
    texts["stdout+stderr"] = stdout + stderr
    assert not [name for name, text in texts.items() if "Traceback" in text]


#: How long the dropout test silences the hand driver's pads [s] (the bridge's watchdog
#: allows 150 ms).
DROPOUT_S = 0.5


def test_a_pad_dropout_stops_a_guarded_move_and_the_grasp_goes_on(tmp_path, ros_domain):
    """The hand driver's pads go silent for DROPOUT_S while the first WRT's guarded move runs:
    the bridge stops the move (STALE_DATA), the executor brings the hand home and answers
    SAFETY_STOP, the planner chooses again on the same belief, and the grasp ends without an
    error."""
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter
    from ros_testing import Launcher, RosClient

    params = tmp_path / "bridge.yaml"
    params.write_text(HW_PARAMS)
    watcher = RosClient(ros_env(ros_domain), "dropout_watcher")
    faults = watcher.node.create_client(SetParameters, "/fake_hw/set_parameters")

    def silent(on: bool) -> None:
        fault = Parameter("fault.silent_tactile", value=on).to_parameter_msg()
        answer = watcher.call(faults, SetParameters.Request(parameters=[fault]))
        assert answer.results[0].successful, answer.results[0].reason

    def dropout() -> None:
        silent(True)
        time.sleep(DROPOUT_S)
        silent(False)

    launcher = Launcher(
        tmp_path,
        "dropout",
        ros_domain,
        *("--mode", "hw", "--fake-hw", "--grasp", "powerdrill", "--level", "high"),
        *("--seed", "0", "--json", "--hw-params", str(params)),
    )
    try:
        text = launcher.disturb_while_moving(1, watcher, dropout)
    finally:
        watcher.close()
    assert launcher.proc.returncode == 0, text[-3000:]
    outcome = json.loads(text.strip().splitlines()[-1])
    assert outcome["error"] == "", outcome["error"]
    assert outcome["actions"] and outcome["actions"][-1] == "goal", outcome
    planner = (launcher.log_dir / "planner.log").read_text()
    assert "stopped by the safety layer" in planner and "replanning" in planner
    assert "no fresh data" in (launcher.log_dir / "hw_bridge.log").read_text()
    texts = [p.read_text() for p in launcher.log_dir.glob("*.log")]
    assert not [t for t in texts if "Traceback" in t]
