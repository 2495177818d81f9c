"""Hinges and pinned rigid motions come from the geometry, the same in any units and any material.

The count of zero-stiffness modes is checked against an independent dense
solve of the whole generalised eigenproblem (scipy.linalg.eigh on the
assembled K and M): its near-zero eigenvalues are the rigid motions and the
hinges, and its other eigenvalues are the elastic ones.
"""

import warnings

import numpy as np
import pytest
import scipy.linalg
from skfem import MeshTri

import skfem_modal as sm
from skfem_modal.fem import vector_dofs
from skfem_modal.mesh import _compact, coincident_vertices
from skfem_modal.modal import hinge_count
from skfem_modal.motions import facet_pieces


def _glued(*meshes):
    """Meshes side by side, their coincident vertices merged (pieces touching at vertices or edges)."""
    p = np.hstack([m.p for m in meshes])
    offsets = np.cumsum([0] + [m.p.shape[1] for m in meshes[:-1]])
    t = np.hstack([m.t + o for m, o in zip(meshes, offsets)])
    p, t = _compact(p, coincident_vertices(p.T)[t])
    return sm.make_mesh(p.T, t.T)


def _square(x, y):
    return _shifted(sm.beam2d(1.0, 1.0, 2, 2), [x, y])


def _shifted(mesh, by):
    return type(mesh)(mesh.p + np.asarray(by, dtype=float)[:, None], mesh.t)


FOUR_BAR = _glued(_square(0, 0), _square(1, 1), _square(2, 0), _square(1, -1))  # a ring of 4 squares at corners
CUBES_ON_AN_EDGE = _glued(sm.box3d(2, 2, 2), _shifted(sm.box3d(2, 2, 2), [1, 1, 0]))
CUBES_AT_A_CORNER = _glued(sm.box3d(2, 2, 2), _shifted(sm.box3d(2, 2, 2), [1, 1, 1]))
CASES = {
    "four-bar": (FOUR_BAR, 1),
    "cubes on an edge": (CUBES_ON_AN_EDGE, 1),
    "cubes at a corner": (CUBES_AT_A_CORNER, 3),
}


def _dense_eigenvalues(mesh, element, fixed=None, lam=1.0):
    K = sm.stiffness_matrix(mesh, 1.0, lam, element).toarray()
    M = sm.mass_matrix(mesh, 1.0, sm.modal.DEFAULT_MASS[element] == "lumped", element).toarray()  # the default
    if fixed is not None:
        dim = mesh.p.shape[0]
        pinned = vector_dofs(sm.modal.fixed_nodes(mesh, fixed, element), dim)
        keep = np.setdiff1d(np.arange(K.shape[0]), pinned)
        K, M = K[np.ix_(keep, keep)], M[np.ix_(keep, keep)]
    return scipy.linalg.eigh(K, M, eigvals_only=True)


@pytest.mark.parametrize("element", ["P1", "P2"])
@pytest.mark.parametrize("name", list(CASES))
def test_hinges_are_the_zero_eigenvalues_of_a_dense_solve(name, element):
    mesh, hinges = CASES[name]
    assert np.unique(facet_pieces(mesh)).size == (4 if name == "four-bar" else 2)
    assert hinge_count(mesh) == hinges
    dense = _dense_eigenvalues(mesh, element)
    zero = int((dense < 1e-9 * dense.max()).sum())
    n_rigid = sm.rigid_mode_count(mesh)
    assert zero == n_rigid + hinges
    k = zero + 5
    with pytest.warns(RuntimeWarning, match=f"{hinges} modes have zero stiffness"):
        values, modes = sm.linear_modal_analysis(mesh, k, element=element)
    np.testing.assert_allclose(values[zero:], dense[zero:k], rtol=1e-10)
    M = sm.mass_matrix(mesh, 1.0, sm.modal.DEFAULT_MASS[element] == "lumped", element)
    K = sm.stiffness_matrix(mesh, 1.0, 1.0, element)
    np.testing.assert_allclose(modes.T @ (M @ modes), np.eye(k), atol=1e-12)
    # the hinges strain nothing: no force, to round-off of the stiffness
    assert np.abs(K @ modes[:, n_rigid:zero]).max() < 1e-12 * abs(K).max()


