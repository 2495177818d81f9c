"""Motions without strain: rigid motions per part, and hinges between pieces.

A displacement with zero strain in every element is rigid on each *piece*,
a set of elements joined through shared facets (edges in 2D, faces in 3D):
two elements sharing a facet share ``dim`` affinely independent nodes, which
pin one rigid motion on both. Pieces of one part that touch only at vertices
(or, in 3D, along an edge) can turn against each other: *hinges*, motions of
zero stiffness besides the part's own rigid ones. Both are found here from
the geometry alone (which nodes the pieces share, where the pins are), with
rank decisions on dimensionless coordinates, so neither the units nor the
eigen solver's round-off decide what is rigid.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sps
from scipy.sparse.csgraph import connected_components

from .eigen import generic_weight, weighted_basis
from .fem import node_positions, scalar_basis, vector_dofs
from .mesh import check_mesh, connected_parts

__all__ = ["fixed_nodes", "rigid_motions", "rigid_mode_count", "held_parts", "hinge_count", "facet_pieces"]

# Singular values below this fraction of the largest (of a dimensionless constraint matrix) are zero.
_RANK_RTOL = 1e-10
# A part of more pieces than this is refused: its constraint matrix is solved densely.
_MAX_PIECES = 400


def fixed_nodes(mesh, fixed, element: str = "P1") -> np.ndarray:
    """The nodes pinned by a set of fixed vertices.

    For P1 these are the vertices themselves; for P2 also every edge node whose
    two end vertices are fixed (so a clamped face is clamped along its edges).

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    fixed : array_like of int, shape (k,) (vertex indices), or of bool, shape (n,)
    element : {"P1", "P2"}

    Returns
    -------
    nodes : ndarray of int, shape (nf,), ascending
    """
    n = mesh.p.shape[1]
    verts = _fixed_vertices(fixed, n)
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


def _fixed_vertices(fixed, n: int) -> np.ndarray:
    """Fixed vertices (indices or a mask of shape (n,)) as ascending indices, checked."""
    arr = np.asarray(fixed)
    if arr.dtype == bool:
        if arr.shape != (n,):
            raise ValueError(f"fixed: a boolean mask must have shape ({n},), got {arr.shape}")
        return np.nonzero(arr)[0]
    if arr.size and not np.issubdtype(arr.dtype, np.integer):
        raise TypeError(f"fixed: vertex indices must be integers, got dtype {arr.dtype}")
    verts = np.unique(arr.astype(np.int64).ravel())
    bad = verts[(verts < 0) | (verts >= n)]
    if bad.size:
        raise ValueError(f"fixed: vertex indices must be in 0..{n - 1}, got {bad[:10].tolist()}")
    return verts


def facet_pieces(mesh) -> np.ndarray:
    """Label each element with its piece: the elements joined to it through shared facets.

    Elements that share only a vertex (or, in 3D, only an edge) are in different pieces.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
        Not checked.

    Returns
    -------
    labels : ndarray of int, shape (nT,)
        Numbered 0.. in order of each piece's first element.

    Examples
    --------
    >>> from skfem import MeshTri
    >>> facet_pieces(MeshTri()).tolist()  # the unit square's two triangles share their diagonal
    [0, 0]
    """
    n = mesh.t.shape[1]
    f2t = mesh.f2t
    inner = f2t[1] >= 0
    graph = sps.coo_matrix((np.ones(int(inner.sum())), (f2t[0, inner], f2t[1, inner])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    _, first = np.unique(labels, return_index=True)
    renumber = np.empty(first.size, dtype=np.int64)
    renumber[np.argsort(first)] = np.arange(first.size)
    return renumber[labels]


def rigid_motions(mesh, fixed=None, element: str = "P1") -> np.ndarray:
    """Canonical basis of the infinitesimal rigid motions that respect ``fixed``.

    Per connected part, in this order: translation along each axis, then
    rotation about the part's centroid (about z in 2D; about x, y, z in 3D).
    With fixed vertices, only the motions of each part that vanish at its fixed
    nodes remain (a part pinned at two points in 2D has none).

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    fixed : array_like of int, shape (k,), or of bool, shape (n,), optional
        Fixed vertices.
    element : {"P1", "P2"}

    Returns
    -------
    R : ndarray, shape (n_nodes * dim, r)
        ``r = 3`` (2D) or ``6`` (3D) per free part. Not orthonormalised.
    """
    check_mesh(mesh)
    return _rigid_motions(mesh, fixed, element)


class _Parts:
    """A mesh's nodes grouped by connected part, with each node's pin; iterated part by part."""

    def __init__(self, mesh, fixed, element: str):
        self.x = node_positions(mesh, element)
        self.pinned = np.zeros(self.x.shape[0], dtype=bool)
        if fixed is not None:
            self.pinned[fixed_nodes(mesh, fixed, element)] = True
        labels = _node_parts(mesh, element)
        self.order = np.argsort(labels, kind="stable")
        self.ends = np.cumsum(np.bincount(labels))

    def __iter__(self):
        """Each part's nodes, ascending."""
        for start, end in zip(np.r_[0, self.ends[:-1]], self.ends):
            yield self.order[start:end]


