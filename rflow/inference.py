"""Fast numpy inference of a trained ImitationFlow (no torch on the control path).

The exported network computes exactly what `rflow.model.ImitationFlow` computes in float64 (equal to ~1e-12),
with the coupling masks folded into the weights: the first layer's rows for the moved coordinates and the
output columns for the conditioner coordinates are zero, so every layer works on the full vector,
    h = act(x W_1 + b_1) ...,  [u, t] = h W_out + b_out,  s = c tanh(u),  y = x * exp(s) + t,
with 1/c folded into the u half of W_out, and b(q) = b_theta(q + c) with the latent offset c = b_theta^-1(z_g)
of `rflow.model`. Batches run as stacks of small blocks (see `NumpyImitationFlow`); single points (the
control loop) use preallocated buffers and weights augmented with the bias row, about ten numpy calls per
layer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import scipy.linalg

from rflow.errors import RFlowError


@dataclass(frozen=True)
class _Layer:
    weights: tuple[np.ndarray, ...]  # hidden layers, (in, out); the first has the moved coordinates' rows zeroed
    biases: tuple[np.ndarray, ...]
    w_out: np.ndarray  # (H, 2D) = [u | t]; u columns scaled by 1/c; conditioner columns zero
    b_out: np.ndarray  # (2D,)
    augmented: tuple[np.ndarray, ...]  # [W; b] of every linear layer, for the single-point path
    clamp: float


class NumpyImitationFlow:
    """Numpy copy of an ImitationFlow: b (latent -> normalised tangent), b^-1, and exact latent steps.

    Build with `from_network`. Batch methods take (N, D) or (D,) arrays and return (N, D);
    `step_single` is the allocation-free closed-loop step of one point.

    Attributes:
        offset: c = b_theta^-1(z_g), the latent translation of the exact goal, (D,).
        drift: the latent drift matrix V, (D, D).
        dt: default step (s).
        dim: tangent dimension D.
    """

    # Batches run as stacks of small blocks, (n_blocks, rows, D + 1) @ W: numpy multiplies each block with one
    # single-threaded BLAS call (OpenBLAS threads a product only above m n k = 2^18), which is as fast as one
    # large product on an idle machine and avoids the collapse of multi-threaded BLAS on a busy one.
    _BLOCK_MNK = 1 << 18
    _MAX_CACHED_STEPS = 64  # step matrices kept per dt

    def __init__(self, layers: list[_Layer], offset: np.ndarray, drift: np.ndarray, dt: float, relu: bool):
        self._layers = layers
        self.offset = offset
        self.drift = drift
        self.dt = float(dt)
        self.dim = int(offset.size)
        self._relu = relu
        self._steps: dict[float, np.ndarray] = {}
        self.step_matrix(self.dt)
        largest = max(w.shape[0] * w.shape[1] for layer in layers for w in layer.weights + (layer.w_out,))
        self._block_rows = max(8, self._BLOCK_MNK // largest)
        d = self.dim
        # single-point buffers: vectors with a trailing 1 so that biases ride along in the products
        self._x = np.ones(d + 1)
        self._xv = self._x[:d]
        widths = {w.shape[1] for layer in layers for w in layer.weights}
        self._hidden = {h: (np.ones(h + 1), np.ones(h + 1)) for h in widths}
        self._zeros = {h: np.zeros(h) for h in widths}
        self._out = np.zeros(2 * d)
        self._scale = self._out[:d]
        self._shift = self._out[d:]

    @classmethod
    def from_network(cls, network, dt: float) -> "NumpyImitationFlow":
        """Export a `rflow.model.ImitationFlow` (weights copied as float64)."""
        import torch

        with torch.no_grad():
            layers = []
            dim = network.dim
            for coupling in network.flow.layers:
                mask = coupling.mask.double().numpy()
                free = 1.0 - mask
                linears = [m for m in coupling.net if isinstance(m, torch.nn.Linear)]
                ws = [lin.weight.double().numpy().T.copy() for lin in linears[:-1]]
                bs = [lin.bias.double().numpy().copy() for lin in linears[:-1]]
                ws[0] = ws[0] * mask[:, None]
                c = float(coupling.log_scale_clamp)
                w_out = linears[-1].weight.double().numpy().T.copy()
                b_out = linears[-1].bias.double().numpy().copy()
                w_out[:, :dim] *= free / c
                b_out[:dim] *= free / c
                w_out[:, dim:] *= free
                b_out[dim:] *= free
                aug = tuple(np.ascontiguousarray(np.vstack([w, b[None]])) for w, b in zip(ws + [w_out], bs + [b_out]))
                layers.append(_Layer(tuple(ws), tuple(bs), np.ascontiguousarray(w_out), b_out, aug, c))
            offset = network.offset().double().numpy().copy()
            drift = network.dynamics.drift_matrix().double().numpy().copy()
            relu = network.config.activation == "relu"
        return cls(layers, offset, drift, dt, relu)

    def step_matrix(self, dt: float) -> np.ndarray:
        """Phi(dt)^T = expm(V dt)^T (for row vectors: q_next = q @ Phi^T), cached per dt."""
        key = float(dt)
        phi_t = self._steps.get(key)
        if phi_t is None:
            if not (math.isfinite(key) and key > 0):
                raise RFlowError(f"step dt={dt} must be > 0")
            phi_t = np.ascontiguousarray(scipy.linalg.expm(self.drift * key).T)
            if len(self._steps) >= self._MAX_CACHED_STEPS:  # a jittering measured dt must not grow it forever
                self._steps.clear()
            self._steps[key] = phi_t
        return phi_t

    # ---- batches ------------------------------------------------------------------------------------

    def _scale_shift(self, layer: _Layer, xa: np.ndarray, sign: float) -> tuple[np.ndarray, np.ndarray]:
        """exp(sign * s) and t of one layer for blocks xa (n_blocks, rows, D + 1) whose last column is 1
        (the first layer's bias rides along in its product)."""
        h = xa @ layer.augmented[0]
        for k, (w, b) in enumerate(zip(layer.weights, layer.biases)):
            if k:
                h = h @ w
                h += b
            if self._relu:
                np.maximum(h, 0.0, out=h)
            else:
                np.tanh(h, out=h)
        out = h @ layer.w_out
        out += layer.b_out
        d = self.dim
        s = out[..., :d]
        np.tanh(s, out=s)
        s *= sign * layer.clamp
        np.exp(s, out=s)
        return s, out[..., d:]

    def _blocks(self, x: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray, int]:
        """x (N, D) copied into zero-padded blocks with a column of ones, (n_blocks, rows, D + 1); the view
        of its first D columns; and N."""
        arr = np.asarray(x, dtype=np.float64)
        if arr.ndim == 1:
            arr = arr[None]
        if arr.ndim != 2 or arr.shape[1] != self.dim:
            raise RFlowError(f"flow input has shape {np.shape(x)}, expected (N, {self.dim})")
        n = arr.shape[0]
        rows = max(1, min(n, self._block_rows))
        n_blocks = -(-n // rows)
        xa = np.ones((n_blocks * rows, self.dim + 1))
        xa[:n, : self.dim] = arr
        xa[n:, : self.dim] = 0.0
        xa = xa.reshape(n_blocks, rows, self.dim + 1)
        return xa, xa[..., : self.dim], n

    def forward(self, q: npt.ArrayLike) -> np.ndarray:
        """p = b(q) = b_theta(q + c) for latent points (N, D) -> (N, D)."""
        xa, x, n = self._blocks(q)
        x += self.offset
        for layer in self._layers:
            scale, shift = self._scale_shift(layer, xa, 1.0)
            x *= scale
            x += shift
        return x.reshape(-1, self.dim)[:n]

    def inverse(self, p: npt.ArrayLike) -> np.ndarray:
        """q = b^-1(p) = b_theta^-1(p) - c for normalised tangent vectors (N, D) -> (N, D)."""
        xa, x, n = self._blocks(p)
        for layer in reversed(self._layers):
            scale, shift = self._scale_shift(layer, xa, -1.0)
            x -= shift
            x *= scale
        x -= self.offset
        return x.reshape(-1, self.dim)[:n]

    def step(self, p: npt.ArrayLike, dt: float | None = None) -> np.ndarray:
        """One exact latent step in normalised tangent space: b(Phi(dt) b^-1(p)), (N, D)."""
        phi_t = self.step_matrix(self.dt if dt is None else dt)
        return self.forward(self.inverse(p) @ phi_t)

    def latent_path(self, q0: npt.ArrayLike, steps: int, dt: float | None = None) -> np.ndarray:
        """Latent states q_k = Phi^k q_0 for k = 0..steps, (N, steps+1, D), by doubling (log2(steps) products)."""
        q0 = np.array(q0, dtype=np.float64, ndmin=2)
        if q0.ndim != 2 or q0.shape[1] != self.dim:
            raise RFlowError(f"latent start has shape {q0.shape}, expected (N, {self.dim})")
        if steps < 0:
            raise RFlowError(f"steps {steps} must be >= 0")
        out = np.empty((q0.shape[0], steps + 1, self.dim))
        out[:, 0] = q0
        power_t = self.step_matrix(self.dt if dt is None else dt)  # (Phi^n)^T
        n = 1
        while n <= steps:
            take = min(n, steps + 1 - n)
            np.matmul(out[:, :take], power_t, out=out[:, n : n + take])
            n += take
            power_t = power_t @ power_t  # (Phi^n)^T for the doubled n (unused after a partial block)
        return out

    # ---- one point, no allocations ------------------------------------------------------------------
    def _layer_single(self, layer: _Layer, sign: float) -> None:
        """Apply one coupling layer (sign +1) or its inverse (sign -1) to the buffer self._x in place."""
        h = self._x
        for w in layer.augmented[:-1]:
            width = w.shape[1]
            nxt = self._hidden[width][0] if h is not self._hidden[width][0] else self._hidden[width][1]
            view = nxt[:width]
            np.dot(h, w, out=view)
            if self._relu:
                np.maximum(view, self._zeros[width], out=view)
            else:
                np.tanh(view, out=view)
            h = nxt
        np.dot(h, layer.augmented[-1], out=self._out)
        scale = self._scale
        np.tanh(scale, out=scale)
        np.multiply(scale, sign * layer.clamp, out=scale)
        np.exp(scale, out=scale)
        if sign > 0:
            np.multiply(self._xv, scale, out=self._xv)
            np.add(self._xv, self._shift, out=self._xv)
        else:
            np.subtract(self._xv, self._shift, out=self._xv)
            np.multiply(self._xv, scale, out=self._xv)

    def step_single(self, p: np.ndarray, dt: float | None = None) -> np.ndarray:
        """The closed-loop step b(Phi(dt) b^-1(p)) of one normalised tangent vector (D,) -> new array (D,)."""
        phi_t = self.step_matrix(self.dt if dt is None else dt)
        xv = self._xv
        xv[:] = p
        for layer in reversed(self._layers):
            self._layer_single(layer, -1.0)
        # latent step: q' = Phi (b_theta^-1(p) - c), then add c back for b_theta
        np.subtract(xv, self.offset, out=xv)
        xv[:] = xv @ phi_t
        np.add(xv, self.offset, out=xv)
        for layer in self._layers:
            self._layer_single(layer, 1.0)
        return xv.copy()


class TangentChart:
    """Log_g / Exp_g at a fixed goal with few numpy calls (the control-loop path), equal to the batched
    maps of `rflow.manifolds` to rounding.

    Euclidean: v = x - g. Quaternions: q * conj(g) = R q with the constant right-multiplication matrix R of
    conj(g), then Log in scalar arithmetic; Exp_g(v) = R_g Exp(v). SPD: G^1/2 and G^-1/2 computed once, one
    eigendecomposition per map (P is positive definite iff G^-1/2 P G^-1/2 is). Other manifolds: their maps.
    """

    def __init__(self, manifold, goal: np.ndarray):
        from rflow.manifolds import sphere

        self.manifold = manifold
        self.goal = np.asarray(goal, dtype=np.float64)
        self.name = manifold.name
        if self.name == "sphere":
            eye = np.eye(4)
            self._right_conj_goal = np.ascontiguousarray(sphere.quat_mul(eye, sphere.quat_conj(self.goal)[None]).T)
            self._right_goal = np.ascontiguousarray(sphere.quat_mul(eye, self.goal[None]).T)
        elif self.name == "spd":
            lam, u = np.linalg.eigh(self.goal)
            self._half = (u * np.sqrt(lam)) @ u.T
            self._inv_half = (u / np.sqrt(lam)) @ u.T
            self._d = self.goal.shape[-1]
            self._rows, self._cols = np.triu_indices(self._d, k=1)

    def log(self, point: np.ndarray) -> np.ndarray:
        """Tangent vector (D,) of one point (SPD: also a batch). Raises RFlowError off the manifold or on NaN."""
        if self.name == "euclidean":
            v = point - self.goal
            if not math.isfinite(float(v.sum())):
                raise RFlowError("point contains NaN or inf")
            return v
        if self.name == "sphere":
            w0, x0, y0, z0 = point.tolist()
            n2 = w0 * w0 + x0 * x0 + y0 * y0 + z0 * z0
            if not abs(n2 - 1.0) <= 2e-6:  # also catches NaN
                raise RFlowError(f"point is not a unit quaternion: ||q||^2 = {n2:.9g}")
            w, x, y, z = (self._right_conj_goal @ point).tolist()
            s = math.sqrt(x * x + y * y + z * z)
            if s < 1e-4 and w > 0:
                f = 1.0 + s * s / 6.0
            elif s == 0.0:
                return np.array([math.pi, 0.0, 0.0])
            else:
                f = math.atan2(s, w) / s
            return np.array([f * x, f * y, f * z])
        if self.name == "spd":
            return self._spd_log(point)
        return np.asarray(self.manifold.log(point, self.goal))

    def exp(self, v: np.ndarray) -> np.ndarray:
        """Point of a tangent vector (D,), or points of a batch (..., D)."""
        if self.name == "euclidean":
            return self.goal + v
        if self.name == "sphere" and v.ndim == 1:
            x, y, z = v.tolist()
            t = math.sqrt(x * x + y * y + z * z)
            f = 1.0 - t * t / 6.0 if t < 1e-4 else math.sin(t) / t
            return self._right_goal @ np.array([math.cos(t), f * x, f * y, f * z])
        if self.name == "spd":
            return self._spd_exp(v)
        return np.asarray(self.manifold.exp(v, self.goal))

    def _spd_log(self, p: np.ndarray) -> np.ndarray:
        """mandel(G^1/2 logm(G^-1/2 P G^-1/2) G^1/2) for P (..., d, d)."""
        if p.shape[-2:] != (self._d, self._d):
            raise RFlowError(f"point has shape {p.shape}, expected (..., {self._d}, {self._d})")
        asym = np.abs(p - np.swapaxes(p, -1, -2)).max()
        if not asym <= 1e-8 * max(1.0, float(np.abs(p).max())):  # also catches NaN
            raise RFlowError(f"point is not a symmetric finite matrix: max |P - P^T| = {asym:.3g}")
        lam, u = np.linalg.eigh(self._inv_half @ p @ self._inv_half)
        if not lam.min() > 0:
            raise RFlowError(f"point is not positive definite: smallest eigenvalue {lam.min():.3g} (relative to G)")
        v = self._half @ ((u * np.log(lam)[..., None, :]) @ np.swapaxes(u, -1, -2)) @ self._half
        d = self._d
        return np.concatenate([v[..., np.arange(d), np.arange(d)], math.sqrt(2.0) * v[..., self._rows, self._cols]], -1)

    def _spd_exp(self, x: np.ndarray) -> np.ndarray:
        """G^1/2 expm(G^-1/2 V G^-1/2) G^1/2 for Mandel vectors (..., d(d+1)/2)."""
        d = self._d
        if d == 2:
            return self._spd2_exp(x)
        v = np.empty(x.shape[:-1] + (d, d))
        v[..., np.arange(d), np.arange(d)] = x[..., :d]
        off = x[..., d:] / math.sqrt(2.0)
        v[..., self._rows, self._cols] = off
        v[..., self._cols, self._rows] = off
        lam, u = np.linalg.eigh(self._inv_half @ v @ self._inv_half)
        out = self._half @ ((u * np.exp(lam)[..., None, :]) @ np.swapaxes(u, -1, -2)) @ self._half
        return 0.5 * (out + np.swapaxes(out, -1, -2))

    @staticmethod
    def _sandwich2(h: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, ...]:
        """Entries (00, 01, 11) of H [[a, b], [b, c]] H for a constant symmetric 2x2 H, elementwise."""
        p, q, s = h[0, 0], h[0, 1], h[1, 1]
        t00, t01, t10, t11 = p * a + q * b, p * b + q * c, q * a + s * b, q * b + s * c
        return t00 * p + t01 * q, t00 * q + t01 * s, t10 * q + t11 * s

    def _spd2_exp(self, x: np.ndarray) -> np.ndarray:
        """2x2 case of `_spd_exp` in closed form, elementwise over the batch (no eigendecomposition):
        for symmetric M with m = tr(M)/2, r = sqrt(((M00 - M11)/2)^2 + M01^2),
        expm(M) = e^m (cosh(r) I + sinh(r)/r (M - m I))."""
        m00, m01, m11 = self._sandwich2(self._inv_half, x[..., 0], x[..., 2] / math.sqrt(2.0), x[..., 1])
        mean = 0.5 * (m00 + m11)
        r = np.hypot(0.5 * (m00 - m11), m01)
        small = r < 1e-6
        sinhc = np.where(small, 1.0 + r * r / 6.0, np.sinh(r) / np.where(small, 1.0, r))
        scale = np.exp(mean)
        cosh = scale * np.cosh(r)
        sinhc *= scale
        e00, e01, e11 = cosh + sinhc * (m00 - mean), sinhc * m01, cosh + sinhc * (m11 - mean)
        o00, o01, o11 = self._sandwich2(self._half, e00, e01, e11)
        return np.stack([np.stack([o00, o01], -1), np.stack([o01, o11], -1)], -2)
