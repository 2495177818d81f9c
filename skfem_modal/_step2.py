"""The 2D numpy backend: local/global iterations on preallocated buffers.

In 2D a cluster's rotation is its feature pair ``(c, s) = (F00 + F11,
F10 - F01)`` scaled to unit length, and both maps are folded into the
operators: ``G`` takes ``z`` to every cluster's ``(c, s)``, ``W`` takes the
unit pairs back to ``z``. An iteration is then five numpy calls on buffers
made once: ``G z``, the pairs' lengths, a check for zero length, the
division (or one compiled call for these three, with numba), and
``[W | c] [(c, s); 1]``, the step's constant ``c`` riding along as one more
column of ``W`` (written once a step, from ``z`` and ``z_dot`` by one
product). See :mod:`skfem_modal.solver` for the backend interface.
"""

from __future__ import annotations

import numpy as np

from ._fast import dot
from .rotations import ROT2
from .solver import ActivationRows, StateLayout

__all__ = ["Step2Backend", "features", "from_rotations"]


def features(rows: np.ndarray) -> np.ndarray:
    """Cluster rows of row-major ``F`` (4 each) -> rows of ``(c, s)`` (2 each), shape (..., 2 n, r)."""
    blocks = rows.reshape(rows.shape[:-2] + (-1, 4, rows.shape[-1]))
    return np.einsum("fj,...kjr->...kfr", ROT2, blocks).reshape(rows.shape[:-2] + (-1, rows.shape[-1]))


def from_rotations(columns: np.ndarray) -> np.ndarray:
    """Columns acting on ``vec(R)`` (4 a cluster) -> columns acting on ``(c, s)`` (2 a cluster)."""
    blocks = columns.reshape(columns.shape[:-1] + (-1, 4))
    return np.einsum("...kj,pj->...kp", blocks, ROT2).reshape(columns.shape[:-1] + (-1,))


