"""Meshes: build, load, validate; built-in shapes; boundary and sampling.

Every function here takes or returns scikit-fem meshes: :class:`skfem.MeshTri`
(linear triangles, 2D) or :class:`skfem.MeshTet` (linear tetrahedra, 3D).
``mesh.p`` has shape ``(dim, n)`` and ``mesh.t`` has shape ``(dim + 1, nT)``;
arrays handed back to users hold positions as ``(n, dim)``.
"""

from __future__ import annotations

import inspect
import math
import os
import re
import warnings
from collections.abc import Sequence
from contextlib import contextmanager

import numpy as np
from skfem import MeshTet, MeshTri
from skfem.element import ElementTetP1, ElementTriP1

from .values import checked_flag, is_finite_real, is_whole

__all__ = [
    "MeshError",
    "body_size",
    "part_boxes",
    "part_sizes",
    "part_thicknesses",
    "make_mesh",
    "check_mesh",
    "check_points",
    "validated",
    "load_mesh",
    "coincident_vertices",
    "MERGE_TOLERANCE",
    "SIZE_RANGE",
    "mirror",
    "tangled_elements",
    "hanging_vertices",
    "caterpillar",
    "beam2d",
    "beam3d",
    "box3d",
    "creature",
    "normalize_and_center",
    "normalizing_transform",
    "boundary_vertices",
    "farthest_point_sampling",
    "sample_boundary",
    "connected_parts",
    "mesh_summary",
    "BUILTIN_SHAPES",
    "builtin_mesh",
    "shape_parameters",
    "shape_parameter_problems",
    "vertices_where",
]

#: An element whose measure is below this fraction of (longest edge)**dim is
#: degenerate. Slivers of aspect ratio 1e4 are still far above it.
DEGENERATE_RTOL = 1e-12

#: Sizes a mesh may have (its extent, and how far from the origin it lies): within them its areas,
#: volumes and operators neither overflow nor underflow (modes exact to 1e-14 from 1e-60 to 1e60)
SIZE_RANGE = (1e-60, 1e60)

_MAX_LISTED = 10


class MeshError(ValueError):
    """A mesh that cannot be used: the message names the elements or vertices."""


def _listing(indices: np.ndarray) -> str:
    shown = ", ".join(str(int(i)) for i in indices[:_MAX_LISTED])
    more = f", ... ({len(indices)} in all)" if len(indices) > _MAX_LISTED else ""
    return f"[{shown}{more}] (numbered from 0)"


def _element_name(dim: int, plural: bool = True) -> str:
    name = "triangle" if dim == 2 else "tetrahedron"
    if plural:
        return "triangles" if dim == 2 else "tetrahedra"
    return name


