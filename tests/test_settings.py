"""Every setting of a simulator is live (assigning it equals building with it) or read-only (assigning raises)."""

import warnings

import numpy as np
import pytest

from skfem_modal import ModalMuscle, caterpillar, creature, linear_modal_analysis, mass_matrix
from skfem_modal.clusters import spectral_clusters
from skfem_modal.mesh import boundary_vertices
from skfem_modal.subspace import mass_orthonormalize, skinning_eigenmodes


def ingredients(mesh, n_muscles=2):
    dim = mesh.p.shape[0]
    n_rigid = 3 if dim == 2 else 6
    _, modes = linear_modal_analysis(mesh, n_rigid + n_muscles)
    _, W, B = skinning_eigenmodes(mesh, 4)
    B = mass_orthonormalize(B, mass_matrix(mesh))
    return dict(mesh=mesh, B=B, D=modes[:, n_rigid:], labels=spectral_clusters(mesh, W, 6, seed=0))


@pytest.fixture(scope="module")
def flat():
    return ingredients(caterpillar(nx=20, ny=10))


@pytest.fixture(scope="module")
def solid():
    return ingredients(creature(cell=0.3))


def build(parts, **settings):
    mesh = parts["mesh"]
    up = mesh.p.shape[0] - 1
    base = dict(
        mu=1e4,
        gamma=2e4,
        rho=1e3,
        h=0.01,
        gravity=[0.0] * up + [-9.8],
        ground=float(mesh.p[up].min()) - 0.01,
        pinned=None,
        backend="numpy",
        tol=1e-6,
    )
    base.update(settings)
    return ModalMuscle(mesh, parts["B"], parts["D"], parts["labels"], **base)


def trajectory(sim, steps=25):
    z, z_dot, _ = sim.rest_state()
    zs = []
    for i in range(steps):
        a = 0.5 * sim.ceilings * np.sin(2 * np.pi * (0.02 * i / np.array([0.3, 0.5]) + [0.0, 0.3]))
        z, z_dot = sim.step(z, z_dot, a, velocity=True)
        zs.append(z)
    return np.array(zs)


LIVE = [
    ("h", 0.02, {}),
    ("max_iter", 3, {}),
    ("tol", 1e-2, {}),
    ("rtol", 1e-2, {"tol": 0.0}),
    ("etol", 1e-3, {"tol": 0.0}),
    ("warm_start", True, {"ground": None}),
    ("acceleration", "anderson", {"ground": None}),
    ("acceleration", "newton", {"ground": None}),
    ("backend", "plain", {}),
    ("gravity", [0.5, -3.0], {}),
    ("gravity", None, {}),
    ("ground", -0.56, {}),  # just below the body
    ("ground", None, {}),
    ("stickiness", 0.2, {"contact_model": "reference"}),
    ("push_out", 1.0, {"contact_model": "reference"}),
    ("friction", 0.05, {}),
    ("allowance", 1e-5, {}),  # (this caterpillar sags less than the default between the vertices looked at)
    ("contact_model", "reference", {}),
    ("damping_mass", 2.0, {}),
    ("damping_stiffness", 1e-3, {"damping_mass": 0.5}),
    ("damping_mass", 0.0, {"damping_mass": 0.5}),
    ("pin_stiffness", 5e4, {"pinned": [0, 1, 2]}),
    ("max_s", 0.5, {}),
    ("up", 0, {"gravity": [-9.8, -9.8], "up": 1, "ground": -1.05}),  # below the body along x and y
]


@pytest.mark.parametrize("name, value, base", LIVE, ids=[f"{n}={v}" for n, v, _ in LIVE])
def test_assigning_a_live_setting_equals_building_with_it(flat, name, value, base):
    sim = build(flat, **base)
    elasticity = sim.model.elasticity
    before = trajectory(sim)
    setattr(sim, name, value)
    assert getattr(sim, name) == pytest.approx(value) if value is not None else getattr(sim, name) is None
    fresh = build(flat, **{**base, name: value})
    after, expected = trajectory(sim), trajectory(fresh)
    np.testing.assert_allclose(after, expected, rtol=0, atol=1e-12 * np.abs(expected).max())
    if name != "backend":  # another backend: the same answer
        assert np.abs(after - before).max() > 1e-9 * np.abs(before).max(), f"assigning {name} changed nothing"
    assert sim.effects == fresh.effects
    assert sim.model.elasticity is elasticity  # the expensive reductions are kept
    if name == "max_s":
        np.testing.assert_allclose(sim.ceilings, fresh.ceilings)


