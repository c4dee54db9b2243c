"""Every numeric option of every `pih` command, driven with extreme values (1e300, -1, NaN, inf, 0, huge integers,
1e10 for a time-out), is refused with one line and exit status 2 before any work, or is accepted within the range
its consumer takes (pihutil.bounds): never a traceback, never work that a bad value then fails in every episode.

The commands stop where their work would begin (scripts.options.work_begins), so the property costs parsing and
checking only; a few real, tiny runs at the top of the ranges show that what is accepted runs (no episode an
"error")."""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
from pathlib import Path
from typing import Callable

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from pihutil import bounds
from rflow.skill_io import save_skill
from scripts import options
from scripts.cli import SUBCOMMANDS, build_parser, main
from scripts.task_options import OPTION_FIELDS
from tests.helpers.evaluation_fixtures import synthetic_evaluation
from tests.helpers.skill_fixtures import synthetic_demos, tiny_skill, write_demo_file

BASES: dict[str, str] = {
    "demos": "demos --num 1 --out {tmp}/d.npz",
    "demos --import": "demos --import {tmp}/rec.npz --tool-offset flange --out {tmp}/i.npz",
    "train": "train --demos {tmp}/demos.npz --out {tmp}/ck",
    "evaluate": "evaluate --model {tmp}/model --episodes 1",
    "compare": "compare {tmp}/a.json {tmp}/b.json",
    "compare --sequential": "compare --sequential --base-model {tmp}/model --cand-model {tmp}/model",
    "sensitivity": "sensitivity --model {tmp}/model --out {tmp}/s",
    "sweep": "sweep --model {tmp}/model --clearance-mm 0.2 --out {tmp}/sw",
    "render": "render --demos {tmp}/demos.npz --out {tmp}/r.mp4",
    "lasa": "lasa --shape NShape --json {tmp}/l.json",
    "lasa --all": "lasa --all --shapes NShape --out {tmp}/la",
    "search": "search --out {tmp}/se --trials 1",
    "benchmark": "benchmark --out {tmp}/b",
    "run": "run --root {tmp} --name r",
    "task": "task show",
    "export": "export --demos {tmp}/demos.npz --format lerobot --out {tmp}/ex",
}
"""A valid command line per command (and per mode whose options the plain one refuses)."""
MODE_OPTIONS: dict[str, tuple[str, ...]] = {
    "demos --import": ("--dt-s",),
    "compare --sequential": ("--max-episodes", "--chunk", "--progress-margin", "--lookahead-s", "--feedforward",
                             "--speed", "--seed", "--pos-range-mm", "--rot-range-deg", "--time-limit-s", "--workers",
                             "--lockstep", "--unit-timeout-s", "--clearance-mm", "--chamfer-mm", "--grasp-force-n",
                             "--hole-error-mm", "--hole-error-deg", "--grasp-offset-mm", "--hole-observation-error-mm",
                             "--hole-observation-error-deg", "--hole-observation-tilt-deg", "--force-limit-n"),
    "lasa --all": ("--workers", "--unit-timeout-s"),
}
"""Options that apply to a mode only, run on its command line."""

SPECS: dict[tuple[str, str], tuple[str, Callable[[float], bool]]] = {
    ("evaluate", "--stiffness"): ("constant:{}", lambda v: bounds.STIFFNESS.contains(v)),
    ("sweep", "--stiffness"): ("constant:{}", lambda v: bounds.STIFFNESS.contains(v)),
    ("demos", "--expert-stiffness"): ("{}/300/1000", lambda v: bounds.STIFFNESS.contains(v)),
    ("demos --import", "--tool-offset"): ("{},0,0,1,0,0,0", lambda v: bounds.TOOL_OFFSET_M.contains(abs(v))),
    ("benchmark", "--demo-seeds"): ("0-{}", lambda v: float(v).is_integer() and 0 <= v < bounds.REPLICATES.high),
    **{("sweep", option): ("{}", lambda v: True) for option in ("--clearance-mm", "--hole-error-mm", "--chamfer-mm",
                                                                 "--hole-error-deg", "--pos-range-mm")},
}
"""Options whose text holds a number: (template, whether an accepted number lies in its quantity's range); the
sweep's axes are task fields (checked by envs.task.task.Task, as the task options are)."""

EXTREMES = ["1e300", "-1", "nan", "inf", "0", "1e10"]
"""Every option meets each of these; hypothesis adds any float and integer (huge ones among them)."""


class Reached(Exception):
    """The command got past its checks (scripts.options.work_begins)."""


def numeric_options() -> list[tuple[str, str]]:
    """(base, option) of every option whose type declares a range (scripts.options: count, number, seed), each run
    on the command line of the mode it belongs to."""
    found = []
    for command in SUBCOMMANDS:
        parser = build_parser(command)
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[command]
        for action in sub._actions:
            if action.option_strings and hasattr(action.type, "bound"):
                option = action.option_strings[-1]
                mode = next((m for m, opts in MODE_OPTIONS.items() if m.split()[0] == command and option in opts),
                            command)
                found.append((mode, option))
    return found


OPTIONS = numeric_options()
CASES = OPTIONS + list(SPECS)


