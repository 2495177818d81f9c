"""Generalised symmetric eigenproblems and the conventions that make them reproducible.

Used by linear modal analysis (elasticity) and skinning eigenmodes
(Laplacian): the lowest eigenpairs of ``K v = lambda M v`` for a positive
semi-definite ``K``, a deterministic sign per vector, and a deterministic basis
inside groups of repeated eigenvalues.
"""

from __future__ import annotations

import warnings

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sps
import scipy.sparse.linalg as spla
from scipy.sparse.csgraph import reverse_cuthill_mckee

__all__ = [
    "lowest_eigenpairs",
    "canonical_eigenpairs",
    "eigenpairs_by_part",
    "spd_solver",
    "sign_convention",
    "canonical_repeated",
    "generic_weight",
    "weighted_basis",
]

# Eigenvalues closer than this (relative) form one repeated group.
_REPEATED_RTOL = 1e-8
# Entries within this fraction of a vector's largest magnitude tie for its sign.
_SIGN_TIE_RTOL = 1e-6
# The shift below zero, relative to a typical DOF's K_ii / M_ii, when the null space of K is known
# (given, if with no columns): near zero, because a thin body's lowest eigenvalues are. At 1e-6 a
# 1000:1 plate's all sat near 1 / sigma after inversion, and Lanczos took 5557 solves for 6 of them,
# against 33. Safe there only because the null space, which the solve multiplies by 1 / |sigma|, is
# projected out of both its right-hand side and its result (see _scaled_pairs_solver). With the
# null space unknown (None), K may be singular anywhere: the shift stays at 1e-6, where the
# eigenvalues keep 1e-9 of their digits (at 1e-10 a free body's lost some: 1.8e-9).
_SHIFT = 1e-10
_SHIFT_UNKNOWN_NULL = 1e-6
# Below this many DOFs, a dense solve is faster.
_DENSE_LIMIT = 600
# Factorisation speeds measured on this project's machine kind (one BLAS
# thread): LAPACK's banded Cholesky runs at about 25 GFlop/s, SuperLU at
# about 5 (docs/performance.md, "Set-up at the paper's scale"). The
# factorisation whose predicted time is smaller is used.
_BANDED_RATE = 25e9
_SPARSE_RATE = 5e9
# Never build a band of more entries than this (480 MB).
_BANDED_ENTRIES = 60_000_000


