"""Interrupts: SIGTERM handled like Ctrl-C, and blocks that an interrupt may not cut.

``terminate_as_interrupt`` makes SIGTERM (``kill``) raise ``KeyboardInterrupt`` as
Ctrl-C (SIGINT) does, so that one ``except KeyboardInterrupt`` keeps what a command has
done, and remembers the interrupt (``Interrupts``) in case Python drops the exception.
``interrupts_deferred`` holds both signals while a block runs (a chunk of an event file
being written, the file being renamed into place) and delivers the first one held when
the block ends, so that an interrupt never lands half-way through a write. Both act
only in the main thread (the only one where Python runs signal handlers) and restore
the previous handlers when the block ends.
"""

from __future__ import annotations

import contextlib
import signal
import threading

#: The signals treated as an interrupt of a command: Ctrl-C and ``kill``.
INTERRUPT_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def _in_main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


class Interrupts:
    """The interrupts received within a ``terminate_as_interrupt`` block.

    The first SIGINT or SIGTERM raises ``KeyboardInterrupt`` where the main thread is;
    every one is remembered. Python drops an exception raised inside a
    garbage-collector callback or a ``__del__`` (JAX runs such callbacks), so a loop
    that must stop calls ``check`` at its safe points, which raises again for an
    interrupt that was lost. Later signals (a second Ctrl-C while the first one's
    clean-up runs) do not raise, so the clean-up is not cut short; neither does any
    signal after ``stop_raising``.

    Attributes:
        received: the number of the last signal received, or None.
        reported: whether the command has told the user what the interrupt kept (set
            by the command; the console entry reports a bare "interrupted" otherwise).
    """

    def __init__(self) -> None:
        self.received: int | None = None
        self.reported = False
        self._raising = True

    def _handle(self, signum, frame) -> None:
        self.received = signum
        if self._raising:
            self._raising = False
            raise KeyboardInterrupt

    def stop_raising(self) -> None:
        """From now on, only remember signals (the command's work is over)."""
        self._raising = False

    @property
    def interrupted(self) -> bool:
        """Whether SIGINT or SIGTERM arrived within the block."""
        return self.received is not None

    def check(self) -> None:
        """Raise ``KeyboardInterrupt`` if an interrupt arrived (its first exception may
        have been dropped); nothing otherwise."""
        if self.received is not None:
            raise KeyboardInterrupt

    def checked(self, items):
        """Yield ``items`` (an iterable, e.g. of events), calling ``check`` before each."""
        for item in items:
            self.check()
            yield item


@contextlib.contextmanager
def terminate_as_interrupt():
    """Within the block, SIGTERM (``kill``) raises ``KeyboardInterrupt`` like Ctrl-C,
    and both are remembered in the ``Interrupts`` yielded, so that an interrupted write
    keeps its checkpoint even when the first exception is lost.

    Nested blocks share the outer block's ``Interrupts``. Outside the main thread the
    block runs with the signals left alone (and a yielded ``Interrupts`` never set).
    """
    if not _in_main_thread():
        yield Interrupts()
        return
    outer = getattr(signal.getsignal(signal.SIGTERM), "__self__", None)
    if isinstance(outer, Interrupts):
        yield outer
        return
    interrupts = Interrupts()
    previous = {signum: signal.signal(signum, interrupts._handle)
                for signum in INTERRUPT_SIGNALS}
    try:
        yield interrupts
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler if handler is not None else signal.SIG_DFL)


@contextlib.contextmanager
def interrupts_deferred():
    """Hold SIGINT and SIGTERM while the block runs; when it ends (normally or with an
    exception), restore their handlers and deliver the first signal held, which then
    acts as it would have (``KeyboardInterrupt``, termination, or nothing if ignored).

    Blocks may nest (the innermost hands a held signal to the one around it). Outside
    the main thread, and for a signal whose handler was not installed from Python, the
    block runs with the signal left alone.
    """
    if not _in_main_thread():
        yield
        return
    held: list[int] = []

    def hold(signum, frame):
        held.append(signum)

    previous = {}
    try:
        for signum in INTERRUPT_SIGNALS:
            if signal.getsignal(signum) is not None:
                previous[signum] = signal.signal(signum, hold)
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        if held:
            signal.raise_signal(held[0])
