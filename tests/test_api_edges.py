"""The Python API at its edges: omitted activations, read-only sizes, states and sizes named (an audit, 2026-11-23)."""

import numpy as np
import pytest

import skfem_modal as sm
from skfem_modal.mesh import make_mesh


@pytest.fixture(scope="module")
def sim():
    return sm.ModalMuscle.from_mesh(sm.caterpillar(nx=20, ny=10), n_muscles=2, n_weights=4, n_clusters=6)


def test_an_omitted_activation_is_the_muscles_at_rest(sim):
    z, z_dot, a = sim.rest_state()
    z_dot = z_dot + 0.1 * sim.coordinates(np.tile([1.0, 0.5], sim.mesh.p.shape[1]))
    np.testing.assert_array_equal(sim.step(z, z_dot), sim.step(z, z_dot, np.zeros(2)))
    assert sim.energy(z, z, z_dot) == sim.energy(z, z, z_dot, np.zeros(2))


@pytest.mark.parametrize("name", ["n_muscles", "n_clusters", "n_active_clusters"])
def test_the_sizes_are_read_only(sim, name):
    before = getattr(sim, name)
    with pytest.raises(AttributeError, match=f"{name} is fixed when a simulator is built"):
        setattr(sim, name, 0)
    assert getattr(sim, name) == before > 0


def test_states_and_activations_are_named(sim):
    z, z_dot, a = sim.rest_state()
    records = list(sm.simulate(sim, 2, state=sim.rest_state()))  # its three values do
    assert len(records) == 2 and records[-1].z.shape == z.shape
    with pytest.raises(ValueError, match=r"state must be \(z, z_dot\)"):
        sm.simulate(sim, 2, state=z)
    with pytest.raises(ValueError, match=r"z_dot must have shape \(24,\), the subspace's coordinates, got \(3,\)"):
        sim.mechanical_energy(z, z_dot[:3])
    with pytest.raises(ValueError, match=r"z must have shape \(24,\)"):
        sim.energy(z, z[:3], z_dot)
    with pytest.raises(ValueError, match=r"activation must be finite, got \[nan, 0.0\]"):
        sim.step(z, z_dot, [np.nan, 0.0])


TRIANGLE = make_mesh(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]), np.array([[0, 1, 2]]))


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (
            dict(n_muscles=4, n_weights=2, n_clusters=1),
            r"n_muscles: 4 is too many for the 6 degrees of freedom of the mesh less its 3 rigid motions: at most 3",
        ),
        (dict(n_muscles=-1, n_weights=2, n_clusters=1), r"n_muscles must be an integer >= 0, got -1"),
        (dict(n_muscles=1), r"n_weights: 8 must be in 1..2 \(fewer than the mesh's 3 vertices\)"),
        (dict(n_muscles=1, n_weights=2, n_clusters=2), r"n_clusters: 2 must be in 1..1 \(the number of elements\)"),
        (dict(n_muscles=1, n_weights=2, n_clusters=1, seed=-1), r"seed: -1 must be an integer in 0..4294967295"),
        (dict(n_muscles=1, n_weights=2, n_clusters=1, n_contacts=0, ground=-1.0), "n_contacts must be a positive"),
        (
            dict(n_muscles=1, n_weights=2, n_clusters=1, gravity=[0.0, 0.0], ground=0.0),
            r"gravity \[0.0, 0.0\] has no component along -y \(up = 1\), so nothing pulls the body onto the ground",
        ),
    ],
)
def test_from_mesh_names_the_argument(kwargs, message):
    with pytest.raises(ValueError, match=message):
        sm.ModalMuscle.from_mesh(TRIANGLE, **kwargs)


def test_a_ground_without_gravity_is_allowed():
    sim = sm.ModalMuscle.from_mesh(TRIANGLE, n_muscles=1, n_weights=2, n_clusters=1, ground=0.0)
    assert sim.ground == 0.0 and sim.gravity is None


