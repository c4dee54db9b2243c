"""Policies that turn a trained pose skill (`rflow.skill_io.PoseSkill`) into commanded peg_tip poses.

Closed loop (`ClosedLoopPolicy`, default of `pih evaluate`): every control step the MEASURED peg_tip pose
x = [p, q] is mapped to the tangent space at the goal, pushed ``lookahead_s`` along the learned flow and
mapped back; that pose is the impedance controller's target for the step:
    x_cmd = Exp_g( denorm( b( Phi(lookahead) b^-1( norm( Log_g(x) ) ) ) ) ),   Phi(t) = expm(V t),
one exact latent step of length ``lookahead_s`` (rflow.generate.next_point), separately for the position
and orientation models (or once for a joint model). A lookahead longer than the control period makes up
for the tracking lag of the compliant arm: the target leads the measured pose by ~lookahead of motion.

Near the hole the closed loop adapts to the contact (`envs.policies.adaptation`, not in the paper): an axial
integral push, a shift and a turn of the skill's frame onto the real hole when the walls refuse the flow's
sideways motion or rotation, and rotational compliance; `ContactAdaptation.off()` runs the bare flow.

Open loop (`OpenLoopPolicy`, the paper's robot experiment): the whole trajectory is generated once from
the measured start pose (rflow.generate.rollout, one point per control period, holding the goal after
convergence) and tracked in time.

Velocity feed-forward. Each action carries the flow's twist xi_d (finite differences over the step:
v = dp/dt, omega = rotvec(q1 conj(q0))/dt) and acceleration, and an anchor (closed loop: the measured pose); the
impedance controller leads the anchor by K^-1 (D xi_d + Lambda a_d) so that the compliant arm moves at the flow's
velocity (controllers.feedforward).

Both policies implement the `Policy` protocol (envs.policies.interface): ``reset(observation, period_s)``
and ``act(observation)`` read the measured tcp pose only (`reset_at` and `command` take that pose directly).

Measured quaternions are put on the goal's hemisphere first (q and -q are the same orientation).

Stiffness. A skill trained with `pih train --stiffness` also generates the translational
stiffness K (3x3, N/m, world frame): with a model on R^3 x SPD(3) beside the two pose models (layout
"separate_stiffness", the default) or inside one joint model on R^3 x S^3 x SPD(3) (``--joint``). Closed loop, the
pose is queried at the measured pose as above, while K is the model's own state (it is not measured): it starts at
the skill's start stiffness and follows the skill's progress, not the clock: each control period it takes one
exact flow step of rho T from [measured pose, K] (T the control period times ``speed``), rho = `progress_ratio` of
the peg's measured displacement over the last period to the flow's displacement asked for it, so the stiffness
holds while the walls hold the peg. Open loop, K is generated with the trajectory. Either
way the commanded K is the generated one with its eigenvalues clipped to the skill's [k_min, k_max]
(`PoseSkill.bound_stiffness`, counted in ``stiffness_clipped_steps``). `StiffnessSetting` chooses between
that learned stiffness, a constant isotropic K, the scripted expert's schedule K(h) at the measured pose's
height above the nominal mouth (closed loop; the teacher itself, as a learned stiffness could at best
reproduce it), or none (the controller's default); the controller makes the 6x6 matrix it holds
(`controllers.impedance.CartesianImpedanceController.action_stiffness`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
import numpy.typing as npt

from envs.errors import EnvError
from envs.policies import closed_loop_kernel as kernel
from envs.policies.adaptation import ContactAdaptation, ContactAdapter
from envs.policies.interface import Action, Observation
from envs.policies.insertion import InsertionPolicy
from envs.policies.skill_settings import DEFAULT_LOOKAHEAD_S, MODES, StiffnessSetting
from envs.policies.stiffness_schedule import expert_stiffness
from envs.poses import Pose, quat_conj, quat_mul, quat_mul_one, quat_to_rotvec, quat_to_rotvec_one, rotate
from numerics.errors import NumericsError
from numerics.small_linalg import dot
from rflow.generate import lookahead_points, next_point, rollout
from rflow.skill_io import PoseSkill

FloatArray = npt.NDArray[np.float64]

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
    except NumericsError as err:  # RFlowError too
        raise EnvError(f"cannot query the skill at pos {p.tolist()}, quat {q.tolist()}: {err}") from None


def skill_lookahead(skill: PoseSkill, pos: npt.ArrayLike, quat: Sequence[npt.ArrayLike], stiffness: Any,
                    horizon_s: float) -> tuple[FloatArray, FloatArray, FloatArray | None]:
    """The poses one and two ``horizon_s`` later along the flow from each row of a batch (B, 3), (B, 4) (with a joint
    skill's stiffness states (B, 3, 3) or None): (pos (2, B, 3), quat (2, B, 4), the joint skill's stiffness after
    the first step (B, 3, 3) or None). Row i of step 1 equals ``skill_state_step`` of row i and step 2
    ``skill_step`` from there, to the last bit (rflow.generate.lookahead_points: both steps of both pose models in
    one compiled call each; a joint skill row by row).

    Raises:
        EnvError: NaN or malformed poses or stiffness, horizon <= 0.
    """
    if not (np.isfinite(horizon_s) and horizon_s > 0.0):
        raise EnvError(f"flow horizon {horizon_s} s must be > 0")
    p = np.asarray(pos, dtype=np.float64)
    if skill.layout == "joint":
        first = [skill_state_step(skill, p[i], quat[i], None if stiffness is None else stiffness[i], horizon_s)
                 for i in range(p.shape[0])]
        second = [skill_state_step(skill, r[0], r[1], r[2], horizon_s) for r in first]
        k = None if first[0][2] is None else np.stack([r[2] for r in first])
        return (np.stack([[r[0] for r in first], [r[0] for r in second]]),
                np.stack([[r[1] for r in first], [r[1] for r in second]]), k)
    goal = skill.goal_quat
    q = np.stack([_unit(on_goal_hemisphere(np.asarray(row, dtype=np.float64), goal)) for row in quat])
    try:
        return (lookahead_points(skill.models["position"], p, horizon_s, 2),
                lookahead_points(skill.models["orientation"], q, horizon_s, 2, hemisphere=goal), None)
    except NumericsError as err:  # RFlowError too
        raise EnvError(f"cannot query the skill at a batch of {p.shape[0]} poses: {err}") from None


def stiffness_step(skill: PoseSkill, pos: npt.ArrayLike, quat: npt.ArrayLike, stiffness: npt.ArrayLike,
                   horizon_s: float) -> FloatArray:
    """A stiffness skill's stiffness state ``horizon_s`` later along its flow from [pose, K] (3, 3): the joint
    model's K part, or the "separate_stiffness" stiffness model's from [p, K] (the orientation is not its input).

    Raises:
        EnvError: a skill without stiffness, NaN or malformed input, horizon <= 0.
    """
    if not skill.has_stiffness:
        raise EnvError("stiffness_step needs a skill with a stiffness model")
    if skill.layout == "joint":
        return skill_state_step(skill, pos, quat, stiffness, horizon_s)[2]  # type: ignore[return-value]
    if not (np.isfinite(horizon_s) and horizon_s > 0.0):
        raise EnvError(f"flow horizon {horizon_s} s must be > 0")
    p = np.asarray(pos, dtype=np.float64)
    try:
        x = next_point(skill.models["stiffness"], skill.stiffness_point(p, stiffness), horizon_s)
    except NumericsError as err:  # RFlowError too
        raise EnvError(f"cannot query the stiffness model at pos {p.tolist()}: {err}") from None
    return x[3:].reshape(3, 3)


def progress_ratio(displacement: npt.ArrayLike, expected: npt.ArrayLike, floor_m: float = 1e-6) -> float:
    """How much of the step the flow asked for the peg made: rho = clip(d . e / (e . e), 0, 1) for the measured
    displacement d over a control period and the flow's displacement e asked for it; 1 when |e| < ``floor_m``
    (at the goal, nothing is asked). A peg the walls hold makes rho ~ 0."""
    e = np.asarray(expected, dtype=np.float64)
    ee = dot(e, e)
    if not ee >= floor_m * floor_m:
        return 1.0
    return min(1.0, max(0.0, dot(np.asarray(displacement, dtype=np.float64), e) / ee))


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
            if skill.has_stiffness:  # "separate_stiffness": K along the stiffness model's own flow from [p0, K0]
                k0 = skill.start_stiffness if start_stiffness is None else start_stiffness
                x = rollout(skill.models["stiffness"], skill.stiffness_point(start.pos, k0)[None], steps, 1e-12,
                            period_s).points[0]
                stiffness, clipped = skill.bound_stiffness(x[:, 3:].reshape(-1, 3, 3))
    except NumericsError as err:  # RFlowError too
        raise EnvError(f"cannot generate a plan from pos {start.pos.tolist()}: {err}") from None
    quat = on_goal_hemisphere(quat, skill.goal_quat)
    return Plan(period_s, pos, quat, skill.to_tangent(pos, quat), stiffness, clipped)


def _commanded_stiffness(setting: StiffnessSetting | None, own: FloatArray | None) -> FloatArray | None:
    """The translational stiffness a policy commands: K I, the policy's own K (the learned one, already bounded,
    or the closed loop's `ClosedLoopPolicy.scheduled_stiffness`), or None (the controller's default)."""
    if setting is None:
        return None
    if setting.kind == "constant":
        return setting.constant_n_m * np.eye(3)
    return None if own is None else own.copy()


class _PoseSkillPolicy:
    """The `Policy` protocol over a pose-level skill policy: ``reset`` starts it at the observation's measured tcp
    pose (``reset_at``) and ``act`` asks ``command`` for the next control step at that pose."""

    _step: int

    def reset_at(self, start: Pose, period_s: float) -> None:
        raise NotImplementedError

    def command(self, step: int, measured: Pose) -> Action:
        raise NotImplementedError

    def reset(self, observation: Observation, period_s: float) -> None:
        """`Policy.reset`: start an episode at the observation's measured tcp pose (`reset_at`)."""
        self.reset_at(observation.tcp, period_s)

    def act(self, observation: Observation) -> Action:
        """`Policy.act`: the action for the next control step at the observation's measured tcp pose (`command`)."""
        self._step += 1
        self.sense(observation)
        return self.command(self._step - 1, observation.tcp)

    def sense(self, observation: Observation) -> None:
        """Read what the policy senses besides the pose (nothing here; the closed loop's contact adaptation reads the
        wrench)."""


