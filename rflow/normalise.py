"""Per-dimension normalisation of tangent vectors (PAPER.md step 6): z = (v - mean) / std."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from rflow.errors import RFlowError

STD_FLOOR = 0.05
"""A dimension's std is at least this fraction of the largest std (and > 0). It binds only for dimensions the
demos (almost) never vary in, e.g. the off-diagonal stiffness of a pose + stiffness skill along a vertical hole
axis (exactly 0): with 1e-3 a start 0.01 off in such a direction lay 12 std out, where the flow, never trained
there, sent the stiffness to 1e23 N/m; with 0.05 it lies within the identity prior's box (rflow.train)."""


@dataclass(frozen=True)
class Normalisation:
    """Affine map of tangent vectors to zero mean, unit variance per dimension.

    Attributes:
        mean: (D,) per-dimension mean of the training tangent vectors.
        std: (D,) per-dimension standard deviation (floored, see STD_FLOOR).
    """

    mean: np.ndarray
    std: np.ndarray

    def __post_init__(self) -> None:
        mean = np.asarray(self.mean, dtype=np.float64).reshape(-1)
        std = np.asarray(self.std, dtype=np.float64).reshape(-1)
        if mean.shape != std.shape or mean.size == 0:
            raise RFlowError(f"normalisation mean {mean.shape} and std {std.shape} must be equal non-empty vectors")
        if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(std)) and np.all(std > 0)):
            raise RFlowError("normalisation mean/std must be finite with std > 0")
        object.__setattr__(self, "mean", mean)
        object.__setattr__(self, "std", std)

    @classmethod
    def fit(cls, tangent: npt.ArrayLike) -> "Normalisation":
        """Mean and std over all leading axes of tangent vectors (..., D).

        Raises:
            RFlowError: fewer than two vectors, NaN.
        """
        v = np.asarray(tangent, dtype=np.float64)
        if v.ndim < 1:
            raise RFlowError("tangent vectors must have at least one dimension")
        flat = v.reshape(-1, v.shape[-1])
        if flat.shape[0] < 2 or not np.all(np.isfinite(flat)):
            raise RFlowError(f"cannot normalise {flat.shape[0]} tangent vectors (need >= 2, finite)")
        std = flat.std(axis=0)
        floor = max(STD_FLOOR * float(std.max()), 1e-12)
        return cls(flat.mean(axis=0), np.maximum(std, floor))

    @property
    def dim(self) -> int:
        """Tangent dimension D."""
        return int(self.mean.size)

    def apply(self, tangent: npt.ArrayLike) -> np.ndarray:
        """z = (v - mean) / std."""
        return (np.asarray(tangent, dtype=np.float64) - self.mean) / self.std

    def invert(self, z: npt.ArrayLike) -> np.ndarray:
        """v = z * std + mean."""
        return np.asarray(z, dtype=np.float64) * self.std + self.mean

    @property
    def goal(self) -> np.ndarray:
        """The normalised image z_g = -mean / std of the goal (tangent vector 0)."""
        return -self.mean / self.std

    def to_dict(self) -> dict[str, list[float]]:
        """JSON-ready dictionary."""
        return {"mean": self.mean.tolist(), "std": self.std.tolist()}

    @classmethod
    def from_dict(cls, data: dict) -> "Normalisation":
        """Inverse of `to_dict`. Raises RFlowError on missing or bad fields."""
        try:
            return cls(np.asarray(data["mean"], dtype=np.float64), np.asarray(data["std"], dtype=np.float64))
        except (KeyError, TypeError, ValueError) as err:
            raise RFlowError(f"bad normalisation record: {err}") from None
