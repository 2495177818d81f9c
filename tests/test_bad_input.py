"""Every public entry point checks its input first and names the problem."""

import warnings

import numpy as np
import pytest
from skfem import MeshTri

import skfem_modal as sm
from skfem_modal.clusters import spectral_clusters
from skfem_modal.mesh import MeshError, boundary_vertices, connected_parts, mesh_summary
from skfem_modal.scene import Scene
from skfem_modal.sim import ModalMuscle
from skfem_modal.subspace import laplacian, lbs_basis, skinning_eigenmodes

GOOD = sm.beam2d(2.0, 1.0, 4, 2)


def nan_mesh():
    p = GOOD.p.copy()
    p[1, 3] = np.nan
    return MeshTri(p, GOOD.t.copy())


def degenerate_mesh():
    p = np.array([[0.0, 1.0, 2.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
    return MeshTri(p, np.array([[0, 0], [1, 1], [2, 3]]), sort_t=False)


def unused_mesh():
    p = np.hstack([GOOD.p, [[9.0], [9.0]]])
    return MeshTri(p, GOOD.t.copy())


ENTRY_POINTS = {
    "linear_modal_analysis": lambda m: sm.linear_modal_analysis(m, 3),
    "stiffness_matrix": lambda m: sm.stiffness_matrix(m),
    "mass_matrix": lambda m: sm.mass_matrix(m),
    "deformation_jacobian": lambda m: sm.deformation_jacobian(m),
    "element_volumes": lambda m: sm.element_volumes(m),
    "gravity_force": lambda m: sm.gravity_force(m, [0.0, -9.8]),
    "rigid_mode_count": lambda m: sm.rigid_mode_count(m),
    "actuation_limits": lambda m: sm.actuation_limits(m, np.zeros((m.p.size, 1))),
    "laplacian": lambda m: laplacian(m),
    "skinning_eigenmodes": lambda m: skinning_eigenmodes(m, 3),
    "spectral_clusters": lambda m: spectral_clusters(m, np.ones((m.p.shape[1], 2)), 2),
    "boundary_vertices": lambda m: boundary_vertices(m),
    "connected_parts": lambda m: connected_parts(m),
    "mesh_summary": lambda m: mesh_summary(m),
    "normalize_and_center": lambda m: sm.normalize_and_center(m),
    "vertices_where": lambda m: sm.vertices_where(m, "x < 1"),
    "export_modes": lambda m: sm.export_modes("/nonexistent/never_written.vtu", m, np.zeros((m.p.size, 1))),
    "ModalMuscle.from_mesh": lambda m: ModalMuscle.from_mesh(m, n_muscles=1, n_weights=2, n_clusters=2),
    "ModalMuscle": lambda m: ModalMuscle(
        m, np.eye(m.p.size), None, np.zeros(m.t.shape[1], int), mu=1.0, gamma=1.0, rho=1.0, h=0.1
    ),
}


@pytest.mark.parametrize("entry", ENTRY_POINTS)
@pytest.mark.parametrize(
    "make, message",
    [
        (nan_mesh, r"1 vertices have non-finite coordinates: \[3\]"),
        (degenerate_mesh, r"1 degenerate \(zero-area\) triangles: \[0\]"),
        (unused_mesh, r"1 vertices belong to no element: \[15\]"),
    ],
    ids=["non-finite", "degenerate", "unused"],
)
def test_bad_meshes_are_refused_before_any_work(entry, make, message):
    with pytest.raises(MeshError, match=message):
        ENTRY_POINTS[entry](make())


def test_not_a_mesh():
    with pytest.raises(TypeError, match="expected a linear skfem.MeshTri or skfem.MeshTet, got ndarray"):
        sm.linear_modal_analysis(np.zeros((2, 3)), 3)


def test_k_larger_than_possible():
    with pytest.raises(ValueError, match=r"k must be in 1..30"):
        sm.linear_modal_analysis(GOOD, 31)
    with pytest.raises(ValueError, match=r"number of skinning weights\) must be in 1..14"):
        skinning_eigenmodes(GOOD, 15)
    with pytest.raises(ValueError, match=r"number of clusters\) must be in 1..16"):
        spectral_clusters(GOOD, np.ones((15, 2)), 17)
    with pytest.raises(ValueError, match=r"k must be an integer in 1..15"):
        sm.farthest_point_sampling(GOOD.p.T, 16)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(h=0.0), "h must be positive"),
        (dict(h=-1.0), "h must be positive"),
        (dict(rho=0.0), "rho must be positive"),
        (dict(mu=-2.0), "mu must be positive"),
        (dict(mu=np.ones(3)), r"mu must be a scalar or have shape \(16,\)"),
        (dict(max_iter=0), "max_iter must be a positive integer"),
        (dict(tol=-1.0), "tol must be non-negative"),
        (dict(contact_model="reference", stickiness=2.0), r"stickiness must be in \[0, 1\], got 2.0"),
        (dict(contact_model="reference", push_out=-0.5), r"push_out must be non-negative"),
        (dict(stickiness=0.5), r"stickiness: settings of contact_model='reference', not of 'coulomb'"),
        (dict(contact_model="reference", friction=0.5), r"friction: a setting of contact_model='coulomb'"),
        (dict(contact_model="sticky"), r"contact_model must be one of 'coulomb', 'reference', got 'sticky'"),
        (dict(friction=-1.0), r"friction must be non-negative"),
        (dict(friction="0.5"), r"friction must be a number, got '0.5'"),  # float() took it
        (
            dict(allowance=0.0),
            r"allowance must be at least 1e-10 \(less is lost in the round-off of the positions\) and at most 0.001 "
            r"\(a tenth of a percent of the body's",
        ),
        (dict(allowance=0.005), r"allowance must be at least 1e-10 .* and at most 0.001 \(a tenth .*\), got 0.005"),
        (dict(allowance=np.nan), r"allowance must be at least 1e-10 .* and at most 0.001"),
        (
            dict(allowance=1e-16),
            r"allowance must be at least 1e-10 \(less is lost in the round-off of the positions\).*got 1e-16",
        ),
        (dict(allowance="a lot"), r"allowance must be a number \(a share of the body's size\), got 'a lot'"),
        (dict(contact_model="reference", allowance=1e-3), r"allowance: a setting of contact_model='coulomb'"),
        (dict(h=True), r"h must be a number, got True"),
        (dict(gravity=[0.0, np.inf]), "gravity must be finite"),
        (dict(up=5), r"up must be an axis index in 0..1"),
        (dict(backend="gpu"), "backend must be one of 'auto', 'numpy', 'numba', 'plain', got 'gpu'"),
    ],
)
def test_simulator_parameters(kwargs, message):
    base = dict(mu=1.0, gamma=1.0, rho=1.0, h=0.1)
    B = lbs_basis(GOOD.p.T, np.ones((GOOD.p.shape[1], 1)))  # the affine maps: the rest pose among them
    with pytest.raises((ValueError, TypeError), match=message):
        ModalMuscle(GOOD, B, None, np.zeros(16, int), **{**base, **kwargs})


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(mu="1e5"), r"mu must be a number, or one number per element, got '1e5'"),
        (dict(rho=True), r"rho must be a number, or one number per element, got True"),
        (dict(gamma=np.array(["1", "2"])), r"gamma must be a number, or one number per element, got an array of <U1"),
    ],
)
def test_material_given_as_text_is_named(kwargs, message):
    """numpy reads "1e5" as a number: from_mesh then failed in numpy's mean, naming no parameter (an audit)."""
    with pytest.raises(TypeError, match=message):
        ModalMuscle.from_mesh(sm.caterpillar(nx=12, ny=6), n_muscles=2, n_weights=3, n_clusters=4, **kwargs)


