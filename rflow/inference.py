"""Fast inference of a trained ImitationFlow without torch: compiled coupling passes (`rflow.flow_kernel`).

The exported network computes what `rflow.model.ImitationFlow` computes in float64 (equal to ~1e-12), with only
the unmasked weights kept: per layer the first layer's rows of the conditioner coordinates and the output
columns of the moved coordinates,
    h = act(x_a W_1 + b_1) ...,  [u, t] = h W_out + b_out,  s = c tanh(u),  y_b = x_b * exp(s) + t,
with 1/c folded into the u columns, and b(q) = b_theta(q + c) with the latent offset c = b_theta^-1(z_g) of
`rflow.model`. Batches and the single-point closed-loop step are each one compiled call; latent paths are
matrix powers of Phi = expm(V dt).
"""

from __future__ import annotations

import math
import multiprocessing

import numpy as np
import numpy.typing as npt

from numerics.errors import shown
from numerics.small_linalg import eigh_sym, expm, matmul, matvec
from rflow import flow_kernel
from rflow.errors import RFlowError
from rflow.flow_kernel import PackedFlow


def check_dt(dt: object) -> None:
    """Refuse a step that is neither None (the default step) nor a finite number of seconds > 0.

    Cheap enough for the control loop (Python floats, no numpy call). A bool is no step, though Python counts it as
    a number.

    Raises:
        RFlowError: naming dt and its value: a string, a sequence, NaN, inf, 0, a negative number, a bool.
    """
    if dt is None:
        return
    try:
        ok = not isinstance(dt, (bool, np.bool_)) and math.isfinite(dt) and dt > 0
    except (TypeError, OverflowError):  # not a real number (a string, a sequence, a complex number), or past a float
        ok = False
    if not ok:
        raise RFlowError(f"step dt={shown(dt)} must be a finite number of seconds > 0")


