"""Linear modal analysis: modes, rigid motions, sign convention, frequencies, ceilings.

The modes solve ``K d = lambda M d`` for the linear elasticity stiffness ``K``
and the mass ``M`` of :mod:`skfem_modal.fem`, with
:func:`scipy.sparse.linalg.eigsh` in shift-invert mode about a small negative
shift: a free body's ``K`` is singular, so a zero shift factors a singular
matrix, while any shift below zero keeps ``K - sigma M`` positive definite and
still targets the lowest eigenvalues.

Results are made deterministic, so they are the same on every machine and do
not depend on the element order:

* the rigid modes of a free body are the canonical rigid motions (translations
  along each axis, then rotations about the part's centroid, per connected
  part), mass-orthonormalised in that order;
* within a group of repeated eigenvalues (symmetric shapes) the basis is fixed
  by diagonalising a generic, position-dependent weight on the group;
* each mode's sign makes its largest entry positive (the lowest DOF index
  among entries within 1e-6 of the largest magnitude).
"""

from __future__ import annotations

import warnings

import numpy as np
import scipy.linalg as sla

from .eigen import canonical_eigenpairs, generic_weight, sign_convention
from .fem import ELEMENTS, _jacobian, _mass, _stiffness, element_volumes, node_positions, scalar_basis, vector_dofs
from .mesh import check_mesh, connected_parts

__all__ = [
    "linear_modal_analysis",
    "rigid_motions",
    "rigid_mode_count",
    "muscle_count_problem",
    "fixed_nodes",
    "natural_frequencies",
    "actuation_limits",
    "ceilings_of_gradients",
    "muscle_modes",
    "mode_sign_convention",
]

#: Deterministic sign of each mode (see :func:`skfem_modal.eigen.sign_convention`).
mode_sign_convention = sign_convention


def _node_parts(mesh, element: str) -> np.ndarray:
    parts = connected_parts(mesh)
    if element == "P1":
        return parts
    basis = scalar_basis(mesh, element)
    node_part = np.empty(basis.N, dtype=np.int64)
    node_part[basis.element_dofs] = parts[mesh.t[0]][None, :]
    return node_part


def fixed_nodes(mesh, fixed, element: str = "P1") -> np.ndarray:
    """The nodes pinned by a set of fixed vertices.

    For P1 these are the vertices themselves; for P2 also every edge node whose
    two end vertices are fixed (so a clamped face is clamped along its edges).

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    fixed : array_like of int (vertex indices) or of bool, shape (n,)
    element : {"P1", "P2"}

    Returns
    -------
    nodes : ndarray of int, shape (nf,), ascending
    """
    n = mesh.p.shape[1]
    arr = np.asarray(fixed)
    if arr.dtype == bool:
        if arr.shape != (n,):
            raise ValueError(f"fixed: a boolean mask must have shape ({n},), got {arr.shape}")
        verts = np.nonzero(arr)[0]
    else:
        if arr.size and not np.issubdtype(arr.dtype, np.integer):
            raise TypeError(f"fixed: vertex indices must be integers, got dtype {arr.dtype}")
        verts = np.unique(arr.astype(np.int64).ravel())
        bad = verts[(verts < 0) | (verts >= n)]
        if bad.size:
            raise ValueError(f"fixed: vertex indices must be in 0..{n - 1}, got {bad[:10].tolist()}")
    if element == "P1":
        return verts
    basis = scalar_basis(mesh, element)
    is_fixed = np.zeros(n, dtype=bool)
    is_fixed[verts] = True
    if mesh.p.shape[0] == 2:
        ends, nodes = mesh.facets, basis.dofs.facet_dofs[0]
    else:
        ends, nodes = mesh.edges, basis.dofs.edge_dofs[0]
    pinned_edges = is_fixed[ends].all(axis=0)
    return np.concatenate([verts, np.sort(nodes[pinned_edges])]).astype(np.int64)


def rigid_motions(mesh, fixed=None, element: str = "P1") -> np.ndarray:
    """Canonical basis of the infinitesimal rigid motions that respect ``fixed``.

    Per connected part, in this order: translation along each axis, then
    rotation about the part's centroid (about z in 2D; about x, y, z in 3D).
    With fixed vertices, only the motions of each part that vanish at its fixed
    nodes remain (a part pinned at two points in 2D has none).

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    fixed : array_like of int or bool, optional
        Fixed vertices.
    element : {"P1", "P2"}

    Returns
    -------
    R : ndarray, shape (n_nodes * dim, r)
        ``r = 3`` (2D) or ``6`` (3D) per free part. Not orthonormalised.
    """
    check_mesh(mesh)
    return _rigid_motions(mesh, fixed, element)


