"""One control period of an episode -- its physics steps under impedance control, each followed by the sensing --
as one compiled call, so Python runs once per period instead of once per physics step.

For each of the period's n physics steps (envs.sim.env.PegInHoleEnv.step):

    controllers.impedance_kernel.impedance_substep   tool load, mj_step1, J, J M^-1, the law, mj_step2
    envs.sim.sensing_kernel.sense_substep_at             wrist wrench, contact forces, peaks, force window, force limit

stopping after the step at which the force limit hits, or before mj_step2 of a step whose law fails. The kernels are
the same functions the per-step path (controller.step with the sensing hook) calls, in the same order, so the
states and the episode records are the same to the last bit (tests/envs/sim/test_period_kernel.py); what goes is the
Python between physics steps (two kernel dispatches, a hook and the bindings' contact views per step).
"""

from __future__ import annotations

import numba
import numpy as np

from controllers.impedance_kernel import STATUS_OK, impedance_substep
from envs.sim.sensing_kernel import sense_substep_at

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")


@_jit
def controlled_period(n_substeps: int, fns: np.ndarray, m: int, d: int, site: int, jac: np.ndarray,
                      jac_minv: np.ndarray, qpos: np.ndarray, qvel: np.ndarray, qfrc_bias: np.ndarray,
                      site_pos: np.ndarray, site_mat: np.ndarray, target: np.ndarray, stiffness: np.ndarray,
                      params: np.ndarray, last_tau: np.ndarray, ctrl: np.ndarray, work: np.ndarray, vec: np.ndarray,
                      tool: np.ndarray, tool_point: np.ndarray, jac_tool: np.ndarray, jac_tool_arm: np.ndarray,
                      applied: np.ndarray, disturbance: np.ndarray, disturbance_state: np.ndarray,
                      smooth: np.ndarray, feedback: np.ndarray, sensor_noise: np.ndarray, feedback_layout: np.ndarray,
                      qfrc_passive: np.ndarray, reading: np.ndarray, layout: np.ndarray, rot: np.ndarray,
                      wrist_pos: np.ndarray, xipos: np.ndarray, force: np.ndarray, torque: np.ndarray, bodies: np.ndarray, load: np.ndarray,
                      counted: np.ndarray, scratch: np.ndarray, limits: np.ndarray, sensor: np.ndarray,
                      noise: np.ndarray, state: np.ndarray, sense_fns: np.ndarray, sense_m: int,
                      jt_index: np.ndarray, jt_jac: np.ndarray, qfrc_constraint: np.ndarray, jt_bodies: np.ndarray,
                      jt_load: np.ndarray, jt_noise: np.ndarray, jt_matrices: np.ndarray, jt_vectors: np.ndarray,
                      jt_estimate: np.ndarray) -> tuple[int, int, bool]:
    """Run up to ``n_substeps`` controlled, sensed physics steps (module docstring).

    Args:
        n_substeps: physics steps of the period.
        fns .. reading: ``CartesianImpedanceController.substep_arguments`` (the arguments of impedance_substep).
        layout .. jt_estimate: ``EpisodeSensing.period_arguments`` (those of sense_substep_at after the data's
            address).

    Returns:
        (physics steps completed, the law's status (STATUS_OK or its failure), whether the force limit hit).
    """
    for done in range(n_substeps):
        status = impedance_substep(fns, m, d, site, jac, jac_minv, qpos, qvel, qfrc_bias, site_pos, site_mat, target,
                                   stiffness, params, last_tau, ctrl, work, vec, tool, tool_point, jac_tool,
                                   jac_tool_arm, applied, disturbance, disturbance_state, smooth, feedback,
                                   sensor_noise, feedback_layout, qfrc_passive, reading)
        if status != STATUS_OK:
            return done, status, False
        if sense_substep_at(d, layout, rot, wrist_pos, xipos, force, torque, bodies, load, counted, scratch, limits,
                            sensor, noise, state, sense_fns, sense_m, jt_index, jt_jac, qfrc_constraint, jt_bodies,
                            jt_load, jt_noise, jt_matrices, jt_vectors, jt_estimate):
            return done + 1, STATUS_OK, True
    return n_substeps, STATUS_OK, False