def test_gravity_and_ground_can_be_switched_on_after_construction(solid):
    sim = build(solid, gravity=None, ground=None)
    assert sim.effects == ("elasticity", "inertia", "muscles")
    sim.gravity = [0.0, 0.0, -9.8]
    sim.ground = float(solid["mesh"].p[2].min()) - 0.01
    fresh = build(solid, contact_vertices=sim.contact_vertices)
    assert sim.effects == fresh.effects == ("elasticity", "inertia", "muscles", "gravity", "contact")
    np.testing.assert_allclose(trajectory(sim), trajectory(fresh), rtol=0, atol=1e-12)


@pytest.mark.parametrize("backend", ["numpy", "plain", "numba"])
def test_live_settings_on_every_3d_backend(solid, backend):
    from skfem_modal import _accel

    if backend == "numba" and not _accel.AVAILABLE:
        pytest.skip("numba is not installed (the optional 'fast' extra)")
    sim = build(solid, backend=backend)
    sim.h, sim.max_iter, sim.friction = 0.005, 6, 0.1
    fresh = build(solid, backend=backend, h=0.005, max_iter=6, friction=0.1)
    np.testing.assert_allclose(trajectory(sim), trajectory(fresh), rtol=0, atol=1e-12)


def test_exact_friction_changes_nothing_in_2d(flat):
    # a 2D slide that does not turn back already moves against its friction: nothing to make exact
    exact, not_exact = build(flat, friction=0.3), build(flat, friction=0.3, exact_friction=False)
    np.testing.assert_array_equal(trajectory(exact, steps=40), trajectory(not_exact, steps=40))
    assert not_exact.model.contact.exact_friction is False


def test_exact_friction_can_be_switched_off_after_construction(solid):
    sim = build(solid, friction=0.3)
    before = trajectory(sim, steps=40)
    sim.exact_friction = False
    assert sim.exact_friction is False and sim.model.contact.exact_friction is False
    fresh = build(solid, friction=0.3, exact_friction=False)
    after, expected = trajectory(sim, steps=40), trajectory(fresh, steps=40)
    np.testing.assert_allclose(after, expected, rtol=0, atol=1e-12 * np.abs(expected).max())
    assert np.abs(after - before).max() > 1e-6 * np.abs(before).max()  # the slides' friction differs
    with pytest.raises(TypeError, match=r"exact_friction must be True or False, got 0"):
        sim.exact_friction = 0
    with pytest.raises(AttributeError, match=r"exact_friction is a setting of contact_model='coulomb'"):
        build(solid, contact_model="reference").exact_friction = True


@pytest.mark.parametrize("model, other", [("coulomb", "reference"), ("reference", "coulomb")])
def test_switching_the_contact_model_takes_its_default_vertices(model, other):
    # from_mesh picks each model's default contact vertices (coulomb: every boundary vertex, reference: 30
    # sampled): a switched simulator kept the old model's, and crawled 0.04 instead of the tutorial's 4.4
    mesh = caterpillar(nx=24, ny=12)
    kw = dict(n_muscles=2, n_weights=4, n_clusters=6, h=0.01, gravity=[0.0, -9.8], ground=float(mesh.p[1].min()) - 0.05)
    switched = ModalMuscle.from_mesh(mesh, contact_model=model, **kw)
    switched.contact_model = other
    fresh = ModalMuscle.from_mesh(mesh, contact_model=other, **kw)
    assert switched.contact_vertices.size == {"coulomb": boundary_vertices(mesh).size, "reference": 30}[other]
    np.testing.assert_array_equal(switched.contact_vertices, fresh.contact_vertices)
    np.testing.assert_allclose(trajectory(switched), trajectory(fresh), rtol=0, atol=1e-12)
    # a ground put in later takes the model's too
    floating = ModalMuscle.from_mesh(mesh, **{**kw, "ground": None})
    floating.contact_model = other
    floating.ground = kw["ground"]
    np.testing.assert_array_equal(floating.contact_vertices, fresh.contact_vertices)
    # vertices asked for by number stay, whatever the model
    counted = ModalMuscle.from_mesh(mesh, contact_model=model, n_contacts=12, **kw)
    counted.contact_model = other
    assert counted.contact_vertices.size == 12


