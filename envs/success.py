"""Success scoring of an insertion from the peg's actual pose in the hole frame.

Hole frame H (site ``hole_<shape>``): origin at the centre of the top opening, z up out of the hole.
At the goal the peg_tip frame P is H turned by pi about x and lowered by the insertion depth, so with
R_rel = R_H^T R_P Rx(pi) (identity at the goal) and r = R_H^T (p_P - p_H):
    depth = -r_z,  lateral = sqrt(r_x^2 + r_y^2),  tilt = arccos(R_rel[2, 2]),
    yaw = atan2(R_rel[1,0] - R_rel[0,1], R_rel[0,0] + R_rel[1,1]) wrapped into (-180/k, 180/k] deg
for a hole with k-fold symmetry (yaw is 0 for a round hole).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np
import numpy.typing as npt

from envs.errors import EnvError
from envs.geometry import R_FLIP_X, as_vector, quat_to_mat, twist_angle_deg

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
    """

    shape: str
    pos: tuple[float, float, float]
    quat: tuple[float, float, float, float]
    symmetry_order: int
    inradius_m: float
    depth_m: float
    clearance_m: float


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
    """

    depth_m: float
    lateral_m: float
    tilt_deg: float
    yaw_error_deg: float
    in_hole: bool


@dataclass(frozen=True)
class SuccessConfig:
    """Criteria of a successful insertion (defaults: the task as posed, 90 % of the target depth).

    The lateral tolerance is clearance/2 + ``lateral_slack_m``: a peg inside its hole cannot sit farther
    than clearance/2 from the axis, up to contact penetration (< 0.1 mm here) and the tip shift of a peg
    tilted in the gap ((w/2)(1 - cos tilt), < 0.05 mm for 3 deg); the 0.5 mm slack covers both with margin,
    so at the default 1 mm clearance the tolerance equals the clearance.

    Attributes:
        depth_fraction: inserted depth >= depth_fraction * target insertion depth.
        lateral_slack_m: see above.
        max_tilt_deg: largest angle between peg and hole axes (a 1 mm gap allows ~2 deg at 27 mm depth).
        max_yaw_error_deg: largest heading error modulo the hole's symmetry (not checked for round holes).
        hold_s: how long (physics time) the criteria must hold without interruption.
    """

    depth_fraction: float = 0.9
    lateral_slack_m: float = 0.0005
    max_tilt_deg: float = 3.0
    max_yaw_error_deg: float = 5.0
    hold_s: float = 0.2

    def __post_init__(self) -> None:
        if not 0.0 < self.depth_fraction <= 1.0:
            raise EnvError(f"depth_fraction={self.depth_fraction} must lie in (0, 1]")
        for name in ("lateral_slack_m", "max_tilt_deg", "max_yaw_error_deg", "hold_s"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0.0):
                raise EnvError(f"{name}={value} must be a finite number >= 0")


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
    wrapped = float(np.mod(angle_deg + period / 2.0, period) - period / 2.0)
    return period / 2.0 if np.isclose(wrapped, -period / 2.0) else wrapped


def insertion_state(peg_tip_pos: npt.ArrayLike, peg_tip_quat: npt.ArrayLike, hole: HoleSpec) -> InsertionState:
    """The peg_tip pose relative to ``hole`` (equations in the module docstring).

    Args:
        peg_tip_pos: peg_tip position in the world (m).
        peg_tip_quat: peg_tip orientation (w, x, y, z), z along the peg axis away from the hand.
        hole: the hole.

    Raises:
        EnvError: if the pose is not 3 + 4 finite numbers or the quaternion is zero.
    """
    pos = as_vector(peg_tip_pos, 3, "peg_tip_pos")
    rot_hole = quat_to_mat(hole.quat)
    rot_rel = rot_hole.T @ quat_to_mat(as_vector(peg_tip_quat, 4, "peg_tip_quat")) @ R_FLIP_X
    offset = rot_hole.T @ (pos - np.asarray(hole.pos, dtype=np.float64))
    depth = float(-offset[2])
    lateral = float(np.hypot(offset[0], offset[1]))
    tilt = float(np.rad2deg(np.arccos(np.clip(rot_rel[2, 2], -1.0, 1.0))))
    yaw = wrap_symmetric_deg(twist_angle_deg(rot_rel), hole.symmetry_order)
    in_hole = MIN_ENTRY_DEPTH_M < depth <= hole.depth_m + FLOOR_SLACK_M and lateral <= hole.inradius_m
    return InsertionState(depth, lateral, tilt, yaw, bool(in_hole))


def criteria_hold(state: InsertionState, hole: HoleSpec, target_depth_m: float, config: SuccessConfig) -> bool:
    """True when the peg is in ``hole``, deep enough, centred, upright and (non-round) turned right.

    depth >= depth_fraction * target_depth_m, lateral <= clearance/2 + lateral_slack_m,
    tilt <= max_tilt_deg, |yaw error| <= max_yaw_error_deg.
    """
    return (
        state.in_hole
        and state.depth_m >= config.depth_fraction * target_depth_m
        and state.lateral_m <= hole.clearance_m / 2.0 + config.lateral_slack_m
        and state.tilt_deg <= config.max_tilt_deg
        and abs(state.yaw_error_deg) <= config.max_yaw_error_deg
    )


def assess_insertion(
    peg_tip_pos: npt.ArrayLike,
    peg_tip_quat: npt.ArrayLike,
    holes: Mapping[str, HoleSpec],
    target: str,
    target_depth_m: float,
    config: SuccessConfig = SuccessConfig(),
) -> Assessment:
    """Which hole the peg_tip is in, its state in the target hole, and whether the criteria hold.

    Raises:
        EnvError: if ``target`` is not among ``holes`` or the pose is malformed.
    """
    if target not in holes:
        raise EnvError(f"target hole {target!r} is not among the holes {sorted(holes)}")
    states = {shape: insertion_state(peg_tip_pos, peg_tip_quat, hole) for shape, hole in holes.items()}
    inside = [shape for shape, state in states.items() if state.in_hole]
    hole = target if target in inside else (inside[0] if inside else None)
    state = states[target]
    inserted = hole == target and criteria_hold(state, holes[target], target_depth_m, config)
    return Assessment(hole, state, inserted)


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
