"""The velocity feed-forward: the pose the impedance controller commands for an `Action` with a twist.

The impedance controller (controllers.impedance) pulls toward an equilibrium pose with F = K e - D v, so to move at a
twist xi_d in quasi-steady state (F ~ 0) the commanded pose must lead the intended pose by K^-1 D xi_d. Without it the
compliant arm lags and, D being anisotropic (it follows the Cartesian inertia), it also drifts sideways (~6 % of the
distance travelled here), which is larger than the hole's clearance. For an action with a twist the controller
therefore commands
    x_cmd = anchor (+) (gain K^-1 (D(q) xi_d + Lambda(q) a_d) + push),   D = P diag(2 zeta sqrt(w)) P^T
(controllers.impedance.CartesianImpedanceController.pose_lead, modal_factors; position + world rotation vector,
q' = exp(delta_r) q), with the twist and the acceleration each scaled down by one factor to the MAX_* limits below
(`feedforward_kernel.limit_factor`), all in one compiled call (`feedforward_kernel.led_pose_into`). The lead needs the
simulator's state (the arm's inertia at q), which a policy never sees: a policy only says how it wants to move.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from controllers import feedforward_kernel as kernel
from controllers import impedance_kernel
from controllers.action import Action
from controllers.errors import ControllerError
from controllers.validation import as_vector
from numerics.pose import Pose

FloatArray = npt.NDArray[np.float64]

MAX_SPEED_M_S: float = 0.5
"""The feed-forward twist is scaled down to at most this linear speed (the demos peak near 0.15 m/s)."""
MAX_ANGULAR_SPEED_RAD_S: float = 2.0
"""... and at most this angular speed."""
MAX_ACCEL_M_S2: float = 2.0
"""The feed-forward acceleration is scaled down to at most this linear acceleration ..."""
MAX_ANGULAR_ACCEL_RAD_S2: float = 10.0
"""... and at most this angular acceleration."""

_LIMITS = np.array([MAX_SPEED_M_S, MAX_ANGULAR_SPEED_RAD_S, MAX_ACCEL_M_S2, MAX_ANGULAR_ACCEL_RAD_S2])
"""The four limits as `feedforward_kernel.led_pose_into` reads them."""
_LIMITS.setflags(write=False)


def check_lead_status(status: int) -> None:
    """Raise for a failed `impedance_kernel.pose_lead_into` (its LEAD_* status).

    Raises:
        ControllerError: J M^-1 J^T not positive definite, or a singular stiffness.
    """
    if status == impedance_kernel.LEAD_NOT_POSITIVE_DEFINITE:
        raise ControllerError("J M^-1 J^T is not positive definite (Cholesky failed)")
    if status == impedance_kernel.LEAD_SINGULAR_STIFFNESS:
        raise ControllerError("the stiffness is singular (a zero pivot)")


def led_pose(controller: Any, data: Any, action: Action, gain: float, stiffness: FloatArray | None) -> Pose:
    """The pose to command for ``action`` with a twist (module docstring): its anchor led by gain K^-1 (D(q) xi +
    Lambda(q) a) + push, K = ``stiffness`` (6x6; None: the controller's default), D and Lambda at the state of
    ``data``; the action's fields are checked first, then the controller's `lead_arguments` (which check K).

    Args:
        controller: a CartesianImpedanceController (its ``lead_arguments(data, stiffness)``).
        data: its MuJoCo data, kinematics and mass matrix current (after mj_forward or a physics step).
        action: an action with a twist.
        gain: the feed-forward gain (> 0).
        stiffness: the 6x6 stiffness commanded with it.

    Raises:
        ControllerError: a twist, acceleration or push that is not 6 finite numbers, an anchor that is not a pose, a
            bad stiffness, a singular arm.
    """
    raw = as_vector(action.twist, 6, "twist")
    accel = np.zeros(6) if action.accel is None else as_vector(action.accel, 6, "accel")  # writable: one signature
    push = np.zeros(6) if action.push is None else np.array(action.push, dtype=np.float64)
    if push.shape != (6,):
        raise ControllerError(f"an action's push must be 6 numbers, got shape {push.shape}")
    anchor = action.pose if action.anchor is None else action.anchor
    anchor_pos = np.asarray(anchor.pos, dtype=np.float64)
    anchor_quat = np.asarray(anchor.quat, dtype=np.float64)
    if anchor_pos.shape != (3,) or anchor_quat.shape != (4,):
        raise ControllerError(f"an action's anchor must be a pose, got shapes {anchor_pos.shape}, {anchor_quat.shape}")
    fns, m, d, site, jac, jac_minv, k, regularisation, two_zeta, scratch = controller.lead_arguments(data, stiffness)
    out = np.empty(7)
    check_lead_status(kernel.led_pose_into(fns, m, d, site, jac, jac_minv, k, regularisation, two_zeta, *scratch, raw,
                                           accel, push, float(gain), anchor_pos, anchor_quat, _LIMITS,
                                           np.empty((3, 6)), out))
    return Pose(pos=out[:3], quat=out[3:])
