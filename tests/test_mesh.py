import inspect
import re
import warnings

import meshio
import numpy as np
import pytest
from skfem import MeshTet, MeshTri

from skfem_modal import (
    MeshError,
    beam2d,
    beam3d,
    boundary_vertices,
    box3d,
    caterpillar,
    check_mesh,
    creature,
    farthest_point_sampling,
    load_mesh,
    make_mesh,
    normalize_and_center,
    vertices_where,
)
from skfem_modal.fem import element_volumes
from skfem_modal.mesh import (
    BUILTIN_SHAPES,
    builtin_mesh,
    connected_parts,
    hanging_vertices,
    mesh_summary,
    shape_parameters,
)


def test_caterpillar_matches_the_tutorial(cat_mesh, reference):
    assert cat_mesh.p.shape == (2, reference["vertices"])
    assert cat_mesh.t.shape == (3, reference["triangles"])
    assert element_volumes(cat_mesh).sum() == pytest.approx(reference["area"], rel=1e-13)
    extent = np.ptp(cat_mesh.p, axis=1)
    assert extent.max() == pytest.approx(2.0, rel=1e-15)
    np.testing.assert_allclose(cat_mesh.p.mean(axis=1), 0.0, atol=1e-14)
    # vertex 0 is the bottom-left corner of the left leg
    assert cat_mesh.p[1, 0] == cat_mesh.p[1].min()
    assert cat_mesh.p[0, 0] == cat_mesh.p[0, cat_mesh.p[1] == cat_mesh.p[1].min()].min()


def test_caterpillar_refined_size():
    m = caterpillar(nx=280, ny=136)
    assert m.p.shape[1] == 25975


def test_beams_and_box_sizes():
    b2 = beam2d(10.0, 1.0, 20, 4)
    assert isinstance(b2, MeshTri) and b2.p.shape[1] == 21 * 5 and b2.t.shape[1] == 2 * 20 * 4
    b3 = beam3d(10.0, 1.0, 1.0, 10, 2, 2)
    assert isinstance(b3, MeshTet) and b3.t.shape[1] == 6 * 10 * 2 * 2
    box = box3d(40, 10, 10, (4.0, 1.0, 1.0))
    assert box.p.shape[1] == 4961 and box.t.shape[1] == 24000
    assert element_volumes(box).sum() == pytest.approx(4.0, rel=1e-12)


def test_creature_is_a_slab_on_four_legs():
    m = creature(length=2.0, width=1.0, body_height=0.3, leg_height=0.4, leg_size=0.3, cell=0.1)
    info = mesh_summary(m)
    assert info["parts"] == 1
    # volume: slab plus four legs, exactly (grid lines pass through every face)
    assert info["measure"] == pytest.approx(2.0 * 1.0 * 0.3 + 4 * 0.3 * 0.3 * 0.4, rel=1e-12)
    feet = m.p[:, m.p[2] == 0.0]
    assert feet.shape[1] > 0
    # feet only under the four corners
    near_x = (feet[0] <= 0.3 + 1e-12) | (feet[0] >= 1.7 - 1e-12)
    near_y = (feet[1] <= 0.3 + 1e-12) | (feet[1] >= 0.7 - 1e-12)
    assert np.all(near_x & near_y)
    # the region under the belly between the legs is empty
    c = m.p[:, m.t].mean(axis=1)
    belly = (c[2] < 0.4) & (c[0] > 0.3) & (c[0] < 1.7)
    assert not belly.any()


def test_normalize_and_center_keeps_order_and_shape():
    m = beam2d(10.0, 2.0, 10, 2)
    n = normalize_and_center(m)
    np.testing.assert_array_equal(n.t, m.t)
    assert np.ptp(n.p, axis=1).max() == pytest.approx(2.0)
    np.testing.assert_allclose(n.p.mean(axis=1), 0.0, atol=1e-15)
    # a similarity: ratios of distances are kept
    d0 = np.linalg.norm(m.p[:, 5] - m.p[:, 0]) / np.linalg.norm(m.p[:, 7] - m.p[:, 0])
    d1 = np.linalg.norm(n.p[:, 5] - n.p[:, 0]) / np.linalg.norm(n.p[:, 7] - n.p[:, 0])
    assert d1 == pytest.approx(d0, rel=1e-14)


