"""Argument types the benchmarks share: a count or a name that cannot work is refused before any work.

argparse reports an :class:`argparse.ArgumentTypeError` raised here as
``argument --steps: <message>``, so each message says what was expected
and what was given, and the option is named for it.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence

#: Why numba's backend cannot run here, for the scripts that need it.
NUMBA_MISSING = "numba is not installed (pip install -e '.[fast]') or is turned off (SKFEM_MODAL_NUMBA=0)"


def at_least(least: int, why: str = "") -> Callable[[str], int]:
    """An argparse ``type``: an integer of at least ``least``.

    Parameters
    ----------
    least : int
        The least value that works.
    why : str, optional
        What needs it, said after the bound (e.g. ``"the first 20 steps are left out"``).

    Returns
    -------
    parse : callable
        ``str -> int``, raising :class:`argparse.ArgumentTypeError` for anything else.
    """
    reason = f" ({why})" if why else ""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer of at least {least}, got {text!r}") from None
        if value < least:
            raise argparse.ArgumentTypeError(f"must be at least {least}{reason}, got {value}")
        return value

    return parse


def one_of(names: Sequence[str]) -> Callable[[str], str]:
    """An argparse ``type``: one of ``names``, for a positional ``nargs="*"`` argument.

    Such an argument cannot take ``choices`` in Python 3.11: given no values, argparse
    checks its default list against them as if it were one value, and refuses it.

    Parameters
    ----------
    names : sequence of str
        The valid names.

    Returns
    -------
    parse : callable
        ``str -> str``, raising :class:`argparse.ArgumentTypeError` naming the valid ones.
    """

    def parse(text: str) -> str:
        if text not in names:
            raise argparse.ArgumentTypeError(
                f"invalid choice: {text!r} (choose from {', '.join(repr(n) for n in names)})"
            )
        return text

    return parse


def by(first: str, second: str) -> Callable[[str], tuple[int, int]]:
    """An argparse ``type``: two positive integers written ``AxB``, e.g. ``8x20`` or ``1280x720``.

    Parameters
    ----------
    first, second : str
        What the two numbers are, for the message (e.g. ``"WEIGHTS"``, ``"CLUSTERS"``).

    Returns
    -------
    parse : callable
        ``str -> (int, int)``, raising :class:`argparse.ArgumentTypeError` for anything else.
    """

    def parse(text: str) -> tuple[int, int]:
        parts = text.lower().split("x")
        try:
            values = tuple(int(p) for p in parts)
        except ValueError:
            values = ()
        if len(values) != 2 or min(values) < 1:
            raise argparse.ArgumentTypeError(f"expected {first}x{second}, two positive integers, got {text!r}")
        return values

    return parse


def backend(text: str) -> str:
    """An argparse ``type``: a simulator backend name (``skfem_modal.solver.BACKENDS``) that can run here.

    Parameters
    ----------
    text : str
        The name given.

    Returns
    -------
    name : str
        ``text``; :class:`argparse.ArgumentTypeError` for an unknown name, or ``numba`` without numba.
    """
    # imported here: the scripts set the BLAS thread variables before numpy (and so skfem_modal) is imported
    from skfem_modal import _accel
    from skfem_modal.solver import BACKENDS

    one_of(BACKENDS)(text)
    if text == "numba" and not _accel.AVAILABLE:
        raise argparse.ArgumentTypeError(f"'numba' cannot run here: {NUMBA_MISSING}")
    return text
