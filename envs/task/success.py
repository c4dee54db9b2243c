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
An insertion counts when the peg_tip is in the target hole, its depth is within
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

from envs.cell.hole import HoleSpec
from envs.cell.shapes import CrossSection
from envs.errors import EnvError
from envs.geometry import R_FLIP_X, as_vector, edge_lines
from envs.poses import rotate
from envs.task.success_kernel import NO_HOLE, NO_POLYGON, assess_tip, wall_penetration, wrap_symmetric
from envs.task.task import SuccessConfig  # the tolerances are part of the task
from numerics.quaternion import quat_to_mat

FloatArray = npt.NDArray[np.float64]

MIN_ENTRY_DEPTH_M: float = 0.002
"""The peg_tip counts as inside a hole only this far below the opening: a peg lying on the top face
(e.g. a square peg over the triangle hole) sinks by its contact penetration only (~1e-5 m)."""
FLOOR_SLACK_M: float = 0.002
"""A peg_tip deeper than the hole floor by more than this has gone through the fixture: not in the hole."""


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
    """Wrap an angle into (-180/k, 180/k] deg; 0 for a round shape (k = 0) (`envs.task.success_kernel.wrap_symmetric`).

    Raises:
        EnvError: for a negative symmetry order.
    """
    if symmetry_order < 0:
        raise EnvError(f"symmetry_order={symmetry_order} must be >= 0")
    return wrap_symmetric(float(angle_deg), symmetry_order)


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
        EnvError: if the pose is not 3 + 4 finite numbers or the quaternion is zero; a peg below the chamfer of a
            hole without a polygon.
    """
    pos = as_vector(peg_tip_pos, 3, "peg_tip_pos")
    rot = quat_to_mat(as_vector(peg_tip_quat, 4, "peg_tip_quat"))
    scorer = EpisodeHoles({hole.shape: hole}, hole.shape, hole.depth_m, SuccessConfig(),
                          None if peg is None else PegFootprint.of(peg), shortcut=False)
    return scorer.assess(pos, rot, speed_m_s).state


def wall_penetration_m(tip: npt.NDArray[np.float64], rot_peg: npt.NDArray[np.float64], hole: HoleSpec,
                       peg: CrossSection) -> float:
    """pen of the module docstring, for a peg_tip at ``tip`` with orientation ``rot_peg``, both in the hole
    frame, with the tip below the straight walls (tip_z < -chamfer) (`envs.task.success_kernel.wall_penetration`).

    Raises:
        EnvError: if ``hole.polygon`` is empty (a HoleSpec without geometry).
    """
    if not hole.polygon:
        raise EnvError(f"hole {hole.shape!r} has no polygon to check the walls against")
    frame, footprint = HoleFrame.of(hole), PegFootprint.of(peg)
    return wall_penetration(np.asarray(tip, dtype=np.float64), np.asarray(rot_peg, dtype=np.float64), hole.chamfer_m,
                            hole.inradius_m, frame.wall_normals, frame.wall_offsets, footprint.corners,
                            peg.is_round, float(peg.radius_m))


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
    """Which hole the peg_tip is in, its state in the target hole, and whether the criteria hold (every hole
    scored, no shortcut: `EpisodeHoles` with ``shortcut`` False).

    Raises:
        EnvError: if ``target`` is not among ``holes`` or the pose is malformed.
    """
    scorer = EpisodeHoles(holes, target, target_depth_m, config, PegFootprint.of(peg), shortcut=False)
    pos = as_vector(peg_tip_pos, 3, "peg_tip_pos")
    rot = quat_to_mat(as_vector(peg_tip_quat, 4, "peg_tip_quat"))
    return scorer.assess(pos, rot, speed_m_s)


class EpisodeHoles:
    """The holes of one episode (where its perturbation put them) with their frames built once, and the scoring of a
    peg_tip against them (`assess`).

    Shortcut, exact: a peg_tip is in a hole only deeper than MIN_ENTRY_DEPTH_M below its opening, so while it is
    above every opening (depth_h = -(p - p_h) . z_h <= MIN_ENTRY_DEPTH_M for all holes h) only the target hole's
    state is computed (without the wall penetration), and otherwise only the holes it is below the opening of.
    """

    def __init__(self, holes: Mapping[str, HoleSpec], target: str, target_depth_m: float, config: SuccessConfig,
                 peg: PegFootprint | None, shortcut: bool = True) -> None:
        """Args:
            holes: every hole of the fixture, by shape; ``target`` among them.
            target, target_depth_m, config: the hole to score against, its seated depth and the criteria.
            peg: the peg's footprint, for the wall penetration (None: not computed, and nothing counts as inserted).
            shortcut: the class docstring's (False: every hole, the penetration whenever the tip is below the
                chamfer, as `assess_insertion` scores a pose alone).

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
        corners = np.zeros((0, 3)) if peg is None else np.ascontiguousarray(peg.corners, dtype=np.float64)
        self._arguments = (  # assess_tip's arguments after the pose (envs.task.success_kernel)
            np.array([f.pos for f in frames]), np.array([f.rot for f in frames]),
            np.array([rotate(spec.quat, [0.0, 0.0, 1.0]) for spec in holes.values()]),  # out of the holes
            np.array([spec.depth_m for spec in holes.values()], dtype=np.float64),
            np.array([spec.inradius_m for spec in holes.values()], dtype=np.float64),
            np.array([spec.chamfer_m for spec in holes.values()], dtype=np.float64),
            np.array([spec.symmetry_order for spec in holes.values()], dtype=np.int64), walls.astype(np.int64),
            np.concatenate([f.wall_normals.reshape(-1, 2) for f in frames]),
            np.concatenate([f.wall_offsets.reshape(-1) for f in frames]), self._shapes.index(target),
            corners.reshape(-1, 3), peg is not None and peg.section.is_round,
            0.0 if peg is None else float(peg.section.radius_m), np.ascontiguousarray(R_FLIP_X, dtype=np.float64),
            MIN_ENTRY_DEPTH_M, FLOOR_SLACK_M, float(target_depth_m), config.seat_tolerance_m,
            config.penetration_tolerance_m, config.max_speed_m_s, bool(shortcut), peg is not None)

    def assess(self, pos: FloatArray, rot: FloatArray, speed_m_s: float) -> Assessment:
        """The hole a checked peg_tip position (3,) and rotation matrix (3, 3) is in, its state in the target hole
        and whether the criteria hold, in one compiled call (`envs.task.success_kernel.assess_tip`).

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
