"""The 3D numpy step: rotations read off matrix powers, certified once a step.

Its trajectory must be the one of the path that certifies each rotation as it
is made (:meth:`ModalMuscle._iterate3_checked`), on easy and hard motions, and
a step whose rotations fail the check must be redone that way. Both fast
forms are covered: the Kronecker form (skinning bases) and the general one.
"""

import numpy as np
import pytest

from skfem_modal import creature
from skfem_modal.rotations import HORN, HORN_SHIFTED, SHIFT, certify_dominant, rotations3_flat
from skfem_modal.sim import ModalMuscle


def shifted(F9):
    """P0 = N(F) + |N(F)| SHIFT I, row-major, for F of shape (m, 9)."""
    N = F9 @ HORN
    s = SHIFT * np.sqrt(np.einsum("ij,ij->i", N, N))
    return np.hstack([F9, s[:, None]]) @ HORN_SHIFTED


def powered_rotations(P0, k):
    P = P0.reshape(-1, 4, 4)
    for _ in range(k):
        P = P / np.abs(P).max(axis=(1, 2), keepdims=True)
        P = P @ P
    from skfem_modal.rotations import QQ_TO_R_TRACE

    RT = P.reshape(-1, 16) @ QQ_TO_R_TRACE
    return RT[:, :9] / RT[:, 9:]


def near_rotations(m, strain, seed=0):
    rng = np.random.default_rng(seed)
    from scipy.spatial.transform import Rotation

    Q = Rotation.random(m, random_state=seed).as_matrix()
    return (Q @ (np.eye(3) + strain * rng.standard_normal((m, 3, 3)))).reshape(-1, 9)


def test_certified_rotations_are_the_closest_rotations():
    F = near_rotations(400, 0.2)
    P0 = shifted(F)
    R = powered_rotations(P0, 6)
    ok, ratio = certify_dominant(P0, R, 6)
    assert ok and 0.0 < ratio < 1.0
    np.testing.assert_allclose(R, rotations3_flat(F), atol=1e-11)


def test_too_few_squarings_fail():
    F = near_rotations(400, 0.3, seed=1)
    P0 = shifted(F)
    R = powered_rotations(P0, 2)  # P^4: far from converged for these strains
    assert np.abs(R - rotations3_flat(F)).max() > 1e-8
    ok, ratio = certify_dominant(P0, R, 2)
    assert not ok and ratio == np.inf


def test_a_wrong_rotation_fails():
    F = near_rotations(50, 0.1, seed=2)
    P0 = shifted(F)
    R = rotations3_flat(F)
    assert certify_dominant(P0, R, 8)[0]
    # the rotation by pi about an axis: another stationary point, a negative eigenvalue
    R_bad = R.copy()
    R_bad[7] = (R[7].reshape(3, 3) @ np.diag([1.0, -1.0, -1.0])).ravel()
    assert not certify_dominant(P0, R_bad, 8)[0]
    R_nan = R.copy()
    R_nan[3, 0] = np.nan
    assert not certify_dominant(P0, R_nan, 8)[0]


def test_a_too_small_shift_fails_on_an_inverted_matrix():
    # det F < 0 with a tiny shift: the most negative eigenvalue dominates in
    # magnitude, and P's powers converge to the wrong eigenvector
    F = np.diag([1.0, 0.9, -0.8]).reshape(1, 9)
    N = F @ HORN
    P0 = np.hstack([F, [[0.01]]]) @ HORN_SHIFTED
    R = powered_rotations(P0, 8)
    assert np.abs(R - rotations3_flat(F)).max() > 0.5
    assert not certify_dominant(P0, R, 8)[0]
    assert np.linalg.eigvalsh(N.reshape(4, 4))[0] < 0


def simulators(scale=1.0):
    mesh = creature(cell=0.2)
    return [
        ModalMuscle.from_mesh(
            mesh, n_muscles=3, n_weights=5, n_clusters=10, mu=1e5 * scale, rho=1e3 * scale, h=0.01, accelerator="numpy"
        )
        for _ in range(2)
    ]


def run_pair(sims, steps, amplitude, monkeypatch, z_dot0=None):
    """Step both simulators; the second certifies each rotation as it is made."""
    checked = sims[1]
    checked._kron = None
    monkeypatch.setattr(checked, "_iterate3_squarings", lambda c, z, contact: None)
    redone = []
    original = sims[0]._iterate3_checked

    def spy(*args):
        redone.append(1)
        return original(*args)

    monkeypatch.setattr(sims[0], "_iterate3_checked", spy)
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
    return states[0][0], states[1][0], len(redone)


def squarings(sim):
    return sim._kron.squarings if sim._kron is not None else sim._squarings


