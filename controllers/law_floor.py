"""Cheaper control laws than the one of record, run only to time them: what a control period would cost if the
controller did less per 1 kHz physics step (`pih bench`, episode_steps.law_floor_us).

Both run a period's physics steps exactly as `impedance_kernel.impedance_substep` does (the tool load, mj_step1,
mj_jacSite, the law, mj_step2; no torque disturbance, no sensing), with one of these laws:

    LAW_SPRING_DAMPER   tau = J^T (K e - D J qdot) + c,   D = diag(2 zeta sqrt(K_ii)),
                        clipped to +-tau_max: the plain Cartesian spring-damper of a torque-controlled arm (no
                        inertia in the damping, no posture torque, no rate limit, no mj_solveM): the least any
                        Cartesian impedance law computes per step.
    LAW_HELD_FACTORS    the law of record (`factored_torque`) with Lambda^-1 and its modal factors P, w
                        (`impedance_factors`) computed at the period's first step only and held for the others.
    LAW_OF_RECORD       the law of record itself (`impedance_torque`: the factors at every step), as the
                        reference the two are timed against.

The first two are not controllers of the testbed: no episode runs them. They bound from below what a cheaper law
of record could save (the README's speed section).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from controllers.impedance_kernel import factored_torque, impedance_factors, pose_error_into, tool_load_into, \
    TOOL_ENABLED
from controllers.mujoco_c import FN_JAC_SITE, FN_SOLVE_M, FN_STEP1, FN_STEP2, call_md, call_mdppi

LAW_SPRING_DAMPER, LAW_HELD_FACTORS, LAW_OF_RECORD = 0, 1, 2
"""The laws `reference_period` runs (module docstring)."""

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")


@_jit
def spring_damper_torque(jac: np.ndarray, qvel: np.ndarray, qfrc_bias: np.ndarray, site_pos: np.ndarray,
                         site_mat: np.ndarray, target: np.ndarray, stiffness: np.ndarray, params: np.ndarray,
                         ctrl: np.ndarray, vec: np.ndarray) -> None:
    """tau = clip(J^T (K e - D J qdot) + c, +-tau_max), D = diag(2 zeta sqrt(K_ii)) (module docstring) into ctrl.
    Arguments as in `impedance_kernel.impedance_torque` (params[1] = 4 zeta^2)."""
    n = ctrl.shape[0]
    nv = jac.shape[1]
    dof0 = int(params[5])
    pose_error_into(target[0:3], target[3:7], site_pos, site_mat, vec[1], vec[7])
    for r in range(6):
        s = 0.0
        for k in range(nv):
            s += jac[r, k] * qvel[k]
        f = 0.0
        for c in range(6):
            f += stiffness[r, c] * vec[1, c]
        vec[5, r] = f - math.sqrt(max(stiffness[r, r], 0.0) * params[1]) * s
    for i in range(n):
        t = qfrc_bias[i]
        for r in range(6):
            t += jac[r, dof0 + i] * vec[5, r]
        limit = params[6 + i]
        ctrl[i] = min(max(t, -limit), limit)


@_jit
def reference_period(n_substeps: int, law: int, fns: np.ndarray, m: int, d: int, site: int, jac: np.ndarray,
                     jac_minv: np.ndarray, qpos: np.ndarray, qvel: np.ndarray, qfrc_bias: np.ndarray,
                     site_pos: np.ndarray, site_mat: np.ndarray, target: np.ndarray, stiffness: np.ndarray,
                     params: np.ndarray, last_tau: np.ndarray, ctrl: np.ndarray, work: np.ndarray, vec: np.ndarray,
                     tool: np.ndarray, tool_point: np.ndarray, jac_tool: np.ndarray, jac_tool_arm: np.ndarray,
                     applied: np.ndarray) -> bool:
    """``n_substeps`` physics steps under ``law`` (LAW_*; module docstring), from the arguments of
    `impedance_kernel.impedance_substep` (its first 23, without the disturbance). False when Lambda^-1 is not
    positive definite (the step is then left after mj_step1). The law of record runs without the friction
    observer (controllers.joint_torque_kernel): a floor of the law, compared with a period whose controller has the
    observer off."""
    nv = jac.shape[1]
    no_offset = np.zeros(last_tau.shape[0])
    for step in range(n_substeps):
        if tool[TOOL_ENABLED] != 0.0:
            tool_load_into(fns, m, d, tool, site_pos, site_mat, tool_point, jac_tool, jac_tool_arm, applied)
        call_md(fns[FN_STEP1], m, d)
        call_mdppi(fns[FN_JAC_SITE], m, d, jac.ctypes.data, jac.ctypes.data + 3 * nv * 8, site)
        if law == LAW_SPRING_DAMPER:
            spring_damper_torque(jac, qvel, qfrc_bias, site_pos, site_mat, target, stiffness, params, ctrl, vec)
        else:
            call_mdppi(fns[FN_SOLVE_M], m, d, jac_minv.ctypes.data, jac.ctypes.data, 6)
            if (law == LAW_OF_RECORD or step == 0) and not impedance_factors(jac, jac_minv, stiffness, params, work,
                                                                              vec):
                return False
            factored_torque(jac, jac_minv, qpos, qvel, qfrc_bias, site_pos, site_mat, target, stiffness, params,
                            last_tau, ctrl, work, vec, no_offset)
        call_md(fns[FN_STEP2], m, d)
    return True


__all__ = ["LAW_HELD_FACTORS", "LAW_OF_RECORD", "LAW_SPRING_DAMPER", "reference_period", "spring_damper_torque"]