def test_labels_and_arrays_of_the_wrong_kind():
    B = lbs_basis(GOOD.p.T, np.ones((GOOD.p.shape[1], 1)))
    kw = dict(mu=1.0, gamma=1.0, rho=1.0, h=0.1)
    with pytest.raises(TypeError, match="labels must be integers"):
        ModalMuscle(GOOD, B, None, np.full(16, "a"), **kw)
    with pytest.raises(ValueError, match=r"D must have shape \(30, m\)"):
        ModalMuscle(GOOD, B, np.ones((29, 2)), np.zeros(16, int), **kw)
    with pytest.raises(ValueError, match="B must be finite"):
        ModalMuscle(GOOD, np.full((30, 1), np.nan), None, np.zeros(16, int), **kw)


def test_activation_of_the_wrong_length():
    sim = ModalMuscle.from_mesh(sm.caterpillar(nx=12, ny=6), n_muscles=2, n_weights=3, n_clusters=4)
    z, z_dot, a = sim.rest_state()
    with pytest.raises(ValueError, match=r"one value per muscle \(2\), got 3"):
        sim.step(z, z_dot, np.zeros(3))
    with pytest.raises(ValueError, match=r"z and z_dot must have shape \(18,\), got \(17,\)"):
        sim.step(z[:-1], z_dot, a)


