"""Scene composition: the Panda, a floor, a table, the shape sorter and a peg, as one MuJoCo model.

The root is the Panda MJCF (world origin = robot base); the sorter ("sorter/...") and the peg ("peg/...")
are separate MJCF models attached to it. Peg modes:
  - "grasped" (default): the peg is a free body held between the two prismatic fingers by friction; the
    fingers are coupled (they move symmetrically, as the Franka hand's) and each finger joint is pushed closed
    with the grasp force (a force-controlled gripper, applied as a generalised
    force by the episode), so the peg may slip or tilt in the grasp under contact. nq = 7 + 2 + 7.
  - "welded": the peg is attached rigidly at the hand's ``peg_mount`` site and the finger joints are removed
    (the fingers are moved onto its sides), so nq = 7: the paper's toy setting.
  - "free": the peg floats on a free joint above its hole (for physics tests).
The hand carries the site ``tcp``: the nominal peg_tip, where the peg_tip is when the peg sits in the hand as
grasped nominally (``nominal_flange_to_peg_tip``). Controllers and skills command and read ``tcp`` (what the
robot knows from its joints); success reads the peg's own ``peg/peg_tip``. The wrist force/torque sensor sits
between flange and hand (site ``ft_sensor`` at the hand's origin, sensors ``wrist_force``/``wrist_torque``).
The sorter is a mocap body, so an episode can move it (a hole-pose error) without recompiling.

What to build is envs.cell.scene_config.SceneConfig, with the goal geometry (the goal peg_tip pose inside the hole,
by default the paper's).

The robot stands on the floor (z = 0); the sorter (blind holes, see envs.cell.sorter) stands on a table whose
height follows from the goal. Cameras: ``CAMERAS``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Mapping

import mujoco
import numpy as np
import numpy.typing as npt
from dm_control import mjcf

import assets
from envs.cell.contact import ContactConfig
from envs.cell.hole import HoleSpec
from envs.cell.pads import make_pads_compliant, pad_patch_m
from envs.cell.peg import build_peg
from envs.cell.scene_config import SceneConfig, goal_from_hole, hole_from_goal
from envs.cell.shapes import PEG_LENGTH_M, SHAPES, check_shape, grip_half_width_m, hole_inradius_m
from envs.cell.sorter import SorterLayout, build_sorter, sorter_layout, symmetry_order
from envs.errors import EnvError
from envs.geometry import FloatArray, look_at_xyaxes
from numerics.quaternion import mat_to_quat, quat_to_mat
from numerics.small_linalg import matmul, matvec, norm

FINGER_JOINTS: tuple[str, ...] = ("finger_joint1", "finger_joint2")
TABLE_MARGIN_M: float = 0.05
MIN_TABLE_HEIGHT_M: float = 0.02
ROBOT_KEEP_OUT_RADIUS_M: float = 0.15
"""The table must stay this far (horizontally) from the robot base axis."""
ARM_JOINTS: tuple[str, ...] = tuple(f"joint{i}" for i in range(1, 8))
ARM_ACTUATORS: tuple[str, ...] = tuple(f"actuator{i}" for i in range(1, 8))
CAMERAS: tuple[str, ...] = ("front", "side", "top", "closeup", "wrist", "cutaway")
"""The named cameras; "cutaway" looks at the goal hole from the side at its depth, and the renderer draws the sorter
translucent from it (envs.media.video), so that the peg is seen inside the hole: seated, or jammed on the chamfer."""


def nominal_flange_to_peg_tip(shape: str) -> tuple[FloatArray, FloatArray]:
    """The nominal grasp: pose of the peg_tip frame in the flange frame, T_F^P = T_F^H T_H^M Tz(L).

    T_F^H is the hand on the flange and T_H^M the ``peg_mount`` site in the hand (both from panda.xml), L the
    peg length: the peg's top face sits at peg_mount with its axis along the hand z axis. The skill commands
    the hand through this transform and never reads the true grasp (which a grasp offset perturbs).

    Returns:
        (position m (3,), quaternion w, x, y, z (4,)).

    Raises:
        EnvError: for an unknown shape, or a panda.xml without the flange / peg_mount sites.
    """
    check_shape(shape)
    try:
        model = mujoco.MjModel.from_xml_path(str(assets.PANDA_XML))
    except ValueError as error:
        raise EnvError(f"cannot read the Panda MJCF {assets.PANDA_XML}: {error}") from error
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, name) for name in ("flange", "peg_mount")]
    if min(ids) < 0:
        raise EnvError(f"{assets.PANDA_XML} lacks the flange or peg_mount site")
    rot_flange, rot_mount = (data.site_xmat[i].reshape(3, 3) for i in ids)
    rot = matmul(rot_flange.T, rot_mount)
    pos = matvec(rot_flange.T, data.site_xpos[ids[1]] - data.site_xpos[ids[0]]) + rot[:, 2] * PEG_LENGTH_M
    return pos, mat_to_quat(rot)


@dataclass(frozen=True)
class SceneIds:
    """MuJoCo ids and addresses of what the controllers, episodes and tests use.

    ``sorter_geoms`` are the sorter's colliding geoms (its visual-only skin is left out); ``peg_qpos_adr``
    and ``peg_dof_adr`` address the peg's free joint (None when welded); ``finger_*_adr`` the finger joints
    (empty when welded); ``wrist_*_adr`` the F/T sensor's entries in sensordata; ``hand_subtree`` the bodies
    the F/T sensor carries (hand, fingers and compliant pads); ``sorter_mocap`` the sorter's mocap index;
    ``home_key`` the Panda's "home" keyframe (None if panda.xml has none).
    """

    flange_site: int
    peg_mount_site: int
    tcp_site: int
    peg_tip_site: int
    ft_site: int
    wrist_force_adr: int
    wrist_torque_adr: int
    hand_subtree: tuple[int, ...]
    finger_geoms: tuple[int, ...]
    finger_qpos_adr: tuple[int, ...]
    finger_dof_adr: tuple[int, ...]
    sorter_mocap: int
    hole_sites: Mapping[str, int]
    hand_body: int
    peg_body: int
    peg_geoms: tuple[int, ...]
    sorter_body: int
    sorter_geoms: tuple[int, ...]
    arm_joints: tuple[int, ...]
    arm_qpos_adr: tuple[int, ...]
    arm_dof_adr: tuple[int, ...]
    actuators: tuple[int, ...]
    peg_qpos_adr: int | None
    peg_dof_adr: int | None
    home_key: int | None


@dataclass(frozen=True, eq=False)
class Scene:
    """A compiled scene and where things are in it.

    Attributes:
        model: the compiled MuJoCo model (treat as read-only).
        config: what was built.
        ids: ids and addresses.
        layout: the sorter geometry in the sorter frame.
        sorter_pos, sorter_quat: pose of the sorter frame (bottom-face centre) in the world.
        build_time_s: wall-clock time build_scene took.
        arm_model: the arm alone (7 joints, finger joints removed, the same ``tcp`` site), for inverse
            kinematics: its qpos are the scene's arm joints.
    """

    model: mujoco.MjModel
    config: SceneConfig
    ids: SceneIds
    layout: SorterLayout
    sorter_pos: FloatArray
    sorter_quat: FloatArray
    build_time_s: float
    mjcf_xml: str = field(repr=False)
    arm_model: mujoco.MjModel = field(repr=False, default=None)  # type: ignore[assignment]

    def hole_pose(self, shape: str) -> tuple[FloatArray, FloatArray]:
        """World pose (position m, quaternion w, x, y, z) of site ``hole_<shape>``.

        Raises:
            EnvError: for an unknown shape.
        """
        check_shape(shape)
        rot_sorter = quat_to_mat(self.sorter_quat)
        return self.sorter_pos + matvec(rot_sorter, self.layout.hole_position(shape)), self.sorter_quat.copy()

    def goal_pose(self) -> tuple[FloatArray, FloatArray]:
        """Goal peg_tip pose (position m, quaternion w, x, y, z) in the hole of ``config.shape``."""
        return goal_from_hole(*self.hole_pose(self.config.shape), self.config.insertion_depth_m)

    def hole_spec(self, shape: str) -> HoleSpec:
        """Everything the success scorer needs about the hole of ``shape``."""
        pos, quat = self.hole_pose(shape)
        return HoleSpec(
            shape=shape,
            pos=tuple(float(v) for v in pos),
            quat=tuple(float(v) for v in quat),
            symmetry_order=symmetry_order(shape),
            inradius_m=hole_inradius_m(shape, self.config.clearance_m),
            depth_m=self.config.hole_depth_m,
            clearance_m=self.config.clearance_m,
            polygon=tuple((float(x), float(y)) for x, y in self.layout.hole_polygons[shape]),
            chamfer_m=self.config.chamfer_m,
        )

    def hole_specs(self) -> Mapping[str, HoleSpec]:
        """``hole_spec`` of every hole."""
        return MappingProxyType({shape: self.hole_spec(shape) for shape in SHAPES})

    def xml(self) -> str:
        """The composed MJCF (for debugging; meshes are inline)."""
        return self.mjcf_xml


def _sorter_placement(config: SceneConfig, layout: SorterLayout) -> tuple[FloatArray, FloatArray]:
    """Sorter frame pose making hole ``config.shape`` the goal's hole: R_s = R_h, p_s = p_h - R_h p_hole_in_sorter."""
    goal_rot = config.goal_rotation()
    hole_pos, hole_quat = hole_from_goal(config.goal_position(), mat_to_quat(goal_rot), config.insertion_depth_m)
    rot = quat_to_mat(hole_quat)
    return hole_pos - matvec(rot, layout.hole_position(config.shape)), hole_quat