def _rigid_motions(mesh, fixed, element: str, count: int | None = None, M=None) -> np.ndarray:
    """The canonical rigid motions, shape (n_nodes * dim, r); only the first ``count`` columns when given.

    Each part's motions live on its own nodes: a part's block is made on them alone (and, with
    the mass matrix ``M``, mass-orthonormalised on them alone: parts share no node, so that is
    Gram-Schmidt in column order over them all), and parts past the ``count`` columns are not
    made. A triangle soup of thousands of parts then costs its columns, not their square.
    """
    x = node_positions(mesh, element)
    n, dim = x.shape
    parts = _node_parts(mesh, element)
    pinned = np.zeros(n, dtype=bool)
    if fixed is not None:
        pinned[fixed_nodes(mesh, fixed, element)] = True
    order = np.argsort(parts, kind="stable")
    ends = np.cumsum(np.bincount(parts))
    blocks, made = [], 0
    for start, end in zip(np.r_[0, ends[:-1]], ends):
        if count is not None and made >= count:
            break
        nodes = order[start:end]
        block = _part_motions(x[nodes], pinned[nodes])
        rows = vector_dofs(nodes, dim)
        if M is not None and block.shape[1]:
            block = _m_orthonormalize(block, M[rows][:, rows])
        blocks.append((rows, block))
        made += block.shape[1]
    R = np.zeros((n * dim, made))
    column = 0
    for rows, block in blocks:
        R[rows, column : column + block.shape[1]] = block
        column += block.shape[1]
    return R if count is None else R[:, :count]


def _part_motions(x, pinned) -> np.ndarray:
    """One part's rigid motions on its own nodes ``x`` (m, dim): translations, then rotations about its
    centroid, the combinations vanishing at its ``pinned`` nodes (m,) only; shape (m dim, r)."""
    m, dim = x.shape
    c = np.zeros((m, 3))
    c[:, :dim] = x - x.mean(axis=0)
    fields = [np.zeros((m, dim)) for _ in range(dim)]
    for axis, u in enumerate(fields):
        u[:, axis] = 1.0
    for axis in [2] if dim == 2 else [0, 1, 2]:
        w = np.zeros(3)
        w[axis] = 1.0
        fields.append(np.cross(w, c)[:, :dim])
    block = np.stack([f.ravel() for f in fields], axis=1)
    at_pins = block[vector_dofs(np.nonzero(pinned)[0], dim)]
    if at_pins.shape[0]:
        # keep the combinations that vanish at this part's fixed nodes
        _, s, vt = np.linalg.svd(at_pins)
        rank = int((s > 1e-10 * max(1.0, s.max())).sum())
        block = block @ vt[rank:].T
    return block


def rigid_mode_count(mesh, fixed=None) -> int:
    """Number of rigid (zero-stiffness) motions: 3 in 2D and 6 in 3D per free part.

    Parts are vertex-connected; fixed vertices remove the motions that move
    them (one pinned vertex in 2D leaves the rotation about it).

    Examples
    --------
    >>> from skfem_modal.mesh import caterpillar
    >>> rigid_mode_count(caterpillar())
    3
    """
    check_mesh(mesh)
    dim = mesh.p.shape[0]
    per_part = 3 if dim == 2 else 6
    parts = connected_parts(mesh)
    if fixed is None:
        return per_part * (int(parts.max()) + 1)
    # only the parts with pins need their motions made
    pinned = fixed_nodes(mesh, fixed)
    touched = np.unique(parts[pinned])
    free = per_part * (int(parts.max()) + 1 - touched.size)
    x = mesh.p.T
    mask = np.zeros(mesh.p.shape[1], dtype=bool)
    mask[pinned] = True
    return free + sum(_part_motions(x[parts == part], mask[parts == part]).shape[1] for part in touched)