def test_unknown_mesh_format(tmp_path):
    path = tmp_path / "mesh.xyz123"
    path.write_text("not a mesh")
    with pytest.raises(ValueError, match="cannot read mesh"):
        sm.load_mesh(path)


def test_an_incline_steeper_than_45_degrees_asks_for_the_up_axis_by_name():
    from skfem_modal.units import up_axis

    # gravity pulls most along +x: the ground's axis is y, which it pulls down along (it said no axis points up)
    with pytest.raises(ValueError, match=r"give it \(up = 1 for y, which it pulls down along\)"):
        up_axis([8.49, -4.9], 2)
    with pytest.raises(ValueError, match="so no axis points up against it"):  # nothing pulls down at all
        up_axis([8.49, 4.9], 2)
    assert up_axis([8.49, -4.9], 2, up=1) == 1
    # the advice names the axis gravity pulls along (it said flip y for a gravity along +x), and turning
    # the gravity is the fix: mirroring the mesh alone, which it offered instead, left the same error
    with pytest.raises(
        ValueError, match=r'give gravity along -x \(if the mesh is upside down too, .*mesh\.flip = \["x"\]'
    ):
        up_axis([9.8, 0.0], 2)
    for up in (0, 1):
        with pytest.raises(ValueError, match=rf"\(up = {up}\): give a gravity that pulls along -[xy]$"):
            up_axis([9.8, 0.0], 2, up=up)  # it said: mirror the mesh along x
    with pytest.raises(ValueError, match=r"\(up = 1\): give up = 0 \(x\), or give a gravity that pulls along -y$"):
        up_axis([-9.8, 0.0], 2, up=1)
    # an incline steeper than 45 degrees: the axis it pulls down along is not its largest (a review)
    with pytest.raises(ValueError, match=r"\(up = 0\): give up = 1 \(y\), or give a gravity that pulls along -x$"):
        up_axis([8.49, -4.9], 2, up=0)
    with pytest.raises(ValueError, match=r"\(up = 1\): give up = 2 \(z\), or give"):
        up_axis([0.0, 9.8, -1.0], 3, up=1)


def test_a_floating_body_may_fall_any_way():
    # without a ground nothing needs an up axis: gravity along +x was refused, naming ground.up
    from skfem_modal.units import up_axis

    assert up_axis([9.8, 0.0], 2, ground=False) == 1 and up_axis([0.0, -9.8, 0.0], 3, ground=False) == 1
    scene = Scene.from_dict({"mesh": {"shape": "caterpillar", "params": {"nx": 12, "ny": 6}},
                             "gravity": {"acceleration": [9.8, 0.0]}, "time": {"steps": 10}})  # fmt: skip
    sim = scene.build()
    z, z_dot, _ = sim.rest_state()
    start = sim.com(z)
    for _ in range(10):
        z, z_dot = sim.step(z, z_dot, velocity=True)
    # free fall along +x as implicit Euler has it: g h^2 (1 + 2 + ... + 10)
    np.testing.assert_allclose(sim.com(z) - start, [9.8 * sim.h**2 * 55, 0.0], atol=1e-9)
    with pytest.raises(ValueError, match=r"gravity \[9.8, 0.0\] has no component along -y"):
        sim.ground = -1.0  # a ground needs gravity pulling onto it
    assert sim.ground is None


def test_a_hand_made_basis_is_named_when_its_columns_depend_and_taken_when_sparse():
    import scipy.sparse as sps

    sim = sm.ModalMuscle.from_mesh(sm.caterpillar(nx=12, ny=6), n_muscles=1, n_weights=3, n_clusters=3)
    args = dict(mu=1e5, gamma=1e5, rho=1e3, h=0.01)
    # numpy's 'Singular matrix' from inside the set-up before
    with pytest.raises(ValueError, match=r"B's 12 columns are not independent \(6 of them"):
        ModalMuscle(sim.mesh, np.hstack([sim.B[:, :6], sim.B[:, :6]]), sim.D, sim.labels, **args)
    # 'setting an array element with a sequence' before: the subspace is dense
    sparse = ModalMuscle(sim.mesh, sps.csr_matrix(sim.B), sim.D, sim.labels, **args)
    dense = ModalMuscle(sim.mesh, sim.B, sim.D, sim.labels, **args)
    z, z_dot, _ = dense.rest_state()
    np.testing.assert_array_equal(sparse.step(z, z_dot, [0.1]), dense.step(z, z_dot, [0.1]))


