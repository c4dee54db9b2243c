"""What scene to build (`SceneConfig`: shape, clearance, chamfer, depths, goal, peg mode, grasp force, contact) and the
goal geometry it is defined by, without MuJoCo: envs.cell.scene composes the model from it.

Goal: the peg_tip pose with the peg inserted ``insertion_depth_m`` into the hole of ``config.shape``:
    p_goal = p_hole - insertion_depth * z_hole,  R_goal = R_hole Rx(pi)   (peg_tip z points down the hole).
By default the goal is the paper's g_p with the heading of g_q, the peg vertical (``goal_pose_from_paper``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import numpy.typing as npt

from envs.cell.contact import ContactConfig
from envs.cell.pads import check_pad_stiffness
from envs.cell.peg import FRANKA_GRASP_FORCE_N, PEG_MODES, check_grasp_force
from envs.cell.shapes import check_shape
from envs.cell.sorter import check_chamfer, check_clearance, check_hole_depth
from envs.errors import EnvError
from envs.geometry import (
    R_FLIP_X,
    FloatArray,
    as_vector,
    normalize_quat,
    tilt_from_down_deg,
    z_down_rotation,
    z_down_yaw_deg,
)
from numerics.quaternion import mat_to_quat, quat_to_mat
from numerics.small_linalg import matmul

PAPER_GOAL_POS_M: tuple[float, float, float] = (0.675, -0.051, 0.203)
"""g_p of the paper's peg-in-hole experiment, robot base frame."""
PAPER_GOAL_QUAT: tuple[float, float, float, float] = (0.022, 0.991, -0.125, 0.035)
"""g_q = 0.022 + [0.991, -0.125, 0.035] (w, x, y, z) of the paper; its z axis is 4.7 deg from vertical."""
PAPER_GOAL_YAW_DEG: float = z_down_yaw_deg(PAPER_GOAL_QUAT)
"""Heading of the z-down orientation nearest to g_q (about -14.4 deg)."""


MAX_GOAL_TILT_DEG: float = 5.0


def goal_pose_from_paper(
    pos: Sequence[float] = PAPER_GOAL_POS_M, quat: Sequence[float] = PAPER_GOAL_QUAT
) -> tuple[FloatArray, FloatArray]:
    """The paper's goal made exactly vertical: position kept, orientation = nearest z-down orientation.

    R = Rz(psi) Rx(pi) with psi = atan2(Q01 + Q10, Q00 - Q11) (``z_down_yaw_deg``).

    Returns:
        (position m, quaternion w, x, y, z).
    """
    yaw_deg = z_down_yaw_deg(quat)
    return as_vector(pos, 3, "goal pos"), mat_to_quat(z_down_rotation(yaw_deg))


def goal_from_hole(
    hole_pos: npt.ArrayLike, hole_quat: npt.ArrayLike, insertion_depth_m: float
) -> tuple[FloatArray, FloatArray]:
    """Goal peg_tip pose inside a hole: p = p_hole - depth z_hole, R = R_hole Rx(pi)."""
    rot_hole = quat_to_mat(hole_quat)
    pos = np.asarray(hole_pos, dtype=np.float64) - insertion_depth_m * rot_hole[:, 2]
    return pos, mat_to_quat(matmul(rot_hole, R_FLIP_X))


def hole_from_goal(
    goal_pos: npt.ArrayLike, goal_quat: npt.ArrayLike, insertion_depth_m: float
) -> tuple[FloatArray, FloatArray]:
    """Inverse of ``goal_from_hole``: R_hole = R_goal Rx(pi), p_hole = p_goal + depth z_hole."""
    rot_hole = matmul(quat_to_mat(goal_quat), R_FLIP_X)
    pos = np.asarray(goal_pos, dtype=np.float64) + insertion_depth_m * rot_hole[:, 2]
    return pos, mat_to_quat(rot_hole)


NUMBER_FIELDS: tuple[str, ...] = ("clearance_m", "chamfer_m", "hole_depth_m", "insertion_depth_m", "goal_yaw_deg",
                                  "grasp_force_n", "pad_stiffness_nm_rad", "free_peg_height_m")
"""The SceneConfig fields that are plain numbers (checked to be numbers before their ranges)."""


