"""The 3D numpy backend: rotations read off matrix powers in Kronecker form, certified once a step.

Its trajectory must be the one of the plain backend, which makes each
rotation exactly as it goes, on easy and hard motions, and a step whose
rotations fail the certificate must be redone by the plain backend.
"""

import numpy as np
import pytest

from skfem_modal import creature
from skfem_modal.rotations import HORN
from skfem_modal.sim import ModalMuscle


def near_rotations(m, strain, seed=0):
    rng = np.random.default_rng(seed)
    from scipy.spatial.transform import Rotation

    Q = Rotation.random(m, random_state=seed).as_matrix()
    return (Q @ (np.eye(3) + strain * rng.standard_normal((m, 3, 3)))).reshape(-1, 9)


def simulators(scale=1.0, backends=("numpy", "plain")):
    mesh = creature(cell=0.2)
    return [
        ModalMuscle.from_mesh(
            mesh, n_muscles=3, n_weights=5, n_clusters=10, mu=1e5 * scale, rho=1e3 * scale, h=0.01, backend=backend
        )
        for backend in backends
    ]


def run_pair(sims, steps, amplitude, z_dot0=None):
    """Step both simulators (the second makes each rotation exactly); also the steps the first redid."""
    assert sims[0].backends[0].name == "numpy (Kronecker form)" and sims[1].backend_used == "plain"
    states = []
    for sim in sims:
        z, z_dot, _ = sim.rest_state()
        if z_dot0 is not None:
            z_dot = z_dot0.copy()
        states.append((z, z_dot))
    for i in range(steps):
        a = amplitude * sims[0].ceilings * np.sin(2 * np.pi * (i * 0.01 / np.array([0.3, 0.5, 0.7]) + [0, 0.3, 0.6]))
        for k, sim in enumerate(sims):
            z, z_dot = states[k]
            z_next = sim.step(z, z_dot, a)
            states[k] = (z_next, (z_next - z) / sim.h)
        assert sims[0].iterations == sims[1].iterations
    return states[0][0], states[1][0], sims[0].solver.redone


def test_same_trajectory_as_rotations_made_exactly():
    sims = simulators()
    fast, checked, redone = run_pair(sims, 80, 0.6)
    assert np.all(np.isfinite(fast))
    assert np.abs(fast - checked).max() <= 1e-10 * np.abs(checked).max()
    assert redone <= 2  # at most the start: the squarings adapt to the motion
    assert 2 <= sims[0].backends[0].squarings <= 8


def test_hard_motion_redoes_uncertified_steps():
    # activations three times the ceilings and a violent spin: clusters
    # invert and strain hard, so some steps must be redone rotation by rotation
    sims = simulators()
    r = sims[0].B.shape[1]
    rng = np.random.default_rng(3)
    z_dot0 = 50.0 * rng.standard_normal(r)
    fast, checked, redone = run_pair(sims, 60, 3.0, z_dot0=z_dot0)
    assert np.all(np.isfinite(fast))
    assert redone >= 1
    assert np.abs(fast - checked).max() <= 1e-9 * np.abs(checked).max()


@pytest.mark.parametrize("scale", [1e-8, 1e8])
def test_material_scale_neither_overflows_nor_underflows_the_powers(scale):
    sims = simulators(scale=scale)
    fast, checked, redone = run_pair(sims, 40, 0.6)
    assert np.all(np.isfinite(fast))
    assert redone <= 2
    assert np.abs(fast - checked).max() <= 1e-10 * np.abs(checked).max()


@pytest.mark.parametrize("backend", ["numpy", "numba", "plain"])
def test_blow_up_is_reported_in_3d(backend):
    from skfem_modal import _accel
    from skfem_modal.sim import SimulationError

    if backend == "numba" and not _accel.AVAILABLE:
        pytest.skip("numba is not installed (the optional 'fast' extra)")
    sim = ModalMuscle.from_mesh(
        creature(cell=0.25), n_muscles=2, n_weights=4, n_clusters=6, mu=1e5, rho=1e3, h=0.01, backend=backend
    )
    z, z_dot, _ = sim.rest_state()
    with pytest.raises(SimulationError, match="non-finite"):
        for _ in range(5):
            z_next = sim.step(z, z_dot, np.full(sim.n_muscles, 1e300))
            z_dot, z = (z_next - z) / sim.h, z_next


def powers_of(P0, s):
    powers = [P0]
    for _ in range(s):
        powers.append(powers[-1] @ powers[-1])
    return np.stack(powers)


