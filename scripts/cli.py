"""`pih`: one console command, one subcommand per module in `scripts/`.

Each subcommand module exposes ``add_arguments(parser)``, ``main(args) -> int`` and ``EXAMPLES`` (command lines
shown at the end of its --help). Exit statuses: 2 for bad input (a bad option value, a bad file, an output that may
not be written: the project's own exception types), 1 for an operating-system error while working (a read-only folder,
a full disk), each as one line on stderr ``pih COMMAND: error: ...``; 4 when a user's --policy failed (it raised, or
returned an action that cannot be commanded: its traceback, then that line); 130 when interrupted (Ctrl-C, or SIGTERM, which
stops a command the same way). Every option's help shows its default; a command's usage line names what it requires
and "[options]" for the rest (the options follow).
"""

from __future__ import annotations

import argparse
import atexit
import contextlib
import ctypes
import importlib
import os
import signal
import sys
import textwrap
import threading
from typing import Iterator, NoReturn, Sequence

from numerics.cpu_dispatch import pin_cpu_dispatch

pin_cpu_dispatch()  # first: the CPU dispatch of torch, MKL and numpy, before they load

from batch.errors import BatchError  # noqa: E402
from controllers.errors import ControllerError  # noqa: E402
from envs.errors import EnvError, PolicyFailure  # noqa: E402
from envs.media.rendering import use_headless_rendering  # noqa: E402
from numerics.errors import NumericsError  # noqa: E402
from pihutil.interrupts import handling  # noqa: E402

DESCRIPTION = ("pih-rflow: a simulated Franka Panda learns peg-in-hole from demonstrations with RiemannianFlow and "
               "executes it under Cartesian impedance control. `pih run` records demos, trains and evaluates on the "
               "defaults; `pih COMMAND --help` for each command.")
"""What `pih --help` says before the commands."""

# subcommand -> (module under scripts/, one-line help)
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "demos": ("scripts.demos", "record scripted peg-in-hole demonstrations in physics"),
    "train": ("scripts.train", "train RiemannianFlow position and orientation models on demos"),
    "evaluate": ("scripts.evaluate", "execute a trained skill, or any policy, from perturbed starts and score it"),
    "compare": ("scripts.compare", "did a change make insertion worse? paired comparison of two skills on the same episodes"),
    "sensitivity": ("scripts.sensitivity", "what each imperfection of a real cell costs a skill, paired with the ideal "
                                           "cell"),
    "sweep": ("scripts.sweep", "success maps of a trained skill over clearance x hole-pose error x ..."),
    "render": ("scripts.render", "render an episode or a demo to MP4"),
    "export": ("scripts.export", "demos or evaluation episodes as a LeRobot v3 or robomimic dataset"),
    "lasa": ("scripts.lasa", "Riemannian LASA benchmark (SPD and unit quaternions)"),
    "search": ("scripts.search", "Optuna hyperparameter search of RiemannianFlow on one LASA shape"),
    "bench": ("scripts.bench", "speed benchmark: each figure against its physical floor (control loop, episodes, lockstep, "
                                "evaluation, training, IK, flow, rendering)"),
    "benchmark": ("scripts.benchmark", "the success-rate protocol: demos, training, evaluation per demo seed, rate "
                                       "over seeds"),
    "run": ("scripts.run", "the main job: demos -> train -> evaluate -> figures and video"),
    "task": ("scripts.task", "print a task (a preset or a task file, with single fields replaced) as a task file"),
    "warmup": ("scripts.warmup", "compile and cache the numba kernels once (setup.sh runs it)"),
}

USER_ERRORS = (EnvError, ControllerError, NumericsError, BatchError, FileNotFoundError)
"""The project's own exception types (NumericsError: rflow's RFlowError too, its subclass): a bad input, exit 2."""
EXIT_USAGE = 2
EXIT_OS_ERROR = 1
EXIT_INTERRUPTED = 130


class UsageError(Exception):
    """A command line argparse rejects: ``prog`` and the one-line message."""

    def __init__(self, prog: str, message: str):
        super().__init__(message)
        self.prog = prog


HELP_COLUMN = 26
"""Where an option's help starts (argparse: 24): room for "--adaptation-off PARTS" and its help on one line."""


