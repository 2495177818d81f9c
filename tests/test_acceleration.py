"""Faster iterations, the same answer (issue 20): restart on every backend, warm starts, Anderson, Newton, etol."""

import pickle
import warnings

import numpy as np
import pytest

import skfem_modal as sm
from skfem_modal import _accel
from skfem_modal.acceleration import Anderson, StepEnergy, SubspaceNewton
from skfem_modal.reference import FullSpaceSimulator
from skfem_modal.solver import PlainBackend

BACKENDS = ("numpy", "plain") + (("numba",) if _accel.AVAILABLE else ())


def gait(sim, i):
    return 0.6 * sim.ceilings * np.sin(2 * np.pi * (i * sim.h / np.array([0.5, 0.7]) + [0.0, 0.3]))


@pytest.fixture(scope="module", params=[2, 3], ids=["2D", "3D"])
def moving(request):
    """A floating body 30 steps into its gait: a simulator, a moving state and its activation."""
    dim = request.param
    mesh = sm.caterpillar(nx=20, ny=10) if dim == 2 else sm.creature(cell=0.3)
    sim = sm.ModalMuscle.from_mesh(
        mesh, n_muscles=2, n_weights=4, n_clusters=8, mu=1e5, rho=1e3, h=0.02 if dim == 2 else 0.01
    )
    z, z_dot, _ = sim.rest_state()
    for i in range(30):
        z, z_dot = sim.step(z, z_dot, gait(sim, i), velocity=True)
    return sim, z, z_dot, gait(sim, 30)


def settle(sim, **settings):
    """The simulator with these settings (and a tight stopping rule unless given)."""
    rule = dict(tol=0.0, rtol=1e-10, etol=0.0, max_iter=1000, warm_start=False, acceleration="none", backend="plain")
    for name, value in {**rule, **settings}.items():
        setattr(sim, name, value)
    return sim


@pytest.mark.parametrize("backend", BACKENDS)
def test_restart_continues_from_the_given_iterate_on_every_backend(moving, backend):
    sim, z, z_dot, a = moving
    settle(sim, backend=backend)
    fast, exact = sim.backends[0], PlainBackend(sim.model)
    kinds = {"numpy": ("numpy (2D buffers)", "numpy (Kronecker form)"), "plain": ("plain",), "numba": ("numba",)}
    assert fast.name == kinds[backend][sim.dim - 2 if backend == "numpy" else 0]
    fast.start(z, z_dot, a)
    exact.start(z, z_dot, a)
    rng = np.random.default_rng(0)
    fast.iterate(1, None)
    exact.iterate(1, None)
    for k in range(2, 6):
        # an iterate the backend never made: near z, off the iteration's path
        x = z + 1e-3 * np.abs(z).max() * rng.standard_normal(z.size)
        fast.restart(x)
        exact.restart(x)
        rows = fast.iterate(1, None)
        g = exact.iterate(1, None)[1]
        np.testing.assert_allclose(fast.result(k), g, rtol=0, atol=1e-10 * np.abs(g).max())
        # the rows keep their promise: their change has the norm of z's change
        assert np.linalg.norm(rows[1] - rows[0]) == pytest.approx(np.linalg.norm(g - x), rel=1e-9)
    # the Kronecker form certifies the rotations it made from the handed iterates
    assert fast.finish(5)
    assert not np.allclose(g, z, atol=1e-6 * np.abs(z).max())  # the restarts moved it


@pytest.mark.parametrize("backend", BACKENDS)
def test_warm_start_and_accelerations_reach_the_same_fixed_point(moving, backend):
    sim, z, z_dot, a = moving
    counts, results = {}, {}
    for key, settings in {
        "plain": {},
        "warm": {"warm_start": True},
        "anderson": {"warm_start": True, "acceleration": "anderson"},
        "newton": {"acceleration": "newton"},
    }.items():
        settle(sim, backend=backend, **settings)
        results[key] = sim.step(z, z_dot, a)
        counts[key] = sim.iterations
    plain = results["plain"]
    for key, found in results.items():
        assert np.abs(found - plain).max() <= 1e-9 * np.abs(plain).max(), key
    # measured on this body: plain 28 (2D) and 17 (3D) iterations; Anderson 11 or 12; Newton 4 or 5
    assert counts["newton"] <= 5 and counts["anderson"] <= 12
    assert counts["plain"] >= 3 * counts["newton"] and counts["plain"] >= 1.4 * counts["anderson"]