def test_assigning_a_gravity_that_does_not_pull_onto_the_ground_is_refused():
    mesh = sm.caterpillar(nx=12, ny=6)
    sim = sm.ModalMuscle.from_mesh(
        mesh, n_muscles=1, n_weights=3, n_clusters=3, gravity=[0.0, -9.8], ground=float(mesh.p[1].min())
    )
    with pytest.raises(ValueError, match=r"gravity \[0.0, 0.0\] has no component along -y"):
        sim.gravity = [0.0, 0.0]
    assert sim.gravity.tolist() == [0.0, -9.8]
    sim.gravity = None  # none at all is allowed, as at construction
    assert sim.gravity is None and sim.ground is not None


@pytest.mark.parametrize("name, value", [("n_weights", "3"), ("n_clusters", 4.0), ("cluster_weights", 2.5)])
def test_counts_of_the_wrong_type_are_named(name, value):
    with pytest.raises(ValueError, match=rf"{name}: {value} \(a {type(value).__name__}\) must be an integer"):
        sm.ModalMuscle.from_mesh(
            sm.beam2d(2.0, 0.5, 8, 2), **{"n_muscles": 1, "n_weights": 3, "n_clusters": 4, name: value}
        )


def test_from_mesh_names_pins_candidates_and_progress_as_given():
    import numpy as np

    import skfem_modal as sm

    mesh = sm.caterpillar(nx=12, ny=6)
    kw = dict(n_muscles=1, n_weights=3, n_clusters=3)
    left = mesh.p[0] == mesh.p[0].min()
    assert sm.ModalMuscle.from_mesh(mesh, pinned=left, **kw).pinned.tolist() == np.flatnonzero(left).tolist()
    with pytest.raises(ValueError, match=r"pinned must be vertex indices in 0..64, got 1000000"):  # said 'fixed'
        sm.ModalMuscle.from_mesh(mesh, pinned=[10**6], **kw)
    with pytest.raises(ValueError, match=r"pinned as a boolean mask must have one value per vertex, shape \(65,\)"):
        sm.ModalMuscle.from_mesh(mesh, pinned=left[:5], **kw)
    ground = dict(ground=float(mesh.p[1].min()), gravity=[0.0, -9.8])
    with pytest.raises(ValueError, match="contact_candidates: 0 vertices select no boundary vertex of the mesh"):
        sm.ModalMuscle.from_mesh(mesh, contact_candidates=[], **ground, **kw)
    with pytest.raises(TypeError, match="progress must be a callable of a stage's name, True or None, got 'yes'"):
        sm.ModalMuscle.from_mesh(mesh, progress="yes", **kw)  # True printed each stage; a bool was called


def test_simulate_takes_a_constant_activation():
    # 'numpy.ndarray' object is not callable before
    sim = sm.ModalMuscle.from_mesh(sm.caterpillar(nx=12, ny=6), n_muscles=1, n_weights=3, n_clusters=3)
    constant = [r.z for r in sm.simulate(sim, 4, 0.1 * sim.ceilings)]
    called = [r.z for r in sm.simulate(sim, 4, lambda t: 0.1 * sim.ceilings)]
    np.testing.assert_array_equal(constant, called)
    with pytest.raises(ValueError, match=r"activation must have one value per muscle \(1\), got 2"):
        sm.simulate(sim, 4, [0.1, 0.2])  # at the call, not at the first step


@pytest.mark.parametrize(
    "gait, message",
    [
        (([1.0, 2.0], [1.0, 0.0], [0.0, 0.0]), r"periods must be positive, got \[1.0, 0.0\]"),  # NaN and a warning
        (([1.0], [-1.0], [0.0]), r"periods must be positive, got \[-1.0\]"),  # ran backwards silently
        (([1.0, 2.0], [1.0, 1.0], None), r"got shapes \(2,\), \(2,\) and \(\)"),  # NaN
        (([1.0, 2.0], [1.0], [0.0, 0.0]), r"one value per muscle each, got shapes \(2,\), \(1,\) and \(2,\)"),
    ],
)
def test_sine_gait_names_what_it_cannot_take(gait, message):
    with pytest.raises(ValueError, match=message):
        sm.sine_gait(0.3, *gait)


