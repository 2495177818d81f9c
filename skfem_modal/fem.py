"""Finite element operators from scikit-fem bases: volumes, mass, stiffness, J, gravity.

Vector fields are vertex-major and interleaved, ``[x0, y0, x1, y1, ...]``:
exactly the DOF order of ``Basis(mesh, ElementVector(ElementTriP1()))``, so a
matrix here and one assembled by scikit-fem can be added without permutation.
For quadratic elements (``element="P2"``) the nodes are scikit-fem's P2 DOFs:
vertices first, then one node per edge.

Element matrices are built from the scalar basis gradients of a scikit-fem
:class:`~skfem.assembly.CellBasis` with vectorised numpy products (the generic
vector forms evaluate every component pair at every quadrature point and are
slow on large 3D meshes); the tests check them against scikit-fem's own
``linear_elasticity`` and ``mass`` forms.
"""

from __future__ import annotations

from functools import cache

import numpy as np
import scipy.sparse as sps
from skfem import Basis
from skfem.element import ElementTetP1, ElementTetP2, ElementTriP1, ElementTriP2

from .mesh import _signed_measures, check_mesh, check_points
from .values import checked_flag

__all__ = [
    "ELEMENTS",
    "element_volumes",
    "lame_parameters",
    "scalar_basis",
    "node_positions",
    "quadrature_volumes",
    "mass_matrix",
    "stiffness_matrix",
    "deformation_jacobian",
    "vertex_jacobian",
    "gravity_force",
    "vector_dofs",
]

ELEMENTS = ("P1", "P2")


def _element_class(dim: int, element: str):
    if element not in ELEMENTS:
        raise ValueError(f"element must be one of {ELEMENTS}, got {element!r}")
    return {
        (2, "P1"): ElementTriP1,
        (2, "P2"): ElementTriP2,
        (3, "P1"): ElementTetP1,
        (3, "P2"): ElementTetP2,
    }[(dim, element)]


@cache
def _centroid_rule(dim: int):
    # one point is exact for P1 gradients (constant per element)
    points = np.full((dim, 1), 1.0 / (dim + 1))
    weights = np.array([0.5 if dim == 2 else 1.0 / 6.0])
    return points, weights


def scalar_basis(mesh, element: str = "P1", intorder: int | None = None):
    """The scalar scikit-fem basis every operator here is built from.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    element : {"P1", "P2"}
    intorder : int, optional
        Quadrature order. Default: the lowest order that is exact for
        gradient products (1 point for P1, order 2 for P2).

    Returns
    -------
    basis : skfem.CellBasis
    """
    dim = mesh.p.shape[0]
    cls = _element_class(dim, element)
    if intorder is None and element == "P1":
        return Basis(mesh, cls(), quadrature=_centroid_rule(dim))
    return Basis(mesh, cls(), intorder=2 if intorder is None else intorder)


def vector_dofs(scalar_dofs: np.ndarray, dim: int) -> np.ndarray:
    """Interleaved vector DOF indices of scalar nodes.

    Parameters
    ----------
    scalar_dofs : ndarray of int, shape (k,)
    dim : int

    Returns
    -------
    dofs : ndarray of int, shape (k * dim,)
        ``[dim*s0, dim*s0 + 1, ..., dim*s1, ...]``.
    """
    s = np.asarray(scalar_dofs, dtype=np.int64)
    return (s[:, None] * dim + np.arange(dim)).ravel()


def element_volumes(mesh) -> np.ndarray:
    """Area (2D) or volume (3D) of every element.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet

    Returns
    -------
    volumes : ndarray, shape (nT,)
        Positive measures, equal to ``scalar_basis(mesh).dx[:, 0]``.
    """
    check_mesh(mesh)
    return np.abs(_signed_measures(mesh.p, mesh.t))