def muscle_count_problem(mesh, n_muscles: int, pinned=None) -> str | None:
    """Why ``n_muscles`` muscles do not fit this mesh (a phrase after the count), or None when they do.

    The muscles are the modes after the rigid ones, so at most the free
    degrees of freedom less the rigid motions (:func:`rigid_mode_count`, per
    part and respecting the pins) fit: the rule :func:`muscle_modes` and a
    scene's ``muscles.count`` check share.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    n_muscles : int
    pinned : array_like of int, optional
        Clamped vertices.

    Examples
    --------
    >>> from skfem_modal.mesh import beam2d
    >>> muscle_count_problem(beam2d(nx=2, ny=1), 4) is None
    True
    >>> muscle_count_problem(beam2d(nx=2, ny=1), 10)
    'is too many for the 12 degrees of freedom of the mesh less its 3 rigid motions: at most 9'
    """
    dim = mesh.p.shape[0]
    n_pinned = 0 if pinned is None else fixed_nodes(mesh, pinned).size
    free = dim * (mesh.p.shape[1] - n_pinned)
    n_rigid = rigid_mode_count(mesh, pinned)
    if n_muscles <= free - n_rigid:
        return None
    where = "the pins leave free" if n_pinned else "of the mesh"
    fits = free - n_rigid
    return f"is too many for the {free} degrees of freedom {where} less its {n_rigid} rigid motions: at most {fits}"


def _m_orthonormalize(V: np.ndarray, M) -> np.ndarray:
    """Gram-Schmidt (in column order) in the M inner product."""
    G = V.T @ (M @ V)
    L = np.linalg.cholesky(G)
    return sla.solve_triangular(L, V.T, lower=True).T


def linear_modal_analysis(
    mesh,
    k: int,
    *,
    mu=1.0,
    lam=1.0,
    rho=1.0,
    fixed=None,
    mass: str = "lumped",
    element: str = "P1",
):
    """Lowest ``k`` linear vibration modes, ``K d = lambda M d``.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    k : int
        Number of modes, including rigid ones.
    mu, lam : float or ndarray of shape (nT,)
        Lame parameters of the stiffness.
    rho : float or ndarray of shape (nT,)
        Density of the mass matrix.
    fixed : array_like of int or bool, optional
        Pinned vertices: their DOFs are eliminated and the modes are zero there
        (with P2, also the edge nodes between two pinned vertices).
    mass : {"lumped", "consistent"}
    element : {"P1", "P2"}

    Returns
    -------
    eigenvalues : ndarray, shape (k,)
        Ascending squared angular frequencies; rigid modes come first, with
        eigenvalues at round-off level.
    modes : ndarray, shape (n_nodes * dim, k)
        Mass-orthonormal (``modes.T @ M @ modes = I``), interleaved vertex-major,
        with the deterministic signs and bases described in the module docs.

    Examples
    --------
    >>> from skfem_modal.mesh import caterpillar
    >>> vals, modes = linear_modal_analysis(caterpillar(), 7)
    >>> modes.shape
    (3438, 7)
    >>> [round(float(v), 6) for v in vals[3:]]
    [0.12494, 0.304251, 0.374627, 0.853441]
    """
    check_mesh(mesh)
    if element not in ELEMENTS:
        raise ValueError(f"element must be one of {ELEMENTS}, got {element!r}")
    if mass not in ("lumped", "consistent"):
        raise ValueError(f"mass must be 'lumped' or 'consistent', got {mass!r}")
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)):
        raise TypeError(f"k must be an integer, got {type(k).__name__}")
    from .checks import _fits_float64  # here: checks imports the simulator's modules, which import this one

    _fits_float64(mesh, mu, 0.0, rho)  # the eigenvalues scale as mu / rho: no infinite or vanishing ones
    dim = mesh.p.shape[0]
    K = _stiffness(mesh, mu, lam, element)
    M = M_all = _mass(mesh, rho, mass == "lumped", element, True)
    n_dofs = K.shape[0]
    pinned = fixed_nodes(mesh, fixed, element) if fixed is not None else np.zeros(0, np.int64)
    free = np.setdiff1d(np.arange(n_dofs), vector_dofs(pinned, dim))
    if free.size == 0:
        raise ValueError(f"fixed: pins all {mesh.p.shape[1]} vertices: no degree of freedom is left free, so no mode")
    if not 1 <= k <= free.size:
        raise ValueError(f"k must be in 1..{free.size} (the number of free DOFs), got {k}")
    if free.size < n_dofs:
        K = K[free][:, free]
        M = M[free][:, free]
    Kf, Mf = K, M

    # mass-orthonormal part by part (a pinned DOF's row is zero in every motion that respects the pins)
    n_rigid = rigid_mode_count(mesh, fixed) if element == "P1" else _rigid_motions(mesh, fixed, element).shape[1]
    rigid = _rigid_motions(mesh, fixed, element, None if k > n_rigid else k, M_all)[free]
    values = np.zeros(k)
    vectors = np.zeros((free.size, k))
    # the rigid motions are known exactly: they are the first modes
    stop = min(n_rigid, k)
    vectors[:, :stop] = rigid[:, :stop]
    values[:stop] = np.einsum("ij,ij->j", rigid[:, :stop], Kf @ rigid[:, :stop])
    if k > n_rigid:
        weight = generic_weight(node_positions(mesh, element)).reshape(-1)[free]
        ev, evec = canonical_eigenpairs(Kf, Mf, k - n_rigid, weight, dim, null=rigid if n_rigid else None)
        values[n_rigid:], vectors[:, n_rigid:] = ev, evec
        _check_elastic(ev, stiffness_scale(mesh, mu, lam, rho), n_rigid, fixed is not None)
    vectors = sign_convention(vectors)
    modes = np.zeros((n_dofs, k))
    modes[free] = vectors
    return values[:k], modes