def _add_environment(root: mjcf.RootElement, layout: SorterLayout, sorter_pos: FloatArray, sorter_quat: FloatArray,
                     contact: ContactConfig) -> None:
    """Floor, table under the sorter, lights, skybox and offscreen buffer size."""
    root.asset.add("texture", name="skybox", type="skybox", builtin="gradient", rgb1=[0.55, 0.7, 0.85],
                   rgb2=[0.1, 0.12, 0.15], width=256, height=256)
    root.asset.add("texture", name="floor_grid", type="2d", builtin="checker", rgb1=[0.32, 0.34, 0.36],
                   rgb2=[0.26, 0.28, 0.30], width=256, height=256, mark="edge", markrgb=[0.4, 0.42, 0.44])
    root.asset.add("material", name="floor", texture="floor_grid", texrepeat=[8, 8], reflectance=0.05)
    root.worldbody.add("geom", name="floor", type="plane", size=[2.0, 2.0, 0.05], material="floor",
                       **contact.geom_attributes())
    rot = quat_to_mat(sorter_quat)
    table_height = float(sorter_pos[2])
    size_x, size_y = layout.size_xy_m
    half = np.array([size_x / 2.0 + TABLE_MARGIN_M, size_y / 2.0 + TABLE_MARGIN_M])
    if table_height < MIN_TABLE_HEIGHT_M:
        raise EnvError(
            f"goal height puts the sorter bottom at z={table_height:.3f} m, below the minimum table height "
            f"{MIN_TABLE_HEIGHT_M} m"
        )
    yaw = float(np.arctan2(rot[1, 0], rot[0, 0]))
    base_in_table = matvec(np.array([[np.cos(yaw), np.sin(yaw)], [-np.sin(yaw), np.cos(yaw)]]), -sorter_pos[:2])
    if norm(base_in_table - np.clip(base_in_table, -half, half)) < ROBOT_KEEP_OUT_RADIUS_M:
        raise EnvError(
            f"the sorter table at {np.round(sorter_pos[:2], 3).tolist()} m comes within "
            f"{ROBOT_KEEP_OUT_RADIUS_M} m of the robot base"
        )
    root.worldbody.add("geom", name="table", type="box", size=[half[0], half[1], table_height / 2.0],
                       pos=[sorter_pos[0], sorter_pos[1], table_height / 2.0],
                       quat=[np.cos(yaw / 2.0), 0.0, 0.0, np.sin(yaw / 2.0)], rgba=[0.45, 0.33, 0.22, 1.0],
                       **contact.geom_attributes())
    root.worldbody.add("light", name="key", pos=[0.4, -0.6, 2.0], dir=[-0.1, 0.3, -1.0], directional=True,
                       diffuse=[0.7, 0.7, 0.7], castshadow=True)
    root.worldbody.add("light", name="fill", pos=[1.5, 1.0, 1.5], dir=[-1.0, -0.6, -0.8], directional=True,
                       diffuse=[0.3, 0.3, 0.3], castshadow=False)
    offscreen = getattr(root.visual, "global")
    offscreen.offwidth, offscreen.offheight = 1920, 1080