def lame_parameters(young: float, poisson: float) -> tuple[float, float]:
    """Lame parameters ``(mu, lam)`` from Young's modulus and Poisson's ratio.

    Note the order: shear modulus first (scikit-fem's ``lame_parameters``
    returns ``(lam, mu)``). In 2D these are used as they are, which is *plane
    strain*: a thin strip bends with ``E / (1 - nu^2)``, its frequencies
    ``1 / sqrt(1 - nu^2)`` above a plane-stress (Euler-Bernoulli) beam's, 4.8 %
    at ``nu = 0.3``. For plane stress pass ``lam = 2 mu lam / (lam + 2 mu)``
    instead.

    Parameters
    ----------
    young : float
        Young's modulus E > 0.
    poisson : float
        Poisson's ratio, -1 < nu < 0.5.

    Returns
    -------
    mu, lam : float
        ``mu = E / (2 (1 + nu))``, ``lam = E nu / ((1 + nu)(1 - 2 nu))``.

    Examples
    --------
    >>> lame_parameters(2.5, 0.25)
    (1.0, 1.0)
    """
    for name, value in (("Young's modulus", young), ("Poisson's ratio", poisson)):
        if isinstance(value, (str, bytes, bool, np.bool_)) or not np.isscalar(value):
            raise TypeError(f"{name} must be a number, got {value!r}")
    if not (np.isfinite(young) and young > 0):
        raise ValueError(f"Young's modulus must be positive and finite, got {young}")
    if not -1.0 < poisson < 0.5:
        raise ValueError(f"Poisson's ratio must be in (-1, 0.5), got {poisson}")
    mu = young / (2.0 * (1.0 + poisson))
    lam = young * poisson / ((1.0 + poisson) * (1.0 - 2.0 * poisson))
    return float(mu), float(lam)


