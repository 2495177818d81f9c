"""The reduced subspace: skinning eigenmodes, linear-blend basis, mass orthonormalisation.

Positions live in the span of a basis ``B``: ``x = B z``. The basis is linear
blend skinning over smooth weights: every weight ``w_k`` carries its own affine
map, so ``x_i = sum_k w_ik A_k [X_i; 1]`` and the reduced coordinates ``z`` are
the entries of the ``A_k``. The weights are the lowest eigenfunctions of the
scalar Laplacian (the constant first, which gives rigid and affine motions);
they are smooth, so a few of them describe large, rotating deformations.
"""

from __future__ import annotations

import warnings

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sps
from skfem import asm
from skfem.models.poisson import laplace

from .eigen import eigenpairs_by_part, generic_weight
from .fem import _mass, scalar_basis
from .mesh import check_mesh, connected_parts
from .values import is_whole

__all__ = [
    "laplacian",
    "skinning_eigenmodes",
    "lbs_basis",
    "mass_orthonormalize",
    "project",
    "com_operator",
]


def laplacian(mesh) -> sps.csr_matrix:
    """The scalar cotangent Laplacian: scikit-fem's ``laplace`` form with P1.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
        Checked (:func:`~skfem_modal.mesh.check_mesh`).

    Returns
    -------
    L : scipy.sparse.csr_matrix, shape (n, n)
        Symmetric positive semi-definite; constants are its null space.

    Raises
    ------
    TypeError, MeshError
        A mesh that cannot be used (:func:`~skfem_modal.mesh.check_mesh`).
    """
    check_mesh(mesh)
    return asm(laplace, scalar_basis(mesh, "P1")).tocsr()


def lbs_basis(positions, weights) -> np.ndarray:
    """Linear-blend-skinning basis of a set of weights.

    ``x_i = sum_k w_ik A_k [X_i; 1]`` is linear in the entries of the affine
    maps ``A_k`` (dim x (dim + 1) each): ``x = B z``.

    Parameters
    ----------
    positions : ndarray, shape (n, dim)
        Rest positions ``X``.
    weights : ndarray, shape (n, k)

    Returns
    -------
    B : ndarray, shape (n * dim, k * (dim + 1) * dim)
        Interleaved rows (vertex-major); column ``(k * (dim + 1) + j) * dim + b``
        moves coordinate ``b`` by ``w_k`` times homogeneous coordinate ``j``.

    Examples
    --------
    >>> X = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    >>> B = lbs_basis(X, np.ones((3, 1)))  # one constant weight: affine maps
    >>> B.shape
    (6, 6)
    >>> z = np.array([1.0, 0.0, 0.0, 1.0, 0.0, 0.0])  # A = [I | 0]
    >>> (B @ z).reshape(3, 2).tolist() == X.tolist()
    True
    """
    X = np.asarray(positions, dtype=np.float64)
    W = np.asarray(weights, dtype=np.float64)
    n, dim = X.shape
    if W.ndim != 2 or W.shape[0] != n:
        raise ValueError(f"weights must have shape ({n}, k), got {W.shape}")
    X1 = np.hstack([X, np.ones((n, 1))])
    scalar = (W[:, :, None] * X1[:, None, :]).reshape(n, -1)  # (n, k (dim + 1))
    B = np.zeros((n, dim, scalar.shape[1], dim))
    for b in range(dim):
        B[:, b, :, b] = scalar
    return B.reshape(n * dim, -1)


def weight_count_problem(n_vertices: int, n_parts: int, k: int) -> str | None:
    """What ``k`` skinning weights must be on a mesh (a phrase after "must be"), or None when they fit.

    Fewer than the vertices, and at least one per connected part (each part
    needs its own constant weight to move on its own): the rule of
    :func:`skinning_eigenmodes` and a scene's ``subspace.weights`` and
    ``subspace.cluster_weights`` checks.

    Parameters
    ----------
    n_vertices : int
        The mesh's number of vertices.
    n_parts : int
        Its number of connected parts (:func:`~skfem_modal.mesh.connected_parts`).
    k : int
        The number of skinning weights asked for, a whole number (checked by the caller).

    Returns
    -------
    problem : str or None

    Examples
    --------
    >>> weight_count_problem(64, 1, 8) is None
    True
    >>> weight_count_problem(64, 1, 100)
    "in 1..63 (fewer than the mesh's 64 vertices)"
    """
    if not 1 <= k < n_vertices:
        return f"in 1..{n_vertices - 1} (fewer than the mesh's {n_vertices} vertices)"
    if k < n_parts:
        return (
            f"at least the mesh's {n_parts} separate parts (one constant weight each, so every part can move on "
            "its own)"
        )
    return None


