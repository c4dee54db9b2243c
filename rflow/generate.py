"""Generation with a trained RiemannianFlow (Algorithm 1 of the paper), on the numpy inference path.

Open loop (`rollout`): start point -> tangent at the goal -> normalise -> latent q_0 = b^-1(.) ->
exact latent steps q_k = Phi^k q_0 (Phi = expm(V dt)) -> batched passes b(q_k) over all starts and steps
(chunks of CHUNK_POINTS points, so finished rollouts stop costing) -> denormalise -> Exp_g.
A rollout stops at the first step whose tangent vector is shorter than xi and holds the goal afterwards.
Closed loop (`next_point`, `velocity`): the current point through b^-1, one latent step, back through b.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from numerics.errors import shown
from rflow.errors import RFlowError
from rflow.inference import check_dt
from rflow.model import RiemannianFlow

CHUNK_POINTS = 8192  # points per batched flow pass: small enough to stay in cache
MAX_ROLLOUT_VALUES = 10**8
"""The most tangent values (starts x (steps + 1) x dim) one `rollout` holds: 800 MB in each of its two paths."""


@dataclass(frozen=True)
class Rollout:
    """Generated trajectories.

    Attributes:
        points: (B, steps+1, *point_shape) points on the manifold; entries from `lengths` on hold the goal.
        tangent: (B, steps+1, D) tangent vectors at the goal (zero once stopped).
        lengths: (B,) number of generated points up to and including the first with ||tangent|| < xi
            (steps+1 if never).
        converged: (B,) True where some point within the step limit had ||tangent|| < xi.
    """

    points: np.ndarray
    tangent: np.ndarray
    lengths: np.ndarray
    converged: np.ndarray


def _check_starts(model: RiemannianFlow, starts: npt.ArrayLike) -> tuple[np.ndarray, bool]:
    try:
        arr = np.asarray(starts, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise RFlowError(f"starts are not a numeric array: {err}") from None
    if arr.shape == model.point_shape:
        return arr[None], True
    if arr.ndim != model.manifold.point_ndim + 1 or tuple(arr.shape[1:]) != model.point_shape:
        raise RFlowError(f"starts have shape {arr.shape}, expected (B, {', '.join(map(str, model.point_shape))})")
    return arr, False


def _check_steps(steps: object) -> int:
    """``steps`` as an int: a whole number >= 0 (an int, a numpy integer or a float without a fraction; no bool).

    Raises:
        RFlowError: naming steps and its value: a string, None, NaN, inf, a fraction, a negative number, a bool.
    """
    try:
        ok = not isinstance(steps, (bool, np.bool_)) and steps >= 0 and int(steps) == steps  # type: ignore[operator]
    except (TypeError, ValueError, OverflowError):  # not a number, or NaN / inf
        ok = False
    if not ok:
        raise RFlowError(f"steps={shown(steps)} must be a non-negative integer")
    return int(steps)  # type: ignore[call-overload]


def _check_xi(xi: object) -> None:
    """Refuse a stop threshold that is not a finite number > 0 (xi = inf would stop every rollout at its start).

    Raises:
        RFlowError: naming xi and its value.
    """
    try:
        ok = not isinstance(xi, (bool, np.bool_)) and math.isfinite(xi) and xi > 0  # type: ignore[arg-type,operator]
    except (TypeError, OverflowError):  # not a real number, or an integer past a float
        ok = False
    if not ok:
        raise RFlowError(f"stop threshold xi={shown(xi)} must be a finite number > 0")


def rollout(
    model: RiemannianFlow,
    starts: npt.ArrayLike,
    steps: int = 1000,
    xi: float = 1e-3,
    dt: float | None = None,
) -> Rollout:
    """Generate trajectories from many start points at once (Algorithm 1, exact latent steps).

    Args:
        model: trained model.
        starts: (B, *point_shape) start points on the manifold (or one point).
        steps: step limit; the trajectories have steps+1 points, the first being the start.
        xi: stop threshold on ||tangent|| (tangent units: m for positions, rad for quaternions).
        dt: step (s); default the demos' sampling time.

    Returns:
        The `Rollout` (a batch of one for a single start point).

    Raises:
        RFlowError: bad start shapes, points off the manifold or NaN/inf; steps not a non-negative integer; xi or dt
            not a finite number > 0; more than MAX_ROLLOUT_VALUES tangent values in all.
    """
    steps = _check_steps(steps)
    _check_xi(xi)
    check_dt(dt)
    arr, _ = _check_starts(model, starts)
    net = model.inference
    b = arr.shape[0]
    dim = model.dim
    if b * (steps + 1) * dim > MAX_ROLLOUT_VALUES:
        raise RFlowError(f"rollout of {b} start(s) x {steps + 1} points x {dim} values exceeds {MAX_ROLLOUT_VALUES:.0e} "
                         f"values (steps={steps}): roll out fewer starts or steps at a time")
    tangent0 = model.to_tangent(arr).reshape(b, dim)
    q_path = net.latent_path(net.inverse(model.normalise(tangent0)), steps, dt)
    tangent = np.empty((b, steps + 1, dim))
    lengths = np.full(b, steps + 1, dtype=np.int64)
    converged = np.zeros(b, dtype=bool)
    active = np.arange(b)
    chunk_steps = max(1, CHUNK_POINTS // max(b, 1))
    k0 = 0
    while k0 <= steps and active.size:
        k1 = min(steps + 1, k0 + chunk_steps)
        z = net.forward(q_path[active, k0:k1].reshape(-1, dim))
        v = model.denormalise(z).reshape(active.size, k1 - k0, dim)
        if k0 == 0:
            v[:, 0] = tangent0[active]  # the start itself, not its round trip through the flow
        tangent[active, k0:k1] = v
        below = np.linalg.norm(v, axis=-1) < xi
        hit = below.any(axis=1)
        first = np.argmax(below, axis=1)
        lengths[active[hit]] = k0 + first[hit] + 1
        converged[active[hit]] = True
        active = active[~hit]
        k0 = k1
    after = np.arange(steps + 1)[None, :] >= lengths[:, None]
    tangent[after] = 0.0
    points = model.from_tangent(tangent)
    return Rollout(points=points, tangent=tangent, lengths=lengths, converged=converged)


def _check_point(model: RiemannianFlow, arr: np.ndarray) -> tuple[np.ndarray, bool]:
    nd = model.manifold.point_ndim
    single = arr.ndim == nd
    if tuple(arr.shape[-nd:]) != model.point_shape or arr.ndim not in (nd, nd + 1):
        want = ", ".join(map(str, model.point_shape))
        raise RFlowError(f"point has shape {arr.shape}, expected ({want}) or a batch (B, {want})")
    return arr, single


def _step_tangent(model: RiemannianFlow, point: npt.ArrayLike, dt: float | None) -> tuple[np.ndarray, np.ndarray, bool]:
    """Tangent vectors now and one step later, (B, D) each, and whether a single point was given."""
    check_dt(dt)
    try:
        arr = np.asarray(point, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise RFlowError(f"point is not a numeric array: {err}") from None
    norm = model.normalisation
    if arr.shape == model.point_shape:  # the control-loop path: one point, no torch, few numpy calls
        tangent = model.chart.log(arr)
        nxt = model.inference.step_single((tangent - norm.mean) / norm.std, dt)
        return tangent[None], (nxt * norm.std + norm.mean)[None], True
    arr, single = _check_point(model, arr)
    tangent = model.to_tangent(arr).reshape(-1, model.dim)
    nxt = model.denormalise(model.inference.step(model.normalise(tangent), dt))
    return tangent, nxt, single


def next_point(model: RiemannianFlow, point: npt.ArrayLike, dt: float | None = None) -> np.ndarray:
    """The point one step dt later (closed loop): Exp_g(denorm(b(Phi(dt) b^-1(norm(Log_g(point)))))).

    Args:
        model: trained model.
        point: current point (*point_shape) or a batch (B, *point_shape).
        dt: step (s); default the demos' sampling time.

    Returns:
        The next point(s), same shape as ``point``.

    Raises:
        RFlowError: bad shape, point off the manifold, NaN; dt not a finite number > 0.
    """
    _, nxt, single = _step_tangent(model, point, dt)
    if single:
        return model.chart.exp(nxt[0])
    return model.from_tangent(nxt)


def lookahead_points(model: RiemannianFlow, points: npt.ArrayLike, dt: float | None, steps: int,
                     hemisphere: npt.ArrayLike | None = None) -> np.ndarray:
    """The points 1..``steps`` steps of dt later along the flow from each of the points (B, *point_shape), (steps,
    B, *point_shape), row by row with the arithmetic of the control loop's single point (Log_g and Exp_g of
    `rflow.inference.TangentChart`; for the Euclidean and quaternion charts all steps of all rows in one compiled
    call, `rflow.flow_kernel.chart_flow_steps`): step 1 of row i equals ``next_point(model, points[i], dt)`` to the
    last bit, and step s + 1 equals ``next_point`` of step s, a quaternion first put on the hemisphere of
    ``hemisphere`` (default the goal's) and divided by its norm. For the closed loop's lookahead (two steps) and
    batches of episodes in lockstep.

    Raises:
        RFlowError: points not numbers, of a bad shape, off the manifold or NaN; dt not a finite number > 0;
            steps < 1; a hemisphere that is not 4 finite numbers, not all zero.
    """
    check_dt(dt)
    if isinstance(steps, bool) or not (isinstance(steps, (int, np.integer)) and steps >= 1):
        raise RFlowError(f"lookahead steps {shown(steps)} must be an integer >= 1")
    try:
        arr = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise RFlowError(f"points are not an array of numbers: {err}") from None
    if arr.shape[1:] != model.point_shape or arr.ndim != len(model.point_shape) + 1:
        want = ", ".join(map(str, model.point_shape))
        raise RFlowError(f"points have shape {arr.shape}, expected a batch (B, {want})")
    norm, chart = model.normalisation, model.chart
    if chart.name in ("euclidean", "sphere"):  # the whole step compiled (rflow.flow_kernel.chart_flow_steps)
        out = np.empty((steps,) + arr.shape)
        side = None if hemisphere is None else _check_hemisphere(hemisphere, chart.name == "sphere")
        bad = model.inference.chart_steps(np.ascontiguousarray(arr), out, chart, norm.mean, norm.std, dt, side)
        if bad >= 0:
            chart.log(arr[bad])  # raises what the single point's query raises
            raise RFlowError(f"point {bad} of the batch left the manifold along the flow")
        return out
    out = np.empty((steps,) + arr.shape)  # other charts: the single path, row by row
    for s in range(steps):
        out[s] = np.stack([next_point(model, point, dt) for point in (arr if s == 0 else out[s - 1])])
    return out


def _check_hemisphere(hemisphere: npt.ArrayLike, checked: bool) -> np.ndarray:
    """``hemisphere`` as a float64 array; with ``checked`` (the quaternion chart reads it) 4 finite numbers, not all
    zero (a zero one has no side), in Python floats: the closed loop passes it every control period.

    Raises:
        RFlowError: naming the hemisphere and what is wrong with it.
    """
    try:
        side = np.asarray(hemisphere, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise RFlowError(f"hemisphere is not an array of numbers: {err}") from None
    if checked:
        values = side.tolist()
        if side.shape != (4,) or not all(map(math.isfinite, values)) or not any(values):
            raise RFlowError(f"hemisphere {shown(values)} must be a quaternion: 4 finite numbers, not all zero")
    return side


def velocity(model: RiemannianFlow, point: npt.ArrayLike, dt: float | None = None) -> np.ndarray:
    """Tangent velocity at ``point``: (Log_g(next_point) - Log_g(point)) / dt, the velocity of one exact step.

    Args:
        model: trained model.
        point: current point (*point_shape) or a batch (B, *point_shape).
        dt: step (s); default the demos' sampling time.

    Returns:
        (D,) or (B, D) tangent velocity (tangent units per second).

    Raises:
        RFlowError: bad shape, point off the manifold, NaN; dt not a finite number > 0.
    """
    tangent, nxt, single = _step_tangent(model, point, dt)
    vel = (nxt - tangent) / (model.dt if dt is None else float(dt))
    return vel[0] if single else vel
