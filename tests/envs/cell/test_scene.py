"""Tests of envs.cell.scene: configuration checks, goal placement, the held and free peg, ids (build time: `pih
bench`)."""

import mujoco
import numpy as np
import pytest

from envs.cell.scene import CAMERAS, build_scene
from envs.cell.scene_config import (PAPER_GOAL_POS_M, PAPER_GOAL_QUAT, SceneConfig, goal_from_hole,
                                    goal_pose_from_paper, hole_from_goal)
from envs.cell.shapes import PEG_LENGTH_M, SHAPES
from envs.errors import EnvError
from envs.geometry import tilt_from_down_deg, z_down_yaw_deg
from numerics.quaternion import mat_to_quat, quat_to_mat


@pytest.fixture(scope="module")
def held():
    return build_scene(SceneConfig(peg_mode="welded"))


@pytest.fixture(scope="module")
def grasped():
    return build_scene(SceneConfig(peg_mode="grasped", chamfer_m=0.001))


def kinematics(scene, key=True):
    data = mujoco.MjData(scene.model)
    if key:
        mujoco.mj_resetDataKeyframe(scene.model, data, scene.ids.home_key)
    mujoco.mj_kinematics(scene.model, data)
    return data


def same_rotation(quat_a, quat_b):
    return np.allclose(quat_to_mat(quat_a), quat_to_mat(quat_b), atol=1e-9)


def test_default_goal_is_the_paper_goal_made_vertical(held):
    pos, quat = held.goal_pose()
    paper_pos, paper_quat = goal_pose_from_paper()
    assert np.allclose(pos, PAPER_GOAL_POS_M) and same_rotation(quat, paper_quat)


def test_default_goal_points_the_peg_straight_down_with_the_paper_heading(held):
    rot = quat_to_mat(held.goal_pose()[1])
    assert np.isclose(tilt_from_down_deg(rot), 0.0, atol=1e-7)
    assert np.isclose(z_down_yaw_deg(held.goal_pose()[1]), z_down_yaw_deg(PAPER_GOAL_QUAT))


def test_goal_is_insertion_depth_below_the_opening(held):
    hole_pos, _ = held.hole_pose("square")
    assert np.allclose(hole_pos - held.goal_pose()[0], [0.0, 0.0, 0.03])


def test_goal_and_hole_round_trip():
    quat = mat_to_quat(quat_to_mat((0.02, 0.99, -0.13, 0.04)))
    pos, q = goal_from_hole(*hole_from_goal([0.5, 0.1, 0.2], quat, 0.03), 0.03)
    assert np.allclose(pos, [0.5, 0.1, 0.2]) and same_rotation(q, quat)


def test_held_scene_has_only_the_arm_joints(held):
    assert held.model.nq == 7 and held.ids.peg_qpos_adr is None


def test_hole_sites_match_hole_pose(held):
    data = kinematics(held)
    for shape in SHAPES:
        pos, quat = held.hole_pose(shape)
        site = held.ids.hole_sites[shape]
        assert np.allclose(data.site_xpos[site], pos)
        assert np.allclose(data.site_xmat[site].reshape(3, 3), quat_to_mat(quat))


def test_held_peg_tip_is_the_peg_length_along_peg_mount_z(held):
    data = kinematics(held)
    mount_rot = data.site_xmat[held.ids.peg_mount_site].reshape(3, 3)
    expected = data.site_xpos[held.ids.peg_mount_site] + PEG_LENGTH_M * mount_rot[:, 2]
    assert np.allclose(data.site_xpos[held.ids.peg_tip_site], expected)
    assert np.allclose(data.site_xmat[held.ids.peg_tip_site].reshape(3, 3), mount_rot)


