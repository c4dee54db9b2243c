"""Flow timings for `pih bench` (extension point ``BENCHMARKS`` of scripts/bench.py). Never imports MuJoCo.

One benchmark, "flow": a pose skill (position on R^3 + orientation on S^3, the paper's architecture:
11 coupling layers, ReLU, Adam, lr 1e-3, batch 128) trained on 7 synthetic minimum-jerk demos of 400
samples, then the medians of
  - train_epoch_s: one epoch per model (4000 transitions), and train_s: the whole default training of both
    models (``epochs`` epochs each; the paper: 61 min per shape on an RTX 2060, 100 epochs);
  - flow_step_ms: one step of one model: state through the inverse flow, one exact latent step, back
    through the flow (rflow.generate.next_point);
  - closed_loop_step_ms: the flow work of one closed-loop control step (envs.policies.flow_skill.ClosedLoopPolicy: two
    lookahead steps x -> x_1 -> x_2 of both models, for the twist and acceleration), done every 10 ms;
  - rollout_1000_ms: one 1000-step rollout of the position model; rollouts_100x1000_ms: 100 at once
    (the paper: 20 s per 1000 samples, about 50 Hz).

A second benchmark, "training": the default skill's training (`pih train`: both models at once in two processes,
`rflow.fit_processes`, the skill's log-scale bound and off-data prior) on the same synthetic demos with the paper's
schedule (`PAPER_SCHEDULE`: batch 128, lr 1e-3, 80 epochs; "former" in the output) and the skill's default one
(`SKILL_SCHEDULE`; "current"), timed alternately in this run (wall seconds of `fit_pose_skill`, process start-up
included), medians and their ratio. Both run on the same code, so the ratio is that of the schedules alone.
"""

from __future__ import annotations

import time
from typing import Any, Callable

import numpy as np

BENCH_EPOCHS_QUICK = 2
BENCH_EPOCHS_FULL = 10
TRAINING_REPEATS_FULL = 3
"""Alternating (former, current) pairs of the "training" benchmark; --quick runs one pair of shortened trainings."""
TRAINING_QUICK_EPOCH_FRACTION = 0.05
"""--quick trains this fraction of each schedule's epochs (at least one): a smoke test, its ratio is mostly start-up."""
SKILL_LOG_SCALE_CLAMP = 0.5
SKILL_PRIOR_WEIGHT = 0.3
"""The skill's model settings (scripts/train.py DEFAULT_LOG_SCALE_CLAMP, DEFAULT_PRIOR_WEIGHT; rflow does not import
scripts, tests/rflow/test_bench.py checks they agree)."""


def synthetic_pose_demos(n: int = 7, m: int = 400, seed: int = 0) -> tuple[np.ndarray, np.ndarray, float]:
    """N minimum-jerk pose demos (pos (N, M, 3), quat (N, M, 4)) ending at one goal, and dt (7 s demos)."""
    from rflow.manifolds import get_manifold

    rng = np.random.default_rng(seed)
    tau = np.linspace(0.0, 1.0, m)
    s = tau**3 * (10 - 15 * tau + 6 * tau**2)
    goal_p = np.array([0.675, -0.051, 0.203])
    goal_q = np.array([0.0, 0.99213864, -0.12514362, 0.0])
    goal_q /= np.linalg.norm(goal_q)
    sphere = get_manifold("sphere")
    pos = np.empty((n, m, 3))
    quat = np.empty((n, m, 4))
    for i in range(n):
        start = goal_p + rng.uniform([-0.15, -0.1, 0.15], [0.0, 0.1, 0.25])
        pos[i] = start + s[:, None] * (goal_p - start)
        v0 = rng.uniform(-0.15, 0.15, 3)
        quat[i] = np.asarray(sphere.exp((1.0 - s)[:, None] * v0, goal_q))
    pos[:, -1] = goal_p
    quat[:, -1] = goal_q
    return pos, quat, 7.0 / (m - 1)


def _median_ms(fn: Callable[[], Any], repeats: int) -> float:
    fn()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return 1e3 * float(np.median(times))


