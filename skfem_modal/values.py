"""Plain values every module checks alike.

>>> import numpy as np
>>> is_whole(3), is_whole(np.int64(3)), is_whole(True), is_whole(3.0)
(True, True, False, False)
"""

from __future__ import annotations

import numpy as np

__all__ = ["is_whole"]


def is_whole(value) -> bool:
    """Whether ``value`` is a whole number: a Python or numpy integer, not a bool (``True`` is an ``int``)."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))
