"""Where each WRT's posture sees the object: the WAM's calibration error as RRG models it.

A WAM's joint zero offsets (WorldProfile.joint_offset_sigma) are one fixed error per robot,
not a fresh one per reading. In one posture q the hand stands where forward kinematics of the
offset readings says, off by a planar map c(q) (x, y and a turn about z, seen from above), so
every reading made in that posture sees the object moved by the same amount: at the object's
position p, by M(p)·c. Two readings in one posture agree with each other, and a goal grasp in
the posture of the readings that localized the object lands where they said; between postures
the error differs, by 0-1.3 mm among top-down grasps and by 4-7 mm between top-down readings
and a side grasp at σ 10 mrad (MuJoCo's WAM, rrg_models.wam).

So a belief is held in a *frame*: the posture class of the readings that made it ("" for the
prior, which a camera gives in the world's frame). ``sigma(a, b)`` is the spread of the offset
between the object as frame a sees it and as frame b sees it, linear in the joint offsets
(Jacobians by central differences at each WRT's reading posture: where, on its path from home
at the nominal object pose, the hand's grasp centre passes nearest the object's centre; the
end of a grasp, the middle of a sweep). A WRT's class is the first earlier WRT's whose offset
from it stays within SAME_FRAME_SIGMA; otherwise it starts a class of its own.

A goal grasp's reading leaves a belief in its frame (``reading_frame``): it closes firmly and
drags the object, so it tells little of where the object is (its closures are not used), and
moving the belief to the goal's frame for it would spend the calibration error's blur for
nothing. Its P(goal) is valued from the belief's frame. Information in the goal grasp's own
posture comes from a probe that closes carefully (objects.wrt_generation.goal_probe_wrt).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rrg_models import wam
from rrg_models.config import WORLD
from rrg_models.objects import ObjectModel
from rrg_models.poses import compose_planar, planar_map, relative_planar, wrap_angle
from rrg_models.trajectory import InfeasiblePath
from rrg_sim.config import WorldProfile
from rrg_sim.executor.wrt_executor import wrt_path

#: Two postures whose offset's σ is within this (x [m], y [m], θ [rad]) share a frame (chosen:
#: a fifth of the tightest goal tolerance, 1 cm and 0.14 rad; the top-down grasps of the ten
#: objects differ by at most 1.3 mm and 0.002 rad at σ 10 mrad).
SAME_FRAME_SIGMA = np.array([0.002, 0.002, 0.007])

#: The hand's grasp centre along its approach axis (hand z) [m] (chosen: between the palm at
#: 0.08 m and the fingertips).
GRASP_CENTRE_Z = 0.12

#: Joint step [rad] of the central differences (chosen: far below the offsets, far above
#: rounding in the forward kinematics).
JACOBIAN_STEP = 1e-5


def reading_posture(obj: ObjectModel, wrt, w: np.ndarray) -> np.ndarray:
    """(7,) the joint angles [rad] on ``wrt``'s path from home at object pose w (3,) where the
    hand's grasp centre passes nearest the object's centre. Raises InfeasiblePath."""
    path = wrt_path(wrt, w, wam.HOME_Q)
    centre = np.r_[w[:2], 0.5 * obj.bounds()[1, 2]]
    grasp = path.poses[:, :3, 3] + GRASP_CENTRE_Z * path.poses[:, :3, 2]
    return path.q[int(np.argmin(np.linalg.norm(grasp - centre, axis=1)))]


def seen_offset_jacobian(q: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(3,7) d(object pose as the posture q sees it)/d(joint offsets), at object pose w (3,):
    the servos bring the offset readings q + off to q, so the hand truly stands at fk(q − off)
    and sees the object at c⁻¹ ∘ w, c = planar_map(fk(q), fk(q − off))."""
    measured = wam.fk(q)
    K = np.zeros((3, 7))
    for k in range(7):
        seen = []
        for sign in (1.0, -1.0):
            off = np.zeros(7)
            off[k] = sign * JACOBIAN_STEP
            c = planar_map(measured, wam.fk(q - off))
            seen.append(relative_planar(c, np.zeros(3)))  # c⁻¹
        a, b = (compose_planar(s, w) for s in seen)
        d = a - b
        d[2] = wrap_angle(d[2])
        K[:, k] = d / (2 * JACOBIAN_STEP)
    return K


@dataclass(frozen=True)
class PostureCalibration:
    """The frames of one object's WRTs under a world profile's joint offsets.

    frames: WRT name → its frame (the name of its class's first WRT). sigma_rad: σ of each
    joint's offset. jacobians: frame → (3,7) seen_offset_jacobian of its posture ("" → 0).
    """

    sigma_rad: float
    frames: dict[str, str] = field(default_factory=dict)
    jacobians: dict[str, np.ndarray] = field(default_factory=dict)
    #: the goal WRTs, whose readings leave a belief in its frame
    goals: frozenset[str] = frozenset()

    @classmethod
    def none(cls) -> PostureCalibration:
        """No calibration error (the nominal world): every WRT in the prior's frame."""
        return cls(0.0)

    @classmethod
    def for_object(cls, obj: ObjectModel, profile: WorldProfile) -> PostureCalibration:
        """The frames of ``obj``'s WRTs at their reading postures (``reading_posture``)."""
        if profile.joint_offset_sigma <= 0:
            return cls.none()
        w = np.asarray(WORLD.nominal_pose, dtype=float)
        sigma = profile.joint_offset_sigma
        frames: dict[str, str] = {}
        jacobians: dict[str, np.ndarray] = {"": np.zeros((3, 7))}
        for wrt in obj.wrts():
            try:
                q = reading_posture(obj, wrt, w)
            except InfeasiblePath:  # unreachable at the nominal pose: the prior's frame
                frames[wrt.name] = ""
                continue
            K = seen_offset_jacobian(q, w)
            for name, J in jacobians.items():
                if name and np.all(sigma * np.linalg.norm(K - J, axis=1) <= SAME_FRAME_SIGMA):
                    frames[wrt.name] = name
                    break
            else:
                frames[wrt.name] = wrt.name
                jacobians[wrt.name] = K
        goals = frozenset(w.name for w in obj.wrts() if w.kind == "goal")
        return cls(sigma, frames, jacobians, goals)

    def frame_of(self, wrt_name: str) -> str:
        """The frame of WRT ``wrt_name``'s posture ("" without calibration error)."""
        return self.frames.get(wrt_name, "")

    def reading_frame(self, wrt_name: str, current: str) -> str:
        """The frame a reading of WRT ``wrt_name`` puts a belief held in ``current`` in: its
        posture's, or for a goal grasp ``current`` (see the module doc)."""
        return current if wrt_name in self.goals else self.frame_of(wrt_name)

    def sigma(self, a: str, b: str) -> np.ndarray:
        """(3,) σ (x [m], y [m], θ [rad], world axes) of the object's pose as frame b sees it
        about where frame a sees it (0 for the same frame)."""
        if a == b or self.sigma_rad <= 0:
            return np.zeros(3)
        D = self.jacobians[b] - self.jacobians[a]
        return self.sigma_rad * np.linalg.norm(D, axis=1)

    def distinct(self, a: str, b: str) -> bool:
        """Whether frames a and b differ by more than SAME_FRAME_SIGMA on some axis."""
        return bool(np.any(self.sigma(a, b) > SAME_FRAME_SIGMA))
