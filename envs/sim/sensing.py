"""What the episode measures at the physics rate: the wrist force/torque sensor and the peg's contacts.

Wrist F/T. MuJoCo's ``force``/``torque`` sensors at site ``ft_sensor`` (between flange and hand) read the
wrench F_s, tau_s that the flange exerts on the hand's subtree, in the site frame S. In static equilibrium
    F_s + m g + F_c = 0,   tau_s + r_com x m g + tau_c = 0,
with m the carried mass (hand, fingers and a grasped or welded peg), r_com its centre of mass relative to the
site and F_c, tau_c the wrench the environment exerts on the tool (contacts). The sensor is zeroed for the
tool load like a real F/T sensor, so the reported wrist wrench is the environment's wrench on the tool:
    F_ext = -(F_s - F_0),  tau_ext = -(tau_s - tau_0),  F_0 = -R_S^T m g,  tau_0 = -R_S^T (r_com x m g).
Dynamic loads (m a of the hand when the arm accelerates) remain in it, as on a real sensor.

Contacts. The environment's normal forces on the peg (contacts of peg geoms with anything but the fingers):
their sum of magnitudes (opposing walls add up, they do not cancel) and the largest single one. With an
elliptic friction cone the first row of a contact's constraint force is its normal force.

Both are read every physics step, so their arithmetic is compiled (envs.sim.sensing_kernel). `EpisodeSensing` is that
per-step work for one episode: the compiled update of a small state (peaks, the force window, the time above the
force limit) after every physics step, copied into the episode's `ContactStats` at the end of a control period.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np
import numpy.typing as npt

from controllers.mujoco_c import FUNCTIONS
from controllers.mujoco_layout import check_layout
from envs.errors import EnvError
from envs.sim import sensing_kernel as kernel
from envs.task.sensor_config import (MAX_ARM_JOINTS, SENSOR_ALPHA, SENSOR_BIAS, SENSOR_JOINT_BIAS, SENSOR_JOINT_TORQUE,
                                     SENSOR_ON, SENSOR_SIZE, SENSOR_WRIST, WristSensorConfig)

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class ToolLoad:
    """Bodies whose weight the wrist sensor carries (hand subtree and, if separate, a grasped peg)."""

    bodies: tuple[int, ...]


class WristSensor:
    """Reads the gravity-compensated wrist wrench (module docstring) from a model's F/T sensor site."""

    def __init__(self, model: mujoco.MjModel, site: int, force_adr: int, torque_adr: int, load: ToolLoad) -> None:
        """Args:
            model: the scene.
            site: the ``ft_sensor`` site id.
            force_adr, torque_adr: the sensors' addresses in ``data.sensordata``.
            load: bodies carried by the sensor (their weight is zeroed out).

        Raises:
            EnvError: a site, sensor address or body that the model does not have, or no body.
        """
        if not 0 <= site < model.nsite:
            raise EnvError(f"WristSensor: site {site} is not one of the model's {model.nsite} sites")
        for name, adr in (("force", force_adr), ("torque", torque_adr)):
            if not 0 <= adr <= model.nsensordata - 3:
                raise EnvError(f"WristSensor: {name} address {adr} leaves no 3 values in the model's "
                               f"{model.nsensordata} sensor values")
        if not load.bodies or not all(0 <= b < model.nbody for b in load.bodies):
            raise EnvError(f"WristSensor: the tool load's bodies {load.bodies} must be 1 or more of the model's "
                           f"{model.nbody} bodies")
        self.site = site
        self._force = slice(force_adr, force_adr + 3)
        self._torque = slice(torque_adr, torque_adr + 3)
        self._bodies = np.asarray(load.bodies, dtype=np.int64)
        masses = model.body_mass[self._bodies]
        gravity = np.asarray(model.opt.gravity, dtype=np.float64)
        self._load = np.concatenate([[float(masses.sum())], gravity, masses])  # [M, g, m_b] (sensing_kernel)
        self._views: tuple = ()  # (data, the kernel's arguments from it), built once per MjData

    def kernel_inputs(self, data: mujoco.MjData) -> tuple:
        """The arguments of ``sensing_kernel.wrist_wrench`` for ``data`` but the output: views of its site
        rotation (9,), site position, body centres of mass and force and torque readings, then the carried bodies
        and [M, g, m_b] (the views are built once per MjData and stay valid for its life)."""
        if not self._views or self._views[0] is not data:
            self._views = (data, data.site_xmat[self.site], data.site_xpos[self.site], data.xipos,
                           data.sensordata[self._force], data.sensordata[self._torque], self._bodies, self._load)
        return self._views[1:]

    def wrench(self, data: mujoco.MjData) -> FloatArray:
        """[F_ext (N); tau_ext (N m)] (6,) in the sensor frame (a new array).

        With M the carried mass and c its centre of mass: F_0 = -M g, tau_0 = -M (c - s) x g (world), rotated
        into the sensor frame.
        """
        out = np.empty(6)
        kernel.wrist_wrench(*self.kernel_inputs(data), out)
        return out


