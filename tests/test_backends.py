"""Every backend steps the same simulator to the same trajectory (issue 14: one driver, interchangeable backends).

The default install has no numba: its path (numpy, with the plain backend as the
fallback of the 3D Kronecker form) must agree with the compiled one and with
the plain backend, which makes every rotation exactly, also through ground
contact, a step's redo after a failed rotation certificate, and both contact rules.
"""

import numpy as np
import pytest
import skfem

import skfem_modal as sm
from skfem_modal import _accel

BACKENDS = ("numpy", "plain") + (("numba",) if _accel.AVAILABLE else ())


@pytest.mark.parametrize("push_out", [0.0, 1.0])
def test_3d_creature_on_the_ground_same_trajectory_on_every_backend(push_out):
    mesh = sm.creature(cell=0.25)
    sims = {
        backend: sm.ModalMuscle.from_mesh(
            mesh,
            n_muscles=4,
            n_weights=6,
            n_clusters=12,
            mu=1e5,
            rho=1e3,
            h=0.01,
            gravity=[0.0, 0.0, -9.8],
            ground=float(mesh.p[2].min()) - 0.02,
            n_contacts=30,
            contact_model="reference",
            push_out=push_out,
            backend=backend,
        )
        for backend in BACKENDS
    }
    assert [sim.backend_used for sim in sims.values()] == list(BACKENDS)
    states = {b: sim.rest_state()[:2] for b, sim in sims.items()}
    worst = dict.fromkeys(BACKENDS, 0.0)
    touching, redone_before = 0, None
    plain = sims["plain"]
    for i in range(300):
        # a kick of four times the ceilings strains the clusters hard: certificates fail, steps are redone
        amplitude = 4.0 if 120 <= i < 126 else 0.5
        phase = i * 0.01 / np.array([0.5, 0.4, 0.7, 0.3]) + [0.0, 0.3, 0.6, 0.1]
        a = amplitude * plain.ceilings * np.sin(2 * np.pi * phase)
        if i == 100:
            redone_before = sims["numpy"].solver.redone
        for b, sim in sims.items():
            states[b] = sim.step(*states[b], a, velocity=True)
        assert {sim.iterations for sim in sims.values()} == {plain.iterations}
        reference = states["plain"][0]
        touching += plain.contact_positions(reference)[:, 2].min() < plain.ground + 0.01
        for b in BACKENDS:
            worst[b] = max(worst[b], np.abs(states[b][0] - reference).max() / np.abs(reference).max())
    assert touching >= 50  # on the ground much of the time
    assert sims["numpy"].solver.redone - redone_before >= 1  # the kick provoked failed certificates
    assert max(worst.values()) <= 1e-9, worst


@pytest.mark.parametrize("dim", [2, 3])
def test_kicks_on_the_ground_same_trajectory_numpy_and_plain(dim):
    # the numpy 3D step redoes a step whose certificate failed: the contact's
    # state must be reset before the redo, or the trajectories part ways
    mesh = sm.caterpillar(nx=16, ny=8) if dim == 2 else sm.creature(cell=0.3)
    up = dim - 1
    kw = dict(n_muscles=2, n_weights=4, n_clusters=6, h=0.01, gravity=[0.0] * up + [-9.8], n_contacts=16)
    kw["contact_model"] = "reference"
    kw["ground"] = float(mesh.p[up].min()) - 0.005
    numpy_sim = sm.ModalMuscle.from_mesh(mesh, backend="numpy", **kw)
    plain_sim = sm.ModalMuscle.from_mesh(mesh, backend="plain", **kw)
    z, z_dot, _ = numpy_sim.rest_state()
    w, w_dot = z.copy(), z_dot.copy()
    for i in range(80):
        a = (3.0 if i % 20 < 3 else 0.4) * numpy_sim.ceilings * np.sin(0.3 * i + np.arange(2))
        z, z_dot = numpy_sim.step(z, z_dot, a, velocity=True)
        w, w_dot = plain_sim.step(w, w_dot, a, velocity=True)
    assert np.abs(z - w).max() <= 1e-9 * np.abs(w).max()
    assert numpy_sim.solver.redone >= (2 if dim == 3 else 0)  # 2D rotations are exact: nothing to redo


@pytest.mark.parametrize("dim", [2, 3])
def test_a_partial_stickiness_on_the_ground_same_trajectory_numpy_and_plain(dim):
    # the numpy backends correct their own state vectors with a contact set's correction made for
    # their layout; the plain backend corrects z: the same, with the tangential rows scaled too
    mesh = sm.caterpillar(nx=16, ny=8) if dim == 2 else sm.creature(cell=0.3)
    up = dim - 1
    kw = dict(n_muscles=2, n_weights=4, n_clusters=6, h=0.01, gravity=[0.0] * up + [-9.8], n_contacts=16)
    kw.update(contact_model="reference", stickiness=0.4, ground=float(mesh.p[up].min()) - 0.005)
    sims = {b: sm.ModalMuscle.from_mesh(mesh, backend=b, **kw) for b in ("numpy", "plain")}
    states = {b: sim.rest_state()[:2] for b, sim in sims.items()}
    held = 0
    for i in range(60):
        a = 0.5 * sims["plain"].ceilings * np.sin(0.3 * i + np.arange(2))
        for b, sim in sims.items():
            states[b] = sim.step(*states[b], a, velocity=True)
        held += sims["numpy"].model.contact.active_count > 0
    assert held >= 20  # its points are held on the ground, with sets met for the first time and again
    reference = states["plain"][0]
    assert np.abs(states["numpy"][0] - reference).max() <= 1e-9 * np.abs(reference).max()


