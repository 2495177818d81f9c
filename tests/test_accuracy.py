"""The full-space reference and the accuracy/cost study."""

import csv
import json

import numpy as np
import pytest
import scipy.optimize

import skfem_modal as sm
from skfem_modal import study
from skfem_modal.muscles import sine_gait
from skfem_modal.reference import FullSpaceSimulator
from skfem_modal.sim import ModalMuscle


@pytest.fixture(scope="module")
def small():
    mesh = sm.caterpillar(nx=10, ny=5)
    _, modes = sm.linear_modal_analysis(mesh, 5)
    return mesh, modes[:, 3:]


def test_reference_step_is_the_energy_minimum(small):
    mesh, D = small
    full = FullSpaceSimulator(
        mesh,
        D,
        mu=1e3,
        gamma=2e3,
        rho=1.0,
        h=0.01,
        gravity=[0.3, -1.0],
        pinned=[0],
        damping_mass=0.5,
        damping_stiffness=0.02,  # corotated: the energy's rotations shared with the elasticity's
        rtol=1e-14,
        max_iter=100_000,
    )
    assert full.effects == ("elasticity", "inertia", "muscles", "gravity", "pinned", "damping")
    x, _, _ = full.rest_state()
    x_dot = np.random.default_rng(0).standard_normal(x.size) * 0.1
    a = 0.4 * sm.actuation_limits(mesh, D)
    x_step = full.step(x, x_dot, a)
    assert full.iterations < 100_000
    fun = lambda y: full.energy(y, x, x_dot, a, gradient=True)  # noqa: E731
    best = scipy.optimize.minimize(fun, x, jac=True, method="BFGS", options={"gtol": 1e-11, "maxiter": 20_000})
    assert np.linalg.norm(best.x - x_step) <= 1e-6 * np.linalg.norm(x_step)
    # and the gradient there vanishes
    assert np.linalg.norm(fun(x_step)[1]) <= 1e-8 * np.linalg.norm(fun(x)[1])


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("push_out", [0.0, 1.0])
def test_full_basis_reduced_simulator_equals_the_reference(dim, push_out):
    mesh = sm.caterpillar(nx=10, ny=5) if dim == 2 else sm.creature(cell=0.3)
    n_rigid = 3 if dim == 2 else 6
    _, modes = sm.linear_modal_analysis(mesh, n_rigid + 2)
    D = modes[:, n_rigid:]
    ceilings = sm.actuation_limits(mesh, D)
    up = dim - 1
    kw = dict(
        mu=1e4,
        gamma=2e4,
        rho=1e3,
        h=0.01,
        gravity=[0.0] * up + [-9.8],
        ground=float(mesh.p[up].min()) - 0.05,
        contact_model="reference",
        push_out=push_out,
        stickiness=0.6,
        damping_stiffness=0.005 * push_out,  # with it, the same too
    )
    full = FullSpaceSimulator(mesh, D, max_iter=7, tol=0.0, rtol=0.0, **kw)
    nT = mesh.t.shape[1]
    # a full basis and one passive cluster per element: the same computation
    reduced = ModalMuscle(
        mesh,
        np.eye(mesh.p.size),
        D,
        np.arange(nT),
        contact_vertices=full.contact_vertices,
        max_iter=7,
        tol=0.0,
        **kw,
    )
    x, x_dot, _ = full.rest_state()
    z, z_dot, _ = reduced.rest_state()
    worst = 0.0
    for i in range(60):
        a = sine_gait(i * 0.01, 0.8 * ceilings, [0.3, 0.5], [0.0, 0.2])
        x_next = full.step(x, x_dot, a)
        x_dot, x = (x_next - x) / 0.01, x_next
        z_next = reduced.step(z, z_dot, a)
        z_dot, z = (z_next - z) / 0.01, z_next
        worst = max(worst, np.abs(reduced.positions(z) - full.positions(x)).max())
    assert np.abs(full.positions(x) - mesh.p.T).max() > 0.1  # it moved, landed and crawled
    assert worst <= 1e-8


