"""The success tolerances against the contact model: the wall penetration a peg reaches when pressed into a wall at
the force limit stays inside the penetration tolerance, and the floor-contact option needs the peg on the floor."""

from __future__ import annotations

import numpy as np
import pytest

from envs.cell.scene import build_scene
from envs.cell.scene_config import SceneConfig
from envs.poses import Pose
from envs.sim.env import PegInHoleEnv
from envs.sim.episode_config import EpisodeConfig
from envs.task.task import SuccessConfig, Task


@pytest.fixture(scope="module")
def scene():
    """The contact task's scene: 0.2 mm clearance, 1 mm chamfers, holes as deep as the insertion (30 mm)."""
    return build_scene(SceneConfig(**Task().scene_fields()))


def _pressed_sideways(scene, push_n: float) -> tuple[float, float]:
    """(wall penetration (envs.task.success), contact force on the peg) of the peg held 10 mm deep in the hole and
    pushed sideways against one wall with ~``push_n`` (a 4000 N/m spring stretched push_n / 4000 m beyond the wall)."""
    env = PegInHoleEnv(scene=scene, episode_config=EpisodeConfig(time_limit_s=5.0, force_limit_n=1000.0))
    inside = Pose(env.goal.pos + 0.02 * env.hole_axis, env.goal.quat)  # 10 mm below the opening
    env.reset(start_pose=inside)
    stiffness = np.diag([4000.0, 4000.0, 4000.0, 200.0, 200.0, 200.0])
    side = np.cross(env.hole_axis, [0.0, 1.0, 0.0])
    side /= np.linalg.norm(side)
    for _ in range(150):
        env.step(Pose(inside.pos + side * (push_n / 4000.0), inside.quat), stiffness)
    return float(env.observation.insertion.wall_penetration_m), float(env.observation.contact_force_n)


def test_a_peg_pressed_into_a_wall_at_the_force_limit_stays_within_the_penetration_tolerance(scene) -> None:
    """Pressed into a wall with the force limit's 40 N (and more), the peg penetrates ~20 um, inside the 30 um
    tolerance (1.5 x): the verdict does not hang on the solver's softness at forces an episode may hold."""
    penetration_m, force_n = _pressed_sideways(scene, 50.0)
    assert force_n > 40.0
    assert 1.5e-5 < penetration_m < SuccessConfig().penetration_tolerance_m


def _held_at(scene, height_m: float, success: SuccessConfig) -> bool:
    """Whether a peg held in the real hole with its tip ``height_m`` above the goal (on the floor) succeeds."""
    config = EpisodeConfig(time_limit_s=1.0, success=success)
    env = PegInHoleEnv(scene=scene, episode_config=config)
    start = Pose(env.goal.pos + 0.005 * env.hole_axis, env.goal.quat)
    env.reset(start_pose=start)
    target = Pose(env.goal.pos + height_m * env.hole_axis, env.goal.quat)
    while not env.done:
        env.step(target, np.diag([4000.0, 4000.0, 4000.0, 200.0, 200.0, 200.0]))
    return env.observation.success


def test_the_floor_contact_option_needs_the_peg_pressed_on_the_floor(scene) -> None:
    """0.5 mm above the floor is seated by depth (within the 1 mm tolerance) but not with floor_force_n = 5; pressed
    2 mm into it at 4000 N/m (~8 N) it is seated either way."""
    floor = SuccessConfig(floor_force_n=5.0)
    assert _held_at(scene, 0.0005, SuccessConfig()) and not _held_at(scene, 0.0005, floor)
    assert _held_at(scene, -0.002, floor) and _held_at(scene, -0.002, SuccessConfig())
