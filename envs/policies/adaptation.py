"""Contact adaptation of the closed-loop skill near the hole: push along the insertion axis, let the walls move
and turn the skill's frame, and turn the wrist compliant in rotation.

Why. The learned flow knows only the demonstrated hole. With a hole-pose error the walls hold the peg up to
~1 mm beside the demos' final path, where the flow asks to move back sideways and barely down (it stalls on
the chamfer or inside the hole with ~0.1 N of contact force on the contact task). And a hole turned
or tilted by up to 1 deg jams a 30 mm square peg held at 80 N m/rad (0.38 deg of yaw fit a 0.2 mm clearance).

What. With the flow's twist xi_d at the measured pose and the measured velocity v, the leaky integral of the
velocity error (T the control period, tau the leak time)
    e_{k+1} = (1 - T / tau) e_k + (xi_d - v)_p T
is split about the skill's insertion axis a (the goal's peg axis, z of R_goal):
  - axial push   u = a a^T e, |u| <= ``push_limit_m``, added to the commanded pose: when the walls stop the peg
    (v = 0) the impedance force grows toward K tau xi_d instead of the ~1 N of the damping feed-forward alone;
    in free space v ~ xi_d and u stays near 0;
  - frame shift  delta_{k+1} = sat(delta_k - (I - a a^T)(xi_d - v)_p T),  |delta| <= ``frame_limit_m``, only
    within ``radius_m`` of the goal: the flow is queried at x - delta and its command shifted by + delta, so a
    sideways motion the walls refuse moves the skill's frame onto the real hole instead of pressing the peg
    into the wall (an admittance of the goal to the contact; the flow's own convergence is unchanged);
  - frame rotation: the same admittance for orientation. With the flow's angular velocity omega_d and the measured
    rotation over the period r = Log(q_k q_{k-1}^-1) (world frame), within ``radius_m`` of the goal
        rho_{k+1} = sat( Log( Exp(-(omega_d T - r)) Exp(rho_k) ),  ``frame_limit_deg`` ),
    and the flow is queried at Exp(rho)^-1 q and its command turned back by Exp(rho) (twist and acceleration
    rotated by R(rho)). Why: a hole tilted or turned by up to 1 deg holds the peg off the demos' goal orientation,
    the flow asks to turn back, and the velocity feed-forward turns that request into a lead K^-1 D omega_d, a
    torque D omega_d away from the hole's axis that does not vanish while the walls hold the peg, so the peg wedges
    against a tilted hole. Letting the skill's frame turn with the walls
    removes the request, so the peg follows the hole's axis;
  - seat push: within ``seat_radius_m`` of the goal the axial push also integrates a seating speed v_s,
        e <- e + a v_s T   while the wrist reads less than ``seat_force_n`` against the axis,
    so a peg that sits farther in the hand than in the demos (a grasp offset: the tcp reaches the demos' goal with
    the tip still above the floor, where the flow is at rest and nothing pushes on) is driven down until
    the floor holds it, as a force-terminated insertion does. A seated peg reads the floor's force and the push then
    only leaks;
  - rotational compliance: within ``radius_m`` of the goal the commanded rotational stiffness is
    ``rotational_stiffness`` (remote-centre compliance at the peg tip: the controlled frame is the tcp);
  - stall search: while the peg stalls at the hole's mouth (the axial push |u| beyond ``search_push_m`` with the
    tip less than ``search_band_m`` below the nominal mouth), a lateral offset circles the axis,
        s = A(t) (cos phi e_1 + sin phi e_2),  phi = 2 pi t / ``search_period_s``,  A(t) = ``search_amplitude_m``
    min(1, t / ``search_period_s``) (t: time stalled), added to the push, which is scaled by
    ``search_push_scale`` meanwhile, and the frame shift holds still. Why: a
    peg that lands off the axis towards a corner of a triangular hole rests on two 45 deg chamfer faces whose
    valley rises at atan(tan 45 deg cos 60 deg) = 26.6 deg, the friction angle of mu = 0.5, so no axial push
    slides it in (in simulation: all contact on those two faces, 0.4-0.8 mm off towards the corner, 0.8-0.95 mm down
    the 1 mm chamfer, until the time limit). A sideways force overcomes the friction; its direction is not known
    (the hole-pose error), so it turns: when it points towards the axis the chamfer leads the peg in, and the
    search ends as the tip passes below the band.

What each part contributes is measured in docs/results/learned-compliance.md (the ablation, on the protocol).
`ContactAdaptation.off()` restores the bare flow (the ablation, `pih evaluate --no-contact-adaptation`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Iterable

import numpy as np
import numpy.typing as npt

from envs.errors import EnvError
from envs.policies import closed_loop_kernel as kernel
from envs.poses import quat_from_rotvec_one
from numerics.small_linalg import dot, norm

FloatArray = npt.NDArray[np.float64]


ADAPTATION_PARTS: dict[str, dict[str, object]] = {
    "push": {"push_limit_m": 0.0},
    "frame": {"frame_limit_m": 0.0, "frame_limit_deg": 0.0},
    "compliance": {"rotational_stiffness": None},
    "search": {"search_amplitude_m": 0.0},
    "seat": {"seat_speed_m_s": 0.0},
    "insertion": {"insertion": False},
}
"""The hand-written parts of the adaptation and the settings that turn each off (`ContactAdaptation.without`)."""


def adaptation_parts(parts: Iterable[str]) -> tuple[str, ...]:
    """``parts`` as a tuple of distinct names of `ADAPTATION_PARTS`.

    Raises:
        EnvError: an unknown or repeated part (one line naming them and the parts).
    """
    names = tuple(parts)
    if any(name not in ADAPTATION_PARTS for name in names) or len(set(names)) != len(names):
        raise EnvError(f"contact adaptation parts {list(names)}: expected distinct parts of "
                       f"{', '.join(ADAPTATION_PARTS)}")
    return names


@dataclass(frozen=True)
class ContactAdaptation:
    """Settings of the contact adaptation (module docstring).

    Attributes:
        push_limit_m: largest axial push offset, m (10 mm: 15 N at the default 1500 N/m); 0 disables the push.
        push_leak_s: leak time constant tau of the integral, s.
        frame_limit_m: largest frame shift across the axis, m (the task's 1 mm hole error plus margin); 0: off.
        frame_limit_deg: largest frame rotation, deg (the task's 1 deg hole error plus margin); 0: off.
        radius_m: distance from the goal within which the frame may shift and turn and the wrist is compliant, m
            (35 mm: the hole mouth is 30 mm above the goal).
        rotational_stiffness: rotational stiffness within ``radius_m``, N m/rad; None keeps the controller's.
        search_amplitude_m: radius A of the stall search's lateral circle, m (0: no search).
        search_period_s: time of one turn of the search, s (also the ramp-up time of its radius).
        search_push_m: axial push |u| beyond which a peg at the mouth counts as stalled, m.
        search_band_m: the search runs while the tip is less than this below the nominal hole's mouth, m (the
            1 mm chamfer plus margin).
        search_push_scale: the axial push is scaled by this while the search runs, in [0, 1]: less axial force
            means less normal force on the chamfer and less friction for the sideways force to overcome (with the
            full push the peg ratchets up the fingers instead of sliding).
        seat_speed_m_s: the seating speed v_s, m/s (0: no seat push); 2 mm/s raises the force by K v_s = 3 N/s at
            1500 N/m.
        seat_radius_m: distance of the measured tcp from the goal within which the seat push runs, m (5 mm: the
            largest grasp offset of the realistic cell, 3 mm, plus margin).
        seat_force_n: the wrist force against the axis (N) at which the seat push stops: the floor holds the peg.
        insertion: from the peg's first touch on the part near the hole, the force-regulated search and insertion
            of envs.policies.insertion take over from the flow (and from the parts above, which then act no more).

    Raises:
        EnvError: a negative, NaN or zero-where-positive field (one line naming it).
    """

    push_limit_m: float = 0.01
    push_leak_s: float = 5.0
    frame_limit_m: float = 0.0015
    frame_limit_deg: float = 1.5
    radius_m: float = 0.035
    rotational_stiffness: float | None = 5.0
    search_amplitude_m: float = 0.002
    search_period_s: float = 1.0
    search_push_m: float = 0.005
    search_band_m: float = 0.002
    search_push_scale: float = 0.3
    seat_speed_m_s: float = 0.002
    seat_radius_m: float = 0.005
    seat_force_n: float = 5.0
    insertion: bool = True

    def __post_init__(self) -> None:
        for name in ("push_limit_m", "frame_limit_m", "frame_limit_deg", "radius_m", "search_amplitude_m",
                     "search_push_m", "search_band_m", "seat_speed_m_s", "seat_radius_m", "seat_force_n"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value >= 0.0):
                raise EnvError(f"contact adaptation {name}={value!r} must be a finite number >= 0")
        if not (isinstance(self.push_leak_s, (int, float)) and np.isfinite(self.push_leak_s) and self.push_leak_s > 0.0):
            raise EnvError(f"contact adaptation push_leak_s={self.push_leak_s!r} must be > 0")
        if not (isinstance(self.search_push_scale, (int, float)) and 0.0 <= self.search_push_scale <= 1.0):
            raise EnvError(f"contact adaptation search_push_scale={self.search_push_scale!r} must be in [0, 1]")
        if not isinstance(self.insertion, bool):
            raise EnvError(f"contact adaptation insertion={self.insertion!r} must be True or False")
        if not (isinstance(self.search_period_s, (int, float)) and np.isfinite(self.search_period_s)
                and self.search_period_s > 0.0):
            raise EnvError(f"contact adaptation search_period_s={self.search_period_s!r} must be > 0")
        k = self.rotational_stiffness
        if k is not None and not (isinstance(k, (int, float)) and np.isfinite(k) and k > 0.0):
            raise EnvError(f"contact adaptation rotational_stiffness={k!r} must be > 0 N m/rad (or None)")

    def without(self, parts: Iterable[str]) -> "ContactAdaptation":
        """These settings with the named parts of `ADAPTATION_PARTS` off (the ablation of each hand-written part):
        "push" (the axial push), "frame" (the frame shift and turn), "compliance" (the lowered rotational
        stiffness), "search" (the stall search), "seat" (the seat push), "insertion" (the search and insertion from
        the first touch, envs.policies.insertion). All six off is `off`.

        Raises:
            EnvError: an unknown or repeated part (`adaptation_parts`).
        """
        changes: dict[str, object] = {}
        for part in adaptation_parts(parts):
            changes.update(ADAPTATION_PARTS[part])
        return dataclasses.replace(self, **changes)

    @classmethod
    def off(cls) -> "ContactAdaptation":
        """No push, no frame shift or rotation, no search, the controller's rotational stiffness: the bare flow."""
        return cls(push_limit_m=0.0, frame_limit_m=0.0, frame_limit_deg=0.0, rotational_stiffness=None,
                   search_amplitude_m=0.0, seat_speed_m_s=0.0, insertion=False)


class ContactAdapter:
    """The state of the contact adaptation along one episode: the integral e (its axial part, the push), the
    frame shift delta, the frame rotation rho and the stall search s (module docstring). The state is one vector
    updated by the compiled kernels of `envs.policies.closed_loop_kernel` (the STATE_* slots); the attributes
    below read (and, for a test, set) it.

    Args:
        config: the settings.
        goal_pos: the skill's goal position g_p (3,), m.
        axis: the insertion axis a (3,), unit (normalised here).
    """

    def __init__(self, config: ContactAdaptation, goal_pos: npt.ArrayLike, axis: npt.ArrayLike):
        self.config = config
        goal = np.asarray(goal_pos, dtype=np.float64)
        a = np.asarray(axis, dtype=np.float64)
        a = a / norm(a)
        helper = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        e1 = helper - dot(helper, a) * a
        e1 = e1 / norm(e1)
        self.geometry = np.ascontiguousarray(np.stack([goal, a, e1, np.cross(a, e1)]))
        slots = {kernel.CONFIG_PUSH_LIMIT: config.push_limit_m, kernel.CONFIG_PUSH_LEAK: config.push_leak_s,
                 kernel.CONFIG_FRAME_LIMIT: config.frame_limit_m,
                 kernel.CONFIG_FRAME_LIMIT_RAD: float(np.deg2rad(config.frame_limit_deg)),
                 kernel.CONFIG_RADIUS: config.radius_m, kernel.CONFIG_SEARCH_AMPLITUDE: config.search_amplitude_m,
                 kernel.CONFIG_SEARCH_PERIOD: config.search_period_s, kernel.CONFIG_SEARCH_PUSH: config.search_push_m,
                 kernel.CONFIG_SEARCH_BAND: config.search_band_m,
                 kernel.CONFIG_SEARCH_PUSH_SCALE: config.search_push_scale,
                 kernel.CONFIG_SEAT_SPEED: config.seat_speed_m_s, kernel.CONFIG_SEAT_RADIUS: config.seat_radius_m,
                 kernel.CONFIG_SEAT_FORCE: config.seat_force_n}
        self.settings = np.full(kernel.CONFIG_SIZE, math.nan)
        for slot, value in slots.items():
            self.settings[slot] = value
        self.state = np.zeros(kernel.STATE_SIZE)
        self.reset()

    def reset(self, mouth_depth_m: float | None = None) -> None:
        """Start an episode: no push, no frame shift, rotation or search. ``mouth_depth_m``: how far the goal lies
        beyond the nominal hole's mouth along the axis, a^T (g_p - mouth), m (None: no stall search)."""
        self.state[:] = 0.0
        self.state[kernel.STATE_MOUTH] = math.nan if mouth_depth_m is None else float(mouth_depth_m)

    def _vector(self, at: int) -> FloatArray:
        return self.state[at:at + 3].copy()

    def _set(self, at: int, value: npt.ArrayLike) -> None:
        self.state[at:at + 3] = np.asarray(value, dtype=np.float64)

    goal_pos = property(lambda self: self.geometry[kernel.GEOMETRY_GOAL].copy(), doc="g_p (3,), m.")
    axis = property(lambda self: self.geometry[kernel.GEOMETRY_AXIS].copy(), doc="The insertion axis a (3,).")
    push = property(lambda self: self._vector(kernel.STATE_PUSH), doc="The axial push u (3,), m.")
    frame = property(lambda self: self._vector(kernel.STATE_FRAME),
                     lambda self, value: self._set(kernel.STATE_FRAME, value), doc="The frame shift delta (3,), m.")
    rotation = property(lambda self: self._vector(kernel.STATE_ROTATION),
                        lambda self, value: self._set(kernel.STATE_ROTATION, value),
                        doc="The frame rotation rho (3,), rad.")
    search = property(lambda self: self._vector(kernel.STATE_SEARCH), doc="The search's lateral offset s (3,), m.")
    search_s = property(lambda self: float(self.state[kernel.STATE_SEARCH_S]), doc="Time stalled, s.")
    resistance_n = property(lambda self: float(self.state[kernel.STATE_RESISTANCE]),
                            doc="The sensed force against the axis, -a^T F, N.")

    @property
    def mouth_depth_m(self) -> float | None:
        """a^T (g_p - mouth), m (None: no stall search)."""
        value = float(self.state[kernel.STATE_MOUTH])
        return None if math.isnan(value) else value

    @property
    def offset(self) -> FloatArray:
        """u + s: the axial push and the stall search's lateral offset, added to the led anchor (m, world)."""
        return self.push_action()[:3].copy()

    def push_action(self) -> FloatArray:
        """[u + s; 0] (6,): the `offset` as the action's push."""
        out = np.empty(6)
        kernel.offset_into(self.state, self.settings, out)
        return out

    @property
    def rotation_quat(self) -> list[float]:
        """Exp(rho), the frame rotation as a unit quaternion [w, x, y, z]."""
        return quat_from_rotvec_one(self.rotation.tolist())

    def near_goal(self, pos: npt.ArrayLike) -> bool:
        """Whether ``pos`` is within ``radius_m`` of the goal."""
        return bool(kernel.near_goal(self.geometry, self.settings, np.asarray(pos, dtype=np.float64)))

    def rotational_stiffness(self, pos: npt.ArrayLike) -> float | None:
        """The rotational stiffness to command at measured position ``pos`` (None: the controller's)."""
        return self.config.rotational_stiffness if self.near_goal(pos) else None

    def sense(self, force_world: npt.ArrayLike) -> None:
        """The sensed force the environment exerts on the tool (3,, N, world) this step: its part against the axis,
        -a^T F, is what the seat push reads."""
        self.state[kernel.STATE_RESISTANCE] = -dot(self.geometry[kernel.GEOMETRY_AXIS],
                                                    np.asarray(force_world, dtype=np.float64))

    def sense_wrench(self, tcp_quat: npt.ArrayLike, wrench: npt.ArrayLike) -> None:
        """`sense` of the wrist wrench, whose axes are the tcp's: F = R(q_tcp) f, f its force (compiled)."""
        kernel.sense_into(self.state, self.geometry, np.asarray(tcp_quat, dtype=np.float64),
                          np.asarray(wrench, dtype=np.float64))

    def update(self, pos: npt.ArrayLike, velocity_d: npt.ArrayLike, period_s: float) -> None:
        """One control step at measured position ``pos`` with the flow's linear velocity ``velocity_d`` (3,):
        e <- (1 - T/tau) e + (xi_d - v) T (+ a v_s T seating near the goal, `sense`), push = sat(a a^T e),
        delta <- sat(delta - (I - a a^T)(xi_d - v) T) near the goal. The first call only records ``pos`` (no
        velocity yet)."""
        kernel.update_translation(self.state, self.settings, self.geometry, np.asarray(pos, dtype=np.float64),
                                  np.asarray(velocity_d, dtype=np.float64), float(period_s))

    def update_rotation(self, pos: npt.ArrayLike, quat: npt.ArrayLike, omega_d: npt.ArrayLike, period_s: float) -> None:
        """One control step at the measured pose (``pos``, ``quat``) with the flow's angular velocity ``omega_d``
        (3,, world frame, already turned by the frame rotation): rho <- sat(Log(Exp(-(omega_d T - r)) Exp(rho)))
        near the goal, r the measured rotation since the last call (module docstring). The first call only
        records ``quat``."""
        kernel.update_rotation(self.state, self.settings, self.geometry, np.asarray(pos, dtype=np.float64),
                               np.asarray(quat, dtype=np.float64), np.asarray(omega_d, dtype=np.float64),
                               float(period_s))


__all__ = ["ContactAdaptation", "ContactAdapter"]
