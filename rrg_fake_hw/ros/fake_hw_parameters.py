"""The emulated drivers node's parameters (rrg_common.ros.parameters): the emulated world, the
sensors' rates, noise and calibration, the Net F/T boxes' addresses, the arm's driver interface,
and the faults and benchmarks (rrg_fake_hw.fake_hw_core.FAULTS), which may change at run time."""

from __future__ import annotations

from rrg_common.ros.parameters import Param

from ..fake_hw_core import ARM_INTERFACES, FAULTS

#: The node's parameters (rrg_common.ros.parameters): fixed at start, and the faults
#: (FAULTS), which may change at run time.
PARAMETERS: tuple[Param, ...] = (
    Param(
        "object_name",
        "powerdrill",
        "Installed object at start (rrg-object list); reset_sim may change it",
        read_only=True,
    ),
    Param("seed", 0, "Seed of the sensor noise", read_only=True, low=0, high=2**31 - 1),
    Param(
        "sensor_noise",
        1.0,
        "Scale of every sensor's noise sigma (1: config values, 0: noiseless)",
        read_only=True,
        low=0.0,
        high=10.0,
    ),
    Param(
        "joint_state_rate",
        500.0,
        "Rate [Hz] of /joint_states (wam_node: 500)",
        read_only=True,
        low=1.0,
        high=1000.0,
    ),
    Param(
        "pad_rate",
        50.0,
        "Rate [Hz] of the pads (BarrettHand feedback: 50)",
        read_only=True,
        low=1.0,
        high=500.0,
    ),
    Param(
        "rdt_rate",
        1000.0,
        "Rate [Hz] of each Net F/T box's RDT stream",
        read_only=True,
        low=1.0,
        high=7000.0,
    ),
    Param(
        "counts_per_force",
        1e6,
        "Net F/T calibration [counts/N]",
        read_only=True,
        low=1.0,
        high=1e9,
    ),
    Param(
        "counts_per_torque",
        1e6,
        "Net F/T calibration [counts/(N m)]",
        read_only=True,
        low=1.0,
        high=1e9,
    ),
    Param(
        "rdt_hosts",
        ["127.0.0.2", "127.0.0.3", "127.0.0.4"],
        "Addresses of the Net F/T boxes, fingers 1-3",
        read_only=True,
    ),
    Param(
        "box_calibration_factors",
        [1.0, 1.0, 1.0],
        "Per box, a factor on counts_per_force and counts_per_torque: "
        "boxes calibrated differently, as three real ones are",
        read_only=True,
    ),
    Param(
        "netft_http_port",
        0,
        "TCP port each box serves its /netftapi2.xml on (0: none; a real box: 80)",
        read_only=True,
        low=0,
        high=65535,
    ),
    Param(
        "rdt_port",
        49152,
        "UDP port of every Net F/T box (RDT: 49152)",
        read_only=True,
        low=1,
        high=65535,
    ),
    Param(
        "unmeasured_interfaces",
        [""],
        "Interfaces the trajectory controller's joint states publish as NaN, "
        "as joint_state_broadcaster does for a joint without them: arm_effort, "
        "hand_velocity",
        read_only=True,
    ),
    Param(
        "tip_zero_offset",
        [0.0] * 6,
        "Every Net F/T box's unloaded reading [N, N m] (Fx Fy Fz Tx Ty Tz) "
        "until bridge/bias removes it",
        read_only=True,
    ),
    Param(
        "controller_name",
        "arm_controller",
        "Name of the emulated trajectory controller",
        read_only=True,
    ),
    Param(
        "arm_interface",
        "both",
        "The arm's driver interface: the trajectory controller, Barrett's "
        f"wam_node, or both (one of {', '.join(ARM_INTERFACES)})",
        read_only=True,
    ),
    *(Param(name, f.default, f.description, low=f.lo, high=f.hi) for name, f in FAULTS.items()),
)
