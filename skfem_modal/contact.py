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
one step to the next, and a cached set costs two small products.
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
        self.active_count = 0
        self._cache: OrderedDict = OrderedDict()

    def start_step(self, z_start: np.ndarray) -> None:
        """Remember the contact positions at the start of the step."""
        self.p_start = self.Je @ z_start
        self.up_start = self.p_start[self.up :: self.dim].copy()
        self.up_iter = self.up_start
        if self.push_out:
            depth = np.maximum(self.ground - self.up_start, 0.0)
            self.lift = self.push_out * depth  # the climb asked of each point over the step
        else:
            self.lift = 0.0

    def positions(self, z: np.ndarray) -> np.ndarray:
        """Contact point positions, shape (p, dim)."""
        return (self.Je @ z).reshape(-1, self.dim)

    def _projection(self, active: np.ndarray):
        """Rows, contact rows of B and the correction matrix for an active set."""
        key = active.tobytes()
        entry = self._cache.get(key)
        if entry is not None:
            self._cache.move_to_end(key)
            return entry
        dim = self.dim
        rows = (active[:, None] * dim + np.arange(dim)).ravel()
        L = self.E[rows]
        if rows.size < L.shape[1]:
            # the least change of force that meets every constraint exactly
            correction = L.T @ np.linalg.solve(L @ L.T, np.eye(rows.size))
        else:
            # more constraints than coordinates: least squares
            correction = np.linalg.lstsq(L, np.eye(rows.size), rcond=None)[0]
        factor = np.full(rows.size, self.stickiness)
        factor[self.up :: dim] = 1.0  # normal velocity removed, tangential scaled
        entry = (rows, np.ascontiguousarray(self.Je[rows]), self.H_inv @ correction, factor)
        self._cache[key] = entry
        if len(self._cache) > _CACHE_SIZE:
            self._cache.popitem(last=False)
        return entry

    def correct(self, z_tent: np.ndarray) -> np.ndarray:
        """The tentative solution with the active contacts projected.

        Parameters
        ----------
        z_tent : ndarray, shape (r,)
            ``H^{-1} f`` before contact. Points are tested against the
            previous iterate (remembered from the last call, or the start of
            the step).

        Returns
        -------
        z : ndarray, shape (r,)
        """
        up_tent = self.Je_up @ z_tent
        # below the plane at the current iterate and moving into it (with
        # push_out: or climbing out slower than asked)
        active = (self.up_iter < self.ground) & (up_tent - self.up_start < self.lift)
        if not active.any():
            self.active_count = 0
            self.up_iter = up_tent
            return z_tent
        active = np.flatnonzero(active)
        self.active_count = active.size
        rows, Je_rows, K, factor = self._projection(active)
        residual = (self.p_start[rows] - Je_rows @ z_tent) * factor
        if self.push_out:
            residual[self.up :: self.dim] += self.lift[active]
        z = z_tent + K @ residual
        self.up_iter = self.Je_up @ z
        return z