def _add_cameras(root: mjcf.RootElement, goal_pos: FloatArray) -> None:
    """Named cameras: front, side and closeup look at the goal hole, top looks down on robot and sorter,
    wrist rides on the hand looking down the peg, cutaway looks at the hole from the side at its depth (the renderer
    draws the sorter translucent from it)."""
    gx, gy, gz = goal_pos
    world_views = {  # name: (position, target, up hint)
        "front": ([gx + 0.75, gy + 0.35, gz + 0.45], [gx - 0.25, gy, gz + 0.15], [0, 0, 1]),
        "side": ([gx - 0.2, gy - 1.15, gz + 0.35], [gx - 0.2, gy, gz + 0.15], [0, 0, 1]),
        "top": ([0.55 * gx, gy, gz + 1.4], [0.55 * gx, gy, 0.0], [1, 0, 0]),
        "closeup": ([gx + 0.16, gy - 0.16, gz + 0.12], [gx, gy, gz + 0.03], [0, 0, 1]),
        "cutaway": ([gx + 0.09, gy - 0.12, gz + 0.06], [gx, gy, gz + 0.02], [0, 0, 1]),
    }
    for name, (pos, target, up) in world_views.items():
        root.worldbody.add("camera", name=name, pos=pos, xyaxes=look_at_xyaxes(pos, target, up), fovy=45)
    hand, mount = _find(root, "body", "hand"), _find(root, "site", "peg_mount")
    wrist_pos = [0.09, 0.0, 0.03]
    wrist_target = np.asarray(mount.pos, dtype=np.float64) + [0.0, 0.0, PEG_LENGTH_M + 0.03]  # past the peg_tip
    hand.add("camera", name="wrist", pos=wrist_pos, xyaxes=look_at_xyaxes(wrist_pos, wrist_target, [-1, 0, 0]),
             fovy=60)