def _per_element(value, n_elements: int, name: str) -> np.ndarray:
    """A material parameter as a per-element array, checked positive or zero."""
    given = np.asarray(value)
    if given.dtype.kind not in "iuf":  # numpy would read "1e5" as a number, True as 1
        what = repr(value) if given.ndim == 0 else f"an array of {given.dtype}"
        raise TypeError(f"{name} must be a number, or one number per element, got {what}")
    arr = given.astype(np.float64)
    if arr.ndim == 0:
        arr = np.full(n_elements, float(arr))
    elif arr.shape != (n_elements,):
        raise ValueError(f"{name} must be a scalar or have shape ({n_elements},), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    return arr


def _positive(value, n_elements: int, name: str, allow_zero: bool = False) -> np.ndarray:
    arr = _per_element(value, n_elements, name)
    bad = np.nonzero(arr < 0 if allow_zero else arr <= 0)[0]
    if bad.size:
        need = "non-negative" if allow_zero else "positive"
        where = "" if np.ndim(value) == 0 else f" at elements {bad[:10].tolist()}"
        raise ValueError(f"{name} must be {need}, got {arr[bad[0]]}{where}")
    return arr


def node_positions(mesh, element: str = "P1") -> np.ndarray:
    """Rest positions of the nodes carrying DOFs.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    element : {"P1", "P2"}

    Returns
    -------
    positions : ndarray, shape (n_nodes, dim)
        The vertices for P1; vertices then edge midpoints for P2
        (scikit-fem's DOF order).
    """
    check_points(mesh)
    if element == "P1":
        return np.ascontiguousarray(mesh.p.T)
    return np.ascontiguousarray(scalar_basis(mesh, element).doflocs.T)


def _gradients(basis) -> np.ndarray:
    """Scalar basis gradients, shape (nloc, dim, nT, nq)."""
    return np.stack([phi[0].grad for phi in basis.basis])


def _values(basis) -> np.ndarray:
    """Scalar basis values, shape (nloc, nT, nq)."""
    return np.stack([np.asarray(phi[0]) for phi in basis.basis])


def quadrature_volumes(mesh, element: str = "P1") -> np.ndarray:
    """Quadrature weights (with the Jacobian) of :func:`deformation_jacobian`'s points.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    element : {"P1", "P2"}

    Returns
    -------
    dx : ndarray, shape (nT, nq)
        ``nq = 1`` for P1 (the centroid), ``nq = dim + 1`` for P2 (a degree-2
        rule). Each row sums to the element's volume.
    """
    check_mesh(mesh)
    return np.asarray(scalar_basis(mesh, element).dx)


def stiffness_matrix(mesh, mu=1.0, lam=1.0, element: str = "P1") -> sps.csr_matrix:
    """Linear elasticity stiffness matrix.

    The bilinear form ``int 2 mu eps(u):eps(v) + lam div(u) div(v)``, i.e. the
    Hessian of the energy ``sum_e vol_e (mu |eps|^2 + lam/2 tr(eps)^2)`` with
    ``eps = (F + F^T)/2 - I``. Equal to scikit-fem's
    ``linear_elasticity(Lambda=lam, Mu=mu)`` and to ``J^T (vol x C) J``.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    mu, lam : float or ndarray of shape (nT,)
        Lame parameters, per element if arrays; ``mu > 0``, ``lam > -2 mu / dim`` (a positive
        bulk modulus: a negative Poisson's ratio gives a negative ``lam``).
    element : {"P1", "P2"}

    Returns
    -------
    K : scipy.sparse.csr_matrix, shape (n_nodes * dim, n_nodes * dim)
        Symmetric positive semi-definite; its null space holds the rigid motions.

    Examples
    --------
    >>> from skfem_modal.mesh import beam2d
    >>> m = beam2d(nx=4, ny=1)
    >>> K = stiffness_matrix(m)
    >>> bool(abs(K @ np.tile([1.0, 0.0], m.p.shape[1])).max() < 1e-12)  # translation
    True
    """
    check_mesh(mesh)
    return _stiffness(mesh, mu, lam, element)


def _stiffness(mesh, mu, lam, element: str) -> sps.csr_matrix:
    mu, lam = _lame(mesh, mu, lam)
    basis = scalar_basis(mesh, element)
    J = _jacobian_from_basis(basis, mesh.p.shape[0])
    C = _elasticity_tensor(basis.dx, mu, lam, mesh.p.shape[0])
    # K = J^T C J: one sparse product instead of summing element matrices
    # (no duplicate entries to sort and merge, several times faster)
    return (J.T @ (C @ J)).tocsr()


#: The largest ``lam / mu`` a stiffness may have (Poisson's ratio 0.499999995): beyond, its shear part,
#: which sets the lowest modes, drowns in the round-off of its volume part (an audit: at 1e15 the
#: eigenvalues came out negative and out of order; at 5e9 the lowest 2 % high; at 5e7 exact)
MOST_LAM_OVER_MU = 1e8


def _lame(mesh, mu, lam) -> tuple[np.ndarray, np.ndarray]:
    """The Lame parameters per element, (nT,) each, or a ValueError naming the element whose are not elastic."""
    nT = mesh.t.shape[1]
    dim = mesh.p.shape[0]
    uniform = np.ndim(lam) == 0
    mu = _positive(mu, nT, "mu")
    lam = _per_element(lam, nT, "lam")
    # a positive bulk modulus lam + 2 mu / dim: any Poisson's ratio in (-1, 0.5), negative ones too
    bad = np.nonzero(~(lam + 2.0 * mu / dim > 0.0))[0]
    if bad.size:
        where = "" if uniform else f" at elements {bad[:10].tolist()}"
        ratio = ": Poisson's ratio above -1" if dim == 3 else ""  # (in 2D every ratio below 0.5 keeps it)
        raise ValueError(
            f"lam must be above -2 mu / {dim} (a positive bulk modulus{ratio}), got {lam[bad[0]]} with mu "
            f"{mu[bad[0]]}, so above {-2.0 * mu[bad[0]] / dim:g}{where}"
        )
    bad = np.nonzero(~(lam <= MOST_LAM_OVER_MU * mu))[0]
    if bad.size:
        where = "" if uniform else f" at elements {bad[:10].tolist()}"
        first_lam, first_mu = float(lam[bad[0]]), float(mu[bad[0]])
        raise ValueError(
            f"lam must be at most {MOST_LAM_OVER_MU:g} mu (a Poisson's ratio up to 0.499999995), got "
            f"{first_lam:g} with mu {first_mu:g} (Poisson's ratio {first_lam / (2.0 * (first_lam + first_mu))!r})"
            f"{where}: a material that nearly keeps its volume puts the stiffness's shear part, which sets the "
            "lowest modes, below the round-off of its volume part (that needs a mixed formulation)"
        )
    return mu, lam


def _elasticity_tensor(dx: np.ndarray, mu: np.ndarray, lam: np.ndarray, dim: int) -> sps.csr_matrix:
    """Block-diagonal ``vol x C`` acting on row-major ``vec(F)`` per quadrature point.

    ``C[ij, kl] = mu (d_ik d_jl + d_il d_jk) + lam d_ij d_kl``; ``dx`` is
    (nT, nq), ``mu`` and ``lam`` per element.
    """
    eye = np.eye(dim)
    shear = (np.einsum("ik,jl->ijkl", eye, eye) + np.einsum("il,jk->ijkl", eye, eye)).reshape(dim * dim, -1)
    bulk = np.einsum("ij,kl->ijkl", eye, eye).reshape(dim * dim, -1)
    w_mu = (dx * mu[:, None]).ravel()
    w_lam = (dx * lam[:, None]).ravel()
    return sps.kron(sps.diags(w_mu), sps.csr_matrix(shear), format="csr") + sps.kron(
        sps.diags(w_lam), sps.csr_matrix(bulk), format="csr"
    )


def _lumped_p1(mesh, rho: np.ndarray) -> np.ndarray:
    dim = mesh.p.shape[0]
    share = np.abs(_signed_measures(mesh.p, mesh.t)) * rho / (dim + 1)
    return np.bincount(mesh.t.ravel(), np.tile(share, dim + 1), minlength=mesh.p.shape[1])


def mass_matrix(mesh, rho=1.0, lumped: bool = True, element: str = "P1", vector: bool = True):
    """Mass matrix, lumped (diagonal) or consistent.

    P1 lumping is the row sum of the consistent matrix: each vertex receives
    ``rho vol / (dim + 1)`` of every element around it. Row sums of the P2
    consistent matrix are zero or negative at vertices, so P2 is lumped by
    diagonal scaling (HRZ): each element's diagonal, scaled to the element's
    mass. All lumped masses are positive.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    rho : float or ndarray of shape (nT,)
        Density, per element if an array.
    lumped : bool
        Diagonal lumped matrix (default) or the consistent one.
    element : {"P1", "P2"}
    vector : bool
        Mass of a vector field ``(n_nodes * dim)`` in interleaved order
        (default), or of a scalar field ``(n_nodes)``.

    Returns
    -------
    M : scipy.sparse.csr_matrix
        Shape ``(n_nodes * dim, n_nodes * dim)`` or ``(n_nodes, n_nodes)``.

    Examples
    --------
    >>> from skfem_modal.mesh import beam2d
    >>> float(mass_matrix(beam2d(2.0, 1.0, 4, 2), rho=3.0, vector=False).sum())
    6.0
    """
    checked_flag(lumped, "lumped")  # lumped=None gave the consistent matrix silently
    checked_flag(vector, "vector")
    check_mesh(mesh)
    return _mass(mesh, rho, lumped, element, vector)


def _mass(mesh, rho, lumped: bool, element: str, vector: bool):
    nT = mesh.t.shape[1]
    rho = _positive(rho, nT, "rho")
    dim = mesh.p.shape[0]
    if lumped and element == "P1":
        diag = _lumped_p1(mesh, rho)
    else:
        basis = scalar_basis(mesh, element, intorder=2 if element == "P1" else 4)
        phi = _values(basis)  # (nloc, nT, nq)
        wdx = basis.dx * rho[:, None]
        edofs = basis.element_dofs
        if lumped:
            # HRZ: scale each element's diagonal so it carries the element's mass
            d = np.einsum("aeq,aeq,eq->ae", phi, phi, wdx)
            d *= wdx.sum(axis=1) / d.sum(axis=0)
            diag = np.bincount(edofs.ravel(), d.ravel(), minlength=basis.N)
        else:
            Me = np.einsum("aeq,beq,eq->abe", phi, phi, wdx)
            r = np.broadcast_to(edofs[:, None, :], Me.shape)
            c = np.broadcast_to(edofs[None, :, :], Me.shape)
            Ms = sps.coo_matrix((Me.ravel(), (r.ravel(), c.ravel())), shape=(basis.N, basis.N)).tocsr()
            return sps.kron(Ms, sps.identity(dim), format="csr") if vector else Ms
    if vector:
        diag = np.repeat(diag, dim)
    return sps.diags(diag, format="csr")


def deformation_jacobian(mesh, element: str = "P1") -> sps.csr_matrix:
    """The linear map from node positions to deformation gradients.

    Row ``((e * nq + q) * dim + i) * dim + j`` of ``J @ x`` is
    ``F[i, j] = dx_i / dX_j`` of element ``e`` at quadrature point ``q``
    (``nq = 1`` for P1, the points of :func:`quadrature_volumes` for P2).
    ``J @ node_positions(mesh).ravel()`` is the identity in every element.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    element : {"P1", "P2"}

    Returns
    -------
    J : scipy.sparse.csr_matrix, shape (nT * nq * dim * dim, n_nodes * dim)

    Examples
    --------
    >>> from skfem_modal.mesh import beam2d
    >>> m = beam2d(nx=3, ny=2)
    >>> F = (deformation_jacobian(m) @ m.p.T.ravel()).reshape(-1, 2, 2)
    >>> bool(np.allclose(F, np.eye(2)))
    True
    """
    check_mesh(mesh)
    return _jacobian(mesh, element)


def _jacobian(mesh, element: str) -> sps.csr_matrix:
    return _jacobian_from_basis(scalar_basis(mesh, element), mesh.p.shape[0])


def vertex_jacobian(mesh, element: str = "P1") -> sps.csr_matrix:
    """The deformation-gradient map at each element's vertices, shape (nT * (dim + 1) * dim * dim, N * dim).

    Where a gradient is largest: P2's varies linearly over an element, so its norm (convex) peaks at a
    vertex; the quadrature points inside missed up to a fifth of it. P1's is one value an element.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    element : {"P1", "P2"}

    Returns
    -------
    J : scipy.sparse.csr_matrix
        Rows ``(e, vertex, i, j)`` as :func:`deformation_jacobian`'s rows ``(e, i, j)`` are.
    """
    dim = mesh.p.shape[0]
    corners = np.hstack([np.zeros((dim, 1)), np.eye(dim)])  # the reference element's vertices
    basis = Basis(mesh, _element_class(dim, element)(), quadrature=(corners, np.full(dim + 1, 1.0 / (dim + 1))))
    return _jacobian_from_basis(basis, dim)


def _jacobian_from_basis(basis, dim: int) -> sps.csr_matrix:
    g = _gradients(basis)  # (nloc, dim(j), nT, nq)
    nloc, _, nT, nq = g.shape
    edofs = basis.element_dofs  # (nloc, nT)
    # row (e, q, i, j) holds g_a[j] at column dim * dof_a + i for every local node a
    vals = np.broadcast_to(g.transpose(2, 3, 1, 0)[:, :, None, :, :], (nT, nq, dim, dim, nloc))
    cols = edofs.T[:, None, None, None, :] * dim + np.arange(dim)[None, None, :, None, None]
    cols = np.broadcast_to(cols, vals.shape)
    n_rows = nT * nq * dim * dim
    indptr = np.arange(0, (n_rows + 1) * nloc, nloc, dtype=np.int64)
    return sps.csr_matrix((vals.ravel(), cols.ravel().astype(np.int64), indptr), shape=(n_rows, basis.N * dim))


def gravity_force(mesh, g, rho=1.0) -> np.ndarray:
    """Nodal gravity force ``M (1 x g)`` with the lumped P1 mass.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    g : array_like, shape (dim,)
        Gravitational acceleration vector, e.g. ``[0, -9.8]``.
    rho : float or ndarray of shape (nT,)
        Density.

    Returns
    -------
    f : ndarray, shape (n * dim,)
        Interleaved force; sums to ``total mass * g`` per axis.
    """
    check_mesh(mesh)
    return _gravity(mesh, g, rho)


def _gravity(mesh, g, rho) -> np.ndarray:
    dim = mesh.p.shape[0]
    given = np.asarray(g)
    if given.dtype.kind not in "biuf" or given.shape != (dim,) or not np.all(np.isfinite(given)):
        raise ValueError(f"gravity must be a finite vector of length {dim}, got {g!r}")
    g = given.astype(np.float64)
    m = _lumped_p1(mesh, _positive(rho, mesh.t.shape[1], "rho"))
    return (m[:, None] * g[None, :]).ravel()
