"""An object's rotational symmetry about the vertical through its origin, found from its mesh.

The paper's goal regions ignore θ for the can, the cup, the bowl and the tape roll, and take it
modulo π for a box: turned about its vertical axis, such an object is the same object, and so
is every grasp of it. ``rotational_symmetry`` turns points sampled on the surface about the
vertical through the origin (``stand_on_table`` puts it at the footprint's centre, which a
symmetric footprint has on its axis) and measures how far they land from the surface: a turn
the mesh maps onto itself puts them back on it. The distance is measured to a denser sample
of the surface (scipy's k-d tree), less the same distance for the unturned points, so the
sampling's own spacing cancels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial import cKDTree

#: The largest deviation [m] of a turned surface from the surface that still counts as the
#: same object (chosen: a fifth of the 1 cm goal region onboarding proposes; a cylinder
#: tessellated with 32 sides deviates 0.2 mm at 4 cm radius, a mug's handle by its whole
#: length).
SYMMETRY_TOLERANCE_M = 0.002
#: Symmetries that fit within this [m] of the best fitting one count as fitting as well (chosen:
#: the reference sample's spacing).
SYMMETRY_MARGIN_M = 0.0007
#: n-fold symmetries tried, and turns [rad] at which a continuous one is checked (chosen: no
#: two of them multiples of each other, nor of any 2π/n tried).
MAX_FOLDS = 12
CONTINUOUS_TURNS = (0.37, 1.13, 2.71)
#: Surface points turned, and the reference sample's spacing [m] and size bounds (chosen: a
#: second on a 50k-triangle mesh; the spacing is well below the tolerance).
TURNED_POINTS = 3000
REFERENCE_SPACING_M = 0.0007
REFERENCE_POINTS = (20_000, 400_000)


@dataclass(frozen=True)
class Symmetry:
    """A mesh's rotational symmetry about the vertical through its origin."""

    #: n: the mesh maps onto itself turned by 2π/n (1: no symmetry); 0: by every turn
    folds: int
    #: the largest deviation [m] of the surface turned by any of the symmetry's turns (for
    #: none: by the half turn)
    deviation_m: float

    @property
    def continuous(self) -> bool:
        return self.folds == 0

    @property
    def theta_period_rad(self) -> float:
        """The goal region's θ period [rad] (inf for a continuous symmetry, 2π for none)."""
        return float("inf") if self.continuous else 2 * np.pi / self.folds

    def describe(self) -> str:
        """One line for the onboarding log."""
        if self.continuous:
            return (
                "symmetric about its vertical axis at every turn (within "
                f"{self.deviation_m * 1000:.1f} mm): its goal region ignores θ"
            )
        if self.folds > 1:
            return (
                f"{self.folds}-fold symmetric about its vertical axis (within "
                f"{self.deviation_m * 1000:.1f} mm): its goal region takes θ modulo "
                f"{np.degrees(self.theta_period_rad):.0f}°"
            )
        return (
            "not symmetric about its vertical axis (turned half round it is "
            f"{self.deviation_m * 1000:.0f} mm off itself)"
        )


def rotational_symmetry(mesh: trimesh.Trimesh, seed: int = 0) -> Symmetry:
    """The symmetry of ``mesh`` (standing on the table, origin on the footprint's centre)
    about the vertical through its origin (see the module doc)."""
    rng = np.random.default_rng(seed)
    reference_count = int(
        np.clip(mesh.area / REFERENCE_SPACING_M**2, *REFERENCE_POINTS)
    )  # area [m²] over the spacing squared
    reference, _ = trimesh.sample.sample_surface(mesh, reference_count, seed=rng)
    points, _ = trimesh.sample.sample_surface(mesh, TURNED_POINTS, seed=rng)
    tree = cKDTree(reference)
    baseline = tree.query(points)[0].max()

    deviations: dict[float, float] = {}  # by turn [rad]: the same turn recurs across folds

    def deviation(turn: float) -> float:
        key = round(turn, 9)
        if key not in deviations:
            c, s = np.cos(turn), np.sin(turn)
            turned = points @ np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
            deviations[key] = max(0.0, float(tree.query(turned)[0].max() - baseline))
        return deviations[key]

    # each candidate's deviation at its turns (every multiple, so that 7-fold is not 6-fold)
    candidates = {0: max(deviation(t) for t in CONTINUOUS_TURNS)}
    for folds in range(MAX_FOLDS, 1, -1):
        turns = 2 * np.pi * np.arange(1, folds // 2 + 1) / folds
        candidates[folds] = max(deviation(t) for t in turns)
    fitting = {n: d for n, d in candidates.items() if d <= SYMMETRY_TOLERANCE_M}
    if not fitting:
        return Symmetry(1, deviation(np.pi))
    # the most turns among those that fit about as well as the best (an octagon fits 12-fold
    # within 2 mm, and 8-fold exactly)
    best = min(fitting.values())
    folds = next(n for n, d in fitting.items() if d <= best + SYMMETRY_MARGIN_M)
    return Symmetry(folds, fitting[folds])