@dataclass(frozen=True)
class SceneConfig:
    """What to build (defaults: the paper's goal, square peg grasped by the hand, 1 mm clearance, no chamfer).

    Attributes:
        shape: the peg's shape and the target hole (the others are on the sorter too).
        clearance_m: total hole-minus-peg clearance, in [0.1 mm, 5 mm].
        chamfer_m: width of the 45 deg chamfer at every hole mouth, in [0, 3 mm] (0: sharp edges).
        hole_depth_m: depth of the blind holes, in [30, 200] mm.
        insertion_depth_m: how deep the goal peg_tip is below the hole opening, in (0, hole_depth_m].
        goal_pos: goal peg_tip position (m, robot base frame); the sorter is placed to match it.
        goal_yaw_deg: heading of the goal peg_tip x axis; the peg axis is vertical, z down.
        peg_mode: "grasped" (a free body held by the fingers), "welded" (rigidly in the hand, nq = 7) or
            "free" (free joint above its hole).
        grasp_force_n: force closing each finger on a grasped peg (N), in (0, 140].
        pad_stiffness_nm_rad: torsional stiffness of each finger pad about the closing axis (N m/rad) for a
            grasped peg: the pad is a rubber layer that lets the held peg turn (envs.cell.pads); 0: rigid pads.
        hole_at_goal: optional (pos, quat) goal peg_tip pose that overrides goal_pos/goal_yaw_deg; its z
            axis must point down within 5 deg, and the sorter is tilted to match it exactly.
        free_peg_height_m: free mode: height of the peg_tip above its hole's opening at qpos0.
        contact: contact parameters of the peg, sorter and table.

    Raises:
        EnvError: on any invalid field (one line naming it).
    """

    shape: str = "square"
    clearance_m: float = 0.001
    chamfer_m: float = 0.0
    hole_depth_m: float = 0.04
    insertion_depth_m: float = 0.03
    goal_pos: tuple[float, float, float] = PAPER_GOAL_POS_M
    goal_yaw_deg: float = PAPER_GOAL_YAW_DEG
    peg_mode: str = "grasped"
    grasp_force_n: float = FRANKA_GRASP_FORCE_N
    pad_stiffness_nm_rad: float = 0.0
    hole_at_goal: tuple[Sequence[float], Sequence[float]] | None = None
    free_peg_height_m: float = 0.05
    contact: ContactConfig = field(default_factory=ContactConfig)

    def __post_init__(self) -> None:
        for name in NUMBER_FIELDS:  # a scene read from a file may hold anything: one line naming the field
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
                raise EnvError(f"scene {name}={value!r} must be a number")
        if not isinstance(self.shape, str) or not isinstance(self.peg_mode, str):
            raise EnvError(f"scene shape={self.shape!r} and peg_mode={self.peg_mode!r} must be strings")
        check_shape(self.shape)
        check_clearance(self.clearance_m)
        check_chamfer(self.chamfer_m)
        check_hole_depth(self.hole_depth_m)
        check_grasp_force(self.grasp_force_n)
        check_pad_stiffness(self.pad_stiffness_nm_rad)
        if not (np.isfinite(self.insertion_depth_m) and 0.0 < self.insertion_depth_m <= self.hole_depth_m):
            raise EnvError(
                f"insertion_depth_m={self.insertion_depth_m} must lie in (0, hole_depth_m={self.hole_depth_m}]"
            )
        object.__setattr__(self, "goal_pos", tuple(float(v) for v in as_vector(self.goal_pos, 3, "goal_pos")))
        if not np.isfinite(self.goal_yaw_deg):
            raise EnvError(f"goal_yaw_deg={self.goal_yaw_deg} must be finite")
        if self.peg_mode not in PEG_MODES:
            raise EnvError(f"peg_mode={self.peg_mode!r} must be one of {', '.join(PEG_MODES)}")
        if not (np.isfinite(self.free_peg_height_m) and self.free_peg_height_m >= 0.0):
            raise EnvError(f"free_peg_height_m={self.free_peg_height_m} must be >= 0")
        if not isinstance(self.contact, ContactConfig):
            raise EnvError(f"contact={self.contact!r} must be a ContactConfig")
        if self.hole_at_goal is not None:
            self.goal_rotation()
            pos, quat = self.hole_at_goal
            object.__setattr__(self, "hole_at_goal", (tuple(float(v) for v in pos), tuple(float(v) for v in quat)))

    def goal_rotation(self) -> FloatArray:
        """Rotation matrix of the goal peg_tip frame (from hole_at_goal if given).

        Raises:
            EnvError: if hole_at_goal is malformed or tilted more than 5 deg from z-down.
        """
        if self.hole_at_goal is None:
            return z_down_rotation(self.goal_yaw_deg)
        try:
            pos, quat = self.hole_at_goal
        except (TypeError, ValueError) as error:
            raise EnvError(f"hole_at_goal={self.hole_at_goal!r} must be a pair (pos, quat)") from error
        as_vector(pos, 3, "hole_at_goal pos")
        rot = quat_to_mat(normalize_quat(quat, "hole_at_goal quat"))
        tilt = tilt_from_down_deg(rot)
        if tilt > MAX_GOAL_TILT_DEG:
            raise EnvError(
                f"hole_at_goal quat={tuple(quat)} tilts the peg axis {tilt:.1f} deg from vertical (max "
                f"{MAX_GOAL_TILT_DEG:g} deg)"
            )
        return rot

    def goal_position(self) -> FloatArray:
        """Goal peg_tip position (from hole_at_goal if given)."""
        if self.hole_at_goal is None:
            return as_vector(self.goal_pos, 3, "goal_pos")
        return as_vector(self.hole_at_goal[0], 3, "hole_at_goal pos")
