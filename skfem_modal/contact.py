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
        self.n_points = vertices.size
        self.active_count = 0

    def bind(self, system, h) -> None:
        """Take the factored system of time step ``h`` (a new one clears the cached corrections)."""
        JeT = self.Je.T.toarray() if sps.issparse(self.Je) else self.Je.T
        self.HinvJeT = system.solve(JeT)  # (r, p dim): H^-1 Je^T
        self.E = self.HinvJeT.T  # Je H^-1: sensitivity of contact positions to the force
        self.solve, self.h = system.solve, float(h)
        self._cache: OrderedDict = OrderedDict()

    def positions(self, z) -> np.ndarray:
        """Contact point positions, shape (p, dim)."""
        return (self.Je @ np.asarray(z, float)).reshape(-1, self.dim)

    def start_step(self, z_start, z_dot=None) -> None:
        """Remember the contact positions at the start of the step."""
        self.p_start = self.Je @ z_start
        up_start = self.p_start[self.up :: self.dim]
        self.up_iter = up_start
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

    def project(self, z) -> bool:
        """Project the active contacts of a global solution ``z`` (r,), in place; True if it changed."""
        p = self.Je @ z
        if self.push_out:
            return self._project_positions(z, p)
        up_tent = p[self.up :: self.dim]
        # below the plane at the current iterate and moving into it
        mask = (self.up_iter < self.ground) & (up_tent < self.limit)
        if not np.count_nonzero(mask):  # a third of .any()'s cost, once an iteration
            self.active_count = 0
            self.up_iter = up_tent
            return False
        self._apply(z, p, mask)
        self.up_iter = p[self.up :: self.dim]
        return True

    def _projection(self, mask: np.ndarray):
        """Rows and the correction matrices of an active set (cached)."""
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
        elif rows.size < L.shape[1]:
            # reference: the least change of force that meets every constraint exactly
            dz = self.solve(L.T @ np.linalg.solve(L @ L.T, np.eye(rows.size)))
        else:
            # reference, more constraints than coordinates: least squares
            dz = self.solve(np.linalg.lstsq(L, np.eye(rows.size), rcond=None)[0])
        factor = np.full(rows.size, self.stickiness)
        factor[self.up :: dim] = 1.0  # normal velocity removed, tangential scaled
        dz = np.ascontiguousarray(dz * factor)
        entry = (active, rows, dz, np.ascontiguousarray(np.asarray(self.Je @ dz)))
        self._cache[key] = entry
        if len(self._cache) > _CACHE_SIZE:
            self._cache.popitem(last=False)
        return entry

    def _apply(self, z, p, mask) -> None:
        """Correct ``z`` and its contact positions ``p`` in place for an active set."""
        active, rows, dz, dp = self._projection(mask)
        self.active_count = active.size
        delta = (self.p_target - p).take(rows)
        z += dot(dz, delta)
        p += dot(dp, delta)

    def _project_positions(self, z, p) -> bool:
        """Position rule: no contact point ends below its target height."""
        tol = 1e-12 * max(1.0, abs(self.ground))
        mask = p[self.up :: self.dim] < self.target - tol
        if not np.count_nonzero(mask):
            self.active_count = 0
            return False
        z_tent, p_tent = z.copy(), p.copy()
        for _ in range(4):
            np.copyto(z, z_tent)
            np.copyto(p, p_tent)
            self._apply(z, p, mask)
            # a correction moves other points too: add any now below target
            violated = p[self.up :: self.dim] < self.target - tol
            if not (violated & ~mask).any():
                break
            mask = mask | violated
        return True
