"""Iterates that reach the local/global fixed point sooner: the step energy, Anderson, Newton.

The plain iteration ``z_(k+1) = g(z_k)`` (local rotations at ``z_k``, then the
global solve) minimises a quadratic that lies above the step energy and
touches it at ``z_k``, so with ``H`` the constant system matrix

    E(g(z)) <= E(z) - 1/2 |g(z) - z|_H^2

and ``grad E(z) = H (z - g(z))``: its fixed points are the stationary points
of ``E``. It converges linearly, and slowly for stiff or strongly rotating
bodies. The driver (:class:`~skfem_modal.solver.LocalGlobal`) can hand the
backend another next iterate, proposed here from what the plain iterations
made, and keeps it only when its energy is at most that of the plain iterate
it replaces: never a worse iterate than the plain one, and the same fixed
points (at one, every proposal is the fixed point).

* :class:`StepEnergy` evaluates ``E`` (up to a constant) and keeps the
  clusters' ``S`` and ``R`` at the last point evaluated;
* :class:`Anderson`: Anderson acceleration of ``g`` (Peng et al. 2018,
  "Anderson Acceleration for Geometry Optimization and Physics
  Simulation"), a multisecant extrapolation from the last few iterates;
* :class:`SubspaceNewton`: a Newton step on ``E`` in a subspace. The rotation
  terms' Hessian has rank ``q`` per cluster (1 in 2D, 3 in 3D): for a
  cluster with ``S = R P``, ``d^2 (-tr(R^T S)) = -a^T K^-1 a`` with
  ``[a]_x = R^T dS - dS^T R`` and ``K = tr(P) I - P``. So the energy's
  Hessian is ``H - U w K^-1 U^T`` with ``U^T = L G`` (``L`` the maps
  ``dS -> a``, ``w`` the clusters' weights), and by the Woodbury identity the
  Newton iterate is

      z_N = g + W L^T (K / w - L G W L^T)^-1 L G (g - z),    W = H^-1 G^T,

  one symmetric ``q n``-sized solve for ``n`` clusters (none when
  ``K / w - L G W L^T`` is not positive definite: the energy is not convex
  there, and the plain iterate is kept).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
from scipy.linalg.lapack import dposv as _posv

from .solver import PlainBackend

__all__ = ["ACCELERATIONS", "StepEnergy", "Anderson", "SubspaceNewton", "make_accelerator"]

#: What ``acceleration`` accepts.
ACCELERATIONS = ("none", "anderson", "newton")

# a = axial(X - X^T) for X = R^T dS: a_q = sum_ij AXIAL[q, j, i] X_ij
_AXIAL = {
    2: np.array([[[0.0, 1.0], [-1.0, 0.0]]]),
    3: np.array(
        [
            [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]],
            [[0.0, 0.0, -1.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]],
            [[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 0.0]],
        ]
    ),
}


class StepEnergy:
    """The energy a step minimises, ``1/2 (z - c)^T H (z - c) - sum_c w_c tr(R_c^T S_c(z))``.

    (``S_c`` with the corotated damping's offset, ``w_c`` its ``1 + beta / h`` for
    the passive clusters, 1 for the others: see :class:`~skfem_modal.model.Model`;
    ``c = H^-1 (Pz z0 + Pv v0 + f)`` with its shift.) That is :meth:`Model.energy
    <skfem_modal.model.Model.energy>` less a constant of the step, in a few
    products: the cluster rows and rotations of an exact backend
    (:class:`~skfem_modal.solver.PlainBackend`), ``H`` summed from the effects.

    Parameters
    ----------
    model : Model

    Attributes
    ----------
    S, R : ndarray, shape (clusters, dim, dim)
        The cluster matrices and their closest rotations at the last point evaluated.
    round_off : float
        How much the last energy evaluated may be off by round-off: energies closer
        than that are equal as far as they tell.
    """

    def __init__(self, model):
        self.dim = model.space.dim
        self.exact = PlainBackend(model)
        self.H = sum(m for m in (e.matrix(model.h) for e in model.effects) if m is not None)
        self.rotation_scale = model.rotation_scale
        self.S = self.R = None
        self.round_off = 0.0

    def start(self, z, z_dot, a) -> None:
        """Set up the step from ``(z, z_dot)`` under activation ``a``.

        Parameters
        ----------
        z, z_dot : ndarray, shape (r,)
            The state at the start of the step: its coordinates and their velocities.
        a : ndarray, shape (m,)
            The muscles' activations over the step.
        """
        self.exact.start(z, z_dot, a)

    @property
    def rows(self):
        """The cluster rows of the step, ``S = rows @ z``, shape (clusters * dim * dim, r)."""
        return self.exact.rows

    @property
    def columns(self):
        """``H^-1 rows^T`` times each cluster's weight (a subspace only), shape (r, clusters * dim * dim)."""
        return self.exact.cols_buffer

    @property
    def weights(self):
        """Each cluster's weight ``w_c`` in the energy, shape (clusters,)."""
        block = self.dim**2
        weights = np.ones(self.exact.rows.shape[0] // block)
        weights[: self.exact.n_passive // block] = self.rotation_scale  # (n_passive counts rows)
        return weights

    def __call__(self, z) -> float:
        """``E(z)`` up to the step's constant; keeps ``S`` and ``R`` at ``z``."""
        d, passive = self.dim, self.exact.n_passive
        S = self.exact.arguments(z)
        R = self.exact.rotations(S).ravel()
        self.S, self.R = S.reshape(-1, d, d), R.reshape(-1, d, d)
        u = z - self.exact.c
        # the passive rotations weigh rotation_scale (the corotated damping's 1 + beta / h)
        rotated = float(R @ S) + (self.rotation_scale - 1.0) * float(R[:passive] @ S[:passive])
        inertia = 0.5 * float(u @ (self.H @ u))
        self.round_off = 1e-13 * (abs(inertia) + abs(rotated))
        return inertia - rotated


class Anderson:
    """Anderson acceleration of the local/global map from the last ``memory`` iterates.

    With residuals ``f_j = g(z_j) - z_j``, the next iterate is
    ``g(z_k) - sum_j theta_j (g(z_(j+1)) - g(z_j))``, ``theta`` minimising
    ``|f_k - sum_j theta_j (f_(j+1) - f_j)|``.

    Parameters
    ----------
    memory : int
        Differences kept, at least 1.
    """

    name = "anderson"

    def __init__(self, memory: int = 5):
        self.memory = int(memory)
        self.reset()

    def reset(self) -> None:
        """Forget the history (after a proposal was refused, and at each step)."""
        self.g = self.f = None
        self.dG, self.dF = [], []

    def propose(self, z, g, energy=None, local=None):
        """The extrapolated iterate from ``z`` and ``g = g(z)``, or None while there is no history.

        Each call adds ``g`` and its residual ``g - z`` to the history (the first only starts it).

        Parameters
        ----------
        z : ndarray, shape (r,)
            The last iterate.
        g : ndarray, shape (r,)
            Its plain iterate, the local/global map of ``z``.
        energy, local : optional
            Not used: taken for the signature of :meth:`SubspaceNewton.propose`.

        Returns
        -------
        proposal : ndarray, shape (r,) or None
        """
        f = g - z
        if self.f is not None:
            self.dG.append(g - self.g)
            self.dF.append(f - self.f)
            del self.dG[: -self.memory], self.dF[: -self.memory]
        self.g, self.f = g, f
        if not self.dF:
            return None
        dF, dG = np.array(self.dF), np.array(self.dG)
        gram = dF @ dF.T
        try:
            theta = sla.solve(gram, dF @ f, assume_a="pos", check_finite=False)
        except (np.linalg.LinAlgError, ValueError):
            theta = np.linalg.lstsq(dF.T, f, rcond=None)[0]
        return g - theta @ dG


class SubspaceNewton:
    """Newton iterates on the step energy in a subspace (the module docstring has the formula).

    Needs the cluster matrices and rotations at ``z``: the step energy must
    have been evaluated there last.

    Parameters
    ----------
    dim : int
    """

    name = "newton"

    def __init__(self, dim: int):
        self.dim = dim
        self.q = 1 if dim == 2 else 3
        self.axial = _AXIAL[dim]

    def reset(self) -> None:
        """Nothing to forget: each Newton iterate uses only the current point."""

    def propose(self, z, g, energy, local):
        """The Newton iterate from ``z``, with ``g = g(z)`` and ``local = (S, R)`` at ``z``; None where not convex.

        Parameters
        ----------
        z : ndarray, shape (r,)
            The last iterate.
        g : ndarray, shape (r,)
            Its plain iterate, the local/global map of ``z``.
        energy : StepEnergy
            The step's energy, started for this step: its cluster ``rows`` and ``columns`` (a subspace's).
        local : tuple of ndarray, shape (clusters, dim, dim)
            ``(S, R)``: the cluster matrices at ``z`` and their closest rotations (``energy.S`` and
            ``energy.R`` after evaluating it at ``z``).

        Returns
        -------
        proposal : ndarray, shape (r,) or None
            None where the energy is not convex at ``z`` (the Newton system is not positive definite).
        """
        d, q = self.dim, self.q
        S, R = local
        n = S.shape[0]
        P = np.einsum("nki,nkj->nij", R, S)
        trace = np.einsum("nii->n", P)
        if q == 1:
            K = trace.reshape(n, 1, 1)
        else:
            K = trace[:, None, None] * np.eye(3) - 0.5 * (P + P.transpose(0, 2, 1))
        L = np.einsum("aji,nki->nakj", self.axial, R).reshape(n, q, d * d)
        r = z.size
        LG = np.matmul(L, energy.rows.reshape(n, d * d, r)).reshape(n * q, r)
        # the columns carry the clusters' weights w (H^-1 G^T w): divided out, the
        # system K / w - L G H^-1 G^T L^T is symmetric, as the Cholesky solve needs
        weights = energy.weights
        WL = np.einsum("rnj,naj,n->rna", energy.columns.reshape(r, n, d * d), L, 1.0 / weights).reshape(r, n * q)
        system = -(LG @ WL)
        blocks = system.reshape(n, q, n, q)
        blocks[self._diagonal(n)] += K / weights[:, None, None]
        # one LAPACK call: Cholesky and solve; info > 0 when not positive definite
        _, y, info = _posv(system, LG @ (g - z), overwrite_a=True, overwrite_b=True)
        if info != 0:
            return None
        return g + WL @ y

    @staticmethod
    def _diagonal(n):
        return np.arange(n), slice(None), np.arange(n), slice(None)


def make_accelerator(name: str, model, memory: int = 5):
    """The accelerator of a name (None for ``"none"``).

    Parameters
    ----------
    name : {"none", "anderson", "newton"}
    model : Model
        Newton needs a subspace (its system is the size of the clusters).
    memory : int
        Anderson's history.

    Returns
    -------
    Anderson, SubspaceNewton or None

    Raises
    ------
    ValueError
        ``"newton"`` on a model without a subspace (every DOF).
    """
    if name == "none":
        return None
    if name == "anderson":
        return Anderson(memory)
    if name == "newton":
        if not model.space.dense:
            raise ValueError(
                "acceleration='newton' needs a subspace (its system has a row per cluster rotation); "
                "on every DOF use 'anderson'"
            )
        return SubspaceNewton(model.space.dim)
    raise ValueError(f"acceleration must be one of {', '.join(map(repr, ACCELERATIONS))}, got {name!r}")
