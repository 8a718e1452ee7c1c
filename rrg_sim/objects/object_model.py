"""An object of the catalogue: collision primitives, physical properties, goal region and WRTs."""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path

import numpy as np
import trimesh
from scipy.special import ndtr

from rrg_sim.config import SETTLING_KERNEL_BANDWIDTH
from rrg_sim.objects.composites import turn_about_z
from rrg_sim.objects.primitives import Primitive, union_bounds
from rrg_sim.poses import wrap_angle
from rrg_sim.wrt import WRT, ReorientOutcome, table_touch_wrt

from .wrt_generation import goal_probe_wrt, info_wrts, sweep_wrt

#: An object folder's planned table touch (rrg_sim.table_touch writes it).
TABLE_TOUCH_FILE = "table_touch.json"

#: An object folder's measured grasp-settling fit (rrg_sim.physics.settle writes it).
SETTLING_FILE = "settling.json"


def settling_file(profile: str = "nominal") -> str:
    """The file of the settling study measured in world ``profile`` (the nominal world's is
    SETTLING_FILE; another's, e.g. settling.realistic.json)."""
    return SETTLING_FILE if profile == "nominal" else f"settling.{profile}.json"


#: An object folder's measured reorientation outcomes (rrg_sim.physics.reorient_study).
REORIENTATION_FILE = "reorientation.json"
#: Half-width [rad] of the θ range of start offsets the settling study samples, at most
#: (chosen: the low level's 3σ of 9° and then some).
SETTLING_THETA_BOX = 0.25


@dataclass(frozen=True)
class AffineSettle:
    """Δ_after = A·Δ + b, with residual σ (x [m], y [m], θ [rad]); Δ = relative_planar(e, w)."""

    A: np.ndarray
    b: np.ndarray
    sigma: np.ndarray

    def apply(self, delta: np.ndarray) -> np.ndarray:
        """(…,3) the mean Δ after, θ wrapped."""
        out = np.asarray(delta, dtype=float) @ self.A.T + self.b
        out[..., 2] = wrap_angle(out[..., 2])
        return out

    @classmethod
    def from_json(cls, fit: dict) -> AffineSettle:
        return cls(np.array(fit["A"]), np.array(fit["b"]), np.array(fit["sigma"]))


@dataclass(frozen=True, eq=False)
class Settling:
    """How a firm goal grasp that arrived moves the object (rrg_sim.physics.settle): the maps of
    start offsets Δ inside ``box`` (3,) half-widths to Δ once the hand has closed (where the
    judge finds it: the goal model, rrg_planner.planning_model.goal_weights) and after the retreat
    (where the next action finds it: the belief's transition), with the measured samples
    (``start`` and, per map, the Δ after (M,3)). Outside the box the object is taken not to
    move (the study did not sample there).

    bandwidth: (3,) [m, m, rad] of the kernel that corrects an affine map near Δ with the
    samples (inf: that axis ignored); ObjectModel sets config.SETTLING_KERNEL_BANDWIDTH goal
    tolerances.
    """

    box: np.ndarray
    closed: AffineSettle
    retreated: AffineSettle
    source: str
    start: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    samples: dict[str, np.ndarray] = field(default_factory=dict)
    #: (M,) 1 where the sample's grasp made its fingers and required contacts and held through
    #: the lift and the hold (the judge's test but for the region); None: not measured.
    held: np.ndarray | None = None
    bandwidth: np.ndarray = field(default_factory=lambda: np.full(3, np.inf))

    def inside(self, delta: np.ndarray) -> np.ndarray:
        """(…) bool: Δ (…,3) lies in the studied box."""
        d = np.asarray(delta, dtype=float).copy()
        d[..., 2] = wrap_angle(d[..., 2])
        return np.all(np.abs(d) <= self.box, axis=-1)

    def outcome(self, delta: np.ndarray, stage: str = "closed") -> tuple[np.ndarray, np.ndarray]:
        """Δ after ``stage`` ("closed" or "retreated") ~ N(mean, diag σ²) for starts Δ (N,3):
        the stage's affine map, corrected by the Gaussian-kernel weighted mean and spread of
        its residuals over the samples (not along an axis of infinite bandwidth). Returns
        mean (N,3) (θ unwrapped next to Δ's) and σ (N,3); without samples, the affine map and
        its residual σ."""
        fit = self.closed if stage == "closed" else self.retreated
        delta = np.asarray(delta, dtype=float)
        mean = delta @ fit.A.T + fit.b
        after = self.samples.get(stage)
        if after is None or len(self.start) == 0:
            return mean, np.broadcast_to(fit.sigma, mean.shape).copy()
        residual = after - (self.start @ fit.A.T + fit.b)
        shift, second = np.empty_like(mean), np.empty_like(mean)
        for lo in range(0, len(delta), 2048):  # bounded memory: 2048 × M kernel weights
            k = self._kernel(delta, lo, lo + 2048)
            shift[lo : lo + 2048], second[lo : lo + 2048] = k @ residual, k @ (residual * residual)
        sigma = np.sqrt(np.maximum(second - shift * shift, 1e-12))
        ignored = ~np.isfinite(self.bandwidth)  # an axis nothing depends on keeps its affine map
        shift[:, ignored], sigma[:, ignored] = 0.0, fit.sigma[ignored]
        return mean + shift, sigma

    def _kernel(self, delta: np.ndarray, lo: int, hi: int) -> np.ndarray:
        """(n, M) normalized Gaussian kernel weights of the samples for starts delta[lo:hi]
        (axes of infinite bandwidth ignored)."""
        scaled = self.start / self.bandwidth
        q = delta[lo:hi] / self.bandwidth
        sq = np.sum(q * q, axis=1)[:, None] - 2 * q @ scaled.T + np.sum(scaled * scaled, axis=1)
        k = np.exp(-0.5 * (sq - sq.min(axis=1, keepdims=True)))
        return k / k.sum(axis=1, keepdims=True)

    def hold_probability(self, delta: np.ndarray) -> np.ndarray:
        """(N,) P(the grasp makes its contacts and holds | start Δ (N,3)): the kernel-weighted
        share of the samples that held; 1 where the study did not judge its grasps. (No prior
        pulls it from the samples: a Jeffreys prior over the kernel's ~10 effective samples
        capped the teacup's centre at 0.955 where all 38 study grasps in its region held, and
        its runs could never declare success at δ = 0.1.)"""
        delta = np.asarray(delta, dtype=float)
        if self.held is None or len(self.start) == 0:
            return np.ones(len(delta))
        out = np.empty(len(delta))
        for lo in range(0, len(delta), 2048):  # bounded memory: 2048 × M kernel weights
            out[lo : lo + 2048] = self._kernel(delta, lo, lo + 2048) @ self.held
        return out


