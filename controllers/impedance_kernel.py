"""The impedance control law of `controllers.impedance`, compiled with numba (no Python work per physics step).

At 1 kHz the law runs once per physics step, so its cost is set by call overhead, not arithmetic: the numpy/LAPACK
version made ~40 Python-level calls per step, more than the physics step costs. Here the whole
law -- Cholesky of Lambda^-1, the symmetric eigenproblem of C^T K C (cyclic Jacobi, exact to rounding for 6x6),
the pose error, the modal damping, the dynamically consistent nullspace and the torque limits -- is one compiled
call on preallocated buffers. `impedance_substep` makes a whole physics step one call: the carried tool's weight
compensation, mj_step1, mj_jacSite, mj_solveM, the law and mj_step2, calling MuJoCo's C functions directly
(controllers.mujoco_c).

Equations (see controllers/impedance.py for the derivation):

    Lambda^-1 = J M^-1 J^T + eps I = C C^T,   C^T K C = U diag(w) U^T,   P = C^-T U
    e   = [p_d - p; Log(q_d conj(q))]                         (world-frame rotation vector)
    F   = K e - P diag(2 zeta sqrt(w)) P^T (J qdot) - P P^T (J M^-1 tau_0)
    tau = J^T F + tau_0 + c,   tau_0 = K_n (q_ref - q) - D_n qdot
    tau_k = clip(clip(tau + f, tau_{k-1} -+ rate dt), -+tau_max)   (f: the friction observer's, 0 without it)
"""

from __future__ import annotations

import math

import numba
import numpy as np

from controllers.joint_torque_kernel import FB_ON, actuator_torque_into, compensation_into, feedback_update
from controllers.mujoco_c import FN_JAC, FN_JAC_SITE, FN_SOLVE_M, FN_STEP1, FN_STEP2, call_jac, call_md, call_mdppi
from numerics import quaternion
from numerics.small_linalg import _solve_into, symmetric_eig

STATUS_OK = 0
STATUS_NOT_POSITIVE_DEFINITE = 1
"""J M^-1 J^T + eps I failed its Cholesky factorisation."""

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")


@_jit
def cholesky_lower(a: np.ndarray, c: np.ndarray) -> bool:
    """C lower triangular with C C^T = a (a symmetric); False when a is not positive definite (or NaN)."""
    n = a.shape[0]
    for j in range(n):
        s = a[j, j]
        for k in range(j):
            s -= c[j, k] * c[j, k]
        if not s > 0.0:
            return False
        d = math.sqrt(s)
        c[j, j] = d
        for i in range(j + 1, n):
            t = a[i, j]
            for k in range(j):
                t -= c[i, k] * c[j, k]
            c[i, j] = t / d
        for i in range(j):
            c[i, j] = 0.0
    return True


@_jit
def modal_factors_into(lambda_inv: np.ndarray, stiffness: np.ndarray, p: np.ndarray, w: np.ndarray,
                       work: np.ndarray) -> bool:
    """P = C^-T U and w with Lambda^-1 = C C^T, C^T K C = U diag(w) U^T (so Lambda = P P^T, K = P diag(w) P^T).

    Args:
        lambda_inv, stiffness: 6x6 inputs (not changed).
        p, w: outputs (6x6, 6).
        work: (3, 6, 6) scratch.

    Returns:
        False when lambda_inv is not positive definite (p, w undefined).
    """
    n = lambda_inv.shape[0]
    c, ckc, u = work[0], work[1], work[2]
    if not cholesky_lower(lambda_inv, c):
        return False
    for i in range(n):  # ckc = C^T K C, using p as the scratch K C
        for j in range(n):
            s = 0.0
            for k in range(j, n):
                s += stiffness[i, k] * c[k, j]
            p[i, j] = s
    for i in range(n):
        for j in range(n):
            s = 0.0
            for k in range(i, n):
                s += c[k, i] * p[k, j]
            ckc[i, j] = s
    for i in range(n):  # symmetrise the rounding
        for j in range(i + 1, n):
            m = 0.5 * (ckc[i, j] + ckc[j, i])
            ckc[i, j] = m
            ckc[j, i] = m
    symmetric_eig(ckc, w, u)
    for j in range(n):  # back substitution of the upper-triangular C^T P = U, column by column
        for i in range(n - 1, -1, -1):
            s = u[i, j]
            for k in range(i + 1, n):
                s -= c[k, i] * p[k, j]
            p[i, j] = s / c[i, i]
    return True


