"""Help a person can read: `pih evaluate --help` fits in 80 lines, every command's help ends with examples that parse,
the task options are documented once (`pih task --help`) and accepted everywhere, and --workers has one default."""

from __future__ import annotations

import argparse
import shlex

import pytest

from scripts.cli import SUBCOMMANDS, build_parser
from scripts.options import CAMERA_NAMES, DEFAULT_WORKERS
from scripts.task_options import OPTION_FIELDS

COMMANDS = sorted(SUBCOMMANDS)
TASK_COMMANDS = ("demos", "evaluate", "run", "benchmark", "compare")
"""The commands that take the single task options (`pih task` documents them)."""
EXAMPLE_VALUES = {"shape": "square", "peg_mount": "welded", "hole_observation": "measured", "around": "demo"}
REQUIRED = {"benchmark": ("--demo-seeds", "0", "--out", "b")}
NOT_TAKEN = {"demos": ("hole_error_mm", "hole_error_deg", "grasp_offset_mm", "hole_observation",
                       "hole_observation_error_mm", "hole_observation_error_deg", "hole_observation_tilt_deg",
                       "force_limit_n", "time_limit_s", "pos_range_mm", "rot_range_deg", "around"),
             "run": ("shape",)}
"""What a command does not take: demos record no perturbed episodes; `pih run` records its demos of the task's shape."""


def help_text(command: str) -> str:
    return build_parser(command)._subparsers._group_actions[0].choices[command].format_help()


def test_evaluate_help_fits_in_80_lines_with_an_example(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("COLUMNS", "80")  # an 80-column terminal
    text = help_text("evaluate")
    assert len(text.splitlines()) <= 80, len(text.splitlines())
    assert "examples:\n  pih evaluate --model" in text
    assert max(len(line) for line in text.splitlines()) <= 80


@pytest.mark.parametrize("command", COMMANDS)
def test_every_command_help_ends_with_examples_that_parse(command: str) -> None:
    text = help_text(command)
    examples = text.split("examples:\n", 1)[1].splitlines()
    assert examples
    for line in examples:
        words = shlex.split(line.split(">")[0])  # a redirection is the shell's
        assert words[:2] == ["pih", command], line
        build_parser(command).parse_args(words[1:])


@pytest.mark.parametrize("command", TASK_COMMANDS)
def test_the_task_options_are_accepted_but_listed_once(command: str) -> None:
    text = help_text(command)
    assert "`pih task --help`" in text and "--hole-observation-tilt-deg" not in text
    parser = build_parser(command)
    for option in OPTION_FIELDS:
        if option in NOT_TAKEN.get(command, ()):
            continue
        flag = "--" + option.replace("_", "-")
        args = parser.parse_args([command, *REQUIRED.get(command, ()), flag, EXAMPLE_VALUES.get(option, "1")])
        assert getattr(args, option) is not None, flag


def test_pih_task_help_documents_every_task_option_with_its_unit() -> None:
    text = " ".join(help_text("task").split())
    for option in OPTION_FIELDS:
        assert "--" + option.replace("_", "-") in text
    assert "mm" in text and "(default 40)" in text and "(default 20.0)" in text


def test_workers_has_one_default_on_every_command() -> None:
    defaults = {}
    for command in COMMANDS:
        parser = build_parser(command)._subparsers._group_actions[0].choices[command]
        for action in parser._actions:
            if "--workers" in action.option_strings:
                defaults[command] = action.default
    assert set(defaults) >= {"evaluate", "sensitivity", "sweep", "train", "run", "benchmark", "lasa", "compare"}
    assert set(defaults.values()) == {DEFAULT_WORKERS}, defaults


def test_the_camera_names_of_the_help_are_the_scenes() -> None:
    from envs.cell.scene import CAMERAS

    assert CAMERA_NAMES == ", ".join(CAMERAS)
