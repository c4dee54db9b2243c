"""Torque-level Cartesian impedance control of a site at the physics rate.

The control law (all vectors in the world frame, twist order [linear; angular]):

    e     = [p_d - p ; Log(q_d * conj(q))]                    pose error, rotation vector in rad
    v     = J qdot                                            site twist
    F     = K e - D v                                         impedance wrench
    tau_0 = K_n (q_ref - q) - D_n qdot                        posture torque (K_n = 0 without q_ref)
    tau   = J^T F + (I - J^T Jbar^T) tau_0 + c(q, qdot)       c = qfrc_bias (Coriolis + gravity)

with Lambda = (J M^-1 J^T)^-1 the Cartesian inertia, Jbar = M^-1 J^T Lambda its dynamically consistent inverse,
and D the damping of the double diagonalisation of (Lambda, K): with Lambda = P P^T and K = P W P^T
(W diagonal), D = P diag(2 zeta sqrt(w_i)) P^T, i.e. every decoupled mode of the closed loop
Lambda x'' + D x' + K x = 0 has damping ratio zeta. P comes from a Cholesky factor C of
Lambda^-1 = C C^T (so Lambda = C^-T C^-1) and the eigenvectors U of C^T K C: P = C^-T U.
The same P gives the nullspace term without inverting Lambda: Lambda x = P (P^T x).

The commanded torque is then limited to the Panda's joint torques and torque rate, relative to the last command
(the controller's one piece of state, set by `reset`):

    tau_k = clip(clip(tau, tau_{k-1} - rate dt, tau_{k-1} + rate dt), -tau_max, tau_max)

`step` runs mj_step1 -> torque -> mj_step2, so the torque sees the state it acts on (no one-step lag). The law
itself is one compiled call per physics step (`controllers.impedance_kernel`, numba) on preallocated buffers,
between MuJoCo's own mj_jacSite and mj_solveM.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass
from typing import Callable

import mujoco
import numpy as np
import numpy.typing as npt
from controllers import feedforward
from controllers import impedance_kernel as kernel
from controllers import joint_torque_kernel as jt_kernel
from controllers.action import Action
from controllers.errors import ControllerError
from controllers.feedforward import check_lead_status
from controllers.mujoco_c import FUNCTIONS
from controllers.mujoco_layout import layout
from controllers.validation import as_unit_quaternion, as_vector, site_id
from numerics.pose import Pose
from numerics.small_linalg import eigh_sym
from pihutil.bounds import STIFFNESS

PANDA_TORQUE_LIMITS_NM: tuple[float, ...] = (87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0)
PANDA_TORQUE_RATE_LIMIT_NM_PER_S: float = 1000.0
_INERTIA_REGULARISATION: float = 1e-6  # added to J M^-1 J^T so Lambda stays finite at singularities
_NO_ACCEL = np.zeros(6)  # pose_lead without an acceleration: a stand-in the kernel does not read (or write)


@dataclass(frozen=True)
class ImpedanceConfig:
    """Gains and limits of the Cartesian impedance controller.

    Defaults: 1500 N/m and 80 N m/rad turn a 10 N contact force into a 6.7 mm deflection and a 0.5 N m contact
    torque into 0.36 deg -- compliant enough for the peg to yield to the hole's walls instead of jamming with large
    forces, stiff enough to track the learned pose trajectory to millimetres in free space (gravity is compensated
    by the model, so there is no steady-state sag).
    A damping ratio of 1 (critical) tracks without overshoot. The posture stiffness is weak (10 N m/rad) so it
    only resolves the redundancy.

    Attributes:
        translational_stiffness: K for x, y, z in N/m.
        rotational_stiffness: K for rotations about x, y, z in N m/rad.
        damping_ratio: zeta of every decoupled Cartesian mode (1 = critical).
        nullspace_stiffness: K_n of the posture torque in N m/rad.
        nullspace_damping: D_n of the posture torque in N m s/rad.
        torque_limits: |tau_i| bound per joint in N m (the Panda's, by default).
        torque_rate_limit: |d tau_i / dt| bound in N m/s (the Panda's, by default).
        friction_observer_time_s: T_o of the joint friction observer closed on the link-side joint torque sensors
            (controllers.joint_torque_kernel, eq. 2), s; 0 turns it off. 5 ms: five physics steps, so the
            compensation follows a friction that flips with the joint's direction within a few steps while one
            reading's noise is averaged over five.
        friction_observer_limit_nm: f_max, the largest compensation per joint, N m: beyond any friction the cell
            has (the identified Panda joints' Coulomb friction is 0.15-0.36 N m, twice that in the harsh cell), so
            a wrong reading (a collision, a sensor fault) cannot turn into more than this much torque.
    """

    translational_stiffness: float = 1500.0
    rotational_stiffness: float = 80.0
    damping_ratio: float = 1.0
    nullspace_stiffness: float = 10.0
    nullspace_damping: float = 3.0
    torque_limits: tuple[float, ...] = PANDA_TORQUE_LIMITS_NM
    torque_rate_limit: float = PANDA_TORQUE_RATE_LIMIT_NM_PER_S
    friction_observer_time_s: float = 0.005
    friction_observer_limit_nm: float = 2.0

    def __post_init__(self) -> None:
        for name, minimum_excluded in (
            ("translational_stiffness", True),
            ("rotational_stiffness", True),
            ("torque_rate_limit", True),
            ("damping_ratio", False),
            ("nullspace_stiffness", False),
            ("nullspace_damping", False),
            ("friction_observer_time_s", False),
            ("friction_observer_limit_nm", False),
        ):
            value = getattr(self, name)
            if not isinstance(value, numbers.Real) or not np.isfinite(value) or value < 0.0 or (
                minimum_excluded and value == 0.0
            ):
                kind = "positive" if minimum_excluded else "non-negative"
                raise ControllerError(f"ImpedanceConfig.{name}={value!r} must be a {kind} finite number")
        try:
            limits = np.asarray(self.torque_limits, dtype=float)
        except (TypeError, ValueError):
            limits = np.array([np.nan])
        if limits.ndim != 1 or limits.size == 0 or not np.all(np.isfinite(limits)) or np.any(limits <= 0.0):
            raise ControllerError(f"ImpedanceConfig.torque_limits={self.torque_limits!r} must be positive numbers")

    def stiffness_matrix(self) -> npt.NDArray[np.float64]:
        """The diagonal 6x6 stiffness diag(k_t, k_t, k_t, k_r, k_r, k_r) in [N/m, N m/rad]."""
        return np.diag([self.translational_stiffness] * 3 + [self.rotational_stiffness] * 3)


MAX_JOINT_ANGLE_RAD = 2.0 * np.pi
"""The largest |joint angle| a posture reference may ask for (every Panda joint lies within +-3.0 rad)."""
MIN_STIFFNESS = STIFFNESS.low
"""The smallest stiffness eigenvalue a command may have (N/m or N m/rad): K^-1 scales the feed-forward lead
(pihutil.bounds.STIFFNESS, what every option and task field of a stiffness is checked against)."""
MAX_STIFFNESS = STIFFNESS.high
"""The largest (N/m or N m/rad): 200x a Panda's Cartesian stiffness of record; far below the law's overflow."""


def validate_stiffness(stiffness: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Check that a Cartesian stiffness is a finite, symmetric, positive definite 6x6 matrix.

    Args:
        stiffness: 6x6 matrix [[K_pp, K_pr], [K_rp, K_rr]] in N/m, N/rad, N m/m, N m/rad (world frame).

    Returns:
        The matrix as a C-contiguous float64 array.

    Raises:
        ControllerError: wrong shape, non-finite entries, asymmetry, a non-positive eigenvalue, or eigenvalues
            outside [MIN_STIFFNESS, MAX_STIFFNESS].
    """
    try:
        k = np.ascontiguousarray(stiffness, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise ControllerError(f"stiffness must be a 6x6 numeric matrix, got {type(stiffness).__name__}") from error
    if k.shape != (6, 6):
        raise ControllerError(f"stiffness must have shape (6, 6), got {k.shape}")
    if not np.all(np.isfinite(k)):
        raise ControllerError("stiffness has non-finite entries")
    scale = float(np.max(np.abs(k)))
    if float(np.max(np.abs(k - k.T))) > 1e-9 * max(scale, 1.0):
        raise ControllerError("stiffness is not symmetric (max |K - K^T| too large)")
    eigenvalues = eigh_sym(k)[0]
    smallest, largest = float(eigenvalues[0]), float(eigenvalues[-1])
    if smallest <= 0.0:
        raise ControllerError(f"stiffness is not positive definite (smallest eigenvalue {smallest:.3g})")
    if smallest < MIN_STIFFNESS or largest > MAX_STIFFNESS:
        raise ControllerError(f"stiffness eigenvalues {smallest:.3g} to {largest:.3g} must lie in [{MIN_STIFFNESS:g}, "
                              f"{MAX_STIFFNESS:g}] (N/m, N m/rad): outside it the law's lead and torque overflow")
    return k


def full_stiffness(k_trans: npt.ArrayLike, k_rot: float | npt.ArrayLike) -> npt.NDArray[np.float64]:
    """The 6x6 Cartesian stiffness K = [[K_t, 0], [0, K_r]] (N/m, N m/rad) from its translational block K_t (3, 3)
    and its rotational block K_r: a scalar k_r (K_r = k_r I, e.g. ImpedanceConfig.rotational_stiffness) or (3, 3).

    Not validated here: `validate_stiffness` (or PegInHoleEnv.step) checks the result.
    """
    k = np.zeros((6, 6))
    k[:3, :3] = np.asarray(k_trans, dtype=np.float64)
    rot = np.asarray(k_rot, dtype=np.float64)
    k[3:, 3:] = rot * np.eye(3) if rot.ndim == 0 else rot
    return k


def modal_factors(
    lambda_inv: npt.NDArray[np.float64], stiffness: npt.NDArray[np.float64]
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Double diagonalisation of the Cartesian inertia and a stiffness.

    With Lambda^-1 = C C^T (Cholesky) and C^T K C = U diag(w) U^T (symmetric eigendecomposition), P = C^-T U
    satisfies Lambda = P P^T and K = P diag(w) P^T, so D = P diag(2 zeta sqrt(w)) P^T damps every mode of
    Lambda x'' + D x' + K x = 0 with ratio zeta. Computed by the compiled kernel the control law uses
    (controllers.impedance_kernel.modal_factors_into: Cholesky and cyclic Jacobi on 6x6 matrices).

    Args:
        lambda_inv: J M^-1 J^T (6x6, symmetric positive definite).
        stiffness: K (6x6, symmetric positive definite).

    Returns:
        (P, w): the 6x6 modal matrix and the 6 modal stiffnesses (eigenvalues of Lambda^-1 K).

    Raises:
        ControllerError: lambda_inv not positive definite.
    """
    p, w = np.zeros((6, 6)), np.zeros(6)
    work, _ = kernel.work_buffers(6)
    ok = kernel.modal_factors_into(np.ascontiguousarray(lambda_inv, dtype=np.float64),
                                   np.ascontiguousarray(stiffness, dtype=np.float64), p, w, work)
    if not ok:
        raise ControllerError("J M^-1 J^T is not positive definite (Cholesky failed)")
    return p, w


def _is_descendant(model: mujoco.MjModel, body: int, ancestor: int) -> bool:
    """True when ``body`` is ``ancestor`` or lies below it in the kinematic tree."""
    while body > 0:
        if body == ancestor:
            return True
        body = int(model.body_parentid[body])
    return False


class CartesianImpedanceController:
    """Cartesian impedance controller of one site of a torque-actuated arm (see the module docstring); a
    `controllers.interface.Controller`, the one the episode environment uses by default.

    The arm is what the model's actuators drive: motor i (gear 1) on the i-th of a contiguous block of hinge or
    slide joints (`dof_slice`, `qpos_slice`). Other dofs are allowed on other kinematic trees (e.g. a free
    peg), where the mass matrix is block diagonal, or below the arm's last joint (e.g. gripper fingers), whose
    coupling to the arm enters exactly through M^-1 in Lambda^-1 = J M^-1 J^T.
    """

    def __init__(
        self, model: mujoco.MjModel, site: int | str, config: ImpedanceConfig = ImpedanceConfig()
    ) -> None:
        """Args:
            model: the MuJoCo model the controller will drive.
            site: name or id of the controlled site (e.g. "flange", "peg_mount"), on the arm.
            config: gains and limits (one torque limit per actuator).

        Raises:
            ControllerError: unknown site, a site off the arm, or actuators that are not gear-1 joint motors on
                a contiguous block of arm joints.
        """
        n = model.nu
        if n == 0 or len(config.torque_limits) != n:
            raise ControllerError(
                f"controller needs one torque limit per actuator: nu={n}, torque_limits has "
                f"{len(config.torque_limits)}"
            )
        joints = model.actuator_trnid[:, 0]
        if (
            np.any(model.actuator_trntype != mujoco.mjtTrn.mjTRN_JOINT)
            or not np.allclose(model.actuator_gear[:, 0], 1.0)
            or np.any(
                (model.jnt_type[joints] != mujoco.mjtJoint.mjJNT_HINGE)
                & (model.jnt_type[joints] != mujoco.mjtJoint.mjJNT_SLIDE)
            )
        ):
            raise ControllerError("every actuator must be a gear-1 motor on a hinge or slide joint")
        dof_adr, qpos_adr = model.jnt_dofadr[joints], model.jnt_qposadr[joints]
        block = np.arange(n)
        if not (np.array_equal(dof_adr, dof_adr[0] + block) and np.array_equal(qpos_adr, qpos_adr[0] + block)):
            raise ControllerError("actuator i must drive the i-th joint of one contiguous block of arm joints")
        self.dof_slice = slice(int(dof_adr[0]), int(dof_adr[0]) + n)
        self.qpos_slice = slice(int(qpos_adr[0]), int(qpos_adr[0]) + n)
        arm_trees = set(model.dof_treeid[self.dof_slice].tolist())
        other = np.ones(model.nv, dtype=bool)
        other[self.dof_slice] = False
        last_arm_body = int(model.dof_bodyid[self.dof_slice.stop - 1])
        for dof in np.flatnonzero(other):  # unactuated dofs on the arm's tree must hang below its last joint
            if int(model.dof_treeid[dof]) in arm_trees and not _is_descendant(model, int(model.dof_bodyid[dof]),
                                                                                last_arm_body):
                raise ControllerError("dofs outside the actuated arm must lie on other kinematic trees or below "
                                      "its last joint (e.g. gripper fingers)")
        self.model = model
        self.site_id = site_id(model, site)
        if int(model.body_treeid[model.site_bodyid[self.site_id]]) not in arm_trees:
            raise ControllerError(f"site {site!r} is not on the actuated arm")
        self.config = config
        self.default_stiffness = config.stiffness_matrix()
        self._tau_max = np.asarray(config.torque_limits, dtype=np.float64)
        self._tau_step = config.torque_rate_limit * model.opt.timestep
        # Kernel parameters [regularisation, 4 zeta^2, K_n, D_n, rate dt, dof start, tau_max...] and preallocated
        # buffers: a physics step allocates nothing (controllers.impedance_kernel).
        self._params = np.concatenate([
            [_INERTIA_REGULARISATION, 4.0 * config.damping_ratio**2, config.nullspace_stiffness,
             config.nullspace_damping, self._tau_step, float(self.dof_slice.start)], self._tau_max])
        self._jac = np.zeros((6, model.nv))
        self._jac_pos, self._jac_rot = self._jac[:3], self._jac[3:]
        self._jac_minv = np.zeros((6, model.nv))
        self._target = np.zeros(7 + n + 1)  # [p_d, q_d, q_ref, use_q_ref]
        self._work, self._vec = kernel.work_buffers(n)
        self._lead_scratch = (np.zeros((6, 6)), np.zeros((6, 6)), np.zeros(6), np.zeros((3, 6, 6)), np.zeros((6, 6)))
        self._last_tau = np.zeros(n)
        self._views: tuple = ()  # (data, its arrays the kernel reads), refreshed when another MjData comes
        self._fns = FUNCTIONS  # MuJoCo's C functions for the compiled physics step
        self._tool = np.zeros(6)  # [enabled, depth, body, m g] (impedance_kernel.TOOL_*): no tool load
        self._tool_point = np.zeros(3)
        self._jac_tool = np.zeros((3, model.nv))
        self._jac_tool_arm = self._jac_tool[:, self.dof_slice]
        self._disturbance = np.zeros((1, n))  # the actuators' torque beyond the command, per physics step
        self._disturbance_state = np.zeros(3)  # [noise on, next row, smooth friction on] (impedance_substep)
        self._smooth = np.zeros((n, 3))  # the joints' smooth transmission friction (joint_torque_kernel, eq. 4)
        # The joint torque sensors and the friction observer (controllers.joint_torque_kernel): its feedback vector,
        # the sensors' noise rows, mjData's layout for the friction rows and a scratch for the reading.
        self._feedback = np.zeros(jt_kernel.feedback_size(n))
        self._fb_f, self._fb_sum, self._fb_bias_hat, self._fb_bias = jt_kernel.feedback_slices(n)
        observer = config.friction_observer_time_s > 0.0
        self._feedback[jt_kernel.FB_ON] = 1.0 if observer else 0.0
        self._feedback[jt_kernel.FB_GAIN] = min(1.0, model.opt.timestep / config.friction_observer_time_s) if (
            observer) else 0.0
        self._feedback[jt_kernel.FB_LIMIT] = config.friction_observer_limit_nm
        self._sensor_noise = np.zeros((1, n))
        self._layout = layout() if observer else np.zeros(1, dtype=np.int64)
        self._reading = np.zeros(n)
        self._no_offset = np.zeros(n)  # the law alone (compute_torque)
        self._checked = self.default_stiffness  # the last stiffness `checked_stiffness` accepted (a private copy)

    def checked_stiffness(self, stiffness: npt.ArrayLike | None) -> npt.NDArray[np.float64]:
        """`validate_stiffness` of a command's stiffness (the config's when None), checked once per distinct
        value: a closed loop commands the same matrix for many control periods, and the pose lead, the
        environment and the control law all ask. Returns a private copy the caller must not modify.

        Raises:
            ControllerError: as `validate_stiffness`.
        """
        if stiffness is None:
            return self.default_stiffness
        if (isinstance(stiffness, np.ndarray) and stiffness.shape == (6, 6)
                and np.array_equal(stiffness, self._checked)):  # False for NaN: then validated, and refused
            return self._checked
        self._checked = validate_stiffness(stiffness).copy()
        return self._checked

    def set_tool_load(self, mass_kg: float, depth_m: float) -> None:
        """Compensate a carried tool's weight, as the robot's own gravity compensation does for a configured
        end-effector load (outside the commanded torque and its limits): before every physics step the arm gets
        qfrc_applied = -(m g)^T J_c, J_c the translational Jacobian at the tool's centre of mass
        p_c = p_site - depth_m z_site on the site's body. ``mass_kg`` 0 removes it.

        Raises:
            ControllerError: a negative or non-finite mass or depth.
        """
        if not (np.isfinite(mass_kg) and mass_kg >= 0.0 and np.isfinite(depth_m)):
            raise ControllerError(f"tool load: mass {mass_kg!r} kg must be finite and >= 0, depth {depth_m!r} m finite")
        weight = float(mass_kg) * np.asarray(self.model.opt.gravity, dtype=np.float64)
        self._tool[:] = [float(mass_kg > 0.0), float(depth_m), float(self.model.site_bodyid[self.site_id]), *weight]

    def set_torque_disturbance(self, rows: npt.ArrayLike | None) -> None:
        """What the arm's actuators deliver beyond the commanded torque (a cell's torque noise, not part of the
        law): one row (N m per arm joint) per coming physics step, added to ctrl after the law, starting at the
        next step; the last row repeats. None: none (the default).

        Raises:
            ControllerError: rows that are not a finite (R, n_joints) array with R >= 1.
        """
        if rows is None:
            self._disturbance_state[:2] = 0.0
            return
        values = np.asarray(rows, dtype=np.float64)
        n = self._last_tau.shape[0]
        if values.ndim != 2 or values.shape[0] < 1 or values.shape[1] != n or not np.isfinite(values).all():
            raise ControllerError(f"torque disturbance must be a finite (R >= 1, {n}) array, got shape {values.shape}")
        if self._disturbance.shape != values.shape:
            self._disturbance = np.zeros(values.shape)
        self._disturbance[:] = values
        self._disturbance_state[:2] = (1.0, 0.0)

    def set_transmission_friction(self, phi: npt.ArrayLike | None) -> None:
        """The joints' smooth transmission friction (controllers.joint_torque_kernel, eq. 4), which the actuators lose
        between the motor and the link every physics step (a cell's friction, not part of the law): rows [phi_1 (N m),
        phi_2 (s/rad), phi_3 (rad/s)] per arm joint, or None (the default) for none.

        Raises:
            ControllerError: not a finite (n_joints, 3) array with phi_1 >= 0 and phi_2 > 0.
        """
        if phi is None:
            self._disturbance_state[2] = 0.0
            return
        values = np.asarray(phi, dtype=np.float64)
        n = self._last_tau.shape[0]
        if (values.shape != (n, 3) or not np.isfinite(values).all() or np.any(values[:, 0] < 0.0)
                or np.any(values[:, 1] <= 0.0)):
            raise ControllerError(f"transmission friction must be a finite ({n}, 3) array of [phi_1 >= 0, phi_2 > 0, "
                                  f"phi_3] rows, got shape {values.shape}")
        self._smooth[:] = values
        self._disturbance_state[2] = 1.0

    def set_joint_torque_sensors(self, bias_nm: npt.ArrayLike | None = None,
                                 noise_rows: npt.ArrayLike | None = None) -> None:
        """What the link-side joint torque sensors add to the torque they read (a cell's sensors): a bias per joint
        (N m, for the episode; None: none) and noise rows (R, n) for the coming physics steps (N m, the last row
        repeating; None: none). The friction observer reads them (controllers.joint_torque_kernel, eq. 1).

        Raises:
            ControllerError: a bias that is not n finite numbers, or noise rows that are not a finite (R >= 1, n) array.
        """
        n = self._last_tau.shape[0]
        if bias_nm is not None:
            bias = np.asarray(bias_nm, dtype=np.float64)
            if bias.shape != (n,) or not np.isfinite(bias).all():
                raise ControllerError(f"joint torque sensor bias must be {n} finite numbers, got shape {bias.shape}")
            self._feedback[self._fb_bias] = bias
        if noise_rows is None:
            self._feedback[jt_kernel.FB_NOISE_ON] = 0.0
            return
        rows = np.asarray(noise_rows, dtype=np.float64)
        if rows.ndim != 2 or rows.shape[0] < 1 or rows.shape[1] != n or not np.isfinite(rows).all():
            raise ControllerError(f"joint torque sensor noise must be a finite (R >= 1, {n}) array, got shape "
                                  f"{rows.shape}")
        if self._sensor_noise.shape != rows.shape:
            self._sensor_noise = np.zeros(rows.shape)
        self._sensor_noise[:] = rows
        self._feedback[jt_kernel.FB_NOISE_ON] = 1.0
        self._feedback[jt_kernel.FB_ROW] = 0.0

    def settled(self) -> None:
        """End the joint torque sensors' tare that `start` began (controllers.joint_torque_kernel, eq. 3): the bias
        estimate b_hat is the mean of the readings taken since, and the friction observer runs from now on. Called
        after the arm held still in free space (the episode's grasp settle, controllers.interface); without readings
        b_hat stays 0."""
        feedback = self._feedback
        if feedback[jt_kernel.FB_TARE] == 0.0:
            return
        count = feedback[jt_kernel.FB_TARE_COUNT]
        feedback[self._fb_bias_hat] = feedback[self._fb_sum] / count if count > 0.0 else 0.0
        feedback[jt_kernel.FB_TARE] = 0.0

    @property
    def friction_compensation(self) -> npt.NDArray[np.float64]:
        """Copy of the friction observer's compensation f per joint, N m (zeros when it is off)."""
        return self._feedback[self._fb_f].copy()

    def reset(self, tau0: npt.ArrayLike | None = None) -> None:
        """Set the last commanded torque, the reference of the torque-rate limit.

        Args:
            tau0: arm torque in N m, one per actuator (e.g. data.qfrc_bias[controller.dof_slice] after
                mj_forward, to start holding against gravity); zeros when None.

        Raises:
            ControllerError: wrong length or non-finite values.
        """
        if tau0 is None:
            self._last_tau[:] = 0.0
            return
        tau = as_vector(tau0, self.model.nu, "tau0")
        np.clip(tau, -self._tau_max, self._tau_max, out=self._last_tau)

    def start(self, data: mujoco.MjData) -> None:
        """Start an episode at the state of ``data`` (after mj_forward, arm at rest): the last commanded torque, the
        reference of the torque-rate limit, becomes the bias torque c(q, 0) there (`reset` with
        data.qfrc_bias[dof_slice]), so the first command holds the arm against gravity (controllers.interface). With
        the friction observer on, its compensation starts at 0 and the joint torque sensors' tare begins (it ends
        with `settled`; until then the observer does not compensate).

        Raises:
            ControllerError: a non-finite bias torque.
        """
        self.reset(data.qfrc_bias[self.dof_slice])
        feedback = self._feedback
        feedback[self._fb_f] = 0.0
        feedback[self._fb_sum] = 0.0
        feedback[self._fb_bias_hat] = 0.0
        feedback[jt_kernel.FB_TARE_COUNT] = 0.0
        feedback[jt_kernel.FB_TARE] = feedback[jt_kernel.FB_ON]

    @property
    def last_torque(self) -> npt.NDArray[np.float64]:
        """Copy of the last commanded torque in N m."""
        return self._last_tau.copy()

    def pose_lead(
        self,
        data: mujoco.MjData,
        twist: npt.ArrayLike,
        accel: npt.ArrayLike | None = None,
        stiffness: npt.ArrayLike | None = None,
    ) -> npt.NDArray[np.float64]:
        """Pose offset delta = K^-1 (D(q) xi + Lambda(q) xi_dot) that lets this controller follow a motion.

        Commanding x_cmd = x_d + delta makes the free-space closed loop Lambda x'' + D x' + K (x - x_cmd) = 0
        hold x = x_d along a path with twist xi and twist rate xi_dot, with the controller's own Lambda
        (regularised as in the control law) and modal damping D = P diag(2 zeta sqrt(w)) P^T, Lambda = P P^T.
        The inputs are checked here; the rest is one compiled call (`impedance_kernel.pose_lead_into`).

        Args:
            data: MuJoCo data with current kinematics and mass matrix (after mj_forward or mj_step1).
            twist: desired site twist (v m/s, omega rad/s), world frame, (6,).
            accel: optional desired twist rate (6,); no inertial lead when None.
            stiffness: optional 6x6 SPD stiffness; the config's when None.

        Returns:
            delta (6,): position offset in m and rotation-vector offset in rad.

        Raises:
            ControllerError: bad twist, accel or stiffness.
        """
        xi = as_vector(twist, 6, "twist")
        rate = _NO_ACCEL if accel is None else as_vector(accel, 6, "accel")
        lead = np.empty(6)
        fns, m, d, site, jac, jac_minv, k, regularisation, two_zeta, scratch = self.lead_arguments(data, stiffness)
        check_lead_status(kernel.pose_lead_into(fns, m, d, site, jac, jac_minv, k, regularisation, two_zeta, xi, rate,
                                                accel is not None, *scratch, lead))
        return lead

    def command(self, data: mujoco.MjData, action: Action,
                feedforward_gain: float = 1.0) -> tuple[Pose, npt.NDArray[np.float64]]:
        """The pose and the 6x6 stiffness this controller holds for one control period of ``action``, at the state
        of ``data`` (controllers.interface.Controller): the stiffness `action_stiffness` makes, and the action's pose,
        or with a twist and a gain > 0 its anchor led by gain K^-1 (D(q) xi + Lambda(q) a) + push so the compliant
        arm moves at the twist instead of lagging behind it (controllers.feedforward).

        Args:
            data: MuJoCo data of `self.model`, kinematics and mass matrix current (after mj_forward or a physics step).
            action: the period's command.
            feedforward_gain: scale of the lead; 0 commands the action's pose.

        Returns:
            (pose, stiffness): the stiffness is not yet validated (`checked_stiffness` does that) and must not be
            modified (without a stiffness in the action it is the controller's default).

        Raises:
            ControllerError: a stiffness of another shape, a twist, acceleration or push that is not 6 finite
                numbers, an anchor that is not a pose, a bad stiffness with a twist, a singular arm.
        """
        stiffness = self.action_stiffness(action)
        if feedforward_gain == 0.0 or action.twist is None:
            return action.pose, stiffness
        return feedforward.led_pose(self, data, action, feedforward_gain, stiffness), stiffness

    def action_stiffness(self, action: Action) -> npt.NDArray[np.float64]:
        """The 6x6 stiffness ``action`` commands: a (6, 6) stiffness as it is; else `full_stiffness` of its
        translational and rotational stiffness, each the config's where the action has none; the default stiffness
        (not to be modified) when it has neither. Not validated here (`checked_stiffness`).

        Raises:
            ControllerError: a stiffness that is not (3, 3) or (6, 6), or a (6, 6) one with a rotational stiffness
                beside it.
        """
        k = action.stiffness
        if k is None and action.rotational_stiffness is None:
            return self.default_stiffness
        if k is not None:
            shape = np.shape(k)
            if shape == (6, 6):
                if action.rotational_stiffness is not None:
                    raise ControllerError("an action with a (6, 6) stiffness must leave rotational_stiffness None")
                return np.asarray(k, dtype=np.float64)
            if shape != (3, 3):
                raise ControllerError(f"action stiffness must be (3, 3) or (6, 6), got shape {shape}")
        config = self.config
        k_trans = config.translational_stiffness * np.eye(3) if k is None else k
        k_rot = config.rotational_stiffness if action.rotational_stiffness is None else action.rotational_stiffness
        return full_stiffness(k_trans, k_rot)

    def lead_arguments(self, data: mujoco.MjData, stiffness: npt.ArrayLike | None = None) -> tuple:
        """What `impedance_kernel.pose_lead_into` needs of this controller for ``data`` and a stiffness (validated
        here, the config's when None): (fns, m, d, site, J and J M^-1 buffers, K, regularisation, 2 zeta, its
        scratch buffers), for `pose_lead` and for the compiled lead of an action (controllers.feedforward).

        Raises:
            ControllerError: a bad stiffness.
        """
        return (self._fns, self.model._address, data._address, self.site_id, self._jac, self._jac_minv,
                self.checked_stiffness(stiffness), _INERTIA_REGULARISATION, 2.0 * self.config.damping_ratio,
                self._lead_scratch)

    def compute_torque(
        self,
        data: mujoco.MjData,
        target_pos: npt.ArrayLike,
        target_quat: npt.ArrayLike,
        stiffness: npt.ArrayLike | None = None,
        q_nullspace: npt.ArrayLike | None = None,
    ) -> npt.NDArray[np.float64]:
        """Validated torque for the current state (positions, velocities and mass matrix of `data` must be
        current, e.g. after mj_step1 or mj_forward). Updates the last-command state.

        Args:
            data: MuJoCo data of `self.model`.
            target_pos: desired site position in m, world frame.
            target_quat: desired site orientation, unit quaternion (w, x, y, z).
            stiffness: optional 6x6 SPD stiffness (world frame); the config's diagonal stiffness when None.
            q_nullspace: optional arm joint reference for the posture torque (rad, one per actuator); only
                posture damping when None.

        Returns:
            A copy of the limited joint torque in N m.

        Raises:
            ControllerError: bad target, stiffness or joint reference.
        """
        k = self._validate(target_pos, target_quat, stiffness, q_nullspace)
        tau = np.zeros(self.model.nu)
        self._torque(data, k, self._data_views(data)[:-1] + (tau,))  # data.ctrl stays untouched
        return tau

    def step(
        self,
        data: mujoco.MjData,
        target_pos: npt.ArrayLike,
        target_quat: npt.ArrayLike,
        stiffness: npt.ArrayLike | None = None,
        q_nullspace: npt.ArrayLike | None = None,
        n_substeps: int = 1,
        before_substep: Callable[[], None] | None = None,
        after_substep: Callable[[], bool] | None = None,
    ) -> int:
        """Advance the simulation n_substeps physics steps under impedance control toward a fixed target.

        Each substep: before_substep(), then one compiled call (impedance_kernel.impedance_substep): the tool load
        (`set_tool_load`) into qfrc_applied, mj_step1 (positions, velocities, mass matrix, bias), the torque into
        data.ctrl, mj_step2; then after_substep(). Inputs are validated once per call, not per substep, so a caller
        that must act between physics steps (read a sensor) passes hooks instead of calling with n_substeps=1.

        Args:
            data: MuJoCo data of `self.model`.
            target_pos, target_quat, stiffness, q_nullspace: as in `compute_torque`.
            n_substeps: number of physics steps (e.g. 10 for a 100 Hz command at 1 kHz physics).
            before_substep: called before each physics step.
            after_substep: called after each physics step; returning True stops early (e.g. a force limit).

        Returns:
            The number of physics steps taken (n_substeps unless after_substep stopped the loop).

        Raises:
            ControllerError: bad inputs, n_substeps < 1, or a singular Cartesian inertia (the state is then
                left after mj_step1 of the failing substep).
        """
        if int(n_substeps) < 1:
            raise ControllerError(f"n_substeps={n_substeps!r} must be >= 1")
        arguments = self.substep_arguments(data, target_pos, target_quat, stiffness, q_nullspace)
        substep = kernel.impedance_substep
        for done in range(1, int(n_substeps) + 1):
            if before_substep is not None:
                before_substep()
            if substep(*arguments) != kernel.STATUS_OK:
                raise ControllerError("J M^-1 J^T is not positive definite (Cholesky failed); the arm is singular")
            if after_substep is not None and after_substep():
                return done
        return int(n_substeps)

    def substep_arguments(self, data: mujoco.MjData, target_pos: npt.ArrayLike, target_quat: npt.ArrayLike,
                          stiffness: npt.ArrayLike | None = None, q_nullspace: npt.ArrayLike | None = None) -> tuple:
        """The arguments of ``impedance_kernel.impedance_substep`` for ``data`` toward this command (validated and
        stored in the kernel's buffers), for `step` and for a compiled loop that runs several substeps in one call
        (envs.sim.period_kernel).

        Raises:
            ControllerError: bad inputs (as `compute_torque`).
        """
        _, qpos, qvel, bias, site_pos, site_mat, ctrl = self._data_views(data)
        k = self._validate(target_pos, target_quat, stiffness, q_nullspace)
        return (self._fns, self.model._address, data._address, self.site_id, self._jac, self._jac_minv, qpos, qvel,
                bias, site_pos, site_mat, self._target, k, self._params, self._last_tau, ctrl, self._work, self._vec,
                self._tool, self._tool_point, self._jac_tool, self._jac_tool_arm, data.qfrc_applied[self.dof_slice],
                self._disturbance, self._disturbance_state, self._smooth, self._feedback, self._sensor_noise,
                self._layout, data.qfrc_passive, self._reading)

    def _validate(
        self,
        target_pos: npt.ArrayLike,
        target_quat: npt.ArrayLike,
        stiffness: npt.ArrayLike | None,
        q_nullspace: npt.ArrayLike | None,
    ) -> npt.NDArray[np.float64]:
        """Check the command, store it in the kernel's target buffer and return the stiffness to use."""
        n = self.model.nu
        target = self._target
        if q_nullspace is None:
            target[7 + n] = 0.0
        else:
            q_ref = as_vector(q_nullspace, n, "q_nullspace")
            values = q_ref.tolist()  # Python floats: a third of numpy's reductions on 7 numbers, once per period
            if max(values) > MAX_JOINT_ANGLE_RAD or min(values) < -MAX_JOINT_ANGLE_RAD:
                raise ControllerError(f"q_nullspace {values} must lie within +-{MAX_JOINT_ANGLE_RAD} rad")
            target[7:7 + n] = q_ref
            target[7 + n] = 1.0
        target[:3] = as_vector(target_pos, 3, "target_pos")
        target[3:7] = as_unit_quaternion(target_quat, "target_quat")
        return self.checked_stiffness(stiffness)

    def _data_views(self, data: mujoco.MjData) -> tuple:
        """The arrays of `data` the kernel reads and writes (views, built once per MjData)."""
        if not self._views or self._views[0] is not data:
            site = self.site_id
            self._views = (data, data.qpos[self.qpos_slice], data.qvel, data.qfrc_bias[self.dof_slice],
                           data.site_xpos[site], data.site_xmat[site], data.ctrl)
        return self._views

    def _torque(self, data: mujoco.MjData, stiffness: npt.NDArray[np.float64], views: tuple) -> None:
        """The control law of the module docstring (controllers.impedance_kernel) at the state of `data` after
        mj_step1 or mj_forward; writes the limited torque into data.ctrl and the last command."""
        mujoco.mj_jacSite(self.model, data, self._jac_pos, self._jac_rot, self.site_id)
        mujoco.mj_solveM(self.model, data, self._jac_minv, self._jac)
        _, qpos, qvel, bias, site_pos, site_mat, ctrl = views
        status = kernel.impedance_torque(self._jac, self._jac_minv, qpos, qvel, bias, site_pos, site_mat,
                                         self._target, stiffness, self._params, self._last_tau, ctrl,
                                         self._work, self._vec, self._no_offset)
        if status != kernel.STATUS_OK:
            raise ControllerError("J M^-1 J^T is not positive definite (Cholesky failed); the arm is singular")
