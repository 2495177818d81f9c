"""Plain values every module checks alike.

>>> import numpy as np
>>> is_whole(3), is_whole(np.int64(3)), is_whole(True), is_whole(3.0)
(True, True, False, False)
>>> is_real(0.5), is_real(np.float32(2)), is_real(3), is_real(True), is_real("0.5")
(True, True, True, False, False)
>>> is_finite_real(1e308), is_finite_real(float("inf")), is_finite_real(10**400), is_finite_real(np.int64(4))
(True, False, False, True)
"""

from __future__ import annotations

import numpy as np

__all__ = ["is_whole", "is_real", "is_finite_real", "checked_flag"]


def is_whole(value) -> bool:
    """Whether ``value`` is a whole number: a Python or numpy integer, not a bool (``True`` is an ``int``)."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def is_real(value) -> bool:
    """Whether ``value`` is a real number: a Python or numpy integer or float, not a bool (nor a string of one)."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


def is_finite_real(value) -> bool:
    """Whether ``value`` is a real number (:func:`is_real`) that a float holds finitely (not ``10**400``, nor inf)."""
    if not is_real(value):
        return False
    try:
        return bool(np.isfinite(float(value)))
    except OverflowError:  # a Python int beyond a float's range
        return False


def checked_flag(value, name: str) -> bool:
    """``value`` as a bool if it is one (Python's or numpy's); otherwise a TypeError naming ``name``.

    Anything else is refused, not taken for its truth: ``parallel="no"`` would be true.
    """
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} must be True or False, got {value!r}")
    return bool(value)
