"""The rigid pose as a value: a position and a unit quaternion (w, x, y, z), MuJoCo's order.

One type for every layer: the controllers' command (`controllers.action.Action`), the simulator's observations and a
policy's actions (`envs.poses` re-exports it with the pose checks and start sampling built on it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Pose:
    """A rigid pose: ``pos`` (3,) in metres and ``quat`` (4,) unit quaternion (w, x, y, z)."""

    pos: FloatArray
    quat: FloatArray
