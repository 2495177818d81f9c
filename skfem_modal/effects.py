"""Effects: each one contributes its own terms to a time step.

A step of length ``h`` minimises, over the next unknowns ``u``, a sum of terms

    E(u) = sum over effects of  1/2 u^T H_e u - u^T (Pz_e u0 + Pv_e v0 + f_e) + c_e
           - sum over rotation clusters of  R_c : S_c(u)

(``u0``, ``v0`` the start-of-step state, ``S_c`` linear in ``u``, ``R_c``
the closest rotation to ``S_c``). Each effect object holds its operators,
already taken into the space of the unknowns (:mod:`skfem_modal.space`), and
answers for its share:

* :meth:`Effect.matrix` its part of the constant system matrix ``H``,
* :meth:`Effect.rhs` its part of the right-hand side, ``Pz u0 + Pv v0 + f``,
* :meth:`Effect.energy` its energy and gradient, for checks and studies,
* ``rows``: the rotation effects (elasticity, muscles) their cluster rows ``S(u)``.

Ground contact (:mod:`skfem_modal.contact`) is an effect too:
it adds no energy term but projects each global solution.

The reduced simulator and the full-space reference build the same effects,
in the same order (:data:`ORDER`), on their own space.
"""

from __future__ import annotations

import numpy as np

from .mesh import connected_labels
from .modal import ceilings_of_gradients
from .motions import held_parts
from .muscles import cluster_sum_operator, muscle_target_constants, muscle_target_operator
from .rotations import rotations2_flat, rotations3_flat
from .values import checked_state

__all__ = ["Effect", "Elasticity", "Inertia", "Muscles", "Gravity", "Pins", "Damping", "ORDER"]

#: The order of effects in every simulator (and of their names in ``sim.effects``).
ORDER = ("elasticity", "inertia", "muscles", "gravity", "pinned", "damping", "contact")

_ROTATIONS = {2: rotations2_flat, 3: rotations3_flat}


class Effect:
    """An effect's share of a time step (the base class: no terms at all)."""

    name = "effect"

    def matrix(self, h):
        """Its part of the system matrix for a time step ``h`` (float), shape (r, r) (sparse in the full space),
        or None."""
        return None

    def rhs(self, h):
        """``(Pz, Pv, f)``: its right-hand side ``Pz u0 + Pv v0 + f`` for a time step ``h`` (float); None for
        absent parts (``Pz``, ``Pv`` (r, r), ``f`` (r,))."""
        return None, None, None

    def energy(self, h, u, u0, v0, a):
        """Its energy at ``u`` for a step of ``h`` from ``(u0, v0)`` under activation ``a``, and the gradient.

        Parameters
        ----------
        h : float
        u, u0, v0 : ndarray, shape (r,)
        a : ndarray, shape (m,)

        Returns
        -------
        E : float
        grad : ndarray, shape (r,), or 0.0 (none)
        """
        return 0.0, 0.0


def _rotation_energy(rows, hessian, u, dim):
    """``1/2 u^T H u - R : S`` and its gradient, ``S = rows @ u`` and ``R`` the closest rotations."""
    S = rows @ u
    R = _ROTATIONS[dim](S.reshape(-1, dim * dim)).ravel()
    Hu = hessian @ u
    return 0.5 * float(u @ Hu) - float(R @ S), Hu - rows.T @ R


class Elasticity(Effect):
    """Passive as-rigid-as-possible elasticity, one rotation per cluster of elements.

    ``sum_e mu_e vol_e / 2 |F_e(u) - R_c(e)|^2``.

    Parameters
    ----------
    space : Subspace or FullSpace
    weights : ndarray, shape (nT,)
        ``mu * vol`` per element.
    labels : ndarray of int, shape (nT,)
        Rotation cluster of each element.

    Attributes
    ----------
    rows : ndarray or sparse matrix, shape (clusters * dim * dim, r)
        ``rows @ u`` holds every cluster's ``sum_e w_e F_e`` (row-major).
    hessian : ndarray or sparse matrix, shape (r, r)
        ``J^T (w x I) J`` in the space.
    """

    name = "elasticity"

    def __init__(self, space, weights, labels):
        self.weights = weights
        self.labels = labels
        self.dim = space.dim
        self.n_clusters = int(labels.max()) + 1
        self.rows = space.through(cluster_sum_operator(labels, weights, space.dim) @ space.J)
        self.hessian = space.elastic_hessian(weights)
        self._rest_energy = 0.5 * space.dim * float(weights.sum())

    def matrix(self, h):
        return self.hessian

    def energy(self, h, u, u0, v0, a):
        E, grad = _rotation_energy(self.rows, self.hessian, u, self.dim)
        return E + self._rest_energy, grad


