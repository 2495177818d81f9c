"""The 3D numpy step in Kronecker form, for subspaces that move x, y and z alike.

A linear-blend-skinning basis (and its mass-orthonormalised form) is
``B = U kron I3``: coordinate ``(s, b)`` of ``z`` moves only coordinate ``b``
of the vertices, by the scalar field ``U[:, s]``. Then every reduced operator
of the step factors the same way, and with ``Z = z.reshape(K, 3)``:

* the cluster matrices are ``F_c^T = Y_c Z`` (``Y_c`` of shape (3, K)): one
  (4 n, K + 1) x (K + 1, 4) product for all clusters, instead of
  (9 n, 3 K) x (3 K,), a sixth of the memory traffic;
* the global solve is ``Z' = sum_c V_c R_c^T + C``: one (K + 1, 4 n + 3) x
  (4 n + 3, 4) product;
* the start-of-step right-hand side is ``C = P_z Z + P_v Z_dot + C_ext``
  with ``K x K`` blocks.

Each cluster's data sits in a 4 x 4 block: ``[[F^T, 0], [0, s]]`` for the
cluster matrix and its power-method shift ``s``, ``[[R^T, 0], [0, 1]]`` for
the rotation; ``Z`` carries a trailing ``[0, 0, 0, 1]`` row and the rotations
three ``[I3, 0]`` rows, which feed the shifts and ``C`` through the same
products. An iteration is then nine numpy calls: the cluster matrices, their
shifted Horn matrices ``P``, 4 or 5 squarings, the rotations with their traces
from the last power, a division, and the global product. The stopping test
(the reference's ``|z_k - z_(k-1)| < tol``) costs two more; for the iterations
the last step says will not stop, it is done afterwards, in one batch, on the
stored iterates, which gives the same answer.

The rotations are certified once a step (:func:`~skfem_modal.rotations.certify_squarings`): the
powers are kept, and their traces say how far each is from rank one; the
shift, kept just above ``|N| / sqrt(12)``, says the dominant eigenvalue is
the top one. A step that fails is handed back (``None``) to the simulator,
which redoes it with every rotation checked as it is made.
"""

from __future__ import annotations

import numpy as np

from ._fast import dot as _dot
from .rotations import HORN, QUAT_TO_R, certify_levels, next_squarings
from .solver import ActivationRows, StateLayout

__all__ = ["KroneckerBackend", "separable_rows", "separable_columns", "separable_square", "separable_watch"]

MAX_SQUARINGS = 8
# the iterations a step's shifts are written for as they are made (more are filled in when a step does them)
_LEVEL0_ROWS = 64

# index 4 e + d of a 4 x 4 block holds F^T[e, d] = F[d, e] (row-major F: 3 d + e)
_BLOCK = [(4 * e + d, 3 * d + e) for d in range(3) for e in range(3)]

# [[F^T, 0], [0, s]] (16 values) -> N(F) + s I (16 values)
HORN_BLOCK = np.zeros((16, 16))
for _b, _f in _BLOCK:
    HORN_BLOCK[_b] = HORN[_f]
HORN_BLOCK[15] = np.eye(4).ravel()

# q q^T (16 values) -> t [[R^T, 0], [0, 1]] and t = tr(q q^T) (17 values)
QQ_TO_BLOCK_TRACE = np.zeros((16, 17))
for _b, _f in _BLOCK:
    QQ_TO_BLOCK_TRACE[:, _b] = QUAT_TO_R[:, _f]
QQ_TO_BLOCK_TRACE[:, 15] = np.eye(4).ravel()
QQ_TO_BLOCK_TRACE[:, 16] = np.eye(4).ravel()

EYE16 = np.eye(4).ravel()  # the trace of a row-major 4 x 4 block, as a dot product


def _close(X, Y, rtol):
    scale = np.abs(X).max(initial=0.0)
    return np.abs(X - Y).max(initial=0.0) <= rtol * scale