def test_warm_start_keeps_a_few_iterations_near_the_converged_trajectory(moving):
    # Stopped early from z, each step lags behind its answer and the body
    # loses momentum, step after step; from the inertial prediction it does
    # not. Measured on these bodies, 60 steps of 4 iterations: 29 % and 0.37 %
    # off the converged trajectory in 2D, 1.4 % and 0.12 % in 3D.
    sim = moving[0]

    def trajectory(**settings):
        settle(sim, **settings)
        z, z_dot, _ = sim.rest_state()
        states = []
        for i in range(60):
            z, z_dot = sim.step(z, z_dot, gait(sim, i), velocity=True)
            states.append(z)
        return np.array(states)

    converged = trajectory()
    errors = {
        warm: np.linalg.norm(trajectory(warm_start=warm, max_iter=4, rtol=0.0) - converged)
        / np.linalg.norm(converged - converged[0])
        for warm in (False, True)
    }
    assert errors[True] < 0.2 * errors[False] and errors[True] < 0.005, errors


@pytest.mark.parametrize("acceleration", ["anderson", "newton"])
def test_accelerated_results_never_rise_in_energy(moving, acceleration):
    sim, z, z_dot, a = moving
    energies = []
    for k in range(1, 13):
        settle(sim, acceleration=acceleration, warm_start=True, max_iter=k, rtol=0.0)
        energies.append(sim.energy(sim.step(z, z_dot, a), z, z_dot, a))
    energies = np.array(energies)
    assert np.all(np.diff(energies) <= 1e-12 * np.abs(energies).max()), np.diff(energies)
    assert energies[0] - energies[-1] > 0


def test_a_proposal_that_raises_the_energy_is_refused(moving, monkeypatch):
    # an accelerator gone wrong (here: proposing a far-off state) changes nothing but the count of refusals
    sim, z, z_dot, a = moving
    plain = settle(sim, max_iter=8, rtol=0.0).step(z, z_dot, a)
    rng = np.random.default_rng(1)
    monkeypatch.setattr(Anderson, "propose", lambda self, x, g, *args: g + 0.3 * np.abs(g).max() * rng.random(g.size))
    settle(sim, acceleration="anderson", max_iter=8, rtol=0.0)
    refused = sim.solver.refused
    np.testing.assert_allclose(sim.step(z, z_dot, a), plain, rtol=0, atol=1e-12 * np.abs(plain).max())
    assert sim.solver.refused - refused == 7  # every iteration but the last proposed, and was refused


@pytest.mark.parametrize("damping_stiffness", [0.0, 0.05])
def test_newton_iterate_is_the_finite_difference_newton_step(moving, damping_stiffness):
    # stiffness damping weighs the passive clusters' rotations by 1 + beta / h (3.5 and 6 here): the
    # Newton system must carry the weights symmetrically (it had been solved unsymmetric, by Cholesky)
    sim, z, z_dot, a = moving
    sim = pickle.loads(pickle.dumps(sim))
    sim.damping_stiffness = damping_stiffness
    energy = StepEnergy(sim.model)
    energy.start(z, z_dot, a)
    exact = PlainBackend(sim.model)
    exact.start(z, z_dot, a)
    x = z + sim.h * z_dot
    exact.restart(x)
    g = exact.iterate(1, None)[1].copy()
    energy(x)
    proposal = SubspaceNewton(sim.dim).propose(x, g, energy, (energy.S, energy.R))
    # the Hessian of the step energy by central differences of its gradient
    gradient = lambda y: sim.energy(y, z, z_dot, a, gradient=True)[1]  # noqa: E731
    step = 1e-6 * np.abs(x).max()
    basis = np.eye(x.size)
    hessian = np.array([(gradient(x + step * e) - gradient(x - step * e)) / (2 * step) for e in basis])
    newton = x - np.linalg.solve(0.5 * (hessian + hessian.T), gradient(x))
    assert np.abs(proposal - newton).max() <= 1e-5 * np.abs(newton - x).max()
    # and it is much nearer the fixed point than the plain iterate (the damped step's start is farther)
    converged = settle(sim).step(z, z_dot, a)
    gain = 0.05 if damping_stiffness == 0.0 else 0.1
    assert np.abs(proposal - converged).max() < gain * np.abs(g - converged).max()


