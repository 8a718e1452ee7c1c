"""The goal model: where the object must end up relative to the hand for a goal grasp to count
(GoalRegion), what the fingers must touch (RequiredContact), how the closing moves the object
and whether the grasp holds through the lift (Settling, the measured settling and hold
study), P(G | Δ) of a goal grasp run relative to an estimate (goal_weights), and what the
robot's own sensors say against a grasp that just closed (goal_grasp_mismatches).

One module for the judge (rrg_sim.physics.judge: the region, the contacts and the hold, on the
simulator's truth), the planner (rrg_planner.planning_model: P(G | Δ) over a goal WRT's table;
P_b(G) is its expectation under the belief, rrg_estimator.update.goal_probability), the
belief's transition (Settling's retreated map) and the robot's verification of its goal grasp.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.special import ndtr

from rrg_models.observation import finger_contacts, fingers_in_contact
from rrg_models.poses import wrap_angle

#: P(G | Δ) below this counts as 0 (goal_weights; chosen: the Gaussian tails of a grid cell's
#: spread are never exactly 0, and keeping them makes the search evaluate the goal over 4-8× as
#: many table entries at high uncertainty, for nothing a δ of 0.1 can see).
GOAL_MIN_PROBABILITY = 1e-4


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
    judge finds it: goal_weights) and after the retreat
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


def holds_object(contact, sensors: np.ndarray, min_fingers: int) -> np.ndarray:
    """(…) whether a grasp holds the object: it arrived (no early contact, ``contact`` (…))
    and at least ``min_fingers`` fingers touch it (sensors (…,10)). Only then does a
    reorientation lift and turn the object (in execution, the geometric world and the belief
    alike)."""
    return ~np.asarray(contact, dtype=bool) & (fingers_in_contact(sensors) >= min_fingers)


def goal_grasp_mismatches(contact: bool, sensors: np.ndarray, goal: GoalRegion) -> list[str]:
    """What the robot's own sensors say is wrong with a goal grasp that just closed (empty:
    nothing they can see): it stopped early (``contact``: short of its end by more than the
    arrival tolerance, so it closed on whatever it met), fewer fingers sensed on the object
    than ``goal.min_fingers``, or fewer of a required contact's fingers sensed than it needs
    (the sensors cannot tell which part a finger touches, so this is necessary, not
    sufficient). Any of these makes the grasp a failure in the judge's test whenever the
    sensors are right; a missed pad can make a good grasp look bad, never the reverse."""
    out = []
    if contact:
        out.append("stopped early")
    touched = finger_contacts(sensors)
    if touched.sum() < goal.min_fingers:
        out.append(f"{int(touched.sum())} of {goal.min_fingers} fingers sensed")
    for rc in goal.required_contacts:
        on = sum(bool(touched[f - 1]) for f in rc.fingers)
        if on < rc.min_fingers:
            fingers = " or ".join(str(f) for f in rc.fingers)
            out.append(f"{rc.name}: no sensor of finger {fingers} fired")
    return out


def _grasp_made(goal: GoalRegion, contact: np.ndarray, sensors: np.ndarray) -> np.ndarray:
    """(N,) bool: the hand reached the grasp pose without an early contact (contact (N,)) and
    closed with at least the goal's fingers on the object (sensors (N,10))."""
    return holds_object(contact, sensors, goal.min_fingers)


def goal_holds(
    goal: GoalRegion, delta: np.ndarray, contact: np.ndarray, sensors: np.ndarray
) -> np.ndarray:
    """G for a goal grasp executed relative to an estimate, with the object really at offset
    delta (N,3) and nothing moving it: delta inside the goal region and the grasp made
    (no early contact, the required contacts)."""
    return goal.contains(delta) & _grasp_made(goal, contact, sensors)


def goal_weights(
    goal: GoalRegion,
    delta: np.ndarray,
    contact: np.ndarray,
    sensors: np.ndarray,
    cell: tuple[float, float, float] | np.ndarray | None = None,
    start_sigma: np.ndarray | None = None,
    settling: Settling | None = None,
) -> np.ndarray:
    """P(G | Δ) (N,) for a goal grasp executed relative to an estimate, the object really at
    offset delta (N,3): the grasp made (as in goal_holds), the object, moved by the
    closing as the settling study measured it (Settling.outcome: Δ_closed ~ N(μ(Δ),
    σ(Δ)²) inside the study's box), inside the goal region, and the grasp making its
    required contacts and holding through the lift (Settling.hold_probability, measured by
    the judge's own test). Outside the box, or for an object without a study, the object is
    taken not to move and to hold (goal_holds).

    cell: (3,) [m, m, rad] grid spacing when delta are grid points that each stand for their
    cell (a belief grid's weight is the mass of the cell around its point): the region is
    then met on average over a uniform offset within the cell, taken as a Gaussian of
    variance g²/12 per axis added to the closing's spread. Without it, Δ is exact. On the
    high-uncertainty grid (1 cm, 0.1 rad against a 1 cm, 0.14 rad region) point values
    claim a grasp holds for the whole cell where only its centre does.

    start_sigma: (3,) σ [m, m, rad] of an unknown offset of the grasp's start, added to the
    spread in the same way: the calibration error between the frame the belief is held in and
    the goal grasp's posture (rrg_sim.posture_calibration; world axes, taken as the
    estimate's, whose θ is near 0 at the nominal pose).

    settling: the object's settling study (ObjectModel.grasp_settling, measured in the nominal
    world; ObjectModel.settling_in gives another world's); None: the object is taken not to
    move and to hold."""
    delta = np.asarray(delta, dtype=float)
    made = _grasp_made(goal, contact, sensors)
    spread2 = np.zeros(3)
    if cell is not None:
        spread2 = spread2 + np.asarray(cell, dtype=float) ** 2 / 12.0
    if start_sigma is not None:
        spread2 = spread2 + np.asarray(start_sigma, dtype=float) ** 2
    if not spread2.any():
        p = (goal.contains(delta) & made).astype(np.float64)
    else:
        p = made * goal.probability(delta, np.sqrt(spread2))
    if settling is not None:
        near = np.flatnonzero(settling.inside(delta))
        mean, sigma = settling.outcome(delta[near], "closed")
        # a uniform offset u in the cell moves the closed Δ by A u: variance Σ_j A_kj² g_j²/12
        sigma = np.sqrt(sigma**2 + (settling.closed.A**2) @ spread2)
        p[near] = (
            made[near] * goal.probability(mean, sigma) * settling.hold_probability(delta[near])
        )
    p[p < GOAL_MIN_PROBABILITY] = 0.0
    return p