@_jit
def inertia_inverse_into(jac: np.ndarray, jac_minv: np.ndarray, regularisation: float, out: np.ndarray) -> None:
    """out = J M^-1 J^T + regularisation I (6x6) from J and J M^-1 (6 x nv), symmetric by construction."""
    rows, nv = jac.shape
    for i in range(rows):
        for j in range(i, rows):
            s = 0.0
            for k in range(nv):
                s += jac_minv[i, k] * jac[j, k]
            out[i, j] = s
            out[j, i] = s
        out[i, i] += regularisation


LEAD_OK, LEAD_NOT_POSITIVE_DEFINITE, LEAD_SINGULAR_STIFFNESS = range(3)
"""What `pose_lead_into` returns."""


@_jit
def pose_lead_into(fns: np.ndarray, m: int, d: int, site: int, jac: np.ndarray, jac_minv: np.ndarray,
                   stiffness: np.ndarray, regularisation: float, two_zeta: float, twist: np.ndarray,
                   accel: np.ndarray, has_accel: bool, lambda_inv: np.ndarray, p: np.ndarray, w: np.ndarray,
                   work: np.ndarray, k_copy: np.ndarray, out: np.ndarray) -> int:
    """delta = K^-1 P (2 zeta sqrt(max(w, 0)) (P^T xi) + P^T xi_dot) into ``out`` (6,): the pose lead of
    `CartesianImpedanceController.pose_lead` in one call, with the same arithmetic as its numpy steps (J and J M^-1
    by mj_jacSite and mj_solveM, `inertia_inverse_into`, `modal_factors_into`, row sums with k ascending, and
    numerics.small_linalg's elimination for K^-1).

    Args:
        fns, m, d, site, jac, jac_minv: as in `impedance_substep`.
        stiffness: K (6, 6), checked SPD; regularisation: added to J M^-1 J^T; two_zeta: 2 zeta.
        twist, accel: xi and xi_dot (6,), finite; ``has_accel`` False: no inertial term.
        lambda_inv, p, k_copy: (6, 6) scratch; w: (6,) scratch; work: (3, 6, 6) scratch.

    Returns:
        LEAD_OK, LEAD_NOT_POSITIVE_DEFINITE (J M^-1 J^T) or LEAD_SINGULAR_STIFFNESS (``out`` then undefined).
    """
    nv = jac.shape[1]
    call_mdppi(fns[FN_JAC_SITE], m, d, jac.ctypes.data, jac.ctypes.data + 3 * nv * 8, site)
    call_mdppi(fns[FN_SOLVE_M], m, d, jac_minv.ctypes.data, jac.ctypes.data, 6)
    inertia_inverse_into(jac, jac_minv, regularisation, lambda_inv)
    if not modal_factors_into(lambda_inv, stiffness, p, w, work):
        return LEAD_NOT_POSITIVE_DEFINITE
    modal = np.empty(6)
    for i in range(6):
        s = 0.0
        for k in range(6):  # (P^T xi)_i
            s += p[k, i] * twist[k]
        v = w[i]
        v = v if (v >= 0.0 or math.isnan(v)) else 0.0  # np.maximum(w, 0.0)
        modal[i] = (two_zeta * math.sqrt(v)) * s
    if has_accel:
        for i in range(6):
            s = 0.0
            for k in range(6):  # (P^T xi_dot)_i
                s += p[k, i] * accel[k]
            modal[i] += s
    rhs = out.reshape(6, 1)
    for i in range(6):
        s = 0.0
        for k in range(6):  # (P modal)_i
            s += p[i, k] * modal[k]
        rhs[i, 0] = s
    for i in range(6):
        for j in range(6):
            k_copy[i, j] = stiffness[i, j]
    if not _solve_into(k_copy, rhs):
        return LEAD_SINGULAR_STIFFNESS
    return LEAD_OK


# The quaternion formulas are numerics.quaternion's, compiled here once: the same Python source as the array versions,
# so the same rounding (tests/test_numba_twins.py). ik_kernel, the feed-forward lead (feedforward_kernel),
# envs.sim.observation_kernel and the policies' closed-loop kernel (envs.policies.closed_loop_kernel) use these too.
hamilton = _jit(quaternion.hamilton)
matrix_to_quat_components = _jit(quaternion.matrix_to_quat_components)
matrix_components = _jit(quaternion.matrix_components)
rotvec_components = _jit(quaternion.rotvec_components)
quat_of_rotvec_components = _jit(quaternion.quat_of_rotvec_components)


