"""Any policy run in the frame of the hole the cell observes (`pih evaluate --follow-observed-hole`).

A skill learned from demonstrations knows the hole where the demonstrations ended: its reference goal g (for the
flow skill, the demos' mean end). When the cell observes where this episode's hole is (the task's
``hole_observation``; with ``"measured"`` a sensor that sees the part, envs.task.perturbation), the policy can run in
that hole's frame. With b the observed goal (the policy's ``nominal_goal``), the rigid motion that takes g onto b is

    T = T_b T_g^-1:   R_T = R_b R_g^T  (q_T = q_b conj(q_g)),   t_T = p_b - R_T p_g,

and the inner policy sees every pose of its observation moved back by T^-1 (x_s = R_T^T (x - t_T), q_s = conj(q_T)
q), so the observed goal sits at g, and every command it returns is moved on by T (x = R_T x_s + t_T, q = q_T q_s;
twists, accelerations and push offsets rotate by R_T, a world-frame stiffness K becomes R_T K R_T^T). The wrist
wrench is in the sensor frame and the joint readings in joint space: they pass as they are (a policy that reads the
joint positions sees the real arm).

T is taken once per episode, at ``reset``, from the observed goal. Where that goal is the reference goal itself (to
the bit), T is the identity and observations and actions pass unchanged, so the inner policy's records are its own.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Sequence

import numpy as np
import numpy.typing as npt

from envs.policies.interface import Action, Observation, PrivilegedState
from envs.poses import Pose
from numerics.quaternion import quat_conj, quat_mul, quat_to_mat
from numerics.small_linalg import matmul, matvec

FloatArray = npt.NDArray[np.float64]


@dataclasses.dataclass(frozen=True)
class RigidMotion:
    """x -> R x + t, q -> q_T q (the module docstring's T), with R = R(q_T)."""

    quat: FloatArray
    rotation: FloatArray
    translation: FloatArray

    @classmethod
    def between(cls, reference: Pose, observed: Pose) -> RigidMotion:
        """T = T_observed T_reference^-1: the motion that takes ``reference`` onto ``observed``."""
        quat = quat_mul(np.asarray(observed.quat, dtype=np.float64), quat_conj(np.asarray(reference.quat,
                                                                                           dtype=np.float64)))
        rotation = quat_to_mat(quat)
        translation = np.asarray(observed.pos, dtype=np.float64) - matvec(rotation, np.asarray(reference.pos,
                                                                                             dtype=np.float64))
        return cls(quat, rotation, translation)

    def pose(self, pose: Pose) -> Pose:
        """T x: (R p + t, q_T q)."""
        return Pose(matvec(self.rotation, np.asarray(pose.pos, dtype=np.float64)) + self.translation,
                    quat_mul(self.quat, np.asarray(pose.quat, dtype=np.float64)))

    def inverse_pose(self, pose: Pose) -> Pose:
        """T^-1 x: (R^T (p - t), conj(q_T) q)."""
        return Pose(matvec(self.rotation.T.copy(), np.asarray(pose.pos, dtype=np.float64) - self.translation),
                    quat_mul(quat_conj(self.quat), np.asarray(pose.quat, dtype=np.float64)))

    def vector(self, v: npt.ArrayLike) -> FloatArray:
        """R v of a (3,) vector."""
        return matvec(self.rotation, np.asarray(v, dtype=np.float64))

    def inverse_vector(self, v: npt.ArrayLike) -> FloatArray:
        """R^T v of a (3,) vector."""
        return matvec(self.rotation.T.copy(), np.asarray(v, dtype=np.float64))

    def twist(self, xi: npt.ArrayLike) -> FloatArray:
        """[R v; R w] of a (6,) twist, acceleration or offset [linear; angular]."""
        xi = np.asarray(xi, dtype=np.float64)
        return np.concatenate([self.vector(xi[:3]), self.vector(xi[3:])])

    def stiffness(self, k: npt.ArrayLike) -> FloatArray:
        """R K R^T of a (3, 3) stiffness, blockdiag(R, R) K blockdiag(R, R)^T of a (6, 6) one."""
        k = np.asarray(k, dtype=np.float64)
        r = self.rotation if k.shape == (3, 3) else np.kron(np.eye(2), self.rotation)
        return matmul(matmul(r, k), r.T.copy())


class GoalFramePolicy:
    """A `Policy` that runs ``inner`` in the frame of the observed goal (module docstring).

    Args:
        inner: any policy (``reset``, ``act``; a class with ``act_many`` keeps answering in batches).
        reference: the goal the inner policy knows (the flow skill's own goal; a user's policy, the task's
            nominal goal).
    """

    def __init__(self, inner: Any, reference: Pose):
        self.inner = inner
        self.reference = Pose(np.asarray(reference.pos, dtype=np.float64), np.asarray(reference.quat, dtype=np.float64))
        self.motion: RigidMotion | None = None

    def reset(self, observation: Observation, period_s: float) -> None:
        """Take T from the observed goal (the identity when it is the reference) and reset the inner policy."""
        goal = observation.nominal_goal
        same = (np.array_equal(np.asarray(goal.pos, dtype=np.float64), self.reference.pos)
                and np.array_equal(np.asarray(goal.quat, dtype=np.float64), self.reference.quat))
        self.motion = None if same else RigidMotion.between(self.reference, goal)
        self.inner.reset(self.to_inner(observation), period_s)

    def act(self, observation: Observation) -> Action:
        """The inner policy's action on the observation moved into its frame, moved back into the world."""
        return self.to_world(self.inner.act(self.to_inner(observation)))

    def batch_key(self) -> Any:
        """The inner policy's batch key where its class answers in batches, else this policy's own."""
        if callable(getattr(type(self.inner), "act_many", None)):
            return (type(self.inner), self.inner.batch_key())
        return id(self)

    @staticmethod
    def act_many(policies: Sequence[GoalFramePolicy], observations: Sequence[Observation]) -> list[Any]:
        """`act` of several policies of one ``batch_key``: the inner policies' ``act_many`` on their moved
        observations (each inner action moved back; an exception in a policy's place passes as it is)."""
        inner_class = type(policies[0].inner)
        if not callable(getattr(inner_class, "act_many", None)):
            return [p.act(o) for p, o in zip(policies, observations)]
        actions = inner_class.act_many([p.inner for p in policies],
                                       [p.to_inner(o) for p, o in zip(policies, observations)])
        return [a if isinstance(a, Exception) else p.to_world(a) for p, a in zip(policies, actions)]

    def to_inner(self, observation: Observation) -> Observation:
        """The observation with its poses (tcp, nominal hole and goal, the privileged truth) moved by T^-1."""
        motion = self.motion
        if motion is None:
            return observation
        truth = observation.privileged
        if truth is not None:
            truth = PrivilegedState(motion.inverse_pose(truth.hole), motion.inverse_vector(truth.hole_axis),
                                    motion.inverse_pose(truth.goal))
        return dataclasses.replace(observation, tcp=motion.inverse_pose(observation.tcp),
                                   nominal_hole=motion.inverse_pose(observation.nominal_hole),
                                   nominal_goal=motion.inverse_pose(observation.nominal_goal), privileged=truth)

    def to_world(self, action: Action) -> Action:
        """The inner policy's action moved by T (poses, twist, acceleration, push, stiffness)."""
        motion = self.motion
        if motion is None or not isinstance(action, Action):
            return action
        return Action(pose=motion.pose(action.pose),
                      stiffness=None if action.stiffness is None else motion.stiffness(action.stiffness),
                      rotational_stiffness=action.rotational_stiffness,
                      twist=None if action.twist is None else motion.twist(action.twist),
                      accel=None if action.accel is None else motion.twist(action.accel),
                      anchor=None if action.anchor is None else motion.pose(action.anchor),
                      push=None if action.push is None else motion.twist(action.push))


__all__ = ["GoalFramePolicy", "RigidMotion"]