def test_energy_tolerance_stops_at_the_energy_rule(moving):
    sim, z, z_dot, a = moving
    settle(sim, rtol=0.0, max_iter=200, etol=1e-6)
    z_next = sim.step(z, z_dot, a)
    k = sim.iterations
    energies = []
    for count in range(k + 1):
        settle(sim, rtol=0.0, max_iter=max(count, 1))
        energies.append(sim.energy(sim.step(z, z_dot, a) if count else z, z, z_dot, a))
    np.testing.assert_allclose(sim.step(z, z_dot, a), z_next, rtol=0, atol=1e-13 * np.abs(z_next).max())
    change = np.abs(np.diff(energies))
    released = np.abs(energies[0] - np.array(energies[1:]))
    assert change[-1] <= 1e-6 * released[-1]  # it stopped where the rule holds
    assert np.all(change[:-1] > 1e-6 * released[:-1])  # and not before
    assert 3 <= k < 200


def test_residual_is_reported_per_step(moving):
    sim, z, z_dot, a = moving
    settle(sim, rtol=0.0, max_iter=6)
    records = list(sm.simulate(sim, 3, lambda t: a, state=(z, z_dot)))
    assert records[-1].change == sim.residual
    for record, previous in zip(records, [z] + [r.z for r in records]):
        assert record.start is previous
        assert record.residual == pytest.approx(record.change / np.linalg.norm(record.z - previous), rel=1e-12)
        assert 0 < record.residual < 1
    # the change is the last iteration's: one more iteration from there moves z by it
    settle(sim, rtol=0.0, max_iter=5)
    five = sim.step(z, z_dot, a)
    settle(sim, rtol=0.0, max_iter=6)
    assert np.linalg.norm(sim.step(z, z_dot, a) - five) == pytest.approx(sim.residual, rel=1e-9)
    # more iterations, a smaller residual
    settle(sim, rtol=0.0, max_iter=20)
    longer = list(sm.simulate(sim, 3, lambda t: a, state=(z, z_dot)))
    assert longer[-1].residual < 0.1 * records[-1].residual


def test_full_space_anderson_matches_the_plain_reference():
    mesh = sm.caterpillar(nx=10, ny=5)
    _, modes = sm.linear_modal_analysis(mesh, 5)
    kw = dict(mu=1e3, gamma=2e3, rho=1.0, h=0.01, gravity=[0.3, -1.0])
    plain = FullSpaceSimulator(mesh, modes[:, 3:], **kw)
    fast = FullSpaceSimulator(mesh, modes[:, 3:], acceleration="anderson", warm_start=True, **kw)
    x, x_dot, _ = plain.rest_state()
    y, y_dot = x.copy(), x_dot.copy()
    plain_its, fast_its = [], []
    for i in range(20):
        a = 0.5 * sm.actuation_limits(mesh, modes[:, 3:]) * np.sin(0.4 * i + np.arange(2))
        x, x_dot = plain.step(x, x_dot, a, velocity=True)
        y, y_dot = fast.step(y, y_dot, a, velocity=True)
        plain_its.append(plain.iterations)
        fast_its.append(fast.iterations)
    assert np.abs(y - x).max() <= 1e-8 * np.abs(x - mesh.p.T.ravel()).max()
    assert np.mean(fast_its) < 0.7 * np.mean(plain_its)
    with pytest.raises(ValueError, match="'newton' needs a subspace"):
        FullSpaceSimulator(mesh, modes[:, 3:], acceleration="newton", **kw)


