"""The scripted expert's plan: its settings (`ExpertConfig`) and the smooth peg_tip path it commands
(`plan_expert_path`) with the path's twists (`plan_twists`); arrays only, no physics. envs.demos.record executes the
plan in physics and records demonstrations; envs.policies.expert runs it as a (privileged) policy.

The scripted expert plans one smooth peg_tip pose path in the hole frame (axis a out of the hole, opening
o; the start offset s - o splits into the height h0 = (s - o) . a and the lateral part l0):
  - lateral offset l(t) = l0 (1 - sigma(t / T_align)) and orientation slerp(q_start, q_goal, sigma(t / T_align)),
    with sigma(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5 (minimum jerk): the peg reaches the hole axis, aligned,
    at T_align, high above the opening;
  - height h(t): a quintic from h0 (at rest) to the entry height h_e above the opening, reached at the
    slow entry speed v_e at T_approach; the constant speed v_e down to the entry depth -d_e below the
    opening (T_entry = (h_e + d_e) / v_e); a second quintic from -d_e (speed v_e) to the goal depth -d
    (at rest) in T_insert (quintics with zero acceleration at their ends, so h is C2);
  - hold at the goal for T_hold.
The path is C2 and never stops before the goal (no spurious rest point for the learned dynamics). The
slow entry matters: the controller damps the absolute velocity through the (non-diagonal) Cartesian
inertia, so a fast vertical motion drags the peg sideways by ~0.013 mm per mm/s -- at the
minimum-jerk peak speed of a plain descent that exceeds the 0.5 mm half clearance.
Every demo lasts the same T = T_approach + T_entry + T_insert + T_hold (7 s by default), so all demos
share one sampling time dt = T / (M - 1).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from envs.errors import EnvError
from envs.policies.stiffness_schedule import StiffnessSchedule
from envs.poses import (
    Pose,
    StartRegion,
    format_pose,
    make_continuous,
    minimum_jerk,
    quat_conj,
    quat_mul,
    quat_to_rotvec,
    quintic_hermite,
    slerp,
)
from numerics.small_linalg import dot, norm

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class ExpertConfig:
    """The scripted expert and the demo recording (defaults: M = 4000 samples, as in the paper).

    Attributes:
        entry_height_m: h_e, height above the opening (on the axis) where the constant entry speed begins.
        entry_depth_m: d_e, depth below the opening where the constant entry speed ends.
        entry_speed_m_s: v_e, speed along the axis from h_e to -d_e.
        align_duration_s: T_align, time to reach the hole axis and the goal orientation.
        approach_duration_s: T_approach, time from the start height down to h_e (>= T_align).
        insertion_duration_s: T_insert, time from -d_e to the goal depth.
        hold_duration_s: T_hold, time holding the goal at the end.
        settle_window_s: the settled pose is the mean measured pose over this last part of the hold.
        num_samples: M, samples per recorded demo.
        goal_tol_m, goal_tol_deg: largest accepted distance of the settled pose from the goal.
        max_failed_attempts: give up after this many failed attempts in one collection (a working expert fails
            fewer than 1 in 100, so reaching it means the expert cannot do this scene).
        start_region: where starts are sampled.
        stiffness: the translational stiffness schedule the expert commands and records (envs.demos.record);
            None: the controller's constant default stiffness, and no stiffness in the demo file.
    """

    entry_height_m: float = 0.005
    entry_depth_m: float = 0.005
    entry_speed_m_s: float = 0.01
    align_duration_s: float = 2.0
    approach_duration_s: float = 3.0
    insertion_duration_s: float = 2.0
    hold_duration_s: float = 1.0
    settle_window_s: float = 0.3
    num_samples: int = 4000
    goal_tol_m: float = 1e-3
    goal_tol_deg: float = 1.0
    max_failed_attempts: int = 20
    start_region: StartRegion = field(default_factory=StartRegion)
    stiffness: StiffnessSchedule | None = field(default_factory=StiffnessSchedule)

    def __post_init__(self) -> None:
        for name in ("entry_height_m", "align_duration_s", "approach_duration_s", "insertion_duration_s",
                     "hold_duration_s", "settle_window_s", "goal_tol_m", "goal_tol_deg"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0.0):
                raise EnvError(f"ExpertConfig.{name}={value!r} must be a positive finite number")
        if not (np.isfinite(self.entry_speed_m_s) and self.entry_speed_m_s > 0.0):
            raise EnvError(f"ExpertConfig.entry_speed_m_s={self.entry_speed_m_s!r} must be > 0")
        if not (np.isfinite(self.entry_depth_m) and self.entry_depth_m >= 0.0):
            raise EnvError(f"ExpertConfig.entry_depth_m={self.entry_depth_m!r} must be >= 0")
        if self.align_duration_s > self.approach_duration_s:
            raise EnvError(f"ExpertConfig.align_duration_s={self.align_duration_s} exceeds approach_duration_s="
                           f"{self.approach_duration_s}")
        if self.settle_window_s > self.hold_duration_s:
            raise EnvError(f"ExpertConfig.settle_window_s={self.settle_window_s} exceeds hold_duration_s="
                           f"{self.hold_duration_s}")
        if not isinstance(self.num_samples, int) or self.num_samples < 2:
            raise EnvError(f"ExpertConfig.num_samples={self.num_samples!r} must be an integer >= 2")
        if self.max_failed_attempts < 1:
            raise EnvError(f"ExpertConfig.max_failed_attempts={self.max_failed_attempts} must be >= 1")
        if self.stiffness is not None and not isinstance(self.stiffness, StiffnessSchedule):
            raise EnvError(f"ExpertConfig.stiffness={self.stiffness!r} must be a StiffnessSchedule or None")

    @property
    def entry_duration_s(self) -> float:
        """T_entry = (h_e + d_e) / v_e, the constant-speed entry."""
        return (self.entry_height_m + self.entry_depth_m) / self.entry_speed_m_s

    @property
    def hold_start_s(self) -> float:
        """Time at which the planned path reaches the goal."""
        return self.approach_duration_s + self.entry_duration_s + self.insertion_duration_s

    @property
    def duration_s(self) -> float:
        """T, the duration of every demo."""
        return self.hold_start_s + self.hold_duration_s


def plan_expert_path(start: Pose, opening_pos: npt.ArrayLike, hole_axis: npt.ArrayLike, goal: Pose,
                     config: ExpertConfig, times: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    """The scripted expert's commanded peg_tip poses at ``times`` (see the module docstring).

    Args:
        start: start pose (t = 0).
        opening_pos: centre of the hole opening o.
        hole_axis: hole axis a, pointing out of the hole.
        goal: goal pose on the axis below the opening, reached at ``config.hold_start_s`` and held.
        config: entry height/speed and segment durations.
        times: (K,) query times in seconds.

    Returns:
        (pos (K, 3), quat (K, 4)), quaternions continuous and ending at +goal.quat.

    Raises:
        EnvError: a start not above the entry height, or a height profile that would not descend
            monotonically (entry speed too high for the distances and durations).
    """
    t = np.asarray(times, dtype=float)
    axis = np.asarray(hole_axis, dtype=float)
    axis = axis / norm(axis)
    opening = np.asarray(opening_pos, dtype=float)
    offset = start.pos - opening
    h0 = dot(offset, axis)
    lateral0 = offset - h0 * axis
    depth = dot(opening - goal.pos, axis)
    h_e, d_e, v_e = config.entry_height_m, config.entry_depth_m, config.entry_speed_m_s
    t_a, t_e, t_i = config.approach_duration_s, config.entry_duration_s, config.insertion_duration_s
    if h0 <= h_e:
        raise EnvError(f"start {format_pose(start)} is {h0 * 1e3:.1f} mm above the opening, not above the entry "
                       f"height {h_e * 1e3:.1f} mm")
    if depth <= d_e:
        raise EnvError(f"goal depth {depth * 1e3:.1f} mm is not below the entry depth {d_e * 1e3:.1f} mm")
    approach = (h0, 0.0, h_e, -v_e * t_a)
    insertion = (-d_e, -v_e * t_i, -depth, 0.0)
    for p0, v0, p1, v1 in (approach, insertion):
        if not _descends(p0, v0, p1, v1):
            raise EnvError(f"entry speed {v_e} m/s is too high for a monotone descent from {p0 * 1e3:.1f} mm to "
                           f"{p1 * 1e3:.1f} mm (start {format_pose(start)})")
    height = np.where(t < t_a, quintic_hermite(t / t_a, *approach),
                      np.where(t < t_a + t_e, h_e - v_e * (t - t_a),
                               quintic_hermite((t - t_a - t_e) / t_i, *insertion)))
    sigma = minimum_jerk(t / config.align_duration_s)
    pos = opening + height[:, None] * axis + (1.0 - sigma)[:, None] * lateral0
    quat = slerp(start.quat, goal.quat, sigma)
    return pos, make_continuous(quat, reference=goal.quat)


def _descends(p0: float, v0: float, p1: float, v1: float) -> bool:
    """Whether the quintic from (p0, v0) to (p1, v1) descends monotonically (checked on 201 points)."""
    return not np.any(np.diff(quintic_hermite(np.linspace(0.0, 1.0, 201), p0, v0, p1, v1)) > 1e-12)


def check_entry_speed(config: ExpertConfig, depth_m: float) -> None:
    """Refuse an entry speed that no start can use: the insertion from the entry depth down to the goal ``depth_m``
    below the opening (in ``config.insertion_duration_s``, starting at the entry speed) must descend monotonically,
    whatever the start (`plan_expert_path` checks the approach too, which depends on the start's height).

    Raises:
        EnvError: naming the speed and the largest one this insertion allows.
    """
    d_e, t_i = config.entry_depth_m, config.insertion_duration_s
    if depth_m <= d_e or _descends(-d_e, -config.entry_speed_m_s * t_i, -depth_m, 0.0):
        return
    low, high = 0.0, config.entry_speed_m_s
    for _ in range(40):  # the largest speed that still descends, for the message
        low, high = ((low + high) / 2, high) if _descends(-d_e, -(low + high) / 2 * t_i, -depth_m, 0.0) else (
            low, (low + high) / 2)
    raise EnvError(f"entry speed {config.entry_speed_m_s * 1e3:g} mm/s is too high for the insertion from "
                   f"{d_e * 1e3:g} mm to {depth_m * 1e3:g} mm below the opening in {t_i:g} s: at most "
                   f"{low * 1e3:.1f} mm/s")


def plan_twists(pos: FloatArray, quat: FloatArray, period_s: float) -> tuple[FloatArray, FloatArray]:
    """The planned path's twist xi_k = [dp/dt; omega] and its rate (K, 6) each, by central differences over the
    sampling period (omega_k = rotvec(q_{k+1} conj(q_{k-1})) / 2T, one-sided at the ends)."""
    v = np.gradient(pos, period_s, axis=0)
    nxt = np.concatenate([quat[1:], quat[-1:]])
    prv = np.concatenate([quat[:1], quat[:-1]])
    span = np.full(len(quat), 2.0 * period_s)
    span[0] = span[-1] = period_s
    omega = quat_to_rotvec(quat_mul(nxt, quat_conj(prv))) / span[:, None]
    twist = np.concatenate([v, omega], axis=1)
    return twist, np.gradient(twist, period_s, axis=0)