def test_error_measures():
    rng = np.random.default_rng(1)
    rest = rng.random(8)
    x_ref = rest + 0.1 * rng.standard_normal((5, 8))
    B = rng.standard_normal((8, 3))
    x = (B @ rng.standard_normal((3, 5))).T
    mass = rng.random(8) + 0.5
    e = study.trajectory_errors(x, x_ref, mass, rest, 1.0, 2, B=B)
    # the projection is the best any trajectory in the subspace can do
    assert e["subspace_error"] <= e["trajectory_error"]
    # and the triangle inequality holds between the three
    assert e["trajectory_error"] <= e["subspace_error"] + e["solver_error"] + 1e-12
    exact = study.trajectory_errors(x_ref, x_ref, mass, rest, 1.0, 2)
    assert exact["trajectory_error"] == 0 and exact["worst_vertex_error"] == 0 and exact["com_error"] == 0


def test_resolution_scene():
    data = study.resolution_scene(study.FLOATING_CATERPILLAR, 2.0)
    assert data["mesh"]["params"] == {"nx": 139, "ny": 67}
    assert study.resolution_scene({"mesh": {"shape": "creature"}}, 2.0)["mesh"]["params"]["cell"] == 0.05
    with pytest.raises(ValueError, match="a mesh from a file has no resolution"):
        study.resolution_scene({"mesh": {"file": "x.msh"}}, 2.0)
    for factor in (0.0, -1.0, float("nan"), "2"):  # (0 divided the creature's cell by zero)
        with pytest.raises(ValueError, match="a resolution factor must be a positive number"):
            study.resolution_scene({"mesh": {"shape": "creature"}}, factor)


def test_pareto_front():
    rows = [
        dict(step_ms=1, trajectory_error=0.5),
        dict(step_ms=2, trajectory_error=0.6),
        dict(step_ms=3, trajectory_error=0.1),
        dict(step_ms=0.5, trajectory_error=0.9),
    ]
    assert study.pareto_front(rows) == [3, 0, 2]


def test_modal_convergence_p2_beats_p1():
    rows = study.modal_convergence(((40, 1), (80, 2)))
    p1 = [r for r in rows if r["element"] == "P1"]
    p2 = [r for r in rows if r["element"] == "P2"]
    assert all(b["error_vs_refined_p2"] < a["error_vs_refined_p2"] for a, b in zip(p1, p2))
    assert p1[1]["error_vs_refined_p2"] < p1[0]["error_vs_refined_p2"]  # P1 converges
    assert p2[-1]["error_vs_euler_bernoulli"] < 0.01


@pytest.fixture(scope="module")
def quick_study(tmp_path_factory):
    out = tmp_path_factory.mktemp("study")
    return study.run_study(study.FLOATING_CATERPILLAR, out, preset="quick", workers=1), out


@pytest.mark.slow
def test_quick_study_errors_shrink_with_subspace_and_clusters(quick_study):
    report, out = quick_study
    rows = report["rows"]
    base = next(r for r in rows if r["sweep"] == "base")

    def series(key, error="trajectory_error"):
        pts = [r for r in rows if r["sweep"] == key] + [base]
        return [r[error] for r in sorted(pts, key=lambda r: r[key])]

    # The trend. More clusters: less error, strictly. More weights: the best
    # error the subspace allows falls strictly; the error of the run falls
    # until the clusters and iterations, not the subspace, limit it (then it
    # stays within 5 % of its neighbour's).
    clusters = series("clusters")
    assert all(b < a for a, b in zip(clusters, clusters[1:])), clusters
    best = series("weights", "subspace_error")
    assert all(b < a for a, b in zip(best, best[1:])), best
    weights = series("weights")
    assert all(b <= a * 1.05 for a, b in zip(weights, weights[1:])), weights
    assert weights[-1] < 0.5 * weights[0] and clusters[-1] < 0.5 * clusters[0]
    iterations = [
        r["trajectory_error"]
        for r in sorted((r for r in rows if r["sweep"] == "iterations"), key=lambda r: r["max_iterations"])
    ]
    assert iterations[-1] < iterations[0]
    # the subspace error bounds the error from below; the solver error is the rest
    for r in rows:
        assert r["subspace_error"] <= r["trajectory_error"] + 1e-12
    assert report["meta"]["seconds"] < 120  # the quick preset's promise, on 2 cores


