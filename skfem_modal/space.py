"""Where a simulator's unknowns live: a subspace ``x = B z``, or every DOF of the mesh.

The effects (:mod:`skfem_modal.effects`) describe their terms on the mesh:
a lumped mass, a weighted Laplacian-type Hessian ``J^T (w x I) J``, sparse
maps from positions to cluster sums of deformation gradients, forces, rows of
vertices. A space turns each of these into the operator that acts on its
unknowns: dense ``B^T (.) B`` products in a :class:`Subspace` (made a few
rows or columns at a time, so no dense copy of a mesh-sized matrix is ever
held), the sparse operators themselves in the :class:`FullSpace`. The same
effect code thus builds the reduced simulator and the full-space reference.
"""

from __future__ import annotations

from functools import cached_property

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sps
import scipy.sparse.linalg as spla

from .fem import _jacobian, scalar_basis, vector_dofs
from .mesh import _signed_measures

__all__ = ["Subspace", "FullSpace"]


class _MeshData:
    """What both spaces read off the mesh: sizes, volumes, J, P1 gradients."""

    def __init__(self, mesh):
        self.mesh = mesh
        self.dim, self.n = mesh.p.shape
        self.n_elements = mesh.t.shape[1]
        self.N = self.n * self.dim

    @cached_property
    def volumes(self) -> np.ndarray:
        """Element volumes, shape (nT,)."""
        return np.abs(_signed_measures(self.mesh.p, self.mesh.t))

    @cached_property
    def J(self) -> sps.csr_matrix:
        """The deformation Jacobian, shape (nT * dim * dim, N)."""
        return _jacobian(self.mesh, "P1")

    @cached_property
    def rest(self) -> np.ndarray:
        """Rest positions, interleaved, shape (N,)."""
        return self.mesh.p.T.ravel()

    def __getstate__(self):
        # what is read off the mesh is made again where it is needed (J is as large as the mesh)
        state = self.__dict__.copy()
        for cached in ("J", "volumes", "rest", "_gradients", "scalar_fields"):
            state.pop(cached, None)
        return state

    def dofs(self, vertices) -> np.ndarray:
        """Interleaved DOF indices of ``vertices`` (ndarray of int, (p,)), vertex-major, shape (p dim,)."""
        return vector_dofs(vertices, self.dim)

    def com_rows(self, mass) -> np.ndarray:
        """The centre of mass as a linear map of the unknowns, shape (dim, r), for the lumped ``mass`` (N,)."""
        selector = np.zeros((self.N, self.dim))
        for axis in range(self.dim):
            selector[axis :: self.dim, axis] = mass[axis :: self.dim]
        return np.asarray(self.force(selector)).T / mass[:: self.dim].sum()

    def full_positions(self, x) -> np.ndarray:
        """A full interleaved field ``x`` (N,) as vertex positions, shape (n, dim)."""
        return np.asarray(x, float).reshape(-1, self.dim)