class Step2Backend:
    """Buffers of the 2D numpy iterations (see the module docstring).

    Parameters
    ----------
    model : Model
        A 2D model in a subspace.
    max_iter : int
    normalize : callable, optional
        Scales the rows of an (n, 2) array to unit length in place, (0, 0)
        to (1, 0): a compiled kernel; numpy calls when None.
    """

    name = "numpy (2D buffers)"
    exact = True

    def __init__(self, model, max_iter, normalize=None):
        G, W, r = model.G, model.W, model.space.r
        muscles = model.A is not None
        G_all = np.vstack([G] + ([model.A[0]] if muscles else []))
        W_all = np.hstack([W] + ([model.WA[0]] if muscles else []))
        # an iterate is [z, 1, the contact's watched values]: the 1 (when the contact watches, or the
        # corotated damping offsets the rotations) carries constant terms, the watched values ride along,
        # so that one product gives the contact's whole state
        watch = getattr(model.contact, "watch", None)
        self.fused = watch is not None
        # the corotated damping's start terms (offset and shift), each step; None without it
        self.start_terms = model.start_terms if model.corotated is not None else None
        has_one = self.fused or self.start_terms is not None
        p = 0 if watch is None else watch.shape[0]
        size = r + has_one + p

        def extend(X):
            ones = [np.zeros((1, X.shape[1]))] if has_one else []
            return np.vstack([X] + ones + ([watch @ X] if self.fused else []))

        self.G = np.zeros((G_all.shape[0] // 2, r + has_one))  # the pairs of [z, 1]: the 1's column the offset's
        self.G[:, :r] = features(G_all)
        two_n = self.G.shape[0]
        self.passive_offset = self.G[: G.shape[0] // 2, r] if has_one else None
        self.max_batch, self.r, self.n = max_iter, r, two_n // 2
        self.normalize = normalize
        self.W_c = np.empty((size, two_n + 1))
        self.W_c[:, :two_n] = extend(from_rotations(W_all))
        self.c = self.W_c[:, two_n]
        self.activation = None
        if muscles and model.n_muscles:
            rows = G.shape[0] // 2
            WA = np.stack([extend(Wk) for Wk in from_rotations(model.WA)])
            self.activation = ActivationRows([(features(model.A), self.G[rows:, :r]), (WA, self.W_c[:, rows:two_n])])
        self.C_operator = np.ascontiguousarray(extend(model.C))
        self.shift_operator = extend(np.eye(r)) if self.start_terms is not None else None  # z's shift, all rows
        self.C_input = np.ones(2 * r + 1)
        if has_one:
            self.C_operator[r, 2 * r] = 1.0  # the state's 1, from C_input's
        self.C_z, self.C_z_dot = self.C_input[:r], self.C_input[r : 2 * r]
        self.cs_1 = np.ones(two_n + 1)  # the unit pairs, then a 1 for c
        self.cs_flat = self.cs_1[:two_n]
        self.cs = self.cs_flat.reshape(-1, 2)
        self.cos, self.sin = self.cs[:, 0], self.cs[:, 1]
        self.norm = np.empty(self.n)
        self.norm_column = self.norm[:, None]
        self.Y = np.empty((max_iter + 1, size))  # iterates, then the 1 and what the contact watches
        self.Y[:, r : r + has_one] = 1.0  # (the product keeps it: row r of W_c is the 1's)
        self.Z = self.Y[:, :r]
        # views made once: indexing costs as much as a small product
        self.rows = list(self.Y)
        self.z_rows = list(self.Z)
        self.g_rows = list(self.Y[:, : r + has_one])  # what G multiplies
        self.watched_rows = list(self.Y[:, r + 1 :]) if self.fused else [None] * (max_iter + 1)
        # the contact corrects a row of Y, z and the watched values together
        self.layout = StateLayout(size, np.arange(r), r + 1 + np.arange(p), r) if self.fused else None
        self.k = 0

    def start(self, z, z_dot, a) -> None:
        if self.activation is not None:
            self.activation.write(a)
        np.copyto(self.C_z, z)
        np.copyto(self.C_z_dot, z_dot)
        np.matmul(self.C_operator, self.C_input, self.c)  # a strided column: matmul
        if self.start_terms is not None:
            offset, shift = self.start_terms(z)
            self.passive_offset[:] = features(offset[:, None])[:, 0]
            self.c += self.shift_operator @ shift
        np.copyto(self.z_rows[0], z)
        self.k = 0

    def start_row(self):
        return self.z_rows[0]

    def restart(self, z) -> None:
        np.copyto(self.z_rows[self.k], z)

    def iterate(self, count, contact):
        G, W_c, cs_1, cs_flat, cs = self.G, self.W_c, self.cs_1, self.cs_flat, self.cs
        cos, sin, norm, norm_column, n = self.cos, self.sin, self.norm, self.norm_column, self.n
        hypot, divide, count_nonzero, normalize = np.hypot, np.divide, np.count_nonzero, self.normalize
        first, last = self.k, self.k + count
        g = self.g_rows[first]
        for y, g_next, z_next, watched in zip(self.rows[first + 1 : last + 1], self.g_rows[first + 1 : last + 1],
                                              self.z_rows[first + 1 : last + 1],
                                              self.watched_rows[first + 1 : last + 1]):  # fmt: skip
            dot(G, g, cs_flat)
            if normalize is not None:
                normalize(cs)
            else:
                hypot(cos, sin, norm)
                if count_nonzero(norm) < n:
                    # a zero target: every rotation is optimal, take the identity
                    zero = norm == 0.0
                    cs[zero] = (1.0, 0.0)
                    norm[zero] = 1.0
                divide(cs, norm_column, cs)
            dot(W_c, cs_1, y)
            if contact is not None:
                if self.layout is not None:
                    contact.project(y, watched, self.layout)
                else:
                    contact.project(z_next)
            g = g_next
        self.k = last
        return self.Z[first : last + 1]

    def finish(self, k) -> bool:
        return True

    def result(self, k):
        return self.z_rows[k].copy()

    def carried(self) -> dict:
        """Nothing: 2D rotations are closed-form."""
        return {}

    def carry(self, state: dict) -> None:
        """Take :meth:`carried`'s (nothing)."""