def test_every_numeric_option_declares_its_range():
    """No option reads a bare int or float, and every range is finite (or its infinity means "no limit"), but for
    the task options, whose fields envs.task.task.Task checks."""
    task_options = {f"--{name.replace('_', '-')}" for name in OPTION_FIELDS}
    for command in SUBCOMMANDS:
        parser = build_parser(command)
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[command]
        for action in sub._actions:
            assert action.type not in (int, float), (command, action.option_strings)
            bound = getattr(action.type, "bound", None)
            if bound is None or action.option_strings[-1] in task_options:
                continue
            assert math.isfinite(bound.low) and (math.isfinite(bound.high) or bound.infinite), (
                command, action.option_strings, bound)


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    tmp = tmp_path_factory.mktemp("bounds")
    save_skill(tmp / "model", tiny_skill())
    write_demo_file(tmp)
    demos = synthetic_demos(n=1)
    np.savez(tmp / "rec.npz", pos=demos.pos, quat=demos.quat, dt=np.float64(demos.dt))
    for name, seed in (("a.json", 0), ("b.json", 0)):
        (tmp / name).write_text(json.dumps(synthetic_evaluation([True, False, True], seed)))
    return tmp


def run_case(tmp: Path, base: str, option: str, value: str) -> tuple[int | None, str]:
    """The exit status (None: it reached its work) and stderr of ``pih BASE OPTION=VALUE``."""
    argv = BASES[base].format(tmp=tmp).split()
    template = SPECS.get((base, option), ("{}",))[0]
    argv.append(f"{option}={template.format(value)}")

    def stop() -> None:
        raise Reached

    err = io.StringIO()
    options.WORK_BEGINS_HOOKS.append(stop)
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            try:
                status: int | None = main(argv)
            except Reached:
                status = None
    finally:
        options.WORK_BEGINS_HOOKS.remove(stop)
    return status, err.getvalue()


def accepted_in_range(base: str, option: str, value: str) -> bool:
    """Whether a value a command accepted lies in the option's declared range (the task's own checks decide for the
    task options)."""
    if (base, option) in SPECS:
        return SPECS[(base, option)][1](float(value))
    parser = build_parser(base.split()[0])
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[base.split()[0]]
    action = next(a for a in sub._actions if option in a.option_strings)
    parsed = action.type(value)
    return action.type.bound.contains(parsed) or math.isinf(action.type.bound.high)


def check(folder: Path, case: tuple[str, str], value: str) -> str | None:
    """What is wrong with the command line ``case`` given ``value`` (None: refused in one line with exit 2, or
    accepted within its range)."""
    if case[0] == "search" and not _importable("optuna"):
        return None
    status, err = run_case(folder, *case, value)
    if "Traceback" in err:
        return f"a traceback: {err[-300:]}"
    if status is None:
        return None if accepted_in_range(*case, value) else "accepted outside its range"
    if status != 2 or err.count("\n") != 1 or not err.startswith(f"pih {case[0].split()[0]}: error:"):
        return f"exit {status}: {err[-300:]!r}"
    return None


def test_every_extreme_value_of_every_option_is_one_line_and_exit_2_or_within_its_range(folder):
    wrong = {(case, value): problem for case in CASES for value in EXTREMES
             if (problem := check(folder, case, value)) is not None}
    assert wrong == {}


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                   HealthCheck.too_slow])
@given(case=st.sampled_from(CASES), value=st.one_of(st.floats(allow_nan=True, allow_infinity=True).map(repr),
                                                    st.integers(-2**70, 2**70).map(str)))
@example(case=("evaluate", "--unit-timeout-s"), value="1e10")
@example(case=("evaluate", "--stiffness"), value="1e300")
@example(case=("benchmark", "--demo-seeds"), value="99999999999")
@example(case=("benchmark", "--workers"), value="1e20")
@example(case=("demos --import", "--tool-offset"), value="1e300")
def test_any_value_of_any_option_is_one_line_and_exit_2_or_within_its_range(folder, case, value):
    assert check(folder, case, value) is None


def _importable(module: str) -> bool:
    import importlib.util

    return importlib.util.find_spec(module) is not None


# ---- the few real runs: the top of each range runs, and no episode is an error -----------------------------------

EDGE = ["--unit-timeout-s", "1e6", "--lookahead-s", "3600", "--feedforward", "100", "--speed", "10",
        "--stiffness", "constant:1e6", "--episodes", "1", "--time-limit-s", "0.05", "--quiet"]


@pytest.mark.parametrize("extra", [[], ["--workers", "2", "--episodes", "2"]], ids=["here", "two workers"])
def test_the_top_of_the_ranges_runs_without_an_error_episode(folder, tmp_path, extra):
    out = tmp_path / "e.json"
    assert main(["evaluate", "--model", str(folder / "model"), *EDGE, *extra, "--json", str(out)]) == 0
    reasons = [r["reason"] for r in json.loads(out.read_text())["per_episode"]]
    assert reasons and not any(r.startswith("error") for r in reasons), reasons


def test_a_policy_runs_under_the_largest_wall_time_limit(folder, tmp_path, monkeypatch):
    monkeypatch.chdir(folder)
    out = tmp_path / "p.json"
    assert main(["evaluate", "--policy", "tests.helpers.policies_for_tests:hold", "--demos", str(folder / "demos.npz"),
                 "--unit-timeout-s", "1e6", "--episodes", "1", "--time-limit-s", "0.05", "--quiet", "--json",
                 str(out)]) == 0
    reasons = [r["reason"] for r in json.loads(out.read_text())["per_episode"]]
    assert reasons and not any(r.startswith("error") for r in reasons), reasons