def _find(root: mjcf.RootElement, kind: str, name: str) -> mjcf.Element:
    element = root.find(kind, name)
    if element is None:
        raise EnvError(f"{assets.PANDA_XML} has no {kind} named {name!r}, which the scene needs")
    return element


def _attach_peg(
    root: mjcf.RootElement, config: SceneConfig, hole_pos: FloatArray, goal_rot: FloatArray
) -> mjcf.Element:
    """Attach the peg: between the fingers as a free body (grasped), rigidly at peg_mount (welded), or on a
    free joint above its hole (free). Adds the hand's ``tcp`` site and the wrist F/T sensor.

    Returns:
        The attachment frame (the peg's body).
    """
    peg = build_peg(config.shape, config.contact)
    mount = _find(root, "site", "peg_mount")
    hand = _find(root, "body", "hand")
    hand.add("site", name="tcp", pos=np.asarray(mount.pos, dtype=np.float64) + [0.0, 0.0, PEG_LENGTH_M],
             size=[0.003], rgba=[0, 1, 1, 1], group=4)
    hand.add("site", name="ft_sensor", pos=[0.0, 0.0, 0.0], size=[0.004], rgba=[1, 0.5, 0, 1], group=4)
    root.sensor.add("force", name="wrist_force", site="ft_sensor")
    root.sensor.add("torque", name="wrist_torque", site="ft_sensor")
    fingers = [(_find(root, "body", name), _find(root, "geom", f"{name}_pad"), sign)
               for name, sign in (("left_finger", 1.0), ("right_finger", -1.0))]
    if config.peg_mode == "welded":
        frame = mount.attach(peg)
        for finger, pad, sign in fingers:
            for joint in finger.find_all("joint", exclude_attachments=True):
                joint.remove()
            finger.pos = [finger.pos[0], sign * grip_half_width_m(config.shape, float(pad.size[0])), finger.pos[2]]
            root.contact.add("exclude", body1=finger, body2=frame)
        return frame
    frame = root.worldbody.attach(peg)
    frame.add("freejoint")
    if _has_pad_hinges(config):
        _, _, centre_z = pad_patch_m(fingers[0][1].size, float(fingers[0][1].pos[2]), float(fingers[0][0].pos[2]),
                                     float(mount.pos[2]), PEG_LENGTH_M)
        make_pads_compliant(fingers, config.pad_stiffness_nm_rad, centre_z, float(root.option.timestep))
        fingers = [(finger, _find(root, "geom", f"{finger.name}_pad"), sign) for finger, _, sign in fingers]
    for _, pad, _ in fingers:  # rubber pads with the scene's stiff contact (soft defaults let a 70 N grasp sink)
        pad.solref, pad.solimp = list(config.contact.solref), list(config.contact.solimp)
        pad.priority = 1  # a peg-pad contact takes the pad's friction (envs.sim.friction), as max-mixing did
    # The Franka hand's fingers are mechanically coupled: they open and close symmetrically about the hand axis.
    root.equality.add("joint", name="finger_coupling", joint1="finger_joint1", joint2="finger_joint2",
                      solref=[0.005, 1.0])
    if config.peg_mode == "grasped":  # placed at the nominal grasp of the home keyframe after compiling
        return frame
    tip = hole_pos + config.free_peg_height_m * (-goal_rot[:, 2])
    frame.pos = tip - PEG_LENGTH_M * goal_rot[:, 2]
    frame.quat = mat_to_quat(goal_rot)
    return frame


