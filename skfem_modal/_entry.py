"""The ``skfem-modal`` console script: the command line, its own start and stop guarded."""

import signal
import sys

from .interrupts import EXIT_INTERRUPTED, terminate_as_interrupt


def main() -> int:
    """Run the command line (:func:`skfem_modal.cli.main`); a Ctrl-C while it loads is said as any other.

    SIGTERM stops the process as Ctrl-C does from start to end, not only while the command runs: a
    second SIGTERM arriving as the first one's stop was said killed the process outright (exit 143),
    and a second Ctrl-C ended it by the signal, instead of the 130 of a command interrupted.
    """
    loaded = False
    try:
        with terminate_as_interrupt():
            from .cli import main as command_line  # numpy, scipy, scikit-fem: most of a second

            loaded = True
            code = command_line()
    except KeyboardInterrupt:
        if not loaded:
            print("skfem-modal: interrupted", file=sys.stderr)
        code = EXIT_INTERRUPTED  # (loaded: a second signal while the first one's stop was said)
    if code == EXIT_INTERRUPTED:
        for signum in (signal.SIGINT, signal.SIGTERM):  # stopped already: any more change nothing
            signal.signal(signum, signal.SIG_IGN)
    return code
