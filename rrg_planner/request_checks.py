"""Validation of what a caller asks of the planner: one place for the agent, the planner node's
services and actions, and the experiment runner.

Each check raises InvalidRequest, whose ``code`` is the name of the error code that the
interfaces (rrg_msgs/SelectAction, rrg_msgs/RobustGrasp) give that mistake.
"""

from __future__ import annotations

import numpy as np

from rrg_estimator.config import LEVELS
from rrg_models.objects import object_names, unknown_object_message

from .config import SEARCH

STRATEGIES = ("open-loop", "rrg-goal", "rrg-info")
HORIZONS = (1, 2, 3)


class InvalidRequest(ValueError):
    """A refused request: ``code`` names its interface error code (e.g. ``"INVALID_HORIZON"``)."""

    def __init__(self, code: str, message: str):
        super().__init__(message)
        self.code = code


def check_choice(strategy: str, horizon: int, delta: float) -> None:
    """A strategy from STRATEGIES, H in 1–3 and δ in (0, 1)."""
    if strategy not in STRATEGIES:
        raise InvalidRequest(
            "UNKNOWN_STRATEGY", f"unknown strategy {strategy!r}; valid: {list(STRATEGIES)}"
        )
    check_search(horizon, delta)


def check_search(horizon: int, delta: float) -> None:
    """H in 1–3 and δ in (0, 1) (NaN is refused)."""
    if horizon not in HORIZONS:
        raise InvalidRequest("INVALID_HORIZON", f"horizon must be 1, 2 or 3, got {horizon}")
    if not 0.0 < delta < 1.0:  # also false for NaN
        raise InvalidRequest("INVALID_DELTA", f"delta must be in (0, 1), got {delta}")


def check_object(object_name: str) -> None:
    """An installed object (UNKNOWN_OBJECT lists what is installed)."""
    if object_name not in object_names():
        raise InvalidRequest("UNKNOWN_OBJECT", unknown_object_message(object_name))


def check_level(level: str, loaded: tuple[str, ...] = tuple(LEVELS)) -> None:
    """A known uncertainty level whose tables are loaded."""
    if level not in LEVELS:
        raise InvalidRequest("UNKNOWN_LEVEL", f"unknown level {level!r}; valid: {sorted(LEVELS)}")
    if level not in loaded:
        raise InvalidRequest(
            "UNKNOWN_LEVEL", f"level {level!r} is not loaded; loaded: {list(loaded)}"
        )


def grasp_prior(level: str, sigma_override, mean) -> tuple[np.ndarray, np.ndarray]:
    """The initial belief's (mean, σ) of a robust grasp: σ per axis from the override where it is
    > 0, else the level's; the mean as given. Refuses negative or non-finite values."""
    override = np.asarray(sigma_override, dtype=float).reshape(3)
    if not np.all(np.isfinite(override)) or np.any(override < 0.0):
        raise InvalidRequest(
            "INVALID_SIGMA", f"sigma overrides must be finite and >= 0, got {override.tolist()}"
        )
    mean = np.asarray(mean, dtype=float).reshape(3)
    if not np.all(np.isfinite(mean)):
        raise InvalidRequest("INVALID_SIGMA", f"initial mean must be finite, got {mean.tolist()}")
    return mean, np.where(override > 0.0, override, LEVELS[level].sigma)


def max_actions(requested: int) -> int:
    """The action budget: 1 to SEARCH.max_actions, 0 meaning SEARCH.max_actions."""
    if not 0 <= requested <= SEARCH.max_actions:
        raise InvalidRequest(
            "INVALID_MAX_ACTIONS",
            f"max_actions must be 1-{SEARCH.max_actions} (0: {SEARCH.max_actions}), "
            f"got {requested}",
        )
    return requested or SEARCH.max_actions
