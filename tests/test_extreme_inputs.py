"""Extreme numbers, everything pinned, contact settings without a ground, and other inputs at the edges.

Each is refused before any work with a message naming the key or argument
(the CLI: exit code 2, nothing written), or does what the docs say.
"""

import json
import warnings

import numpy as np
import pytest

import skfem_modal as sm
from skfem_modal.cli import main
from skfem_modal.eigen import lowest_eigenpairs
from skfem_modal.fem import mass_matrix, stiffness_matrix
from skfem_modal.scene import Scene, SceneError
from skfem_modal.sim import ModalMuscle
from skfem_modal.subspace import lbs_basis

SMALL = sm.caterpillar(nx=20, ny=10)
FAST = dict(n_muscles=2, n_weights=3, n_clusters=3)


def scene(**sections):
    data = {"mesh": {"shape": "caterpillar", "params": {"nx": 20, "ny": 10}}, "muscles": {"count": 2}}
    data.update(sections)
    return data


def write_scene(tmp_path, text):
    path = tmp_path / "scene.toml"
    path.write_text('[mesh]\nshape = "caterpillar"\nparams = { nx = 20, ny = 10 }\n[muscles]\ncount = 2\n' + text)
    return path


# ------------------------------------------------------------ extreme numbers
@pytest.mark.parametrize(
    "sections, message",
    [
        ({"time": {"step": 1e300, "steps": 5}}, r"time.step = 1e\+300: the time step squared, h\^2, would be 1e\+600"),
        ({"time": {"step": 1e-300, "steps": 5}}, r"time.step = 1e-300: the time step squared, h\^2, would be 1e-600"),
        (
            {"material": {"mu": 1e300, "rho": 1e-300}},
            r"material.mu = 1e\+300 and material.rho = 1e-300: the modes' squared angular frequencies",
        ),
        (
            {"material": {"young": 1e300, "poisson": 0.3, "rho": 1e-300}},
            r"material.young = 1e\+300 and material.rho = 1e-300: the modes' squared angular frequencies",
        ),
        ({"material": {"rho": 1e-310}}, r"material.rho = 1e-310: the vertex masses, rho x element measure, would be"),
        (
            {"gravity": {"acceleration": [0.0, -1e308]}},
            r"material.rho = 1000.0 and gravity.acceleration = \[0.0, -1e\+308\]: the weights, vertex mass x",
        ),
    ],
)
def test_numbers_beyond_float64_are_scene_errors_naming_the_keys(sections, message):
    with pytest.raises(SceneError, match=message):
        Scene.from_dict(scene(**sections))


def test_a_negative_lam_is_taken_as_from_young_and_poisson_and_refused_below_the_bulk_bound():
    """``lam = -5e4`` was refused ("expected a number >= 0") while ``poisson = -0.5`` gave the same lam; the
    modes' own bound is a positive bulk modulus, lam > -2 mu / dim."""
    negative = Scene.from_dict(scene(material={"mu": 1e5, "lam": -5e4}))
    from_ratio = Scene.from_dict(scene(material={"young": 1e5, "poisson": -0.5}))
    assert negative.material()["lam"] == -5e4 == pytest.approx(from_ratio.material()["lam"])
    with pytest.raises(SceneError, match=r"material.lam = -200000.0: lam must be above -2 mu / 2 \(a positive bulk"):
        Scene.from_dict(scene(material={"mu": 1e5, "lam": -2e5}))


@pytest.mark.parametrize(
    "material, key",
    [({"mu": 1e200}, "material.mu = 1e+200"), ({"gamma": 1e300}, "material.gamma = 1e+300")],
)
def test_a_free_body_whose_inertia_is_lost_beside_its_stiffness_is_a_scene_error(material, key):
    """(Within float64's range, so ``info`` took it; ``run`` refused it after the precompute, naming no key.)"""
    with pytest.raises(SceneError) as refused:
        Scene.from_dict(scene(material=material))
    said = str(refused.value)
    assert f"{key} and material.rho = 1000.0 and time.step = 0.01: the inertia, vertex mass / h^2 (up to 1e" in said
    assert "below float64's round-off: the system matrix would be singular to working precision" in said
    # pinned, the rigid motions are the pins': the scene is taken (the system's own check decides)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # (a ScaleWarning: stiff for the step)
        Scene.from_dict(scene(material=material, pinned={"where": ["x == min"]}))


