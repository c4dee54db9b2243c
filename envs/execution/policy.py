"""Policies that turn a trained pose skill (`rflow.skill_io.PoseSkill`) into commanded peg_tip poses.

Closed loop (`ClosedLoopPolicy`, default of `pih evaluate`): every control step the MEASURED peg_tip pose
x = [p, q] is mapped to the tangent space at the goal, pushed ``lookahead_s`` along the learned flow and
mapped back; that pose is the impedance controller's target for the step:
    x_cmd = Exp_g( denorm( b( Phi(lookahead) b^-1( norm( Log_g(x) ) ) ) ) ),   Phi(t) = expm(V t),
one exact latent step of length ``lookahead_s`` (rflow.generate.next_point), separately for the position
and orientation models (or once for a joint model). A lookahead longer than the control period makes up
for the tracking lag of the compliant arm: the target leads the measured pose by ~lookahead of motion.

Near the hole the closed loop adapts to the contact (`envs.execution.adaptation`, not in the paper): an axial
integral push, a shift and a turn of the skill's frame onto the real hole when the walls refuse the flow's
sideways motion or rotation, and rotational compliance; `ContactAdaptation.off()` runs the bare flow.

Open loop (`OpenLoopPolicy`, the paper's robot experiment): the whole trajectory is generated once from
the measured start pose (rflow.generate.rollout, one point per control period, holding the goal after
convergence) and tracked in time.

Velocity feed-forward. The impedance controller (controllers.impedance) pulls toward an equilibrium pose
with F = K e - D v, so to move at the flow's twist xi_d in quasi-steady state (F ~ 0) the commanded pose
must lead the intended pose by K^-1 D xi_d. Without it the compliant arm lags and, D being anisotropic
(it follows the Cartesian inertia), it also drifts sideways (~6 % of the distance travelled here), which
is larger than the hole's clearance. `feedforward_pose` adds
    delta = K^-1 D(q) xi_d,    D = P diag(2 zeta sqrt(w)) P^T   (controllers.impedance.modal_factors)
to the commanded pose (position + world rotation vector), with xi_d the flow's twist from finite
differences over the step (v = dp/dt, omega = rotvec(q1 conj(q0))/dt).

Measured quaternions are put on the goal's hemisphere first (q and -q are the same orientation).

Stiffness (issue #10). A skill trained with `pih train --stiffness` is one joint model on R^3 x S^3 x SPD(3)
that also generates the translational stiffness K (3x3, N/m, world frame). Closed loop, the pose part is
queried at the measured pose as above, while K is the model's own state (it is not measured): it starts at
the skill's start stiffness and is integrated alongside, one exact flow step of the control period (times
``speed``) per control step from [measured pose, K]. Open loop, K is generated with the trajectory. Either
way the commanded K is the generated one with its eigenvalues clipped to the skill's [k_min, k_max]
(`PoseSkill.bound_stiffness`, counted in ``stiffness_clipped_steps``). `StiffnessSetting` chooses between
that learned stiffness, a constant isotropic K, or none (the controller's default);
`controllers.impedance.full_stiffness` makes the 6x6 matrix for env.step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from controllers.impedance import full_stiffness
from envs.errors import EnvError
from envs.execution.adaptation import ContactAdaptation, ContactAdapter
from envs.execution.config import DEFAULT_LOOKAHEAD_S, MODES, StiffnessSetting
from envs.poses import (Pose, quat_conj, quat_from_rotvec_one, quat_mul, quat_mul_one, quat_to_rotvec,
                         quat_to_rotvec_one, rotate)
from rflow.errors import RFlowError
from rflow.generate import next_point, rollout
from rflow.skill_io import PoseSkill
from rflow.small_linalg import norm

FloatArray = npt.NDArray[np.float64]

@dataclass(frozen=True)
class Command:
    """A commanded peg_tip pose and the twist the skill moves with there.

    Attributes:
        pose: the target pose without feed-forward.
        twist: (6,) [v (m/s); omega (rad/s)] in the world frame, for velocity feed-forward.
        anchor: the pose the feed-forward lead is added to (closed loop: the measured pose, so the arm
            moves at the flow's twist from where it is; open loop: the plan's pose).
        accel: (6,) [a (m/s^2); alpha (rad/s^2)] of the skill there, for inertia feed-forward.
        stiffness: (3, 3) translational stiffness to command (N/m, world frame, SPD), or None for the
            controller's default; pass ``full_stiffness(stiffness, k_rot)`` to env.step.
        rotational_stiffness: rotational stiffness to command (N m/rad; closed loop near the hole, see
            envs.execution.adaptation), or None for the controller's default.
        push: (6,) [m; rad] world-frame offset added to the anchor (closed loop: the axial integral of the velocity
            error, see `ClosedLoopPolicy`), zero otherwise.
    """

    pose: Pose
    twist: FloatArray
    anchor: Pose
    accel: FloatArray = field(default_factory=lambda: np.zeros(6))
    stiffness: FloatArray | None = None
    push: FloatArray = field(default_factory=lambda: np.zeros(6))
    rotational_stiffness: float | None = None


def pose_twist(p0: npt.ArrayLike, q0: npt.ArrayLike, p1: npt.ArrayLike, q1: npt.ArrayLike, dt: float) -> FloatArray:
    """Finite-difference twist [(p1 - p0)/dt; rotvec(q1 conj(q0))/dt] (6,) or (..., 6), world frame."""
    p0, q0, p1, q1 = (np.asarray(a, dtype=np.float64) for a in (p0, q0, p1, q1))
    if p0.shape == p1.shape == (3,) and q0.shape == q1.shape == (4,):  # one pose pair: the control-loop path
        return _pose_twist_single(p0.tolist(), q0.tolist(), p1.tolist(), q1.tolist(), np.float64(dt))
    v = (p1 - p0) / dt
    w = quat_to_rotvec(quat_mul(q1, quat_conj(q0))) / dt
    return np.concatenate([v, w], axis=-1)


def _pose_twist_single(p0: list[float], q0: list[float], p1: list[float], q1: list[float],
                       dt: np.float64) -> FloatArray:
    """`pose_twist` of one pose pair (dt a numpy float: dividing by 0 gives inf as the array version does)."""
    w0, x0, y0, z0 = q0
    w = quat_to_rotvec_one(quat_mul_one(q1, [w0, -x0, -y0, -z0]))
    return np.array([(p1[0] - p0[0]) / dt, (p1[1] - p0[1]) / dt, (p1[2] - p0[2]) / dt,
                     w[0] / dt, w[1] / dt, w[2] / dt])


def on_goal_hemisphere(quat: npt.ArrayLike, goal_quat: npt.ArrayLike) -> FloatArray:
    """Quaternion(s) (..., 4) sign-flipped where needed so that q . g >= 0."""
    q = np.array(quat, dtype=np.float64)
    g = np.asarray(goal_quat, dtype=np.float64)
    if q.shape == g.shape == (4,):  # one quaternion: the control-loop path
        w, x, y, z = q.tolist()
        a, b, c, d = g.tolist()
        return -q if w * a + x * b + y * c + z * d < 0.0 else q
    sign = np.where(np.sum(q * g, axis=-1) < 0.0, -1.0, 1.0)
    return q * sign[..., None]


def _unit(q: FloatArray) -> FloatArray:
    """q / np.linalg.norm(q, axis=-1, keepdims=True), with one quaternion (4,) in Python floats."""
    if q.shape == (4,):
        w, x, y, z = q.tolist()
        return q / math.sqrt(w * w + x * x + y * y + z * z)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def skill_step(skill: PoseSkill, pos: npt.ArrayLike, quat: npt.ArrayLike, horizon_s: float,
               stiffness: npt.ArrayLike | None = None) -> tuple[FloatArray, FloatArray]:
    """The pose ``horizon_s`` later along the learned flow from (pos, quat), batched or single.

    Args:
        skill: the trained skill.
        pos: (3,) or (B, 3) peg_tip positions, m.
        quat: (4,) or (B, 4) unit quaternions (either hemisphere).
        horizon_s: flow time to advance (s), > 0.
        stiffness: a stiffness skill's current stiffness state (3, 3) or (B, 3, 3) (default: the goal's).

    Returns:
        (pos, quat) of the same shapes.

    Raises:
        EnvError: NaN or malformed poses, horizon <= 0.
    """
    pos1, quat1, _ = skill_state_step(skill, pos, quat, stiffness, horizon_s)
    return pos1, quat1


def skill_state_step(skill: PoseSkill, pos: npt.ArrayLike, quat: npt.ArrayLike, stiffness: npt.ArrayLike | None,
                     horizon_s: float) -> tuple[FloatArray, FloatArray, FloatArray | None]:
    """`skill_step` that also advances a stiffness skill's stiffness state: (pos, quat, stiffness or None).

    Raises:
        EnvError: NaN or malformed poses or stiffness, horizon <= 0.
    """
    if not (np.isfinite(horizon_s) and horizon_s > 0.0):
        raise EnvError(f"flow horizon {horizon_s} s must be > 0")
    p = np.asarray(pos, dtype=np.float64)
    q = _unit(on_goal_hemisphere(quat, skill.goal_quat))
    try:
        if skill.layout == "joint":
            return skill.split_point(next_point(skill.models["joint"], skill.joint_point(p, q, stiffness), horizon_s))
        return (next_point(skill.models["position"], p, horizon_s),
                next_point(skill.models["orientation"], q, horizon_s), None)
    except RFlowError as err:
        raise EnvError(f"cannot query the skill at pos {p.tolist()}, quat {q.tolist()}: {err}") from None


@dataclass(frozen=True)
class Plan:
    """A generated pose trajectory sampled every ``period_s`` (first sample = the start).

    Attributes:
        period_s: sampling period (s).
        pos: (K, 3) positions, m.
        quat: (K, 4) unit quaternions on the goal's hemisphere.
        tangent: (K, 6) [p - g_p, Log_g(q)].
        stiffness: (K, 3, 3) generated translational stiffness clipped to the skill's bounds (N/m), or None
            for a skill without stiffness.
        stiffness_clipped: (K,) where that clip acted (None without stiffness).
    """

    period_s: float
    pos: FloatArray
    quat: FloatArray
    tangent: FloatArray
    stiffness: FloatArray | None = None
    stiffness_clipped: npt.NDArray[np.bool_] | None = None

    @property
    def times_s(self) -> FloatArray:
        """(K,) sample times from 0."""
        return self.period_s * np.arange(self.pos.shape[0])


def generate_plan(skill: PoseSkill, start: Pose, duration_s: float, period_s: float,
                  xi_pos_m: float = 1e-4, xi_rot_rad: float = 1e-4, start_stiffness: npt.ArrayLike | None = None) -> Plan:
    """Generate the skill's trajectory from ``start`` (Algorithm 1, exact latent steps of ``period_s``).

    Each model stops at its own threshold (``xi_pos_m`` on ||p - g_p||, ``xi_rot_rad`` on ||Log_g(q)||;
    the joint model stops on ||tangent|| < min of both) and then holds its goal. A stiffness skill starts
    its stiffness at ``start_stiffness`` (default: the skill's start stiffness).

    Args:
        skill: the trained skill.
        start: start pose.
        duration_s: length of the plan (s); K = round(duration / period) + 1 samples.
        period_s: step (s), e.g. the control period.

    Returns:
        The Plan.

    Raises:
        EnvError: bad durations or a start the models reject.
    """
    if not (np.isfinite(duration_s) and duration_s > 0.0 and np.isfinite(period_s) and period_s > 0.0):
        raise EnvError(f"plan duration {duration_s} s and period {period_s} s must be > 0")
    steps = int(round(duration_s / period_s))
    quat0 = on_goal_hemisphere(start.quat, skill.goal_quat)
    try:
        stiffness = clipped = None
        if skill.layout == "joint":
            k0 = (skill.start_stiffness if start_stiffness is None else start_stiffness) if skill.has_stiffness else None
            r = rollout(skill.models["joint"], skill.joint_point(start.pos, quat0, k0)[None], steps,
                        min(xi_pos_m, xi_rot_rad), period_s)
            pos, quat, stiffness = skill.split_point(r.points[0])
            if stiffness is not None:
                stiffness, clipped = skill.bound_stiffness(stiffness)
        else:
            pos = rollout(skill.models["position"], start.pos[None], steps, xi_pos_m, period_s).points[0]
            quat = rollout(skill.models["orientation"], quat0[None], steps, xi_rot_rad, period_s).points[0]
    except RFlowError as err:
        raise EnvError(f"cannot generate a plan from pos {start.pos.tolist()}: {err}") from None
    quat = on_goal_hemisphere(quat, skill.goal_quat)
    return Plan(period_s, pos, quat, skill.to_tangent(pos, quat), stiffness, clipped)


def _commanded_stiffness(setting: StiffnessSetting | None, learned: FloatArray | None) -> FloatArray | None:
    """The translational stiffness a policy commands: the learned (already bounded) one, K I, or None."""
    if setting is None:
        return None
    if setting.kind == "constant":
        return setting.constant_n_m * np.eye(3)
    return None if learned is None else learned.copy()


class ClosedLoopPolicy:
    """Command the flow's pose ``lookahead_s`` ahead of the measured peg_tip pose (module docstring), with the
    contact adaptation of `envs.execution.adaptation` near the hole: the flow is queried at x - delta (delta
    the frame shift the walls impose), its pose shifted back by + delta, the axial push added to the anchor,
    and the rotational stiffness lowered within the adaptation radius.

    For a stiffness skill the stiffness state K is integrated alongside (module docstring) whatever
    ``stiffness`` commands, since the joint model's pose part is conditioned on it.
    """

    def __init__(self, skill: PoseSkill, lookahead_s: float = DEFAULT_LOOKAHEAD_S, speed: float = 1.0,
                 stiffness: StiffnessSetting | None = None, adaptation: ContactAdaptation = ContactAdaptation()):
        if not (np.isfinite(lookahead_s) and lookahead_s > 0.0):
            raise EnvError(f"lookahead {lookahead_s} s must be > 0")
        if not (np.isfinite(speed) and speed > 0.0):
            raise EnvError(f"speed factor {speed} must be > 0")
        if stiffness is not None:
            stiffness.check_skill(skill)
        self.skill = skill
        self.lookahead_s = float(lookahead_s)
        self.speed = float(speed)
        self.stiffness = stiffness
        self.adapter = ContactAdapter(adaptation, skill.goal_pos, rotate(skill.goal_quat, [0.0, 0.0, 1.0]))
        self.stiffness_state: FloatArray | None = None
        self.stiffness_clipped_steps = 0
        self._period_s = 0.0
        self._flow_period_s = 0.0

    def reset(self, start: Pose, period_s: float) -> None:
        """Start an episode: no push or frame shift; the stiffness state (stiffness skills) starts at the
        skill's start stiffness."""
        self._flow_period_s = float(period_s) * self.speed
        self._period_s = float(period_s)
        self.adapter.reset()
        self.stiffness_state = self.skill.start_stiffness if self.skill.has_stiffness else None
        self.stiffness_clipped_steps = 0

    def command(self, step: int, measured: Pose) -> Command:
        """Target for control step ``step`` (from 0) given the measured peg_tip pose x: the flow's pose
        x_1 = Phi(L) x, L = ``lookahead_s``; the twist and acceleration at x from the flow poses x, x_1 and
        x_2 = Phi(2L) x (xi_1 = (x_1 - x)/L, xi_2 = (x_2 - x_1)/L, a = (xi_2 - xi_1)/L, xi = xi_1 - a L/2),
        both time-scaled by ``speed`` (xi * s, a * s^2). The flow is queried in the frame shifted and turned by
        the contact adaptation (p - delta and Exp(rho)^-1 q in; + delta, Exp(rho) q and R(rho) omega out)."""
        step_s = self.lookahead_s
        k = self.stiffness_state
        delta = self.adapter.frame
        turned = self.adapter.rotation.any()
        rho = np.array(self.adapter.rotation_quat)
        query = np.asarray(measured.pos, dtype=np.float64) - delta
        query_quat = quat_mul(quat_conj(rho), measured.quat) if turned else measured.quat
        p1, q1, k1 = skill_state_step(self.skill, query, query_quat, k, step_s)
        p2, q2 = skill_step(self.skill, p1, q1, step_s, k1)
        q1 = q1 / norm(q1)
        here = Pose(pos=query, quat=on_goal_hemisphere(query_quat, q1))
        xi1 = pose_twist(here.pos, here.quat, p1, q1, step_s)
        xi2 = pose_twist(p1, q1, p2, on_goal_hemisphere(q2, q1), step_s)
        accel = (xi2 - xi1) / step_s
        twist = xi1 - 0.5 * step_s * accel
        if turned:  # back from the turned frame: q1 <- Exp(rho) q1, angular rates rotated by R(rho)
            q1 = quat_mul(rho, q1)
            twist[3:], accel[3:] = rotate(rho, twist[3:]), rotate(rho, accel[3:])
        learned = None
        if k is not None:
            learned, clipped = self.skill.bound_stiffness(k)
            self.stiffness_clipped_steps += int(clipped)
            self.stiffness_state = skill_state_step(self.skill, query, query_quat, k, self._flow_period_s)[2]
        self.adapter.update(measured.pos, self.speed * twist[:3], self._period_s)
        self.adapter.update_rotation(measured.pos, measured.quat, self.speed * twist[3:], self._period_s)
        push = np.concatenate([self.adapter.push, np.zeros(3)])
        anchor = Pose(pos=here.pos + delta, quat=on_goal_hemisphere(measured.quat, q1) if turned else here.quat)
        return Command(Pose(pos=p1 + delta, quat=q1), self.speed * twist, anchor, self.speed**2 * accel,
                       _commanded_stiffness(self.stiffness, learned), push,
                       self.adapter.rotational_stiffness(measured.pos))


class OpenLoopPolicy:
    """Generate the whole trajectory at reset and play it back one sample per control step.

    With ``speed`` s the plan is generated with flow steps of s x the control period (the same path,
    s times as fast); twists and accelerations are taken per real control period.
    """

    def __init__(self, skill: PoseSkill, duration_s: float = 20.0, speed: float = 1.0,
                 stiffness: StiffnessSetting | None = None):
        if not (np.isfinite(speed) and speed > 0.0):
            raise EnvError(f"speed factor {speed} must be > 0")
        if stiffness is not None:
            stiffness.check_skill(skill)
        self.stiffness = stiffness
        self.skill = skill
        self.duration_s = float(duration_s)
        self.speed = float(speed)
        self.period_s = 0.0
        self.plan: Plan | None = None

    def reset(self, start: Pose, period_s: float) -> None:
        """Generate the plan from the measured start pose."""
        self.period_s = float(period_s)
        self.plan = generate_plan(self.skill, start, self.duration_s * self.speed, period_s * self.speed)

    def command(self, step: int, measured: Pose) -> Command:
        """The plan's sample ``step + 1`` (one period after the current time; the goal after the plan's
        end) with the plan's twist there (backward difference)."""
        plan = self.plan
        if plan is None:
            raise EnvError("OpenLoopPolicy.command before reset")
        last = plan.pos.shape[0] - 1
        k = min(step + 1, last)
        pose = Pose(pos=plan.pos[k].copy(), quat=plan.quat[k].copy())
        stiffness = _commanded_stiffness(self.stiffness, None if plan.stiffness is None else plan.stiffness[k])
        if k >= last:
            return Command(pose, np.zeros(6), pose, stiffness=stiffness)
        dt = self.period_s
        back = pose_twist(plan.pos[k - 1], plan.quat[k - 1], plan.pos[k], plan.quat[k], dt)
        ahead = pose_twist(plan.pos[k], plan.quat[k], plan.pos[k + 1], plan.quat[k + 1], dt)
        return Command(pose, 0.5 * (back + ahead), pose, (ahead - back) / dt, stiffness)

    @property
    def stiffness_clipped_steps(self) -> int:
        """Plan samples up to now whose generated stiffness the eigenvalue clip changed (0 without stiffness)."""
        plan = self.plan
        return 0 if plan is None or plan.stiffness_clipped is None else int(plan.stiffness_clipped.sum())


def make_policy(skill: PoseSkill, mode: str, lookahead_s: float = DEFAULT_LOOKAHEAD_S,
                duration_s: float = 20.0, speed: float = 1.0, stiffness: StiffnessSetting | None = None,
                adaptation: ContactAdaptation = ContactAdaptation()) -> ClosedLoopPolicy | OpenLoopPolicy:
    """The policy of ``mode`` ("closed-loop" or "open-loop"), commanding ``stiffness`` (None: the default);
    closed loop with the contact ``adaptation`` (open loop plays the plan as generated).

    Raises:
        EnvError: unknown mode, "learned" stiffness for a skill without one.
    """
    if mode == "closed-loop":
        return ClosedLoopPolicy(skill, lookahead_s, speed, stiffness, adaptation)
    if mode == "open-loop":
        return OpenLoopPolicy(skill, duration_s, speed, stiffness)
    raise EnvError(f"unknown mode {mode!r}; expected one of {', '.join(MODES)}")


def impedance_damping_lead(env: Any, twist: npt.ArrayLike, accel: npt.ArrayLike | None = None,
                           stiffness: npt.ArrayLike | None = None) -> FloatArray:
    """delta = K^-1 (D(q) twist + Lambda(q) accel) (6,): the pose lead that makes the impedance controller
    of ``env`` (Lambda x'' + D x' + K (x - x_cmd) = 0 in free space) follow ``twist`` and ``accel``
    (module docstring), computed by the controller itself from the current state of ``env`` (not changed),
    with the 6x6 ``stiffness`` to be commanded (None: the controller's default; D follows K).
    """
    return env.controller.pose_lead(env.data, twist, accel, stiffness)


def command_stiffness(env: Any, command: Command) -> FloatArray | None:
    """The 6x6 stiffness to pass to ``env.step`` with ``command``: `full_stiffness` of the command's translational
    stiffness and rotational stiffness, each the controller's default where the command has none; None (the
    default) when it has neither."""
    if command.stiffness is None and command.rotational_stiffness is None:
        return None
    config = env.controller.config
    k_trans = config.translational_stiffness * np.eye(3) if command.stiffness is None else command.stiffness
    k_rot = config.rotational_stiffness if command.rotational_stiffness is None else command.rotational_stiffness
    return full_stiffness(k_trans, k_rot)


MAX_SPEED_M_S: float = 0.5
"""The feed-forward twist is scaled down to at most this linear speed (the demos peak near 0.15 m/s)."""
MAX_ANGULAR_SPEED_RAD_S: float = 2.0
"""... and at most this angular speed."""


def limit_twist(twist: npt.ArrayLike, max_speed_m_s: float = MAX_SPEED_M_S,
                max_angular_speed_rad_s: float = MAX_ANGULAR_SPEED_RAD_S) -> FloatArray:
    """The twist scaled by one factor <= 1 so that |v| <= max_speed and |omega| <= max_angular_speed."""
    xi = np.asarray(twist, dtype=np.float64)
    v, w = xi[:3], xi[3:]
    speed, spin = norm(v), norm(w)
    factor = min(1.0, max_speed_m_s / speed if speed > 0 else 1.0, max_angular_speed_rad_s / spin if spin > 0 else 1.0)
    return xi * factor


MAX_ACCEL_M_S2: float = 2.0
"""The feed-forward acceleration is scaled down to at most this linear acceleration ..."""
MAX_ANGULAR_ACCEL_RAD_S2: float = 10.0
"""... and at most this angular acceleration."""


def limit_accel(accel: npt.ArrayLike) -> FloatArray:
    """The acceleration scaled by one factor <= 1 to |a| <= MAX_ACCEL_M_S2, |alpha| <= MAX_ANGULAR_ACCEL_RAD_S2."""
    return limit_twist(accel, MAX_ACCEL_M_S2, MAX_ANGULAR_ACCEL_RAD_S2)


def feedforward_pose(env: Any, command: Command, gain: float = 1.0) -> Pose:
    """The pose to send to ``env.step``: with gain > 0 the command's anchor led by gain * K^-1 D(q) twist
    (position + world-frame rotation vector: q' = exp(delta_r) q), the twist limited by `limit_twist`, K the
    stiffness commanded with it (`command_stiffness`); with gain 0 the command's pose."""
    if gain == 0.0:
        return command.pose
    return led_pose(env, command, gain, command_stiffness(env, command))


def led_pose(env: Any, command: Command, gain: float, stiffness: FloatArray | None) -> Pose:
    """`feedforward_pose` given the command's 6x6 stiffness as made by `command_stiffness(env, command)` (the
    episode loop makes it once and passes the same matrix to ``env.step``)."""
    if gain == 0.0:
        return command.pose
    twist = limit_twist(command.twist)
    raw = np.asarray(command.twist, dtype=np.float64)
    scale = norm(twist) / norm(raw) if raw.any() else 1.0  # ratio of the norms
    accel = limit_accel(scale * command.accel)
    lead = (gain * impedance_damping_lead(env, twist, accel, stiffness) + command.push).tolist()
    anchor = command.anchor
    quat = np.array(quat_mul_one(quat_from_rotvec_one(lead[3:]),
                                     np.asarray(anchor.quat, dtype=np.float64).tolist()))
    return Pose(pos=anchor.pos + np.array(lead[:3]), quat=quat / norm(quat))
