"""The coupling flow b_theta of `rflow.flow` as compiled loops (numba): whole passes of many points, and the
closed-loop step of one point, without Python work per layer.

Each affine coupling layer l keeps its conditioner coordinates a_l and moves the others b_l (`rflow.flow`):

    h = act(x_a W_1 + b_1) (-> act(h W_k + b_k) ...),   u = h W_u + b_u,   t = h W_t + b_t,
    s = c tanh(u),   forward: x_b <- x_b exp(s) + t,   inverse: x_b <- (x_b - t) exp(-s),

with W_u, b_u already divided by c (`rflow.inference`). Only the conditioner rows of W_1 and the moved columns of
the output layer are stored: the zero rows and columns of the masked network are never multiplied. Batches run in
blocks of BLOCK_POINTS points whose inner loops run across the block (vectorised by the compiler), the blocks spread
over the cores (numba prange); the closed-loop step of one point is a single call on preallocated buffers.
Results equal the previous numpy export to ~1e-15 (float64 throughout; only the summation order differs).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

_jit = numba.njit(cache=True, nogil=True, fastmath={"contract"}, error_model="numpy")


@dataclass(frozen=True)
class PackedFlow:
    """The weights of all layers in dense arrays (L layers, D coordinates, width H, K hidden layers).

    Attributes:
        cond: (L, D) conditioner coordinates of each layer, the first n_cond[l] valid.
        n_cond: (L,) number of conditioner coordinates.
        moved: (L, D) moved coordinates, the first n_moved[l] valid.
        n_moved: (L,) number of moved coordinates.
        w_first: (L, D, H) rows of W_1 for the conditioner coordinates (in `cond` order).
        b_first: (L, H).
        w_hidden: (L, max(K - 1, 1), H, H) further hidden layers (unused when K = 1), as (in, out).
        b_hidden: (L, max(K - 1, 1), H).
        w_out: (L, 2 D, H) output rows: u of the moved coordinates, then t of the moved coordinates.
        b_out: (L, 2 D).
        clamp: (L,) c of s = c tanh(u).
        n_hidden_extra: K - 1.
        relu: ReLU (True) or tanh activations.
    """

    cond: np.ndarray
    n_cond: np.ndarray
    moved: np.ndarray
    n_moved: np.ndarray
    w_first: np.ndarray
    b_first: np.ndarray
    w_hidden: np.ndarray
    b_hidden: np.ndarray
    w_out: np.ndarray
    b_out: np.ndarray
    clamp: np.ndarray
    n_hidden_extra: int
    relu: bool

    @property
    def width(self) -> int:
        """Hidden width H."""
        return int(self.b_first.shape[1])


@_jit
def _layer(x, hid, l, sign, cond, n_cond, moved, n_moved, w_first, b_first, w_hidden, b_hidden, w_out, b_out,
           clamp, n_extra, relu):
    """Apply coupling layer l (sign +1) or its inverse (sign -1) to the point x in place; hid is (2, H) scratch."""
    width = b_first.shape[1]
    h = hid[0]
    for j in range(width):
        h[j] = b_first[l, j]
    for c in range(n_cond[l]):
        xc = x[cond[l, c]]
        for j in range(width):
            h[j] += xc * w_first[l, c, j]
    for j in range(width):
        h[j] = max(h[j], 0.0) if relu else math.tanh(h[j])
    for k in range(n_extra):
        src, dst = hid[k % 2], hid[(k + 1) % 2]
        for j in range(width):
            dst[j] = b_hidden[l, k, j]
        for i in range(width):
            hi = src[i]
            for j in range(width):
                dst[j] += hi * w_hidden[l, k, i, j]
        for j in range(width):
            dst[j] = max(dst[j], 0.0) if relu else math.tanh(dst[j])
        h = dst
    m = n_moved[l]
    for o in range(m):
        u = b_out[l, o]
        t = b_out[l, m + o]
        for j in range(width):
            u += h[j] * w_out[l, o, j]
            t += h[j] * w_out[l, m + o, j]
        s = clamp[l] * math.tanh(u)
        i = moved[l, o]
        if sign > 0:
            x[i] = x[i] * math.exp(s) + t
        else:
            x[i] = (x[i] - t) * math.exp(-s)


@_jit
def flow_step(x, phi_t, offset, hid, latent, cond, n_cond, moved, n_moved, w_first, b_first, w_hidden, b_hidden, w_out,
              b_out, clamp, n_extra, relu):
    """The closed-loop step of one normalised tangent vector x (D,), in place: x <- b(Phi b^-1(x)), i.e.
    q = b_theta^-1(x) - c, q' = q Phi^T, x' = b_theta(q' + c). hid (2, H) and latent (D,) are scratch."""
    dim = x.shape[0]
    layers = b_first.shape[0]
    for k in range(layers):
        _layer(x, hid, layers - 1 - k, -1.0, cond, n_cond, moved, n_moved, w_first, b_first, w_hidden, b_hidden,
               w_out, b_out, clamp, n_extra, relu)
    q = latent
    for j in range(dim):
        s = 0.0
        for i in range(dim):
            s += (x[i] - offset[i]) * phi_t[i, j]
        q[j] = s
    for j in range(dim):
        x[j] = q[j] + offset[j]
    for l in range(layers):
        _layer(x, hid, l, 1.0, cond, n_cond, moved, n_moved, w_first, b_first, w_hidden, b_hidden, w_out, b_out,
               clamp, n_extra, relu)


BLOCK_POINTS = 32
"""Points per block of `flow_pass`: the inner loops run across a block's points, so the compiler vectorises
them (AVX2: 4 doubles per instruction), and a block's hidden layer (H x 32 doubles) stays in the L1 cache."""


@_jit
def _pass_block(xs, hb, hb2, u, t, sign, cond, n_cond, moved, n_moved, w_first, b_first, w_hidden, b_hidden, w_out,
                b_out, clamp, n_extra, relu):
    """All layers (sign +1) or all inverses (sign -1) on a block xs (D, B) of points, in place."""
    layers, width = b_first.shape
    nb = xs.shape[1]
    for k in range(layers):
        l = k if sign > 0 else layers - 1 - k
        for j in range(width):
            bj = b_first[l, j]
            for p in range(nb):
                hb[j, p] = bj
        for c in range(n_cond[l]):
            ci = cond[l, c]
            for j in range(width):
                w = w_first[l, c, j]
                for p in range(nb):
                    hb[j, p] += xs[ci, p] * w
        for j in range(width):
            for p in range(nb):
                hb[j, p] = max(hb[j, p], 0.0) if relu else math.tanh(hb[j, p])
        h = hb
        for e in range(n_extra):
            src, dst = (hb, hb2) if e % 2 == 0 else (hb2, hb)
            for j in range(width):
                bj = b_hidden[l, e, j]
                for p in range(nb):
                    dst[j, p] = bj
            for i in range(width):
                for j in range(width):
                    w = w_hidden[l, e, i, j]
                    for p in range(nb):
                        dst[j, p] += src[i, p] * w
            for j in range(width):
                for p in range(nb):
                    dst[j, p] = max(dst[j, p], 0.0) if relu else math.tanh(dst[j, p])
            h = dst
        m = n_moved[l]
        for o in range(m):
            bu, bt = b_out[l, o], b_out[l, m + o]
            for p in range(nb):
                u[p] = bu
                t[p] = bt
            for j in range(width):
                wu, wt = w_out[l, o, j], w_out[l, m + o, j]
                for p in range(nb):
                    u[p] += h[j, p] * wu
                    t[p] += h[j, p] * wt
            i = moved[l, o]
            c = clamp[l] * sign
            for p in range(nb):
                scale = math.exp(c * math.tanh(u[p]))
                if sign > 0:
                    xs[i, p] = xs[i, p] * scale + t[p]
                else:
                    xs[i, p] = (xs[i, p] - t[p]) * scale


@_jit
def _run_block(points, blk, sign, offset_before, offset_after, cond, n_cond, moved, n_moved, w_first, b_first,
               w_hidden, b_hidden, w_out, b_out, clamp, n_extra, relu):
    """Block blk (rows blk * BLOCK_POINTS ...) of points (N, D), in place: x <- pass(x + offset_before) +
    offset_after, the pass being all layers (sign +1) or all inverses in reverse order (sign -1)."""
    n, dim = points.shape
    width = b_first.shape[1]
    start = blk * BLOCK_POINTS
    nb = min(BLOCK_POINTS, n - start)
    xs = np.empty((dim, nb))
    hb = np.empty((width, nb))
    hb2 = np.empty((width, nb))
    u = np.empty(nb)
    t = np.empty(nb)
    for p in range(nb):
        for i in range(dim):
            xs[i, p] = points[start + p, i] + offset_before[i]
    _pass_block(xs, hb, hb2, u, t, sign, cond, n_cond, moved, n_moved, w_first, b_first, w_hidden, b_hidden,
                w_out, b_out, clamp, n_extra, relu)
    for p in range(nb):
        for i in range(dim):
            points[start + p, i] = xs[i, p] + offset_after[i]


@_jit
def flow_pass(points, sign, offset_before, offset_after, cond, n_cond, moved, n_moved, w_first, b_first, w_hidden,
              b_hidden, w_out, b_out, clamp, n_extra, relu):
    """Every row of points (N, D) through the flow (`_run_block`), block after block on one core."""
    for blk in range((points.shape[0] + BLOCK_POINTS - 1) // BLOCK_POINTS):
        _run_block(points, blk, sign, offset_before, offset_after, cond, n_cond, moved, n_moved, w_first, b_first,
                   w_hidden, b_hidden, w_out, b_out, clamp, n_extra, relu)


@numba.njit(cache=True, nogil=True, fastmath={"contract"}, error_model="numpy", parallel=True)
def flow_pass_parallel(points, sign, offset_before, offset_after, cond, n_cond, moved, n_moved, w_first, b_first,
                       w_hidden, b_hidden, w_out, b_out, clamp, n_extra, relu):
    """`flow_pass` with the blocks spread over the cores (numba prange); for large batches only, where the
    threads' start-up pays and the result is the same (blocks are independent)."""
    for blk in numba.prange((points.shape[0] + BLOCK_POINTS - 1) // BLOCK_POINTS):
        _run_block(points, blk, sign, offset_before, offset_after, cond, n_cond, moved, n_moved, w_first, b_first,
                   w_hidden, b_hidden, w_out, b_out, clamp, n_extra, relu)
