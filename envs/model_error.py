"""An episode's errors of the arm's model: what the simulated cell has and the controller does not know.

- Payload: the simulated peg's mass and rotational inertia are scaled by (1 + e) (envs.perturbation), while the
  controller's tool load (controllers.impedance: the weight it compensates) and the wrist sensor's zeroing
  (envs.sensing.ToolLoad) keep the nominal mass they were given when the environment was built. A heavier peg
  sags by e m g / K_z under a translational stiffness K_z and shows as e m g on the zeroed sensor.
- Joint friction: each arm joint gets Coulomb friction with stiction of f N m (MuJoCo's dof frictionloss: a joint
  stays at rest until its torque exceeds f, then slides against f), which the impedance law does not compensate;
  a compliant arm stops short of its target by up to about J^-T f / K.

Both are written into the environment's model at reset (environments built on one Scene share them).
"""

from __future__ import annotations

import mujoco
import numpy as np

from envs.perturbation import Perturbation


class ModelError:
    """Writes an episode's payload and joint-friction errors into the model (module docstring)."""

    def __init__(self, model: mujoco.MjModel, peg_body: int | None, arm_dofs: tuple[int, ...]) -> None:
        self.model = model
        self._peg = peg_body
        self._dofs = np.asarray(arm_dofs, dtype=np.int64)
        self.mass_kg = float(model.body_mass[peg_body]) if peg_body is not None else 0.0
        self.inertia = model.body_inertia[peg_body].copy() if peg_body is not None else np.zeros(3)
        self.frictionloss = model.dof_frictionloss[self._dofs].copy()

    def apply(self, perturbation: Perturbation) -> None:
        """Write the episode's payload mass (and inertia) and arm joint friction into the model."""
        model = self.model
        if self._peg is not None:
            scale = 1.0 + perturbation.payload_mass_error
            model.body_mass[self._peg] = self.mass_kg * scale if scale != 1.0 else self.mass_kg
            model.body_inertia[self._peg] = self.inertia * scale if scale != 1.0 else self.inertia
        friction = perturbation.joint_friction_nm
        model.dof_frictionloss[self._dofs] = friction if friction > 0.0 else self.frictionloss