class ClosedLoopPolicy(_PoseSkillPolicy):
    """Command the flow's pose ``lookahead_s`` ahead of the measured peg_tip pose (module docstring), with the
    contact adaptation of `envs.policies.adaptation` near the hole: the flow is queried at x - delta (delta
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
        self._mouth_depth_m: float | None = None
        self._last_pos: FloatArray | None = None
        self._asked_step = np.zeros(3)
        self._period_s = 0.0
        self._flow_period_s = 0.0
        self._step = 0

    def sense(self, observation: Observation) -> None:
        """Hand the contact adaptation the sensed force on the tool in the world frame: the wrist wrench is in the
        sensor frame, whose axes are the hand's and the tcp's (envs.cell.scene), so R(q_tcp) F."""
        self.adapter.sense_wrench(observation.tcp.quat, observation.wrist_wrench)

    def reset(self, observation: Observation, period_s: float) -> None:
        """`Policy.reset`: `reset_at` the measured tcp pose, with the nominal hole's mouth for the stall search."""
        below = self.adapter.goal_pos - np.asarray(observation.nominal_hole.pos, dtype=np.float64)
        self.reset_at(observation.tcp, period_s, mouth_depth_m=dot(self.adapter.axis, below))

    def reset_at(self, start: Pose, period_s: float, mouth_depth_m: float | None = None) -> None:
        """Start an episode: no push, frame shift or search; ``mouth_depth_m``: how far the goal lies beyond the
        nominal hole's mouth along the axis (None: no stall search); the stiffness state (stiffness skills) starts
        at the skill's start stiffness."""
        if self.stiffness is not None and self.stiffness.kind == "schedule" and mouth_depth_m is None:
            raise EnvError("stiffness 'schedule' needs the nominal hole's mouth (reset with an observation)")
        self._step = 0
        self._flow_period_s = float(period_s) * self.speed
        self._period_s = float(period_s)
        self._mouth_depth_m = mouth_depth_m
        self._last_pos, self._asked_step = None, np.zeros(3)
        self.adapter.reset(mouth_depth_m)
        self.stiffness_state = self.skill.start_stiffness if self.skill.has_stiffness else None
        self.stiffness_clipped_steps = 0

    def command(self, step: int, measured: Pose) -> Action:
        """Action for control step ``step`` (from 0; unused) given the measured peg_tip pose x: the flow's pose
        x_1 = Phi(L) x, L = ``lookahead_s``; the twist and acceleration at x from the flow poses x, x_1 and
        x_2 = Phi(2L) x (xi_1 = (x_1 - x)/L, xi_2 = (x_2 - x_1)/L, a = (xi_2 - xi_1)/L, xi = xi_1 - a L/2),
        both time-scaled by ``speed`` (xi * s, a * s^2). The flow is queried in the frame shifted and turned by
        the contact adaptation (p - delta and Exp(rho)^-1 q in; + delta, Exp(rho) q and R(rho) omega out)."""
        query = self._query(measured)
        k = None if query.stiffness is None else query.stiffness[None]
        p, q, _ = skill_lookahead(self.skill, query.pos[None], [query.quat], k, self.lookahead_s)
        return self._complete(measured, query, p[0, 0], q[0, 0], p[1, 0], q[1, 0])

    def batch_key(self) -> tuple:
        """Policies of one skill with one lookahead and speed answer together (`act_many`)."""
        return (id(self.skill), self.lookahead_s, self.speed, self._flow_period_s)

    @staticmethod
    def act_many(policies: Sequence[ClosedLoopPolicy], observations: Sequence[Observation]) -> list[Any]:
        """`Policy.act` of several closed-loop policies of one skill (``batch_key``), each with its observation:
        the flow queries of all of them as one batch (`skill_lookahead`, row by row the arithmetic of one query,
        so each action is the one its own ``act`` gives to the last bit). Changes no policy when it raises; a policy
        whose own part fails after the batched query gets the exception in its place (envs.rollout.lockstep).

        Raises:
            EnvError: a query the skill rejects (NaN, off the manifold).
        """
        skill, lookahead = policies[0].skill, policies[0].lookahead_s
        queries = [p._query(o.tcp) for p, o in zip(policies, observations)]
        pos = np.array([q.pos for q in queries])
        quat = [q.quat for q in queries]
        k = None if queries[0].stiffness is None else np.array([q.stiffness for q in queries])
        p, q, _ = skill_lookahead(skill, pos, quat, k, lookahead)
        p1, q1, p2, q2 = p[0], q[0], p[1], q[1]
        actions: list[Any] = []
        for i, (policy, observation, query) in enumerate(zip(policies, observations, queries)):
            try:
                policy._step += 1
                policy.sense(observation)
                actions.append(policy._complete(observation.tcp, query, p1[i], q1[i], p2[i], q2[i]))
            except Exception as err:  # this policy's own part: its episode ends, the others go on
                actions.append(err)
        return actions

    def _query(self, measured: Pose) -> _Query:
        """Where the flow is queried for the measured pose: in the frame shifted by delta and turned by Exp(rho)
        (only near the hole, after the walls refused a rotation); changes nothing (compiled,
        `closed_loop_kernel.query_into`)."""
        pos, quat, delta, rho = np.empty(3), np.empty(4), np.empty(3), np.empty(4)
        turned = kernel.query_into(self.adapter.state, np.asarray(measured.pos, dtype=np.float64),
                                   np.asarray(measured.quat, dtype=np.float64), pos, quat, delta, rho)
        return _Query(pos, quat, delta, rho, turned, self.stiffness_state)

    def _complete(self, measured: Pose, query: _Query, p1: FloatArray, q1: FloatArray, p2: FloatArray,
                  q2: FloatArray) -> Action:
        """The action from the flow's poses x_1 = Phi(L) x and x_2 = Phi(L) x_1 at the query (`command`), and the
        policy's state advanced (adaptation, stiffness state): the pose, twist, acceleration and anchor compiled
        (`closed_loop_kernel.action_into`)."""
        out = np.empty(kernel.ACTION_SIZE)
        mpos = np.asarray(measured.pos, dtype=np.float64)
        mquat = np.asarray(measured.quat, dtype=np.float64)
        kernel.action_into(mpos, mquat, query.pos, query.quat, query.delta, query.rho, query.turned, p1, q1, p2, q2,
                           self.lookahead_s, self.speed, self.speed**2, out)
        twist = out[kernel.ACTION_TWIST:kernel.ACTION_TWIST + 6]
        learned = None
        k = query.stiffness
        if k is not None:
            learned, clipped = self.skill.bound_stiffness(k)
            self.stiffness_clipped_steps += int(clipped)
            self.stiffness_state = self._next_stiffness(measured.pos, query, k, twist[:3])
        self.adapter.update(mpos, twist[:3], self._period_s)
        self.adapter.update_rotation(mpos, mquat, twist[3:], self._period_s)
        scheduled = self.stiffness is not None and self.stiffness.kind == "schedule"
        own = self.scheduled_stiffness(measured.pos) if scheduled else learned
        return Action(Pose(pos=out[kernel.ACTION_POS:kernel.ACTION_POS + 3],
                           quat=out[kernel.ACTION_QUAT:kernel.ACTION_QUAT + 4]),
                      _commanded_stiffness(self.stiffness, own), self.adapter.rotational_stiffness(mpos), twist,
                      out[kernel.ACTION_ACCEL:kernel.ACTION_ACCEL + 6],
                      Pose(pos=out[kernel.ACTION_ANCHOR_POS:kernel.ACTION_ANCHOR_POS + 3],
                           quat=out[kernel.ACTION_ANCHOR_QUAT:kernel.ACTION_ANCHOR_QUAT + 4]),
                      self.adapter.push_action())

    def _next_stiffness(self, pos: npt.ArrayLike, query: _Query, k: FloatArray, velocity: FloatArray) -> FloatArray:
        """The stiffness state after this period: one flow step of rho T from [query pose, K] (module docstring;
        rho from the displacement since the last period against the step then asked for, 1 at the first
        period); remembers this period's position and the step asked for now (``velocity`` T)."""
        here = np.asarray(pos, dtype=np.float64)
        rho = 1.0 if self._last_pos is None else progress_ratio(here - self._last_pos, self._asked_step)
        self._last_pos, self._asked_step = here.copy(), velocity * self._period_s
        if rho <= 0.0:
            return k
        return stiffness_step(self.skill, query.pos, query.quat, k, rho * self._flow_period_s)

    def scheduled_stiffness(self, pos: npt.ArrayLike) -> FloatArray:
        """K(h) of the "schedule" stiffness (`envs.policies.stiffness_schedule.expert_stiffness`) at the measured
        peg_tip position: h = (p - o) . (-a), the height above the nominal mouth o = g - d a (g the skill's goal, a its
        insertion axis, d the goal's depth below the nominal mouth, from `reset`), axis -a out of the hole."""
        setting, depth = self.stiffness, self._mouth_depth_m
        if setting is None or setting.schedule is None or depth is None:
            raise EnvError("scheduled_stiffness needs a 'schedule' stiffness and a reset with the nominal hole")
        axis = self.adapter.axis
        return expert_stiffness(pos, self.adapter.goal_pos - depth * axis, -axis, setting.schedule)


