"""The scoring of a peg_tip pose against holes (`envs.task.success`: `EpisodeHoles.assess`, `assess_insertion`,
`insertion_state`, `wall_penetration_m`) as one compiled call, so a control period's success check costs ~3 us
instead of ~30 us of small numpy calls.

It computes what its numpy reference (tests/envs/task/test_success_kernel.py) computes, step for step -- the same
products summed in the same order (numerics.small_linalg), libm's acos, atan2 and hypot as a pinned numpy calls them,
Python's float modulo -- so the states and records equal the reference's to the last bit. With the peg_tip's position p and rotation R in the world, per hole h (p_h, R_h, its axis z_h out of
the hole):

    depth_h = -(p - p_h) . z_h                          only holes with depth_h > MIN_ENTRY_DEPTH_M can hold the tip
    r = R_T^T (p - p_T), R_peg = R_T^T R, R_rel = R_peg R_flip      the target hole T's frame
    depth = -r_z, lateral = |r_xy|, tilt = acos(R_rel[2, 2]), yaw = atan2(R_rel[1,0] - R_rel[0,1], R_rel[0,0] + R_rel[1,1])
    wrapped into (-180/k, 180/k] deg for a k-fold symmetric hole; the wall penetration below the chamfer.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import numpy.typing as npt

from numerics.small_linalg import _matmul2, matvec

FloatArray = npt.NDArray[np.float64]

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")
_RAD2DEG = 180.0 / math.pi  # numpy's rad2deg: x * (180 / pi)

NO_HOLE = -1
"""`assess_tip`'s hole index when the peg_tip is in no hole."""
NO_POLYGON = -2
"""`assess_tip`'s hole index when the target hole has no polygon to check the walls against (an error)."""


def wrap_symmetric(angle_deg: float, symmetry_order: int) -> float:
    """An angle wrapped into (-180/k, 180/k] deg, 0 for a round shape (k = 0); k >= 0 is the caller's to check
    (`envs.task.success.wrap_symmetric_deg`). Plain Python, compiled below as it is: one source, one rounding."""
    if symmetry_order == 0:
        return 0.0
    period = 360.0 / symmetry_order
    half = period / 2.0
    wrapped = (angle_deg + half) % period - half
    return half if abs(wrapped + half) <= 1e-8 + 1e-5 * half else wrapped  # np.isclose(wrapped, -half)


_wrap_symmetric = _jit(wrap_symmetric)


@_jit
def _inside(offset: FloatArray, depth_m: float, inradius_m: float, min_entry_m: float,
            floor_slack_m: float) -> tuple[float, float, bool]:
    """`envs.task.success._inside`: (depth, lateral, in_hole) of a peg_tip at ``offset`` in a hole's frame."""
    depth = -offset[2]
    lateral = math.hypot(offset[0], offset[1])
    return depth, lateral, min_entry_m < depth <= depth_m + floor_slack_m and lateral <= inradius_m


@_jit
def wall_penetration(tip: FloatArray, rot_peg: FloatArray, chamfer_m: float, inradius_m: float,
                     normals: FloatArray, offsets: FloatArray, corners: FloatArray, round_peg: bool,
                     radius_m: float) -> float:
    """pen of `envs.task.success` for a tip in the hole frame with the peg's orientation there: the hole's wall lines
    {n_i . x <= d_i} (``normals`` (W, 2), ``offsets`` (W,), W > 0) and the peg's tip-face vertices ``corners``
    (k, 3), or its radius for a round peg."""
    up = np.empty(3)
    for i in range(3):
        up[i] = -rot_peg[i, 2]
    level = -chamfer_m
    if up[2] <= 1e-9:
        return math.inf
    if round_peg:
        along = level - tip[2]
        cx = tip[0] + up[0] * along / up[2]
        cy = tip[1] + up[1] * along / up[2]
        radial = max(math.hypot(tip[0], tip[1]), math.hypot(cx, cy))
        return radial + radius_m / up[2] - inradius_m
    k = corners.shape[0]
    turned = _matmul2(corners, rot_peg.T)
    points = np.empty((2 * k, 2))
    for c in range(k):
        z = tip[2] + turned[c, 2]
        rise = max(level - z, 0.0) / up[2]
        for i in range(2):
            at = tip[i] + turned[c, i]
            points[c, i] = at
            points[k + c, i] = at + rise * up[i]
    across = _matmul2(points, normals.T)
    worst = -math.inf
    for r in range(across.shape[0]):
        for w in range(across.shape[1]):
            value = across[r, w] - offsets[w]
            if math.isnan(value):
                return math.nan
            worst = max(worst, value)
    return worst


