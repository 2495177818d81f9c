"""Optional compiled kernels (numba): availability and lazy loading.

The numpy path in :mod:`skfem_modal.rotations` is the reference; the kernels
in :mod:`skfem_modal._kernels` compute the same quantities with the same
methods, compiled, so a step does not pay numpy's per-call overhead a couple
of dozen times per iteration. Installed with ``pip install skfem_modal[fast]``;
when numba is missing (or ``SKFEM_MODAL_NUMBA=0``) nothing here is used and
every result comes from numpy. numba itself is imported only when a
simulator first steps with it. The tests check that both paths agree.
"""

from __future__ import annotations

import importlib.util
import os

__all__ = ["AVAILABLE", "kernels"]

AVAILABLE = os.environ.get("SKFEM_MODAL_NUMBA", "1") != "0" and importlib.util.find_spec("numba") is not None


def kernels():
    """The compiled kernels module (imports numba; compiled code is cached on disk)."""
    if not AVAILABLE:
        raise RuntimeError("numba is not available")
    from . import _kernels

    return _kernels
