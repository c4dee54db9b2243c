"""The closed loop's per-period arithmetic as Python computed it before it was compiled
(envs.policies.closed_loop_kernel): the reference that tests/envs/policies/test_closed_loop_kernel.py holds the kernels
to, bit for bit. `ReferenceAdapter` is the former `ContactAdapter`; `reference_query` and `reference_action` are the
former `ClosedLoopPolicy._query` and the pose, twist and acceleration part of `ClosedLoopPolicy._complete`."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from envs.policies.adaptation import ContactAdaptation
from envs.policies.flow_skill import on_goal_hemisphere, pose_twist
from envs.poses import quat_conj, quat_from_rotvec_one, quat_mul, quat_mul_one, quat_to_rotvec_one, rotate
from numerics.small_linalg import dot, norm

FloatArray = npt.NDArray[np.float64]


class ReferenceAdapter:
    """The former `ContactAdapter` (numpy arrays and Python floats), kept as it was."""

    def __init__(self, config: ContactAdaptation, goal_pos: npt.ArrayLike, axis: npt.ArrayLike):
        self.config = config
        self.goal_pos = np.asarray(goal_pos, dtype=np.float64).copy()
        a = np.asarray(axis, dtype=np.float64)
        self.axis = a / norm(a)
        helper = np.array([1.0, 0.0, 0.0]) if abs(self.axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        e1 = helper - dot(helper, self.axis) * self.axis
        self._search_plane = (e1 / norm(e1), np.cross(self.axis, e1 / norm(e1)))
        self.mouth_depth_m: float | None = None
        self.reset()

    def reset(self, mouth_depth_m: float | None = None) -> None:
        """Start an episode: no push, no frame shift, rotation or search. ``mouth_depth_m``: how far the goal lies
        beyond the nominal hole's mouth along the axis, a^T (g_p - mouth), m (None: no stall search)."""
        self.push = np.zeros(3)
        self.resistance_n = 0.0
        self.frame = np.zeros(3)
        self.rotation = np.zeros(3)
        self.search = np.zeros(3)
        self.search_s = 0.0
        self.mouth_depth_m = mouth_depth_m
        self._previous: FloatArray | None = None
        self._previous_quat: list[float] | None = None

    @property
    def offset(self) -> FloatArray:
        """u + s: the axial push and the stall search's lateral offset, added to the led anchor (m, world)."""
        if self.search_s == 0.0:
            return self.push  # no search: s = 0 (no new array on the control path)
        return self.config.search_push_scale * self.push + self.search

    @property
    def rotation_quat(self) -> list[float]:
        """Exp(rho), the frame rotation as a unit quaternion [w, x, y, z]."""
        return quat_from_rotvec_one(self.rotation.tolist())

    def near_goal(self, pos: npt.ArrayLike) -> bool:
        """Whether ``pos`` is within ``radius_m`` of the goal."""
        return norm(np.asarray(pos, dtype=np.float64) - self.goal_pos) < self.config.radius_m

    def rotational_stiffness(self, pos: npt.ArrayLike) -> float | None:
        """The rotational stiffness to command at measured position ``pos`` (None: the controller's)."""
        return self.config.rotational_stiffness if self.near_goal(pos) else None

    def sense(self, force_world: npt.ArrayLike) -> None:
        """The sensed force the environment exerts on the tool (3,, N, world) this step: its part against the axis,
        -a^T F, is what the seat push reads."""
        self.resistance_n = -dot(self.axis, np.asarray(force_world, dtype=np.float64))

    def update(self, pos: npt.ArrayLike, velocity_d: npt.ArrayLike, period_s: float) -> None:
        """One control step at measured position ``pos`` with the flow's linear velocity ``velocity_d`` (3,):
        e <- (1 - T/tau) e + (xi_d - v) T (+ a v_s T seating near the goal, `sense`), push = sat(a a^T e),
        delta <- sat(delta - (I - a a^T)(xi_d - v) T) near the goal. The first call only records ``pos`` (no
        velocity yet)."""
        here = np.asarray(pos, dtype=np.float64)
        previous, self._previous = self._previous, here.copy()
        cfg = self.config
        if previous is None or (cfg.push_limit_m == 0.0 and cfg.frame_limit_m == 0.0):
            return
        error = (np.asarray(velocity_d, dtype=np.float64) - (here - previous) / period_s) * period_s
        a = self.axis
        axial = dot(a, error)
        lateral = error - axial * a
        if (cfg.seat_speed_m_s > 0.0 and self.resistance_n < cfg.seat_force_n
                and norm(here - self.goal_pos) < cfg.seat_radius_m):
            axial += cfg.seat_speed_m_s * period_s
        self.push = _saturate(max(0.0, 1.0 - period_s / cfg.push_leak_s) * self.push + axial * a, cfg.push_limit_m)
        if self._update_search(here, period_s):
            return  # the frame holds still while the search moves the peg
        if cfg.frame_limit_m > 0.0 and self.near_goal(here):
            self.frame = _saturate(self.frame - lateral, cfg.frame_limit_m)

    def _update_search(self, here: FloatArray, period_s: float) -> bool:
        """Advance (or end) the stall search at measured position ``here``; whether it runs."""
        cfg = self.config
        stalled = (cfg.search_amplitude_m > 0.0 and self.mouth_depth_m is not None
                   and norm(self.push) > cfg.search_push_m
                   and dot(self.axis, here - self.goal_pos) + self.mouth_depth_m < cfg.search_band_m)
        if not stalled:
            if self.search_s > 0.0:  # the search ends
                self.search, self.search_s = np.zeros(3), 0.0
            return False
        self.search_s += period_s
        phase = 2.0 * np.pi * self.search_s / cfg.search_period_s
        radius = cfg.search_amplitude_m * min(1.0, self.search_s / cfg.search_period_s)
        e1, e2 = self._search_plane
        self.search = radius * (np.cos(phase) * e1 + np.sin(phase) * e2)
        return True


    def update_rotation(self, pos: npt.ArrayLike, quat: npt.ArrayLike, omega_d: npt.ArrayLike, period_s: float) -> None:
        """One control step at the measured pose (``pos``, ``quat``) with the flow's angular velocity ``omega_d``
        (3,, world frame, already turned by the frame rotation): rho <- sat(Log(Exp(-(omega_d T - r)) Exp(rho)))
        near the goal, r the measured rotation since the last call (module docstring). The first call only
        records ``quat``."""
        q = [float(v) for v in np.asarray(quat, dtype=np.float64)]
        previous, self._previous_quat = self._previous_quat, q
        limit = np.deg2rad(self.config.frame_limit_deg)
        if previous is None or limit == 0.0 or not self.near_goal(pos):
            return
        w, x, y, z = previous
        turned = quat_to_rotvec_one(quat_mul_one(q, [w, -x, -y, -z]))
        error = [float(o) * period_s - r for o, r in zip(np.asarray(omega_d, dtype=np.float64), turned)]
        rho = np.array(quat_to_rotvec_one(quat_mul_one(quat_from_rotvec_one([-e for e in error]), self.rotation_quat)))
        self.rotation = _saturate(rho, limit)


