"""The graph ``rrg-launch`` runs (operations §8): its child processes, their respawn, the
launcher's own node, and one robust grasp on it. ``rrg_bringup.launch`` is the command line
around it; the soak (``--grasps``) and the benchmarks drive the same ``Graph``.
"""

from __future__ import annotations

import os
import shutil
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from rrg_bringup.supervisor import (
    RESPAWN_DELAY_S,
    RESPAWN_MAX,
    Child,
    LaunchError,
    LaunchTimeout,
    Supervisor,
    ros_args,
)
from rrg_estimator.config import LEVELS
from rrg_hw_bridge.contact_guard import DEFAULT_PAD_SOURCE, UNSENSED_PADS
from rrg_models.config import WORLD
from rrg_models.poses import compose_planar

ROOT = Path(__file__).resolve().parents[1]
RECORDER = "rrg_bag_recorder"
#: The nodes' recovery state of each run goes in STATE_ROOT/<run name>/ (removed at the end).
STATE_ROOT = ROOT / ".cache" / "state"
#: The launcher's record of its children's exits and restarts: latched with a history deep
#: enough for every event of a run, so that a restarted recorder receives them all.
NODE_EVENTS_TOPIC = "/rrg/launch/node_events"
NODE_EVENTS_DEPTH = 100
#: Longest wait [s] for the recorder to acknowledge the last node events before the launcher's
#: node goes (with it their history).
NODE_EVENTS_ACK_S = 2.0
#: After the judgement the launcher waits (at most this long [s]) until its own subscription
#: has the grasp outcome message, then OUTCOME_GRACE_S more, before it stops the graph: the
#: recorder, busy writing beliefs on a loaded machine, lost that last message to the stop
#: (CI on a fresh clone, once).
OUTCOME_WAIT_S = 10.0
OUTCOME_GRACE_S = 0.5
#: Longest wait [s] for a restarted planner to be back (it loads its models first) before the
#: grasp it was running is resumed.
RESUME_WAIT_S = 300.0
#: With --grasps: longest a grasp may run before it counts as hung [s] (chosen: a robust grasp of
#: the drill at high uncertainty takes ~20 s unpaced; ten actions at real time stay under 5 min).
GRASP_TIMEOUT_S = 600.0
#: Module of each node process, in start order (the recorder is started first, stopped last).
NODES = {
    "sim": "rrg_sim.ros.sim_node",
    "fake_hw": "rrg_fake_hw.fake_hw_node",
    "hw_bridge": "rrg_hw_bridge.ros.bridge_node",
    "executor": "rrg_sim.executor.executor_node",
    "estimator": "rrg_estimator.ros.estimator_node",
    "planner": "rrg_planner.ros.planner_node",
}
#: The arm/hand interface's processes per mode: the simulator, the bridge on the real drivers,
#: or the bridge on emulated drivers.
INTERFACE = {"sim": ("sim",), "hw": ("hw_bridge",), "fake_hw": ("fake_hw", "hw_bridge")}
#: Drivers' topics not recorded in hw mode: the 500 Hz joint states would cost the recorder
#: ~ 40 % of a core (measured); the bridge's /rrg/joint_states carries the arm and hand at 50 Hz.
DRIVER_TOPICS = ("/joint_states",)
#: Simulation-only services (the simulator's, or the emulated drivers').
EVAL_SERVICES = ("/rrg/reset_sim", "/rrg/eval/judge_grasp")
#: What must answer before the graph counts as ready (with EVAL_SERVICES when simulated), besides
#: the planner's and the estimator's services and action that ``RRGClient`` waits for.
SERVICES = ("/rrg/hand_command", "/rrg/retreat")
ACTIONS = ("/rrg/guarded_move", "/rrg/execute_wrt")


@dataclass
class GraspOutcome:
    """What ``--grasp`` prints (and, with ``--json``, prints as JSON on the last line)."""

    object_name: str
    level: str
    strategy: str
    true_pose: list[float]
    actions: list[str] = field(default_factory=list)
    p_goal: float = float("nan")
    planner_success: bool = False  # the planner believed P(goal) > 1 - δ
    success: bool = False  # judged by the simulator: ground truth in the goal region + lift
    judge: str = ""
    error: str = ""
    bag: str = ""
    launch_to_first_action_s: float = float("nan")