class JointTorqueSensors:
    """The arm's joint torque sensors as a wrench sensor (envs.task.sensor_config, ``sensor_mode = "joint_torque"``):
    the estimate at the F/T site through its Jacobian over the arm's joints, zeroed for the nominal weight of the tool
    the arm's model does not contain (a grasped peg; a welded peg is part of the hand's body and of the model)."""

    def __init__(self, model: mujoco.MjModel, site: int, arm_dofs: tuple[int, ...], tool: ToolLoad) -> None:
        """Args:
            model: the scene.
            site: the ``ft_sensor`` site id (the estimate's reference point and frame, as the wrist sensor's).
            arm_dofs: the arm joints' dof addresses (at most MAX_ARM_JOINTS).
            tool: the tool bodies outside the arm's model (empty: none).

        Raises:
            EnvError: a site, dof or body that the model does not have, or too many joints.
        """
        if not 0 <= site < model.nsite:
            raise EnvError(f"JointTorqueSensors: site {site} is not one of the model's {model.nsite} sites")
        if not 0 < len(arm_dofs) <= MAX_ARM_JOINTS or not all(0 <= v < model.nv for v in arm_dofs):
            raise EnvError(f"JointTorqueSensors: arm dofs {arm_dofs} must be 1 to {MAX_ARM_JOINTS} of the model's "
                           f"{model.nv} dofs")
        if not all(0 <= b < model.nbody for b in tool.bodies):
            raise EnvError(f"JointTorqueSensors: tool bodies {tool.bodies} are not all the model's")
        self.model = model
        self.index = np.array([site, int(mujoco.mjtConstraint.mjCNSTR_FRICTION_DOF), len(arm_dofs), *arm_dofs],
                              dtype=np.int64)
        self.bodies = np.asarray(tool.bodies, dtype=np.int64)
        masses = model.body_mass[self.bodies]
        gravity = np.asarray(model.opt.gravity, dtype=np.float64)
        self.load = np.concatenate([[float(masses.sum())], gravity, masses])  # [M, g, m_b] (sensing_kernel)


class PegContacts:
    """Normal forces of the environment's contacts on the peg (module docstring)."""

    def __init__(self, model: mujoco.MjModel, peg_geoms: tuple[int, ...], ignored_geoms: tuple[int, ...]) -> None:
        """Args:
            model: the scene (must use the elliptic friction cone).
            peg_geoms: the peg's geoms.
            ignored_geoms: geoms whose contacts with the peg are not the environment's (the fingers).

        Raises:
            EnvError: a pyramidal friction cone (its constraint rows are not normal forces), or a geom that the
                model does not have.
        """
        if model.opt.cone != mujoco.mjtCone.mjCONE_ELLIPTIC:
            raise EnvError("PegContacts needs the elliptic friction cone (ContactConfig.cone='elliptic')")
        if not all(0 <= g < model.ngeom for g in (*peg_geoms, *ignored_geoms)):
            raise EnvError(f"PegContacts: geoms {peg_geoms} (peg) and {ignored_geoms} (ignored) must be among the "
                           f"model's {model.ngeom} geoms")
        peg = np.zeros(model.ngeom, dtype=bool)
        peg[list(peg_geoms)] = True
        ignored = np.zeros(model.ngeom, dtype=bool)
        ignored[list(ignored_geoms)] = True
        # counted[g1, g2]: exactly one of the pair is a peg geom and the other is not ignored (a table built once,
        # so a physics step looks each contact up in one read)
        one_peg = peg[:, None] != peg[None, :]
        other_ignored = np.where(peg[:, None], ignored[None, :], ignored[:, None])
        self._counted = one_peg & ~other_ignored
        self._peg = peg
        self._scratch = kernel.contact_scratch()

    def kernel_inputs(self) -> tuple[npt.NDArray[np.bool_], FloatArray]:
        """The last arguments of ``sensing_kernel.normal_forces``: the counted-pair table and the forces' buffer."""
        return self._counted, self._scratch

    def force_on(self, data: mujoco.MjData, geom: int) -> float:
        """Sum of the normal forces (N) of the peg's contacts with ``geom`` now (e.g. the hole's floor)."""
        contact = data.contact
        total = 0.0
        for g1, g2, adr in zip(contact.geom1.tolist(), contact.geom2.tolist(), contact.efc_address.tolist()):
            if adr >= 0 and ((g1 == geom and self._peg[g2]) or (g2 == geom and self._peg[g1])):
                total += abs(float(data.efc_force[adr]))
        return total

    def normal_forces(self, data: mujoco.MjData) -> tuple[float, float]:
        """(sum of normal-force magnitudes, largest single normal force) in N, now."""
        contact = data.contact
        return kernel.normal_forces(contact.geom, contact.efc_address, data.efc_force, self._counted, self._scratch)