def _keyframe_qpos(root: mjcf.RootElement, config: SceneConfig, arm_qpos: npt.ArrayLike,
                   peg_qpos: FloatArray) -> FloatArray:
    """Keyframe qpos of the composed scene: arm, fingers (grasped/free; at the peg's sides or open), peg."""
    arm = np.asarray(arm_qpos, dtype=np.float64)[: len(ARM_JOINTS)]
    if config.peg_mode == "welded":
        return arm
    pad = float(_find(root, "geom", "left_finger_pad").size[0])
    opening = grip_half_width_m(config.shape, pad) if config.peg_mode == "grasped" else 0.04
    if _has_pad_hinges(config):  # each finger's joint, then its pad's hinge (kinematic tree order)
        return np.concatenate([arm, [opening, 0.0, opening, 0.0], peg_qpos])
    return np.concatenate([arm, [opening, opening], peg_qpos])


def _has_pad_hinges(config: SceneConfig) -> bool:
    """Whether the scene's finger pads are on torsion hinges (envs.cell.pads): a grasped peg and compliant pads."""
    return config.peg_mode == "grasped" and config.pad_stiffness_nm_rad > 0.0


def _scene_ids(model: mujoco.MjModel, peg_mode: str) -> SceneIds:
    def named(kind: mujoco.mjtObj, name: str) -> int:
        index = mujoco.mj_name2id(model, kind, name)
        if index < 0:
            raise EnvError(f"the composed scene has no {kind.name[6:].lower()} named {name!r}")
        return index

    body = mujoco.mjtObj.mjOBJ_BODY
    peg_body = named(body, "peg/")
    sorter_body = named(body, "sorter/")
    hand_body = named(body, "hand")
    joints = tuple(named(mujoco.mjtObj.mjOBJ_JOINT, name) for name in ARM_JOINTS)
    fingers = () if peg_mode == "welded" else tuple(named(mujoco.mjtObj.mjOBJ_JOINT, n) for n in FINGER_JOINTS)
    free = int(model.body_jntadr[peg_body]) if peg_mode != "welded" else -1
    key = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, "home")
    finger_bodies = (named(body, "left_finger"), named(body, "right_finger"))
    pad_bodies = tuple(b for b in (mujoco.mj_name2id(model, body, f"{name}_pad_body")
                                   for name in ("left_finger", "right_finger")) if b >= 0)
    finger_bodies = finger_bodies + pad_bodies  # compliant pads (envs.cell.pads) carry the pad geoms
    sensor = mujoco.mjtObj.mjOBJ_SENSOR
    return SceneIds(
        flange_site=named(mujoco.mjtObj.mjOBJ_SITE, "flange"),
        peg_mount_site=named(mujoco.mjtObj.mjOBJ_SITE, "peg_mount"),
        tcp_site=named(mujoco.mjtObj.mjOBJ_SITE, "tcp"),
        peg_tip_site=named(mujoco.mjtObj.mjOBJ_SITE, "peg/peg_tip"),
        ft_site=named(mujoco.mjtObj.mjOBJ_SITE, "ft_sensor"),
        wrist_force_adr=int(model.sensor_adr[named(sensor, "wrist_force")]),
        wrist_torque_adr=int(model.sensor_adr[named(sensor, "wrist_torque")]),
        hand_subtree=(hand_body, *finger_bodies),
        finger_geoms=tuple(int(g) for g in np.flatnonzero(np.isin(model.geom_bodyid, finger_bodies))),
        finger_qpos_adr=tuple(int(model.jnt_qposadr[j]) for j in fingers),
        finger_dof_adr=tuple(int(model.jnt_dofadr[j]) for j in fingers),
        sorter_mocap=int(model.body_mocapid[sorter_body]),
        hole_sites=MappingProxyType({s: named(mujoco.mjtObj.mjOBJ_SITE, f"sorter/hole_{s}") for s in SHAPES}),
        hand_body=hand_body,
        peg_body=peg_body,
        peg_geoms=tuple(int(g) for g in np.flatnonzero(model.geom_bodyid == peg_body)),
        sorter_body=sorter_body,
        sorter_geoms=tuple(
            int(g)
            for g in np.flatnonzero(model.geom_bodyid == sorter_body)
            if model.geom_contype[g] or model.geom_conaffinity[g]
        ),
        arm_joints=joints,
        arm_qpos_adr=tuple(int(model.jnt_qposadr[j]) for j in joints),
        arm_dof_adr=tuple(int(model.jnt_dofadr[j]) for j in joints),
        actuators=tuple(named(mujoco.mjtObj.mjOBJ_ACTUATOR, name) for name in ARM_ACTUATORS),
        peg_qpos_adr=int(model.jnt_qposadr[free]) if free >= 0 else None,
        peg_dof_adr=int(model.jnt_dofadr[free]) if free >= 0 else None,
        home_key=key if key >= 0 else None,
    )


