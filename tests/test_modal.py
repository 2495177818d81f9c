import numpy as np
import pytest
import scipy.linalg
from skfem import Basis, ElementTetP2, MeshTri

import skfem_modal as sm
from skfem_modal import (
    actuation_limits,
    beam2d,
    beam3d,
    box3d,
    caterpillar,
    eigen,
    linear_modal_analysis,
    make_mesh,
    mass_matrix,
    natural_frequencies,
    rigid_mode_count,
    rigid_motions,
    stiffness_matrix,
    vertices_where,
)
from skfem_modal.modal import hinge_count, mode_sign_convention, stiffness_scale

BETA_L = np.array([1.8751040687119611, 4.6940911329739180])  # cantilever roots


@pytest.fixture(scope="module")
def tutorial_modes(cat_mesh):
    return linear_modal_analysis(cat_mesh, 7)


def test_tutorial_eigenvalues(tutorial_modes, reference):
    values, _ = tutorial_modes
    np.testing.assert_allclose(values[3:7], reference["eigenvalues_3_6"], rtol=1e-6)
    assert np.all(np.abs(values[:3]) < 1e-8)
    assert np.all(np.diff(values) >= -1e-12)


def test_tutorial_amplitude_ceilings(cat_mesh, tutorial_modes, reference):
    _, modes = tutorial_modes
    ceilings = actuation_limits(cat_mesh, modes, max_s=2.0)
    np.testing.assert_allclose(ceilings[3:7], reference["ceilings_3_6"], rtol=1e-6)
    # translations do not deform: no ceiling
    assert np.isinf(ceilings[0]) and np.isinf(ceilings[1])
    # scaling max_s scales the ceiling
    np.testing.assert_allclose(actuation_limits(cat_mesh, modes[:, 3:], max_s=1.0), ceilings[3:] / 2)


def test_modes_are_mass_orthonormal_eigenvectors(cat_mesh, tutorial_modes):
    values, modes = tutorial_modes
    M = mass_matrix(cat_mesh)
    K = stiffness_matrix(cat_mesh)
    np.testing.assert_allclose(modes.T @ M @ modes, np.eye(7), atol=1e-10)
    residual = K @ modes - (M @ modes) * values
    assert abs(residual).max() < 1e-9 * abs(K).max()


def test_rigid_modes_are_the_canonical_rigid_motions(cat_mesh, tutorial_modes):
    _, modes = tutorial_modes
    x, y = cat_mesh.p
    # first rigid mode: a pure x translation, the second a pure y translation
    np.testing.assert_allclose(modes[1::2, 0], 0.0, atol=1e-14)
    np.testing.assert_allclose(modes[0::2, 0], modes[0, 0], rtol=1e-12)
    np.testing.assert_allclose(modes[0::2, 1], 0.0, atol=1e-14)
    # the third: a rotation about the centre of mass (u = w x (X - c))
    u = modes[:, 2].reshape(-1, 2)
    m = mass_matrix(cat_mesh, vector=False).diagonal()
    c = (m[:, None] * cat_mesh.p.T).sum(0) / m.sum()
    w = u[:, 1] / (x - c[0])
    ok = np.abs(x - c[0]) > 0.1
    np.testing.assert_allclose(w[ok], w[ok][0], rtol=1e-9)


def test_rigid_mode_count():
    assert rigid_mode_count(beam2d(2.0, 1.0, 4, 2)) == 3
    assert rigid_mode_count(box3d(2, 2, 2)) == 6
    two = make_mesh([[0, 0], [1, 0], [0, 1], [3, 0], [4, 0], [3, 1]], [[0, 1, 2], [3, 4, 5]])
    assert rigid_mode_count(two) == 6
    values, _ = linear_modal_analysis(two, 7)
    assert np.all(np.abs(values[:6]) < 1e-10) and values[6] > 1e-3
    beam = beam2d(2.0, 1.0, 4, 2)
    assert rigid_mode_count(beam, fixed=[0]) == 1  # rotation about the pin
    assert rigid_mode_count(beam, fixed=vertices_where(beam, "x == min")) == 0
    assert rigid_mode_count(box3d(2, 2, 2), fixed=[0]) == 3


