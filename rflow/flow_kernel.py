"""The coupling flow b_theta of `rflow.flow` as compiled loops (numba): whole passes of many points, and the
closed-loop step of one point, without Python work per layer.

Each affine coupling layer l keeps its conditioner coordinates a_l and moves the others b_l (`rflow.flow`):

    h = act(x_a W_1 + b_1) (-> act(h W_k + b_k) ...),   u = h W_u + b_u,   t = h W_t + b_t,
    s = c tanh(u),   forward: x_b <- x_b exp(s) + t,   inverse: x_b <- (x_b - t) exp(-s),

with W_u, b_u already divided by c (`rflow.inference`). Only the conditioner rows of W_1 and the moved columns of
the output layer are stored: the zero rows and columns of the masked network are never multiplied. Batches run in
blocks of BLOCK_POINTS points whose inner loops run across the block (vectorised by the compiler), the blocks spread
over the cores (numba prange); the closed-loop step of one point is a single call on preallocated buffers.
In the batches exp(c tanh(u)) is a vectorised Taylor series with argument halving (`_exp_clamped_tanh`) instead of
libm's scalar calls, and the output sums run four hidden units at a time: batch results equal the single-point step
(libm, plain summation order) and the torch flow to ~1e-14 relative in float64 (timings: `pih bench`, README).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")


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


CHART_EUCLIDEAN = 0
CHART_SPHERE = 1
"""The charts `chart_flow_steps` computes itself (rflow.inference.TangentChart's Euclidean and quaternion maps)."""


@_jit
def chart_flow_steps(points, out, chart, goal, right_conj_goal, right_goal, mean, std, phi_t, offset, hid, latent,
                     cond, n_cond, moved, n_moved, w_first, b_first, w_hidden, b_hidden, w_out, b_out, clamp, n_extra,
                     relu, hemisphere):
    """S chained closed-loop steps of every row of points (B, P) into out (S, B, P): out[0] the step from the row,
    out[s] the step from out[s-1], each with the arithmetic of the single point path (rflow.generate.next_point on
    one point: TangentChart.log, (v - mean) / std, `flow_step`, x std + mean, TangentChart.exp), operation for
    operation, so each row equals that path to the last bit. A quaternion step from out[s-1] first puts it on the
    hemisphere of ``hemisphere`` (4,) and divides it by its norm, as a caller querying the next point would
    (envs.policies.flow_skill: ``_unit(on_goal_hemisphere(q, goal))``); out[s-1] itself is left as it came.

    Returns:
        -1, or the first row the chart rejects (not finite; a quaternion with |q|^2 off 1 by more than 2e-6), where
        the caller raises as the single path does (out is then incomplete).
    """
    dim = mean.shape[0]
    x = np.empty(dim)
    q = np.empty(4)
    p = np.empty(points.shape[1])
    for step in range(out.shape[0]):
        for r in range(points.shape[0]):
            if step == 0:
                for i in range(p.shape[0]):
                    p[i] = points[r, i]
            elif chart == CHART_EUCLIDEAN:
                for i in range(p.shape[0]):
                    p[i] = out[step - 1, r, i]
            else:  # on the hemisphere, then unit: -q exactly, then q / sqrt(w^2 + x^2 + y^2 + z^2)
                w0, x0, y0, z0 = out[step - 1, r, 0], out[step - 1, r, 1], out[step - 1, r, 2], out[step - 1, r, 3]
                if w0 * hemisphere[0] + x0 * hemisphere[1] + y0 * hemisphere[2] + z0 * hemisphere[3] < 0.0:
                    w0, x0, y0, z0 = -w0, -x0, -y0, -z0
                n = math.sqrt(w0 * w0 + x0 * x0 + y0 * y0 + z0 * z0)
                p[0], p[1], p[2], p[3] = w0 / n, x0 / n, y0 / n, z0 / n
            if chart == CHART_EUCLIDEAN:
                total = 0.0
                for i in range(dim):
                    x[i] = p[i] - goal[i]
                    total += x[i]
                if not math.isfinite(total):
                    return r
            else:
                w0, x0, y0, z0 = p[0], p[1], p[2], p[3]
                n2 = w0 * w0 + x0 * x0 + y0 * y0 + z0 * z0
                if not abs(n2 - 1.0) <= 2e-6:
                    return r
                for i in range(4):
                    acc = 0.0
                    for k in range(4):
                        acc += right_conj_goal[i, k] * p[k]
                    q[i] = acc
                w, qx, qy, qz = q[0], q[1], q[2], q[3]
                sn = math.sqrt(qx * qx + qy * qy + qz * qz)
                if sn < 1e-4 and w > 0:
                    f = 1.0 + sn * sn / 6.0
                    x[0], x[1], x[2] = f * qx, f * qy, f * qz
                elif sn == 0.0:
                    x[0], x[1], x[2] = math.pi, 0.0, 0.0
                else:
                    f = math.atan2(sn, w) / sn
                    x[0], x[1], x[2] = f * qx, f * qy, f * qz
            for i in range(dim):
                x[i] = (x[i] - mean[i]) / std[i]
            flow_step(x, phi_t, offset, hid, latent, cond, n_cond, moved, n_moved, w_first, b_first, w_hidden,
                      b_hidden, w_out, b_out, clamp, n_extra, relu)
            for i in range(dim):
                x[i] = x[i] * std[i] + mean[i]
            if chart == CHART_EUCLIDEAN:
                for i in range(dim):
                    out[step, r, i] = goal[i] + x[i]
            else:
                t = math.sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2])
                f = 1.0 - t * t / 6.0 if t < 1e-4 else math.sin(t) / t
                q[0], q[1], q[2], q[3] = math.cos(t), f * x[0], f * x[1], f * x[2]
                for i in range(4):
                    acc = 0.0
                    for k in range(4):
                        acc += right_goal[i, k] * q[k]
                    out[step, r, i] = acc
    return -1


