"""Rigid transforms: 4×4 homogeneous matrices (SE(3)) and planar object poses (x, y, θ).

Rotations go through scipy's ``Rotation``; everything is vectorized over leading axes.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from rrg_models.config import HOME_ROTVEC, WORLD


def make_pose(position, rotation: Rotation | None = None) -> np.ndarray:
    """(…,3) position and a (batched) Rotation → (…,4,4) transforms."""
    position = np.asarray(position, dtype=float)
    T = np.zeros(position.shape[:-1] + (4, 4))
    T[..., :3, 3] = position
    T[..., :3, :3] = np.eye(3) if rotation is None else rotation.as_matrix()
    T[..., 3, 3] = 1.0
    return T


def planar_pose(w, z: float = WORLD.table_top_z) -> np.ndarray:
    """Object pose(s) (…,3) = (x [m], y [m], θ [rad]) on the table → (…,4,4) in ``world``."""
    w = np.asarray(w, dtype=float)
    T = np.zeros(w.shape[:-1] + (4, 4))
    c, s = np.cos(w[..., 2]), np.sin(w[..., 2])
    T[..., 0, 0], T[..., 0, 1] = c, -s
    T[..., 1, 0], T[..., 1, 1] = s, c
    T[..., 2, 2] = 1.0
    T[..., 0, 3], T[..., 1, 3], T[..., 2, 3] = w[..., 0], w[..., 1], z
    T[..., 3, 3] = 1.0
    return T


def invert(T: np.ndarray) -> np.ndarray:
    """Inverse of (…,4,4) rigid transforms."""
    R = T[..., :3, :3]
    Ti = np.zeros_like(T)
    Ti[..., :3, :3] = np.swapaxes(R, -1, -2)
    Ti[..., :3, 3] = -np.einsum("...ji,...j->...i", R, T[..., :3, 3])
    Ti[..., 3, 3] = 1.0
    return Ti


def wrap_angle(a):
    """Wrap angles to [-π, π) (a float stays a float: the same remainder, without NumPy's
    overhead per call)."""
    if isinstance(a, float):
        return (a + math.pi) % (2 * math.pi) - math.pi
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def relative_planar(e, w) -> np.ndarray:
    """Δ = e⁻¹ ⊕ w: the pose w expressed in the frame of pose e (both (…,3) planar poses).

    This is the relative transform on which an observation of τ(e) in world w depends
    (the paper's Fig. 3).
    """
    e = np.asarray(e, dtype=float)
    w = np.asarray(w, dtype=float)
    dx, dy = w[..., 0] - e[..., 0], w[..., 1] - e[..., 1]
    c, s = np.cos(e[..., 2]), np.sin(e[..., 2])
    return np.stack([c * dx + s * dy, -s * dx + c * dy, wrap_angle(w[..., 2] - e[..., 2])], axis=-1)


def compose_planar(e, d) -> np.ndarray:
    """e ⊕ Δ: the planar pose Δ (given in e's frame) expressed in ``world``."""
    e = np.asarray(e, dtype=float)
    d = np.asarray(d, dtype=float)
    c, s = np.cos(e[..., 2]), np.sin(e[..., 2])
    return np.stack(
        [
            e[..., 0] + c * d[..., 0] - s * d[..., 1],
            e[..., 1] + s * d[..., 0] + c * d[..., 1],
            wrap_angle(e[..., 2] + d[..., 2]),
        ],
        axis=-1,
    )


def planar_map(measured: np.ndarray, true: np.ndarray) -> np.ndarray:
    """(3,) the planar map (x [m], y [m], θ [rad], applied as compose_planar, i.e. about the
    world origin) that takes the (4,4) pose ``measured`` to the pose ``true`` as seen from
    above: the turn about z of true·measuredᵀ and the translation that goes with it."""
    R = true[:3, :3] @ measured[:3, :3].T
    yaw = float(np.arctan2(R[1, 0] - R[0, 1], R[0, 0] + R[1, 1]))
    c, s = np.cos(yaw), np.sin(yaw)
    t = true[:2, 3] - np.array([[c, -s], [s, c]]) @ measured[:2, 3]
    return np.array([t[0], t[1], yaw])


def raised(T: np.ndarray, dz: float) -> np.ndarray:
    """A copy of hand pose(s) T (…,4,4) moved up by dz [m] along the world's z."""
    up = np.array(T, dtype=float)
    up[..., 2, 3] += dz
    return up


def home_pose() -> np.ndarray:
    """The home hand pose in ``world`` (every WRT starts and ends here)."""
    return make_pose(WORLD.home_position, Rotation.from_rotvec(HOME_ROTVEC))


def interpolate_poses(T0: np.ndarray, T1: np.ndarray, n: int) -> np.ndarray:
    """n poses from T0 to T1 inclusive: straight line in position, slerp in rotation."""
    t = np.linspace(0.0, 1.0, n)
    p = T0[:3, 3][None] * (1 - t[:, None]) + T1[:3, 3][None] * t[:, None]
    from scipy.spatial.transform import Slerp

    rots = Rotation.from_matrix(np.stack([T0[:3, :3], T1[:3, :3]]))
    return make_pose(p, Slerp([0.0, 1.0], rots)(t))
