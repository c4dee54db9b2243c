"""The closed loop's per-period arithmetic compiled: the contact adaptation's state update and the action's pose,
twist and acceleration from the flow's two lookahead poses (envs.policies.adaptation, envs.policies.flow_skill).

Around its flow query the closed loop has ~40 small numpy and Python-float operations per control period (the
twists, the hemisphere flips, the adaptation's integrals, saturations and the stall search), about 45 us in numpy,
as much as the compiled flow itself. Here they are two compiled calls on preallocated arrays; the equations are
those of the two modules' docstrings, operation for operation as their Python reference computes them
(tests/envs/policies/test_closed_loop_kernel.py: the same sums in the same order, numpy's own sin, cos and arctan2
on scalars, `numerics.quaternion`'s scalar formulas compiled from their source), so the records equal the
reference's to the last bit.

The adaptation's state is one float64 vector (the STATE_* slots; None is NaN or a 0 flag), its settings another
(the CONFIG_* slots, `ContactAdapter.settings`), its geometry a (4, 3) array: the goal position, the
insertion axis a and the search plane's e_1, e_2.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from controllers.impedance_kernel import hamilton, quat_of_rotvec_components, rotvec_components
from numerics.small_linalg import dot, norm

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")

STATE_PUSH, STATE_RESISTANCE, STATE_FRAME, STATE_ROTATION, STATE_SEARCH = 0, 3, 4, 7, 10
STATE_SEARCH_S, STATE_MOUTH, STATE_PREVIOUS, STATE_HAS_PREVIOUS = 13, 14, 15, 18
STATE_PREVIOUS_QUAT, STATE_HAS_PREVIOUS_QUAT, STATE_SIZE = 19, 23, 24
"""Slots of the adaptation's state: push u (3), resistance -a^T F (1), frame shift delta (3), frame rotation rho
(3), search offset s (3), time stalled (1), mouth depth (1, NaN: no search), the last measured position (3) and
whether there is one (1), the last measured quaternion (4) and whether there is one (1)."""

(CONFIG_PUSH_LIMIT, CONFIG_PUSH_LEAK, CONFIG_FRAME_LIMIT, CONFIG_FRAME_LIMIT_RAD, CONFIG_RADIUS,
 CONFIG_SEARCH_AMPLITUDE, CONFIG_SEARCH_PERIOD, CONFIG_SEARCH_PUSH, CONFIG_SEARCH_BAND, CONFIG_SEARCH_PUSH_SCALE,
 CONFIG_SEAT_SPEED, CONFIG_SEAT_RADIUS, CONFIG_SEAT_FORCE, CONFIG_SIZE) = range(14)
"""Slots of the settings the kernels read (`ContactAdaptation`'s fields, the frame limit in radians too)."""

GEOMETRY_GOAL, GEOMETRY_AXIS, GEOMETRY_E1, GEOMETRY_E2 = range(4)
"""Rows of the geometry."""

ACTION_POS, ACTION_QUAT, ACTION_TWIST, ACTION_ACCEL, ACTION_ANCHOR_POS, ACTION_ANCHOR_QUAT, ACTION_SIZE = (
    0, 3, 7, 13, 19, 22, 26)
"""Slots of `action_into`'s output: the target pose p_1 + delta, q_1 (3 + 4), the twist s xi and acceleration s^2 a
(6 + 6), the anchor (3 + 4)."""


@_jit
def _saturate_into(state: np.ndarray, at: int, v0: float, v1: float, v2: float, limit: float) -> None:
    """state[at:at+3] = v scaled down to norm ``limit`` if longer: v (limit / |v|)."""
    vec = np.empty(3)
    vec[0], vec[1], vec[2] = v0, v1, v2
    length = norm(vec)
    if length > limit:
        f = limit / length
        v0, v1, v2 = v0 * f, v1 * f, v2 * f
    state[at], state[at + 1], state[at + 2] = v0, v1, v2


@_jit
def near_goal(geometry: np.ndarray, config: np.ndarray, pos: np.ndarray) -> bool:
    """|pos - g_p| < radius."""
    d = np.empty(3)
    for i in range(3):
        d[i] = pos[i] - geometry[GEOMETRY_GOAL, i]
    return norm(d) < config[CONFIG_RADIUS]


@_jit
def _update_search(state: np.ndarray, config: np.ndarray, geometry: np.ndarray, here: np.ndarray,
                   period_s: float) -> bool:
    """Advance (or end) the stall search (envs.policies.adaptation, "stall search"); whether it runs."""
    mouth = state[STATE_MOUTH]
    stalled = False
    if config[CONFIG_SEARCH_AMPLITUDE] > 0.0 and not math.isnan(mouth):
        if norm(state[STATE_PUSH:STATE_PUSH + 3]) > config[CONFIG_SEARCH_PUSH]:
            d = np.empty(3)
            for i in range(3):
                d[i] = here[i] - geometry[GEOMETRY_GOAL, i]
            stalled = dot(geometry[GEOMETRY_AXIS], d) + mouth < config[CONFIG_SEARCH_BAND]
    if not stalled:
        if state[STATE_SEARCH_S] > 0.0:
            for i in range(3):
                state[STATE_SEARCH + i] = 0.0
            state[STATE_SEARCH_S] = 0.0
        return False
    state[STATE_SEARCH_S] += period_s
    period = config[CONFIG_SEARCH_PERIOD]
    phase = 2.0 * np.pi * state[STATE_SEARCH_S] / period
    radius = config[CONFIG_SEARCH_AMPLITUDE] * min(1.0, state[STATE_SEARCH_S] / period)
    c, s = np.cos(phase), np.sin(phase)
    for i in range(3):
        state[STATE_SEARCH + i] = radius * (c * geometry[GEOMETRY_E1, i] + s * geometry[GEOMETRY_E2, i])
    return True


@_jit
def update_translation(state: np.ndarray, config: np.ndarray, geometry: np.ndarray, pos: np.ndarray,
                       velocity_d: np.ndarray, period_s: float) -> None:
    """`ContactAdapter.update`: e <- (1 - T/tau) e + (xi_d - v) T (+ the seat push), push = sat(a a^T e), the
    stall search, delta <- sat(delta - (I - a a^T)(xi_d - v) T) near the goal; the first call only records pos."""
    had = state[STATE_HAS_PREVIOUS] != 0.0
    previous = np.empty(3)
    for i in range(3):
        previous[i] = state[STATE_PREVIOUS + i]
        state[STATE_PREVIOUS + i] = pos[i]
    state[STATE_HAS_PREVIOUS] = 1.0
    if not had or (config[CONFIG_PUSH_LIMIT] == 0.0 and config[CONFIG_FRAME_LIMIT] == 0.0):
        return
    error = np.empty(3)
    for i in range(3):
        error[i] = (velocity_d[i] - (pos[i] - previous[i]) / period_s) * period_s
    a = geometry[GEOMETRY_AXIS]
    axial = dot(a, error)
    lateral = np.empty(3)
    for i in range(3):
        lateral[i] = error[i] - axial * a[i]
    if config[CONFIG_SEAT_SPEED] > 0.0 and state[STATE_RESISTANCE] < config[CONFIG_SEAT_FORCE]:
        d = np.empty(3)
        for i in range(3):
            d[i] = pos[i] - geometry[GEOMETRY_GOAL, i]
        if norm(d) < config[CONFIG_SEAT_RADIUS]:
            axial += config[CONFIG_SEAT_SPEED] * period_s
    leak = max(0.0, 1.0 - period_s / config[CONFIG_PUSH_LEAK])
    _saturate_into(state, STATE_PUSH, leak * state[STATE_PUSH] + axial * a[0],
                   leak * state[STATE_PUSH + 1] + axial * a[1], leak * state[STATE_PUSH + 2] + axial * a[2],
                   config[CONFIG_PUSH_LIMIT])
    if _update_search(state, config, geometry, pos, period_s):
        return  # the frame holds still while the search moves the peg
    if config[CONFIG_FRAME_LIMIT] > 0.0 and near_goal(geometry, config, pos):
        f = STATE_FRAME
        _saturate_into(state, f, state[f] - lateral[0], state[f + 1] - lateral[1], state[f + 2] - lateral[2],
                       config[CONFIG_FRAME_LIMIT])


@_jit
def update_rotation(state: np.ndarray, config: np.ndarray, geometry: np.ndarray, pos: np.ndarray, quat: np.ndarray,
                    omega_d: np.ndarray, period_s: float) -> None:
    """`ContactAdapter.update_rotation`: rho <- sat(Log(Exp(-(omega_d T - r)) Exp(rho))) near the goal, r the
    measured rotation since the last call; the first call only records quat."""
    had = state[STATE_HAS_PREVIOUS_QUAT] != 0.0
    p = STATE_PREVIOUS_QUAT
    w, x, y, z = state[p], state[p + 1], state[p + 2], state[p + 3]
    for i in range(4):
        state[p + i] = quat[i]
    state[STATE_HAS_PREVIOUS_QUAT] = 1.0
    limit = config[CONFIG_FRAME_LIMIT_RAD]
    if not had or limit == 0.0 or not near_goal(geometry, config, pos):
        return
    r0, r1, r2 = rotvec_components(*hamilton(quat[0], quat[1], quat[2], quat[3], w, -x, -y, -z))
    e0, e1, e2 = omega_d[0] * period_s - r0, omega_d[1] * period_s - r1, omega_d[2] * period_s - r2
    q = STATE_ROTATION
    ew, ex, ey, ez = quat_of_rotvec_components(-e0, -e1, -e2)
    rw, rx, ry, rz = quat_of_rotvec_components(state[q], state[q + 1], state[q + 2])
    rho0, rho1, rho2 = rotvec_components(*hamilton(ew, ex, ey, ez, rw, rx, ry, rz))
    _saturate_into(state, q, rho0, rho1, rho2, limit)


@_jit
def offset_into(state: np.ndarray, config: np.ndarray, out: np.ndarray) -> None:
    """out[:3] = u (+ the search: ``search_push_scale`` u + s), out[3:] = 0: the push of the action."""
    searching = state[STATE_SEARCH_S] != 0.0
    scale = config[CONFIG_SEARCH_PUSH_SCALE]
    for i in range(3):
        u = state[STATE_PUSH + i]
        out[i] = scale * u + state[STATE_SEARCH + i] if searching else u
        out[3 + i] = 0.0


@_jit
def _on_hemisphere(w: float, x: float, y: float, z: float, a: float, b: float, c: float,
                   d: float) -> tuple[float, float, float, float]:
    """(w, x, y, z), negated when its dot product with (a, b, c, d) is negative (`flow_skill.on_goal_hemisphere`)."""
    if w * a + x * b + y * c + z * d < 0.0:
        return -w, -x, -y, -z
    return w, x, y, z


@_jit
def _twist_into(out: np.ndarray, p0: np.ndarray, q0: tuple, p1: np.ndarray, q1: tuple, dt: float) -> None:
    """out (6,) = [(p1 - p0)/dt; rotvec(q1 conj(q0))/dt] (`flow_skill.pose_twist` of one pose pair)."""
    w0, x0, y0, z0 = q0
    r0, r1, r2 = rotvec_components(*hamilton(q1[0], q1[1], q1[2], q1[3], w0, -x0, -y0, -z0))
    for i in range(3):
        out[i] = (p1[i] - p0[i]) / dt
    out[3], out[4], out[5] = r0 / dt, r1 / dt, r2 / dt


@_jit
def _rotate(w: float, x: float, y: float, z: float, v0: float, v1: float,
            v2: float) -> tuple[float, float, float]:
    """R(q) v as q (0, v) conj(q) (`numerics.quaternion.rotate` of one vector)."""
    _, a, b, c = hamilton(*hamilton(w, x, y, z, 0.0, v0, v1, v2), w, -x, -y, -z)
    return a, b, c


@_jit
def action_into(measured_pos: np.ndarray, measured_quat: np.ndarray, query_pos: np.ndarray, query_quat: np.ndarray,
                delta: np.ndarray, rho: np.ndarray, turned: bool, p1: np.ndarray, q1_raw: np.ndarray,
                p2: np.ndarray, q2: np.ndarray, step_s: float, speed: float, speed_squared: float,
                out: np.ndarray) -> None:
    """The closed loop's action from the flow's poses x_1 = Phi(L) x and x_2 = Phi(L) x_1 at the query
    (`ClosedLoopPolicy._complete` before the adaptation's update): q_1 normalised and put on the query's
    hemisphere, xi_1 = (x_1 - x)/L, xi_2 = (x_2 - x_1)/L, a = (xi_2 - xi_1)/L, xi = xi_1 - a L/2, all turned back by
    Exp(rho) when ``turned``.

    Args:
        measured_pos, measured_quat: the measured tcp pose; query_pos, query_quat: the flow's query (in the shifted
            and turned frame); delta: the frame shift; rho (4,): Exp(rho) (read when ``turned``).
        p1, q1_raw, p2, q2: the flow's two lookahead poses.
        step_s: L; speed, speed_squared: s and s^2 (s^2 as Python computed it).
        out: (ACTION_SIZE,) receives the target pose, the scaled twist and acceleration and the anchor
            (ACTION_* slots).
    """
    n = math.sqrt(((q1_raw[0] * q1_raw[0] + q1_raw[1] * q1_raw[1]) + q1_raw[2] * q1_raw[2]) + q1_raw[3] * q1_raw[3])
    q1 = (q1_raw[0] / n, q1_raw[1] / n, q1_raw[2] / n, q1_raw[3] / n)
    here = _on_hemisphere(query_quat[0], query_quat[1], query_quat[2], query_quat[3], *q1)
    xi1, xi2 = np.empty(6), np.empty(6)
    _twist_into(xi1, query_pos, here, p1, q1, step_s)
    _twist_into(xi2, p1, q1, p2, _on_hemisphere(q2[0], q2[1], q2[2], q2[3], *q1), step_s)
    accel, twist = np.empty(6), np.empty(6)
    half = 0.5 * step_s
    for i in range(6):
        accel[i] = (xi2[i] - xi1[i]) / step_s
    for i in range(6):
        twist[i] = xi1[i] - half * accel[i]
    if turned:
        q1 = hamilton(rho[0], rho[1], rho[2], rho[3], *q1)
        twist[3], twist[4], twist[5] = _rotate(rho[0], rho[1], rho[2], rho[3], twist[3], twist[4], twist[5])
        accel[3], accel[4], accel[5] = _rotate(rho[0], rho[1], rho[2], rho[3], accel[3], accel[4], accel[5])
        anchor_quat = _on_hemisphere(measured_quat[0], measured_quat[1], measured_quat[2], measured_quat[3], *q1)
    else:
        anchor_quat = here
    for i in range(3):
        out[ACTION_POS + i] = p1[i] + delta[i]
        out[ACTION_ANCHOR_POS + i] = query_pos[i] + delta[i]
    for i in range(4):
        out[ACTION_QUAT + i] = q1[i]
        out[ACTION_ANCHOR_QUAT + i] = anchor_quat[i]
    for i in range(6):
        out[ACTION_TWIST + i] = speed * twist[i]
        out[ACTION_ACCEL + i] = speed_squared * accel[i]


@_jit
def sense_into(state: np.ndarray, geometry: np.ndarray, tcp_quat: np.ndarray, wrench: np.ndarray) -> None:
    """`ContactAdapter.sense` of the wrist wrench (sensor frame = the tcp's axes): the resistance -a^T R(q_tcp) F."""
    force = np.empty(3)
    force[0], force[1], force[2] = _rotate(tcp_quat[0], tcp_quat[1], tcp_quat[2], tcp_quat[3],
                                           wrench[0], wrench[1], wrench[2])
    state[STATE_RESISTANCE] = -dot(geometry[GEOMETRY_AXIS], force)


@_jit
def query_into(state: np.ndarray, measured_pos: np.ndarray, measured_quat: np.ndarray, pos: np.ndarray,
               quat: np.ndarray, delta: np.ndarray, rho: np.ndarray) -> bool:
    """Where the flow is queried (`ClosedLoopPolicy._query`): pos = p - delta, quat = Exp(rho)^-1 q (q when rho =
    0), with delta and Exp(rho) (the identity when rho = 0) copied out; whether the frame is turned."""
    turned = False
    for i in range(3):
        delta[i] = state[STATE_FRAME + i]
        pos[i] = measured_pos[i] - delta[i]
        turned = turned or state[STATE_ROTATION + i] != 0.0
    if not turned:
        for i in range(4):
            quat[i] = measured_quat[i]
        rho[0], rho[1], rho[2], rho[3] = 1.0, 0.0, 0.0, 0.0
        return False
    r = STATE_ROTATION
    rho[0], rho[1], rho[2], rho[3] = quat_of_rotvec_components(state[r], state[r + 1], state[r + 2])
    quat[0], quat[1], quat[2], quat[3] = hamilton(rho[0], -rho[1], -rho[2], -rho[3], measured_quat[0],
                                                  measured_quat[1], measured_quat[2], measured_quat[3])
    return True
