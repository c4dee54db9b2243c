"""`pih task show`: print a task as a task file, to start your own from; `pih task --help` documents every single task
option, which the other commands accept without listing them.

    pih task show [--task NAME|FILE.toml] [task options] > my_task.toml

The task is resolved as every command resolves it (scripts/task_options.py): --task (a preset of envs/task/presets/ or a
file; default the contact preset) with the single options given replacing its fields, all checked (envs/task/task.py).
Edit the file and give it to any command with --task my_task.toml.
"""

from __future__ import annotations

import argparse

from scripts.options import work_begins
from scripts.task_options import add_start_arguments, add_task_arguments, task_from_args


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `pih task`: the action and every task option."""
    parser.add_argument("action", choices=("show",), help="show: print the task as TOML")
    group = add_task_arguments(parser, expanded=True)
    group.add_argument("--shape", help="peg and hole shape (default: the task's; left out: the demos')")
    add_start_arguments(group, expanded=True)


def main(args: argparse.Namespace) -> int:
    """Print the resolved task as TOML; returns 0."""
    task = task_from_args(args)
    work_begins()
    print(task.to_toml(), end="")
    return 0


EXAMPLES: tuple[str, ...] = ("pih task show --task contact > my_task.toml",
                             "pih task show --task realistic --clearance-mm 0.5 --hole-error-mm 2 > loose.toml")

__all__ = ["EXAMPLES", "add_arguments", "main"]
