"""One differential-IK step of `controllers.ik` compiled with numba: the same quadratic program mink builds and daqp
solves (frame task + posture task + configuration limits), without mink's Python per iteration.

For the site pose T_b = (R_b, p_b), the target T_t and T_tb = T_t^-1 T_b, with twists ordered [v; w] (mink):

    frame task     e_f = log(T_b^-1 T_t) = -log(T_tb),   J_f = -Jr^-1(log T_tb) J_b = -Jl^-1(e_f) J_b
                   (J_b: body Jacobian, the world-aligned mj_jacSite rotated by R_b^T)
    posture task   e_p = q - q_nom on hinge and slide dofs (0 on free joints), J_p = I
    objective      min 1/2 dq^T H dq + c^T dq,   H = J_f^T J_f + w_p^2 I_p + (mu_0 + lm ||e_f||^2) I,
                   c = J_f^T e_f + w_p^2 e_p
    limits         -gain (q - q_min) <= dq <= gain (q_max - q) on limited dofs

The box-constrained QP (H positive definite) is solved exactly by a primal active-set method (Nocedal & Wright,
Algorithm 16.3) from the feasible dq = 0. SE(3) maps follow Sola et al., "A micro Lie theory" (2018): log via
V^-1(theta), the left Jacobian inverse [[Jl^-1, -Jl^-1 Q Jl^-1], [0, Jl^-1]] with Barfoot's Q(rho, theta).

`ik_iterations` runs several steps in one call: mj_jacSite, the QP step, mj_integratePos (q <- q (+) dq),
mj_kinematics and mj_comPos each, MuJoCo's C functions called directly (controllers.mujoco_c).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from controllers.impedance_kernel import cholesky_lower, mat_to_quat_into
from controllers.mujoco_c import FN_COM_POS, FN_INTEGRATE_POS, FN_JAC_SITE, FN_KINEMATICS, call_integrate_pos, call_md, \
    call_mdppi
from numerics.small_linalg import matmul_into

_EPS = float(np.finfo(np.float64).eps)
_jit = numba.njit(cache=True, nogil=True, error_model="numpy")


@_jit
def _skew(v, out):
    out[0, 0], out[0, 1], out[0, 2] = 0.0, -v[2], v[1]
    out[1, 0], out[1, 1], out[1, 2] = v[2], 0.0, -v[0]
    out[2, 0], out[2, 1], out[2, 2] = -v[1], v[0], 0.0


@_jit
def _so3_left_jacobian_inverse(theta, out):
    """Jl^-1(theta) = I - [theta]/2 + beta [theta]^2, beta = (1 - t sin t / (2 (1 - cos t))) / t^2 (series near 0)."""
    t2 = theta[0] ** 2 + theta[1] ** 2 + theta[2] ** 2
    t = math.sqrt(t2)
    if t < _EPS:
        beta = (1.0 / 12.0) * (1.0 + t2 / 60.0 * (1.0 + t2 / 42.0 * (1.0 + t2 / 40.0)))
    else:
        beta = (1.0 - t * math.sin(t) / (2.0 * (1.0 - math.cos(t)))) / t2
    for i in range(3):
        for j in range(3):
            out[i, j] = beta * (theta[i] * theta[j] - (t2 if i == j else 0.0)) + (1.0 if i == j else 0.0)
    out[0, 1] += 0.5 * theta[2]
    out[0, 2] -= 0.5 * theta[1]
    out[1, 0] -= 0.5 * theta[2]
    out[1, 2] += 0.5 * theta[0]
    out[2, 0] += 0.5 * theta[1]
    out[2, 1] -= 0.5 * theta[0]


@_jit
def _se3_q(rho, theta, m):
    """Barfoot's Q(rho, theta) (3x3): A V + B (WV + VW + WVW) - C (VWW - (VWW)^T - 3 WVW) + D (WVW W + W WVW)
    with V = [rho], W = [theta]; m is (8, 3, 3) scratch, the result in m[7]."""
    t2 = theta[0] ** 2 + theta[1] ** 2 + theta[2] ** 2
    t = math.sqrt(t2)
    if t2 < _EPS:
        b, c, d = 1.0 / 6.0 + t2 / 120.0, -1.0 / 24.0 + t2 / 720.0, -1.0 / 60.0
    else:
        t4 = t2 * t2
        s, co = math.sin(t), math.cos(t)
        b = (t - s) / (t2 * t)
        c = (1.0 - 0.5 * t2 - co) / t4
        d = (2.0 * t - 3.0 * s + t * co) / (2.0 * t4 * t)
    v, w, vw, wv, wvw, vww, wvww, q = m[0], m[1], m[2], m[3], m[4], m[5], m[6], m[7]
    _skew(rho, v)
    _skew(theta, w)
    matmul_into(v, w, vw)
    for i in range(3):  # WV = (VW)^T for skew V, W
        for j in range(3):
            wv[i, j] = vw[j, i]
    matmul_into(wv, w, wvw)
    matmul_into(vw, w, vww)
    matmul_into(wvw, w, wvww)
    wwvw = m[2]  # reuse: VW is not needed below (its transpose WV is)
    matmul_into(w, wvw, wwvw)
    for i in range(3):
        for j in range(3):
            q[i, j] = (0.5 * v[i, j] + b * (wv[i, j] + wv[j, i] + wvw[i, j])
                       - c * (vww[i, j] - vww[j, i] - 3.0 * wvw[i, j]) + d * (wvww[i, j] + wwvw[i, j]))


@_jit
def frame_task(jac_world, site_pos, site_mat, target_pos, target_mat, error, jac_task, scratch):
    """e_f (6,) and J_f (6 x nv) of the frame task (module docstring).

    Args:
        jac_world: mj_jacSite [J_p; J_r] (6 x nv), world-aligned.
        site_pos, site_mat: site position (3,) and row-major rotation (9,).
        target_pos, target_mat: target position (3,) and row-major rotation (9,).
        error, jac_task: outputs.
        scratch: (12, 3, 3).
    """
    nv = jac_world.shape[1]
    r_b = site_mat.reshape(3, 3)
    r_t = target_mat.reshape(3, 3)
    r_tb = scratch[8]
    for i in range(3):
        for j in range(3):
            r_tb[i, j] = r_t[0, i] * r_b[0, j] + r_t[1, i] * r_b[1, j] + r_t[2, i] * r_b[2, j]
    quat = np.empty(4)
    mat_to_quat_into(r_tb.ravel(), quat)  # w >= 0: the rotation of angle <= pi
    vnorm = math.sqrt(quat[1] ** 2 + quat[2] ** 2 + quat[3] ** 2)
    theta = np.zeros(3)
    if vnorm >= _EPS:
        angle = 2.0 * math.atan2(vnorm, quat[0])
        for i in range(3):
            theta[i] = angle * quat[i + 1] / vnorm
    p_tb = np.empty(3)
    for i in range(3):
        sum_ = 0.0
        for k in range(3):
            sum_ += r_t[k, i] * (site_pos[k] - target_pos[k])
        p_tb[i] = sum_
    # rho = V^-1(theta) p_tb, V^-1 = I - W/2 + k W^2
    t2 = theta[0] ** 2 + theta[1] ** 2 + theta[2] ** 2
    w, w2 = scratch[9], scratch[11]
    _skew(theta, w)
    matmul_into(w, w, w2)
    if t2 < _EPS:
        k = 1.0 / 12.0
    else:
        t = math.sqrt(t2)
        k = (1.0 - 0.5 * t * math.cos(0.5 * t) / math.sin(0.5 * t)) / t2
    for i in range(3):  # e_f = -log(T_tb) = -[rho; theta]
        rho_i = p_tb[i]
        for j in range(3):
            rho_i += (-0.5 * w[i, j] + k * w2[i, j]) * p_tb[j]
        error[i] = -rho_i
        error[3 + i] = -theta[i]
    # Jl^-1(e_f) (6x6)
    jl = np.zeros((6, 6))
    for i in range(6):
        jl[i, i] = 1.0
    if error[3] ** 2 + error[4] ** 2 + error[5] ** 2 >= _EPS:
        block, tmp = scratch[10], scratch[9]
        _so3_left_jacobian_inverse(error[3:], block)
        _se3_q(error[:3], error[3:], scratch)
        matmul_into(block, scratch[7], tmp)
        matmul_into(tmp, block, scratch[11])
        for i in range(3):
            for j in range(3):
                jl[i, j] = block[i, j]
                jl[3 + i, 3 + j] = block[i, j]
                jl[i, 3 + j] = -scratch[11][i, j]
    body = np.empty((6, nv))  # body Jacobian: R_b^T on both halves
    for half in range(2):
        for i in range(3):
            for col in range(nv):
                row = 3 * half
                body[row + i, col] = (r_b[0, i] * jac_world[row, col] + r_b[1, i] * jac_world[row + 1, col]
                                      + r_b[2, i] * jac_world[row + 2, col])
    for i in range(6):  # J_f = -Jl^-1 J_b
        for col in range(nv):
            s = 0.0
            for k in range(6):
                s += jl[i, k] * body[k, col]
            jac_task[i, col] = -s


@_jit
def solve_box_qp(h, c, lower, upper, x):
    """x = argmin 1/2 x^T H x + c^T x s.t. lower <= x <= upper (H SPD, lower <= upper), by a primal active set
    from x = clip(0). Returns False when a subproblem is not positive definite (or no convergence)."""
    n = c.shape[0]
    active = np.zeros(n, dtype=np.int64)  # 0 free, -1 at lower, +1 at upper
    for i in range(n):  # x = 0 clipped into the box (a joint already past a limit starts on it)
        x[i] = 0.0
        if lower[i] > 0.0:
            x[i], active[i] = lower[i], -1
        elif upper[i] < 0.0:
            x[i], active[i] = upper[i], 1
    g = np.empty(n)
    step = np.empty(n)
    free = np.empty(n, dtype=np.int64)
    at_minimiser = False  # x minimises the objective with the active bounds fixed
    for _ in range(8 * n + 20):
        for i in range(n):
            s = c[i]
            for j in range(n):
                s += h[i, j] * x[j]
            g[i] = s
        if at_minimiser:  # the active bounds' multipliers must be >= 0, else release the worst
            worst, worst_i = 0.0, -1
            for i in range(n):
                multiplier = g[i] if active[i] < 0 else (-g[i] if active[i] > 0 else 0.0)
                if multiplier < worst:
                    worst, worst_i = multiplier, i
            if worst_i < 0:
                return True
            active[worst_i] = 0
            at_minimiser = False
            continue
        m = 0
        for i in range(n):
            if active[i] == 0:
                free[m] = i
                m += 1
        for i in range(n):
            step[i] = 0.0
        if m:
            sub = np.empty((m, m))
            rhs = np.empty(m)
            for a in range(m):
                rhs[a] = -g[free[a]]
                for b in range(m):
                    sub[a, b] = h[free[a], free[b]]
            chol = np.zeros((m, m))
            if not cholesky_lower(sub, chol):
                return False
            y = np.empty(m)  # forward then backward substitution
            for a in range(m):
                s = rhs[a]
                for b in range(a):
                    s -= chol[a, b] * y[b]
                y[a] = s / chol[a, a]
            for a in range(m - 1, -1, -1):
                s = y[a]
                for b in range(a + 1, m):
                    s -= chol[b, a] * step[free[b]]
                step[free[a]] = s / chol[a, a]
        alpha, blocking, side = 1.0, -1, 0
        for i in range(n):
            if step[i] > 0.0 and x[i] + step[i] > upper[i]:
                a = (upper[i] - x[i]) / step[i]
                if a < alpha:
                    alpha, blocking, side = a, i, 1
            elif step[i] < 0.0 and x[i] + step[i] < lower[i]:
                a = (lower[i] - x[i]) / step[i]
                if a < alpha:
                    alpha, blocking, side = a, i, -1
        for i in range(n):
            x[i] += alpha * step[i]
        if blocking >= 0:
            x[blocking] = upper[blocking] if side > 0 else lower[blocking]
            active[blocking] = side
        else:
            at_minimiser = True
    return False


@_jit
def ik_step(jac_world, site_pos, site_mat, target_pos, target_mat, qpos, q_nominal, dof_qpos_adr, posture_weight,
            lm_damping, damping, limited, q_min, q_max, limit_gain, dq, scratch):
    """dq (nv) of one differential-IK step (module docstring); False when the QP failed.

    Args:
        dof_qpos_adr: (nv,) qpos address of each hinge/slide dof, -1 on free-joint dofs (no posture term).
        posture_weight: w_p, the posture task's cost.
        limited, q_min, q_max: (nv,) 1.0 where the dof's joint is limited, and its range.
        limit_gain: the configuration limit's gain (mink: 0.95).
        scratch: (12, 3, 3).
    """
    nv = jac_world.shape[1]
    error = np.empty(6)
    jac_task = np.empty((6, nv))
    frame_task(jac_world, site_pos, site_mat, target_pos, target_mat, error, jac_task, scratch)
    mu = damping + lm_damping * (error[0] ** 2 + error[1] ** 2 + error[2] ** 2 + error[3] ** 2 + error[4] ** 2
                                 + error[5] ** 2)
    h = np.empty((nv, nv))
    c = np.empty(nv)
    for i in range(nv):
        s = 0.0
        for r in range(6):
            s += jac_task[r, i] * error[r]
        c[i] = s
        for j in range(nv):
            s = 0.0
            for r in range(6):
                s += jac_task[r, i] * jac_task[r, j]
            h[i, j] = s
    w2 = posture_weight * posture_weight
    lower = np.empty(nv)
    upper = np.empty(nv)
    for i in range(nv):
        lower[i] = -np.inf
        upper[i] = np.inf
        h[i, i] += mu
        adr = dof_qpos_adr[i]
        if adr >= 0:
            h[i, i] += w2
            c[i] += w2 * (qpos[adr] - q_nominal[adr])
            if limited[i] != 0.0:
                lower[i] = -limit_gain * (qpos[adr] - q_min[i])
                upper[i] = limit_gain * (q_max[i] - qpos[adr])
    return solve_box_qp(h, c, lower, upper, dq)


@_jit
def ik_iterations(fns, m, d, site, iterations, jac, site_pos, site_mat, target_pos, target_mat, qpos, q_nominal,
                  dof_qpos_adr, posture_weight, lm_damping, damping, limited, q_min, q_max, limit_gain, dq,
                  scratch):
    """``iterations`` differential-IK steps of the configuration of MjData ``d`` (its qpos, site_xpos[site] and
    site_xmat[site] views are ``qpos``, ``site_pos``, ``site_mat``): per step mj_jacSite into ``jac`` (6, nv,
    C-contiguous), `ik_step`, mj_integratePos(qpos, dq, 1), mj_kinematics and mj_comPos. Returns the number of
    steps taken: fewer than ``iterations`` when a QP failed (the configuration is then that of the steps before).

    Args:
        fns, m, d: controllers.mujoco_c.FUNCTIONS, MjModel._address, MjData._address.
        the others: as in `ik_step`.
    """
    nv = jac.shape[1]
    for k in range(iterations):
        call_mdppi(fns[FN_JAC_SITE], m, d, jac.ctypes.data, jac.ctypes.data + 3 * nv * 8, site)
        if not ik_step(jac, site_pos, site_mat, target_pos, target_mat, qpos, q_nominal, dof_qpos_adr,
                       posture_weight, lm_damping, damping, limited, q_min, q_max, limit_gain, dq, scratch):
            return k
        call_integrate_pos(fns[FN_INTEGRATE_POS], m, qpos.ctypes.data, dq.ctypes.data, 1.0)
        call_md(fns[FN_KINEMATICS], m, d)
        call_md(fns[FN_COM_POS], m, d)
    return iterations
