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
"""

from __future__ import annotations

import numpy as np

__all__ = ["GroundContact"]


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
    """

    def __init__(self, B_contact, H_inv, h, dim, up, ground, stickiness=1.0, push_out=0.0):
        self.Je = np.ascontiguousarray(B_contact)
        self.Je_up = np.ascontiguousarray(self.Je[up::dim])
        self.dim, self.up, self.h = dim, up, float(h)
        self.ground = float(ground)
        self.keep_tangential = 1.0 - float(stickiness)
        self.push_out = float(push_out)
        self.E = self.Je @ H_inv  # rows: the tentative solution's sensitivity to force
        self.EEt = self.E @ self.E.T
        self.HinvEt = H_inv @ self.E.T
        self.H_inv = H_inv
        self.n_points = self.Je.shape[0] // dim
        self.active_count = 0

    def start_step(self, z_start: np.ndarray) -> None:
        """Remember the contact positions at the start of the step."""
        self.p_start = self.Je @ z_start
        if self.push_out:
            depth = np.maximum(self.ground - self.p_start[self.up :: self.dim], 0.0)
            self.recover = self.push_out * depth / self.h
        else:
            self.recover = 0.0

    def positions(self, z: np.ndarray) -> np.ndarray:
        """Contact point positions, shape (p, dim)."""
        return (self.Je @ z).reshape(-1, self.dim)

    def correct(self, z_iter: np.ndarray, z_tent: np.ndarray) -> np.ndarray:
        """The tentative solution with the active contacts projected.

        Parameters
        ----------
        z_iter : ndarray, shape (r,)
            The iterate before this global step (decides who is below ground).
        z_tent : ndarray, shape (r,)
            ``H^{-1} f`` before contact.

        Returns
        -------
        z : ndarray, shape (r,)
        """
        dim, up, h = self.dim, self.up, self.h
        below = (self.Je_up @ z_iter) < self.ground
        p_tent = self.Je @ z_tent
        vel = (p_tent - self.p_start).reshape(-1, dim) / h
        # moving into the ground (or, with push_out, climbing out too slowly)
        active = np.nonzero(below & (vel[:, up] < self.recover))[0]
        self.active_count = active.size
        if active.size == 0:
            return z_tent
        target_vel = self.keep_tangential * vel[active]
        target_vel[:, up] = self.recover[active] if self.push_out else 0.0
        rows = (active[:, None] * dim + np.arange(dim)).ravel()
        residual = (target_vel * h).ravel() + self.p_start[rows] - p_tent[rows]
        r = self.E.shape[1]
        if rows.size < r:
            # fewest-force change that meets every constraint exactly
            lam = np.linalg.solve(self.EEt[np.ix_(rows, rows)], residual)
            return z_tent + self.HinvEt[:, rows] @ lam
        # more constraints than coordinates: least squares (normal equations,
        # as the reference; an SVD only if they are singular)
        L = self.E[rows]
        try:
            df = np.linalg.solve(L.T @ L, L.T @ residual)
        except np.linalg.LinAlgError:
            df = np.linalg.lstsq(L, residual, rcond=None)[0]
        return z_tent + self.H_inv @ df
