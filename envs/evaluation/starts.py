"""Where an evaluation's episodes start: perturbed start poses around the demos' starts, and each episode's
perturbation.

A centre pose is perturbed: position + d, d uniform in the box [-pos_range_m, pos_range_m]^3; orientation exp(r) * q,
r a rotation vector (world frame) uniform in the ball of radius rot_range_deg (envs.poses.sample_start_poses). The
centre (``around``) is the mean of the demos' start poses ("mean", default: arithmetic mean position,
normalised-sum quaternion) or, per episode, the start of a demo drawn uniformly ("demo": harder, it reaches up to
15 deg past the demos' own orientation range). The ranges and the centre are the task's (envs.task.task.StartRange;
defaults +-5 cm, +-15 deg). All starts come from one generator seeded with ``seed``, drawn before any episode runs,
so the result does not depend on the number of workers.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from envs.errors import EnvError
from envs.evaluation.config import EvaluationConfig
from envs.poses import Pose, StartRegion, mean_quat, sample_start_poses
from envs.rollout.episode import StartPose
from envs.task.perturbation import PerturbationRanges, sample_perturbation
from envs.task.task import StartRange
from numerics.errors import shown
from numerics.small_linalg import norm


def sample_starts(demo_start_pos: npt.ArrayLike, demo_start_quat: npt.ArrayLike, num: int, seed: int,
                  pos_range_m: float, rot_range_deg: float, around: str = "mean",
                  perturbations: PerturbationRanges = PerturbationRanges()) -> list[StartPose]:
    """Perturbed start poses around the demos' starts (module docstring).

    Args:
        demo_start_pos: (N, 3) demo start positions.
        demo_start_quat: (N, 4) demo start orientations.
        num: number of starts.
        seed: generator seed.
        pos_range_m, rot_range_deg: perturbation box half-width and ball radius.
        around: "mean" (the mean demo start; demo_index -1) or "demo" (a random demo's start).
        perturbations: ranges of each episode's hole-pose error and grasp offset, drawn from a second
            generator seeded with (seed, 1) so that the start poses do not depend on them.

    Raises:
        EnvError: malformed demo starts, or ranges or a centre that envs.task.task.StartRange refuses.
    """
    StartRange(pos_range_m, rot_range_deg, around)
    p = np.asarray(demo_start_pos, dtype=np.float64)
    q = np.asarray(demo_start_quat, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or q.shape != (p.shape[0], 4) or p.shape[0] < 1:
        raise EnvError(f"demo starts must be pos (N, 3) and quat (N, 4), got {p.shape} and {q.shape}")
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(q))):
        raise EnvError("demo start poses contain NaN or inf")
    region = StartRegion(pos_half_width_m=(pos_range_m,) * 3, max_angle_deg=rot_range_deg)
    rng = np.random.default_rng(seed)
    mean = Pose(pos=p.mean(axis=0), quat=mean_quat(q))
    starts = []
    for k, perturbation in enumerate(seeded_perturbations(perturbations, seed, num)):
        n = int(rng.integers(p.shape[0])) if around == "demo" else -1
        centre = Pose(pos=p[n], quat=q[n] / norm(q[n])) if n >= 0 else mean
        starts.append(StartPose(k, n, sample_start_poses(centre, region, rng, 1)[0], perturbation))
    return starts


def seeded_perturbations(perturbations: PerturbationRanges, seed: int, num: int) -> list[Any]:
    """The perturbations of episodes 0..num-1 of an evaluation with ``seed``: drawn in order from a generator seeded
    with (seed, 1), apart from the start poses (what `sample_starts` gives each episode; needs no demo starts)."""
    task_rng = np.random.default_rng([seed, 1])
    return [sample_perturbation(perturbations, task_rng) for _ in range(num)]


def evaluation_starts(demo_starts: dict[str, Any], config: EvaluationConfig) -> list[StartPose]:
    """The ``config.episodes`` starts (and perturbations) of an evaluation around the demos' starts
    ({"pos": (N, 3), "quat": (N, 4)}, the checkpoint's metadata "demo_starts").

    Raises:
        EnvError: malformed demo starts.
    """
    start = config.task.start
    return sample_starts(demo_starts["pos"], demo_starts["quat"], config.episodes, config.seed, start.pos_range_m,
                         start.rot_range_deg, start.around, config.task.perturbations)


def metadata_starts(metadata: dict[str, Any], source: str) -> dict[str, Any]:
    """The demos' start poses of a checkpoint's (or demo file's) metadata, {"pos": (N, 3), "quat": (N, 4)} as
    float arrays, every field checked.

    Raises:
        EnvError: naming ``source`` and the field when there are none, or when one is not finite numbers of its
            shape (a hand-edited file).
    """
    meta_starts = metadata.get("demo_starts") if isinstance(metadata, dict) else None
    if meta_starts is None:
        raise EnvError(f"{source} has no demo start poses (metadata 'demo_starts')")
    if not isinstance(meta_starts, dict) or "pos" not in meta_starts or "quat" not in meta_starts:
        raise EnvError(f"{source}: metadata 'demo_starts' must be an object with 'pos' and 'quat', got "
                       f"{shown(meta_starts)}")
    arrays = {}
    for key, width in (("pos", 3), ("quat", 4)):
        value = meta_starts[key]
        try:
            array = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            array = np.zeros(0)
        if array.ndim != 2 or array.shape[0] < 1 or array.shape[1] != width or not np.all(np.isfinite(array)):
            raise EnvError(f"{source}: metadata 'demo_starts.{key}' must be finite numbers of shape (N, {width}), got "
                           f"{shown(value)}")
        arrays[key] = array
    if arrays["pos"].shape[0] != arrays["quat"].shape[0]:
        raise EnvError(f"{source}: metadata 'demo_starts' holds {arrays['pos'].shape[0]} positions and "
                       f"{arrays['quat'].shape[0]} orientations")
    return arrays
