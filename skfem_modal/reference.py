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
from .modal import muscle_modes
from .sim import ModalMuscle

__all__ = ["FullSpaceSimulator"]


class FullSpaceSimulator(ModalMuscle):
    """Modal-muscle dynamics on every DOF of the mesh, one rotation per element.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    D : ndarray, shape (n * dim, m), or None
        Muscle modes (without the rest pose).
    **kwargs
        The settings of :class:`~skfem_modal.sim.ModalMuscle` (all but ``B``,
        ``labels`` and ``backend``): ``mu``, ``gamma``, ``rho`` and ``h``
        (required), ``active_labels``, ``gravity``, ``contact_vertices``,
        ``ground``, ``up``, ``contact_model``, ``friction``, ``allowance``,
        ``exact_friction``, ``stickiness``, ``push_out``, ``pinned``,
        ``pin_stiffness``, ``damping_mass``, ``damping_stiffness``, ``etol``,
        ``warm_start``, ``acceleration``, ``max_s``.
    max_iter : int
        Local/global iterations per step, at most (default 2000).
    tol, rtol : float
        Stop when the change of ``x`` is below ``tol`` or below ``rtol`` times
        the step's motion (defaults 0 and 1e-10: a tight, scale-free rule).

    The state is the positions themselves, interleaved, shape (n * dim,).
    """

    def __init__(self, mesh, D, *, max_iter=2000, tol=0.0, rtol=1e-10, **kwargs):
        _plain_only(kwargs.pop("backend", "plain"))  # (it was Python's "got multiple values for 'backend'")
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

    @property
    def backend(self) -> str:
        """The backend: ``plain``, the only one on every DOF (assigning another is refused, naming it)."""
        return self._backend

    @backend.setter
    def backend(self, value) -> None:
        _plain_only(value)  # ("numba" was taken and said, while the plain one stepped)

    @classmethod
    def from_mesh(cls, mesh, n_muscles=4, *, muscle_signs=None, mu=1e5, gamma=None, lam=None, rho=1e3, h=0.02,
                  pinned=None, **kwargs):  # fmt: skip
        """A full-space simulator of a mesh, its muscles the mesh's lowest modes.

        Parameters
        ----------
        mesh : skfem.MeshTri or skfem.MeshTet
        n_muscles : int
            Muscle modes: the lowest modes but the rigid ones (:func:`~skfem_modal.modal.muscle_modes`).
        muscle_signs : array_like of +1 / -1, shape (n_muscles,), optional
            Flip muscles.
        mu, gamma, lam, rho, h, pinned :
            As for :meth:`ModalMuscle.from_mesh <skfem_modal.sim.ModalMuscle.from_mesh>`: the material
            (``gamma`` and ``lam`` default to ``mu``), the time step, the pinned vertices.
        **kwargs
            The constructor's other settings (``gravity``, ``ground``, ``max_iter``, ...).

        Returns
        -------
        sim : FullSpaceSimulator

        Examples
        --------
        >>> from skfem_modal import beam2d
        >>> sim = FullSpaceSimulator.from_mesh(beam2d(2.0, 0.5, 8, 2), n_muscles=1, h=0.01)
        >>> sim.rest_state()[0].shape, sim.n_muscles  # the positions of 27 vertices
        ((54,), 1)
        """
        check_mesh(mesh)
        D = muscle_modes(mesh, n_muscles, mu=mu, lam=lam, rho=rho, pinned=pinned, signs=muscle_signs)
        gamma = mu if gamma is None else gamma
        return cls(mesh, D, mu=mu, gamma=gamma, rho=rho, h=h, pinned=pinned, **kwargs)


def _plain_only(backend) -> None:
    """Refuse a backend other than ``plain`` (or ``auto``, which takes it) for the full space, naming it."""
    if backend not in ("plain", "auto"):
        raise ValueError(
            f"backend: the full space steps on the plain backend only (a rotation per element), got {backend!r}"
        )
