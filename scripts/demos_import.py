"""`pih demos --import`: convert demos recorded at another tool frame (e.g. a real Panda) into a demo file.

    pih demos --import recorded.npz --tool-offset franka-tcp --dt-s 0.001 --out demos.npz [--ends-apart | --snap-goal]
    pih demos --import recorded.npz --tool-offset 0,0,0.1034,0.92388,0,0,-0.38268 --out demos.npz
    pih demos --import datasets/demos-lerobot --format lerobot --out demos.npz     # an export of `pih export`

The file format and the conversion are documented in envs/demos/importing.py, the LeRobot and robomimic layouts in
envs/datasets/ (the tcp poses observation.state / obs/tcp_pose and the stiffness action.stiffness /
action_stiffness; an export of `pih export` names its frame, dt, shape and clearance, so --tool-offset and --dt-s
are not needed).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from envs.datasets import LAYOUTS
from envs.errors import EnvError
from envs.io.owned_output import check_free_space, check_output
from pihutil.bounds import SAMPLE_PERIOD_S
from scripts.options import number, work_begins
from scripts.task_options import task_from_args


def add_import_arguments(parser: argparse.ArgumentParser) -> None:
    """The import options of `pih demos` (--out, --shape, --clearance-mm and --samples are shared)."""
    group = parser.add_argument_group("importing demos recorded elsewhere (see envs/demos/importing.py)")
    group.add_argument("--import", dest="import_file", type=Path, metavar="FILE",
                       help="convert recorded tool-frame poses: pos (N, M, 3) + quat (N, M, 4) (w, x, y, z), or "
                            "pos_0, quat_0, pos_1, ... for demos of different lengths; optional dt, shape, "
                            "clearance_m. Resampled to --samples per demo")
    group.add_argument("--format", dest="import_format", choices=("npz", *LAYOUTS), default="npz",
                       help="with --import: the file's layout: npz (default, above), lerobot (a LeRobot v3 folder) "
                            "or robomimic (an .hdf5 file or its folder)")
    group.add_argument("--tool-offset", metavar="X,Y,Z,QW,QX,QY,QZ",
                       help="with --import: the recorded tool frame's pose in the flange frame (metres, quaternion "
                            "w, x, y, z), or 'franka-tcp' (the Franka hand's TCP: 0,0,0.1034,0.92388,0,0,-0.38268, "
                            "103.4 mm along z, -45 deg about z) or 'flange'; write --tool-offset=-0.01,... when the "
                            "first number is negative")
    group.add_argument("--dt-s", type=number(bound=SAMPLE_PERIOD_S), metavar="SECONDS",
                       help="with --import: sampling time of the recording, s (required when the file has no dt)")
    group.add_argument("--snap-goal", action="store_true",
                       help="with --import: blend demos that end off their common goal onto it (minimum-jerk "
                            "blend over the last 20 %% of each demo) instead of failing")
    group.add_argument("--ends-apart", action="store_true",
                       help="with --import: keep demos that end off their common goal as they are; the goal is "
                            "their mean end and `pih train` learns each demo relative to its own end")


def run_import(args: argparse.Namespace) -> int:
    """Validate every option, convert, write the demo file, print the per-demo goal jumps; exit status."""
    from envs.cell.scene import nominal_flange_to_peg_tip
    from envs.datasets import read_dataset
    from envs.demos.file import save_demos
    from envs.demos.importing import ImportConfig, import_demos, load_recorded_demos, parse_tool_offset, resolve_dt
    from envs.poses import Pose

    if args.check is not None:
        raise EnvError("--import and --check cannot be combined")
    if args.out is None:
        raise EnvError("--out FILE.npz is required with --import")
    if args.video is not None:
        raise EnvError("--video records the scripted expert; it does not apply to --import")
    for option, given in (("--noise", args.noise), ("--expert-stiffness", args.expert_stiffness)):
        if given is not None:
            raise EnvError(f"{option} shapes the scripted expert's demos; it does not apply to --import")
    check_output("--out", args.out, args.overwrite, suffix=".npz", inputs=[args.import_file])
    if args.tool_offset is None and args.import_format == "npz":
        raise EnvError("--tool-offset is required with --import (e.g. --tool-offset franka-tcp)")
    if args.tool_offset is not None:
        parse_tool_offset(args.tool_offset)
    config = ImportConfig(num_samples=args.samples, snap_goal=args.snap_goal, ends_apart=args.ends_apart)
    task = task_from_args(args)
    shape, clearance_m = task.shape or "square", task.clearance_m
    if args.import_format == "npz":
        recorded = load_recorded_demos(args.import_file)
    else:
        if not args.import_file.exists():
            raise EnvError(f"import file {args.import_file} not found")
        recorded = read_dataset(args.import_file, args.import_format)
    check_free_space(f"--out {args.out}", args.out.parent if str(args.out.parent) else Path("."),
                     2 * len(recorded.lengths) * args.samples * (3 + 4 + 9) * 8)
    dt = resolve_dt(recorded.dt, args.dt_s, str(args.import_file))
    if recorded.shape is not None and recorded.shape != shape:
        raise EnvError(f"{args.import_file} is for shape {recorded.shape!r} but --shape is {shape!r}; pass "
                       f"--shape {recorded.shape}")
    if recorded.clearance_m is not None and abs(recorded.clearance_m - clearance_m) > 1e-9:
        raise EnvError(f"{args.import_file} is for a {recorded.clearance_m * 1e3:g} mm clearance but --clearance-mm "
                       f"is {clearance_m * 1e3:g}; pass --clearance-mm {recorded.clearance_m * 1e3:g}")
    grasp = Pose(*nominal_flange_to_peg_tip(shape))
    if args.tool_offset is None and recorded.tool_frame != "tcp":
        raise EnvError(f"--tool-offset is required: {args.import_file} does not name its poses' frame (e.g. "
                       "--tool-offset franka-tcp)")
    tool_offset = grasp if args.tool_offset is None else parse_tool_offset(args.tool_offset)  # tcp: no conversion
    source_config = recorded.source_config or {}
    work_begins()
    result = import_demos(recorded, tool_offset, grasp, dt, shape, clearance_m, config,
                          provenance={"source_file": str(args.import_file.resolve()),
                                      "tool_offset_arg": args.tool_offset or recorded.tool_frame,
                                      "dt_from": "flag" if args.dt_s is not None else "file",
                                      **({"scene": source_config["scene"]} if "scene" in source_config else {})})
    for n, (jump_m, jump_rad) in enumerate(zip(result.jump_m, result.jump_rad)):
        print(f"demo {n}: {recorded.lengths[n]} samples, jump to the common goal {jump_m * 1e3:.4f} mm, "
              f"{np.rad2deg(jump_rad):.4f} deg")
    if result.demos.ends_apart:
        print(f"kept apart: the goal is the demos' mean end, {np.sqrt(np.mean(result.jump_m ** 2)) * 1e3:.3f} mm and "
              f"{np.rad2deg(np.sqrt(np.mean(result.jump_rad ** 2))):.3f} deg root-mean-square from it")
    if result.snapped:
        print(f"snapped onto the common goal: minimum-jerk blend over the last {100 * config.snap_fraction:g} % "
              f"({result.snap_duration_s:.3f} s) of each demo")
    path = save_demos(args.out, result.demos)
    demos = result.demos
    print(f"wrote {path}: {demos.num_demos} demos x {demos.num_samples} samples, dt {demos.dt * 1e3:.4f} ms, "
          f"shape {demos.shape}, clearance {demos.clearance_m * 1e3:g} mm ({recorded.layout} layout, tool offset "
          f"{args.tool_offset or recorded.tool_frame})")
    return 0
