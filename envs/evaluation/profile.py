"""Where a closed-loop control period goes: wall time per period of each part of the episode step, for `pih bench`.

The parts are timed by wrapping, for the duration of the profile only, the instance methods that do them (the
environment's, its controller's and the policy's own objects): the controlled physics steps with the per-step sensing
(``env.run_period``), the observation and success check (``env._observe``), the policy with its flow queries
(``policy.act``), the controller's command of the action, its stiffness and feed-forward lead
(``controller.command``), the nullspace IK (``nullspace.update``) and the instability check (``env._instability``).
"other" is the rest of the loop (validation, the policy's observation, bookkeeping). The episode's reset (start pose,
grasp settling) is timed apart and left out of the periods. A wrapper adds ~0.3 us per call, a few us per period.

Apart from the parts, the compiled kernels are timed on their own (COMPILED, wrapped where their callers look them
up): the work a period cannot shed by moving Python into compiled code, its floor.
"""

from __future__ import annotations

import importlib
import time
from typing import Any, Callable, Sequence

import mujoco
import numpy as np

from controllers.law_floor import LAW_HELD_FACTORS, LAW_OF_RECORD, LAW_SPRING_DAMPER, reference_period
from envs.rollout.episode import run_episode
from envs.sim.period_kernel import controlled_period

PARTS: tuple[tuple[str, str, str], ...] = (
    ("control_and_sensing", "env", "run_period"),
    ("observation_and_success", "env", "_observe"),
    ("policy", "policy", "act"),
    ("feedforward_lead", "controller", "command"),
    ("nullspace_ik", "nullspace", "update"),
    ("instability_check", "env", "_instability"),
)
"""(part, owner, method): the owner is the environment, the policy, the environment's controller or its nullspace."""

COMPILED: tuple[tuple[str, str, tuple[str, ...]], ...] = (
    ("physics_law_and_sensing", "envs.sim.env", ("controlled_period",)),
    ("flow", "rflow.flow_kernel", ("chart_flow_steps", "flow_step")),
    ("nullspace_ik", "controllers.ik_kernel", ("ik_iterations",)),
    ("feedforward_lead", "controllers.feedforward_kernel", ("led_pose_into",)),
    ("contact_adaptation", "envs.policies.closed_loop_kernel",
     ("query_into", "action_into", "sense_into", "offset_into", "near_goal", "update_translation", "update_rotation")),
    ("observation", "envs.sim.observation_kernel", ("read_sites_into",)),
    ("success", "envs.task.success", ("assess_tip",)),
)
"""(part, module, functions): the compiled kernels of a control period, each timed where its caller looks it up (the
module attribute its caller reads)."""


class _Timers:
    """Nanoseconds per part, not counted while the episode resets."""

    def __init__(self) -> None:
        self.totals = {part: 0 for part, _, _ in PARTS}
        self.reset_ns = 0
        self.resetting = False

    def part(self, method: Callable[..., Any], part: str) -> Callable[..., Any]:
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            start = time.perf_counter_ns()
            try:
                return method(*args, **kwargs)
            finally:
                if not self.resetting:
                    self.totals[part] += time.perf_counter_ns() - start
        return wrapper

    def reset(self, method: Callable[..., Any]) -> Callable[..., Any]:
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            start = time.perf_counter_ns()
            self.resetting = True
            try:
                return method(*args, **kwargs)
            finally:
                self.resetting = False
                self.reset_ns += time.perf_counter_ns() - start
        return wrapper


