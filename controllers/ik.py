"""Inverse kinematics of a site: one-shot poses and a nullspace joint reference.

Each iteration solves the differential IK quadratic program of mink (tasks and limit as mink.FrameTask,
mink.PostureTask and mink.ConfigurationLimit define them, solved exactly like daqp does)

    min_dq  || J dq + e(q) ||^2_W  +  c_post || dq - (q_nom - q) ||^2  +  mu || dq ||^2
    s.t.    q_min <= q + dq <= q_max        (ConfigurationLimit)

with e the site pose error (a body twist, FrameTask) and a posture task toward the nominal joints, then
integrates q <- q + dq. `solve_ik` first iterates with the posture task (to choose the redundant posture near
q_nominal), then refines with a vanishing posture cost so the pose is met exactly (a posture cost biases the
fixed point off the target by about c_post / (J J^T)).

Two solvers of this one problem (`solve_ik`'s ``solver``):
  - "mink": mink itself (mink.FrameTask, PostureTask, ConfigurationLimit, daqp), the IK of record. It answers
    whether a pose is reachable (the evaluation's goal check) and is the reference of the tests.
  - "compiled": the same QP step in numba (`controllers.ik_kernel`), equal to mink + daqp to ~1e-9 rad per step
    (tests/controllers/test_ik_kernel.py, which runs on every CI run). `NullspaceReference` runs it every control step,
    where mink's Python iterations would cost more than the control law, and `PegInHoleEnv.reset` takes the
    start joints from it: from the starts of the contact and paper tasks the two solvers end within 2e-12 rad
    of each other and agree on every reachability verdict, but not to the bit, and a start 1e-12 rad away is
    another contact-rich episode (another record), so the record path keeps the solver its records were made
    with.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass

import mujoco
import numpy as np
import numpy.typing as npt

from controllers import ik_kernel
from controllers.errors import ControllerError
from controllers.mujoco_c import FUNCTIONS
from controllers.validation import as_unit_quaternion, as_vector, site_id, site_name
from numerics.small_linalg import norm

@dataclass(frozen=True)
class IKConfig:
    """Settings of the iterative IK.

    Attributes:
        position_tolerance_m: accepted site position residual in m.
        orientation_tolerance_deg: accepted site orientation residual in degrees.
        posture_cost: weight of the posture task while choosing the posture (per rad, vs 1 per m / per rad).
        refine_posture_cost: posture weight while refining to tolerance (keeps the QP strictly convex).
        lm_damping: Levenberg-Marquardt scale of the frame task (damps steps toward far or infeasible targets).
        max_iterations: iterations of each of the two phases before the pose is declared unreachable.
        floor_height_m: targets below this height are rejected (the scene's floor is at z = 0).
    """

    position_tolerance_m: float = 1e-4
    orientation_tolerance_deg: float = 0.05
    posture_cost: float = 1e-2
    refine_posture_cost: float = 1e-6
    lm_damping: float = 1.0
    max_iterations: int = 100
    floor_height_m: float = 0.0

    def __post_init__(self) -> None:
        for name, zero_allowed in (
            ("position_tolerance_m", False),
            ("orientation_tolerance_deg", False),
            ("refine_posture_cost", False),
            ("posture_cost", True),
            ("lm_damping", True),
        ):
            value = getattr(self, name)
            if not isinstance(value, numbers.Real) or not np.isfinite(value) or value < 0.0 or (
                value == 0.0 and not zero_allowed
            ):
                kind = "non-negative" if zero_allowed else "positive"
                raise ControllerError(f"IKConfig.{name}={value!r} must be a {kind} finite number")
        if not isinstance(self.max_iterations, int) or self.max_iterations < 1:
            raise ControllerError(f"IKConfig.max_iterations={self.max_iterations!r} must be an integer >= 1")
        if not isinstance(self.floor_height_m, numbers.Real) or not np.isfinite(self.floor_height_m):
            raise ControllerError(f"IKConfig.floor_height_m={self.floor_height_m!r} must be a finite number")


def pose_residual(
    data: mujoco.MjData, site_id: int, target_pos: npt.NDArray, target_quat: npt.NDArray
) -> tuple[float, float]:
    """Position residual ||p_d - p|| in m and orientation residual ||Log(conj(q) q_d)|| in degrees."""
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, data.site_xmat[site_id])
    rotation = np.zeros(3)
    mujoco.mju_subQuat(rotation, target_quat, quat)
    return norm(target_pos - data.site_xpos[site_id]), float(np.degrees(norm(rotation)))


class _DifferentialIK:
    """The differential-IK problem of one site of one model (module docstring): its own configuration (MjData),
    the frame target, the posture target and weight, and the compiled QP step (`controllers.ik_kernel`)."""

    LIMIT_GAIN = 0.95  # a step covers at most 95 % of the way to a joint limit (mink.ConfigurationLimit's gain)
    DAMPING = 1e-9  # mu_0 on every dof

    def __init__(self, model: mujoco.MjModel, site: int | str, config: IKConfig) -> None:
        if np.any(model.jnt_type == mujoco.mjtJoint.mjJNT_BALL):
            raise ControllerError("the IK supports hinge, slide and free joints, not ball joints")
        self.model = model
        self.site_id = site_id(model, site)
        self.site_name = site_name(model, site)
        self.lm_damping = config.lm_damping
        self.posture_cost = config.posture_cost
        self.data = mujoco.MjData(model)
        self.q_posture = self.data.qpos.copy()
        dof_qpos_adr = np.full(model.nv, -1, dtype=np.int64)
        limited = np.zeros(model.nv)
        q_min, q_max = np.zeros(model.nv), np.zeros(model.nv)
        for joint in range(model.njnt):
            if model.jnt_type[joint] == mujoco.mjtJoint.mjJNT_FREE:
                continue
            dof = int(model.jnt_dofadr[joint])
            dof_qpos_adr[dof] = int(model.jnt_qposadr[joint])
            limited[dof] = float(bool(model.jnt_limited[joint]))
            q_min[dof], q_max[dof] = model.jnt_range[joint]
        self._dof_qpos_adr, self._limited, self._q_min, self._q_max = dof_qpos_adr, limited, q_min, q_max
        self._jac = np.zeros((6, model.nv))
        self._dq = np.zeros(model.nv)
        self._target_pos = np.zeros(3)
        self._target_mat = np.zeros(9)
        self._scratch = np.zeros((12, 3, 3))
        self._fns = FUNCTIONS  # MuJoCo's C functions for the compiled iterations

    def joints(self, value: npt.ArrayLike, name: str) -> npt.NDArray[np.float64]:
        """A joint vector of the model's size, hinge and slide joints clipped into their limits."""
        q = as_vector(value, self.model.nq, name)
        model = self.model
        for joint in range(model.njnt):
            if model.jnt_limited[joint] and model.jnt_type[joint] != mujoco.mjtJoint.mjJNT_FREE:
                adr = model.jnt_qposadr[joint]
                q[adr] = np.clip(q[adr], model.jnt_range[joint, 0], model.jnt_range[joint, 1])
        return q

    @property
    def q(self) -> npt.NDArray[np.float64]:
        """The configuration (a view of its MjData's qpos)."""
        return self.data.qpos

    def set_configuration(self, q: npt.NDArray[np.float64]) -> None:
        """Set the joints and run the kinematics the step needs (frames and the Jacobian's com positions)."""
        self.data.qpos[:] = q
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_comPos(self.model, self.data)

    def set_target(self, target_pos: npt.NDArray, target_quat: npt.NDArray) -> None:
        self._target_pos[:] = target_pos
        mujoco.mju_quat2Mat(self._target_mat, target_quat)

    def iterate(self, iterations: int = 1) -> None:
        """``iterations`` differential-IK QP steps, each integrated into the configuration: q <- q (+) dq
        (one compiled call, `ik_kernel.ik_iterations`).

        Raises:
            ControllerError: a QP was not solved (the configuration is that of the steps before it).
        """
        data, site = self.data, self.site_id
        done = ik_kernel.ik_iterations(self._fns, self.model._address, data._address, site, iterations, self._jac,
                                       data.site_xpos[site], data.site_xmat[site], self._target_pos,
                                       self._target_mat, data.qpos, self.q_posture, self._dof_qpos_adr,
                                       self.posture_cost, self.lm_damping, self.DAMPING, self._limited, self._q_min,
                                       self._q_max, self.LIMIT_GAIN, self._dq, self._scratch)
        if done < iterations:
            raise ControllerError(f"IK step failed for site {self.site_name!r}: the QP was not solved")

    def residual(self, target_pos: npt.NDArray, target_quat: npt.NDArray) -> tuple[float, float]:
        return pose_residual(self.data, self.site_id, target_pos, target_quat)


class _MinkIK(_DifferentialIK):
    """The same problem built from mink's own pieces -- mink.FrameTask (position and orientation cost 1,
    ``lm_damping``), mink.PostureTask, mink.ConfigurationLimit (gain 0.95) -- and solved by daqp (damping 1e-9):
    the IK of record, which the compiled step equals to ~1e-9 rad (tests/controllers/test_ik_kernel.py). Its iterations
    run in Python, many times slower than the compiled ones (README: `pih bench --only ik`)."""

    def __init__(self, model: mujoco.MjModel, site: int | str, config: IKConfig) -> None:
        import mink

        self._mink = mink
        self._posture = mink.PostureTask(model, cost=config.posture_cost)  # before the base sets its target
        super().__init__(model, site, config)
        self._configuration = mink.Configuration(model)
        self._frame = mink.FrameTask(self.site_name, "site", position_cost=1.0, orientation_cost=1.0,
                                     lm_damping=config.lm_damping)
        self._limits = [mink.ConfigurationLimit(model, gain=self.LIMIT_GAIN)]

    @property
    def posture_cost(self) -> float:
        return float(np.max(self._posture.cost))

    @posture_cost.setter
    def posture_cost(self, cost: float) -> None:
        self._posture.set_cost(cost)

    @property
    def q_posture(self) -> npt.NDArray[np.float64]:
        return self._posture.target_q

    @q_posture.setter
    def q_posture(self, q: npt.NDArray[np.float64]) -> None:
        self._posture.set_target(q)

    def set_configuration(self, q: npt.NDArray[np.float64]) -> None:
        super().set_configuration(q)
        self._configuration.update(self.q.copy())

    def set_target(self, target_pos: npt.NDArray, target_quat: npt.NDArray) -> None:
        self._frame.set_target(self._mink.SE3(wxyz_xyz=np.concatenate([target_quat, target_pos])))

    def iterate(self, iterations: int = 1) -> None:
        """``iterations`` steps of mink.solve_ik, each integrated (mink's Configuration.integrate_inplace).

        Raises:
            ControllerError: daqp found no solution.
        """
        mink = self._mink
        for _ in range(iterations):
            try:
                velocity = mink.solve_ik(self._configuration, [self._frame, self._posture], dt=1.0, solver="daqp",
                                         damping=self.DAMPING, limits=self._limits)
            except mink.NoSolutionFound as err:
                raise ControllerError(f"IK step failed for site {self.site_name!r}: {err}") from None
            self._configuration.integrate_inplace(velocity, 1.0)
        super().set_configuration(self._configuration.q)


SOLVERS: dict[str, type[_DifferentialIK]] = {"compiled": _DifferentialIK, "mink": _MinkIK}
"""`solve_ik`'s solvers: the compiled QP step (numba) and mink itself (the reference)."""


def solve_ik(
    model: mujoco.MjModel,
    site: int | str,
    target_pos: npt.ArrayLike,
    target_quat: npt.ArrayLike,
    q_nominal: npt.ArrayLike,
    config: IKConfig = IKConfig(),
    solver: str = "compiled",
) -> npt.NDArray[np.float64]:
    """Joint positions that put a site at a pose, within joint limits, near a nominal posture.

    Args:
        model: the arm or a scene containing it (extra fixed bodies are fine).
        site: name or id of the site (e.g. "peg_mount", or the scene's peg tip).
        target_pos: site position in m, world frame.
        target_quat: site orientation, unit quaternion (w, x, y, z).
        q_nominal: start and posture reference (rad), length nq; clipped into the joint limits.
        config: tolerances and weights.
        solver: "compiled" (the QP step in numba, `controllers.ik_kernel`) or "mink" (mink + daqp, the
            reference, slower); the same problem, phases and stopping rules.

    Returns:
        q (rad), length nq, inside the joint limits, with the site within the tolerances of the pose.

    Raises:
        ControllerError: bad inputs or solver, a target below the floor, or a pose not reached to tolerance
            (the message names the pose and the residual in mm and deg).
    """
    if solver not in SOLVERS:
        raise ControllerError(f"solver={solver!r} must be one of {sorted(SOLVERS)}")
    problem = SOLVERS[solver](model, site, config)
    pos = as_vector(target_pos, 3, "target_pos")
    quat = as_unit_quaternion(target_quat, "target_quat")
    q_nom = problem.joints(q_nominal, "q_nominal")
    pose = f"p={np.round(pos, 4).tolist()} m, q={np.round(quat, 4).tolist()}"
    if pos[2] < config.floor_height_m:
        raise ControllerError(
            f"IK target {pose} for site {problem.site_name!r} is below the floor (z < {config.floor_height_m} m)"
        )
    problem.set_configuration(q_nom)
    problem.q_posture = q_nom
    problem.set_target(pos, quat)

    previous = problem.q.copy()
    for _ in range(config.max_iterations):  # choose the posture
        problem.iterate()
        if np.max(np.abs(problem.q - previous)) < 1e-6:
            break
        previous = problem.q.copy()
    problem.posture_cost = config.refine_posture_cost
    residual = problem.residual(pos, quat)
    for _ in range(config.max_iterations):  # meet the pose to tolerance
        if _within(residual, config):
            break
        problem.iterate()
        residual = problem.residual(pos, quat)
    if _within(residual, config):
        return problem.q.copy()
    raise ControllerError(
        f"IK target {pose} for site {problem.site_name!r} is unreachable: residual {1e3 * residual[0]:.2f} mm, "
        f"{residual[1]:.3f} deg (tolerance {1e3 * config.position_tolerance_m:.2f} mm, "
        f"{config.orientation_tolerance_deg} deg)"
    )


def _within(residual: tuple[float, float], config: IKConfig) -> bool:
    return residual[0] <= config.position_tolerance_m and residual[1] <= config.orientation_tolerance_deg


class NullspaceReference:
    """Joint reference for the impedance controller's nullspace that follows the commanded pose.

    Every `update` runs a few warm-started differential-IK iterations (frame task + posture task toward q_nominal,
    joint limits) from the previous reference, so the reference tracks a moving target at the command rate (100 Hz)
    without solving to convergence.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        site: int | str,
        q_nominal: npt.ArrayLike,
        iterations: int = 3,
        config: IKConfig = IKConfig(),
    ) -> None:
        """Args:
            model: the arm or a scene containing it (hinge, slide and free joints).
            site: name or id of the controlled site.
            q_nominal: posture reference and initial reference (rad).
            iterations: IK iterations per update (>= 1).
            config: posture cost and LM damping (tolerances unused).

        Raises:
            ControllerError: bad site, q_nominal or iterations, or a model with ball joints.
        """
        if int(iterations) < 1:
            raise ControllerError(f"iterations={iterations!r} must be >= 1")
        self._problem = _DifferentialIK(model, site, config)
        self._iterations = int(iterations)
        self.q_nominal = self._problem.joints(q_nominal, "q_nominal")
        self._problem.q_posture = self.q_nominal
        self.reset()

    def reset(self, q: npt.ArrayLike | None = None) -> None:
        """Restart the reference from q (rad), or from q_nominal when None."""
        self._problem.set_configuration(self.q_nominal if q is None else self._problem.joints(q, "q"))

    @property
    def q(self) -> npt.NDArray[np.float64]:
        """Copy of the current joint reference (rad)."""
        return self._problem.q.copy()

    def update(self, target_pos: npt.ArrayLike, target_quat: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Advance the reference toward the pose and return it.

        Args:
            target_pos: commanded site position in m.
            target_quat: commanded site orientation (w, x, y, z).

        Returns:
            The joint reference (rad), length nq, within the joint limits.

        Raises:
            ControllerError: bad target or a failed QP.
        """
        self._problem.set_target(as_vector(target_pos, 3, "target_pos"), as_unit_quaternion(target_quat, "target_quat"))
        self._problem.iterate(self._iterations)
        return self.q