def _node_graph(A, node_dim: int) -> sps.csc_matrix:
    """The graph of ``A``'s nodes as a diagonally dominant M-matrix (safe to factor without pivoting)."""
    coo = A.tocoo()
    nodes = A.shape[0] // node_dim
    off = coo.row // node_dim != coo.col // node_dim
    G = sps.csr_matrix(
        (-np.ones(int(off.sum())), (coo.row[off] // node_dim, coo.col[off] // node_dim)), shape=(nodes, nodes)
    )
    G.data[:] = -1.0  # duplicates summed: back to one entry per edge
    degree = -np.asarray(G.sum(axis=1)).ravel()
    return (G + sps.diags(degree + 1.0)).tocsc()


def _dof_order(node_order: np.ndarray, node_dim: int) -> np.ndarray:
    """DOF permutation (new position -> old DOF) that keeps each node's DOFs together."""
    return (node_order[:, None] * node_dim + np.arange(node_dim)).ravel()


def _sparse_plan(G, node_dim: int):
    """A fill-reducing node ordering and the flops of a sparse factorisation with it.

    SuperLU's minimum-degree ordering is computed on the node graph ``G``
    (``node_dim`` times smaller than the matrix) by factoring it; the column
    counts of that factor predict the fill of the matrix's own factor, whose
    DOFs are then ordered node by node (giving SuperLU dense blocks).
    """
    lu = spla.splu(G, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    order = np.empty_like(lu.perm_c)
    order[lu.perm_c] = np.arange(order.size)
    counts = np.diff(lu.L.tocsc().indptr).astype(np.float64)
    return order, node_dim**3 * float((counts**2).sum())


def _banded_plan(G, node_dim: int):
    """Reverse Cuthill-McKee node ordering and the band (in DOFs) it gives the matrix."""
    order = reverse_cuthill_mckee(G.tocsr(), symmetric_mode=True)
    rank = np.empty(order.size, dtype=np.int64)
    rank[order] = np.arange(order.size)
    coo = G.tocoo()
    band = int(np.abs(rank[coo.row] - rank[coo.col]).max()) * node_dim + node_dim - 1
    return order, band


def _permuted(factor_solve, dof_order: np.ndarray | None, method: str):
    """``b -> x`` for ``A``, given the solve of ``A`` with rows and columns in ``dof_order`` (None: as is)."""
    if dof_order is None:

        def solve(b):
            return factor_solve(b)

    else:
        position = np.empty_like(dof_order)
        position[dof_order] = np.arange(dof_order.size)

        def solve(b):
            return factor_solve(b[dof_order])[position]

    solve.method = method
    return solve


def spd_solver(A, node_dim: int = 1):
    """A direct solver for a sparse symmetric positive definite ``A``: ``b -> A^{-1} b``.

    Two factorisations, chosen by their predicted time: LAPACK's banded
    Cholesky after a reverse Cuthill-McKee ordering (fast per flop, but the
    band of an unstructured 3D mesh is wide: 3.3 s on the 38689-tetrahedron
    seal, against 0.3 s sparse), and SuperLU with a minimum-degree ordering of
    the nodes and diagonal pivots (``A`` is SPD), each node's DOFs kept
    together. Both predictions come from the orderings alone (the band; the
    column counts of the node graph's factor), at the measured speeds
    ``_BANDED_RATE`` and ``_SPARSE_RATE``.

    Parameters
    ----------
    A : scipy.sparse matrix, shape (n, n)
        Symmetric positive definite.
    node_dim : int
        DOFs per node, interleaved (orderings work on nodes).

    Returns
    -------
    solve : callable
        ``solve(b)`` for ``b`` of shape (n,) or (n, m); its attribute
        ``method`` is ``"banded"`` or ``"sparse"``.

    Examples
    --------
    >>> import scipy.sparse as sps
    >>> A = sps.diags([-1.0, 2.5, -1.0], [-1, 0, 1], shape=(5, 5))
    >>> solve = spd_solver(A)
    >>> bool(np.allclose(A @ solve(np.ones(5)), 1.0))
    True
    """
    n = A.shape[0]
    if node_dim < 1 or n % node_dim:
        raise ValueError(f"node_dim must divide the matrix size {n}, got {node_dim}")
    A = A.tocsr()
    if node_dim == 1:
        # a scalar problem: its own graph is the node graph, and factoring it
        # to plan would double the cost
        lu = spla.splu(A.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
        return _permuted(lu.solve, None, "sparse")
    G = _node_graph(A, node_dim)
    band_order, band = _banded_plan(G, node_dim)
    banded_time = n * (band + 1) ** 2 / _BANDED_RATE
    sparse_order, sparse_flops = _sparse_plan(G, node_dim)
    if (band + 1) * n <= _BANDED_ENTRIES and banded_time < sparse_flops / _SPARSE_RATE:
        dofs = _dof_order(band_order, node_dim)
        Ap = A[dofs][:, dofs].tocoo()
        lower = Ap.row >= Ap.col
        ab = np.zeros((band + 1, n))
        ab[(Ap.row - Ap.col)[lower], Ap.col[lower]] = Ap.data[lower]
        try:
            factor = sla.cholesky_banded(ab, lower=True, check_finite=False)
        except np.linalg.LinAlgError:
            # not positive definite to round-off: a sliver element (a triangle 1e-12 high on a 0.125 edge)
            # stopped Cholesky; the pivoted sparse factorisation solves it as it solves any other
            pass
        else:
            return _permuted(lambda b: sla.cho_solve_banded((factor, True), b, check_finite=False), dofs, "banded")
    dofs = _dof_order(sparse_order, node_dim)
    lu = spla.splu(
        A[dofs][:, dofs].tocsc(), permc_spec="NATURAL", diag_pivot_thresh=0.0, options={"SymmetricMode": True}
    )
    return _permuted(lu.solve, dofs, "sparse")


def _dense_pairs(K, M, null, MN):
    """Every eigenpair, densely, ascending; in the M-orthogonal complement of ``null`` if given.

    Solved inverted, ``(K - sigma M)^-1 M v = theta v`` with ``theta = 1 / (lambda - sigma)``
    and ``sigma`` minus a typical DOF's ``K_ii / M_ii``: the lowest modes come out to
    round-off of that scale, as from the sparse shift-invert. Solved directly, their errors
    are round-off of the largest eigenvalue, which one thin element makes huge (a triangle
    1e-8 high on a beam's side turned its lowest bending mode's 0.467 into -9.27).
    """
    Kd, Md = K.toarray(), M.toarray()
    C = None
    if null is not None and null.shape[1]:
        # an orthonormal basis of the M-orthogonal complement of the null space
        C = sla.null_space(MN.T)
        Kd, Md = C.T @ Kd @ C, C.T @ Md @ C
    Kd, Md = (Kd + Kd.T) / 2, (Md + Md.T) / 2
    sigma = -float(np.median(np.diag(Kd) / np.diag(Md)))
    # symmetric, with M = L L^T: L^T (K - sigma M)^-1 L w = theta w, v = L^-T w (M-orthonormal);
    # the solve by LDL^T, which one thin element's near-singular K - sigma M does not stop
    L = np.linalg.cholesky(Md)
    with warnings.catch_warnings():  # ill-conditioned, as it should be: its large theta are what is wanted
        warnings.simplefilter("ignore", sla.LinAlgWarning)
        T = L.T @ sla.solve(Kd - sigma * Md, L, assume_a="sym")
    theta, W = np.linalg.eigh((T + T.T) / 2)
    theta, W = theta[::-1], W[:, ::-1]  # the largest theta: the lowest lambda
    with np.errstate(divide="ignore"):
        values = sigma + 1.0 / theta
    vectors = sla.solve_triangular(L, W, trans="T", lower=True)
    return values, (vectors if C is None else C @ vectors)


def _pairs_solver(K, M, node_dim: int, null):
    """``k -> (values, vectors)``: the ``k`` lowest eigenpairs, one factorisation for every ``k``.

    Solved on ``K`` and ``M`` scaled to unit size by powers of two (exact),
    then scaled back: the solver sees the same numbers whatever the units
    (a stiffness of 1e200 would otherwise underflow the Lanczos vectors'
    M-norms to zero). The eigenvalues come back infinite when the true ones
    are beyond float64.
    """
    k_exponent = _power_of_two(K.diagonal())
    m_exponent = _power_of_two(M.diagonal()) // 2
    K, M = _times_power_of_two(K, -k_exponent), _times_power_of_two(M, -2 * m_exponent)
    null = None if null is None else np.ldexp(null, m_exponent)
    solve_scaled = _scaled_pairs_solver(K, M, node_dim, null)

    def pairs(k):
        values, vectors = solve_scaled(k)
        with np.errstate(over="ignore"):
            return np.ldexp(values, k_exponent - 2 * m_exponent), np.ldexp(vectors, -m_exponent)

    return pairs


def _power_of_two(diagonal) -> int:
    """The exponent of the power of two nearest the median magnitude of a diagonal (0 if that is 0)."""
    median = float(np.median(np.abs(diagonal)))
    return int(np.round(np.log2(median))) if median > 0 else 0


def _times_power_of_two(A, exponent: int):
    """A sparse matrix times ``2**exponent``, exactly (a new matrix of the same format)."""
    A = A.copy()
    A.data = np.ldexp(A.data, exponent)
    return A


def _scaled_pairs_solver(K, M, node_dim: int, null):
    """:func:`_pairs_solver` on matrices of unit size."""
    n = K.shape[0]
    q = 0 if null is None else null.shape[1]
    MN = None if null is None else np.asarray(M @ null)
    if n <= _DENSE_LIMIT:
        all_values, all_vectors = _dense_pairs(K, M, null, MN)
        return lambda k: (all_values[:k], all_vectors[:, :k])
    # a shift just below zero: K - sigma M is positive definite even for a
    # free body, and the modes nearest sigma are the lowest ones (see _SHIFT)
    sigma = -(_SHIFT_UNKNOWN_NULL if null is None else _SHIFT) * float(np.median(K.diagonal() / M.diagonal()))
    solve = spd_solver(K - sigma * M, node_dim)
    if q:

        def deflated(b):
            # b is M v: v's null-space part goes before the solve, not only after it. Lanczos
            # vectors regain some of it from round-off, and the solve multiplies it by
            # 1 / |sigma| (1e10 of a typical 1 / lambda): projected away afterwards, it left
            # round-off of that size in the result, which fed the next vector more (a free cube's
            # 60 modes kept 1e-7 of rigid motion, and residuals of 1.6e-6, against 3e-14 now)
            x = solve(b - MN @ (null.T @ b))
            return x - null @ (MN.T @ x)

        op = spla.LinearOperator(K.shape, matvec=deflated, dtype=np.float64)
    else:
        op = spla.LinearOperator(K.shape, matvec=solve, dtype=np.float64)
    v0 = np.random.default_rng(20261121).standard_normal(n)
    if q:
        v0 -= null @ (MN.T @ v0)

    def shift_invert(k):
        if k + q >= n - 1:
            # ARPACK needs k < n - 1: every pair, densely
            all_values, all_vectors = _dense_pairs(K, M, null, MN)
            return all_values[:k], all_vectors[:, :k]
        # a slightly larger Krylov space than ARPACK's default saves restarts
        ncv = min(n - q, max(2 * k + 1, 20))
        try:
            values, vectors = spla.eigsh(K, k=k, M=M, sigma=sigma, which="LM", OPinv=op, v0=v0, ncv=ncv)
        except spla.ArpackNoConvergence as err:
            # many equal eigenvalues (20 identical separate squares: 0 of 7 converged) or a very thin body
            raise FloatingPointError(
                f"the eigen solver (ARPACK) found {len(err.eigenvalues)} of {k} modes before giving up: many "
                "nearly equal frequencies (a mesh of many identical separate parts) or a very thin body make "
                "shift-invert Lanczos stall; ask for fewer modes, or analyse the parts one at a time"
            ) from None
        order = np.argsort(values)
        return values[order], vectors[:, order]

    return shift_invert


def lowest_eigenpairs(K, M, k: int, node_dim: int = 1, null=None):
    """The ``k`` lowest eigenpairs of ``K v = lambda M v``, ascending.

    ``K`` symmetric positive semi-definite (a free body's stiffness, a
    Laplacian), ``M`` symmetric positive definite. Shift-invert Lanczos
    (:func:`scipy.sparse.linalg.eigsh`) about a shift just below zero, so a
    singular ``K`` is never factored (:func:`spd_solver` factors it); small
    problems are solved densely.

    Parameters
    ----------
    K, M : scipy.sparse matrix, shape (n, n)
    k : int
        ``1 <= k <= n - q``.
    node_dim : int
        DOFs per node, interleaved (orderings work on nodes).
    null : ndarray, shape (n, q), optional
        A known, M-orthonormal basis of the null space of ``K`` (rigid
        motions, constants). The solver then works in its M-orthogonal
        complement and returns the ``k`` lowest eigenpairs *there*: no effort
        is spent on the null space, which is known exactly. Given (``q = 0``
        for a ``K`` known to be definite), the shift sits near zero, as a thin
        body's lowest modes need; without it, ``K`` may be singular anywhere,
        and the shift keeps its distance (see ``_SHIFT``).

    Returns
    -------
    values : ndarray, shape (k,)
    vectors : ndarray, shape (n, k)
        M-orthonormal (and M-orthogonal to ``null``). Signs and
        repeated-eigenvalue bases are whatever the solver returns; see
        :func:`canonical_eigenpairs` for reproducible ones.
    """
    _check_count(K, k, null)
    return _pairs_solver(K, M, node_dim, null)(k)


def _check_count(K, k: int, null) -> None:
    n = K.shape[0]
    q = 0 if null is None else null.shape[1]
    if k < 1 or k + q > n:
        raise ValueError(f"cannot compute {k} eigenpairs besides {q} null vectors of a {n}-DOF problem")


def _group_end(values: np.ndarray, i: int, scale: float) -> int:
    """One past the last eigenvalue in the repeated group that holds ``values[i]``."""
    stop = i + 1
    while stop < values.size and _repeated(values[stop - 1], values[stop], scale):
        stop += 1
    return stop


def _repeated(a: float, b: float, scale: float) -> bool:
    """Whether neighbouring eigenvalues ``a <= b`` belong to one repeated group."""
    return abs(b - a) <= _REPEATED_RTOL * max(abs(b), 1e-3 * scale)


def canonical_eigenpairs(K, M, k: int, weight, node_dim: int = 1, null=None):
    """The ``k`` lowest eigenpairs with a reproducible basis: the same on every machine.

    Like :func:`lowest_eigenpairs`, then :func:`canonical_repeated` and
    :func:`sign_convention`. A repeated group that the ``k``-th eigenvalue
    belongs to is solved whole before the basis is fixed (a few more pairs
    are computed until one beyond the group is found), so which vectors of a
    cut group are kept does not depend on the solver.

    Parameters
    ----------
    K, M : scipy.sparse matrix, shape (n, n)
    k : int
    weight : ndarray, shape (n,)
        :func:`generic_weight` of the nodes.
    node_dim : int
    null : ndarray, shape (n, q), optional
        See :func:`lowest_eigenpairs`.

    Returns
    -------
    values : ndarray, shape (k,)
    vectors : ndarray, shape (n, k)
        M-orthonormal, M-orthogonal to ``null``.

    Examples
    --------
    >>> from skfem import MeshTri
    >>> from skfem_modal.subspace import laplacian
    >>> from skfem_modal.fem import _mass
    >>> square = MeshTri.init_symmetric().refined(2)  # symmetric: repeated eigenvalues
    >>> M = _mass(square, 1.0, True, "P1", False)
    >>> values, _ = canonical_eigenpairs(laplacian(square), M, 3, generic_weight(square.p.T, 1))
    >>> bool(values[1] == values[2])
    True
    """
    _check_count(K, k, null)
    available = K.shape[0] - (0 if null is None else null.shape[1])
    pairs = _pairs_solver(K, M, node_dim, null)
    extra = 1  # one more pair tells whether the k-th one's group goes on
    while True:
        count = min(k + extra, available)
        values, vectors = pairs(count)
        scale = max(float(np.abs(values).max()), 1e-300)
        end = _group_end(values, k - 1, scale)
        if end < count or count == available:
            break
        extra *= 2
    values, vectors = canonical_repeated(values[:end].copy(), vectors[:, :end].copy(), M, weight)
    return values[:k], sign_convention(vectors[:, :k])


def sign_convention(modes: np.ndarray) -> np.ndarray:
    """Flip each column so its largest entry is positive (deterministic sign).

    Among the entries whose magnitude is within 1e-6 (relative) of the largest,
    the one with the lowest index decides; ties from symmetric meshes are thus
    resolved by DOF order, not by round-off.

    Parameters
    ----------
    modes : ndarray, shape (n_dofs, k)

    Returns
    -------
    modes : ndarray, shape (n_dofs, k)
        A copy with signs fixed.
    """
    out = np.array(modes, dtype=np.float64, copy=True)
    if out.ndim != 2:  # (one mode is a column: a 1-D array was an IndexError)
        raise ValueError(f"modes must have shape (n_dofs, k), got {out.shape}")
    mag = np.abs(out)
    top = mag.max(axis=0)
    for col in range(out.shape[1]):
        if top[col] == 0:
            continue
        first = np.argmax(mag[:, col] >= (1.0 - _SIGN_TIE_RTOL) * top[col])
        if out[first, col] < 0:
            out[:, col] *= -1.0
    return out


def generic_weight(x: np.ndarray, components: int | None = None) -> np.ndarray:
    """A smooth, generic positive weight per DOF, shape (n * components,).

    Used to split repeated eigenvalues deterministically: it has no symmetry a
    mesh can share (different along each axis and for each component).

    Parameters
    ----------
    x : ndarray, shape (n, dim)
        Node positions.
    components : int, optional
        DOFs per node, interleaved: ``dim`` for vector fields (the default),
        1 for scalar ones.

    Returns
    -------
    weight : ndarray, shape (n * components,)
    """
    n, dim = x.shape
    components = dim if components is None else components
    lo, hi = x.min(axis=0), x.max(axis=0)
    xi = (x - (lo + hi) / 2) / np.maximum((hi - lo) / 2, 1e-300)
    lin = np.array([0.31, 0.17, 0.11])[:dim]
    quad = np.array([0.23, 0.37, 0.29])[:dim]
    f = 1.0 + 0.1 * xi @ lin + 0.05 * (xi**2) @ quad
    if dim >= 2:
        f += 0.013 * xi[:, 0] * xi[:, 1]
    if dim == 3:
        f += 0.007 * xi[:, 1] * xi[:, 2] + 0.019 * xi[:, 0] * xi[:, 2]
    comp = 1.0 + 0.03 * np.arange(components)
    return (f[:, None] * comp[None, :]).ravel()


def weighted_basis(V, M, weight):
    """The basis of an M-orthonormal ``V``'s span that diagonalises a generic ``weight`` on it.

    Unique up to sign and the same whatever basis of the span ``V`` is given
    (the solver's, the vertex numbering's): the weight has no symmetry to share.

    Parameters
    ----------
    V : ndarray, shape (n, g)
        M-orthonormal columns.
    M : scipy.sparse matrix, shape (n, n)
    weight : ndarray, shape (n,)
        :func:`generic_weight`.

    Returns
    -------
    basis : ndarray, shape (n, g)
        M-orthonormal, in ascending order of the weight's values on it.
    """
    S = V.T @ (M @ (weight[:, None] * V))
    _, Q = np.linalg.eigh((S + S.T) / 2)
    return V @ Q


def canonical_repeated(values, vectors, M, weight):
    """Fix the basis inside every group of repeated eigenvalues.

    Within a group (consecutive eigenvalues closer than 1e-8 relative) the
    eigenvectors are only defined up to a rotation. The group's basis is made
    unique (up to sign) by diagonalising the generic weight ``weight`` on it.

    Parameters
    ----------
    values : ndarray, shape (k,), ascending
    vectors : ndarray, shape (n, k), M-orthonormal
    M : scipy.sparse matrix, shape (n, n)
    weight : ndarray, shape (n,)
        Positive, position-dependent, without the mesh's symmetries
        (:func:`generic_weight`).

    Returns
    -------
    values, vectors : ndarray
        Repeated eigenvalues replaced by their group mean; vectors still
        M-orthonormal and spanning the same spaces.
    """
    k = values.size
    start = 0
    scale = max(float(np.abs(values).max(initial=0.0)), 1e-300)
    while start < k:
        stop = _group_end(values, start, scale)
        if stop - start > 1:
            vectors[:, start:stop] = weighted_basis(vectors[:, start:stop], M, weight)
            values[start:stop] = values[start:stop].mean()
        start = stop
    return values, vectors


def eigenpairs_by_part(K, M, known, count: int, weight, node_dim: int, part_of_row):
    """The ``count`` lowest eigenpairs beside the ``known`` null space, part by part of a mesh of several.

    ``K`` and ``M`` are block-diagonal by part: each part is solved alone for its own lowest pairs, then
    the lowest of all are kept, a repeated group whole before its basis is fixed (:func:`canonical_repeated`).
    Identical parts repeat every eigenvalue: solved together, 20 squares made shift-invert Lanczos give up
    with 1 of 7 modes, and return 15 of a group of 40 copies followed by the next value (the group's basis
    then changed with the vertices' numbering).

    Parameters
    ----------
    K, M : scipy.sparse matrix, shape (n, n)
    known : ndarray, shape (n, q)
        The null space of ``K`` (each column on one part).
    count : int
    weight : ndarray, shape (n,)
        :func:`generic_weight`'s, for repeated groups.
    node_dim : int
    part_of_row : ndarray of int, shape (n,)
        Each row's part.

    Returns
    -------
    values : ndarray, shape (count,)
    vectors : ndarray, shape (n, count)
        As :func:`canonical_eigenpairs`'s.
    """
    parts = np.unique(part_of_row)
    if parts.size == 1:
        return canonical_eigenpairs(K, M, count, weight, node_dim, null=known)  # known: the whole null space
    K, M = K.tocsr(), M.tocsr()
    found = []  # (value, rows, vector on them)
    for part in parts:
        rows = np.flatnonzero(part_of_row == part)
        null = known[rows][:, np.abs(known[rows]).max(axis=0, initial=0.0) > 0]
        wanted = min(count, rows.size - null.shape[1])
        if wanted:
            part_values, part_vectors = canonical_eigenpairs(
                K[rows][:, rows], M[rows][:, rows], wanted, weight[rows], node_dim, null
            )
            found += [(value, rows, part_vectors[:, i]) for i, value in enumerate(part_values)]
    values = np.array([value for value, _, _ in found])
    order = np.argsort(values, kind="stable")  # ties in part order
    end = _group_end(values[order], count - 1, max(float(np.abs(values).max()), 1e-300))
    vectors = np.zeros((K.shape[0], end))
    for column, i in enumerate(order[:end]):
        vectors[found[i][1], column] = found[i][2]
    values, vectors = canonical_repeated(values[order[:end]], vectors, M, weight)
    return values[:count], sign_convention(vectors[:, :count])