def skinning_eigenmodes(mesh, k: int, rho=1.0):
    """Skinning eigenmodes: Laplacian eigenfunctions as weights, and their LBS basis.

    The lowest ``k`` eigenpairs of ``L w = lambda M w`` with ``L`` the scalar
    cotangent Laplacian (:func:`laplacian`) and ``M`` the lumped scalar mass.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    k : int
        Number of weights, ``1 <= k < n``.
    rho : float or ndarray of shape (nT,)
        Density of the mass matrix (a uniform density only scales weights).

    Returns
    -------
    eigenvalues : ndarray, shape (k,)
        Ascending; the first is 0 (the constant weight), and one more 0 for
        each further connected part.
    weights : ndarray, shape (n, k)
        M-orthonormal, deterministic signs (:func:`~skfem_modal.eigen.sign_convention`).
    B : ndarray, shape (n * dim, k * (dim + 1) * dim)
        The linear-blend-skinning basis of the weights (:func:`lbs_basis`)
        for the positions relative to the mesh's bounding-box centre (the
        same span as for the positions themselves, without their round-off
        far from the origin), not yet mass-orthonormal.

    Examples
    --------
    >>> from skfem_modal.mesh import caterpillar
    >>> vals, W, B = skinning_eigenmodes(caterpillar(), 8)
    >>> B.shape
    (3438, 48)
    >>> [round(float(v), 6) for v in vals[1:4]]
    [1.122035, 2.881554, 3.646288]
    """
    check_mesh(mesh)
    n = mesh.p.shape[1]
    if not is_whole(k):
        raise TypeError(f"k (the number of skinning weights) must be an integer, got {type(k).__name__}")
    parts = connected_parts(mesh)
    n_parts = int(parts.max()) + 1
    problem = weight_count_problem(n, n_parts, k)
    if problem:
        raise ValueError(f"k (the number of skinning weights) must be {problem}, got {k}")
    L = laplacian(mesh)
    M = _mass(mesh, rho, True, "P1", False)
    # the first eigenfunctions are known exactly: the constant on each
    # connected part (eigenvalue 0); the solver only looks for the others
    m = M.diagonal()
    indicators = np.zeros((n, n_parts))
    indicators[np.arange(n), parts] = 1.0
    indicators /= np.sqrt(m @ indicators)
    values = np.einsum("ij,ij->j", indicators, L @ indicators)
    W = indicators
    if k > n_parts:
        # part by part (identical parts repeat every eigenvalue, more than Lanczos resolves at once)
        found, vectors = eigenpairs_by_part(L, M, indicators, k - n_parts, generic_weight(mesh.p.T, 1), 1, parts)
        values, W = np.concatenate([values, found]), np.hstack([indicators, vectors])
    # the homogeneous coordinate beside positions of the body's own size (the same span): far
    # from the origin, X and 1 would be nearly dependent columns, and Gram-Schmidt would
    # drop the affine ones (a caterpillar moved by 1e6 lost 12 of 36 and moved 8 % off)
    centre = (mesh.p.min(axis=1) + mesh.p.max(axis=1)) / 2
    return values, W, lbs_basis(mesh.p.T - centre, W)


def mass_orthonormalize(B, M, overwrite: bool = False) -> np.ndarray:
    """Make the columns of ``B`` orthonormal in the mass inner product.

    Gram-Schmidt in column order (a QR factorisation of ``M^(1/2) B`` for a
    diagonal ``M``, a Cholesky factor of ``B^T M B`` otherwise), so
    ``B'^T M B' = I`` and every leading set of columns spans what it spanned
    before. Columns that depend linearly on others are dropped, with a
    warning; then which go is a rank-revealing factorisation's choice (a
    pivoted QR, or the eigenvectors of ``B^T M B``), the kept ones span all
    of ``B``'s columns, and the leading ones no longer keep their own span.

    Parameters
    ----------
    B : ndarray, shape (N, r)
    M : scipy.sparse matrix or ndarray, shape (N, N)
        Symmetric positive definite.
    overwrite : bool
        Work in ``B``'s own memory (it is destroyed): no copy of a large basis.

    Returns
    -------
    B : ndarray, shape (N, r'), r' <= r
    """
    B = np.asarray(B, dtype=np.float64)
    if B.ndim != 2 or M.shape != (B.shape[0], B.shape[0]):
        raise ValueError(f"B must be (N, r) and M (N, N); got {B.shape} and {M.shape}")
    diagonal = sps.issparse(M) and (M - sps.diags(M.diagonal())).count_nonzero() == 0
    if diagonal:
        m = M.diagonal()
        if np.any(m <= 0):
            raise ValueError("mass_orthonormalize: the mass matrix must be positive definite")
        root = np.sqrt(m)
        Bm = B if overwrite and B.flags.c_contiguous else np.array(B, order="C")
        Bm *= root[:, None]
        Q = _cholesky_qr2(Bm)
        if Q is None:
            # (numerically) dependent columns: a rank-revealing QR drops them
            Q, R, _ = sla.qr(Bm, mode="economic", pivoting=True)
            keep = np.abs(np.diag(R)) > 1e-10 * np.abs(R[0, 0])
            _warn_dropped(keep, B.shape[1])
            Q = Q[:, keep]
        Q /= root[:, None]
        return Q
    G = B.T @ (M @ B)
    G = (G + G.T) / 2
    try:
        Lc = np.linalg.cholesky(G)
        return sla.solve_triangular(Lc, B.T, lower=True).T
    except np.linalg.LinAlgError:
        vals, vecs = np.linalg.eigh(G)
        keep = vals > 1e-10 * vals.max()
        _warn_dropped(keep, B.shape[1])
        return B @ (vecs[:, keep] / np.sqrt(vals[keep]))