@dataclass
class ContactStats:
    """Peaks over an episode at the physics rate, and control-rate samples for medians (the peaks are copied from
    the compiled sense state, envs.sim.sensing_kernel, at the end of every control period).

    Attributes:
        peak_contact_force_n: largest sum of the environment's normal-force magnitudes on the peg.
        peak_single_contact_n: largest single normal force on the peg.
        peak_wrist_force_n, peak_wrist_torque_nm: largest |F_ext| and |tau_ext| of the wrist sensor.
        peak_sustained_wrist_force_n: largest |F_ext| held for the force limit's whole window (the largest
            minimum of |F_ext| over any window of ``force_limit_window_s``): what the force limit compares.
        wrist_force_samples, wrist_torque_samples: |F_ext|, |tau_ext| at the end of every control period.
        force_limit_time_s: physics time the force first stayed above the limit for the window (None: never).
    """

    peak_contact_force_n: float = 0.0
    peak_single_contact_n: float = 0.0
    peak_wrist_force_n: float = 0.0
    peak_wrist_torque_nm: float = 0.0
    peak_sustained_wrist_force_n: float = 0.0
    wrist_force_samples: list[float] = field(default_factory=list)
    wrist_torque_samples: list[float] = field(default_factory=list)
    force_limit_time_s: float | None = None

    def summary(self) -> dict[str, float | None]:
        """Peaks and medians, JSON-ready."""
        def median(values: list[float]) -> float | None:
            return float(np.median(values)) if values else None

        return {
            "peak_contact_force_n": self.peak_contact_force_n,
            "peak_single_contact_n": self.peak_single_contact_n,
            "peak_wrist_force_n": self.peak_wrist_force_n,
            "peak_sustained_wrist_force_n": self.peak_sustained_wrist_force_n,
            "median_wrist_force_n": median(self.wrist_force_samples),
            "peak_wrist_torque_nm": self.peak_wrist_torque_nm,
            "median_wrist_torque_nm": median(self.wrist_torque_samples),
        }


@dataclass(frozen=True)
class SenseInputs:
    """The arguments of ``sensing_kernel.sense_substep`` that stay the same for an MjData (all but its contacts):
    views of the data, built once.

    Attributes:
        wrist_rot, wrist_pos: the F/T site's rotation (9,) and position (3,) (views; `WristSensor.kernel_inputs`).
        xipos: the bodies' centres of mass (view).
        force, torque: the F/T sensor's readings (views).
        bodies, load: the carried bodies and [M, g, m_b] of the tool load.
        counted, scratch: the counted contact pairs and the forces' buffer (`PegContacts.kernel_inputs`).
        limits: [force_limit_n, force_limit_window_s, timestep] (sensing_kernel.LIMIT_*).
        sensor: [on, alpha, bias (6)] of the wrist sensor's model (envs.task.sensor_config.SENSOR_*).
        noise: (n_substeps, 6) the current control period's sensor noise, one row per physics step.
        state: the sense state (sensing_kernel.sense_state): peaks, force window, time above the force limit.
        layout: where the mjData keeps its contacts (controllers.mujoco_layout, checked on this data).
        fns, model_address: MuJoCo's functions and the model's address (controllers.mujoco_c).
        jt_index .. jt_estimate: the joint-torque estimate's index, Jacobian buffer, qfrc_constraint view, tool load,
            the period's joint noise (n_substeps, 7), scratch and the estimate (sensing_kernel.joint_torque_estimate;
            unused in the other modes).
    """

    wrist_rot: FloatArray
    wrist_pos: FloatArray
    xipos: FloatArray
    force: FloatArray
    torque: FloatArray
    bodies: npt.NDArray[np.int64]
    load: FloatArray
    counted: npt.NDArray[np.bool_]
    scratch: FloatArray
    limits: FloatArray
    sensor: FloatArray
    noise: FloatArray
    state: FloatArray
    layout: npt.NDArray[np.int64]
    fns: npt.NDArray[np.int64]
    model_address: int
    jt_index: npt.NDArray[np.int64]
    jt_jac: FloatArray
    qfrc_constraint: FloatArray
    jt_bodies: npt.NDArray[np.int64]
    jt_load: FloatArray
    jt_noise: FloatArray
    jt_matrices: FloatArray
    jt_vectors: FloatArray
    jt_estimate: FloatArray

    def kernel_arguments(self) -> tuple:
        """The arguments of ``sensing_kernel.sense_substep_at`` after the mjData's address."""
        return (self.layout, self.wrist_rot, self.wrist_pos, self.xipos, self.force, self.torque, self.bodies,
                self.load, self.counted, self.scratch, self.limits, self.sensor, self.noise, self.state, self.fns,
                self.model_address, self.jt_index, self.jt_jac, self.qfrc_constraint, self.jt_bodies, self.jt_load,
                self.jt_noise, self.jt_matrices, self.jt_vectors, self.jt_estimate)


