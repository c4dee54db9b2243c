"""The simulator reads of an observation in one compiled call (envs.sim.observation.Observer.observe).

Every control period the observation read three site poses (each a quaternion by mju_mat2Quat through the bindings),
checked the peg tip's pose, turned its quaternion back into a rotation matrix for the success check and read its
velocity (mj_objectVelocity): about 10 us of Python a period. Here it is one call to the same MuJoCo functions
(controllers.mujoco_c) and the same rotation formula (`numerics.quaternion.matrix_components`, compiled from its
source), so the observation and the records are the same to the last bit (tests/envs/sim/test_observation_kernel.py).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from controllers.impedance_kernel import matrix_components
from controllers.mujoco_c import FN_MAT2QUAT, FN_OBJECT_VELOCITY, call_md, call_object_velocity
from numerics.small_linalg import norm

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")

OBJ_SITE = 6
"""mjtObj.mjOBJ_SITE (tests/controllers/test_mujoco_c.py checks it)."""
NOT_FINITE = -1.0
"""What `read_sites_into` returns for a peg tip whose pose is not finite (a speed is >= 0 or NaN)."""


@_jit
def read_sites_into(fns: np.ndarray, m: int, d: int, sites: np.ndarray, site_xpos: np.ndarray, site_xmat: np.ndarray,
                    poses: np.ndarray, rotation: np.ndarray, velocity: np.ndarray) -> float:
    """The world poses of ``sites`` into ``poses`` (S, 7: position, quaternion w, x, y, z by mju_mat2Quat); for the
    last site (the peg tip), when its pose is finite with |q| > 0.5, its rotation matrix from that quaternion into
    ``rotation`` (3, 3) and its linear speed (mj_objectVelocity in the world frame into ``velocity`` (6,)).

    Returns:
        The last site's linear speed |v| (m/s; NaN where the velocities are), or NOT_FINITE when its pose is not finite
        (``rotation`` and ``velocity`` then unset).
    """
    count = sites.shape[0]
    base = poses.ctypes.data
    for i in range(count):
        site = sites[i]
        for k in range(3):
            poses[i, k] = site_xpos[site, k]
        call_md(fns[FN_MAT2QUAT], base + (7 * i + 3) * 8, site_xmat.ctypes.data + 9 * 8 * site)
    tip = poses[count - 1]
    finite = True
    for k in range(7):
        finite = finite and math.isfinite(tip[k])
    if not (finite and norm(tip[3:7]) > 0.5):
        return NOT_FINITE
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = matrix_components(tip[3], tip[4], tip[5], tip[6])
    rotation[0, 0], rotation[0, 1], rotation[0, 2] = r00, r01, r02
    rotation[1, 0], rotation[1, 1], rotation[1, 2] = r10, r11, r12
    rotation[2, 0], rotation[2, 1], rotation[2, 2] = r20, r21, r22
    call_object_velocity(fns[FN_OBJECT_VELOCITY], m, d, OBJ_SITE, sites[count - 1], velocity.ctypes.data, 0)
    return norm(velocity[3:6])