@pytest.mark.parametrize("ramp", [-0.1, float("nan"), float("inf"), "soon", "1", True])
def test_sine_gait_names_a_ramp_it_cannot_take(ramp):
    with pytest.raises(ValueError, match=r"ramp must be a time >= 0, got"):
        sm.sine_gait(0.3, [1.0], [1.0], [0.0], ramp=ramp)


def test_a_ramped_gait_starts_at_rest_and_is_the_plain_gait_from_the_ramp_on():
    gait = ([0.7, -0.4], [1.0, 0.6], [0.25, 0.5])
    assert sm.sine_gait(0.0, *gait, ramp=0.5).tolist() == [0.0, 0.0]  # a phase of 1/4 starts at full stroke
    for t in (0.5, 0.77, 3.1):
        np.testing.assert_array_equal(sm.sine_gait(t, *gait, ramp=0.5), sm.sine_gait(t, *gait))
    # the smoothstep: half way up at half the ramp, 0.104 of the way at a fifth
    np.testing.assert_allclose(sm.sine_gait(0.25, *gait, ramp=0.5), 0.5 * sm.sine_gait(0.25, *gait), rtol=1e-15)
    np.testing.assert_allclose(sm.sine_gait(0.1, *gait, ramp=0.5), 0.104 * sm.sine_gait(0.1, *gait), rtol=1e-14)
    # times before 0 (at rest under a ramp) and arrays of times, as without one
    assert sm.sine_gait(-0.2, *gait, ramp=0.5).tolist() == [0.0, 0.0]
    np.testing.assert_allclose(
        sm.sine_gait(-0.2, *gait), [0.7 * np.sin(2 * np.pi * 0.05), -0.4 * np.sin(np.pi * 2 / 3)]
    )
    times = np.array([[0.25], [0.5]])
    np.testing.assert_array_equal(sm.sine_gait(times, *gait, ramp=0.5)[1], sm.sine_gait(0.5, *gait))
    np.testing.assert_allclose(sm.sine_gait(times, *gait, ramp=0.5)[0], 0.5 * sm.sine_gait(0.25, *gait), rtol=1e-15)
    with pytest.raises(ValueError, match="the gait must be finite"):  # not a division by zero
        sm.sine_gait(float("nan"), *gait, ramp=0.5)


def test_actuation_limits_name_transposed_and_non_finite_modes():
    mesh = sm.caterpillar(nx=12, ny=6)
    _, modes = sm.linear_modal_analysis(mesh, 5)
    with pytest.raises(ValueError, match=r"\(130, m\) for P1 or \(406, m\) for P2 on this mesh, got \(5, 130\)"):
        sm.actuation_limits(mesh, modes.T)  # said 'for P2'
    with pytest.raises(ValueError, match="modes must be finite"):  # gave inf
        sm.actuation_limits(mesh, np.full_like(modes, np.nan))


def test_raw_errors_of_numbers_are_named():
    from skfem_modal.units import scale_mismatch

    with pytest.raises(TypeError, match="Young's modulus must be a number, got '1e5'"):
        sm.lame_parameters("1e5", 0.3)
    with pytest.raises(TypeError, match="Poisson's ratio must be a number, got None"):
        sm.lame_parameters(1e5, None)
    with pytest.raises(ValueError, match=r"mu must be positive and finite, got 0.0"):  # ZeroDivisionError
        scale_mismatch(sm.beam2d(), 0.0, 1e3)
    sim = sm.ModalMuscle.from_mesh(sm.caterpillar(nx=12, ny=6), n_muscles=1, n_weights=3, n_clusters=3)
    with pytest.raises(ValueError, match=r"max_iter must be at most 100000"):  # a MemoryError at the first step
        sim.max_iter = 10**9
    z, z_dot, _ = sim.rest_state()
    z[0] = np.nan
    with pytest.raises(sm.SimulationError, match="the state is non-finite as given: z holds NaN"):
        sim.step(z, z_dot)  # 'the state became non-finite'
    for call in (lambda: sim.positions(z), lambda: sim.com(z)):
        with pytest.raises(ValueError, match="z must be finite, got NaN or infinity in it"):
            call()  # NaN positions