def _saturate(vector: FloatArray, limit: float) -> FloatArray:
    """``vector`` scaled down to norm ``limit`` if longer."""
    length = norm(vector)
    return vector * (limit / length) if length > limit else vector


def reference_query(adapter: ReferenceAdapter, pos: FloatArray, quat: FloatArray):
    """(query pos, query quat, delta, Exp(rho) or None) as `ClosedLoopPolicy._query` computed them."""
    delta = adapter.frame
    turned = bool(adapter.rotation.any())
    query_quat = quat
    rho = None
    if turned:
        rho = np.array(adapter.rotation_quat)
        query_quat = quat_mul(quat_conj(rho), quat)
    return np.asarray(pos, dtype=np.float64) - delta, query_quat, delta, rho


def reference_action(measured_pos, measured_quat, query_pos, query_quat, delta, rho, p1, q1, p2, q2, step_s, speed):
    """(target pos, target quat, twist, accel, anchor pos, anchor quat) as `ClosedLoopPolicy._complete` computed
    them (the twist and acceleration scaled by the speed)."""
    q1 = q1 / norm(q1)
    here_quat = on_goal_hemisphere(query_quat, q1)
    xi1 = pose_twist(query_pos, here_quat, p1, q1, step_s)
    xi2 = pose_twist(p1, q1, p2, on_goal_hemisphere(q2, q1), step_s)
    accel = (xi2 - xi1) / step_s
    twist = xi1 - 0.5 * step_s * accel
    if rho is not None:
        q1 = quat_mul(rho, q1)
        twist[3:], accel[3:] = rotate(rho, twist[3:]), rotate(rho, accel[3:])
    anchor_quat = on_goal_hemisphere(measured_quat, q1) if rho is not None else here_quat
    return p1 + delta, q1, speed * twist, speed**2 * accel, query_pos + delta, anchor_quat
