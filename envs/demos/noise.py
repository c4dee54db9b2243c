"""Imperfect demonstrations: what recordings of a real robot do to the scripted expert's clean demos.

A kinesthetic or teleoperated demonstration on a real cell is not the expert's: it ends where the person's target
was (the part sat elsewhere, the peg sat differently in the hand), its samples come with timing jitter, its last
centimetres before the hole are not a straight line along the hole axis, and its poses carry the sensors' noise.
`add_demo_noise` applies, per demo n with its own generator (seeded by the noise seed and n):

1. Timing jitter: sample k is the pose at t_k + e_k, e_k ~ N(0, sigma_t^2) (clipped to the demo), recorded at its
   nominal time t_k = k dt (`resample_trajectory` between the clean samples).
2. Approach curvature: on the approach, from ``approach_length_m`` + MOUTH_MARGIN_M + the insertion depth to
   MOUTH_MARGIN_M + the insertion depth from the demo's end (distances from the end, so the bow ends 5 mm above the
   hole's mouth: a peg in the hole cannot bow), the path bows sideways, b(u) = a sin(pi u) n, u from 0 to 1 along
   the segment's samples, n a unit vector normal to its chord (random direction).
3. Final-pose scatter: the demo's target (where the part sat, how the peg sat in the hand) moves rigidly, by a
   rotation r_n (rotation vector, world frame) about the demo's end p_N and a translation d_n. The approach and the
   insertion move with it (they were made at that target); the free motion before the approach blends it in with the
   minimum-jerk weight w (0 at the start, 1 where the approach begins):
   p <- p_N + w d_n + R(w r_n) (p - p_N), q <- Exp(w r_n) q. The draws d_n, r_n ~ N(0, I) are scaled so that the
   root-mean-square distance of the ends from their mean is exactly ``final_pos_scatter_m`` (and the angles'
   ``final_rot_scatter_deg``, to first order).
4. Sensor noise: white noise on every sample but the last, N(0, sigma_p^2) per axis on the position and a rotation
   of N(0, sigma_r^2) per axis on the orientation.

The result ends apart (`envs.demos.file.DemoSet.ends_apart`): its goal is the mean of the ends, and each end's distance
from it is recorded. Where the magnitudes come from: docs/results/imperfect-demos.md.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from envs.demos.file import DemoSet
from envs.errors import EnvError
from envs.task.task import check_number
from envs.poses import (make_continuous, mean_quat, minimum_jerk, quat_angle_rad, quat_from_rotvec, quat_mul,
                        resample_trajectory, rotate)
from numerics.small_linalg import dot, norm

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class DemoNoise:
    """How imperfect the demonstrations are (module docstring; every field >= 0, 0 turns that part off).

    Attributes:
        final_pos_scatter_m: root-mean-square distance of the demos' ends from their mean, m.
        final_rot_scatter_deg: root-mean-square angle of the demos' end orientations from their mean, deg.
        timing_jitter_s: standard deviation of each sample's time error, s.
        approach_bow_m: sideways bow of the approach at its middle, m.
        approach_length_m: length of the approach (as distance from the end) that bows, above the mouth, m.
        pos_noise_m: standard deviation of the position noise per axis, m.
        rot_noise_deg: standard deviation of the orientation noise per axis, deg.
    """

    final_pos_scatter_m: float = 0.0
    final_rot_scatter_deg: float = 0.0
    timing_jitter_s: float = 0.0
    approach_bow_m: float = 0.0
    approach_length_m: float = 0.03
    pos_noise_m: float = 0.0
    rot_noise_deg: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            check_number(f"demo noise {f.name}", getattr(self, f.name))
        if not 0.0 < self.approach_length_m <= 0.5:
            raise EnvError(f"demo noise approach_length_m={self.approach_length_m!r} must lie in (0, 0.5] m")
        if self.final_pos_scatter_m > 0.01 or self.final_rot_scatter_deg > 10.0:
            raise EnvError("demo noise: a final-pose scatter above 10 mm or 10 deg is not demos of one hole")

    @classmethod
    def parse(cls, text: str) -> DemoNoise:
        """A preset name and/or FIELD=VALUE pairs, comma-separated: "realistic", "realistic,timing_jitter_s=0",
        "final_pos_scatter_m=0.004,final_rot_scatter_deg=4".

        Raises:
            EnvError: an unknown preset or field, or a value that is not a number >= 0.
        """
        noise = cls()
        names = {f.name for f in fields(cls)}
        for part in (p.strip() for p in str(text).split(",")):
            if not part:
                continue
            if "=" not in part:
                if part not in NOISE_PRESETS:
                    raise EnvError(f"demo noise {part!r}: not a preset ({', '.join(NOISE_PRESETS)}) nor FIELD=VALUE")
                noise = NOISE_PRESETS[part]
                continue
            key, _, value = (s.strip() for s in part.partition("="))
            if key not in names:
                raise EnvError(f"demo noise field {key!r} is unknown; fields: {', '.join(sorted(names))}")
            try:
                number = float(value)
            except ValueError:
                raise EnvError(f"demo noise {key}={value!r} is not a number") from None
            noise = replace(noise, **{key: number})
        return noise

    def to_dict(self) -> dict[str, float]:
        """The settings, JSON-ready."""
        return {k: float(v) for k, v in asdict(self).items()}


NOISE_PRESETS: dict[str, DemoNoise] = {
    "realistic": DemoNoise(final_pos_scatter_m=0.003, final_rot_scatter_deg=3.0, timing_jitter_s=1e-4,
                           approach_bow_m=0.0015, approach_length_m=0.03, pos_noise_m=5e-5, rot_noise_deg=0.05),
}
"""Named settings of `DemoNoise.parse` (the magnitudes' sources: README, "Imperfect demonstrations")."""


def add_demo_noise(demos: DemoSet, noise: DemoNoise, seed: int) -> DemoSet:
    """The demos as a real cell would have recorded them (module docstring), ending apart at their mean goal.

    A recorded stiffness schedule is left out of the result (it was the expert's, for the clean poses).

    Raises:
        EnvError: demos that already end apart.
    """
    if demos.ends_apart:
        raise EnvError("demo noise: these demos already end apart (noise is added once, to clean demos)")
    n, m = demos.num_demos, demos.num_samples
    times = demos.dt * np.arange(m)
    rngs = [np.random.default_rng([seed, k]) for k in range(n)]
    pos = np.array(demos.pos, dtype=np.float64)
    quat = np.array(demos.quat, dtype=np.float64)
    scene = demos.config.get("scene") if isinstance(demos.config.get("scene"), dict) else {}
    mouth = float(scene.get("insertion_depth_m") or 0.0) + MOUTH_MARGIN_M
    segments = [_approach(pos[k], mouth, noise.approach_length_m) for k in range(n)]  # on the clean paths
    if noise.timing_jitter_s > 0:
        for k, rng in enumerate(rngs):
            jittered = np.clip(times + rng.normal(0.0, noise.timing_jitter_s, m), times[0], times[-1])
            jittered[[0, -1]] = times[[0, -1]]
            pos[k], quat[k] = resample_trajectory(times, pos[k], quat[k], jittered)
    if noise.approach_bow_m > 0:
        for k, rng in enumerate(rngs):
            first, last = segments[k]
            if last - first >= 2:
                u = np.linspace(0.0, 1.0, last - first + 1)
                pos[k, first:last + 1] += noise.approach_bow_m * np.sin(np.pi * u)[:, None] * _normal_to(
                    pos[k, last] - pos[k, first], rng)[None]
    shift = _scaled_scatter(np.stack([rng.normal(size=3) for rng in rngs]), noise.final_pos_scatter_m)
    turn = _scaled_scatter(np.stack([rng.normal(size=3) for rng in rngs]), math.radians(noise.final_rot_scatter_deg))
    for k in range(n):
        weight = np.ones(m)
        first = segments[k][0]
        weight[:first + 1] = minimum_jerk(np.linspace(0.0, 1.0, first + 1)) if first > 0 else 1.0
        rotation = quat_from_rotvec(weight[:, None] * turn[k][None])  # (M, 4)
        end = pos[k, -1].copy()
        pos[k] = end + weight[:, None] * shift[k][None] + rotate(rotation, pos[k] - end)
        quat[k] = quat_mul(rotation, quat[k])
    for k, rng in enumerate(rngs):
        if noise.pos_noise_m > 0:
            pos[k, :-1] += rng.normal(0.0, noise.pos_noise_m, (m - 1, 3))
        if noise.rot_noise_deg > 0:
            jitter = rng.normal(0.0, math.radians(noise.rot_noise_deg), (m - 1, 3))
            quat[k, :-1] = quat_mul(quat_from_rotvec(jitter), quat[k, :-1])
    quat /= np.linalg.norm(quat, axis=-1, keepdims=True)
    goal_quat = mean_quat(quat[:, -1])
    quat = np.stack([make_continuous(q, reference=goal_quat) for q in quat])
    goal_pos = np.mean(pos[:, -1], axis=0)
    jump_m = np.linalg.norm(pos[:, -1] - goal_pos, axis=-1)
    jump_deg = np.rad2deg(quat_angle_rad(quat[:, -1], goal_quat))
    config: dict[str, Any] = {**demos.config, "noise": {"settings": noise.to_dict(), "seed": int(seed),
                                                        "end_scatter_rms_mm": float(np.sqrt(np.mean(jump_m**2)) * 1e3),
                                                        "end_scatter_rms_deg": float(np.sqrt(np.mean(jump_deg**2)))},
                              "stiffness_left_out": demos.stiffness is not None,
                              "clean_goal_pos": np.asarray(demos.goal_pos).tolist(),
                              "clean_goal_quat": np.asarray(demos.goal_quat).tolist()}
    return DemoSet(pos=pos, quat=quat, dt=demos.dt, goal_pos=goal_pos, goal_quat=goal_quat, shape=demos.shape,
                   clearance_m=demos.clearance_m, config=config, residual_pos_m=jump_m, residual_rot_deg=jump_deg,
                   ends_apart=True)


MOUTH_MARGIN_M = 0.005
"""The approach's bow ends this far above the hole's mouth (distance from the end: insertion depth + this)."""


def _approach(pos: FloatArray, mouth_m: float, length_m: float) -> tuple[int, int]:
    """(first, last) sample of a clean demo's approach: the first samples within ``mouth_m + length_m`` and within
    ``mouth_m`` of its end (distance from the end; (0, 0) for a demo that starts inside)."""
    distance = np.linalg.norm(pos - pos[-1], axis=1)
    inside = distance <= mouth_m + length_m
    first = int(np.argmax(inside)) if inside.any() else 0
    near = distance <= mouth_m
    last = int(np.argmax(near)) if near.any() else pos.shape[0] - 1
    return first, max(first, last)


def _scaled_scatter(draws: FloatArray, rms: float) -> FloatArray:
    """Draws (N, 3) scaled so that the root-mean-square distance of the rows from their mean is ``rms`` (zero rows
    when rms is 0 or the draws coincide)."""
    spread = math.sqrt(float(np.mean(np.sum((draws - draws.mean(axis=0)) ** 2, axis=1))))
    if rms == 0.0 or spread == 0.0:
        return np.zeros_like(draws)
    return draws * (rms / spread)


def _normal_to(direction: FloatArray, rng: np.random.Generator) -> FloatArray:
    """A unit vector normal to ``direction``, in a random direction about it (any unit vector for a zero one)."""
    d = np.asarray(direction, dtype=np.float64)
    length = norm(d)
    v = rng.normal(size=3)
    if length > 0.0:
        v -= dot(v, d) / length**2 * d
    return v / norm(v)
