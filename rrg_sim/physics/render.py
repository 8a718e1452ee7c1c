"""PNG snapshots of the physics world, headless on the CPU (``MUJOCO_GL=egl`` by default).

``render_png(world, path)`` draws the current state from a free camera looking at the
object. ``render_goal_grasps()`` executes every catalogue object's goal WRT at its true pose
and saves one picture per object (``python -m rrg_sim.physics.render --out docs/img``).

The GL context is created here from MUJOCO_GL's backend module (egl, or osmesa), so
rendering works whatever imported mujoco first.
"""

from __future__ import annotations

import argparse
import importlib
import os
from pathlib import Path

import mujoco
import numpy as np
from matplotlib import image as mpimg

from rrg_models.objects import PAPER_OBJECTS
from rrg_sim.physics.world import PhysicsWorld

DEFAULT_SIZE = (640, 480)  # px


class OffscreenRenderer:
    """An offscreen MuJoCo renderer for one model (framebuffer up to the model's
    offwidth/height)."""

    def __init__(
        self, model: mujoco.MjModel, width: int = DEFAULT_SIZE[0], height: int = DEFAULT_SIZE[1]
    ):
        backend = os.environ.get("MUJOCO_GL", "egl").lower()
        if backend not in ("egl", "osmesa"):
            backend = "egl"
        context_cls = importlib.import_module(f"mujoco.{backend}").GLContext
        self.width, self.height = width, height
        self._gl = context_cls(width, height)
        self._gl.make_current()
        self.model = model
        self.scene = mujoco.MjvScene(model, maxgeom=10000)
        self.option = mujoco.MjvOption()
        self.context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self.context)

    def render(
        self, data: mujoco.MjData, camera: mujoco.MjvCamera, shadows: bool = True
    ) -> np.ndarray:
        """(height, width, 3) uint8 RGB image of ``data`` seen from ``camera``."""
        self._gl.make_current()
        self.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = shadows
        mujoco.mjv_updateScene(
            self.model, data, self.option, None, camera, mujoco.mjtCatBit.mjCAT_ALL, self.scene
        )
        rect = mujoco.MjrRect(0, 0, self.width, self.height)
        mujoco.mjr_render(rect, self.scene, self.context)
        rgb = np.empty((self.height, self.width, 3), dtype=np.uint8)
        mujoco.mjr_readPixels(rgb, None, rect, self.context)
        return np.flipud(rgb)

    def close(self) -> None:
        self.context.free()
        self._gl.free()


def object_camera(
    world: PhysicsWorld, distance: float = 0.75, azimuth: float = 135.0, elevation: float = -20.0
) -> mujoco.MjvCamera:
    """A free camera looking at the object (azimuth/elevation in degrees, distance in m)."""
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.lookat[:] = world.object_pose()[:3, 3] + [0.0, 0.0, 0.08]
    cam.distance, cam.azimuth, cam.elevation = distance, azimuth, elevation
    return cam


def grasp_camera(world: PhysicsWorld, elevation: float = -25.0) -> mujoco.MjvCamera:
    """A camera on the hand and the object: across the approach direction for a grasp from
    the side, from the far side of the table (facing the robot) for a grasp from above."""
    T = world.true_hand_pose()
    palm = T[:3, 3] + T[:3, 2] * 0.12  # between the palm and the fingertips
    size = float(np.ptp(world.obj.bounds(), axis=0).max())
    cam = object_camera(world, 0.45 + 1.5 * size, elevation=elevation)
    cam.lookat[:] = (palm + world.object_pose()[:3, 3]) / 2
    approach = T[:2, 2]
    side = np.linalg.norm(approach) > 0.3
    cam.azimuth = float(np.degrees(np.arctan2(approach[1], approach[0]))) - 90.0 if side else 160.0
    return cam


def render_png(
    world: PhysicsWorld,
    path: str | Path,
    camera: mujoco.MjvCamera | None = None,
    size: tuple[int, int] = DEFAULT_SIZE,
    shadows: bool = True,
) -> Path:
    """Write a PNG of the world's current state (default camera: ``grasp_camera``)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    renderer = OffscreenRenderer(world.model, *size)
    try:
        image = renderer.render(world.data, camera or grasp_camera(world), shadows)
    finally:
        renderer.close()
    mpimg.imsave(path, image)
    return path


def render_goal_grasps(
    out_dir: str | Path = "docs/img", names: tuple[str, ...] = PAPER_OBJECTS
) -> list[Path]:
    """Execute each object's goal WRT at its true (nominal) pose, noise-free, and save
    ``goal_<name>.png`` showing the closed hand on the object."""
    paths = []
    for name in names:
        world = PhysicsWorld(name, sensor_noise=0.0)
        world.execute_wrt(world.obj.goal_wrt, world.true_object_pose())
        paths.append(render_png(world, Path(out_dir) / f"goal_{name}.png"))
    return paths


def main(argv: list[str] | None = None) -> int:
    """``python -m rrg_sim.physics.render [--out DIR] [names…]``: render every goal grasp."""
    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument("--out", type=Path, default=Path("docs/img"))
    parser.add_argument("names", nargs="*", default=list(PAPER_OBJECTS))
    args = parser.parse_args(argv)
    for path in render_goal_grasps(args.out, tuple(args.names)):
        print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
