"""``rrg-bag plot``: the belief over the actions of a recorded grasp, like the paper's Fig. 4.

For every belief on ``/rrg/belief`` (the reset one, then one after each observation) a column
with the x–y marginal as a heat map and the θ marginal below it; the object's true pose (from
``/rrg/eval/object_pose``, simulation only) is marked where the bag has it, and so is w*(b).
Writes one PNG per belief and an overview PNG with all of them side by side.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from scipy.spatial.transform import Rotation

from rrg_bags.bag_read import (
    BELIEF_TOPIC,
    OBSERVATION_TOPIC,
    TRUE_POSE_TOPIC,
    read_messages,
)
from rrg_estimator.belief import Belief
from rrg_estimator.ros.belief_msgs import belief_from_msg
from rrg_models.poses import wrap_angle


@dataclass
class BeliefFrame:
    """One belief of the bag with its label and the true pose at the time (if recorded)."""

    label: str
    belief: Belief
    true_pose: np.ndarray | None  # (x [m], y [m], θ [rad])


def _planar(pose_msg) -> np.ndarray:
    p, q = pose_msg.pose.position, pose_msg.pose.orientation
    yaw = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_euler("ZYX")[0]
    return np.array([p.x, p.y, yaw])


def belief_frames(bag: str | Path) -> list[BeliefFrame]:
    """The bag's beliefs in order, labelled 'reset' or 'after <WRT>' (matched by stamp)."""
    frames: list[BeliefFrame] = []
    observed: dict[tuple[int, int], str] = {}
    true_pose = None
    for m in read_messages(bag, {BELIEF_TOPIC, OBSERVATION_TOPIC, TRUE_POSE_TOPIC}):
        if m.topic == TRUE_POSE_TOPIC:
            true_pose = _planar(m.msg)
        elif m.topic == OBSERVATION_TOPIC:
            observed[(m.msg.header.stamp.sec, m.msg.header.stamp.nanosec)] = m.msg.wrt_name
        else:
            stamp = (m.msg.header.stamp.sec, m.msg.header.stamp.nanosec)
            label = f"after {observed[stamp]}" if stamp in observed else "reset"
            frames.append(BeliefFrame(label, belief_from_msg(m.msg), true_pose))
    return frames


def draw_belief(ax_xy, ax_theta, frame: BeliefFrame, title: str) -> None:
    """x–y marginal heat map (cm) and θ marginal (deg) of one belief, true pose in red, w* in
    white."""
    b = frame.belief
    ax, ay, at = b.grid.axes()
    dx, dy, _ = b.grid.spacing
    extent = np.array([ax[0] - dx / 2, ax[-1] + dx / 2, ay[0] - dy / 2, ay[-1] + dy / 2]) * 100
    ax_xy.imshow(
        b.marginal_xy().T,
        origin="lower",
        extent=extent,
        cmap="viridis",
        aspect="equal",
        interpolation="nearest",
    )
    w_star = b.w_star()
    ax_xy.plot(w_star[0] * 100, w_star[1] * 100, "wx", ms=8, mew=2, label="w*(b)")
    theta_deg = np.degrees(at)
    ax_theta.plot(theta_deg, b.marginal_theta(), "k-")
    if frame.true_pose is not None:
        t = frame.true_pose
        ax_xy.plot(t[0] * 100, t[1] * 100, "r+", ms=12, mew=2, label="true pose")
        theta_true = b.grid.center[2] + wrap_angle(t[2] - b.grid.center[2])
        ax_theta.axvline(np.degrees(theta_true), color="r", lw=1.5)
    ax_xy.set_title(title, fontsize=9)
    ax_xy.set_xlabel("x [cm]")
    ax_xy.set_ylabel("y [cm]")
    ax_theta.set_xlabel("θ [deg]")
    ax_theta.set_ylabel("P(θ)")


def plot_bag(bag: str | Path, out_dir: str | Path) -> list[Path]:
    """Write one PNG per belief and ``overview.png``; returns their paths (overview last)."""
    frames = belief_frames(bag)
    if not frames:
        raise ValueError(f"no beliefs on {BELIEF_TOPIC} in {bag}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for k, frame in enumerate(frames):
        fig, (a, b) = plt.subplots(2, 1, figsize=(4, 6), gridspec_kw={"height_ratios": [3, 1]})
        draw_belief(a, b, frame, f"{k}: {frame.label}")
        a.legend(loc="upper right", fontsize=7)
        fig.tight_layout()
        path = out / f"belief_{k:02d}_{frame.label.replace(' ', '_')}.png"
        fig.savefig(path, dpi=100)
        plt.close(fig)
        written.append(path)
    fig, axes = plt.subplots(
        2,
        len(frames),
        figsize=(3.2 * len(frames), 5.5),
        squeeze=False,
        gridspec_kw={"height_ratios": [3, 1]},
    )
    for k, frame in enumerate(frames):
        draw_belief(axes[0, k], axes[1, k], frame, f"{k}: {frame.label}")
    fig.suptitle(f"Belief over the actions: {Path(bag).name}")
    fig.tight_layout()
    overview = out / "overview.png"
    fig.savefig(overview, dpi=100)
    plt.close(fig)
    written.append(overview)
    return written