def _signed_measures(p: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Signed area/volume of each simplex; ``p`` (dim, n), ``t`` (dim+1, nT)."""
    dim = p.shape[0]
    edges = p[:, t[1:]] - p[:, t[0]][:, None, :]  # (dim, dim, nT): edge vectors from vertex 0
    return _determinants(edges.transpose(0, 2, 1)) / (2.0 if dim == 2 else 6.0)


def _determinants(e: np.ndarray) -> np.ndarray:
    """Determinants of a stack of square matrices laid out (dim, m, dim): row, matrix, column."""
    if e.shape[0] == 2:
        return e[0, :, 0] * e[1, :, 1] - e[0, :, 1] * e[1, :, 0]
    return (
        e[0, :, 0] * (e[1, :, 1] * e[2, :, 2] - e[1, :, 2] * e[2, :, 1])
        - e[0, :, 1] * (e[1, :, 0] * e[2, :, 2] - e[1, :, 2] * e[2, :, 0])
        + e[0, :, 2] * (e[1, :, 0] * e[2, :, 1] - e[1, :, 1] * e[2, :, 0])
    )


def _longest_edges(p: np.ndarray, t: np.ndarray) -> np.ndarray:
    corners = p[:, t]  # (dim, nv, nT)
    nv = t.shape[0]
    longest = np.zeros(t.shape[1])
    for a in range(nv):
        for b in range(a + 1, nv):
            d = corners[:, a] - corners[:, b]
            np.maximum(longest, np.einsum("ie,ie->e", d, d), out=longest)
    return np.sqrt(longest)


def _check_arrays(p: np.ndarray, t: np.ndarray, *, what: str = "mesh") -> None:
    """Validate raw mesh arrays ``p`` (dim, n) and ``t`` (dim+1, nT)."""
    _check_points(p, t, what=what)
    dim, n = p.shape
    out = np.nonzero(((t < 0) | (t >= n)).any(axis=0))[0]
    if out.size:
        raise MeshError(f"{what}: {out.size} elements reference vertices outside 0..{n - 1}: {_listing(out)}")
    ordered = np.sort(t, axis=0)
    repeated = np.nonzero((np.diff(ordered, axis=0) == 0).any(axis=0))[0]
    if repeated.size:
        raise MeshError(f"{what}: {repeated.size} elements use the same vertex twice: {_listing(repeated)}")
    measure = np.abs(_signed_measures(p, t))
    scale = _longest_edges(p, t) ** dim
    degenerate = np.nonzero(~(measure > DEGENERATE_RTOL * scale))[0]
    if degenerate.size:
        kind = "area" if dim == 2 else "volume"
        raise MeshError(
            f"{what}: {degenerate.size} degenerate (zero-{kind}) {_element_name(dim)}: "
            f"{_listing(degenerate)}; every element needs a positive {kind}"
        )
    used = np.zeros(n, dtype=bool)
    used[t.ravel()] = True
    unused = np.nonzero(~used)[0]
    if unused.size:
        raise MeshError(
            f"{what}: {unused.size} vertices belong to no element: {_listing(unused)}; "
            "remove them (load_mesh does this for files)"
        )
    groups = _facet_groups(p, t)
    tangled = _tangled(p, t, groups)
    if tangled.size:
        # a copy of an element overlaps it across every facet: say so, rather than "tangled"
        _, first, group = np.unique(ordered.T, axis=0, return_index=True, return_inverse=True)
        copies = np.flatnonzero(first[group.ravel()] != np.arange(t.shape[1]))
        if copies.size:
            raise MeshError(
                f"{what}: {copies.size} {_element_name(dim)} repeat earlier ones (the same vertices): "
                f"{_listing(copies)}; remove the copies"
            )
        facet = "edge" if dim == 2 else "face"
        raise MeshError(
            f"{what}: {tangled.size} tangled (inverted or folded) {_element_name(dim)}: {_listing(tangled)}; "
            f"each overlaps a neighbour across a shared {facet} (e.g. a vertex moved across its neighbours)"
        )
    hanging, facets = _hanging(p, t, groups)
    if hanging.size:
        facet = "edge" if dim == 2 else "face"
        first = ", ".join(map(str, facets[0]))
        raise MeshError(
            f"{what}: {hanging.size} hanging vertices (the mesh is not conforming): {_listing(hanging)}; each lies "
            f"inside {'an' if dim == 2 else 'a'} {facet} of a neighbouring element without being one of its corners "
            f"(vertex {hanging[0]} in the {facet} ({first})), so the elements are not joined there: a crack "
            "through the body. Split the elements at the vertex, or mesh the body in one piece"
        )


def _check_points(p: np.ndarray, t: np.ndarray, *, what: str = "mesh") -> None:
    """The checks of :func:`_check_arrays` that read the points once: types, shapes, finite coordinates, range."""
    if not isinstance(p, np.ndarray) or not isinstance(t, np.ndarray):
        raise TypeError(f"{what}: points and elements must be numpy arrays")
    if p.ndim != 2 or p.shape[0] not in (2, 3):
        raise MeshError(f"{what}: points must have shape (dim, n) with dim 2 or 3, got {p.shape}")
    dim, n = p.shape
    if not np.issubdtype(p.dtype, np.floating):
        raise TypeError(f"{what}: point coordinates must be floating point, got dtype {p.dtype}")
    if t.ndim != 2 or t.shape[0] != dim + 1:
        raise MeshError(
            f"{what}: a {dim}D mesh needs elements of shape ({dim + 1}, nT) ({_element_name(dim)}), got {t.shape}"
        )
    if not np.issubdtype(t.dtype, np.integer):
        raise TypeError(f"{what}: element indices must be integers, got dtype {t.dtype}")
    if n == 0 or t.shape[1] == 0:
        raise MeshError(f"{what}: needs at least one element, got {n} points and {t.shape[1]} elements")
    _refuse_non_finite(what, p)
    extent, farthest = float(np.ptp(p, axis=1).max()), float(np.abs(p).max())
    if extent > 0.0 and not (SIZE_RANGE[0] <= extent and farthest <= SIZE_RANGE[1]):
        raise MeshError(
            f"{what}: the mesh is {extent:.3g} across, with coordinates up to {farthest:.3g}: its areas, volumes "
            f"and matrices overflow or underflow outside {SIZE_RANGE[0]:g} to {SIZE_RANGE[1]:g}; rescale its "
            "coordinates first (e.g. make_mesh(points * scale, elements))"
        )


def _facets(t: np.ndarray):
    """Every element's facets: (sorted vertices (nv, dim, nT), opposite vertex (nv, nT))."""
    nv = t.shape[0]
    faces = np.stack([np.sort(np.delete(t, i, axis=0), axis=0) for i in range(nv)])
    return faces, t


def _facet_keys(faces: np.ndarray, n: int) -> np.ndarray:
    """One integer (or row) per facet, equal for equal vertex sets; ``faces`` (k, m) sorted rows."""
    if float(n) ** faces.shape[1] < 2.0**62:
        return np.ravel_multi_index(tuple(faces.T), (n,) * faces.shape[1])
    return np.unique(faces, axis=0, return_inverse=True)[1].ravel()


def tangled_elements(p: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Elements that overlap a neighbour: inverted or folded, e.g. by a vertex moved across its neighbours.

    In a valid mesh every interior facet (edge in 2D, triangle in 3D) has
    exactly two elements, one on each side of it. An element is tangled when
    it shares a facet with a neighbour that lies on the same side, or shares
    it with two or more other elements. The test does not use the elements'
    orientation (scikit-fem sorts each element's vertices), only where their
    vertices are.

    Parameters
    ----------
    p : ndarray, shape (dim, n)
    t : ndarray of int, shape (dim + 1, nT)

    Returns
    -------
    indices : ndarray of int, shape (k,)
        Tangled elements, ascending (empty for a valid mesh).

    Examples
    --------
    >>> from skfem import MeshTri
    >>> square = MeshTri.init_symmetric()  # four triangles around the centre vertex 4
    >>> tangled_elements(square.p, square.t).tolist()
    []
    >>> p = square.p.copy(); p[:, 4] = [1.2, 0.5]  # the centre moved out across the right edge
    >>> tangled_elements(p, square.t).tolist()
    [0, 1, 2]
    """
    return _tangled(p, t, _facet_groups(p, t))


def _facet_groups(p, t):
    """Every element's facets grouped by their vertices: ``(flat, opposite, order, starts, counts)``.

    ``flat`` (nv nT, dim): facet ``i`` of element ``e`` (sorted vertices) at row ``i nT + e``, its
    opposite vertex at the same place of ``opposite`` (nv, nT); ``order`` sorts the rows so that
    equal facets are adjacent, in groups beginning at ``starts`` of ``counts`` rows.
    """
    dim, n = p.shape
    nv, nT = t.shape
    faces, opposite = _facets(t)
    flat = faces.transpose(0, 2, 1).reshape(nv * nT, dim)
    keys = _facet_keys(flat, n)
    order = np.argsort(keys, kind="stable")
    sorted_keys = keys[order]
    starts = np.flatnonzero(np.r_[True, sorted_keys[1:] != sorted_keys[:-1]])
    counts = np.diff(np.r_[starts, sorted_keys.size])
    return flat, opposite, order, starts, counts


def _tangled(p, t, groups) -> np.ndarray:
    """:func:`tangled_elements` from the facets' groups (:func:`_facet_groups`)."""
    flat, opposite, order, starts, counts = groups
    nT = t.shape[1]
    bad = [order[np.repeat(counts > 2, counts)] % nT]
    pairs = starts[counts == 2]
    first, second = order[pairs], order[pairs + 1]
    # the side of the shared facet each opposite vertex lies on
    corners = p[:, flat[first]]  # (dim, pairs, dim)
    edges = corners[:, :, 1:] - corners[:, :, :1]  # (dim, pairs, dim - 1)

    def side(rows):
        v = p[:, opposite.ravel()[rows]] - corners[:, :, 0]
        return _determinants(np.concatenate([edges, v[:, :, None]], axis=2))

    # (the signs, not the product: two volumes of a mesh 1e-54 across multiply to an underflow, 0)
    same = np.sign(side(first)) * np.sign(side(second)) > 0
    bad.append(first[same] % nT)
    bad.append(second[same] % nT)
    return np.unique(np.concatenate(bad))


def hanging_vertices(p: np.ndarray, t: np.ndarray):
    """Vertices inside a boundary facet of their own part without being one of its corners.

    In a conforming mesh two elements meet across a whole facet (edge in 2D,
    triangle in 3D). A vertex in the middle of a neighbour's facet (a
    T-junction, as merging meshes of different refinement makes) leaves that
    facet and the pieces on the other side each with one element: the mesh
    is cut along them, a crack inside the body. A vertex of another part
    touching a facet is two bodies touching, not a crack.

    Parameters
    ----------
    p : ndarray, shape (dim, n)
    t : ndarray of int, shape (dim + 1, nT)

    Returns
    -------
    vertices : ndarray of int, shape (k,)
        The hanging vertices, ascending.
    facets : ndarray of int, shape (len(vertices), dim)
        The corners of the facet each lies in.

    Examples
    --------
    >>> p = np.array([[0.0, 1.0, 1.0, 0.0, 2.0, 2.0, 1.0], [0.0, 0.0, 1.0, 1.0, 0.0, 1.0, 0.5]])
    >>> t = np.array([[0, 1, 2], [0, 2, 3], [1, 4, 6], [4, 5, 6], [5, 2, 6]]).T  # 6 on the edge (1, 2)
    >>> vertices, facets = hanging_vertices(p, t)
    >>> vertices.tolist(), facets.tolist()
    ([6], [[1, 2]])
    """
    return _hanging(p, t, _facet_groups(p, t))


def _hanging(p, t, groups):
    """:func:`hanging_vertices` from the facets' groups (:func:`_facet_groups`)."""
    from scipy.spatial import cKDTree

    dim, n = p.shape
    flat, opposite, order, starts, counts = groups
    rows = order[starts[counts == 1]]
    boundary = flat[rows]  # (f, dim) corner indices
    own = opposite.ravel()[rows]  # the rest of the facet's one element: a sliver's own tip is no T-junction
    corners = p[:, boundary]  # (dim, f, dim)
    centre = corners.mean(axis=2)
    radius = np.sqrt(((corners - centre[:, :, None]) ** 2).sum(axis=0).max(axis=1))
    # candidates: boundary vertices within each facet's circumscribing ball, not its corners
    on_boundary = np.unique(boundary)
    hits = cKDTree(p[:, on_boundary].T).query_ball_point(centre.T, radius * (1.0 + 1e-9), return_sorted=False)
    sizes = np.fromiter(map(len, hits), np.int64, len(hits))
    vertex = on_boundary[np.fromiter((i for found in hits for i in found), np.int64, int(sizes.sum()))]
    facet = np.repeat(np.arange(boundary.shape[0]), sizes)
    keep = (vertex[:, None] != boundary[facet]).all(axis=1) & (vertex != own[facet])
    vertex, facet = vertex[keep], facet[keep]
    # inside the facet: on its line or plane and strictly within it (to a billionth of its size)
    a = p[:, boundary[facet, 0]]
    edges = p[:, boundary[facet, 1:]] - a[:, :, None]  # (dim, k, dim - 1)
    w = p[:, vertex] - a
    size2 = (edges**2).sum(axis=0).max(axis=1)
    if dim == 2:
        d = edges[:, :, 0]
        off = (d[0] * w[1] - d[1] * w[0]) ** 2 / size2  # squared distance times its length squared
        along = (d * w).sum(axis=0) / size2
        inside = (off <= 1e-18 * size2) & (along > 1e-9) & (along < 1.0 - 1e-9)
    else:
        normal = np.cross(edges[:, :, 0], edges[:, :, 1], axis=0)
        area2 = (normal**2).sum(axis=0)
        off = (normal * w).sum(axis=0) ** 2 / area2
        # barycentric coordinates from the sub-triangles' signed areas along the normal
        e1, e2 = edges[:, :, 0], edges[:, :, 1]
        b1 = (np.cross(w, e2, axis=0) * normal).sum(axis=0) / area2
        b2 = (np.cross(e1, w, axis=0) * normal).sum(axis=0) / area2
        inside = (off <= 1e-18 * size2) & (b1 > 1e-9) & (b2 > 1e-9) & (b1 + b2 < 1.0 - 1e-9)
    vertex, facet = vertex[inside], facet[inside]
    same = _parts(t, n)
    in_part = same[vertex] == same[boundary[facet, 0]]
    order = np.argsort(vertex[in_part], kind="stable")
    return vertex[in_part][order], boundary[facet[in_part][order]]


def _parts(t: np.ndarray, n: int) -> np.ndarray:
    """The connected part of each of ``n`` vertices (elements sharing a vertex are connected), shape (n,)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    rows = np.repeat(t[:1], t.shape[0] - 1, axis=0).ravel()
    graph = coo_matrix((np.ones(rows.size), (rows, t[1:].ravel())), shape=(n, n))
    return connected_components(graph, directed=False)[1]


# ids of meshes checked by an enclosing `validated` block
_TRUSTED: set[int] = set()


@contextmanager
def validated(mesh, *, what: str = "mesh"):
    """Check a mesh once for a whole pipeline of calls.

    Inside the block, :func:`check_mesh` on this mesh returns at once, so a
    pipeline of public functions (each of which checks its input) validates
    the mesh a single time.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
        The mesh to check, on entry. It is trusted by identity: it must not
        change inside the block.
    what : str
        How to name the mesh in error messages (e.g. ``"scene.mesh"``).

    Yields
    ------
    mesh : skfem.MeshTri or skfem.MeshTet
        The same mesh.

    Raises
    ------
    TypeError, MeshError
        On entry, as :func:`check_mesh`.

    Examples
    --------
    >>> m = beam2d(nx=4, ny=2)
    >>> with validated(m):
    ...     pass
    """
    check_mesh(mesh, what=what)
    key = id(mesh)
    added = key not in _TRUSTED
    _TRUSTED.add(key)
    try:
        yield mesh
    finally:
        if added:
            _TRUSTED.discard(key)


def check_mesh(mesh, *, what: str = "mesh") -> None:
    """Raise a clear error if ``mesh`` cannot be used.

    Checks, before any work is done: the mesh type (linear ``MeshTri`` or
    ``MeshTet``), array shapes and dtypes, finite coordinates, element indices
    in range, no element using a vertex twice, no degenerate (zero-measure)
    element, no unused vertex, no tangled element and no hanging vertex
    (:func:`hanging_vertices`). Offending elements and vertices are listed by
    index.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
        The mesh to check.
    what : str
        How to name the mesh in messages (e.g. ``"scene.mesh"``).

    Raises
    ------
    TypeError
        Not a linear triangle or tetrahedron mesh, or wrong dtypes.
    MeshError
        (a ``ValueError``) for everything else, naming the problem.

    Examples
    --------
    >>> import numpy as np
    >>> from skfem import MeshTri
    >>> p = np.array([[0.0, 1.0, 2.0], [0.0, 0.0, 0.0]])
    >>> check_mesh(MeshTri(p, np.array([[0], [1], [2]])))  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    skfem_modal.mesh.MeshError: mesh: 1 degenerate (zero-area) triangles: [0] (numbered from 0); every element ...
    """
    if id(mesh) in _TRUSTED:
        return
    _check_kind(mesh, what)
    _check_arrays(mesh.p, mesh.t, what=what)


def check_points(mesh, *, what: str = "mesh") -> None:
    """The checks of :func:`check_mesh` that read the points only, one pass: for functions that use nothing else.

    The mesh type, array shapes and dtypes, finite coordinates and their range.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
        The mesh to check (at once accepted inside :func:`validated`).
    what : str
        How to name the mesh in error messages.

    Raises
    ------
    TypeError
        Not a linear triangle or tetrahedron mesh, or wrong dtypes.
    MeshError
        Wrong shapes, no element, non-finite coordinates, or a size out of range.
    """
    if id(mesh) in _TRUSTED:
        return
    _check_kind(mesh, what)
    _check_points(mesh.p, mesh.t, what=what)


def _check_kind(mesh, what: str) -> None:
    if not isinstance(mesh, (MeshTri, MeshTet)) or mesh.elem not in (ElementTriP1, ElementTetP1):
        raise TypeError(
            f"{what}: expected a linear skfem.MeshTri or skfem.MeshTet, got {type(mesh).__name__}{_hint(mesh)}"
        )


def _hint(mesh) -> str:
    """How to get a linear triangle or tetrahedron mesh from another scikit-fem mesh ('' if no hint)."""
    name = type(mesh).__name__
    if name.startswith("MeshQuad"):
        return " (split it into triangles: mesh.to_meshtri())"
    if name.startswith("MeshHex"):
        return " (split it into tetrahedra: mesh.to_meshtet())"
    if name in ("MeshTri2", "MeshTet2"):
        return " (a quadratic mesh: pass the linear mesh of its corners; element='P2' gives quadratic modes)"
    return ""


def body_size(mesh, *, what: str = "mesh") -> float:
    """The size of a body ``mesh``: its largest extent along an axis, what relative lengths refer to.

    Its points are checked first (:func:`check_points`), the errors naming it ``what``.

    >>> body_size(beam2d(2.0, 0.5, 4, 2))
    2.0
    """
    check_points(mesh, what=what)
    return float(np.ptp(mesh.p, axis=1).max())


def connected_labels(mesh) -> np.ndarray:
    """The connected part of each vertex of ``mesh`` (elements sharing a vertex are connected), unchecked, shape (n,).

    :func:`connected_parts` for a mesh already checked (numbered as scipy's graph search finds them).
    ``mesh``: a skfem.MeshTri or skfem.MeshTet.
    """
    return _parts(mesh.t, mesh.p.shape[1])


def part_sizes(mesh, labels=None) -> np.ndarray:
    """Each vertex's part size: the largest extent along an axis of the connected part it is in.

    What a vertex's relative lengths refer to: two bodies far apart in one
    mesh are each as large as themselves, not as the distance between them.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
        Not checked.
    labels : ndarray of int, shape (n,), optional
        The parts (:func:`connected_labels`), if already known.

    Returns
    -------
    sizes : ndarray, shape (n,)

    Examples
    --------
    >>> two = MeshTri(np.array([[0.0, 1, 0, 10, 12, 10], [0, 0, 1, 0, 0, 2]]), np.array([[0, 3], [1, 4], [2, 5]]))
    >>> part_sizes(two).tolist()
    [1.0, 1.0, 1.0, 2.0, 2.0, 2.0]
    """
    labels = connected_labels(mesh) if labels is None else labels
    low, high = part_boxes(mesh, labels)
    return (high - low).max(axis=1)[labels]


def part_boxes(mesh, labels=None, points=None) -> tuple[np.ndarray, np.ndarray]:
    """Each connected part's bounding box: its lowest and highest corners, shape (parts, dim) each.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
        Not checked.
    labels : ndarray of int, shape (n,), optional
        The parts (:func:`connected_labels`), if already known.
    points : ndarray, shape (n, dim), optional
        The vertices where they are (default: the mesh's own, ``mesh.p.T``).

    Returns
    -------
    low, high : ndarray, shape (parts, dim)
    """
    labels = connected_labels(mesh) if labels is None else labels
    points = mesh.p.T if points is None else points
    low = np.full((labels.max() + 1, mesh.p.shape[0]), np.inf)
    high = np.full_like(low, -np.inf)
    np.minimum.at(low, labels, points)
    np.maximum.at(high, labels, points)
    return low, high


def part_thicknesses(mesh, labels=None) -> np.ndarray:
    """Each vertex's part thickness: the least width of the connected part it is in, across its convex hull.

    The width across each face of the hull (the farthest hull vertex from its plane), least over
    the faces: a box's or a plank's thickness however it is turned or moved (in 3D the least
    width can fall between two edges instead, and is then up to the least face's). A thin body
    that bends (an L, a ring) is as thick as its hull.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
        Not checked.
    labels : ndarray of int, shape (n,), optional
        The parts (:func:`connected_labels`), if already known.

    Returns
    -------
    thicknesses : ndarray, shape (n,)

    Examples
    --------
    >>> plank = beam2d(10.0, 1.0, 20, 2)
    >>> turn = np.array([[1.0, -1.0], [1.0, 1.0]]) / np.sqrt(2.0)
    >>> round(float(part_thicknesses(MeshTri(turn @ plank.p + 0.1, plank.t)).max()), 12)
    1.0
    """
    labels = connected_labels(mesh) if labels is None else labels
    thicknesses = np.array([_hull_width(mesh.p[:, labels == part].T) for part in range(labels.max() + 1)])
    return thicknesses[labels]


def _hull_width(points) -> float:
    """The least width of the convex hull of ``points`` (n, dim) across one of its faces."""
    from scipy.spatial import ConvexHull

    points = points - points.mean(axis=0)  # (qhull's planes are exact to the coordinates' size)
    hull = ConvexHull(points)
    corners, normals, offsets = points[hull.vertices], hull.equations[:, :-1], hull.equations[:, -1]
    # the hull lies below each face's plane: its width across a face is its deepest corner's depth there
    # (512 faces at a time: a seal's hull has thousands of corners and faces)
    return min(
        float((-(corners @ normals[k : k + 512].T + offsets[k : k + 512])).max(axis=0).min())
        for k in range(0, len(normals), 512)
    )


def make_mesh(points, elements, *, what: str = "mesh"):
    """Build a validated scikit-fem mesh from plain arrays.

    Parameters
    ----------
    points : array_like, shape (n, dim)
        Vertex positions, dim 2 (triangles) or 3 (tetrahedra).
    elements : array_like of int, shape (nT, dim + 1)
        Vertex indices of each element.
    what : str
        How to name the mesh in error messages.

    Returns
    -------
    mesh : skfem.MeshTri or skfem.MeshTet
        Vertex and element order are kept (scikit-fem sorts the indices
        *within* each element; read ``mesh.t`` back).

    Examples
    --------
    >>> m = make_mesh([[0, 0], [1, 0], [0, 1]], [[0, 1, 2]])
    >>> m.p.shape, m.t.shape
    ((2, 3), (3, 1))
    """
    p = np.asarray(points)
    t = np.asarray(elements)
    if p.ndim != 2 or t.ndim != 2:
        raise MeshError(f"{what}: points must be (n, dim) and elements (nT, dim + 1); got {p.shape} and {t.shape}")
    if np.issubdtype(p.dtype, np.integer):
        p = p.astype(np.float64)
    if np.issubdtype(t.dtype, np.floating):
        if not np.all(t == np.round(t)):
            raise TypeError(f"{what}: element indices must be integers")
        t = t.astype(np.int64)
    p = np.ascontiguousarray(p.T)
    t = np.ascontiguousarray(t.T)
    _check_arrays(p, t, what=what)
    cls = MeshTri if p.shape[0] == 2 else MeshTet
    return cls(np.ascontiguousarray(p, dtype=np.float64), np.ascontiguousarray(t))


def _compact(p: np.ndarray, t: np.ndarray):
    """Drop vertices no element uses, keeping the order of the rest.

    ``p`` (dim, n), ``t`` (dim+1, nT) -> (p', t') with t' renumbered.
    """
    used = np.unique(t)
    renumber = np.full(p.shape[1], -1, dtype=np.int64)
    renumber[used] = np.arange(used.size)
    return p[:, used], renumber[t]


#: Quadratic cells read as their linear corners (the first nodes of each cell, as meshio orders them).
_LINEAR = {"tetra10": "tetra", "triangle6": "triangle"}
#: Cell types by dimension (meshio's names; higher orders start the same way).
_SOLIDS = {3: ("tetra", "hexahedron", "wedge", "pyramid", "polyhedron"), 2: ("triangle", "quad", "polygon")}


def _refuse_other_cells(path: str, blocks, dim: int) -> None:
    """Refuse cells of the body's dimension that are not (linear or quadratic) triangles or tetrahedra.

    Leaving them out would leave holes in the body (a gmsh mesh recombined into some quads,
    boundary-layer prisms); lower-dimensional cells (a solid's boundary faces, lines) are only
    dropped.
    """
    read = ("tetra", "tetra10") if dim == 3 else ("triangle", "triangle6")
    counts = {}
    for block in blocks:
        if block.type not in read and block.type.startswith(_SOLIDS[dim]):
            counts[block.type] = counts.get(block.type, 0) + len(block.data)
    if counts:
        found = ", ".join(f"{n} {kind}" for kind, n in counts.items())
        element, split = ("tetrahedra", "MeshHex.to_meshtet") if dim == 3 else ("triangles", "MeshQuad.to_meshtri")
        raise MeshError(
            f"mesh file {path!r}: {found} cells beside the {element} would be left out, a hole in the body; "
            f"only {' and '.join(read)} cells are read: split the others into {element} (gmsh: without "
            f"recombining; scikit-fem: {split})"
        )


def _warn_straightened(path: str, n: int, solid: bool) -> None:
    """Say that quadratic cells were read by their corners (their mid-edge nodes dropped, edges straight)."""
    kind = "tetra10" if solid else "triangle6"
    warnings.warn(
        f"mesh file {path!r}: quadratic {kind} cells are read by their corner vertices; their {n} mid-edge nodes "
        "are dropped, so curved edges become straight (a body with a curved boundary loses a little of it). "
        "For quadratic elements, build them on the linear mesh: element='P2' (modes)",
        UserWarning,
        stacklevel=3,
    )


def _warn_unused(path: str, unused: np.ndarray, n: int, element: str) -> None:
    """Say which vertices of a file no element uses (they are dropped, so the rest are renumbered)."""
    shown = ", ".join(map(str, unused[:5])) + (", ..." if unused.size > 5 else "")
    warnings.warn(
        f"mesh file {path!r}: {unused.size} of its {n} vertices ({'index' if unused.size == 1 else 'indices'} "
        f"{shown}) belong to no {element} and were "
        f"dropped, so the mesh has {n - unused.size}: the others keep their order, but point data from the file "
        "lines up with them only without those rows",
        UserWarning,
        stacklevel=3,
    )


#: Vertices closer than this fraction of the mesh's largest extent are the same vertex (:func:`coincident_vertices`).
MERGE_TOLERANCE = 1e-9


def coincident_vertices(points, tolerance: float = MERGE_TOLERANCE) -> np.ndarray:
    """The vertex each vertex is the same as: groups of vertices closer than ``tolerance`` of the size.

    Triangle soups (OBJ and STL exports that repeat a vertex for each element
    using it) hold such vertices: their elements share no vertex, so each is
    a separate part.

    Parameters
    ----------
    points : array_like, shape (n, dim)
    tolerance : float
        Relative to the largest extent of the points.

    Returns
    -------
    representative : ndarray of int, shape (n,)
        The lowest index of each vertex's group (``representative[i] == i``
        for a vertex that coincides with no earlier one).

    Examples
    --------
    >>> coincident_vertices([[0.0, 0.0], [1.0, 0.0], [0.0, 0.0]]).tolist()
    [0, 1, 0]
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    pts = np.asarray(points, dtype=np.float64)
    n = pts.shape[0]
    size = float(np.ptp(pts, axis=0).max()) if n else 0.0
    pairs = cKDTree(pts).query_pairs(tolerance * size, output_type="ndarray") if size > 0 else np.zeros((0, 2), int)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    first = np.full(labels.max() + 1 if n else 0, n, dtype=np.int64)
    np.minimum.at(first, labels, np.arange(n))
    return first[labels]


def load_mesh(path: str | os.PathLike, *, merge: bool = False):
    """Read a triangle (2D) or tetrahedron (3D) mesh from any file meshio reads.

    Tetrahedra make a 3D ``MeshTet``. Otherwise triangles make a 2D ``MeshTri``
    from a flat mesh: its constant coordinate is dropped (z for an OBJ outline
    with z = 0; in a plane y = c, the (x, z) of a side view become (x, y), so
    up stays up; in x = c, (y, z) do), and a mesh in no such plane is refused
    (a curved surface is not a planar body). What the 2D body writes (frames,
    modes) lies in the x-y plane at z = 0, whatever plane it was read from.
    Quadratic cells (``triangle6``, ``tetra10``) keep their corner vertices,
    with a ``UserWarning`` that their mid-edge nodes are dropped (curved edges
    become straight). Other cells of the body's
    dimension (quads, hexahedra, prisms, cubic triangles) are refused: left
    out, they would leave holes; lower-dimensional ones (a solid's boundary
    faces, lines) are dropped. Vertices no element uses (e.g. gmsh's geometry points)
    are removed, with a ``UserWarning`` naming how many and which (the
    file's point data then lines up only without them). Coordinates are kept as they are in the file (see
    :func:`normalize_and_center` and :func:`mirror` for units and y-down
    outlines).

    Parameters
    ----------
    path : str or path-like
        The mesh file: Medit ``.mesh``, Gmsh ``.msh``, ``.vtu``, ``.vtk``,
        ``.obj``, ``.off``, ``.xdmf``, ``.stl`` and everything else meshio reads.
    merge : bool
        Merge coincident vertices (closer than :data:`MERGE_TOLERANCE` of the
        mesh's size; :func:`coincident_vertices`) into one, so a triangle
        soup becomes one connected body. Without it, a file holding such
        vertices loads as it is, with a ``UserWarning`` saying how many
        coincide and into how many parts they split the mesh.

    Returns
    -------
    mesh : skfem.MeshTri or skfem.MeshTet

    Raises
    ------
    FileNotFoundError
        No such file (``IsADirectoryError``: a folder).
    MeshError
        (a ``ValueError``) naming the file: unreadable or unknown format, no
        triangle or tetrahedron cells, other cells of the body's dimension
        beside them, a non-flat triangle surface, or an invalid mesh (see
        :func:`check_mesh`; non-finite coordinates are named before anything
        else reads them).
    """
    checked_flag(merge, "merge")
    path = os.fspath(path)
    if os.path.isdir(path):
        raise IsADirectoryError(f"mesh file {path!r} is a folder")
    if not os.path.isfile(path):
        raise FileNotFoundError(f"mesh file not found: {path!r}")
    raw = _read_meshio(path)
    blocks, groups, midside = {}, {}, []
    physical = raw.cell_data.get("gmsh:physical") or [None] * len(raw.cells)
    for index, (block, tags) in enumerate(zip(raw.cells, physical)):
        kind = _LINEAR.get(block.type, block.type)
        ncorner = {"tetra": 4, "triangle": 3}.get(kind)
        if ncorner is None:
            continue
        data = np.asarray(block.data)
        if not data.size:  # (an empty section, as Medit's "Tetrahedra 0", made a 2D file 3D)
            continue
        blocks.setdefault(kind, []).append(data[:, :ncorner])
        # each element's group: its physical group (Gmsh), or its block
        group = np.full(data.shape[0], -1 - index) if tags is None else np.asarray(tags, dtype=np.int64).ravel()
        groups.setdefault(kind, []).append(group)
        midside.append(data[:, ncorner:].ravel())
    if blocks:
        _refuse_other_cells(path, raw.cells, 3 if "tetra" in blocks else 2)
    points = np.asarray(raw.points, dtype=np.float64)
    if points.size == 0:
        raise MeshError(f"mesh file {path!r} holds no vertices")
    if points.ndim != 2 or points.shape[1] not in (2, 3):
        raise MeshError(f"mesh file {path!r}: points must have 2 or 3 coordinates, got shape {points.shape}")
    if "tetra" in blocks:
        if points.shape[1] != 3:
            raise MeshError(f"mesh file {path!r}: tetrahedra need 3D points, got {points.shape[1]} columns")
        cells = _once_across_groups(path, blocks["tetra"], groups["tetra"], "tetrahedra")
    elif "triangle" in blocks:
        cells = _once_across_groups(path, blocks["triangle"], groups["triangle"], "triangles")
        if points.shape[1] == 3 and cells.min() >= 0 and cells.max() < len(points):
            # judged on the vertices the triangles use: the others are dropped below (a stray vertex off
            # the plane made a flat mesh "not in a plane", a NaN one "non-finite")
            points = _planar_points(path, points, np.unique(cells))
    else:
        found = sorted({b.type for b in raw.cells}) or ["none"]
        raise MeshError(
            f"mesh file {path!r}: no triangle or tetrahedron cells (only triangle, triangle6, tetra and tetra10 "
            f"are read; found: {', '.join(found)}); a 2D body needs triangles, a 3D one tetrahedra"
        )
    if cells.size and (cells.min() < 0 or cells.max() >= len(points)):
        raise MeshError(f"mesh file {path!r}: cells reference vertices outside 0..{len(points) - 1}")
    unused = np.setdiff1d(np.arange(len(points)), cells)
    midside = np.intersect1d(unused, np.concatenate(midside))
    if midside.size:
        _warn_straightened(path, midside.size, "tetra" in blocks)
        unused = np.setdiff1d(unused, midside)
    if unused.size:
        _warn_unused(path, unused, len(points), "tetrahedron" if "tetra" in blocks else "triangle")
    p, t = _compact(points.T, cells.T.astype(np.int64))
    what = f"mesh file {path!r}"
    # checked before its vertices are compared: an infinite one is named, not a k-d tree error
    mesh = make_mesh(p.T, t.T, what=what)
    same = coincident_vertices(p.T)
    repeated = int(np.sum(same != np.arange(same.size)))
    if repeated and merge:
        p, t = _compact(p, same[t])
        mesh = make_mesh(p.T, t.T, what=what + " (coincident vertices merged)")
    if repeated and not merge:
        parts = int(connected_parts(mesh).max()) + 1
        warnings.warn(
            f"mesh file {path!r}: {repeated} of its {same.size} vertices coincide with an earlier one (only "
            f"{same.size - repeated} distinct positions, within {MERGE_TOLERANCE:g} of the mesh's size), so "
            "elements that touch there share no vertex and the mesh "
            f"falls into {parts} separate part(s) (a triangle soup, as OBJ and STL exports write); merge them "
            "with mesh.merge = true in a scene, --merge on the command line, or load_mesh(..., merge=True)",
            UserWarning,
            stacklevel=2,
        )
    return mesh


def mirror(mesh, axes):
    """Mirror a mesh along some axes, e.g. a y-down image outline into y up.

    Each named coordinate ``c`` becomes ``min + max - c``, so the mesh keeps
    its bounding box.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    axes : str or sequence of str
        Axis names among ``"x"``, ``"y"``, ``"z"`` (the mesh's own).

    Returns
    -------
    mesh : same type
        A new mesh; vertex and element order unchanged.

    Examples
    --------
    >>> m = mirror(beam2d(2.0, 1.0, 2, 1), "y")
    >>> m.p[:, 0].tolist()  # vertex 0 was at (0, 0)
    [0.0, 1.0]
    """
    check_mesh(mesh)
    dim = mesh.p.shape[0]
    names = [axes] if isinstance(axes, str) else list(axes)
    p = mesh.p.copy()
    for name in names:
        if name not in "xyz"[:dim] or len(name) != 1:
            raise ValueError(f"mirror: axis {name!r} is not one of {list('xyz'[:dim])} for this {dim}D mesh")
        axis = "xyz".index(name)
        p[axis] = p[axis].min() + p[axis].max() - p[axis]
    return type(mesh)(p, mesh.t.copy(), sort_t=False)


def _read_meshio(path: str, role: str = "mesh"):
    """``meshio.read``, with every failure a :class:`MeshError` naming the file.

    When no reader understands a file, meshio prints each reader's complaint
    and calls ``sys.exit``; those complaints become the error's message.
    ``role`` names the file in the message (``cannot read ROLE 'path': ...``).
    """
    import contextlib
    import io

    import meshio

    said = io.StringIO()
    try:
        with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
            raw = meshio.read(path)
        if path.lower().endswith(".obj") and (
            raw.points.ndim != 2 or raw.points.shape[1] > 3 or any(np.min(b.data, initial=0) < 0 for b in raw.cells)
        ):
            # vertex colours read as coordinates, relative indices as vertices before the first
            return _read_obj(path) or raw
        return raw
    except SystemExit:
        # the readers' complaints, then meshio's "Error: Couldn't read file ... as FORMATS"
        complaints, _, summary = " ".join(said.getvalue().split()).partition("Error: ")
        tried = re.search(r" as (?:either of )?([\w, -]+)$", summary)
        what = f"not a file meshio reads as {tried.group(1)}" if tried else "not a file meshio reads"
        reason = f"{complaints.strip()} ({what})" if complaints.strip() else what
        raise MeshError(f"cannot read {role} {path!r}: {reason}") from None
    except meshio.ReadError as err:
        if "deduce file format" in str(err):  # an extension no reader claims: say which ones do
            known = ", ".join(sorted(meshio.extension_to_filetypes))
            raise MeshError(
                f"cannot read {role} {path!r}: no mesh format has the extension "
                f"{os.path.splitext(path)[1] or '(none)'!r}; meshio reads {known}"
            ) from None
        raise MeshError(f"cannot read {role} {path!r}: ReadError: {err}") from None
    except ImportError as err:  # a format meshio reads with a package of its own (.xdmf: h5py)
        raise MeshError(
            f"cannot read {role} {path!r}: meshio reads {os.path.splitext(path)[1]} files with the package "
            f"{err.name!r}, which is not installed (pip install {err.name}), or write the mesh as .vtu or .msh"
        ) from None
    except Exception as err:  # meshio raises many kinds for broken files
        kind = os.path.splitext(path)[1] or "mesh"
        if kind.lower() == ".obj":
            found = _read_obj(path)  # (meshio refuses normals, texture coordinates and relative indices)
            if found is not None:
                return found
        raise MeshError(
            f"cannot read {role} {path!r}: it is empty, cut short or not a valid {kind} file "
            f"(meshio's reader failed with {type(err).__name__}: {err})"
        ) from None


def _once_across_groups(path: str, blocks: list, groups: list, kind: str) -> np.ndarray:
    """A file's elements of one kind (n, corners), an element repeated in another group dropped.

    ``groups``: each block's elements' groups (their Gmsh physical groups, or else one a block).
    Gmsh 2.2 writes an element once for each physical group it is in: a body in two groups came
    with every element twice, refused as copies. A copy within one group is left for the mesh's own
    check to name.
    """
    cells, group = np.vstack(blocks), np.concatenate(groups)
    if np.unique(group).size == 1:
        return cells
    _, first, inverse = np.unique(np.sort(cells, axis=1), axis=0, return_index=True, return_inverse=True)
    first = first[inverse.ravel()]
    again = (first != np.arange(cells.shape[0])) & (group[first] != group)
    if np.count_nonzero(again):
        warnings.warn(
            f"mesh file {path!r}: {np.count_nonzero(again)} {kind} are listed again in other physical groups or "
            "cell blocks (a Gmsh 2.2 file writes an element once for each physical group it is in): each is "
            "kept once",
            UserWarning,
            stacklevel=3,
        )
    return cells[~again]


def _read_obj(path: str):
    """An OBJ file's vertices and triangles as a meshio Mesh, or None if it holds anything else as faces.

    For the files meshio's reader refuses: ``vt`` and ``vn`` records beside the vertices (Blender
    writes them: meshio fails on counts that differ, nschloe/meshio#1261), vertex colours after the
    coordinates, and negative (relative) indices. Only ``v`` (the first three numbers) and ``f``
    (three corners, each ``v``, ``v/vt``, ``v//vn`` or ``v/vt/vn``) are read.
    """
    import meshio

    points, faces = [], []
    try:
        with open(path, encoding="utf-8", errors="replace") as f:
            for line in f:
                words = line.split()
                if not words or words[0] not in ("v", "f"):
                    continue
                if words[0] == "v":
                    points.append([float(w) for w in words[1:4]])
                    continue
                if len(words) != 4:
                    return None  # a polygon: not guessed at
                corners = [int(w.split("/")[0]) for w in words[1:]]
                faces.append([c - 1 if c > 0 else len(points) + c for c in corners])
    except (OSError, ValueError):
        return None
    if not points or not faces or any(len(p) != 3 for p in points):
        return None
    return meshio.Mesh(np.array(points), [("triangle", np.array(faces, dtype=np.int64))])


def normalize_and_center(mesh):
    """Translate the vertex mean to the origin and scale the largest extent to 2.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet

    Returns
    -------
    mesh : same type
        A new mesh; vertex and element order unchanged.

    Examples
    --------
    >>> m = normalize_and_center(beam2d(length=10.0, height=1.0, nx=10, ny=2))
    >>> float(np.ptp(m.p, axis=1).max())
    2.0
    """
    x, _, _ = _normalized(mesh)
    return type(mesh)(np.ascontiguousarray(x.T), mesh.t.copy(), sort_t=False)


def normalizing_transform(mesh) -> tuple[np.ndarray, float]:
    """What :func:`normalize_and_center` does to a mesh: its vertices go to ``factor * (x - centre)``.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet

    Returns
    -------
    centre : ndarray, shape (dim,)
        The vertex mean.
    factor : float
        2 over the largest extent.

    Examples
    --------
    >>> centre, factor = normalizing_transform(beam2d(length=10.0, height=1.0, nx=10, ny=2))
    >>> centre.tolist(), factor
    ([5.0, 0.5], 0.2)
    """
    _, centre, factor = _normalized(mesh)
    return centre, factor


def _normalized(mesh):
    """The normalised vertices (n, dim), the centre (dim,) and the factor of :func:`normalize_and_center`."""
    check_mesh(mesh)
    # work on (n, dim) rows: the same summation order as the usual
    # ``X -= X.mean(0)`` on vertex rows, so results agree to the last bit
    x = np.array(mesh.p.T, order="C")
    centre = x.mean(axis=0)
    x -= centre
    factor = 2.0 / (x.max(axis=0) - x.min(axis=0)).max()
    x *= factor
    return x, centre, float(factor)


#: Elements a built-in shape may have, at most (a few GB to build and analyse)
MAX_SHAPE_ELEMENTS = 10_000_000


def _shape_checked(name: str, counts: dict, sizes: dict, elements=lambda: 0.0) -> None:
    """Refuse a built-in shape's parameters, naming them: counts not integers, sizes not positive and
    finite, or more than :data:`MAX_SHAPE_ELEMENTS` elements (``elements()``, an estimate before any work)."""
    for key, value in counts.items():
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
            raise ValueError(f"{name}: {key} must be an integer, got {value!r}")
    for key, value in sizes.items():
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.number)):
            raise ValueError(f"{name}: {key} must be a number, got {value!r}")
        if not (is_finite_real(value) and value > 0):
            raise ValueError(f"{name}: {key} must be positive and finite, got {value!r}")
    try:
        estimate = float(elements())
    except OverflowError:  # (counts beyond a float's range)
        estimate = math.inf
    if not estimate <= MAX_SHAPE_ELEMENTS:
        raise ValueError(
            f"{name}: these parameters make about {estimate:.3g} elements, more than {MAX_SHAPE_ELEMENTS:.0e} "
            "(tens of GB to build and analyse): use fewer cells"
        )


def caterpillar(
    nx: int = 70,
    ny: int = 34,
    width: float = 4.0,
    height: float = 2.0,
    body_fraction: float = 0.34,
    n_legs: int = 4,
    leg_fraction: float = 0.5,
    normalize: bool = True,
):
    """The tutorial's 2D caterpillar: a body bar over ``n_legs`` stubby legs.

    A regular grid of ``nx`` by ``ny`` vertices over ``width`` x ``height`` is
    split into two triangles per cell; triangles whose centroid lies in the top
    bar (the upper ``body_fraction`` of the height) or in one of the legs
    (centred in ``n_legs`` equal spans, together ``leg_fraction`` of the width)
    are kept, and unused vertices dropped. With the defaults and
    ``normalize=True`` (vertex mean at the origin, largest extent 2) this is
    the reference mesh: 1719 vertices, 3058 triangles, area 1.3429951690821.

    Parameters
    ----------
    nx, ny : int
        Grid vertices along x and y (``nx=280, ny=136`` gives 25975 vertices).
    width, height : float
        Size of the grid before normalisation.
    body_fraction : float
        Fraction of the height taken by the top bar, in (0, 1).
    n_legs : int
        Number of legs.
    leg_fraction : float
        Fraction of the width covered by legs, in (0, 1].
    normalize : bool
        Centre and scale as :func:`normalize_and_center`.

    Returns
    -------
    mesh : skfem.MeshTri

    Examples
    --------
    >>> m = caterpillar()
    >>> m.p.shape, m.t.shape
    ((2, 1719), (3, 3058))
    """
    _shape_checked(
        "caterpillar", {"nx": nx, "ny": ny, "n_legs": n_legs}, {"width": width, "height": height}, lambda: 2.0 * nx * ny
    )
    if nx < 2 or ny < 2:
        raise ValueError(f"caterpillar: nx and ny must be at least 2, got nx={nx}, ny={ny}")
    if not 0 < body_fraction < 1:
        raise ValueError(f"caterpillar: body_fraction must be in (0, 1), got {body_fraction}")
    # (at most a leg a triangle: each leg is a pass over the triangles, and 10**400 of them never ended)
    if not 0 < leg_fraction <= 1 or not 1 <= n_legs <= 2 * nx * ny:
        raise ValueError(
            f"caterpillar: need n_legs in [1, 2 nx ny] (no more legs than triangles) and leg_fraction in (0, 1], "
            f"got n_legs = {n_legs}, leg_fraction = {leg_fraction}"
        )
    xs = np.linspace(0.0, width, nx)
    ys = np.linspace(0.0, height, ny)
    px, py = np.meshgrid(xs, ys, indexing="xy")
    points = np.vstack([px.ravel(), py.ravel()])  # vertex j*nx + i sits at (xs[i], ys[j])

    col, row = np.meshgrid(np.arange(nx - 1), np.arange(ny - 1), indexing="xy")
    lower_left = (row * nx + col).ravel()
    lower_right = lower_left + 1
    upper_left = lower_left + nx
    upper_right = upper_left + 1
    # two triangles per grid cell, the cell's pair stored consecutively
    tri = np.stack(
        [
            np.stack([lower_left, lower_right, upper_right]),
            np.stack([lower_left, upper_right, upper_left]),
        ],
        axis=2,
    ).reshape(3, -1)

    centroid = points[:, tri].mean(axis=1)
    bar_bottom = height * (1.0 - body_fraction)
    in_body = centroid[1] >= bar_bottom
    leg_width = width * leg_fraction / n_legs
    span = width / n_legs
    in_leg = np.zeros(tri.shape[1], dtype=bool)
    for k in range(n_legs):
        centre = span * (k + 0.5)
        in_leg |= (np.abs(centroid[0] - centre) <= leg_width / 2) & (centroid[1] < bar_bottom)
    p, t = _compact(points, tri[:, in_body | in_leg])
    mesh = MeshTri(np.ascontiguousarray(p), np.ascontiguousarray(t))
    return normalize_and_center(mesh) if normalize else mesh


def beam2d(length: float = 10.0, height: float = 1.0, nx: int = 80, ny: int = 8):
    """A rectangular 2D beam ``[0, length] x [0, height]`` of triangles.

    Parameters
    ----------
    length, height : float
        Beam size (x along the beam).
    nx, ny : int
        Cells along x and y (each split into two triangles).

    Returns
    -------
    mesh : skfem.MeshTri
        ``(nx + 1) * (ny + 1)`` vertices, ``2 * nx * ny`` triangles.
    """
    _shape_checked("beam2d", {"nx": nx, "ny": ny}, {"length": length, "height": height}, lambda: 2.0 * nx * ny)
    if nx < 1 or ny < 1:
        raise ValueError(f"beam2d: need positive cell counts, got nx={nx}, ny={ny}")
    return MeshTri.init_tensor(np.linspace(0.0, length, nx + 1), np.linspace(0.0, height, ny + 1))


def box3d(nx: int = 8, ny: int = 8, nz: int = 8, size: Sequence[float] = (1.0, 1.0, 1.0)):
    """A box ``[0, size[0]] x [0, size[1]] x [0, size[2]]`` of tetrahedra.

    Each of the ``nx * ny * nz`` cells is split into 6 tetrahedra; ``box3d(40, 10,
    10, (4, 1, 1))`` is the 24000-tetrahedron benchmark box.

    Parameters
    ----------
    nx, ny, nz : int
        Cells along x, y and z.
    size : sequence of 3 floats
        Edge lengths of the box.

    Returns
    -------
    mesh : skfem.MeshTet
    """
    if isinstance(size, str) or not isinstance(size, Sequence | np.ndarray) or len(size) != 3:
        raise ValueError(f"box3d: size must be 3 edge lengths, got {size!r}")
    return _tet_box("box3d", {"nx": nx, "ny": ny, "nz": nz}, {f"size[{k}]": v for k, v in enumerate(size)})


def _tet_box(name: str, counts: dict, sizes: dict):
    """:func:`box3d`'s tetrahedra, the parameters checked under the names ``name`` gives them (3 of each)."""
    _shape_checked(name, counts, sizes, lambda: 6.0 * float(np.prod(list(counts.values()), dtype=float)))
    if min(counts.values()) < 1:
        raise ValueError(f"{name}: need positive cell counts, got {', '.join(f'{k}={v}' for k, v in counts.items())}")
    return MeshTet.init_tensor(*(np.linspace(0.0, size, n + 1) for n, size in zip(counts.values(), sizes.values())))


def beam3d(length: float = 10.0, width: float = 1.0, height: float = 1.0, nx: int = 40, ny: int = 4, nz: int = 4):
    """A 3D beam ``[0, length] x [0, width] x [0, height]`` of tetrahedra.

    The :func:`box3d` of these sizes and counts, its parameters named as here.

    Parameters
    ----------
    length, width, height : float
        Beam size (x along the beam).
    nx, ny, nz : int
        Cells along x, y and z (each split into 6 tetrahedra).

    Returns
    -------
    mesh : skfem.MeshTet
        ``(nx+1)(ny+1)(nz+1)`` vertices and ``6 nx ny nz`` tetrahedra.
    """
    sizes = {"length": length, "width": width, "height": height}
    return _tet_box("beam3d", {"nx": nx, "ny": ny, "nz": nz}, sizes)


def _axis_breaks(extent: float, cell: float, cuts: Sequence[float]) -> np.ndarray:
    """Grid lines over [0, extent] at spacing about ``cell`` that include ``cuts``."""
    fixed = np.unique(np.clip(np.concatenate([[0.0, extent], np.asarray(cuts, float)]), 0.0, extent))
    lines = [fixed[:1]]
    for a, b in zip(fixed[:-1], fixed[1:]):
        if b - a <= 1e-12:
            continue
        count = max(1, int(round((b - a) / cell)))
        lines.append(np.linspace(a, b, count + 1)[1:])
    return np.concatenate(lines)


def creature(
    length: float = 2.0,
    width: float = 1.0,
    body_height: float = 0.3,
    leg_height: float = 0.4,
    leg_size: float = 0.3,
    cell: float = 0.1,
):
    """A 3D four-legged creature of tetrahedra: a body slab on four square legs.

    The slab spans ``[0, length] x [0, width]`` in x and y and
    ``[leg_height, leg_height + body_height]`` in z (z is up). Four legs of
    cross-section ``leg_size`` x ``leg_size`` stand under its corners, feet at
    z = 0. Grid lines pass through every face of the shape, so each hexahedral
    cell (split in 6 tetrahedra) is wholly inside or outside.

    Parameters
    ----------
    length, width, body_height, leg_height, leg_size : float
        Shape dimensions; ``2 * leg_size`` must fit in both length and width.
    cell : float
        Target grid spacing.

    Returns
    -------
    mesh : skfem.MeshTet

    Examples
    --------
    >>> m = creature()
    >>> m.p.shape, m.t.shape
    ((3, 1180), (4, 4464))
    """
    sizes = dict(length=length, width=width, body_height=body_height, leg_height=leg_height, leg_size=leg_size)
    cells = lambda: (length / cell + 3) * (width / cell + 3) * ((leg_height + body_height) / cell + 2)  # noqa: E731
    _shape_checked("creature", {}, {**sizes, "cell": cell}, lambda: 6.0 * cells())
    if 2 * leg_size >= min(length, width):
        raise ValueError(f"creature: two legs of size {leg_size} do not fit in length {length} and width {width}")
    xs = _axis_breaks(length, cell, [leg_size, length - leg_size])
    ys = _axis_breaks(width, cell, [leg_size, width - leg_size])
    zs = _axis_breaks(leg_height + body_height, cell, [leg_height])
    box = MeshTet.init_tensor(xs, ys, zs)
    c = box.p[:, box.t].mean(axis=1)
    in_body = c[2] > leg_height
    near_x = (c[0] < leg_size) | (c[0] > length - leg_size)
    near_y = (c[1] < leg_size) | (c[1] > width - leg_size)
    in_leg = (c[2] < leg_height) & near_x & near_y
    p, t = _compact(box.p, box.t[:, in_body | in_leg])
    return MeshTet(np.ascontiguousarray(p), np.ascontiguousarray(t))


def boundary_vertices(mesh) -> np.ndarray:
    """Indices of the vertices on the boundary, ascending.

    A boundary vertex lies on a facet (edge in 2D, triangle in 3D) that belongs
    to exactly one element.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet

    Returns
    -------
    indices : ndarray of int, shape (nb,)
    """
    check_mesh(mesh)
    t = np.sort(mesh.t, axis=0).astype(np.int64)
    n = mesh.p.shape[1]
    nv = t.shape[0]
    # a boundary facet (its vertices sorted) occurs in exactly one element
    faces = np.concatenate([np.delete(t, i, axis=0) for i in range(nv)], axis=1)
    if float(n) ** (nv - 1) < 2.0**62:
        keys = np.ravel_multi_index(tuple(faces), (n,) * (nv - 1))  # one integer per facet: fast
        unique, counts = np.unique(keys, return_counts=True)
        once = np.array(np.unravel_index(unique[counts == 1], (n,) * (nv - 1)))
    else:
        unique, counts = np.unique(faces.T, axis=0, return_counts=True)
        once = unique[counts == 1].T
    return np.unique(once)


def _refuse_non_finite(what: str, p: np.ndarray) -> None:
    """Raise :class:`MeshError` naming the vertices of ``p`` (dim, n) with a non-finite coordinate."""
    bad = np.nonzero(~np.isfinite(p).all(axis=0))[0]
    if bad.size:
        raise MeshError(f"{what}: {bad.size} vertices have non-finite coordinates: {_listing(bad)}")


#: How far from flat a triangle mesh's vertices may be, across its plane, for a 2D body: a share of its
#: largest extent (float32's round-off, as binary STL and many exports store coordinates, is 6e-8 of it)
FLAT_RTOL = 1e-6


def _planar_points(path: str, points: np.ndarray, used: np.ndarray) -> np.ndarray:
    """A flat triangle mesh's 3D points as 2D ones: x-y, or the other two axes of a plane x = c or y = c.

    A mesh drawn in the x-z plane (a side view, z up) becomes x-y with its z as y, so that
    its up stays up; one in y-z becomes x-y from (y, z). Flat to :data:`FLAT_RTOL` of its size, judged
    on the vertices the triangles use (``used``, indices).
    """
    corners = points[used]
    _refuse_non_finite(f"mesh file {path!r}", corners.T)  # (a NaN spans NaN: no plane would be found)
    spans = np.ptp(corners, axis=0) if len(corners) else np.zeros(3)
    flat = [a for a in (2, 1, 0) if spans[a] <= FLAT_RTOL * spans.max()]
    if not flat:
        raise MeshError(
            f"mesh file {path!r}: triangles are not in a plane of constant x, y or z (they span "
            f"{spans[0]:.3g}, {spans[1]:.3g} and {spans[2]:.3g}): a 2D mesh must be flat, a 3D body needs tetrahedra"
        )
    return np.ascontiguousarray(np.delete(points, flat[0], axis=1))


def farthest_point_sampling(points, k: int, start: int | None = None) -> np.ndarray:
    """Pick ``k`` well-spread points, deterministically.

    Starts at ``start`` (default: the point with the smallest first coordinate,
    the first such on ties) and repeatedly adds the point farthest from the
    chosen set (the first such on ties), never one already picked: coincident
    points are distinct rows.

    Parameters
    ----------
    points : array_like, shape (n, d)
    k : int
        Number of points to pick, ``1 <= k <= n``.
    start : int, optional
        Index of the first point.

    Returns
    -------
    indices : ndarray of int, shape (k,)
        Row indices into ``points`` in the order they were picked.

    Examples
    --------
    >>> farthest_point_sampling([[0.0], [1.0], [0.4], [0.9]], 3).tolist()
    [0, 1, 2]
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2:
        raise ValueError(f"farthest_point_sampling: points must be (n, d), got shape {pts.shape}")
    if not np.isfinite(pts).all():  # a NaN is no distance: the same point was picked k times
        raise ValueError("farthest_point_sampling: points must be finite")
    n = pts.shape[0]
    if not (is_whole(k) and 1 <= k <= n):
        raise ValueError(f"farthest_point_sampling: k must be an integer in 1..{n}, got {k!r}")
    if start is not None and not (is_whole(start) and 0 <= start < n):
        raise ValueError(f"farthest_point_sampling: start must be an integer in 0..{n - 1}, got {start!r}")
    first = int(np.argmin(pts[:, 0])) if start is None else int(start)
    chosen = np.empty(k, dtype=np.int64)
    chosen[0] = first
    distance = np.sqrt(((pts - pts[first]) ** 2).sum(axis=1))
    distance[first] = -1.0  # picked: never again (a copy of a picked point is at 0, and is next in line)
    for i in range(1, k):
        nxt = int(np.argmax(distance))
        chosen[i] = nxt
        distance = np.minimum(distance, np.sqrt(((pts - pts[nxt]) ** 2).sum(axis=1)))
        distance[nxt] = -1.0
    return chosen


def sample_boundary(mesh, count: int | None, candidates=None) -> np.ndarray:
    """Boundary vertices spread by farthest-point sampling: the ground-contact points.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    count : int or None
        How many; None (or more than there are) gives all of them.
    candidates : array_like of int, optional
        Only boundary vertices among these (e.g. the feet).

    Returns
    -------
    indices : ndarray of int
        In sampling order (all boundary vertices: ascending).
    """
    boundary = boundary_vertices(mesh)
    if candidates is not None:
        boundary = np.intersect1d(boundary, np.asarray(candidates, dtype=np.int64))
        if boundary.size == 0:
            raise ValueError("the contact candidates hold no boundary vertex: nothing could touch the ground")
    if count is None or count >= boundary.size:
        return boundary
    return boundary[farthest_point_sampling(mesh.p.T[boundary], count)]


def connected_parts(mesh) -> np.ndarray:
    """Label each vertex with the connected part of the mesh it belongs to.

    Two elements are connected when they share a vertex.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
        Checked (:func:`check_mesh`).

    Returns
    -------
    labels : ndarray of int, shape (n,)
        Part index of each vertex, numbered 0.. in order of first vertex.

    Raises
    ------
    TypeError, MeshError
        A mesh that cannot be used (:func:`check_mesh`).
    """
    check_mesh(mesh)
    labels = connected_labels(mesh)
    # renumber parts by their first vertex so labels do not depend on the solver
    _, first = np.unique(labels, return_index=True)
    order = np.argsort(first)
    renumber = np.empty_like(order)
    renumber[order] = np.arange(order.size)
    return renumber[labels]


def mesh_summary(mesh) -> dict:
    """Sizes and extents of a mesh, for printing and for ``summary.json``.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
        Checked (:func:`check_mesh`).

    Returns
    -------
    info : dict
        ``dim``, ``vertices``, ``elements``, ``element`` name, ``measure``
        (total area/volume), ``bounds`` (min and max per axis), ``parts``.

    Raises
    ------
    TypeError, MeshError
        A mesh that cannot be used (:func:`check_mesh`).
    """
    check_mesh(mesh)
    dim = mesh.p.shape[0]
    return {
        "dim": dim,
        "vertices": int(mesh.p.shape[1]),
        "elements": int(mesh.t.shape[1]),
        "element": _element_name(dim, plural=False),
        "measure": float(np.abs(_signed_measures(mesh.p, mesh.t)).sum()),
        "bounds": [mesh.p.min(axis=1).tolist(), mesh.p.max(axis=1).tolist()],
        "parts": int(connected_parts(mesh).max() + 1),
    }


#: Built-in shapes by name, for the command line and scene files.
BUILTIN_SHAPES = {
    "caterpillar": caterpillar,
    "beam2d": beam2d,
    "beam3d": beam3d,
    "box3d": box3d,
    "creature": creature,
}


def shape_parameters(name: str) -> dict:
    """The parameters of a built-in shape and their defaults.

    Parameters
    ----------
    name : {"caterpillar", "beam2d", "beam3d", "box3d", "creature"}

    Returns
    -------
    defaults : dict of str to int, float, bool or tuple
        In the order of the shape function's signature.

    Examples
    --------
    >>> shape_parameters("box3d")
    {'nx': 8, 'ny': 8, 'nz': 8, 'size': (1.0, 1.0, 1.0)}
    """
    if name not in BUILTIN_SHAPES:
        raise ValueError(f"unknown built-in shape {name!r}; expected one of {sorted(BUILTIN_SHAPES)}")
    return {k: p.default for k, p in inspect.signature(BUILTIN_SHAPES[name]).parameters.items()}


def _expected_like(default, value) -> str | None:
    """What ``value`` should be, for a parameter whose default is ``default``; None if it fits."""

    if isinstance(default, bool):
        return None if isinstance(value, (bool, np.bool_)) else "true or false"
    if isinstance(default, int):
        return None if is_whole(value) else "an integer"
    if isinstance(default, float):
        return None if is_finite_real(value) else "a finite number"
    ok = isinstance(value, (list, tuple)) and len(value) == len(default) and all(map(is_finite_real, value))
    return None if ok else f"a list of {len(default)} numbers"


def shape_parameter_problems(name: str, params: dict) -> list[tuple[str, str]]:
    """What is wrong with parameters given to a built-in shape, by parameter.

    Types are checked against the defaults (:func:`shape_parameters`); ranges
    are checked by the shape function itself.

    Parameters
    ----------
    name : {"caterpillar", "beam2d", "beam3d", "box3d", "creature"}
        The built-in shape.
    params : dict
        Parameter names to the values given (as read from a scene: bools, ints, floats, lists).

    Returns
    -------
    problems : list of (parameter, message)
        Empty when every parameter is known and of the right type.

    Raises
    ------
    ValueError
        An unknown shape ``name`` (:func:`shape_parameters`).

    Examples
    --------
    >>> shape_parameter_problems("beam2d", {"nx": "a", "wide": 2})
    [('nx', "expected an integer, got 'a' (str)"), ('wide', 'unknown; beam2d takes length, height, nx, ny')]
    """
    defaults = shape_parameters(name)
    problems = []
    for key, value in params.items():
        if key not in defaults:
            problems.append((key, f"unknown; {name} takes {', '.join(defaults)}"))
            continue
        expected = _expected_like(defaults[key], value)
        if expected:
            problems.append((key, f"expected {expected}, got {value!r} ({type(value).__name__})"))
    return problems


def builtin_mesh(name: str, **params):
    """A built-in shape by name, with keyword parameters.

    Parameters
    ----------
    name : {"caterpillar", "beam2d", "beam3d", "box3d", "creature"}
    **params
        Passed to the shape's function (e.g. ``nx=280``); every parameter has
        a default (:func:`shape_parameters`).

    Returns
    -------
    mesh : skfem.MeshTri or skfem.MeshTet

    Raises
    ------
    ValueError
        An unknown shape, or a parameter that is unknown or of the wrong
        type (named), or out of range.
    """
    problems = shape_parameter_problems(name, params)
    if problems:
        raise ValueError(f"shape {name!r}: " + "; ".join(f"parameter {key}: {text}" for key, text in problems))
    return BUILTIN_SHAPES[name](**params)


_CONDITION = re.compile(r"^\s*([xyz])\s*(<=|>=|==|<|>)\s*(min|max|[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*$")


def vertices_where(mesh, condition: str) -> np.ndarray:
    """Vertices satisfying a coordinate condition such as ``"x <= 0.01"``.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    condition : str
        ``AXIS OP VALUE`` with AXIS one of x, y, z; OP one of <, <=, >, >=, ==
        (``==`` within 1e-9 of the mesh size); VALUE a number, or ``min`` /
        ``max`` for the mesh's extreme along that axis.

    Returns
    -------
    indices : ndarray of int, shape (k,)
        The vertices, ascending.

    Examples
    --------
    >>> m = beam2d(2.0, 1.0, 2, 1)
    >>> m.p[:, vertices_where(m, "x == min")].T.tolist()
    [[0.0, 0.0], [0.0, 1.0]]
    """
    check_mesh(mesh)
    match = _CONDITION.match(condition)
    if match is None:
        raise ValueError(f"cannot read vertex condition {condition!r}; expected e.g. 'x <= 0.01' or 'y == min'")
    axis = "xyz".index(match.group(1))
    dim = mesh.p.shape[0]
    if axis >= dim:
        raise ValueError(f"condition {condition!r} uses axis {match.group(1)} but the mesh is {dim}D")
    coord = mesh.p[axis]
    value = match.group(3)
    value = coord.min() if value == "min" else coord.max() if value == "max" else float(value)
    tol = 1e-9 * body_size(mesh)
    op = match.group(2)
    chosen = {
        "<": coord < value - tol,
        "<=": coord <= value + tol,
        ">": coord > value + tol,
        ">=": coord >= value - tol,
        "==": np.abs(coord - value) <= tol,
    }[op]
    return np.nonzero(chosen)[0]
