"""rrg_sim's ROS 2 layer: the simulated arm/hand interface node, the WRT executor node, and the
message converters for the world's types (poses, observations, joint states).

Importing this package does not import rclpy; modules that need it import it themselves.
"""