def test_boundary_vertices_match_scikit_fem():
    m = beam2d(4.0, 1.0, 8, 2)
    b = boundary_vertices(m)
    np.testing.assert_array_equal(b, np.sort(m.boundary_nodes()))
    assert b.size == 2 * (8 + 2)  # the perimeter of a 9 x 3 grid
    t = box3d(3, 3, 3)
    assert boundary_vertices(t).size == 4**3 - 2**3


def test_farthest_point_sampling_is_deterministic_and_spread():
    rng = np.random.default_rng(1)
    pts = rng.random((300, 2))
    a = farthest_point_sampling(pts, 20)
    b = farthest_point_sampling(pts.copy(), 20)
    np.testing.assert_array_equal(a, b)
    assert a[0] == np.argmin(pts[:, 0])
    assert len(set(a.tolist())) == 20
    # each added point is the farthest from those before it
    for i in range(1, 20):
        d = np.min(np.linalg.norm(pts[:, None] - pts[a[:i]][None], axis=2), axis=1)
        assert d[a[i]] == pytest.approx(d.max())
    # ties go to the first index (the reference's rule for its contact vertices), the start's and each pick's
    line = np.array([[0.0], [1.0], [-1.0], [2.0]])
    assert farthest_point_sampling(line[[1, 0, 2, 3]], 2).tolist() == [2, 3]
    assert farthest_point_sampling(np.array([[0.0], [1.0], [-1.0]]), 2, start=0).tolist() == [0, 1]  # 1 and -1 tie
    assert farthest_point_sampling(np.array([[0.0], [0.0], [1.0]]), 2).tolist() == [0, 2]  # two smallest x
    with pytest.raises(ValueError, match="k must be an integer in 1..4"):
        farthest_point_sampling(line, 5)
    # coincident points are distinct rows, each picked once (an audit: [0, 2, 0], and [0, 0, 0, 0] of 4 copies)
    assert farthest_point_sampling(np.array([[0.0], [0.0], [1.0]]), 3).tolist() == [0, 2, 1]
    assert farthest_point_sampling(np.zeros((4, 2)), 4).tolist() == [0, 1, 2, 3]
    for k, start in ((2.0, None), (True, None), (2, 1.7)):  # numpy's own message, or a silent truncation
        with pytest.raises(ValueError, match=r"farthest_point_sampling: (k|start) must be an integer"):
            farthest_point_sampling(line, k, start=start)


def test_vertices_where():
    m = beam2d(2.0, 1.0, 2, 1)
    x, y = m.p
    assert vertices_where(m, "x == min").tolist() == np.nonzero(x == 0)[0].tolist()
    assert len(vertices_where(m, "x == min")) == 2
    assert vertices_where(m, "x >= 1").tolist() == np.nonzero(x >= 1)[0].tolist()
    assert len(vertices_where(m, "x >= 1")) == 4
    assert vertices_where(m, "y < 0.5").tolist() == np.nonzero(y == 0)[0].tolist()
    assert vertices_where(m, "y <= 1e-12").tolist() == np.nonzero(y == 0)[0].tolist()
    with pytest.raises(ValueError, match="axis z but the mesh is 2D"):
        vertices_where(m, "z < 1")
    with pytest.raises(ValueError, match="cannot read vertex condition"):
        vertices_where(m, "x ~ 1")


def test_builtin_mesh_by_name():
    assert builtin_mesh("beam2d", nx=3, ny=1).t.shape[1] == 6
    with pytest.raises(ValueError, match="unknown built-in shape 'blob'"):
        builtin_mesh("blob")
    with pytest.raises(ValueError, match="parameter width2: unknown; beam2d takes length, height, nx, ny"):
        builtin_mesh("beam2d", width2=3)


# --- validation -------------------------------------------------------------

P = [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]]
T = [[0, 1, 2], [1, 3, 2]]


def test_make_mesh_accepts_good_arrays():
    m = make_mesh(P, T)
    assert isinstance(m, MeshTri) and m.t.shape == (3, 2)
    m3 = make_mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], [[0, 1, 2, 3]])
    assert isinstance(m3, MeshTet)


