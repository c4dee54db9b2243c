"""The physics-rate sensing of an episode (envs.sim.sensing.EpisodeSensing), compiled with numba (no Python work per
step).

Every physics step (1 kHz) the episode reads the wrist F/T sensor and the peg's contacts, keeps their peaks and
checks the force limit. In numpy that was ~30 Python-level calls per step, costing about half of the physics step;
here it is one compiled call on views of MjData and preallocated buffers. (The grasped peg's weight, applied before every step, is the controller's tool load:
controllers.impedance_kernel.tool_load_into.)

Wrist wrench (envs.sim.sensing), in the sensor frame S with rotation R_S, from the readings F_s, tau_s:

    F_ext = -(F_s - F_0),   tau_ext = -(tau_s - tau_0),
    F_0 = -R_S^T M g,       tau_0 = -R_S^T (M (c - s) x g),   M (c - s) = sum_b m_b c_b - M s

with m_b, c_b the carried bodies' masses and centres of mass, M = sum_b m_b and s the site position.

Contacts (envs.sim.sensing): over the contacts whose geom pair is counted and that have constraint rows (efc_address
>= 0), the sum and the largest of |f_n| = |efc_force[efc_address]| (the normal row of an elliptic cone).

Per physics step (envs.sim.sensing.EpisodeSensing.substep), with h the timestep, |F| the force the limit reads (|F_ext|,
or with the sensor model of envs.task.sensor_config on, |y_F| of the sensed y <- y + alpha (F_ext + b + n_k - y)):

    peaks     <- max(peaks, (contact sum, single contact, |F_ext|, |tau_ext|))
    window    <- the last W = max(1, round(force_limit_window_s / h)) values of |F| (a ring buffer)
    sustained <- max(sustained, min(window))          once W values were read
    above     <- above + h if |F| > force_limit_n else 0
    limit hit <=> above >= force_limit_window_s - 1e-12 and above > 0

With ``sensor_mode = "joint_torque"`` (envs.task.sensor_config) the sensed y filters the estimate from the joint torques
instead (`joint_torque_estimate`: tau_c from qfrc_constraint less the joints' own friction rows, plus the sensors'
bias and noise, mapped by (J J^T)^-1 J at the F/T site and zeroed for the nominal peg), while the record's wrench
stays the F/T site's exact one.

Every sum is taken in the order the numpy version used (left to right for the 3-vector products, numpy's pairwise
summation for the contact sum, four interleaved partial sums for the mass-weighted centre as numpy's matmul through
OpenBLAS does for up to 7 bodies), so the readings, and the episode records, stayed the same to the last bit.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from controllers.impedance_kernel import cholesky_lower
from controllers.mujoco_c import FN_JAC_SITE, call_mdppi, float64_pointer, int32_pointer, load_i32, load_pointer
from controllers.mujoco_layout import (LAYOUT_CONTACT, LAYOUT_CONTACT_SIZE, LAYOUT_EFC_ADDRESS, LAYOUT_EFC_FORCE,
                                       LAYOUT_EFC_ID, LAYOUT_EFC_TYPE, LAYOUT_GEOM, LAYOUT_NCON, LAYOUT_NEFC)
from envs.errors import EnvError
from envs.task.sensor_config import SENSOR_JOINT_TORQUE, SENSOR_JOINT_BIAS

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")

# The sense state: a float64 array of these slots followed by the force window (see `sense_state`).
PEAK_CONTACT = 0
"""Largest sum of the environment's normal forces on the peg (N)."""
PEAK_SINGLE = 1
"""Largest single normal force on the peg (N)."""
PEAK_FORCE = 2
"""Largest |F_ext| (N)."""
PEAK_TORQUE = 3
"""Largest |tau_ext| (N m)."""
PEAK_SUSTAINED = 4
"""Largest minimum of |F_ext| over a full window (N)."""
ABOVE_LIMIT_S = 5
"""Time |F_ext| has stayed above the force limit (s)."""
READINGS = 6
"""Number of |F_ext| values written to the window (an integer)."""
WRENCH = 7
"""The latest [F_ext; tau_ext] (6 slots)."""
SENSED = 13
"""The latest sensed wrench y (6 slots; envs.task.sensor_config): what the force limit and the policy read when the
sensor model is on."""
SUBSTEP = 19
"""Physics steps sensed in the current control period (the row of the period's noise to add)."""
WINDOW = 20
"""First slot of the ring buffer of the last W values of the force limit's |F|."""