def _place_grasped_peg(model: mujoco.MjModel, ids: SceneIds) -> None:
    """Put the grasped peg at the nominal grasp of every keyframe and of qpos0: its peg_tip on ``tcp``."""
    data = mujoco.MjData(model)
    tip_in_peg = model.site_pos[ids.peg_tip_site]  # peg frame axes = tcp axes; the tip is at (0, 0, L)
    adr = ids.peg_qpos_adr
    for key in range(model.nkey):
        data.qpos[:] = model.key_qpos[key]
        mujoco.mj_kinematics(model, data)
        rot = data.site_xmat[ids.tcp_site].reshape(3, 3)
        model.key_qpos[key, adr:adr + 3] = data.site_xpos[ids.tcp_site] - matvec(rot, tip_in_peg)
        model.key_qpos[key, adr + 3:adr + 7] = mat_to_quat(rot)
    if ids.home_key is not None:  # only the free joint: hinge and slide joints measure from their qpos0
        model.qpos0[adr:adr + 7] = model.key_qpos[ids.home_key, adr:adr + 7]


def build_arm_model() -> mujoco.MjModel:
    """The Panda alone with the ``tcp`` site (as in every scene) and jointless fingers: nq = 7, for IK.

    Raises:
        EnvError: if panda.xml cannot be read or lacks the hand or peg_mount.
    """
    try:
        root = mjcf.from_path(str(assets.PANDA_XML))
    except (OSError, ValueError) as error:
        raise EnvError(f"cannot read the Panda MJCF {assets.PANDA_XML}: {error}") from error
    mount = _find(root, "site", "peg_mount")
    _find(root, "body", "hand").add("site", name="tcp", size=[0.003],
                                    pos=np.asarray(mount.pos, dtype=np.float64) + [0.0, 0.0, PEG_LENGTH_M])
    for name in ("left_finger", "right_finger"):
        for joint in _find(root, "body", name).find_all("joint", exclude_attachments=True):
            joint.remove()
    for key in root.keyframe.key:
        key.qpos = np.asarray(key.qpos, dtype=np.float64)[: len(ARM_JOINTS)]
    return mujoco.MjModel.from_xml_string(root.to_xml_string(), root.get_assets())


