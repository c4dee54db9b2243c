"""The command of one control period, as a policy gives it and a controller takes it: the `Action`.

An `Action` is the commanded tcp pose, optionally a stiffness (6x6, or a translational 3x3 with an optional
rotational scalar) and optionally the motion the controller leads the pose by: with a ``twist`` xi (and ``accel``) the
controller commands ``anchor`` led by K^-1 (D(q) xi + Lambda(q) xi') + ``push`` (controllers.feedforward), so a
compliant arm moves at the intended velocity instead of lagging behind it. The controller turns it into the pose and
stiffness it holds for the period (`controllers.interface.Controller.command`); a policy only says how it wants to
move, never computes the lead, which needs the simulator's state (the arm's inertia at q).

It lives here, below the policies (envs.policies.interface re-exports it) and beside the controllers that read it,
so both import it downward.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from numerics.pose import Pose

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Action:
    """One control period's command (module docstring). Only ``pose`` is required.

    Attributes:
        pose: the commanded tcp pose (world frame); with a ``twist`` the lead is added to ``anchor`` instead.
        stiffness: None (the controller's default), a (3, 3) translational stiffness (N/m, world frame, SPD) or the
            full (6, 6) Cartesian stiffness [[K_t, 0], [0, K_r]] (N/m, N m/rad).
        rotational_stiffness: with a (3, 3) or no ``stiffness``: the rotational stiffness k_r (N m/rad, K_r = k_r I);
            None: the controller's default. Must be None with a (6, 6) stiffness.
        twist: (6,) [v m/s; omega rad/s] world frame, the velocity to move with (velocity feed-forward); None: none.
        accel: (6,) [m/s^2; rad/s^2] the acceleration there (inertia feed-forward); None: zero.
        anchor: the pose the feed-forward lead is added to (e.g. the measured pose); None: ``pose``.
        push: (6,) [m; rad] world-frame offset added to the led anchor (e.g. an integral push into the hole); None: zero.
    """

    pose: Pose
    stiffness: FloatArray | None = None
    rotational_stiffness: float | None = None
    twist: FloatArray | None = None
    accel: FloatArray | None = None
    anchor: Pose | None = None
    push: FloatArray | None = None