READ_ONLY = [
    "mesh",
    "B",
    "D",
    "labels",
    "active_labels",
    "mu",
    "gamma",
    "rho",
    "pinned",
    "contact_vertices",
    "dim",
    "mass",
]


@pytest.mark.parametrize("name", READ_ONLY)
def test_read_only_settings_refuse_assignment(flat, name):
    sim = build(flat)
    value = getattr(sim, name)
    with pytest.raises(AttributeError, match=f"{name} is fixed when a simulator is built"):
        setattr(sim, name, value)


@pytest.mark.parametrize("name", ["effects", "ceilings", "backends", "model", "solver", "backend_used"])
def test_derived_values_cannot_be_assigned(flat, name):
    sim = build(flat)
    with pytest.raises(AttributeError):
        setattr(sim, name, getattr(sim, name))


def test_settings_are_checked_when_assigned(flat):
    sim = build(flat, pinned=None)
    with pytest.raises(ValueError, match="h must be positive"):
        sim.h = -1.0
    with pytest.raises(ValueError, match="max_iter must be a positive integer"):
        sim.max_iter = 0
    with pytest.raises(ValueError, match="backend must be one of"):
        sim.backend = "gpu"
    with pytest.raises(ValueError, match=r"stickiness must be in \[0, 1\]"):
        sim.stickiness = 3.0
    with pytest.raises(AttributeError, match=r"stickiness is a setting of contact_model='reference'"):
        build(flat).stickiness = 0.5
    with pytest.raises(ValueError, match=r"allowance must be at least 1e-10 .* and at most 0.001"):
        sim.allowance = 0.05
    with pytest.raises(ValueError, match=r"allowance must be at least 1e-10 \(less is lost in the round-off"):
        sim.allowance = 1e-300  # (it failed in 'stay below the ground after 8 tries')
    with pytest.raises(AttributeError, match=r"allowance is a setting of contact_model='coulomb'"):
        build(flat, contact_model="reference").allowance = 1e-3
    with pytest.raises(AttributeError, match="no pinned vertices"):
        sim.pin_stiffness = 10.0
    with pytest.raises(ValueError, match="gravity"):
        sim.gravity = [0.0, 9.8]  # pulls up along the up axis
    # a failed assignment leaves the simulator as it was
    before = trajectory(sim)
    with pytest.raises(ValueError, match="singular to working precision"):
        sim.gravity, sim.ground = None, None
        sim.h = 1e9
    sim.gravity, sim.ground = [0.0, -9.8], float(flat["mesh"].p[1].min()) - 0.01
    np.testing.assert_array_equal(trajectory(sim), before)


def test_a_misspelt_setting_is_refused_naming_the_one_meant():
    # assigning a name that is no setting made a new attribute that changed nothing: sim.dt = 0.5 left h as it was
    sim = ModalMuscle.from_mesh(caterpillar(nx=12, ny=6), n_muscles=1, n_weights=3, n_clusters=3, h=0.02)
    with pytest.raises(AttributeError, match=r"ModalMuscle has no setting 'dt': did you mean 'h'\?"):
        sim.dt = 0.5
    with pytest.raises(AttributeError, match=r"no setting 'max_iters': did you mean 'max_iter'"):
        sim.max_iters = 50
    with pytest.raises(AttributeError, match=r"no setting 'colour'; the settings one can assign are .*\bh, max_iter\b"):
        sim.colour = "red"
    assert sim.h == 0.02 and not hasattr(sim, "dt")
    sim.max_iter = 50  # the real ones still take
    assert sim.max_iter == 50