def test_held_peg_tip_lies_on_the_flange_axis(held):
    data = kinematics(held)
    flange_rot = data.site_xmat[held.ids.flange_site].reshape(3, 3)
    offset = flange_rot.T @ (data.site_xpos[held.ids.peg_tip_site] - data.site_xpos[held.ids.flange_site])
    assert np.allclose(offset[:2], 0.0, atol=1e-12) and offset[2] > PEG_LENGTH_M


def test_held_peg_moves_with_the_hand(held):
    before = kinematics(held).site_xpos[held.ids.peg_tip_site].copy()
    data = mujoco.MjData(held.model)
    mujoco.mj_resetDataKeyframe(held.model, data, held.ids.home_key)
    data.qpos[held.ids.arm_qpos_adr[0]] += 0.3
    mujoco.mj_kinematics(held.model, data)
    assert np.linalg.norm(data.site_xpos[held.ids.peg_tip_site] - before) > 0.05


@pytest.mark.parametrize("shape", ["square", "triangle", "circle"])
@pytest.mark.parametrize("mode", ["welded", "grasped"])
def test_fingers_touch_the_peg(shape, mode):
    scene = build_scene(SceneConfig(shape=shape, peg_mode=mode))
    data = kinematics(scene)
    mujoco.mj_forward(scene.model, data)
    peg_geom = scene.ids.peg_geoms[0]
    for pad in ("left_finger_pad", "right_finger_pad"):
        distance = mujoco.mj_geomDistance(scene.model, data, scene.model.geom(pad).id, peg_geom, 0.01, None)
        assert abs(distance) < 1e-6


def test_held_peg_has_no_contact_with_the_hand(held):
    data = kinematics(held)
    mujoco.mj_forward(held.model, data)
    assert data.ncon == 0


def test_grasped_scene_has_arm_fingers_and_a_free_peg(grasped):
    model = grasped.model
    assert model.nq == 7 + 2 + 7 and len(grasped.ids.finger_qpos_adr) == 2 and grasped.ids.peg_qpos_adr == 9
    assert model.body_parentid[grasped.ids.peg_body] == 0  # a body of its own, not part of the hand


def test_grasped_peg_tip_starts_on_the_tcp(grasped):
    data = kinematics(grasped)
    np.testing.assert_allclose(data.site_xpos[grasped.ids.peg_tip_site], data.site_xpos[grasped.ids.tcp_site],
                               atol=1e-9)
    np.testing.assert_allclose(data.site_xmat[grasped.ids.peg_tip_site], data.site_xmat[grasped.ids.tcp_site],
                               atol=1e-9)


def test_welded_tcp_is_the_peg_tip(held):
    data = kinematics(held)
    np.testing.assert_allclose(data.site_xpos[held.ids.peg_tip_site], data.site_xpos[held.ids.tcp_site], atol=1e-12)


def test_wrist_sensor_sits_between_flange_and_hand(grasped):
    model = grasped.model
    assert model.site_bodyid[grasped.ids.ft_site] == grasped.ids.hand_body
    data = kinematics(grasped)
    np.testing.assert_allclose(data.site_xpos[grasped.ids.ft_site], data.site_xpos[grasped.ids.flange_site],
                               atol=1e-12)


def test_chamfer_meshes_exist_only_with_a_chamfer(grasped, held):
    names = [grasped.model.geom(g).name for g in grasped.ids.sorter_geoms]
    assert sum(n.startswith("sorter/chamfer_square") for n in names) >= 4
    assert not any(held.model.geom(g).name.startswith("sorter/chamfer") for g in held.ids.sorter_geoms)


def test_free_peg_starts_above_its_hole():
    scene = build_scene(SceneConfig(peg_mode="free", free_peg_height_m=0.05))
    data = kinematics(scene)
    assert scene.model.nq == 16
    assert np.allclose(data.site_xpos[scene.ids.peg_tip_site], scene.hole_pose("square")[0] + [0.0, 0.0, 0.05])