class EpisodeSensing:
    """The physics-rate sensing of an episode on one MjData: `reset` at the start of an episode, `start_period` at
    the start of a control period, `substep` after each of its physics steps and `copy_peaks` at its end; ``stats``
    holds the episode's figures."""

    def __init__(self, data: mujoco.MjData, wrist: WristSensor, contacts: PegContacts, force_limit_n: float,
                 force_limit_window_s: float, timestep: float, n_substeps: int,
                 sensor: WristSensorConfig = WristSensorConfig(), joints: JointTorqueSensors | None = None) -> None:
        """Args:
            data: the episode's MjData (views of it are kept).
            wrist, contacts: the sensors.
            force_limit_n, force_limit_window_s: a wrist force above the limit for the window hits the force limit.
            timestep: the physics timestep (s); the force window holds ``force_limit_window_s / timestep``
                readings (at least one).
            n_substeps: physics steps per control period (rows of the period's sensor noise).
            sensor: the wrench sensing's model (envs.task.sensor_config; "ideal": the exact wrench).
            joints: the joint torque sensors (required by ``sensor_mode = "joint_torque"``).

        Raises:
            EnvError: the joint-torque mode without ``joints``.
        """
        window = max(1, int(round(force_limit_window_s / timestep)))
        limits = np.array([force_limit_n, force_limit_window_s, timestep], dtype=np.float64)
        self.data = data
        self.sensor = sensor
        parameters = np.zeros(SENSOR_SIZE)
        parameters[SENSOR_ON] = sensor.mode_code
        parameters[SENSOR_ALPHA] = sensor.alpha(timestep)
        if sensor.mode_code == SENSOR_JOINT_TORQUE and joints is None:
            raise EnvError("sensor_mode 'joint_torque' needs the arm's joint torque sensors (JointTorqueSensors)")
        self._sigma = sensor.noise_sigma
        self._rng: np.random.Generator | None = None
        rows = max(1, n_substeps)
        if joints is None:
            jt_index, jt_bodies, jt_load = np.zeros(kernel.JT_DOFS, dtype=np.int64), np.zeros(0, np.int64), np.zeros(4)
            model_address = 0
        else:
            jt_index, jt_bodies, jt_load = joints.index, joints.bodies, joints.load
            model_address = joints.model._address
        self.inputs = SenseInputs(*wrist.kernel_inputs(data), *contacts.kernel_inputs(), limits, parameters,
                                  np.zeros((rows, 6)), kernel.sense_state(window), check_layout(data), FUNCTIONS,
                                  model_address, jt_index, np.zeros((6, data.qvel.shape[0])), data.qfrc_constraint,
                                  jt_bodies, jt_load, np.zeros((rows, MAX_ARM_JOINTS)), np.zeros((2, 6, 6)),
                                  np.zeros((4, MAX_ARM_JOINTS)), np.zeros(6))
        self._arguments = self.inputs.kernel_arguments()
        self.stats = ContactStats()
        self._period_start_s = 0.0

    def reset(self, rng: np.random.Generator | None = None) -> None:
        """New figures for a new episode (the earlier episode's ``stats`` object is left as it was); with the sensor
        model on, the episode's bias and noise come from ``rng`` (envs.sim.sensor_reading.episode_generator;
        required)."""
        self.stats = ContactStats()
        self.inputs.state[:] = 0.0
        self.inputs.jt_estimate[:] = 0.0
        mode = self.inputs.sensor[SENSOR_ON]
        if mode:
            if rng is None:
                raise EnvError("the wrench sensor model needs the episode's generator at reset")
            self._rng = rng
        if mode == SENSOR_WRIST:
            self.inputs.sensor[SENSOR_BIAS:SENSOR_JOINT_BIAS] = rng.standard_normal(6) * self.sensor.bias_sigma
        elif mode == SENSOR_JOINT_TORQUE:
            self.inputs.sensor[SENSOR_JOINT_BIAS:] = (rng.standard_normal(MAX_ARM_JOINTS)
                                                      * self.sensor.joint_torque_bias_nm)

    def start_period(self, time_s: float) -> None:
        """A control period starts at episode time ``time_s`` (the time a force limit hit in it is recorded at); with
        the sensor model on, its noise is drawn."""
        self._period_start_s = time_s
        mode = self.inputs.sensor[SENSOR_ON]
        if self._rng is not None and mode == SENSOR_WRIST:
            noise = self.inputs.noise
            noise[:] = self._rng.standard_normal(noise.shape) * self._sigma
            self.inputs.state[kernel.SUBSTEP] = 0.0
        elif self._rng is not None and mode == SENSOR_JOINT_TORQUE:
            noise = self.inputs.jt_noise
            noise[:] = self._rng.standard_normal(noise.shape) * self.sensor.joint_torque_noise_nm
            self.inputs.state[kernel.SUBSTEP] = 0.0

    def joint_torque_errors(self, settle_steps: int = 0) -> tuple[FloatArray, FloatArray | None]:
        """What the arm's joint torque sensors add to the torque they read: (the episode's bias per joint (7,), the
        noise rows (R, 7) of this control period or None when they have none). Their noise and bias are the task's
        only with ``sensor_mode = "joint_torque"`` (the wrench estimate reads the same); in the other modes the joint
        sensors read exactly. ``settle_steps`` > 0: rows for that many physics steps of the grasp's settle instead,
        drawn from the episode's generator after its bias (before the first control period's)."""
        inputs = self.inputs
        bias = inputs.sensor[SENSOR_JOINT_BIAS:SENSOR_JOINT_BIAS + MAX_ARM_JOINTS]
        if inputs.sensor[SENSOR_ON] != SENSOR_JOINT_TORQUE or self.sensor.joint_torque_noise_nm == 0.0:
            return bias, None
        if settle_steps > 0:
            return bias, self._rng.standard_normal((settle_steps, MAX_ARM_JOINTS)) * self.sensor.joint_torque_noise_nm
        return bias, inputs.jt_noise

    def sensed_wrench(self, true_wrench: FloatArray) -> FloatArray:
        """What the cell's sensor reads now: ``true_wrench`` itself when ideal, else the sensed y (a new array)."""
        if not self.inputs.sensor[SENSOR_ON]:
            return true_wrench
        return self.inputs.state[kernel.SENSED:kernel.SENSED + 6].copy()

    def substep(self) -> bool:
        """Update the peaks, the force window and the time above the force limit after a physics step
        (sensing_kernel.sense_substep_at); True when the force limit hits (`after_period` records its time)."""
        return self.after_period(kernel.sense_substep_at(self.data._address, *self._arguments))

    def period_arguments(self) -> tuple:
        """The arguments of ``sensing_kernel.sense_substep_at`` after the mjData's address, for a compiled loop that
        senses after each of its physics steps itself (envs.sim.period_kernel)."""
        return self._arguments

    def after_period(self, limit_hit: bool) -> bool:
        """Record a force limit hit in this control period (at the period's start unless it hit earlier); returns
        ``limit_hit``."""
        if limit_hit:
            stats = self.stats
            stats.force_limit_time_s = stats.force_limit_time_s or self._period_start_s
        return bool(limit_hit)

    def copy_peaks(self) -> None:
        """Copy the peaks of the sense state into ``stats``."""
        state, stats = self.inputs.state, self.stats
        stats.peak_contact_force_n = float(state[kernel.PEAK_CONTACT])
        stats.peak_single_contact_n = float(state[kernel.PEAK_SINGLE])
        stats.peak_wrist_force_n = float(state[kernel.PEAK_FORCE])
        stats.peak_wrist_torque_nm = float(state[kernel.PEAK_TORQUE])
        stats.peak_sustained_wrist_force_n = float(state[kernel.PEAK_SUSTAINED])