def test_complex_and_table_shaped_inputs_are_refused():
    sim = sm.ModalMuscle.from_mesh(sm.caterpillar(nx=12, ny=6), n_muscles=1, n_weights=3, n_clusters=3)
    z, z_dot, a = sim.rest_state()
    with pytest.raises(ValueError, match="z must be real, got complex values"):
        sim.step(z + 0j, z_dot)  # its imaginary part dropped, with numpy's ComplexWarning only
    with pytest.raises(ValueError, match="z_dot must be real"):
        sim.step(z, z_dot + 1j)
    with pytest.raises(ValueError, match="activation must be real"):
        sim.step(z, z_dot, a + 0j)
    with pytest.raises(ValueError, match=r"one value per muscle \(1\), shape \(1,\), got shape \(1, 1\)"):
        sim.step(z, z_dot, a[:, None])  # flattened, whatever order a table was in
    np.testing.assert_array_equal(sim.step(z, z_dot, 0.1), sim.step(z, z_dot, [0.1]))  # one muscle: a number will do


def test_the_full_space_simulator_names_itself_for_a_misspelt_argument():
    mesh = sm.caterpillar(nx=8, ny=4)
    with pytest.raises(TypeError, match=r"^FullSpaceSimulator\(\) got an unexpected keyword argument 'gama'"):
        sm.FullSpaceSimulator(mesh, None, mu=1.0, gama=1.0, rho=1.0, h=0.01)  # said ModalMuscle.__init__()


def test_the_full_space_simulator_given_points_for_a_mesh_names_the_mesh():
    mesh = sm.caterpillar(nx=8, ny=4)
    with pytest.raises(TypeError, match=r"^mesh: expected a linear skfem.MeshTri or skfem.MeshTet, got ndarray"):
        sm.FullSpaceSimulator(mesh.p, None, mu=1.0, rho=1.0, h=0.01)  # AttributeError: no attribute 't'


def test_the_full_space_simulator_is_made_from_a_mesh_as_the_reduced_one():
    # it inherited ModalMuscle.from_mesh, which passed a subspace and clusters it does not take (a TypeError)
    mesh = sm.beam2d(2.0, 0.5, 8, 2)
    kw = dict(mu=1e4, rho=1e3, h=0.01, gravity=[0.0, -9.8])
    sim = sm.FullSpaceSimulator.from_mesh(mesh, n_muscles=2, muscle_signs=[1, -1], **kw)
    D = sm.muscle_modes(mesh, 2, mu=1e4, rho=1e3, signs=[1, -1])
    built = sm.FullSpaceSimulator(mesh, D, gamma=1e4, **kw)
    np.testing.assert_array_equal(sim.D, built.D)
    z, z_dot, _ = sim.rest_state()
    a = 0.5 * sim.ceilings
    np.testing.assert_array_equal(sim.step(z, z_dot, a), built.step(z, z_dot, a))


def test_the_package_lists_its_public_names_only():
    names = dir(sm)
    assert {"ModalMuscle", "simulate", "sine_gait", "Scene", "__version__"} <= set(names)
    assert not [name for name in names if name.startswith("_") and not name.startswith("__")]
    assert "importlib" not in names  # an import of the lazy loader was listed as the package's