def test_pins_hold_hinges_as_a_dense_solve_says():
    # the ring with its first square held by its left side: a four-bar linkage on its ground link, one turn
    fixed = sm.vertices_where(FOUR_BAR, "x == min")
    dense = _dense_eigenvalues(FOUR_BAR, "P1", fixed)
    zero = int((dense < 1e-9 * dense.max()).sum())
    assert sm.rigid_mode_count(FOUR_BAR, fixed) + hinge_count(FOUR_BAR, fixed) == zero == 1
    with pytest.warns(RuntimeWarning, match="1 modes have zero stiffness besides the 0 rigid motions the pins"):
        values, _ = sm.linear_modal_analysis(FOUR_BAR, 4, fixed=fixed)
    np.testing.assert_allclose(values[1:], dense[1:4], rtol=1e-10)


def test_a_stiff_material_is_no_hinge():
    # lam = 1e8 mu (the most a stiffness takes): the shear modes sit far below (2 mu + lam) / l^2, but they
    # bend; a threshold on that scale called the first two hinges, printed at 0 Hz with a hinge warning
    beam = sm.beam2d(4.0, 1.0, 16, 4)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        values, _ = sm.linear_modal_analysis(beam, 7, lam=1e8)
    assert hinge_count(beam) == 0 and values[3] > 1.0


def test_the_modes_command_labels_by_geometry_not_by_size(tmp_path, capsys):
    from skfem_modal.cli import main

    assert main(["modes", "beam2d:length=4,height=1,nx=16,ny=4", "--lam", "1e8", "-k", "6",
                 "--out", str(tmp_path / "stiff.vtu")]) == 0  # fmt: skip
    rows = [line.split() for line in capsys.readouterr().out.splitlines() if line.split()[-1:] == ["elastic"]]
    assert len(rows) == 3 and all(float(row[2]) > 0.2 for row in rows)  # frequencies, not 0


@pytest.mark.parametrize("scale", [1e-55, 1e-10, 3e8, 1e55])
def test_a_pinned_body_has_the_same_modes_in_any_units(scale):
    # the pins' rank was decided on translations (dimensionless) beside rotations (lengths): a beam
    # clamped at its left end, 1e-10 across, kept a fake rigid motion and eigenvalues 2-82 % off
    beam = sm.beam2d(4.0, 1.0, 16, 4)
    left = sm.vertices_where(beam, "x == min")
    base, _ = sm.linear_modal_analysis(beam, 4, fixed=left)
    scaled = sm.beam2d(4.0 * scale, 1.0 * scale, 16, 4)
    assert sm.rigid_mode_count(scaled, left) == 0
    for pins, expected in (([0], 1), (left[:2], 0)):
        assert sm.rigid_mode_count(scaled, pins) == expected
    values, _ = sm.linear_modal_analysis(scaled, 4, fixed=left)
    np.testing.assert_allclose(values * scale**2, base, rtol=1e-9)


def test_a_part_of_too_many_pieces_is_refused_by_name():
    # 401 triangles in a row, each touching the next at one vertex: 400 hinges, refused, not solved
    tips = np.arange(402, dtype=float)
    points = np.r_[np.c_[tips, np.zeros(402)], np.c_[tips[:-1] + 0.5, np.ones(401)]]
    triangles = np.c_[np.arange(401), np.arange(1, 402), 402 + np.arange(401)]
    chain = sm.make_mesh(points, triangles)
    with pytest.raises(ValueError, match="part 0 of the mesh falls into 401 pieces joined only at vertices"):
        sm.linear_modal_analysis(chain, 5)
    assert sm.rigid_mode_count(chain) == 3  # the rigid motions alone need no pieces


def _side_by_side(meshes):
    p = np.hstack([_shifted(m, [3.0 * i, 0.0]).p for i, m in enumerate(meshes)])
    offsets = np.cumsum([0] + [m.p.shape[1] for m in meshes[:-1]])
    return sm.make_mesh(p.T, np.hstack([m.t + o for m, o in zip(meshes, offsets)]).T)