def traces_of(powers):
    return np.einsum("jnii->jn", powers[1:])


def test_squarings_certificate_measures_the_weight_off_the_top():
    from skfem_modal.rotations import certify_squarings

    F = near_rotations(300, 0.2, seed=4)
    N = (F @ HORN).reshape(-1, 4, 4)
    shift = 1.07 * np.sqrt(np.einsum("nij,nij->n", N, N) / 12)
    P0 = N + shift[:, None, None] * np.eye(4)
    lam = np.linalg.eigvalsh(P0)
    for s in (2, 3, 5, 7):
        ok, top, rho = certify_squarings(traces_of(powers_of(P0, s)), shift)
        assert top
        # exact: the other eigenvalues' weight next to the top one, 2^j-th powers
        for j, r in enumerate(rho, start=1):
            mu = np.abs(lam) ** (2**j)
            eps = mu[:, :3].sum(axis=1) / mu[:, 3]
            # eps <= rho (1 + eps)^2 / 2 for each matrix
            assert eps.max() <= (r * (1 + eps) ** 2 / 2).max() * (1 + 1e-9) + 1e-15
            if eps.max() > 1e-10:
                assert r <= 2.0 * eps.max() * (1 + 1e-6)
        # what ok promises: the last power's weight within 1e-13
        mu = np.abs(lam) ** (2**s)
        eps = (mu[:, :3].sum(axis=1) / mu[:, 3]).max()
        assert not ok or eps <= 1e-13
        assert ok == (s == 7)  # strains of 0.2: 2^5 powers are not enough for some


def test_squarings_certificate_needs_the_shift_or_the_sign():
    from skfem_modal.rotations import certify_squarings

    # det F < 0 with a tiny shift: the most negative eigenvalue dominates, the
    # powers are rank one along the wrong eigenvector, and the shift proves nothing
    F = np.diag([1.0, 0.9, -0.8]).reshape(1, 9)
    P0 = (F @ HORN).reshape(1, 4, 4) + 0.01 * np.eye(4)
    P0 = P0 / np.abs(P0).max()
    ok, top, rho = certify_squarings(traces_of(powers_of(P0, 8)), 0.01 / np.abs(P0).max())
    assert ok and not top
    powers = powers_of(P0, 8)
    assert np.einsum("nab,nab->n", powers[0], powers[8]).min() < 0  # the caller's check fails
    traces = traces_of(powers)
    traces[-1, 0] = np.nan  # an overflow propagates to the last power
    assert not certify_squarings(traces, 10.0)[0]


def test_certificate_with_the_shift_bound_folded_into_level_zero():
    # the Kronecker step stores 4 s / 1.05 at level 0 and asks t_1 / level_0^2
    # < 1.05^2: the same decisions as 4 s and t_1 / (4 s)^2 < 1
    from skfem_modal.rotations import certify_levels

    F = near_rotations(50, 0.2, seed=5)
    N = (F @ HORN).reshape(-1, 4, 4)
    norm = np.sqrt(np.einsum("nij,nij->n", N, N) / 12)
    for factor in (1.07, 0.9):  # above |N| / sqrt(12) for all, and below it for some
        shift = factor * norm
        P0 = N + shift[:, None, None] * np.eye(4)
        levels = np.vstack([4.0 * shift, traces_of(powers_of(P0, 5))])
        plain = certify_levels(levels)
        folded = levels.copy()
        folded[0] /= 1.05
        assert certify_levels(folded, top_bound=1.05**2)[:2] == plain[:2]
        assert plain[1] == (factor > 1.0)
        np.testing.assert_allclose(certify_levels(folded, top_bound=1.05**2)[2], plain[2])


def test_kronecker_form_only_for_bases_that_move_coordinates_alike():
    sim = simulators()[0]
    assert sim.backends[0].name == "numpy (Kronecker form)"
    # mixing the coordinates of z by a generic rotation keeps the subspace
    # but not the factored form: the plain backend takes over, same answer
    r = sim.B.shape[1]
    Q, _ = np.linalg.qr(np.random.default_rng(5).standard_normal((r, r)))

    def on_basis(B):
        return ModalMuscle(
            sim.mesh, B, sim.D, sim.labels, mu=1e5, gamma=1e5, rho=1e3, h=0.01, backend="numpy",
            active_labels=sim.active_labels,
        )  # fmt: skip

    mixed, plain = on_basis(sim.B @ Q), on_basis(sim.B)
    assert mixed.backends[0].name == "plain" and plain.backends[0].name == "numpy (Kronecker form)"
    z, z_dot, _ = plain.rest_state()
    w, w_dot = Q.T @ z, Q.T @ z_dot
    for i in range(30):
        a = 0.5 * plain.ceilings * np.sin(2 * np.pi * i * 0.01 / np.array([0.3, 0.5, 0.7]))
        z_next, w_next = plain.step(z, z_dot, a), mixed.step(w, w_dot, a)
        assert plain.iterations == mixed.iterations
        z, z_dot, w, w_dot = z_next, (z_next - z) / 0.01, w_next, (w_next - w) / 0.01
    assert np.abs(Q @ w - z).max() <= 1e-9 * np.abs(z).max()


