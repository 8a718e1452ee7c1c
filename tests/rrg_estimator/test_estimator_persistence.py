"""The estimator's state on disk (rrg_estimator.persistence): a restored tracker goes on exactly
as the one that was stopped, a write is whole or absent, and a bad file is refused clearly."""

from __future__ import annotations

import os

import numpy as np
import pytest

from rrg_common.state_file import StateError
from rrg_estimator.config import LOW, MID
from rrg_estimator.persistence import STATE_FORMAT, EstimatorState, load_state, save_state
from rrg_estimator.tracker import BeliefTracker
from rrg_sim.geometric_sim import GeometricSimulator

MEAN = np.array([0.62, 0.0, 0.0])


@pytest.fixture(scope="module")
def drill_after_a_goal_grasp() -> BeliefTracker:
    """A drill tracker whose goal grasp arrived and whose retreat is still pending."""
    tracker = BeliefTracker.gaussian(
        "powerdrill", MEAN, LOW.sigma, level=LOW, variable_resolution=False
    )
    goal = tracker.obj.goal_wrt
    tracker.update(goal.name, MEAN, GeometricSimulator(tracker.obj, goal).simulate(MEAN, MEAN))
    assert tracker.pending is not None
    return tracker


def test_a_restored_tracker_goes_on_bit_for_bit(drill_after_a_goal_grasp, tmp_path):
    """Save with a retreat pending, restore, then retreat and update both: the two beliefs stay
    identical to the last bit, and the pending goal grasp's settling is not lost."""
    original = drill_after_a_goal_grasp
    path = tmp_path / "estimator.npz"
    save_state(path, EstimatorState.of(original, last_event_ns=1234, map_load_ns=1000))
    state = load_state(path)
    assert (state.object_name, state.pending_wrt) == ("powerdrill", original.obj.goal_wrt.name)
    assert (state.last_event_ns, state.map_load_ns) == (1234, 1000)
    restored = state.tracker(variable_resolution=False)
    assert restored.belief.grid == original.belief.grid
    assert np.array_equal(restored.belief.weights, original.belief.weights)
    before_retreat = original.belief
    a, b = original.retreated(), restored.retreated()
    assert np.array_equal(a.weights, b.weights)
    assert np.abs(a.weights - before_retreat.weights).sum() > 1e-3  # the settling was applied
    info = original.obj.info_wrts[0]
    obs = GeometricSimulator(original.obj, info).simulate(MEAN, MEAN + [0.004, -0.003, 0.02])
    assert np.array_equal(
        original.update(info.name, MEAN, obs).weights, restored.update(info.name, MEAN, obs).weights
    )


def test_a_state_without_a_pending_retreat_restores_none(tmp_path):
    tracker = BeliefTracker.gaussian("box", MEAN, MID.sigma, level=MID)
    save_state(tmp_path / "s.npz", EstimatorState.of(tracker, 5, 5))
    restored = load_state(tmp_path / "s.npz").tracker()
    assert restored.pending is None and restored.belief.grid == tracker.belief.grid


def test_a_failed_write_keeps_the_previous_state(drill_after_a_goal_grasp, tmp_path):
    """Writing into a folder that cannot take the file raises OSError and leaves the previous
    state whole (nothing half-written, no temporary file left)."""
    path = tmp_path / "estimator.npz"
    save_state(path, EstimatorState.of(drill_after_a_goal_grasp, 1, 1))
    before = path.read_bytes()
    missing = tmp_path / "gone" / "estimator.npz"
    with pytest.raises(OSError):
        save_state(missing, EstimatorState.of(drill_after_a_goal_grasp, 2, 2))
    if os.geteuid() != 0:  # root writes into read-only folders
        tmp_path.chmod(0o500)
        try:
            with pytest.raises(OSError):
                save_state(path, EstimatorState.of(drill_after_a_goal_grasp, 3, 3))
        finally:
            tmp_path.chmod(0o700)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["estimator.npz"]


def test_torn_foreign_and_missing_files_are_refused_clearly(drill_after_a_goal_grasp, tmp_path):
    path = tmp_path / "estimator.npz"
    save_state(path, EstimatorState.of(drill_after_a_goal_grasp, 1, 1))
    whole = path.read_bytes()
    path.write_bytes(whole[: len(whole) // 2])
    with pytest.raises(StateError, match="not a whole estimator state"):
        load_state(path)
    path.write_bytes(b"not a state")
    with pytest.raises(StateError, match="not a whole estimator state"):
        load_state(path)
    (tmp_path / "whole.npz").write_bytes(whole)
    with np.load(tmp_path / "whole.npz") as z:
        fields = {k: z[k] for k in z.files}
    fields["format"] = np.int64(STATE_FORMAT + 1)
    np.savez(path, **fields)
    with pytest.raises(StateError, match=f"state format {STATE_FORMAT + 1}"):
        load_state(path)
    with pytest.raises(FileNotFoundError):
        load_state(tmp_path / "none.npz")


def test_a_grasp_state_reads_back_whole_or_is_refused(tmp_path):
    """The planner's restart state goes through the same loader: the same state back, and a
    torn file, a foreign file or another format refused with StateError."""
    import json

    from rrg_planner.closed_loop import Step
    from rrg_planner.grasp_state import GraspState, load_grasp_state, save_grasp_state

    step = Step("info1", "info", np.array([0.6, 0.01, 0.2]), True, ["tip1"], 0.3, 0.05)
    state = GraspState({"object_name": "box"}, [step], [(2, [0.6, 0.0, 0.1])], 0.05, 0.3, lost=2)
    path = tmp_path / "grasp.json"
    save_grasp_state(path, state)
    back = load_grasp_state(path)
    assert back.request == state.request and back.blocked == state.blocked and back.lost == 2
    assert back.steps[0].wrt == "info1" and np.array_equal(back.steps[0].estimate, step.estimate)
    whole = path.read_text()
    path.write_text(whole[: len(whole) // 2])
    with pytest.raises(StateError, match="not a whole grasp state"):
        load_grasp_state(path)
    path.write_text('["a list"]')
    with pytest.raises(StateError, match="not a whole grasp state"):
        load_grasp_state(path)
    path.write_text(json.dumps({**json.loads(whole), "format": 99}))
    with pytest.raises(StateError, match="grasp state format 99, this planner reads"):
        load_grasp_state(path)
    with pytest.raises(FileNotFoundError):
        load_grasp_state(tmp_path / "none.json")
