"""Ground contact: effects that project each global solution onto a ground plane.

Two models, both for a plane ``x[up] = ground``:

* :class:`CoulombContact` (``model = "coulomb"``, the default): every
  boundary vertex is a candidate; no vertex ends a step below the ground
  (positions, not velocities, are constrained), and Coulomb friction holds
  the touching vertices (sticking while the tangential force needed stays
  within ``friction`` times the normal force, sliding against the motion
  otherwise, in every tangent direction).
* :class:`ReferenceContact` (``model = "reference"``): the reference
  implementation's rule, described next, kept so its numbers can be
  reproduced: it lets vertices end inside the ground.

The reference rule: a set of contact vertices. In every global step
the tentative solution ``z_t = H^{-1} f`` is checked: each contact point that
is below the plane (at the current iterate) and moving into it (comparing
``z_t`` with the start of the step) is *active*. For the active points the
reduced force is changed as little as possible (least norm, or least squares
when there are more constraints than coordinates) so that each moves, over
the step, by ``h v``: normal velocity zero, tangential velocity kept times
``1 - stickiness`` (``stickiness = 1`` sticks, ``0`` slides freely).

``push_out = 0`` is the reference behaviour, and it lets points end inside
the ground: activity is decided on the previous iterate and only velocity is
constrained. With ``push_out > 0`` the contact works on positions instead: a
point may not end the step below its target height, the ground (or, for a
point that starts inside the ground, its start height raised by
``push_out`` of its depth, so it climbs out within a step or two); points
whose tentative end height is below target are constrained to it, and the
active set is re-checked after each correction.

The correction for a given set of active points is a fixed matrix, so it is
computed once per set and cached: contact sets repeat from one iteration and
one step to the next.

Both models report the deepest of all boundary vertices below the ground
(:meth:`penetration`), whatever vertices they constrain.
"""

from __future__ import annotations

import math
from collections import OrderedDict

import numpy as np
import scipy.sparse as sps
from scipy.linalg import lapack

from ._contact_sets import (
    Aims,
    Picked,
    SetOperator,
    compliance_matrix,
    coulomb_forces,
    given_back,
    pyramid_projection,
    spread_few,
)
from ._fast import dot
from .effects import Effect
from .mesh import boundary_vertices, connected_labels, part_sizes, part_thicknesses
from .solver import SimulationError
from .values import checked_state, is_finite_real, is_real

__all__ = [
    "CoulombContact",
    "ReferenceContact",
    "MODELS",
    "MODEL_SETTINGS",
    "DEFAULT_CONTACTS",
    "ALLOWANCE",
    "LEAST_ALLOWANCE",
    "MOST_ALLOWANCE",
    "checked_allowance",
    "allowance_lengths",
    "thin",
    "THIN",
    "THIN_WORDS",
]

#: Contact models by name (a scene's ``ground.model``).
MODELS = ("coulomb", "reference")
#: Each model's own settings (the simulator's and a scene's ``[ground]`` keys): the other model refuses them.
MODEL_SETTINGS = {"coulomb": ("friction", "allowance", "exact_friction"), "reference": ("stickiness", "push_out")}
#: How many boundary vertices each model takes as contacts unless told (None: all; the reference's tutorial: 30).
DEFAULT_CONTACTS = {"coulomb": None, "reference": 30}

#: How far below the ground (of the body's size) the Coulomb contact lets a vertex end a step, by default.
ALLOWANCE = 2e-4
#: The smallest allowance one may choose: double precision's round-off of the positions (1e-16 of their
#: coordinates, of a body up to :data:`~skfem_modal.units.FAR_FROM_ORIGIN` sizes from the origin, with a margin)
#: must stay within it (the caterpillar held 1e-12; with 1e-16 it ended 1.1 times it below, with 1e-17 no
#: step could hold it)
LEAST_ALLOWANCE = 1e-10
#: The largest allowance one may choose, a tenth of a percent of the body's size: a vertex that sank that far
#: climbs back out, and the body regains about the potential energy of the depth (a ghost dropped at h = 0.01
#: with 5e-3 gained 0.5 % of what its fall released in single steps, 2.2 % in all, and bounced; the seal at
#: 1e-3 at most 1.3e-4 a step, at 2e-4 4.9e-5)
MOST_ALLOWANCE = 1e-3
#: A part thinner than its size over this has its allowance relative to this many times its thickness instead:
#: the energy a sunk vertex regains by climbing out is the depth's, and a 100:1:1 beam's allowance of its size,
#: 2 % of its thickness, let it gain 3 % of what a short drop released in single steps (30:1:1 0.6 %)
THIN = 3.0
#: What a thin part's allowance is a share of, in words (messages and docs)
THIN_WORDS = f"{THIN:g} times a thin part's thickness"

_CACHE_SIZE = 512
# layouts whose corrections the reference contact keeps (a simulator's backends, rebuilt when settings change)
_LAYOUTS = 4
# passes of the active set in one projection before the exact solve (half changing whole sets, half one vertex)
_PASSES = 16
# vertices below the ground joining the active set per pass, at most
_JOIN = 4
# operators of sets of pushed and sticking vertices kept, the latest used
_OPERATORS = 64
# steps that keep the last step's picked vertices (while none is found below the ground at an end)
_KEEP = 10
# projections at the end of a step that may each find more vertices below the ground
_FINISH = 8
# what the Coulomb contact keeps for each candidate vertex from step to step (changed in place)
_PER_VERTEX = ("touching", "sliding", "direction")
# solves that may take back the way the compliance lets the ground give (see SetOperator.refined)
_REFINE = 16
# times the exact Coulomb solve takes in the picked vertices it left below (CoulombContact._exact_coulomb)
_WIDEN = 4
# a slide's friction this close to straight against its motion (1 - cos of the angle) needs no exact solve
_STRAIGHT = 1e-12


#: Why a state is checked against a ground (or up axis) assigned during a run, said when it is refused.
GROUND_DURING_A_RUN = (
    "assigning {setting} during a run moved the ground plane, and the state stepped from is this deep under the "
    "new one: assign it at most the allowance above that state's lowest vertex"
)


def allowance_lengths(mesh, labels=None) -> np.ndarray:
    """What each vertex's allowance is a share of: its part's size, or :data:`THIN` times its thickness if less.

    ``mesh``: a scikit-fem mesh; ``labels`` (n,): its connected parts
    (:func:`~skfem_modal.mesh.connected_labels`), if already known.

    Returns
    -------
    lengths : ndarray, shape (n,)

    Examples
    --------
    >>> from skfem_modal.mesh import beam2d
    >>> allowance_lengths(beam2d(2.0, 1.0, 4, 2)).max(), allowance_lengths(beam2d(30.0, 1.0, 60, 2)).max()
    (np.float64(2.0), np.float64(3.0))
    """
    labels = connected_labels(mesh) if labels is None else labels
    return np.minimum(part_sizes(mesh, labels), THIN * part_thicknesses(mesh, labels))