def _node_parts(mesh, element: str) -> np.ndarray:
    parts = connected_parts(mesh)
    if element == "P1":
        return parts
    node_part = np.empty(scalar_basis(mesh, element).N, dtype=np.int64)
    node_part[_element_nodes(mesh, element)] = parts[mesh.t[0]][None, :]
    return node_part


def _element_nodes(mesh, element: str) -> np.ndarray:
    """The nodes of each element, shape (nodes per element, nT)."""
    return mesh.t if element == "P1" else scalar_basis(mesh, element).element_dofs


def _rigid_motions(mesh, fixed, element: str, count: int | None = None, M=None) -> np.ndarray:
    """The canonical rigid motions, shape (n_nodes * dim, r); only the first ``count`` columns when given.

    Each part's motions live on its own nodes: a part's block is made on them alone (and, with
    the mass matrix ``M``, mass-orthonormalised on them alone: parts share no node, so that is
    Gram-Schmidt in column order over them all), and parts past the ``count`` columns are not
    made. A triangle soup of thousands of parts then costs its columns, not their square.
    """
    parts = _Parts(mesh, fixed, element)
    dim = parts.x.shape[1]
    blocks, made = [], 0
    for nodes in parts:
        if count is not None and made >= count:
            break
        block = _part_motions(parts.x[nodes], parts.pinned[nodes])
        rows = vector_dofs(nodes, dim)
        if M is not None and block.shape[1]:
            block = _m_orthonormalize(block, M[rows][:, rows])
        blocks.append((rows, block))
        made += block.shape[1]
    R = _assembled(blocks, parts.x.size)
    return R if count is None else R[:, :count]


def _assembled(blocks, n_rows: int) -> np.ndarray:
    """Columns given on rows of their own, ``[(rows, block), ...]``, side by side in one matrix."""
    out = np.zeros((n_rows, sum(block.shape[1] for _, block in blocks)))
    column = 0
    for rows, block in blocks:
        out[rows, column : column + block.shape[1]] = block
        column += block.shape[1]
    return out


def _rotation_rows(d: np.ndarray) -> np.ndarray:
    """``omega -> omega x d`` at points ``d`` (m, dim): shape (m, dim, 1) in 2D, (m, dim, 3) in 3D."""
    m, dim = d.shape
    if dim == 2:
        return np.stack([-d[:, 1], d[:, 0]], axis=1)[:, :, None]
    zero = np.zeros(m)
    x, y, z = d.T
    return np.stack(
        [np.stack([zero, z, -y], axis=1), np.stack([-z, zero, x], axis=1), np.stack([y, -x, zero], axis=1)], axis=1
    )


def _motion_rows(d: np.ndarray) -> np.ndarray:
    """A rigid motion's displacement at points ``d`` (m, dim) from its centre, as rows (m dim, r) acting on
    its coefficients: the translation along each axis, then the rotation(s)."""
    m, dim = d.shape
    translation = np.broadcast_to(np.eye(dim), (m, dim, dim))
    return np.concatenate([translation, _rotation_rows(d)], axis=2).reshape(m * dim, -1)


def _part_motions(x, pinned) -> np.ndarray:
    """One part's rigid motions on its own nodes ``x`` (m, dim): translations, then rotations about its
    centroid, the combinations vanishing at its ``pinned`` nodes (m,) only; shape (m dim, r)."""
    c = x - x.mean(axis=0)
    block = _motion_rows(c)
    at_pins = block[vector_dofs(np.nonzero(pinned)[0], x.shape[1])]
    if at_pins.shape[0]:
        # keep the combinations that vanish at this part's fixed nodes; the rank is decided on
        # rotations measured in the part's size, so it is the same in any units
        unit = np.r_[np.ones(x.shape[1]), np.full(block.shape[1] - x.shape[1], 1.0 / _size(c))]
        block = block @ (_null_space(at_pins * unit) * unit[:, None])
    return block


