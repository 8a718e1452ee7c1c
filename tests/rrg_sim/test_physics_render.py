"""Headless PNG snapshots of the physics world (MUJOCO_GL=egl on the CPU)."""

from __future__ import annotations

import numpy as np
from matplotlib import image as mpimg

from rrg_sim.physics.render import render_png
from rrg_sim.physics.world import PhysicsWorld


def test_render_png_draws_the_scene(tmp_path):
    world = PhysicsWorld("cup", sensor_noise=0.0)
    world.execute_wrt(world.obj.goal_wrt, world.true_object_pose())
    path = render_png(world, tmp_path / "cup.png", size=(320, 240), shadows=False)
    image = mpimg.imread(path)
    assert image.shape[:2] == (240, 320)
    rgb = image[..., :3]
    assert rgb.std() > 0.05  # not a blank frame
    # The orange object is in view: some pixels are clearly more red than blue.
    assert np.mean(rgb[..., 0] - rgb[..., 2] > 0.3) > 0.005
