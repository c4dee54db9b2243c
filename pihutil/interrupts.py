"""Signal handlers installed for a while, except over a signal the process was started with ignored.

A command turns Ctrl-C (SIGINT) and SIGTERM into an orderly stop: journals kept, staging folders removed, exit 130.
A parent may start it with a signal ignored instead -- a POSIX shell does so for SIGINT in every background job of a
script (``pih evaluate ... &``), so that a Ctrl-C at the terminal stops only the foreground. Python then leaves SIGINT
ignored (no KeyboardInterrupt), and so does every handler here: the process behaves one way from start to end,
rather than stopping at a signal only while a batch runs and ignoring it in between.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator, Sequence
from typing import Any, Callable

Handler = Callable[[int, Any], None]


@contextlib.contextmanager
def handling(signals: Sequence[signal.Signals], handler: Handler) -> Iterator[None]:
    """``handler`` for each of ``signals`` for the duration, then the previous handlers again.

    A signal that is ignored (SIG_IGN) stays ignored, and so does one whose handler Python did not install (C code's:
    it could not be put back). Outside the main thread, where Python cannot install handlers, nothing changes.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous: dict[signal.Signals, Any] = {}
    try:
        for sig in signals:
            current = signal.getsignal(sig)
            if current is signal.SIG_IGN or current is None:
                continue
            previous[sig] = signal.signal(sig, handler)
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


__all__ = ["Handler", "handling"]