def _warn_dropped(keep: np.ndarray, columns: int) -> None:
    """Say how many of ``columns`` were dropped as combinations of the others, and what is left (if any were).

    ``keep`` (k,): which of the first ``k`` the factorisation kept; the others (more columns than rows) are
    dropped too.
    """
    kept = int(np.count_nonzero(keep))
    if kept < columns:
        wide = f"; with more columns than its {keep.size} rows, at most that many stay" if columns > keep.size else ""
        warnings.warn(
            f"mass_orthonormalize: dropped {columns - kept} of {columns} columns, linear combinations of the others "
            f"(to 1e-10 relative{wide}): the basis has {kept}",
            RuntimeWarning,
            stacklevel=3,  # where mass_orthonormalize was called
        )


def _cholesky_qr2(A: np.ndarray, block: int = 1 << 15):
    """Orthonormalise the columns of ``A`` in place (Gram-Schmidt order), or return None.

    Cholesky QR twice: two products with the small Gram matrix instead of a
    Householder QR of the tall matrix (several times faster for n >> r), and
    accurate to round-off for condition numbers up to ~1e7. Rows are updated
    a block at a time, so no copy of ``A`` is made. The columns are first
    scaled to about unit norm by powers of two (exact; it changes no span and
    no result), so columns of very different sizes (a body 1e-6 across: its
    weights times positions beside the weights) are not taken for dependent
    ones. Returns None, with ``A`` untouched, when the columns are (nearly)
    dependent.
    """
    if A.shape[1] > A.shape[0]:
        # more columns than rows: certainly dependent (and a Gram matrix of 25344 columns, its product
        # threaded, crashed the process in OpenBLAS 0.3.31)
        return None
    norms = np.sqrt(np.einsum("ij,ij->j", A, A))
    exponents = np.round(np.log2(np.where(norms > 0, norms, 1.0))).astype(int)
    A *= np.ldexp(1.0, -exponents)
    for attempt in range(2):
        G = A.T @ A
        try:
            L = np.linalg.cholesky((G + G.T) / 2)
        except np.linalg.LinAlgError:
            L = None
        if L is None or np.diag(L).min() <= 1e-7 * np.diag(L).max():
            if attempt == 0:
                A *= np.ldexp(1.0, exponents)  # untouched again (the second pass works on orthonormal columns)
            return None
        # A L^-T, block by block, with the small inverse factor
        inv_t = sla.solve_triangular(L, np.eye(L.shape[0]), lower=True, check_finite=False).T
        for start in range(0, A.shape[0], block):
            A[start : start + block] = A[start : start + block] @ inv_t
    return A


def project(x, B, M) -> np.ndarray:
    """Mass-weighted least-squares coordinates of ``x`` in the span of ``B``.

    Parameters
    ----------
    x : ndarray, shape (N,) or (n, dim)
        A full field (positions or displacements).
    B : ndarray, shape (N, r)
    M : scipy.sparse matrix, shape (N, N)

    Returns
    -------
    z : ndarray, shape (r,)
        ``argmin_z (B z - x)^T M (B z - x)``.
    """
    x = np.asarray(x, dtype=np.float64).ravel()
    if x.size != B.shape[0]:
        raise ValueError(f"x has {x.size} values, the basis has {B.shape[0]} rows")
    MB = M @ B
    return np.linalg.solve(B.T @ MB, MB.T @ x)


def com_operator(mesh, B, rho=1.0) -> np.ndarray:
    """The centre of mass as a linear map of the reduced coordinates.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    B : ndarray, shape (n * dim, r)
    rho : float or ndarray of shape (nT,)

    Returns
    -------
    C : ndarray, shape (dim, r)
        ``C @ z`` is the centre of mass of ``B @ z`` with the lumped masses.
    """
    check_mesh(mesh)
    dim, n = mesh.p.shape
    m = _mass(mesh, rho, True, "P1", False).diagonal()
    weights = m / m.sum()
    return np.einsum("i,iar->ar", weights, np.asarray(B).reshape(n, dim, -1))
