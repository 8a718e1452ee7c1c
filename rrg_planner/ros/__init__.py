"""RRG's ROS 2 layer: thin rclpy nodes over the ROS-free cores, plus bag recording and reading.

Importing this package does not import rclpy; modules that need it import it themselves.
"""
