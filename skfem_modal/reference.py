"""The full-space simulator: the ground truth for accuracy studies.

The same energy as :class:`~skfem_modal.sim.ModalMuscle` with every mesh DOF
free and one passive rotation per element (the muscles keep their rotation
clusters: one by default, as the reduced model; they are part of the muscle
model, not an approximation of it): implicit-Euler
inertia, passive ARAP, the muscles' plastic-stretch target, gravity, pins,
damping and the same ground contact, iterated to a tight tolerance. The
global system matrix ``M/h^2 + J^T (w x I) J`` (+ pins, damping) is constant,
so it is factored once (sparse) and each iteration is one back-solve.

With the reduced simulator given a full basis (``B = I``), one passive cluster
per element and the same muscle clusters, both compute the same thing: the
tests check they agree to 1e-8.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sps
import scipy.sparse.linalg as spla

from .contact import GroundContact
from .fem import _gravity, _jacobian, _mass, _positive, vector_dofs
from .mesh import _signed_measures, check_mesh
from .rotations import polar_rotations
from .sim import SimulationError, _muscle_modes, _positive_scalar

__all__ = ["FullSpaceSimulator"]


class _SparseSolve:
    """``X -> H^{-1} X`` with a sparse factorisation (picklable wrapper)."""

    def __init__(self, lu):
        self.lu = lu

    def __call__(self, X):
        return self.lu.solve(np.asarray(X, dtype=np.float64))


class FullSpaceSimulator:
    """Modal-muscle dynamics on every DOF of the mesh, one rotation per element.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    D : ndarray, shape (n * dim, m), or None
        Muscle modes (without the rest pose).
    mu, gamma, rho : float or ndarray of shape (nT,)
    h : float
    active_labels : ndarray of int, shape (nT,), optional
        Muscle rotation cluster of each element (default one cluster).
    gravity, contact_vertices, ground, up, stickiness, push_out, pinned,
    pin_stiffness, damping_mass, damping_stiffness :
        As for :class:`~skfem_modal.sim.ModalMuscle`.
    max_iter : int
        Local/global iterations per step, at most (default 2000).
    tol, rtol : float
        Stop when the change of ``x`` is below ``tol`` or below ``rtol`` times
        the step's motion (defaults 0 and 1e-10: a tight, scale-free rule).

    Attributes
    ----------
    iterations : int
        Iterations of the last step.
    effects : tuple of str
    """

    def __init__(
        self,
        mesh,
        D,
        *,
        mu,
        gamma,
        rho,
        h,
        active_labels=None,
        gravity=None,
        contact_vertices=None,
        ground=None,
        up=None,
        stickiness=1.0,
        push_out=0.0,
        pinned=None,
        pin_stiffness=None,
        damping_mass=0.0,
        damping_stiffness=0.0,
        max_iter=2000,
        tol=0.0,
        rtol=1e-10,
    ):
        clock = time.perf_counter()
        check_mesh(mesh)
        dim, n = mesh.p.shape
        nT = mesh.t.shape[1]
        N = n * dim
        D = _muscle_modes(D, N)
        self.h = _positive_scalar(h, "h")
        self.max_iter = int(max_iter)
        if self.max_iter < 1:
            raise ValueError(f"max_iter must be a positive integer, got {max_iter!r}")
        self.tol = _positive_scalar(tol, "tol", allow_zero=True)
        self.rtol = _positive_scalar(rtol, "rtol", allow_zero=True)
        self.up = dim - 1 if up is None else int(up)
        vol = np.abs(_signed_measures(mesh.p, mesh.t))
        w_mu = _positive(mu, nT, "mu") * vol
        w_gamma = _positive(gamma, nT, "gamma", allow_zero=True) * vol
        rho_e = _positive(rho, nT, "rho")
        self.mesh, self.D, self.dim, self.n_muscles = mesh, D, dim, D.shape[1]
        dd = dim * dim
        self.J = _jacobian(mesh, "P1")
        self.M = _mass(mesh, rho_e, True, "P1", True)
        m = D.shape[1]
        self._w_mu = np.repeat(w_mu, dd)
        self._w_gamma = np.repeat(w_gamma, dd) if m else np.zeros(nT * dd)
        W = sps.diags(self._w_mu + self._w_gamma)
        L = (self.J.T @ W @ self.J).tocsr()
        self._L_mu = (self.J.T @ sps.diags(self._w_mu) @ self.J).tocsr()
        H = self.M / self.h**2 + L
        self._f = np.zeros(N)
        self._pins = np.zeros(N)
        effects = ["elasticity", "inertia"] + (["muscles"] if m else [])
        if gravity is not None:
            self._f += _gravity(mesh, gravity, rho_e)
            effects.append("gravity")
        self.pinned = np.zeros(0, np.int64) if pinned is None else np.unique(np.asarray(pinned))
        if self.pinned.size:
            if pin_stiffness is None:
                row_norms = np.asarray(self.J.multiply(self.J).sum(axis=1)).ravel()
                pin_stiffness = 1e3 * max(
                    float(self._w_mu @ row_norms) / N, float(self.M.diagonal().mean()) / self.h**2
                )
            dofs = vector_dofs(self.pinned, dim)
            pins = np.zeros(N)
            pins[dofs] = pin_stiffness
            H = H + sps.diags(pins)
            self._f += pins * mesh.p.T.ravel()
            self._pins = pins
            effects.append("pinned")
        self._damping = damping_mass * self.M + damping_stiffness * self._L_mu
        if damping_mass or damping_stiffness:
            H = H + self._damping / self.h
            effects.append("damping")
        self._lu = spla.splu(
            sps.csc_matrix(H), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True}
        )
        self._solve = _SparseSolve(self._lu)
        # per element, per muscle: the gradient change (J D_k)_e
        self._G = (self.J @ D).reshape(nT, dim, dim, m) if m else None
        labels = np.zeros(nT, np.int64) if active_labels is None else np.asarray(active_labels, np.int64)
        if labels.shape != (nT,) or labels.min() < 0:
            raise ValueError(f"active_labels must hold one non-negative label per element ({nT})")
        na = int(labels.max()) + 1
        self._active = labels
        # sums over each muscle cluster of per-element values
        self._cluster_sum = sps.csr_matrix((np.ones(nT), (labels, np.arange(nT))), shape=(na, nT))
        self._contact = None
        self.ground = ground
        if ground is not None:
            cv = np.asarray(contact_vertices) if contact_vertices is not None else None
            if cv is None:
                from .mesh import boundary_vertices

                cv = boundary_vertices(mesh)
            cv = np.unique(cv)
            rows = vector_dofs(cv, dim)
            Je = sps.csr_matrix((np.ones(rows.size), (np.arange(rows.size), rows)), shape=(rows.size, N))
            self._contact = GroundContact(Je, self._solve, self.h, dim, self.up, ground, stickiness, push_out)
            self.contact_vertices = cv
            effects.append("contact")
        self.effects = tuple(effects)
        self.iterations = 0
        self.timings = {"precompute": time.perf_counter() - clock}

    def _muscle_rotations(self, F, Y) -> np.ndarray:
        """Each element's muscle-cluster rotation: polar of the cluster's sum of w F Y^T."""
        dim = self.dim
        w = self._w_gamma[:: dim * dim]
        sums = self._cluster_sum @ (w[:, None, None] * (F @ np.swapaxes(Y, 1, 2))).reshape(-1, dim * dim)
        return polar_rotations(sums.reshape(-1, dim, dim))[self._active]

    def rest_state(self):
        """``(x, x_dot, a)``: rest positions (interleaved), zero velocity and activation."""
        x = self.mesh.p.T.ravel().copy()
        return x, np.zeros_like(x), np.zeros(self.n_muscles)

    def positions(self, x) -> np.ndarray:
        """Vertex positions, shape (n, dim)."""
        return np.asarray(x).reshape(-1, self.dim)

    def com(self, x) -> np.ndarray:
        """Centre of mass, shape (dim,)."""
        m = self.M.diagonal()[:: self.dim]
        return (m[:, None] * self.positions(x)).sum(axis=0) / m.sum()

    def step(self, x, x_dot, a=None) -> np.ndarray:
        """One time step, iterated to the tolerance; returns the next positions."""
        h, dim = self.h, self.dim
        nT = self.mesh.t.shape[1]
        x = np.asarray(x, float)
        x_dot = np.asarray(x_dot, float)
        rhs0 = self.M @ (x + h * x_dot) / h**2 + self._f + self._damping @ x / h
        m = self.n_muscles
        if m:
            a = np.asarray(a, float).ravel()
            if a.shape != (m,):
                raise ValueError(f"activation must have one value per muscle ({m}), got {a.size}")
            Y = np.eye(dim) + np.tensordot(self._G, a, axes=([3], [0]))  # (nT, dim, dim)
        contact = self._contact
        if contact is not None:
            contact.start_step(x)
        x_iter = x
        for it in range(1, self.max_iter + 1):  # noqa: B007 - the count is kept
            F = (self.J @ x_iter).reshape(nT, dim, dim)
            target = self._w_mu * polar_rotations(F).ravel()
            if m:
                R_a = self._muscle_rotations(F, Y)
                target += self._w_gamma * (R_a @ Y).ravel()
            x_next = self._solve(rhs0 + self.J.T @ target)
            if contact is not None:
                y = contact.correct(np.concatenate([x_next, contact.Je @ x_next]))
                x_next = y[: x.size]
            change = np.linalg.norm(x_next - x_iter)
            if not np.isfinite(change):
                raise SimulationError("the state became non-finite")
            x_iter = x_next
            if change < self.tol or change <= self.rtol * np.linalg.norm(x_next - x):
                break
        self.iterations = it
        return x_iter

    def energy(self, x_next, x, x_dot, a=None, gradient: bool = False):
        """The energy one step minimises, at ``x_next`` (rotations optimal; no contact).

        Returns
        -------
        E : float
        grad : ndarray, shape (n * dim,), only with ``gradient=True``
        """
        h, dim = self.h, self.dim
        nT = self.mesh.t.shape[1]
        xn = np.asarray(x_next, float)
        x = np.asarray(x, float)
        d = xn - x - h * np.asarray(x_dot, float)
        v = xn - x
        F = (self.J @ xn).reshape(nT, dim, dim)
        R_p = polar_rotations(F)
        E = d @ (self.M @ d) / (2 * h**2) + v @ (self._damping @ v) / (2 * h)
        E += 0.5 * self._w_mu @ ((F - R_p) ** 2).reshape(-1)
        force = self._w_mu * (F - R_p).ravel()
        if self.n_muscles:
            Y = np.eye(dim) + np.tensordot(self._G, np.asarray(a, float), axes=([3], [0]))
            R_a = self._muscle_rotations(F, Y)
            E += 0.5 * self._w_gamma @ ((F - R_a @ Y) ** 2).reshape(-1)
            force += self._w_gamma * (F - R_a @ Y).ravel()
        rest = self.mesh.p.T.ravel()
        E += 0.5 * self._pins @ ((xn - rest) ** 2) - xn @ (self._f - self._pins * rest)
        if not gradient:
            return float(E)
        grad = self.M @ d / h**2 + self._damping @ v / h + self.J.T @ force
        grad += self._pins * (xn - rest) - (self._f - self._pins * rest)
        return float(E), grad