def test_rigid_motions_have_no_strain():
    for mesh in (beam2d(3.0, 1.0, 3, 2), box3d(2, 2, 2)):
        R = rigid_motions(mesh)
        K = stiffness_matrix(mesh)
        assert abs(K @ R).max() < 1e-12


def test_two_element_meshes_solve():
    tri = make_mesh([[0, 0], [1, 0], [0, 1], [1, 1]], [[0, 1, 2], [1, 3, 2]])
    values, modes = linear_modal_analysis(tri, 8)
    assert modes.shape == (8, 8)
    assert np.all(np.abs(values[:3]) < 1e-12) and np.all(values[3:] > 1e-2)
    tet = make_mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], [[0, 1, 2, 3], [1, 2, 3, 4]])
    values, modes = linear_modal_analysis(tet, 15)
    assert modes.shape == (15, 15)
    assert np.all(np.abs(values[:6]) < 1e-12) and np.all(values[6:] > 1e-2)
    with pytest.raises(ValueError, match=r"k must be in 1..15"):
        linear_modal_analysis(tet, 16)


def test_cantilever_2d_p2_matches_euler_bernoulli():
    # slender (L/h = 40) so shear deformation is below 0.3 % in mode 2
    L, h, E, rho = 40.0, 1.0, 3.0, 2.0
    mesh = beam2d(L, h, 160, 2)
    values, modes = linear_modal_analysis(
        mesh, 2, mu=E / 2, lam=0.0, rho=rho, fixed=vertices_where(mesh, "x == min"), element="P2"
    )
    omega_eb = BETA_L**2 * np.sqrt(E * h**2 / (12 * rho * L**4))
    np.testing.assert_allclose(np.sqrt(values), omega_eb, rtol=0.01)
    np.testing.assert_allclose(natural_frequencies(values), omega_eb / (2 * np.pi), rtol=0.01)


def test_cantilever_3d_p2_matches_euler_bernoulli():
    L, h, E, rho = 20.0, 1.0, 1.0, 1.0
    mesh = beam3d(L, h, h, 20, 2, 2)
    values, modes = linear_modal_analysis(
        mesh, 4, mu=E / 2, lam=0.0, rho=rho, fixed=vertices_where(mesh, "x == min"), element="P2"
    )
    omega_eb = BETA_L**2 * np.sqrt(E * h**2 / (12 * rho * L**4))
    # square section: each bending frequency twice (bending in y and in z)
    np.testing.assert_allclose(np.sqrt(values), np.repeat(omega_eb, 2), rtol=0.02)
    # clamped: modes vanish on the clamped face, edge nodes included (its P2 nodes by scikit-fem's own places)
    nodes = Basis(mesh, ElementTetP2()).doflocs
    assert modes.shape[0] == 3 * nodes.shape[1]
    face = np.flatnonzero(np.isclose(nodes[0], mesh.p[0].min()))
    assert face.size > np.count_nonzero(np.isclose(mesh.p[0], mesh.p[0].min()))  # edge midpoints among them
    assert np.all(modes.reshape(-1, 3, modes.shape[1])[face] == 0.0)
    assert np.abs(modes).max() > 0


def test_p1_frequencies_converge_under_refinement():
    L, h = 40.0, 1.0
    omega_eb = BETA_L[0] ** 2 * np.sqrt(h**2 / (12 * L**4))
    errors = []
    for nx, ny in [(40, 1), (80, 2), (160, 4), (320, 8)]:
        mesh = beam2d(L, h, nx, ny)
        values, _ = linear_modal_analysis(mesh, 1, mu=0.5, lam=0.0, fixed=vertices_where(mesh, "x == min"))
        errors.append(abs(np.sqrt(values[0]) / omega_eb - 1))
    errors = np.array(errors)
    assert np.all(np.diff(errors) < 0)
    rates = np.log2(errors[:-1] / errors[1:])
    assert rates[-1] > 1.8  # P1 eigenvalues converge at second order
    assert errors[-1] < 0.03