BLOCK_POINTS = 128
"""Points per block of `flow_pass`, a compile-time constant (the last block is padded): the inner loops run across a
block's points with a known trip count, so the compiler vectorises and unrolls them (AVX2: 4 doubles per
instruction)."""

TAYLOR_RADIUS = 0.3125
"""|r| up to which `_expm1_small` is accurate to rounding (next Taylor term r^15 / 15! < 1e-19)."""
TANH_SATURATION = 20.0
"""tanh(u) rounds to +-1 in float64 for |u| >= 20 (1 - tanh(20) = 8.5e-18 < half an ulp of 1)."""


@numba.njit(inline="always", error_model="numpy")
def _expm1_small(r):
    """expm1(r) = sum_{n=1}^{14} r^n / n! (Horner) for |r| <= TAYLOR_RADIUS; plain arithmetic, so loops over
    points that call it vectorise (libm's exp and tanh are scalar calls without SVML)."""
    a = 1.0 / 87178291200.0
    a = a * r + 1.0 / 6227020800.0
    a = a * r + 1.0 / 479001600.0
    a = a * r + 1.0 / 39916800.0
    a = a * r + 1.0 / 3628800.0
    a = a * r + 1.0 / 362880.0
    a = a * r + 1.0 / 40320.0
    a = a * r + 1.0 / 5040.0
    a = a * r + 1.0 / 720.0
    a = a * r + 1.0 / 120.0
    a = a * r + 1.0 / 24.0
    a = a * r + 1.0 / 6.0
    a = a * r + 0.5
    a = a * r + 1.0
    return a * r


@_jit
def _halvings(bound):
    """Smallest n >= 0 with bound / 2^n <= TAYLOR_RADIUS."""
    n = 0
    while bound * 0.5**n > TAYLOR_RADIUS:
        n += 1
    return n


_TANH_HALVINGS = 7  # 2 TANH_SATURATION / 2^7 = TAYLOR_RADIUS


@_jit
def _exp_clamped_tanh(u, out, c, halvings):
    """out = exp(c tanh(u)) elementwise over a block (B,), vectorised (B = BLOCK_POINTS), equal to libm to ~1e-14
    relative:

        e = expm1(2 |u|) from a = expm1(2 |u| / 2^7) by 7 times a <- a (a + 2)   (= (1 + a)^2 - 1),
        tanh(u) = sign(u) e / (e + 2)   (|u| capped at TANH_SATURATION),
        exp(s) = (1 + expm1(s / 2^n))^(2^n),   n = `_halvings`(|c|)   (|s| <= |c|),

    so every Taylor argument is at most TAYLOR_RADIUS. The expm1 form keeps tanh's relative accuracy near 0 (no
    1 - 1 cancellation); the squarings of exp double its relative error n times (c = 9: n = 5, ~1e-14).
    """
    for p in range(BLOCK_POINTS):
        out[p] = _expm1_small(min(abs(u[p]), TANH_SATURATION) * (2.0 / 2**_TANH_HALVINGS))
    for _ in range(_TANH_HALVINGS):
        for p in range(BLOCK_POINTS):
            out[p] = out[p] * (out[p] + 2.0)
    scale = c * 0.5**halvings
    for p in range(BLOCK_POINTS):
        out[p] = 1.0 + _expm1_small(scale * math.copysign(out[p] / (out[p] + 2.0), u[p]))
    for _ in range(halvings):
        for p in range(BLOCK_POINTS):
            out[p] = out[p] * out[p]


