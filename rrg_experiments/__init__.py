"""The experiment runner (``rrg-experiment``): the paper's simulation results in MuJoCo physics."""
