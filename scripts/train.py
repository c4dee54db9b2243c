"""`pih train`: learn the peg-in-hole skill from a demo file (position + orientation RiemannianFlow models).

Writes a checkpoint directory (rflow.skill_io): the models (weights.pt, loaded with weights_only=True, and
model.json with normalisation and goal), skill.json (demo metadata: shape, clearance, SHA-256 of the demo
file, demo start poses, the demos' task (envs/task/task.py, versioned: the one the demo file records, else the default
task, with the demos' scene), training config and loss history), demos.npz (a subsampled copy of the demos for
figures, with the demos' stiffness for a stiffness skill) and loss.png. Built in DIR.tmp-XXXX and renamed into place.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from rflow.stiffness import StiffnessBounds
from scripts.options import work_begins

DEFAULT_SUBSAMPLE = 10
"""Demo samples kept: every 10th (M = 4000 -> 400, dt ~17.5 ms); generation steps are exact for any dt."""
DEFAULT_LOG_SCALE_CLAMP = 0.5
"""Bound of each layer's log-scale: 0.5 (vs rflow's 2) keeps the ReLU flow tame outside the demos
(with 2, 19 of 20 closed-loop episodes failed on the default demos; with 0.5, 20 of 20 succeeded)."""
DEFAULT_PRIOR_WEIGHT = 0.3
"""Weight of rflow's off-data identity prior (TrainConfig.prior_weight; rflow's default 0 is the paper's plain
likelihood). Seven demos leave most of the start region empty, and there the unconstrained ReLU flow sends
the latent state far out (|b^-1(z)| ~ 60 at a start 5 std out): plans jumped by up to 1.4 rad in one 10 ms
step or swung the peg 20 deg away before turning back (7 of 100 open-loop episodes failed). Chosen on
held-out starts (seeds 1 and 2, not the evaluation seed 0), plans only, no physics: weight 0 gave 56 of 200
plans with a jump over 0.5 m/s or 2 rad/s and 25 more than 1 deg off at the hole's opening; 0.3 gave 0-3
jumps, none off by 1 deg, and the best lateral precision at the opening (90th percentile 0.14-0.16 mm vs 0.20
mm at 0 and 0.30 mm at 1, a stronger prior trading fit near the goal for tameness)."""
PREVIEW_SAMPLES = 400
STIFFNESS_SOURCES = ("expert", "variability")
DEFAULT_BOUNDS = StiffnessBounds()


CHECKPOINT_BYTES = 64 * 2**20
"""Generous size of a checkpoint (weights of the default models are ~1 MB, the preview and figure a few)."""
SCENE_METADATA: tuple[str, ...] = ("goal_pos", "goal_yaw_deg", "hole_depth_m", "insertion_depth_m", "chamfer_m",
                                   "peg_mode", "grasp_force_n")
"""The demos' scene settings a checkpoint keeps, so `pih evaluate` rebuilds the scene the skill was taught in."""


EXAMPLES: tuple[str, ...] = ('pih train --demos demos.npz --out model/',
                             'pih train --demos demos.npz --stiffness expert --joint --out joint/')
"""Shown at the end of --help (scripts.cli)."""

