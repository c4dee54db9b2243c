"""Value types of the `pih` options, checked while the command line is parsed (before any work): a bad value
is one line ``pih CMD: error: argument --OPT: ...`` and exit status 2.

    --seed S         an integer seed in 0 .. 2**32 - 1 (NumPy's and torch's seed range)
    counts           an integer in 1 .. a stated maximum (episodes, demos, samples, workers, epochs, trials)
    numbers          a finite float, optionally bounded (NaN is refused, infinity where it means no limit)
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Callable, Sequence

from pihutil.bounds import DEMOS, EPISODES, EPOCHS, SAMPLES, SEED, TRIALS, WORKERS, Bound

MAX_SEED = SEED.high
MAX_EPISODES = EPISODES.high
"""Episodes of one evaluation or of one sweep cell (pihutil.bounds.EPISODES)."""
MAX_DEMOS = DEMOS.high
MAX_SAMPLES = SAMPLES.high
"""Samples per demo (M = 4000 in the paper)."""
MAX_WORKERS = WORKERS.high
MAX_EPOCHS = EPOCHS.high
MAX_TRIALS = TRIALS.high
DEFAULT_WORKERS = 2
"""Worker processes of every command that runs episodes or trains in parallel (one default for all of them)."""
CAMERA_NAMES = "front, side, top, closeup, wrist, cutaway"
"""The scene's cameras (envs.cell.scene.CAMERAS, named here so that --help loads no MuJoCo; a test keeps them equal)."""


def seed(text: str) -> int:
    """An integer seed in 0 .. 2**32 - 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer seed") from None
    if not SEED.contains(value):
        raise argparse.ArgumentTypeError(f"{text} is outside 0..{MAX_SEED} (2**32 - 1)")
    return value


seed.bound = SEED  # type: ignore[attr-defined]


def count(maximum: int, minimum: int = 1) -> Callable[[str], int]:
    """An option type: an integer in ``minimum`` .. ``maximum`` (its `pihutil.bounds.Bound` as ``.bound``)."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
        if not minimum <= value <= maximum:
            raise argparse.ArgumentTypeError(f"{text} is outside {minimum}..{maximum:,}")
        return value

    parse.__name__ = "count"
    parse.bound = Bound(minimum, maximum, integer=True)  # type: ignore[attr-defined]
    return parse


def number(minimum: float | None = None, maximum: float | None = None, above: float | None = None,
           infinite: bool = False, bound: Bound | None = None) -> Callable[[str], float]:
    """An option type: a finite float (or +inf with ``infinite``: "no limit"), >= ``minimum``, <= ``maximum``
    and > ``above`` where given; or within ``bound`` (a `pihutil.bounds.Bound`, the quantity's one range). The
    range is the parser's ``.bound``."""
    if bound is not None:
        minimum, above = (None, bound.low) if bound.low_open else (bound.low, None)
        maximum, infinite = (None if math.isinf(bound.high) else bound.high), bound.infinite

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not (math.isfinite(value) or (infinite and value == math.inf)):
            raise argparse.ArgumentTypeError(f"{text} must be a finite number")
        if minimum is not None and value < minimum:
            raise argparse.ArgumentTypeError(f"{text} must be >= {minimum:g}")
        if maximum is not None and value > maximum:
            raise argparse.ArgumentTypeError(f"{text} must be <= {maximum:g}")
        if above is not None and value <= above:
            raise argparse.ArgumentTypeError(f"{text} must be > {above:g}")
        return value

    parse.__name__ = "number"
    low = above if above is not None else (minimum if minimum is not None else -math.inf)
    parse.bound = bound or Bound(low, math.inf if maximum is None else maximum,  # type: ignore[attr-defined]
                                 low_open=above is not None, infinite=infinite)
    return parse


WORK_BEGINS_HOOKS: list[Callable[[], None]] = []
"""Called by `work_begins` (none in a command run; the tests of the option bounds stop a command there)."""


def add_source_arguments(parser: argparse.ArgumentParser, episodes_help: str) -> None:
    """The one required source of a command that reads recorded motion: --demos (a demo file of `pih demos`) or
    --episodes (an evaluation of `pih evaluate --json`, described by ``episodes_help``)."""
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--demos", type=Path, metavar="FILE.npz", help="a demo file of `pih demos`")
    source.add_argument("--episodes", type=Path, metavar="EVAL.json", help=episodes_help)


def work_begins() -> None:
    """Called by every command once its whole input is checked, right before its first piece of work (an episode, a
    training epoch, a demo recorded, an output written): bad input is refused before this line, with one line and
    exit status 2 (tests/scripts/test_option_bounds.py stops every command here through WORK_BEGINS_HOOKS)."""
    for hook in WORK_BEGINS_HOOKS:
        hook()


def check_camera(camera: str) -> None:
    """--camera names a camera of the scene (checked in main: the scene module loads MuJoCo).

    Raises:
        EnvError: naming the camera and the available ones.
    """
    from envs.cell.scene import CAMERAS
    from envs.errors import EnvError

    if camera not in CAMERAS:
        raise EnvError(f"--camera {camera!r} is not a camera of the scene (available: {', '.join(CAMERAS)})")


def refuse_unused(args: argparse.Namespace, add_arguments: Callable[[argparse.ArgumentParser], None],
                  dests: Sequence[str] | None, why: str, *, keep: Sequence[str] = ()) -> None:
    """An option given on the command line that this use of the command would ignore is refused, so a user never
    believes an option acted: every ``dests`` whose value differs from the default ``add_arguments`` gives it.

    Args:
        args: the parsed command line.
        add_arguments: the command's option builder (the defaults are read from a parser it fills).
        dests: the options' destinations that do not apply; None: every option but those in ``keep``.
        why: the reason, completing "--OPTION: ..." (e.g. "applies to --all only").

    Raises:
        EnvError: naming the first such option.
    """
    from envs.errors import EnvError

    parser = argparse.ArgumentParser(add_help=False)
    add_arguments(parser)
    options = {action.dest: action.option_strings[-1] for action in parser._actions if action.option_strings}
    for dest in dests if dests is not None else [d for d in options if d not in keep]:
        if getattr(args, dest, None) != parser.get_default(dest):
            raise EnvError(f"{options.get(dest, dest)}: {why}")
