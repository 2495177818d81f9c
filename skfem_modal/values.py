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

import math

import numpy as np

__all__ = ["is_whole", "is_real", "is_finite_real", "checked_flag", "checked_state", "positive_number"]


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


def checked_state(value, size: int, name: str = "z") -> np.ndarray:
    """A state (or velocity) as a float array of shape (size,), finite; otherwise a ValueError naming ``name``.

    A complex one is refused too (casting would drop its imaginary part).

    Parameters
    ----------
    value : array_like, shape (size,)
    size : int
        The coordinates a state has (a subspace's ``r``).
    name : str
        What the error calls it.

    Returns
    -------
    ndarray, shape (size,)

    Examples
    --------
    >>> checked_state([0.0, 1.0], 3)
    Traceback (most recent call last):
    ...
    ValueError: z must have shape (3,), the subspace's coordinates, got (2,)
    """
    if np.iscomplexobj(value):
        raise ValueError(f"{name} must be real, got complex values")
    state = np.asarray(value, dtype=np.float64)
    if state.shape != (size,):
        raise ValueError(f"{name} must have shape ({size},), the subspace's coordinates, got {state.shape}")
    if not np.all(np.isfinite(state)):
        raise ValueError(f"{name} must be finite, got NaN or infinity in it")
    return state


def positive_number(value, name: str, *, allow_zero: bool = False) -> float:
    """``value`` as a float if it is a positive (``allow_zero``: non-negative) finite number; else an error.

    A string, bytes or bool is refused (TypeError), not converted: ``float("0.5")`` and ``float(True)``
    would take them. An integer beyond a float's range counts as infinite (ValueError).

    Parameters
    ----------
    value : object
    name : str
        What the error calls it.
    allow_zero : bool

    Returns
    -------
    float

    Raises
    ------
    TypeError
        Not a number.
    ValueError
        Not positive (non-negative), or not finite.
    """
    if isinstance(value, (str, bytes, bool, np.bool_)):
        raise TypeError(f"{name} must be a number, got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a number, got {value!r}") from None
    except OverflowError:  # an integer beyond a float's range
        v = math.inf
    if not np.isfinite(v) or (v < 0 if allow_zero else v <= 0):
        raise ValueError(f"{name} must be {'non-negative' if allow_zero else 'positive'} and finite, got {value!r}")
    return v
