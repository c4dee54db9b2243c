"""The skill's insertion near the hole: from the peg's first touch on the part, a force-regulated spiral search with a
wiggle about the insertion axis until the peg is in the bore, then a speed-limited, force-capped insertion with the
wrist compliant across the axis.

Why. The learned flow knows the demonstrated hole. In a real cell the peg's tip lands beside it by the hole's pose
error plus the peg's pose error in the hand (up to 1 mm + 1 mm + 90 mm x 1 deg = 3.6 mm in the realistic cell), beyond
the 1 mm chamfer's reach, and a square peg meets the hole turned by up to 2 deg where 0.38 deg fit a 0.2 mm clearance;
the flow, asked at a pose it never saw, stalls there or drives the peg into the part's top. A torque-controlled arm
inserts as industrial insertion skills do: it holds a contact force along the hole's axis through its impedance,
searches across the axis, and turns the peg a little about the axis so the corners find the hole's.

Phases (a the skill's insertion axis, the goal's peg axis; h = a^T p the measured tcp's position along it; the sensed
force against the axis F_a = -a^T R(q_tcp) (f - f_0), f_0 the wrist reading at the episode's start in free space, its
tare):

1. approach: the inner skill's action, until the peg touches the part near the hole: |p - g_p| < ``radius_m`` and
   F_a > ``touch_force_n``. The touch fixes the search's centre c (the tcp then), its height h_0 and the orientation
   q_0 the skill then commanded.
2. search: the command is p_cmd = c_perp + s(t) + a (h + F / K_a), the lateral offset s along an Archimedean spiral of
   pitch ``spiral_pitch_m`` (so it passes within half a pitch of every point it covers, less than the chamfer's
   reach), at ``spiral_speed_m_s`` along it, out to ``spiral_radius_m``; the stiffness K_l across the axis and K_a
   along it holds the force F = ``force_n`` against the part; the orientation q(t) = Exp(a psi sin(2 pi f t)) q_0
   wiggles by ``wiggle_deg`` at ``wiggle_hz`` (more than the worst turn of a square peg against its hole) with
   the rotational stiffness ``search_rotational_stiffness_nm_rad`` (stiff enough that the peg does not tilt as the
   spiral drags it). The peg is in the bore once h - h_0 > ``entry_depth_m`` (twice the chamfer).
3. insert: along the axis a reference h_r advancing at ``insert_speed_m_s`` but never more than F / K_a ahead of the
   measured tcp (h_r <- min(h_r + v T, h + F / K_a): the peg descends at v in the bore and presses with at most F on
   its floor, so it reaches the floor without the impact a free push would give; and never past the goal by more than
   ``overshoot_m``); across the axis the measured
   position (no lateral force: the walls guide the peg), the rotation q_0 with the compliant
   ``insert_rotational_stiffness_nm_rad`` (a remote-centre compliance at the tcp, the peg's tip), q_0 following the
   measured rotation q with the time constant ``follow_s``, q_0 <- Exp((T / tau) Log(q q_0^-1)) q_0, so the walls
   turn the peg into line and the spring's moment that would press it on them (and wedge it) fades; when the tip made
   no progress along the axis for ``wedge_s`` (a wedged peg) the wiggle resumes until it moves again.

The seated-success check stays the physics' (envs.task.success); this policy only commands poses and stiffnesses.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
import numpy.typing as npt

from envs.policies.interface import Action, Observation
from envs.poses import Pose
from envs.task.task import check_number
from numerics.quaternion import quat_conj, quat_from_rotvec, quat_mul, quat_to_mat, quat_to_rotvec
from numerics.small_linalg import dot, matvec, norm

FloatArray = npt.NDArray[np.float64]

APPROACH, SEARCH, INSERT = "approach", "search", "insert"
"""The phases (module docstring)."""
PROGRESS_M: float = 0.0002
"""Progress along the axis that counts against a wedge, m: above the tip's jitter under the insertion force."""


