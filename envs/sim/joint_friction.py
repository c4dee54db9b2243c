"""The arm joints' transmission friction in the imperfect cell: the Panda's friction as identified on a real robot,
scaled per episode, as stick-slip or as the identified smooth law.

Source. Gaz, Cognetti, Oliva, Robuffo Giordano, De Luca, "Dynamic identification of the Franka Emika Panda robot
with retrieval of feasible parameters using penalty-based optimization", IEEE RA-L 4(4), 2019, supplementary material
(github.com/marcocognetti/FrankaEmikaPandaDynModel, pdf/): identified from the robot's link-side joint torques while it
followed exciting trajectories under the FCI, i.e. the friction the robot's own compensation leaves.

- Stick-slip (``joint_friction_model = "stick_slip"``): the linear model of their Table III (classical identification,
  column pi_CLS), tau_f = f_v qdot + f_c sign(qdot) + f_o, without the offset f_o (a constant torque the tare of the
  joint torque sensors absorbs). f_c is written as MuJoCo's dof frictionloss, which holds a joint at rest until its
  torque exceeds f_c (stiction: the identification cannot tell stiction from f_c at qdot = 0, so holding at rest is an
  assumption) and slides against f_c; f_v adds to the model's joint damping.
- Smooth (``"smooth"``): their Table I, the sigmoid tau_f(qdot) = phi_1 / (1 + exp(-phi_2 (qdot + phi_3))) - phi_1 /
  (1 + exp(-phi_2 phi_3)) per joint, zero at rest and smooth through it (0.007-0.019 N m at 0.01 rad/s): delivered
  by the actuator model (controllers.joint_torque_kernel.smooth_friction, the controller's transmission friction).

Both are scaled by the episode's s (envs.task.perturbation: ``joint_friction_scale``; phi_1 for the smooth law), which
the controller does not know. The friction sits between the motor and the link-side joint torque sensor (the
joints' harmonic drives), so those sensors read the torque after it (controllers.joint_torque_kernel, eq. 1).
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np
import numpy.typing as npt

from envs.errors import EnvError
from envs.task.perturbation import JOINT_FRICTION_MODELS, Perturbation

FloatArray = npt.NDArray[np.float64]

PANDA_COULOMB_NM: tuple[float, ...] = (0.2450, 0.1523, 0.1827, 0.3591, 0.2669, 0.1658, 0.2109)
"""f_c per joint, N m (Gaz et al. 2019, supplementary Table III, pi_CLS)."""
PANDA_VISCOUS_NM_S: tuple[float, ...] = (0.0665, 0.1987, 0.0399, 0.2257, 0.1023, 0.0, 0.0638)
"""f_v per joint, N m s/rad (the same column; joint 6's identified -0.0132, a negative damping within its 12 %
standard deviation of nothing, is taken as 0)."""
PANDA_SIGMOID: tuple[tuple[float, float, float], ...] = (
    (0.54615, 5.1181, 0.039533), (0.87224, 9.0657, 0.025882), (0.64068, 10.136, -0.04607),
    (1.2794, 5.5903, 0.036194), (0.83904, 8.3469, 0.026226), (0.30301, 17.133, -0.021047),
    (0.56489, 10.336, 0.0035526))
"""(phi_1 N m, phi_2 s/rad, phi_3 rad/s) per joint (Gaz et al. 2019, supplementary Table I)."""


class JointFriction:
    """Writes an episode's joint friction into the model (stick-slip) or the controller's actuator model (smooth).

    Args:
        model: the environment's MjModel (its arm dofs' frictionloss and damping are written).
        arm_dofs: the 7 arm dofs, in joint order.
        controller: the episode's controller; the smooth law needs its `set_transmission_friction` (the impedance
            controller's).
        law: one of `JOINT_FRICTION_MODELS`.

    Raises:
        EnvError: an unknown law, or an arm that is not the Panda's 7 joints.
    """

    def __init__(self, model: mujoco.MjModel, arm_dofs: tuple[int, ...], controller: Any, law: str) -> None:
        if law not in JOINT_FRICTION_MODELS:
            raise EnvError(f"joint friction model {law!r} must be one of {', '.join(JOINT_FRICTION_MODELS)}")
        if len(arm_dofs) != len(PANDA_COULOMB_NM):
            raise EnvError(f"the identified joint friction is the Panda's 7 joints, not {len(arm_dofs)}")
        self.model = model
        self.law = law
        self._dofs = np.asarray(arm_dofs, dtype=np.int64)
        self._frictionloss = model.dof_frictionloss[self._dofs].copy()
        self._damping = model.dof_damping[self._dofs].copy()
        self._transmission = getattr(controller, "set_transmission_friction", None)
        self._controller = controller

    def apply(self, perturbation: Perturbation) -> None:
        """Write the episode's scale s: stick-slip, frictionloss s f_c and damping + s f_v (the model's own at s = 0);
        smooth, the controller's transmission friction with s phi_1 (none at s = 0).

        Raises:
            EnvError: a smooth law asked of a controller without transmission friction.
        """
        s = float(perturbation.joint_friction_scale)
        model = self.model
        stick_slip = self.law == "stick_slip" and s > 0.0
        model.dof_frictionloss[self._dofs] = s * np.asarray(PANDA_COULOMB_NM) if stick_slip else self._frictionloss
        model.dof_damping[self._dofs] = (self._damping + s * np.asarray(PANDA_VISCOUS_NM_S) if stick_slip
                                         else self._damping)
        if self.law == "smooth" and s > 0.0:
            if self._transmission is None:
                raise EnvError(f"the smooth joint friction needs a controller with transmission friction "
                               f"(set_transmission_friction); {type(self._controller).__name__} has none")
            self._transmission(smooth_parameters(s))
        elif self._transmission is not None:
            self._transmission(None)


def smooth_parameters(scale: float) -> FloatArray:
    """The smooth law's rows [s phi_1, phi_2, phi_3] per joint (7, 3)."""
    phi = np.array(PANDA_SIGMOID, dtype=np.float64)
    phi[:, 0] *= scale
    return phi


__all__ = ["JointFriction", "PANDA_COULOMB_NM", "PANDA_SIGMOID", "PANDA_VISCOUS_NM_S", "smooth_parameters"]
