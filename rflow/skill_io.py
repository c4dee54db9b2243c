"""A pose skill: RiemannianFlow models of a peg_tip pose trajectory, and their checkpoint directory.

Two layouts, as in the paper or jointly (its "future work"):
  - "separate": a position model on R^3 (tangent p - g_p) and an orientation model on S^3 (tangent
    Log_{g_q}(q)), each its own RiemannianFlow;
  - "joint": one model on the product R^3 x S^3 (`PoseManifold`): points [p, q] (7,), tangent
    [p - g_p, Log_{g_q}(q)] (6,), built from the same two maps, one 6-D flow.

Checkpoint directory (``save_skill`` / ``load_skill``)::

    DIR/skill.json            format, layout, metadata (shape, clearance, demo checksum, ...),
                              training config and loss history per model
    DIR/position/             RiemannianFlow.save (model.json + weights.pt)   } "separate"
    DIR/orientation/          RiemannianFlow.save                             }
    DIR/joint/                RiemannianFlow.save                               "joint"
    DIR/<extra files>         e.g. loss.png, written by a caller-supplied writer

The directory is built in ``DIR.tmp-XXXX`` beside DIR and renamed into place only when complete, so a
failure never leaves a half-written checkpoint. Weights are read with torch.load(weights_only=True).
Never imports MuJoCo.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
import numpy.typing as npt

from rflow.errors import RFlowError
from rflow.manifolds import Manifold, euclidean, get_manifold, sphere
from rflow.model import RiemannianFlow

SKILL_FILE = "skill.json"
SKILL_FORMAT = "rflow.PoseSkill/1"
LAYOUTS = ("separate", "joint")
MODEL_DIRS: Mapping[str, tuple[str, ...]] = {"separate": ("position", "orientation"), "joint": ("joint",)}


class PoseManifold(Manifold):
    """The product R^3 x S^3 of peg_tip poses, points [x, y, z, w, qx, qy, qz] (7,).

    Log_g([p, q]) = [p - g_p, Log(q * conj(g_q))] (6,), Exp_g([u, v]) = [g_p + u, Exp(v) * g_q]:
    the two maps of the paper applied to the two factors (numpy or torch, batched).
    """

    name = "pose"
    point_ndim = 1

    def check_points(self, points: Any, name: str = "points") -> Any:
        x = euclidean.check_points(points, name)
        if x.shape[-1] != 7:
            raise RFlowError(f"{name} has shape {tuple(x.shape)}, expected (..., 7) poses [x, y, z, w, qx, qy, qz]")
        sphere.check_quaternions(x[..., 3:], f"{name} quaternion part")
        return x

    def tangent_dim(self, point_shape: tuple[int, ...]) -> int:
        return 6

    def log(self, points: Any, goal: Any) -> Any:
        x, g = self.check_points(points, "pose"), self.check_points(goal, "goal pose")
        return _concat(euclidean.log_map(x[..., :3], g[..., :3]), sphere.log_map(x[..., 3:], g[..., 3:]))

    def exp(self, tangent: Any, goal: Any) -> Any:
        v = euclidean.check_points(tangent, "tangent")
        if v.shape[-1] != 6:
            raise RFlowError(f"tangent has shape {tuple(v.shape)}, expected (..., 6)")
        g = self.check_points(goal, "goal pose")
        return _concat(euclidean.exp_map(v[..., :3], g[..., :3]), sphere.exp_map(v[..., 3:], g[..., 3:]))

    def distance(self, a: Any, b: Any) -> Any:
        """sqrt(||p_a - p_b||^2 + ||2 Log(q_a conj(q_b))||^2) (m and rad mixed: for ordering only)."""
        a, b = self.check_points(a, "a"), self.check_points(b, "b")
        dp = euclidean.distance(a[..., :3], b[..., :3])
        dq = sphere.distance(a[..., 3:], b[..., 3:])
        return (dp * dp + dq * dq) ** 0.5

    def prepare(self, trajectories: Any) -> Any:
        """Hemisphere continuity of the quaternion part along each trajectory, all ending on one hemisphere."""
        x = np.array(self.check_points(trajectories, "demos"), dtype=np.float64)
        x[..., 3:] = np.asarray(get_manifold("sphere").prepare(x[..., 3:]))
        return x


POSE = PoseManifold()


def _concat(a: Any, b: Any) -> Any:
    if isinstance(a, np.ndarray):
        return np.concatenate([a, b], axis=-1)
    import torch

    return torch.cat([a, b], dim=-1)


class PoseFlow(RiemannianFlow):
    """A RiemannianFlow that also knows the "pose" product manifold by name (for ``load``)."""

    def __init__(self, manifold: str | Manifold, *args: Any, **kwargs: Any):
        super().__init__(POSE if manifold == POSE.name else manifold, *args, **kwargs)


def file_sha256(path: str | os.PathLike[str]) -> str:
    """Hex SHA-256 of a file's bytes. Raises FileNotFoundError if missing."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


