"""The MuJoCo physics world RRG's trials run in and are judged by (algorithm §2; ROS-free).

``world.PhysicsWorld`` is the simulated robot: WAM + BarrettHand + Nano17s on a table with
one catalogue object. ``runner.run_wrt`` executes a WRT τ(e) end to end; ``judge`` lifts and
judges a grasp; ``render`` draws PNGs; ``agreement`` measures physics against the geometric
simulator. The MJCF comes from rrg_models.description.mjcf_robot and ``scene`` (written to
rrg_sim/assets/ by ``python -m rrg_sim.physics.scene``). Submodules are imported explicitly
(each also runs with ``python -m``).
"""