def test_non_finite_coordinates_are_named():
    p = np.array(P)
    p[2, 1] = np.nan
    with pytest.raises(MeshError, match=r"1 vertices have non-finite coordinates: \[2\]"):
        make_mesh(p, T)


def test_degenerate_elements_are_listed():
    p = np.array(P + [[2.0, 0.0], [3.0, 0.0]])
    t = T + [[1, 4, 5]]
    with pytest.raises(MeshError, match=r"1 degenerate \(zero-area\) triangles: \[2\]"):
        make_mesh(p, t)
    tet_p = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0, 0, 1]]
    with pytest.raises(MeshError, match=r"degenerate \(zero-volume\) tetrahedra: \[1\]"):
        make_mesh(np.array(tet_p, float), [[0, 1, 2, 4], [0, 1, 2, 3]])


def test_slivers_are_not_degenerate():
    p = np.array([[0.0, 0.0], [1.0, 0.0], [0.5, 1e-4]])
    check_mesh(make_mesh(p, [[0, 1, 2]]))  # aspect ratio 1e4 is still a triangle


def test_unused_vertices_are_listed():
    with pytest.raises(MeshError, match=r"1 vertices belong to no element: \[4\]"):
        make_mesh(P + [[5.0, 5.0]], T)


def test_wrong_shapes_and_dtypes():
    with pytest.raises(MeshError, match=r"elements of shape \(3, nT\)"):
        make_mesh(P, [[0, 1, 2, 3]])
    with pytest.raises(TypeError, match="must be integers"):
        make_mesh(P, [[0.5, 1, 2]])
    with pytest.raises(MeshError, match="reference vertices outside 0..3"):
        make_mesh(P, [[0, 1, 7]])
    with pytest.raises(MeshError, match="use the same vertex twice"):
        make_mesh(P, [[0, 1, 1], [1, 3, 2]])
    with pytest.raises(TypeError, match="expected a linear skfem.MeshTri or skfem.MeshTet"):
        check_mesh(np.zeros((2, 3)))


# --- files --------------------------------------------------------------------


def test_load_flat_triangles_drops_z(tmp_path):
    m = beam2d(2.0, 1.0, 4, 2)
    pts = np.hstack([m.p.T, np.full((m.p.shape[1], 1), 3.5)])
    extra = np.vstack([pts, [[9.0, 9.0, 3.5]]])  # a geometry point no cell uses
    path = tmp_path / "beam.vtu"
    meshio.write(path, meshio.Mesh(extra, [("triangle", m.t.T), ("vertex", [[extra.shape[0] - 1]])]))
    with pytest.warns(UserWarning, match=r"1 of its 16 vertices \(index 15\) belong to no triangle and were dropped"):
        loaded = load_mesh(path)
    assert isinstance(loaded, MeshTri)
    np.testing.assert_allclose(loaded.p, m.p)
    np.testing.assert_array_equal(loaded.t, m.t)


