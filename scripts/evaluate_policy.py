"""The `--policy` options of `pih evaluate`: score any policy in the demos' scene (envs/evaluation/evaluate_policy.py).

    pih evaluate --policy mypkg.mymodule:make --demos demos.npz [--policy-option dataset=ds/] [--privileged] ...

The factory is imported from the current folder first (as `python -m` does) and called as
``factory(task, **options)`` (the options as strings), in the supervised worker processes only (pih's own process
only finds the module's file): a spec without ':' or a module that is not found ends `pih evaluate` with one line
and exit status 2 before any work; a module that fails to import, a missing attribute or one that is not callable,
and a factory that fails or returns no Policy end it with one line and exit status 2 before any episode; a factory
that takes its worker down or hangs (past --start-timeout-s) is an infrastructure fault: one line, exit status 1
(envs/evaluation/evaluate_policy.py).
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import TYPE_CHECKING

from envs.errors import EnvError
from envs.evaluation.config import EvaluationConfig
from envs.policies.skill_settings import DEFAULT_LOOKAHEAD_S

if TYPE_CHECKING:  # the simulator loads when the command runs, never for --help
    from envs.evaluation.evaluate_policy import PolicySpec

SKILL_ONLY: tuple[str, ...] = ("--mode", "--lookahead-s", "--speed", "--stiffness", "--no-contact-adaptation",
                               "--adaptation-off", "--model", "--video", "--figure", "--stiffness-figure",
                               "--force-figure")
"""Options of `pih evaluate` that act on the RiemannianFlow skill only (or replay it), refused with --policy."""


def add_policy_arguments(parser: argparse.ArgumentParser) -> None:
    """The "policy" option group of `pih evaluate`."""
    group = parser.add_argument_group("policy (instead of --model; docs/policy.md)")
    group.add_argument("--policy", metavar="MODULE:FACTORY", help="factory(task, **options) -> Policy")
    group.add_argument("--demos", type=Path, metavar="FILE.npz", help="the demos whose scene and starts to run")
    group.add_argument("--policy-option", action="append", default=[], metavar="KEY=VALUE",
                       help="a string for the factory; repeatable")
    group.add_argument("--privileged", action="store_true", help="observations carry the true hole (a teacher)")


def policy_spec(args: argparse.Namespace) -> PolicySpec:
    """The PolicySpec of the parsed options (the current folder as the import's search path).

    Raises:
        EnvError: a malformed spec or option.
    """
    from envs.evaluation.evaluate_policy import PolicySpec, parse_policy_options

    return PolicySpec(args.policy, parse_policy_options(args.policy_option), bool(args.privileged), os.getcwd())


def check_policy_args(args: argparse.Namespace) -> None:
    """The rules of --policy, before any work: --demos given and readable, no skill-only option, a spec whose module is
    found (without importing it: it is imported, and its factory called, in the supervised workers).

    Raises:
        EnvError: naming the offending option.
    """
    from envs.evaluation.evaluate_policy import demo_metadata, policy_files

    d = EvaluationConfig()
    given = {"--mode": args.mode != d.mode, "--lookahead-s": args.lookahead_s != DEFAULT_LOOKAHEAD_S,
             "--speed": args.speed != d.speed, "--stiffness": args.stiffness is not None,
             "--no-contact-adaptation": args.no_contact_adaptation,
             "--adaptation-off": getattr(args, "adaptation_off", None) is not None, "--model": args.model is not None,
             "--video": args.video is not None, "--figure": args.figure is not None,
             "--stiffness-figure": args.stiffness_figure is not None, "--force-figure": args.force_figure is not None}
    refused = [option for option in SKILL_ONLY if given[option]]
    if refused:
        raise EnvError(f"{', '.join(refused)}: not with --policy (they act on the RiemannianFlow skill of --model)")
    if args.demos is None:
        raise EnvError("--policy needs --demos FILE: the demo file whose scene and start poses the episodes use")
    demo_metadata(args.demos)  # readable and valid
    policy_files(policy_spec(args))