def test_settings_are_checked_and_survive_pickling(moving):
    sim, z, z_dot, a = moving
    with pytest.raises(ValueError, match="acceleration must be one of 'none', 'anderson', 'newton', got 'quasi'"):
        sim.acceleration = "quasi"
    with pytest.raises(TypeError, match="warm_start must be True or False, got 'yes'"):
        sim.warm_start = "yes"
    with pytest.raises(ValueError, match="etol must be non-negative"):
        sim.etol = -1.0
    settle(sim, acceleration="newton", warm_start=True, max_iter=5, rtol=0.0)
    expected = sim.step(z, z_dot, a)
    copy = pickle.loads(pickle.dumps(sim))
    assert (copy.acceleration, copy.warm_start) == ("newton", True)
    np.testing.assert_array_equal(copy.step(z, z_dot, a), expected)


def test_under_contact_iterations_are_not_accelerated():
    # a projection is not an energy the accelerator could guard: the iterations stay plain (warm-started, as asked)
    mesh = sm.caterpillar(nx=16, ny=8)
    kw = dict(n_muscles=2, n_weights=4, n_clusters=6, h=0.01, gravity=[0.0, -9.8], n_contacts=16, warm_start=True)
    kw["ground"] = float(mesh.p[1].min()) - 0.005
    plain = sm.ModalMuscle.from_mesh(mesh, **kw)
    with pytest.warns(UserWarning, match="acceleration='newton' has no effect under ground contact"):
        other = sm.ModalMuscle.from_mesh(mesh, acceleration="newton", **kw)
    # said again when it is switched on after construction, or when a ground comes under it
    with pytest.warns(UserWarning, match="acceleration='anderson' has no effect"):
        plain.acceleration = "anderson"
    plain.acceleration = "none"
    floating = sm.ModalMuscle.from_mesh(mesh, acceleration="newton", **{**kw, "ground": None, "n_contacts": None})
    with pytest.warns(UserWarning, match="no effect under ground contact"):
        floating.ground = kw["ground"]
    z, z_dot, _ = plain.rest_state()
    w, w_dot = z.copy(), z_dot.copy()
    for i in range(40):
        a = 0.5 * plain.ceilings * np.sin(0.3 * i + np.arange(2))
        z, z_dot = plain.step(z, z_dot, a, velocity=True)
        w, w_dot = other.step(w, w_dot, a, velocity=True)
    np.testing.assert_array_equal(w, z)
    assert other.solver.accepted == 0


def test_a_warm_start_on_frictionless_ground_reaches_the_cold_start_s_answer():
    # docs/accuracy.md: the same fixed point from either start on the Coulomb contact without friction
    # (with friction the slides' directions are settled along the iterations: not the same, documented)
    mesh = sm.creature(cell=0.3)
    kw = dict(n_muscles=2, n_weights=4, n_clusters=8, h=0.01, gravity=[0.0, 0.0, -9.8], friction=0.0)
    kw["ground"] = float(mesh.p[2].min()) - 0.02
    sim = sm.ModalMuscle.from_mesh(mesh, tol=0.0, max_iter=400, **kw)
    runs = []
    for warm_start in (False, True):
        sim.warm_start = warm_start
        z, z_dot, _ = sim.rest_state()
        states = []
        for i in range(12):
            z, z_dot = sim.step(z, z_dot, gait(sim, i), velocity=True)
            states.append(z)
        runs.append(np.array(states))
    rest = sim.rest_state()[0]
    assert sim.model.contact.touching.any()  # it landed
    assert np.abs(runs[1] - runs[0]).max() <= 1e-9 * np.abs(runs[0] - rest).max()