class NumpyImitationFlow:
    """Torch-free copy of an ImitationFlow: b (latent -> normalised tangent), b^-1, and exact latent steps.

    Build with `from_network`. Batch methods take (N, D) or (D,) arrays and return new (N, D) arrays;
    `step_single` is the allocation-free closed-loop step of one point.

    Attributes:
        offset: c = b_theta^-1(z_g), the latent translation of the exact goal, (D,).
        drift: the latent drift matrix V, (D, D).
        dt: default step (s).
        dim: tangent dimension D.
    """

    _MAX_CACHED_STEPS = 64  # step matrices kept per dt
    PARALLEL_MIN_POINTS = 16384
    """Batches of at least this many points run on all cores (flow_kernel.flow_pass_parallel), smaller ones on one:
    a control loop or an evaluation worker's single rollout must not wake threads that compete with other workers.
    A worker process (a child of multiprocessing) runs every batch on one core: the workers share the cores
    already, and a forked one must not enter a parallel region, since GNU OpenMP (numba's "omp" layer) terminates a
    forked child whose parent ran one (`tests/rflow/test_inference.py`)."""

    def __init__(self, packed: PackedFlow, offset: np.ndarray, drift: np.ndarray, dt: float):
        self._packed = packed
        self._weights = (packed.cond, packed.n_cond, packed.moved, packed.n_moved, packed.w_first, packed.b_first,
                         packed.w_hidden, packed.b_hidden, packed.w_out, packed.b_out, packed.clamp,
                         packed.n_hidden_extra, packed.relu)
        self.offset = np.ascontiguousarray(offset, dtype=np.float64)
        self._zero = np.zeros_like(self.offset)
        self._minus_offset = -self.offset
        self.drift = drift
        self.dt = float(dt)
        self.dim = int(offset.size)
        self._steps: dict[float, np.ndarray] = {}
        self.step_matrix(self.dt)
        self._x = np.zeros(self.dim)  # single-point buffers
        self._latent = np.zeros(self.dim)
        self._hid = np.zeros((2, packed.width))

    @classmethod
    def from_network(cls, network, dt: float) -> "NumpyImitationFlow":
        """Export a `rflow.model.ImitationFlow` (weights copied as float64, masked entries dropped)."""
        import torch

        with torch.no_grad():
            dim = network.dim
            layers = list(network.flow.layers)
            linears = [[m for m in c.net if isinstance(m, torch.nn.Linear)] for c in layers]
            width = linears[0][0].out_features
            extra = len(linears[0]) - 2
            n_layers = len(layers)
            cond = np.zeros((n_layers, dim), dtype=np.int64)
            moved = np.zeros((n_layers, dim), dtype=np.int64)
            n_cond = np.zeros(n_layers, dtype=np.int64)
            n_moved = np.zeros(n_layers, dtype=np.int64)
            w_first = np.zeros((n_layers, dim, width))
            b_first = np.zeros((n_layers, width))
            w_hidden = np.zeros((n_layers, max(extra, 1), width, width))
            b_hidden = np.zeros((n_layers, max(extra, 1), width))
            w_out = np.zeros((n_layers, 2 * dim, width))
            b_out = np.zeros((n_layers, 2 * dim))
            clamp = np.zeros(n_layers)
            for l, (coupling, lins) in enumerate(zip(layers, linears)):
                mask = coupling.mask.double().numpy()
                a, b = np.flatnonzero(mask > 0.5), np.flatnonzero(mask < 0.5)
                cond[l, : a.size], n_cond[l] = a, a.size
                moved[l, : b.size], n_moved[l] = b, b.size
                w1 = lins[0].weight.double().numpy()  # (H, D)
                w_first[l, : a.size] = w1[:, a].T
                b_first[l] = lins[0].bias.double().numpy()
                for k, lin in enumerate(lins[1:-1]):
                    w_hidden[l, k] = lin.weight.double().numpy().T
                    b_hidden[l, k] = lin.bias.double().numpy()
                c = float(coupling.log_scale_clamp)
                wo = lins[-1].weight.double().numpy()  # (2D, H): rows [raw log-scale (D); shift (D)]
                bo = lins[-1].bias.double().numpy()
                w_out[l, : b.size] = wo[b] / c
                b_out[l, : b.size] = bo[b] / c
                w_out[l, b.size : 2 * b.size] = wo[dim + b]
                b_out[l, b.size : 2 * b.size] = bo[dim + b]
                clamp[l] = c
            packed = PackedFlow(cond, n_cond, moved, n_moved, w_first, b_first, w_hidden, b_hidden,
                                np.ascontiguousarray(w_out), b_out, clamp, extra,
                                network.config.activation == "relu")
            offset = network.offset().double().numpy().copy()
            drift = network.dynamics.drift_matrix().double().numpy().copy()
        return cls(packed, offset, drift, dt)

    def step_matrix(self, dt: float | None) -> np.ndarray:
        """Phi(dt)^T = expm(V dt)^T (for row vectors: q_next = q @ Phi^T), cached per dt (None: the default step).

        Raises:
            RFlowError: dt is not a finite number > 0 (`check_dt`).
        """
        if type(dt) is not float:  # checked on every call: float() would take "0.01" or True from the cache
            check_dt(dt)
            dt = self.dt if dt is None else dt
        key = float(dt)
        phi_t = self._steps.get(key)
        if phi_t is None:
            check_dt(key)
            phi_t = np.ascontiguousarray(expm(self.drift * key).T)
            if len(self._steps) >= self._MAX_CACHED_STEPS:  # a jittering measured dt must not grow it forever
                self._steps.clear()
            self._steps[key] = phi_t
        return phi_t

    # ---- batches ------------------------------------------------------------------------------------

    def _rows(self, x: npt.ArrayLike) -> np.ndarray:
        """A C-contiguous float64 copy of x as (N, D).

        Raises:
            RFlowError: not numbers, a shape other than (N, D) or (D,), or NaN/inf.
        """
        try:
            arr = np.array(x, dtype=np.float64, ndmin=2, order="C")
        except (TypeError, ValueError) as err:
            raise RFlowError(f"flow input is not an array of numbers: {err}") from None
        if arr.ndim != 2 or arr.shape[1] != self.dim:
            raise RFlowError(f"flow input has shape {np.shape(x)}, expected (N, {self.dim})")
        if not np.isfinite(arr).all():
            raise RFlowError(f"flow input contains NaN or inf (row {int(np.argmin(np.isfinite(arr).all(axis=1)))})")
        return arr

    def forward(self, q: npt.ArrayLike) -> np.ndarray:
        """p = b(q) = b_theta(q + c) for latent points (N, D) -> (N, D)."""
        x = self._rows(q)
        self._pass(x, 1.0, self.offset, self._zero)
        return x

    def inverse(self, p: npt.ArrayLike) -> np.ndarray:
        """q = b^-1(p) = b_theta^-1(p) - c for normalised tangent vectors (N, D) -> (N, D)."""
        x = self._rows(p)
        self._pass(x, -1.0, self._zero, self._minus_offset)
        return x

    def _pass(self, x: np.ndarray, sign: float, before: np.ndarray, after: np.ndarray) -> None:
        """x <- pass(x + before) + after in place: all layers (sign +1) or all inverses (sign -1)."""
        parallel = x.shape[0] >= self.PARALLEL_MIN_POINTS and multiprocessing.parent_process() is None
        run = flow_kernel.flow_pass_parallel if parallel else flow_kernel.flow_pass
        run(x, sign, before, after, *self._weights)

    def step(self, p: npt.ArrayLike, dt: float | None = None) -> np.ndarray:
        """One exact latent step in normalised tangent space: b(Phi(dt) b^-1(p)), (N, D)."""
        phi_t = self.step_matrix(self.dt if dt is None else dt)
        return self.forward(matmul(self.inverse(p), phi_t))

    def latent_path(self, q0: npt.ArrayLike, steps: int, dt: float | None = None) -> np.ndarray:
        """Latent states q_k = Phi^k q_0 for k = 0..steps, (N, steps+1, D), by doubling (log2(steps) products)."""
        q0 = np.array(q0, dtype=np.float64, ndmin=2)
        if q0.ndim != 2 or q0.shape[1] != self.dim:
            raise RFlowError(f"latent start has shape {q0.shape}, expected (N, {self.dim})")
        if isinstance(steps, (bool, np.bool_)) or not isinstance(steps, (int, np.integer)) or steps < 0:
            raise RFlowError(f"steps={shown(steps)} must be an integer >= 0")
        out = np.empty((q0.shape[0], steps + 1, self.dim))
        out[:, 0] = q0
        power_t = self.step_matrix(self.dt if dt is None else dt)  # (Phi^n)^T
        n = 1
        while n <= steps:
            take = min(n, steps + 1 - n)
            out[:, n : n + take] = matmul(out[:, :take], power_t)
            n += take
            power_t = matmul(power_t, power_t)  # (Phi^n)^T for the doubled n (unused after a partial block)
        return out

    # ---- one point, no allocations ------------------------------------------------------------------

    def step_single(self, p: np.ndarray, dt: float | None = None) -> np.ndarray:
        """The closed-loop step b(Phi(dt) b^-1(p)) of one normalised tangent vector (D,) -> new array (D,)."""
        phi_t = self.step_matrix(self.dt if dt is None else dt)
        x = self._x
        x[:] = p
        flow_kernel.flow_step(x, phi_t, self.offset, self._hid, self._latent, *self._weights)
        return x.copy()

    def chart_steps(self, points: np.ndarray, out: np.ndarray, chart: TangentChart, mean: np.ndarray, std: np.ndarray,
                    dt: float | None = None, hemisphere: np.ndarray | None = None) -> int:
        """S chained single-point closed-loop steps of every row of points (B, P), Euclidean or quaternion, into out
        (S, B, P), in one compiled call (`flow_kernel.chart_flow_steps`: the chart's maps, the normalisation and
        `step_single` operation for operation; a quaternion step from the previous step's point first puts it on
        the hemisphere of ``hemisphere`` (4,; default the chart's goal) and normalises it); -1, or the first row the
        chart rejects."""
        phi_t = self.step_matrix(self.dt if dt is None else dt)
        kind = flow_kernel.CHART_EUCLIDEAN if chart.name == "euclidean" else flow_kernel.CHART_SPHERE
        rot = chart.rotations()
        side = _EYE4[0] if hemisphere is None and kind == flow_kernel.CHART_EUCLIDEAN else (
            chart.goal if hemisphere is None else hemisphere)
        return int(flow_kernel.chart_flow_steps(points, out, kind, chart.goal, rot[0], rot[1],
                                                np.ascontiguousarray(mean, dtype=np.float64),
                                                np.ascontiguousarray(std, dtype=np.float64), phi_t, self.offset,
                                                self._hid, self._latent, *self._weights,
                                                np.ascontiguousarray(side, dtype=np.float64)))


