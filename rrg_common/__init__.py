"""What every RRG package shares: the nodes' ROS 2 plumbing (``ros``), the worker pool and the
restart-state files.

``ros`` holds run_node, the parameter tables, QoS, futures, diagnostics, liveliness, frames,
message conversions, and the arm/hand interface both the simulator and the bridge serve;
``parallel`` the worker pool; ``state_file`` the nodes' restart state on disk."""
