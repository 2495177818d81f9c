"""Damping: mass-proportional drag and the corotated stiffness damping, on every backend."""

import numpy as np
import pytest

from skfem_modal import _accel, body_size, caterpillar, creature
from skfem_modal.sim import ModalMuscle

BACKENDS = ["plain", "numpy"] + (["numba"] if _accel.AVAILABLE else [])


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("contact", [None, "reference", "coulomb"])
def test_every_backend_steps_the_corotated_damping_alike(dim, contact):
    """The offset rotations and the shifted constant, in each backend's own buffers: one trajectory."""
    mesh = caterpillar(nx=16, ny=4) if dim == 2 else creature(cell=0.3)
    up = dim - 1
    settings = {}
    if contact:
        settings = dict(gravity=[0.0] * up + [-9.8], ground=float(mesh.p[up].min()) - 0.02, contact_model=contact)
    final = {}
    for backend in BACKENDS:
        sim = ModalMuscle.from_mesh(mesh, n_muscles=3, n_weights=5, n_clusters=8, mu=1e5, rho=1e3, h=0.01,
                                    damping_stiffness=0.01, backend=backend, **settings)  # fmt: skip
        z, z_dot, _ = sim.rest_state()
        for i in range(50):
            z, z_dot = sim.step(z, z_dot, 0.4 * sim.ceilings * np.sin(0.2 * i + np.arange(3)), velocity=True)
        final[backend] = z
    moved = np.abs(final["plain"] - sim.rest_state()[0]).max()
    assert moved > 1e-2
    for backend, z in final.items():
        assert np.abs(z - final["plain"]).max() <= 1e-10 * np.abs(final["plain"]).max(), backend


def test_the_step_is_a_stationary_point_of_its_energy_with_the_corotated_damping():
    """``sim.energy`` (the damping's term with the elasticity's rotations) is what the iterations minimise."""
    rng = np.random.default_rng(0)
    for mesh in (caterpillar(nx=16, ny=4), creature(cell=0.3)):
        sim = ModalMuscle.from_mesh(mesh, n_muscles=2, n_weights=4, n_clusters=6, mu=1e5, rho=1e3, h=0.01,
                                    max_iter=400, damping_stiffness=0.02)  # fmt: skip
        sim.tol = 1e-14
        z, z_dot, _ = sim.rest_state()
        z_dot = z_dot + 0.3 * rng.standard_normal(z.size)
        a = 0.3 * sim.ceilings
        z_next = sim.step(z, z_dot, a)
        scale = np.abs(sim.energy(z, z, z_dot, a, gradient=True)[1]).max()
        assert np.abs(sim.energy(z_next, z, z_dot, a, gradient=True)[1]).max() <= 1e-10 * scale
        # and the gradient is the energy's, by central differences at another point
        x, d, eps = z_next + 1e-3 * rng.standard_normal(z.size), rng.standard_normal(z.size), 1e-6
        slope = (sim.energy(x + eps * d, z, z_dot, a) - sim.energy(x - eps * d, z, z_dot, a)) / (2 * eps)
        assert slope == pytest.approx(sim.energy(x, z, z_dot, a, gradient=True)[1] @ d, rel=1e-6)


def test_stiffness_damping_leaves_a_free_spin_alone():
    """The corotated stiffness damping damps deformation, not rigid motion: a free spin keeps its momentum.

    The caterpillar spun at 2 rad/s, floating, h = 0.002, 1 s: 99.2 % of the angular momentum kept without
    damping (implicit Euler's own loss) and with damping_stiffness 0.001 and 0.01 alike (Rayleigh damping
    with the stiffness at rest kept 0.8 % at 0.001), on every backend.
    """
    from skfem_modal import caterpillar

    mesh = caterpillar()

    def angular_momentum(sim, z, z_dot):
        r, v = sim.positions(z) - sim.com(z), (sim.B @ z_dot).reshape(-1, 2)
        m = sim.mass[::2]
        return float(np.sum(m * (r[:, 0] * v[:, 1] - r[:, 1] * v[:, 0])))

    for backend in ("numpy", "plain"):
        sim = ModalMuscle.from_mesh(mesh, n_muscles=0, n_weights=8, n_clusters=10, mu=1e6, rho=1e3, h=0.002,
                                    max_iter=50, warm_start=True, backend=backend)  # fmt: skip
        kept = {}
        for beta in (0.0, 0.001, 0.01):
            sim.damping_stiffness = beta
            z, _, _ = sim.rest_state()
            r = sim.positions(z) - sim.com(z)
            z_dot = sim.coordinates(2.0 * np.stack([-r[:, 1], r[:, 0]], axis=1))
            start = angular_momentum(sim, z, z_dot)
            for _ in range(500):
                z, z_dot = sim.step(z, z_dot, velocity=True)
            kept[beta] = angular_momentum(sim, z, z_dot) / start
        assert kept[0.0] == pytest.approx(0.992, abs=0.002)
        assert kept[0.001] == pytest.approx(kept[0.0], abs=1e-4)
        assert kept[0.01] == pytest.approx(kept[0.0], abs=1e-4)