def test_a_flat_file_is_judged_on_the_vertices_its_triangles_use(tmp_path):
    """An audit: a square with one stray vertex 3 off its plane was "not in a plane", a NaN stray one
    "non-finite", before the strays were dropped; a 2D Medit file's empty "Tetrahedra 0" section made it 3D."""
    square = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n{}f 1 2 3\nf 1 3 4\n"
    for stray in ("v 0.5 0.5 3\n", "v nan nan nan\n"):
        path = tmp_path / "stray.obj"
        path.write_text(square.format(stray))
        with pytest.warns(UserWarning, match=r"1 of its 5 vertices \(index 4\) belong to no triangle"):
            loaded = load_mesh(path)
        assert isinstance(loaded, MeshTri) and loaded.p.shape == (2, 4)
    medit = tmp_path / "square.mesh"
    medit.write_text(
        "MeshVersionFormatted 2\nDimension 3\nVertices\n4\n0 0 0 0\n1 0 0 0\n1 1 0 0\n0 1 0 0\n"
        "Triangles\n2\n1 2 3 0\n1 3 4 0\nTetrahedra\n0\nEnd\n"
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        loaded = load_mesh(medit)
    assert isinstance(loaded, MeshTri) and float(element_volumes(loaded).sum()) == pytest.approx(1.0)


@pytest.mark.parametrize("size, noise", [(1.0, 4.4e-8), (1e-13, 0.0), (1e6, 1e-7)])
def test_an_outline_flat_to_float32_round_off_is_read_in_its_plane(tmp_path, size, noise):
    """An audit: float32's round-off across an x-z outline's plane (4.4e-8 of it) was "not in a plane", and an
    outline 1e-13 across was read in the wrong plane (an absolute floor of 1e-12)."""
    m = beam2d(2.0, 1.0, 4, 2)
    rng = np.random.default_rng(0)
    points = np.column_stack([m.p[0], noise * rng.standard_normal(m.p.shape[1]), m.p[1]]) * size  # in x-z
    path = tmp_path / "outline.vtu"
    meshio.write(path, meshio.Mesh(points, [("triangle", m.t.T)]))
    loaded = load_mesh(path)
    assert isinstance(loaded, MeshTri)
    np.testing.assert_allclose(loaded.p, m.p * size, rtol=1e-15, atol=0.0)  # z became y
    tilted = points.copy()
    tilted[:, 1] += 1e-5 * size * m.p[0]  # beyond FLAT_RTOL: not flat
    meshio.write(path, meshio.Mesh(tilted, [("triangle", m.t.T)]))
    with pytest.raises(MeshError, match="triangles are not in a plane of constant x, y or z"):
        load_mesh(path)


def test_vertices_no_element_uses_are_dropped_with_a_warning_naming_them(tmp_path):
    # point data of the file lines up with the mesh only without the dropped rows: the user must hear of them
    m = box3d(2, 2, 2)
    n = m.p.shape[1]
    points = np.vstack([[[5.0, 5.0, 5.0]], m.p.T, [[6.0, 6.0, 6.0]]])  # unused first and last
    path = tmp_path / "box.vtu"
    meshio.write(path, meshio.Mesh(points, [("tetra", m.t.T + 1)]))
    with pytest.warns(UserWarning) as said:
        loaded = load_mesh(path)
    assert [str(w.message) for w in said] == [
        f"mesh file {str(path)!r}: 2 of its {n + 2} vertices (indices 0, {n + 1}) belong to no tetrahedron and were "
        f"dropped, so the mesh has {n}: the others keep their order, but point data from the file lines up with "
        "them only without those rows"
    ]
    np.testing.assert_array_equal(loaded.p, m.p)
    np.testing.assert_array_equal(loaded.t, m.t)
    meshio.write(path, meshio.Mesh(m.p.T, [("tetra", m.t.T)]))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # every vertex used: nothing said
        assert load_mesh(path).p.shape == (3, n)


def test_load_tetrahedra_and_quadratic_cells(tmp_path):
    m = box3d(2, 2, 2)
    path = tmp_path / "box.msh"
    meshio.write(path, meshio.Mesh(m.p.T, [("tetra", m.t.T)]), file_format="gmsh22")
    loaded = load_mesh(path)
    assert isinstance(loaded, MeshTet) and loaded.t.shape == m.t.shape
    np.testing.assert_allclose(element_volumes(loaded).sum(), 1.0)
    # the same box as quadratic tetrahedra (meshio's order: the corners, then the midpoints of edges
    # 01, 12, 02, 03, 13, 23, here each tetrahedron's own): read by its corners, and said so
    edges = [(0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3)]
    n, count = m.p.shape[1], m.t.shape[1]
    midpoints = np.concatenate([(m.p[:, m.t[a]] + m.p[:, m.t[b]]).T / 2 for a, b in edges])
    cells = np.hstack([m.t.T] + [n + k * count + np.arange(count)[:, None] for k in range(6)])
    meshio.write(path, meshio.Mesh(np.vstack([m.p.T, midpoints]), [("tetra10", cells)]), file_format="gmsh22")
    said = r"quadratic tetra10 cells are read by their corner vertices; their 288 mid-edge"
    with pytest.warns(UserWarning, match=said):
        quadratic = load_mesh(path)
    assert isinstance(quadratic, MeshTet)
    np.testing.assert_array_equal(quadratic.p, loaded.p)
    np.testing.assert_array_equal(quadratic.t, loaded.t)


def test_load_refuses_curved_surfaces_and_unknown_formats(tmp_path):
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.3]], float)
    path = tmp_path / "surface.vtu"
    meshio.write(path, meshio.Mesh(pts, [("triangle", [[0, 1, 2]])]))
    with pytest.raises(ValueError, match="not in a plane of constant x, y or z"):
        load_mesh(path)
    bad = tmp_path / "mesh.unknownext"
    bad.write_text("hello")
    with pytest.raises(ValueError, match="cannot read mesh"):
        load_mesh(bad)
    with pytest.raises(FileNotFoundError, match="mesh file not found"):
        load_mesh(tmp_path / "missing.msh")
    lines = tmp_path / "lines.vtu"
    meshio.write(lines, meshio.Mesh(pts, [("line", [[0, 1]])]))
    with pytest.raises(ValueError, match="no triangle or tetrahedron cells"):
        load_mesh(lines)


