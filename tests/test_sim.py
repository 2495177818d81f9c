"""The modal-muscle simulator against the tutorial's numbers, physics and a direct minimiser."""

import numpy as np
import pytest
import scipy.optimize

from skfem_modal import (
    actuation_limits,
    boundary_vertices,
    caterpillar,
    creature,
    farthest_point_sampling,
    linear_modal_analysis,
    mass_matrix,
)
from skfem_modal.clusters import spectral_clusters
from skfem_modal.muscles import sine_gait
from skfem_modal.sim import ModalMuscle, SimulationError
from skfem_modal.subspace import mass_orthonormalize, skinning_eigenmodes

FLOAT_GAIT = dict(amplitudes=[0.9, 0.6, 0.0, 0.0], periods=[1.0, 0.7, 1.0, 1.0], phases=[0.0, 0.25, 0.0, 0.0])
CRAWL_GAIT = dict(amplitudes=[0.45, 0.35, 0.25, 0.15], periods=[1.2, 0.8, 1.0, 0.6], phases=[0.0, 0.25, 0.5, 0.1])


@pytest.fixture(scope="module")
def tutorial(cat_mesh, reference):
    """The tutorial's inputs built with our functions, with its mode signs."""
    mesh = cat_mesh
    _, modes = linear_modal_analysis(mesh, 7)
    D = modes[:, 3:7] * (reference["mode_signs_3_6"] * np.sign(modes[0, 3:7]))
    ceilings = actuation_limits(mesh, D)
    skin_values, W, B = skinning_eigenmodes(mesh, 8)
    B = mass_orthonormalize(B, mass_matrix(mesh))
    labels = spectral_clusters(mesh, W, 20, seed=0)
    return dict(mesh=mesh, D=D, ceilings=ceilings, skin_values=skin_values, W=W, B=B, labels=labels)


def run(sim, gait, steps, ceilings):
    z, z_dot, _ = sim.rest_state()
    amplitudes = np.asarray(gait["amplitudes"]) * ceilings
    coms, zs = [sim.com(z)], [z]
    for i in range(steps):
        a = sine_gait(i * sim.h, amplitudes, gait["periods"], gait["phases"])
        z_next = sim.step(z, z_dot, a)
        z_dot = (z_next - z) / sim.h
        z = z_next
        coms.append(sim.com(z))
        zs.append(z)
    return np.array(coms), np.array(zs)


def test_skinning_eigenvalues_match_the_tutorial(tutorial, reference):
    values = tutorial["skin_values"]
    assert abs(values[0]) < 1e-9
    np.testing.assert_allclose(values[1:], reference["skinning_eigenvalues"][1:], rtol=1e-6)


def test_subspace_is_mass_orthonormal(tutorial):
    B = tutorial["B"]
    assert B.shape == (3438, 48)
    M = mass_matrix(tutorial["mesh"], rho=1e3)
    np.testing.assert_allclose(B.T @ M @ B, 1000.0 * np.eye(48), atol=1e-9)


def test_clusters_are_reproducible_and_complete(tutorial):
    labels = tutorial["labels"]
    assert labels.shape == (3058,)
    assert set(np.unique(labels).tolist()) == set(range(20))
    again = spectral_clusters(tutorial["mesh"], tutorial["W"], 20, seed=0)
    np.testing.assert_array_equal(labels, again)
    other = spectral_clusters(tutorial["mesh"], tutorial["W"], 20, seed=1)
    assert not np.array_equal(labels, other)
    # sign flips of the weights do not change k-means distances, hence labels
    flipped = spectral_clusters(tutorial["mesh"], -tutorial["W"], 20, seed=0)
    np.testing.assert_array_equal(labels, flipped)


def test_no_empty_cluster_even_with_many_clusters():
    mesh = caterpillar(nx=12, ny=6)
    _, W, _ = skinning_eigenmodes(mesh, 6)
    k = mesh.t.shape[1] - 3
    labels = spectral_clusters(mesh, W, k, seed=0)
    assert np.bincount(labels, minlength=k).min() >= 1
    np.testing.assert_array_equal(spectral_clusters(mesh, W, mesh.t.shape[1]), np.arange(mesh.t.shape[1]))


def floating(tutorial, **kw):
    return ModalMuscle(
        tutorial["mesh"], tutorial["B"], tutorial["D"], tutorial["labels"], mu=1e5, gamma=1e5, rho=1e3, h=0.02, **kw
    )