class HelpFormatter(argparse.HelpFormatter):
    """Appends "(default X)" to an option's help unless the help already states its default or there is none; keeps
    the lines of a text that has several (the examples of an epilog) as they are."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        if "\n" in text:
            return "\n".join(indent + line if line else line for line in text.splitlines())
        return super()._fill_text(text, width, indent)

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if (not action.option_strings or "default" in text or action.default is None or action.default is False
                or action.default == argparse.SUPPRESS or action.default == []):
            return text
        return f"{text} (default %(default)s)"


class Parser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line (`main` prints them) instead of usage + message + exit, and
    which takes no abbreviated option (an old spelling whose unit changed would match the new one)."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        kwargs.setdefault("formatter_class", lambda prog: HelpFormatter(prog, max_help_position=HELP_COLUMN))
        kwargs.setdefault("allow_abbrev", False)  # a renamed option (--pos-range, now --pos-range-mm) must not match
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]

    def error(self, message: str) -> NoReturn:  # type: ignore[override]
        raise UsageError(self.prog, f"{message} (see `{self.prog} --help`)")


def build_parser(command: str = "") -> argparse.ArgumentParser:
    """Build the `pih` parser: every subcommand is listed with its one-line help, and only ``command``'s module
    (none for "") is imported to add its options: importing all of them would load torch, MuJoCo, Optuna, ... on
    every call, seconds before the first line of help (README: the figures)."""
    parser = Parser(prog="pih", description=DESCRIPTION)
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
        examples = getattr(module, "EXAMPLES", ())
        sp = sub.add_parser(name, help=help_text, description=help_text,
                            epilog="examples:\n" + "\n".join(f"  {line}" for line in examples) if examples else None)
        module.add_arguments(sp)
        usage = getattr(module, "USAGE", None)
        sp.usage = _wrapped(usage) if usage else compact_usage(sp)
        sp.set_defaults(_main=module.main)
    return parser


def compact_usage(parser: argparse.ArgumentParser) -> str:
    """``pih COMMAND`` with its positional arguments, its required options (a required choice of options as
    (A | B)) and "[options]": the options themselves are listed below it, one by one."""
    words = []
    grouped = {id(a) for g in parser._mutually_exclusive_groups if g.required for a in g._group_actions}
    for group in parser._mutually_exclusive_groups:
        if group.required:
            words.append("(" + " | ".join(f"{a.option_strings[0]} {_metavar(a)}".strip()
                                          for a in group._group_actions) + ")")
    for action in parser._actions:
        if id(action) in grouped or action.help == argparse.SUPPRESS:
            continue
        if not action.option_strings:
            words.append(_metavar(action) + (" ..." if action.nargs in ("*", "+") else ""))
        elif action.required:
            words.append(f"{action.option_strings[0]} {_metavar(action)}".strip())
    return _wrapped(" ".join([parser.prog, *words, "[options]"]))


def _wrapped(usage: str) -> str:
    """A usage line wrapped to fit 80 columns after argparse's "usage: "."""
    return textwrap.fill(usage, width=72, subsequent_indent="    ", break_on_hyphens=False)


def _metavar(action: argparse.Action) -> str:
    """The word an option's value is shown as (none for a flag)."""
    if action.nargs == 0:
        return ""
    if action.metavar is not None:
        return action.metavar if isinstance(action.metavar, str) else " ".join(action.metavar)
    if action.choices is not None:
        return "{" + ",".join(map(str, action.choices)) + "}"
    return action.dest.upper() if action.option_strings else action.dest


def chosen_command(argv: Sequence[str]) -> str:
    """The subcommand named in ``argv`` (its first word that is not an option), or "" when there is none."""
    return next((word for word in argv if not word.startswith("-")), "")


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `pih` console script; returns the exit status (module docstring)."""
    words = list(sys.argv[1:] if argv is None else argv)
    command = chosen_command(words)
    use_headless_rendering()  # before any command imports MuJoCo; worker processes inherit it
    try:
        args = build_parser(command).parse_args(words)
    except UsageError as err:
        prog = f"pih {command}" if command in SUBCOMMANDS else err.prog  # words left over are the command's
        print(f"{prog}: error: {str(err).replace('`pih --help`', f'`{prog} --help`')}", file=sys.stderr)
        return EXIT_USAGE
    from envs.io.owned_output import set_command

    set_command(args.command)
    try:
        with _sigterm_interrupts():
            return int(args._main(args) or 0)
    except PolicyFailure as failure:  # a command that runs a --policy stops at its first error
        from scripts.evaluate_policy import report_policy_failure

        return report_policy_failure(args.command, failure)
    except USER_ERRORS as err:
        print(f"pih {args.command}: error: {err}", file=sys.stderr)
        return EXIT_USAGE
    except OSError as err:
        where = f"{err.filename}: " if err.filename else ""
        print(f"pih {args.command}: error: {where}{err.strerror or err}", file=sys.stderr)
        return EXIT_OS_ERROR
    except KeyboardInterrupt:
        print(f"pih {args.command}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


@contextlib.contextmanager
def _sigterm_interrupts() -> Iterator[None]:
    """SIGTERM (a scheduler's or a CI's stop, `kill`) raises KeyboardInterrupt in the main thread while a command runs,
    as Ctrl-C does: the command stops the same way (its journal kept, its temporary outputs removed) and exits 130,
    instead of dying at once with 143 and leaving its staging folders behind."""
    def interrupt(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    with handling((signal.SIGTERM,), interrupt):
        yield


def run() -> NoReturn:
    """The `pih` console script: `main`, then the process ends without the interpreter's teardown.

    Tearing down a process that has loaded torch (freeing its modules, libtorch's static destructors) takes about
    half a second, and no result depends on it: every output is written, closed and renamed before `main`
    returns. So when no other non-daemon thread runs (one that the normal exit would wait for), the standard
    streams are flushed, the atexit handlers run (multiprocessing reaps its children, logging flushes), C's stdio
    is flushed (a native library's output) and the process ends with ``os._exit``. An exception out of `main`, a
    live non-daemon thread and a profiler or tracer watching the process (cProfile, coverage, a debugger: they
    write their results after the program returns) take the interpreter's normal exit.
    """
    status = main()
    others = [t for t in threading.enumerate() if t is not threading.main_thread() and not t.daemon and t.is_alive()]
    if others or sys.getprofile() is not None or sys.gettrace() is not None:
        sys.exit(status)
    _flush_streams()
    atexit._run_exitfuncs()  # what the normal exit would run; the handlers' errors are printed, not raised
    _flush_streams()
    try:
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError):  # no C library to flush
        pass
    os._exit(status)


def _flush_streams() -> None:
    """Flush stdout and stderr; a reader that went away (a closed pipe) loses what it did not read."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass


if __name__ == "__main__":
    run()
