"""Success scoring of an insertion from the peg's actual pose and speed in the hole frame.

Hole frame H (site ``hole_<shape>``): origin at the centre of the top opening, z up out of the hole.
At the goal the peg_tip frame P is H turned by pi about x and lowered by the insertion depth, so with
R_rel = R_H^T R_P Rx(pi) (identity at the goal) and r = R_H^T (p_P - p_H):
    depth = -r_z,  lateral = sqrt(r_x^2 + r_y^2),  tilt = arccos(R_rel[2, 2]),
    yaw = atan2(R_rel[1,0] - R_rel[0,1], R_rel[0,0] + R_rel[1,1]) wrapped into (-180/k, 180/k] deg
for a hole with k-fold symmetry (yaw is 0 for a round hole).

Seated and inside the walls. The peg is a prism over its cross-section; the part of it inside the straight
hole (below the chamfer, z_H <= -c) is the convex hull of its tip-face vertices w_k = p_P + R_P [v_k; 0] and of
the points where its lateral edges w_k - t z_P cross the plane z_H = -c. By convexity it lies inside the hole
prism {n_i . x <= d_i} exactly when all those points do, so the wall penetration is
    pen = max_k,i (n_i . x_k - d_i)      (<= 0: the walls allow the state; > 0: only by penetrating them)
and for the round peg pen = max(|c_xy|) + r / cos(tilt) - r_hole over the axis points at the tip and at z_H = -c.
An insertion counts (``criteria_hold``) when the peg_tip is in the target hole, its depth is within
``seat_tolerance_m`` of the target depth, pen <= ``penetration_tolerance_m`` (MuJoCo's soft contacts penetrate
~1e-6 m under the forces here) and the peg moves slower than ``max_speed_m_s``; success needs that to hold
for ``hold_s``. Lateral offset, tilt and yaw are therefore bounded by what the walls allow, not by
thresholds of their own. The commanded pose is never consulted.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

import numpy as np
import numpy.typing as npt

from envs.errors import EnvError
from envs.geometry import R_FLIP_X, as_vector, edge_lines, twist_angle_deg
from envs.poses import rotate
from envs.shapes import CrossSection
from envs.success_kernel import NO_HOLE, NO_POLYGON, assess_tip
from envs.task import SuccessConfig  # the tolerances are part of the task
from rflow.quaternion import quat_to_mat
from rflow.small_linalg import matmul, matvec

FloatArray = npt.NDArray[np.float64]

MIN_ENTRY_DEPTH_M: float = 0.002
"""The peg_tip counts as inside a hole only this far below the opening: a peg lying on the top face
(e.g. a square peg over the triangle hole) sinks by its contact penetration only (~1e-5 m)."""
FLOOR_SLACK_M: float = 0.002
"""A peg_tip deeper than the hole floor by more than this has gone through the fixture: not in the hole."""


@dataclass(frozen=True)
class HoleSpec:
    """What the scorer needs to know about one hole.

    Attributes:
        shape: the hole's shape name.
        pos: position of the top-opening centre in the world (m).
        quat: orientation (w, x, y, z) of the hole frame, z up out of the hole.
        symmetry_order: k-fold rotational symmetry about the hole axis, 0 for round.
        inradius_m: radius of the largest axis-centred circle inside the hole.
        depth_m: depth of the (blind) hole.
        clearance_m: total clearance between the matching peg and the hole.
        polygon: the hole's counter-clockwise cross-section vertices in the hole frame (m).
        chamfer_m: width of the 45 deg chamfer at the mouth (the straight walls start at z_H = -chamfer).
    """

    shape: str
    pos: tuple[float, float, float]
    quat: tuple[float, float, float, float]
    symmetry_order: int
    inradius_m: float
    depth_m: float
    clearance_m: float
    polygon: tuple[tuple[float, float], ...] = ()
    chamfer_m: float = 0.0


@dataclass(frozen=True)
class InsertionState:
    """Pose of the peg_tip relative to one hole.

    Attributes:
        depth_m: how far the peg_tip is below the top opening along the hole axis (negative above).
        lateral_m: distance of the peg_tip from the hole axis.
        tilt_deg: angle between the peg axis and the hole axis (pointing into the hole).
        yaw_error_deg: rotation about the hole axis from the nearest symmetric goal heading.
        in_hole: the peg_tip is inside this hole: MIN_ENTRY_DEPTH_M < depth <= depth_m + FLOOR_SLACK_M
            and lateral <= inradius.
        wall_penetration_m: pen of the module docstring (NaN when not computed: no peg given or the
            peg_tip above the straight walls).
        speed_m_s: speed of the peg (NaN when not given).
    """

    depth_m: float
    lateral_m: float
    tilt_deg: float
    yaw_error_deg: float
    in_hole: bool
    wall_penetration_m: float = float("nan")
    speed_m_s: float = float("nan")


@dataclass(frozen=True)
class Assessment:
    """Scoring of one peg pose against the target hole.

    Attributes:
        hole: the shape of the hole the peg_tip is in (None: in no hole); differs from the target for a
            "wrong hole" insertion.
        state: the peg_tip relative to the target hole.
        inserted: all success criteria hold at this instant.
    """

    hole: str | None
    state: InsertionState
    inserted: bool


def wrap_symmetric_deg(angle_deg: float, symmetry_order: int) -> float:
    """Wrap an angle into (-180/k, 180/k] deg; 0 for a round shape (k = 0).

    Raises:
        EnvError: for a negative symmetry order.
    """
    if symmetry_order < 0:
        raise EnvError(f"symmetry_order={symmetry_order} must be >= 0")
    if symmetry_order == 0:
        return 0.0
    period = 360.0 / symmetry_order
    half = period / 2.0
    wrapped = (float(angle_deg) + half) % period - half  # Python's float % is numpy's mod (sign of the divisor)
    return half if abs(wrapped + half) <= 1e-8 + 1e-5 * half else wrapped  # np.isclose(wrapped, -half)


@dataclass(frozen=True)
class HoleFrame:
    """A hole with what scoring needs of it computed once (per episode, not per pose): its position p_H, its
    rotation R_H and the lines {n_i . x <= d_i} of its walls in the hole frame (empty without a polygon).

    Build it with `HoleFrame.of`.
    """

    spec: HoleSpec
    pos: FloatArray
    rot: FloatArray
    wall_normals: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    wall_offsets: FloatArray = field(default_factory=lambda: np.zeros(0))

    @classmethod
    def of(cls, hole: HoleSpec) -> "HoleFrame":
        """The frame of ``hole`` (its quaternion normalised, as `insertion_state` does)."""
        pos = np.asarray(hole.pos, dtype=np.float64).copy()
        if not hole.polygon:
            return cls(hole, pos, quat_to_mat(hole.quat))
        normals, offsets = edge_lines(np.asarray(hole.polygon, dtype=np.float64))
        return cls(hole, pos, quat_to_mat(hole.quat), normals, offsets)


@dataclass(frozen=True)
class PegFootprint:
    """A peg's cross-section with its tip-face vertices [v_k; 0] (k, 3) stacked once (prism pegs)."""

    section: CrossSection
    corners: FloatArray

    @classmethod
    def of(cls, peg: CrossSection) -> "PegFootprint":
        """The footprint of ``peg`` (no corners for a round peg)."""
        if peg.is_round:
            return cls(peg, np.zeros((0, 3)))
        return cls(peg, np.column_stack([peg.polygon, np.zeros(len(peg.polygon))]))


