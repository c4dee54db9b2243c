"""The scripted expert's translational stiffness schedule: stiff in free space, compliant across the hole axis.

A teacher varying the robot's compliance during the insertion. In the hole frame (axis a out of the hole,
opening o) with the peg_tip's height above the opening h = (p - o) . a, the blend weight is
    s(h) = sigma((h_free - h) / (h_free - h_hole)),   sigma(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5 (tau clipped to [0, 1]),
so s = 0 at and above h_free and s = 1 at and below h_hole (minimum jerk in between: C2 in h). The stiffness
is the Log-Euclidean (here: geometric) blend of the free-space and the in-hole stiffness, which share the
eigenvectors a and the plane across it:
    k_lateral(h) = k_free^(1 - s) k_lateral_hole^s,   k_axial(h) = k_free^(1 - s) k_axial_hole^s,
    K(h) = k_lateral (I - a a^T) + k_axial a a^T     (world frame, N/m).
In free space K = k_free I (the impedance controller's default translational stiffness); near and in the hole
the peg is compliant across the axis (the walls and the chamfer guide it) and stiffer along it (it still
pushes to the depth). Every demo ends in the hole, below h_hole, so every demo ends at the same goal
stiffness K_goal = k_lateral_hole (I - a a^T) + k_axial_hole a a^T.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from controllers.impedance import ImpedanceConfig
from envs.errors import EnvError
from envs.poses import minimum_jerk
from numerics.small_linalg import matmul, norm
from pihutil.bounds import STIFFNESS

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class StiffnessSchedule:
    """The expert's stiffness schedule (module docstring).

    Attributes:
        free_n_m: k_free, isotropic stiffness in free space (default: ImpedanceConfig's translational stiffness).
        lateral_hole_n_m: k_lateral_hole, across the hole axis near and in the hole.
        axial_hole_n_m: k_axial_hole, along the hole axis near and in the hole.
        free_height_m: h_free, height above the opening where the blend starts (s = 0 above it).
        hole_height_m: h_hole, height above the opening where the blend ends (s = 1 below it; the
            expert's default entry height, where its slow entry begins).
    """

    free_n_m: float = ImpedanceConfig().translational_stiffness
    lateral_hole_n_m: float = 300.0
    axial_hole_n_m: float = 1000.0
    free_height_m: float = 0.03
    hole_height_m: float = 0.005

    def __post_init__(self) -> None:
        for name in ("free_n_m", "lateral_hole_n_m", "axial_hole_n_m"):
            value = getattr(self, name)
            if not STIFFNESS.contains(value):
                raise EnvError(f"StiffnessSchedule.{name}={value!r} must be a stiffness {STIFFNESS.text()} (what the "
                               "controller commands)")
        if not (np.isfinite(self.free_height_m) and np.isfinite(self.hole_height_m)
                and self.free_height_m > self.hole_height_m):
            raise EnvError(f"StiffnessSchedule needs free_height_m > hole_height_m, got {self.free_height_m!r} "
                           f"and {self.hole_height_m!r}")

    @classmethod
    def parse(cls, text: str) -> "StiffnessSchedule":
        """The schedule "FREE/LATERAL/AXIAL" (k_free, k_lateral_hole, k_axial_hole in N/m; the heights the
        defaults'). Raises EnvError saying what is wrong (the caller names the input)."""
        try:
            free, lateral, axial = (float(v) for v in str(text).split("/"))
        except ValueError:
            raise EnvError("expected FREE/LATERAL/AXIAL, three stiffnesses in N/m") from None
        return cls(free, lateral, axial)

    def goal_stiffness(self, hole_axis: npt.ArrayLike) -> FloatArray:
        """K_goal (3, 3), the in-hole stiffness every demo ends at."""
        return self._matrix(self.lateral_hole_n_m, self.axial_hole_n_m, _unit_axis(hole_axis))

    @staticmethod
    def _matrix(lateral: npt.ArrayLike, axial: npt.ArrayLike, axis: FloatArray) -> FloatArray:
        lat, ax = np.asarray(lateral, dtype=float)[..., None, None], np.asarray(axial, dtype=float)[..., None, None]
        aat = np.outer(axis, axis)
        return lat * (np.eye(3) - aat) + ax * aat


def _unit_axis(hole_axis: npt.ArrayLike) -> FloatArray:
    a = np.asarray(hole_axis, dtype=float)
    n = norm(a) if a.shape == (3,) else float("nan")
    if not (np.isfinite(n) and n > 0.0):
        raise EnvError(f"hole axis {np.asarray(hole_axis).tolist()} must be a non-zero finite 3-vector")
    return a / n


def expert_stiffness(peg_tip_pos: npt.ArrayLike, hole_pos: npt.ArrayLike, hole_axis: npt.ArrayLike,
                     config: StiffnessSchedule = StiffnessSchedule()) -> FloatArray:
    """The expert's translational stiffness K(h) at peg_tip position(s) (module docstring).

    Args:
        peg_tip_pos: (3,) or (..., 3) peg_tip positions, m, world frame.
        hole_pos: (3,) centre of the hole opening o.
        hole_axis: (3,) hole axis a, pointing out of the hole (normalised here).
        config: the schedule.

    Returns:
        (3, 3) or (..., 3, 3) SPD stiffness, N/m, world frame.

    Raises:
        EnvError: non-finite or wrongly shaped positions, a zero axis.
    """
    p = np.asarray(peg_tip_pos, dtype=float)
    o = np.asarray(hole_pos, dtype=float)
    if p.ndim < 1 or p.shape[-1] != 3 or o.shape != (3,) or not (np.all(np.isfinite(p)) and np.all(np.isfinite(o))):
        raise EnvError(f"expert_stiffness needs finite positions (..., 3) and a hole position (3,), got shapes "
                       f"{p.shape} and {o.shape}")
    axis = _unit_axis(hole_axis)
    height = matmul(p - o, axis)
    s = minimum_jerk((config.free_height_m - height) / (config.free_height_m - config.hole_height_m))
    lateral = config.free_n_m ** (1.0 - s) * config.lateral_hole_n_m ** s
    axial = config.free_n_m ** (1.0 - s) * config.axial_hole_n_m ** s
    return StiffnessSchedule._matrix(lateral, axial, axis)


__all__ = ["StiffnessSchedule", "expert_stiffness"]
