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
import multiprocessing.context
import os
import signal
import threading
import time

#: The exit code of a command stopped by Ctrl-C (128 + SIGINT), or SIGTERM, as shells give.
EXIT_INTERRUPTED = 130

__all__ = [
    "Terminated",
    "terminate_as_interrupt",
    "signals_ignored",
    "HeldSignals",
    "QuietSpawnContext",
    "exit_with_parent",
]

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


@contextlib.contextmanager
def signals_ignored():
    """Within: SIGINT and SIGTERM change nothing (in the main thread; elsewhere nothing changes).

    For the bookkeeping of a command already stopping on one: a second Ctrl-C while a stopped
    search drew its plot and said how to resume lost both (an audit).
    """
    if not _in_main_thread():
        yield
        return
    previous = {signum: signal.signal(signum, signal.SIG_IGN) for signum in _SIGNALS}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


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


class _QuietSpawnProcess(multiprocessing.context.SpawnProcess):
    """A spawned process that starts with Ctrl-C blocked (inherited through fork and exec).

    A worker's Python imports numpy and the rest before its pool's initializer
    can ignore SIGINT: a Ctrl-C in those seconds printed a traceback from each
    worker, ending in numpy's import. Blocked in the parent's thread only while
    it starts the process, the signal still reaches the parent.
    """

    def start(self):
        if not hasattr(signal, "pthread_sigmask"):  # not on Windows: started as it is
            return super().start()
        previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            return super().start()
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, previous)


class QuietSpawnContext(multiprocessing.context.SpawnContext):
    """The spawn context for pools whose workers leave Ctrl-C to their parent (:class:`_QuietSpawnProcess`)."""

    Process = _QuietSpawnProcess


def exit_with_parent(poll: float = 1.0) -> None:
    """In a pool's worker: end this process once the process that started it is gone.

    A parent killed outright (SIGKILL, the out-of-memory killer) cannot shut its
    pool down: its workers, handed to init, held 191 MB each for good (an audit).
    A daemon thread checks every ``poll`` seconds. The parent is the process that
    started this one (multiprocessing knows it), not whichever has it now: a worker
    still importing when its parent was killed took init for its parent, and stayed.
    """
    started_by = multiprocessing.parent_process()
    parent = started_by.pid if started_by is not None else os.getppid()

    def watch():
        while os.getppid() == parent:
            time.sleep(poll)
        os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()