@pytest.mark.parametrize(
    "text, key",
    [
        ("[time]\nsteps = 5\nstep = 1e300\n", "time.step = 1e+300"),
        ("[material]\nmu = 1e300\nrho = 1e-300\n[time]\nsteps = 5\n", "material.mu = 1e+300 and material.rho = 1e-300"),
    ],
)
def test_the_cli_refuses_extreme_numbers_with_exit_2_and_writes_nothing(tmp_path, capsys, text, key):
    path = write_scene(tmp_path, text)
    out = tmp_path / "out"
    assert main(["run", str(path), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert key in err and "beyond float64" in err and "Traceback" not in err
    assert not out.exists()
    assert main(["info", str(path)]) == 2
    assert key in capsys.readouterr().err


@pytest.mark.parametrize(
    "arguments, message",
    [
        (dict(h=1e300), r"h = 1e\+300: the time step squared"),
        (dict(mu=1e300, rho=1e-300), r"mu = 1e\+300, rho = 1e-300: the modes' squared angular frequencies"),
        (dict(h=1e-300, gravity=[0.0, -9.8]), r"h = 1e-300: the time step squared"),
        # an OverflowError from deep in the contact's set-up before
        (dict(damping_mass=1e307, gravity=[0.0, -9.8], ground=-2.0), r"damping_mass = 1e\+307, .*: the damping"),
    ],
)
def test_from_mesh_refuses_extreme_numbers_with_a_value_error(arguments, message):
    with pytest.raises(ValueError, match=message):
        ModalMuscle.from_mesh(SMALL, **FAST, **arguments)


def test_assigning_an_extreme_time_step_is_refused_and_the_old_one_stays():
    sim = ModalMuscle.from_mesh(SMALL, **FAST, h=0.01)
    with pytest.raises(ValueError, match=r"h = 1e\+300: the time step squared"):
        sim.h = 1e300
    assert sim.h == 0.01
    with pytest.raises(ValueError, match=r"damping_mass = 1e\+307, rho = 1000, h = 0.01: the damping"):
        sim.damping_mass = 1e307
    assert sim.damping_mass == 0.0


def test_modes_refuse_frequencies_beyond_float64(capsys):
    with pytest.raises(ValueError, match=r"mu = 1e\+300, rho = 1e-300: the modes' squared angular frequencies"):
        sm.linear_modal_analysis(SMALL, 5, mu=1e300, lam=1e300, rho=1e-300)
    assert main(["modes", "caterpillar:nx=20,ny=10", "--mu", "1e300", "--rho", "1e-300", "--quiet"]) == 2
    assert "mu = 1e+300, rho = 1e-300" in capsys.readouterr().err


@pytest.mark.parametrize("mu, rho", [(1e200, 1e3), (1e6, 1e-290), (1e-150, 1e150)])
def test_the_eigensolver_does_not_depend_on_units(mu, rho):
    """Eigenvalues scale as mu / rho and modes as 1 / sqrt(rho), exactly, where the numbers fit float64.

    (A stiffness of 1e200 used to underflow ARPACK's M-norms to zero: "ARPACK error -9".)
    """
    mesh = sm.caterpillar(nx=40, ny=20)  # 630 DOFs: past the dense solver, ARPACK's shift-invert
    values, modes = sm.linear_modal_analysis(mesh, 6, mu=1.0, lam=1.0, rho=1.0)
    scaled_values, scaled_modes = sm.linear_modal_analysis(mesh, 6, mu=mu, lam=mu, rho=rho)
    np.testing.assert_allclose(scaled_values[3:], values[3:] * (mu / rho), rtol=1e-9)
    np.testing.assert_allclose(scaled_modes[:, 3:] * np.sqrt(rho), modes[:, 3:], atol=1e-9 * np.abs(modes).max())
    K, M = stiffness_matrix(mesh, mu=mu, lam=mu), mass_matrix(mesh, rho=rho)
    lowest, _ = lowest_eigenpairs(K, M, 6, 2)
    np.testing.assert_allclose(lowest[3:], values[3:] * (mu / rho), rtol=1e-9)


def test_a_stiffness_of_1e200_now_reaches_the_named_system_check():
    """Past the modes (ARPACK's, on this mesh), the system says why it cannot be solved.

    The inertia is lost beside the stiffness: the existing check names the time step.
    """
    with pytest.raises(ValueError, match=r"singular to working precision: with h = 0.01 the inertia term"):
        ModalMuscle.from_mesh(sm.caterpillar(nx=40, ny=20), **FAST, mu=1e200, rho=1e3, h=0.01)


def test_damping_too_large_for_float64_is_named_with_each_term_before_any_warning():
    """Damping coefficients within the float range check's estimate but whose system matrix overflows.

    The factorisation's symmetrisation overflowed (a RuntimeWarning) into a 'singular' matrix
    blamed on the stiffness.
    """
    mesh = sm.caterpillar(nx=20, ny=10)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        with pytest.raises(ValueError, match=r"entries overflow, .*muscles \S+, damping inf; make the largest term"):
            ModalMuscle.from_mesh(mesh, **FAST, damping_stiffness=1e300)
        # smaller, it still swamps the inertia: the damping is named, not the stiffness
        with pytest.raises(ValueError, match=r"of the damping term \(up to .*make the damping coefficients smaller"):
            ModalMuscle.from_mesh(mesh, **FAST, damping_stiffness=1e290)


# ---------------------------------------------------------- pinning everything
def test_pinning_every_vertex_is_a_scene_error_naming_the_key():
    for pinned in ({"where": ["x >= min"]}, {"box": {"min": [-9.0, -9.0], "max": [9.0, 9.0]}}):
        with pytest.raises(
            SceneError,
            match=f"pinned: the selection holds all {SMALL.p.shape[1]} vertices of the mesh: nothing is left free",
        ):
            Scene.from_dict(scene(pinned=pinned))


def test_muscles_beyond_the_pins_free_dofs_are_named():
    x = SMALL.p[0]
    keep = np.unique(x)[-2]  # pin all but the column of vertices at the largest x
    free = 2 * int(np.sum(x > keep))
    assert free > 0
    with pytest.raises(SceneError, match=f"muscles.count: {free + 1} is too many for the {free} degrees of freedom"):
        Scene.from_dict({**scene(pinned={"where": [f"x <= {keep}"]}), "muscles": {"count": free + 1}})


def test_the_modes_command_and_function_refuse_pinning_every_vertex(capsys):
    args = ["modes", "caterpillar:nx=20,ny=10", "-k", "5", "--fix", "x >= min", "--quiet"]
    assert main(args) == 2
    assert (
        f"--fix x >= min holds all {SMALL.p.shape[1]} vertices of the mesh: nothing is left free to move (fix fewer)"
        in capsys.readouterr().err
    )
    with pytest.raises(ValueError, match=f"fixed: pins all {SMALL.p.shape[1]} vertices: no degree of freedom"):
        sm.linear_modal_analysis(SMALL, 2, fixed=np.arange(SMALL.p.shape[1]))


# ------------------------------------------------------ contacts: info and run
def test_info_and_run_agree_on_the_contact_points(tmp_path, capsys):
    path = write_scene(
        tmp_path, "[time]\nsteps = 2\n[gravity]\nacceleration = [0.0, -9.8]\n[ground]\ncontacts = 100000\n"
    )
    boundary = sm.boundary_vertices(SMALL).size
    assert main(["info", str(path)]) == 0
    text = capsys.readouterr().out
    assert f"contact at all {boundary} boundary vertices (contacts = 100000 asks for more: all are used)" in text
    assert main(["run", str(path), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["sizes"]["contact_points"] == boundary


@pytest.mark.parametrize("model", ["reference", "coulomb"])
def test_contacts_all_takes_every_boundary_vertex_under_either_model(tmp_path, capsys, model):
    """'all' is all, not the model's default (the reference's 30: info said all, the run took 30)."""
    ground = f'[ground]\nmodel = "{model}"\ncontacts = "all"\n'
    path = write_scene(tmp_path, "[time]\nsteps = 2\n[gravity]\nacceleration = [0.0, -9.8]\n" + ground)
    boundary = sm.boundary_vertices(SMALL).size
    assert boundary > 30
    assert main(["info", str(path)]) == 0
    assert f"contact at all {boundary} boundary vertices" in capsys.readouterr().out
    assert main(["run", str(path), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["sizes"]["contact_points"] == boundary
    ground = float(SMALL.p[1].min()) - 0.1
    small = dict(n_muscles=2, n_weights=4, n_clusters=4, gravity=[0.0, -9.8], ground=ground, contact_model=model)
    sim = sm.ModalMuscle.from_mesh(SMALL, **small, n_contacts="all")
    assert sim.contact_vertices.size == boundary
    with pytest.raises(ValueError, match="n_contacts must be a positive integer, got 'every'"):
        sm.ModalMuscle.from_mesh(SMALL, ground=0.0, gravity=[0.0, -9.8], n_contacts="every")


def test_info_counts_contacts_among_the_candidates(tmp_path, capsys):
    ground = '[ground]\ncontacts = 5\ncontacts_where = ["y <= -0.5"]\n'
    path = write_scene(tmp_path, "[gravity]\nacceleration = [0.0, -9.8]\n" + ground)
    candidates = np.intersect1d(sm.boundary_vertices(SMALL), np.nonzero(SMALL.p[1] <= -0.5)[0]).size
    assert main(["info", str(path)]) == 0
    assert f"contact at 5 of the {candidates} boundary vertices where contacts_where holds" in capsys.readouterr().out
    assert Scene.from_toml(path).contact_vertices().size == 5


# ------------------------------------------------------ ground.up and gravity
@pytest.mark.parametrize("up, said", [(0, "along -x (up = 0)"), (None, "along -y (up = 1)")])
def test_a_zero_gravity_under_a_ground_is_an_error_naming_both_keys(up, said):
    ground = {} if up is None else {"up": up}
    with pytest.raises(SceneError, match=r"gravity.acceleration and ground.up: gravity \[0.0, 0.0\] has no component"):
        Scene.from_dict(scene(gravity={"acceleration": [0.0, 0.0]}, ground=ground))
    with pytest.raises(SceneError) as err:
        Scene.from_dict(scene(gravity={"acceleration": [0.0, 0.0]}, ground=ground))
    assert said in str(err.value)


def test_a_ground_without_gravity_may_have_any_up_axis():
    assert Scene.from_dict(scene(ground={"up": 0})).up == 0


# ------------------------------------------------------------ the Python API
@pytest.mark.parametrize(
    "arguments, named",
    [
        (dict(friction=0.3), "friction=0.3: a contact setting, but there is no ground"),
        (
            dict(contact_model="reference", stickiness=0.5),
            "contact_model='reference', stickiness=0.5: contact settings",
        ),
        (dict(contact_model="reference", push_out=1.0), "contact_model='reference', push_out=1.0"),
        (dict(n_contacts=10), "n_contacts=10: a contact setting, but there is no ground"),
        (dict(contact_candidates=[0, 1]), "contact_candidates: a contact setting, but there is no ground"),
    ],
)
def test_contact_settings_without_a_ground_are_named(arguments, named, monkeypatch):
    import skfem_modal.sim as sim_module

    def no_work(*args, **kwargs):
        raise AssertionError("the precompute ran before the arguments were checked")

    monkeypatch.setattr(sim_module, "ingredients", no_work)
    with pytest.raises(ValueError) as err:
        ModalMuscle.from_mesh(SMALL, **FAST, **arguments)
    assert named in str(err.value)


def test_the_constructor_names_contact_settings_without_a_ground():
    m = SMALL
    B = lbs_basis(m.p.T, np.ones((m.p.shape[1], 1)))
    with pytest.raises(ValueError, match="friction=0.1: a contact setting, but there is no ground"):
        ModalMuscle(m, B, None, np.zeros(m.t.shape[1], int), mu=1.0, gamma=1.0, rho=1.0, h=0.1, friction=0.1)


def test_simulate_refuses_negative_steps_at_the_call():
    sim = ModalMuscle.from_mesh(SMALL, **FAST)
    for steps in (-1, 2.5, True):
        with pytest.raises(ValueError, match=f"steps must be an integer >= 0, got {steps!r}"):
            sm.simulate(sim, steps)
    assert list(sm.simulate(sim, 0)) == []
    assert [record.step for record in sm.simulate(sim, 2)] == [1, 2]


def test_state_readers_name_the_expected_shape():
    sim = ModalMuscle.from_mesh(SMALL, **FAST, gravity=[0.0, -9.8], ground=-2.0)
    z = sim.rest_state()[0]
    r = z.size
    for read in (sim.positions, sim.com, sim.muscle_amplitudes, sim.contact_positions, sim.penetration):
        with pytest.raises(ValueError, match=rf"z must have shape \({r},\), the subspace's coordinates, got \(3,\)"):
            read(z[:3])
    np.testing.assert_allclose(sim.positions(z), SMALL.p.T, atol=1e-12)


# ------------------------------------------------- a body 1e-6 across: its basis
SHARED = __import__("pathlib").Path(__file__).resolve().parents[1].parent / "shared" / "meshes"


@pytest.mark.skipif(not (SHARED / "ghost.obj").is_file(), reason=f"the real meshes are not at {SHARED}")
def test_a_tiny_body_is_orthonormalised_in_order_without_a_warning():
    """Columns of very different sizes are not dependent: no warning, Gram-Schmidt order kept.

    (The ghost 1e-6 across used to fall back to a pivoted QR, which reordered the
    basis, and warned "dropped 0 linearly dependent columns".)
    """
    import warnings

    from skfem_modal.mesh import load_mesh
    from skfem_modal.subspace import mass_orthonormalize, skinning_eigenmodes

    ghost = sm.normalize_and_center(load_mesh(SHARED / "ghost.obj"))
    tiny = type(ghost)(ghost.p * 1e-6, ghost.t)
    _, _, B = skinning_eigenmodes(tiny, 8)  # as the scene that warned: 48 columns
    M = mass_matrix(tiny)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        Q = mass_orthonormalize(B, M)
    assert Q.shape == B.shape
    np.testing.assert_allclose(Q.T @ (M @ Q), np.eye(B.shape[1]), atol=1e-12)
    # Gram-Schmidt order: each column of B is a combination of Q's columns up to its own
    R = Q.T @ (M @ B)
    assert np.abs(np.tril(R, -1)).max() < 1e-9 * np.abs(R).max()
    # a column that is a combination of others is dropped, and the warning says how many of how many
    with pytest.warns(RuntimeWarning, match=r"dropped 1 of 49 columns, linear combinations of the others.*has 48"):
        dropped = mass_orthonormalize(np.hstack([B, B[:, :1] * 3 + B[:, 1:2]]), M)
    assert dropped.shape[1] == 48
    # more columns than rows: the ones beyond are dropped too, and counted (it said it dropped none of 564)
    wide = np.random.default_rng(0).standard_normal((30, 48))
    with pytest.warns(RuntimeWarning, match=r"dropped 18 of 48 columns, .*more columns than its 30 rows.*has 30$"):
        assert mass_orthonormalize(wide, M[:30, :30]).shape == (30, 30)


def test_info_says_a_subspace_of_more_columns_than_dofs_is_the_whole_space(capsys, tmp_path):
    # 47 weights on a 64-vertex tetrahedral cube: 564 columns, 192 DOFs; info said 564, the run used 192
    path = tmp_path / "scene.toml"
    path.write_text('[mesh]\nshape = "box3d"\nparams = { nx = 3, ny = 3, nz = 3 }\n[subspace]\nweights = 47\n')
    assert main(["info", str(path)]) == 0
    assert "sizes: 192 DOFs, subspace 192 (of 564 columns: the whole space)" in capsys.readouterr().out


@pytest.mark.parametrize("offset", [1e6, 1e8])
def test_a_body_far_from_the_origin_moves_as_it_does_there(offset, recwarn):
    # the skinning basis held the positions beside the constant: at 1e6 Gram-Schmidt dropped 12 of
    # its 36 columns as dependent, and a crawl ended 8 % of the body's size off the one at the origin
    def crawl(shift):
        mesh = sm.caterpillar(nx=30, ny=15)
        mesh = type(mesh)(mesh.p + np.array([[shift], [0.0]]), mesh.t)
        sim = ModalMuscle.from_mesh(mesh, n_muscles=4, gravity=[0.0, -9.8], ground=float(mesh.p[1].min()) - 0.1)
        z, z_dot, _ = sim.rest_state()
        for i in range(60):
            z, z_dot = sim.step(z, z_dot, 0.3 * sim.ceilings * np.sin(0.1 * i), velocity=True)
        return sim.positions(z) - [shift, 0.0], sim.model.space.r

    here, r = crawl(0.0)
    there, r_there = crawl(offset)
    assert r_there == r == 8 * 3 * 2  # every weight keeps its affine columns
    assert not [w for w in recwarn if "dropped" in str(w.message)]
    # what is left: the coordinates' own round-off there (1e-16 of the offset), grown over the crawl
    # (measured 4e-13 and 8e-13 of the offset, 4e-7 and 8e-5 of the body's size)
    assert np.abs(there - here).max() <= 5e-12 * offset


def test_a_body_far_from_the_origin_is_warned_of():
    # floating at rest 5e5 sizes away, the caterpillar drifted 1.2 % of its size in 10 s, ever faster,
    # and its energy at rest read 4.6e5: the round-off of its coordinates, said as the scale is
    mesh = sm.caterpillar(nx=20, ny=10)
    size = sm.body_size(mesh)
    far = type(mesh)(mesh.p + 2000.0 * size, mesh.t)  # 2000 sizes along x and y: 2830 from the origin
    with pytest.warns(sm.ScaleWarning, match=r"centre is 2\.83e\+03 of its sizes \(2\) from the origin.*normalize"):
        sim = ModalMuscle.from_mesh(far, n_muscles=4, h=0.01)

    # and what it warns of: at rest, no load, yet a force, many times the one at the origin
    def force_at_rest(sim):
        z, z_dot, a = sim.rest_state()
        return np.linalg.norm(sim.energy(z, z, z_dot, a, gradient=True)[1])

    assert force_at_rest(sim) > 100 * force_at_rest(ModalMuscle.from_mesh(mesh, n_muscles=4, h=0.01))
    near = type(mesh)(mesh.p + 500.0 * size, mesh.t)
    with warnings.catch_warnings():
        warnings.simplefilter("error", sm.ScaleWarning)
        ModalMuscle.from_mesh(near, n_muscles=4, h=0.01)


@pytest.mark.parametrize(
    "candidates, message",
    [
        ([10**6], r"contact_candidates: 1 vertices must be vertex indices 0\.\.\d+ \(got 1000000\)"),
        ([-1, 3], r"must be vertex indices 0\.\.\d+ \(got -1\)"),
        ([0.5], r"must be vertex indices 0\.\.\d+ \(not integers\)"),
    ],
)
def test_contact_candidates_outside_the_mesh_are_named(candidates, message):
    # they were "1 vertices select no boundary vertex of the mesh"
    ground = float(SMALL.p[1].min())
    with pytest.raises(ValueError, match=message):
        ModalMuscle.from_mesh(SMALL, **FAST, gravity=[0.0, -9.8], ground=ground, contact_candidates=candidates)
