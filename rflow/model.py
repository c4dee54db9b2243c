"""ImitationFlow in the normalised tangent space at the goal, and the RiemannianFlow skill model.

ImitationFlow (Urain et al. 2020): latent q follows the stable linear SDE of `rflow.dynamics`; the
observation (normalised tangent vector) is p = b(q) with the coupling flow of `rflow.flow`. The goal is
exact: the tangent goal is 0, normalised z_g = -mean/std, and the learned map is
    b(q) = b_theta(q + c),   c = b_theta^-1(z_g),
a diffeomorphism composed with a translation of the latent space (same Jacobian), so b(0) = z_g and every
latent trajectory, which converges to 0, converges in observation space to the goal itself. (Translating
in latent space lets training get c from the same batched inverse pass as the data.)

`RiemannianFlow` bundles manifold, goal, normalisation, sampling time and the network, and saves/loads
them: weights with torch.save(state_dict) / torch.load(weights_only=True), the rest as JSON.
"""

from __future__ import annotations

import json
import math
import pickle
import warnings
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import torch
from torch import nn

from numerics.errors import shown
from pihutil.bounds import LOG_SCALE_CLAMP
from rflow.dynamics import StableLinearDynamics
from rflow.errors import RFlowError
from rflow.flow import ACTIVATIONS, CouplingFlow
from rflow.manifolds import Manifold, get_manifold
from rflow.normalise import Normalisation

CONFIG_FILE = "model.json"
WEIGHTS_FILE = "weights.pt"
FORMAT = "rflow.RiemannianFlow/1"


MAX_WIDTH = 4096
MAX_HIDDEN_LAYERS = 16


def read_json(path: Path, missing: str) -> Any:
    """The JSON value in the file ``path`` (a model's or a checkpoint's record).

    Raises:
        RFlowError: ``missing`` when there is no such file; "corrupt PATH: ..." when it cannot be read or parsed.
    """
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise RFlowError(missing) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise RFlowError(f"corrupt {path}: {err}") from None


