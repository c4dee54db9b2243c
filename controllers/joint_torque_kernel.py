"""The arm's link-side joint torque sensors, the friction observer closed on them, and the joints' smooth transmission
friction, compiled for the impedance controller's physics step (controllers.impedance_kernel.impedance_substep).

Joint model. A joint's motor delivers tau_m (the command, plus the actuator's torque noise where the cell has one);
its transmission loses the friction tau_f before the link-side torque sensor, which reads

    tau_J = tau_m - tau_f + b + n_k                                                  (1)

with b the sensor's bias (per episode) and n_k its noise (per reading). In MuJoCo the transmission friction is the
joint's own: the dof's stick-slip friction rows (frictionloss) and its viscous damping (qfrc_passive), and, for the
smooth identified law, a torque the actuator subtracts from what it delivers (`smooth_friction`). So the reading is
ctrl + qfrc_applied + qfrc_passive + the dof friction rows' force, plus b + n_k, on the arm's dofs (ctrl carries the
noise and the smooth friction already; qfrc_applied carries the tool load the motors hold).

Friction observer (Le Tien, Albu-Schaeffer, De Luca, Hirzinger, "Friction observer and compensation for control of
robots with joint torque measurement", IROS 2008; the Panda's joints carry such sensors). The torque the transmission
lost is what the motor was told minus what the sensor reads, r_k = tau_c,k - (tau_J,k - b_hat), with tau_c the
commanded motor torque (the law's with the compensation, and the tool load). A first-order low pass of it,

    f_{k+1} = sat(f_k + (T / T_o) (r_k - f_k), +-f_max),                             (2)

is added to the next command, tau_c = tau_law + f (inside the Panda's torque and rate limits: the law's command
tau_c is what they bound, controllers.impedance_kernel). At rest the joint sticks while the command stays below the
friction, r_k equals the command and f grows until the joint breaks free; sliding, f settles on the friction itself,
so the link feels tau_law less the friction's change over T_o. What the observer cannot tell from friction is the
sensor's bias: uncorrected, f would absorb -b and the arm would push with b. The bias is therefore tared once per
episode at rest in free space (`FB_TARE` while the grasp settles): the links then hold their own weight and the
tool's, so the reading less the model's bias torque c(q, 0) (qfrc_bias) and the tool load the motors hold
(qfrc_applied) is b plus the payload's model error,

    b_hat = mean_k (tau_J,k - (c_k + tau_tool,k)),                                   (3)

which is removed from every reading after it. T_o, f_max: `controllers.impedance.ImpedanceConfig`.

Smooth transmission friction (Gaz, Cognetti, Oliva, Robuffo Giordano, De Luca, "Dynamic identification of the Franka
Emika Panda robot with retrieval of feasible parameters using penalty-based optimization", RA-L 2019, supplementary
Table I): per joint

    tau_f(qdot) = phi_1 / (1 + exp(-phi_2 (qdot + phi_3))) - phi_1 / (1 + exp(-phi_2 phi_3)),  (4)

zero at rest and smooth through it (no stiction).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from controllers.mujoco_c import float64_pointer, int32_pointer, load_i32, load_pointer
from controllers.mujoco_layout import LAYOUT_EFC_FORCE, LAYOUT_EFC_ID, LAYOUT_EFC_TYPE, LAYOUT_NEFC

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")

FRICTION_DOF_ROW = 1
"""MuJoCo's mjCNSTR_FRICTION_DOF: a dof's stick-slip friction row in mjData.efc_type."""

(FB_ON, FB_GAIN, FB_LIMIT, FB_TARE, FB_TARE_COUNT, FB_ROW, FB_NOISE_ON, FB_SIZE_HEAD) = range(8)
"""Head slots of the feedback vector: observer on (0/1), its gain T / T_o, the compensation's bound f_max (N m), tare
running (0/1), readings in the tare, the next sensor-noise row, sensor noise on (0/1). Then four blocks of n: the
compensation f, the tare's sum, the bias estimate b_hat and the sensors' true bias b (`feedback_slices`)."""


def feedback_size(n: int) -> int:
    """Length of the feedback vector for an arm of n joints."""
    return FB_SIZE_HEAD + 4 * n


def feedback_slices(n: int) -> tuple[slice, slice, slice, slice]:
    """(f, tare sum, b_hat, b) blocks of the feedback vector."""
    head = FB_SIZE_HEAD
    return (slice(head, head + n), slice(head + n, head + 2 * n), slice(head + 2 * n, head + 3 * n),
            slice(head + 3 * n, head + 4 * n))


@_jit
def smooth_friction(qdot: float, phi_1: float, phi_2: float, phi_3: float) -> float:
    """tau_f(qdot) of (4), N m (the torque friction takes from the joint's motion)."""
    return phi_1 / (1.0 + math.exp(-phi_2 * (qdot + phi_3))) - phi_1 / (1.0 + math.exp(-phi_2 * phi_3))


@_jit
def friction_rows_into(d: int, layout: np.ndarray, dof0: int, out: np.ndarray) -> None:
    """out[i] += the force of the stick-slip friction rows of dof dof0 + i (mjData's efc arrays after mj_step2)."""
    n = out.shape[0]
    nefc = load_i32(d + layout[LAYOUT_NEFC])
    if nefc <= 0:
        return
    kinds = numba.carray(int32_pointer(load_pointer(d + layout[LAYOUT_EFC_TYPE])), (nefc,))
    ids = numba.carray(int32_pointer(load_pointer(d + layout[LAYOUT_EFC_ID])), (nefc,))
    forces = numba.carray(float64_pointer(load_pointer(d + layout[LAYOUT_EFC_FORCE])), (nefc,))
    for r in range(nefc):
        if kinds[r] == FRICTION_DOF_ROW:
            k = ids[r] - dof0
            if 0 <= k < n:
                out[k] += forces[r]


@_jit
def feedback_update(d: int, layout: np.ndarray, dof0: int, ctrl: np.ndarray, applied: np.ndarray,
                    qfrc_passive: np.ndarray, qfrc_bias: np.ndarray, last_tau: np.ndarray, feedback: np.ndarray,
                    noise: np.ndarray, reading: np.ndarray) -> None:
    """After mj_step2: the sensors' reading (1) into ``reading`` (n,), then the tare (3) or the observer (2).

    Args:
        d, layout: the mjData's address and controllers.mujoco_layout's offsets.
        dof0: the arm's first dof; ctrl, applied, qfrc_bias, last_tau: the arm's (n,) views; qfrc_passive: all nv.
        feedback: the feedback vector (FB_* slots, `feedback_slices`), updated.
        noise: the sensors' noise rows (R, n), read from FB_ROW on (the last repeating) when FB_NOISE_ON.
        reading: (n,) scratch, receives tau_J less b_hat.
    """
    n = ctrl.shape[0]
    head = FB_SIZE_HEAD
    for i in range(n):
        reading[i] = ctrl[i] + applied[i] + qfrc_passive[dof0 + i]
    friction_rows_into(d, layout, dof0, reading)
    row = -1
    if feedback[FB_NOISE_ON] != 0.0:
        row = min(int(feedback[FB_ROW]), noise.shape[0] - 1)
        feedback[FB_ROW] += 1.0
    for i in range(n):
        reading[i] += feedback[head + 3 * n + i] + (noise[row, i] if row >= 0 else 0.0)
    if feedback[FB_TARE] != 0.0:
        feedback[FB_TARE_COUNT] += 1.0
        for i in range(n):
            feedback[head + n + i] += reading[i] - (qfrc_bias[i] + applied[i])
        return
    gain, limit = feedback[FB_GAIN], feedback[FB_LIMIT]
    for i in range(n):
        f = feedback[head + i]
        lost = (last_tau[i] + applied[i]) - (reading[i] - feedback[head + 2 * n + i])
        f += gain * (lost - f)
        feedback[head + i] = min(max(f, -limit), limit)


@_jit
def compensation_into(feedback: np.ndarray, out: np.ndarray) -> None:
    """out (n,) = the observer's compensation f where it runs (on, tare over), else 0: what the law adds to its torque
    before the Panda's torque and rate limits (controllers.impedance_kernel.factored_torque)."""
    n = out.shape[0]
    active = feedback[FB_ON] != 0.0 and feedback[FB_TARE] == 0.0
    for i in range(n):
        out[i] = feedback[FB_SIZE_HEAD + i] if active else 0.0


@_jit
def actuator_torque_into(dof0: int, qvel: np.ndarray, ctrl: np.ndarray, disturbance: np.ndarray,
                         disturbance_state: np.ndarray, smooth: np.ndarray) -> None:
    """What the motors deliver this physics step, into ctrl (which holds the command, the law's with the observer's
    compensation): plus the actuators' noise row (when on), less the smooth transmission friction (4) at the joint's
    speed (when on; ``smooth`` rows [phi_1, phi_2, phi_3])."""
    n = ctrl.shape[0]
    if disturbance_state[0] != 0.0:
        row = int(disturbance_state[1])
        disturbance_state[1] = row + 1
        row = min(row, disturbance.shape[0] - 1)
        for i in range(n):
            ctrl[i] += disturbance[row, i]
    if disturbance_state[2] != 0.0:
        for i in range(n):
            ctrl[i] -= smooth_friction(qvel[dof0 + i], smooth[i, 0], smooth[i, 1], smooth[i, 2])