# ------------------------------------------------------------ found by checking the docstrings' claims
HUGE = 10**400  # a Python int no float holds: float() raised OverflowError past the checks


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda: sm.muscles.checked_ramp(HUGE), "ramp must be a time >= 0"),
        (lambda: sm.contact.checked_allowance(HUGE), "allowance must be at least 1e-10"),
        (lambda: sm.contact.checked_allowance("0.001"), r"allowance must be a number \(a share"),
        (lambda: sm.study.resolution_scene({"mesh": {"shape": "caterpillar"}}, HUGE), "a resolution factor must be"),
        (lambda: sm.mesh.builtin_mesh("beam2d", nx=HUGE), "beam2d: these parameters make about inf elements"),
        (lambda: sm.mesh.beam2d(length=HUGE), "beam2d: length must be positive and finite"),
        (lambda: sm.mesh.caterpillar(n_legs=HUGE), r"caterpillar: need n_legs in \[1, 2 nx ny\]"),
        (lambda: ModalMuscle.from_mesh(GOOD, n_muscles=1, n_weights=3, n_clusters=2, h=HUGE), "h must be positive"),
    ],
)
def test_numbers_beyond_a_float_are_named(call, message):
    with pytest.raises(ValueError, match=message):
        call()


BEAM = sm.beam2d(4.0, 1.0, 8, 2)
BEAM_MODES = np.eye(BEAM.p.size)[:, :4]


@pytest.mark.parametrize(
    "call, error, message",
    [
        # an audit: an IndexError, NaN back, numpy's "ufunc 'isfinite' not supported", "could not convert string"
        (lambda: sm.mode_sign_convention(BEAM_MODES[:, 0]), ValueError, r"modes must have shape \(n_dofs, k\)"),
        (lambda: sm.mode_sign_convention(np.full((4, 2), np.nan)), ValueError, "modes must be finite"),
        (lambda: sm.actuation_limits(BEAM, BEAM_MODES, max_s="2"), TypeError, "max_s must be a number, got '2'"),
        (lambda: sm.actuation_limits(BEAM, BEAM_MODES, max_s=None), TypeError, "max_s must be a number, got None"),
        (lambda: sm.gravity_force(BEAM, "down"), ValueError, "gravity must be a finite vector of length 2, got 'down'"),
        (lambda: sm.natural_frequencies(None), TypeError, "eigenvalues must be numbers, got None"),
    ],
)
def test_the_modal_helpers_name_what_they_were_given(call, error, message):
    with pytest.raises(error, match=message):
        call()


def test_model_edits_are_checked():
    sim = ModalMuscle.from_mesh(GOOD, n_muscles=1, n_weights=3, n_clusters=2)
    model, h = sim.model, sim.h
    for bad in (-1, 0, HUGE, float("inf"), True):  # (-1 was taken, and left h at -1)
        with pytest.raises(ValueError, match="the time step h must be a positive, finite number"):
            model.retime(bad)
    assert model.h == h
    with pytest.raises(ValueError, match="the model has no effect called 'gravityy'; it has elasticity, inertia"):
        model.remove("gravityy")  # (did nothing and said nothing)
    with pytest.raises(TypeError, match="effect must be an Effect"):
        model.replace("gravity")
    assert [e.name for e in model.effects] == ["elasticity", "inertia", "muscles"]


def test_overwrite_is_a_bool_before_any_file_goes(tmp_path):
    """``overwrite="no"`` is true: it removed an earlier run's files."""
    from skfem_modal.outputs import clear_earlier_run, clear_earlier_study

    run_dir = tmp_path / "run"
    sm.run.run_scene(Scene.from_dict({"time": {"steps": 2}}), run_dir, progress=False)
    before = sorted(p.name for p in run_dir.iterdir())
    for clear in (clear_earlier_run, clear_earlier_study):
        with pytest.raises(TypeError, match="overwrite must be True or False, got 'no'"):
            clear(run_dir, "no")
    assert sorted(p.name for p in run_dir.iterdir()) == before