@dataclass(frozen=True)
class InsertionConfig:
    """Settings of the insertion (module docstring); each threshold's physical reason in docs/design.md.

    Attributes:
        touch_force_n: the sensed force against the axis that says the peg sits on the part, N (above the joint
            torque sensors' wrench estimate's noise, well below the force limit).
        radius_m: distance of the tcp from the skill's goal within which a touch is the hole's, m (the mouth is 30 mm
            above the goal).
        force_n: the force held along the axis while searching and the most pressed while inserting, N.
        axial_stiffness_n_m, lateral_stiffness_n_m: the stiffness along and across the axis, N/m.
        search_rotational_stiffness_nm_rad, insert_rotational_stiffness_nm_rad: the rotational stiffness while
            searching and while inserting, N m/rad.
        spiral_pitch_m, spiral_speed_m_s, spiral_radius_m: the search spiral's pitch, speed along it and largest
            radius.
        wiggle_deg, wiggle_hz: the turn about the axis while searching (and while wedged), amplitude and frequency.
        capture_depth_m: how far past the touch along the axis the peg is on the chamfer, m: the spiral stops there
            and the chamfer centres the peg (a third of the 1 mm chamfer: beyond the tip's jitter on the flat top).
        entry_depth_m: how far past the touch along the axis the peg is in the bore, m.
        insert_speed_m_s: the speed of the insertion's reference along the axis, m/s.
        wedge_s: time without progress along the axis after which the wiggle resumes, s.
        follow_s: the time constant with which the commanded orientation follows the measured one while inserting,
            s: the walls turn the peg into line, and the rotational spring's moment, which would press the peg on
            them (and wedge it), fades.
        overshoot_m: how far past the skill's goal along the axis the insertion's reference may go, m: a peg that sits
            farther in the hand than in the demonstrations (the realistic cell's grasp offset, up to 3 mm) reaches
            the floor there; a hole deeper than the goal is not followed further.

    Raises:
        EnvError: a field that is not a finite number > 0 (one line naming it).
    """

    touch_force_n: float = 3.0
    radius_m: float = 0.035
    force_n: float = 8.0
    axial_stiffness_n_m: float = 1000.0
    lateral_stiffness_n_m: float = 2000.0
    search_rotational_stiffness_nm_rad: float = 20.0
    insert_rotational_stiffness_nm_rad: float = 5.0
    spiral_pitch_m: float = 0.0008
    spiral_speed_m_s: float = 0.004
    spiral_radius_m: float = 0.004
    wiggle_deg: float = 3.0
    wiggle_hz: float = 2.0
    capture_depth_m: float = 0.0003
    entry_depth_m: float = 0.002
    insert_speed_m_s: float = 0.01
    wedge_s: float = 1.5
    follow_s: float = 1.0
    overshoot_m: float = 0.003

    def __post_init__(self) -> None:
        for field in dataclasses.fields(self):
            check_number(f"InsertionConfig.{field.name}", getattr(self, field.name), strict=True)