def test_a_redone_step_starts_its_contact_afresh():
    # the creature lands while a kick of five times the ceilings strains it:
    # certificates fail during the landing and those steps are redone. The
    # redo must see the contact as at the start of the step (if it kept the
    # failed attempt's contact state the trajectories part by 2e-4)
    mesh = sm.creature(cell=0.25)
    kw = dict(n_muscles=4, n_weights=6, n_clusters=12, h=0.01, gravity=[0.0, 0.0, -9.8], n_contacts=30)
    kw["contact_model"] = "reference"
    kw["ground"] = float(mesh.p[2].min()) - 0.05  # lands at step 10
    sims = {b: sm.ModalMuscle.from_mesh(mesh, backend=b, **kw) for b in ("numpy", "plain")}
    states = {b: sim.rest_state()[:2] for b, sim in sims.items()}
    for i in range(50):
        amplitude = 5.0 if 6 <= i < 14 else 0.3
        phase = i * 0.01 / np.array([0.5, 0.4, 0.7, 0.3]) + [0.0, 0.3, 0.6, 0.1]
        a = amplitude * sims["plain"].ceilings * np.sin(2 * np.pi * phase)
        for b, sim in sims.items():
            states[b] = sim.step(*states[b], a, velocity=True)
    assert sims["numpy"].solver.redone >= 3
    reference = states["plain"][0]
    assert np.abs(states["numpy"][0] - reference).max() <= 1e-9 * np.abs(reference).max()


def test_a_redone_step_under_the_coulomb_contact_agrees_with_the_plain_backend():
    # the Coulomb contact keeps who touched, slid and which way from step to step: a step the
    # numpy backend's certificate refused must be redone from that state as the step began, not
    # as the refused run left it (it was: single steps differed from the plain backend's by up
    # to 5.7e-5 of the size)
    x = np.linspace(0.0, 1.0, 5)
    mesh = skfem.MeshTet.init_tensor(x, x, x)
    kw = dict(n_muscles=3, mu=1e4, h=0.01, gravity=[0.0, -9.8, 0.0], ground=-0.02, friction=0.5)
    sims = {b: sm.ModalMuscle.from_mesh(mesh, backend=b, **kw) for b in ("numpy", "plain")}
    plain = sims["plain"]
    z, z_dot, _ = plain.rest_state()
    worst, touched = 0.0, 0
    for i in range(70):
        a = sm.sine_gait(i * 0.01, 0.5 * plain.ceilings, [1.0, 0.8, 0.6], [0.0, 0.3, 0.6])
        for sim in sims.values():
            sim.reset()  # a new backend each step: strained clusters fail its first certificate
        ends = {b: sim.step(z, z_dot, a, velocity=True) for b, sim in sims.items()}
        worst = max(worst, np.abs(ends["numpy"][0] - ends["plain"][0]).max() / plain.motion_scale)
        touched += plain.model.contact.active_count > 0
        z, z_dot = ends["plain"]
    assert touched >= 40
    assert sims["numpy"].solver.redone >= 10
    assert worst <= 1e-12


@pytest.mark.parametrize("clusters", [8, 18, 19])
def test_auto_takes_numpys_kronecker_form_in_3d_from_twenty_clusters(clusters):
    # numba's compiled 3D step costs more than numpy's Kronecker form from about 20 clusters on
    # (benchmarks/bench_backends.py), so "auto" takes numba below that and numpy from there; the
    # muscles' own cluster counts (one more rotation a step): 19 clusters with muscles are 20
    from skfem_modal.solver import KRONECKER_OVER_NUMBA

    assert KRONECKER_OVER_NUMBA == 20
    sim = sm.ModalMuscle.from_mesh(sm.box3d(8, 3, 3, (4.0, 1.0, 1.0)), n_muscles=2, n_weights=4,
                                   n_clusters=clusters, mu=1e5, rho=1e3, h=0.01)  # fmt: skip
    assert sim.backend == "auto" and sim.n_clusters + sim.n_active_clusters == clusters + 1
    if clusters + 1 >= KRONECKER_OVER_NUMBA or not _accel.AVAILABLE:
        assert sim.backend_used == "numpy" and sim.backends[0].name == "numpy (Kronecker form)"
    else:
        assert sim.backend_used == "numba"
    # the same trajectory as the other backend asked for by name
    other = sm.ModalMuscle.from_mesh(sm.box3d(8, 3, 3, (4.0, 1.0, 1.0)), n_muscles=2, n_weights=4,
                                     n_clusters=clusters, mu=1e5, rho=1e3, h=0.01, backend="plain")  # fmt: skip
    states = [s.rest_state()[:2] for s in (sim, other)]
    for i in range(30):
        a = 0.5 * sim.ceilings * np.sin(2 * np.pi * i * 0.01 / np.array([0.5, 0.7]))
        states = [s.step(*state, a, velocity=True) for s, state in zip((sim, other), states)]
    assert np.abs(states[0][0] - states[1][0]).max() <= 1e-9 * np.abs(states[1][0]).max()


