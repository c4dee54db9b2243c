"""The paper's naive baseline: learn manifold data as Euclidean vectors, project the output back.

Unit quaternions are learned as raw 4-D vectors and the generated vectors are normalised to unit norm.
2x2 SPD matrices are learned as the 3-D vector of their unique entries in Mandel's notation
[S11, S22, sqrt2 S12] (the paper's footnote; with the per-dimension normalisation this is the same learning
problem as [S11, S22, S12]), and each generated vector becomes the nearest SPD matrix (Higham 1988) of the
symmetric matrix it describes. The learner is the same ImitationFlow, on the Euclidean manifold with the
goal at the demos' last point.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from rflow.errors import RFlowError
from rflow.generate import rollout
from rflow.manifolds import get_manifold, spd
from rflow.model import RiemannianFlow
from rflow.train import TrainConfig, TrainHistory, fit

NAIVE_MANIFOLDS = ("spd", "sphere")
_MIN_QUATERNION_NORM = 1e-12  # a generated 4-vector shorter than this has no direction


def _check_manifold(manifold: str) -> str:
    if manifold not in NAIVE_MANIFOLDS:
        raise RFlowError(f"naive baseline: unknown manifold {manifold!r}; expected one of {NAIVE_MANIFOLDS}")
    return manifold


def to_features(points: npt.ArrayLike, manifold: str) -> np.ndarray:
    """Euclidean features of manifold points: quaternions as they are, SPD matrices as Mandel vectors.

    Args:
        points: (..., 4) unit quaternions (w, x, y, z) or (..., d, d) SPD matrices.
        manifold: "sphere" or "spd".

    Returns:
        (..., 4) or (..., d(d+1)/2) features.

    Raises:
        RFlowError: unknown manifold or points off the manifold.
    """
    if _check_manifold(manifold) == "sphere":
        return np.asarray(get_manifold("sphere").check_points(points, "quaternions"), dtype=np.float64)
    return np.asarray(spd.mandel(get_manifold("spd").check_points(points, "SPD matrices")), dtype=np.float64)


def to_points(features: npt.ArrayLike, manifold: str) -> np.ndarray:
    """Project Euclidean features back onto the manifold.

    Quaternions: q = f / ||f||. SPD: P = nearest_spd(mandel_inverse(f)) (Higham 1988).

    Args:
        features: (..., 4) or (..., d(d+1)/2) vectors.
        manifold: "sphere" or "spd".

    Returns:
        (..., 4) unit quaternions or (..., d, d) SPD matrices.

    Raises:
        RFlowError: unknown manifold, NaN, wrong length, or a (near) zero 4-vector.
    """
    manifold = _check_manifold(manifold)
    f = np.asarray(get_manifold("euclidean").check_points(features, "naive features"), dtype=np.float64)
    if manifold == "spd":
        return np.asarray(spd.nearest_spd(spd.mandel_inverse(f)), dtype=np.float64)
    if f.shape[-1] != 4:
        raise RFlowError(f"naive features have shape {f.shape}, expected (..., 4) for quaternions")
    length = np.linalg.norm(f, axis=-1, keepdims=True)
    if float(length.min(initial=np.inf)) < _MIN_QUATERNION_NORM:
        raise RFlowError("naive features: a generated quaternion vector is (near) zero, cannot normalise")
    return f / length


@dataclass(frozen=True)
class NaiveModel:
    """A Euclidean RiemannianFlow on naive features, with the projection back to the manifold.

    Attributes:
        manifold: "sphere" or "spd", where the generated points are projected.
        flow: the model trained on the Euclidean features.
    """

    manifold: str
    flow: RiemannianFlow

    def generate(self, starts: npt.ArrayLike, steps: int, xi: float = 1e-3) -> np.ndarray:
        """Roll out the Euclidean model from manifold start points and project every point.

        Args:
            starts: (K, *point_shape) start points on the manifold.
            steps: integration steps (see `rflow.generate.rollout`).
            xi: stop threshold on the Euclidean tangent norm ||f - f_goal|| (> 0).

        Returns:
            (K, L, *point_shape) projected points, L as returned by `rollout`.

        Raises:
            RFlowError: invalid starts, steps < 0 or xi <= 0.
        """
        result = rollout(self.flow, to_features(starts, self.manifold), steps, xi=xi)
        return to_points(result.points, self.manifold)


def fit_naive(
    demos: npt.ArrayLike, manifold: str, dt: float, config: TrainConfig = TrainConfig(), progress: bool = True
) -> tuple[NaiveModel, TrainHistory]:
    """Train the naive baseline: `rflow.train.fit` on the Euclidean features of the demos.

    Args:
        demos: (N, M, 4) unit quaternions or (N, M, d, d) SPD matrices, all ending at one goal.
        manifold: "sphere" or "spd".
        dt: sampling time (s).
        config: hyperparameters, the same as RiemannianFlow's.
        progress: show a progress bar.

    Returns:
        The model and its loss history.

    Raises:
        RFlowError: unknown manifold, invalid demos, or a failed training.
    """
    manifold = _check_manifold(manifold)
    points = np.asarray(demos, dtype=np.float64)
    if manifold == "sphere":
        points = np.asarray(get_manifold("sphere").prepare(points))  # same hemisphere handling as rflow
    flow, history = fit(to_features(points, manifold), "euclidean", dt, config, progress=progress)
    return NaiveModel(manifold=manifold, flow=flow), history