def stiffness_scale(mesh, mu=1.0, lam=1.0, rho=1.0) -> float:
    """The scale of a mesh's highest eigenvalues: ``(2 mu + lam) / (rho l^2)``, the median over elements.

    ``l`` is an element's size (its measure to the power ``1 / dim``); ``mu``, ``lam``, ``rho``
    floats or arrays of shape (nT,). Round-off in the eigenvalues is relative to it.
    """
    dim = mesh.p.shape[0]
    size_squared = element_volumes(mesh) ** (2.0 / dim)
    return float(np.median((2.0 * np.asarray(mu) + np.asarray(lam)) / (np.asarray(rho) * size_squared)))


def zero_stiffness(values, scale: float) -> np.ndarray:
    """Which elastic eigenvalues are zero, to round-off: at most 1e-12 of ``scale``, shape like ``values``.

    ``scale``: :func:`stiffness_scale`, that of the highest eigenvalues. Such a mode bends a
    hinge: parts joined at one vertex (or, in 3D, one edge) turn about it freely. (A real mode
    is far above: the lowest bending mode of a 100:1 beam of 400 x 4 cells is 1e-8 of it.)

    >>> zero_stiffness(np.array([-6e-15, 0.09, 1.5]), scale=100.0)
    array([ True, False, False])
    """
    return np.abs(np.asarray(values, dtype=np.float64)) <= 1e-12 * scale


def _check_elastic(values, scale: float, n_rigid: int, pinned: bool) -> None:
    """Warn of hinges (zero-stiffness elastic modes); refuse eigenvalues negative beyond round-off."""
    zero = zero_stiffness(values, scale)
    if np.any(values[~zero] < 0.0):
        i = int(np.flatnonzero(~zero & (values < 0.0))[0])
        raise FloatingPointError(
            f"elastic mode {n_rigid + i} came out with eigenvalue {values[i]:.6g}, negative beyond round-off "
            f"(of the highest eigenvalues' scale, {scale:.6g}): the stiffness is not positive semi-definite "
            "to float64's precision"
        )
    if np.any(zero):
        besides = f"the {n_rigid} rigid motions the pins leave" if pinned else f"the mesh's {n_rigid} rigid motions"
        warnings.warn(
            f"{int(zero.sum())} modes have zero stiffness besides {besides}: "
            "parts joined at a single vertex or edge act as hinges",
            RuntimeWarning,
            stacklevel=3,
        )


def natural_frequencies(eigenvalues) -> np.ndarray:
    """Natural frequencies in Hz, ``sqrt(lambda) / (2 pi)``.

    Negative eigenvalues give 0 (a rigid mode's round-off; :func:`linear_modal_analysis` refuses
    one negative beyond round-off, which this function has no scale to tell); NaN is refused
    (ValueError).

    Parameters
    ----------
    eigenvalues : array_like, shape (k,)

    Returns
    -------
    frequencies : ndarray, shape (k,)

    Examples
    --------
    >>> natural_frequencies([(2 * np.pi) ** 2, -1e-15]).tolist()
    [1.0, 0.0]
    """
    vals = np.asarray(eigenvalues, dtype=np.float64)
    if np.isnan(vals).any():  # would pass as a frequency (infinity is one: beyond float64)
        raise ValueError(f"eigenvalues must be numbers, got NaN at {np.flatnonzero(np.isnan(vals))[:10].tolist()}")
    return np.sqrt(np.clip(vals, 0.0, None)) / (2.0 * np.pi)


