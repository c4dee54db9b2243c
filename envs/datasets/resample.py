"""Per-step signals resampled onto the frame grid of a dataset: t_j = j / fps for j = 0 .. floor(T fps), an integer
frame rate the user picks (LeRobot's tooling assumes integer fps), from signals sampled every ``dt`` seconds from 0.

Two ways, by what a signal is:

- a measurement (a pose, joints, a wrench) is interpolated between its two neighbouring samples: linearly, a
  quaternion by slerp (the samples made sign-continuous first);
- a command (an action, a success flag) is held: frame j takes the latest sample at or before t_j, as the controller
  held each command for its period.

A frame time within SNAP of a sample time takes that sample as it is, so a grid that meets the samples (fps dividing
the sampling rate, e.g. 100, 50 or 20 frames per second of a 100 Hz recording) copies them bit for bit.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from envs.errors import EnvError
from envs.poses import make_continuous
from numerics.quaternion import slerp

FloatArray = npt.NDArray[np.float64]

SNAP: float = 1e-9
"""A frame time this close to a sample time (in sample periods) is that sample."""
MAX_FPS: int = 1000
"""The highest frame rate an export writes (10x the control rate)."""


def frame_times(duration_s: float, fps: int) -> FloatArray:
    """The frame grid j / fps, j = 0 .. floor(duration fps), of a signal lasting ``duration_s`` seconds.

    Raises:
        EnvError: a frame rate that is not an integer in 1 .. MAX_FPS, or a negative duration.
    """
    if isinstance(fps, bool) or not isinstance(fps, (int, np.integer)) or not 1 <= fps <= MAX_FPS:
        raise EnvError(f"fps={fps!r} must be an integer number of frames per second in 1..{MAX_FPS}")
    if not (math.isfinite(duration_s) and duration_s >= 0.0):
        raise EnvError(f"a signal of {duration_s!r} s cannot be resampled")
    count = int(math.floor(duration_s * fps + SNAP)) + 1
    return np.arange(count, dtype=np.float64) / fps


def _positions(times: FloatArray, dt: float, samples: int) -> tuple[npt.NDArray[np.int64], FloatArray]:
    """(index k, weight w) of each time: between samples k and k + 1 at w in [0, 1), w = 0 exactly on a sample."""
    u = np.clip(times / dt, 0.0, samples - 1)
    nearest = np.rint(u)
    on_sample = np.abs(u - nearest) <= SNAP
    index = np.where(on_sample, nearest, np.floor(u)).astype(np.int64)
    weight = np.where(on_sample, 0.0, u - index)
    index = np.minimum(index, samples - 1)
    return index, weight


def interpolated(values: npt.ArrayLike, dt: float, times: FloatArray) -> FloatArray:
    """A measurement (K, ...) sampled every ``dt`` s at ``times``: linear between neighbours (module docstring)."""
    x = np.asarray(values, dtype=np.float64)
    index, weight = _positions(times, dt, x.shape[0])
    upper = np.minimum(index + 1, x.shape[0] - 1)
    w = weight.reshape((-1,) + (1,) * (x.ndim - 1))
    out = x[index] + w * (x[upper] - x[index])
    exact = weight == 0.0
    out[exact] = x[index[exact]]
    return out


def held(values: npt.ArrayLike, dt: float, times: FloatArray) -> np.ndarray:
    """A command (K, ...) sampled every ``dt`` s at ``times``: the latest sample at or before each time."""
    x = np.asarray(values)
    index, _ = _positions(times, dt, x.shape[0])
    return x[index].copy()


def interpolated_pose(pose: npt.ArrayLike, dt: float, times: FloatArray) -> FloatArray:
    """Poses (K, 7) [x, y, z, qw, qx, qy, qz] at ``times``: positions linearly, orientations by slerp.

    Raises:
        EnvError: poses that are not (K, 7) with K >= 1.
    """
    p = np.asarray(pose, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 7 or p.shape[0] < 1:
        raise EnvError(f"poses to resample must have shape (K, 7), got {p.shape}")
    quat = make_continuous(p[:, 3:])
    index, weight = _positions(times, dt, p.shape[0])
    upper = np.minimum(index + 1, p.shape[0] - 1)
    out = np.empty((len(times), 7))
    out[:, :3] = interpolated(p[:, :3], dt, times)
    between = weight > 0.0
    out[:, 3:] = quat[index]
    if np.any(between):
        out[between, 3:] = slerp(quat[index[between]], quat[upper[between]], weight[between])
    return out