def test_a_warm_start_under_the_reference_contact_is_said_to_do_nothing():
    # its rule reads the iterates: the iterations start from the step's state whatever warm_start says
    mesh = sm.caterpillar(nx=16, ny=8)
    kw = dict(n_muscles=2, n_weights=4, n_clusters=6, h=0.01, gravity=[0.0, -9.8], n_contacts=16)
    kw["ground"] = float(mesh.p[1].min()) - 0.005
    idle = "warm_start=True has no effect under the reference contact"
    with pytest.warns(UserWarning, match=idle):
        reference = sm.ModalMuscle.from_mesh(mesh, contact_model="reference", warm_start=True, **kw)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the Coulomb contact takes it: nothing said
        coulomb = sm.ModalMuscle.from_mesh(mesh, warm_start=True, **kw)
        reference.warm_start = False
    with pytest.warns(UserWarning, match=idle):
        reference.warm_start = True
    with pytest.warns(UserWarning, match=idle):
        coulomb.contact_model = "reference"
    # the acceleration's warning recommends a warm start only where it works
    with pytest.warns(UserWarning) as said:
        reference.acceleration = "anderson"
        sm.ModalMuscle.from_mesh(mesh, acceleration="anderson", **kw)
    assert [str(w.message).endswith("warm_start=True speeds them up there (docs/contact.md)") for w in said] == [
        False,
        True,
    ]
    assert "has no effect under ground contact" in str(said[0].message)


def test_a_scene_says_its_idle_settings_once_as_loaded_and_info_says_them(tmp_path, capsys):
    """``skfem-modal info`` built no simulator, so it said nothing of them (an audit); ``run`` said them."""
    from skfem_modal.cli import main
    from skfem_modal.scene import Scene

    data = Scene.default().config | {"time": {**Scene.default().config["time"], "warm_start": True, "steps": 3}}
    idle = "warm_start=True has no effect under the reference contact"
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        scene = Scene.from_dict(data)
        scene.build()  # (the simulator's own warning of it is not said again)
    assert [str(w.message).startswith(idle) for w in said] == [True]
    path = tmp_path / "warm.toml"
    path.write_text(sm.optimize.scene_to_toml(data))
    assert main(["info", str(path)]) == 0
    assert f"skfem-modal info: warning: {idle}" in capsys.readouterr().err
    coulomb = {**data, "ground": {**data["ground"], "model": "coulomb", "contacts": None, "stickiness": None}}
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the Coulomb contact takes a warm start: nothing said
        Scene.from_dict(coulomb)
    accelerated = {**data, "time": {**data["time"], "warm_start": False, "acceleration": "anderson"}}
    with pytest.warns(UserWarning, match="acceleration='anderson' has no effect under ground contact"):
        Scene.from_dict(accelerated)


def test_a_setting_s_warning_names_the_line_that_assigned_it():
    """Behind ``__setattr__`` and a property setter, the warning still points at the user's line, not at sim.py."""
    mesh = sm.caterpillar(nx=16, ny=8)
    kw = dict(n_muscles=2, n_weights=4, n_clusters=6, h=0.01, gravity=[0.0, -9.8], n_contacts=16)
    sim = sm.ModalMuscle.from_mesh(mesh, ground=float(mesh.p[1].min()) - 0.005, contact_model="reference", **kw)
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        sim.acceleration = "anderson"
        sim.warm_start = True
        sim.h = 0.5  # too large for this material: a ScaleWarning
        sm.ModalMuscle.from_mesh(mesh, ground=-9.0, contact_model="reference", acceleration="newton", **kw)
    assert [(w.category.__name__, w.filename) for w in said] == [
        ("UserWarning", __file__),
        ("UserWarning", __file__),
        ("ScaleWarning", __file__),
        ("UserWarning", __file__),
    ]
    assert len({w.lineno for w in said}) == 4