@pytest.mark.parametrize("kronecker", [True, False])
def test_same_trajectory_as_rotations_checked_one_by_one(kronecker, monkeypatch):
    sims = simulators()
    assert sims[0]._kron is not None  # a skinning basis: the Kronecker form
    if not kronecker:
        sims[0]._kron = None
    fast, checked, redone = run_pair(sims, 80, 0.6, monkeypatch)
    assert np.all(np.isfinite(fast))
    assert np.abs(fast - checked).max() <= 1e-10 * np.abs(checked).max()
    assert redone <= 2  # at most the start: the squarings adapt to the motion
    assert 2 <= squarings(sims[0]) <= 8


@pytest.mark.parametrize("kronecker", [True, False])
def test_hard_motion_redoes_uncertified_steps(kronecker, monkeypatch):
    # activations three times the ceilings and a violent spin: clusters
    # invert and strain hard, so some steps must be redone rotation by rotation
    sims = simulators()
    if not kronecker:
        sims[0]._kron = None
    r = sims[0].B.shape[1]
    rng = np.random.default_rng(3)
    z_dot0 = 50.0 * rng.standard_normal(r)
    fast, checked, redone = run_pair(sims, 60, 3.0, monkeypatch, z_dot0=z_dot0)
    assert np.all(np.isfinite(fast))
    assert redone >= 1
    assert np.abs(fast - checked).max() <= 1e-9 * np.abs(checked).max()


@pytest.mark.parametrize("scale", [1e-8, 1e8])
def test_material_scale_neither_overflows_nor_underflows_the_powers(scale, monkeypatch):
    sims = simulators(scale=scale)
    fast, checked, redone = run_pair(sims, 40, 0.6, monkeypatch)
    assert np.all(np.isfinite(fast))
    assert redone <= 2
    assert np.abs(fast - checked).max() <= 1e-10 * np.abs(checked).max()


@pytest.mark.parametrize("accelerator", ["numpy", "numba"])
def test_blow_up_is_reported_in_3d(accelerator):
    from skfem_modal import _accel
    from skfem_modal.sim import SimulationError

    if accelerator == "numba" and not _accel.AVAILABLE:
        pytest.skip("numba is not installed (the optional 'fast' extra)")
    sim = ModalMuscle.from_mesh(
        creature(cell=0.25), n_muscles=2, n_weights=4, n_clusters=6, mu=1e5, rho=1e3, h=0.01, accelerator=accelerator
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
    P0 = (np.hstack([F, [[0.01]]]) @ HORN_SHIFTED).reshape(1, 4, 4)
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
    from skfem_modal._kron3 import separable_columns, separable_rows, separable_square

    sim = simulators()[0]
    assert sim._kron is not None
    assert separable_rows(sim._G) is not None and separable_columns(sim._W) is not None
    assert separable_square(sim._K_inertia) is not None
    # mixing the coordinates of z by a generic rotation keeps the subspace
    # but not the factored form: the general step takes over, same answer
    r = sim.B.shape[1]
    Q, _ = np.linalg.qr(np.random.default_rng(5).standard_normal((r, r)))

    def on_basis(B):
        return ModalMuscle(
            sim.mesh, B, sim.D, sim.labels, mu=1e5, gamma=1e5, rho=1e3, h=0.01, accelerator="numpy",
            active_labels=sim.active_labels,
        )  # fmt: skip

    mixed, plain = on_basis(sim.B @ Q), on_basis(sim.B)
    assert mixed._kron is None and plain._kron is not None
    z, z_dot, _ = plain.rest_state()
    w, w_dot = Q.T @ z, Q.T @ z_dot
    for i in range(30):
        a = 0.5 * plain.ceilings * np.sin(2 * np.pi * i * 0.01 / np.array([0.3, 0.5, 0.7]))
        z_next, w_next = plain.step(z, z_dot, a), mixed.step(w, w_dot, a)
        assert plain.iterations == mixed.iterations
        z, z_dot, w, w_dot = z_next, (z_next - z) / 0.01, w_next, (w_next - w) / 0.01
    assert np.abs(Q @ w - z).max() <= 1e-9 * np.abs(z).max()


@pytest.mark.parametrize("rtol", [0.0, 1e-3])
def test_kronecker_step_with_damping_pins_gravity_and_relative_stopping(rtol, monkeypatch):
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
            accelerator="numpy",
        )
        for _ in range(2)
    ]
    assert sims[0]._kron is not None and {"gravity", "pinned", "damping"} <= set(sims[0].effects)
    fast, checked, redone = run_pair(sims, 40, 0.6, monkeypatch)
    assert redone <= 2
    assert np.abs(fast - checked).max() <= 1e-10 * np.abs(checked).max()


def test_kronecker_step_checks_the_sign_itself_when_the_shift_proves_nothing(monkeypatch):
    # when the shift is too small to prove the top eigenvalue dominant, the
    # step computes tr(P P^(2^s)) itself: same trajectory, no redone step
    from skfem_modal import _kron3

    sims = simulators()
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