def thin(lengths, sizes) -> np.ndarray:
    """Which vertices are in a thin part: their allowance's length (:func:`allowance_lengths`) below their part's size.

    ``lengths``, ``sizes``: arrays of one shape (or numbers); returns booleans of that shape.
    """
    return np.less(lengths, sizes)


def checked_allowance(value, name: str = "allowance") -> float:
    """The Coulomb contact's allowance ``value`` as a float, checked to be in [:data:`LEAST_ALLOWANCE`,
    :data:`MOST_ALLOWANCE`]; ``name`` is the setting's name in the error.

    Raises
    ------
    ValueError
        Naming ``name``, if the value is not a number in that range.
    """
    if not is_real(value):  # (float() would take "0.001" and True)
        raise ValueError(f"{name} must be a number (a share of the body's size), got {value!r}")
    allowance = float(value) if is_finite_real(value) else math.inf  # (10**400: beyond a float's range)
    if not LEAST_ALLOWANCE <= allowance <= MOST_ALLOWANCE:
        raise ValueError(
            f"{name} must be at least {LEAST_ALLOWANCE:g} (less is lost in the round-off of the positions) and at "
            f"most {MOST_ALLOWANCE:g} (a tenth of a percent of the body's size), got {value!r}"
        )
    return allowance


def _gram_inverse(G) -> np.ndarray | None:
    """``G^-1`` (m, m) for ``G = L L^T`` well conditioned for certain: condition (1-norm) below 1e12.

    A well-posed set of contact points costs a factor and its inverse (m x m: the right-hand
    sides are the m rows, not the n columns; 15 x 96 took 13 us in LAPACK's solve, its inverse
    2). None otherwise: rows that depend on each other, or nearly (``G``'s condition is ``L``'s
    squared), or whose products leave float64's range (a time step of 1000 made ``G`` 1e-319, and
    its inverse NaN); the caller then solves with ``L`` itself, by least squares.

    The condition is bounded by the diagonals: an SPD matrix's entries are at most its largest
    diagonal entry (``|a_ij| <= sqrt(a_ii a_jj)``), so ``cond_1(G) <= m^2 max G_ii max (G^-1)_ii``
    (the contact sets of the tutorial's crawl and the dropped seal: condition 41 to 189, the
    bound at most 1.2e4). A non-finite inverse has a non-finite diagonal and fails the bound too.
    """
    m = G.shape[0]
    factor, info = lapack.dpotrf(G)
    if info != 0:
        return None
    upper = lapack.dpotri(factor)[0]  # the inverse's upper triangle, zeros below (scipy cleans them)
    inverse = upper + upper.T
    inverse.flat[:: m + 1] *= 0.5  # (np.triu's masks cost 13 us each)
    bound = m * m * float(G.diagonal().max()) * float(inverse.diagonal().max())
    return inverse if bound < 1e12 else None


class _Ground(Effect):
    """What every ground contact has: the plane, and the deepest boundary vertex below it."""

    name = "contact"
    # whether the rule reads the iterate a global solution came from (then a warm start would change it)
    reads_iterates = False
    # why a run's last state is checked as a new start: the assignment that made this contact (see follow)
    replaced_for = None
    _end = None  # where the last step ended (the Coulomb model keeps it)

    def _plane(self, space, ground, up, thin=False):
        """The plane, and each vertex's part and lengths (``thin``: a thin part's allowance is of its thickness)."""
        self.dim, self.up, self.ground = space.dim, up, float(ground)
        boundary = boundary_vertices(space.mesh)
        self.boundary = space.heights(boundary, up)
        self.parts = connected_labels(space.mesh)  # (n,): the connected part each vertex is in
        self.sizes = part_sizes(space.mesh, self.parts)  # (n,): what each vertex's depth is relative to
        self.boundary_sizes = self.sizes[boundary]
        self.boundary_parts = self.parts[boundary]
        # the boundary vertices body by body (for each body's deepest: one gather and one reduceat)
        self._by_part = np.argsort(self.boundary_parts, kind="stable")
        self._part_starts = np.flatnonzero(np.r_[True, np.diff(self.boundary_parts[self._by_part]) != 0])
        # (n,): what the depth a vertex is allowed (or let sink, by the reference) is a share of
        self.lengths = allowance_lengths(space.mesh, self.parts) if thin else self.sizes
        self.boundary_lengths = self.lengths[boundary]

    def depths(self, z) -> np.ndarray:
        """How deep each boundary vertex is below the ground (negative above it), for a state ``z``, shape (nb,).

        ``boundary_sizes`` (nb,) has the size of each one's own part (:func:`~skfem_modal.mesh.part_sizes`).
        """
        return self.ground - self.boundary(np.asarray(z, float))

    def deepest_of_each_body(self, depths) -> np.ndarray:
        """Each body's (connected part's) deepest boundary vertex, given :meth:`depths` (nb,) or (nb, T): (bodies,)
        or (bodies, T)."""
        if self._part_starts.size == 1:
            return np.max(depths, axis=0, keepdims=True)
        return np.maximum.reduceat(depths[self._by_part], self._part_starts)

    def penetration(self, z, relative: bool = False) -> float:
        """How deep the lowest boundary vertex is below the ground (0 when none is), for a state ``z``.

        ``relative``: the deepest relative to the size of the vertex's own part.
        """
        depth = self.depths(z)
        if relative:
            depth /= self.boundary_sizes
        return max(0.0, float(depth.max()))

    def missed(self, z) -> bool:
        """Whether the step's iterations should run again, seeing more vertices (see the Coulomb model)."""
        return False

    def forget(self) -> None:
        """Forget what earlier steps leave for the next (nothing, here: see the Coulomb model)."""

    def follow(self, earlier, setting: str) -> None:
        """Take over a run from ``earlier``, the contact this one replaces since ``setting`` was assigned.

        A run goes on from where the last step ended (as with ``earlier``) under the same model and
        ground plane; under another model, that state is a new run's start, checked as one, and the
        refusal says why (another up axis or height: checked as one too).
        """
        if type(earlier) is type(self) and (earlier.up, earlier.ground) == (self.up, self.ground):
            self._end = earlier._end
        elif type(earlier) is not type(self):
            self.replaced_for = (
                f"assigning {setting} made a contact of another model, which goes on from no earlier step: a run "
                "under the other model left the body this deep"
            )
        elif earlier._end is not None:
            self.replaced_for = GROUND_DURING_A_RUN.format(setting=setting)

    def finish_step(self, z) -> None:
        """The end of a step's iterations, ``z`` (r,) the result: nothing to do (see the Coulomb model)."""