def test_study_and_gait_inputs_are_named():
    for cases in ((), ((8.5, 1),), "ab", ((4, 1, 2),)):  # (an IndexError; 8.5 named as the doubled 17.0)
        with pytest.raises(ValueError, match="cases must be a non-empty list of \\(nx, ny\\) pairs"):
            sm.study.modal_convergence(cases)
    with pytest.raises(ValueError, match="rounds must be a whole number >= 1, got 0"):
        sm.study.time_steps([], rounds=0)
    with pytest.raises(ValueError, match="steps must be a whole number >= 1, got 0"):
        sm.study.time_steps([], steps=0)
    with pytest.raises(ValueError, match="shape 'caterpillar': parameter zz: unknown"):
        sm.study.resolution_scene({"mesh": {"shape": "caterpillar", "params": {"zz": 1}}}, 2.0)  # (dropped)
    with pytest.raises(ValueError, match="unknown built-in shape 'blob'"):
        sm.study.resolution_scene({"mesh": {"shape": "blob"}}, 2.0)  # (a KeyError)
    with pytest.raises(ValueError, match="a gait needs one amplitude and one period per muscle"):
        sm.muscles.shortest_period([0.2, 0.1], [1.0, 0.1, 0.5])  # (an IndexError)
    space = sm.optimize.GaitSpace(2)
    with pytest.raises(ValueError, match="a point of the gait space must be finite"):
        space.gait([0.5, np.nan, 0.5, 0.5, 0.5, 0.5])  # (a gait of NaN: a collapsed search's candidates)
    with pytest.raises(TypeError, match="a gait is a dict of amplitude, period and phase, got None"):
        space.point(None)
    assert sm.play.window_size_problem((960.5, 600)).startswith("window size must be two whole numbers")
    assert sm.play.window_size_problem((True, True)).startswith("window size must be two whole numbers")
    assert sm.play.window_size_problem((960, 600)) is None


def test_submodules_are_attributes_of_the_package():
    """``sm.mesh.beam2d`` works without ``import skfem_modal.mesh`` first (an AttributeError before)."""
    import subprocess
    import sys

    code = "import skfem_modal as sm; print(sm.mesh.beam2d(2.0, 1.0, 4, 2).p.shape, hasattr(sm, 'no_such'))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "(2, 15) False"


def test_far_from_origin_names_the_mesh_as_its_caller_does():
    """(Its points' checks said "mesh:" whatever ``what`` was.)"""
    from skfem_modal.units import far_from_origin

    with pytest.raises(MeshError, match="^the scene's mesh: 1 vertices have non-finite coordinates"):
        far_from_origin(nan_mesh(), what="the scene's mesh")


def test_internal_readers_name_a_wrong_input():
    """Helpers callers reach through ``sim.model``: their errors name what they got.

    Before: ``unit_direction(dim=True)`` took a 1-vector, ``stiffness_scale`` returned a negative scale for a
    negative material, and a state of the wrong length gave numpy's "mismatch in its core dimension".
    """
    from skfem_modal.modal import stiffness_scale
    from skfem_modal.rollouts import unit_direction

    with pytest.raises(ValueError, match="dim must be 2 or 3, the scene's dimension, got True"):
        unit_direction(None, True)
    # any non-zero finite vector (an audit: 1e308s overflowed to [0, 0] and were refused, 1e-320 was "zero")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_array_equal(unit_direction([1e308, 1e308], 2), unit_direction([1.0, 1.0], 2))
        np.testing.assert_array_equal(unit_direction([1e-320, 0.0, 0.0], 3), [1.0, 0.0, 0.0])
    np.testing.assert_array_equal(unit_direction([3.0, 4.0], 2), [3.0 / 5.0, 4.0 / 5.0])  # (as before: unscaled)
    beam = sm.mesh.beam2d(nx=4, ny=1)
    with pytest.raises(ValueError, match="mu must be positive, got -1.0"):
        stiffness_scale(beam, mu=-1.0)
    with pytest.raises(ValueError, match="lam must be above -2 mu / 2"):
        stiffness_scale(beam, lam=-5.0)
    with pytest.raises(ValueError, match="rho must be positive"):
        stiffness_scale(beam, rho=0.0)
    assert stiffness_scale(beam) == pytest.approx(3.0 / 1.25)  # (2 mu + lam) / (rho l^2), elements of area 1.25 / 1
    mesh = sm.mesh.caterpillar(nx=16, ny=4)
    for model in ("coulomb", "reference"):
        sim = sm.ModalMuscle.from_mesh(
            mesh, n_muscles=2, n_weights=4, n_clusters=4, gravity=[0.0, -9.8], ground=-1.0, contact_model=model
        )
        r = sim.rest_state()[0].size
        for reader, name in ((sim.model.muscles.amplitudes, "u"), (sim.model.contact.positions, "z")):
            with pytest.raises(ValueError, match=f"^{name} must have shape \\({r},\\), the subspace's coordinates"):
                reader(np.zeros(r + 1))