def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the options of `pih train`, in groups: input, output, skill, training, run."""
    from pihutil.bounds import LEARNING_RATE, LOG_SCALE_CLAMP, PRIOR_RADIUS, PRIOR_WEIGHT, STIFFNESS
    from rflow.model import MAX_WIDTH
    from scripts.options import DEFAULT_WORKERS, MAX_EPOCHS, MAX_SAMPLES, MAX_WORKERS, count, number, seed

    d = skill_train_config()  # the defaults train the skill `pih run` and `pih benchmark` train
    given = parser.add_argument_group("input")
    given.add_argument("--demos", required=True, type=Path, help="demo file (.npz) from `pih demos` or the same schema")
    given.add_argument("--config", type=Path, metavar="FILE.json",
                       help="training hyperparameters from a config file (e.g. `pih search`'s best.json) instead of "
                            "the training options; --seed and --threads still apply")
    out = parser.add_argument_group("output")
    out.add_argument("--out", required=True, type=Path,
                     help="checkpoint directory to write (built beside it and renamed into place); an earlier "
                          "checkpoint there is replaced only with --overwrite, anything else never")
    out.add_argument("--overwrite", action="store_true", help="replace an earlier checkpoint at --out")
    skill = parser.add_argument_group("skill")
    skill.add_argument("--joint", action="store_true",
                       help="one joint 6-D model on R^3 x S^3 instead of separate position and orientation models "
                            "(with --stiffness: one joint 12-D model on R^3 x S^3 x SPD(3))")
    skill.add_argument("--stiffness", choices=STIFFNESS_SOURCES,
                       help="also learn the translational stiffness, in a model on R^3 x SPD(3) beside the position "
                            "and orientation models (or inside the joint model with --joint): 'expert' = the "
                            "stiffness recorded in the demo file, 'variability' = alpha (Sigma + eps I)^-1 from the "
                            "demos' spread (rflow.stiffness)")
    skill.add_argument("--k-min-n-m", type=number(bound=STIFFNESS), default=DEFAULT_BOUNDS.k_min_n_m,
                       help="--stiffness: smallest eigenvalue of the commanded stiffness, N/m")
    skill.add_argument("--k-max-n-m", type=number(bound=STIFFNESS), default=DEFAULT_BOUNDS.k_max_n_m,
                       help="--stiffness: largest eigenvalue of the commanded stiffness, N/m")
    skill.add_argument("--subsample", type=count(MAX_SAMPLES), default=DEFAULT_SUBSAMPLE,
                       help="keep every k-th demo sample, counted from the goal")
    train = parser.add_argument_group("training (replaced by --config)")
    train.add_argument("--epochs", type=count(MAX_EPOCHS), default=d.epochs, help="training epochs")
    train.add_argument("--layers", type=count(64), default=d.model.layers, help="coupling layers, 1..64")
    train.add_argument("--width", type=count(MAX_WIDTH), default=d.model.width,
                       help=f"hidden units per coupling MLP, 1..{MAX_WIDTH}")
    train.add_argument("--log-scale-clamp", type=number(bound=LOG_SCALE_CLAMP), default=DEFAULT_LOG_SCALE_CLAMP,
                       help="bound c of each coupling layer's log-scale")
    train.add_argument("--prior-weight", type=number(bound=PRIOR_WEIGHT), default=DEFAULT_PRIOR_WEIGHT,
                       help="weight of the off-data identity prior, 0 for the paper's plain likelihood")
    train.add_argument("--prior-radius", type=number(bound=PRIOR_RADIUS), default=d.prior_radius,
                       help="prior box half-width in multiples of the demos' extent")
    train.add_argument("--lr", type=number(bound=LEARNING_RATE), default=d.lr, help="Adam learning rate")
    train.add_argument("--batch-size", type=count(1_000_000), default=d.batch_size, help="batch size")
    train.add_argument("--transitions-per-epoch", type=count(100_000_000), default=d.transitions_per_epoch,
                       help="transitions sampled per epoch")
    train.add_argument("--horizon", type=count(1_000_000), default=d.horizon,
                       help="largest transition horizon in (subsampled) steps")
    run = parser.add_argument_group("run")
    run.add_argument("--seed", type=seed, default=d.seed, help="training seed, 0..2**32-1")
    run.add_argument("--threads", type=count(256), default=1,
                     help="torch threads (default 1: deterministic and polite on a shared 2-core machine)")
    run.add_argument("--workers", type=count(MAX_WORKERS), default=DEFAULT_WORKERS,
                     help="processes training the position and orientation models at the same time (default 2; "
                          "1 trains them one after the other; same weights either way)")
    run.add_argument("--quiet", action="store_true", help="no progress bars")


def skill_train_config(**overrides: Any) -> Any:
    """rflow's TrainConfig (the paper's architecture: 11 layers, ReLU, Adam) with this command's log-scale bound,
    off-data prior, one thread and the skill's schedule (rflow.train.SKILL_SCHEDULE: batch 128, lr 2e-3, 40 epochs,
    half the steps of the paper's lr 1e-3 and 80 epochs at the same validation DTW; why there), plus ``overrides``
    (TrainConfig fields)."""
    from rflow.model import ModelConfig
    from rflow.train import SKILL_SCHEDULE, TrainConfig

    values: dict[str, Any] = {"model": ModelConfig(log_scale_clamp=DEFAULT_LOG_SCALE_CLAMP),
                              "prior_weight": DEFAULT_PRIOR_WEIGHT, "threads": 1, **SKILL_SCHEDULE}
    values.update(overrides)
    return TrainConfig(**values)


def train_config_from_args(args: argparse.Namespace) -> Any:
    """The rflow TrainConfig of the parsed options (or of --config FILE, with the options' seed and threads)."""
    from rflow.model import ModelConfig
    from rflow.train import TrainConfig

    if getattr(args, "config", None) is not None:
        import dataclasses

        from rflow.config_file import load_train_config

        return dataclasses.replace(load_train_config(args.config), seed=args.seed, threads=args.threads)

    model = ModelConfig(layers=args.layers, width=args.width, log_scale_clamp=args.log_scale_clamp)
    return TrainConfig(model=model, epochs=args.epochs, lr=args.lr, prior_weight=args.prior_weight,
                       prior_radius=args.prior_radius, batch_size=args.batch_size,
                       transitions_per_epoch=args.transitions_per_epoch, horizon=args.horizon, seed=args.seed,
                       threads=args.threads)


def demo_stiffness(demos: Any, source: str, bounds: StiffnessBounds, demos_path: str | Path) -> np.ndarray:
    """The demos' stiffness (N, M, 3, 3) from ``source``: "expert" (recorded in the file) or "variability"
    (rflow.stiffness.variability_stiffness, one profile for all demos).

    Raises:
        EnvError: "expert" and the file has no stiffness. RFlowError: unknown source, too few demos.
    """
    from envs.errors import EnvError
    from rflow.errors import RFlowError
    from rflow.stiffness import VariabilityConfig, variability_stiffness

    if source == "expert":
        if demos.stiffness is None:
            raise EnvError(f"--stiffness expert: demo file {demos_path} has no 'stiffness' (record it with the "
                           "scripted expert, or use --stiffness variability)")
        return np.asarray(demos.stiffness, dtype=np.float64)
    if source == "variability":
        profile = variability_stiffness(demos.pos, VariabilityConfig(bounds=bounds))
        return np.broadcast_to(profile, demos.pos.shape[:2] + (3, 3)).copy()
    raise RFlowError(f"unknown stiffness source {source!r}; expected one of {STIFFNESS_SOURCES}")


def train_skill(demos_path: str | Path, out: str | Path, config: Any = None, joint: bool = False,
                subsample: int = DEFAULT_SUBSAMPLE, progress: bool = True, stiffness: str | None = None,
                bounds: StiffnessBounds = DEFAULT_BOUNDS, overwrite: bool = False, workers: int = 1) -> Path:
    """Load demos, train the skill, write the checkpoint directory (see the module docstring).

    With ``stiffness`` ("expert" or "variability", see `demo_stiffness`) the skill also has a stiffness model on
    R^3 x SPD(3) beside its two pose models (layout "separate_stiffness"), or with ``joint`` is one joint model on
    R^3 x S^3 x SPD(3); skill.json's metadata["stiffness"] also records the
    source and the Log-Euclidean distance of the stiffness generated from each demo's start to the
    demo's (rflow.skill_io.stiffness_reproduction). With ``workers`` >= 2 the separate models train in
    parallel processes (`rflow.fit_processes`), to the same weights. Demos that end apart (a demo file with
    ``ends_apart``, e.g. from `pih demos --noise` or `--import --ends-apart`) are learned each relative to its own end
    (`envs.demos.file.anchored_at_goal`), the skill's goal being their mean end.

    Returns:
        The checkpoint directory.

    Raises:
        EnvError: unreadable or invalid demo file (as strictly as `pih evaluate`: shape, clearance and the
            recorded scene must make a valid scene), "expert" stiffness missing from it.
        RFlowError: ``out`` holds something other than a checkpoint, or a checkpoint without ``overwrite``
            (checked before training); training failures, bad subsampling, stiffness outside ``bounds``.
    """
    from envs.demos.file import anchored_at_goal, load_demos
    from envs.media.figures import plot_loss
    from rflow.skill_io import check_checkpoint_target, file_sha256, fit_pose_skill, save_skill, stiffness_reproduction, subsample as take_every
    from rflow.train import check_training_memory
    cfg = skill_train_config() if config is None else config
    check_checkpoint_target(out, overwrite)
    demos = load_demos(demos_path)
    task = demos_task(demos, demos_path)
    anchored_pos, anchored_quat = anchored_at_goal(demos)  # demos that end apart: each relative to its own end
    pos, quat = take_every(anchored_pos, subsample), take_every(anchored_quat, subsample)
    k_demo = None if stiffness is None else demo_stiffness(demos, stiffness, bounds, demos_path)
    k = None if k_demo is None else take_every(k_demo, subsample)
    dt = demos.dt * subsample
    layout = "joint" if joint else "separate" if k is None else "separate_stiffness"
    dims = {"joint": [6 if k is None else 12], "separate": [3, 3], "separate_stiffness": [3, 3, 6]}[layout]
    check_training_memory(cfg, dims if workers > 1 else [max(dims)])  # the models that train at the same time
    work_begins()
    wall = time.perf_counter()
    skill = fit_pose_skill(pos, quat, dt, cfg, layout, progress, stiffness=k, bounds=bounds, workers=workers)
    train_s = time.perf_counter() - wall
    scene = demos.config.get("scene") if isinstance(demos.config.get("scene"), dict) else None
    if k is not None:
        skill.metadata["stiffness"].update(source=stiffness, **stiffness_reproduction(skill, pos, quat, k))
    skill.metadata = {
        **skill.metadata,  # the stiffness record of a stiffness skill
        "shape": demos.shape,
        "clearance_m": demos.clearance_m,
        "demo_file": str(Path(demos_path).resolve()),
        "demo_sha256": file_sha256(demos_path),
        "num_demos": demos.num_demos,
        "num_samples": demos.num_samples,
        "demo_dt_s": demos.dt,
        "subsample": subsample,
        "train_dt_s": dt,
        "goal_pos": demos.goal_pos.tolist(),
        "goal_quat": demos.goal_quat.tolist(),
        "ends_apart": demos.ends_apart,
        "demo_starts": {"pos": demos.pos[:, 0].tolist(), "quat": demos.quat[:, 0].tolist()},
        "scene": {k: scene[k] for k in SCENE_METADATA if k in scene} if scene else None,
        "task": task.to_dict(),
        "train_seconds": train_s,
    }
    step = max(1, demos.num_samples // PREVIEW_SAMPLES)

    def write_preview(path: Path) -> None:
        stiffness_preview = {} if k_demo is None else {"stiffness": take_every(k_demo, step)}
        np.savez(path, pos=take_every(demos.pos, step), quat=take_every(demos.quat, step),
                 dt=np.float64(demos.dt * step), **stiffness_preview)

    histories = {name: rec["history"] for name, rec in skill.training.items()}
    extra = {"demos.npz": write_preview, "loss.png": lambda path: plot_loss(histories, path)}
    return save_skill(out, skill, extra, overwrite=overwrite)


def demos_task(demos: Any, demos_path: str | Path) -> Any:
    """The demos' task for the checkpoint: the task the demo file records (`pih demos`), else the default task, with
    the scene `pih evaluate` rebuilds from the demos (their shape, clearance and recorded scene).

    Raises:
        EnvError: naming the demo file and the problem (unknown shape, clearance <= 0 or out of range, an invalid
            recorded task, ...).
    """
    from envs.errors import EnvError
    from envs.evaluation.evaluate import EvaluationConfig, scene_config_for
    from envs.poses import Pose
    from envs.task.task import Task

    scene = demos.config.get("scene") if isinstance(demos.config.get("scene"), dict) else None
    metadata = {"shape": demos.shape, "clearance_m": demos.clearance_m, "scene": scene}
    recorded = demos.config.get("task")
    try:
        task = Task() if recorded is None else Task.from_dict(recorded, "task")
        return task.with_scene(scene_config_for(metadata, EvaluationConfig(), Pose(pos=demos.goal_pos,
                                                                                    quat=demos.goal_quat)))
    except (EnvError, TypeError, ValueError) as err:
        raise EnvError(f"demo file {demos_path}: {err}") from None


def main(args: argparse.Namespace) -> int:
    """Run `pih train`."""
    from envs.io.owned_output import check_output

    wall = time.perf_counter()
    bounds = StiffnessBounds(args.k_min_n_m, args.k_max_n_m)
    config = train_config_from_args(args)
    check_output("--out", args.out, args.overwrite, folder=True, inputs=[args.demos, args.config],
                 estimate_bytes=CHECKPOINT_BYTES)
    out = train_skill(args.demos, args.out, config, args.joint, args.subsample,
                      progress=not args.quiet, stiffness=args.stiffness, bounds=bounds, overwrite=args.overwrite,
                      workers=args.workers)
    record = json.loads((out / "skill.json").read_text())
    losses = {name: rec["history"]["train_loss"][-1] for name, rec in record["training"].items()}
    print(f"wrote {out} ({record['layout']}: "
          + ", ".join(f"{n} loss {v:.3f}" for n, v in losses.items())
          + f") in {time.perf_counter() - wall:.1f} s")
    rec = record["metadata"].get("stiffness")
    if rec:
        print(f"stiffness ({rec['source']}): mean Log-Euclidean distance of generated to demonstrated profiles "
              f"{rec['log_euclidean_mean']:.3f} (per demo " + ", ".join(f"{d:.3f}" for d in rec["log_euclidean_per_demo"])
              + f"); eigenvalue clip acted on {100 * rec['clip_fraction']:.2f} % of generated samples, changing an "
              f"eigenvalue by at most {100 * np.expm1(rec['clip_max_log_change']):.2f} %")
    return 0


__all__ = ["EXAMPLES", "add_arguments", "main", "train_skill", "train_config_from_args"]
