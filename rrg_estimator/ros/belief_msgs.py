"""Conversions between the belief (rrg_estimator.belief.Belief on an rrg_estimator.grid.Grid) and
rrg_msgs/BeliefGrid, with the validation every node applies to a belief it receives.

Both layouts agree: the grid is centred on ``metadata.origin`` and the weights are C-ordered
over (x, y, θ), so a belief goes out and comes back without reshuffling.
"""

from __future__ import annotations

import array

import numpy as np
from builtin_interfaces.msg import Time
from visualization_msgs.msg import Marker, MarkerArray

from rrg_common.ros.msg_conversions import WORLD_FRAME, planar_from_msg, planar_to_msg
from rrg_estimator.belief import Belief
from rrg_estimator.grid import Grid
from rrg_msgs.msg import BeliefGrid, BeliefGridMetaData


class InvalidGrid(ValueError):
    """A grid with a zero, negative or non-finite spacing, a zero size, or a non-finite origin."""


class InvalidBelief(ValueError):
    """Weights that do not fit the grid, or NaN, negative or all-zero weights."""


def float64_array(values) -> array.array:
    """An ``array('d')`` for an unbounded float64[] field (assigning one skips rclpy's per-element
    checks)."""
    out = array.array("d")
    out.frombytes(np.ascontiguousarray(values, dtype=np.float64).tobytes())
    return out


def grid_to_metadata(
    grid: Grid, map_load_time: Time | None = None, update_time: Time | None = None
) -> BeliefGridMetaData:
    sx, sy, st = (float(s) for s in grid.spacing)
    nx, ny, nt = (int(n) for n in grid.shape)
    return BeliefGridMetaData(
        map_load_time=map_load_time or Time(),
        update_time=update_time or Time(),
        resolution_x=sx,
        resolution_y=sy,
        resolution_theta=st,
        size_x=nx,
        size_y=ny,
        size_theta=nt,
        origin=planar_to_msg(grid.center),
    )


def grid_from_metadata(meta: BeliefGridMetaData) -> Grid:
    """The Grid a metadata message describes; raises InvalidGrid when it describes none."""
    spacing = np.array([meta.resolution_x, meta.resolution_y, meta.resolution_theta], dtype=float)
    shape = (int(meta.size_x), int(meta.size_y), int(meta.size_theta))
    center = planar_from_msg(meta.origin)
    if not np.all(np.isfinite(spacing)) or np.any(spacing <= 0.0):
        raise InvalidGrid(
            f"grid resolution must be finite and > 0, got (x, y, theta) = {spacing.tolist()}"
        )
    if min(shape) < 1:
        raise InvalidGrid(f"grid size must be >= 1 along every axis, got (x, y, theta) = {shape}")
    if not np.all(np.isfinite(center)):
        raise InvalidGrid(f"grid origin must be finite, got {center.tolist()}")
    return Grid(tuple(center.tolist()), tuple(spacing.tolist()), shape)


def belief_to_msg(
    belief: Belief, stamp: Time, map_load_time: Time | None = None, frame_id: str = WORLD_FRAME
) -> BeliefGrid:
    """A Belief → rrg_msgs/BeliefGrid stamped ``stamp`` (also the metadata's update time)."""
    msg = BeliefGrid(
        metadata=grid_to_metadata(belief.grid, map_load_time or stamp, stamp),
        argmax=planar_to_msg(belief.w_star()),
        mean=planar_to_msg(belief.mean()),
    )
    msg.header.stamp, msg.header.frame_id = stamp, frame_id
    msg.weights = float64_array(belief.weights)
    msg.covariance = belief.cov().ravel()
    msg.posture_frame = belief.frame
    return msg


def belief_from_msg(msg: BeliefGrid) -> Belief:
    """rrg_msgs/BeliefGrid → Belief; raises InvalidGrid or InvalidBelief (with the reason)."""
    grid = grid_from_metadata(msg.metadata)
    weights = (
        np.frombuffer(msg.weights, dtype=np.float64)
        if isinstance(msg.weights, array.array)
        else np.asarray(msg.weights, dtype=np.float64)
    )
    if weights.size != grid.size:
        raise InvalidBelief(
            f"belief has {weights.size} weights, its grid {grid.shape} needs {grid.size}"
        )
    try:
        return Belief(grid, weights, msg.posture_frame)
    except ValueError as exc:
        raise InvalidBelief(str(exc)) from exc


def belief_markers(
    belief: Belief,
    stamp: Time,
    count: int,
    max_diameter_m: float,
    frame_id: str = WORLD_FRAME,
    namespace: str = "belief",
) -> MarkerArray:
    """The ``count`` heaviest grid points as spheres on the table (z = 0) with volume ∝ weight
    (diameter ``max_diameter_m`` for the heaviest) and colour from blue (θ low) to red (θ high),
    after a DELETEALL that clears the previous set."""
    w = belief.weights
    top = np.argsort(-w, kind="stable")[:count]
    top = top[w[top] > 0.0]
    points = belief.grid.points()[top]
    theta_axis = belief.grid.axes()[2]
    span = max(float(theta_axis[-1] - theta_axis[0]), 1e-12)
    clear = Marker(action=Marker.DELETEALL, ns=namespace)
    clear.header.stamp, clear.header.frame_id = stamp, frame_id
    markers = [clear]
    for k, (i, p) in enumerate(zip(top, points)):
        m = Marker(ns=namespace, id=k, type=Marker.SPHERE, action=Marker.ADD)
        m.header.stamp, m.header.frame_id = stamp, frame_id
        m.pose.position.x, m.pose.position.y = float(p[0]), float(p[1])
        m.pose.orientation.w = 1.0
        d = max_diameter_m * float(np.cbrt(w[i] / w[top[0]]))
        m.scale.x = m.scale.y = m.scale.z = d
        hue = float((p[2] - theta_axis[0]) / span)
        m.color.r, m.color.g, m.color.b, m.color.a = hue, 0.2, 1.0 - hue, 0.8
        markers.append(m)
    return MarkerArray(markers=markers)