@pytest.mark.parametrize("element", ["P1", "P2"])
def test_a_translation_has_no_ceiling_and_a_rotation_one(element):
    """An audit: a translation's gradients, round-off, gave ceilings of 5.6e14 to 1.4e15 (P2), not inf."""
    mesh = sm.creature()
    values, modes = sm.linear_modal_analysis(mesh, 8, element=element)
    ceilings = sm.actuation_limits(mesh, modes, element=element)
    rigid = modes[:, :6]
    translation = np.tile(np.eye(3), rigid.shape[0] // 3).T  # (3 nodes, 3): the three translations, interleaved
    along = np.linalg.lstsq(translation, rigid, rcond=None)[1]  # residuals: 0 for a translation
    is_translation = along < 1e-20 * (rigid**2).sum(axis=0)
    assert 0 < is_translation.sum() <= 3
    assert np.all(np.isinf(ceilings[:6][is_translation]))
    assert np.all(np.isfinite(ceilings[6:])) and np.all(ceilings[6:] > 0)
    assert np.all(np.isinf(sm.actuation_limits(mesh, translation, element=element)))


# ------------------------------------------------------------ a new user's trial (2026-11-27, ninth session)


def test_a_basis_that_misses_the_rest_pose_is_refused(sim):
    """Built, its 'rest state' half the body away, and it moved 1.4 units in 20 steps without input."""
    args = dict(mu=1e5, gamma=1e5, rho=1e3, h=0.01)
    with pytest.raises(
        ValueError, match=r"B's columns do not span the rest pose: the closest B z is 1.06 from the mesh"
    ):
        sm.ModalMuscle(sim.mesh, sim.B[:, 6:], sim.D, sim.labels, **args)
    again = sm.ModalMuscle(sim.mesh, sim.B, sim.D, sim.labels, **args)  # its own basis does
    z, _, _ = again.rest_state()
    assert np.abs(again.positions(z) - sim.mesh.p.T).max() < 1e-12


def test_frames_are_checked_before_they_are_written(tmp_path):
    import meshio

    from skfem_modal.export import FrameWriter

    mesh = sm.beam2d(nx=4, ny=2)
    n = mesh.p.shape[1]
    with FrameWriter(tmp_path, mesh) as frames:
        frames.write(0.0, mesh.p.T, point_data={"s": np.zeros(n)})
        refused = [
            ((0.1, mesh.p.T), {"point_data": {"s": np.zeros(3)}}, ValueError, r"point data 's' needs shape \(15,\)"),
            ((0.1, mesh.p.T), {"point_data": {"displacement": np.zeros(n)}}, ValueError, "written with every frame"),
            ((np.nan, mesh.p.T), {}, ValueError, "time must be finite, got nan"),
            ((10**400, mesh.p.T), {}, ValueError, "time must fit a float"),
            (("0.1", mesh.p.T), {}, TypeError, "time must be a number, got '0.1'"),
            ((0.0, mesh.p.T), {}, ValueError, r"time must come after the last frame's \(0.0\), got 0.0"),
            ((0.1, np.full((n, 2), np.nan)), {}, ValueError, "positions must be finite"),
        ]
        for args, kwargs, error, said in refused:
            with pytest.raises(error, match=said):
                frames.write(*args, **kwargs)
        frames.write(np.array(0.5), mesh.p.T + 0.1)  # a 0-d array is a number
    assert sorted(p.name for p in (tmp_path / "frames").iterdir()) == ["frame_00000.vtu", "frame_00001.vtu"]
    assert meshio.read(tmp_path / "frames" / "frame_00000.vtu").point_data["s"].shape == (n,)
    assert frames.times == [0.0, 0.5]


def test_functions_that_take_a_mesh_check_it():
    from skfem import MeshQuad, MeshTri

    from skfem_modal.export import FrameWriter
    from skfem_modal.fem import node_positions

    nan_mesh = MeshTri(np.array([[0.0, 1.0, np.nan], [0.0, 0.0, 1.0]]), np.array([[0], [1], [2]]))
    calls = [
        sm.body_size,
        node_positions,
        lambda m: sm.muscle_modes(m, 1),
        lambda m: sm.scale_mismatch(m, 1e5, 1e3, [0.0, -9.8]),
        lambda m: FrameWriter("never", m),
    ]
    for call in calls:
        with pytest.raises(TypeError, match="expected a linear skfem.MeshTri or skfem.MeshTet, got str"):
            call("m")
        with pytest.raises(TypeError, match=r"got MeshQuad1 \(split it into triangles: mesh.to_meshtri\(\)\)"):
            call(MeshQuad())
        with pytest.raises(sm.MeshError, match=r"1 vertices have non-finite coordinates: \[2\]"):
            call(nan_mesh)


def test_more_arguments_are_named_when_wrong(sim):
    z, z_dot, a = sim.rest_state()
    n = sim.mesh.p.shape[1]
    with pytest.raises(ValueError, match="farthest_point_sampling: points must be finite"):
        sm.farthest_point_sampling([[np.nan, 0.0], [1.0, 0.0], [2.0, 0.0]], 3)  # was [0, 0, 0]
    for gravity in ([np.nan, -9.8], [0.0, -np.inf]):
        with pytest.raises(ValueError, match="gravity must be finite"):
            sm.up_axis(gravity, 2)  # [nan, -9.8] gave x
    with pytest.raises(ValueError, match=rf"x must have shape \({n}, 2\) or \({2 * n},\), one value per vertex"):
        sim.coordinates(np.zeros((10, 2)))
    with pytest.raises(ValueError, match="x must be finite"):
        sim.coordinates(np.full((n, 2), np.nan))
    with pytest.raises(ValueError, match=r"z must have shape \(24,\)"):
        sim.penetration(z[:-1])  # no ground: it said 0.0
    with pytest.raises(TypeError, match="velocity must be True or False, got 'yes'"):
        sim.step(z, z_dot, a, velocity="yes")
    with pytest.raises(TypeError, match="parallel must be True or False, got 'no'"):
        sm.ModalMuscle.from_mesh(sim.mesh, parallel="no")
    for muscles in (4, 0):  # it blamed the muscles, or built a body pinned everywhere
        with pytest.raises(
            ValueError, match=rf"pinned holds all {n} vertices of the mesh: nothing is left free to move \(pin fewer\)"
        ):
            sm.ModalMuscle.from_mesh(sim.mesh, n_muscles=muscles, pinned=np.arange(n))


def test_an_affine_basis_at_any_scale_is_taken_or_refused_by_what_is_wrong():
    """A review: at 1e-9 the affine basis's columns are 1e9 apart, and the fit dropped the small ones. Then the
    rank check called 4 of its 6 columns combinations of the others: their mass is 1e-19 of the others', and
    the system matrix cannot be factored for that; the error now says so, and mass_orthonormalize mends it."""
    from skfem import MeshTri

    from skfem_modal.fem import mass_matrix
    from skfem_modal.subspace import lbs_basis, mass_orthonormalize

    base = sm.caterpillar(nx=12, ny=6)
    moved = {}
    for scale in (1e-9, 1.0, 1e9):
        mesh = MeshTri(base.p * scale, base.t)
        B = lbs_basis(mesh.p.T, np.ones((mesh.p.shape[1], 1)))
        D = np.zeros((mesh.p.size, 1))
        D[::2, 0] = mesh.p[0]  # a stretch along x, the same at every scale
        labels = np.zeros(mesh.t.shape[1], dtype=np.int64)
        # lengths times s, density and time kept: stiffness times s^2 gives the same motion, scaled
        material = dict(mu=1e5 * scale**2, gamma=1e5 * scale**2, rho=1e3, h=0.01)
        if scale != 1.0:
            with pytest.raises(ValueError, match=r"B's columns differ in mass by [0-9.]+e\+1[7-9] .*mass_orthonormal"):
                sm.ModalMuscle(mesh, B, D, labels, **material)
        sim = sm.ModalMuscle(mesh, mass_orthonormalize(B, mass_matrix(mesh)), D, labels, **material)
        z, z_dot, _ = sim.rest_state()
        assert np.abs(sim.positions(z) - mesh.p.T).max() <= 1e-15 * scale
        for _ in range(20):
            z, z_dot = sim.step(z, z_dot, np.array([0.1]), velocity=True)
        moved[scale] = sim.positions(z) / scale - base.p.T
    assert np.abs(moved[1.0]).max() > 0.04  # it stretched by 4 % of its size
    np.testing.assert_allclose(moved[1e-9], moved[1.0], atol=1e-13)
    np.testing.assert_allclose(moved[1e9], moved[1.0], atol=1e-13)
    with pytest.raises(ValueError, match="B's columns do not span the rest pose"):
        sm.ModalMuscle(mesh, B[:, [0, 1, 2, 4, 5]], D, labels, **material)  # without y e_y: y = a x + b


# ---------------------------------------------------------- an audit of the API (2026-11-29)

CRAWL = {
    "mesh": {"shape": "caterpillar", "params": {"nx": 20, "ny": 10}},
    "subspace": {"weights": 4, "clusters": 6},
    "muscles": {"count": 2, "gait": {"amplitude": [0.5, 0.4], "period": [1.0, 0.7]}},
    "gravity": {"acceleration": [0.0, -9.8]},
    "ground": {"offset": 0.0},
    "time": {"step": 0.01, "steps": 30},
}


def test_arrays_given_to_and_read_from_a_simulator_are_its_own():
    """Changed in place, the caller's gravity was reported and not used; ``sim.contact_vertices[:] = 0`` broke the
    next step; ``sim.ceilings *= 2`` doubled the ceilings."""
    g, mu = np.array([0.0, -9.8]), np.full(sm.caterpillar(nx=20, ny=10).t.shape[1], 1e5)
    sim = sm.ModalMuscle.from_mesh(
        sm.caterpillar(nx=20, ny=10), n_muscles=2, n_weights=4, n_clusters=6, gravity=g, mu=mu, ground=-2.0
    )
    g[1], mu[:] = -100.0, 1.0
    np.testing.assert_array_equal(sim.gravity, [0.0, -9.8])
    assert float(sim.mu.min()) == 1e5
    for name in ("gravity", "ceilings", "B", "D", "labels", "pinned", "contact_vertices", "mu"):
        value = getattr(sim, name)
        if isinstance(value, np.ndarray) and value.size:
            with pytest.raises(ValueError, match="read-only"):
                value[...] = 0
    before = sim.gravity.copy()
    g2 = np.array([0.0, -19.6])
    sim.gravity = g2
    g2[1] = -1.0
    np.testing.assert_array_equal(sim.gravity, 2 * before)
    with pytest.raises(TypeError, match="ground must be real, got complex values"):
        sim.ground = complex(-2.0, 5.0)


def test_a_setting_assigned_its_own_value_changes_nothing_and_max_iter_keeps_the_run():
    """On the ground, ``sim.friction = sim.friction`` (and allowance, ground, up, max_iter) put in a fresh
    contact, which forgot what it held (a 3D crawl moved 4e-4 of its size); max_iter's reset made a later
    ground be judged on the rest shape."""
    scene = sm.Scene.from_dict(CRAWL)
    runs = []
    for assign in (None, "friction", "allowance", "exact_friction", "ground", "up", "max_iter"):
        sim = scene.build()
        z, z_dot, _ = sim.rest_state()
        for step in range(30):
            if step == 15 and assign is not None:
                setattr(sim, assign, getattr(sim, assign))
            z, z_dot = sim.step(z, z_dot, scene.activation(step * sim.h, sim.ceilings), velocity=True)
        runs.append(z)
    for z in runs[1:]:
        np.testing.assert_array_equal(z, runs[0])
    # thrown up, then a ground just below where the body is: taken, after max_iter was assigned too
    sim = scene.build()
    z, z_dot, _ = sim.rest_state()
    z_up = z + sim.coordinates(np.tile([0.0, 3.0], sim.mesh.p.shape[1]))
    sim.step(z_up, z_dot)
    sim.max_iter = 20
    sim.ground = float(sim.positions(z_up)[:, 1].min()) - 0.001


def test_pin_stiffness_none_gives_back_the_default_that_follows_h():
    """Read and assigned back, the default froze at its value for h = 0.01; None was refused."""
    beam = sm.beam2d(4.0, 0.4, 20, 2)
    sim = sm.ModalMuscle.from_mesh(
        beam, n_muscles=1, n_weights=3, n_clusters=4, pinned=sm.vertices_where(beam, "x == min")
    )
    default = sim.pin_stiffness
    sim.pin_stiffness = default
    sim.h = sim.h / 5
    assert sim.pin_stiffness == default
    sim.pin_stiffness = None
    fresh = sm.ModalMuscle.from_mesh(
        beam, n_muscles=1, n_weights=3, n_clusters=4, pinned=sm.vertices_where(beam, "x == min"), h=sim.h
    )
    assert sim.pin_stiffness == fresh.pin_stiffness > 2 * default  # the default, at the new step


def test_records_of_a_body_at_rest_and_the_run_of_a_scene_on_a_simulator_used_before():
    """A body at rest had a residual of 1 (1.5e-16 over 1.5e-16); run_scene(sim=) went on from the
    simulator's last run (the second run of a 3D crawl on one simulator was off by 2e-4)."""
    sim = sm.ModalMuscle.from_mesh(sm.caterpillar(nx=20, ny=10), n_muscles=2, n_weights=4, n_clusters=6)
    records = list(sm.simulate(sim, 5))
    assert [r.residual for r in records] == [0.0] * 5
    a = np.array([0.3 * float(sim.ceilings[0]), 0.0])
    fed = list(sm.simulate(sim, 3, a))
    a[0] = np.nan  # the caller's array, changed after the call: not the run's
    assert all(np.isfinite(r.z).all() for r in fed)
    import copy
    import pathlib
    import tomllib

    examples = pathlib.Path(__file__).resolve().parent.parent / "examples"
    data = tomllib.loads((examples / "creature_crawl.toml").read_text())  # 3D, the Coulomb contact
    data["mesh"]["params"] = {**data["mesh"].get("params", {}), "cell": 0.2}
    data["time"] = {**{k: v for k, v in data.get("time", {}).items() if k != "duration"}, "steps": 60}
    scene = sm.Scene.from_dict(copy.deepcopy(data), base_dir=str(examples))
    sim = scene.build()
    first = sm.run_scene(scene, sim=sim)["com"]["travel"]
    np.testing.assert_array_equal(sm.run_scene(scene, sim=sim)["com"]["travel"], first)


def test_flags_and_the_full_space_s_backend_are_checked():
    sim = sm.ModalMuscle.from_mesh(sm.caterpillar(nx=20, ny=10), n_muscles=2, n_weights=4, n_clusters=6, ground=-2.0)
    z, z_dot, _ = sim.rest_state()
    with pytest.raises(TypeError, match="relative must be True or False"):
        sim.penetration(z, relative="yes")
    with pytest.raises(TypeError, match="gradient must be True or False"):
        sim.energy(z, z, z_dot, gradient="yes")
    mesh = sm.beam2d(2.0, 0.5, 4, 1)
    with pytest.raises(ValueError, match="the full space steps on the plain backend only"):
        sm.FullSpaceSimulator(mesh, None, mu=1e5, gamma=1e5, rho=1e3, h=0.01, backend="numba")
    full = sm.FullSpaceSimulator(mesh, None, mu=1e5, gamma=1e5, rho=1e3, h=0.01)
    with pytest.raises(ValueError, match="got 'numba'"):
        full.backend = "numba"
    assert full.backend == full.backend_used == "plain"


def test_a_scene_s_dict_is_a_copy_to_change():
    """``d = scene.to_dict(); d["time"]["step"] = 0.005`` changed the scene too (its h, even to -0.5)."""
    scene = sm.Scene.from_dict(CRAWL)
    d = scene.to_dict()
    d["time"]["step"] = -0.5
    assert scene.h == 0.01 and scene.config["time"]["step"] == 0.01


def test_step_names_arguments_that_are_no_numbers_and_muscles_that_deform_nothing():
    """An audit: numpy's "could not convert string to float: 'abc'"; a zero muscle mode had an infinite ceiling."""
    mesh = sm.caterpillar(nx=20, ny=10)
    sim = sm.ModalMuscle.from_mesh(mesh, n_muscles=2, n_weights=4, n_clusters=6)
    z, z_dot, a = sim.rest_state()
    with pytest.raises(TypeError, match="z must be numbers, got 'abc'"):
        sim.step("abc", z_dot)
    with pytest.raises(TypeError, match=r"activation must be numbers, got \{'a': 1\}"):
        sim.step(z, z_dot, {"a": 1})
    D = np.zeros((mesh.p.size, 2))
    D[:, 1] = sm.muscle_modes(mesh, 1)[:, 0]
    D[0::2, 0] = 1.0  # a translation along x
    with pytest.raises(ValueError, match=r"muscle modes \[0\] \(columns of D\) deform no element"):
        sm.ModalMuscle(mesh, sim.B, D, sim.labels, mu=1e5, gamma=1e5, rho=1e3, h=0.01)