def bench_flow(quick: bool) -> dict[str, Any]:
    """Training and generation timings of a pose skill (module docstring)."""
    import torch

    from rflow.generate import next_point, rollout
    from rflow.skill_io import fit_pose_skill
    from rflow.train import TrainConfig

    torch.set_num_threads(1)
    pos, quat, dt = synthetic_pose_demos()
    epochs = BENCH_EPOCHS_QUICK if quick else BENCH_EPOCHS_FULL
    default_epochs = TrainConfig().epochs
    config = TrainConfig(epochs=epochs, threads=1)
    start = time.perf_counter()
    skill = fit_pose_skill(pos, quat, dt, config, progress=False)
    train_s = time.perf_counter() - start
    epoch_s = train_s / (2 * epochs)
    position, orientation = skill.models["position"], skill.models["orientation"]
    p0, q0 = pos[0, 0], quat[0, 0]
    starts = pos[:, 0][np.arange(100) % pos.shape[0]] + np.random.default_rng(1).normal(0, 0.01, (100, 3))
    repeats = 20 if quick else 100

    def closed_loop_step() -> None:
        next_point(position, next_point(position, p0, 0.05), 0.05)
        next_point(orientation, next_point(orientation, q0, 0.05), 0.05)

    return {
        "train_epoch_s": epoch_s,
        "train_s_default_epochs": epoch_s * 2 * default_epochs,
        "default_epochs": default_epochs,
        "flow_step_ms": _median_ms(lambda: next_point(position, p0, 0.05), 10 * repeats),
        "closed_loop_step_ms": (step_ms := _median_ms(closed_loop_step, 10 * repeats)),
        "closed_loop_rate_hz": 1e3 / step_ms,
        "rollout_1000_ms": _median_ms(lambda: rollout(position, p0[None], 1000, 1e-12), repeats),
        "rollouts_100x1000_ms": _median_ms(lambda: rollout(position, starts, 1000, 1e-12), max(3, repeats // 10)),
        "paper_rollout_1000_ms": 20_000.0,
        "paper_train_s_per_shape": 61 * 60.0,
    }


def skill_training_configs() -> tuple[Any, Any]:
    """(former, current) TrainConfig of the default skill: `PAPER_SCHEDULE` and `SKILL_SCHEDULE` over the skill's
    log-scale bound and prior weight (the current one is `scripts.train.skill_train_config()`)."""
    from rflow.model import ModelConfig
    from rflow.train import PAPER_SCHEDULE, SKILL_SCHEDULE, TrainConfig

    common = {"model": ModelConfig(log_scale_clamp=SKILL_LOG_SCALE_CLAMP), "prior_weight": SKILL_PRIOR_WEIGHT,
              "threads": 1}
    return TrainConfig(**common, **PAPER_SCHEDULE), TrainConfig(**common, **SKILL_SCHEDULE)


def bench_training(quick: bool) -> dict[str, Any]:
    """The default skill's training with the paper's ("former") and the skill's ("current") schedule, alternately
    (module docstring)."""
    import dataclasses

    from rflow.skill_io import fit_pose_skill

    pos, quat, dt = synthetic_pose_demos()
    former, current = skill_training_configs()
    if quick:
        former, current = (dataclasses.replace(c, epochs=max(1, round(c.epochs * TRAINING_QUICK_EPOCH_FRACTION)))
                           for c in (former, current))
    times: dict[str, list[float]] = {"former": [], "current": []}
    for _ in range(1 if quick else TRAINING_REPEATS_FULL):
        for name, config in (("former", former), ("current", current)):
            start = time.perf_counter()
            fit_pose_skill(pos, quat, dt, config, progress=False, workers=2)
            times[name].append(time.perf_counter() - start)
    former_s, current_s = float(np.median(times["former"])), float(np.median(times["current"]))
    return {
        "former_schedule": f"batch {former.batch_size}, lr {former.lr:g}, {former.epochs} epochs",
        "current_schedule": f"batch {current.batch_size}, lr {current.lr:g}, {current.epochs} epochs",
        "former_s": former_s,
        "current_s": current_s,
        "speedup": former_s / current_s,
        "repeats": len(times["current"]),
        "quick": quick,
    }


BENCHMARKS: list[tuple[str, Callable[[bool], dict[str, Any]]]] = [("flow", bench_flow), ("training", bench_training)]