@_jit
def assess_tip(pos: FloatArray, rot: FloatArray, hole_pos: FloatArray, hole_rot: FloatArray, hole_axis: FloatArray,
               hole_depth_m: FloatArray, hole_inradius_m: FloatArray, hole_chamfer_m: FloatArray,
               hole_symmetry: npt.NDArray[np.int64], hole_walls: npt.NDArray[np.int64], wall_normals: FloatArray,
               wall_offsets: FloatArray, target: int, corners: FloatArray, round_peg: bool, radius_m: float,
               flip: FloatArray, min_entry_m: float, floor_slack_m: float, target_depth_m: float,
               seat_tolerance_m: float, penetration_tolerance_m: float, max_speed_m_s: float, shortcut: bool,
               with_penetration: bool, speed_m_s: float) -> tuple[int, float, float, float, float, bool, float, bool]:
    """`envs.task.success.EpisodeHoles.assess` of a peg_tip at ``pos`` (3,) with rotation ``rot`` (3, 3) in the world.

    Args:
        hole_pos, hole_rot, hole_axis: per hole (H, 3), (H, 3, 3), (H, 3): p_h, R_h and z_h.
        hole_depth_m, hole_inradius_m, hole_chamfer_m, hole_symmetry: per hole.
        hole_walls: (H + 1,) where each hole's wall lines start in ``wall_normals`` (W, 2) and ``wall_offsets`` (W,);
            a hole without a polygon has none.
        target: the target hole's index.
        corners, round_peg, radius_m: the peg's tip-face vertices (k, 3) (prism) or its radius (round).
        flip: R_flip (envs.geometry.R_FLIP_X).
        min_entry_m, floor_slack_m: envs.task.success.MIN_ENTRY_DEPTH_M and FLOOR_SLACK_M.
        target_depth_m .. max_speed_m_s: the success criteria (the module docstring of envs.task.success).
        shortcut: only the target's state while the tip is above every opening, and only the holes the tip is
            below the opening of (exact: `envs.task.success.EpisodeHoles`); False: every hole, as a pose scored alone.
        with_penetration: compute the wall penetration (else NaN, and no insertion).
        speed_m_s: the peg's speed.

    Returns:
        (the hole the tip is in: its index, NO_HOLE, or NO_POLYGON when the penetration cannot be checked; then the
        target-hole state depth, lateral, tilt_deg, yaw_deg, in_hole, wall penetration (NaN when not computed);
        whether every criterion holds).
    """
    n = hole_pos.shape[0]
    entered = np.empty(n, dtype=np.bool_)
    above_all = True
    for h in range(n):
        s = 0.0
        for i in range(3):
            s += (pos[i] - hole_pos[h, i]) * hole_axis[h, i]
        entered[h] = -s > min_entry_m or not shortcut
        above_all = above_all and -s <= min_entry_m and shortcut  # np.all(depths <= MIN_ENTRY_DEPTH_M)
    rot_t = hole_rot[target].T
    rot_peg = _matmul2(rot_t, rot)
    rot_rel = _matmul2(rot_peg, flip)
    rel = np.empty(3)
    for i in range(3):
        rel[i] = pos[i] - hole_pos[target, i]
    offset = matvec(rot_t, rel)
    depth, lateral, in_hole = _inside(offset, hole_depth_m[target], hole_inradius_m[target], min_entry_m,
                                      floor_slack_m)
    tilt = math.acos(min(max(rot_rel[2, 2], -1.0), 1.0)) * _RAD2DEG
    yaw = _wrap_symmetric(math.atan2(rot_rel[1, 0] - rot_rel[0, 1], rot_rel[0, 0] + rot_rel[1, 1]) * _RAD2DEG,
                              hole_symmetry[target])
    penetration = math.nan
    if above_all:
        return NO_HOLE, depth, lateral, tilt, yaw, in_hole, penetration, False
    if with_penetration and depth > hole_chamfer_m[target]:
        first, last = hole_walls[target], hole_walls[target + 1]
        if first == last:
            return NO_POLYGON, depth, lateral, tilt, yaw, in_hole, penetration, False
        penetration = wall_penetration(offset, rot_peg, hole_chamfer_m[target], hole_inradius_m[target],
                                       wall_normals[first:last], wall_offsets[first:last], corners, round_peg,
                                       radius_m)
    hole = NO_HOLE
    if in_hole:
        hole = target
    else:
        for h in range(n):
            if h == target or not entered[h]:
                continue
            for i in range(3):
                rel[i] = pos[i] - hole_pos[h, i]
            if _inside(matvec(hole_rot[h].T, rel), hole_depth_m[h], hole_inradius_m[h], min_entry_m,
                       floor_slack_m)[2]:
                hole = h
                break
    inserted = (hole == target and in_hole and abs(depth - target_depth_m) <= seat_tolerance_m
                and penetration <= penetration_tolerance_m and speed_m_s <= max_speed_m_s)
    return hole, depth, lateral, tilt, yaw, in_hole, penetration, inserted