def test_fixed_vertices_have_zero_modes():
    mesh = beam2d(4.0, 1.0, 8, 2)
    fixed = vertices_where(mesh, "x == min")
    _, modes = linear_modal_analysis(mesh, 3, fixed=fixed)
    np.testing.assert_array_equal(modes.reshape(-1, 2, 3)[fixed], 0.0)
    mask = np.zeros(mesh.p.shape[1], bool)
    mask[fixed] = True
    _, modes_mask = linear_modal_analysis(mesh, 3, fixed=mask)
    np.testing.assert_array_equal(modes, modes_mask)
    with pytest.raises(ValueError, match=r"fixed: vertex indices must be in 0..26"):
        linear_modal_analysis(mesh, 3, fixed=[100])


def test_mode_signs_are_deterministic(cat_mesh, tutorial_modes):
    values, modes = tutorial_modes
    values2, modes2 = linear_modal_analysis(cat_mesh, 7)
    np.testing.assert_array_equal(np.sign(modes[np.abs(modes) > 1e-8]), np.sign(modes2[np.abs(modes) > 1e-8]))
    perm = np.random.default_rng(7).permutation(cat_mesh.t.shape[1])
    shuffled = MeshTri(cat_mesh.p.copy(), cat_mesh.t[:, perm].copy())
    values3, modes3 = linear_modal_analysis(shuffled, 7)
    np.testing.assert_allclose(values3, values, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(modes3, modes, atol=1e-8 * abs(modes).max())
    # the largest entry of each mode (the first, among round-off ties) is positive
    mag = np.abs(modes)
    top = np.argmax(mag >= (1 - 1e-6) * mag.max(axis=0), axis=0)
    assert np.all(modes[top, np.arange(7)] > 0)


def test_sign_convention_resolves_ties_by_index():
    v = np.array([[1.0, -1.0], [-1.0 + 1e-9, 1.0], [0.5, 0.2]])
    out = mode_sign_convention(v)
    np.testing.assert_array_equal(out[0], [1.0, 1.0])


def test_repeated_eigenvalues_give_a_stable_subspace():
    # a square plate: symmetric, with repeated eigenvalues
    mesh = MeshTri.init_sqsymmetric().refined(3)
    values, modes = linear_modal_analysis(mesh, 10)
    rel_gap = np.diff(values[3:]) / values[4:]
    assert (rel_gap < 1e-8).any(), "expected a repeated pair on the symmetric square"
    # the same modes (not just the same subspace) after permuting the elements
    perm = np.random.default_rng(0).permutation(mesh.t.shape[1])
    values2, modes2 = linear_modal_analysis(MeshTri(mesh.p.copy(), mesh.t[:, perm].copy()), 10)
    np.testing.assert_allclose(values2, values, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(modes2[:, :9], modes[:, :9], atol=1e-6 * abs(modes).max())


def test_consistent_mass_and_bad_arguments():
    mesh = beam2d(8.0, 1.0, 40, 4)  # 820 DOFs: the sparse shift-invert path
    vc, mc = linear_modal_analysis(mesh, 5, mass="consistent")
    M = mass_matrix(mesh, lumped=False)
    np.testing.assert_allclose(mc.T @ M @ mc, np.eye(5), atol=1e-10)
    dense = scipy.linalg.eigh(stiffness_matrix(mesh).toarray(), M.toarray(), eigvals_only=True)
    np.testing.assert_allclose(vc[3:], dense[3:5], rtol=1e-10)
    with pytest.raises(ValueError, match="mass must be 'lumped' or 'consistent'"):
        linear_modal_analysis(mesh, 5, mass="diagonal")
    with pytest.raises(TypeError, match="k must be an integer"):
        linear_modal_analysis(mesh, 2.5)


def _with_thin_element(mesh, height):
    """``mesh`` and one more element on its top face, ``height`` high: valid, but nearly flat."""
    P, T = mesh.p.T, mesh.t.T
    dim = P.shape[1]
    top = P[:, dim - 1] == P[:, dim - 1].max()
    face = mesh.facets[:, mesh.boundary_facets()].T
    face = face[top[face].all(axis=1)][0]
    apex = P[face].mean(axis=0) + height * np.eye(dim)[dim - 1]
    return type(mesh)(np.vstack([P, apex]).T, np.vstack([T, np.r_[face, len(P)]]).T)


@pytest.mark.parametrize("mesh", [beam2d(4.0, 1.0, 8, 2), beam3d(4.0, 1.0, 1.0, 4, 2, 2)], ids=["2d", "3d"])
def test_a_thin_element_leaves_the_lowest_modes_as_they_were(mesh):
    # few DOFs: the dense solve; solved directly, its errors were round-off of the thin element's
    # huge eigenvalue (h = 1e-8 gave the 2D beam -9.27 for its lowest bending mode, 0.467)
    dim = mesh.p.shape[0]
    n_rigid = 3 if dim == 2 else 6
    clean, _ = linear_modal_analysis(mesh, n_rigid + 4)
    for height in (1e-6, 1e-8, 1e-10):
        values, modes = linear_modal_analysis(_with_thin_element(mesh, height), n_rigid + 4)
        np.testing.assert_allclose(values[n_rigid:], clean[n_rigid:], rtol=1e-5)
        assert modes.shape[0] <= eigen._DENSE_LIMIT  # the dense path (the test is about it: fewer DOFs than its limit)


def _hinged_squares():
    """Two squares of 3 x 3 cells touching at one corner, (1, 1): a hinge."""
    grid = np.linspace(0.0, 1.0, 4)
    a = MeshTri.init_tensor(grid, grid)
    p = np.hstack([a.p, a.p + 1.0])
    t = np.hstack([a.t, a.t + a.p.shape[1]])
    corner = a.p.shape[1] + int(np.flatnonzero((a.p == 0.0).all(axis=0))[0])  # (1, 1) of the second
    joint = int(np.flatnonzero((a.p == 1.0).all(axis=0))[0])
    t[t == corner] = joint
    keep = np.setdiff1d(np.arange(p.shape[1]), [corner])
    renumber = np.full(p.shape[1], -1)
    renumber[keep] = np.arange(keep.size)
    return MeshTri(p[:, keep], renumber[t])


def test_a_hinge_is_said_also_when_pins_hold_the_rest():
    mesh = _hinged_squares()
    with pytest.warns(RuntimeWarning, match="1 modes have zero stiffness besides the mesh's 3 rigid motions"):
        free, _ = linear_modal_analysis(mesh, 5)
    assert abs(free[3]) < 1e-12 and free[4] > 1e-3
    left = np.flatnonzero(mesh.p[0] == 0.0)
    with pytest.warns(RuntimeWarning, match="1 modes have zero stiffness besides the 0 rigid motions the pins leave"):
        pinned, _ = linear_modal_analysis(mesh, 2, fixed=left)
    assert abs(pinned[0]) < 1e-12 and pinned[1] > 1e-3
    assert hinge_count(mesh) == 1 and hinge_count(mesh, left) == 1


def test_a_mesh_of_hinges_only_is_said_not_refused():
    # legs of a coarse caterpillar joined at single vertices: every elastic mode asked for is a hinge
    with pytest.warns(RuntimeWarning, match="3 modes have zero stiffness"):
        values, _ = linear_modal_analysis(caterpillar(nx=8, ny=5), 6)
    assert np.abs(values).max() < 1e-12 * stiffness_scale(caterpillar(nx=8, ny=5))


def test_rigid_modes_part_by_part_are_gram_schmidt_over_all_parts():
    # each part's motions are mass-orthonormalised on its own nodes (parts share none): the same columns
    # as Gram-Schmidt over all of them, at the cost of the columns asked for (a soup of 3000 triangles,
    # 9000 rigid motions, took minutes and GB for k = 4; now 0.2 s)
    from skfem_modal.eigen import sign_convention
    from skfem_modal.motions import _m_orthonormalize

    one = beam2d(2.0, 1.0, 4, 2)
    p = np.hstack([one.p, one.p + [[3.0], [0.5]], one.p * 0.5 + [[0.0], [2.0]]])
    n = one.p.shape[1]
    three = MeshTri(p, np.hstack([one.t, one.t + n, one.t + 2 * n]))
    values, modes = linear_modal_analysis(three, 11)
    whole = _m_orthonormalize(rigid_motions(three), mass_matrix(three, 1.0))
    np.testing.assert_allclose(modes[:, :9], sign_convention(whole), atol=1e-12)
    np.testing.assert_allclose(linear_modal_analysis(three, 4)[1], modes[:, :4], atol=1e-12)  # only 4 made
    assert rigid_mode_count(three) == 9 and rigid_mode_count(three, [0, n + 1]) == 9 - 2 - 2


@pytest.mark.parametrize("signs", [[1, 0], [1], [1, 2], "1,1"])
def test_muscle_modes_name_signs_that_are_not_plus_or_minus_one(signs):
    # [1, 0] made an all-zero muscle, [1] broadcast, [1, 2] doubled a mode: silently (from_mesh checked them)
    from skfem_modal.modal import muscle_modes

    with pytest.raises(ValueError, match=r"signs must be 2 values of \+1 or -1, got"):
        muscle_modes(caterpillar(nx=12, ny=6), 2, signs=signs)


def test_a_nan_eigenvalue_is_no_frequency():
    """natural_frequencies([nan]) returned NaN, and export_modes wrote it as the mode's frequency (an audit)."""
    with pytest.raises(ValueError, match=r"eigenvalues must be numbers, got NaN at \[1\]"):
        natural_frequencies([1.0, np.nan])
    assert natural_frequencies([np.inf, -1e-15]).tolist() == [np.inf, 0.0]  # beyond float64, and round-off


def test_export_refuses_a_nan_eigenvalue_before_writing(tmp_path):
    mesh = sm.beam2d(2.0, 0.5, 8, 2)
    values, modes = linear_modal_analysis(mesh, 5)
    with pytest.raises(ValueError, match=r"eigenvalues must be numbers, got NaN at \[4\]"):
        sm.export_modes(tmp_path / "m.vtu", mesh, modes, np.r_[values[:4], np.nan])
    assert not (tmp_path / "m.vtu").exists()


def test_a_thin_plate_needs_few_solves(monkeypatch):
    # a 1000:1 plate's lowest eigenvalues are 1e-9 of its elements' scale: with the shift at 1e-6 of it,
    # shift-invert Lanczos saw them all near 1 / sigma and took 5557 solves for 6 modes (one 20 x 20 cell
    # plate did not finish in 25 minutes); work is counted in solves, not timed
    import skfem_modal.eigen as eigen

    solves = []
    factor = eigen.spd_solver

    def counted(A, node_dim=1):
        solve = factor(A, node_dim)
        return lambda b: solves.append(1) or solve(b)

    monkeypatch.setattr(eigen, "spd_solver", counted)
    plate = box3d(8, 8, 1, size=(1.0, 1.0, 0.001))
    values, modes = linear_modal_analysis(plate, 12, element="P2")
    assert len(solves) <= 100
    # Kirchhoff plate: the free square's lowest modes scale as the thickness squared
    thicker, _ = linear_modal_analysis(box3d(8, 8, 1, size=(1.0, 1.0, 0.002)), 12, element="P2")
    np.testing.assert_allclose(thicker[6:9] / values[6:9], 4.0, rtol=0.01)


def test_many_modes_of_a_free_body_stay_accurate():
    # the solve multiplies a Lanczos vector's rigid-motion part by 1 / |sigma| (1e10 of the elastic
    # modes' scale): removed only after the solve, its round-off fed back, and a free cube's 60 modes
    # kept 1e-7 of rigid motion (orthogonality 2.2e-7, residuals 1.6e-6; plain eigsh: 3e-15, 1e-12)
    mesh = box3d()
    K, M = stiffness_matrix(mesh), mass_matrix(mesh)
    values, modes = linear_modal_analysis(mesh, 60)
    assert abs(modes.T @ M @ modes - np.eye(60)).max() < 1e-10
    elastic = modes[:, 6:]
    residual = np.linalg.norm(K @ elastic - M @ elastic * values[6:], axis=0) / np.linalg.norm(K @ elastic, axis=0)
    assert residual.max() < 1e-10


@pytest.mark.slow
def test_p2_frequencies_converge_at_fourth_order_with_their_default_mass():
    """An audit: with the lumped mass P2's frequencies converged at second order (0.0016 % off at 320 x 8 cells)."""
    length, height = 40.0, 1.0

    def frequencies(nx, ny, mass=None):
        mesh = beam2d(length, height, nx, ny)
        fixed = vertices_where(mesh, "x == min")
        return np.sqrt(linear_modal_analysis(mesh, 4, mu=0.5, lam=0.0, fixed=fixed, element="P2", mass=mass)[0])

    fine = frequencies(640, 16)

    def errors(mass=None):
        return np.array([np.abs(frequencies(nx, nx // 40, mass) / fine - 1.0).max() for nx in (80, 160, 320)])

    consistent, lumped = errors(), errors("lumped")
    assert np.log2(consistent[:-1] / consistent[1:]).min() > 3.5 and consistent[-1] < 2e-6
    # the lumped mass: second order, and ten times as far off on the finest of them
    assert np.log2(lumped[-2] / lumped[-1]) < 2.5 and lumped[-1] > 10 * consistent[-1]


@pytest.mark.parametrize("dim", [2, 3])
def test_p2_ceilings_hold_the_largest_gradient_anywhere_in_an_element(dim):
    """An audit: P2 ceilings were read at the quadrature points, where a P2 gradient (linear over an element)
    is not largest: a mode scaled by its ceiling reached |dF| = 2.48 at element vertices with max_s = 2 (24 %)."""
    from skfem import ElementTriP2, ElementVector

    mesh = sm.beam2d(4.0, 1.0, 8, 2) if dim == 2 else sm.box3d(3, 3, 3)
    _, modes = linear_modal_analysis(mesh, 10, element="P2")
    modes = modes[:, 3 * (dim - 1) :]  # the elastic ones
    ceilings = sm.actuation_limits(mesh, modes, max_s=2.0, element="P2")
    # barycentric points all over the reference element: its vertices, edge midpoints and random inner ones
    rng = np.random.default_rng(0)
    weights = np.vstack([np.eye(dim + 1), rng.dirichlet(np.ones(dim + 1), 200)])
    corners = np.hstack([np.zeros((dim, 1)), np.eye(dim)])
    points = corners @ weights.T
    element = ElementVector(ElementTriP2() if dim == 2 else ElementTetP2())
    basis = Basis(mesh, element, quadrature=(points, np.full(points.shape[1], 1.0)))
    for k, ceiling in enumerate(ceilings):
        grad = basis.interpolate(ceiling * modes[:, k]).grad  # (dim, dim, elements, points)
        largest = np.sqrt((grad**2).sum(axis=(0, 1))).max()
        assert largest == pytest.approx(2.0, rel=1e-9)  # reached, at a vertex, and nowhere exceeded