def actuation_limits(mesh, modes, max_s: float = 2.0, element: str | None = None) -> np.ndarray:
    """Per-mode amplitude ceilings for modal muscles.

    Ceiling ``a_k = max_s / max_e |J_e d_k|_F``: scaling mode ``d_k`` by
    ``a_k`` makes the largest per-element deformation-gradient change have
    Frobenius norm ``max_s``. Modes with no deformation (rigid translations)
    have no ceiling (``inf``).

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    modes : ndarray, shape (n_nodes * dim, m)
    max_s : float
        Largest allowed gradient change, > 0.
    element : {"P1", "P2"}, optional
        Inferred from the number of rows when omitted.

    Returns
    -------
    ceilings : ndarray, shape (m,)
    """
    check_mesh(mesh)
    if not (np.isfinite(max_s) and max_s > 0):
        raise ValueError(f"max_s must be positive and finite, got {max_s}")
    D = np.asarray(modes, dtype=np.float64)
    if D.ndim == 1:
        D = D[:, None]
    dim, n = mesh.p.shape
    if element is None:
        rows = {e: node_positions(mesh, e).size for e in ELEMENTS}
        if D.ndim != 2 or D.shape[0] not in rows.values():
            shapes = " or ".join(f"({count}, m) for {e}" for e, count in rows.items())
            raise ValueError(f"modes must have shape {shapes} on this mesh, got {D.shape}")
        element = "P1" if D.shape[0] == n * dim else "P2"
    n_rows = node_positions(mesh, element).size
    if D.ndim != 2 or D.shape[0] != n_rows:
        raise ValueError(f"modes must have shape ({n_rows}, m) for {element} on this mesh, got {D.shape}")
    if not np.all(np.isfinite(D)):
        raise ValueError("modes must be finite")
    return ceilings_of_gradients(_jacobian(mesh, element) @ D, dim, max_s)


def ceilings_of_gradients(JD, dim: int, max_s: float = 2.0) -> np.ndarray:
    """:func:`actuation_limits` from the modes' gradient changes ``JD = J @ D``.

    Parameters
    ----------
    JD : ndarray, shape (nT * nq * dim * dim, m)
    dim : int
    max_s : float

    Returns
    -------
    ceilings : ndarray, shape (m,)
        ``max_s / max_e |(J D_k)_e|_F``, ``inf`` for modes that do not deform.
    """
    largest = np.sqrt((JD.reshape(-1, dim * dim, JD.shape[1]) ** 2).sum(axis=1)).max(axis=0, initial=0.0)
    with np.errstate(divide="ignore"):
        return np.where(largest > 0, max_s / np.where(largest > 0, largest, 1.0), np.inf)


def muscle_modes(mesh, n_muscles: int, *, mu=1.0, lam=None, rho=1.0, pinned=None, signs=None) -> np.ndarray:
    """The muscles of a body: its lowest linear modes without the rigid ones.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    n_muscles : int
    mu, lam, rho : float or ndarray of shape (nT,)
        Material of the modal analysis (``lam`` defaults to ``mu``).
    pinned : array_like of int, optional
        Clamped vertices: then the modes of the clamped body (no rigid ones).
    signs : array_like of +1 / -1, shape (n_muscles,), optional
        Flip muscles (the modes' own signs follow
        :func:`~skfem_modal.eigen.sign_convention`).

    Returns
    -------
    D : ndarray, shape (n * dim, n_muscles)
    """
    if isinstance(n_muscles, bool) or not isinstance(n_muscles, (int, np.integer)) or n_muscles < 0:
        raise ValueError(f"n_muscles must be an integer >= 0, got {n_muscles!r}")
    if not n_muscles:
        return np.zeros((mesh.p.size, 0))
    signs = muscle_signs(signs, n_muscles, "signs")
    problem = muscle_count_problem(mesh, n_muscles, pinned)
    if problem:
        raise ValueError(f"n_muscles: {n_muscles} {problem}")
    n_rigid = rigid_mode_count(mesh, pinned)
    _, found = linear_modal_analysis(
        mesh, n_rigid + n_muscles, mu=mu, lam=mu if lam is None else lam, rho=rho, fixed=pinned
    )
    D = found[:, n_rigid:]
    return D if signs is None else D * signs


def muscle_signs(signs, n_muscles: int, name: str = "muscle_signs"):
    """Muscles' signs checked: an array of +-1, shape (n_muscles,), or None (as the modes come).

    Raises
    ------
    ValueError
        Not ``n_muscles`` values of +1 or -1 (``name`` says which argument).
    """
    if signs is None or not n_muscles:
        return None
    values = np.asarray(signs, dtype=np.float64) if not isinstance(signs, str) else np.zeros(0)
    if values.shape != (n_muscles,) or not np.all(np.abs(values) == 1):
        raise ValueError(f"{name} must be {n_muscles} values of +1 or -1, got {signs!r}")
    return values