def profile_periods(env: Any, policy: Any, starts: Sequence[Any], feedforward_gain: float = 1.0) -> dict[str, Any]:
    """Run the episodes of ``starts`` and split their control periods' wall time into PARTS.

    Returns:
        {part: us per period} for every part, "other" and "total" (per period, resets excluded), "compiled" ({part
        of COMPILED: us per period}, inside the parts), "reset_ms" (per episode) and "periods" (the number timed).
    """
    owners = {"env": env, "policy": policy, "controller": env.controller, "nullspace": env.nullspace}
    timers = _Timers()
    originals = {(owner, name): getattr(owners[owner], name) for _, owner, name in PARTS}
    for part, owner, name in PARTS:
        setattr(owners[owner], name, timers.part(originals[(owner, name)], part))
    kernels = {(module, name): getattr(importlib.import_module(module), name)
               for _, module, names in COMPILED for name in names}
    for part, module, names in COMPILED:
        timers.totals["compiled." + part] = 0
        for name in names:
            setattr(importlib.import_module(module), name, timers.part(kernels[(module, name)], "compiled." + part))
    env.reset = timers.reset(env.reset)
    periods, wall = 0, 0
    try:
        for start in starts:
            begin = time.perf_counter_ns()
            record, _ = run_episode(env, policy, start, feedforward_gain=feedforward_gain)
            wall += time.perf_counter_ns() - begin
            periods += record.steps
    finally:
        for (module, name), kernel in kernels.items():
            setattr(importlib.import_module(module), name, kernel)
        for _, owner, name in PARTS:
            delattr(owners[owner], name)  # the class's method again
        del env.reset
    scale = 1e-3 / max(periods, 1)
    out = {part: timers.totals[part] * scale for part, _, _ in PARTS}
    out["total"] = (wall - timers.reset_ns) * scale
    out["other"] = out["total"] - sum(out[part] for part, _, _ in PARTS)
    out["compiled"] = {part: timers.totals["compiled." + part] * scale for part, _, _ in COMPILED}
    out["reset_ms"] = timers.reset_ns * 1e-6 / max(len(starts), 1)
    out["periods"] = float(periods)
    return out


LAW_FLOOR_PARTS: tuple[str, ...] = ("physics", "spring_damper_law", "held_factors_law", "law_of_record",
                                    "law_of_record_and_sensing")
"""What `law_floor_periods` times from every period's state: bare mj_step; the period under the cheaper laws of
controllers.law_floor and under the law of record, without sensing; the compiled period of record (law and sensing,
envs.sim.period_kernel)."""


def law_floor_periods(env: Any, policy: Any, starts: Sequence[Any], feedforward_gain: float = 1.0) -> dict[str, Any]:
    """Time each LAW_FLOOR_PARTS from the state at the start of every control period of the episodes of ``starts``.

    Before each period of record runs, its state (the whole MjData, whose kinematics the tool load reads before
    mj_step1, and every writable buffer of the period's arguments) is saved; each part then runs from it, in an
    order shuffled per period, and the state is restored after each, so all parts pay for the same contacts and the
    episodes themselves run as they would unprofiled.
    The first period is left out of the timings (the kernels' load).

    Returns:
        {part: us per period} and "periods" (the number timed).
    """
    model = env.model
    saved_data = mujoco.MjData(model)
    totals = dict.fromkeys(LAW_FLOOR_PARTS, 0)
    seen = [0]
    run_period = env.run_period
    n = env.n_substeps
    laws = {"spring_damper_law": LAW_SPRING_DAMPER, "held_factors_law": LAW_HELD_FACTORS,
            "law_of_record": LAW_OF_RECORD}

    def timed(period: Any) -> None:
        args = period.arguments
        if period.problem is None and args is not None:
            data = env.data
            mujoco.mj_copyData(saved_data, model, data)
            saved = [(a, a.copy()) for a in args if isinstance(a, np.ndarray) and a.flags.writeable]
            order = list(LAW_FLOOR_PARTS)
            np.random.default_rng(seen[0]).shuffle(order)
            for part in order:
                begin = time.perf_counter_ns()
                if part == "physics":
                    for _ in range(n):
                        mujoco.mj_step(model, data)
                elif part == "law_of_record_and_sensing":
                    controlled_period(n, *args)
                else:
                    reference_period(n, laws[part], *args[:23])
                if seen[0] > 0:
                    totals[part] += time.perf_counter_ns() - begin
                mujoco.mj_copyData(data, model, saved_data)
                for array, copy in saved:
                    np.copyto(array, copy)
            seen[0] += 1
        run_period(period)

    env.run_period = timed
    try:
        for start in starts:
            run_episode(env, policy, start, feedforward_gain=feedforward_gain)
    finally:
        del env.run_period
    periods = max(seen[0] - 1, 1)
    out: dict[str, Any] = {part: totals[part] * 1e-3 / periods for part in LAW_FLOOR_PARTS}
    out["periods"] = float(seen[0] - 1)
    return out