def test_separate_parts_are_solved_one_by_one_and_agree_with_a_dense_solve():
    parts = [sm.beam2d(2.0, 1.0, 6, 3), sm.beam2d(1.0, 1.0, 3, 3), sm.beam2d(2.5, 0.5, 8, 2)]
    mesh = _side_by_side(parts)
    dense = _dense_eigenvalues(mesh, "P1")
    values, modes = sm.linear_modal_analysis(mesh, 9 + 12)
    np.testing.assert_allclose(values[9:], dense[9:21], rtol=1e-10)
    alone = np.sort(np.concatenate([sm.linear_modal_analysis(part, 3 + 12)[0][3:] for part in parts]))
    np.testing.assert_allclose(values[9:], alone[:12], rtol=1e-12)
    M, K = sm.mass_matrix(mesh), sm.stiffness_matrix(mesh)
    np.testing.assert_allclose(modes.T @ (M @ modes), np.eye(21), atol=1e-12)
    np.testing.assert_allclose(K @ modes, (M @ modes) * values, atol=1e-9 * values.max())


def test_many_identical_parts_repeat_their_frequencies_instead_of_stalling():
    # 20 identical squares solved as one problem: ARPACK gave up after 72 s with 1 of 7 modes
    square = sm.beam2d(1.0, 1.0, 6, 6)
    one, _ = sm.linear_modal_analysis(square, 3 + 2)
    mesh = _side_by_side([square] * 20)
    values, modes = sm.linear_modal_analysis(mesh, 60 + 6)
    np.testing.assert_allclose(values[60:], one[3], rtol=1e-12)  # the first 20 are all the lowest
    np.testing.assert_allclose(modes.T @ (sm.mass_matrix(mesh) @ modes), np.eye(66), atol=1e-12)
    again, twice = sm.linear_modal_analysis(mesh, 60 + 6)
    np.testing.assert_array_equal(twice, modes)  # the repeated group's basis is fixed


def test_a_material_that_nearly_keeps_its_volume_is_refused_where_round_off_would_take_its_modes():
    """An audit: lam = 1e15 mu gave eigenvalues -2, -1, -0.5 (out of order, 'elastic' at 0 Hz), exit 0."""
    beam = sm.beam2d(4.0, 0.5, 8, 2)
    with pytest.raises(ValueError, match=r"lam must be at most 1e\+08 mu .* got 1e\+15 with mu 1 .*mixed"):
        sm.linear_modal_analysis(beam, 6, mu=1.0, lam=1e15)
    lam = [1.0] * (beam.t.shape[1] - 1) + [2e8]  # per element: named
    with pytest.raises(
        ValueError, match=r"got 2e\+08 with mu 1 \(Poisson's ratio 0\.4999999975\d*\) at elements \[31\]"
    ):
        sm.linear_modal_analysis(beam, 6, mu=1.0, lam=np.array(lam))
    # up to the limit the lowest modes keep their values: they rise towards the locked limit, never fall
    lowest = [sm.linear_modal_analysis(beam, 4, mu=1.0, lam=ratio)[0][3] for ratio in (1e4, 1e6, 1e8)]
    assert 0.0 < lowest[0] <= lowest[1] <= lowest[2] and lowest[2] == pytest.approx(lowest[1], rel=1e-3)


def test_a_sliver_element_that_passes_the_mesh_check_is_solved():
    """An audit: a triangle 1e-12 high on a 0.125 edge stopped the banded Cholesky ("1460-th leading minor")."""
    beam = sm.beam2d(10.0, 1.0, 80, 8)
    top = np.flatnonzero(beam.p[1] == beam.p[1].max())
    a, b = top[np.argsort(beam.p[0, top])][2:4]
    apex = 0.5 * (beam.p[:, a] + beam.p[:, b]) + [0.0, 1e-12]
    sliver = MeshTri(np.hstack([beam.p, apex[:, None]]), np.hstack([beam.t, [[a], [b], [beam.p.shape[1]]]]))
    with_sliver, _ = sm.linear_modal_analysis(sliver, 6)
    without, _ = sm.linear_modal_analysis(beam, 6)
    np.testing.assert_allclose(with_sliver[3:], without[3:], rtol=1e-5)
