"""What the cell's controller side does with a policy's `Action`: the 6x6 stiffness and the feed-forward lead.

Velocity feed-forward. The impedance controller (controllers.impedance) pulls toward an equilibrium pose
with F = K e - D v, so to move at a twist xi_d in quasi-steady state (F ~ 0) the commanded pose must lead the
intended pose by K^-1 D xi_d. Without it the compliant arm lags and, D being anisotropic (it follows the
Cartesian inertia), it also drifts sideways (~6 % of the distance travelled here), which is larger than the hole's
clearance. For an action with a twist the episode loop therefore sends
    x_cmd = anchor (+) (gain K^-1 (D(q) xi_d + Lambda(q) a_d) + push),   D = P diag(2 zeta sqrt(w)) P^T
(controllers.impedance.pose_lead, modal_factors; position + world rotation vector, q' = exp(delta_r) q), with
the twist and the acceleration each scaled down by one factor to the MAX_* limits below
(`feedforward_kernel.limit_factor`). The lead is computed by the controller from the simulator's state, which a
policy never sees: a policy only says how it wants to move.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from controllers.impedance import check_lead_status, full_stiffness
from controllers.validation import as_vector
from envs.errors import EnvError
from envs.policies import feedforward_kernel as kernel
from envs.policies.interface import Action
from envs.poses import Pose

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


def command_stiffness(env: Any, action: Action) -> FloatArray | None:
    """The 6x6 stiffness to pass to ``env.step`` with ``action``: a (6, 6) stiffness as it is; else `full_stiffness`
    of the translational and rotational stiffness, each the controller's default where the action has none; None
    (the default) when it has neither.

    Raises:
        EnvError: a stiffness that is not (3, 3) or (6, 6), or a (6, 6) one with a rotational stiffness beside it.
    """
    k = action.stiffness
    if k is None and action.rotational_stiffness is None:
        return None
    if k is not None:
        shape = np.shape(k)
        if shape == (6, 6):
            if action.rotational_stiffness is not None:
                raise EnvError("an action with a (6, 6) stiffness must leave rotational_stiffness None")
            return np.asarray(k, dtype=np.float64)
        if shape != (3, 3):
            raise EnvError(f"action stiffness must be (3, 3) or (6, 6), got shape {shape}")
    config = env.controller.config
    k_trans = config.translational_stiffness * np.eye(3) if k is None else k
    k_rot = config.rotational_stiffness if action.rotational_stiffness is None else action.rotational_stiffness
    return full_stiffness(k_trans, k_rot)


def translational_stiffness(action: Action, default: FloatArray) -> FloatArray:
    """The (3, 3) translational stiffness ``action`` commands (``default``: the controller's, when it has none)."""
    k = action.stiffness
    if k is None:
        return default
    k = np.asarray(k, dtype=float)
    return k[:3, :3] if k.shape == (6, 6) else k


def feedforward_pose(env: Any, action: Action, gain: float = 1.0) -> Pose:
    """The pose to send to ``env.step``: with gain > 0 and a twist, the action's anchor led by gain * K^-1 D(q)
    twist (module docstring), K the stiffness commanded with it (`command_stiffness`); else the action's pose."""
    if gain == 0.0 or action.twist is None:
        return action.pose
    return led_pose(env, action, gain, command_stiffness(env, action))


def led_pose(env: Any, action: Action, gain: float, stiffness: FloatArray | None) -> Pose:
    """`feedforward_pose` given the action's 6x6 stiffness as made by `command_stiffness(env, action)` (the
    episode loop makes it once and passes the same matrix to ``env.step``): the limits, the lead, the push and the
    composition onto the anchor in one compiled call (`feedforward_kernel.led_pose_into`).

    Raises:
        ControllerError: a twist or acceleration that is not 6 finite numbers, a bad stiffness, a singular arm.
        EnvError: a push that is not 6 numbers, an anchor that is not a pose.
    """
    if gain == 0.0 or action.twist is None:
        return action.pose
    raw = as_vector(action.twist, 6, "twist")
    accel = np.zeros(6) if action.accel is None else as_vector(action.accel, 6, "accel")  # writable: one signature
    push = np.zeros(6) if action.push is None else np.array(action.push, dtype=np.float64)
    if push.shape != (6,):
        raise EnvError(f"an action's push must be 6 numbers, got shape {push.shape}")
    anchor = action.pose if action.anchor is None else action.anchor
    anchor_pos = np.asarray(anchor.pos, dtype=np.float64)
    anchor_quat = np.asarray(anchor.quat, dtype=np.float64)
    if anchor_pos.shape != (3,) or anchor_quat.shape != (4,):
        raise EnvError(f"an action's anchor must be a pose, got shapes {anchor_pos.shape}, {anchor_quat.shape}")
    fns, m, d, site, jac, jac_minv, k, regularisation, two_zeta, scratch = env.controller.lead_arguments(env.data,
                                                                                                          stiffness)
    out = np.empty(7)
    check_lead_status(kernel.led_pose_into(fns, m, d, site, jac, jac_minv, k, regularisation, two_zeta, *scratch, raw,
                                           accel, push, float(gain), anchor_pos, anchor_quat, _LIMITS,
                                           np.empty((3, 6)), out))
    return Pose(pos=out[:3], quat=out[3:])
