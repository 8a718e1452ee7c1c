"""MuJoCo physics as the agent's Environment: the object really moves when bumped, and a
goal grasp is judged by lifting it (rrg_sim.physics)."""

from __future__ import annotations

import numpy as np

from rrg_models.observation import Observation
from rrg_models.wrt import WRT
from rrg_sim.physics.judge import judge_grasp
from rrg_sim.physics.world import PhysicsWorld


class PhysicsEnvironment:
    """Wraps a PhysicsWorld (reused across trials: ``reset`` places the next true pose)."""

    def __init__(self, world: PhysicsWorld):
        self.world = world
        #: What the last judge found (rrg_sim.physics.judge: in_region, held, fingers, …).
        self.last_judgement: dict = {}

    @classmethod
    def for_object(
        cls,
        object_name: str,
        seed: int = 0,
        profile: str = "nominal",
        confirm_stops: bool = True,
        touch_table: bool | None = None,
    ) -> PhysicsEnvironment:
        """A world of one object under a world profile (rrg_sim.config.world_profile), its
        guarded moves confirming their stops unless ``confirm_stops`` is off, and touching the
        table before a goal grasp as PhysicsWorld's ``touch_table`` says."""
        return cls(
            PhysicsWorld(
                object_name,
                seed=seed,
                profile=profile,
                confirm_stops=confirm_stops,
                touch_table=touch_table,
            )
        )

    def reset(self, true_pose, seed: int) -> None:
        """Start a trial: sensor noise reseeded and the profile's conditions drawn from
        ``seed``, robot home, object at its true pose."""
        self.world.reseed(seed)
        self.world.reset(np.asarray(true_pose, dtype=float))
        self.last_judgement = {}

    def execute(self, wrt: WRT, e: np.ndarray) -> Observation:
        return self.world.execute_wrt(wrt, e)

    def retreat(self) -> None:
        self.world.retreat()

    def judge(self, wrt: WRT, e: np.ndarray) -> bool:
        ok, self.last_judgement = judge_grasp(self.world, self.world.obj, e, goal=wrt.name)
        return bool(ok)
