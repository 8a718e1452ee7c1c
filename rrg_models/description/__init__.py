"""The WAM and BarrettHand described for other tools: MuJoCo's MJCF (``mjcf_robot``) and a URDF
(``urdf_robot``, for robot_state_publisher and the lab's tools)."""