class Subspace(_MeshData):
    """A reduced space: positions ``x = B z``.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    B : ndarray, shape (n * dim, r)
        Interleaved rows (vertex-major).
    """

    dense = True

    def __init__(self, mesh, B):
        super().__init__(mesh)
        self.B = B
        self.r = B.shape[1]

    @cached_property
    def _gradients(self) -> np.ndarray:
        """P1 basis gradients per element, shape (dim + 1, dim, nT)."""
        basis = scalar_basis(self.mesh, "P1")
        return np.stack([phi[0].grad[..., 0] for phi in basis.basis])

    def gram(self, diagonal) -> np.ndarray:
        """``B^T diag(diagonal) B``, shape (r, r), a few rows of ``B`` at a time (no copy of ``B``).

        ``diagonal`` (N,): per interleaved DOF, a lumped mass for instance.
        """
        B = self.B
        out = np.zeros((self.r, self.r))
        rows = max(1, int(2e6 // max(self.r, 1)))
        for start in range(0, B.shape[0], rows):
            Bc = B[start : start + rows]
            out += (Bc * diagonal[start : start + rows, None]).T @ Bc
        return (out + out.T) / 2

    def elastic_hessian(self, weights) -> np.ndarray:
        """``B^T J^T (w x I) J B``, shape (r, r): ``sum_i B_i^T L_w B_i`` with ``L_w`` the w-weighted Laplacian.

        ``weights`` (nT,): per element, ``w`` (a stiffness times the element's volume, say).
        """
        dim, n, t = self.dim, self.n, self.mesh.t
        grads = self._gradients
        vals = np.einsum("ake,bke->abe", grads, grads) * weights
        rows = np.broadcast_to(t[:, None, :], vals.shape).ravel()
        cols = np.broadcast_to(t[None, :, :], vals.shape).ravel()
        L = sps.csr_matrix((vals.ravel(), (rows, cols)), shape=(n, n))
        Bv = self.B.reshape(n, dim, -1)
        H = np.zeros((self.r, self.r))
        # a few columns at a time: the temporaries stay near 16 MB on any mesh
        width = max(1, int(1e6 // max(n, 1)))
        for i in range(dim):
            for start in range(0, self.r, width):
                block = np.ascontiguousarray(Bv[:, i, start : start + width])
                H[:, start : start + width] += Bv[:, i].T @ (L @ block)
        return (H + H.T) / 2

    def through(self, T) -> np.ndarray:
        """``T @ B`` for a sparse ``T`` with few rows, dense, shape (rows, r).

        Densified a few rows at a time (a dense product is twice as fast as
        the sparse one here), so the dense copy stays near 16 MB on any mesh.
        """
        T = sps.csr_matrix(T)
        rows, N = T.shape
        out = np.empty((rows, self.r))
        chunk = max(1, int(2e6 // max(N, 1)))
        for start in range(0, rows, chunk):
            out[start : start + chunk] = T[start : start + chunk].toarray() @ self.B
        return out

    def force(self, f) -> np.ndarray:
        """``B^T f`` for a full field (or fields) ``f`` of shape (N,) or (N, k)."""
        return self.B.T @ f

    def rows(self, dofs) -> np.ndarray:
        """The rows of ``B`` of some interleaved ``dofs`` (ndarray of int), shape (len(dofs), r)."""
        return np.ascontiguousarray(self.B[dofs])

    @cached_property
    def scalar_fields(self):
        """``U`` (n, K) when ``B`` moves every coordinate alike (``B = U kron I``, as skinning bases do), else None."""
        dim, K = self.dim, self.r // self.dim
        if self.r % dim:
            return None
        B4 = self.B.reshape(self.n, dim, K, dim)
        U = B4[:, 0, :, 0]
        scale = np.abs(self.B).max(initial=0.0)
        for a in range(dim):
            for b in range(dim):
                expected = U if a == b else 0.0
                if np.abs(B4[:, a, :, b] - expected).max(initial=0.0) > 1e-12 * scale:
                    return None
        return np.ascontiguousarray(U)

    def heights(self, vertices, up) -> Heights:
        """A reader of the ``vertices``' (ndarray of int) coordinate ``up`` (int) from ``z``.

        A few flops a vertex for skinning bases (:attr:`scalar_fields`).
        """
        U = self.scalar_fields
        if U is not None:
            return Heights(U[vertices], slice(up, None, self.dim))
        return Heights(self.rows(self.dofs(vertices)[up :: self.dim]), slice(None))

    def coordinates(self, x, mass) -> np.ndarray:
        """Coordinates ``z`` (r,) of a full field ``x`` (N,) in the span of ``B``, by least squares weighted by
        ``mass`` (N,)."""
        MB = self.B * mass[:, None]
        return np.linalg.solve(self.B.T @ MB, MB.T @ np.asarray(x, float).ravel())

    def positions(self, z) -> np.ndarray:
        """Vertex positions ``B z`` of a state ``z`` (r,), shape (n, dim)."""
        return (self.B @ np.asarray(z, float)).reshape(-1, self.dim)

    def factor(self, H) -> DenseSystem:
        """The system matrix ``H`` (r, r) factored: a :class:`DenseSystem`."""
        return DenseSystem(H)


class FullSpace(_MeshData):
    """Every DOF of the mesh is an unknown: operators stay sparse, the system is factored sparse.

    The reference a :class:`Subspace` is checked against (its methods are the same, with ``B = I``).

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    """

    dense = False

    def __init__(self, mesh):
        super().__init__(mesh)
        self.r = self.N

    def gram(self, diagonal) -> sps.csr_matrix:
        """``diag(diagonal)`` for ``diagonal`` (N,), sparse (N, N)."""
        return sps.diags(np.asarray(diagonal, float), format="csr")

    def elastic_hessian(self, weights) -> sps.csr_matrix:
        """``J^T (w x I) J``, sparse (N, N), for the per-element ``weights`` ``w`` (nT,)."""
        W = sps.diags(np.repeat(weights, self.dim * self.dim))
        return (self.J.T @ W @ self.J).tocsr()

    def through(self, T) -> sps.csr_matrix:
        """A sparse operator ``T`` (rows, N) itself, as CSR."""
        return sps.csr_matrix(T)

    def force(self, f):
        """A full field (or fields) ``f``, (N,) or (N, k), itself."""
        return f

    def rows(self, dofs) -> sps.csr_matrix:
        """Selector rows of some interleaved ``dofs`` (ndarray of int), sparse (len(dofs), N)."""
        dofs = np.asarray(dofs)
        return sps.csr_matrix((np.ones(dofs.size), (np.arange(dofs.size), dofs)), shape=(dofs.size, self.N))

    def heights(self, vertices, up) -> Heights:
        """A reader of the ``vertices``' (ndarray of int) coordinate ``up`` (int): the DOFs themselves."""
        return Heights(None, np.asarray(vertices) * self.dim + up)

    def coordinates(self, x, mass) -> np.ndarray:
        """A full field ``x`` as the unknowns, a copy of shape (N,) (``mass`` unused: every DOF is free)."""
        return np.array(x, dtype=float).ravel()

    def positions(self, x) -> np.ndarray:
        """Vertex positions of a state ``x`` (N,), shape (n, dim)."""
        return self.full_positions(x)

    def factor(self, H) -> SparseSystem:
        """The sparse system matrix ``H`` (N, N) factored: a :class:`SparseSystem`."""
        return SparseSystem(H)


# magnitudes whose products single precision holds with room to spare (it overflows at 2^128)
_SINGLE_RANGE = 2.0**100


class Heights:
    """Reads one coordinate of some vertices from the unknowns: ``rows @ z[pick]``, or ``z[pick]`` itself.

    Parameters
    ----------
    rows : ndarray of shape (p, q), or None
    pick : slice or ndarray of int
        Which entries of ``z`` the rows act on (all of them, every ``dim``-th one, or the vertices' own DOFs).
    """

    #: rows from which :meth:`above` reads in single precision first (below that, the product costs less)
    SCREEN = 2000
    _single = None  # the rows in single precision and their error bound, made when first needed (above)

    def __init__(self, rows, pick):
        self.rows, self.pick = rows, pick

    def __getstate__(self):
        state = self.__dict__.copy()
        state.pop("_single", None)  # made again where needed
        return state

    def __call__(self, z, which=None) -> np.ndarray:
        """The vertices' coordinates, shape (p,); or only those of ``which`` (indices into the vertices)."""
        picked = z[self.pick]
        if which is None:
            return picked if self.rows is None else self.rows @ picked
        return picked[which] if self.rows is None else self.rows[which] @ picked

    def above(self, z, floor) -> np.ndarray:
        """The coordinates (p,) of a state ``z`` (r,), in double precision wherever one may be below its ``floor`` (p,).

        For many rows, a product that reads each once a step (the seal's 6227 boundary vertices:
        1.6 MB) is made in single precision first, half the bytes, then again in double precision
        (``self(z, near)``) for the vertices within single precision's error of their floor: the
        others are above it for certain. A float32 dot product of ``q`` terms, its inputs rounded
        too, is off by at most ``(q + 3) u sum_s |U_s z_s|`` (``u = 2^-24``; Higham, *Accuracy and
        Stability of Numerical Algorithms*, 3.1), bounded here by the largest row's absolute sum
        times ``max |z_s|``; underflow (inputs, products and sums below ``2^-126``, flushed to zero
        or not) adds at most ``2^-126`` for each of them; the bound is taken twice. Rows or states
        whose products single precision could overflow are read in double precision only. So
        ``above(z, floor) < floor`` is ``self(z, which) < floor`` for each vertex ``which`` (a
        product over some rows alone can round a unit in the last place apart from one over all).

        >>> import numpy as np
        >>> rows = np.random.default_rng(0).random((3000, 8)); heights = Heights(rows, slice(None))
        >>> z = np.ones(8); floor = np.full(3000, np.median(rows @ z))
        >>> found = heights.above(z, floor); near = np.flatnonzero(found < floor + 1e-6)
        >>> bool(np.array_equal(found < floor, heights(z) < floor)), bool(np.all(found[near] == heights(z, near)))
        (True, True)
        """
        rows = self.rows
        if rows is None or rows.shape[0] < self.SCREEN:
            return self(z)
        if self._single is None:
            largest = float(np.abs(rows).sum(axis=1).max())
            # False: rows single precision cannot hold, read in double precision every time
            self._single = (rows.astype(np.float32), largest) if largest < _SINGLE_RANGE else False
        if self._single is False:
            return self(z)
        single, largest = self._single
        picked = z[self.pick]
        reach = float(np.abs(picked).max())
        if not (reach < _SINGLE_RANGE and largest * reach < _SINGLE_RANGE):  # also non-finite
            return self(z)
        q = rows.shape[1]
        margin = 2.0 * ((q + 3) * 2.0**-24 * largest * reach + (q * reach + largest + 2 * q) * 2.0**-126)
        values = (single @ picked.astype(np.float32)).astype(np.float64)
        near = np.flatnonzero(values < floor + margin)
        if near.size:
            values[near] = self(z, near)
        return values

    def __len__(self) -> int:
        return len(self.pick) if self.rows is None else self.rows.shape[0]


class DenseSystem:
    """The reduced system matrix, Cholesky-factored, and its dense inverse (``r`` is small).

    Raises
    ------
    ValueError
        When ``H`` is not positive definite (a basis without full column rank).
    """

    dense = True

    def __init__(self, H):
        H = (H + H.T) / 2
        self.matrix = H
        try:
            chol = sla.cho_factor(H)
        except np.linalg.LinAlgError:
            raise ValueError(
                "the reduced system matrix is not positive definite: check that B has full column rank"
            ) from None
        self.inverse = sla.cho_solve(chol, np.eye(H.shape[0]))
        # a factor of a numerically singular matrix can pass with round-off pivots
        if not np.abs(H).max() * np.abs(self.inverse).max() < 1e14:
            raise ValueError("the reduced system matrix is singular to working precision")

    def solve(self, X) -> np.ndarray:
        """``H^-1 X`` for dense ``X`` of shape (r,) or (r, k)."""
        return self.inverse @ X


class SparseSystem:
    """The full-space system matrix, factored once (sparse LU, symmetric mode).

    Parameters
    ----------
    H : sparse matrix, shape (N, N)
        Symmetric positive definite.
    """

    dense = False

    def __init__(self, H):
        self.matrix = sps.csc_matrix(H)
        self._factor()

    def _factor(self) -> None:
        self._lu = spla.splu(
            self.matrix.copy(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True}
        )

    # SuperLU objects cannot be pickled: a copy keeps the matrix and factors it again (the same factors:
    # the same matrix, ordering and pivoting), so simulators holding one can be pickled and deep-copied
    def __getstate__(self) -> dict:
        return {"matrix": self.matrix}

    def __setstate__(self, state: dict) -> None:
        self.matrix = state["matrix"]
        self._factor()

    def solve(self, X) -> np.ndarray:
        """``H^-1 X`` for ``X`` (dense or sparse) of shape (N,) or (N, k), dense."""
        X = X.toarray() if sps.issparse(X) else np.asarray(X, dtype=np.float64)
        return self._lu.solve(X)
