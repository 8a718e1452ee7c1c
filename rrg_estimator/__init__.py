"""The belief over the object's pose: the grid, the observation tables and models, the
update, the transition, and the estimator node."""