def build_scene(config: SceneConfig = SceneConfig()) -> Scene:
    """Compose and compile the scene described by ``config`` (well under a second).

    Raises:
        EnvError: if the Panda MJCF lacks a body/site the scene needs, the goal puts the sorter below the
            floor or onto the robot base, or MuJoCo rejects the composed model.
    """
    start = time.perf_counter()
    layout = sorter_layout(config.clearance_m, config.hole_depth_m, config.chamfer_m)
    sorter_pos, sorter_quat = _sorter_placement(config, layout)
    try:
        root = mjcf.from_path(str(assets.PANDA_XML))
    except (OSError, ValueError) as error:
        raise EnvError(f"cannot read the Panda MJCF {assets.PANDA_XML}: {error}") from error
    config.contact.apply_options(root)
    _add_environment(root, layout, sorter_pos, sorter_quat, config.contact)
    frame = root.worldbody.attach(build_sorter(layout, config.contact))
    frame.pos, frame.quat = sorter_pos, sorter_quat
    frame.mocap = True
    goal_rot = config.goal_rotation()
    hole_pos = sorter_pos + matvec(quat_to_mat(sorter_quat), layout.hole_position(config.shape))
    peg_frame = _attach_peg(root, config, hole_pos, goal_rot)
    _add_cameras(root, config.goal_position())
    peg_qpos = np.concatenate([np.asarray(peg_frame.pos if peg_frame.pos is not None else np.zeros(3), dtype=float),
                               np.asarray(peg_frame.quat if peg_frame.quat is not None else [1, 0, 0, 0], dtype=float)])
    for key in root.keyframe.key:
        key.qpos = _keyframe_qpos(root, config, key.qpos, peg_qpos)
    xml = root.to_xml_string()
    try:
        model = mujoco.MjModel.from_xml_string(xml, root.get_assets())
    except ValueError as error:
        raise EnvError(f"MuJoCo rejected the composed scene: {error}") from error
    ids = _scene_ids(model, config.peg_mode)
    if config.peg_mode == "welded" and model.nq != len(ARM_JOINTS):
        raise EnvError(f"the welded-peg scene has nq={model.nq}, expected {len(ARM_JOINTS)} (arm joints only)")
    if config.peg_mode == "grasped":
        _place_grasped_peg(model, ids)
    return Scene(
        model=model,
        config=config,
        ids=ids,
        layout=layout,
        sorter_pos=sorter_pos,
        sorter_quat=sorter_quat,
        build_time_s=time.perf_counter() - start,
        mjcf_xml=xml,
        arm_model=build_arm_model(),
    )
