"""The ``skfem-modal`` console script: the command line, its own start guarded."""

import sys

from .interrupts import EXIT_INTERRUPTED


def main() -> int:
    """Run the command line (:func:`skfem_modal.cli.main`); a Ctrl-C while it loads is said as any other."""
    try:
        from .cli import main as command_line  # numpy, scipy, scikit-fem: most of a second
    except KeyboardInterrupt:
        print("skfem-modal: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    return command_line()