@pytest.mark.parametrize("rtol", [0.0, 1e-3])
def test_kronecker_step_with_damping_pins_gravity_and_relative_stopping(rtol):
    mesh = creature(cell=0.2)
    top = np.flatnonzero(mesh.p[2] >= mesh.p[2].max() - 1e-9)
    sims = [
        ModalMuscle.from_mesh(
            mesh,
            n_muscles=3,
            n_weights=5,
            n_clusters=10,
            mu=1e5,
            rho=1e3,
            h=0.01,
            gravity=[0.0, 0.0, -9.8],
            pinned=top,
            damping_mass=0.5,
            damping_stiffness=1e-3,
            rtol=rtol,
            backend=backend,
        )
        for backend in ("numpy", "plain")
    ]
    assert {"gravity", "pinned", "damping"} <= set(sims[0].effects)
    fast, checked, redone = run_pair(sims, 40, 0.6)
    assert redone <= 2
    assert np.abs(fast - checked).max() <= 1e-10 * np.abs(checked).max()


def test_kronecker_step_checks_the_sign_itself_when_the_shift_proves_nothing(monkeypatch):
    # when the shift is too small to prove the top eigenvalue dominant, the
    # step computes tr(P P^(2^s)) itself: same trajectory, no redone step
    from skfem_modal import _kron3

    sims = simulators(backends=("numpy", "numpy"))
    unproven = []
    certify = _kron3.certify_levels

    def without_shift_proof(levels, **options):
        ok, top, rho = certify(levels, **options)
        unproven.append(ok)
        return ok, False, rho

    z_ref = z = sims[0].rest_state()[0]
    z_dot_ref = z_dot = np.zeros_like(z)
    for i in range(30):
        a = 0.6 * sims[0].ceilings * np.sin(2 * np.pi * i * 0.01 / np.array([0.3, 0.5, 0.7]))
        z_next_ref = sims[0].step(z_ref, z_dot_ref, a)
        with monkeypatch.context() as patch:
            patch.setattr(_kron3, "certify_levels", without_shift_proof)
            z_next = sims[1].step(z, z_dot, a)
        assert sims[0].iterations == sims[1].iterations
        z_dot_ref, z_ref = (z_next_ref - z_ref) / 0.01, z_next_ref
        z_dot, z = (z_next - z) / 0.01, z_next
    assert len(unproven) == 30 and all(unproven)  # every step took the explicit check, and passed it
    np.testing.assert_array_equal(z, z_ref)


def test_kronecker_step_is_redone_when_the_sign_check_fails(monkeypatch):
    # the explicit check decides: a negative tr(P P^(2^s)) (the powers found another eigenvector than
    # the top one's) refuses the step's rotations, and the exact backend redoes the step
    from skfem_modal import _kron3

    sims = simulators(backends=("numpy", "plain"))
    certify, einsum = _kron3.certify_levels, np.einsum

    certified = []

    def without_shift_proof(levels, **options):
        ok, top, rho = certify(levels, **options)
        certified.append(ok)
        return ok, False, rho

    def sign_fails(subscripts, *operands, **options):
        found = einsum(subscripts, *operands, **options)
        return -np.abs(found) if subscripts == "knab,knab->kn" else found

    before = sims[0].solver.redone
    with monkeypatch.context() as patch:
        patch.setattr(_kron3, "certify_levels", without_shift_proof)
        patch.setattr(_kron3.np, "einsum", sign_fails)
        fast, checked, _ = run_pair(sims, 10, 0.6)
    assert len(certified) == 10 and all(certified)  # the powers passed: the sign check alone refused them
    assert sims[0].solver.redone - before == 10  # every step refused, and redone
    assert np.abs(fast - checked).max() <= 1e-10 * np.abs(checked).max()
