"""`pih bench`: speed of the simulation pieces, as medians over repeats (one process, one core each).

    pih bench [--json runs/bench.json] [--quick] [--model runs/default/model] [--only NAME ...]

Every figure is also reported relative to bare `mj_step` from the same run (section "relative_to_bare"):
rates as the ratio rate / bare steps per s, times as the number of bare mj_steps that fit in them (so machines
of different speed compare). With a trained skill (``--model``, default runs/default/model when it exists) the
episode figures run the skill's closed-loop policy with the flow in the loop, and "evaluation" times a
100-episode evaluation on all local cores (episodes/s).

Bare `mj_step` of the scene is not what an episode must pay: the grasp (finger contacts) and the walls add
contacts. So the episode figures also time bare `mj_step` over the episodes' own states
("episode_physics_steps_per_s", the ceiling of the episode's real-time factor), and section "physics_bounds"
gives the least wall time the evaluation's physics steps allow on its workers, beside the measured one.

Benchmarks are entries of ``BENCHMARKS`` (name, function(quick) -> dict of figures). Other packages add
theirs without editing this file: every module named in ``EXTRA_BENCHMARK_MODULES`` that can be imported
and defines ``BENCHMARKS`` (same format) is appended, e.g. the flow timings (closed-loop step, 1000-step
rollout, 100 batched rollouts) next to the paper's 61 min training / 20 s per 1000 samples.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import os
import platform
import tempfile
import time
from pathlib import Path
from typing import Any, Callable

import mujoco
import numpy as np

from controllers.timing import physics_state, replayed_step_rate
from envs.cell.scene import build_scene
from envs.cell.scene_config import SceneConfig
from envs.demos.record import demo_episode_config
from envs.errors import EnvError
from envs.io.owned_output import MiB, check_output, write_json
from envs.media.video import EpisodeVideo, VideoConfig, episode_overlay
from envs.policies.expert import ScriptedExpertPolicy
from envs.policies.expert_plan import ExpertConfig, plan_expert_path
from envs.rollout.episode import StartPose, run_episode
from envs.sim.env import PegInHoleEnv
from scripts.options import work_begins

Benchmark = tuple[str, Callable[[bool], dict[str, Any]]]

CONTROL_RATE_BAR_STEPS_PER_S = 15_000.0
RENDER_FPS_BAR = 15.0
EXTRA_BENCHMARK_MODULES: tuple[str, ...] = ("rflow.bench",)


def bench_control(quick: bool) -> dict[str, Any]:
    """Impedance loop (mj_step1 + controller + mj_step2) on the held-peg scene vs bare mj_step, same run."""
    from controllers.timing import measure_control_rate

    scene = build_scene(SceneConfig())
    rates = measure_control_rate(scene.model, site=scene.ids.tcp_site, n_steps=1000 if quick else 2000,
                                 repeats=3 if quick else 7)
    rates["bar_steps_per_s"] = CONTROL_RATE_BAR_STEPS_PER_S
    rates["meets_bar"] = rates["closed_loop_steps_per_s"] >= CONTROL_RATE_BAR_STEPS_PER_S
    return rates


DEFAULT_MODEL = Path("runs/default/model")
EVALUATION_EPISODES = 100


def bench_episode_steps(quick: bool, model: Path | None = None) -> dict[str, Any]:
    """Control steps per second of whole episodes.

    With a skill: closed-loop episodes from the evaluation's perturbed starts (flow query, feed-forward, nullspace
    IK, 10 controlled physics steps, observation and success check per step), timed from reset to the end; then
    the same episodes again split per control period into their parts (envs.evaluation.profile, "period_us", with
    "physics" the bare mj_steps of a period over the episodes' own states). "ratio_ceiling_without_python" is that
    bare physics over the compiled period alone (`env.run_period`: physics, control law and sensing in one compiled
    call, with the few us of the call itself): the ratio the loop would reach if nothing else ran per period.
    "ratio_floor_compiled_work" is that bare physics over all the compiled kernels of a period ("compiled_us", each
    timed alone: the physics with the law and sensing, the flow, the IK, the lead, the contact adaptation, the
    observation's reads, the success check): the ratio that no compiling of the remaining Python could beat.
    "law_floor_us" times, from every period's state, bare physics, the period under the law of record and under two
    cheaper laws (controllers.law_floor), and the period of record with its sensing; the "ratio_floor_*_law" keys are
    that floor if the law were one of them (`law_floor_ratios`).
    Without: 100 steps toward a fixed target 2 cm below the start (no flow), per repeat.
    """
    if model is None:
        env = PegInHoleEnv()
        rates = []
        for repeat in range(3 if quick else 5):
            env.reset(seed=repeat)
            target = (env.observation.peg_tip.pos - np.array([0.0, 0.0, 0.02]), env.observation.peg_tip.quat)
            start = time.perf_counter()
            for _ in range(100):
                env.step(target)
            rates.append(100 / (time.perf_counter() - start))
        median = float(np.median(rates))
        period = env.control_period_s
        substeps = env.n_substeps
        extra: dict[str, Any] = {"flow_in_loop": False}
    else:
        from envs.evaluation.evaluate import EvaluationConfig, build_setup
        from envs.evaluation.profile import law_floor_periods, profile_periods
        from envs.evaluation.starts import evaluation_starts

        config = EvaluationConfig(episodes=2 if quick else 5)
        skill, env, policy = build_setup(model, config)
        demo = skill.metadata["demo_starts"]
        starts = evaluation_starts(demo, config)
        rates, physics, successes = [], [], 0
        for start in starts:
            states: list[np.ndarray] = []
            record, _ = run_episode(env, policy, start, feedforward_gain=config.feedforward_gain,
                                    on_step=lambda e: states.append(physics_state(e.model, e.data)))
            rates.append(record.steps / record.wall_s)
            physics.append(episode_physics_rate(env, states))
            successes += int(record.success)
        median = float(np.median(rates))
        period = env.control_period_s
        substeps = env.n_substeps
        bare = float(np.median(physics))
        profile = profile_periods(env, policy, starts, config.feedforward_gain)
        compiled = profile.pop("compiled")
        profile["physics"] = 1e6 * substeps / bare  # inside control_and_sensing
        law_floor = law_floor_periods(env, policy, starts, config.feedforward_gain)
        extra = {"flow_in_loop": True, "episodes": len(starts), "successes": successes,
                 "episode_physics_steps_per_s": bare,
                 "physics_realtime_factor": bare * float(env.model.opt.timestep),
                 "ratio_to_episode_physics": median * substeps / bare,
                 "ratio_ceiling_without_python": profile["physics"] / profile["control_and_sensing"],
                 "ratio_floor_compiled_work": profile["physics"] / sum(compiled.values()),
                 "period_us": {key: round(value, 1) for key, value in profile.items()},
                 "compiled_us": {key: round(value, 1) for key, value in compiled.items()},
                 **law_floor_ratios(law_floor, compiled)}
    return {"env_steps_per_s": median, "physics_steps_per_s": median * substeps,
            "realtime_factor": median * period, **extra}


def law_floor_ratios(law_floor: dict[str, float], compiled: dict[str, float]) -> dict[str, Any]:
    """The ratio to bare physics that no compiling of the remaining Python could beat, under the law of record and
    under the cheaper laws of controllers.law_floor: bare physics over (the period under that law + the sensing +
    every other compiled kernel of a period). The laws, the sensing (the period of record less its law) and the
    physics are timed from the same states (`law_floor_periods`); the other kernels are `profile_periods`' of the
    same episodes."""
    sensing = law_floor["law_of_record_and_sensing"] - law_floor["law_of_record"]
    others = sum(compiled.values()) - compiled["physics_law_and_sensing"]
    physics = law_floor["physics"]
    return {"law_floor_us": {key: round(value, 1) for key, value in law_floor.items()},
            "ratio_floor_law_of_record": physics / (law_floor["law_of_record_and_sensing"] + others),
            "ratio_floor_held_factors_law": physics / (law_floor["held_factors_law"] + sensing + others),
            "ratio_floor_spring_damper_law": physics / (law_floor["spring_damper_law"] + sensing + others)}


def episode_physics_rate(env: PegInHoleEnv, states: list[np.ndarray]) -> float:
    """Bare mj_step steps/s over an episode's own states (one per control step, grasp and wall contacts as they
    were; `controllers.timing.replayed_step_rate` with ``env.n_substeps`` steps from each). This is the physics
    an episode cannot avoid, so its steps/s times the timestep is the ceiling of ``realtime_factor``."""
    return replayed_step_rate(env.model, states, env.n_substeps)


def bench_evaluation(quick: bool, model: Path | None = None) -> dict[str, Any]:
    """A closed-loop evaluation of the skill (10 episodes with --quick) on all local cores, episodes/s, with the
    default lockstep batches and again one episode at a time (``lockstep=1``; same records)."""
    if model is None:
        return {"skipped": "no trained skill (--model)"}
    from envs.evaluation.evaluate import EvaluationConfig, evaluate

    config = EvaluationConfig(episodes=10 if quick else EVALUATION_EPISODES, workers=os.cpu_count() or 1)
    start = time.perf_counter()
    result = evaluate(model, config, progress=False)
    wall = time.perf_counter() - start
    start = time.perf_counter()
    alone = evaluate(model, dataclasses.replace(config, lockstep=1), progress=False)
    wall_alone = time.perf_counter() - start
    same = [r.to_dict() | {"wall_s": 0} for r in alone.records] == [r.to_dict() | {"wall_s": 0} for r in result.records]
    successes = sum(int(r.success) for r in result.records)
    env = PegInHoleEnv()
    settle = int(round(env.config.grasp_settle_s / float(env.model.opt.timestep)))
    physics_steps = sum(r.steps * env.n_substeps + settle for r in result.records)
    return {"episodes": config.episodes, "workers": config.workers, "lockstep": config.lockstep, "wall_s": wall,
            "episodes_per_s": config.episodes / wall, "successes": successes, "physics_steps": physics_steps,
            "wall_s_one_at_a_time": wall_alone, "records_equal_one_at_a_time": same}


LOCKSTEP_SLOTS: tuple[int, ...] = (1, 8, 32, 128)
"""Episodes per lockstep batch timed by `bench_lockstep` (--quick: the first two)."""


def bench_lockstep(quick: bool, model: Path | None = None) -> dict[str, Any]:
    """Episodes in lockstep (envs.rollout.lockstep) against their own bare physics, one core.

    The same evaluation starts (128; 16 with --quick) run one at a time (`run_episode`) and in lockstep
    with K = LOCKSTEP_SLOTS slots on one thread, and with K = 32 (8 with --quick) on two threads. Their physics is
    timed apart: bare mj_step from every control period's state of every episode (`episode_physics_rate` after each
    episode, in that episode's model), the least time the episodes need on one core. Each figure's
    "ratio_to_physics" is that time over its wall time (1.0: no cost beyond the physics; above 1 only with threads).
    The records of every variant equal the one-at-a-time ones ("records_equal")."""
    if model is None:
        return {"skipped": "no trained skill (--model)"}
    from envs.evaluation.evaluate import EvaluationConfig, build_slots
    from envs.evaluation.starts import evaluation_starts
    from envs.rollout.lockstep import run_lockstep

    sizes = LOCKSTEP_SLOTS[:2] if quick else LOCKSTEP_SLOTS
    config = EvaluationConfig(episodes=16 if quick else max(sizes))
    skill, envs, policies = build_slots(model, config, max(sizes))
    starts = evaluation_starts(skill.metadata["demo_starts"], config)
    env, policy = envs[0], policies[0]
    physics_s, periods = 0.0, 0
    for start in starts:
        states: list[np.ndarray] = []
        record, _ = run_episode(env, policy, start, feedforward_gain=config.feedforward_gain,
                                on_step=lambda e: states.append(physics_state(e.model, e.data)))
        periods += record.steps
        physics_s += len(states) * env.n_substeps / episode_physics_rate(env, states)

    def strip(records: list[Any]) -> list[dict[str, Any]]:
        return [{k: v for k, v in r.to_dict().items() if k != "wall_s"} for r in records]

    wall = time.perf_counter()
    reference = strip([run_episode(env, policy, s, feedforward_gain=config.feedforward_gain)[0] for s in starts])
    one_at_a_time = time.perf_counter() - wall
    figures: dict[str, Any] = {"episodes": len(starts), "periods": periods, "physics_s": physics_s,
                               "one_at_a_time": {"wall_s": one_at_a_time,
                                                 "ratio_to_physics": physics_s / one_at_a_time}}
    equal = True
    for slots, threads in [(k, 1) for k in sizes] + [(8 if quick else 32, 2)]:
        wall = time.perf_counter()
        records = run_lockstep(envs[:slots], policies[:slots], starts, config.feedforward_gain, threads=threads)
        elapsed = time.perf_counter() - wall
        equal = equal and strip(records) == reference
        figures[f"slots_{slots}" + ("" if threads == 1 else f"_threads_{threads}")] = {
            "wall_s": elapsed, "ratio_to_physics": physics_s / elapsed, "periods_per_s": periods / elapsed,
            "speedup_over_one_at_a_time": one_at_a_time / elapsed}
    figures["records_equal"] = equal
    return figures


def bench_render(quick: bool) -> dict[str, Any]:
    """A scripted episode (the expert through the episode loop, 10 s, 3 s with --quick) rendered at 640x480, 30 fps,
    to MP4 (with the overlay of `pih evaluate --video`), and the same episode without video: "video_over_physics" is what the video adds
    (rendering and encoding) over the wall time of the episode's own physics, a ratio that compares across machines
    (`pih evaluate --video` of realistic episodes costs about this much more than without)."""
    expert = ExpertConfig()
    seconds = 3.0 if quick else 10.0
    episode = dataclasses.replace(demo_episode_config(expert), time_limit_s=seconds + 1.0)
    env = PegInHoleEnv(episode_config=episode)
    steps = int(round(seconds / env.control_period_s))
    times = env.control_period_s * np.arange(1, steps + 1)
    env.reset(seed=0)
    start = StartPose(0, -1, env.start)
    plan = plan_expert_path(env.start, env.hole.pos, env.hole_axis, env.goal, expert, times)

    def run(on_step: Callable[[PegInHoleEnv], None] | None = None) -> None:
        run_episode(env, ScriptedExpertPolicy(expert, plan=plan), start, on_step=on_step, privileged=True,
                    max_steps=steps)

    begin = time.perf_counter()
    run()
    physics_s = time.perf_counter() - begin
    with tempfile.TemporaryDirectory() as folder:
        begin = time.perf_counter()
        with EpisodeVideo(env.model, Path(folder) / "bench.mp4", VideoConfig(), goal=env.goal,
                          commanded_path=plan[0]) as video:

            def capture(sim: PegInHoleEnv) -> None:
                obs = sim.observation
                video.capture(sim.data, obs.time_s, text=lambda: episode_overlay(
                    "episode 0", None, obs.time_s, float(np.linalg.norm(obs.wrist_wrench[:3]))))

            run(capture)
        wall = time.perf_counter() - begin
        size = (Path(folder) / "bench.mp4").stat().st_size
    render_encode_fps = video.frames / (video.render_s + video.encode_s)
    return {
        "episode_s": seconds,
        "physics_s": physics_s,
        "video_s": video.render_s + video.encode_s,
        "video_over_physics": (video.render_s + video.encode_s) / physics_s,
        "frames": video.frames,
        "render_encode_fps": render_encode_fps,
        "end_to_end_fps": video.frames / wall,
        "render_ms_per_frame": 1e3 * video.render_s / video.frames,
        "encode_ms_per_frame": 1e3 * video.encode_s / video.frames,
        "mp4_kib": size / 1024,
        "bar_fps": RENDER_FPS_BAR,
        "meets_bar": render_encode_fps >= RENDER_FPS_BAR,
    }


def bench_ik(quick: bool) -> dict[str, Any]:
    """IK solves (`solve_ik`) of the tcp on the arm model (from the home posture) per second, and the nullspace
    reference's per-control-step update."""
    from controllers.timing import measure_ik_rate, measure_nullspace_update

    scene = build_scene(SceneConfig())
    figures = measure_ik_rate(scene.arm_model, site="tcp", n_solves=10 if quick else 30)
    figures.update(measure_nullspace_update(scene.arm_model, site="tcp", n_updates=200 if quick else 1000))
    return figures


BENCHMARKS: list[Benchmark] = [
    ("control", bench_control),
    ("episode_steps", bench_episode_steps),
    ("evaluation", bench_evaluation),
    ("render", bench_render),
    ("ik", bench_ik),
    ("lockstep", bench_lockstep),
]
NEEDS_MODEL: frozenset[str] = frozenset({"episode_steps", "evaluation", "lockstep"})
"""Benchmarks called with the trained skill (function(quick, model))."""

RATE_FIGURES: dict[str, str] = {
    "control.closed_loop_steps_per_s": "control.ratio",
    "episode_steps.physics_steps_per_s": "episode_steps.ratio",
    "render.render_encode_fps": "render.frames_per_bare_step",
    "ik.ik_solves_per_s": "ik.solves_per_bare_step",
    "evaluation.episodes_per_s": "evaluation.episodes_per_bare_step",
    "flow.closed_loop_rate_hz": "flow.closed_loop_steps_per_bare_step",
}
"""Rates reported as rate / bare mj_step rate."""
TIME_FIGURES_S: dict[str, float] = {
    "flow.flow_step_ms": 1e-3,
    "flow.closed_loop_step_ms": 1e-3,
    "flow.rollout_1000_ms": 1e-3,
    "flow.rollouts_100x1000_ms": 1e-3,
    "render.render_ms_per_frame": 1e-3,
    "ik.ik_ms_median": 1e-3,
    "ik.nullspace_update_us_median": 1e-6,
    "control.controller_us_per_step": 1e-6,
}
"""Times (with their unit in seconds) reported as the number of bare mj_steps that take as long."""


def relative_to_bare(results: dict[str, Any]) -> dict[str, float]:
    """Every figure of RATE_FIGURES and TIME_FIGURES_S present in `results`, relative to the bare mj_step rate of
    the same run (results["control"]["bare_steps_per_s"]); empty without the control benchmark."""
    bare = results.get("control", {}).get("bare_steps_per_s")
    if not bare:
        return {}
    out: dict[str, float] = {"bare_steps_per_s": float(bare)}
    for figure, name in RATE_FIGURES.items():
        section, key = figure.split(".")
        value = results.get(section, {}).get(key)
        if isinstance(value, (int, float)):
            out[name] = float(value) / bare
    for figure, unit_s in TIME_FIGURES_S.items():
        section, key = figure.split(".")
        value = results.get(section, {}).get(key)
        if isinstance(value, (int, float)):
            out[f"{figure}_in_bare_steps"] = float(value) * unit_s * bare
    return out


def physics_bounds(results: dict[str, Any]) -> dict[str, float]:
    """What the episodes' own physics allows, from the same run: the evaluation's least possible wall time,
    its physics steps / (workers x bare steps/s over episode states), against the measured one. Empty without
    the episode_steps and evaluation benchmarks."""
    rate = results.get("episode_steps", {}).get("episode_physics_steps_per_s")
    evaluation = results.get("evaluation", {})
    if not rate or "physics_steps" not in evaluation:
        return {}
    bound = evaluation["physics_steps"] / (evaluation["workers"] * rate)
    return {"evaluation.physics_bound_s": bound, "evaluation.wall_over_physics_bound": evaluation["wall_s"] / bound}


def all_benchmarks() -> list[Benchmark]:
    """BENCHMARKS plus those of the importable modules in EXTRA_BENCHMARK_MODULES."""
    found = list(BENCHMARKS)
    for name in EXTRA_BENCHMARK_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as err:
            if err.name != name:
                raise
            continue
        found.extend(getattr(module, "BENCHMARKS", []))
    return found


def machine() -> dict[str, Any]:
    """Where the figures were taken: CPU, cores, load, versions."""
    return {
        "cpu": platform.processor() or platform.machine(),
        "cores": os.cpu_count(),
        "load_average_1min": os.getloadavg()[0],
        "python": platform.python_version(),
        "mujoco": mujoco.__version__,
        "mujoco_gl": os.environ.get("MUJOCO_GL"),
    }


def _format(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:,.1f}" if abs(value) >= 10 else f"{value:.3g}"
    return str(value)


EXAMPLES: tuple[str, ...] = ('pih bench --model runs/default/model --json bench.json',
                             'pih bench --only render --quick')
"""Shown at the end of --help (scripts.cli)."""

def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `pih bench`."""
    parser.add_argument("--json", type=Path, help="also write the figures to this JSON file")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace --json when an earlier pih run wrote it (never a file pih did not write)")
    parser.add_argument("--quick", action="store_true", help="fewer repeats and a 3 s render (smoke test)")
    parser.add_argument("--only", nargs="+", metavar="NAME", help="run only these benchmarks")
    parser.add_argument("--model", type=Path,
                        help=f"trained skill for the episode and evaluation figures (default {DEFAULT_MODEL} "
                             "when it exists; without one the episode figure uses a fixed target)")


def main(args: argparse.Namespace) -> int:
    """Run the benchmarks, print them, optionally write JSON; returns the exit status."""
    model = getattr(args, "model", None)
    check_output("--json", args.json, args.overwrite, suffix=".json", inputs=[model, DEFAULT_MODEL if model is None
                                                                              else None], estimate_bytes=MiB)
    if model is not None:
        from numerics.errors import NumericsError
        from rflow.skill_io import load_skill

        try:
            load_skill(model)
        except NumericsError as err:  # RFlowError too
            raise EnvError(f"--model {model}: {err}") from None
    elif DEFAULT_MODEL.is_dir():
        model = DEFAULT_MODEL
    benchmarks = all_benchmarks()
    if args.only:
        unknown = sorted(set(args.only) - {name for name, _ in benchmarks})
        if unknown:
            raise EnvError(f"unknown benchmark(s) {unknown}; available: {[name for name, _ in benchmarks]}")
        benchmarks = [b for b in benchmarks if b[0] in args.only]
    work_begins()
    results: dict[str, Any] = {"machine": machine()}
    for name, function in benchmarks:
        start = time.perf_counter()
        figures = function(bool(args.quick), model) if name in NEEDS_MODEL else function(bool(args.quick))
        figures["bench_wall_s"] = time.perf_counter() - start
        results[name] = figures
        print(f"{name}:")
        for key, value in figures.items():
            if isinstance(value, dict):
                print(f"  {key}:")
                for part, number in value.items():
                    print(f"    {part:26s} {_format(number)}")
            else:
                print(f"  {key:28s} {_format(value)}")
    results["machine"]["load_average_1min_end"] = os.getloadavg()[0]
    results["relative_to_bare"] = relative_to_bare(results)
    results["physics_bounds"] = physics_bounds(results)
    for section in ("relative_to_bare", "physics_bounds"):
        if results[section]:
            print(f"{section}:")
        for key, value in results[section].items():
            print(f"  {key:40s} {_format(value)}")
    if args.json is not None:
        write_json(args.json, results)
        print(f"wrote {args.json}")
    return 0