def test_a_contact_setting_assigned_mid_run_goes_on_from_where_the_run_is():
    # a fresh contact forgot where the last step ended: the next step was refused as a run starting in the ground
    import pathlib

    from skfem_modal.scene import Scene

    examples = pathlib.Path(__file__).resolve().parents[1] / "examples"
    scene = Scene.from_toml(examples / "creature_crawl.toml")
    scene.config["ground"]["allowance"] = 1e-3
    sim = scene.build()
    size = float(np.ptp(sim.mesh.p, axis=1).max())
    z, z_dot, _ = sim.rest_state()
    step = 0
    while sim.penetration(z) <= 2.5e-4 * size and step < 200:  # until a vertex is deeper than the default
        z, z_dot = sim.step(z, z_dot, scene.activation(step * sim.h, sim.ceilings), velocity=True)
        step += 1
    assert sim.penetration(z) > 2.5e-4 * size
    sim.allowance, sim.friction = 2e-4, 0.8  # the same model: the run goes on
    for _ in range(5):
        z, z_dot = sim.step(z, z_dot, scene.activation(step * sim.h, sim.ceilings), velocity=True)
        step += 1
    assert sim.penetration(z) <= 2e-4 * size  # held within the new allowance
    # another model is another run: refused, saying why, and a refused assignment changes nothing
    small = caterpillar(nx=12, ny=6)
    ground = float(small.p[1].min()) + 5e-4 * float(np.ptp(small.p, axis=1).max())  # 5e-4 of its size inside
    deep = ModalMuscle.from_mesh(small, n_muscles=1, n_weights=3, n_clusters=3, gravity=[0.0, -9.8], ground=ground,
                                 allowance=1e-3)  # fmt: skip
    with pytest.raises(ValueError, match="below the ground"):
        deep.contact_model = "reference"  # its allowance, 2e-4, is less than the rest shape's depth
    assert deep.contact_model == "coulomb" and deep.allowance == 1e-3 and deep.model.contact.model == "coulomb"


def test_assigning_the_contact_model_it_has_keeps_its_settings():
    sim = build(ingredients(caterpillar(nx=12, ny=6)), friction=2.0, allowance=1e-3)
    sim.contact_model = "coulomb"  # reset friction and allowance to the defaults
    assert (sim.friction, sim.allowance) == (2.0, 1e-3)


def test_a_reference_scene_switched_to_coulomb_holds_every_boundary_vertex():
    # the scene asked for no number of contacts: the reference's 30 were kept after a switch, and feet sank 4.4 %
    from skfem_modal.scene import DEFAULT_SCENE, Scene

    data = {**DEFAULT_SCENE, "mesh": {"shape": "caterpillar", "params": {"nx": 24, "ny": 12}},
            "ground": {"offset": 0.15, "model": "reference"}}  # fmt: skip
    sim = Scene.from_dict(data).build()
    assert sim.contact_vertices.size == 30
    sim.contact_model = "coulomb"
    assert np.array_equal(sim.contact_vertices, boundary_vertices(sim.mesh))
    counted = Scene.from_dict({**data, "ground": {**data["ground"], "contacts": 30}}).build()
    counted.contact_model = "coulomb"
    assert counted.contact_vertices.size == 30  # asked for by number: kept
    # a run of the reference contact (feet a few percent deep) does not go on under the Coulomb one: said so
    scene = Scene.from_dict(data)
    sim = scene.build()
    z, z_dot, _ = sim.rest_state()
    for step in range(150):
        z, z_dot = sim.step(z, z_dot, scene.activation(step * sim.h, sim.ceilings), velocity=True)
    sim.contact_model = "coulomb"
    with pytest.raises(ValueError, match="assigning contact_model made a contact of another model, which goes on"):
        sim.step(z, z_dot)


def test_a_contact_goes_on_from_the_last_step_only_on_the_same_ground_plane():
    # a new up axis or ground height makes the last step's end a new run's start, checked as one
    from skfem_modal.contact import CoulombContact

    sim = build(ingredients(caterpillar(nx=12, ny=6)))
    space, vertices, ground = sim.model.space, sim.contact_vertices, sim.ground
    earlier = CoulombContact(space, vertices, ground, 1)
    earlier._end = np.ones(space.r)
    planes = ((ground, 1), (ground, 0), (ground - 1.0, 1))
    same, other_up, lower = (CoulombContact(space, vertices, height, up) for height, up in planes)
    for contact in (same, other_up, lower):
        contact.follow(earlier, "allowance")
    assert same._end is earlier._end and other_up._end is None and lower._end is None
    assert same.replaced_for is None
    for contact in (other_up, lower):  # the next step's check of the last state says why it is checked
        assert contact.replaced_for.startswith("assigning allowance during a run moved the ground plane")