class Inertia(Effect):
    """Implicit-Euler inertia ``|u - u0 - h v0|^2_M / (2 h^2)`` with the lumped mass.

    Parameters
    ----------
    space : Subspace or FullSpace
    mass : ndarray, shape (N,)
        Lumped mass per interleaved DOF.

    Attributes
    ----------
    mass_matrix : ndarray or sparse matrix, shape (r, r)
        ``B^T M B``.
    """

    name = "inertia"

    def __init__(self, space, mass):
        self.mass = mass
        self.mass_matrix = space.gram(mass)

    def matrix(self, h):
        return self.mass_matrix / h**2

    def rhs(self, h):
        return self.mass_matrix / h**2, self.mass_matrix / h, None

    def energy(self, h, u, u0, v0, a):
        d = u - u0 - h * v0
        Md = self.mass_matrix @ d
        return float(d @ Md) / (2 * h**2), Md / h**2


class Muscles(Effect):
    """Modal muscles: the clustered plastic-stretch target of :mod:`skfem_modal.muscles`.

    ``sum_e gamma_e vol_e / 2 |F_e(u) - R_a(e) Y_e(a)|^2`` with
    ``Y_e(a) = I + sum_k a_k (J D_k)_e``.

    Parameters
    ----------
    space : Subspace or FullSpace
    modes : ndarray, shape (N, m)
        The muscle modes ``D`` (displacements).
    weights : ndarray, shape (nT,)
        ``gamma * vol`` per element.
    labels : ndarray of int, shape (nT,)
        Muscle rotation cluster of each element.
    mass : ndarray, shape (N,)
        Lumped mass, for the realised amplitudes.
    max_s : float
        The ceilings' largest gradient change (:func:`~skfem_modal.modal.actuation_limits`).

    Attributes
    ----------
    blocks : list of m + 1 matrices of shape (clusters * dim * dim, r)
        The cluster rows ``A_0 + sum_k a_k A_(k + 1)``.
    ceilings : ndarray, shape (m,)
    """

    name = "muscles"

    def __init__(self, space, modes, weights, labels, mass, max_s=2.0):
        dim = self.dim = space.dim
        self.modes, self.weights, self.labels = modes, weights, labels
        self.count = modes.shape[1]
        self.n_clusters = int(labels.max()) + 1
        JD = space.J @ modes
        self._JD = JD
        self.max_s = max_s
        # a mode that deforms no element (zero, or a rigid translation: its gradients are round-off) has no
        # ceiling: its activations, fractions of one, were inf and NaN (an audit)
        reach = float(abs(space.J).sum(axis=1).max()) * np.abs(modes).max(axis=0, initial=0.0)
        still = np.flatnonzero(~(self.max_s / self.ceilings > 1e-10 * reach) | (reach == 0.0))
        if still.size:
            raise ValueError(
                f"muscle modes {still.tolist()} (columns of D) deform no element: zero or a rigid motion; a muscle "
                "must change the body's shape"
            )
        stacked = space.through(muscle_target_operator(JD, labels, weights, dim) @ space.J)
        size = self.n_clusters * dim * dim
        self.blocks = [stacked[k * size : (k + 1) * size] for k in range(self.count + 1)]
        self.hessian = space.elastic_hessian(weights)
        self._constants = muscle_target_constants(JD, weights, dim)
        # the realised amplitude of muscle k: the mass-weighted projection of x - X on D_k
        MD = modes * mass[:, None]
        scale = 1.0 / np.einsum("ik,ik->k", MD, modes)
        self.amplitude_rows = np.asarray(space.force(MD)).T * scale[:, None]
        self.amplitude_rest = (MD.T @ space.rest) * scale
        self._frame_inputs = (space, modes, mass, scale)
        self._frames = {}  # the parts' frames, by which parts are held, made when first asked for (amplitudes)

    @property
    def max_s(self) -> float:
        """The ceilings' largest gradient change; assigning recomputes :attr:`ceilings`."""
        return self._max_s

    @max_s.setter
    def max_s(self, value) -> None:
        value = float(value)
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"max_s must be positive and finite, got {value!r}")
        self._max_s = value
        self.ceilings = ceilings_of_gradients(self._JD, self.dim, value)

    def rows_for(self, a):
        """The cluster rows under activation ``a``, shape (clusters * dim * dim, r)."""
        rows = self.blocks[0]
        for k in range(self.count):
            rows = rows + a[k] * self.blocks[k + 1]
        return rows

    def matrix(self, h):
        return self.hessian

    def energy(self, h, u, u0, v0, a):
        E, grad = _rotation_energy(self.rows_for(a), self.hessian, u, self.dim)
        c0, c1, Q = self._constants
        return E + c0 + float(c1 @ a) + float(a @ Q @ a), grad

    def amplitudes(self, u, pinned=None) -> np.ndarray:
        """Realised modal amplitudes of a state ``u`` (r,), shape (m,).

        Each body of the mesh (connected part) by its own share of the projection: of the displacement
        from its rest shape moved by its best rigid motion (:class:`_BodyFrame`), so that a body that
        turned or moved is not read as muscle action; or, for a body its pins hold in place (no rigid
        motion left, :func:`~skfem_modal.motions.held_parts`), of the displacement from its rest shape.

        Parameters
        ----------
        u : ndarray, shape (r,)
        pinned : ndarray of int, shape (k,), optional
            The pinned vertices.

        Returns
        -------
        amplitudes : ndarray, shape (m,)
        """
        u = checked_state(u, self.amplitude_rows.shape[1], "u")
        pinned = np.zeros(0, np.int64) if pinned is None else np.asarray(pinned, np.int64)
        frames = self._frames.get(pinned.tobytes())
        if frames is None:
            # each body in its own frame (one for all: a part that turned read as muscle action; a pin on one
            # body had put every body in the rest frame, and a body turning about one pin read as a muscle)
            held = held_parts(self._frame_inputs[0].mesh, pinned) if pinned.size else None
            frames = self._frames[pinned.tobytes()] = _part_frames(*self._frame_inputs, held)
        return sum(frame.amplitudes(u) for frame in frames)


