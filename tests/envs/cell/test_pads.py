"""Compliant finger pads (envs.cell.pads): a grasped peg side-loaded at its tip turns in the fingers by F L / (2 k), the
rigid pads of the contact task hold it within a hundredth of a degree, and the realistic preset's k is the rubber
layer the module models."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from envs.cell.pads import layer_torsion_stiffness, pad_patch_m, shore_a_shear_modulus_pa
from envs.cell.scene import build_scene
from envs.cell.scene_config import SceneConfig
from envs.cell.shapes import PEG_LENGTH_M
from envs.errors import EnvError
from envs.poses import Pose
from envs.sim.env import PegInHoleEnv
from envs.sim.episode_config import EpisodeConfig
from envs.task.task import Task, preset


def _env(stiffness: float) -> PegInHoleEnv:
    return PegInHoleEnv(scene=build_scene(SceneConfig(pad_stiffness_nm_rad=stiffness)),
                        episode_config=EpisodeConfig(time_limit_s=5.0))


def _turn_under_side_load(env: PegInHoleEnv, force_n: float) -> tuple[float, float]:
    """Hold the peg 60 mm above the hole and push its tip along the hand's x (across the closing axis) with
    ``force_n`` for 1.5 s; (its turn in the hand about the closing axis (rad), the lever L from the tip to the pads'
    hinge line (m); L = nan with rigid pads)."""
    start = Pose(env.nominal_goal.pos + 0.06 * env.hole_axis, env.nominal_goal.quat)
    env.reset(start_pose=start)
    model, data, peg = env.model, env.data, env.scene.ids.peg_body
    adr = env.scene.ids.peg_qpos_adr

    def tilt() -> float:
        hand = data.site_xmat[env.tcp_site].reshape(3, 3)
        peg_rot = np.zeros(9)
        mujoco.mju_quat2Mat(peg_rot, data.qpos[adr + 3:adr + 7])
        relative = hand.T @ peg_rot.reshape(3, 3)
        return math.atan2(relative[0, 2], relative[2, 2])

    before = tilt()
    for _ in range(150):
        hand = data.site_xmat[env.tcp_site].reshape(3, 3)
        force = force_n * hand[:, 0]
        tip = data.site_xpos[env.scene.ids.peg_tip_site]
        data.xfrc_applied[peg, :3] = force
        data.xfrc_applied[peg, 3:] = np.cross(tip - data.xipos[peg], force)
        env.step(start)
    hinges = [j for j in range(model.njnt) if model.joint(j).name.endswith("_pad_hinge")]
    hand = data.site_xmat[env.tcp_site].reshape(3, 3)
    lever = (float(hand[:, 2] @ (data.site_xpos[env.scene.ids.peg_tip_site] - data.xanchor[hinges[0]]))
             if hinges else math.nan)
    return tilt() - before, lever


@pytest.mark.parametrize("stiffness", [30.0, 67.4, 200.0])
def test_a_side_loaded_peg_turns_in_compliant_pads_by_f_l_over_2k(stiffness) -> None:
    env = _env(stiffness)
    for force_n in (10.0, -10.0):
        turn, lever = _turn_under_side_load(env, force_n)
        assert turn == pytest.approx(force_n * lever / (2.0 * stiffness), rel=0.08)  # measured within 6 %
    assert lever == pytest.approx(0.0712, abs=0.002)  # the tip to the patch's centre on the nominal grasp


def test_rigid_pads_hold_the_peg_within_a_hundredth_of_a_degree() -> None:
    env = _env(0.0)
    assert not any(env.model.joint(j).name.endswith("_pad_hinge") for j in range(env.model.njnt))
    turn, _ = _turn_under_side_load(env, 10.0)
    assert abs(math.degrees(turn)) < 0.01


def test_the_realistic_pads_are_a_2_mm_shore_60a_layer_on_the_grasped_patch() -> None:
    shear_pa = shore_a_shear_modulus_pa(60.0)
    assert shear_pa == pytest.approx(1.2e6, rel=0.01)  # Gent: E(60 Shore A) = 3.6 MPa
    scene = build_scene(SceneConfig())
    model = scene.model
    pad = model.geom("left_finger_pad")
    finger_z = float(model.body("left_finger").pos[2])
    mount_z = float(model.site("peg_mount").pos[2])
    width, length, _ = pad_patch_m(pad.size, float(pad.pos[2]), finger_z, mount_z, PEG_LENGTH_M)
    assert (width, length) == pytest.approx((0.02, 0.0374), abs=1e-6)
    k = layer_torsion_stiffness(shear_pa, 0.002, width, length)
    assert preset("realistic").pad_stiffness_nm_rad == pytest.approx(k, rel=0.002)


@pytest.mark.parametrize("value", [-1.0, math.nan, 1e4, True])
def test_a_bad_pad_stiffness_is_refused_naming_the_field(value) -> None:
    with pytest.raises(EnvError, match="pad_stiffness_nm_rad"):
        Task(pad_stiffness_nm_rad=value)