def load_settling(path: Path, bandwidth: np.ndarray | None = None) -> Settling | None:
    """The Settling measured in the fit file ``path``, or None if there is none
    (``bandwidth``: see Settling; default inf, the affine maps alone)."""
    if not path.exists():
        return None
    f = json.loads(path.read_text())
    raw = dict(f.get("samples", {}))
    held = np.asarray(raw.pop("held", []), dtype=float)
    samples = {k: np.asarray(v, dtype=float).reshape(-1, 3) for k, v in raw.items()}
    start = samples.pop("start", np.zeros((0, 3)))
    return Settling(
        np.array(f["box"]),
        AffineSettle.from_json(f["closed"]),
        AffineSettle.from_json(f["retreated"]),
        start=start,
        samples=samples,
        held=held if len(held) == len(start) else None,
        bandwidth=np.full(3, np.inf) if bandwidth is None else bandwidth,
        source=f"{f.get('source', path.name)}: {f['arrived']} of {f['grasps']} grasps arrived",
    )


def measured_reorientation(wrts: tuple[WRT, ...], path: Path | None) -> tuple[WRT, ...]:
    """The reorientation WRTs with the outcomes measured in ``path`` for them
    (WRT.reorient_outcome); unmeasured ones unchanged."""
    fits = json.loads(path.read_text()) if path is not None and path.exists() else {}
    return tuple(
        replace(
            w,
            reorient_outcome=ReorientOutcome(
                *(np.array(fits[w.name][k]) for k in ("box", "shift", "sigma"))
            ),
        )
        if w.name in fits
        else w
        for w in wrts
    )


@dataclass(frozen=True)
class RequiredContact:
    """A contact the goal grasp must make (the paper's "required contact locations"): at
    least ``min_fingers`` of ``fingers`` (1-3) touch the object's ``parts`` (indices into
    ObjectModel.parts) once the hand has closed."""

    name: str
    parts: tuple[int, ...]
    fingers: tuple[int, ...] = (1, 2, 3)
    min_fingers: int = 1

    def __post_init__(self) -> None:
        if not set(self.fingers) <= {1, 2, 3} or not 1 <= self.min_fingers <= len(self.fingers):
            raise ValueError(f"{self.name}: fingers must be among 1-3, at least min_fingers")
        if not self.parts:
            raise ValueError(f"{self.name}: no parts")

    def met(self, touching: dict[int, set[int]]) -> bool:
        """Whether the contact is made, given the parts each finger touches (finger → parts)."""
        return (
            sum(bool(touching.get(f, set()) & set(self.parts)) for f in self.fingers)
            >= self.min_fingers
        )