LIMIT_FORCE, LIMIT_WINDOW_S, LIMIT_TIMESTEP = 0, 1, 2
"""Slots of the limits array: force_limit_n, force_limit_window_s, the physics timestep (s)."""

JT_SITE, JT_FRICTION_TYPE, JT_ARM, JT_DOFS = 0, 1, 2, 3
"""Slots of the joint-torque sensing's index array: the F/T site, MuJoCo's mjCNSTR_FRICTION_DOF, the number n of arm
dofs, then their dof addresses (n)."""
JT_TAU, JT_RHS, JT_SOLUTION, JT_READING = 0, 1, 2, 3
"""Rows of the joint-torque sensing's vectors (4, 7): tau_m, J tau_m, [F_hat; M_hat], the reading -R_S^T W_hat."""
JT_REGULARISATION = 1e-9
"""Added to the diagonal of J J^T (m^2, rad^2 mixed; ~1e-8 of its smallest eigenvalue on the task's postures)."""

_PAIRWISE_BLOCK = 128  # numpy's PW_BLOCKSIZE
_SCRATCH_SIZE = 256


def sense_state(window_size: int) -> np.ndarray:
    """A zeroed sense state (the slot constants above) with a force window of ``window_size`` >= 1 values."""
    if window_size < 1:
        raise EnvError(f"window_size={window_size} must be >= 1")
    return np.zeros(WINDOW + window_size)


def contact_scratch() -> np.ndarray:
    """Scratch for the contact forces (a larger set of contacts gets a temporary array)."""
    return np.zeros(_SCRATCH_SIZE)