def separable_rows(G, rtol=1e-11):
    """Cluster rows of ``vec(F)`` as ``F_c^T = Y_c Z``, if the operator factors.

    Parameters
    ----------
    G : ndarray, shape (q * 9, 3 K)
        Rows: row-major ``F`` of each of ``q`` clusters; columns: ``z``, with
        ``z[3 s + b]`` moving coordinate ``b``.
    rtol : float
        Largest deviation from the factored form, relative to ``max |G|``.

    Returns
    -------
    Y : ndarray, shape (q, 3, K), or None
        ``F_c[d, e] = sum_s Y[c, e, s] z[3 s + d]``; None if ``G`` does not factor.
    """
    q, K = G.shape[0] // 9, G.shape[1] // 3
    if G.shape != (9 * q, 3 * K):
        return None
    G5 = G.reshape(q, 3, 3, K, 3)  # cluster, d, e, s, b
    Y = G5[:, 0, :, :, 0].copy()
    if not _close(G5, np.einsum("db,ces->cdesb", np.eye(3), Y), rtol):
        return None
    return Y


def separable_columns(W, rtol=1e-11):
    """Cluster columns of ``vec(R)`` as ``Z = sum_c V_c R_c^T``, if the operator factors.

    Parameters
    ----------
    W : ndarray, shape (3 K, q * 9)
    rtol : float

    Returns
    -------
    V : ndarray, shape (K, q, 3), or None
        ``z[3 s + d] = sum_(c, e) V[s, c, e] R_c[d, e]``.
    """
    K, q = W.shape[0] // 3, W.shape[1] // 9
    if W.shape != (3 * K, 9 * q):
        return None
    W5 = W.reshape(K, 3, q, 3, 3)  # s, b, cluster, d, e
    V = W5[:, 0, :, 0, :].copy()
    if not _close(W5, np.einsum("bd,sce->sbcde", np.eye(3), V), rtol):
        return None
    return V


def separable_square(P, rtol=1e-11):
    """``P = P_s kron I3`` (interleaved), if it is: ``P_s`` of shape (K, K), or None."""
    K = P.shape[0] // 3
    if P.shape != (3 * K, 3 * K):
        return None
    P4 = P.reshape(K, 3, K, 3)
    Ps = P4[:, 0, :, 0].copy()
    if not _close(P4, np.einsum("ab,st->satb", np.eye(3), Ps), rtol):
        return None
    return Ps


def separable_watch(watch, up, rtol=1e-11):
    """``watch = U kron e_up^T`` (interleaved: row j reads coordinate ``up`` only), if it is.

    Parameters
    ----------
    watch : ndarray, shape (p, 3 K)
    up : int
    rtol : float
        Largest deviation from the factored form, relative to ``max |watch|``.

    Returns
    -------
    U : ndarray, shape (p, K), or None
        None if ``watch`` does not factor.
    """
    p, K = watch.shape[0], watch.shape[1] // 3
    W3 = np.asarray(watch).reshape(p, K, 3)
    U = W3[:, :, up].copy()
    expected = np.zeros_like(W3)
    expected[:, :, up] = U
    return U if _close(W3, expected, rtol) else None


def _row_blocks(Y, scale, extra=0):
    """(q, 3, K) -> the (q, 4, K + 1 + extra) row blocks ``[[Y / w, 0, 0], [0, shift, 0]]`` (shift left 0)."""
    q, _, K = Y.shape
    blocks = np.zeros((q, 4, K + 1 + extra))
    blocks[:, :3, :K] = Y / scale[:, None, None]
    return blocks


def _column_blocks(V):
    """(K, q, 3) -> the (K, 4 q) columns acting on ``[[R^T, 0], [0, 1]]`` blocks."""
    K, q, _ = V.shape
    blocks = np.zeros((K, q, 4))
    blocks[:, :, :3] = V
    return blocks.reshape(K, 4 * q)


