"""No process a batch starts outlives the process that started it, whatever ends that one (SIGKILL included).

Workers. A worker process (`batch.processes`) asks the kernel to kill it when its parent dies
(``prctl(PR_SET_PDEATHSIG, SIGKILL)`` on Linux, `die_with_parent`) and checks that its parent is still the one
that started it (it may have died before the request); a forked worker also closes the ends of the pipes it
inherited that belong to the parent (`close_inherited`), so that where the signal is not available (not Linux)
its next read of the pipe sees end-of-file and it returns.

Ray. The processes of a local Ray instance that a batch starts (`batch.ray_backend`: GCS, raylet, the dashboard
and runtime-env agents, the workers) are not all tied to the driver: Ray's agents, children of the raylet, outlive
a raylet that died with its driver (their own check of their parent sees the death but does not end the process).
So a `Reaper` watches them: a small process of its own that notes every process descended from the driver and started after the
reaper while the driver lives, and, once the driver's end of its pipe closes (the driver returned, or died), ends those that
are still there (SIGTERM, then SIGKILL after a grace period). It ignores SIGINT, SIGTERM and SIGHUP, so the Ctrl-C
or the hang-up that reaches the whole process group of the driver does not end it before its work.

Stdlib only; the parent-death signal and the /proc walk are Linux's, elsewhere they are skipped.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import IO, Iterable

PR_SET_PDEATHSIG = 1
"""prctl(2) option: the signal this process gets when its parent thread ends."""
REAP_GRACE_S = 2.0
"""How long the processes the reaper ends get between SIGTERM and SIGKILL."""
REAP_POLL_S = 0.2
"""How often the reaper notes the driver's descendants."""


def die_with_parent(parent_pid: int) -> None:
    """Have the kernel SIGKILL this process when its parent dies (Linux), and end it now (``os._exit``) if its
    parent is no longer ``parent_pid``: the parent died before the request."""
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
    if os.getppid() != parent_pid:
        os._exit(1)


def close_inherited(fds: Iterable[int]) -> None:
    """Close file descriptors a forked child inherited from its parent and must not hold (the parent's ends of the
    workers' pipes), so that they close when the parent dies."""
    for fd in fds:
        with contextlib.suppress(OSError):
            os.close(fd)


# --------------------------------------------------------------------------------------------- the reaper


def _children() -> dict[int, list[int]]:
    """ppid -> pids of every process (Linux /proc)."""
    tree: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            stat = _stat(int(entry.name))
            if stat is not None:
                tree.setdefault(stat[0], []).append(int(entry.name))
    return tree


def _stat(pid: int) -> tuple[int, int] | None:
    """(ppid, start time in clock ticks since boot) of ``pid``, or None when it is gone or a zombie."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    if fields[0] == "Z":
        return None
    return int(fields[1]), int(fields[19])


def descendants(root: int) -> dict[int, int]:
    """pid -> start time of every living process descended from ``root`` (Linux /proc; elsewhere none)."""
    if not Path("/proc/self/stat").exists():
        return {}
    tree, found, todo = _children(), {}, [root]
    while todo:
        for child in tree.get(todo.pop(), []):
            stat = _stat(child)
            if stat is not None and child not in found:
                found[child] = stat[1]
                todo.append(child)
    return found


def end_processes(noted: dict[int, int], grace_s: float = REAP_GRACE_S) -> list[int]:
    """SIGTERM each process of ``noted`` (pid -> start time) still running with that start time (not a reused pid),
    then SIGKILL those left after ``grace_s``; returns the pids signalled."""
    def alive() -> list[int]:
        return [pid for pid, start in noted.items() if (stat := _stat(pid)) is not None and stat[1] == start]

    ended = alive()
    for sig, wait_s in ((signal.SIGTERM, grace_s), (signal.SIGKILL, 0.0)):
        for pid in alive():
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.kill(pid, sig)
        deadline = time.monotonic() + wait_s
        while alive() and time.monotonic() < deadline:
            time.sleep(0.05)
    return ended


def reap(driver: int, pipe: IO[bytes]) -> None:
    """The reaper's loop (`Reaper`): note ``driver``'s descendants started since the reaper every REAP_POLL_S until
    ``pipe`` (the read end of the driver's pipe) ends, then end every noted one still there."""
    import selectors

    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_IGN)
    me = os.getpid()
    before = descendants(driver)  # what the driver started before the reaper is not the reaper's business
    print("ready", flush=True)
    noted: dict[int, int] = {}
    with selectors.DefaultSelector() as selector:
        selector.register(pipe, selectors.EVENT_READ)
        while True:
            noted.update({pid: start for pid, start in descendants(driver).items()
                          if pid != me and before.get(pid) != start})
            if selector.select(REAP_POLL_S) and not os.read(pipe.fileno(), 4096):
                break
    end_processes(noted)


class Reaper:
    """A process that ends, once this one returns or dies, every process descended from this one that it saw
    (module docstring). Use as a context manager around the code that starts them (a local Ray instance): on a
    normal exit the pipe is closed and the reaper's work awaited (up to ``wait_s``). Entering waits until the
    reaper has noted the processes that ran before it, which it leaves alone."""

    def __init__(self, wait_s: float = REAP_GRACE_S + 5.0) -> None:
        self.wait_s = wait_s
        self.process: subprocess.Popen[bytes] | None = None

    def __enter__(self) -> Reaper:
        if Path("/proc/self/stat").exists():
            code = "import sys; from batch.lifetime import reap; reap(int(sys.argv[1]), sys.stdin.buffer)"
            root = str(Path(__file__).resolve().parents[1])  # the folder holding batch/: the reaper imports it
            env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH")) if p)}
            self.process = subprocess.Popen([sys.executable, "-c", code, str(os.getpid())], stdin=subprocess.PIPE,
                                            stdout=subprocess.PIPE, env=env, close_fds=True)
            assert self.process.stdout is not None
            self.process.stdout.readline()  # "ready": it has noted what ran before it
            self.process.stdout.close()
        return self

    def __exit__(self, *exc: object) -> None:
        if self.process is None:
            return
        with contextlib.suppress(OSError):
            assert self.process.stdin is not None
            self.process.stdin.close()
        with contextlib.suppress(subprocess.TimeoutExpired):
            self.process.wait(self.wait_s)


__all__ = ["Reaper", "close_inherited", "descendants", "die_with_parent", "end_processes", "reap"]
