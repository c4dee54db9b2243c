"""`pih bench`: speed of the simulation pieces, as medians over repeats (one process, one core each).

    pih bench [--json runs/bench.json] [--quick]

Benchmarks are entries of ``BENCHMARKS`` (name, function(quick) -> dict of figures). Other packages add
theirs without editing this file: every module named in ``EXTRA_BENCHMARK_MODULES`` that can be imported
and defines ``BENCHMARKS`` (same format) is appended, e.g. the flow timings (closed-loop step, 1000-step
rollout, 100 batched rollouts) next to the paper's 61 min training / 20 s per 1000 samples.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import json
import os
import platform
import tempfile
import time
from pathlib import Path
from typing import Any, Callable

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from envs.demos import ExpertConfig, demo_episode_config, plan_expert_path  # noqa: E402
from envs.env import PegInHoleEnv  # noqa: E402
from envs.errors import EnvError  # noqa: E402
from envs.scene import SceneConfig, build_scene  # noqa: E402
from envs.video import EpisodeVideo, VideoConfig  # noqa: E402

Benchmark = tuple[str, Callable[[bool], dict[str, Any]]]

CONTROL_RATE_BAR_STEPS_PER_S = 15_000.0
RENDER_FPS_BAR = 15.0
EXTRA_BENCHMARK_MODULES: tuple[str, ...] = ("rflow.bench",)


def bench_control(quick: bool) -> dict[str, Any]:
    """Impedance loop (mj_step1 + controller + mj_step2) on the held-peg scene vs bare mj_step, same run."""
    from controllers.benchmark import measure_control_rate

    scene = build_scene(SceneConfig())
    rates = measure_control_rate(scene.model, site="peg/peg_tip", n_steps=1000 if quick else 2000,
                                 repeats=3 if quick else 7)
    rates["bar_steps_per_s"] = CONTROL_RATE_BAR_STEPS_PER_S
    rates["meets_bar"] = rates["closed_loop_steps_per_s"] >= CONTROL_RATE_BAR_STEPS_PER_S
    return rates


def bench_episode_steps(quick: bool) -> dict[str, Any]:
    """Full environment control steps (nullspace IK + 10 controlled physics steps + observation) per second."""
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
    return {"env_steps_per_s": median, "physics_steps_per_s": median * env.n_substeps,
            "realtime_factor": median * env.control_period_s}


def bench_render(quick: bool) -> dict[str, Any]:
    """A scripted episode (10 s, 3 s with --quick) rendered at 640x480, 30 fps, to MP4."""
    expert = ExpertConfig()
    seconds = 3.0 if quick else 10.0
    episode = dataclasses.replace(demo_episode_config(expert), time_limit_s=seconds + 1.0)
    env = PegInHoleEnv(episode_config=episode)
    env.reset(seed=0)
    steps = int(round(seconds / env.control_period_s))
    times = env.control_period_s * np.arange(1, steps + 1)
    path_pos, path_quat = plan_expert_path(env.start, env.hole.pos, env.hole_axis, env.goal, expert, times)
    with tempfile.TemporaryDirectory() as folder:
        start = time.perf_counter()
        with EpisodeVideo(env.model, Path(folder) / "bench.mp4", VideoConfig(), goal=env.goal,
                          commanded_path=path_pos) as video:
            video.capture(env.data, 0.0)
            for k in range(steps):
                result = env.step((path_pos[k], path_quat[k]))
                video.capture(env.data, result.obs.time_s)
        wall = time.perf_counter() - start
        size = (Path(folder) / "bench.mp4").stat().st_size
    render_encode_fps = video.frames / (video.render_s + video.encode_s)
    return {
        "episode_s": seconds,
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
    """mink IK solves (peg_tip site, from the home posture) per second."""
    from controllers.benchmark import measure_ik_rate

    scene = build_scene(SceneConfig())
    return measure_ik_rate(scene.model, site="peg/peg_tip", n_solves=10 if quick else 30)


BENCHMARKS: list[Benchmark] = [
    ("control", bench_control),
    ("episode_steps", bench_episode_steps),
    ("render", bench_render),
    ("ik", bench_ik),
]


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


def write_json(path: Path, payload: dict[str, Any]) -> None:
    """Write JSON atomically (temp file in the same folder, then os.replace)."""
    if not path.parent.is_dir():
        raise EnvError(f"--json {path}: folder {path.parent} does not exist")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as handle:
            json.dump(payload, handle, indent=2, sort_keys=True)
            handle.write("\n")
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _format(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:,.1f}" if abs(value) >= 10 else f"{value:.3g}"
    return str(value)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `pih bench`."""
    parser.add_argument("--json", type=Path, help="also write the figures to this JSON file")
    parser.add_argument("--quick", action="store_true", help="fewer repeats and a 3 s render (smoke test)")
    parser.add_argument("--only", nargs="+", metavar="NAME", help="run only these benchmarks")


def main(args: argparse.Namespace) -> int:
    """Run the benchmarks, print them, optionally write JSON; returns the exit status."""
    if args.json is not None and not args.json.parent.is_dir():
        raise EnvError(f"--json {args.json}: folder {args.json.parent} does not exist")
    benchmarks = all_benchmarks()
    if args.only:
        unknown = sorted(set(args.only) - {name for name, _ in benchmarks})
        if unknown:
            raise EnvError(f"unknown benchmark(s) {unknown}; available: {[name for name, _ in benchmarks]}")
        benchmarks = [b for b in benchmarks if b[0] in args.only]
    results: dict[str, Any] = {"machine": machine()}
    for name, function in benchmarks:
        start = time.perf_counter()
        figures = function(bool(args.quick))
        figures["bench_wall_s"] = time.perf_counter() - start
        results[name] = figures
        print(f"{name}:")
        for key, value in figures.items():
            print(f"  {key:28s} {_format(value)}")
    results["machine"]["load_average_1min_end"] = os.getloadavg()[0]
    if args.json is not None:
        write_json(args.json, results)
        print(f"wrote {args.json}")
    return 0