def _size(offsets: np.ndarray) -> float:
    """The largest distance of points from their centre (1 for a single point)."""
    size = float(np.sqrt((offsets**2).sum(axis=1).max()))
    return size if size > 0 else 1.0


def _null_space(A: np.ndarray) -> np.ndarray:
    """An orthonormal basis of ``A``'s null space (columns), singular values below ``_RANK_RTOL`` of the
    largest counted as zero; ``A`` dimensionless."""
    if A.shape[0] > A.shape[1]:
        A = sla.qr(A, mode="r")[0][: A.shape[1]]  # the same null space and singular values, square
    _, s, vt = np.linalg.svd(A)
    rank = int((s > _RANK_RTOL * max(1.0, s.max(initial=0.0))).sum())
    return vt[rank:].T


def rigid_mode_count(mesh, fixed=None) -> int:
    """Number of rigid (zero-stiffness) motions: 3 in 2D and 6 in 3D per free part.

    Parts are vertex-connected; fixed vertices remove the motions that move
    them (one pinned vertex in 2D leaves the rotation about it).

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    fixed : array_like of int, shape (k,), or of bool, shape (n,), optional
        Pinned vertices.

    Returns
    -------
    int

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


def held_parts(mesh, fixed) -> np.ndarray:
    """Which connected parts their fixed vertices leave no rigid motion (held in place: a frame of their own).

    One pinned vertex in 2D (two in 3D) leaves a part free to turn about it: not held.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    fixed : array_like of int, shape (k,), or of bool, shape (n,)
        Pinned vertices.

    Returns
    -------
    held : ndarray of bool, shape (parts,)
        By part label (:func:`~skfem_modal.mesh.connected_parts`).

    Examples
    --------
    >>> from skfem_modal.mesh import beam2d
    >>> held_parts(beam2d(2.0, 0.5, 4, 2), [0]).tolist(), held_parts(beam2d(2.0, 0.5, 4, 2), [0, 5]).tolist()
    ([False], [True])
    """
    check_mesh(mesh)
    parts = connected_parts(mesh)
    pinned = np.zeros(mesh.p.shape[1], dtype=bool)
    pinned[fixed_nodes(mesh, fixed)] = True
    x = mesh.p.T
    return np.array(
        [pinned[parts == part].any() and not _part_motions(x[parts == part], pinned[parts == part]).shape[1]
         for part in range(int(parts.max()) + 1)]
    )  # fmt: skip


def hinge_count(mesh, fixed=None) -> int:
    """Number of hinges: motions of zero stiffness besides the rigid ones (:func:`rigid_mode_count`).

    Pieces of a part joined only at a vertex (or, in 3D, along an edge) turn
    against each other; pins hold some of those turns. Counted from the
    geometry (P1 and P2 alike: the pieces' shared nodes decide).

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    fixed : array_like of int, shape (k,), or of bool, shape (n,), optional
        Pinned vertices.

    Returns
    -------
    int

    Examples
    --------
    >>> from skfem_modal.mesh import caterpillar
    >>> hinge_count(caterpillar()), hinge_count(caterpillar(nx=8, ny=5))  # coarse legs touch at a vertex
    (0, 4)
    """
    check_mesh(mesh)
    return _hinge_motions(mesh, fixed, "P1").shape[1]


def _hinge_motions(mesh, fixed, element: str, M=None) -> np.ndarray:
    """The hinges, shape (n_nodes * dim, h): zero-strain motions M-orthogonal to the rigid ones (to the
    Euclidean complement without ``M``); with ``M``, M-orthonormal part by part in a basis fixed by a
    generic weight of the nodes."""
    pieces = facet_pieces(mesh)
    parts = _Parts(mesh, fixed, element)
    dim = parts.x.shape[1]
    node_piece = np.empty(parts.x.shape[0], dtype=np.int64)
    node_piece[_element_nodes(mesh, element)] = pieces[None, :]
    weight = generic_weight(parts.x).reshape(parts.x.shape)
    blocks = []
    for part, nodes in enumerate(parts):
        found = np.unique(node_piece[nodes])
        if found.size < 2:
            continue
        if found.size > _MAX_PIECES:
            raise ValueError(
                f"part {part} of the mesh falls into {found.size} pieces joined only at vertices or edges "
                f"(hinges), more than the {_MAX_PIECES} whose free turns can be found: join its pieces "
                "through shared faces (or edges in 2D)"
            )
        rows = vector_dofs(nodes, dim)
        mass = None if M is None else M[rows][:, rows]
        free = _piece_motions(mesh, parts, nodes, pieces, node_piece)
        block = _hinges_of_part(free, _part_motions(parts.x[nodes], parts.pinned[nodes]), mass)
        if block.shape[1] and mass is not None:
            block = weighted_basis(block, mass, weight[nodes].ravel())  # reproducible: the solver's would not be
        blocks.append((rows, block))
    return _assembled(blocks, parts.x.size)


def _piece_motions(mesh, parts: _Parts, nodes, pieces, node_piece) -> np.ndarray:
    """A part's zero-strain motions on its ``nodes``, shape (m dim, q): rigid on each piece, equal where
    pieces share a vertex, zero at pins."""
    x, dim = parts.x[nodes], parts.x.shape[1]
    local = np.searchsorted(np.unique(node_piece[nodes]), node_piece[nodes])
    r = 3 if dim == 2 else 6
    centre = np.array([x[local == j].mean(axis=0) for j in range(local.max() + 1)])
    scale = _size(x - x.mean(axis=0))
    # every (vertex, piece) the part's elements make; a vertex in several pieces joins them
    is_part = np.isin(mesh.t[0], nodes)
    pairs = np.unique(np.stack([mesh.t[:, is_part].ravel(), np.tile(pieces[is_part], mesh.t.shape[0])], axis=1), axis=0)
    vertex, piece = pairs[:, 0], np.searchsorted(np.unique(node_piece[nodes]), pairs[:, 1])
    at = np.searchsorted(nodes, vertex)  # vertices are P1 nodes: the same index in any element
    first = np.r_[True, vertex[1:] != vertex[:-1]]
    lead = np.maximum.accumulate(np.where(first, np.arange(vertex.size), 0))
    joints, pins = ~first, first & parts.pinned[nodes][at]
    rows_at = _motion_rows((x[at] - centre[piece]) / scale).reshape(-1, dim, r)
    lead_rows = _motion_rows((x[at] - centre[piece[lead]]) / scale).reshape(-1, dim, r)
    C = np.zeros((int(joints.sum() + pins.sum()), dim, local.max() + 1, r))
    k = np.arange(int(joints.sum()))
    C[k, :, piece[joints]] = rows_at[joints]
    C[k, :, piece[lead[joints]]] -= lead_rows[joints]
    C[k.size + np.arange(int(pins.sum())), :, piece[pins]] = rows_at[pins]
    coefficients = _null_space(C.reshape(C.shape[0] * dim, -1))
    fields = _motion_rows((x - centre[local]) / scale).reshape(-1, dim, r)
    per_node = np.einsum("mdr,mrq->mdq", fields, coefficients.reshape(-1, r, coefficients.shape[1])[local])
    return per_node.reshape(-1, coefficients.shape[1])


def _hinges_of_part(free: np.ndarray, rigid: np.ndarray, mass) -> np.ndarray:
    """The part's zero-strain motions ``free`` (m dim, q) less its ``rigid`` ones (m dim, r): an orthonormal
    (M-orthonormal with ``mass``) basis of the rest, shape (m dim, q - r)."""
    hinges = free.shape[1] - rigid.shape[1]
    if hinges <= 0:
        return np.zeros((free.shape[0], 0))
    inner = (lambda a, b: a.T @ b) if mass is None else (lambda a, b: a.T @ (mass @ b))
    if rigid.shape[1]:
        rigid = rigid @ np.linalg.inv(np.linalg.cholesky(inner(rigid, rigid))).T
        free = free - rigid @ inner(rigid, free)
    # the rigid ones lie in the span of ``free``: what is left has rank q - r, known, so no threshold
    gram, vectors = np.linalg.eigh(inner(free, free))
    return free @ (vectors[:, -hinges:] / np.sqrt(gram[-hinges:]))


def _m_orthonormalize(V: np.ndarray, M) -> np.ndarray:
    """Gram-Schmidt (in column order) in the M inner product."""
    G = V.T @ (M @ V)
    L = np.linalg.cholesky(G)
    return sla.solve_triangular(L, V.T, lower=True).T