def _part_frames(space, modes, mass, scale, held=None) -> list:
    """A frame per connected part of the mesh, each of its part's masses (the others' zero): a :class:`_RestFrame`
    for the parts ``held`` (bool, (parts,)) marks, a :class:`_BodyFrame` for the others."""
    parts = np.repeat(connected_labels(space.mesh), space.dim)  # (N,): each DOF's part
    frames = []
    for q in range(parts.max() + 1):
        part_mass = mass if parts.max() == 0 else np.where(parts == q, mass, 0.0)
        frame = _RestFrame if held is not None and held[q] else _BodyFrame
        frames.append(frame(space, modes, part_mass, scale))
    return frames


class _RestFrame:
    """Modal amplitudes of a held body: the mass-weighted projection of ``x - X`` on each mode, its masses'."""

    def __init__(self, space, modes, mass, scale):
        MD = modes * mass[:, None]
        self.rows = np.asarray(space.force(MD)).T * scale[:, None]
        self.rest = (MD.T @ space.rest) * scale

    def amplitudes(self, u) -> np.ndarray:
        return self.rows @ u - self.rest


class _BodyFrame:
    """Modal amplitudes in the body's own frame, from a few operators linear in the state.

    With masses ``m_i``, rest positions ``X_i`` (centre ``C``) and positions ``x_i`` (centre
    ``c``), the best rigid motion of the rest shape onto the state is ``x ~ R (X - C) + c`` with
    ``R`` the closest rotation to ``S = sum_i m_i x_i (X_i - C)^T`` (Kabsch). The amplitude of
    mode ``D_k`` is the mass-weighted projection of ``R^T (x_i - c) - (X_i - C)`` on it:
    ``(R : P_k - c . R s_k - t_k) / n_k`` with ``P_k = sum_i m_i x_i D_ki^T`` (linear in the state),
    ``s_k = sum_i m_i D_ki``, ``t_k = sum_i m_i D_ki . (X_i - C)`` and ``n_k = sum_i m_i |D_ki|^2``.
    At ``R = I`` and ``c = C`` it is the plain projection of ``x - X``.
    """

    def __init__(self, space, modes, mass, scale):
        d, m = space.dim, modes.shape[1]
        n = modes.shape[0] // d
        m_v = mass[::d]
        X = space.rest.reshape(n, d)
        C = m_v @ X / m_v.sum()
        D = modes.reshape(n, d, m)
        # columns over the interleaved DOFs: S's (a, b) entry reads coordinate a weighted by m (X - C)_b,
        # P_k's reads coordinate a weighted by m D_k,b
        weights = np.zeros((n, d, d * d + m * d * d))
        for a in range(d):
            weights[:, a, a * d : a * d + d] = m_v[:, None] * (X - C)
            for k in range(m):
                start = d * d + k * d * d + a * d
                weights[:, a, start : start + d] = m_v[:, None] * D[:, :, k]
        rows = np.asarray(space.force(weights.reshape(n * d, -1))).T
        self.dim = d
        self.cov_rows, self.moment_rows = rows[: d * d], rows[d * d :].reshape(m, d * d, -1)
        self.com_rows = space.com_rows(mass)  # (d, r)
        self.mode_sums = np.einsum("i,idk->kd", m_v, D)  # s_k
        self.rest_terms = np.einsum("i,idk,id->k", m_v, D, X - C)  # t_k
        self.scale = scale

    def amplitudes(self, u) -> np.ndarray:
        d = self.dim
        R = _ROTATIONS[d]((self.cov_rows @ u).reshape(1, d * d)).reshape(d, d)
        c = self.com_rows @ u
        moments = np.einsum("ab,kab->k", R, (self.moment_rows @ u).reshape(-1, d, d))
        return (moments - self.mode_sums @ (R.T @ c) - self.rest_terms) * self.scale


