"""The contact-rich task in physics: the grasp, the hole-pose error, the force limit, and success read from the
simulated peg (never from the command)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from envs.cell.scene import build_scene
from envs.cell.scene_config import SceneConfig
from envs.cell.shapes import PEG_LENGTH_M
from envs.poses import Pose
from envs.sim.env import PegInHoleEnv
from envs.sim.episode_config import EpisodeConfig
from envs.sim.observation import REASON_FORCE_LIMIT
from envs.task.perturbation import Perturbation


@pytest.fixture(scope="module")
def scene():
    return build_scene(SceneConfig(clearance_m=0.0002, chamfer_m=0.001))


def make_env(scene, **episode) -> PegInHoleEnv:
    return PegInHoleEnv(episode_config=EpisodeConfig(**{"time_limit_s": 10.0, **episode}), scene=scene)


def above(env: PegInHoleEnv, height_m: float = 0.04) -> Pose:
    return Pose(env.hole.pos + height_m * env.hole_axis, env.goal.quat)


def test_the_grasped_peg_is_a_free_body_held_by_the_fingers(scene) -> None:
    assert scene.ids.peg_qpos_adr is not None and len(scene.ids.finger_qpos_adr) == 2
    env = make_env(scene)
    obs = env.reset(start_pose=above(env))
    assert obs.gripper_width_m == pytest.approx(0.030, abs=1e-4)  # the 30 mm square peg's width


def test_the_grasp_holds_through_a_fast_move(scene) -> None:
    """Friction alone (70 N per finger, mu = 1) keeps the peg within 0.2 mm of where it was grasped after the
    hand swings 10 cm sideways and back in 1 s and comes to rest (MuJoCo's soft contacts let it tilt ~0.1 mm)."""
    env = make_env(scene)
    start = above(env, 0.06)
    obs = env.reset(start_pose=start)
    grasped = obs.peg_tip.pos - obs.tcp.pos
    for k in range(100):
        env.step((start.pos + [0.1 * np.sin(2 * np.pi * k / 100), 0.0, 0.0], start.quat))
    for _ in range(50):
        obs = env.step(start).obs
    assert np.linalg.norm(obs.peg_tip.pos - obs.tcp.pos - grasped) < 2e-4


def test_without_grasp_force_the_peg_falls_out(scene) -> None:
    """The grasp force is what holds the peg: with it nearly off, gravity pulls the peg out of the fingers."""
    weak = build_scene(SceneConfig(clearance_m=0.0002, chamfer_m=0.001, grasp_force_n=0.05))
    env = make_env(weak)
    env.reset(start_pose=above(env, 0.1))
    for _ in range(50):
        obs = env.step(above(env, 0.1)).obs
    assert np.linalg.norm(obs.peg_tip.pos - obs.tcp.pos) > 0.005


def test_grasp_offset_shifts_the_peg_along_its_axis(scene) -> None:
    env = make_env(scene)
    obs = env.reset(start_pose=above(env), perturbation=Perturbation(grasp_offset_m=0.003))
    axis = env.data.site_xmat[env.tcp_site].reshape(3, 3)[:, 2]
    assert (obs.peg_tip.pos - obs.tcp.pos) @ axis == pytest.approx(0.003, abs=1e-4)


def test_hole_error_moves_the_sorter_and_the_scored_hole(scene) -> None:
    env = make_env(scene)
    geom = scene.ids.sorter_geoms[0]
    env.reset(start_pose=above(env))
    before = env.data.geom_xpos[geom].copy()
    error = Perturbation(hole_dx_m=0.001, hole_dy_m=-0.0005, hole_yaw_deg=1.0, hole_tilt_deg=0.5)
    env.reset(start_pose=above(env), perturbation=error)
    assert np.linalg.norm(env.hole.pos - env.nominal_hole.pos) == pytest.approx(np.hypot(0.001, 0.0005), abs=1e-6)
    assert np.linalg.norm(env.data.geom_xpos[geom] - before) > 1e-4  # the walls moved with it
    assert np.degrees(np.arccos(np.clip(env.hole_axis @ [0.0, 0.0, 1.0], -1, 1))) == pytest.approx(0.5, abs=1e-6)


def test_force_limit_ends_a_hard_push(scene) -> None:
    """Pressing 5 cm into the plate at 1500 N/m (75 N) ends the episode at the 40 N limit."""
    env = make_env(scene)
    beside = env.hole.pos + [0.05, 0.0, 0.01]
    env.reset(start_pose=(beside, env.goal.quat))
    for _ in range(200):
        result = env.step((beside - [0.0, 0.0, 0.06], env.goal.quat))
        if result.done:
            break
    assert result.reason == REASON_FORCE_LIMIT and env.stats.peak_wrist_force_n > 40.0


def test_force_limit_reached_on_the_last_substep_ends_the_episode(scene) -> None:
    """A wrist force held above the limit for exactly the window, the window ending on a control period's last
    physics step, ends the episode in that period (a limit of 1 uN, which the arm's own motion exceeds at every
    reading, over a window of one control period: it is reached at physics step 10 of step 1, not before)."""
    env = make_env(scene, force_limit_n=1e-6, force_limit_window_s=0.01)
    env.reset(start_pose=above(env))
    start_s = env.data.time
    result = env.step(above(env, 0.05))
    assert result.done and result.reason == REASON_FORCE_LIMIT
    assert env.data.time - start_s == pytest.approx(env.control_period_s)  # all 10 physics steps ran
    assert env.stats.force_limit_time_s == 0.0


def test_a_short_force_spike_does_not_end_the_episode(scene) -> None:
    """The same push with a limit that must be exceeded for 10 s never triggers within 1 s."""
    env = make_env(scene, force_limit_window_s=10.0)
    beside = env.hole.pos + [0.05, 0.0, 0.01]
    env.reset(start_pose=(beside, env.goal.quat))
    results = [env.step((beside - [0.0, 0.0, 0.06], env.goal.quat)) for _ in range(100)]
    assert not any(r.done for r in results) and env.stats.peak_wrist_force_n > 40.0


def test_commanding_the_goal_does_not_succeed_when_the_hole_is_elsewhere(scene) -> None:
    """Success must come from the simulated peg: with the real hole 4 mm away (more than the 1 mm chamfer can
    catch) the peg pressed at the commanded goal rests on the plate, and nothing succeeds."""
    env = make_env(scene, time_limit_s=3.0)
    env.reset(start_pose=above(env), perturbation=Perturbation(hole_dx_m=0.004))
    goal = Pose(env.nominal_goal.pos, env.nominal_goal.quat)
    while not env.done:
        result = env.step(goal)
    assert not result.obs.success and result.obs.hole is None
    assert np.linalg.norm(result.info["target"].pos - goal.pos) < 1e-12


def place_peg(env: PegInHoleEnv, offset_in_hole: tuple[float, float, float]) -> None:
    """Teleport the free peg (fingers opened, arm far above) so that its peg_tip sits at ``offset_in_hole``
    in the real hole frame, upright, at rest."""
    data, ids = env.data, env.scene.ids
    data.qpos[env._finger_qpos] = 0.04
    data.qfrc_applied[env._finger_dof] = 0.0
    tip_rot = np.empty(9)
    mujoco.mju_quat2Mat(tip_rot, env.goal.quat)
    tip_rot = tip_rot.reshape(3, 3)
    hole_rot = np.empty(9)
    mujoco.mju_quat2Mat(hole_rot, env.hole.quat)
    tip = env.hole.pos + hole_rot.reshape(3, 3) @ np.asarray(offset_in_hole)
    adr = ids.peg_qpos_adr
    data.qpos[adr:adr + 3] = tip - tip_rot[:, 2] * PEG_LENGTH_M
    data.qpos[adr + 3:adr + 7] = env.goal.quat
    data.qvel[:] = 0.0
    mujoco.mj_forward(env.model, data)


def test_a_seated_peg_succeeds_wherever_the_arm_is(scene) -> None:
    """The peg teleported seated into the hole while the tcp is 4 cm above: scored inserted."""
    env = make_env(scene)
    env.reset(start_pose=above(env))
    place_peg(env, (0.0, 0.0, -env.scene.config.insertion_depth_m))
    assessment = env.assess()
    assert assessment.inserted and np.linalg.norm(env.observation.tcp.pos - env.goal.pos) > 0.03


@pytest.mark.parametrize("offset, why", [
    ((0.0005, 0.0, -0.03), "0.4 mm into a wall of the 0.2 mm clearance"),
    ((0.0, 0.0, -0.026), "4 mm short of seated"),
    ((0.0, 0.0, 0.01), "above the opening"),
])
def test_teleported_states_that_are_not_seated_score_false(scene, offset, why) -> None:
    env = make_env(scene)
    env.reset(start_pose=above(env))
    place_peg(env, offset)
    assert not env.assess().inserted, why


def test_a_moving_seated_peg_is_not_at_rest(scene) -> None:
    env = make_env(scene)
    env.reset(start_pose=above(env))
    place_peg(env, (0.0, 0.0, -0.03))
    env.data.qvel[env.scene.ids.peg_dof_adr + 2] = -0.05
    mujoco.mj_forward(env.model, env.data)
    assert not env.assess().inserted
