"""pihutil.interrupts.handling: the handler for the duration and the previous one after, but a signal the process
was started with ignored stays ignored (a background job of a shell script gets SIGINT so), in the batch runner too."""

from __future__ import annotations

import signal
import threading

from batch.runner import _Interrupts
from pihutil.interrupts import handling


def _handler(signum, frame) -> None:
    raise AssertionError("not called in these tests")


def test_the_handler_is_installed_for_the_duration_and_the_previous_one_put_back() -> None:
    before = signal.getsignal(signal.SIGTERM)
    with handling((signal.SIGTERM,), _handler):
        assert signal.getsignal(signal.SIGTERM) is _handler
    assert signal.getsignal(signal.SIGTERM) is before


def test_an_ignored_signal_stays_ignored_in_the_command_and_in_a_batch() -> None:
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        with handling((signal.SIGINT, signal.SIGTERM), _handler):
            assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
            assert signal.getsignal(signal.SIGTERM) is _handler
        with _Interrupts().installed():
            assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
            assert signal.getsignal(signal.SIGTERM) is not signal.SIG_IGN
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, previous)


def test_outside_the_main_thread_nothing_changes() -> None:
    seen = []

    def body() -> None:
        with handling((signal.SIGTERM,), _handler):
            seen.append(signal.getsignal(signal.SIGTERM))

    before = signal.getsignal(signal.SIGTERM)
    thread = threading.Thread(target=body)
    thread.start()
    thread.join()
    assert seen == [before]