class Gravity(Effect):
    """Uniform gravity: the potential ``-u^T f`` with ``f`` the lumped weight.

    Parameters
    ----------
    space : Subspace or FullSpace
    mass : ndarray, shape (N,)
    acceleration : ndarray, shape (dim,)
    """

    name = "gravity"

    def __init__(self, space, mass, acceleration):
        self.acceleration = acceleration
        self.force = space.force(mass * np.tile(acceleration, space.n))

    def rhs(self, h):
        return None, None, self.force

    def energy(self, h, u, u0, v0, a):
        return -float(u @ self.force), -self.force


class Pins(Effect):
    """Vertices held at their rest positions by stiff springs ``k / 2 |x_i - X_i|^2``.

    Parameters
    ----------
    space : Subspace or FullSpace
    vertices : ndarray of int
    stiffness : float or None
        ``k``; None: 1e3 times the larger of the passive stiffness and the
        mass over ``h^2`` per DOF (``scale``), so it follows the time step.
    scale : tuple of float
        ``(passive, mass)``: the mean diagonal of the passive Hessian and of
        the mass matrix per DOF, for the default stiffness.
    """

    name = "pinned"

    def __init__(self, space, vertices, stiffness=None, scale=(0.0, 0.0)):
        self.vertices = vertices
        self.given_stiffness = stiffness
        self._scale = scale
        rows = space.rows(space.dofs(vertices))
        targets = space.rest[space.dofs(vertices)]
        self._gram = rows.T @ rows
        self._pull = rows.T @ targets
        self._rest = 0.5 * float(targets @ targets)

    def stiffness(self, h) -> float:
        """The spring stiffness at time step ``h``."""
        if self.given_stiffness is not None:
            return self.given_stiffness
        return self.default_stiffness(h)

    def default_stiffness(self, h) -> float:
        """The stiffness pins get when none is given, at time step ``h``."""
        passive, mass = self._scale
        return 1e3 * max(passive, mass / h**2)

    def matrix(self, h):
        return self.stiffness(h) * self._gram

    def rhs(self, h):
        return None, None, self.stiffness(h) * self._pull

    def energy(self, h, u, u0, v0, a):
        k = self.stiffness(h)
        Gu = self._gram @ u
        return k * (0.5 * float(u @ Gu) - float(u @ self._pull) + self._rest), k * (Gu - self._pull)


