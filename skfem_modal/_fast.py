"""numpy calls without per-call dispatch, for the step's small products.

A step makes a hundred or so numpy calls on arrays of a few dozen entries,
so what a call costs before any arithmetic matters: ``np.dot`` goes through
the ``__array_function__`` protocol (a third of its cost on these sizes) and
the ``@`` operator through the matmul ufunc's machinery (half). The step's
operands are always our own float64 ndarrays, which need neither.
"""

from __future__ import annotations

import numpy as np

__all__ = ["dot"]

#: ``np.dot`` itself, without the ``__array_function__`` dispatch (the same
#: function where numpy does not expose it)
dot = getattr(np.dot, "_implementation", np.dot)
