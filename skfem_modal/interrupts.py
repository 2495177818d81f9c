"""Stopping cleanly: SIGTERM as Ctrl-C, and bookkeeping that an interrupt cannot split.

``timeout 5 skfem-modal run ...`` (or a batch system ending a job) sends
SIGTERM, whose default kills the process at once: no ``summary.json``, tables
cut mid-buffer. The command line turns SIGTERM into :class:`Terminated`, a
``KeyboardInterrupt``, so every command stops as on Ctrl-C (a run writes its
summary with status ``interrupted``, a search keeps its checkpoint).

A signal arriving while one step's records are written (its frame, its table
rows, the summary's counts) would leave them disagreeing about the last step.
:class:`HeldSignals` holds SIGINT and SIGTERM during such bookkeeping and
raises them when it is done: the records then all stop at the same step.
Only handlers that raise (Python's Ctrl-C, :func:`terminate_as_interrupt`'s)
are held; a signal whose default ends the process still does so at once.
"""

from __future__ import annotations

import contextlib
import signal
import threading

__all__ = ["Terminated", "terminate_as_interrupt", "HeldSignals"]

_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Terminated(KeyboardInterrupt):
    """SIGTERM arrived: stop as Ctrl-C stops (files consistent, status ``interrupted``)."""


def _in_main_thread() -> bool:
    # signal handlers can be set, and run, only in the main thread
    return threading.current_thread() is threading.main_thread()


def _raise_terminated(signum, frame):
    raise Terminated(f"terminated by signal {signal.Signals(signum).name}")


@contextlib.contextmanager
def terminate_as_interrupt():
    """Within: SIGTERM raises :class:`Terminated` (a ``KeyboardInterrupt``) in the main thread.

    Elsewhere than the main thread, or when SIGTERM is ignored, nothing changes.
    """
    if not _in_main_thread() or signal.getsignal(signal.SIGTERM) == signal.SIG_IGN:
        yield
        return
    previous = signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


class HeldSignals:
    """SIGINT and SIGTERM held during :meth:`hold` blocks, for as long as the ``with`` lasts.

    Examples
    --------
    >>> with HeldSignals() as held:
    ...     with held.hold():
    ...         pass  # a Ctrl-C here is raised when the block ends
    """

    def __init__(self):
        self._previous = {}
        self._holding = 0
        self._pending = None

    def __enter__(self):
        if _in_main_thread():
            for signum in _SIGNALS:
                handler = signal.getsignal(signum)
                if callable(handler):  # a Python handler; the defaults and SIG_IGN stay as they are
                    self._previous[signum] = signal.signal(signum, self._arrived)
        return self

    def __exit__(self, *exc):
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)
        self._previous = {}
        return False

    def _arrived(self, signum, frame):
        if self._holding:
            self._pending = (signum, frame)
        else:
            self._previous[signum](signum, frame)

    @contextlib.contextmanager
    def hold(self):
        """Within: a signal waits; its handler runs when the block ends."""
        self._holding += 1
        try:
            yield
        finally:
            self._holding -= 1
            if not self._holding and self._pending is not None:
                (signum, frame), self._pending = self._pending, None
                self._previous[signum](signum, frame)
