"""The estimator's state on disk, so that a restarted estimator goes on from where it was.

The state is everything ``BeliefTracker`` carries between two events: the object, the belief
(its grid, and so its level, and its weights) and the pending retreat (the last WRT, its
estimate and whether it stopped early), plus the stamp of the last event the belief includes,
so that a restarted estimator can tell an event it has already applied from one it has not.

``save_state`` writes it atomically (``state_file.write_atomically``), so the file on disk is
always one whole state, the old or the new, whatever moment the process is killed at. A failed
write (a full disk, a read-only folder) raises OSError and leaves the previous state in place.
"""

from __future__ import annotations

import io
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rrg_common.state_file import check_format, read_state, write_atomically
from rrg_estimator.belief import Belief
from rrg_estimator.grid import Grid
from rrg_estimator.tracker import BeliefTracker, WrtTables
from rrg_models.objects import get_object

#: Bumped when the stored fields change; a state of another format is refused.
STATE_FORMAT = 2


@dataclass(frozen=True)
class EstimatorState:
    """One estimator's state between two events.

    last_event_ns: stamp [ns] of the last event (reset, observation or retreat) the belief
    includes; map_load_ns: stamp [ns] the belief's grid was made at (BeliefGrid's map load time).
    """

    object_name: str
    belief: Belief
    pending_wrt: str  # "" when no retreat is pending
    pending_estimate: np.ndarray  # (3,) e = (x [m], y [m], θ [rad]) of the pending WRT
    pending_contact: bool
    last_event_ns: int
    map_load_ns: int

    @classmethod
    def of(cls, tracker: BeliefTracker, last_event_ns: int, map_load_ns: int) -> EstimatorState:
        """The state of a tracker whose belief includes the event stamped ``last_event_ns``."""
        wrt, e, contact = tracker.pending or (None, np.zeros(3), False)
        return cls(
            tracker.obj.name,
            tracker.belief,
            wrt.name if wrt is not None else "",
            np.asarray(e, dtype=float),
            bool(contact),
            int(last_event_ns),
            int(map_load_ns),
        )

    def tracker(self, tables: WrtTables | None = None, **kwargs) -> BeliefTracker:
        """A BeliefTracker in this state (kwargs: BeliefTracker's levels, variable_resolution).
        Raises KeyError for an object or WRT that is not installed."""
        tracker = BeliefTracker(get_object(self.object_name), self.belief, tables, **kwargs)
        if self.pending_wrt:
            tracker.pending = (
                tracker.tables.wrt(self.pending_wrt),
                self.pending_estimate.copy(),
                self.pending_contact,
            )
        return tracker


def save_state(path: Path | str, state: EstimatorState) -> None:
    """Write ``state`` to ``path`` atomically (a whole file or none); OSError if it cannot."""
    path = Path(path)
    grid = state.belief.grid
    buffer = io.BytesIO()
    np.savez(
        buffer,
        format=np.int64(STATE_FORMAT),
        object_name=np.str_(state.object_name),
        grid_center=np.asarray(grid.center, dtype=float),
        grid_spacing=np.asarray(grid.spacing, dtype=float),
        grid_shape=np.asarray(grid.shape, dtype=np.int64),
        weights=state.belief.weights,
        posture_frame=np.str_(state.belief.frame),
        pending_wrt=np.str_(state.pending_wrt),
        pending_estimate=np.asarray(state.pending_estimate, dtype=float),
        pending_contact=np.bool_(state.pending_contact),
        last_event_ns=np.int64(state.last_event_ns),
        map_load_ns=np.int64(state.map_load_ns),
    )
    write_atomically(path, buffer.getvalue())


def load_state(path: Path | str) -> EstimatorState:
    """The state stored at ``path``. FileNotFoundError when there is none; StateError when the
    file is not a whole state of this format."""
    errors = (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile)
    return read_state(path, _parse_state, "estimator state", errors)


def _parse_state(path: Path) -> EstimatorState:
    with np.load(path, allow_pickle=False) as z:
        check_format(path, "state", int(z["format"]), STATE_FORMAT, "estimator")
        grid = Grid(
            tuple(float(v) for v in z["grid_center"]),
            tuple(float(v) for v in z["grid_spacing"]),
            tuple(int(v) for v in z["grid_shape"]),
        )
        return EstimatorState(
            str(z["object_name"]),
            Belief(grid, z["weights"], str(z["posture_frame"])),
            str(z["pending_wrt"]),
            np.array(z["pending_estimate"], dtype=float),
            bool(z["pending_contact"]),
            int(z["last_event_ns"]),
            int(z["map_load_ns"]),
        )