def test_unreadable_files_are_mesh_errors_naming_the_file(tmp_path, capsys):
    # meshio prints each reader's complaint and calls sys.exit when none can read a file
    garbage = tmp_path / "garbage.msh"
    garbage.write_text("garbage\n")
    with pytest.raises(MeshError, match=r"cannot read mesh '.*garbage.msh': not a file meshio reads as ansys, gmsh$"):
        load_mesh(garbage)
    empty = tmp_path / "nocells.vtu"
    meshio.write(empty, meshio.Mesh(np.random.default_rng(0).random((5, 3)), []))
    with pytest.raises(
        MeshError, match=r"cannot read mesh '.*nocells.vtu': Inconsistent data! \(not a file meshio reads as vtu\)$"
    ):
        load_mesh(empty)
    # a reader failing with an error of its own: what the file may be, then what meshio said
    hollow = tmp_path / "empty.msh"
    hollow.write_text("")
    with pytest.raises(MeshError, match=r"cannot read mesh '.*empty.msh': it is empty, cut short or not a valid \.msh "
                       r"file \(meshio's reader failed with ValueError: "):  # fmt: skip
        load_mesh(hollow)
    # meshio's own printing does not reach the terminal
    assert capsys.readouterr() == ("", "")


def test_builtin_shape_parameters_are_typed_and_all_have_defaults():
    for name in BUILTIN_SHAPES:
        defaults = shape_parameters(name)
        assert all(value is not inspect.Parameter.empty for value in defaults.values()), name
        assert builtin_mesh(name).p.shape[1] > 0  # every shape builds from its defaults alone
    box = builtin_mesh("box3d")
    assert box.t.shape[1] == 6 * 8**3 and np.ptp(box.p, axis=1).tolist() == [1.0, 1.0, 1.0]
    with pytest.raises(ValueError, match=r"shape 'caterpillar': parameter nx: expected an integer, got 'a' \(str\)"):
        builtin_mesh("caterpillar", nx="a")
    with pytest.raises(ValueError, match=r"parameter width: expected a finite number, got '2' \(str\)"):
        builtin_mesh("caterpillar", width="2")
    with pytest.raises(ValueError, match=r"parameter size: expected a list of 3 numbers, got \[1, 2\]"):
        builtin_mesh("box3d", size=[1, 2])
    with pytest.raises(ValueError, match=r"parameter normalize: expected true or false, got 1"):
        builtin_mesh("caterpillar", normalize=1)
    # an integer is a fine float, and a list a fine size
    assert builtin_mesh("box3d", nx=1, ny=1, nz=1, size=[2, 1, 1]).p[0].max() == 2.0
    # numpy's integers and bools are Python's (counts from an array, say); a float cannot hold 10**400
    box = builtin_mesh("box3d", nx=np.int64(1), ny=1, nz=np.int32(2), size=[np.int64(2), 1.0, np.float32(1)])
    assert box.t.shape[1] == 6 * 2 and builtin_mesh("caterpillar", normalize=np.bool_(False)).p.shape[1] > 0
    with pytest.raises(ValueError, match=r"parameter width: expected a finite number, got 1000000000000"):
        builtin_mesh("caterpillar", width=10**400)


def test_connected_parts():
    p = [[0, 0], [1, 0], [0, 1], [5, 5], [6, 5], [5, 6]]
    m = make_mesh(np.array(p, float), [[3, 4, 5], [0, 1, 2]])
    np.testing.assert_array_equal(connected_parts(m), [0, 0, 0, 1, 1, 1])


