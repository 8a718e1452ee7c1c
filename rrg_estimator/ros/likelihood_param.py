"""The ``unsensed_sensors`` parameter that the estimator and the planner share: the robot's
sensors without a reading (e.g. the palm and proximal pads of a BarrettHand without pad
feedback), left out of the likelihood (rrg_estimator.config.LikelihoodParams.unsensed)."""

from __future__ import annotations

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node

from rrg_estimator.config import LikelihoodParams, likelihood_without
from rrg_models.config import SENSOR_NAMES


def declare_unsensed_sensors(node: Node) -> LikelihoodParams:
    """Declare ``unsensed_sensors`` on ``node``; the likelihood parameters it gives (ValueError
    for a name that is not a sensor)."""
    node.declare_parameter(
        "unsensed_sensors",
        [""],
        ParameterDescriptor(
            description="Sensors the robot has no reading of, left out of the likelihood "
            f"({', '.join(SENSOR_NAMES)}; e.g. palm and prox1-3 when the hardware bridge "
            "derives the pads from the fingertips; the estimator's and the planner's must match)",
            read_only=True,
        ),
    )
    names = list(node.get_parameter("unsensed_sensors").value)
    params = likelihood_without(names)
    if params.unsensed:
        node.get_logger().info(
            f"sensors without a reading, left out of the likelihood: {[n for n in names if n]}"
        )
    return params
