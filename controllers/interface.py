"""What the episode stepping (envs.sim.env.PegInHoleEnv) needs of a controller: the `Controller` protocol.

A controller is bound to one MuJoCo model (it knows the arm's joints and the site it controls) and owns the
physics steps of a control period: the environment hands it the command of the period and the simulator state, and
the controller steps the physics, calling the environment's sensing hook after every physics step. Per episode:

    start(data)                           once the start state is in ``data`` (after mj_forward), before any step
    set_tool_load(mass_kg, depth_m)       the grasped peg, a known tool load (once, when the scene has one)
    checked_stiffness(stiffness)          per commanded stiffness, before the period: a bad one is the caller's error
    step(data, pos, quat, stiffness, q_nullspace, n_substeps, after_substep=hook) -> physics steps taken

``q_nullspace`` is the environment's joint reference for the commanded pose (controllers.ik.NullspaceReference: a
few IK iterations per period), which a redundant arm uses for its posture and a joint-space controller may track.
A ``step`` that cannot control the arm raises ControllerError (numpy's LinAlgError and FloatingPointError are
accepted too): the environment records it as an instability and ends the episode, it does not raise.

`controllers.impedance.CartesianImpedanceController` is the one the environment builds by default. Skill execution
reads more of it than this protocol (its gains for the default stiffness, `pose_lead` for the feed-forward,
envs.policies.feedforward), so evaluating a policy needs that controller; the environment itself needs only this.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Callable, Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

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