@_jit
def mat_to_quat_into(mat: np.ndarray, quat: np.ndarray) -> None:
    """quat (4,) = the unit quaternion (w, x, y, z), w >= 0, of a row-major 3x3 rotation matrix mat (9,)
    (`numerics.quaternion.matrix_to_quat_components`)."""
    quat[0], quat[1], quat[2], quat[3] = matrix_to_quat_components(mat[0], mat[1], mat[2], mat[3], mat[4], mat[5],
                                                                   mat[6], mat[7], mat[8])


@_jit
def pose_error_into(pos: np.ndarray, quat: np.ndarray, site_pos: np.ndarray, site_mat: np.ndarray,
                    error: np.ndarray, scratch: np.ndarray) -> None:
    """error = [p_d - p; Log(q_d conj(q))], the rotation error as a world-frame rotation vector of angle <= pi.

    Args:
        pos, quat: desired position (3,) and unit quaternion (4,).
        site_pos, site_mat: measured position (3,) and row-major rotation matrix (9,).
        error: output (6,).
        scratch: (4,) buffer for the measured quaternion.
    """
    for i in range(3):
        error[i] = pos[i] - site_pos[i]
    mat_to_quat_into(site_mat, scratch)
    w, x, y, z = hamilton(quat[0], quat[1], quat[2], quat[3], scratch[0], -scratch[1], -scratch[2], -scratch[3])
    if w < 0.0:  # q and -q are one rotation: take the shorter way
        w, x, y, z = -w, -x, -y, -z
    s = math.sqrt(x * x + y * y + z * z)
    factor = 2.0 * math.atan2(s, w) / s if s > 1e-12 else 2.0 / max(w, 1e-300)
    error[3], error[4], error[5] = factor * x, factor * y, factor * z


@_jit
def impedance_factors(jac: np.ndarray, jac_minv: np.ndarray, stiffness: np.ndarray, params: np.ndarray,
                      work: np.ndarray, vec: np.ndarray) -> bool:
    """The law's state-dependent factors: Lambda^-1 = J M^-1 J^T + eps I into work[3], and its modal factors P
    (work[4]) and w (vec[0]) with Lambda = P P^T, K = P diag(w) P^T; False when Lambda^-1 is not positive definite.
    (Arguments as in `impedance_torque`.)"""
    inertia_inverse_into(jac, jac_minv, params[0], work[3])
    return modal_factors_into(work[3], stiffness, work[4], vec[0], work)


@_jit
def impedance_torque(
    jac: np.ndarray,
    jac_minv: np.ndarray,
    qpos: np.ndarray,
    qvel: np.ndarray,
    qfrc_bias: np.ndarray,
    site_pos: np.ndarray,
    site_mat: np.ndarray,
    target: np.ndarray,
    stiffness: np.ndarray,
    params: np.ndarray,
    last_tau: np.ndarray,
    ctrl: np.ndarray,
    work: np.ndarray,
    vec: np.ndarray,
    offset: np.ndarray,
) -> int:
    """One evaluation of the control law (module docstring); writes the limited torque to last_tau and ctrl.

    Args:
        jac, jac_minv: J and J M^-1 (6 x nv) of the site at the current state (mj_jacSite, mj_solveM).
        qpos, qvel, qfrc_bias: the arm's joint positions, velocities and bias forces (n,) (views of MjData).
        site_pos, site_mat: the site's world position (3,) and rotation matrix (9,).
        target: [p_d (3), q_d (4), q_ref (n), use_q_ref (1)].
        stiffness: K (6x6).
        params: [regularisation, 4 zeta^2, K_n, D_n, rate dt, dof_start, tau_max (n)].
        last_tau: the last command (n,), updated.
        ctrl: MjData.ctrl (n,), receives the torque.
        work, vec: scratch matrices (5, 6, 6) and vectors (8, max(6, n)) (see `work_buffers`).
        offset: a torque (n,) added to the law's before its limits (the friction observer's compensation; zeros for
            the law alone).

    Returns:
        STATUS_OK, or STATUS_NOT_POSITIVE_DEFINITE (nothing written).
    """
    if not impedance_factors(jac, jac_minv, stiffness, params, work, vec):
        return STATUS_NOT_POSITIVE_DEFINITE
    factored_torque(jac, jac_minv, qpos, qvel, qfrc_bias, site_pos, site_mat, target, stiffness, params, last_tau,
                    ctrl, work, vec, offset)
    return STATUS_OK


