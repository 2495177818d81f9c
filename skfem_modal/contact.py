"""Ground contact: a projection of each global solution, the reference implementation's model.

A plane ``x[up] = ground`` and a set of contact vertices. In every global step
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
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np
import scipy.sparse as sps

from ._fast import dot
from .effects import Effect

__all__ = ["GroundContact"]

_CACHE_SIZE = 512


class GroundContact(Effect):
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

    name = "contact"

    def __init__(self, space, vertices, ground, up, stickiness=1.0, push_out=0.0):
        self.vertices = vertices
        self.dim, self.up = space.dim, up
        self.ground = float(ground)
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