def test_rest_stays_at_rest(tutorial):
    sim = floating(tutorial)
    z, z_dot, a = sim.rest_state()
    assert a.shape == (4,) and not a.any()
    np.testing.assert_allclose(sim.positions(z), tutorial["mesh"].p.T, atol=1e-12)
    z_next = sim.step(z, z_dot, a)
    assert np.abs(z_next - z).max() <= 1e-12
    assert sim.iterations == 1


def test_floating_conserves_the_centre_of_mass(tutorial):
    sim = floating(tutorial)
    assert sim.effects == ("elasticity", "inertia", "muscles")
    assert sim.ground is None and sim.contact_vertices.size == 0
    coms, zs = run(sim, FLOAT_GAIT, 180, tutorial["ceilings"])
    assert np.abs(coms - coms[0]).max() <= 1e-8
    # ... while the shape really moves
    moved = np.abs(sim.positions(zs[-1]) - sim.positions(zs[0])).max()
    assert moved > 0.05


def test_tutorial_crawl(tutorial, reference):
    mesh = tutorial["mesh"]
    X = mesh.p.T
    boundary = boundary_vertices(mesh)
    contacts = boundary[farthest_point_sampling(X[boundary], 30)]
    ground = float(X[:, 1].min()) - 0.15
    sim = ModalMuscle(
        mesh,
        tutorial["B"],
        tutorial["D"],
        tutorial["labels"],
        mu=1e6,
        gamma=1e6,
        rho=1e3,
        h=0.01,
        gravity=[0.0, -9.8],
        contact_vertices=contacts,
        ground=ground,
        contact_model="reference",
    )
    assert sim.effects == ("elasticity", "inertia", "muscles", "gravity", "contact")
    coms, _ = run(sim, CRAWL_GAIT, 450, tutorial["ceilings"])
    coms = coms[1:]
    assert coms[-1, 0] - coms[0, 0] == pytest.approx(reference["crawl_com_dx"], abs=0.01)
    lo, hi = reference["crawl_com_y_range"]
    assert coms[:, 1].min() == pytest.approx(lo, abs=0.005)
    assert coms[:, 1].max() == pytest.approx(hi, abs=0.005)


def test_stopping_rules(tutorial):
    sim = floating(tutorial, tol=0.0, max_iter=7)
    z, z_dot, _ = sim.rest_state()
    a = 0.5 * tutorial["ceilings"]
    sim.step(z, z_dot, a)
    assert sim.iterations == 7
    loose = floating(tutorial, tol=0.0, rtol=1e-2, max_iter=50)
    loose.step(z, z_dot, a)
    assert 1 < loose.iterations < 50


def test_energy_never_increases_across_iterations(tutorial):
    sim = floating(tutorial, tol=0.0)
    z, z_dot, _ = sim.rest_state()
    # start from a moving, deformed state
    for i in range(20):
        a = sine_gait(
            i * sim.h, np.array([0.9, 0.6, 0.3, 0.2]) * tutorial["ceilings"], [1.0, 0.7, 0.5, 0.4], [0, 0.25, 0.1, 0.3]
        )
        z_next = sim.step(z, z_dot, a)
        z_dot, z = (z_next - z) / sim.h, z_next
    energies = []
    for k in range(1, 16):
        sim.max_iter = k
        energies.append(sim.energy(sim.step(z, z_dot, a), z, z_dot, a))
    energies = np.array(energies)
    assert np.all(np.diff(energies) <= 1e-12 * np.abs(energies).max())
    assert energies[0] - energies[-1] > 0


def test_converged_step_is_the_energy_minimum():
    mesh = caterpillar(nx=16, ny=8)
    _, modes = linear_modal_analysis(mesh, 5)
    D = modes[:, 3:5]
    _, W, B = skinning_eigenmodes(mesh, 3)
    B = mass_orthonormalize(B, mass_matrix(mesh))
    labels = spectral_clusters(mesh, W, 4)
    sim = ModalMuscle(
        mesh, B, D, labels, mu=1e3, gamma=2e3, rho=1.0, h=0.05, gravity=[0.3, -1.0], tol=1e-13, max_iter=5000
    )
    z, _, _ = sim.rest_state()
    z_dot = np.random.default_rng(0).standard_normal(z.size) * 0.1
    a = 0.4 * actuation_limits(mesh, D)
    z_step = sim.step(z, z_dot, a)
    assert sim.iterations < 5000
    fun = lambda x: sim.energy(x, z, z_dot, a, gradient=True)  # noqa: E731
    best = scipy.optimize.minimize(fun, z, jac=True, method="BFGS", options={"gtol": 1e-11, "maxiter": 10000})
    assert np.linalg.norm(best.x - z_step) <= 1e-6 * np.linalg.norm(z_step)
    assert np.linalg.norm(fun(z_step)[1]) <= 1e-6 * np.linalg.norm(fun(z)[1])


