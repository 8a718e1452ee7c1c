"""Constants of the hardware bridge, each with its source. Everything a lab may need to change
is also a node parameter (rrg_hw_bridge.ros.bridge_node); these are the defaults."""

from __future__ import annotations

from dataclasses import dataclass


# ------------------------------------------------------------------------ the bridge
@dataclass(frozen=True)
class BridgeParams:
    """Defaults of the bridge node's safety layer and timing."""

    #: Age [s] of the newest joint state or fingertip wrench beyond which the arm holds and new
    #: goals are refused (docs/sources.md §6: "older than about 0.1 s").
    watchdog_timeout: float = 0.1
    #: Period [s] of the watchdog's check (chosen: a tenth of the timeout, so a silence is
    #: caught within 0.11 s; the issue asks for a hold within 0.15 s).
    watchdog_period: float = 0.01
    #: Fingertip force [N] / torque [N m] ceiling that aborts any move and holds (chosen: 80 %
    #: of the Nano17 SI-25-0.25 calibration's Fx/Fy range of 25 N and Tx/Ty/Tz range of
    #: 0.25 N m, ATI Nano17 datasheet; beyond it the reading saturates).
    force_ceiling: float = 20.0
    torque_ceiling: float = 0.2
    #: How long [s] after a Net F/T sequence gap or status error new goals are still refused
    #: (chosen: a stream must run clean this long before the bridge trusts it again).
    sensor_fault_hold: float = 1.0
    #: A Net F/T box silent this long [s] is asked to stream again (chosen: 5× the watchdog;
    #: a box that was not up when the bridge started, or rebooted, never streams by itself).
    rdt_revive_after: float = 0.5
    #: Via-points closer in time [s] than this to the previous one are the same instant (one
    #: 500 Hz WAM control period; the executor's paths start with a repeated point a few ns
    #: after the first).
    min_segment_time: float = 0.002
    #: The arm counts as settled after a stop when every joint is slower than this [rad/s] ...
    settle_speed: float = 0.02
    #: ... or after this long [s] (chosen: a WAM stop from the executor's 0.2 m/s guarded speed
    #: takes ~ 0.05 s; 0.3 s leaves margin).
    settle_timeout: float = 0.3
    #: Extra time [s] the controller may take past the trajectory's end (JTC's
    #: goal_time_tolerance; the notes: "goal_time 0 means wait forever, so set it").
    goal_time_tolerance: float = 1.0
    #: A controller that has not ended a canceled goal after this long [s] gets a hold and the
    #: robot is declared faulty until reset (chosen: a JTC or wam_node cancel takes effect
    #: within a control period, 2 ms; a WAM at the guarded speed has stopped in ~ 0.05 s) ...
    cancel_escalation: float = 0.5
    #: ... the hold: a one-point trajectory to the measured configuration this long [s] ahead
    #: (chosen: a few of JTC's control periods, so the interpolation is a stop, not a jump).
    hold_time: float = 0.05
    #: Largest uniform slow-down [×] the bridge applies to a trajectory over the arm's velocity
    #: or acceleration limits before it refuses it instead (chosen: the executor's transits run
    #: J5-J7 at up to 2× Barrett's 1.5 rad/s, and one powerdrill retreat reaches 18.8× the
    #: 10 rad/s² limit where the speed cap changes between samples, which needs 4.3×;
    #: tests/rrg_hw_bridge/test_hw_safety.py measures them).
    max_slowdown: float = 6.0
    #: Gain [1/s] of the momentum observer that estimates the arm's external joint torques
    #: (chosen: a 20 ms time constant; on the emulated WAM with 0.2 N m torque noise its
    #: free-motion residual stays below 0.5 N m, tests/rrg_hw_bridge/test_external_torque.py).
    observer_gain: float = 50.0
    #: Longest gap [s] between joint states the observer integrates over; after a longer one
    #: it starts again (chosen: 50 periods of a 500 Hz controller).
    observer_max_gap: float = 0.1
    #: Rate [Hz] of the upward state topics (joint states, wrenches, pads), as the simulator's
    #: default state_rate, whatever the drivers' rates are.
    state_rate: float = 50.0
    #: Finger velocity commands are repeated this often [s] while closing (Robotnik's
    #: BarrettHand driver stops a velocity move after 0.1 s without a command; the notes).
    finger_command_period: float = 0.05
    #: A hand position move is done when every commanded joint is this close [rad] ...
    hand_position_tolerance: float = 0.03
    #: ... or has stopped moving (slower than PHYSICS.stall_speed) for this long [s] (chosen).
    hand_still_time: float = 0.1
    #: A hand loop counts only joint states stamped after its command went out; one that
    #: arrives this long [s] after the command counts whatever its stamp, so a driver whose
    #: clock is behind the bridge's cannot hang the loop (chosen: 5× a 0.1 s hand round trip).
    hand_stamp_grace: float = 0.5


BRIDGE = BridgeParams()


# ------------------------------------------------------------------------ RDT (Net F/T)
# ATI Industrial Automation, "Net F/T Installation and Operation Manual", document 9620-05-NET FT,
# section "Raw Data Transfer (RDT)": the UDP protocol every Net F/T box serves.

#: UDP port of the RDT server on the box (manual, RDT section).
RDT_PORT = 49152
#: First field of every RDT request (manual, RDT request structure: "Header = 0x1234").
RDT_HEADER = 0x1234
#: RDT request commands (manual, RDT request structure, "command" field).
RDT_CMD_STOP = 0x0000
RDT_CMD_START_REALTIME = 0x0002
RDT_CMD_START_BUFFERED = 0x0003
RDT_CMD_RESET_THRESHOLD_LATCH = 0x0041
RDT_CMD_SET_SOFTWARE_BIAS = 0x0042
#: RDT request: uint16 header, uint16 command, uint32 sample count (0 = infinite), big-endian,
#: 8 bytes (manual, RDT request structure).
RDT_REQUEST_FORMAT = ">HHI"
#: RDT record: uint32 rdt_sequence, uint32 ft_sequence, uint32 status, int32 Fx Fy Fz Tx Ty Tz
#: in counts, big-endian, 36 bytes (manual, RDT record structure).
RDT_RECORD_FORMAT = ">III6i"
#: Counts per N and per N m of a box configured to report N and N m (the box serves the values
#: it uses as cfgcpf / cfgcpt in http://<box>/netftapi2.xml; a parameter of the bridge).
RDT_DEFAULT_COUNTS_PER_FORCE = 1_000_000.0
RDT_DEFAULT_COUNTS_PER_TORQUE = 1_000_000.0
#: Receive timeout [s] of the RDT client's socket, so stop() returns within it (chosen).
RDT_SOCKET_TIMEOUT = 0.05
#: Receive buffer [bytes] asked of the kernel per RDT socket (chosen: ~1 s of 1 kHz records at
#: the kernel's per-datagram overhead; the kernel caps it at net.core.rmem_max).
RDT_RECEIVE_BUFFER = 1 << 20
#: Window [s] over which RdtClient.health() reports the receive rate (chosen).
RDT_RATE_WINDOW = 1.0
