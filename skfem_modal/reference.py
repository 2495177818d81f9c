"""The full-space simulator: the ground truth for accuracy studies.

The same energy as :class:`~skfem_modal.sim.ModalMuscle`, built from the same
effects in the same order, with every mesh DOF free and one passive rotation
per element (the muscles keep their rotation clusters: one by default, as the
reduced model; they are part of the muscle model, not an approximation of
it), iterated to a tight tolerance. The global system matrix is constant, so
it is factored once (sparse) and each iteration is one back-solve.

With the reduced simulator given a full basis (``B = I``), one passive cluster
per element and the same muscle clusters, both compute the same thing: the
tests check they agree to 1e-8.
"""

from __future__ import annotations

import numpy as np

from .mesh import check_mesh
from .sim import ModalMuscle

__all__ = ["FullSpaceSimulator"]


class FullSpaceSimulator(ModalMuscle):
    """Modal-muscle dynamics on every DOF of the mesh, one rotation per element.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    D : ndarray, shape (n * dim, m), or None
        Muscle modes (without the rest pose).
    mu, gamma, rho, h, active_labels, gravity, contact_vertices, ground, up,
    stickiness, push_out, pinned, pin_stiffness, damping_mass,
    damping_stiffness, max_s :
        As for :class:`~skfem_modal.sim.ModalMuscle`.
    max_iter : int
        Local/global iterations per step, at most (default 2000).
    tol, rtol : float
        Stop when the change of ``x`` is below ``tol`` or below ``rtol`` times
        the step's motion (defaults 0 and 1e-10: a tight, scale-free rule).

    The state is the positions themselves, interleaved, shape (n * dim,).
    """

    def __init__(self, mesh, D, *, max_iter=2000, tol=0.0, rtol=1e-10, **kwargs):
        if not hasattr(mesh, "t"):
            check_mesh(mesh)  # not a mesh at all (its points, say): named before its elements are counted
        try:
            super().__init__(
                mesh,
                None,
                D,
                np.arange(mesh.t.shape[1]),
                max_iter=max_iter,
                tol=tol,
                rtol=rtol,
                backend="plain",
                **kwargs,
            )
        except TypeError as err:
            # an argument misspelt or missing: Python names the class it went to; name this one
            if "ModalMuscle.__init__()" in str(err):
                raise TypeError(str(err).replace("ModalMuscle.__init__()", "FullSpaceSimulator()")) from None
            raise
