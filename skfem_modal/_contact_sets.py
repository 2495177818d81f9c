"""The Coulomb contact's small solves: the picked vertices, and one operator per set of them.

A step's projections look at a few dozen *picked* vertices
(:class:`~skfem_modal.contact.CoulombContact`). Everything a projection
solves is gathered from what :class:`Picked` makes once per pick: the
picked coordinates' rows ``J`` of the basis, their pushes on ``z``
(``H^-1 J^T``, as rows) and how far a unit force on each moves every picked
coordinate (``J H^-1 J^T``, the *reach*).

For given sets of pushed, sticking and sliding vertices, a
:class:`SetOperator` holds the solve: its forces, the projection they make,
and the checks that the sets hold. The active set makes several of these a
step, so one is gathered from the pick's arrays (and a small inverse)
rather than computed: a pass costs a few dozen numpy calls on a few dozen
numbers, with no product of the size of the subspace but the projection.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sps
from scipy.linalg import lapack
from scipy.optimize import nnls

from ._fast import dot

__all__ = [
    "Aims",
    "Picked",
    "SetOperator",
    "compliance_matrix",
    "coulomb_forces",
    "given_back",
    "pyramid_projection",
    "spread_few",
]

# a normal force this far below zero, relative to the largest, counts as zero (round-off)
_PULL = 1e-9
# a tangential force this much over friction times the normal force, relative, still sticks
_CONE = 1e-9
_min, _max = np.minimum.reduce, np.maximum.reduce  # without the ndarray methods' Python wrappers
# vertices a step's projections look at, at most (the end of the step checks them all)
_MOST = 32
# heights that differ by less than this fraction of the size count as level when the lowest are picked
_LEVEL = 1e-8


def spread_few(near, low, rest, part, touching, ground, size, most: int = _MOST) -> np.ndarray:
    """At most a few dozen of the ``near`` candidates of each body in the mesh, spread over it.

    Bodies apart in one mesh are each looked at as one alone (spread over their common box, a
    body had as few vertices as the gap left cells for, and sagged between them).

    Parameters
    ----------
    near : ndarray of int, shape (n,)
        Candidates to choose from (indices into the ``p`` candidates).
    low : ndarray, shape (p,)
        Each candidate's lowest height in view (the lowest of each patch is kept).
    rest : ndarray, shape (dim, p)
        The candidates' rest positions (where the picking spreads).
    part : ndarray of int, shape (p,)
        Which body of the mesh each candidate belongs to.
    touching : ndarray of bool, shape (p,)
        Candidates the ground pushes (kept first).
    ground : float
    size : ndarray, shape (p,)
        The size of each candidate's body.
    most : int
        Candidates to choose from each body, at most.

    Returns
    -------
    ndarray of int
        The chosen candidates: the touching ones first, then the lowest of each cell.

    Examples
    --------
    Ten vertices in a row, all near the ground: four cells, the lowest of each.

    >>> rest = np.vstack([np.arange(10.0), np.zeros(10)])
    >>> low = np.array([3, 1, 2, 0, 5, 4, 9, 8, 7, 6.0])
    >>> none = np.zeros(10, bool)
    >>> spread_few(np.arange(10), low, rest, np.zeros(10, int), none, 0.0, np.ones(10), most=4).tolist()
    [3, 1, 5, 9]
    """
    parts = part[near]
    if not parts.size or parts.min() == parts.max():
        return _spread_body(near, low, rest, touching, ground, size, most)
    order = np.argsort(parts, kind="stable")
    groups = np.split(near[order], np.flatnonzero(np.diff(parts[order])) + 1)
    return np.concatenate([_spread_body(group, low, rest, touching, ground, size, most) for group in groups])


def _spread_body(near, low, rest, touching, ground, size, most) -> np.ndarray:
    """:func:`spread_few` for the candidates of one body, the touching ones first.

    The heights of neighbouring vertices nearly repeat each other (a subspace moves them
    alike): a spread few hold a whole patch up, with far fewer, better separated rows to
    solve for. The near vertices' box in the rest shape is cut into about as many cells as
    there is room for, and the lowest vertex of each (by ``low``) is kept. The step's end
    checks every candidate, so none is left below.
    """
    if near.size <= most:
        return near
    held = touching[near]
    kept, others = near[held][:most], near[~held]
    room = most - kept.size
    if room <= 0 or not others.size:
        return kept
    where = np.take(rest, others, axis=1)  # (dim, n), its rows contiguous
    low_corner, high_corner = where.min(axis=1), where.max(axis=1)
    extent = high_corner - low_corner
    # a flat patch is cut along its width only (the bound nudged off a round 0.05: a creature's feet,
    # 0.1 high and 2 long, were cut in height or not by the round-off of where the scene stood)
    wide = extent > 0.0500001 * extent.max()
    side = (float(np.prod(extent[wide])) / room) ** (1.0 / np.count_nonzero(wide))
    # cells centred on the box's middle, half a cell off it: a body mirrored, or turned a quarter
    # about an axis, is cut alike, and a regular mesh's vertices keep off the cells' edges (from a
    # corner, they fell either side of an edge by the round-off of where the scene stood)
    middle = 0.5 * (low_corner + high_corner)
    cells = np.floor((where - middle[:, None]) / side + 0.5).astype(np.int64)
    cells -= cells.min(axis=1, keepdims=True)
    cell = np.ravel_multi_index(cells, cells.max(axis=1) + 1)
    # heights equal but for round-off are level: the lowest of a flat sole is the first numbered (by
    # the last digits of its height, moving the whole scene changed the pick: 1e-3 of the size a step)
    level = np.rint((low[others] - ground) / (_LEVEL * size[others]))
    order = np.lexsort((level, cell))  # by cell, the lowest first in each (then the first numbered)
    first = order[np.r_[True, cell[order][1:] != cell[order][:-1]]]
    first = first[np.lexsort((others[first], level[first]))][:room]  # the lowest cells', if too many
    return np.concatenate([kept, others[first]])


def _inverse(K) -> np.ndarray:
    """The inverse of a small square matrix (LAPACK's LU directly: numpy's inv costs twice as much here)."""
    lu, pivots, info = lapack.dgetrf(K)
    if info == 0:
        inverse, info = lapack.dgetri(lu, pivots)
    if info != 0:
        raise np.linalg.LinAlgError(f"a contact operator is singular (LAPACK info {info})")
    return inverse


class Picked:
    """The picked vertices' rows, pushes and reach, and where each starts the step.

    Parameters
    ----------
    J : ndarray or sparse matrix, shape (p dim, r)
        The picked vertices' rows of the basis, vertex-major.
    pushes : ndarray, shape (p dim, r)
        ``H^-1 J^T`` as rows: how a unit force on each row moves ``z``.
    dim, up : int
    compliance : float or ndarray, shape (p dim,)
        How far the ground gives per unit force on each row (the small solves' regularisation).

    Attributes
    ----------
    reach : ndarray, shape (p dim, p dim)
        ``J H^-1 J^T``: how far a unit force on each row moves each picked coordinate.
    up_rows : ndarray of int, shape (p,)
        Each vertex's height row; ``tangent_rows`` (p, dim - 1) its tangents'.
    start, target : ndarray, shape (p dim,)
        Set by :meth:`aim`: where each picked coordinate starts the step and where a
        pushed (heights) or sticking (tangents) one is held.
    floor : ndarray, shape (p,)
        Below it, a vertex's height needs a push.
    stamp : int
        Changes with every :meth:`aim` (the operators take their targets again).
    """

    def __init__(self, J, pushes, dim, up, compliance):
        self.J, self.pushes, self.dim, self.up = J, pushes, dim, up
        self.compliance = np.broadcast_to(np.asarray(compliance, dtype=float), (pushes.shape[0],))
        reach = J @ pushes.T
        self.reach = reach.toarray() if sps.issparse(reach) else np.asarray(reach)
        self.tangents = np.array([a for a in range(dim) if a != up], dtype=np.int64)
        p = pushes.shape[0] // dim
        self.up_rows = np.arange(p) * dim + up
        self.tangent_rows = np.arange(p)[:, None] * dim + self.tangents
        # the tangent rows' pushes and reach by vertex, side by side, (p, dim - 1, r + p dim): a
        # sliding vertex's friction leans its normal force onto them (one product for both)
        self.tangent_leans = np.concatenate([pushes[self.tangent_rows], self.reach.T[self.tangent_rows]], axis=2)
        self.stamp = 0

    def aim(self, start, target, floor) -> None:
        """The step's start positions (p dim,), targets (p dim,) and floors (p,)."""
        self.start, self.target, self.floor = start, target, floor
        self.stamp += 1

    def positions(self, z) -> np.ndarray:
        """The picked coordinates of a state ``z`` (r,), shape (p dim,)."""
        return np.asarray(self.J @ z)

    @property
    def nbytes(self) -> int:
        """Memory held by the pick's arrays (``J`` too when dense)."""
        arrays = (self.J, self.pushes, self.reach, self.tangent_leans)
        return sum(a.nbytes for a in arrays if isinstance(a, np.ndarray))


class SetOperator:
    """The solve for sets of pushed, sticking and sliding picked vertices, and its checks.

    ``(A H^-1 F^T + c I) lam = target_A - A z``: the rows ``A`` are the pushed
    vertices' heights, then the sticking ones' tangents; ``F = A`` but for the
    sliding vertices, whose normal force leans by ``friction`` the way their
    friction pushes (``direction``), so it is exactly ``friction`` times the normal
    force. ``z + pushes^T lam`` is the projection; the picked coordinates
    after it are ``x = x_t + reach lam``.

    Parameters
    ----------
    picked : Picked
    active, stick, sliding : ndarray of bool, shape (p,)
        Pushed vertices; those of them that stick, and that slide.
    direction : ndarray, shape (p, dim)
        The way friction pushes each sliding vertex (unit, tangent).
    friction : float

    Attributes
    ----------
    pushed, slid, free : ndarray of int
        The pushed vertices, the sliding ones and the vertices not pushed (indices into the picked).
    sticking : ndarray of int
        The pushed vertices that stick; ``stuck`` the same as indices into ``pushed``.
    """

    def __init__(self, picked, active, stick, sliding, direction, friction):
        self.friction, self.dim, self.tangents = friction, picked.dim, picked.tangents
        self.cone = friction * (1.0 + _CONE)  # a sticking vertex's tangential force over its normal force, at most
        self.pushed = pushed = active.nonzero()[0]
        self.slid = slid = sliding.nonzero()[0] if friction else np.zeros(0, np.int64)
        self.sticking = sticking = stick.nonzero()[0]
        self.stuck = pushed.searchsorted(sticking)  # (the method: a third of np.searchsorted's cost)
        self.free = (~active).nonzero()[0]
        held = picked.tangent_rows[sticking].ravel()
        self.n_pushed = n = pushed.size
        rows = self.rows = np.concatenate([picked.up_rows[pushed], held])
        pushes, reach = picked.pushes[rows], picked.reach[:, rows]
        if slid.size:
            ways = direction[slid][:, picked.tangents]  # (s, dim - 1)
            at = pushed.searchsorted(slid)
            lean = np.matmul(ways[:, None], picked.tangent_leans[slid])[:, 0]
            lean *= friction
            r = pushes.shape[1]
            pushes[at] += lean[:, :r]
            reach[:, at] += lean[:, r:].T
            # each sliding vertex's motion along its friction's way is one row over the picked coordinates
            self.way_map = np.zeros((slid.size, reach.shape[0]))
            self.way_map[np.arange(slid.size)[:, None], picked.tangent_rows[slid]] = ways
        if sticking.size:
            # each sticking vertex's tangential forces and normal force, gathered at once from the forces
            index = self.cone_index = np.empty((sticking.size, self.dim), np.int64)
            index[:, :-1] = np.arange(n, n + held.size).reshape(sticking.size, -1)
            index[:, -1] = self.stuck
            # squared, weighed by these, they sum to the tangential force squared less (cone normal)^2
            self.cone_weights = np.array([1.0] * (self.dim - 1) + [-self.cone * self.cone])
        K = reach[rows]
        K.flat[:: rows.size + 1] += picked.compliance[rows]
        self.inverse = _inverse(K)
        self.gives = picked.compliance[rows[:n]]  # how far each pushed height gives per unit force
        self.pushes, self.reach = pushes, reach
        self.free_rows = picked.up_rows[self.free]
        self._stamp = None

    def _aim(self, picked) -> None:
        """The targets and floors of the step (gathered once a step)."""
        self._stamp = picked.stamp
        self.targets = picked.target[self.rows]
        self.floors = picked.floor[self.free]
        if self.slid.size:
            self.way_start = dot(self.way_map, picked.start)

    def evaluate(self, picked, x_t, refine=0, quiet=np.inf):
        """The forces and the picked coordinates after the solve, for a global solution's ``x_t``.

        Parameters
        ----------
        picked : Picked
        x_t : ndarray, shape (p dim,)
            The picked coordinates of the global solution (:meth:`Picked.positions`).
        refine : int
            Solves that take back the way the compliance lets the ground give (:meth:`refined`).
        quiet : float
            The squared give (a length squared) that needs no more.

        Returns
        -------
        lam : ndarray, shape (k,)
            The rows' forces: the pushed vertices' normal forces, then the sticking tangents'.
        x : ndarray, shape (p dim,)
            The picked coordinates after the projection.
        """
        if self._stamp != picked.stamp:
            self._aim(picked)
        lam = dot(self.inverse, self.targets - x_t[self.rows])
        if refine:
            lam = self.refined(lam, refine, quiet)
        return lam, x_t + dot(self.reach, lam)

    def refined(self, lam, count, quiet):
        """``lam`` with its targets moved by the compliance's give, at most ``count`` times.

        The compliance lets a pushed vertex give way by ``c`` times its force; each solve aims
        that much further, leaving ``c^2`` times the force over a row's compliance. ``quiet``: the
        squared give (a length squared) that needs no more.
        """
        force = lam[: self.n_pushed]
        for _ in range(count):
            give = self.gives * force
            if give @ give <= quiet:
                break
            step = self.inverse[:, : self.n_pushed] @ give
            lam = lam + step
            force = step[: self.n_pushed]
        return lam

    def _backwards(self, x) -> np.ndarray:
        """How far each sliding vertex moved the way its friction pushes, shape (s,)."""
        moved = dot(self.way_map, x)
        moved -= self.way_start
        return moved

    def holds(self, lam, x, tol) -> bool:
        """Whether the sets hold: no pull, none left below, none sticking beyond its cone or sliding back.

        ``tol``: how far a sliding vertex may move against its friction's way.
        """
        n = self.n_pushed
        if n:
            normal = lam[:n]
            least = _min(normal)
            if least < 0.0 and least < -_PULL * max(_max(normal), 1e-300):
                return False
        if self.free.size and _min(x[self.free_rows] - self.floors) < 0.0:
            return False
        if self.sticking.size:
            forces = lam[self.cone_index]
            forces *= forces
            if _max(dot(forces, self.cone_weights)) > 0.0:  # tangential^2 - (cone normal)^2
                return False
        if self.slid.size and _max(self._backwards(x)) > tol:
            return False
        return True

    def apply(self, z, lam) -> None:
        """``z += pushes^T lam``, in place."""
        z += dot(lam, self.pushes)

    def diagnose(self, lam, x, p, tol):
        """Which of the ``p`` picked vertices break the sets, after :meth:`evaluate`.

        Returns
        -------
        normal : ndarray, shape (p,)
            Every picked vertex's normal force (0 where not pushed).
        ways : ndarray, shape (p, dim), or None
            The way each vertex in ``slips`` would slide, against the tangential force its
            sticking took, unit (None without any).
        release, below, slips, stops : ndarray of bool, shape (p,)
            Pulled by the ground; not pushed and below its floor; sticking beyond the
            cone (and not pulled); sliding back against its friction's way by over ``tol``.
        depth : ndarray, shape (p,)
            The height above its floor of each vertex not pushed (inf for the others).
        """
        n = self.n_pushed
        normal = np.zeros(p)
        normal[self.pushed] = lam[:n]
        release = normal < -_PULL * max(_max(normal), 1e-300)
        depth = np.empty(p)
        depth.fill(np.inf)
        depth[self.free] = x[self.free_rows] - self.floors
        below = depth < 0.0
        slips, stops = np.zeros(p, bool), np.zeros(p, bool)
        ways = None
        if self.slid.size:
            stops[self.slid] = self._backwards(x) > tol
        if self.sticking.size:
            held = lam[n:].reshape(-1, self.dim - 1)  # the sticking vertices' tangential forces
            needed = np.sqrt(np.add.reduce(held * held, axis=1))
            slipping = needed > self.cone * lam[self.stuck]
            slipping &= ~release[self.sticking]
            if np.count_nonzero(slipping):
                at = self.sticking[slipping]
                slips[at] = True
                ways = np.zeros((p, self.dim))
                ways[at[:, None], self.tangents] = held[slipping] / needed[slipping, None]
        return normal, ways, release, below, slips, stops, depth

    @property
    def nbytes(self) -> int:
        """Memory held by the operator's arrays."""
        return sum(a.nbytes for a in vars(self).values() if isinstance(a, np.ndarray))


def coulomb_forces(W, free, dim, up, friction, tol, iterations=60, start=None):
    """Exact Coulomb contact of a few vertices, by a semismooth Newton method on Alart and Curnier's function.

    Forces ``lam`` on the vertices' rows leave the rows at ``y = free + W lam``,
    relative to where they are held: each height over its target, each
    tangent's motion over the step. A vertex's height ends at or above its
    target, its normal force ``N >= 0``, and not both strictly; its tangential
    force ``T`` is at most ``friction N``, and where it slides (``y_t != 0``)
    exactly ``friction N`` straight against the slide. These are the zeros of
    ``N - max(0, N - rho y_n)`` and ``T - P(T - rho y_t)``, ``P`` the
    projection onto the disc of radius ``friction max(0, N - rho y_n)``,
    ``rho`` a height row's ``1 / W_ii`` and the mean of its tangents' for those; each Newton step on them is one small
    linear solve, backtracked until their sum of squares falls.

    Parameters
    ----------
    W : ndarray, shape (q dim, q dim)
        How far a unit force on each row moves each row (symmetric positive definite).
    free : ndarray, shape (q dim,)
        Each row's place with no force, relative to where it is held.
    dim, up : int
        Rows are vertex-major: vertex ``k``'s coordinate ``a`` is row ``k dim + a``; ``up`` the height's.
    friction : float
    tol : float
        How far from the conditions a row may end, in its length units.
    iterations : int
        Newton steps at most.
    start : ndarray, shape (q dim,), optional
        Forces to start from (zero by default).

    Returns
    -------
    lam : ndarray, shape (q dim,), or None
        The forces, or None where the method did not converge.

    Examples
    --------
    One vertex in 2D, pressed 1 into the ground and moving 1 along it, each
    row moved 1 by a unit force: the ground pushes it back out (1), and
    friction 0.5 takes half its slide (-0.5).

    >>> import numpy as np
    >>> coulomb_forces(np.eye(2), np.array([1.0, -1.0]), 2, 1, 0.5, 1e-12)
    array([-0.5,  1. ])
    """
    # each vertex's rows with its height first: the method works in that order and puts the forces back
    q = free.size // dim
    order = (np.arange(q)[:, None] * dim + np.array([up] + [a for a in range(dim) if a != up])).ravel()
    evaluate = _AlartCurnier(W[np.ix_(order, order)], free[order], dim, friction)
    lam = np.zeros(free.size) if start is None else np.asarray(start, dtype=float)[order]
    value, jacobian = evaluate(lam)
    scale = evaluate.rho.ravel()
    for _ in range(iterations):
        if np.abs(value / scale).max(initial=0.0) <= tol:
            found = np.empty_like(lam)
            found[order] = lam
            return found
        try:
            step = np.linalg.solve(jacobian, -value)
        except np.linalg.LinAlgError:
            return None
        merit, length = value @ value, 1.0
        while length > 1e-9:
            trial = lam + length * step
            trial_value, trial_jacobian = evaluate(trial)
            if trial_value @ trial_value <= (1.0 - 1e-4 * length) * merit:
                break
            length /= 2.0
        else:
            return None
        lam, value, jacobian = trial, trial_value, trial_jacobian
    return None


class _AlartCurnier:
    """Alart and Curnier's function of the forces (:func:`coulomb_forces`) and a generalised Jacobian.

    The rows come vertex by vertex, each vertex's height first; what does not change with the
    forces is made once: each vertex's rows of ``W`` and of the identity, (q, dim, q dim), and the ``rho``.
    """

    def __init__(self, W, free, dim, friction):
        q, size = free.size // dim, free.size
        self.W = W.reshape(q, dim, size)
        self.E = np.eye(size).reshape(q, dim, size)
        self.free, self.friction = free.reshape(q, dim), friction
        diagonal = W.diagonal().reshape(q, dim)
        # one rho for a vertex's tangents (with one per row, T - rho y_t would not point along the slide)
        self.rho = np.empty((q, dim))
        self.rho[:, 0] = 1.0 / diagonal[:, 0]
        self.rho[:, 1:] = 1.0 / diagonal[:, 1:].mean(axis=1, keepdims=True)
        self.pushed = self.rho[:, :, None] * self.W  # the rows of rho W
        self.given = self.E - self.pushed  # the rows of d sigma = d lam - rho d y (the same for every force)
        self.across = np.eye(dim - 1)

    def __call__(self, lam):
        q, dim = self.rho.shape
        forces = lam.reshape(q, dim)
        y = self.free + self.W @ lam  # (q, dim): where the rows end
        sigma = forces - self.rho * y  # the normal's, then the tangents'
        touching = sigma[:, 0] > 0.0
        radius = self.friction * np.maximum(sigma[:, 0], 0.0)
        slid = sigma[:, 1:]
        length = np.sqrt(np.einsum("ij,ij->i", slid, slid))
        stick = touching & (length <= radius) & (radius > 0.0)  # (frictionless: T = 0 always)
        value = forces.copy()  # as for a vertex let go: N = 0, T = 0
        value[:, 0] = np.where(touching, self.rho[:, 0] * y[:, 0], forces[:, 0])
        jacobian = np.where(touching[:, None, None], self.pushed, self.E)
        # sliding (or let go: radius 0): T - radius way; stuck: rho y_t
        way = slid / np.maximum(length, 1e-300)[:, None]
        value[:, 1:] = np.where(stick[:, None], self.rho[:, 1:] * y[:, 1:], forces[:, 1:] - radius[:, None] * way)
        # d radius = friction (e_n - rho_n W_n) while touching; d slid = e_t - rho_t W_t
        d_radius = (self.friction * touching)[:, None] * self.given[:, 0]  # (q, size)
        d_slid = self.given[:, 1:]  # (q, dim - 1, size)
        across = self.across - way[:, :, None] * way[:, None, :]
        across *= (radius / np.maximum(length, 1e-300))[:, None, None]
        sliding = self.E[:, 1:] - way[:, :, None] * d_radius[:, None, :] - across @ d_slid
        jacobian[:, 1:] = np.where(stick[:, None, None], self.pushed[:, 1:], sliding)
        return value.ravel(), jacobian.reshape(q * dim, -1)


class Aims(NamedTuple):
    """Where a whole-problem solve aims the picked rows (``target`` (p dim,)), and how it takes back the give.

    ``refine``: solves that may aim further by the way the compliance let the ground give, while it
    gives more than ``enough`` (see :meth:`SetOperator.refined`).
    """

    target: np.ndarray
    refine: int
    enough: float


def compliance_matrix(picked, rows) -> np.ndarray:
    """How far a unit force on each of ``rows`` moves each, the rows' compliance on the diagonal, symmetric (k, k)."""
    K = picked.reach[np.ix_(rows, rows)]
    K = (K + K.T) / 2
    K.flat[:: rows.size + 1] += picked.compliance[rows]
    return K


def given_back(solve, rows, heights, aims: Aims):
    """``solve(goal)`` -> (forces on ``rows``, picked coordinates after), or None; aimed further by the give.

    ``heights``: the positions of the height rows among ``rows``. The compliance lets a pushed
    height end below its target by its give; each further solve aims that much higher.
    """
    goal = aims.target[rows].copy()
    for _ in range(aims.refine + 1):
        found = solve(goal)
        if found is None:
            return None
        forces, x = found
        give = np.where(forces[heights] > 0.0, aims.target[rows[heights]] - x[rows[heights]], 0.0)
        if np.abs(give).max(initial=0.0) <= aims.enough:
            break
        goal[heights] += give
    return found


def pyramid_projection(picked, near, stick, x_t, z_t, z, friction, aims: Aims) -> np.ndarray:
    """The projection over the near vertices as a least-distance problem, solved by NNLS (Lawson and Hanson).

    Each force is a non-negative combination of *generators*: a height's push, or for a
    vertex that may stick (``stick``) the pushes ``n +- friction t_a`` along each tangent
    ``t_a``, the edges of a pyramid inside Coulomb's cone (so its friction stays within
    ``friction`` times its normal force along each tangent, and it slides where that is not
    enough; but its push up is tied to its friction, so what slides is lifted). The dual,
    ``min 1/2 b^T A K A^T b - (A d)^T b`` over ``b >= 0`` (``A`` the generators over the rows,
    ``K`` the rows' compliance matrix, positive definite by its compliance, ``d`` the gaps),
    is ``|L^T A^T b|^2 / 2 - (A d)^T b`` with ``L L^T = K``.

    Parameters
    ----------
    picked : Picked
    near, stick : ndarray of bool, shape (p,)
    x_t : ndarray, shape (p dim,)
        The picked coordinates of the global solution ``z_t``.
    z_t : ndarray, shape (r,)
        The global solution projected.
    z : ndarray, shape (r,)
        Set to the projection.
    friction : float
    aims : Aims

    Returns
    -------
    ndarray, shape (p,)
        The normal forces.
    """
    dim, up, tangents = picked.dim, picked.up, picked.tangents
    p = near.size
    normal_only, sticking = np.flatnonzero(near & ~stick), np.flatnonzero(near & stick)
    # the rows involved (heights of the near vertices, tangents of those that may stick) ...
    rows = np.concatenate([np.flatnonzero(near) * dim + up, (sticking[:, None] * dim + tangents).ravel()])
    column = np.full(p * dim, -1)
    column[rows] = np.arange(rows.size)
    # ... and the generators over them: a push, or a pyramid's edges n +- friction t_a
    edges = (sticking[:, None, None] * dim + tangents[None, :, None]).repeat(2, axis=2)  # (s, t, 2)
    generators = np.zeros((normal_only.size + edges.size, rows.size))
    generators[np.arange(normal_only.size), column[normal_only * dim + up]] = 1.0
    at = normal_only.size + np.arange(edges.size)
    generators[at, column[np.repeat(sticking * dim + up, 2 * (dim - 1))]] = 1.0
    generators[at, column[edges.ravel()]] = friction * np.tile([1.0, -1.0], edges.size // 2)
    # NNLS decides by comparing its rows: K is brought near 1 by an even power of two before the
    # factoring (exact, the square root too), so that the forces are the same in any units
    K = compliance_matrix(picked, rows)
    half = np.frexp(K.diagonal().max())[1] // 2
    factor = generators @ np.linalg.cholesky(np.ldexp(K, -2 * half))  # times 2^-half
    pushes = generators @ picked.pushes[rows]  # (g, r): each generator's push on z

    def solve(goal):
        b = _least_distance(factor, half, generators @ (goal - x_t[rows]))
        np.add(z_t, pushes.T @ b, out=z)
        return generators.T @ b, picked.positions(z)

    forces, _ = given_back(solve, rows, np.arange(np.count_nonzero(near)), aims)  # (the height rows first)
    on_rows = np.zeros(p * dim)
    on_rows[rows] = forces
    return on_rows[up::dim].copy()


def _least_distance(factor, half, gap) -> np.ndarray:
    """The generators' non-negative forces (g,) of one least-distance solve for their gaps ``gap`` (g,).

    ``factor`` (g, k) times its transpose is the generators' compliance matrix times ``2^-half``.
    """
    # the gaps brought to [0.5, 1) by a power of two b (exact): the forces of (2^-half factor,
    # b gap) are b 4^half times those of (factor, gap)
    b = np.ldexp(1.0, -np.frexp(np.abs(gap).max(initial=1.0))[1])
    gap = b * gap
    E = np.vstack([factor.T, gap])
    f = np.zeros(E.shape[0])
    f[-1] = 1.0
    u, _ = nnls(E, f, maxiter=50 * E.shape[1])
    scale = 1.0 - float(gap @ u)
    return np.ldexp(u / (b * scale), -2 * half) if scale > 0.0 else np.zeros_like(u)
