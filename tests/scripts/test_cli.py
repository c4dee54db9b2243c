"""scripts.cli: `pih` lists every subcommand but imports only the one it runs, so a command starts without
loading the others' dependencies (torch, Optuna, Ray, ...); the console script ends without the interpreter's
teardown, losing nothing."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from scripts.cli import SUBCOMMANDS, build_parser, chosen_command, main
from tests.helpers import REPO



def imported_after(code: str) -> dict[str, object]:
    """Run ``code`` in a fresh interpreter and report which scripts.* modules and heavy libraries it loaded."""
    probe = (f"import sys, json\n{code}\n"
             "print(json.dumps({'scripts': sorted(m for m in sys.modules if m.startswith('scripts.')),"
             " 'torch': 'torch' in sys.modules, 'optuna': 'optuna' in sys.modules,"
             " 'mujoco': 'mujoco' in sys.modules, 'numba': 'numba' in sys.modules}))")
    out = subprocess.run([sys.executable, "-c", probe], cwd=REPO, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_building_the_parser_for_one_command_imports_only_that_command():
    loaded = imported_after("from scripts.cli import build_parser\nbuild_parser('demos')")
    others = {module for name, (module, _) in SUBCOMMANDS.items() if name != "demos"} - {"scripts.task_options"}
    assert "scripts.demos" in loaded["scripts"]
    assert not others & set(loaded["scripts"])
    assert not loaded["torch"] and not loaded["optuna"]  # the simulator's path needs neither


@pytest.mark.parametrize("command", ["evaluate", "demos", "sweep", "run"])
def test_the_help_of_the_simulator_commands_loads_neither_torch_nor_mujoco(command):
    loaded = imported_after(f"from scripts.cli import build_parser\nbuild_parser({command!r}).format_help()")
    assert not loaded["torch"] and not loaded["mujoco"]
    if command in ("evaluate", "sweep"):  # nor numba's 0.4 s: `pih evaluate --help` within 1 s
        assert not loaded["numba"]


def test_help_is_grouped_and_shows_units_and_defaults(capsys):
    with pytest.raises(SystemExit):
        main(["evaluate", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for heading in ("skill:", "starts and run:", "output:", "task:"):
        assert heading in text
    assert "`pih task --help`" in text and "--force-limit-n" not in text  # the task options: documented once
    with pytest.raises(SystemExit):
        main(["task", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "--pos-range-mm" in text and "--time-limit-s" in text and "--force-limit-n" in text
    assert "(default 50.0)" in text and "(default 0.2)" in text  # the start range and the preset's clearance


def test_the_top_level_help_lists_every_command_without_importing_them():
    loaded = imported_after("from scripts.cli import build_parser\nprint(build_parser('').format_help())")
    assert loaded["scripts"] == ["scripts.cli"]
    text = build_parser("").format_help()
    for name in SUBCOMMANDS:
        assert name in text


@pytest.mark.parametrize("argv, command", [(["evaluate", "--model", "m"], "evaluate"), (["-h"], ""),
                                           ([], ""), (["-h", "train"], "train")])
def test_the_chosen_command_is_the_first_word_that_is_not_an_option(argv, command):
    assert chosen_command(argv) == command


def test_a_command_still_gets_its_own_options():
    args = build_parser("evaluate").parse_args(["evaluate", "--model", "m", "--episodes", "3"])
    assert args.command == "evaluate" and args.episodes == 3 and callable(args._main)


def run_console_script(main_body: str, before: str = "") -> subprocess.CompletedProcess:
    """`scripts.cli.run` in a fresh interpreter, its `main` replaced by ``main_body`` (a function body returning the
    status), with an atexit handler of the caller's and ``before`` run first; stdout and stderr are pipes
    (block-buffered)."""
    body = "\n".join("    " + line for line in main_body.splitlines())
    code = (f"import atexit, sys, threading, time\n{before}\nimport scripts.cli as cli\n"
            "atexit.register(lambda: print('atexit handler ran'))\n"
            f"def fake_main():\n{body}\n"
            "cli.main = fake_main\ncli.run()\n")
    return subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("status", [0, 2])
def test_the_console_script_flushes_runs_atexit_and_keeps_the_status(status):
    """What `main` printed reaches the pipes, the atexit handlers run after it, the status is `main`'s (os._exit
    without atexit._run_exitfuncs loses the handler's line)."""
    done = run_console_script(f"print('result ' * 2000)\nprint('one line', file=sys.stderr)\nreturn {status}")
    assert done.returncode == status
    assert done.stdout == "result " * 2000 + "\n" + "atexit handler ran\n"
    assert done.stderr == "one line\n"


def test_the_console_script_waits_for_a_running_thread():
    """A non-daemon thread still working when `main` returns finishes, as the interpreter's exit would let it."""
    done = run_console_script("threading.Thread(target=lambda: (time.sleep(0.3), print('thread done'))).start()\n"
                              "return 0")
    assert done.returncode == 0
    assert done.stdout.splitlines() == ["thread done", "atexit handler ran"]


def test_the_console_script_is_run():
    """pyproject's `pih` is `run` (the prompt exit), not `main`."""
    assert 'pih = "scripts.cli:run"' in (REPO / "pyproject.toml").read_text()


FINALIZED = ("import os\n"
             "class Finalized:\n"
             "    def __del__(self, write=os.write):\n"
             "        write(1, b'finalized\\n')\n"
             "KEEP = Finalized()")
"""A module global whose destructor writes to stdout's file descriptor (sys.stdout and the module's globals may be
gone by then, so the write is bound as a default): it runs in the interpreter's teardown only."""


def test_the_console_script_skips_the_teardown():
    """The fast exit is taken: a module global's destructor, which only the interpreter's teardown would run, does
    not print."""
    done = run_console_script("return 0", before=FINALIZED)
    assert done.returncode == 0
    assert done.stdout.splitlines() == ["atexit handler ran"]


@pytest.mark.parametrize("watcher", ["sys.settrace(lambda *a: None)", "sys.setprofile(lambda *a: None)"])
def test_a_profiler_or_tracer_gets_the_normal_exit(watcher):
    """With a tracer (coverage, a debugger) or a profiler (cProfile) watching, the interpreter exits normally, so
    the watcher can write its results after the program: the teardown runs the global's destructor."""
    done = run_console_script("return 3", before=f"{FINALIZED}\n{watcher}")
    assert done.returncode == 3
    assert done.stdout.splitlines() == ["atexit handler ran", "finalized"]