@_jit
def _pass_block(xs, hb, hb2, u, t, sign, cond, n_cond, moved, n_moved, w_first, b_first, w_hidden, b_hidden, w_out,
                b_out, clamp, n_extra, relu):
    """All layers (sign +1) or all inverses (sign -1) on a block xs (D, BLOCK_POINTS) of points, in place.

    hb and hb2 (H, BLOCK_POINTS) hold the pre-activations (ReLU) or activations (tanh) of a hidden layer; the ReLU
    is applied where they are read. The output sums run four hidden units at a time, u += (h_j w_j + h_j+1 w_j+1)
    + (h_j+2 w_j+2 + h_j+3 w_j+3), which quarters the loads and stores of the accumulators.
    """
    layers, width = b_first.shape
    nb = BLOCK_POINTS
    scale = np.empty(nb)
    w4 = width - width % 4
    for k in range(layers):
        l = k if sign > 0 else layers - 1 - k
        c0 = cond[l, 0]
        if n_cond[l] == 1:
            for j in range(width):
                bj, w0 = b_first[l, j], w_first[l, 0, j]
                for p in range(nb):
                    hb[j, p] = bj + xs[c0, p] * w0
        else:
            c1 = cond[l, 1]
            for j in range(width):
                bj, w0, w1 = b_first[l, j], w_first[l, 0, j], w_first[l, 1, j]
                for p in range(nb):
                    hb[j, p] = bj + xs[c0, p] * w0 + xs[c1, p] * w1
        for c in range(2, n_cond[l]):
            ci = cond[l, c]
            for j in range(width):
                w = w_first[l, c, j]
                for p in range(nb):
                    hb[j, p] += xs[ci, p] * w
        if not relu:
            for j in range(width):
                for p in range(nb):
                    hb[j, p] = math.tanh(hb[j, p])
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
                        dst[j, p] += (max(src[i, p], 0.0) if relu else src[i, p]) * w
            if not relu:
                for j in range(width):
                    for p in range(nb):
                        dst[j, p] = math.tanh(dst[j, p])
            h = dst
        m = n_moved[l]
        halvings = _halvings(clamp[l])
        for o in range(m):
            bu, bt = b_out[l, o], b_out[l, m + o]
            for p in range(nb):
                u[p] = bu
                t[p] = bt
            for j in range(0, w4, 4):
                wu0, wu1, wu2, wu3 = w_out[l, o, j], w_out[l, o, j + 1], w_out[l, o, j + 2], w_out[l, o, j + 3]
                wt0, wt1 = w_out[l, m + o, j], w_out[l, m + o, j + 1]
                wt2, wt3 = w_out[l, m + o, j + 2], w_out[l, m + o, j + 3]
                for p in range(nb):
                    if relu:
                        h0, h1 = max(h[j, p], 0.0), max(h[j + 1, p], 0.0)
                        h2, h3 = max(h[j + 2, p], 0.0), max(h[j + 3, p], 0.0)
                    else:
                        h0, h1, h2, h3 = h[j, p], h[j + 1, p], h[j + 2, p], h[j + 3, p]
                    u[p] += (h0 * wu0 + h1 * wu1) + (h2 * wu2 + h3 * wu3)
                    t[p] += (h0 * wt0 + h1 * wt1) + (h2 * wt2 + h3 * wt3)
            for j in range(w4, width):
                wu, wt = w_out[l, o, j], w_out[l, m + o, j]
                for p in range(nb):
                    hj = max(h[j, p], 0.0) if relu else h[j, p]
                    u[p] += hj * wu
                    t[p] += hj * wt
            _exp_clamped_tanh(u, scale, clamp[l] * sign, halvings)
            i = moved[l, o]
            if sign > 0:
                for p in range(nb):
                    xs[i, p] = xs[i, p] * scale[p] + t[p]
            else:
                for p in range(nb):
                    xs[i, p] = (xs[i, p] - t[p]) * scale[p]


@_jit
def _run_block(points, blk, sign, offset_before, offset_after, cond, n_cond, moved, n_moved, w_first, b_first,
               w_hidden, b_hidden, w_out, b_out, clamp, n_extra, relu):
    """Block blk (rows blk * BLOCK_POINTS ...) of points (N, D), in place: x <- pass(x + offset_before) +
    offset_after, the pass being all layers (sign +1) or all inverses in reverse order (sign -1)."""
    n, dim = points.shape
    width = b_first.shape[1]
    start = blk * BLOCK_POINTS
    nb = min(BLOCK_POINTS, n - start)
    xs = np.zeros((dim, BLOCK_POINTS))  # the last block's padding is computed and dropped
    hb = np.empty((width, BLOCK_POINTS))
    hb2 = np.empty((width, BLOCK_POINTS))
    u = np.empty(BLOCK_POINTS)
    t = np.empty(BLOCK_POINTS)
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


@numba.njit(cache=True, nogil=True, error_model="numpy", parallel=True)
def flow_pass_parallel(points, sign, offset_before, offset_after, cond, n_cond, moved, n_moved, w_first, b_first,
                       w_hidden, b_hidden, w_out, b_out, clamp, n_extra, relu):
    """`flow_pass` with the blocks spread over the cores (numba prange); for large batches only, where the
    threads' start-up pays and the result is the same (blocks are independent)."""
    for blk in numba.prange((points.shape[0] + BLOCK_POINTS - 1) // BLOCK_POINTS):
        _run_block(points, blk, sign, offset_before, offset_after, cond, n_cond, moved, n_moved, w_first, b_first,
                   w_hidden, b_hidden, w_out, b_out, clamp, n_extra, relu)