def test_3d_creature_crawling_under_coulomb_friction_same_trajectory_on_every_backend():
    # the Coulomb contact (the default) is the same code on every backend; its sets' decisions would
    # amplify any difference of the iterations' round-off, and over 150 steps none shows
    mesh = sm.creature(cell=0.25)
    kw = dict(n_muscles=4, n_weights=6, n_clusters=12, mu=1e5, rho=1e3, h=0.01, gravity=[0.0, 0.0, -9.8],
              ground=float(mesh.p[2].min()) - 0.02, friction=0.5)  # fmt: skip
    sims = {backend: sm.ModalMuscle.from_mesh(mesh, backend=backend, **kw) for backend in BACKENDS}
    assert [sim.backend_used for sim in sims.values()] == list(BACKENDS)
    states = {b: sim.rest_state()[:2] for b, sim in sims.items()}
    plain, worst, touched = sims["plain"], 0.0, 0
    for i in range(150):
        phase = i * 0.01 / np.array([0.5, 0.4, 0.7, 0.3]) + [0.0, 0.3, 0.6, 0.1]
        a = 0.5 * plain.ceilings * np.sin(2 * np.pi * phase)
        states = {b: sim.step(*states[b], a, velocity=True) for b, sim in sims.items()}
        reference = states["plain"][0]
        worst = max(worst, max(np.abs(s[0] - reference).max() for s in states.values()) / np.abs(reference).max())
        touched += plain.model.contact.active_count > 0
    assert touched >= 80  # it crawls on the ground
    assert worst <= 1e-10


@pytest.mark.parametrize("max_iter", [60, 150, 5000])
def test_the_kronecker_form_certifies_the_iterations_a_step_does_of_any_max_iter(max_iter):
    # steps of about 90 iterations (a stiff body, rtol) under max_iter 60 (every iteration's traces at once),
    # 150 (only those done) and 5000 (the shifts written for 64 a step, filled in past them): the certificate
    # read each step's traces where they were (all 5000 iterations' had been taken, ten times the step's cost)
    kw = dict(n_muscles=2, n_weights=4, n_clusters=8, mu=1e6, rho=1e3, h=0.02, tol=0.0, rtol=1e-9)
    mesh = sm.box3d(8, 3, 3, (4.0, 1.0, 1.0))
    sims = [sm.ModalMuscle.from_mesh(mesh, backend=b, max_iter=max_iter, **kw) for b in ("numpy", "plain")]
    assert sims[0].backends[0].name == "numpy (Kronecker form)"
    states = [s.rest_state()[:2] for s in sims]
    iterations = []
    for i in range(12):
        a = 0.8 * sims[0].ceilings * np.sin(2 * np.pi * i * 0.01 / np.array([0.3, 0.4]))
        states = [s.step(*state, a, velocity=True) for s, state in zip(sims, states)]
        iterations.append(sims[0].iterations)
        assert sims[0].backend_used == "numpy"  # certified, not redone by the plain backend
    assert np.abs(states[0][0] - states[1][0]).max() <= 1e-9 * np.abs(states[1][0]).max()
    assert min(iterations[1:]) > 64 or max_iter == 60


@pytest.mark.parametrize("backend", ["numpy", "plain"])
def test_a_first_step_under_a_large_max_iter_runs_a_first_batch_not_all_of_it(backend, monkeypatch):
    # the driver batches as many iterations as the last step took before testing them; a first step (or one
    # after a reset) had batched all of max_iter: 5000 iterations for the 6 a resting body's step needs
    from skfem_modal.solver import FIRST_BATCH

    kw = dict(n_muscles=2, n_weights=4, n_clusters=8, mu=1e5, rho=1e3, h=0.01, tol=0.0, rtol=1e-7, max_iter=5000)
    sim = sm.ModalMuscle.from_mesh(sm.box3d(8, 3, 3, (4.0, 1.0, 1.0)), backend=backend, **kw)
    run = []
    iterate = type(sim.backends[0]).iterate
    monkeypatch.setattr(type(sim.backends[0]), "iterate", lambda self, count, contact: run.append(count) or
                        iterate(self, count, contact))  # fmt: skip
    z, z_dot, _ = sim.rest_state()
    for _ in range(2):
        run.clear()
        sim.step(z, z_dot, 0.1 * sim.ceilings)
        assert sim.iterations < FIRST_BATCH and sum(run) <= FIRST_BATCH
        sim.reset()