def insertion_state(peg_tip_pos: npt.ArrayLike, peg_tip_quat: npt.ArrayLike, hole: HoleSpec,
                    peg: CrossSection | None = None, speed_m_s: float = float("nan")) -> InsertionState:
    """The peg_tip pose relative to ``hole`` (equations in the module docstring).

    Args:
        peg_tip_pos: peg_tip position in the world (m).
        peg_tip_quat: peg_tip orientation (w, x, y, z), z along the peg axis away from the hand.
        hole: the hole.
        peg: the peg's cross-section, to compute the wall penetration (skipped when None).
        speed_m_s: the peg's speed, carried into the state.

    Raises:
        EnvError: if the pose is not 3 + 4 finite numbers or the quaternion is zero.
    """
    pos = as_vector(peg_tip_pos, 3, "peg_tip_pos")
    rot = quat_to_mat(as_vector(peg_tip_quat, 4, "peg_tip_quat"))
    return frame_state(pos, rot, HoleFrame.of(hole), None if peg is None else PegFootprint.of(peg), speed_m_s)


def _hole_offset(pos: FloatArray, frame: HoleFrame) -> FloatArray:
    """r = R_H^T (p_P - p_H): the peg_tip in the hole frame."""
    return matvec(frame.rot.T, pos - frame.pos)


