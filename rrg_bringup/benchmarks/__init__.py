"""The benchmarks (``rrg-bench``): the search, the tables, the physics world, the ROS graph,
the service, the campaign and the hardware loop."""