class Damping(Effect):
    """Rayleigh damping, corotated: mass-proportional drag and a damped rate of deformation.

    The dissipation of a step from ``u0`` to ``u`` is

        alpha |u - u0|^2_M / (2 h)
        + beta / (2 h) sum_e w_e |(F_e(u) - R_c) - (F_e(u0) - R0_c)|^2,

    ``w_e`` the elasticity's ``mu vol`` and ``R_c`` its cluster's rotation,
    shared with the elasticity (``R0_c`` the closest rotation at ``u0``). The
    second term damps the change of each element's departure from its
    cluster's rotation, so a rigid motion (a spin included) goes undamped;
    its quadratic part is ``beta K / h`` (``K`` the elastic Hessian), as
    stiffness-proportional Rayleigh damping. Folded into the elasticity, a
    cluster's rotation term becomes ``(1 + b) R : (S(u) + o)`` with
    ``b = beta / h`` and the offset ``o = b / (1 + b) (W_c R0 - S(u0))``
    (:meth:`offset`; ``S`` the cluster rows, ``W_c`` the cluster's weight),
    and the right-hand side gains ``-b G^T vec(R0)``.

    Parameters
    ----------
    inertia : Inertia
        Its mass matrix ``M``.
    elasticity : Elasticity
        Its rows, weights and Hessian ``K``.
    mass, stiffness : float
        ``alpha`` (1 / time: damps all motion, like drag) and ``beta`` (time:
        damps the rate of deformation, not rigid motion).
    """

    name = "damping"

    def __init__(self, inertia, elasticity, mass=0.0, stiffness=0.0):
        self.mass_coefficient, self.stiffness_coefficient = mass, stiffness
        self.elasticity = elasticity
        self.operator = mass * inertia.mass_matrix + stiffness * elasticity.hessian
        dd = elasticity.dim**2
        # each cluster's weight sum_e w_e, per row of the cluster rows
        totals = np.bincount(elasticity.labels, elasticity.weights, minlength=elasticity.n_clusters)
        self._row_weights = np.repeat(totals, dd)

    def rotation_scale(self, h) -> float:
        """``1 + beta / h``: the weight of the elasticity's rotation term with this damping, at the step ``h``."""
        return 1.0 + self.stiffness_coefficient / h

    def offset(self, h, S0):
        """The rotation terms' offset and the start rotations, from the cluster rows at the start ``S0``.

        Parameters
        ----------
        h : float
        S0 : ndarray, shape (clusters * dim * dim,)
            ``elasticity.rows @ u0``.

        Returns
        -------
        offset : ndarray, shape (clusters * dim * dim,)
            ``o``: the rotations of a step are those closest to ``S(u) + o``.
        R0 : ndarray, shape (clusters * dim * dim,)
            The closest rotations to ``S0``.
        """
        d = self.elasticity.dim
        R0 = _ROTATIONS[d](S0.reshape(-1, d * d)).ravel()
        b = self.stiffness_coefficient / h
        return b / (1.0 + b) * (self._row_weights * R0 - S0), R0

    def matrix(self, h):
        return self.operator / h

    def rhs(self, h):
        return self.operator / h, None, None

    def energy(self, h, u, u0, v0, a):
        v = u - u0
        Dv = self.operator @ v
        E, grad = float(v @ Dv) / (2 * h), Dv / h
        if not self.stiffness_coefficient:
            return E, grad
        # the rotations are the elasticity's: this term is the pair's energy less the elasticity's alone
        d, rows, b = self.elasticity.dim, self.elasticity.rows, self.stiffness_coefficient / h
        S, S0 = rows @ u, rows @ u0
        offset, R0 = self.offset(h, S0)
        R_alone = _ROTATIONS[d](S.reshape(-1, d * d)).ravel()
        R = _ROTATIONS[d]((S + offset).reshape(-1, d * d)).ravel()
        # (|R - R0|^2 = 2 d - 2 R : R0, a cluster's weight repeated on its d^2 rows)
        E += float((R_alone - R) @ S - b * (S - S0) @ (R - R0) + b * self._row_weights @ (1.0 / d - R * R0))
        # (the rotations are optimal: their derivatives drop out)
        grad = grad + rows.T @ (R_alone - (1.0 + b) * R + b * R0)
        return E, grad
