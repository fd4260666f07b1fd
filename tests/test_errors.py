"""Ctrl-C inside :func:`ocalib.errors.deferred_interrupts` takes effect when the block ends, once."""

import signal

import pytest

from ocalib.errors import deferred_interrupts


@pytest.fixture
def python_handler():
    """Python's own SIGINT handler in force (whatever an earlier test in this process left), restored after."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def test_an_interrupt_inside_the_block_is_raised_when_it_ends(python_handler):
    reached = []
    with pytest.raises(KeyboardInterrupt):
        with deferred_interrupts():
            signal.raise_signal(signal.SIGINT)  # to this thread: delivered at once
            signal.raise_signal(signal.SIGINT)
            reached.append("the block ran to its end")
    assert reached == ["the block ran to its end"]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_the_handler_in_force_runs_once_and_none_without_an_interrupt():
    calls = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: calls.append(signum))
    try:
        with deferred_interrupts():
            pass
        assert calls == []
        with deferred_interrupts():
            signal.raise_signal(signal.SIGINT)
            signal.raise_signal(signal.SIGINT)
            assert calls == []
        assert calls == [signal.SIGINT]
    finally:
        signal.signal(signal.SIGINT, previous)