@dataclass(frozen=True)
class ModelConfig:
    """Architecture of ImitationFlow (paper: 11 coupling layers, ReLU).

    Attributes:
        layers: coupling layers of the flow b_theta.
        width: hidden units of each coupling MLP.
        hidden_layers: hidden layers of each coupling MLP.
        activation: "relu" or "tanh".
        log_scale_clamp: c in s = c tanh(s_raw / c), bounds each layer's log-scale.
        min_rate: eps of the latent drift V (1/s): every eigenvalue has real part <= -min_rate.
    """

    layers: int = 11
    width: int = 64
    hidden_layers: int = 1
    activation: str = "relu"
    log_scale_clamp: float = 2.0
    min_rate: float = 0.05

    def __post_init__(self) -> None:
        for name in ("layers", "width", "hidden_layers"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int):
                raise RFlowError(f"{name}={value!r} must be an integer")
        for name in ("log_scale_clamp", "min_rate"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise RFlowError(f"{name}={value!r} must be a number")
        if not isinstance(self.activation, str):
            raise RFlowError(f"activation={self.activation!r} must be a name, one of {sorted(ACTIVATIONS)}")
        if not 1 <= self.layers <= 64:
            raise RFlowError(f"layers {self.layers} must be in 1..64")
        if not (1 <= self.width <= MAX_WIDTH and 1 <= self.hidden_layers <= MAX_HIDDEN_LAYERS):
            raise RFlowError(f"width {self.width} and hidden_layers {self.hidden_layers} must be in 1..{MAX_WIDTH} "
                             f"and 1..{MAX_HIDDEN_LAYERS}")
        if self.activation not in ACTIVATIONS:
            raise RFlowError(f"unknown activation {self.activation!r}; expected one of {sorted(ACTIVATIONS)}")
        if not (LOG_SCALE_CLAMP.contains(self.log_scale_clamp) and self.min_rate > 0):
            raise RFlowError(f"log_scale_clamp {self.log_scale_clamp!r} must be {LOG_SCALE_CLAMP.text()} and min_rate "
                             f"{self.min_rate!r} > 0")


class ImitationFlow(nn.Module):
    """Flow b (latent -> normalised tangent) with the exact goal, plus the stable latent dynamics.

    Args:
        dim: tangent dimension D (>= 2).
        config: architecture.
        goal: z_g (D,), the normalised tangent goal, where b sends the latent origin.
        init_rate: initial latent convergence rate (1/s), V = -init_rate I at start.
        init_noise: initial diagonal diffusion F.
    """

    def __init__(
        self,
        dim: int,
        config: ModelConfig,
        goal: npt.ArrayLike,
        init_rate: float = 1.0,
        init_noise: float = 0.5,
    ):
        super().__init__()
        self.config = config
        self.flow = CouplingFlow(
            dim, config.layers, config.width, config.hidden_layers, config.activation, config.log_scale_clamp
        )
        self.dynamics = StableLinearDynamics(dim, config.min_rate, max(init_rate, config.min_rate), init_noise)
        goal_t = torch.as_tensor(np.asarray(goal, dtype=np.float64)).reshape(-1)
        if goal_t.numel() != dim:
            raise RFlowError(f"normalised goal has {goal_t.numel()} entries, expected {dim}")
        self.register_buffer("goal", goal_t.to(torch.get_default_dtype()))

    @property
    def dim(self) -> int:
        """Tangent dimension D."""
        return self.flow.dim

    def offset(self) -> torch.Tensor:
        """c = b_theta^-1(z_g), the latent translation that makes b(0) = z_g exactly, (D,)."""
        return self.flow.inverse(self.goal[None])[0][0]

    def observe(self, q: torch.Tensor, offset: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """p = b(q) = b_theta(q + c); returns (p, log|det dp/dq|)."""
        return self.flow(q + (self.offset() if offset is None else offset))

    def latent(self, p: torch.Tensor, offset: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """q = b^-1(p) = b_theta^-1(p) - c; returns (q, log|det dq/dp|)."""
        q, logdet = self.flow.inverse(p)
        return q - (self.offset() if offset is None else offset), logdet

    def transition_log_prob(self, p0: torch.Tensor, p1: torch.Tensor, tau: torch.Tensor) -> torch.Tensor:
        """log p(p1 | p0) over times tau (B,) s: log N(b^-1(p1); Phi b^-1(p0), Sigma) + log|det db^-1/dp (p1)|.

        Args:
            p0, p1: normalised tangent vectors (B, D), p1 observed tau after p0.
            tau: (B,) elapsed times in seconds.

        Returns:
            (B,) conditional log-densities.
        """
        n = p0.shape[0]
        q, logdet = self.flow.inverse(torch.cat([p0, p1, self.goal[None].to(p0.dtype)], 0))
        q = q[:-1] - q[-1]  # the goal row gives c in the same pass
        unique, index = torch.unique(tau, return_inverse=True)
        phi, sigma = self.dynamics.transition(unique)
        return self.dynamics.log_prob(q[:n], q[n:], phi[index], sigma[index]) + logdet[n:-1]

    def transition_log_prob_and_latent(self, p0: torch.Tensor, p1: torch.Tensor, tau: torch.Tensor,
                                       points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """`transition_log_prob` of (p0, p1, tau) and the latent points b^-1(points), from ONE inverse pass.

        Training with the off-data prior (`rflow.train.identity_prior`) needs both; one pass over all rows
        instead of two halves the per-layer work of Python and autograd, which dominates at these sizes (a
        step of the skill's training, batch 128 with the prior, one thread: 6.1 instead of 9.2 ms). The
        result equals the two passes up to float32 rounding.

        Args:
            p0, p1: normalised tangent vectors (B, D), p1 observed tau after p0.
            tau: (B,) elapsed times in seconds.
            points: (K, D) further normalised tangent vectors.

        Returns:
            (B,) conditional log-densities and (K, D) latent points q = b^-1(points) (goal-centred, as `latent`).
        """
        n, k = p0.shape[0], points.shape[0]
        q, logdet = self.flow.inverse(torch.cat([p0, p1, points, self.goal[None].to(p0.dtype)], 0))
        q = q[:-1] - q[-1]  # the goal row gives c in the same pass
        unique, index = torch.unique(tau, return_inverse=True)
        phi, sigma = self.dynamics.transition(unique)
        log_prob = self.dynamics.log_prob(q[:n], q[n:2 * n], phi[index], sigma[index]) + logdet[n:2 * n]
        return log_prob, q[2 * n:2 * n + k]


class RiemannianFlow:
    """A learned skill on a manifold: Log at the goal, normalisation, ImitationFlow, Exp back.

    Attributes:
        manifold: the manifold of the points.
        goal: the goal point (point shape, e.g. (3,), (4,), (d, d)).
        normalisation: per-dimension tangent normalisation.
        dt: sampling time of the demonstrations (s), the step of generation.
        config: architecture of the network.
        network: the trained ImitationFlow (float64, eval mode).
    """

    def __init__(
        self,
        manifold: str | Manifold,
        goal: npt.ArrayLike,
        normalisation: Normalisation,
        dt: float,
        config: ModelConfig,
        network: ImitationFlow,
    ):
        self.manifold = get_manifold(manifold)
        goal_arr = np.asarray(self.manifold.check_points(np.asarray(goal, dtype=np.float64), "goal"))
        if goal_arr.ndim != self.manifold.point_ndim:
            raise RFlowError(f"goal has shape {goal_arr.shape}, expected one {self.manifold.name} point")
        self.goal = goal_arr
        if not (np.isfinite(dt) and dt > 0):
            raise RFlowError(f"sampling time dt={dt} must be > 0")
        self.dt = float(dt)
        self.normalisation = normalisation
        self.config = config
        self.network = network.double().eval()
        if normalisation.dim != network.dim or self.manifold.tangent_dim(goal_arr.shape) != network.dim:
            raise RFlowError(
                f"dimensions disagree: tangent {self.manifold.tangent_dim(goal_arr.shape)}, "
                f"normalisation {normalisation.dim}, network {network.dim}"
            )
        z_goal = torch.as_tensor(normalisation.goal, dtype=torch.float64)
        if not torch.allclose(network.goal, z_goal, rtol=1e-5, atol=1e-5):
            raise RFlowError("network goal differs from the normalised tangent goal -mean/std")
        with torch.no_grad():
            self.network.goal.copy_(z_goal)  # exact in float64 (training may have rounded it to float32)
        self._inference: Any = None
        self._chart: Any = None

    @property
    def dim(self) -> int:
        """Tangent dimension D."""
        return self.network.dim

    @property
    def point_shape(self) -> tuple[int, ...]:
        """Shape of one point on the manifold."""
        return tuple(self.goal.shape)

    def to_tangent(self, points: npt.ArrayLike) -> np.ndarray:
        """Tangent vectors (..., D) at the goal of points (..., *point_shape). Raises RFlowError on bad points."""
        return np.asarray(self.manifold.log(points, self.goal))

    def from_tangent(self, tangent: npt.ArrayLike) -> np.ndarray:
        """Points (..., *point_shape) of tangent vectors (..., D) at the goal. Raises RFlowError on bad input."""
        v = np.asarray(tangent, dtype=np.float64)
        if v.ndim < 1 or v.shape[-1] != self.dim:
            raise RFlowError(f"tangent has shape {v.shape}, expected (..., {self.dim})")
        if not np.all(np.isfinite(v)):
            raise RFlowError("tangent contains NaN or inf")
        if self.manifold.name == "spd":
            return self.chart.exp(v)  # G^(+-1/2) precomputed: one eigendecomposition instead of four
        return np.asarray(self.manifold.exp(v, self.goal))

    def normalise(self, tangent: npt.ArrayLike) -> np.ndarray:
        """z = (v - mean) / std."""
        return self.normalisation.apply(tangent)

    def denormalise(self, z: npt.ArrayLike) -> np.ndarray:
        """v = z std + mean."""
        return self.normalisation.invert(z)

    @property
    def inference(self) -> Any:
        """The numpy export of the network (`rflow.inference.NumpyImitationFlow`), built on first use.

        Call `refresh_inference()` after changing the network's weights.
        """
        if self._inference is None:
            from rflow.inference import NumpyImitationFlow

            self._inference = NumpyImitationFlow.from_network(self.network, self.dt)
        return self._inference

    @property
    def chart(self) -> Any:
        """Single-point Log_g / Exp_g (`rflow.inference.TangentChart`), built on first use."""
        if self._chart is None:
            from rflow.inference import TangentChart

            self._chart = TangentChart(self.manifold, self.goal)
        return self._chart

    def refresh_inference(self) -> None:
        """Drop the cached numpy export (rebuilt on next use)."""
        self._inference = None

    # ---- persistence -------------------------------------------------------------------------------
    def save(self, directory: str | Path) -> Path:
        """Write ``model.json`` (manifold, goal, dt, normalisation, architecture) and ``weights.pt``.

        Returns:
            The directory.
        """
        out = Path(directory)
        out.mkdir(parents=True, exist_ok=True)
        record = {
            "format": FORMAT,
            "manifold": self.manifold.name,
            "goal": self.goal.tolist(),
            "dt": self.dt,
            "dim": self.dim,
            "normalisation": self.normalisation.to_dict(),
            "model": asdict(self.config),
        }
        (out / CONFIG_FILE).write_text(json.dumps(record, indent=2))
        torch.save(self.network.state_dict(), out / WEIGHTS_FILE)
        return out

    @classmethod
    def load(cls, directory: str | Path) -> "RiemannianFlow":
        """Load a model written by `save`.

        Raises:
            RFlowError: missing or corrupt model.json / weights.pt, or weights that do not fit.
        """
        src = Path(directory)
        record = read_json(src / CONFIG_FILE, f"no {CONFIG_FILE} in model directory {src}")
        if record.get("format") != FORMAT:
            raise RFlowError(f"{src / CONFIG_FILE} has format {record.get('format')!r}, expected {FORMAT!r}")
        try:
            names = {f.name for f in fields(ModelConfig)}
            model = record["model"]
            if not isinstance(model, dict):
                raise RFlowError(f"'model' must be an object, got {shown(model)}")
            try:
                config = ModelConfig(**{k: v for k, v in model.items() if k in names})
            except RFlowError as err:
                raise RFlowError(f"model.{err}") from None
            normalisation = Normalisation.from_dict(record["normalisation"])
            dim, dt = record["dim"], record["dt"]
            if isinstance(dim, bool) or not isinstance(dim, int):
                raise RFlowError(f"dim={shown(dim)} must be an integer")
            if isinstance(dt, bool) or not isinstance(dt, (int, float)) or not (math.isfinite(dt) and dt > 0):
                raise RFlowError(f"dt={shown(dt)} must be a positive number of seconds")
            manifold = record["manifold"]
            goal = np.asarray(record["goal"], dtype=np.float64)
        except KeyError as err:
            raise RFlowError(f"corrupt {src / CONFIG_FILE}: missing field {err}") from None
        except (RFlowError, TypeError, ValueError, AttributeError) as err:
            what = err if isinstance(err, RFlowError) else f"a field of the wrong type ({err})"
            raise RFlowError(f"corrupt {src / CONFIG_FILE}: {what}") from None
        if dim != normalisation.mean.size:  # checked before the network is built: its size follows dim
            raise RFlowError(f"corrupt {src / CONFIG_FILE}: dim={dim} differs from the normalisation's "
                             f"{normalisation.mean.size} dimensions")
        network = ImitationFlow(dim, config, normalisation.goal).double()
        try:
            with warnings.catch_warnings():  # torch warns about pickle protocols before refusing them
                warnings.simplefilter("ignore")
                state = torch.load(src / WEIGHTS_FILE, map_location="cpu", weights_only=True)
        except FileNotFoundError:
            raise RFlowError(f"no {WEIGHTS_FILE} in model directory {src}") from None
        except pickle.UnpicklingError:  # never unpickled: a foreign or damaged file
            raise RFlowError(f"corrupt {src / WEIGHTS_FILE}: not a file of plain tensors (it is damaged, or it "
                             "needs unpickling, which pih never does)") from None
        except Exception as err:  # torch raises assorted errors for truncated or foreign files
            first_line = str(err).splitlines()[0] if str(err) else ""
            raise RFlowError(f"corrupt {src / WEIGHTS_FILE}: {type(err).__name__}: {first_line}") from None
        try:
            network.load_state_dict(state)
        except (RuntimeError, TypeError, AttributeError) as err:
            first_line = str(err).splitlines()[0]
            raise RFlowError(
                f"{src / WEIGHTS_FILE} does not fit the architecture in {CONFIG_FILE}: {first_line}"
            ) from None
        return cls(manifold, goal, normalisation, dt, config, network)
