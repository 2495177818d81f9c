"""The model: a space, its effects and the operators of one time step, precomputed.

:class:`Model` sums the effects' terms (:mod:`skfem_modal.effects`) at a time
step ``h`` into the system a step solves,

    H u = Pz u0 + Pv v0 + f + G^T vec(R) + A(a)^T vec(R_a),

factors ``H`` once, and keeps what the iterations use: the cluster rows ``G``
(passive) and ``A(a) = A_0 + sum_k a_k A_k`` (muscles) and, in a subspace,
the dense products ``W = H^-1 G^T``, ``W_A = H^-1 A^T`` and
``C = H^-1 [Pz | Pv | f]``. Changing ``h`` or an effect reassembles these
(cheap: sums of ``r x r`` matrices and one small factorisation); the
expensive reductions stay in the effects. With the corotated stiffness
damping the passive rotations are those closest to ``G u + o`` and weigh
``1 + b`` (``b = beta / h``), and the right-hand side gains ``-b G^T vec(R0)``,
``o`` and ``R0`` made at each step's start (:meth:`Model.start_terms`). The stepping lives elsewhere
(:mod:`skfem_modal.solver`).
"""

from __future__ import annotations

import numpy as np

from .effects import ORDER, Effect
from .mesh import body_size, connected_labels, part_boxes
from .values import is_finite_real

__all__ = ["Model", "motion_scale"]


def motion_scale(space, mass, mass_matrix) -> float:
    """How long a change of ``z`` is that moves the body's vertices by its size, on average.

    A change ``dz`` moves the vertices by ``dx = B dz``; their mass-weighted
    root mean square displacement is ``sqrt(dz^T (B^T M B) dz / m)``, ``m``
    the body's mass. With ``B^T M B`` replaced by its mean diagonal ``c``
    (exact for a mass-orthonormal ``B``), a displacement of the body's size
    ``L`` (its largest extent) is a change of length ``L sqrt(m / c)``.

    A mesh of several bodies (connected parts) takes the least of its bodies' own: a change within it
    then moves no body by more than that share of its size, however light (of the whole mesh's, a
    spinning copy of a body a twentieth its size, beside it at rest, kept none of its spin: the body's
    stillness stopped every step's iterations after one or two; an audit).

    Parameters
    ----------
    space : Subspace or FullSpace
    mass : ndarray, shape (N,)
        Lumped mass per interleaved DOF.
    mass_matrix : ndarray or sparse matrix, shape (r, r)
        ``B^T M B``.

    Returns
    -------
    float
    """
    body_size(space.mesh)  # (its points checked)
    parts = connected_labels(space.mesh)
    low, high = part_boxes(space.mesh, parts)
    bodies = np.bincount(parts, weights=np.asarray(mass)[:: space.dim])  # each part's mass
    least = float(np.min((high - low).max(axis=1) * np.sqrt(bodies)))
    return least * float(np.sqrt(1.0 / np.mean(mass_matrix.diagonal())))


def _full_rank(space, mass_matrix) -> None:
    """Refuse a subspace whose columns depend on each other (its mass matrix ``B^T M B`` is singular).

    Judged on the columns at unit mass (``B^T M B`` scaled by its diagonal): an affine basis of a body
    1e-9 across has columns 1e9 apart in length, which are no less independent for it.
    """
    if not space.dense:
        return
    gram = np.asarray(mass_matrix)
    lengths = np.sqrt(np.maximum(gram.diagonal(), 0.0))
    massless = lengths == 0.0
    lengths[massless] = 1.0
    values = np.linalg.eigvalsh(gram / np.outer(lengths, lengths))
    dependent = int(np.count_nonzero(values <= 1e-12 * values.max())) if values.size else 0
    if dependent:
        raise ValueError(
            f"B's {space.r} columns are not independent ({dependent} of them are combinations of the others, "
            "e.g. a column repeated): B needs full column rank, as mass_orthonormalize(B, M) gives"
        )


