"""A pose skill: RiemannianFlow models of a peg_tip pose trajectory, and their checkpoint directory.

Three layouts, as in the paper, jointly (its "future work"), or as in the paper with a stiffness model beside:
  - "separate": a position model on R^3 (tangent p - g_p) and an orientation model on S^3 (tangent
    Log_{g_q}(q)), each its own RiemannianFlow;
  - "separate_stiffness": the same two models, and beside them a model on R^3 x SPD(3) (`POSITION_STIFFNESS`:
    points [p, vec(K)] (12,), tangent (9,)) that generates the translational stiffness K from the position, so
    that learning the stiffness leaves the pose skill the two-model one;
  - "joint": one model on the product R^3 x S^3 (`POSE`): points [p, q] (7,), tangent
    [p - g_p, Log_{g_q}(q)] (6,), built from the same two maps, one 6-D flow; or, for a skill that also
    varies its translational stiffness K, one model on R^3 x S^3 x SPD(3) (`POSE_STIFFNESS`):
    points [p, q, vec(K)] (16,), tangent (12,), one 12-D flow. Generated stiffness is SPD by construction
    (Exp map) and converges to the goal stiffness; `PoseSkill.bound_stiffness` clips its eigenvalues to
    [k_min, k_max] (stored in skill.json's metadata) and says where it acted.

Checkpoint directory (``save_skill`` / ``load_skill``)::

    DIR/skill.json            format, layout, metadata (shape, clearance, demo checksum, ...),
                              training config and loss history per model
    DIR/position/             RiemannianFlow.save (model.json + weights.pt)   } "separate"
    DIR/orientation/          RiemannianFlow.save                             }
    DIR/stiffness/            RiemannianFlow.save                               + "separate_stiffness"
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
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
import numpy.typing as npt

from numerics.small_linalg import eigh_sym
from pihutil.atomic import atomic_folder
from pihutil.manifest import folder_strangers, shown, write_manifest
from rflow.errors import RFlowError
from rflow.manifolds import EuclideanSpace, Manifold, ProductManifold, SPDNormalMatrices, UnitQuaternions
from rflow.model import CONFIG_FILE, WEIGHTS_FILE, RiemannianFlow, read_json
from rflow.stiffness import StiffnessBounds, clip_eigenvalues, log_euclidean_mean

SKILL_FILE = "skill.json"
SKILL_FORMAT = "rflow.PoseSkill/1"
LAYOUTS = ("separate", "joint", "separate_stiffness")
MODEL_DIRS: Mapping[str, tuple[str, ...]] = {"separate": ("position", "orientation"), "joint": ("joint",),
                                             "separate_stiffness": ("position", "orientation", "stiffness")}


POSE = ProductManifold("pose", ((EuclideanSpace(), (3,)), (UnitQuaternions(), (4,))))
"""R^3 x S^3 of peg_tip poses: points [x, y, z, w, qx, qy, qz] (7,), Log_g([p, q]) = [p - g_p, Log(q * conj(g_q))]
(6,), Exp_g([u, v]) = [g_p + u, Exp(v) * g_q]: the paper's two maps applied to the two factors."""

POSE_STIFFNESS = ProductManifold(
    "pose_stiffness", ((EuclideanSpace(), (3,)), (UnitQuaternions(), (4,)), (SPDNormalMatrices(), (3, 3))))
"""R^3 x S^3 x SPD(3) of peg_tip poses and translational stiffness: points [p (3), q (4), vec(K) (9)] (16,),
tangent [p - g_p, Log_{g_q}(q), mandel(logm(G^-1/2 K G^-1/2))] (12,) at the goal (g_p, g_q, G). The SPD
part is the affine-invariant Log at the goal stiffness G in normal coordinates (dimensionless, see
`rflow.manifolds.spd.normal_log_map`); Exp of any tangent vector is SPD."""

POSITION_STIFFNESS = ProductManifold(
    "position_stiffness", ((EuclideanSpace(), (3,)), (SPDNormalMatrices(), (3, 3))))
"""R^3 x SPD(3) of peg_tip positions and translational stiffness: points [p (3), vec(K) (9)] (12,), tangent
[p - g_p, mandel(logm(G^-1/2 K G^-1/2))] (9,) at the goal (g_p, G); the stiffness model of a "separate_stiffness"
skill, whose K follows the position it is queried at."""

