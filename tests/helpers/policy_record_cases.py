"""The short evaluation whose episode records pin the RiemannianFlow skill's behaviour, so that a refactor that means
to change nothing can show it changed nothing.

`record_cases()` runs the tiny skill (tests/helpers/skill_fixtures.py) closed loop (controller stiffness and a constant
500 N/m) and open loop from two starts 45 mm above the goal with a 1 mm / 1 deg hole-pose error, so that the episodes
reach the chamfer and the contact adaptation and the insertion act; tests/envs/policies/test_policy_records.py runs it
and compares with the stored records. A change that means to change the skill's episodes writes the fixture again
(`python -m tests.helpers.policy_record_cases tests/data/policy_records.json` from the repository's root) and says so
in its commit message.
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path
from typing import Any

from numerics.cpu_dispatch import pin_cpu_dispatch

pin_cpu_dispatch()  # before numpy loads, when this runs as a script: the records of pih, not of the host's loops

import numpy as np  # noqa: E402

CASES: tuple[tuple[str, str | None], ...] = (("closed-loop", None), ("closed-loop", "constant:500"), ("open-loop", None))
TIME_LIMIT_S = 3.0
FIXTURE = Path(__file__).resolve().parents[1] / "data" / "policy_records.json"
"""The stored records."""


def trace_sha256(trace: Any) -> str:
    """SHA-256 over every array of an EpisodeTrace, in field order (float64 / bool bytes)."""
    digest = hashlib.sha256()
    for name in ("times_s", "pos", "quat", "cmd_pos", "cmd_quat", "force_n", "stiffness", "tcp_pos", "tcp_quat",
                 "qpos", "qvel", "wrist_wrench", "success"):
        value = np.ascontiguousarray(getattr(trace, name))
        digest.update(name.encode())
        digest.update(value.astype(bool if value.dtype == bool else np.float64).tobytes())
    return digest.hexdigest()


def skill_fingerprint(skill: Any) -> list[float]:
    """Where the tiny skill's flow takes one fixed pose 50 ms ahead: equal only if it trained to the same weights."""
    from envs.policies.flow_skill import skill_step
    from tests.helpers.skill_fixtures import GOAL_POS, GOAL_QUAT

    pos, quat = skill_step(skill, GOAL_POS + np.array([0.01, -0.02, 0.1]), GOAL_QUAT, 0.05)
    return [*np.asarray(pos).tolist(), *np.asarray(quat).tolist()]


def record_cases() -> dict[str, Any]:
    """{"fingerprint": ..., "episodes": [{"mode", "stiffness", "record" (without wall_s), "trace_sha256"}, ...]}."""
    from envs.evaluation.evaluate import sample_starts
    from envs.policies.flow_skill import StiffnessSetting, make_policy
    from envs.rollout.episode import run_episode
    from envs.sim.env import EpisodeConfig, PegInHoleEnv
    from envs.task.perturbation import PerturbationRanges
    from tests.helpers.skill_fixtures import GOAL_POS, GOAL_QUAT, tiny_skill

    skill = tiny_skill()
    env = PegInHoleEnv(episode_config=EpisodeConfig(time_limit_s=TIME_LIMIT_S))
    starts = sample_starts(GOAL_POS[None] + np.array([[0.0, 0.0, 0.045]]), GOAL_QUAT[None], 2, 5, 0.002, 2.0,
                           perturbations=PerturbationRanges(hole_error_m=0.001, hole_error_deg=1.0))
    episodes = []
    for mode, stiffness in CASES:
        setting = None if stiffness is None else StiffnessSetting.parse(stiffness)
        policy = make_policy(skill, mode, duration_s=TIME_LIMIT_S, stiffness=setting)
        for start in starts:
            record, trace = run_episode(env, policy, start, record_trace=True)
            values = record.to_dict()
            values.pop("wall_s")
            episodes.append({"mode": mode, "stiffness": stiffness, "record": values, "trace_sha256": trace_sha256(trace)})
    return {"fingerprint": skill_fingerprint(skill), "episodes": episodes}


if __name__ == "__main__":
    Path(sys.argv[1]).write_text(json.dumps(record_cases(), indent=1) + "\n")
