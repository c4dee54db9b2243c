"""The feed-forward lead of an action in one compiled call (controllers.feedforward.led_pose): the twist and
acceleration limits, the lead, the push and the rotation vector onto the anchor,

    f(xi)   = min(1, v_max / |v|, w_max / |omega|)            (1 where |v| or |omega| is 0)
    xi'     = f(xi) xi,     a' = f(s a) s a,   s = |xi'| / |xi|  (1 for xi = 0), the acceleration limits in f
    delta   = gain K^-1 (D(q) xi' + Lambda(q) a') + push         (controllers.impedance_kernel.pose_lead_into)
    x_cmd   = (p_anchor + delta_p,  normalised Exp(delta_r) q_anchor)

with the sums in the order of the Python reference in tests/controllers/test_feedforward.py (limits, `pose_lead`,
push, `numerics.quaternion`'s scalar formulas compiled from their source), so the commanded poses equal it to the last
bit: a control period pays one call instead of ~15 small numpy steps.
"""

from __future__ import annotations

import numba
import numpy as np

from controllers.impedance_kernel import LEAD_OK, hamilton, pose_lead_into, quat_of_rotvec_components
from numerics.small_linalg import norm

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")


@_jit
def limit_factor(xi: np.ndarray, max_linear: float, max_angular: float) -> float:
    """f = min(1, max_linear / |xi[:3]|, max_angular / |xi[3:]|), a term 1 where its norm is 0 (or NaN): the one
    factor that scales a twist (or an acceleration) down to both limits."""
    speed = norm(xi[0:3])
    spin = norm(xi[3:6])
    return min(1.0, max_linear / speed if speed > 0 else 1.0, max_angular / spin if spin > 0 else 1.0)


@_jit
def led_pose_into(fns: np.ndarray, m: int, d: int, site: int, jac: np.ndarray, jac_minv: np.ndarray,
                  stiffness: np.ndarray, regularisation: float, two_zeta: float, lambda_inv: np.ndarray,
                  p: np.ndarray, w: np.ndarray, work: np.ndarray, k_copy: np.ndarray, raw_twist: np.ndarray,
                  raw_accel: np.ndarray, push: np.ndarray, gain: float, anchor_pos: np.ndarray,
                  anchor_quat: np.ndarray, limits: np.ndarray, scratch: np.ndarray, out: np.ndarray) -> int:
    """The commanded pose x_cmd (module docstring) into ``out`` (7,: position, unit quaternion w, x, y, z).

    Args:
        fns .. k_copy: `CartesianImpedanceController.lead_arguments` (K checked SPD).
        raw_twist, raw_accel, push: the action's twist, acceleration (zero: none) and push (6,), finite.
        gain: the feed-forward gain.
        anchor_pos, anchor_quat: the pose the lead is added to (3,), (4,).
        limits: [max speed, max angular speed, max acceleration, max angular acceleration].
        scratch: (3, 6) buffer.

    Returns:
        LEAD_OK, or `pose_lead_into`'s failure status (``out`` then undefined).
    """
    twist, accel, lead = scratch[0], scratch[1], scratch[2]
    factor = limit_factor(raw_twist, limits[0], limits[1])
    moving = False
    for i in range(6):
        twist[i] = raw_twist[i] * factor
        moving = moving or raw_twist[i] != 0.0
    scale = norm(twist) / norm(raw_twist) if moving else 1.0
    for i in range(6):
        accel[i] = scale * raw_accel[i]
    factor = limit_factor(accel, limits[2], limits[3])
    for i in range(6):
        accel[i] = accel[i] * factor
    status = pose_lead_into(fns, m, d, site, jac, jac_minv, stiffness, regularisation, two_zeta, twist, accel, True,
                            lambda_inv, p, w, work, k_copy, lead)
    if status != LEAD_OK:
        return status
    for i in range(6):
        lead[i] = gain * lead[i] + push[i]
    rw, rx, ry, rz = quat_of_rotvec_components(lead[3], lead[4], lead[5])
    quat = out[3:7]
    quat[0], quat[1], quat[2], quat[3] = hamilton(rw, rx, ry, rz, anchor_quat[0], anchor_quat[1], anchor_quat[2],
                                                  anchor_quat[3])
    length = norm(quat)
    for i in range(4):
        quat[i] = quat[i] / length
    for i in range(3):
        out[i] = anchor_pos[i] + lead[i]
    return LEAD_OK