@pytest.mark.parametrize("shape", SHAPES)
def test_chosen_shape_hole_is_at_the_goal(shape):
    scene = build_scene(SceneConfig(shape=shape))
    assert np.allclose(scene.goal_pose()[0], PAPER_GOAL_POS_M)


def test_hole_at_goal_places_the_chosen_hole():
    tilted = mat_to_quat(quat_to_mat(PAPER_GOAL_QUAT))
    scene = build_scene(SceneConfig(shape="triangle", hole_at_goal=((0.6, 0.1, 0.25), tilted)))
    pos, quat = scene.goal_pose()
    assert np.allclose(pos, [0.6, 0.1, 0.25]) and same_rotation(quat, tilted)


def test_hole_at_goal_tilted_more_than_five_degrees_is_rejected():
    tilt = np.deg2rad(6.0)
    quat = mat_to_quat(np.array([[1, 0, 0], [0, -np.cos(tilt), -np.sin(tilt)], [0, np.sin(tilt), -np.cos(tilt)]]))
    with pytest.raises(EnvError, match="tilts"):
        SceneConfig(hole_at_goal=((0.6, 0.0, 0.2), quat))


def test_goal_onto_the_robot_base_is_rejected():
    with pytest.raises(EnvError, match="robot base"):
        build_scene(SceneConfig(goal_pos=(0.1, 0.0, 0.2)))


def test_goal_below_the_floor_is_rejected():
    with pytest.raises(EnvError, match="table"):
        build_scene(SceneConfig(goal_pos=(0.6, 0.0, 0.02)))


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"shape": "star"}, "shape"),
        ({"clearance_m": 0.01}, "clearance_m"),
        ({"insertion_depth_m": 0.05}, "insertion_depth_m"),
        ({"peg_mode": "glued"}, "peg_mode"),
        ({"goal_pos": (0.6, 0.0)}, "goal_pos"),
        ({"hole_at_goal": ((0.6, 0.0, 0.2), (0.0, 0.0, 0.0, 0.0))}, "hole_at_goal quat"),
    ],
)
def test_bad_config_is_rejected_naming_the_field(kwargs, name):
    with pytest.raises(EnvError, match=name):
        SceneConfig(**kwargs)


def test_named_cameras_exist(held):
    for name in CAMERAS:
        assert mujoco.mj_name2id(held.model, mujoco.mjtObj.mjOBJ_CAMERA, name) >= 0


def test_ids_cover_arm_and_peg(held):
    assert len(held.ids.arm_qpos_adr) == 7 and len(held.ids.actuators) == 7
    assert held.ids.peg_geoms and all(held.model.geom_bodyid[g] == held.ids.peg_body for g in held.ids.peg_geoms)


def test_peg_weighs_a_few_tens_of_grams(held):
    assert 0.03 < held.model.body_mass[held.ids.peg_body] < 0.08


def test_xml_recompiles_to_the_same_model_size(held):
    model = mujoco.MjModel.from_xml_string(held.xml(), {})
    assert (model.nq, model.ngeom) == (held.model.nq, held.model.ngeom)


@pytest.mark.parametrize("camera", ["front", "side", "closeup", "top"])
def test_world_cameras_see_the_goal(held, camera):
    data = kinematics(held)
    mujoco.mj_camlight(held.model, data)
    cam = held.model.camera(camera).id
    to_goal = held.goal_pose()[0] - data.cam_xpos[cam]
    viewing = -data.cam_xmat[cam].reshape(3, 3)[:, 2]
    angle_deg = np.rad2deg(np.arccos(viewing @ to_goal / np.linalg.norm(to_goal)))
    assert angle_deg < held.model.cam_fovy[cam] / 2.0


def test_config_stores_hole_at_goal_as_tuples():
    config = SceneConfig(hole_at_goal=(np.array([0.6, 0.0, 0.2]), [0.0, 1.0, 0.0, 0.0]))
    assert config.hole_at_goal == ((0.6, 0.0, 0.2), (0.0, 1.0, 0.0, 0.0))
