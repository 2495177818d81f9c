"""Ground contact: a velocity-level projection folded into the global solve.

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
one step to the next. The solver carries the contact positions along with
``z`` (its global solve produces both in one product), so a cached set costs
one small product.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

from ._fast import dot

__all__ = ["GroundContact"]

_CACHE_SIZE = 512


class GroundContact:
    """Precomputed ground-contact projection for one reduced system.

    Parameters
    ----------
    Je : ndarray or scipy.sparse matrix, shape (p * dim, r)
        The map from the unknowns to the contact vertices' positions
        (interleaved): rows of the subspace basis, or a selection matrix in
        the full space.
    solve : callable
        ``solve(X)`` returns ``H^{-1} X`` for the global system matrix ``H``
        and a dense ``X`` of shape (r, k).
    h : float
        Time step.
    dim, up : int
        Dimension and the index of the up axis.
    ground : float
        Height of the plane along ``up``.
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

    def __init__(self, Je, solve, h, dim, up, ground, stickiness=1.0, push_out=0.0):
        import scipy.sparse as sps

        if sps.issparse(Je):
            self.Je = Je.tocsr()
            self.Je_up = self.Je[up::dim]
            JeT = self.Je.T.toarray()
        else:
            self.Je = np.ascontiguousarray(Je)
            self.Je_up = np.ascontiguousarray(self.Je[up::dim])
            JeT = self.Je.T
        self.solve = solve
        self.dim, self.up, self.h = dim, up, float(h)
        self.ground = float(ground)
        self.stickiness = float(stickiness)
        self.push_out = float(push_out)
        self.HinvJeT = solve(JeT)  # (r, p dim): H^-1 Je^T
        self.E = self.HinvJeT.T  # Je H^-1: sensitivity of contact positions to the force
        self.n_points = self.Je.shape[0] // dim
        self.lift = 0.0
        self.active_count = 0
        self._cache: OrderedDict = OrderedDict()

    def start_step(self, z_start: np.ndarray) -> None:
        """Remember the contact positions at the start of the step."""
        self.p_start = self.Je @ z_start
        up_start = self.p_start[self.up :: self.dim]
        self.up_iter = up_start
        if self.push_out:
            depth = np.maximum(self.ground - up_start, 0.0)
            # the lowest end height allowed: the ground, or on the way out of it
            self.target = np.where(depth > 0, up_start + self.push_out * depth, self.ground)
            self.lift = self.target - up_start
            self.limit = self.target
            # the positions the corrections aim at: the start, lifted out of the ground
            self.p_target = self.p_start.copy()
            self.p_target[self.up :: self.dim] += self.lift
        else:
            # reference rule: a point below ground may not move further down
            self.lift = 0.0
            self.limit = up_start
            self.p_target = self.p_start

    def positions(self, z: np.ndarray) -> np.ndarray:
        """Contact point positions, shape (p, dim)."""
        return (self.Je @ z).reshape(-1, self.dim)

    def _projection(self, mask: np.ndarray):
        """Rows and the stacked correction matrix of an active set (cached)."""
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
        # the correction of z and of every contact position, in one product,
        # the tangential scaling folded in
        entry = (active, rows, np.vstack([dz, np.asarray(self.Je @ dz)]) * factor)
        self._cache[key] = entry
        if len(self._cache) > _CACHE_SIZE:
            self._cache.popitem(last=False)
        return entry

    def correct(self, y: np.ndarray, in_place: bool = False) -> np.ndarray:
        """Project the active contacts.

        Parameters
        ----------
        y : ndarray, shape (r + p * dim,)
            The tentative solution ``z_t = H^{-1} f`` followed by its contact
            positions ``Je z_t``. In the reference rule points are tested
            against the previous iterate (from the last call, or the start of
            the step).
        in_place : bool
            Correct ``y`` itself (and return it).

        Returns
        -------
        y : ndarray, shape (r + p * dim,)
            Corrected solution and positions.
        """
        r = y.size - self.Je.shape[0]
        if self.push_out:
            corrected = self._correct_positions(y, r)
            if in_place and corrected is not y:
                np.copyto(y, corrected)
                return y
            return corrected
        p_tent = y[r:]
        up_tent = p_tent[self.up :: self.dim]
        # below the plane at the current iterate and moving into it
        mask = (self.up_iter < self.ground) & (up_tent < self.limit)
        if not np.count_nonzero(mask):  # a third of .any()'s cost, once an iteration
            self.active_count = 0
            self.up_iter = up_tent
            return y
        y = self._apply(y, r, mask, y if in_place else None)
        self.up_iter = y[r + self.up :: self.dim]
        return y

    def _apply(self, y, r, mask, out=None):
        active, rows, K = self._projection(mask)
        self.active_count = active.size
        return np.add(y, dot(K, (self.p_target - y[r:]).take(rows)), out=out)

    def _correct_positions(self, y, r):
        """Position rule: no contact point ends below its target height."""
        tol = 1e-12 * max(1.0, abs(self.ground))
        mask = y[r + self.up :: self.dim] < self.target - tol
        if not np.count_nonzero(mask):
            self.active_count = 0
            return y
        tentative = y
        for _ in range(4):
            y = self._apply(tentative, r, mask)
            # a correction moves other points too: add any now below target
            violated = y[r + self.up :: self.dim] < self.target - tol
            if not (violated & ~mask).any():
                break
            mask = mask | violated
        return y
