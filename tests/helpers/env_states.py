"""States of the peg-in-hole environment for kernel tests: episodes moved by small random commands."""

from __future__ import annotations

from typing import Iterator

import numpy as np

from envs.poses import Pose
from envs.sim.env import PegInHoleEnv


def wandering_states(env: PegInHoleEnv, rng: np.random.Generator, episodes: int, periods: int,
                     step_m: float) -> Iterator[tuple[int, int]]:
    """Yield (episode, period) at each state of ``episodes`` episodes (reset with seed = episode) of up to
    ``periods`` control periods, each period commanding the measured tcp moved by N(0, ``step_m``) per axis; an
    episode that ends stops early."""
    for episode in range(episodes):
        env.reset(seed=episode)
        for period in range(periods):
            yield episode, period
            tcp = env.observation.tcp
            env.step(Pose(tcp.pos + rng.normal(0.0, step_m, 3), tcp.quat))
            if env.done:
                break