class Model:
    """Precomputed operators of a simulator at one time step.

    Parameters
    ----------
    space : Subspace or FullSpace
    effects : sequence of Effect
        In the order of :data:`skfem_modal.effects.ORDER`; elasticity and
        inertia are required.
    h : float
        Time step.

    Attributes
    ----------
    G : ndarray or sparse matrix, shape (clusters * dim * dim, r)
        Passive cluster rows.
    A : ndarray, shape (m + 1, active clusters * dim * dim, r), or None
        Muscle cluster rows (a subspace only; without muscles None).
    W, WA, C : ndarray
        ``H^-1 G^T`` (r, clusters dd; times :attr:`rotation_scale`), ``H^-1 A_k^T`` (m + 1, r, active
        clusters dd), ``H^-1 [Pz | Pv | f]`` (r, 2 r + 1); a subspace only.
    system : DenseSystem or SparseSystem
        The factored ``H``.
    rest : ndarray, shape (r,)
        The rest state.
    rotation_scale : float
        The weight of the passive rotation term, ``1 + beta / h`` with the
        corotated stiffness damping (:class:`~skfem_modal.effects.Damping`),
        else 1; see :meth:`start_terms`.
    scale : float
        The length of a change of ``z`` that moves the body's vertices by its
        size (mass-weighted root mean square): what makes ``z``'s changes
        comparable between bodies and units (the stopping rule's ``tol``).
    """

    def __init__(self, space, effects, h):
        self.space = space
        self._set(effects)
        _full_rank(space, self.inertia.mass_matrix)
        self.rest = space.coordinates(space.rest, self.inertia.mass)
        self.scale = motion_scale(space, self.inertia.mass, self.inertia.mass_matrix)
        self.h = _checked_step(h)
        self.assemble()

    def _set(self, effects) -> None:
        names = [e.name for e in effects]
        unknown = [name for name in names if name not in ORDER]
        if unknown:
            raise ValueError(f"effects must be of {ORDER}, got {unknown}")
        if names != sorted(names, key=ORDER.index) or names[:2] != ["elasticity", "inertia"]:
            raise ValueError(f"effects must start with elasticity and inertia and follow {ORDER}, got {names}")
        self.effects = tuple(effects)
        self.named = {e.name: e for e in effects}
        self.elasticity, self.inertia = self.named["elasticity"], self.named["inertia"]
        self.muscles = self.named.get("muscles")
        self.contact = self.named.get("contact")
        self.G = self.elasticity.rows
        self.A = np.stack(self.muscles.blocks) if self.muscles is not None and self.space.dense else None

    @property
    def n_muscles(self) -> int:
        return 0 if self.muscles is None else self.muscles.count

    def assemble(self) -> None:
        """(Re)build the system of the current time step and effects."""
        h, space = self.h, self.space
        with np.errstate(over="ignore", invalid="ignore"):  # a term out of range is named below
            terms = {e.name: m for e in self.effects if (m := e.matrix(h)) is not None}
            H = sum(terms.values())
        _check_in_range(H, terms)
        parts = [e.rhs(h) for e in self.effects]
        r = space.r
        self.Pz = sum((p[0] for p in parts if p[0] is not None), 0 * H)
        self.Pv = sum((p[1] for p in parts if p[1] is not None), 0 * H)
        self.f = sum((p[2] for p in parts if p[2] is not None), np.zeros(r))
        try:
            self.system = space.factor(H)
        except ValueError:
            raise ValueError(self._singular_why(H, terms)) from None
        damping = self.named.get("damping")
        self.corotated = damping if damping is not None and damping.stiffness_coefficient else None
        self.rotation_scale = 1.0 if self.corotated is None else self.corotated.rotation_scale(h)
        if space.dense:
            self.C = self.system.solve(np.hstack([self.Pz, self.Pv, self.f[:, None]]))
            self.W = self.system.solve(self.G.T) * self.rotation_scale
            if self.A is not None:
                self.WA = np.stack([self.system.solve(Ak.T) for Ak in self.A])
        if self.contact is not None:
            gravity = self.named.get("gravity")
            self.contact.bind(self.system, h, None if gravity is None else gravity.acceleration)

    def assemble_or_undo(self, undo) -> None:
        """Assemble after a change; if that fails (a singular system, a term out of range), ``undo()`` the
        change, assemble as before, and raise: a refused setting leaves the model as it was (a refused
        pin stiffness stayed, read back but not stepped with, and broke the next assignment of ``h``)."""
        try:
            self.assemble()
        except BaseException:  # (Ctrl-C too: a half-made change would stay)
            undo()
            self.assemble()
            raise

    def retime(self, h: float) -> None:
        """Reassemble at the time step ``h`` (s, > 0); if its system is singular, the old step stays and the
        error is raised."""
        old, self.h = self.h, _checked_step(h)
        self.assemble_or_undo(lambda: setattr(self, "h", old))

    def _singular_why(self, H, terms: dict) -> str:
        """Why the system matrix could not be factored, in words (``terms``: each effect's part of ``H``)."""
        M = self.inertia.mass_matrix
        mass = float(np.abs(M.diagonal()).max()) / self.h**2
        stiff = float(np.abs(H.diagonal()).max())
        if mass < 1e-12 * stiff:
            others = {name: _largest_entry(m) for name, m in terms.items() if name != "inertia"}
            name = max(others, key=others.get)
            what = "the stiffness" if name in ("elasticity", "muscles") else f"the {name} term"
            if name == "pinned":  # (it said 'pin the body' of a pinned one)
                remedy = "; give the pins a smaller stiffness (pin_stiffness, [pinned] stiffness)"
                remedy += ", or a smaller time step"
            else:
                remedy = ", which leaves a free body's rigid motions undetermined; use a smaller time step"
                remedy += ", or pin the body"
                remedy += "" if what == "the stiffness" else f", or make the {name} coefficients smaller"
            return (
                f"the system matrix is singular to working precision: with h = {self.h:g} the inertia term "
                f"(mass / h^2, up to {mass:.3g}) is {mass / stiff:.1e} of {what} (up to {others[name]:.3g})" + remedy
            )
        column_mass = M.diagonal()
        spread = float(column_mass.max() / column_mass.min()) if column_mass.min() > 0.0 else np.inf
        if spread > 1e12:
            return (
                "the system matrix is too unevenly scaled to solve to working precision: B's columns differ in mass "
                f"by {spread:.1e} (B^T M B's diagonal from {column_mass.min():.3g} to {column_mass.max():.3g}); "
                "scale them to comparable lengths (mass_orthonormalize(B, M) gives each unit mass)"
            )
        return "the reduced system matrix is not positive definite: check that B has full column rank"

    def replace(self, effect) -> None:
        """Put ``effect`` (an :class:`~skfem_modal.effects.Effect`) in, replacing the one of its name or adding it
        in the order of :data:`~skfem_modal.effects.ORDER`, and reassemble (or raise, the model unchanged)."""
        if not isinstance(effect, Effect):
            raise TypeError(f"effect must be an Effect (skfem_modal.effects), got {effect!r}")
        named, before = {**self.named, effect.name: effect}, list(self.effects)
        self._set([named[n] for n in ORDER if n in named])
        self.assemble_or_undo(lambda: self._set(before))

    def remove(self, name: str) -> None:
        """Take the effect called ``name`` (e.g. ``"gravity"``) out and reassemble (or raise, the model unchanged)."""
        if name not in self.named:
            raise ValueError(f"the model has no effect called {name!r}; it has {', '.join(self.named)}")
        before = list(self.effects)
        self._set([e for e in self.effects if e.name != name])
        self.assemble_or_undo(lambda: self._set(before))

    def constant(self, z, z_dot) -> np.ndarray:
        """The start-of-step part of a global solution, ``H^-1 (Pz z + Pv z_dot + f)``, shape (r,).

        ``z``, ``z_dot`` (r,): the state the step starts from.
        """
        if self.space.dense:
            return self.C[:, : z.size] @ z + self.C[:, z.size : 2 * z.size] @ z_dot + self.C[:, -1]
        return self.system.solve(self.Pz @ z + self.Pv @ z_dot + self.f)

    def start_terms(self, z):
        """A step's terms from the corotated damping at its start ``z``, or None without it.

        Returns
        -------
        offset : ndarray, shape (G rows,)
            Added to the passive cluster rows ``G z`` before their rotations are taken.
        shift : ndarray, shape (r,)
            Added to the step's constant (:meth:`constant`): ``-b H^-1 G^T vec(R0)``.
        """
        if self.corotated is None:
            return None
        offset, R0 = self.corotated.offset(self.h, self.G @ z)
        b = self.rotation_scale - 1.0
        if self.space.dense:
            return offset, self.W @ R0 * (-b / self.rotation_scale)
        return offset, self.system.solve(self.G.T @ R0) * -b

    def energy(self, u, u0, v0, a, gradient: bool = False):
        """The energy a step minimises, at ``u``, rotations optimal (contact adds none).

        Parameters
        ----------
        u : ndarray, shape (r,)
            The candidate end of the step.
        u0, v0 : ndarray, shape (r,)
            The step's start and velocity.
        a : ndarray, shape (m,)
            The activation.
        gradient : bool
            Also the gradient.

        Returns
        -------
        E : float
        grad : ndarray, shape (r,)
            Only with ``gradient=True``.
        """
        E, grad = 0.0, np.zeros(u.size)
        for effect in self.effects:
            e, g = effect.energy(self.h, u, u0, v0, a)
            E += e
            grad = grad + g
        return (float(E), np.asarray(grad)) if gradient else float(E)


