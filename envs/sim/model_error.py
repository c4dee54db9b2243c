"""An episode's errors of the arm's model: what the simulated cell has and the controller does not know.

- Payload: the simulated peg's mass and rotational inertia are scaled by (1 + e) (envs.task.perturbation), while the
  controller's tool load (controllers.impedance: the weight it compensates) and the wrist sensor's zeroing
  (envs.sim.sensing.ToolLoad) keep the nominal mass they were given when the environment was built. A heavier peg
  sags by e m g / K_z under a translational stiffness K_z and shows as e m g on the zeroed sensor.
- Payload centre of mass: the simulated peg's centre of mass is moved across its axis by c (its body's ipos), while
  the controller's tool load and the sensor's zeroing keep it on the axis: the zeroed wrist sensor reads the moment
  c x m g, and the compliant wrist turns by about |c| m g / K_rot.
- Torque noise (`ActuatorNoise`): each arm joint delivers its commanded torque plus white noise of sigma N m per
  physics step (the controller's torque disturbance, controllers.impedance), which the law never sees.

(The joints' friction: envs.sim.joint_friction.) The payload errors are written into the environment's model at reset (environments built on one
Scene share them). A changed mass or centre of mass also changes the constants MuJoCo derives from them at compile
time (the bodies' and dofs' inverse weights that scale the constraint solver's regularisation, the subtree masses,
the dofs' M0): without them the contact solver worked with the nominal peg's weights and 10 of 300 episodes of the
realistic task blew up (bad accelerations on the peg's free joint); they are recomputed with ``mj_setConst`` for a
changed payload and restored to the compiled values at the nominal one, so an episode without a payload error is the
same to the last bit.
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np

from envs.errors import EnvError
from envs.sim.sensor_reading import episode_generator
from envs.task.perturbation import Perturbation


MASS_CONSTANTS: tuple[str, ...] = ("body_mass", "body_inertia", "body_ipos", "body_subtreemass", "body_invweight0",
                                    "dof_M0", "dof_invweight0", "cam_poscom0", "light_poscom0")
"""The model's arrays a payload error changes: the masses, the centres of mass and what mj_setConst derives from
them."""


class ModelError:
    """Writes an episode's payload errors into the model (module docstring)."""

    def __init__(self, model: mujoco.MjModel, peg_body: int | None) -> None:
        self.model = model
        self._peg = peg_body
        self.mass_kg = float(model.body_mass[peg_body]) if peg_body is not None else 0.0
        self._compiled = {name: getattr(model, name).copy() for name in MASS_CONSTANTS}
        self._scratch: mujoco.MjData | None = None
        self._payload = (1.0, 0.0, 0.0)  # (mass scale, centre-of-mass shift x, y) now in the model

    def apply(self, perturbation: Perturbation) -> None:
        """Write the episode's payload mass (and inertia) and centre of mass (and the constants derived from them)
        into the model."""
        model = self.model
        payload = ((1.0 + perturbation.payload_mass_error, perturbation.payload_com_x_m, perturbation.payload_com_y_m)
                   if self._peg is not None else (1.0, 0.0, 0.0))
        if payload != self._payload:
            for name, compiled in self._compiled.items():
                getattr(model, name)[:] = compiled
            if payload != (1.0, 0.0, 0.0):
                scale, com_x, com_y = payload
                model.body_mass[self._peg] *= scale
                model.body_inertia[self._peg] *= scale
                model.body_ipos[self._peg, :2] += (com_x, com_y)
                if self._scratch is None:
                    self._scratch = mujoco.MjData(model)
                mujoco.mj_setConst(model, self._scratch)
            self._payload = payload


ACTUATOR_NOISE_SALT: int = 0x70_71_75_65
"""Appended to the episode's seed words, so the torque noise has a generator of its own (the wrist sensor's,
envs.sim.sensor_reading.episode_generator, draws from the same words without it)."""


class ActuatorNoise:
    """The torque noise of an episode's arm (module docstring): drawn per control period, one row per physics step,
    from a generator seeded by the episode's perturbation, and handed to the controller as its torque disturbance.

    Args:
        controller: the episode's CartesianImpedanceController (its `set_torque_disturbance`).
        n_joints, n_substeps: arm joints and physics steps per control period.
    """

    def __init__(self, controller: Any, n_joints: int, n_substeps: int) -> None:
        self.controller = controller
        self._disturb = getattr(controller, "set_torque_disturbance", None)  # the impedance controller's
        self._shape = (max(1, int(n_substeps)), int(n_joints))
        self._sigma = 0.0
        self._rng: np.random.Generator | None = None

    def reset(self, perturbation: Perturbation) -> None:
        """Start an episode: its sigma and generator (none at sigma 0, and no disturbance).

        Raises:
            EnvError: torque noise asked of a controller that has no torque disturbance (only the impedance
                controller has one).
        """
        self._sigma = float(perturbation.actuator_noise_nm)
        self._rng = None
        if self._sigma > 0.0:
            if self._disturb is None:
                raise EnvError(f"actuator_noise_nm={self._sigma:g} needs a controller with a torque disturbance "
                               f"(set_torque_disturbance); {type(self.controller).__name__} has none")
            self._rng = episode_generator(perturbation, ACTUATOR_NOISE_SALT)
        if self._disturb is not None:
            self._disturb(None)

    def start_period(self) -> None:
        """Draw the coming control period's noise (nothing at sigma 0)."""
        if self._rng is not None:  # only with a disturbance to hand it to (`reset`)
            self._disturb(self._rng.standard_normal(self._shape) * self._sigma)
