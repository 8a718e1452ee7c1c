"""rrg_planner."""
