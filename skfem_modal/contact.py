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

from collections import OrderedDict

import numpy as np
import scipy.sparse as sps
from scipy.optimize import nnls

from ._fast import dot
from .effects import Effect
from .mesh import boundary_vertices, farthest_point_sampling

__all__ = ["CoulombContact", "ReferenceContact", "MODELS"]

#: Contact models by name (a scene's ``ground.model``).
MODELS = ("coulomb", "reference")

_CACHE_SIZE = 512
# passes of the active set in one projection before the exact solve (half changing whole sets, half one vertex)
_PASSES = 16
# vertices below the ground joining the active set per pass, at most
_JOIN = 4
# vertices a step's projections look at, at most (the end of the step checks them all)
_MOST = 32


class _Ground(Effect):
    """What every ground contact has: the plane, and the deepest boundary vertex below it."""

    name = "contact"

    def _plane(self, space, ground, up):
        self.dim, self.up, self.ground = space.dim, up, float(ground)
        self.boundary = space.heights(boundary_vertices(space.mesh), up)

    def penetration(self, z) -> float:
        """How deep the lowest boundary vertex is below the ground (0 when none is), for a state ``z``."""
        return max(0.0, self.ground - float(self.boundary(np.asarray(z, float)).min()))

    def missed(self, z) -> bool:
        """Whether the step's iterations should run again, seeing more vertices (see the Coulomb model)."""
        return False

    def forget(self) -> None:
        """Forget what earlier steps leave for the next (nothing, here: see the Coulomb model)."""

    def finish_step(self, z) -> None:
        """The end of a step's iterations, ``z`` (r,) the result: nothing to do (see the Coulomb model)."""


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

    def bind(self, system, h) -> None:
        """Take the factored system of time step ``h`` (a new one clears the cached corrections)."""
        JeT = self.Je.T.toarray() if sps.issparse(self.Je) else self.Je.T
        self.HinvJeT = system.solve(JeT)  # (r, p dim): H^-1 Je^T
        self.E = self.HinvJeT.T  # Je H^-1: sensitivity of contact positions to the force
        self.solve, self.h = system.solve, float(h)
        self._cache: OrderedDict = OrderedDict()

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_cache"] = OrderedDict()
        state.pop("_dot", None)
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._dot = (lambda A, x: A @ x) if sps.issparse(self.Je) else dot

    def positions(self, z) -> np.ndarray:
        """Contact point positions, shape (p, dim)."""
        return (self.Je @ np.asarray(z, float)).reshape(-1, self.dim)

    def start_step(self, z_start, z_dot=None) -> None:
        """Remember the contact positions at the start of the step."""
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

    def project(self, z, watched=None) -> bool:
        """Project the active contacts of a global solution, in place; True if it changed.

        Parameters
        ----------
        z : ndarray, shape (r,)
            Corrected in place.
        watched : ndarray, shape (p,), optional
            ``watch @ z`` (the contact heights) if the caller has it; corrected along with ``z``.
        """
        heights = self._dot(self.Je_up, z) if watched is None else watched
        if self.push_out:
            return self._project_positions(z, heights)
        # active: below the plane at the current iterate and moving into it
        if self.n_below:
            mask = np.less(heights, self.limit)
            mask &= self.below
            if np.count_nonzero(mask):
                self._apply(z, heights, mask)
            else:
                self.active_count = 0
        else:
            self.active_count = 0
        below = np.less(heights, self.ground, self.below)
        self.n_below = np.count_nonzero(below)
        return self.active_count > 0

    def _projection(self, mask: np.ndarray):
        """The active points' position rows and correction matrices (cached per active set)."""
        key = mask.tobytes()
        entry = self._cache.get(key)
        if entry is not None:
            self._cache.move_to_end(key)
            return entry
        dim = self.dim
        active = np.flatnonzero(mask)
        rows = (active[:, None] * dim + np.arange(dim)).ravel()
        L = self.E[rows]
        if self.push_out:
            # position rule: the least change of z in the energy norm of the
            # global step (contact forces at the points), z += H^-1 Je^T lam
            # with (Je H^-1 Je^T + eps I) lam = residual. The small eps keeps
            # it well posed when the points ask more than the subspace can do
            # (then it is a least-squares compromise instead of a blow-up).
            S = np.asarray(self.Je[rows] @ self.HinvJeT[:, rows])
            eps = 1e-9 * np.trace(S) / rows.size
            dz = self.HinvJeT[:, rows] @ np.linalg.solve(S + eps * np.eye(rows.size), np.eye(rows.size))
        elif rows.size < L.shape[1] and np.linalg.matrix_rank(L) == rows.size:
            # reference: the least change of force that meets every constraint exactly
            dz = self.solve(L.T @ np.linalg.solve(L @ L.T, np.eye(rows.size)))
        else:
            # reference, more constraints than coordinates: least squares
            dz = self.solve(np.linalg.lstsq(L, np.eye(rows.size), rcond=None)[0])
        factor = np.full(rows.size, self.stickiness)
        factor[self.up :: dim] = 1.0  # normal velocity removed, tangential scaled
        dz = np.ascontiguousarray(dz * factor)
        Je_rows = self.Je[rows]
        Je_rows = Je_rows.toarray() if sps.issparse(Je_rows) else np.ascontiguousarray(Je_rows)
        entry = (active, rows, Je_rows, dz, np.ascontiguousarray(np.asarray(self.Je_up @ dz)))
        self._cache[key] = entry
        if len(self._cache) > _CACHE_SIZE:
            self._cache.popitem(last=False)
        return entry

    def _apply(self, z, heights, mask) -> None:
        """Correct ``z`` and its contact heights in place for an active set."""
        active, rows, Je_rows, dz, dheights = self._projection(mask)
        self.active_count = active.size
        delta = self.p_target[rows] - dot(Je_rows, z)
        z += dot(dz, delta)
        heights += dot(dheights, delta)

    def _project_positions(self, z, heights) -> bool:
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
            self._apply(z, heights, mask)
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
    normal force found in the same solve. Who sticks and who slides (and
    which way) is updated after each projection: the local/global iterations
    settle it with the rotations.

    The vertices pushed are found by a primal-dual active set, warm-started
    from the last projection; a pass is one small solve over the pushed rows.
    A compliance a millionth of a row's own stiffness keeps that solve well
    posed when rows depend on each other (many vertices on a flat face, more
    than a subspace can tell apart): their pushes spread over them as the
    smallest forces do, and the ground gives way by about a millionth of a
    step's correction.

    A step looks only at the vertices that can reach the ground in it (those
    within half a percent of the body's size of it, or moving towards it
    fast enough); at the end of the step every candidate is checked, and one
    that ended below is held up too, so no vertex ends a step in the ground.

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

    Attributes
    ----------
    active_count : int
        Vertices the ground pushed in the last projection.
    """

    model = "coulomb"
    watch = None  # the candidates change from step to step: nothing a backend could compute ahead

    def __init__(self, space, vertices, ground, up, friction=0.5):
        self._plane(space, ground, up)
        self.space, self.vertices = space, np.asarray(vertices)
        self.friction = float(friction)
        self.heights_of = space.heights(self.vertices, up)
        self.size = float(np.ptp(space.mesh.p, axis=1).max())
        self.tol = 1e-9 * self.size
        # how far below the ground a vertex may end a step: the compliance's give, a ten-thousandth of the size
        self.allowance = 1e-4 * self.size
        self.tangents = np.array([a for a in range(self.dim) if a != up], dtype=np.int64)
        p = self.vertices.size
        # per vertex, kept from step to step: pushed, sliding, normal force, the way friction pushes
        self.touching = np.zeros(p, bool)
        self.sliding = np.zeros(p, bool)
        self.normal_force = np.zeros(p)
        self.direction = np.zeros((p, self.dim))
        self.picked = np.zeros(0, np.int64)
        self._missed = np.zeros(0, np.int64)  # seen below at the end of a step's first run
        self._first = False
        self.active_count = 0

    def bind(self, system, h) -> None:
        """Take the factored system of time step ``h`` (a new one clears the pushes made so far)."""
        self.system, self.h = system, float(h)
        self.picked = np.zeros(0, np.int64)
        # each candidate row's push on z, H^-1 B_row^T, made when first needed: memory
        # O(candidates x subspace) at most, and only for the vertices that ever touch
        self._pushes = np.zeros((self.vertices.size * self.dim, self.space.r))
        self._made = np.zeros(self.vertices.size * self.dim, bool)
        # the compliance: a millionth of the mean stiffness of a vertex's height row, 1 / (e H^-1 e)
        sample = np.arange(0, self.vertices.size, max(1, self.vertices.size // 64)) * self.dim + self.up
        reach = np.einsum("ij,ij->i", self._rows_of(sample), self._push_of(sample))
        self.compliance = 1e-3 * float(reach.mean())

    def _rows_of(self, candidate_rows) -> np.ndarray:
        """Rows of ``B`` for candidate rows (vertex ``k``'s coordinate ``a`` is row ``k dim + a``), dense."""
        dofs = self.vertices[candidate_rows // self.dim] * self.dim + candidate_rows % self.dim
        rows = self.space.rows(dofs)
        return rows.toarray() if sps.issparse(rows) else rows

    def _push_of(self, candidate_rows) -> np.ndarray:
        """``H^-1 B_row^T`` of candidate rows, shape (k, r), each made once."""
        missing = candidate_rows[~self._made[candidate_rows]]
        if missing.size:
            missing = np.unique(missing)
            made = self.system.solve(np.ascontiguousarray(self._rows_of(missing).T))
            self._pushes[missing] = np.asarray(made).T
            self._made[missing] = True
        return self._pushes[candidate_rows]

    def __getstate__(self):
        state = self.__dict__.copy()
        if "_pushes" in state:  # made again where needed
            state["_pushes"] = np.zeros_like(self._pushes)
            state["_made"] = np.zeros_like(self._made)
        return state

    def positions(self, z) -> np.ndarray:
        """Positions of the candidate vertices, shape (p, dim)."""
        return self.space.positions(np.asarray(z, float))[self.vertices]

    # ------------------------------------------------------------ a step
    def start_step(self, z_start, z_dot=None) -> None:
        """Pick the vertices that can reach the ground in this step, and make their operators."""
        reach = self.heights_of(z_start) - 0.005 * self.size
        if z_dot is not None:
            reach += 2.0 * self.h * np.minimum(self.heights_of(z_dot), 0.0)
        self.z_start = z_start
        self._first = True
        picked = self._spread(np.flatnonzero((reach < self.ground) | self.touching), z_start)
        self._pick(np.union1d(picked, self._missed), z_start)

    def _spread(self, near, z_start) -> np.ndarray:
        """At most a few dozen of the near vertices, well spread along the ground, the touching ones first.

        The heights of neighbouring vertices nearly repeat each other (a subspace moves them
        alike): a spread few hold a whole patch up, with far fewer, better separated rows to
        solve for. The step's end checks every candidate, so none is left below.
        """
        if near.size <= _MOST:
            return near
        kept = near[self.touching[near]][:_MOST]
        rest = np.setdiff1d(near, kept, assume_unique=True)
        room = _MOST - kept.size
        if room > 0 and rest.size:
            where = self.space.positions(z_start)[self.vertices[rest]]
            where[:, self.up] = 0.0  # spread along the ground
            kept = np.concatenate([kept, rest[farthest_point_sampling(where, min(room, rest.size))]])
        return kept

    def _pick(self, picked, z_start, start=None) -> None:
        """Make ``picked`` (indices into the candidates) the vertices the projections look at.

        ``start`` gives the first ones' start-of-step positions when they are known (the others
        start where ``z_start`` has them).
        """
        self.picked = picked
        if not picked.size:
            return
        dim = self.dim
        rows = self.space.rows(self.space.dofs(self.vertices[picked]))
        self.J = rows.tocsr() if sps.issparse(rows) else rows
        self.start = np.asarray(self.J @ z_start).reshape(-1, dim)
        if start is not None:
            self.start[: start.shape[0]] = start
        self.target = self.start.ravel().copy()
        self.target[self.up :: dim] = self.ground
        self.rows_of_picked = (picked[:, None] * dim + np.arange(dim)).ravel()  # candidate rows, picked order

    def project(self, z, watched=None) -> bool:
        """Project a global solution ``z`` (r,) in place; True if it changed."""
        if self._first:
            # the step's first global solution says where the body is going (gravity, muscles,
            # momentum): the vertices it brings near the ground join the picked ones
            self._first = False
            near = np.flatnonzero(self.heights_of(z) < self.ground + 0.005 * self.size)
            joining = np.setdiff1d(near, self.picked, assume_unique=True)
            if joining.size and self.picked.size < _MOST:
                extra = self._spread(np.concatenate([self.picked, joining]), self.z_start)
                self._pick(np.concatenate([self.picked, np.setdiff1d(extra, self.picked)]), self.z_start)
        if not self.picked.size:
            self.active_count = 0
            return False
        return self._constrain(z)

    def forget(self) -> None:
        """Forget who touched, slid and how hard: the next step starts as a first one."""
        self.touching[:] = False
        self.sliding[:] = False
        self.normal_force[:] = 0.0
        self.direction[:] = 0.0
        self.picked = np.zeros(0, np.int64)
        self._missed = np.zeros(0, np.int64)

    def missed(self, z) -> bool:
        """Did the step leave vertices below the ground that its projections did not look at?

        Then the driver runs the step's iterations again, with them (``z`` the result).
        """
        below = np.flatnonzero(self.heights_of(z) < self.ground - self.allowance)
        self._missed = np.setdiff1d(below, self.picked, assume_unique=True)
        return bool(self._missed.size)

    def finish_step(self, z) -> None:
        """Hold up any candidate the step left below the ground (``z`` the result, in place)."""
        self._missed = np.zeros(0, np.int64)
        below = np.flatnonzero(self.heights_of(z) < self.ground - self.allowance)
        if not below.size:
            return
        missed = np.setdiff1d(below, self.picked, assume_unique=True)
        if missed.size:
            # seen only now: constrained from here on, with the others (their start: where they are)
            start = self.start if self.picked.size else np.zeros((0, self.dim))
            self._pick(np.concatenate([self.picked, missed]), z, start)
        self._constrain(z)

    # ---------------------------------------------------------- the solve
    def _constrain(self, z) -> bool:
        """Rounds of (the sliding vertices' friction as known forces, the active set) to a fixed point."""
        picked, dim, up, mu = self.picked, self.dim, self.up, self.friction
        x_base = np.asarray(self.J @ z)
        # hysteresis against going round in circles on flat faces: a vertex joins when it ends a
        # hundred-thousandth of the body's size below the ground, leaves when the ground would pull
        # it by more than a thousandth of the largest push
        joining = self.ground - self.allowance
        # the first guess: the vertices pushed last time, and the deepest few below the ground
        below = x_base[up::dim] < joining
        active = self.touching[picked].copy()
        active[np.argsort(np.where(below, x_base[up::dim], np.inf))[: min(_JOIN, np.count_nonzero(below))]] = True
        if not np.count_nonzero(active):
            self._release()
            return False
        z_base = z.copy()
        sliding = active & self.sliding[picked] if mu else np.zeros(picked.size, bool)
        estimate = self.normal_force[picked].copy()  # the sliding vertices' normal forces
        direction = self.direction[picked].copy()
        for _ in range(3):
            z_t, x_t = self._push(sliding, estimate, direction, z_base, x_base)
            stick = active & ~sliding if mu else np.zeros(picked.size, bool)
            active, normal, tangential, x = self._active_set(active, stick, z_t, x_t, z, joining)
            if not np.count_nonzero(active):
                np.copyto(z, z_base)
                self._release()
                return False
            stick &= active
            needed = np.sqrt(np.einsum("ij,ij->i", tangential, tangential))
            # sticking takes more than friction gives: slide, friction leaning the way the ground held it
            slips = stick & (needed > mu * normal * (1.0 + 1e-9))
            # a sliding vertex that its friction drove back (it overshot) sticks again
            moved = (x.reshape(-1, dim) - self.start) * (np.arange(dim) != up)
            stops = sliding & active & (np.einsum("ij,ij->i", moved, direction) > 0.0)
            leaves = sliding & ~active
            # the sliding ones' normal forces from this round lead the next projection's friction
            if not (np.count_nonzero(slips) or np.count_nonzero(stops) or np.count_nonzero(leaves)):
                break
            direction[slips] = tangential[slips] / needed[slips, None]
            sliding = (sliding | slips) & ~stops & active
            estimate = normal
        self._update_state(active, sliding, normal, direction, x)
        return True

    def _push(self, which, force, direction, z_t, x_t):
        """``z_t`` and the positions after the friction of some vertices: ``mu`` times their force, that way."""
        if not np.count_nonzero(which):
            return z_t, x_t
        rows = self.rows_of_picked.reshape(-1, self.dim)[which][:, self.tangents].ravel()
        push = (self.friction * force[which])[:, None] * direction[which][:, self.tangents]
        z_t = z_t + self._push_of(rows).T @ push.ravel()
        return z_t, np.asarray(self.J @ z_t)

    def _active_set(self, active, stick, z_t, x_t, z, joining):
        """Vertices pushed onto the ground (and sticking ones held) by a primal-dual active set; z in place.

        Returns the active set, the normal forces (c,), the tangential forces (c, dim) and the positions.
        A vertex joins when it ends below ``joining`` and leaves when the ground would pull it.
        """
        up, dim = self.up, self.dim
        seen = set()
        for attempt in range(_PASSES):
            normal, tangential, x = self._solve(active, stick & active, z_t, x_t, z)
            release = active & (normal < -1e-2 * max(normal.max(initial=0.0), 1e-300))
            below = ~active & (x[up::dim] < joining)
            if not (np.count_nonzero(release) or np.count_nonzero(below)):
                return active, np.maximum(normal, 0.0), tangential, x
            if attempt == _PASSES - 1:
                break
            key = active.tobytes()
            if attempt < _PASSES // 2 and key not in seen:
                seen.add(key)
                # release every vertex the ground pulls, hold the deepest few below: the rows of
                # neighbouring vertices nearly repeat each other, so a few stand for a whole patch
                heights = np.where(below, x[up::dim], np.inf)
                active = active & ~release
                active[np.argsort(heights)[: min(_JOIN, np.count_nonzero(below))]] = True
            elif np.count_nonzero(below):
                # going round in circles: one change at a time, the deepest vertex first
                active = active | (below & (x[up::dim] <= x[up::dim][below].min()))
            else:
                active = active.copy()
                active[np.flatnonzero(release)[np.argmin(normal[release])]] = False
            if not np.count_nonzero(active):
                # nothing pushed after all: unless the unpushed state leaves a vertex below
                active = x_t[up::dim] < joining
                if not np.count_nonzero(active):
                    np.copyto(z, z_t)
                    return active, np.zeros(active.size), np.zeros((active.size, dim)), x_t
        # going round in circles: the whole problem over the rows concerned, exactly
        return self._least_distance(active | below, stick, z_t, x_t, z)

    def _least_distance(self, near, stick, z_t, x_t, z):
        """The projection as a least-distance problem over some rows, solved by NNLS (Lawson and Hanson).

        The dual, ``min 1/2 m^T K m - d^T m`` with the height pushes ``m >= 0`` and the sticking
        tangents' forces free (each split into two non-negative parts), is ``|G^T m|^2 / 2 - d^T m``
        with ``G G^T = K`` (a Cholesky factor: the compliance keeps ``K`` positive definite).
        """
        picked, dim, up = self.picked, self.dim, self.up
        normal_rows = np.flatnonzero(near) * dim + up
        tangent_rows = (np.flatnonzero(stick & near)[:, None] * dim + self.tangents).ravel()
        rows = np.concatenate([normal_rows, tangent_rows, tangent_rows])
        signs = np.concatenate([np.ones(normal_rows.size + tangent_rows.size), -np.ones(tangent_rows.size)])
        HA = self._push_of(self.rows_of_picked[rows])  # (k, r): each row's push on z
        K = (self._rows_of(self.rows_of_picked[rows]) @ HA.T) * np.outer(signs, signs)
        G = np.linalg.cholesky((K + K.T) / 2 + self.compliance * np.eye(rows.size))
        gap = signs * (self.target[rows] - x_t[rows])
        E = np.vstack([G.T, gap])
        f = np.zeros(E.shape[0])
        f[-1] = 1.0
        u, _ = nnls(E, f, maxiter=50 * E.shape[1])
        scale = 1.0 - float(gap @ u)
        lam = u / scale if scale > 0.0 else np.zeros_like(u)
        np.add(z_t, HA.T @ (signs * lam), out=z)
        x = np.asarray(self.J @ z)
        normal = np.zeros(picked.size)
        normal[near] = lam[: normal_rows.size]
        k = tangent_rows.size
        tangential = np.zeros((picked.size, dim))
        both = lam[normal_rows.size : normal_rows.size + k] - lam[normal_rows.size + k :]
        tangential[np.ix_(stick & near, self.tangents)] = both.reshape(-1, dim - 1)
        return normal > 0.0, normal, tangential, x

    def _solve(self, active, stick, z_t, x_t, z):
        """One pass: the active vertices onto the ground, the sticking ones held; z in place.

        ``(A H^-1 A^T + c I) lam = targets - A z_t``, ``z = z_t + H^-1 A^T lam`` over the rows of
        the active vertices' heights and the sticking ones' tangents.
        Returns the normal forces (c,), the tangential forces (c, dim) and the positions after.
        """
        picked, dim, up = self.picked, self.dim, self.up
        normal_rows = np.flatnonzero(active) * dim + up
        tangent_rows = (np.flatnonzero(stick)[:, None] * dim + self.tangents).ravel()
        rows = np.concatenate([normal_rows, tangent_rows])
        HA = self._push_of(self.rows_of_picked[rows])  # (k, r): each row's push on z
        K = self._rows_of(self.rows_of_picked[rows]) @ HA.T
        K.flat[:: rows.size + 1] += self.compliance
        lam = np.linalg.solve(K, self.target[rows] - x_t[rows])
        np.add(z_t, HA.T @ lam, out=z)
        x = np.asarray(self.J @ z)
        normal = np.zeros(picked.size)
        normal[active] = lam[: normal_rows.size]
        tangential = np.zeros((picked.size, dim))
        tangential[np.ix_(stick, self.tangents)] = lam[normal_rows.size :].reshape(-1, dim - 1)
        return normal, tangential, x

    def _update_state(self, active, sliding, normal, direction, x) -> None:
        """What the next projection starts from: who touches, who slides and which way, the normal forces."""
        picked, dim, up = self.picked, self.dim, self.up
        self.touching[picked] = active
        self.normal_force[picked] = np.where(active, np.maximum(normal, 0.0), 0.0)
        self.sliding[picked] = sliding & active
        self.active_count = int(np.count_nonzero(active))
        if np.count_nonzero(sliding):
            # keep pushing against the way each sliding vertex goes
            moved = (x.reshape(-1, dim) - self.start)[sliding]
            moved[:, up] = 0.0
            length = np.sqrt(np.einsum("ij,ij->i", moved, moved))
            moving = length > self.tol
            where = np.flatnonzero(sliding)[moving]
            direction[where] = -moved[moving] / length[moving, None]
        self.direction[picked] = direction

    def _release(self) -> None:
        picked = self.picked
        self.touching[picked] = False
        self.sliding[picked] = False
        self.normal_force[picked] = 0.0
        self.active_count = 0
