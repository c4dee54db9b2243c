"""One physics episode of a pose skill: reset at a start pose, command the policy, record what the
simulated peg did (the success check of envs.success on the MEASURED peg, never the plan).

An unreachable or colliding start is recorded as a failure with its reason, and any exception inside an
episode is recorded as "error: ..."; an episode never raises.
"""

from __future__ import annotations

import math
import time
import traceback
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
import numpy.typing as npt

from envs.errors import EnvError
from envs.execution.policy import feedforward_pose
from envs.poses import Pose, quat_angle_rad

FloatArray = npt.NDArray[np.float64]

@dataclass(frozen=True)
class StartPose:
    """A perturbed start: episode index, the demo it was drawn around, and the pose."""

    index: int
    demo_index: int
    pose: Pose


@dataclass
class EpisodeRecord:
    """Outcome of one episode (JSON-ready through ``to_dict``; NaN where not applicable).

    Attributes:
        index: episode index.
        demo_index: the demo whose start was perturbed (-1: the mean demo start).
        start_pos, start_quat: start pose (m; w, x, y, z).
        success: the physics check declared success.
        reason: "success", "time_limit (...)", "instability: ...", "unreachable start: ...", "error: ...".
        time_to_insert_s: simulated time until success (None on failure).
        final_pos_error_mm: ||p_final - g_p|| against the scene's goal.
        final_angle_error_deg: angle between the final and the goal orientation.
        insertion_depth_mm: depth of the peg_tip below the target hole's opening (negative above).
        lateral_error_mm, tilt_deg: peg_tip distance from the hole axis and peg tilt at the end.
        max_contact_force_n: largest contact force magnitude on the peg over the episode.
        final_pos, final_quat: measured peg_tip pose at the end.
        steps: control steps run.
        wall_s: wall-clock seconds.
    """

    index: int
    demo_index: int
    start_pos: list[float]
    start_quat: list[float]
    success: bool = False
    reason: str = "not run"
    time_to_insert_s: float | None = None
    final_pos_error_mm: float = float("nan")
    final_angle_error_deg: float = float("nan")
    insertion_depth_mm: float = float("nan")
    lateral_error_mm: float = float("nan")
    tilt_deg: float = float("nan")
    max_contact_force_n: float = float("nan")
    final_pos: list[float] | None = None
    final_quat: list[float] | None = None
    steps: int = 0
    wall_s: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (NaN becomes None)."""
        return {k: _finite_or_none(v) for k, v in asdict(self).items()}


def _finite_or_none(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


@dataclass
class EpisodeTrace:
    """The executed trajectory of one episode, one row per control step (t = 0 first), for figures.

    Attributes:
        times_s, pos, quat: measured peg_tip poses.
        cmd_pos, cmd_quat: commanded poses (row 0 repeats the start).
        force_n: contact force magnitude.
    """

    times_s: FloatArray
    pos: FloatArray
    quat: FloatArray
    cmd_pos: FloatArray
    cmd_quat: FloatArray
    force_n: FloatArray


# --------------------------------------------------------------------------------------------- episode


def run_episode(env: Any, policy: Any, start: StartPose, record_trace: bool = False,
                on_step: Callable[[Any], None] | None = None, feedforward_gain: float = 1.0) -> tuple[EpisodeRecord, EpisodeTrace | None]:
    """Run one episode from ``start`` with ``policy`` and score it (never raises for a failed episode).

    Args:
        env: a PegInHoleEnv (stop_on_success=True).
        policy: an envs.execution.policy policy.
        start: the start pose.
        record_trace: also return the executed trajectory.
        on_step: called with the env after reset and after every step (e.g. video capture).
        feedforward_gain: scale of the velocity feed-forward (envs.execution.policy.feedforward_pose); 0 disables it.

    Returns:
        (EpisodeRecord, EpisodeTrace or None).
    """
    wall = time.perf_counter()
    rec = EpisodeRecord(start.index, start.demo_index, start.pose.pos.tolist(), start.pose.quat.tolist())
    rows: list[tuple[float, FloatArray, FloatArray, FloatArray, FloatArray, float]] = []
    try:
        try:
            obs = env.reset(start_pose=start.pose)
        except EnvError as err:
            rec.reason = f"unreachable start: {err}"
            return rec, None
        period = env.control_period_s
        policy.reset(obs.peg_tip, period)
        max_force = float(np.linalg.norm(obs.wrench[:3]))
        rows.append((obs.time_s, obs.peg_tip.pos, obs.peg_tip.quat, obs.peg_tip.pos, obs.peg_tip.quat, max_force))
        if on_step is not None:
            on_step(env)
        step = 0
        result = None
        while not env.done:
            command = policy.command(step, env.observation.peg_tip)
            target = feedforward_pose(env, command, feedforward_gain)
            result = env.step(target)
            step += 1
            force = float(np.linalg.norm(result.obs.wrench[:3]))
            max_force = max(max_force, force)
            if record_trace:
                o = result.obs
                rows.append((o.time_s, o.peg_tip.pos, o.peg_tip.quat, target.pos, target.quat, force))
            if on_step is not None:
                on_step(env)
        obs = env.observation
        rec.steps = step
        rec.success = bool(obs.success)
        ins = obs.insertion
        if rec.success:
            rec.reason = "success"
            rec.time_to_insert_s = float(env.tracker.success_time_s)
        else:
            reason = env.reason or "not inserted"
            rec.reason = (f"{reason} (depth {ins.depth_m * 1e3:.1f} mm, lateral {ins.lateral_m * 1e3:.2f} mm, "
                          f"tilt {ins.tilt_deg:.1f} deg, yaw {ins.yaw_error_deg:.1f} deg, hole {obs.hole})")
        rec.final_pos = obs.peg_tip.pos.tolist()
        rec.final_quat = obs.peg_tip.quat.tolist()
        rec.final_pos_error_mm = float(np.linalg.norm(obs.peg_tip.pos - env.goal.pos) * 1e3)
        rec.final_angle_error_deg = float(np.rad2deg(quat_angle_rad(obs.peg_tip.quat, env.goal.quat)))
        rec.insertion_depth_mm = float(ins.depth_m * 1e3)
        rec.lateral_error_mm = float(ins.lateral_m * 1e3)
        rec.tilt_deg = float(ins.tilt_deg)
        rec.max_contact_force_n = max_force
    except Exception as err:  # an episode must never abort the batch
        last = traceback.extract_tb(err.__traceback__)[-1] if err.__traceback__ else None
        where = f" at {Path(last.filename).name}:{last.lineno}" if last else ""
        rec.success = False
        rec.reason = f"error: {type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''}{where}"
    finally:
        rec.wall_s = time.perf_counter() - wall
    trace = None
    if record_trace and rows:
        t, p, q, cp, cq, f = zip(*rows)
        trace = EpisodeTrace(np.array(t), np.array(p), np.array(q), np.array(cp), np.array(cq), np.array(f))
    return rec, trace