@dataclass(frozen=True)
class _Query:
    """Where a closed-loop policy queries its flow this period (`ClosedLoopPolicy._query`): the position p - delta
    and quaternion Exp(rho)^-1 q in the adaptation's frame, the frame shift delta, Exp(rho) (the identity when not
    turned), whether the frame is turned, and the stiffness state (None: a skill without stiffness)."""

    pos: FloatArray
    quat: FloatArray
    delta: FloatArray
    rho: FloatArray
    turned: bool
    stiffness: FloatArray | None


class OpenLoopPolicy(_PoseSkillPolicy):
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
            if stiffness.kind == "schedule":
                raise EnvError("stiffness 'schedule' reads the measured pose: use the closed loop")
        self.stiffness = stiffness
        self.skill = skill
        self.duration_s = float(duration_s)
        self.speed = float(speed)
        self.period_s = 0.0
        self.plan: Plan | None = None
        self._step = 0

    def reset_at(self, start: Pose, period_s: float) -> None:
        """Generate the plan from the measured start pose."""
        self._step = 0
        self.period_s = float(period_s)
        self.plan = generate_plan(self.skill, start, self.duration_s * self.speed, period_s * self.speed)

    def command(self, step: int, measured: Pose) -> Action:
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
            return Action(pose, stiffness, twist=np.zeros(6), anchor=pose)
        dt = self.period_s
        back = pose_twist(plan.pos[k - 1], plan.quat[k - 1], plan.pos[k], plan.quat[k], dt)
        ahead = pose_twist(plan.pos[k], plan.quat[k], plan.pos[k + 1], plan.quat[k + 1], dt)
        return Action(pose, stiffness, twist=0.5 * (back + ahead), accel=(ahead - back) / dt, anchor=pose)

    @property
    def stiffness_clipped_steps(self) -> int:
        """Plan samples up to now whose generated stiffness the eigenvalue clip changed (0 without stiffness)."""
        plan = self.plan
        return 0 if plan is None or plan.stiffness_clipped is None else int(plan.stiffness_clipped.sum())


def make_policy(skill: PoseSkill, mode: str, lookahead_s: float = DEFAULT_LOOKAHEAD_S,
                duration_s: float = 20.0, speed: float = 1.0, stiffness: StiffnessSetting | None = None,
                adaptation: ContactAdaptation = ContactAdaptation()) -> ClosedLoopPolicy | InsertionPolicy | OpenLoopPolicy:
    """The policy of ``mode`` ("closed-loop" or "open-loop"), commanding ``stiffness`` (None: the default);
    closed loop with the contact ``adaptation`` (its insertion part wraps the closed loop in an `InsertionPolicy`,
    envs.policies.insertion); open loop plays the plan as generated.

    Raises:
        EnvError: unknown mode, "learned" stiffness for a skill without one.
    """
    if mode == "closed-loop":
        closed = ClosedLoopPolicy(skill, lookahead_s, speed, stiffness, adaptation)
        if not adaptation.insertion:
            return closed
        return InsertionPolicy(closed, Pose(pos=skill.goal_pos, quat=skill.goal_quat))
    if mode == "open-loop":
        return OpenLoopPolicy(skill, duration_s, speed, stiffness)
    raise EnvError(f"unknown mode {mode!r}; expected one of {', '.join(MODES)}")
