"""Ground contact: a velocity-level projection folded into the global solve.

A plane ``x[up] = ground`` and a set of contact vertices. In every global step
the tentative solution ``z_t = H^{-1} f`` is checked: each contact point that
is below the plane (at the current iterate) and moving into it (comparing
``z_t`` with the start of the step) is *active*. For the active points the
reduced force is changed as little as possible (least norm, or least squares
when there are more constraints than coordinates) so that each moves, over
the step, by ``h v``: normal velocity zero, tangential velocity kept times
``1 - stickiness`` (``stickiness = 1`` sticks, ``0`` slides freely).

With an optional ``push_out`` fraction, a point that starts the step inside
the ground is asked to climb out by that fraction of its depth within the
step (``push_out = 1``: back on the plane at the end of the step), so points
do not stay inside the ground. ``push_out = 0`` is the reference behaviour.

The correction for a given set of active points is a fixed matrix, so it is
computed once per set and cached: contact sets repeat from one iteration and
one step to the next. The solver carries the contact positions along with
``z`` (its global solve produces both in one product), so a cached set costs
one small product.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

__all__ = ["GroundContact"]

_CACHE_SIZE = 512


class GroundContact:
    """Precomputed ground-contact projection for one reduced system.

    Parameters
    ----------
    B_contact : ndarray, shape (p * dim, r)
        Rows of the subspace basis for the contact vertices (interleaved).
    H_inv : ndarray, shape (r, r)
        Inverse of the global system matrix.
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

    def __init__(self, B_contact, H_inv, h, dim, up, ground, stickiness=1.0, push_out=0.0):
        self.Je = np.ascontiguousarray(B_contact)
        self.Je_up = np.ascontiguousarray(self.Je[up::dim])
        self.dim, self.up, self.h = dim, up, float(h)
        self.ground = float(ground)
        self.stickiness = float(stickiness)
        self.push_out = float(push_out)
        self.E = self.Je @ H_inv  # sensitivity of contact positions to the reduced force
        self.H_inv = H_inv
        self.n_points = self.Je.shape[0] // dim
        self.lift = 0.0
        self.active_count = 0
        self._cache: OrderedDict = OrderedDict()

    def start_step(self, z_start: np.ndarray) -> None:
        """Remember the contact positions at the start of the step."""
        self.p_start = self.Je @ z_start
        up_start = self.p_start[self.up :: self.dim]
        # a point is active when its end-of-step height would stay below this
        self.limit = up_start.copy()
        if self.push_out:
            self.lift = self.push_out * np.maximum(self.ground - up_start, 0.0)
            self.limit += self.lift
        self.up_iter = up_start

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
        if rows.size < L.shape[1]:
            # the least change of force that meets every constraint exactly
            correction = L.T @ np.linalg.solve(L @ L.T, np.eye(rows.size))
        else:
            # more constraints than coordinates: least squares
            correction = np.linalg.lstsq(L, np.eye(rows.size), rcond=None)[0]
        dz = self.H_inv @ correction
        factor = np.full(rows.size, self.stickiness)
        factor[self.up :: dim] = 1.0  # normal velocity removed, tangential scaled
        # the correction of z and of every contact position, in one product
        entry = (active, rows, np.vstack([dz, self.Je @ dz]), factor)
        self._cache[key] = entry
        if len(self._cache) > _CACHE_SIZE:
            self._cache.popitem(last=False)
        return entry

    def correct(self, y: np.ndarray) -> np.ndarray:
        """Project the active contacts.

        Parameters
        ----------
        y : ndarray, shape (r + p * dim,)
            The tentative solution ``z_t = H^{-1} f`` followed by its contact
            positions ``Je z_t``. Points are tested against the previous
            iterate (from the last call, or the start of the step).

        Returns
        -------
        y : ndarray, shape (r + p * dim,)
            Corrected solution and positions.
        """
        r = y.size - self.Je.shape[0]
        p_tent = y[r:]
        up_tent = p_tent[self.up :: self.dim]
        # below the plane at the current iterate and moving into it (with
        # push_out: or climbing out slower than asked)
        mask = (self.up_iter < self.ground) & (up_tent < self.limit)
        if not mask.any():
            self.active_count = 0
            self.up_iter = up_tent
            return y
        active, rows, K, factor = self._projection(mask)
        self.active_count = active.size
        residual = (self.p_start[rows] - p_tent[rows]) * factor
        if self.push_out:
            residual[self.up :: self.dim] += self.lift[active]
        y = y + K @ residual
        self.up_iter = y[r + self.up :: self.dim]
        return y
