"""rrg_estimator's ROS 2 layer: the estimator node and the belief ↔ message converters.

Importing this package does not import rclpy; modules that need it import it themselves.
"""