class Graph(Supervisor):
    """The running graph: RRG's nodes as child processes (Supervisor), plus the launcher's
    own client node and one robust grasp on it."""

    def __init__(
        self,
        env: dict[str, str],
        bag_dir: Path | None,
        log_dir: Path | None,
        interface: str = "sim",
        respawn_max: int = RESPAWN_MAX,
        respawn_delay_s: float = RESPAWN_DELAY_S,
        state_dir: Path | None = None,
    ):
        super().__init__(env, log_dir, respawn_max, respawn_delay_s, cwd=ROOT)
        #: where the estimator and the planner keep the state a restarted one resumes from
        self.state_dir = state_dir
        self.interface = interface  # a key of INTERFACE
        self.simulated = interface != "hw"  # the world can be reset and judged
        self.bag_dir = bag_dir
        self.started = time.monotonic()
        self.node = None
        self.executor = None
        self._context = None
        self.clients: dict = {}  # service name → client (wait_ready creates them)
        self.actions: dict = {}  # action name → ActionClient
        self.rrg = None  # the planner's client, an rrg_planner.client.RRGClient (connect makes it)
        self.outcomes_seen = 0  # grasp outcome messages the launcher has received
        self.grasp_task = None  # the running robust grasp (an rrg_planner.client.GraspTask)
        self.interrupted = False  # set by Ctrl-C or SIGTERM, acted on in spin_until
        self.node_events = None  # the publisher of NODE_EVENTS_TOPIC (connect creates it)
        self.planner = None  # the planner's liveliness (connect creates it)

    def start(
        self,
        object_name: str,
        levels: list[str],
        seed: int,
        real_time_factor: float,
        sensor_noise: float = 1.0,
        hw_params: dict[str, str] | None = None,
        world_profile: str = "nominal",
        preload: list[str] | None = None,
        hw_params_file: Path | None = None,
    ) -> None:
        """Start the recorder (if recording), the arm/hand interface and the executor, estimator
        and planner (the launch time counts from here). ``hw_params``: the bridge's parameters;
        ``world_profile``: the simulator's (rrg_sim.config.WORLD_PROFILES), which the estimator
        and the planner assume too (on hardware they assume "realistic": a real robot's
        calibration error); ``preload``: the objects whose planning models the planner loads
        first (default: ``object_name``); ``hw_params_file``: a ROS 2 parameters YAML for the
        bridge, which ``hw_params`` override."""
        self.started = time.monotonic()
        if self.bag_dir is not None:
            self.spawn(
                "recorder",
                [
                    "-m",
                    "rrg_bags.recorder_node",
                    "--output",
                    str(self.bag_dir),
                    *ros_args(
                        {
                            "discovery_period": 0.1,
                            **(
                                {"exclude_topics": list(DRIVER_TOPICS)}
                                if self.interface != "sim"
                                else {}
                            ),
                        }
                    ),
                ],
                restart_args=["--append"],  # the next split of the bag
            )
        self.start_interface(
            object_name,
            seed,
            real_time_factor,
            sensor_noise,
            hw_params,
            world_profile,
            hw_params_file,
        )
        state = {}
        if self.state_dir is not None:  # a fresh run: no state of an earlier one
            shutil.rmtree(self.state_dir, ignore_errors=True)
            self.state_dir.mkdir(parents=True)
            state = {n: {"state_file": str(self.state_dir / f"{n}.state")} for n in NODES}
        assumed = world_profile if self.simulated else "realistic"
        # the pads the bridge has no reading of are left out of the belief's likelihood
        unsensed = (
            ()
            if self.interface == "sim"
            else UNSENSED_PADS[bridge_pad_source(hw_params or {}, hw_params_file)]
        )
        sensing = {"unsensed_sensors": list(unsensed or ("",))}
        params = {
            "executor": {"world_profile": assumed},
            "estimator": {"world_profile": assumed, **sensing, **state.get("estimator", {})},
            "planner": {
                **sensing,
                "world_profile": assumed,
                "levels": list(levels),
                "preload": list(preload or [object_name]),
                **state.get("planner", {}),
            },
        }
        for name, values in params.items():
            self.spawn(name, ["-m", NODES[name], *ros_args(values)])

    def start_interface(
        self,
        object_name: str,
        seed: int,
        real_time_factor: float = 0.0,
        sensor_noise: float = 1.0,
        hw_params: dict[str, str] | None = None,
        world_profile: str = "nominal",
        hw_params_file: Path | None = None,
    ) -> None:
        """Start the arm/hand interface's processes (INTERFACE[self.interface])."""
        world = {"object_name": object_name, "seed": seed, "sensor_noise": sensor_noise}
        hosts = rdt_addresses(int(self.env["ROS_DOMAIN_ID"]))
        # The emulated robot's bridge arms itself at start; its latch lives as long as the run
        # (a restarted bridge keeps an E-stop). On a real arm the operator arms it.
        emulated_bridge = {"arm_on_start": "true", "netft_http_port": str(FAKE_NETFT_HTTP_PORT)}
        run_dir = self.state_dir or self.log_dir
        if run_dir is not None:
            emulated_bridge["estop_latch_file"] = str(Path(run_dir) / "estop.latched")
        params = {
            "sim": {**world, "real_time_factor": real_time_factor, "world_profile": world_profile},
            "fake_hw": {
                **world,
                "rdt_hosts": hosts,
                "netft_http_port": str(FAKE_NETFT_HTTP_PORT),
            },
            "hw_bridge": {
                **({"rdt_hosts": hosts, **emulated_bridge} if self.interface == "fake_hw" else {}),
                **(hw_params or {}),
            },
        }
        for name in INTERFACE[self.interface]:
            params_file = hw_params_file if name == "hw_bridge" else None
            self.spawn(name, ["-m", NODES[name], *ros_args(params[name], params_file)])

    def on_event(self, c: Child, event: str, message: str, attempt: int, delay: float) -> None:
        """Publish a child's event on NODE_EVENTS_TOPIC once the launcher's node runs."""
        if self.node_events is None:
            return
        from rrg_msgs.msg import NodeEvent

        status = c.proc.returncode if event != "EVENT_RESTARTED" else None
        msg = NodeEvent(
            node=c.name,
            event=getattr(NodeEvent, event),
            pid=c.proc.pid,
            exit_code=max(status or 0, 0),
            signal=max(-(status or 0), 0),
            attempt=attempt,
            max_attempts=self.respawn_max,
            delay=delay,
            message=message,
        )
        msg.header.stamp = self.node.get_clock().now().to_msg()
        self.node_events.publish(msg)

    # ------------------------------------------------------------------ the launcher's node
    def connect(self) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from rclpy.signals import SignalHandlerOptions

        from rrg_common.ros.liveliness import PeerWatch
        from rrg_msgs.msg import NodeEvent
        from rrg_planner.client import RRGClient

        os.environ.update(
            {
                k: self.env[k]
                for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_STATIC_PEERS")
                if k in self.env
            }
        )
        self._context = rclpy.Context()
        # The launcher handles SIGINT itself (it must stop the children in order).
        rclpy.init(context=self._context, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node("rrg_launch", context=self._context)
        self.node_events = self.node.create_publisher(
            NodeEvent,
            NODE_EVENTS_TOPIC,
            QoSProfile(
                depth=NODE_EVENTS_DEPTH,
                durability=DurabilityPolicy.TRANSIENT_LOCAL,
                reliability=ReliabilityPolicy.RELIABLE,
            ),
        )
        self.planner = PeerWatch(self.node, "planner")
        self.executor = SingleThreadedExecutor(context=self._context)
        self.executor.add_node(self.node)
        self.rrg = RRGClient(self.node, spin_once=self.spin_once)

    def disconnect(self) -> None:
        import rclpy

        if self.node is not None:
            from rclpy.duration import Duration

            # the recorder must have the last events before their history goes with the node
            if self.node_events is not None and self.node_events.get_subscription_count():
                self.node_events.wait_for_all_acked(Duration(seconds=NODE_EVENTS_ACK_S))
            self.node_events = None
            self.executor.shutdown()
            self.node.destroy_node()
            rclpy.try_shutdown(context=self._context)
            self.node = None

    def spin_once(self, timeout_s: float = 0.05) -> None:
        """Restart children that died, then spin the launcher's node once; KeyboardInterrupt
        (once) after Ctrl-C or SIGTERM, LaunchError when a child has used up its restarts."""
        if self.interrupted:
            self.interrupted = False  # once: the shutdown that follows may spin again
            raise KeyboardInterrupt
        self.supervise()
        self.executor.spin_once(timeout_sec=timeout_s)

    def spin_until(self, condition: Callable[[], bool], timeout_s: float, what: str) -> None:
        """``spin_once`` until ``condition()``; LaunchTimeout after ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while not condition():
            if time.monotonic() > deadline:
                raise LaunchTimeout(f"timed out after {timeout_s:.0f} s waiting for {what}")
            self.spin_once()

    def result(self, future, timeout_s: float, what: str):
        self.spin_until(future.done, timeout_s, what)
        return future.result()

    def wait_armed(self, timeout_s: float) -> None:
        """On a real arm: wait until the bridge's status says ready, which needs an operator to
        arm it (it starts not armed); says once what it waits for."""
        from diagnostic_msgs.msg import DiagnosticStatus

        status: list = []
        self.node.create_subscription(
            DiagnosticStatus, "/rrg/bridge/status", lambda m: status.append(m), 10
        )
        self.spin_until(lambda: status, timeout_s, "the bridge's status")
        if status[-1].level != DiagnosticStatus.OK:
            print(
                f"[rrg-launch] the bridge is not ready: {status[-1].message}. Release the E-stop "
                "and arm it: ros2 service call /rrg/bridge/reset_estop std_srvs/srv/Trigger",
                flush=True,
            )
        ready = lambda: status[-1].level == DiagnosticStatus.OK
        self.spin_until(ready, timeout_s, "an armed bridge with fresh data")

    def wait_ready(self, timeout_s: float) -> float:
        """Wait for every service and action server and for the recorder's subscriptions;
        returns the seconds since the launch."""
        from rclpy.action import ActionClient
        from std_srvs.srv import Trigger

        from rrg_msgs.action import ExecuteWrt, GuardedMove
        from rrg_msgs.msg import GraspOutcome
        from rrg_msgs.srv import HandCommand, ResetSim, Retreat

        types = {
            "/rrg/reset_sim": ResetSim,
            "/rrg/hand_command": HandCommand,
            "/rrg/eval/judge_grasp": Trigger,
            "/rrg/retreat": Retreat,
            "/rrg/guarded_move": GuardedMove,
            "/rrg/execute_wrt": ExecuteWrt,
        }
        services = [*SERVICES, *(EVAL_SERVICES if self.simulated else ())]
        self.clients = {name: self.node.create_client(types[name], name) for name in services}
        self.actions = {name: ActionClient(self.node, types[name], name) for name in ACTIONS}
        self.node.create_subscription(GraspOutcome, "/rrg/eval/grasp_outcome", self.on_outcome, 10)
        deadline = time.monotonic() + timeout_s
        for name, client in [*self.clients.items(), *self.actions.items()]:
            ready = client.service_is_ready if name in self.clients else client.server_is_ready
            self.spin_until(ready, deadline - time.monotonic(), name)
        self.spin_until(
            self.rrg.is_ready,
            deadline - time.monotonic(),
            "the planner's and the estimator's services (planning models load first)",
        )
        # The planner's liveliness too: a grasp that starts before it is seen would take the
        # planner for lost at once, and resend the goal.
        self.spin_until(
            lambda: self.planner.alive, deadline - time.monotonic(), "the planner's liveliness"
        )
        if self.bag_dir is not None:
            self.spin_until(
                self.recorder_caught_up, deadline - time.monotonic(), "the recorder's subscriptions"
            )
        return time.monotonic() - self.started

    def recorder_caught_up(self) -> bool:
        """Whether the recorder subscribes to every visible topic that has a publisher."""
        from rrg_bags.recorder_node import is_hidden

        excluded = DRIVER_TOPICS if self.interface != "sim" else ()
        for topic, _ in self.node.get_topic_names_and_types():
            if (
                is_hidden(topic)
                or topic in excluded
                or not self.node.get_publishers_info_by_topic(topic)
            ):
                continue
            if not any(
                s.node_name == RECORDER for s in self.node.get_subscriptions_info_by_topic(topic)
            ):
                return False
        return True

    # ------------------------------------------------------------------ one grasp
    def grasp(
        self,
        outcome: GraspOutcome,
        horizon: int,
        delta: float,
        max_actions: int,
        on_first_action: Callable[[], None] | None = None,
        timeout_s: float = 3600.0,
        verbose: bool = True,
    ) -> GraspOutcome:
        """Place the object, run the robust grasp, judge it; fills and returns ``outcome``.
        ``timeout_s``: longest wait for the robust grasp's result (LaunchTimeout after it);
        ``verbose``: print a line per step."""
        from rrg_msgs.action import RobustGrasp
        from rrg_planner.client import GraspFeedback

        if self.simulated:
            self.reset_sim(outcome)

        def feedback(fb: GraspFeedback) -> None:
            if fb.step == 1 and on_first_action is not None:
                on_first_action()
            if verbose:
                goal = f" of {fb.goal_wrt_name}" if fb.goal_wrt_name not in ("", "goal") else ""
                print(
                    f"[rrg-launch] step {fb.step}: {fb.wrt_name} "
                    f"(P(goal) = {fb.p_goal:.3f}{goal}, value = {fb.value:.3f})",
                    flush=True,
                )

        goal = dict(
            level=outcome.level,
            strategy=outcome.strategy,
            horizon=horizon,
            delta=delta,
            max_actions=max_actions,
            on_feedback=feedback,
        )
        res = self.robust_grasp(outcome.object_name, goal, timeout_s)
        outcome.actions, outcome.p_goal, outcome.planner_success = (
            res.actions,
            res.final_p_goal,
            res.success,
        )
        if res.error_code != RobustGrasp.Result.NONE:
            outcome.error = f"robust_grasp error {res.error_code}: {res.error_msg}"
        elif not self.simulated:
            outcome.judge = "not judged: a real robot has no ground truth"
        else:
            self.judge(outcome)
        return outcome

    def reset_sim(self, outcome: GraspOutcome) -> None:
        """Place the object at the outcome's true pose in the simulator."""
        from rrg_common.ros.msg_conversions import planar_to_msg
        from rrg_msgs.srv import ResetSim

        request = ResetSim.Request(
            object_name=outcome.object_name, pose=planar_to_msg(outcome.true_pose)
        )
        reset = self.result(self.clients["/rrg/reset_sim"].call_async(request), 60.0, "reset_sim")
        if reset.error_code != ResetSim.Response.NONE:
            raise LaunchError(f"reset_sim failed: {reset.error_msg}")

    def robust_grasp(self, object_name: str, goal: dict, timeout_s: float):
        """The planner's robust grasp of ``object_name`` (``goal``: start_robust_grasp's
        keywords) to its result; a goal a restarted planner lost is sent again to resume."""
        from rrg_planner.client import RRGError

        resumes = 0  # goals sent again to a restarted planner
        task = None
        while task is None or not task.done():
            if task is None:
                planner_proc = self.process("planner")
                losses = self.planner.losses
                try:
                    task = self.rrg.start_robust_grasp(
                        object_name, **goal, resume=resumes > 0, timeout_s=30.0
                    )
                except RRGError as exc:
                    raise LaunchError(str(exc)) from exc
                self.grasp_task = task
            self.spin_until(
                lambda t=task, n=losses: t.done() or self.planner.lost_since(n),
                timeout_s,
                "the robust grasp",
            )
            if task.done():
                break
            print(
                "[rrg-launch] the planner went away in the middle of the grasp: resuming it "
                "once the planner is back",
                flush=True,
            )
            self.spin_until(
                lambda: self.planner.alive and self.rrg.is_ready(),
                RESUME_WAIT_S,
                "the restarted planner",
            )
            if planner_proc is not None and self.process("planner") is planner_proc:
                # its liveliness lapsed (a stalled host), but the process that runs the grasp
                # lives: a second goal would be refused, so wait on the first
                print(
                    "[rrg-launch] the planner had stalled, not died (same process): waiting on "
                    "its grasp",
                    flush=True,
                )
                losses = self.planner.losses
                continue
            resumes += 1
            if resumes > self.respawn_max:
                raise LaunchError("the planner kept going away: the grasp was not completed")
            task = None
        self.grasp_task = None
        return task.result(0.0)

    def judge(self, outcome: GraspOutcome) -> None:
        """The simulator's judgement of the grasp into ``outcome``; waits until the outcome
        message has reached the recorder."""
        from std_srvs.srv import Trigger

        seen = self.outcomes_seen
        judged = self.result(
            self.clients["/rrg/eval/judge_grasp"].call_async(Trigger.Request()),
            120.0,
            "judge_grasp",
        )
        outcome.success, outcome.judge = judged.success, judged.message
        try:  # let the outcome message reach the recorder before anything stops
            self.spin_until(
                lambda: self.outcomes_seen > seen, OUTCOME_WAIT_S, "/rrg/eval/grasp_outcome"
            )
            grace = time.monotonic() + OUTCOME_GRACE_S
            self.spin_until(lambda: time.monotonic() > grace, OUTCOME_GRACE_S + 1.0, "the recorder")
        except LaunchTimeout as exc:
            print(f"[rrg-launch] warning: {exc}", file=sys.stderr, flush=True)

    def on_outcome(self, _msg) -> None:
        self.outcomes_seen += 1

    def cancel_grasp(self) -> None:
        """Cancel a running robust grasp (best effort, before the nodes are stopped)."""
        self.stopping = True
        task = self.grasp_task
        if task is not None and self.node is not None:
            cancelled = task.cancel()
            if cancelled is not None:
                try:
                    self.result(cancelled, 3.0, "the grasp's cancellation")
                except LaunchError:
                    pass


#: TCP port the emulated Net F/T boxes serve their netftapi2.xml on (a real box: 80, which
#: only root may bind).
FAKE_NETFT_HTTP_PORT = 8080


def bridge_pad_source(hw_params: dict[str, str], hw_params_file: Path | None) -> str:
    """The bridge's pad_source: from ``hw_params``, else from the parameters file (any node
    section's ros__parameters), else its default; LaunchError for an unknown one."""
    source = hw_params.get("pad_source")
    if source is None and hw_params_file is not None:
        sections = yaml.safe_load(Path(hw_params_file).read_text()) or {}
        for section in sections.values():
            source = ((section or {}).get("ros__parameters") or {}).get("pad_source", source)
    source = str(source if source is not None else DEFAULT_PAD_SOURCE).strip("'\"")
    if source not in UNSENSED_PADS:
        raise LaunchError(f"pad_source must be one of {list(UNSENSED_PADS)}, got {source!r}")
    return source


def rdt_addresses(domain_id: int) -> list[str]:
    """Loopback addresses of the emulated Net F/T boxes of fingers 1-3: 127.0.0.2-4 in domain
    0, 127.0.<domain>.2-4 in another, so that graphs in different domains never share a port."""
    return [f"127.0.{domain_id}.{k}" for k in (2, 3, 4)]


def warm_tables(object_name: str, levels: list[str]) -> None:
    """Load, or build in parallel (with progress bars), the object's observation tables at the
    given levels, before any node starts: the nodes then only read the cache (they must not
    fork build workers while running DDS threads)."""
    from rrg_estimator.obs_tables import load_or_build
    from rrg_models.objects import get_object

    obj = get_object(object_name)
    for level in levels:
        for wrt in obj.wrts():
            load_or_build(obj, wrt, LEVELS[level], workers=2, progress=True)


def draw_pose(rng: np.random.Generator, level: str) -> np.ndarray:
    """A true pose drawn from the level's Gaussian around the nominal pose."""
    return compose_planar(np.asarray(WORLD.nominal_pose), rng.normal(0.0, LEVELS[level].sigma))