def test_a_ground_assigned_mid_run_is_checked_against_where_the_body_is():
    """An audit: a body risen 5 sizes was refused a ground just below it (checked against its rest shape)."""
    import skfem

    import skfem_modal as sm

    sim = sm.ModalMuscle.from_mesh(
        skfem.MeshTri.init_symmetric().refined(3), n_muscles=2, n_weights=4, n_clusters=4, gravity=[0, 9.8]
    )
    with pytest.raises(ValueError, match=r"the body starts inside the ground: its lowest vertex \(y = 0\)"):
        sim.gravity, sim.ground = [0.0, -9.8], 0.1  # before a run: at rest
    sim.gravity = [0.0, 9.8]
    z, z_dot, _ = sim.rest_state()
    for _ in range(100):
        z, z_dot = sim.step(z, z_dot, velocity=True)
    lowest = float(sim.positions(z)[:, 1].min())
    assert lowest > 4.0  # risen, under gravity pointing up
    sim.gravity, z_dot = [0.0, -9.8], np.zeros_like(z_dot)  # stopped there, to fall back
    sim.ground = lowest - 0.1  # just below where the body is: accepted
    for _ in range(60):
        z, z_dot = sim.step(z, z_dot, velocity=True)
    landed = float(sim.positions(z)[:, 1].min())
    assert sim.penetration(z, relative=True) <= 2e-4 and landed == pytest.approx(lowest - 0.1, abs=2e-4)
    sim.ground = landed + 0.05  # above it: the step from there refuses, saying why
    with pytest.raises(ValueError, match=r"0.05 \(5 % of the body's size\) below .*\(assigning ground during a run"):
        sim.step(z, z_dot)
    sim.reset()  # a new run starts at rest: checked there at once
    with pytest.raises(ValueError, match="the body starts inside the ground"):
        sim.ground = 0.1


def test_settings_assigned_again_and_again_do_not_pile_up_contact_corrections():
    """Each assignment of max_iter rebuilds the backends; the reference contact's corrections for the old ones go.

    Its corrections are kept per backend's state layout (about 120 kB a layout here): 40 rebuilds kept
    4.8 MB more, growing with every one, before the old layouts' were let go.
    """
    import tracemalloc

    from skfem_modal import box3d

    mesh = box3d(8, 3, 3, (2.0, 0.5, 0.5))
    ground = float(mesh.p[1].min()) - 0.01
    sim = ModalMuscle.from_mesh(mesh, n_muscles=2, n_weights=4, n_clusters=4, gravity=[0.0, -9.8, 0.0],
                                ground=ground, contact_model="reference", backend="numpy")  # fmt: skip
    state = sim.rest_state()

    def rebuilds(count):
        nonlocal state
        for i in range(count):
            sim.max_iter = 10 + i % 2
            for _ in range(5):
                state = (*sim.step(state[0], state[1], state[2], velocity=True), state[2])

    rebuilds(20)
    assert sim.model.contact.active_count > 0  # it rests on the ground: corrections are made
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        rebuilds(40)
        grown = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    assert grown < 1.5e6


def test_simulate_follows_a_time_step_assigned_mid_run(flat):
    """simulate's clock (and the gait it reads) takes h as it is at each step, not as it was at the start."""
    from skfem_modal import simulate

    sim = build(flat)
    h = sim.h
    times = []
    for record in simulate(sim, 20, lambda t: (times.append(t), np.full(sim.n_muscles, 0.1 * t))[1]):
        if record.step == 10:
            sim.h = h / 2
        last = record
    expected_starts = [k * h for k in range(10)] + [10 * h + k * h / 2 for k in range(10)]
    np.testing.assert_allclose(times, expected_starts, rtol=0, atol=1e-15)
    assert last.time == pytest.approx(10 * h + 10 * h / 2, abs=1e-15)
    np.testing.assert_allclose(last.a, 0.1 * expected_starts[-1], rtol=1e-15)


def test_the_masses_cannot_be_changed_in_place_either(flat):
    """Gravity and inertia were built from them: doubling them in place moved gravity's half (twice the fall)."""
    sim = build(flat)
    with pytest.raises(ValueError, match="read-only"):
        sim.mass[:] *= 2.0