@pytest.mark.slow
def test_quick_study_faster_iterations_and_rotation_clusters(quick_study):
    report, _ = quick_study
    rows = {r["label"]: r for r in report["rows"]}
    error = {label: r["trajectory_error"] for label, r in rows.items()}
    # measured: 10 iterations from the state 7.8 %, from the inertial prediction 3.8 %
    assert error["warm,iterations=10"] < 0.6 * error["iterations=10"]
    # accelerated iterations converge to the converged iteration's answer (3.36 %) in few iterations
    converged = error["warm,iterations=20"]
    assert rows["warm,iterations=20"]["residual_median"] < 1e-5
    for label in ("warm,anderson,iterations=10", "warm,newton,iterations=5"):
        assert error[label] == pytest.approx(converged, rel=0.01), label
        assert rows[label]["residual_median"] < 1e-7
    # clusters by rotation: more accuracy per cluster where few are used (20: 2.4 % against 3.4 %)
    for c in (10, 20):
        by = {b: error[f"warm,clusters={c},by={b},iterations=20"] for b in ("weights", "rotations")}
        assert by["rotations"] < 0.8 * by["weights"], (c, by)
    # the accuracy targets (their step times are in docs/accuracy.md, measured under the CPU lock)
    assert error["warm,rtol=1e-4,weights=8,clusters=40"] <= 0.02
    assert error["warm,rtol=1e-4,weights=16,clusters=80"] <= 0.01


@pytest.mark.slow
def test_quick_study_writes_its_report(quick_study):
    report, out = quick_study
    rows = list(csv.DictReader(open(out / "study.csv")))
    assert len(rows) == len(report["rows"]) and {"step_ms", "trajectory_error", "precompute_s"} <= set(rows[0])
    text = (out / "study.md").read_text()
    assert "## Recommendation" in text and "weights, 20 clusters and 10 iterations give" in text
    assert "P1 against P2" in text
    assert (out / "pareto.png").stat().st_size > 5000
    assert json.loads((out / "study.json").read_text())["pareto"] == report["pareto"]
    assert report["pareto"], "the Pareto front is never empty"


@pytest.mark.slow
def test_study_runs_on_dask_like_on_the_local_pool(tmp_path, monkeypatch):
    distributed = pytest.importorskip("dask.distributed", reason="dask is in the distributed extra")
    tiny = dict(
        steps=20,
        weights=[4],
        clusters=[8],
        iterations=[3],
        rtol=[],
        resolution=[1.0],
        grid=[],
        modal=[(20, 1)],
        timing_rounds=1,
    )
    monkeypatch.setitem(study.PRESETS, "tiny", tiny)
    scene = dict(study.FLOATING_CATERPILLAR, mesh={"shape": "caterpillar", "params": {"nx": 24, "ny": 12}})
    local = study.run_study(scene, tmp_path / "local", preset="tiny", workers=2)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True) as cluster:
        remote = study.run_study(scene, tmp_path / "dask", preset="tiny", scheduler=cluster.scheduler_address)
    for a, b in zip(local["rows"], remote["rows"]):
        assert a["label"] == b["label"]
        assert a["trajectory_error"] == pytest.approx(b["trajectory_error"], rel=1e-9)


def test_step_times_one_per_task(monkeypatch):
    # each task's time is the lowest of its per-round medians; a fake clock
    # that advances 1 ms per reading makes every timed step 1 ms long
    scene = dict(study.FLOATING_CATERPILLAR, mesh={"shape": "caterpillar", "params": {"nx": 24, "ny": 12}})
    tasks = [
        {"scene": scene, "base_dir": None, "steps": 30, "overrides": over, "sweep": "", "label": ""}
        for over in ({"iterations": 1}, {"iterations": 20})
    ]
    ticks = iter(np.arange(0.0, 1e3, 1e-3))
    monkeypatch.setattr(study.time, "perf_counter", lambda: next(ticks))
    ms = study.time_steps(tasks, rounds=2, steps=30)
    assert ms == pytest.approx([1.0, 1.0])


@pytest.mark.parametrize("active_clusters", [1, 3])
def test_the_study_reference_has_the_reduced_model_s_muscle_clusters(tmp_path, active_clusters):
    """Two beams in one mesh: the reduced model gives each its muscle rotation (at least one per part).

    The reference had one for both, another model: a study's error against it 12.5 %, against
    the same model 4.3 % (an audit).
    """
    import meshio

    one = sm.beam2d(2.0, 0.4, 10, 2)
    p = np.hstack([one.p, one.p + np.array([[3.0], [0.0]])])
    t = np.hstack([one.t, one.t + one.p.shape[1]])
    meshio.write(tmp_path / "two.vtu", meshio.Mesh(p.T, [("triangle", t.T)]))
    scene = sm.Scene.from_dict(
        {
            "mesh": {"file": str(tmp_path / "two.vtu")},
            "subspace": {"weights": 6, "clusters": 8, "active_clusters": active_clusters},
            "muscles": {"count": 2, "gait": {"amplitude": [0.4, 0.4], "period": [0.5, 0.4]}},
            "time": {"step": 0.01, "steps": 5},
        }
    )
    reduced, reference = scene.build().active_labels, scene.build_reference().active_labels
    assert np.unique(reduced).size == max(active_clusters, 2)
    np.testing.assert_array_equal(reference, reduced)