def _t_junction_2d():
    """Two unit squares side by side, the right one's triangles around a vertex on the shared edge."""
    p = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0], [2.0, 0.0], [2.0, 1.0], [1.0, 0.5]]
    t = [[0, 1, 2], [0, 2, 3], [1, 4, 6], [4, 5, 6], [5, 2, 6]]
    return np.array(p), np.array(t)


def test_a_hanging_vertex_is_named_with_the_edge_it_cracks():
    # vertex 6 lies inside the left square's edge (1, 2): the squares meet only at two corners there
    p, t = _t_junction_2d()
    message = r"1 hanging vertices \(the mesh is not conforming\): \[6\] .*vertex 6 in the edge \(1, 2\)"
    with pytest.raises(MeshError, match=message):
        make_mesh(p, t)
    # conforming: the left square split at the same vertex is accepted, and so are scikit-fem's own meshes
    make_mesh(p, [[0, 1, 6], [0, 6, 2], [0, 2, 3], [1, 4, 6], [4, 5, 6], [5, 2, 6]])
    for mesh in (MeshTri.init_symmetric().refined(3), MeshTri.init_sqsymmetric(), MeshTet.init_ball(2), box3d(4, 3, 2)):
        check_mesh(mesh)


def test_a_hanging_vertex_in_a_face_is_named():
    # a tetrahedron under one face, that face split into three around its centroid (vertex 4) on the other side
    p = np.array(
        [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.2, 0.2, -1.0], [1 / 3, 1 / 3, 0.0], [0.3, 0.3, 1.0]]
    )
    t = [[0, 1, 2, 3], [0, 1, 4, 5], [1, 2, 4, 5], [2, 0, 4, 5]]
    with pytest.raises(MeshError, match=r"\[4\] .* inside a face .*vertex 4 in the face \(0, 1, 2\)"):
        make_mesh(p, t)


def test_a_vertex_of_another_part_on_a_facet_is_two_bodies_touching():
    # a triangle whose corner rests on the middle of another's edge: two parts, no crack
    p = np.array([[0.0, 0.0], [2.0, 0.0], [1.0, 1.0], [1.0, 0.0], [0.5, -1.0], [1.5, -1.0]])
    mesh = make_mesh(p, [[0, 1, 2], [3, 4, 5]])
    assert np.unique(connected_parts(mesh)).size == 2


