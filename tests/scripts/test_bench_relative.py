"""`pih bench`: figures relative to bare mj_step from the same run, and the --model option."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import numpy as np

from controllers.timing import physics_state
from scripts.bench import episode_physics_rate, physics_bounds, relative_to_bare
from scripts.cli import main


def test_rates_are_divided_and_times_converted_to_bare_steps() -> None:
    results = {
        "control": {"closed_loop_steps_per_s": 10_000.0, "bare_steps_per_s": 20_000.0, "controller_us_per_step": 50.0},
        "episode_steps": {"physics_steps_per_s": 5_000.0},
        "flow": {"rollouts_100x1000_ms": 50.0},
        "ik": {"nullspace_update_us_median": 100.0},
    }
    relative = relative_to_bare(results)
    assert relative["control.ratio"] == pytest.approx(0.5)
    assert relative["episode_steps.ratio"] == pytest.approx(0.25)
    assert relative["flow.rollouts_100x1000_ms_in_bare_steps"] == pytest.approx(1000.0)  # 50 ms at 20 k/s
    assert relative["ik.nullspace_update_us_median_in_bare_steps"] == pytest.approx(2.0)
    assert relative["control.controller_us_per_step_in_bare_steps"] == pytest.approx(1.0)
    assert "render.frames_per_bare_step" not in relative  # absent benchmarks are skipped


def test_nothing_relative_without_the_bare_figure() -> None:
    assert relative_to_bare({"flow": {"rollouts_100x1000_ms": 50.0}}) == {}


def test_bench_json_has_the_relative_section(tmp_path: Path) -> None:
    out = tmp_path / "bench.json"
    assert main(["bench", "--quick", "--only", "control", "--json", str(out)]) == 0
    figures = json.loads(out.read_text())
    assert figures["relative_to_bare"]["control.ratio"] == pytest.approx(figures["control"]["ratio"])


def test_bad_model_exits_2_before_any_benchmark(tmp_path: Path, capsys) -> None:
    out = tmp_path / "bench.json"
    assert main(["bench", "--model", str(tmp_path / "no_model"), "--json", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("pih bench: error: --model") and "no_model" in err[0]
    assert not out.exists()


def test_the_physics_bound_is_the_evaluations_steps_over_its_workers_physics_rate() -> None:
    results = {"episode_steps": {"episode_physics_steps_per_s": 20_000.0},
               "evaluation": {"physics_steps": 800_000, "workers": 2, "wall_s": 60.0}}
    bounds = physics_bounds(results)
    assert bounds["evaluation.physics_bound_s"] == pytest.approx(20.0)  # 800 k steps / (2 x 20 k/s)
    assert bounds["evaluation.wall_over_physics_bound"] == pytest.approx(3.0)
    assert physics_bounds({"evaluation": results["evaluation"]}) == {}


def test_timing_the_episode_physics_leaves_the_episode_alone() -> None:
    from envs.sim.env import PegInHoleEnv

    env = PegInHoleEnv()
    env.reset(seed=0)
    states = [physics_state(env.model, env.data)]
    for _ in range(3):
        env.step(env.observation.tcp)
        states.append(physics_state(env.model, env.data))
    before = physics_state(env.model, env.data)
    assert episode_physics_rate(env, states) > 0
    np.testing.assert_array_equal(physics_state(env.model, env.data), before)
