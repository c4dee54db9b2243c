"""What the episode stepping (envs.sim.env.PegInHoleEnv) needs of a controller: the `Controller` protocol.

A controller is bound to one MuJoCo model (it knows the arm's joints and the site it controls) and owns what happens
between a policy's `Action` (controllers.action) and the arm: it turns the action into the command it holds for the
period, and it runs the physics steps of the period, calling the environment's sensing hook after every physics step.
Per episode:

    start(data)                           once the start state is in ``data`` (after mj_forward), before any step
    settled()                             once the arm has held its start pose at rest (the grasp settled)
    set_tool_load(mass_kg, depth_m)       the grasped peg, a known tool load (once, when the scene has one)
    command(data, action, gain)           per period: the action's target pose and stiffness (e.g. with a lead)
    checked_stiffness(stiffness)          per commanded stiffness, before the period: a bad one is the caller's error
    step(data, pos, quat, stiffness, q_nullspace, n_substeps, after_substep=hook) -> physics steps taken

``q_nullspace`` is the environment's joint reference for the commanded pose (controllers.ik.NullspaceReference: a
few IK iterations per period), which a redundant arm uses for its posture and a joint-space controller may track.
A ``step`` that cannot control the arm raises ControllerError (numpy's LinAlgError and FloatingPointError are
accepted too): the environment records it as an instability and ends the episode, it does not raise.

`controllers.impedance.CartesianImpedanceController` is the one the environment builds by default; its ``command``
adds the velocity feed-forward lead (controllers.feedforward) that only a controller can compute, from its own gains
and the arm's inertia at the simulator's state.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Callable, Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

from controllers.action import Action
from numerics.pose import Pose

if TYPE_CHECKING:
    import mujoco

FloatArray = npt.NDArray[np.float64]


@runtime_checkable
class Controller(Protocol):
    """A controller that runs the physics steps of one control period toward a commanded tcp pose (module
    docstring)."""

    def start(self, data: mujoco.MjData) -> None:
        """Take up the episode's start state in ``data`` (positions set, mj_forward done, velocities zero).

        Raises:
            ControllerError: a state it cannot start from.
        """

    def settled(self) -> None:
        """The arm has held its start pose at rest in free space since `start` (the episode's grasp settled; possibly
        for no time at all): calibrate what needs it, e.g. tare joint torque sensors. Called once per episode, before
        its first control period."""

    def set_tool_load(self, mass_kg: float, depth_m: float) -> None:
        """Compensate a carried tool of ``mass_kg`` whose centre of mass is ``depth_m`` below the controlled site
        along its z axis (0 kg: none).

        Raises:
            ControllerError: a negative or non-finite mass or depth.
        """

    def command(self, data: mujoco.MjData, action: Action,
                feedforward_gain: float = 1.0) -> tuple[Pose, FloatArray | None]:
        """The target pose and the 6x6 Cartesian stiffness (N/m, N m/rad, world frame; None: the controller's
        default) to hold for one control period of ``action``, at the state of ``data`` (the period's start): the
        action's pose, or with a ``twist`` and a gain > 0 what the controller commands to move at that twist (e.g.
        the pose led by its feed-forward, scaled by ``feedforward_gain``). The stiffness is checked afterwards by
        `checked_stiffness`.

        Raises:
            ControllerError: an action it cannot command (a malformed stiffness, twist, acceleration, push or anchor),
                or a state it cannot compute the command at.
        """

    def checked_stiffness(self, stiffness: npt.ArrayLike | None) -> FloatArray | None:
        """The commanded 6x6 Cartesian stiffness (N/m, N m/rad, world frame) as ``step`` takes it, checked; None
        asks for the controller's default.

        Raises:
            ControllerError: a stiffness it cannot command (the environment raises EnvError "bad stiffness").
        """

    def step(self, data: mujoco.MjData, target_pos: npt.ArrayLike, target_quat: npt.ArrayLike,
             stiffness: npt.ArrayLike | None, q_nullspace: npt.ArrayLike | None, n_substeps: int, *,
             after_substep: Callable[[], bool] | None = None) -> int:
        """Advance ``data`` by ``n_substeps`` physics steps toward the target pose (m; unit quaternion w, x, y, z)
        under the commanded stiffness, calling ``after_substep()`` after every physics step and stopping early
        when it returns True.

        Returns:
            The number of physics steps taken.

        Raises:
            ControllerError: when it cannot control the arm (the episode ends as an instability).
        """