_EYE4 = np.eye(4)


class TangentChart:
    """Log_g / Exp_g at a fixed goal with few numpy calls (the control-loop path), equal to the batched
    maps of `rflow.manifolds` to rounding.

    Euclidean: v = x - g. Quaternions: q * conj(g) = R q with the constant right-multiplication matrix R of
    conj(g), then Log in scalar arithmetic; Exp_g(v) = R_g Exp(v). SPD: G^1/2 and G^-1/2 computed once, one
    eigendecomposition per map (P is positive definite iff G^-1/2 P G^-1/2 is). Other manifolds: their maps.
    """

    def __init__(self, manifold, goal: np.ndarray):
        from numerics.quaternion import quat_conj, quat_mul

        self.manifold = manifold
        self.goal = np.asarray(goal, dtype=np.float64)
        self.name = manifold.name
        if self.name == "sphere":
            eye = np.eye(4)
            self._right_conj_goal = np.ascontiguousarray(quat_mul(eye, quat_conj(self.goal)[None]).T)
            self._right_goal = np.ascontiguousarray(quat_mul(eye, self.goal[None]).T)
        elif self.name == "spd":
            lam, u = eigh_sym(self.goal)
            self._half = matmul(u * np.sqrt(lam), u.T)
            self._inv_half = matmul(u / np.sqrt(lam), u.T)
            self._d = self.goal.shape[-1]
            self._rows, self._cols = np.triu_indices(self._d, k=1)

    def rotations(self) -> tuple[np.ndarray, np.ndarray]:
        """The quaternion chart's right multiplications by conj(g) and g (4, 4) (identity placeholders otherwise),
        for the compiled batch of steps (`ImitationFlowInference.chart_steps`)."""
        if self.name == "sphere":
            return self._right_conj_goal, self._right_goal
        return _EYE4, _EYE4

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
            w, x, y, z = matvec(self._right_conj_goal, point).tolist()
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
            return matvec(self._right_goal, np.array([math.cos(t), f * x, f * y, f * z]))
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
        lam, u = eigh_sym(matmul(matmul(self._inv_half, p), self._inv_half))
        if not lam.min() > 0:
            raise RFlowError(f"point is not positive definite: smallest eigenvalue {lam.min():.3g} (relative to G)")
        v = matmul(matmul(self._half, matmul(u * np.log(lam)[..., None, :], np.swapaxes(u, -1, -2))), self._half)
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
        lam, u = eigh_sym(matmul(matmul(self._inv_half, v), self._inv_half))
        out = matmul(matmul(self._half, matmul(u * np.exp(lam)[..., None, :], np.swapaxes(u, -1, -2))), self._half)
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