class _LayoutCache(OrderedDict):
    """The reference contact's corrections for one layout (None: a plain z), by active set, the latest used last."""

    def __init__(self, layout):
        super().__init__()
        self.layout = layout
        # where z and the heights sit in the state, in the order of the contact's pushes
        self.columns = None if layout is None else np.concatenate([layout.z_index, layout.watched_index])

    def made(self, contact, mask):
        """The correction of the active set ``mask`` (not yet cached), as :meth:`ReferenceContact._apply` takes it."""
        layout = self.layout
        if layout is None:
            return contact._projection(mask)
        rows = contact._point_rows[mask].ravel()
        read, write_t = np.zeros((rows.size, layout.size)), np.zeros((rows.size, layout.size))
        read[:, layout.z_index] = contact._position_rows(rows)
        write_t[:, self.columns] = contact._pushes(rows)
        return [rows.size // contact.dim, rows, read, write_t, None]


class ReferenceContact(_Ground):
    """Ground contact at a set of vertices, projecting each global solution.

    Parameters
    ----------
    space : Subspace or FullSpace
    vertices : ndarray of int
        The contact vertices.
    ground : float
        Height of the plane along ``up``.
    up : int
        Index of the up axis.
    stickiness : float
        In [0, 1]: fraction of the tangential velocity removed on contact.
    push_out : float
        In [0, 1]: fraction of a penetration removed per step (0: none, as the
        reference implementation).

    Attributes
    ----------
    active_count : int
        Contact points active in the last projection.
    """

    model = "reference"
    reads_iterates = True  # a point is active when below the ground at the current iterate

    def __init__(self, space, vertices, ground, up, stickiness=1.0, push_out=0.0):
        self.vertices = vertices
        self._plane(space, ground, up)
        self.stickiness = float(stickiness)
        self.push_out = float(push_out)
        Je = space.rows(space.dofs(vertices))
        self.Je = Je.tocsr() if sps.issparse(Je) else Je
        self.Je_up = self.Je[up :: self.dim]  # the heights: all a projection reads when nothing touches
        self._dot = (lambda A, x: A @ x) if sps.issparse(Je) else dot
        #: the rows a projection reads, ``watch @ z`` (a backend may compute them in its own products)
        self.watch = self.Je_up
        self.n_points = vertices.size
        self.active_count = 0
        self._mask = np.empty(vertices.size, bool)  # the active points, made in place
        self._point_rows = np.arange(vertices.size * self.dim).reshape(-1, self.dim)  # each point's position rows

    def bind(self, system, h, gravity=None) -> None:
        """Take the factored ``system`` (:meth:`~skfem_modal.space.Subspace.factor`) of time step ``h``.

        A new one clears the cached corrections; ``gravity`` is unused (the reference contact has no climb rule).
        """
        JeT = self.Je.T.toarray() if sps.issparse(self.Je) else self.Je.T
        self.HinvJeT = system.solve(JeT)  # (r, p dim): H^-1 Je^T
        self.E = self.HinvJeT.T  # Je H^-1: sensitivity of contact positions to the force
        # per point row, made once (a new active set then costs products of the points' size, not the
        # subspace's): E E^T, whose rows and columns of a set are its L L^T; and, negated, H^-1 E^T (the
        # change of z a unit correction of the row makes) followed by that change's heights
        self._gram = self.E @ self.E.T  # (p dim, p dim)
        pull = system.solve(np.ascontiguousarray(self.HinvJeT))  # (r, p dim): H^-1 E^T
        self._push_t = -np.hstack([pull.T, np.asarray(self.Je_up @ pull).T])  # (p dim, r + p)
        self.solve, self.h = system.solve, float(h)
        # per position row, what its correction is scaled by: the normal velocity removed, the tangential scaled
        self._row_factor = np.full(self._point_rows.size, self.stickiness)
        self._row_factor[self.up :: self.dim] = 1.0
        # per layout (None: a plain z), the corrections of the active sets met, the latest used last
        self._caches: dict = {}

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_caches"] = {}
        state.pop("_dot", None)
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._dot = (lambda A, x: A @ x) if sps.issparse(self.Je) else dot

    def positions(self, z) -> np.ndarray:
        """Contact point positions of a state ``z`` (r,), shape (p, dim)."""
        return (self.Je @ checked_state(z, self.Je.shape[1])).reshape(-1, self.dim)

    def start_step(self, z_start, z_dot=None, again=False) -> None:
        """Remember the contact positions at the step's start ``z_start`` (r,); ``again``: the same step once more.

        ``z_dot`` (the start velocity) is unused: the reference's rule reads positions only.
        """
        self.p_start = self.Je @ z_start
        up_start = self.p_start[self.up :: self.dim]
        if self.push_out:
            depth = np.maximum(self.ground - up_start, 0.0)
            # the lowest end height allowed: the ground, or on the way out of it
            self.target = np.where(depth > 0, up_start + self.push_out * depth, self.ground)
            self.limit = self.target
            # the positions the corrections aim at: the start, lifted out of the ground
            self.p_target = self.p_start.copy()
            self.p_target[self.up :: self.dim] += self.target - up_start
        else:
            # reference rule: a point below ground may not move further down
            self.limit = up_start
            self.p_target = self.p_start
            self.below = up_start < self.ground  # at the current iterate
            self.n_below = np.count_nonzero(self.below)
            self._ground = np.array(self.ground)  # (numpy compares with an array faster than with a float)

    def project(self, z, watched=None, layout=None) -> bool:
        """Project the active contacts of a global solution, in place; True if it changed.

        Parameters
        ----------
        z : ndarray, shape (r,), or (layout.size,) with a layout
            Corrected in place.
        watched : ndarray, shape (p,), optional
            ``watch @ z`` (the contact heights) if the caller has it; corrected along with ``z``.
        layout : StateLayout, optional
            ``z`` is a backend's state vector holding z and ``watched`` (a view into it) where
            ``layout`` says: corrected in place, with corrections made once for the layout.

        Returns
        -------
        bool
            Whether a contact point was active (``z`` changed).
        """
        heights = self._dot(self.Je_up, z) if watched is None else watched
        if self.push_out:
            return self._project_positions(z, heights, layout)
        # active: below the plane at the current iterate and moving into it
        self.active_count = 0
        if self.n_below:
            mask = np.less(heights, self.limit, self._mask)
            mask &= self.below
            if np.count_nonzero(mask):
                self._apply(z, heights, mask, layout)
        self.n_below = np.count_nonzero(np.less(heights, self._ground, self.below))
        return self.active_count > 0

    def _correction(self, mask: np.ndarray, layout):
        """An active set's correction, cached per layout and set: the points' count, and what :meth:`_apply` takes.

        Plain: ``(count, rows, Je_rows, dz, dheights)`` (:meth:`_projection`). With a layout whose state
        holds a 1, ``[count, rows, read, write_t, targets]``: ``read @ state`` is the rows' positions less
        their targets (``targets``, the targets' array its column of the 1 was last written from), and
        ``(read @ state) @ write_t`` the state's correction.
        """
        cache = self._caches.get(layout)
        if cache is None:
            if len(self._caches) >= _LAYOUTS:  # a rebuilt backend's layout replaces its old one's: the oldest go
                del self._caches[next(iter(self._caches))]
            cache = self._caches[layout] = _LayoutCache(layout)
        key = mask.tobytes()
        entry = cache.get(key)
        if entry is not None:
            cache.move_to_end(key)
            return entry
        entry = cache.made(self, mask)
        cache[key] = entry
        if len(cache) > _CACHE_SIZE:
            cache.popitem(last=False)
        return entry

    def _projection(self, mask: np.ndarray):
        """The active points' count, their position rows, and the corrections of ``z`` and its heights per unit."""
        rows = self._point_rows[mask].ravel()
        pushes = self._pushes(rows)
        r = self.E.shape[1]
        dz, dheights = np.ascontiguousarray(-pushes[:, :r].T), np.ascontiguousarray(-pushes[:, r:].T)
        return rows.size // self.dim, rows, self._position_rows(rows), dz, dheights

    def _pushes(self, rows) -> np.ndarray:
        """The changes of z, then of the heights, per unit of each row's position above its target, (k, r + p).

        The tangential rows' scaled by the stickiness. One place for the rules: the position rule
        (``push_out``), the reference's exact least change, and its least squares when that is not well posed.
        """
        r = self.E.shape[1]
        if self.push_out:
            # position rule: the least change of z in the energy norm of the
            # global step (contact forces at the points), z += H^-1 Je^T lam
            # with (Je H^-1 Je^T + eps I) lam = residual. The small eps keeps
            # it well posed when the points ask more than the subspace can do
            # (then it is a least-squares compromise instead of a blow-up).
            S = np.asarray(self.Je[rows] @ self.HinvJeT[:, rows])
            eps = 1e-9 * np.trace(S) / rows.size
            dz = self.HinvJeT[:, rows] @ np.linalg.solve(S + eps * np.eye(rows.size), np.eye(rows.size))
        elif rows.size < r and (X := _gram_inverse(self._gram_rows(rows))) is not None:
            # reference: the least change of force that meets every constraint exactly,
            # H^-1 L^T (L L^T)^-1 (and its heights) from the rows made once
            pushes = X @ self._push_t.take(rows, 0)
            return pushes if self.stickiness == 1.0 else pushes * self._row_factor[rows, None]
        else:
            # reference, more constraints than coordinates: least squares
            dz = self.solve(np.linalg.lstsq(self.E[rows], np.eye(rows.size), rcond=None)[0])
        pushes = -np.vstack([dz, np.asarray(self.Je_up @ dz)]).T
        return pushes * self._row_factor[rows, None]

    def _position_rows(self, rows) -> np.ndarray:
        """``Je``'s rows ``rows``, dense (p_rows, r)."""
        Je_rows = self.Je[rows]
        return Je_rows.toarray() if sps.issparse(Je_rows) else np.ascontiguousarray(Je_rows)

    def _gram_rows(self, rows) -> np.ndarray:
        """``L L^T`` of the position rows ``rows``, from the Gram matrix of all of them made once."""
        return self._gram.take(rows, 0).take(rows, 1)

    def _apply(self, z, heights, mask, layout) -> None:
        """Correct ``z`` (or a layout's state) and its contact heights in place for an active set."""
        entry = self._correction(mask, layout)
        self.active_count = entry[0]
        if layout is None:
            _, rows, Je_rows, dz, dheights = entry
            delta = self.p_target[rows] - dot(Je_rows, z)
            z += dot(dz, delta)
            heights += dot(dheights, delta)
            return
        _, rows, read, write_t, targets = entry
        if targets is not self.p_target:  # a new step's targets, read through the state's 1
            read[:, layout.one_index] = -self.p_target[rows]
            entry[4] = self.p_target
        z += dot(dot(read, z), write_t)

    def _project_positions(self, z, heights, layout) -> bool:
        """Position rule: no contact point ends below its target height."""
        tol = 1e-12 * max(1.0, abs(self.ground))
        mask = heights < self.target - tol
        if not np.count_nonzero(mask):
            self.active_count = 0
            return False
        z_tent, heights_tent = z.copy(), heights.copy()
        for _ in range(4):
            np.copyto(z, z_tent)
            np.copyto(heights, heights_tent)
            self._apply(z, heights, mask, layout)
            # a correction moves other points too: add any now below target
            violated = heights < self.target - tol
            if not (violated & ~mask).any():
                break
            mask = mask | violated
        return True


class CoulombContact(_Ground):
    """Every boundary vertex kept above the ground, with Coulomb friction.

    Each global solution ``z_t`` is projected, in the energy norm of the
    global step, onto the states the ground allows: ``z = z_t + H^-1 F^T m``,
    the smallest change that leaves no candidate vertex below the ground
    (``m >= 0`` the normal forces, zero where a vertex is not pushed). With
    ``friction = mu > 0`` a pushed vertex *sticks*, keeping its place along
    the ground over the step (its tangent rows become equalities too), while
    the tangential force that takes is at most ``mu`` times its normal force;
    otherwise it *slides*, and its force ``F`` leans back by ``mu`` against
    the way it slides, so that the friction is exactly ``mu`` times the
    normal force found in the same solve. Who is pushed, sticks or slides is
    updated after each projection (the local/global iterations settle it
    with the rotations). Each step begins with every pushed vertex sticking;
    one whose sticking takes more than friction gives slides, its friction
    the way that force points: against the motion the vertex would have over
    the step without friction (the return mapping of implicit Coulomb
    friction), so a sliding body that friction can stop sticks in the step
    it stops. (Sliding on in the way a vertex slid over the step before, a
    step late, a 3D block on a 20 degree incline with ``mu = 1.05 tan 20``
    slid at 0.071 m/s for ever: the vertices' sideways motion turned their
    friction, which turned the motion back the next step, and the friction's
    share downhill settled where it only balanced gravity.) With many
    vertices pushing each other through the body, a slide's friction so fixed
    need not point against its motion: the step's last projection is made
    again by an exact solve of Coulomb's conditions (:func:`coulomb_forces`,
    a semismooth Newton method started from the sets' forces), which is also
    what an active set going round in circles ends in.

    The vertices pushed are found by a primal-dual active set, warm-started
    from the last projection; a pass is one small solve over the pushed rows
    (its operator kept while the sets repeat). A compliance of a thousandth
    of a row's own compliance (``e H^-1 e``, on average over the vertex's
    part of the mesh) keeps that solve well posed when
    rows depend on each other (many vertices on a flat face, more than a
    subspace can tell apart): their pushes spread over them as the smallest
    forces do, and the ground gives way by about a thousandth of a step's
    correction.

    A step looks at a few dozen vertices at most: those near the ground at
    the start of the step or in its first global solution (within half a
    percent of the body's size, or moving towards it fast enough), spread
    over the body, the lowest of each patch, the touching ones first. A run
    that goes on from where the last step ended keeps them for up to ten
    steps (and with them the small solves' operators), until a step's end
    finds a vertex below that they missed. At the end of the step every
    candidate is checked: if any they missed ended more than ``allowance`` of
    the body's size below the ground, the step's iterations run again looking
    at a spread few of those too (and once more if that run missed others);
    what is still below after that is held up with the others. So no vertex
    ends a step in the ground by more than about ``allowance`` of the size
    (between the vertices held, a subspace cannot keep every vertex of a flat
    face exactly on the plane).

    Parameters
    ----------
    space : Subspace or FullSpace
    vertices : ndarray of int
        The candidates (every boundary vertex, unless chosen).
    ground : float
        Height of the plane along ``up``.
    up : int
    friction : float
        The Coulomb coefficient ``mu >= 0`` (0: frictionless).
    allowance : float
        How far below the ground a vertex may end a step, a share of its part's
        size (or of :data:`THIN` times its thickness, if less: :func:`allowance_lengths`),
        in [:data:`LEAST_ALLOWANCE`, :data:`MOST_ALLOWANCE`] (default :data:`ALLOWANCE`). A larger
        one is cheaper: fewer steps find a vertex their iterations missed and run
        them again (``benchmarks/bench_contact.py``'s last table).
    exact_friction : bool
        Whether the step's last projection is made again with exact Coulomb
        friction where a slide's friction is not straight against its motion
        (default True). False keeps the active set's friction: within Coulomb's
        cone and of its size, but fixed as each vertex starts to slide (on the
        creature's crawl 4.4 degrees off the slide by the median, 88 at most),
        for a step with friction 0.5 about 40 % cheaper on the seal.

    Attributes
    ----------
    active_count : int
        Vertices the ground pushed in the last projection.
    """

    model = "coulomb"
    exact_friction = True  # (a contact pickled before the setting was there had it)
    watch = None  # the candidates change from step to step: nothing a backend could compute ahead

    def __init__(self, space, vertices, ground, up, friction=0.5, allowance=ALLOWANCE, exact_friction=True):
        self._plane(space, ground, up, thin=True)
        self.space, self.vertices = space, np.asarray(vertices)
        self.friction = float(friction)
        self.exact_friction = bool(exact_friction)
        self.relative_allowance = checked_allowance(allowance)
        self.heights_of = space.heights(self.vertices, up)
        # each candidate's lengths relative to its own part: bodies far apart in one mesh are each held
        # as close to the ground as one alone (relative to the whole mesh, a part 60 sizes away let
        # a body sink 30 times the allowance)
        self.size = self.sizes[self.vertices]  # (p,)
        self.part = self.parts[self.vertices]  # (p,)
        self.tol = 1e-9 * float(self.size.min())
        self.allowance = self.relative_allowance * self.lengths[self.vertices]
        # per candidate, made once (the ground of a contact does not move): the lowest height a step may
        # leave it at, and below which it counts as near the ground
        self._lowest = self.ground - self.allowance
        self._near_level = self.ground + 0.005 * self.size
        self.tangents = np.array([a for a in range(self.dim) if a != up], dtype=np.int64)
        p = self.vertices.size
        # (dim, p): where the picking spreads; a coordinate a row (reductions along rows are
        # twenty times faster than down the columns of a (p, dim) array)
        self.rest = np.ascontiguousarray(space.mesh.p[:, self.vertices])
        # per vertex, kept from step to step: pushed, sliding, the way friction pushes
        self.touching = np.zeros(p, bool)
        self.sliding = np.zeros(p, bool)
        self.direction = np.zeros((p, self.dim))
        self.picked = np.zeros(0, np.int64)
        self._missed = np.zeros(0, np.int64)  # missed by a step's first run, looked at in its second
        self._last = None  # the sets of the last projection, tried first by the next
        self._sources = []  # what the step's projections by sets started from and gave (_polish)
        self._made_for = np.zeros(0, np.int64)  # the picked vertices the operators are for
        self._first = False
        self._retest = False
        self._checked = None  # a state at the end of a step and its candidates' heights
        self._saved = None  # the state a step starts from (a backend refusing it has it redone from there)
        self._end = None  # where the last step ended
        self._previous = np.zeros(0, np.int64)  # the last step's picked vertices
        self._keep = 0  # steps that may keep them before the vertices are picked anew
        self.active_count = 0

    def bind(self, system, h, gravity=None) -> None:
        """Take the factored ``system`` (:meth:`~skfem_modal.space.Subspace.factor`) of time step ``h``.

        A new one clears the pushes made so far.

        ``gravity`` (dim,), or None: how far a vertex below the ground may climb in a step.
        """
        self.system, self.h = system, float(h)
        self.climb = 0.0 if gravity is None else max(0.0, -float(gravity[self.up])) * self.h**2
        self.picked = np.zeros(0, np.int64)
        self._keep = 0
        # each candidate row's push on z, H^-1 B_row^T, made when first needed: memory
        # O(candidates x subspace) at most, and only for the vertices that ever touch
        self._pushes = np.zeros((self.vertices.size * self.dim, self.space.r))
        self._made = np.zeros(self.vertices.size * self.dim, bool)
        self._operators, self._last, self._made_for = {}, None, np.zeros(0, np.int64)
        self.compliance = np.repeat(self._part_compliances(), self.dim)  # (p dim,): each candidate row's
        # a give that needs no second solve
        self._quiet = (0.1 * float(self.allowance.min())) ** 2
        self._refine = 0  # solves that take the give back: at the end of a step only

    def _part_compliances(self) -> np.ndarray:
        """Each candidate's compliance, (p,): a thousandth of its part's height rows' own, ``e H^-1 e``, on average.

        Per part: a light part's rows move far more per unit force than a heavy one's, and a
        thousandth of the mean over a mesh holding a seal and its copy a fiftieth the size let the
        seal's ground give 60 times its own rows' reach (the seal sank 30 % of its size in a step).
        """
        groups = [np.flatnonzero(self.part == q) for q in np.unique(self.part)]
        samples = [group[:: max(1, group.size // 64)] for group in groups]
        rows = self._rows_of(np.concatenate(samples) * self.dim + self.up)
        # not kept as pushes: those are each made alone (_push_of)
        reach = np.einsum("ij,ji->i", rows, np.asarray(self.system.solve(np.ascontiguousarray(rows.T))))
        compliances = np.empty(self.vertices.size)
        for group, part_reach in zip(groups, np.split(reach, np.cumsum([x.size for x in samples])[:-1])):
            compliances[group] = 1e-3 * float(part_reach.mean())
        return compliances

    def _rows_of(self, candidate_rows) -> np.ndarray:
        """Rows of ``B`` for candidate rows (vertex ``k``'s coordinate ``a`` is row ``k dim + a``), dense."""
        dofs = self.vertices[candidate_rows // self.dim] * self.dim + candidate_rows % self.dim
        rows = self.space.rows(dofs)
        return rows.toarray() if sps.issparse(rows) else rows

    def _push_of(self, candidate_rows) -> np.ndarray:
        """``H^-1 B_row^T`` of candidate rows, shape (k, r), each made once.

        A vertex's rows are solved together and alone: a solve of several columns rounds each by
        the others (BLAS blocks them), so a push made in a batch differed in the last digits with
        whatever else was missing then, and a run with its history (a fresh simulator, one
        unpickled, one run before) differed in the 13th digit of a search's travel.
        """
        dim = self.dim
        for vertex in np.unique(candidate_rows[~self._made[candidate_rows]] // dim):
            rows = np.arange(vertex * dim, (vertex + 1) * dim)
            made = self.system.solve(np.ascontiguousarray(self._rows_of(rows).T))
            self._pushes[rows] = np.asarray(made).T
            self._made[rows] = True
        return self._pushes[candidate_rows]

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_saved"] = None  # a step's start: a new step takes its own
        if "_pushes" in state:  # made again where needed
            state["_pushes"] = np.zeros_like(self._pushes)
            state["_made"] = np.zeros_like(self._made)
            state["_operators"] = {}
            state["_last"] = None
            state["_made_for"] = np.zeros(0, np.int64)
        state["_sources"] = []
        return state

    def positions(self, z) -> np.ndarray:
        """Positions of the candidate vertices in a state ``z`` (r,), shape (p, dim)."""
        return self.space.positions(checked_state(z, self.space.r))[self.vertices]

    # ------------------------------------------------------------ a step
    def start_step(self, z_start, z_dot=None, again=False) -> None:
        """Remember where the step starts; the step's first global solution picks the vertices.

        ``z_start``, ``z_dot`` (r,, or None): the start state and velocity (the velocity says which vertices
        move towards the ground fast). ``again``: the same step run again by another backend (the first
        refused it): from what the step started with, not from what the refused run left (who touched, slid,
        which way).

        Raises
        ------
        ValueError
            If a run starts (``z_start`` is not where the last step ended) with a vertex deeper
            below the ground than the allowance: the contact would fling the body out.
        """
        continuing = self._end is not None and not np.not_equal(self._end, z_start).any()
        if not (again or continuing):
            self._check_clear(z_start)
        if again:
            saved, arrays = self._saved
            self.__dict__.update(saved)
            for name, values in arrays.items():
                np.copyto(getattr(self, name), values)
        else:
            # the arrays change in place (copied into buffers of their own); the rest is replaced,
            # not changed (caches aside)
            if self._saved is None:
                self._saved = ({}, {name: getattr(self, name).copy() for name in _PER_VERTEX})
            saved, arrays = self._saved
            for name, values in arrays.items():
                np.copyto(values, getattr(self, name))
            saved.clear()
            saved.update(self.__dict__)
            del saved["_saved"]
        self.z_start, self.z_dot = z_start, z_dot
        self._previous = self.picked
        if not continuing:
            self._keep = 0  # not where the last step ended: a run of its own, whose vertices are picked anew
        self.picked = np.zeros(0, np.int64)
        self._first = True
        self._sources = []
        # the sliding vertices are tested against sticking again in the step's first projection (_constrain)
        self._retest = bool(self.friction) and bool(np.count_nonzero(self.sliding))

    def _check_clear(self, z) -> None:
        """Raise if a state has a vertex deeper below the ground than the allowance (see :meth:`start_step`)."""
        depths = self.ground - self.heights_of(z)
        deepest = int(np.argmax(depths / self.allowance))
        depth = float(depths[deepest])
        if depth > self.allowance[deepest]:
            share = 100 * depth / self.size[deepest]
            of = f" of {THIN_WORDS}" if thin(self.lengths[self.vertices[deepest]], self.size[deepest]) else ""
            raise ValueError(
                f"the state starts inside the ground: a boundary vertex is {depth:.4g} ({share:.3g} % "
                f"of the body's size) below the ground at {self.ground:.6g}, more than the contact's allowance "
                f"({100 * self.relative_allowance:.3g} %{of}); it would fling the body out. Start from a state above "
                "the ground (sim.rest_state() is), or go on from where the last step ended"
                + (f" ({self.replaced_for})" if self.replaced_for else "")
            )

    def _near(self, z) -> np.ndarray:
        """The vertices near the ground (indices into the candidates), spread; ``z`` the step's first global solution.

        It says where the body is going (gravity, muscles, momentum): the vertices near the ground
        there or at the start (or coming towards it fast) are taken.
        """
        states = [z, self.z_start] + ([self.z_dot] if self.z_dot is not None else [])
        heights = self.heights_of(np.stack(states, axis=1)).T  # one pass over the rows for all
        low = heights[1].copy()
        if self.z_dot is not None:
            low += 2.0 * self.h * np.minimum(heights[2], 0.0)
        np.minimum(low, heights[0], out=low)
        near = np.flatnonzero((low < self._near_level) | self.touching)
        return self._spread(near, low)

    def _spread(self, near, low) -> np.ndarray:
        """At most a few dozen of the ``near`` candidates, spread over each body (:func:`spread_few`)."""
        return spread_few(near, low, self.rest, self.part, self.touching, self.ground, self.size)

    def _pick(self, picked, z_start, start=None) -> None:
        """Make ``picked`` (indices into the candidates) the vertices the projections look at.

        ``start`` gives the first ones' start-of-step positions when they are known (the others
        start where ``z_start`` has them).
        """
        # (the vertices kept from the last step are the very array the operators were made for)
        same = picked.size and (picked is self._made_for or np.array_equal(picked, self._made_for))
        self.picked = picked
        if not picked.size:
            return
        dim = self.dim
        if not same:  # the operators index the picked vertices: made again for others
            self._operators, self._last, self._made_for = {}, None, picked
            rows = self.space.rows(self.space.dofs(self.vertices[picked]))
            self.J = rows.tocsr() if sps.issparse(rows) else rows
            candidate_rows = (picked[:, None] * dim + np.arange(dim)).ravel()  # picked order
            self.sets = Picked(self.J, self._push_of(candidate_rows), dim, self.up, self.compliance[candidate_rows])
        self.start = self.sets.positions(z_start).reshape(-1, dim)
        if start is not None:
            self.start[: start.shape[0]] = start
        self.target = self.start.ravel().copy()
        # a vertex that starts the step a little below the ground (within the allowance, less a
        # margin: left there by an earlier step's end) climbs out by at most what gravity moves
        # a body in a step: lifted onto the ground at once, a tiny step would kick it up, adding
        # energy; a deeper one (the end of a step holding one that sagged) comes into that band
        band = self.ground - 0.9 * self.allowance[picked]
        heights = self.start[:, self.up] + self.climb
        self.target[self.up :: dim] = np.minimum(np.maximum(heights, band, out=heights), self.ground, out=heights)
        self.floor = self.target[self.up :: dim] - self.tol  # a vertex below it joins the pushed ones
        self.sets.aim(self.start.ravel(), self.target, self.floor)

    def project(self, z, watched=None) -> bool:
        """Project a global solution ``z`` (r,) in place; True if it changed.

        ``watched`` is unused (nothing is watched: :attr:`watch` is None); it is the backend interface's.
        """
        if self._first:
            self._first = False
            if self._keep > 0 and self._previous.size and not self._missed.size:
                # the last step's vertices again: their operators are kept (the end of the step
                # checks every candidate; one found below has the vertices picked anew)
                self._keep -= 1
                self._pick(self._previous, self.z_start)
            else:
                # a step run again for vertices it missed keeps those its first run held: holding the
                # missed ones with a fresh spread few instead (a thin plate resting on 45 vertices
                # looked at 33 in its second run) left the end of the step to hold the rest, a kick
                again = self._previous[self.touching[self._previous]] if self._missed.size else self._missed
                self._pick(np.union1d(np.union1d(self._near(z), self._missed), again), self.z_start)
                self._keep = _KEEP
        if not self.picked.size:
            self.active_count = 0
            return False
        return self._constrain(z)

    def forget(self) -> None:
        """Forget who touched, slid and how hard: the next step starts as a first one."""
        self.touching[:] = False
        self.sliding[:] = False
        self.direction[:] = 0.0
        self._operators, self._last, self._made_for = {}, None, np.zeros(0, np.int64)
        self.picked = np.zeros(0, np.int64)
        self._previous = np.zeros(0, np.int64)
        self._keep = 0
        self._missed = np.zeros(0, np.int64)

    def missed(self, z) -> bool:
        """Whether the step's iterations missed a vertex that ended below the allowance (``z`` the result).

        Holding it up only at the end would kick the body (moved by ``d`` at the end of a step, it
        gets the velocity ``d / h``: a 3D beam settling flat gained 0.82 % of its fall's energy in
        one step): the driver runs the step's iterations again, with a spread few of the missed
        ones among the vertices looked at (those still below at the end are held up there).
        """
        heights = self.heights_of.above(z, self._lowest)  # in double precision near the lowest allowed
        self._checked = (z.copy(), heights)  # the end of the step needs them too
        below = self._unpicked(np.flatnonzero(heights < self._lowest))
        self._missed = self._spread(below, heights)  # a flat face's sag: a spread few hold it all
        return bool(self._missed.size)

    def _unpicked(self, vertices) -> np.ndarray:
        """Those of ``vertices`` (indices into the candidates) the projections did not look at."""
        if not vertices.size:
            return vertices
        picked = np.zeros(self.vertices.size, bool)  # a mask: np.isin sorts both
        picked[self.picked] = True
        return vertices[~picked[vertices]]

    def finish_step(self, z) -> None:
        """Hold up every candidate the step left below the ground (``z`` (r,) the result, in place).

        The spread few the iterations looked at hold most of a patch up; a vertex between them
        that sagged below joins them here (its start: where it is), and the projection is
        repeated until no candidate is below. The next step looks at it from the start.
        """
        self._missed = np.zeros(0, np.int64)
        checked, self._checked = self._checked, None
        for _ in range(_FINISH):
            same = checked is not None and np.array_equal(checked[0], z)
            heights = checked[1] if same else self.heights_of.above(z, self._lowest)
            checked = None
            below = np.flatnonzero(heights < self._lowest)
            if not below.size:
                if self._polish(z):  # the step's last projection, by sets: with exact friction (checked again)
                    continue
                self._end = z.copy()
                return
            missed = self._unpicked(below)
            if missed.size:
                start = self.start if self.picked.size else np.zeros((0, self.dim))
                self._pick(np.concatenate([self.picked, missed]), z, start)
                self._keep = 0  # the vertices are picked anew next step
            # (a picked one below: the compliance let it give, at a large step, or the last
            # projection's fallback, a least-distance solve over the rows it saw, left it there)
            self._refine = _REFINE
            try:
                self._constrain(z)
            finally:
                self._refine = 0
        raise SimulationError(f"ground contact: {below.size} vertices stay below the ground after {_FINISH} tries")

    # ---------------------------------------------------------- the solve
    def _constrain(self, z) -> bool:
        """The pushed, sticking and sliding vertices by an active set, warm-started; z (r,) in place."""
        picked, mu = self.picked, self.friction
        # the exact projection (no slack: a vertex let a little below, then pushed out in a later
        # step, would be kicked; each global step then lowers the step's energy); a vertex joins
        # below its own target height (the ground, or where it starts a little below it)
        retest, self._retest = self._retest, False
        last, self._last = (None if retest else self._last), None
        x_t = self.sets.positions(z)
        if last is not None:
            # the local/global iterations change the solution less and less, and so seldom who is
            # pushed, who sticks or slides and which way: the last sets are tried first
            found = last.evaluate(self.sets, x_t, self._refine, self._quiet)
            if last.holds(*found, self.tol):
                self._accept(last, z, found[0])
                return True
        active = self.touching[picked]  # (a copy: fancy indexing)
        if not np.count_nonzero(active):
            depth = x_t[self.up :: self.dim] - self.floor
            if not np.count_nonzero(depth < 0.0):
                self._release()
                return False
            active[self._deepest(depth)] = True
            last = None
        # a step begins with every pushed vertex sticking: one that slid on would push the way it
        # slid in the step before, a step late (the class docstring); one that sticking takes
        # more than friction gives slides the way that force points, against the motion it would
        # have without friction (implicit Coulomb friction's return mapping)
        sliding = active & self.sliding[picked] if not retest else np.zeros_like(active)
        direction = self.direction[picked]
        seen = set()
        for attempt in range(_PASSES):
            stick = active & ~sliding if mu else np.zeros_like(active)
            if last is not None:  # the last sets' solve, refused above: the first pass
                op, last = last, None
            else:
                op = self._operator(active, stick, sliding, direction)
                found = op.evaluate(self.sets, x_t, self._refine, self._quiet)
            normal, ways, release, below, slips, stops, depth = op.diagnose(*found, picked.size, self.tol)
            n_below = np.count_nonzero(below)
            if not (np.count_nonzero(release) or n_below) and not (
                mu and (np.count_nonzero(slips) or np.count_nonzero(stops))
            ):
                self._update_state(active, sliding, direction)
                self._accept(op, z, found[0])  # the next projection tries the same sets first
                return True
            if attempt == _PASSES - 1:
                break
            key = active.tobytes() + sliding.tobytes() + direction[sliding].tobytes()
            friction_changes = bool(mu)
            if attempt < _PASSES // 2 and key not in seen:
                seen.add(key)
                # release every vertex the ground pulls, hold the deepest few below: the rows of
                # neighbouring vertices nearly repeat each other, so a few stand for a whole patch
                active = active & ~release
                if n_below:
                    active[self._deepest(depth)] = True
            elif n_below:
                # going round in circles: one change at a time, the deepest vertex first
                active = active | (below & (depth <= depth[below].min()))
                friction_changes = False
            elif np.count_nonzero(release):
                active = active.copy()
                active[np.flatnonzero(release)[np.argmin(normal[release])]] = False
                sliding &= active
                friction_changes = False
            else:
                # only friction changes, and the sets repeat or half the passes are spent (it goes round: a
                # vertex slips when it sticks and slides back when it slides). Taking the slide back, as the
                # second half once did, let friction push a vertex the way it moved: a thin bowl (a half
                # ring) rocking with friction 2 gained 16.5 % of its fall in one step. The exact solve below
                # has no such choice to make
                break
            if friction_changes:
                if ways is not None:
                    direction[slips] = ways[slips]
                sliding = (sliding | slips) & ~stops
            sliding &= active
            if not np.count_nonzero(active):
                # nothing pushed after all: unless the unpushed state leaves a vertex below
                active = x_t[self.up :: self.dim] < self.floor
                sliding &= active
                if not np.count_nonzero(active):
                    self._release()
                    return False
        # going round in circles: the whole problem over the rows concerned, at once: exact Coulomb friction
        # (_exact_coulomb), or where that does not converge, friction within a pyramid inside Coulomb's cone
        # (pyramid_projection), which lifts what slides: its push up is tied to its friction
        near = active | below
        if mu and self._exact_coulomb(near, x_t, z):
            return True
        stick = near if mu else np.zeros_like(near)
        normal = pyramid_projection(self.sets, near, stick, x_t, z.copy(), z, mu, self._aims())
        self._update_state(normal > 0.0, np.zeros(picked.size, bool), direction)
        return True

    def _accept(self, op, z, lam) -> None:
        """Project ``z`` (r,) by sets that hold, in place, remembering them, where they started and what they gave."""
        # what _polish may make again: not without friction (nothing slides) nor in 2D (a slide that does not
        # turn back by more than tol moves against its friction: the sets' own test, SetOperator.holds)
        z_t = z.copy() if self.friction and self.exact_friction and self.dim == 3 else None
        op.apply(z, lam)
        self._last = op
        if z_t is not None:
            self._sources.append((op, z_t, lam, z.copy(), self._refine))

    def _polish(self, z) -> bool:
        """The step's last projection again, with exact Coulomb friction, if its sets let a vertex slide; z in place.

        The active set fixes a sliding vertex's friction as the vertex starts to slide and keeps
        it while the vertex does not move back along it; with many vertices pushing each other
        through the body, it need not point against the motion (the creature's crawl: 4.4
        degrees off at the end of a step by the median, 88 at most), and the 3D crawls went 15 %
        less far than with Coulomb's friction. Started from the sets' forces, the exact solve
        takes two to four Newton steps. Returns whether it changed ``z``.
        """
        # (the driver's iterations run in batches: the step's result may be an iterate before the last)
        sources, self._sources = self._sources, []
        source = next((each for each in reversed(sources) if np.array_equal(each[3], z)), None)
        if source is None or not source[0].slid.size:
            return False
        op, z_t, lam, _, refine = source
        dim, up, n = self.dim, self.up, op.n_pushed
        moved = (self.sets.positions(z) - self.sets.start).reshape(-1, dim)[np.ix_(op.slid, self.tangents)]
        moved /= np.maximum(np.linalg.norm(moved, axis=1), 1e-300)[:, None]
        way = self.direction[np.ix_(self.picked[op.slid], self.tangents)]
        if np.einsum("ij,ij->i", moved, way).max() <= _STRAIGHT - 1.0:  # every slide's friction against it already
            return False
        forces = np.zeros((self.picked.size, dim))
        forces[op.pushed, up] = lam[:n]
        forces[np.ix_(op.sticking, self.tangents)] = lam[n:].reshape(-1, dim - 1)
        # a slide's friction started against the way it moved (not the way the sets fixed): a Newton step less
        forces[np.ix_(op.slid, self.tangents)] = -self.friction * forces[op.slid, up, None] * moved
        near = np.zeros(self.picked.size, bool)
        near[op.pushed] = True
        polished, self._refine = z_t.copy(), refine
        try:
            if not self._exact_coulomb(near, self.sets.positions(z_t), polished, forces):
                return False
        finally:
            self._refine = 0
        np.copyto(z, polished)
        return True

    def _exact_coulomb(self, near, x_t, z, start=None) -> bool:
        """Exact Coulomb contact over the near vertices and any picked one it leaves below (:func:`coulomb_forces`).

        ``start`` (p, dim): forces on the picked vertices to start from. Returns whether it converged
        (then ``z`` (r,) is its projection, in place, and the state follows it).
        """
        sets, dim, up, tangents, p = self.sets, self.dim, self.up, self.tangents, self.picked.size
        near = near.copy()
        for _ in range(_WIDEN):
            held = np.flatnonzero(near)
            rows = (held[:, None] * dim + np.arange(dim)).ravel()
            W, free = compliance_matrix(sets, rows), x_t[rows]
            guess = None if start is None else start[held].ravel()

            def solve(goal, W=W, free=free, rows=rows, guess=guess):
                lam = coulomb_forces(W, free - goal, dim, up, self.friction, self.tol, start=guess)
                return None if lam is None else (lam, x_t + sets.reach[:, rows] @ lam)

            found = given_back(solve, rows, np.arange(held.size) * dim + up, self._aims())
            if found is None:
                return False
            lam, x = found
            below = ~near & (x[up::dim] < self.floor)
            if not np.count_nonzero(below):
                break
            near |= below
        else:
            return False
        z += lam @ sets.pushes[rows]
        forces = np.zeros((p, dim))
        forces[held] = lam.reshape(-1, dim)
        # sliding: moved along the ground, its friction on the cone (a sticking vertex moves by its give too)
        moved = (x - sets.start).reshape(p, dim)[:, tangents]
        friction = np.sqrt(np.einsum("ij,ij->i", forces[:, tangents], forces[:, tangents]))
        pushed = forces[:, up] > 0.0
        sliding = pushed & (np.sqrt(np.einsum("ij,ij->i", moved, moved)) > self.tol)
        sliding &= friction >= self.friction * forces[:, up] * (1.0 - 1e-9)
        direction = np.zeros((p, dim))
        direction[np.ix_(sliding, tangents)] = forces[np.ix_(sliding, tangents)] / friction[sliding, None]
        self._update_state(pushed, sliding, direction)
        return True

    def _deepest(self, depth) -> np.ndarray:
        """The few deepest below their floors, given every picked vertex's height over its floor (p,)."""
        return np.argsort(depth)[: min(_JOIN, np.count_nonzero(depth < 0.0))]

    def _aims(self) -> Aims:
        """Where the whole-problem solves aim the picked rows, and how far they take back the give."""
        return Aims(self.target, self._refine, 0.1 * float(self.allowance.min()))

    def _operator(self, active, stick, sliding, direction) -> SetOperator:
        """The solve for sets of pushed, sticking and sliding vertices (and the slides' ways).

        Kept: the sets repeat from one iteration to the next, and so do the ways the vertices
        slide (found once a step, as it begins: :meth:`_constrain`).
        """
        slid = sliding.nonzero()[0] if self.friction else np.zeros(0, np.int64)
        key = active.tobytes() + stick.tobytes() + slid.tobytes() + direction[slid].tobytes()
        found = self._operators.get(key)
        if found is None:
            found = SetOperator(self.sets, active, stick, sliding, direction, self.friction)
            self._operators[key] = found
            if len(self._operators) > _OPERATORS:
                self._operators.pop(next(iter(self._operators)))
        return found

    def _update_state(self, active, sliding, direction) -> None:
        """What the next projection starts from: who touches, who slides and which way."""
        picked = self.picked
        self.touching[picked] = active
        self.sliding[picked] = sliding & active
        self.direction[picked] = direction
        self.active_count = int(np.count_nonzero(active))

    def _release(self) -> None:
        self._last = None
        picked = self.picked
        self.touching[picked] = False
        self.sliding[picked] = False
        self.active_count = 0