def test_energy_gradient_matches_finite_differences(tutorial):
    sim = floating(tutorial)
    z, z_dot, _ = sim.rest_state()
    rng = np.random.default_rng(2)
    x = z + 1e-2 * rng.standard_normal(z.size)
    a = 0.3 * tutorial["ceilings"]
    E, g = sim.energy(x, z, z_dot, a, gradient=True)
    d = rng.standard_normal(z.size)
    eps = 1e-6
    fd = (sim.energy(x + eps * d, z, z_dot, a) - sim.energy(x - eps * d, z, z_dot, a)) / (2 * eps)
    assert fd == pytest.approx(g @ d, rel=1e-5)


def test_stickiness_zero_slides_and_one_sticks():
    mesh = caterpillar(nx=20, ny=10)
    results = {}
    for stickiness in (0.0, 1.0):
        sim = ModalMuscle.from_mesh(
            mesh,
            n_muscles=0,
            n_weights=4,
            n_clusters=6,
            mu=1e5,
            rho=1e3,
            h=0.01,
            gravity=[0.0, -9.8],
            ground=float(mesh.p[1].min()),
            contact_model="reference",
            stickiness=stickiness,
        )
        z, z_dot, _ = sim.rest_state()
        # slide sideways at 1 unit/s: the translation part of z
        z_dot = sim.coordinates(np.tile([1.0, 0.0], mesh.p.shape[1]))
        start = sim.com(z)[0]
        for _ in range(50):
            z_next = sim.step(z, z_dot, None)
            z_dot, z = (z_next - z) / sim.h, z_next
        results[stickiness] = sim.com(z)[0] - start
    assert results[0.0] > 0.4  # keeps most of its 0.5 of free travel
    assert results[1.0] < 0.5 * results[0.0]


def test_creature_floats_with_its_centre_of_mass_fixed():
    mesh = creature()
    sim = ModalMuscle.from_mesh(mesh, n_muscles=4, mu=1e5, rho=1e3, h=0.01)
    assert sim.B.shape[1] == 8 * 4 * 3
    coms, zs = run(
        sim, dict(amplitudes=[0.4] * 4, periods=[1.0, 0.8, 0.6, 0.9], phases=[0, 0.25, 0.5, 0.75]), 100, sim.ceilings
    )
    assert np.abs(coms - coms[0]).max() <= 1e-8
    assert np.abs(sim.positions(zs[-1]) - sim.positions(zs[0])).max() > 0.01


def test_creature_lands_and_moves_on_the_ground():
    from skfem_modal.contact import ALLOWANCE

    mesh = creature()
    ground = float(mesh.p[2].min()) - 0.05
    sim = ModalMuscle.from_mesh(mesh, n_muscles=4, mu=1e5, rho=1e3, h=0.01, gravity=[0.0, 0.0, -9.8], ground=ground)
    assert sim.contact_positions(sim.rest_state()[0]).shape[0] == boundary_vertices(mesh).size  # every one
    gait = dict(amplitudes=[0.2] * 4, periods=[1.0, 0.8, 0.6, 0.9], phases=[0, 0.25, 0.5, 0.75])
    z, z_dot, _ = sim.rest_state()
    amplitudes = np.asarray(gait["amplitudes"]) * sim.ceilings
    start = sim.com(z)
    assert sim.contact_positions(z)[:, 2].min() == pytest.approx(ground + 0.05)
    heights, depths = [], []
    for i in range(300):
        a = sine_gait(i * sim.h, amplitudes, gait["periods"], gait["phases"])
        z_next = sim.step(z, z_dot, a)
        z_dot, z = (z_next - z) / sim.h, z_next
        heights.append(sim.contact_positions(z)[:, 2].min() - ground)
        depths.append(sim.penetration(z, relative=True))
    heights = np.array(heights)
    # it fell onto the ground (free fall over 0.05 takes 0.1 s) and walks on it
    assert heights[:20].min() < 0.005
    assert np.mean(heights[20:] < 0.01) > 0.8
    # ... no boundary vertex below the ground by more than the allowance, at any step
    assert max(depths) <= ALLOWANCE * (1 + 1e-9)
    # ... and it moves
    assert np.linalg.norm((sim.com(z) - start)[:2]) > 0.05