@pytest.mark.parametrize("backend", BACKENDS)
def test_stiffness_damping_decays_a_small_vibration_as_rayleigh_damping(backend):
    """Near rest the corotated damping is Rayleigh damping ``beta K`` (``K`` the elastic Hessian at rest).

    A mode of ``K q = omega^2 M q`` under implicit Euler with ``beta K`` damping: its amplitude
    follows ``q_(n+1) = a q_n - |lambda|^2 q_(n-1)`` with ``1 / |lambda|^2 = 1 + h omega^2 (beta + h)``
    (``h omega^2 h`` implicit Euler's own loss). Fitted from 400 steps of the caterpillar's lowest
    vibration at 1e-5 of its size: within 0.1 % (measured at most 1.4e-4) for beta = 0, 0.002 and 0.01.
    """
    import scipy.linalg as sla

    from skfem_modal import caterpillar

    h = 0.002
    sim = ModalMuscle.from_mesh(caterpillar(), n_muscles=0, n_weights=6, n_clusters=10, mu=1e5, rho=1e3, h=h,
                                max_iter=100, backend=backend)  # fmt: skip
    sim.tol = 1e-13
    rest, zero, _ = sim.rest_state()
    M = sim.B.T @ (sim.mass[:, None] * sim.B)

    def gradient(z):
        return sim.energy(z, rest, zero, gradient=True)[1]

    eps = 1e-6
    columns = [(gradient(rest + eps * e) - gradient(rest - eps * e)) / (2 * eps) for e in np.eye(rest.size)]
    K = np.column_stack(columns) - M / h**2  # the step energy's Hessian less the inertia's
    omega2, modes = sla.eigh(0.5 * (K + K.T), M)
    assert np.sum(omega2 < 1e-6 * omega2.max()) == 3  # the rigid motions
    k = 3
    mode = modes[:, k] / np.abs(sim.B @ modes[:, k]).max()
    for beta in (0.0, 0.002, 0.01):
        sim.damping_stiffness = beta
        z, z_dot = rest + 1e-5 * body_size(sim.mesh) * mode, zero
        q = []
        for _ in range(400):
            z, z_dot = sim.step(z, z_dot, velocity=True)
            q.append(mode @ M @ (z - rest))
        q = np.array(q)
        a, b = np.linalg.lstsq(np.column_stack([q[1:-1], q[:-2]]), q[2:], rcond=None)[0]
        loss = 1.0 / -b - 1.0
        assert loss == pytest.approx(h * omega2[k] * (beta + h), rel=1e-3)


def test_stiffness_damping_that_makes_the_iterations_lag_is_warned_with_the_step_that_avoids_it():
    """An audit: beta = 1 at h = 0.005 stopped a free spin dead at 10 iterations a step (angular momentum kept
    -0.002 after 1 s, 0.995 undamped or warm-started), without a word: the damping stiffens each step's
    system by 1 + beta / h, and the wave crossing it was not counted in."""
    import re
    import warnings

    import skfem_modal as sm
    from skfem_modal.units import ScaleWarning

    mesh = sm.beam2d(2.0, 1.0, nx=16, ny=8)
    build = dict(n_muscles=0, n_weights=8, n_clusters=20, mu=1e5, rho=1e3, h=0.005)
    with warnings.catch_warnings():
        warnings.simplefilter("error", ScaleWarning)
        sm.ModalMuscle.from_mesh(mesh, **build, damping_stiffness=0.1)  # 1 + beta / h = 21: 0.16 of its size
    with pytest.warns(ScaleWarning, match=r"1 \+ beta / h = 201 times the stiffness") as caught:
        sim = sm.ModalMuscle.from_mesh(mesh, **build, damping_stiffness=1.0)
    largest = float(re.search(r"h <= ([0-9.e-]+) here, at this damping", str(caught[-1].message)).group(1))
    with warnings.catch_warnings():
        warnings.simplefilter("error", ScaleWarning)
        sim.h = 0.98 * largest  # the step it names is warned no more
    with pytest.warns(ScaleWarning, match="at this damping"):
        sim.damping_stiffness = 10.0  # assigned: warned too
