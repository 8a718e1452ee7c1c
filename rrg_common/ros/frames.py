"""The robot's description and frames on ROS, as robot_state_publisher gives them: the URDF on
``/robot_description`` (latched std_msgs/String), its fixed joints on ``/tf_static`` (latched)
and its moving joints on ``/tf`` (tf2_msgs/TFMessage) from each joint state the arm/hand
interface publishes; and the object's frames (``object_estimate``, ``object_true``) in
``world``. The simulator node and the hardware bridge publish the robot's frames from the joint
states they publish, the estimator the estimate, the simulator the truth (rrg_models.robot_frames
computes them without ROS)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Quaternion, TransformStamped
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage

from rrg_common.ros.msg_conversions import vector_to_msg
from rrg_models.robot_frames import RobotFrames, Transform

TF_TOPIC = "/tf"
TF_STATIC_TOPIC = "/tf_static"
ROBOT_DESCRIPTION_TOPIC = "/robot_description"
#: The object's frames in WORLD_FRAME: the belief's most likely pose (the estimator), and the
#: true pose (the simulator only).
OBJECT_ESTIMATE_FRAME = "object_estimate"
OBJECT_TRUE_FRAME = "object_true"
#: tf2's QoS: /tf as tf2_ros's TransformBroadcaster (reliable, volatile, depth 100), /tf_static
#: and /robot_description latched as StaticTransformBroadcaster and robot_state_publisher.
TF_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
LATCHED_STATIC = QoSProfile(
    depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE
)


def transform_to_msg(
    parent: str, child: str, T: np.ndarray, quat_xyzw: np.ndarray, stamp: Time
) -> TransformStamped:
    """The pose of frame ``child`` in ``parent`` (translation from T (4,4), rotation as the
    quaternion (x, y, z, w) of T's) as a TransformStamped."""
    msg = TransformStamped()
    msg.header.stamp, msg.header.frame_id, msg.child_frame_id = stamp, parent, child
    msg.transform.translation = vector_to_msg(T[:3, 3])
    x, y, z, w = (float(v) for v in quat_xyzw)
    msg.transform.rotation = Quaternion(x=x, y=y, z=z, w=w)
    return msg


def tf_message(transforms: Sequence[Transform], stamp: Time) -> TFMessage:
    """The transforms (parent, child, (4,4)) in one TFMessage stamped ``stamp``."""
    if not transforms:
        return TFMessage()
    quats = Rotation.from_matrix(np.array([T[:3, :3] for _, _, T in transforms])).as_quat()
    return TFMessage(
        transforms=[transform_to_msg(p, c, T, q, stamp) for (p, c, T), q in zip(transforms, quats)]
    )


class TfPublisher:
    """Publishes transforms on ``/tf``."""

    def __init__(self, node: Node):
        self.pub = node.create_publisher(TFMessage, TF_TOPIC, TF_QOS)

    def publish(self, transforms: Sequence[Transform], stamp: Time) -> None:
        self.pub.publish(tf_message(transforms, stamp))


class RobotFramesPublisher:
    """The robot's description once (latched) and its frames from each joint state."""

    def __init__(self, node: Node, urdf: str):
        self.frames = RobotFrames(urdf)
        self.tf = TfPublisher(node)
        description = node.create_publisher(String, ROBOT_DESCRIPTION_TOPIC, LATCHED_STATIC)
        description.publish(String(data=urdf))
        self.static = node.create_publisher(TFMessage, TF_STATIC_TOPIC, LATCHED_STATIC)
        self.static.publish(tf_message(self.frames.static(), node.get_clock().now().to_msg()))

    def publish(self, joint_state: JointState) -> None:
        """The moving joints' frames at ``joint_state`` (its stamp)."""
        moving = self.frames.moving(joint_state.name, joint_state.position)
        self.tf.publish(moving, joint_state.header.stamp)
