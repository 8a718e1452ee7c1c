"""rrg_sim."""