@pytest.mark.parametrize("scale", [1e-70, 1e61, 1e200])
def test_a_mesh_too_small_or_too_large_for_float64_is_named_with_its_size(scale):
    # its areas underflowed (reported as degenerate elements) or the modal analysis raised numpy's own errors
    mesh = MeshTri.init_symmetric()
    with pytest.raises(MeshError, match=re.escape(f"the mesh is {scale:.3g} across") + ".* rescale its coordinates"):
        make_mesh(mesh.p.T * scale, mesh.t.T)
    make_mesh(mesh.p.T * 1e-59, mesh.t.T)  # inside the range: accepted


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda: beam2d(length=np.inf), "beam2d: length must be positive and finite, got inf"),  # NaN coordinates
        (lambda: box3d(size=(1.0, np.nan, 1.0)), r"box3d: size\[1\] must be positive and finite, got nan"),
        (lambda: box3d(size=(1.0, 2.0)), r"box3d: size must be 3 edge lengths, got \(1.0, 2.0\)"),
        (lambda: box3d(0, 2, 2), "box3d: need positive cell counts, got nx=0, ny=2, nz=2"),
        # a beam's own parameters, not those of the box it is made as
        (lambda: beam3d(width=-1.0), "beam3d: width must be positive and finite, got -1.0"),
        (lambda: beam3d(nz=0), "beam3d: need positive cell counts, got nx=40, ny=4, nz=0"),
        (lambda: beam3d(nx=2.5), "beam3d: nx must be an integer, got 2.5"),
        (lambda: caterpillar(width=-1.0), "caterpillar: width must be positive and finite, got -1.0"),  # accepted
        (lambda: caterpillar(nx=3.5), "caterpillar: nx must be an integer, got 3.5"),  # numpy's own error
        (lambda: caterpillar(nx="70"), "caterpillar: nx must be an integer, got '70'"),
        (lambda: creature(cell=np.nan), "creature: cell must be positive and finite, got nan"),
        # 10 TiB asked of numpy, or minutes of building, before any word
        (lambda: creature(cell=1e-4), r"creature: these parameters make about 8.41e\+12 elements, more than 1e\+07"),
        (lambda: beam2d(nx=10**7), r"beam2d: these parameters make about 1.6e\+08 elements"),
    ],
)
def test_built_in_shapes_name_parameters_they_cannot_take(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_a_sliver_on_the_boundary_is_no_hanging_vertex():
    # a triangle whose tip is 1e-10 from its own boundary edge: the tip is no T-junction (the element
    # owning the edge is its own), but it was reported as hanging in that edge and the mesh refused
    p = [[0.0, 0.0], [1.0, 0.0], [0.5, 1e-10], [0.0, 1.0]]
    t = [[0, 1, 2], [0, 2, 3]]
    vertices, _ = hanging_vertices(np.array(p).T, np.array(t).T)
    assert vertices.size == 0
    make_mesh(p, t)


@pytest.mark.parametrize(
    "text",
    [
        # Blender's: texture coordinates and a normal beside the vertices (meshio fails on the counts)
        "o Plane\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn 0 0 1\ns 0\n"
        "f 1/1/1 2/2/1 3/3/1\nf 1/1/1 3/3/1 4/4/1\n",
        "v 0 0 0 1 0 0\nv 1 0 0 0 1 0\nv 1 1 0 0 0 1\nv 0 1 0 1 1 1\nf 1 2 3\nf 1 3 4\n",  # vertex colours
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nf -3 -2 -1\nv 0 1 0\nf -4 -2 -1\n",  # relative indices
    ],
)
def test_obj_files_as_exporters_write_them_are_read(tmp_path, text):
    """An audit: each was refused ("not a valid .obj file", "points must have 2 or 3 coordinates", "cells
    reference vertices outside 0..3"): the same unit square, two triangles."""
    path = tmp_path / "square.obj"
    path.write_text(text)
    loaded = load_mesh(path)
    np.testing.assert_array_equal(loaded.p, [[0.0, 1.0, 1.0, 0.0], [0.0, 0.0, 1.0, 1.0]])
    assert sorted(map(sorted, loaded.t.T.tolist())) == [[0, 1, 2], [0, 2, 3]]


def test_a_format_whose_reader_needs_a_package_names_it(tmp_path, monkeypatch):
    """An audit: an .xdmf without h5py was "empty, cut short or not a valid .xdmf file"."""
    import meshio

    def needs_h5py(path, *args, **kwargs):
        raise ModuleNotFoundError("No module named 'h5py'", name="h5py")

    monkeypatch.setattr(meshio, "read", needs_h5py)
    (tmp_path / "mesh.xdmf").write_text("<Xdmf/>")
    with pytest.raises(MeshError, match=r"reads \.xdmf files with the package 'h5py', which is not installed"):
        load_mesh(tmp_path / "mesh.xdmf")


def test_a_gmsh_2_2_body_in_two_physical_groups_is_read_once(tmp_path):
    """An audit: Gmsh 2.2 writes an element once for each physical group it is in; such a body was refused,
    its every element "a copy"."""
    nodes = "\n".join(f"{i + 1} {x} {y} {z}" for i, (x, y, z) in enumerate(
        [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 1)]))  # fmt: skip
    elements = ["1 4 2 1 1 1 2 3 4", "2 4 2 2 1 1 2 3 4", "3 4 2 1 1 2 3 4 5", "4 4 2 2 1 2 3 4 5"]
    text = (
        "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n5\n" + nodes + "\n$EndNodes\n"
        "$Elements\n4\n" + "\n".join(elements) + "\n$EndElements\n"
    )
    path = tmp_path / "two_groups.msh"
    path.write_text(text)
    with pytest.warns(UserWarning, match="2 tetrahedra are listed again in other physical groups"):
        loaded = load_mesh(path)
    assert loaded.t.shape == (4, 2) and float(element_volumes(loaded).sum()) == pytest.approx(1 / 6 + 1 / 3)
    path.write_text(text.replace("2 4 2 2 1", "2 4 2 1 1").replace("4 4 2 2 1", "4 4 2 1 1"))  # copies in one group
    with pytest.raises(MeshError, match="repeat earlier ones"):
        load_mesh(path)