@dataclass(frozen=True)
class GoalRegion:
    """Where the object must end up relative to the hand for the goal grasp to count.

    tol: (|dx| [m], |dy| [m], |dθ| [rad]) bounds on Δ = relative_planar(e, w), the true pose
    w in the frame of the estimate e at which the goal WRT ran (θ bound inf: θ ignored).
    min_fingers: how many of the 3 fingers must end in contact with the object.
    required_contacts: the contacts the grasp must make (judged in physics; the goal model
    predicts them from the settling study).
    theta_period: the object's rotational symmetry [rad] about its vertical axis through the
    origin (π for a box: turned half round it is the same object), dθ is taken modulo it.
    centre: (Δx [m], Δy [m], Δθ [rad]) the Δ the bounds are about: 0 for a grasp designed to
    leave the object where the estimate put it; an onboarded grasp's is where it leaves the
    object from a perfect start (the settling study's intercept).
    """

    tol: tuple[float, float, float]
    min_fingers: int = 3
    required_contacts: tuple[RequiredContact, ...] = ()
    theta_period: float = 2 * np.pi
    centre: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if not 0 <= self.min_fingers <= 3:
            raise ValueError("min_fingers must be in 0..3")

    @property
    def ignores_theta(self) -> bool:
        return bool(np.isinf(self.tol[2]))

    def contains(self, delta) -> np.ndarray:
        """(…) bool: Δ (…,3) lies in the pose part of the region."""
        delta = np.asarray(delta, dtype=float) - self.centre
        ok = (np.abs(delta[..., 0]) <= self.tol[0]) & (np.abs(delta[..., 1]) <= self.tol[1])
        if self.ignores_theta:
            return ok
        scale = 2 * np.pi / self.theta_period
        return ok & (np.abs(wrap_angle(delta[..., 2] * scale)) / scale <= self.tol[2])

    def probability(self, mean, sigma) -> np.ndarray:
        """(…) P(Δ in the pose part of the region) for Δ ~ N(mean (…,3), diag(sigma (3,))²)
        (θ taken modulo the period about the wrapped mean)."""
        mean = np.asarray(mean, dtype=float) - self.centre
        sigma = np.maximum(np.asarray(sigma, dtype=float), 1e-9)
        tol = np.asarray(self.tol, dtype=float)
        m = mean.copy()
        scale = 2 * np.pi / self.theta_period
        m[..., 2] = wrap_angle(m[..., 2] * scale) / scale
        axes = 2 if self.ignores_theta else 3
        s = sigma[..., :axes]
        inside = ndtr((tol[:axes] - m[..., :axes]) / s) - ndtr((-tol[:axes] - m[..., :axes]) / s)
        return np.prod(inside, axis=-1)