def _largest_entry(matrix) -> float:
    """The largest magnitude of a dense or sparse matrix's entries (inf or nan if any is)."""
    values = matrix.data if hasattr(matrix, "tocsr") else np.asarray(matrix)
    return float(np.abs(values).max()) if values.size else 0.0


def _check_in_range(H, terms: dict) -> None:
    """Raise, naming each effect's share, if the system matrix ``H`` overflows float64 or comes near it.

    The factorisation adds ``H`` to its transpose: entries within a factor of 4 of float64's
    largest would overflow there (to a 'singular' matrix, blaming the wrong term).
    """
    largest = _largest_entry(H)
    limit = np.finfo(np.float64).max / 4
    if largest <= limit:
        return
    shares = ", ".join(f"{name} {_largest_entry(m):.3g}" for name, m in terms.items())
    reach = f"reach {largest:.3g}" if np.isfinite(largest) else "overflow"
    raise ValueError(
        f"the system matrix's entries {reach}, beyond what float64 computes with (at most {limit:.3g}): "
        f"its terms' largest entries are {shares}; make the largest term's coefficients smaller"
    )


def _checked_step(h) -> float:
    """The time step ``h`` as a float, if it is a positive, finite number; else a ValueError naming it."""
    if not (is_finite_real(h) and h > 0):
        raise ValueError(f"the time step h must be a positive, finite number, got {h!r}")
    return float(h)