def _inside(offset: FloatArray, hole: HoleSpec) -> tuple[float, float, bool]:
    """(depth, lateral, in_hole) of a peg_tip at ``offset`` in the hole frame (module docstring)."""
    depth = float(-offset[2])
    lateral = float(np.hypot(offset[0], offset[1]))
    return depth, lateral, MIN_ENTRY_DEPTH_M < depth <= hole.depth_m + FLOOR_SLACK_M and lateral <= hole.inradius_m


def frame_state(pos: FloatArray, rot: FloatArray, frame: HoleFrame, peg: PegFootprint | None = None,
                speed_m_s: float = float("nan")) -> InsertionState:
    """`insertion_state` of a checked peg_tip pose: position ``pos`` (3,) and rotation matrix ``rot`` (3, 3) in
    the world, against a precomputed hole frame (no validation: the caller's inputs are finite)."""
    hole = frame.spec
    rot_peg = matmul(frame.rot.T, rot)
    rot_rel = matmul(rot_peg, R_FLIP_X)
    offset = _hole_offset(pos, frame)
    depth, lateral, in_hole = _inside(offset, hole)
    tilt = float(np.rad2deg(np.arccos(min(max(float(rot_rel[2, 2]), -1.0), 1.0))))  # = np.clip, without its overhead
    yaw = wrap_symmetric_deg(twist_angle_deg(rot_rel), hole.symmetry_order)
    penetration = float("nan")
    if peg is not None and depth > hole.chamfer_m:
        penetration = _wall_penetration(offset, rot_peg, frame, peg)
    return InsertionState(depth, lateral, tilt, yaw, bool(in_hole), penetration, float(speed_m_s))


def wall_penetration_m(tip: npt.NDArray[np.float64], rot_peg: npt.NDArray[np.float64], hole: HoleSpec,
                       peg: CrossSection) -> float:
    """pen of the module docstring, for a peg_tip at ``tip`` with orientation ``rot_peg``, both in the hole
    frame, with the tip below the straight walls (tip_z < -chamfer).

    Raises:
        EnvError: if ``hole.polygon`` is empty (a HoleSpec without geometry).
    """
    return _wall_penetration(tip, rot_peg, HoleFrame.of(hole), PegFootprint.of(peg))


def _wall_penetration(tip: FloatArray, rot_peg: FloatArray, frame: HoleFrame, peg: PegFootprint) -> float:
    """`wall_penetration_m` with the hole's wall lines and the peg's corners precomputed."""
    hole, section = frame.spec, peg.section
    if not hole.polygon:
        raise EnvError(f"hole {hole.shape!r} has no polygon to check the walls against")
    up = -rot_peg[:, 2]  # along the peg from the tip toward the hand
    level = -hole.chamfer_m
    if up[2] <= 1e-9:  # the peg points up out of the hole: it cannot be inside
        return float("inf")
    if section.is_round:
        crossing = tip + up * (level - tip[2]) / up[2]
        cos_tilt = up[2]
        radial = max(float(np.hypot(*tip[:2])), float(np.hypot(*crossing[:2])))
        return radial + section.radius_m / cos_tilt - hole.inradius_m
    corners = tip + matmul(peg.corners, rot_peg.T)
    rise = np.maximum(level - corners[:, 2], 0.0) / up[2]
    points = np.vstack([corners, corners + rise[:, None] * up])[:, :2]
    return float(np.max(matmul(points, frame.wall_normals.T) - frame.wall_offsets))