def test_bad_inputs_are_named(tutorial):
    mesh, B, D, labels = tutorial["mesh"], tutorial["B"], tutorial["D"], tutorial["labels"]
    kw = dict(mu=1e5, gamma=1e5, rho=1e3, h=0.02)
    with pytest.raises(ValueError, match=r"B must have shape \(3438, r\)"):
        ModalMuscle(mesh, B[:-1], D, labels, **kw)
    with pytest.raises(ValueError, match=r"labels must have one label per element"):
        ModalMuscle(mesh, B, D, labels[:-1], **kw)
    with pytest.raises(ValueError, match="h must be positive"):
        ModalMuscle(mesh, B, D, labels, **{**kw, "h": 0.0})
    with pytest.raises(ValueError, match="rho must be positive"):
        ModalMuscle(mesh, B, D, labels, **{**kw, "rho": -1.0})
    with pytest.raises(ValueError, match=r"gravity must have shape \(2,\)"):
        ModalMuscle(mesh, B, D, labels, gravity=[0, 0, -9.8], **kw)
    with pytest.raises(ValueError, match="contact_vertices: a contact setting, but there is no ground"):
        ModalMuscle(mesh, B, D, labels, contact_vertices=[0, 1], **kw)
    sim = ModalMuscle(mesh, B, D, labels, **kw)
    z, z_dot, a = sim.rest_state()
    with pytest.raises(ValueError, match=r"one value per muscle \(4\), got 3"):
        sim.step(z, z_dot, a[:3])


def test_non_finite_state_raises(tutorial):
    sim = floating(tutorial)
    z, z_dot, a = sim.rest_state()
    z_dot = z_dot.copy()
    z_dot[0] = np.nan
    with pytest.raises(SimulationError, match="the state is non-finite as given: z_dot holds NaN or infinity"):
        sim.step(z, z_dot, a)


@pytest.mark.parametrize("contact", [False, True])
def test_batched_stopping_test_gives_the_answer_of_testing_each_iteration(tutorial, contact):
    # a loose tolerance, so the iteration counts vary from step to step; the
    # numpy path tests the iterations it predicts in one batch afterwards
    kw = dict(tol=2e-4, backend="numpy")
    if contact:
        mesh = tutorial["mesh"]
        kw.update(gravity=[0.0, -9.8], ground=float(mesh.p[1].min()) - 0.05, contact_vertices=np.arange(0, 200, 7))
        kw.update(contact_model="reference")
    batched, each = floating(tutorial, **kw), floating(tutorial, **kw)
    z, z_dot, _ = batched.rest_state()
    w, w_dot = z.copy(), z_dot.copy()
    counts = []
    amplitudes = np.asarray(FLOAT_GAIT["amplitudes"]) * tutorial["ceilings"]
    for i in range(60):
        a = sine_gait(i * 0.02, amplitudes, FLOAT_GAIT["periods"], FLOAT_GAIT["phases"])
        each.solver.batch = False  # test every iteration as it is made
        z_next, w_next = batched.step(z, z_dot, a), each.step(w, w_dot, a)
        assert batched.iterations == each.iterations
        np.testing.assert_array_equal(z_next, w_next)
        counts.append(batched.iterations)
        z, z_dot, w, w_dot = z_next, (z_next - z) / 0.02, w_next, (w_next - w) / 0.02
    assert len(set(counts)) >= 3  # the predictions were wrong now and then, both ways
    # a state that turns non-finite inside the unchecked iterations is reported
    z_dot = z_dot.copy()
    z_dot[0] = np.inf
    with pytest.raises(SimulationError, match="non-finite"):
        batched.step(z, z_dot, a)