@dataclass(frozen=True, eq=False)
class ObjectModel:
    """One object of the catalogue (object frame: origin at the centre of the part resting on
    the table, z up, resting on z = 0).

    parts: collision primitives (shared by the geometric and the MuJoCo simulators).
    mass [kg]; friction: sliding friction coefficient.
    dimensions: documented sizes [m]; ``size_x``, ``size_y``, ``size_z`` are the bounding-box
    extents, other keys name features (e.g. a handle's opening). source: where they come from.
    goal / goal_wrt: the goal region and the hand-designed goal WRT.
    reorient_wrts: reorientation WRTs (empty when the goal grasp stays feasible at any θ).
    designed_info_wrts: hand-designed information-gathering WRTs, added to the generated ones
    (the paper's WRTs were mostly demonstrated by hand).
    symmetric: the goal region ignores θ.
    placement_yaw: the parts are the object built in its canonical frame (where the
    documented sizes are the bounding box) turned by this yaw [rad] about z, so that its goal
    grasp is reachable at the nominal pose.
    folder: the object's folder (rrg_sim.objects.object_file), where its measured studies
    live (SETTLING_FILE, REORIENTATION_FILE); None: an object built in code, never measured.
    """

    name: str
    parts: tuple[Primitive, ...]
    mass: float
    friction: float
    dimensions: dict[str, float]
    source: str
    goal: GoalRegion
    goal_wrt: WRT
    reorient_wrts: tuple[WRT, ...] = ()
    designed_info_wrts: tuple[WRT, ...] = ()
    symmetric: bool = False
    placement_yaw: float = 0.0
    #: whether the belief applies the measured settling of the goal grasp (see ``settling``)
    track_settling: bool = True
    description: str = field(default="", repr=False)
    folder: Path | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if self.symmetric != self.goal.ignores_theta:
            raise ValueError(f"{self.name}: symmetric must match a goal region that ignores θ")
        for rc in self.goal.required_contacts:
            if max(rc.parts) >= len(self.parts) or min(rc.parts) < 0:
                raise ValueError(f"{self.name}: required contact {rc.name!r} names a missing part")

    def bounds(self) -> np.ndarray:
        """(2,3) axis-aligned bounds [m] of the parts in the object frame."""
        return union_bounds(self.parts)

    def canonical_bounds(self) -> np.ndarray:
        """(2,3) axis-aligned bounds [m] of the parts turned back by -placement_yaw."""
        return union_bounds(turn_about_z(self.parts, -self.placement_yaw))

    @cached_property
    def _mesh(self) -> trimesh.Trimesh:
        return trimesh.util.concatenate([part.mesh() for part in self.parts])

    def mesh(self) -> trimesh.Trimesh:
        """Visualization mesh: the concatenated primitive meshes (cached; do not modify)."""
        return self._mesh

    @cached_property
    def info_wrts(self) -> tuple[WRT, ...]:
        """Information-gathering WRTs: generated from the primitives (pinches, then the sweep),
        then the hand-designed ones, then for a side goal grasp its probe (goal_probe_wrt)."""
        probe = goal_probe_wrt(self.goal_wrt)
        return (
            info_wrts(self.parts)
            + (sweep_wrt(self.parts),)
            + self.designed_info_wrts
            + (() if probe is None else (probe,))
        )

    @cached_property
    def _wrts(self) -> tuple[WRT, ...]:
        wrts = (
            (self.goal_wrt,)
            + self.info_wrts
            + measured_reorientation(self.reorient_wrts, self._artefact(REORIENTATION_FILE))
        )
        names = [w.name for w in wrts]
        if len(set(names)) != len(names):
            raise ValueError(f"{self.name}: WRT names are not unique: {names}")
        return wrts

    @cached_property
    def grasp_settling(self) -> Settling | None:
        """How the firm goal grasp moves the object (measured), or None if not measured."""
        path = self._artefact(SETTLING_FILE)
        return None if path is None else self._load_settling(path)

    def _load_settling(self, path: Path) -> Settling | None:
        """A settling study of this object's goal grasp (load_settling, with its kernel
        bandwidth of SETTLING_KERNEL_BANDWIDTH goal tolerances)."""
        return load_settling(
            path, bandwidth=SETTLING_KERNEL_BANDWIDTH * np.asarray(self.goal.tol, dtype=float)
        )

    @cached_property
    def _settling_by_profile(self) -> dict[str, Settling]:
        """The settling studies of other world profiles, loaded on first use."""
        return {}

    def settling_in(self, profile: str) -> Settling | None:
        """How the firm goal grasp moves the object and holds it in world ``profile`` (a
        profile spec's base name, config.world_profile): its own study where one was measured
        (settling_file), else the nominal world's."""
        base = profile.partition(":")[0]
        path = self._artefact(settling_file(base))
        if base == "nominal" or path is None or not path.exists():
            return self.grasp_settling
        if base not in self._settling_by_profile:
            self._settling_by_profile[base] = self._load_settling(path)
        return self._settling_by_profile[base]

    def _artefact(self, filename: str) -> Path | None:
        """Where the object's measured ``filename`` lives (None: the object has no folder)."""
        return None if self.folder is None else self.folder / filename

    @property
    def settling(self) -> Settling | None:
        """The measured settling if the belief tracks it after a retreat (``track_settling``),
        else None."""
        return self.grasp_settling if self.track_settling else None

    def wrts(self) -> tuple[WRT, ...]:
        """The goal WRT, the generated info WRTs, the sweep and the reorientation WRTs (cached)."""
        return self._wrts

    @cached_property
    def table_touch(self) -> WRT | None:
        """The planned table touch (rrg_sim.table_touch), a WRT of kind "touch" that is no
        action of the planner's; None where none was planned."""
        path = self._artefact(TABLE_TOUCH_FILE)
        if path is None or not path.exists():
            return None
        plan = json.loads(path.read_text())
        return table_touch_wrt(
            plan["poses"],
            plan["spread"],
            plan["preclose"],
            plan["finger"],
            plan["serves"],
            plan["clear"],
        )

    def wrt(self, name: str) -> WRT:
        """The WRT called ``name`` (an action's, or the table touch)."""
        wrts = self._wrts + (() if self.table_touch is None else (self.table_touch,))
        for w in wrts:
            if w.name == name:
                return w
        raise KeyError(f"{self.name} has no WRT {name!r}; valid: {[w.name for w in wrts]}")