@dataclass
class PoseSkill:
    """The trained models of one pose skill plus what is needed to use and audit them.

    Attributes:
        layout: "separate" (position + orientation) or "joint".
        models: {"position": ..., "orientation": ...} or {"joint": ...}.
        metadata: JSON-ready facts about the demos (shape, clearance_m, demo_sha256, goal, dt, ...).
        training: per model name, {"config": TrainConfig as dict, "history": TrainHistory as dict}.
    """

    layout: str
    models: dict[str, RiemannianFlow]
    metadata: dict[str, Any] = field(default_factory=dict)
    training: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.layout not in LAYOUTS:
            raise RFlowError(f"unknown skill layout {self.layout!r}; expected one of {LAYOUTS}")
        if set(self.models) != set(MODEL_DIRS[self.layout]):
            raise RFlowError(f"a {self.layout} skill needs models {MODEL_DIRS[self.layout]}, got {sorted(self.models)}")

    @property
    def goal_pos(self) -> np.ndarray:
        """Goal position g_p (3,), m."""
        return (self.models["position"].goal if self.layout == "separate" else self.models["joint"].goal[:3]).copy()

    @property
    def goal_quat(self) -> np.ndarray:
        """Goal orientation g_q (4,), w-x-y-z."""
        return (self.models["orientation"].goal if self.layout == "separate" else self.models["joint"].goal[3:]).copy()

    @property
    def dt(self) -> float:
        """Sampling time of the training demos (s)."""
        return float(next(iter(self.models.values())).dt)

    def to_tangent(self, pos: npt.ArrayLike, quat: npt.ArrayLike) -> np.ndarray:
        """[p - g_p, Log_{g_q}(q)] (..., 6) of poses. Raises RFlowError on bad input."""
        if self.layout == "joint":
            return self.models["joint"].to_tangent(np.concatenate([np.asarray(pos, float), np.asarray(quat, float)], -1))
        return np.concatenate([self.models["position"].to_tangent(pos), self.models["orientation"].to_tangent(quat)], -1)

    def from_tangent(self, tangent: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Poses (pos (..., 3), quat (..., 4)) of tangent vectors (..., 6)."""
        v = np.asarray(tangent, dtype=np.float64)
        if self.layout == "joint":
            x = self.models["joint"].from_tangent(v)
            return x[..., :3], x[..., 3:]
        return self.models["position"].from_tangent(v[..., :3]), self.models["orientation"].from_tangent(v[..., 3:])


def save_skill(directory: str | os.PathLike[str], skill: PoseSkill,
               extra: Mapping[str, Callable[[Path], None]] | None = None, overwrite: bool = True) -> Path:
    """Write a skill checkpoint directory atomically (build in DIR.tmp-XXXX, then rename).

    Args:
        directory: the checkpoint directory DIR.
        skill: the skill.
        extra: file name -> writer(path) called inside the temporary directory (e.g. the loss figure).
        overwrite: replace an existing DIR (it is moved aside and deleted only after the rename).

    Returns:
        DIR.

    Raises:
        RFlowError: DIR exists and overwrite is False, or its parent folder does not exist.
        Whatever a writer raises (the temporary directory is removed first).
    """
    out = Path(directory)
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir():
        raise RFlowError(f"cannot write checkpoint {out}: folder {parent} does not exist")
    if out.exists() and not overwrite:
        raise RFlowError(f"checkpoint {out} already exists")
    tmp = Path(tempfile.mkdtemp(prefix=f"{out.name}.tmp-", dir=parent))
    old: Path | None = None
    try:
        for name in MODEL_DIRS[skill.layout]:
            skill.models[name].save(tmp / name)
        record = {"format": SKILL_FORMAT, "layout": skill.layout, "models": list(MODEL_DIRS[skill.layout]),
                  "metadata": skill.metadata, "training": skill.training}
        (tmp / SKILL_FILE).write_text(json.dumps(record, indent=2, allow_nan=True))
        for name, writer in (extra or {}).items():
            writer(tmp / name)
        if out.exists():
            old = Path(tempfile.mkdtemp(prefix=f"{out.name}.old-", dir=parent))
            os.replace(out, old / out.name)
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        if old is not None and not out.exists() and (old / out.name).exists():
            os.replace(old / out.name, out)  # put the previous checkpoint back
        raise
    finally:
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    return out


def load_skill(directory: str | os.PathLike[str]) -> PoseSkill:
    """Read a checkpoint written by `save_skill`.

    Raises:
        RFlowError: missing directory, missing or corrupt skill.json, or a missing/corrupt model.
    """
    src = Path(directory)
    if not src.is_dir():
        raise RFlowError(f"checkpoint directory {src} not found")
    try:
        record = json.loads((src / SKILL_FILE).read_text())
    except FileNotFoundError:
        raise RFlowError(f"no {SKILL_FILE} in checkpoint {src} (not a `pih train` output?)") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise RFlowError(f"corrupt {src / SKILL_FILE}: {err}") from None
    if not isinstance(record, dict) or record.get("format") != SKILL_FORMAT:
        got = record.get("format") if isinstance(record, dict) else type(record).__name__
        raise RFlowError(f"{src / SKILL_FILE} has format {got!r}, expected {SKILL_FORMAT!r}")
    layout = record.get("layout")
    if layout not in LAYOUTS:
        raise RFlowError(f"{src / SKILL_FILE} has unknown layout {layout!r}")
    models = {name: PoseFlow.load(src / name) for name in MODEL_DIRS[layout]}
    metadata, training = record.get("metadata", {}), record.get("training", {})
    if not isinstance(metadata, dict) or not isinstance(training, dict):
        raise RFlowError(f"corrupt {src / SKILL_FILE}: metadata and training must be JSON objects")
    skill = PoseSkill(layout, models, metadata, training)
    _check_models(skill, src)
    return skill


def _check_models(skill: PoseSkill, src: Path) -> None:
    expected = {"position": ("euclidean", (3,)), "orientation": ("sphere", (4,)), "joint": ("pose", (7,))}
    for name, model in skill.models.items():
        manifold, shape = expected[name]
        if model.manifold.name != manifold or model.point_shape != shape:
            raise RFlowError(f"{src / name}: expected a {manifold} model of {shape} points, got "
                             f"{model.manifold.name} {model.point_shape}")


def subsample(trajectories: npt.ArrayLike, factor: int) -> np.ndarray:
    """Every ``factor``-th sample of (N, M, ...) trajectories counted back from the last (the goal), so the
    sampling stays uniform (dt * factor) and the goal is kept; up to factor - 1 first samples are dropped.

    Raises:
        RFlowError: factor < 1 or fewer than 2 samples left.
    """
    arr = np.asarray(trajectories)
    if not isinstance(factor, (int, np.integer)) or factor < 1:
        raise RFlowError(f"subsampling factor {factor!r} must be an integer >= 1")
    if arr.ndim < 2:
        raise RFlowError(f"trajectories have shape {arr.shape}, expected (N, M, ...)")
    first = (arr.shape[1] - 1) % factor
    out = arr[:, first::factor]
    if out.shape[1] < 2:
        raise RFlowError(f"subsampling {arr.shape[1]} samples by {factor} leaves fewer than 2")
    return out


def fit_pose_skill(pos: npt.ArrayLike, quat: npt.ArrayLike, dt: float, config: Any = None,
                   layout: str = "separate", progress: bool = True) -> PoseSkill:
    """Train the models of a pose skill on peg_tip demonstrations (rflow.train.fit per model).

    Args:
        pos: (N, M, 3) positions, all ending at the goal position.
        quat: (N, M, 4) unit quaternions w-x-y-z, all ending at the goal orientation.
        dt: sampling time (s).
        config: rflow.train.TrainConfig shared by the models (default: the paper's).
        layout: "separate" (position on R^3 and orientation on S^3, as in the paper) or "joint"
            (one model on R^3 x S^3).
        progress: tqdm bars.

    Returns:
        The PoseSkill, with ``training`` holding each model's config and loss history.

    Raises:
        RFlowError: bad shapes, NaN, demos without a shared goal, diverged training, unknown layout.
    """
    from dataclasses import asdict

    from rflow.train import TrainConfig, fit

    cfg = TrainConfig() if config is None else config
    p = np.asarray(pos, dtype=np.float64)
    q = np.asarray(quat, dtype=np.float64)
    if p.ndim != 3 or p.shape[-1] != 3 or q.shape != p.shape[:2] + (4,):
        raise RFlowError(f"demos need pos (N, M, 3) and quat (N, M, 4), got {p.shape} and {q.shape}")
    if layout not in LAYOUTS:
        raise RFlowError(f"unknown skill layout {layout!r}; expected one of {LAYOUTS}")
    if layout == "joint":
        data = {"joint": (np.concatenate([p, q], axis=-1), POSE)}
    else:
        data = {"position": (p, "euclidean"), "orientation": (q, "sphere")}
    models: dict[str, RiemannianFlow] = {}
    training: dict[str, Any] = {}
    for name, (demos, manifold) in data.items():
        if progress:
            print(f"training the {name} model ({np.asarray(demos).shape[0]} demos x {np.asarray(demos).shape[1]} samples)")
        model, history = fit(demos, manifold, dt, cfg, progress=progress)
        models[name] = model
        training[name] = {"config": asdict(cfg), "history": asdict(history)}
    return PoseSkill(layout, models, {}, training)
