"""`pih`: one console command, one subcommand per module in `scripts/`.

Each subcommand module exposes ``add_arguments(parser)`` and ``main(args) -> int``. Errors of the
project's own exception types are printed as one line on stderr and give exit status 2.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from typing import Sequence

from batch.errors import BatchError
from controllers.errors import ControllerError
from envs.errors import EnvError
from rflow.errors import RFlowError

# subcommand -> (module under scripts/, one-line help)
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "demos": ("scripts.demos", "record scripted peg-in-hole demonstrations in physics"),
    "train": ("scripts.train", "train RiemannianFlow position and orientation models on demos"),
    "evaluate": ("scripts.evaluate", "execute a trained skill from perturbed starts and score it"),
    "compare": ("scripts.compare", "did a change make insertion worse? paired comparison of two skills on the same episodes"),
    "sweep": ("scripts.sweep", "success maps of a trained skill over clearance x hole-pose error x ..."),
    "render": ("scripts.render", "render an episode or a demo to MP4"),
    "export": ("scripts.export", "demos or evaluation episodes as a LeRobot v3 or robomimic dataset"),
    "lasa": ("scripts.lasa", "Riemannian LASA benchmark (SPD and unit quaternions)"),
    "search": ("scripts.search", "Optuna hyperparameter search of RiemannianFlow on one LASA shape"),
    "bench": ("scripts.bench", "speed benchmark: control loop, rendering, IK, flow"),
    "benchmark": ("scripts.benchmark", "the success-rate protocol: demos, training, evaluation per demo seed, rate "
                                       "over seeds"),
    "run": ("scripts.run", "the main job: demos -> train -> evaluate -> figures and video"),
    "warmup": ("scripts.warmup", "compile and cache the numba kernels once (setup.sh runs it)"),
}

USER_ERRORS = (EnvError, ControllerError, RFlowError, BatchError, FileNotFoundError)


def build_parser(command: str = "") -> argparse.ArgumentParser:
    """Build the `pih` parser: every subcommand is listed with its one-line help, and only ``command``'s module
    (none for "") is imported to add its options. Importing all of them loaded torch, MuJoCo, Optuna, ... on
    every call: `pih --help` took 3.6-4.0 s on the development machine (now 0.1 s), `pih demos --help` 3.6 s (1.0 s)."""
    parser = argparse.ArgumentParser(prog="pih", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (module_name, help_text) in SUBCOMMANDS.items():
        if name != command:
            sub.add_parser(name, help=help_text, description=help_text, add_help=False)
            continue
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as err:
            if err.name != module_name:
                raise
            continue  # subcommand not built yet
        sp = sub.add_parser(name, help=help_text, description=help_text)
        module.add_arguments(sp)
        sp.set_defaults(_main=module.main)
    return parser


def chosen_command(argv: Sequence[str]) -> str:
    """The subcommand named in ``argv`` (its first word that is not an option), or "" when there is none."""
    return next((word for word in argv if not word.startswith("-")), "")


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `pih` console script."""
    words = list(sys.argv[1:] if argv is None else argv)
    args = build_parser(chosen_command(words)).parse_args(words)
    try:
        return int(args._main(args) or 0)
    except USER_ERRORS as err:
        print(f"pih {args.command}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"pih {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
