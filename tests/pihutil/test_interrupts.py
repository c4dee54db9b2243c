"""pihutil.interrupts.handling: the handler for the duration and the previous one after, but a signal the process
was started with ignored stays ignored (a background job of a shell script gets SIGINT so), in the batch runner and
in `pih`'s SIGTERM handler too."""

from __future__ import annotations

import signal
import threading

import pytest

from batch.runner import _Interrupts
from pihutil.interrupts import handling
from scripts.cli import _sigterm_interrupts


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
        interrupts = _Interrupts()
        with interrupts.installed():
            assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
            assert signal.getsignal(signal.SIGTERM) == interrupts._handle
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


def test_pih_turns_sigterm_into_ctrl_c_unless_it_was_started_with_sigterm_ignored() -> None:
    before = signal.getsignal(signal.SIGTERM)
    with _sigterm_interrupts():
        with pytest.raises(KeyboardInterrupt):
            signal.getsignal(signal.SIGTERM)(signal.SIGTERM, None)
    assert signal.getsignal(signal.SIGTERM) is before
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    try:
        with _sigterm_interrupts():
            assert signal.getsignal(signal.SIGTERM) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGTERM, before)