def criteria_hold(state: InsertionState, target_depth_m: float, config: SuccessConfig) -> bool:
    """True when the peg is in the hole, seated (|depth - target| <= seat tolerance), inside the walls
    (penetration <= tolerance) and at rest (speed <= max speed); NaN penetration or speed fail."""
    return bool(
        state.in_hole
        and abs(state.depth_m - target_depth_m) <= config.seat_tolerance_m
        and state.wall_penetration_m <= config.penetration_tolerance_m
        and state.speed_m_s <= config.max_speed_m_s
    )


def assess_insertion(
    peg_tip_pos: npt.ArrayLike,
    peg_tip_quat: npt.ArrayLike,
    holes: Mapping[str, HoleSpec],
    target: str,
    target_depth_m: float,
    config: SuccessConfig,
    peg: CrossSection,
    speed_m_s: float,
) -> Assessment:
    """Which hole the peg_tip is in, its state in the target hole, and whether the criteria hold.

    Raises:
        EnvError: if ``target`` is not among ``holes`` or the pose is malformed.
    """
    if target not in holes:
        raise EnvError(f"target hole {target!r} is not among the holes {sorted(holes)}")
    pos = as_vector(peg_tip_pos, 3, "peg_tip_pos")
    rot = quat_to_mat(as_vector(peg_tip_quat, 4, "peg_tip_quat"))
    frames = {shape: HoleFrame.of(hole) for shape, hole in holes.items()}
    return frame_assessment(pos, rot, frames, target, target_depth_m, config, PegFootprint.of(peg), speed_m_s)


def frame_assessment(pos: FloatArray, rot: FloatArray, frames: Mapping[str, HoleFrame], target: str,
                     target_depth_m: float, config: SuccessConfig, peg: PegFootprint,
                     speed_m_s: float) -> Assessment:
    """`assess_insertion` of a checked peg_tip pose (``pos`` (3,), ``rot`` (3, 3), world) against precomputed
    hole frames that contain ``target`` (no validation)."""
    state = frame_state(pos, rot, frames[target], peg, speed_m_s)
    if state.in_hole:  # the target first: the other holes only matter when the peg_tip is not in it
        hole: str | None = target
    else:
        hole = next((shape for shape, frame in frames.items()
                     if shape != target and _inside(_hole_offset(pos, frame), frame.spec)[2]), None)
    inserted = hole == target and criteria_hold(state, target_depth_m, config)
    return Assessment(hole, state, inserted)


