"""An episode's sliding friction: the peg against the sorter and against the finger pads, written into the model.

MuJoCo gives a contact the parameters of its higher-priority geom (equal priorities: the larger friction of the
two). The sorter's and the pads' geoms have priority 1 over the peg's 0 (envs.cell.sorter, envs.cell.scene), so a
peg-sorter contact slides with the sorter's mu and a peg-pad contact with the pad's, and an episode's mu_hole and mu_pad
(envs.task.perturbation; 0: the scene's) are set on those geoms alone. At the scene's values the contacts are those of
max-mixing, so episodes without a friction range are unchanged.

The model is the environment's: environments built on one Scene share its frictions, so they must not step
episodes of different frictions side by side.
"""

from __future__ import annotations

import mujoco
import numpy as np

from envs.errors import EnvError
from envs.task.perturbation import Perturbation


class EpisodeFriction:
    """Sets the sliding friction of the sorter's and the pads' geoms for an episode (module docstring)."""

    def __init__(self, model: mujoco.MjModel, sorter_geoms: tuple[int, ...], pad_geoms: tuple[int, ...],
                 peg_geoms: tuple[int, ...]) -> None:
        """Raises:
            EnvError: a sorter or pad geom whose priority is not above every peg geom's (its friction would not
                be the contact's).
        """
        peg = int(model.geom_priority[list(peg_geoms)].max())
        for name, geoms in (("sorter", sorter_geoms), ("pad", pad_geoms)):
            if geoms and int(model.geom_priority[list(geoms)].min()) <= peg:
                raise EnvError(f"the {name} geoms need a priority above the peg's ({peg}) to set its friction")
        self.model = model
        self._sorter = np.asarray(sorter_geoms, dtype=np.int64)
        self._pads = np.asarray(pad_geoms, dtype=np.int64)
        self.scene_hole = model.geom_friction[self._sorter, 0].copy()
        self.scene_pad = model.geom_friction[self._pads, 0].copy()

    def apply(self, perturbation: Perturbation) -> None:
        """Write the episode's mu_hole and mu_pad (the scene's where 0) into the model."""
        friction = self.model.geom_friction
        friction[self._sorter, 0] = perturbation.hole_friction if perturbation.hole_friction > 0 else self.scene_hole
        friction[self._pads, 0] = perturbation.pad_friction if perturbation.pad_friction > 0 else self.scene_pad
