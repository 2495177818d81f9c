"""The 3D numpy step: rotations read off matrix powers, certified once a step.

Its trajectory must be the one of the path that certifies each rotation as it
is made (:meth:`ModalMuscle._iterate3_checked`), on easy and hard motions, and
a step whose rotations fail the check must be redone that way.
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


def test_same_trajectory_as_rotations_checked_one_by_one(monkeypatch):
    sims = simulators()
    fast, checked, redone = run_pair(sims, 80, 0.6, monkeypatch)
    assert np.all(np.isfinite(fast))
    assert np.abs(fast - checked).max() <= 1e-10 * np.abs(checked).max()
    assert redone <= 2  # at most the start: the squarings adapt to the motion
    assert 2 <= sims[0]._squarings <= 8


def test_hard_motion_redoes_uncertified_steps(monkeypatch):
    # activations three times the ceilings and a violent spin: clusters
    # invert and strain hard, so some steps must be redone rotation by rotation
    sims = simulators()
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