@_jit
def factored_torque(jac: np.ndarray, jac_minv: np.ndarray, qpos: np.ndarray, qvel: np.ndarray,
                    qfrc_bias: np.ndarray, site_pos: np.ndarray, site_mat: np.ndarray, target: np.ndarray,
                    stiffness: np.ndarray, params: np.ndarray, last_tau: np.ndarray, ctrl: np.ndarray,
                    work: np.ndarray, vec: np.ndarray, offset: np.ndarray) -> None:
    """The law from the factors `impedance_factors` left in work[4] (P) and vec[0] (w): the pose error, the
    posture torque, the modal damping, the nullspace and the limits (module docstring); into last_tau and ctrl.
    (Arguments as in `impedance_torque`.)"""
    n = last_tau.shape[0]
    nv = jac.shape[1]
    dof0 = int(params[5])
    p = work[4]  # vec rows: 0 w, 1 error, 2 twist, 3 null x, 4 modal, 5 wrench
    tau0 = vec[6]
    quat_scratch = vec[7]
    pose_error_into(target[0:3], target[3:7], site_pos, site_mat, vec[1], quat_scratch)
    use_ref = target[7 + n] != 0.0
    for i in range(n):  # posture torque tau_0 = K_n (q_ref - q) - D_n qdot
        t = -params[3] * qvel[dof0 + i]
        if use_ref:
            t += params[2] * (target[7 + i] - qpos[i])
        tau0[i] = t
    for r in range(6):  # v = J qdot (full nv), x = (J M^-1)_arm tau_0
        s = 0.0
        for k in range(nv):
            s += jac[r, k] * qvel[k]
        vec[2, r] = s
        s = 0.0
        for i in range(n):
            s += jac_minv[r, dof0 + i] * tau0[i]
        vec[3, r] = s
    for m in range(6):  # modal coordinates: 2 zeta sqrt(w_m) (P^T v)_m + (P^T x)_m
        sv = 0.0
        sx = 0.0
        for r in range(6):
            sv += p[r, m] * vec[2, r]
            sx += p[r, m] * vec[3, r]
        vec[4, m] = math.sqrt(max(vec[0, m], 0.0) * params[1]) * sv + sx
    for r in range(6):  # F = K e - P (modal)
        s = 0.0
        for c in range(6):
            s += stiffness[r, c] * vec[1, c] - p[r, c] * vec[4, c]
        vec[5, r] = s
    rate = params[4]
    for i in range(n):  # tau = J^T F + tau_0 + c (+ the offset), then rate and magnitude limits
        t = tau0[i] + qfrc_bias[i] + offset[i]
        for r in range(6):
            t += jac[r, dof0 + i] * vec[5, r]
        previous = last_tau[i]
        t = min(max(t, previous - rate), previous + rate)
        limit = params[6 + i]
        t = min(max(t, -limit), limit)
        last_tau[i] = t
        ctrl[i] = t


TOOL_ENABLED, TOOL_DEPTH, TOOL_BODY, TOOL_WEIGHT = 0, 1, 2, 3
"""Slots of the tool-load parameters: [enabled (0/1), depth d (m), body, m g (3)]."""


@_jit
def tool_load_into(fns: np.ndarray, m: int, d: int, tool: np.ndarray, site_pos: np.ndarray, site_mat: np.ndarray,
                   point: np.ndarray, jac_tool: np.ndarray, jac_tool_arm: np.ndarray, applied: np.ndarray) -> None:
    """applied = -(m g)^T J_c (the arm's generalised forces that carry a tool of weight m g): J_c the translational
    Jacobian (mj_jac on the tool's body) at its centre of mass p_c = p_site - d z_site, z_site the site's z axis
    (column 2 of its rotation matrix, row-major (9,)).

    Args:
        tool: [enabled, d, body, m g (3)] (TOOL_* slots).
        jac_tool, jac_tool_arm: a (3, nv) buffer and its view on the arm's columns (3, n).
        applied: the arm's qfrc_applied (n,), a view of MjData.
    """
    depth = tool[TOOL_DEPTH]
    for i in range(3):
        point[i] = site_pos[i] - site_mat[3 * i + 2] * depth
    call_jac(fns[FN_JAC], m, d, jac_tool.ctypes.data, 0, point.ctypes.data, int(tool[TOOL_BODY]))
    wx, wy, wz = tool[TOOL_WEIGHT], tool[TOOL_WEIGHT + 1], tool[TOOL_WEIGHT + 2]
    for j in range(jac_tool_arm.shape[1]):
        applied[j] = -((wx * jac_tool_arm[0, j] + wy * jac_tool_arm[1, j]) + wz * jac_tool_arm[2, j])