def test_a_pickled_simulator_steps_as_the_original():
    # what a process pool or dask sends to its workers: the precompute travels, the backends are rebuilt
    import pickle

    mesh = creature(cell=0.3)
    sim = ModalMuscle.from_mesh(
        mesh, n_muscles=3, n_weights=4, n_clusters=6, h=0.01, gravity=[0, 0, -9.8], ground=float(mesh.p[2].min()) - 0.02
    )
    copy = pickle.loads(pickle.dumps(sim))
    assert copy.effects == sim.effects and copy.backends[0].name == sim.backends[0].name
    z, z_dot, _ = sim.rest_state()
    w, w_dot = z.copy(), z_dot.copy()
    for i in range(40):
        a = 0.4 * sim.ceilings * np.sin(0.2 * i + np.arange(3))
        z, z_dot = sim.step(z, z_dot, a, velocity=True)
        w, w_dot = copy.step(w, w_dot, a, velocity=True)
    np.testing.assert_array_equal(w, z)
    assert np.abs(z - sim.rest_state()[0]).max() > 1e-3  # it moved


def test_skinning_eigenmodes_with_repeated_eigenvalues():
    """scikit-fem's symmetric mesh and a body of two equal parts: repeated eigenvalues, a fixed basis."""
    import skfem

    from skfem_modal import beam2d, make_mesh, mass_matrix
    from skfem_modal.eigen import generic_weight

    beam = beam2d(2.0, 0.5, 8, 2)
    two = make_mesh(np.vstack([beam.p.T, beam.p.T + [3.0, 0.0]]), np.vstack([beam.t.T, beam.t.T + beam.p.shape[1]]))
    for mesh, zeros in ((skfem.MeshTri.init_symmetric().refined(2), 1), (two, 2)):
        values, W, B = skinning_eigenmodes(mesh, 6)
        M = mass_matrix(mesh, lumped=True, vector=False)
        np.testing.assert_allclose(W.T @ (M @ W), np.eye(6), atol=1e-10)
        assert np.sum(np.abs(values) < 1e-9) == zeros  # one constant per part
        repeated = np.flatnonzero(np.isclose(values[1:], values[:-1], rtol=1e-8) & (values[1:] > 1e-9))
        assert repeated.size  # a repeated pair, resolved by the generic weight: diagonal on it
        pair = W[:, [repeated[0], repeated[0] + 1]]
        S = pair.T @ (M @ (generic_weight(mesh.p.T)[::2, None] * pair))
        assert abs(S[0, 1]) < 1e-10 * abs(S).max()
        np.testing.assert_array_equal(W, skinning_eigenmodes(mesh, 6)[1])
        assert B.shape == (2 * mesh.p.shape[1], 6 * 3 * 2)


@pytest.mark.parametrize("make", [lambda: caterpillar(nx=20, ny=10), lambda: creature(cell=0.3)])
def test_realised_amplitudes_are_the_bodys_own_not_its_turning(make):
    """An audit: the creature turned 64 degrees read muscle 0 at +3.16 while commanded -0.22 (the rotation
    projected on the mode). In the body's frame a rigid motion changes no amplitude; pinned, the rest frame."""
    from skfem_modal.rotations import polar_rotations

    mesh = make()
    sim = ModalMuscle.from_mesh(mesh, n_muscles=3, n_weights=5, n_clusters=6, h=0.01)
    d, rest = sim.dim, sim.positions(sim.rest_state()[0])

    def plain(sim, u):  # the mass-weighted projection of x - X, in no frame
        return sim.model.muscles.amplitude_rows @ u - sim.model.muscles.amplitude_rest

    mode = sim.model.muscles.modes[:, 1].reshape(-1, d)
    bent = sim.coordinates(rest + 0.05 * mode / np.abs(mode).max())
    amplitudes = sim.muscle_amplitudes(bent)
    # the bent state's own amplitudes are the plain projection's (no rigid part to take out), mode 1's alone
    np.testing.assert_allclose(amplitudes, plain(sim, bent), atol=1e-6 * np.abs(amplitudes).max())
    assert abs(amplitudes[1]) > 100 * np.abs(amplitudes[[0, 2]]).max()
    turn = np.array([[0.0, -1.0], [1.0, 0.0]]) if d == 2 else np.array([[0, -1.0, 0.3], [1.0, 0, 0], [-0.3, 0, 0]])
    R = polar_rotations(np.eye(d) + turn)
    moved = sim.coordinates((sim.positions(bent) - rest.mean(axis=0)) @ R.T + 0.7)
    np.testing.assert_allclose(sim.muscle_amplitudes(moved), amplitudes, rtol=1e-9, atol=1e-12)
    assert np.abs(plain(sim, moved) - amplitudes).max() > 2 * np.abs(amplitudes).max()
    # one pin leaves the body free to turn about it: its own frame still (it had read a swing about the pin as
    # muscle action: -3.61 of a ceiling, commanded nothing; an audit); pins that hold it: the rest frame
    kw = dict(n_muscles=3, n_weights=5, n_clusters=6, h=0.01)
    one = ModalMuscle.from_mesh(mesh, pinned=[0], **kw)
    np.testing.assert_allclose(one.muscle_amplitudes(moved), one.muscle_amplitudes(bent), rtol=1e-9, atol=1e-12)
    end = np.flatnonzero(mesh.p[0] == mesh.p[0].min())
    held = ModalMuscle.from_mesh(mesh, pinned=end, **kw)
    np.testing.assert_allclose(held.muscle_amplitudes(moved), plain(held, moved), rtol=1e-12, atol=1e-12)