class EpisodeHoles:
    """The holes of one episode (where its perturbation put them) with their frames built once, and the scoring of a
    peg_tip against them (`assess`).

    Shortcut, exact: a peg_tip is in a hole only deeper than MIN_ENTRY_DEPTH_M below its opening, so while it is
    above every opening (depth_h = -(p - p_h) . z_h <= MIN_ENTRY_DEPTH_M for all holes h) only the target hole's
    state is computed, and otherwise only the holes it is below the opening of.
    """

    def __init__(self, holes: Mapping[str, HoleSpec], target: str, target_depth_m: float, config: SuccessConfig,
                 peg: PegFootprint) -> None:
        """Args:
            holes: every hole of the fixture, by shape; ``target`` among them.
            target, target_depth_m, config, peg: as in `frame_assessment`.

        Raises:
            EnvError: a target that is not among the holes.
        """
        if target not in holes:
            raise EnvError(f"target hole {target!r} is not among the holes {sorted(holes)}")
        for spec in holes.values():
            if spec.symmetry_order < 0:
                raise EnvError(f"hole {spec.shape!r}: symmetry_order={spec.symmetry_order} must be >= 0")
        self.target, self.target_depth_m, self.config, self.peg = target, target_depth_m, config, peg
        self.frames = {shape: HoleFrame.of(spec) for shape, spec in holes.items()}
        self._shapes = list(holes)
        frames = list(self.frames.values())
        walls = np.cumsum([0] + [len(f.wall_offsets) for f in frames])
        section = peg.section
        self._arguments = (  # assess_tip's arguments after the pose (envs.success_kernel)
            np.array([f.pos for f in frames]), np.array([f.rot for f in frames]),
            np.array([rotate(spec.quat, [0.0, 0.0, 1.0]) for spec in holes.values()]),  # out of the holes
            np.array([spec.depth_m for spec in holes.values()], dtype=np.float64),
            np.array([spec.inradius_m for spec in holes.values()], dtype=np.float64),
            np.array([spec.chamfer_m for spec in holes.values()], dtype=np.float64),
            np.array([spec.symmetry_order for spec in holes.values()], dtype=np.int64), walls.astype(np.int64),
            np.concatenate([f.wall_normals.reshape(-1, 2) for f in frames]),
            np.concatenate([f.wall_offsets.reshape(-1) for f in frames]), self._shapes.index(target),
            np.ascontiguousarray(peg.corners, dtype=np.float64).reshape(-1, 3), bool(section.is_round),
            float(section.radius_m), np.ascontiguousarray(R_FLIP_X, dtype=np.float64), MIN_ENTRY_DEPTH_M,
            FLOOR_SLACK_M, float(target_depth_m), config.seat_tolerance_m, config.penetration_tolerance_m,
            config.max_speed_m_s)

    def assess(self, pos: FloatArray, rot: FloatArray, speed_m_s: float) -> Assessment:
        """`assess_insertion` of a checked peg_tip position (3,) and rotation matrix (3, 3) (class docstring), in one
        compiled call (`envs.success_kernel.assess_tip`: the arithmetic of `frame_assessment`, bit for bit).

        Raises:
            EnvError: the peg_tip is below the target's chamfer and the target hole has no polygon.
        """
        hole, depth, lateral, tilt, yaw, in_hole, penetration, inserted = assess_tip(
            pos, rot, *self._arguments, float(speed_m_s))
        if hole == NO_POLYGON:
            raise EnvError(f"hole {self.target!r} has no polygon to check the walls against")
        state = InsertionState(depth, lateral, tilt, yaw, in_hole, penetration, float(speed_m_s))
        return Assessment(None if hole == NO_HOLE else self._shapes[hole], state, inserted)


class SuccessTracker:
    """Declares success once the criteria have held without interruption for ``hold_s`` of physics time.

    Success latches: once reached it stays reached until ``reset``.
    """

    def __init__(self, config: SuccessConfig = SuccessConfig()) -> None:
        self.config = config
        self.reset()

    def reset(self) -> None:
        """Forget the history (a new episode)."""
        self._since_s: float | None = None
        self._last_time_s: float | None = None
        self.success_time_s: float | None = None

    @property
    def succeeded(self) -> bool:
        """True once the criteria have held for hold_s."""
        return self.success_time_s is not None

    def update(self, time_s: float, inserted: bool) -> bool:
        """Record whether the criteria hold at physics time ``time_s``; return ``succeeded``.

        Raises:
            EnvError: if time runs backwards (call ``reset`` between episodes).
        """
        if self._last_time_s is not None and time_s < self._last_time_s:
            raise EnvError(f"time_s={time_s} is earlier than the last update {self._last_time_s}; reset first")
        self._last_time_s = time_s
        if self.succeeded:
            return True
        if not inserted:
            self._since_s = None
            return False
        if self._since_s is None:
            self._since_s = time_s
        if time_s - self._since_s >= self.config.hold_s - 1e-9:
            self.success_time_s = time_s
        return self.succeeded
