"""rrg_estimator."""