@_jit
def _pairwise_block(a: np.ndarray, start: int, n: int) -> float:
    """sum(a[start:start + n]) for n <= 128 as numpy's pairwise_sum: sequential below 8 values, else eight
    interleaved partial sums added pairwise, then the rest."""
    if n < 8:
        res = -0.0
        for i in range(start, start + n):
            res += a[i]
        return res
    r0, r1, r2, r3 = a[start], a[start + 1], a[start + 2], a[start + 3]
    r4, r5, r6, r7 = a[start + 4], a[start + 5], a[start + 6], a[start + 7]
    i = 8
    while i < n - n % 8:
        j = start + i
        r0 += a[j]
        r1 += a[j + 1]
        r2 += a[j + 2]
        r3 += a[j + 3]
        r4 += a[j + 4]
        r5 += a[j + 5]
        r6 += a[j + 6]
        r7 += a[j + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[start + i]
        i += 1
    return res


@_jit
def pairwise_sum(a: np.ndarray, n: int) -> float:
    """sum(a[:n]) in numpy's pairwise order (so it equals np.sum to the last bit).

    numpy splits n > 128 values into halves (the first rounded down to a multiple of 8) and recurses; here that
    recursion runs on explicit stacks (numba caches no recursive function), allocated only for n > 128.
    """
    if n <= _PAIRWISE_BLOCK:
        return _pairwise_block(a, 0, n)
    nodes = np.empty((130, 3), np.int64)  # (start, length, children summed); depth <= 63 halvings
    sums = np.empty(66)
    nodes[0, 0], nodes[0, 1], nodes[0, 2] = 0, n, 0
    top, done = 1, 0
    while top > 0:
        start, length, expanded = nodes[top - 1, 0], nodes[top - 1, 1], nodes[top - 1, 2]
        if length <= _PAIRWISE_BLOCK:
            top -= 1
            sums[done] = _pairwise_block(a, start, length)
            done += 1
        elif expanded:
            top -= 1
            sums[done - 2] = sums[done - 2] + sums[done - 1]  # first half + second half
            done -= 1
        else:
            half = length // 2
            half -= half % 8
            nodes[top - 1, 2] = 1
            nodes[top, 0], nodes[top, 1], nodes[top, 2] = start + half, length - half, 0  # summed second
            nodes[top + 1, 0], nodes[top + 1, 1], nodes[top + 1, 2] = start, half, 0  # summed first
            top += 2
    return sums[0]


@_jit
def normal_forces(geom: np.ndarray, efc_address: np.ndarray, efc_force: np.ndarray, counted: np.ndarray,
                  scratch: np.ndarray) -> tuple[float, float]:
    """(sum, largest) of |efc_force[efc_address[i]]| over the contacts i with counted[geom[i, 0], geom[i, 1]] and
    efc_address[i] >= 0; (0, 0) when there are none. NaN forces make both NaN.

    Args:
        geom, efc_address: MjData.contact.geom (ncon, 2) and .efc_address (ncon,).
        efc_force: MjData.efc_force (nefc,).
        counted: (ngeom, ngeom) bool, the geom pairs that count (envs.sim.sensing.PegContacts).
        scratch: float buffer for the forces (a larger set gets a temporary array).
    """
    m = 0
    for i in range(geom.shape[0]):
        if counted[geom[i, 0], geom[i, 1]] and efc_address[i] >= 0:
            m += 1
    if m == 0:
        return 0.0, 0.0
    forces = scratch if m <= scratch.shape[0] else np.empty(m)
    k = 0
    largest = 0.0
    for i in range(geom.shape[0]):
        adr = efc_address[i]
        if counted[geom[i, 0], geom[i, 1]] and adr >= 0:
            f = abs(efc_force[adr])
            forces[k] = f
            if k == 0 or f > largest or f != f:  # as np.max: a NaN propagates
                largest = f
            k += 1
    return pairwise_sum(forces, m), largest


@_jit
def _mass_moment(xipos: np.ndarray, bodies: np.ndarray, load: np.ndarray, axis: int) -> float:
    """sum_b m_b c_b[axis]: four interleaved partial sums added pairwise, then the rest (numpy's matmul order)."""
    k = bodies.shape[0]
    blocked = k - k % 4
    s = 0.0
    if blocked > 0:
        p0 = p1 = p2 = p3 = 0.0
        for b in range(0, blocked, 4):
            p0 += load[4 + b] * xipos[bodies[b], axis]
            p1 += load[5 + b] * xipos[bodies[b + 1], axis]
            p2 += load[6 + b] * xipos[bodies[b + 2], axis]
            p3 += load[7 + b] * xipos[bodies[b + 3], axis]
        s = (p0 + p1) + (p2 + p3)
    for b in range(blocked, k):
        s += load[4 + b] * xipos[bodies[b], axis]
    return s


@_jit
def wrist_wrench(rot: np.ndarray, site_pos: np.ndarray, xipos: np.ndarray, force: np.ndarray, torque: np.ndarray,
                 bodies: np.ndarray, load: np.ndarray, out: np.ndarray) -> None:
    """out = [F_ext; tau_ext] (module docstring), in the sensor frame.

    Args:
        rot: the site's row-major rotation matrix R_S (9,) (MjData.site_xmat row).
        site_pos: the site's position s (3,).
        xipos: MjData.xipos (nbody, 3), the bodies' centres of mass.
        force, torque: the sensor readings F_s, tau_s (3,) each.
        bodies: the carried bodies (k,).
        load: [M, g (3), m_1 .. m_k].
        out: output (6,).
    """
    mass, gx, gy, gz = load[0], load[1], load[2], load[3]
    lx = _mass_moment(xipos, bodies, load, 0) - mass * site_pos[0]  # M (c - s)
    ly = _mass_moment(xipos, bodies, load, 1) - mass * site_pos[1]
    lz = _mass_moment(xipos, bodies, load, 2) - mass * site_pos[2]
    wx, wy, wz = -mass * gx, -mass * gy, -mass * gz  # -M g (world)
    tx, ty, tz = -(ly * gz - lz * gy), -(lz * gx - lx * gz), -(lx * gy - ly * gx)  # -M (c - s) x g (world)
    for j in range(3):  # R_S^T v = v @ R_S
        out[j] = ((wx * rot[j] + wy * rot[3 + j]) + wz * rot[6 + j]) - force[j]
        out[3 + j] = ((tx * rot[j] + ty * rot[3 + j]) + tz * rot[6 + j]) - torque[j]


@_jit
def sense_substep(rot: np.ndarray, site_pos: np.ndarray, xipos: np.ndarray, force: np.ndarray, torque: np.ndarray,
                  bodies: np.ndarray, load: np.ndarray, geom: np.ndarray, efc_address: np.ndarray,
                  efc_force: np.ndarray, counted: np.ndarray, scratch: np.ndarray, limits: np.ndarray,
                  sensor: np.ndarray, noise: np.ndarray, state: np.ndarray, estimate: np.ndarray) -> bool:
    """One physics step's update of the sense state (module docstring); True when the force limit is hit.

    Args:
        rot .. load: as in `wrist_wrench`.
        geom .. scratch: as in `normal_forces`.
        limits: [force_limit_n, force_limit_window_s, timestep].
        sensor: [mode, alpha, bias (6), joint bias (7)] (envs.task.sensor_config.SENSOR_*).
        noise: (n_substeps, 6) the period's noise n_k, one row per physics step (read in the wrist mode).
        state: the sense state (`sense_state`), updated.
        estimate: the zeroed joint-torque estimate of this step (6,) (read in the joint-torque mode:
            `joint_torque_estimate`).
    """
    total, single = normal_forces(geom, efc_address, efc_force, counted, scratch)
    if total > state[PEAK_CONTACT]:  # max(peak, x) as Python's max: a NaN reading leaves the peak
        state[PEAK_CONTACT] = total
    if single > state[PEAK_SINGLE]:
        state[PEAK_SINGLE] = single
    wrench = state[WRENCH:WRENCH + 6]
    wrist_wrench(rot, site_pos, xipos, force, torque, bodies, load, wrench)
    f = math.sqrt(wrench[0] * wrench[0] + wrench[1] * wrench[1] + wrench[2] * wrench[2])
    t = math.sqrt(wrench[3] * wrench[3] + wrench[4] * wrench[4] + wrench[5] * wrench[5])
    if f > state[PEAK_FORCE]:
        state[PEAK_FORCE] = f
    if t > state[PEAK_TORQUE]:
        state[PEAK_TORQUE] = t
    if sensor[0] == SENSOR_JOINT_TORQUE:  # y <- y + alpha (W_hat - y); the limit reads |y_F|
        alpha = sensor[1]
        for j in range(6):  # alpha = 1: no low-pass, the reading itself (y + (x - y) is not x to the bit)
            y = state[SENSED + j]
            state[SENSED + j] = estimate[j] if alpha == 1.0 else y + alpha * (estimate[j] - y)
        y0, y1, y2 = state[SENSED], state[SENSED + 1], state[SENSED + 2]
        f = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
    elif sensor[0] != 0.0:  # the wrist sensor: y <- y + alpha (w + b + n - y); the limit reads |y_F|
        row = int(state[SUBSTEP])
        state[SUBSTEP] = row + 1
        alpha = sensor[1]
        for j in range(6):
            y = state[SENSED + j]
            x = (wrench[j] + sensor[2 + j]) + noise[row, j]
            state[SENSED + j] = x if alpha == 1.0 else y + alpha * (x - y)
        y0, y1, y2 = state[SENSED], state[SENSED + 1], state[SENSED + 2]
        f = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
    window = state[WINDOW:]
    size = window.shape[0]
    readings = int(state[READINGS])
    window[readings % size] = f
    readings += 1
    state[READINGS] = readings
    if readings >= size:
        lowest = window[0]
        for i in range(1, size):  # min(window) as Python's min
            if window[i] < lowest:
                lowest = window[i]
        if lowest > state[PEAK_SUSTAINED]:
            state[PEAK_SUSTAINED] = lowest
    above = state[ABOVE_LIMIT_S] + limits[LIMIT_TIMESTEP] if f > limits[LIMIT_FORCE] else 0.0
    state[ABOVE_LIMIT_S] = above
    return above >= limits[LIMIT_WINDOW_S] - 1e-12 and above > 0.0


@_jit
def contacts_at(d: int, layout: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Views of the contacts of the mjData at address ``d`` now: (geom (ncon, 2), efc_address (ncon,),
    efc_force (nefc,)), the arrays `normal_forces` reads, read through the offsets of controllers.mujoco_layout
    (so a compiled loop needs no Python between physics steps to get them)."""
    ncon = load_i32(d + layout[LAYOUT_NCON])
    nefc = load_i32(d + layout[LAYOUT_NEFC])
    words = layout[LAYOUT_CONTACT_SIZE] // 4
    table = numba.carray(int32_pointer(load_pointer(d + layout[LAYOUT_CONTACT])), (ncon, words))
    g, e = layout[LAYOUT_GEOM] // 4, layout[LAYOUT_EFC_ADDRESS] // 4
    efc_force = numba.carray(float64_pointer(load_pointer(d + layout[LAYOUT_EFC_FORCE])), (nefc,))
    return table[:, g:g + 2], table[:, e], efc_force


@_jit
def joint_torque_estimate(fns: np.ndarray, m: int, d: int, layout: np.ndarray, index: np.ndarray, jac: np.ndarray,
                          qfrc_constraint: np.ndarray, sensor: np.ndarray, noise_row: np.ndarray,
                          matrices: np.ndarray, vectors: np.ndarray, rot: np.ndarray, site_pos: np.ndarray,
                          xipos: np.ndarray, bodies: np.ndarray, load: np.ndarray, out: np.ndarray) -> bool:
    """The external wrench estimated from the joint torques (envs.task.sensor_config), zeroed for the nominal peg, into
    ``out`` (6,) in the sensor frame; False (``out`` untouched) when J J^T is not positive definite.

    tau_c,i = qfrc_constraint_i - (the dof friction rows' efc_force on dof i): the torque the constraints other than
    the joint's own friction put on joint i (contacts through the hand and fingers; joint limits, not reached in
    the task, would count too). tau_m = tau_c + b_tau + n_k; [F_hat; M_hat] = (J J^T + eps I)^-1 J tau_m with J the
    F/T site's Jacobian over the arm's columns (mj_jacSite, at the state the step's forces were computed at); the
    reading -R_S^T [F_hat; M_hat] is zeroed for the nominal peg by `wrist_wrench` (``bodies``, ``load``: the peg).

    Args:
        fns, m, d: MuJoCo's functions, the model and data addresses (controllers.mujoco_c).
        layout: the mjData offsets (controllers.mujoco_layout).
        index: JT_* slots (the site, the friction row type, n, the arm's dofs).
        jac: (6, nv) buffer for the site's Jacobian.
        qfrc_constraint: MjData.qfrc_constraint (view).
        sensor: the sensor array (the joint bias b_tau from SENSOR_JOINT_BIAS).
        noise_row: this step's joint noise n_k (>= n).
        matrices, vectors: scratch (2, 6, 6) and (4, 7) (JT_* rows).
        rot, site_pos, xipos: the F/T site's rotation (9,) and position, the bodies' centres of mass.
        bodies, load: the nominal peg's tool load (as `wrist_wrench`'s).
        out: the estimate (6,).
    """
    n = index[JT_ARM]
    nv = jac.shape[1]
    call_mdppi(fns[FN_JAC_SITE], m, d, jac.ctypes.data, jac.ctypes.data + 3 * nv * 8, int(index[JT_SITE]))
    tau = vectors[JT_TAU]
    for i in range(n):
        tau[i] = qfrc_constraint[index[JT_DOFS + i]]
    nefc = load_i32(d + layout[LAYOUT_NEFC])
    if nefc > 0:
        kinds = numba.carray(int32_pointer(load_pointer(d + layout[LAYOUT_EFC_TYPE])), (nefc,))
        ids = numba.carray(int32_pointer(load_pointer(d + layout[LAYOUT_EFC_ID])), (nefc,))
        forces = numba.carray(float64_pointer(load_pointer(d + layout[LAYOUT_EFC_FORCE])), (nefc,))
        for r in range(nefc):
            if kinds[r] == index[JT_FRICTION_TYPE]:
                for i in range(n):
                    if ids[r] == index[JT_DOFS + i]:
                        tau[i] -= forces[r]
    for i in range(n):
        tau[i] += sensor[SENSOR_JOINT_BIAS + i] + noise_row[i]
    a, c = matrices[0], matrices[1]
    rhs, x = vectors[JT_RHS], vectors[JT_SOLUTION]
    for r in range(6):
        s = 0.0
        for i in range(n):
            s += jac[r, index[JT_DOFS + i]] * tau[i]
        rhs[r] = s
        for q in range(r + 1):
            t = 0.0
            for i in range(n):
                t += jac[r, index[JT_DOFS + i]] * jac[q, index[JT_DOFS + i]]
            a[r, q] = t
            a[q, r] = t
        a[r, r] += JT_REGULARISATION
    if not cholesky_lower(a, c):
        return False
    for r in range(6):  # C y = rhs, then C^T x = y
        s = rhs[r]
        for q in range(r):
            s -= c[r, q] * x[q]
        x[r] = s / c[r, r]
    for r in range(5, -1, -1):
        s = x[r]
        for q in range(r + 1, 6):
            s -= c[q, r] * x[q]
        x[r] = s / c[r, r]
    reading = vectors[JT_READING]
    for j in range(3):  # -R_S^T F_hat, -R_S^T M_hat: what the F/T sensor would read for this wrench
        reading[j] = -((x[0] * rot[j] + x[1] * rot[3 + j]) + x[2] * rot[6 + j])
        reading[3 + j] = -((x[3] * rot[j] + x[4] * rot[3 + j]) + x[5] * rot[6 + j])
    wrist_wrench(rot, site_pos, xipos, reading[0:3], reading[3:6], bodies, load, out)
    return True


@_jit
def sense_substep_at(d: int, layout: np.ndarray, rot: np.ndarray, site_pos: np.ndarray, xipos: np.ndarray,
                     force: np.ndarray, torque: np.ndarray, bodies: np.ndarray, load: np.ndarray, counted: np.ndarray,
                     scratch: np.ndarray, limits: np.ndarray, sensor: np.ndarray, noise: np.ndarray,
                     state: np.ndarray, fns: np.ndarray, m: int, jt_index: np.ndarray, jt_jac: np.ndarray,
                     qfrc_constraint: np.ndarray, jt_bodies: np.ndarray, jt_load: np.ndarray, jt_noise: np.ndarray,
                     jt_matrices: np.ndarray, jt_vectors: np.ndarray, jt_estimate: np.ndarray) -> bool:
    """`sense_substep` on the contacts of the mjData at address ``d`` (`contacts_at`), with the joint-torque
    estimate (`joint_torque_estimate`) first in that mode; True when the force limit is hit. A singular J J^T keeps
    the last estimate."""
    if sensor[0] == SENSOR_JOINT_TORQUE:
        row = int(state[SUBSTEP])
        state[SUBSTEP] = row + 1
        joint_torque_estimate(fns, m, d, layout, jt_index, jt_jac, qfrc_constraint, sensor, jt_noise[row],
                              jt_matrices, jt_vectors, rot, site_pos, xipos, jt_bodies, jt_load, jt_estimate)
    geom, efc_address, efc_force = contacts_at(d, layout)
    return sense_substep(rot, site_pos, xipos, force, torque, bodies, load, geom, efc_address, efc_force, counted,
                         scratch, limits, sensor, noise, state, jt_estimate)