def test_mu_is_youngs_modulus_at_poisson_zero_in_small_strains():
    """ARAP's energy mu / 2 |F - R|^2 vibrates as linear elasticity with Lame (mu / 2, 0): E = mu, nu = 0.

    A 4 x 1 beam, every DOF, from rest plus 1e-6 of its first bending mode: the fitted implicit-Euler
    recurrence (``arg lambda = atan(h omega)``) gives the modal analysis' omega of (mu / 2, 0) to 1e-6
    (measured 5e-9); with (mu, 0), as the docs once said, it would be sqrt(2) off.
    """
    import skfem

    mesh = skfem.MeshTri.init_tensor(np.linspace(0, 4, 17), np.linspace(0, 1, 5))
    mu, rho, h = 1e5, 1e3, 0.002
    values, modes = sm.linear_modal_analysis(mesh, 4, mu=mu / 2, lam=0.0, rho=rho)
    mode = modes[:, 3] / np.abs(modes[:, 3]).max()
    full = FullSpaceSimulator(mesh, np.zeros((mesh.p.size, 0)), mu=mu, gamma=mu, rho=rho, h=h, rtol=1e-13,
                              max_iter=100_000)  # fmt: skip
    rest, x_dot, _ = full.rest_state()
    x, q = rest + 1e-6 * mode, []
    for _ in range(300):
        x_next = full.step(x, x_dot)
        x_dot, x = (x_next - x) / h, x_next
        q.append(mode @ (x - rest))
    q = np.array(q)
    a, b = np.linalg.lstsq(np.column_stack([q[1:-1], q[:-2]]), q[2:], rcond=None)[0]
    omega = np.tan(abs(np.angle(np.roots([1.0, -a, -b])[0]))) / h
    assert omega == pytest.approx(np.sqrt(values[3]), rel=1e-6)


def test_a_scene_given_youngs_modulus_simulates_it():
    """``young`` sets the ARAP mu to E (so the body stretches and bends as E); ``poisson`` shapes the modes."""
    from skfem_modal.scene import Scene

    base = {"mesh": {"shape": "caterpillar", "params": {"nx": 20, "ny": 5}}, "muscles": {"count": 3}}
    scene = Scene.from_dict({**base, "material": {"young": 2.6e5, "poisson": 0.3}})
    mat = scene.material()
    assert mat["mu"] == 2.6e5 and mat["gamma"] == 2.6e5
    shear, lam = sm.fem.lame_parameters(2.6e5, 0.3)
    # the modes made with (mu, lam) are those of the Lame parameters, their eigenvalues scaled by E / shear
    ours = sm.linear_modal_analysis(scene.mesh, 6, mu=mat["mu"], lam=mat["lam"])
    lame = sm.linear_modal_analysis(scene.mesh, 6, mu=shear, lam=lam)
    np.testing.assert_allclose(ours[0][3:], lame[0][3:] * 2.6e5 / shear, rtol=1e-9)
    np.testing.assert_allclose(ours[1][:, 3:], lame[1][:, 3:], atol=1e-9 * np.abs(lame[1]).max())


def test_the_reference_stops_a_step_that_does_not_move():
    """An audit: a floating scene's first step (at rest, the gait at 0) met no relative rule and ran all 5000
    iterations at a change of 1e-16, and the study called its reference unsettled."""
    from skfem_modal.scene import Scene

    scene = Scene.from_dict({"mesh": {"shape": "caterpillar", "params": {"nx": 20, "ny": 10}}, "muscles": {"count": 2}})
    ref = scene.build_reference()
    x, x_dot, _ = ref.rest_state()
    x_next = ref.step(x, x_dot, np.zeros(2))
    assert ref.iterations == 1 and np.abs(x_next - x).max() <= 1e-12
    ref.step(x, x_dot, 0.3 * scene.build().ceilings)  # moving, the relative rule decides
    assert 5 < ref.iterations < 100