@_jit
def impedance_substep(fns: np.ndarray, m: int, d: int, site: int, jac: np.ndarray, jac_minv: np.ndarray,
                      qpos: np.ndarray, qvel: np.ndarray, qfrc_bias: np.ndarray, site_pos: np.ndarray,
                      site_mat: np.ndarray, target: np.ndarray, stiffness: np.ndarray, params: np.ndarray,
                      last_tau: np.ndarray, ctrl: np.ndarray, work: np.ndarray, vec: np.ndarray, tool: np.ndarray,
                      tool_point: np.ndarray, jac_tool: np.ndarray, jac_tool_arm: np.ndarray,
                      applied: np.ndarray, disturbance: np.ndarray, disturbance_state: np.ndarray,
                      smooth: np.ndarray, feedback: np.ndarray, sensor_noise: np.ndarray, layout: np.ndarray,
                      qfrc_passive: np.ndarray, reading: np.ndarray) -> int:
    """One controlled physics step: the tool load (when enabled, from the site pose of the last step, as a
    hook before mj_step1 sees it), mj_step1, J and J M^-1 of the site (mj_jacSite, mj_solveM), the law
    (`impedance_torque`) into ctrl, the actuators' torque disturbance (when on) added to ctrl, mj_step2.

    Args:
        fns: controllers.mujoco_c.FUNCTIONS; m, d: MjModel._address, MjData._address.
        site: the controlled site; jac, jac_minv: (6, nv) C-contiguous buffers.
        qpos .. vec: as in `impedance_torque` (site_mat (9,)).
        tool .. applied: as in `tool_load_into`.
        disturbance, disturbance_state: the torque the actuators deliver beyond the command, one row (n,) per
            physics step (R, n), and [noise on, the next row, smooth friction on]: the row's values are added to ctrl
            after the law (the law's own record of its command, last_tau, keeps the command), the last row
            repeating past R; with smooth friction on, ctrl loses the joints' smooth transmission friction at their
            speed (``smooth`` (n, 3), controllers.joint_torque_kernel).
        feedback, sensor_noise, layout, qfrc_passive, reading: the joint torque sensors and the friction observer
            closed on them (controllers.joint_torque_kernel: the feedback vector, the sensors' noise rows, mjData's
            layout, its qfrc_passive and an (n,) scratch for the reading); off when feedback[FB_ON] is 0.

    Returns:
        STATUS_OK, or the law's failure status (the state is then left after mj_step1, nothing applied).
    """
    if tool[TOOL_ENABLED] != 0.0:
        tool_load_into(fns, m, d, tool, site_pos, site_mat, tool_point, jac_tool, jac_tool_arm, applied)
    call_md(fns[FN_STEP1], m, d)
    nv = jac.shape[1]
    call_mdppi(fns[FN_JAC_SITE], m, d, jac.ctypes.data, jac.ctypes.data + 3 * nv * 8, site)
    call_mdppi(fns[FN_SOLVE_M], m, d, jac_minv.ctypes.data, jac.ctypes.data, 6)
    compensation_into(feedback, reading)  # the friction observer's compensation, inside the law's limits
    status = impedance_torque(jac, jac_minv, qpos, qvel, qfrc_bias, site_pos, site_mat, target, stiffness, params,
                              last_tau, ctrl, work, vec, reading)
    if status != STATUS_OK:
        return status
    dof0 = int(params[5])
    actuator_torque_into(dof0, qvel, ctrl, disturbance, disturbance_state, smooth)
    call_md(fns[FN_STEP2], m, d)
    if feedback[FB_ON] != 0.0:
        feedback_update(d, layout, dof0, ctrl, applied, qfrc_passive, qfrc_bias, last_tau, feedback, sensor_noise,
                        reading)
    return STATUS_OK


def work_buffers(n_joints: int) -> tuple[np.ndarray, np.ndarray]:
    """Scratch for `impedance_torque`: matrices (5, 6, 6) and vectors (8, max(6, n_joints))."""
    return np.zeros((5, 6, 6)), np.zeros((8, max(6, n_joints)))