class InsertionPolicy:
    """A `Policy` that runs ``inner`` until the peg touches the part near the hole, then searches and inserts
    (module docstring).

    Args:
        inner: the skill (any policy; a class with ``act_many`` keeps answering in batches).
        goal: the skill's goal pose (its axis, z of the goal's rotation, is the insertion axis a).
        config: the settings.
    """

    def __init__(self, inner: Any, goal: Pose, config: InsertionConfig = InsertionConfig()):
        self.inner = inner
        self.config = config
        self.goal_pos = np.asarray(goal.pos, dtype=np.float64).copy()
        self.axis = quat_to_mat(np.asarray(goal.quat, dtype=np.float64))[:, 2].copy()
        a = self.axis
        helper = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        e1 = helper - dot(helper, a) * a
        self.e1 = e1 / norm(e1)
        self.e2 = np.cross(a, self.e1)
        across = np.eye(3) - np.outer(a, a)
        self.stiffness = config.lateral_stiffness_n_m * across + config.axial_stiffness_n_m * np.outer(a, a)
        self._reset_state()

    def _reset_state(self) -> None:
        self.phase = APPROACH
        self.period_s = 0.0
        self.time_s = 0.0
        self.tare = np.zeros(3)
        self.centre = np.zeros(3)
        self.touch_height = 0.0
        self.hold_quat = np.array([1.0, 0.0, 0.0, 0.0])
        self.spiral_phase = 0.0
        self.reference = 0.0
        self.deepest = 0.0
        self.progress_s = 0.0

    def reset(self, observation: Observation, period_s: float) -> None:
        """Start an episode in the approach, taring the wrist reading (the start is at rest in free space)."""
        self._reset_state()
        self.period_s = float(period_s)
        self.tare = np.asarray(observation.wrist_wrench, dtype=np.float64)[:3].copy()
        self.inner.reset(observation, period_s)

    def act(self, observation: Observation) -> Action:
        """The inner skill's action until the touch, then the search's and the insertion's."""
        return self.complete(observation, self.inner.act(observation))

    def batch_key(self) -> Any:
        """The inner policy's batch key where its class answers in batches, else this policy's own."""
        if callable(getattr(type(self.inner), "act_many", None)):
            return (type(self), type(self.inner), self.inner.batch_key())
        return id(self)

    @staticmethod
    def act_many(policies: Sequence[InsertionPolicy], observations: Sequence[Observation]) -> list[Any]:
        """`act` of several policies of one ``batch_key``: the inner policies' ``act_many``, then each one's own
        phase (an exception in a policy's place passes as it is)."""
        inner_class = type(policies[0].inner)
        if not callable(getattr(inner_class, "act_many", None)):
            return [p.act(o) for p, o in zip(policies, observations)]
        actions = inner_class.act_many([p.inner for p in policies], list(observations))
        out: list[Any] = []
        for policy, observation, action in zip(policies, observations, actions):
            if isinstance(action, Exception):
                out.append(action)
                continue
            try:
                out.append(policy.complete(observation, action))
            except Exception as err:  # this policy's own part: its episode ends, the others go on
                out.append(err)
        return out

    def resistance_n(self, observation: Observation) -> float:
        """F_a: the tared sensed force against the insertion axis, N."""
        force = np.asarray(observation.wrist_wrench, dtype=np.float64)[:3] - self.tare
        world = matvec(quat_to_mat(np.asarray(observation.tcp.quat, dtype=np.float64)), force)
        return -dot(self.axis, world)

    def complete(self, observation: Observation, inner_action: Any) -> Any:
        """This period's action from the inner skill's (module docstring); advances the phase."""
        config, a = self.config, self.axis
        pos = np.asarray(observation.tcp.pos, dtype=np.float64)
        if self.phase == APPROACH:
            near = norm(pos - self.goal_pos) < config.radius_m
            if not (near and isinstance(inner_action, Action) and self.resistance_n(observation) > config.touch_force_n):
                return inner_action
            self.phase = SEARCH
            self.centre = pos.copy()
            self.touch_height = dot(a, pos)
            self.hold_quat = np.asarray(inner_action.pose.quat, dtype=np.float64).copy()
        self.time_s += self.period_s
        height = dot(a, pos)
        if self.phase == SEARCH:
            depth = height - self.touch_height
            if config.capture_depth_m < depth <= config.entry_depth_m:
                return self._centring_action(pos, height)
            if depth <= config.entry_depth_m:
                return self._search_action(height)
            self.phase = INSERT
            self.reference = height
            self.deepest = height
            self.progress_s = self.time_s
        return self._insert_action(pos, np.asarray(observation.tcp.quat, dtype=np.float64), height)

    def _wiggle(self) -> FloatArray:
        """Exp(a psi sin(2 pi f t)) q_0."""
        config = self.config
        angle = math.radians(config.wiggle_deg) * math.sin(2.0 * math.pi * config.wiggle_hz * self.time_s)
        return quat_mul(quat_from_rotvec(self.axis * angle), self.hold_quat)

    def _search_action(self, height: float) -> Action:
        config, a = self.config, self.axis
        pitch = config.spiral_pitch_m
        radius = min(pitch * self.spiral_phase / (2.0 * math.pi), config.spiral_radius_m)
        self.spiral_phase += config.spiral_speed_m_s * self.period_s / max(radius, 0.5 * pitch)
        radius = min(pitch * self.spiral_phase / (2.0 * math.pi), config.spiral_radius_m)
        offset = radius * (math.cos(self.spiral_phase) * self.e1 + math.sin(self.spiral_phase) * self.e2)
        across = self.centre - dot(a, self.centre) * a
        target = across + offset + a * (height + config.force_n / config.axial_stiffness_n_m)
        return Action(Pose(pos=target, quat=self._wiggle()), self.stiffness,
                      config.search_rotational_stiffness_nm_rad)

    def _centring_action(self, pos: FloatArray, height: float) -> Action:
        """On the chamfer: the measured position across the axis (no lateral force: the chamfer centres the peg), the
        force along it, the wiggle."""
        config, a = self.config, self.axis
        target = pos - height * a + a * (height + config.force_n / config.axial_stiffness_n_m)
        return Action(Pose(pos=target, quat=self._wiggle()), self.stiffness, config.search_rotational_stiffness_nm_rad)

    def _insert_action(self, pos: FloatArray, quat: FloatArray, height: float) -> Action:
        config, a = self.config, self.axis
        if height > self.deepest + PROGRESS_M:
            self.deepest, self.progress_s = height, self.time_s
        self.reference = min(self.reference + config.insert_speed_m_s * self.period_s,
                             height + config.force_n / config.axial_stiffness_n_m,
                             dot(a, self.goal_pos) + config.overshoot_m)
        turn = quat_to_rotvec(quat_mul(quat, quat_conj(self.hold_quat)))
        self.hold_quat = quat_mul(quat_from_rotvec(turn * min(1.0, self.period_s / config.follow_s)), self.hold_quat)
        wedged = self.time_s - self.progress_s > config.wedge_s
        target = pos - height * a + self.reference * a
        return Action(Pose(pos=target, quat=self._wiggle() if wedged else self.hold_quat), self.stiffness,
                      config.insert_rotational_stiffness_nm_rad)


__all__ = ["InsertionConfig", "InsertionPolicy"]