def test_a_contact_model_switched_back_to_keeps_its_settings(flat):
    """friction 0.1, to the reference model and back: 0.1 again (it was silently the default 0.5)."""
    sim = build(flat, contact_model="coulomb", friction=0.1, allowance=5e-4)
    sim.contact_model = "reference"
    sim.stickiness = 0.25
    assert (sim.friction, sim.allowance, sim.stickiness) == (None, None, 0.25)
    sim.contact_model = "coulomb"
    assert (sim.friction, sim.allowance, sim.stickiness) == (0.1, 5e-4, None)
    sim.contact_model = "reference"
    assert sim.stickiness == 0.25
    same = build(flat, contact_model="reference", stickiness=0.25)
    state = sim.rest_state()
    np.testing.assert_array_equal(sim.step(*state), same.step(*state))


def test_a_setting_refused_by_the_system_keeps_its_value_and_the_trajectory():
    """An audit: a pin stiffness refused as singular read back as assigned (the steps kept the old one) and
    broke the next assignment of h; a damping refused as overflowing read back 1e300."""
    from skfem_modal.mesh import beam2d

    mesh = beam2d(2.0, 0.5, 8, 2)
    pins = np.flatnonzero(mesh.p[0] < 1e-9)
    sim = ModalMuscle.from_mesh(mesh, n_muscles=1, n_weights=4, n_clusters=4, h=0.01, pinned=pins,
                                gravity=[0.0, -9.8])  # fmt: skip
    fresh = ModalMuscle.from_mesh(mesh, n_muscles=1, n_weights=4, n_clusters=4, h=0.01, pinned=pins,
                                  gravity=[0.0, -9.8])  # fmt: skip
    stiffness = sim.pin_stiffness
    with pytest.raises(ValueError, match=r"give the pins a smaller stiffness \(pin_stiffness, \[pinned\] stiffness\)"):
        sim.pin_stiffness = 1e30
    assert sim.pin_stiffness == stiffness
    with pytest.raises(ValueError, match="overflow"):
        sim.damping_stiffness = 1e300
    assert sim.damping_stiffness == 0.0 and "damping" not in sim.effects
    z, z_dot, _ = sim.rest_state()
    for _ in range(5):
        z, z_dot = sim.step(z, z_dot, velocity=True)
    y, y_dot, _ = fresh.rest_state()
    for _ in range(5):
        y, y_dot = fresh.step(y, y_dot, velocity=True)
    np.testing.assert_array_equal(z, y)
    sim.h = 0.02  # (refused: 'with h = 0.01', for the stiffness it had refused)
    assert sim.h == 0.02


def test_pins_far_stiffer_than_their_default_are_warned():
    """An audit: pins of 1e17 (3.2e4 times the default) made a cantilever sag 5 % off, 1e20 four times, with
    every step at its iteration cap and no word."""
    from skfem_modal.mesh import beam2d

    mesh = beam2d(10.0, 1.0, 40, 4)
    pins = np.flatnonzero(mesh.p[0] < 1e-9)
    build = dict(n_muscles=0, n_weights=8, n_clusters=20, mu=1e9, h=0.05, pinned=pins, gravity=[0.0, -9.8])
    from skfem_modal.units import ScaleWarning

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.simplefilter("ignore", ScaleWarning)  # (the audit's beam is stiff for its step too)
        sim = ModalMuscle.from_mesh(mesh, **build, pin_stiffness=1e15)  # 320 times the default: converges
    with pytest.warns(UserWarning, match=r"the pins' stiffness 1e\+17 is 3.2e\+04 times their default"):
        ModalMuscle.from_mesh(mesh, **build, pin_stiffness=1e17)
    with pytest.warns(UserWarning, match=r"stop short of converging"):
        sim.pin_stiffness = 1e18


def test_a_time_step_that_makes_given_pins_far_stiffer_than_the_default_is_warned():
    """A review: the default pin stiffness follows 1 / h^2, a given one does not: a larger h made given pins
    3e4 times the default without a word."""
    from skfem_modal.mesh import beam2d

    mesh = beam2d(2.0, 0.5, 8, 2)
    pins = np.flatnonzero(mesh.p[0] < 1e-9)
    sim = ModalMuscle.from_mesh(mesh, n_muscles=0, n_weights=4, n_clusters=4, mu=1e4, h=0.005, pinned=pins)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sim.pin_stiffness = 500 * sim.pin_stiffness
    with pytest.warns(UserWarning, match="stop short of converging"):
        sim.h = 0.1
