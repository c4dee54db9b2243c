"""Synthetic evaluation records (the JSON of `pih evaluate --json`, no physics) for the comparison tests."""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from envs.rollout.episode import EpisodeRecord
from envs.evaluation.starts import seeded_perturbations
from envs.task.perturbation import PerturbationRanges

TIME_LIMIT_S = 20.0
TARGET_DEPTH_M = 0.03


def synthetic_evaluation(successes: Sequence[bool], seed: int = 0, time_limit_s: float = TIME_LIMIT_S) -> dict[str, Any]:
    """An evaluation dict of len(successes) episodes from seeded starts and hole-pose errors (drawn as an evaluation
    with ``seed`` on the default task draws them, envs.evaluation.starts.seeded_perturbations): a success is seated
    (30 mm deep, 2-4 s, 20 N held), a failure stalls 25 mm deep at the time limit with 35 N held."""
    rng, outcome_rng = np.random.default_rng(seed), np.random.default_rng([seed, 2])
    ranges = PerturbationRanges(hole_error_m=0.001, hole_error_deg=1.0)
    perturbations = seeded_perturbations(ranges, seed, len(successes))
    records = []
    for i, ok in enumerate(successes):
        quat = rng.normal(size=4)
        records.append(EpisodeRecord(
            i, -1, rng.uniform(-0.05, 0.05, 3).tolist(), (quat / np.linalg.norm(quat)).tolist(), success=bool(ok),
            reason="success" if ok else "time_limit (stalled)",
            perturbation=perturbations[i].to_dict(),
            time_to_insert_s=float(outcome_rng.uniform(2.0, 4.0)) if ok else None,
            insertion_depth_mm=30.0 if ok else 25.0, peak_sustained_wrist_force_n=20.0 if ok else 35.0).to_dict())
    return {"config": {"time_limit_s": time_limit_s, "seed": seed}, "scene": {"insertion_depth_m": TARGET_DEPTH_M},
            "episodes": len(records), "per_episode": records}
