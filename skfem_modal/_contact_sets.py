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

import numpy as np
import scipy.sparse as sps
from scipy.linalg import lapack

from ._fast import dot

__all__ = ["Picked", "SetOperator"]

# a normal force this far below zero, relative to the largest, counts as zero (round-off)
_PULL = 1e-9
# a tangential force this much over friction times the normal force, relative, still sticks
_CONE = 1e-9
_min, _max = np.minimum.reduce, np.maximum.reduce  # without the ndarray methods' Python wrappers


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

    def __init__(self, J, pushes, dim, up):
        self.J, self.pushes, self.dim, self.up = J, pushes, dim, up
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
    friction, compliance : float

    Attributes
    ----------
    pushed, slid, free : ndarray of int
        The pushed vertices, the sliding ones and the vertices not pushed (indices into the picked).
    sticking : ndarray of int
        The pushed vertices that stick; ``stuck`` the same as indices into ``pushed``.
    """

    def __init__(self, picked, active, stick, sliding, direction, friction, compliance):
        self.friction, self.compliance, self.dim, self.tangents = friction, compliance, picked.dim, picked.tangents
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
        K.flat[:: rows.size + 1] += compliance
        self.inverse = _inverse(K)
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
            The squared give that needs no more.

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
        that much further, leaving ``c^2`` times the force over a row's compliance.
        """
        n = self.n_pushed
        give = lam[:n]
        for _ in range(count):
            if give @ give <= quiet:
                break
            step = self.inverse[:, :n] @ (self.compliance * give)
            lam = lam + step
            give = step[:n]
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
