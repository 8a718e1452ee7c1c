"""The emulated drivers' ROS side: the node's parameters and the driver interfaces it serves."""