JOINT_MANIFOLDS: Mapping[str, ProductManifold] = {m.name: m for m in (POSE, POSE_STIFFNESS, POSITION_STIFFNESS)}


class PoseFlow(RiemannianFlow):
    """A RiemannianFlow that also knows the "pose" and "pose_stiffness" product manifolds by name (for ``load``)."""

    def __init__(self, manifold: str | Manifold, *args: Any, **kwargs: Any):
        joint = JOINT_MANIFOLDS.get(manifold) if isinstance(manifold, str) else None
        super().__init__(manifold if joint is None else joint, *args, **kwargs)


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
        layout: "separate" (position + orientation), "joint" or "separate_stiffness" (+ stiffness).
        models: {"position": ..., "orientation": ...}, {"joint": ...} or {"position", "orientation", "stiffness"}.
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
        return (self.models["joint"].goal[:3] if self.layout == "joint" else self.models["position"].goal).copy()

    @property
    def goal_quat(self) -> np.ndarray:
        """Goal orientation g_q (4,), w-x-y-z."""
        return (self.models["joint"].goal[3:7] if self.layout == "joint" else self.models["orientation"].goal).copy()

    # ---- stiffness (a joint model on R^3 x S^3 x SPD(3), `POSE_STIFFNESS`, or a model on R^3 x SPD(3) beside the
    # ---- two pose models, `POSITION_STIFFNESS`) ---------------------------------------------------------------------
    @property
    def has_stiffness(self) -> bool:
        """True when the skill also generates the translational stiffness (a joint model on POSE_STIFFNESS, or the
        "separate_stiffness" layout)."""
        return self.layout == "separate_stiffness" or (self.layout == "joint"
                                                       and self.models["joint"].manifold.name == POSE_STIFFNESS.name)

    def _require_stiffness(self) -> None:
        if not self.has_stiffness:
            raise RFlowError("this skill has no stiffness model (train it with `pih train --stiffness ...`)")

    @property
    def goal_stiffness(self) -> np.ndarray:
        """Goal stiffness G (3, 3), N/m. Raises RFlowError for a skill without stiffness."""
        self._require_stiffness()
        if self.layout == "separate_stiffness":
            return self.models["stiffness"].goal[3:].reshape(3, 3).copy()
        return self.models["joint"].goal[7:].reshape(3, 3).copy()

    @property
    def stiffness_bounds(self) -> StiffnessBounds:
        """[k_min, k_max] (N/m) of the commanded stiffness's eigenvalues, from the training metadata."""
        self._require_stiffness()
        rec = self.metadata.get("stiffness") or {}
        try:
            return StiffnessBounds(float(rec["k_min_n_m"]), float(rec["k_max_n_m"]))
        except (KeyError, TypeError, ValueError):
            raise RFlowError("skill metadata has no valid stiffness bounds (k_min_n_m, k_max_n_m)") from None

    @property
    def start_stiffness(self) -> np.ndarray:
        """The stiffness a new episode starts from (3, 3): the Log-Euclidean mean of the demos' first samples
        (the stiffness is the model's own state, never measured)."""
        self._require_stiffness()
        start = (self.metadata.get("stiffness") or {}).get("start_n_m")
        if start is None:
            return self.goal_stiffness
        return np.asarray(POSE_STIFFNESS.factors[2][0].check_points(np.asarray(start, float).reshape(3, 3),
                                                                    "start stiffness"))

    def bound_stiffness(self, stiffness: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """(clip(K), where the clip acted) of generated stiffness (..., 3, 3): eigenvalues clipped to the skill's
        bounds (`rflow.stiffness.clip_eigenvalues`; the identity inside the bounds)."""
        return clip_eigenvalues(stiffness, self.stiffness_bounds)

    def joint_point(self, pos: npt.ArrayLike, quat: npt.ArrayLike, stiffness: npt.ArrayLike | None = None) -> np.ndarray:
        """The joint model's point: [p, q] (..., 7), or [p, q, vec(K)] (..., 16) for a stiffness skill."""
        parts = [np.asarray(pos, float), np.asarray(quat, float)]
        if self.has_stiffness:
            k = np.asarray(self.goal_stiffness if stiffness is None else stiffness, float)
            parts.append(k.reshape(k.shape[:-2] + (9,)))
        return np.concatenate(parts, -1)

    def stiffness_point(self, pos: npt.ArrayLike, stiffness: npt.ArrayLike) -> np.ndarray:
        """The "separate_stiffness" stiffness model's point [p, vec(K)] (..., 12)."""
        k = np.asarray(stiffness, float)
        return np.concatenate([np.asarray(pos, float), k.reshape(k.shape[:-2] + (9,))], -1)

    def split_point(self, x: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """(pos (..., 3), quat (..., 4), stiffness (..., 3, 3) or None) of joint-model points."""
        v = np.asarray(x, float)
        k = v[..., 7:16].reshape(v.shape[:-1] + (3, 3)) if self.has_stiffness else None
        return v[..., :3], v[..., 3:7], k

    @property
    def dt(self) -> float:
        """Sampling time of the training demos (s)."""
        return float(next(iter(self.models.values())).dt)

    def to_tangent(self, pos: npt.ArrayLike, quat: npt.ArrayLike) -> np.ndarray:
        """[p - g_p, Log_{g_q}(q)] (..., 6) of poses. Raises RFlowError on bad input."""
        if self.layout == "joint":
            pose = np.concatenate([np.asarray(pos, float), np.asarray(quat, float)], -1)
            return np.asarray(POSE.log(pose, self.models["joint"].goal[:7]))
        return np.concatenate([self.models["position"].to_tangent(pos), self.models["orientation"].to_tangent(quat)], -1)

    def from_tangent(self, tangent: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Poses (pos (..., 3), quat (..., 4)) of tangent vectors (..., 6)."""
        v = np.asarray(tangent, dtype=np.float64)
        if self.layout == "joint":
            x = np.asarray(POSE.exp(v, self.models["joint"].goal[:7]))
            return x[..., :3], x[..., 3:]
        return self.models["position"].from_tangent(v[..., :3]), self.models["orientation"].from_tangent(v[..., 3:])


def is_checkpoint(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` is a folder holding a skill.json with this module's format marker."""
    try:
        record = json.loads((Path(path) / SKILL_FILE).read_text())
    except (OSError, UnicodeDecodeError, ValueError):
        return False
    return isinstance(record, dict) and record.get("format") == SKILL_FORMAT


LEGACY_EXTRAS: tuple[str, ...] = ("demos.npz", "loss.png", ".pih-outputs.json")
"""Files `pih train` wrote beside skill.json and the model folders before checkpoints listed their files (the
last: the registry of the loss figure, envs.io.owned_output)."""


def checkpoint_strangers(path: str | os.PathLike[str]) -> list[str]:
    """What inside the checkpoint folder ``path`` `save_skill` did not write, or changed since (its file list,
    pihutil.manifest; a checkpoint without one: anything but skill.json, the models' folders with their
    model.json and weights.pt, and LEGACY_EXTRAS). [] when --overwrite may replace the folder."""
    try:
        models = json.loads((Path(path) / SKILL_FILE).read_text()).get("models", [])
    except (OSError, UnicodeDecodeError, ValueError, AttributeError):
        models = []
    names = [SKILL_FILE, *LEGACY_EXTRAS]
    for name in models if isinstance(models, list) else []:
        if isinstance(name, str) and any(name in names_ for names_ in MODEL_DIRS.values()):
            names += [f"{name}/{CONFIG_FILE}", f"{name}/{WEIGHTS_FILE}"]
    return folder_strangers(path, dict.fromkeys(names))


def check_checkpoint_target(directory: str | os.PathLike[str], overwrite: bool = False) -> Path:
    """Check that a checkpoint may be written at ``directory`` (call before any work).

    Only a previous checkpoint (`is_checkpoint`) holding nothing but what `save_skill` wrote there
    (`checkpoint_strangers`) is ever replaced, and only with ``overwrite``; a plain file, any other folder, or
    a checkpoint somebody added files to or changed, is never touched.

    Raises:
        RFlowError: the parent folder is missing; something that is not a checkpoint is there; a checkpoint
            is there and ``overwrite`` is False; it holds files that are not the checkpoint's.
    """
    out = Path(directory)
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir():
        raise RFlowError(f"cannot write checkpoint {out}: folder {parent} does not exist")
    if out.exists() or out.is_symlink():
        if not is_checkpoint(out):
            kind = "folder" if out.is_dir() else "file"
            raise RFlowError(f"{out} is a {kind} that is not a checkpoint (no {SKILL_FILE} of format "
                             f"{SKILL_FORMAT!r}): not replacing it; choose another path")
        if not overwrite:
            raise RFlowError(f"checkpoint {out} already exists (use --overwrite to replace it)")
        found = checkpoint_strangers(out)
        if found:
            raise RFlowError(f"checkpoint {out} holds files it did not write or that changed since "
                             f"({shown(found)}): not replacing it; move them out or choose another path")
    return out


def save_skill(directory: str | os.PathLike[str], skill: PoseSkill,
               extra: Mapping[str, Callable[[Path], None]] | None = None, overwrite: bool = False) -> Path:
    """Write a skill checkpoint directory atomically (`pihutil.atomic.atomic_folder`: built in .DIR.tmp-XXXX beside
    it, then swapped in).

    Args:
        directory: the checkpoint directory DIR.
        skill: the skill.
        extra: file name -> writer(path) called inside the temporary directory (e.g. the loss figure).
        overwrite: replace an existing checkpoint at DIR (moved aside, deleted only after the rename).
            Anything else at DIR is never replaced (`check_checkpoint_target`).

    Returns:
        DIR (mode 0777 & ~umask, 0755 by default).

    Raises:
        RFlowError: see `check_checkpoint_target`.
        Whatever a writer raises (the temporary directory is removed first).
    """
    out = check_checkpoint_target(directory, overwrite)
    with atomic_folder(out, before_swap=lambda: check_checkpoint_target(out, overwrite),  # still ours, and
                       keep_replaced=lambda old: bool(checkpoint_strangers(old))) as tmp:  # still so when moved
        for name in MODEL_DIRS[skill.layout]:
            skill.models[name].save(tmp / name)
        for name, writer in (extra or {}).items():
            writer(tmp / name)
        record = {"format": SKILL_FORMAT, "layout": skill.layout, "models": list(MODEL_DIRS[skill.layout]),
                  "metadata": skill.metadata, "training": skill.training}
        (tmp / SKILL_FILE).write_text(json.dumps(record, indent=2, allow_nan=True))
        write_manifest(tmp)
    return out


def load_skill(directory: str | os.PathLike[str]) -> PoseSkill:
    """Read a checkpoint written by `save_skill`.

    Raises:
        RFlowError: missing directory, missing or corrupt skill.json, or a missing/corrupt model.
    """
    src = Path(directory)
    if not src.is_dir():
        raise RFlowError(f"checkpoint directory {src} not found")
    record = read_json(src / SKILL_FILE, f"no {SKILL_FILE} in checkpoint {src} (not a `pih train` output?)")
    if not isinstance(record, dict) or record.get("format") != SKILL_FORMAT:
        got = record.get("format") if isinstance(record, dict) else type(record).__name__
        raise RFlowError(f"{src / SKILL_FILE} has format {got!r}, expected {SKILL_FORMAT!r}")
    layout = record.get("layout")
    if layout not in LAYOUTS:
        raise RFlowError(f"{src / SKILL_FILE} has unknown layout {layout!r}")
    for name in MODEL_DIRS[layout]:
        _check_finite_weights(src / name)
    models = {name: PoseFlow.load(src / name) for name in MODEL_DIRS[layout]}
    metadata, training = record.get("metadata", {}), record.get("training", {})
    if not isinstance(metadata, dict) or not isinstance(training, dict):
        raise RFlowError(f"corrupt {src / SKILL_FILE}: metadata and training must be JSON objects")
    skill = PoseSkill(layout, models, metadata, training)
    _check_models(skill, src)
    return skill


def _check_finite_weights(model_dir: Path) -> None:
    """Raise RFlowError naming the weights file when a tensor in it is NaN or inf (a missing or unreadable
    file is left to RiemannianFlow.load to report). Read with weights_only=True."""
    import torch

    from rflow.model import WEIGHTS_FILE

    path = model_dir / WEIGHTS_FILE
    try:
        with warnings.catch_warnings():  # torch warns about pickle protocols before refusing them
            warnings.simplefilter("ignore")
            state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception:  # noqa: BLE001 -- reported by RiemannianFlow.load with its own message
        return
    if not isinstance(state, dict):
        return
    for key, tensor in state.items():
        if isinstance(tensor, torch.Tensor) and tensor.is_floating_point() and not bool(tensor.isfinite().all()):
            raise RFlowError(f"{path}: weight {key!r} contains NaN or inf")


def _check_models(skill: PoseSkill, src: Path) -> None:
    expected = {"position": ("euclidean", (3,)), "orientation": ("sphere", (4,)), "joint": ("pose", (7,)),
                "stiffness": (POSITION_STIFFNESS.name, (POSITION_STIFFNESS.point_size,))}
    for name, model in skill.models.items():
        manifold, shape = expected[name]
        if name == "joint" and model.manifold.name == POSE_STIFFNESS.name:
            manifold, shape = POSE_STIFFNESS.name, (POSE_STIFFNESS.point_size,)
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
                   layout: str = "separate", progress: bool = True, stiffness: npt.ArrayLike | None = None,
                   bounds: StiffnessBounds | None = None, workers: int = 1) -> PoseSkill:
    """Train the models of a pose skill on peg_tip demonstrations (rflow.train.fit per model).

    Args:
        pos: (N, M, 3) positions, all ending at the goal position.
        quat: (N, M, 4) unit quaternions w-x-y-z, all ending at the goal orientation.
        dt: sampling time (s).
        config: rflow.train.TrainConfig shared by the models (default: the paper's).
        layout: "separate" (position on R^3 and orientation on S^3, as in the paper), "joint"
            (one model on R^3 x S^3, or on R^3 x S^3 x SPD(3) with ``stiffness``) or "separate_stiffness" (the two
            separate models and, with ``stiffness``, a third on R^3 x SPD(3)).
        progress: tqdm bars.
        stiffness: optional (N, M, 3, 3) translational stiffness (N/m, SPD, ending at one goal stiffness),
            learned inside the joint model (layout "joint") or by the stiffness model (layout "separate_stiffness").
        bounds: [k_min, k_max] of the stiffness (default `StiffnessBounds()`); every demonstrated
            stiffness must lie inside, and the skill clips generated stiffness to them.
        workers: with 2 or more and the separate layout, the two models train at the same time in two
            processes (`rflow.fit_processes`; the same weights, bit for bit; timings in the README).

    Returns:
        The PoseSkill, with ``training`` holding each model's config and loss history, and with stiffness
        ``metadata["stiffness"]`` = {k_min_n_m, k_max_n_m, start_n_m (Log-Euclidean mean of the demos'
        first stiffness), goal_n_m}.

    Raises:
        RFlowError: bad shapes, NaN, demos without a shared goal, diverged training, unknown layout,
            stiffness with the separate layout, non-SPD stiffness or stiffness outside the bounds.
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
    metadata: dict[str, Any] = {}
    if stiffness is not None:
        k, limits = _check_demo_stiffness(stiffness, p.shape[:2], layout, bounds)
        if layout == "separate_stiffness":
            data = {"position": (p, "euclidean"), "orientation": (q, "sphere"),
                    "stiffness": (np.concatenate([p, k.reshape(k.shape[:2] + (9,))], axis=-1), POSITION_STIFFNESS)}
        else:
            data = {"joint": (np.concatenate([p, q, k.reshape(k.shape[:2] + (9,))], axis=-1), POSE_STIFFNESS)}
        metadata["stiffness"] = {"k_min_n_m": limits.k_min_n_m, "k_max_n_m": limits.k_max_n_m,
                                 "start_n_m": log_euclidean_mean(k[:, 0]).tolist(), "goal_n_m": k[0, -1].tolist()}
    elif layout == "joint":
        data = {"joint": (np.concatenate([p, q], axis=-1), POSE)}
    elif layout == "separate_stiffness":
        raise RFlowError("the separate_stiffness layout needs the demos' stiffness")
    else:
        data = {"position": (p, "euclidean"), "orientation": (q, "sphere")}
    models: dict[str, RiemannianFlow] = {}
    training: dict[str, Any] = {}
    if workers > 1 and len(data) > 1:
        from rflow.fit_processes import fit_in_processes

        if progress:
            print(f"training the {' and '.join(data)} models in {min(workers, len(data))} processes "
                  f"({p.shape[0]} demos x {p.shape[1]} samples)", flush=True)
        fitted = fit_in_processes({name: (np.asarray(demos), manifold) for name, (demos, manifold) in data.items()},
                                  dt, cfg, workers, progress, PoseFlow.load)
    else:
        fitted = {}
        for name, (demos, manifold) in data.items():
            if progress:
                print(f"training the {name} model ({np.asarray(demos).shape[0]} demos x {np.asarray(demos).shape[1]} samples)")
            fitted[name] = fit(demos, manifold, dt, cfg, progress=progress)
    for name, (model, history) in fitted.items():
        models[name] = model
        training[name] = {"config": asdict(cfg), "history": asdict(history)}
    return PoseSkill(layout, models, metadata, training)


def _check_demo_stiffness(stiffness: npt.ArrayLike, lead: tuple[int, ...], layout: str,
                          bounds: StiffnessBounds | None) -> tuple[np.ndarray, StiffnessBounds]:
    """The demos' stiffness (N, M, 3, 3) as SPD float64, checked against the layout and the bounds."""
    if layout not in ("joint", "separate_stiffness"):
        raise RFlowError("stiffness is learned by a joint model R^3 x S^3 x SPD(3) (layout 'joint') or beside the "
                         "pose models (layout 'separate_stiffness')")
    limits = StiffnessBounds() if bounds is None else bounds
    k = np.asarray(POSE_STIFFNESS.factors[2][0].check_points(np.asarray(stiffness, dtype=np.float64), "stiffness"))
    if k.shape != tuple(lead) + (3, 3):
        raise RFlowError(f"stiffness has shape {k.shape}, expected {tuple(lead) + (3, 3)} to match the poses")
    lam = eigh_sym(k)[0]
    if not limits.contains(k):
        raise RFlowError(f"demonstrated stiffness has eigenvalues in [{lam.min():.4g}, {lam.max():.4g}] N/m, outside "
                         f"the bounds [{limits.k_min_n_m:g}, {limits.k_max_n_m:g}] N/m")
    return k, limits


def stiffness_reproduction(skill: PoseSkill, pos: npt.ArrayLike, quat: npt.ArrayLike,
                           stiffness: npt.ArrayLike) -> dict[str, Any]:
    """How well a stiffness skill reproduces the demonstrated stiffness: from each demo's start [p, q, K]
    generate M - 1 exact steps of the skill's dt (Algorithm 1, no early stop), clip the stiffness to the
    bounds, and take the mean Log-Euclidean distance 1/M sum_m ||logm(K_m) - logm(K_hat_m)||_F per demo.

    Args:
        skill: a stiffness skill.
        pos, quat, stiffness: the (subsampled) training demos (N, M, 3), (N, M, 4), (N, M, 3, 3).

    Returns:
        JSON-ready {"log_euclidean_mean", "log_euclidean_per_demo" (N,), "clip_fraction" (of generated
        samples the eigenvalue clip changed), "clip_max_log_change" (the largest |log(lambda_clipped /
        lambda)| of any eigenvalue: how far outside the bounds generation went)}.

    Raises:
        RFlowError: a skill without stiffness, bad shapes.
    """
    from rflow.generate import rollout
    from rflow.stiffness import profile_distance

    skill._require_stiffness()
    p, q, k = (np.asarray(a, dtype=np.float64) for a in (pos, quat, stiffness))
    if p.ndim != 3 or k.shape != p.shape[:2] + (3, 3) or q.shape != p.shape[:2] + (4,):
        raise RFlowError(f"demos need pos (N, M, 3), quat (N, M, 4), stiffness (N, M, 3, 3); got {p.shape}, "
                         f"{q.shape}, {k.shape}")
    if skill.layout == "separate_stiffness":
        starts = np.asarray(POSITION_STIFFNESS.prepare(skill.stiffness_point(p, k)))[:, 0]
        points = rollout(skill.models["stiffness"], starts, p.shape[1] - 1, xi=1e-12).points
        generated = points[..., 3:].reshape(points.shape[:-1] + (3, 3))
    else:
        starts = np.asarray(POSE_STIFFNESS.prepare(skill.joint_point(p, q, k)))[:, 0]
        generated = skill.split_point(rollout(skill.models["joint"], starts, p.shape[1] - 1, xi=1e-12).points)[2]
    bounded, clipped = skill.bound_stiffness(generated)
    per_demo = profile_distance(k, bounded)
    change = np.abs(np.log(eigh_sym(bounded)[0] / eigh_sym(generated)[0]))
    return {"log_euclidean_mean": float(per_demo.mean()), "log_euclidean_per_demo": per_demo.tolist(),
            "clip_fraction": float(clipped.mean()), "clip_max_log_change": float(change.max())}