def _iterate_layout(p, K, up, extra=0):
    """An iterate ``Z[i]`` (p watched heights in column ``up``, z's K rows, the trailing row ending in 1,
    ``extra`` constant rows) as a state."""
    z_index = ((p + np.arange(K))[:, None] * 4 + np.arange(3)).ravel()  # z[3 s + b] = Z[p + s, b]
    return StateLayout((p + K + 1 + extra) * 4, z_index, np.arange(p) * 4 + up, (p + K) * 4 + 3)


class KroneckerBackend:
    """Buffers and state of the Kronecker-form 3D iterations (see the module docstring).

    Built by :meth:`build`, which returns None when the operators do not
    factor. Its rotations are not exact until :meth:`finish` has certified
    them (``exact = False``).

    Attributes
    ----------
    squarings : int
        Squarings of the shifted Horn matrices in the next step, chosen from
        the last step's powers.
    """

    name = "numpy (Kronecker form)"
    exact = False

    def __init__(self, Y, V, YA, VA, Pz, Pv, c_ext, scale, n_active, max_iter, U=None, up=0, start_terms=None):
        n, _, K = Y.shape
        # with the corotated damping (``start_terms``: the model's, each step), Z has three more
        # rows, [I3, 0], and the passive clusters' row blocks three more columns for the offset they add
        self.start_terms = start_terms
        extra = 3 if start_terms is not None else 0
        # U (p, K): the contact's watched heights are U Z[:, up]; they ride
        # along in the global product as p more rows of Z, first, so that
        # they and z's rows take C and the activation in one write each
        watching = U is not None
        U = np.zeros((0, K)) if U is None else U
        p = U.shape[0]
        m = YA.shape[0] - 1 if YA is not None else 0
        self.K, self.n, self.m, self.p, self.max_batch = K, n, m, p, max_iter
        self.nc = n - n_active
        nc = self.nc
        # the two big operands of an iteration's products in Fortran order:
        # OpenBLAS multiplies them by a 4-column right side a fifth faster
        self.Yt = np.asfortranarray(_row_blocks(Y, scale, extra).reshape(4 * n, K + 1 + extra))
        self.shift_column = self.Yt[3::4, K]
        self.offset_blocks = self.Yt.reshape(n, 4, K + 1 + extra)[: n - n_active, :3, K + 1 :]  # (cluster, e, d)
        self.passive_scale = scale[: n - n_active, None, None]
        # rows: the watched heights, z, the trailing row, the constant rows
        self.Wt = np.zeros((p + K + 1 + extra, 4 * n + 3), order="F")
        self.Wt[p : p + K, : 4 * n] = _column_blocks(V)
        self.Wt[p + K, 3] = 1.0  # picks the 1 of cluster 0's rotation block: Z's trailing row
        self.Wt[p + K + 1 + np.arange(extra), 4 * n + np.arange(extra)] = 1.0  # the rotations' I3 rows
        self.Wt[:p, : 4 * n] = U @ self.Wt[p : p + K, : 4 * n]
        self.C_slot = self.Wt[: p + K, 4 * n :]
        self.activation = None
        if m:
            # the active clusters' F rows (not their shift rows, which the
            # step keeps) and columns, affine in the activation
            rows = np.stack([_row_blocks(YA[k], scale[nc:], extra)[:, :3] for k in range(m + 1)])
            cols = np.stack([_column_blocks(VA[k]) for k in range(m + 1)])
            Yt_active = self.Yt.reshape(n, 4, K + 1 + extra)[nc:, :3]
            assert np.shares_memory(Yt_active, self.Yt), "the active rows must be a view of the operator"
            cols = np.concatenate([np.einsum("pk,mkc->mpc", U, cols), cols], axis=1)
            self.activation = ActivationRows([(rows, Yt_active), (cols, self.Wt[: p + K, 4 * nc : 4 * n])])
        # C = [P_z, P_v, C_ext] [Z; Z_dot; I3], and the watched heights' U C
        C_operator = np.hstack([Pz, Pv, c_ext.reshape(K, 3)])
        self.C_operator = np.vstack([U @ C_operator, C_operator])
        self.shift_operator = np.vstack([U, np.eye(K)])  # the start terms' shift of z, and of the heights
        self.C_input = np.zeros((2 * K + 3, 3))
        self.C_input[2 * K :] = np.eye(3)
        # iterates Z (with the trailing row), rotations (with the I3 rows), powers
        self.Z = np.zeros((max_iter + 1, p + K + 1 + extra, 4))
        self.Z[:, p + K, 3] = 1.0
        self.Z[:, p + K + 1 + np.arange(extra), np.arange(extra)] = 1.0
        self.R = np.zeros((max_iter, 4 * n + 3, 4))
        self.R[:, 4 * n :, :3] = np.eye(3)
        # level first: each level's traces are one matrix-vector product over
        # all iterations (zeros, so that the iterations a step does not reach
        # hold finite values)
        self.powers = np.zeros((MAX_SQUARINGS + 1, max_iter, n, 4, 4))
        self.powers_rows = self.powers.reshape(-1, 16)
        self.powers_levels = self.powers.reshape(MAX_SQUARINGS + 1, -1, 16)
        self.F = np.empty((4 * n, 4))
        # [4 s / 1.05, tr P^2, tr P^4, ...] per iteration and cluster, for the
        # certificate (level 0 as the shifts are made: s = 1.05 sqrt(t_1) / 4)
        self.levels = np.empty((MAX_SQUARINGS + 1, max_iter, n))
        self.levels_flat = self.levels.reshape(-1)
        # (level, iteration and cluster): a step's first k iterations are a 2D slice, cheaper to reduce
        self.levels_2d = self.levels.reshape(MAX_SQUARINGS + 1, -1)
        self.Z_rows = self.Z[:, p:].reshape(max_iter + 1, -1)
        assert np.shares_memory(self.Z_rows, self.Z), "the rows must be a view of the iterates"
        self.C_z = self.C_input[:K].reshape(-1)  # contiguous rows: views
        self.C_z_dot = self.C_input[K : 2 * K].reshape(-1)
        self.Z0 = self.Z[0, p : p + K, :3]
        self.RT = np.empty((n, 17))  # t R^T blocks and t = tr(P^(2^s))
        self.shifted = False  # the shifts are set (from the last step)
        self.squarings = 4
        self.F16 = self.F.reshape(n, 16)
        self.RT16, self.trace = self.RT[:, :16], self.RT[:, 16:]
        self.C_z_block = self.C_input[:K]  # the same z, as (K, 3)
        self.outputs = [Zk[p : p + K, :3] for Zk in self.Z]
        # a watching contact corrects an iterate in place; another gets a contiguous copy of z
        self.layout = _iterate_layout(p, K, up, extra) if watching else None
        self.z_flat = np.empty(3 * K)
        self.z_block = self.z_flat.reshape(K, 3)
        self._watched_column = up if watching else None
        self._views = {}  # squarings -> the operands of each iteration reached (_iteration_views)
        # the powers of levels 1..s and where their traces go, per number of squarings s
        rows = max_iter * n
        self._trace_rows = [
            (self.powers_rows[rows : (s + 1) * rows], self.levels_flat[rows : (s + 1) * rows])
            for s in range(MAX_SQUARINGS + 1)
        ]
        # level 0 (the shifts) is written for this many iterations a step; a step that does more fills the rest
        self._level0_rows = min(max_iter, _LEVEL0_ROWS)

    def _iteration_views(self, s, upto):
        """Each iteration's operands with ``s`` squarings, up to iteration ``upto``, made as steps first reach them.

        An iteration's operands: its iterate and the next, the first and last powers, the rotations
        (and as 16 a cluster), the squarings' (input, output) pairs, the next z, the whole next
        iterate and its watched heights (column ``up``; None: no contact watches). (Made for every
        iteration and count of squarings up front, a backend with max_iter 5000 took 0.4 s to build.)
        """
        n, p, up = self.n, self.p, self._watched_column
        views = self._views.setdefault(s, [])
        views.extend(
            (
                self.Z[i, p:],
                self.Z[i + 1],
                self.powers[0, i].reshape(n, 16),
                self.powers[s, i].reshape(n, 16),
                self.R[i],
                self.R[i, : 4 * n].reshape(n, 16),
                tuple(zip(self.powers[:s, i], self.powers[1 : s + 1, i])),
                self.outputs[i + 1],
                self.Z[i + 1].reshape(-1),
                self.Z[i + 1, :p, up] if up is not None else None,
            )
            for i in range(len(views), upto)
        )
        return views

    @classmethod
    def build(cls, model, max_iter):
        """The Kronecker backend of a 3D model, or None if its operators do not factor.

        Parameters
        ----------
        model : Model
        max_iter : int
        """
        r = model.space.r
        muscles = model.A is not None and model.n_muscles
        G_all = np.vstack([model.G] + ([model.A[0]] if model.A is not None else []))
        W_all = np.hstack([model.W] + ([model.WA[0]] if model.A is not None else []))
        C = model.C
        Y, V = separable_rows(G_all), separable_columns(W_all)
        Pz_s, Pv_s = separable_square(C[:, :r]), separable_square(C[:, r : 2 * r])
        if Y is None or V is None or Pz_s is None or Pv_s is None:
            return None
        YA = VA = None
        if muscles:
            YA = [separable_rows(Ak) for Ak in model.A]
            VA = [separable_columns(Wk) for Wk in model.WA]
            if any(x is None for x in YA + VA):
                return None
            YA, VA = np.stack(YA), np.stack(VA)
        # each cluster's |F| at rest (1 where it is 0): rows are divided by it,
        # so that the powers neither overflow nor underflow
        rest = (G_all @ model.rest).reshape(-1, 9)
        scale = np.sqrt(np.einsum("ij,ij->i", rest, rest))
        scale = np.where(scale > 0.0, scale, 1.0)
        n_active = 0 if model.A is None else model.A.shape[1] // 9
        U, up = None, 0
        if getattr(model.contact, "watch", None) is not None:
            up = model.contact.up
            U = separable_watch(model.contact.watch, up)
            if U is None:
                return None
        start_terms = model.start_terms if model.corotated is not None else None
        C_ext = np.ascontiguousarray(C[:, 2 * r])
        return cls(Y, V, YA, VA, Pz_s, Pv_s, C_ext, scale, n_active, max_iter, U, up, start_terms)

    def start(self, z, z_dot, a) -> None:
        if self.activation is not None:
            self.activation.write(a)
        np.copyto(self.C_z, z)
        np.copyto(self.C_z_dot, z_dot)
        np.matmul(self.C_operator, self.C_input, self.C_slot)  # a strided slot: matmul
        if self.start_terms is not None:
            offset, shift = self.start_terms(z)
            self.C_slot += self.shift_operator @ shift.reshape(self.K, 3)
            # the offset's F[d, e] to the block's (e, d), scaled as the rows
            np.divide(offset.reshape(-1, 3, 3).transpose(0, 2, 1), self.passive_scale, out=self.offset_blocks)
        np.copyto(self.Z0, self.C_z_block)
        if not self.shifted:
            # |F| / sqrt(3), the root mean square singular value: the best
            # shift for a rotation (eigenvalues 3, -1, -1, -1 become 4, 0, 0, 0),
            # with a margin for the certificate (see finish)
            self.shift_column[:] = 0.0
            np.dot(self.Yt, self.Z[0, self.p :], self.F)
            shift = 1.1 * np.sqrt(np.einsum("ij,ij->i", self.F16, self.F16) / 3.0)
            self.shift_column[:] = shift
            np.multiply(shift, 4.0 / 1.05, self.levels[0, : self._level0_rows])
            self.shifted = True
        self.s = self.squarings  # fixed for the step: the certificate needs one count
        self.k = 0

    def start_row(self):
        return self.Z_rows[0]

    def restart(self, z) -> None:
        np.copyto(self.outputs[self.k], z.reshape(self.K, 3))

    def iterate(self, count, contact):
        Yt, Wt, F, F16 = self.Yt, self.Wt, self.F, self.F16
        RT, RT16, trace = self.RT, self.RT16, self.trace
        dot, matmul, divide = _dot, np.matmul, np.divide
        first = self.k
        layout = self.layout
        views = self._views.get(self.s, ())
        if len(views) < first + count:
            views = self._iteration_views(self.s, first + count)
        views = views[first : first + count]
        for Z_old, Z_new, P0, P_last, R, R16, squarings, z_new, state, watched in views:
            # dot for the 2D products: the same BLAS call as matmul, less dispatch
            dot(Yt, Z_old, F)
            dot(F16, HORN_BLOCK, P0)
            for P, P_squared in squarings:
                matmul(P, P, P_squared)
            dot(P_last, QQ_TO_BLOCK_TRACE, RT)
            divide(RT16, trace, R16)
            dot(Wt, R, Z_new)
            if contact is None:
                continue
            if layout is not None:
                contact.project(state, watched, layout)
            else:
                np.copyto(self.z_block, z_new)
                if contact.project(self.z_flat):
                    np.copyto(z_new, self.z_block)
        self.k = first + count
        return self.Z_rows[first : self.k + 1]

    def finish(self, k) -> bool:
        """Certify the rotations of the step's first ``k`` iterations (None: it went non-finite)."""
        s = self.s
        if k is not None:
            if k > self._level0_rows:
                self.levels[0, self._level0_rows : k] = self.levels[0, 0]
            if 2 * k >= self.max_batch:  # the traces of levels 1..s, all iterations: one matrix-vector product
                powers, traces = self._trace_rows[s]
                _dot(powers, EYE16, traces)
            else:  # those the step did (all of max_iter 5000 made a step 10 times slower)
                rows = k * self.n
                np.matmul(self.powers_levels[1 : s + 1, :rows], EYE16, out=self.levels_2d[1 : s + 1, :rows])
            ok, top, rho = certify_levels(self.levels_2d[: s + 1, : k * self.n], top_bound=1.05**2)
            if ok and not top:
                ok = bool(np.einsum("knab,knab->kn", self.powers[0, :k], self.powers[s, :k]).min() > 0.0)
        if k is None or not ok:
            self.squarings = min(s + 1, MAX_SQUARINGS)
            self.shifted = False
            return False
        self.squarings = next_squarings(rho, most=MAX_SQUARINGS)
        # the next step's shifts: |P|^2 = |N|^2 + 4 s^2, so s' = 1.05 |P| / 4
        # tends to 1.07 |N| / sqrt(12), just above the bound the certificate needs
        np.sqrt(self.levels[1, k - 1], self.levels[0, : self._level0_rows])  # |P| = 4 s' / 1.05, each iteration
        np.multiply(self.levels[0, 0], 1.05 / 4.0, self.shift_column)
        return True

    def result(self, k):
        return self.outputs[k].ravel()

    def carried(self) -> dict:
        """The next step's shifts and squarings, made from this one's powers (unpickled, a 3D run went on
        1e-16 off at its first step, 2.5e-12 after 300 steps of a crawl)."""
        return {"shifted": self.shifted, "squarings": self.squarings, "shift": self.shift_column.copy(),
                "levels": self.levels[0].copy()}  # fmt: skip

    def carry(self, state: dict) -> None:
        """Take :meth:`carried`'s, if it is for buffers of this size."""
        if state.get("levels") is None or state["levels"].shape != self.levels[0].shape:
            return
        self.shifted, self.squarings = state["shifted"], state["squarings"]
        self.shift_column[:] = state["shift"]
        self.levels[0] = state["levels"]
