"""The planner: the forward search over beliefs, the planning model, the robust-grasp loop,
the planner node and its client."""