def test_realised_amplitudes_of_a_free_body_beside_a_held_one_are_in_its_own_frame():
    """An audit: a pin on one body put every body of the mesh in the rest frame: a floating caterpillar's
    amplitudes beside a pinned square were read with its travel and turning (-5.62 where its frame gives -7.16)."""
    from skfem_modal import beam2d, make_mesh
    from skfem_modal.rotations import polar_rotations

    # a long free beam (the muscles are its bending: the lowest modes) and a short one clamped at both ends
    beam, short = beam2d(4.0, 0.5, 16, 2), beam2d(1.0, 0.5, 4, 2)
    points = np.vstack([beam.p.T, short.p.T + [6.0, 0.0]])
    two = make_mesh(points, np.vstack([beam.t.T, short.t.T + beam.p.shape[1]]))
    clamped = np.flatnonzero((two.p[0] == 6.0) | (two.p[0] == 7.0))  # held: no rigid motion left
    with pytest.warns(UserWarning, match="gets none of them"):
        sim = ModalMuscle.from_mesh(two, n_muscles=2, n_weights=5, n_clusters=6, h=0.01, pinned=clamped)
    rest = sim.positions(sim.rest_state()[0])
    mode = sim.model.muscles.modes[:, 0].reshape(-1, 2)
    free = two.p[0] < 5.0
    assert np.abs(mode[free]).max() > 100 * np.abs(mode[~free]).max()  # the free beam's
    bent = rest + 0.05 * mode / np.abs(mode).max()
    moved = bent.copy()
    R = polar_rotations(np.array([[1.0, -0.6], [0.6, 1.0]]))
    moved[free] = (bent[free] - rest[free].mean(axis=0)) @ R.T + [0.4, 1.3]
    amplitudes = sim.muscle_amplitudes(sim.coordinates(bent))
    assert np.abs(amplitudes).max() > 1e-3
    np.testing.assert_allclose(sim.muscle_amplitudes(sim.coordinates(moved)), amplitudes, rtol=1e-8, atol=1e-12)


def test_skinning_weights_of_many_identical_bodies_do_not_depend_on_the_numbering():
    """An audit: 20 identical squares repeat each eigenvalue 40 times; solved together, shift-invert Lanczos
    returned 15 copies and then the next value, and the weights' span changed with the vertices' numbering
    (residual 0.99). Solved body by body, the group is whole."""
    from skfem import MeshTri

    from skfem_modal import make_mesh
    from skfem_modal.fem import mass_matrix

    square = MeshTri.init_sqsymmetric().refined(2)
    points = np.vstack([square.p.T + [2.0 * i, 0.0] for i in range(20)])
    cells = np.vstack([square.t.T + i * square.p.shape[1] for i in range(20)])
    mesh = make_mesh(points, cells)
    order = np.random.default_rng(1).permutation(points.shape[0])
    renumbered = make_mesh(points[order], np.argsort(order)[cells])
    values, W, _ = skinning_eigenmodes(mesh, 23)
    again, W2, _ = skinning_eigenmodes(renumbered, 23)
    single = skinning_eigenmodes(square, 2)[0][1]  # one square's lowest non-constant eigenvalue (a double one)
    np.testing.assert_allclose(values[20:], single, rtol=1e-9)
    np.testing.assert_allclose(again, values, rtol=1e-9)
    M = mass_matrix(renumbered, lumped=True, vector=False)
    extra = W[order, 20:]  # the renumbered mesh's vertex i is the original's order[i]
    residual = extra - W2[:, 20:] @ (W2[:, 20:].T @ (M @ extra))
    assert np.sqrt(np.einsum("ij,ij->j", residual, M @ residual)).max() < 1e-8
