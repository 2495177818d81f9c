"""The optional compiled kernels (numba) give the numpy path's results."""

import numpy as np
import pytest

from skfem_modal import _accel, caterpillar, creature
from skfem_modal.rotations import polar_rotations, rotations3_flat
from skfem_modal.sim import ModalMuscle

needs_numba = pytest.mark.skipif(not _accel.AVAILABLE, reason="numba is not installed (the optional 'fast' extra)")


@pytest.fixture(scope="module")
def kernels():
    return _accel.kernels()


@needs_numba
def test_compiled_3d_rotations_match_numpy(kernels):
    rng = np.random.default_rng(5)
    F = np.concatenate(
        [
            rng.standard_normal((300, 9)),
            (np.eye(3) + 0.1 * rng.standard_normal((300, 3, 3))).reshape(-1, 9),
            -np.tile(np.eye(3).ravel(), (3, 1)),  # inverted, a degenerate maximiser
            np.zeros((2, 9)),
        ]
    )
    R, q = kernels.rotations3(F, None)
    dets = np.linalg.det(R.reshape(-1, 3, 3))
    np.testing.assert_allclose(dets, 1.0, atol=1e-12)
    objective = np.einsum("ij,ij->i", R, F)
    best = np.einsum("ij,ij->i", rotations3_flat(F), F)
    assert np.all(objective >= best - 1e-12 * np.abs(F).max(axis=1) - 1e-300)
    unique = slice(0, 600)  # where the maximiser is unique, the same rotation
    np.testing.assert_allclose(R[unique], rotations3_flat(F[unique]), atol=1e-9)
    # warm-started from the result of a nearby batch
    F2 = F[:600] + 1e-3 * rng.standard_normal((600, 9))
    R2, _ = kernels.rotations3(F2, q[:600].copy())
    np.testing.assert_allclose(R2, rotations3_flat(F2), atol=1e-9)


@needs_numba
def test_compiled_2d_normalisation(kernels):
    cs = np.array([[3.0, 4.0], [0.0, 0.0], [-1.0, 0.0]])
    kernels.normalize_cs(cs)
    np.testing.assert_allclose(cs, [[0.6, 0.8], [1.0, 0.0], [-1.0, 0.0]])


@needs_numba
@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("scene", ["crawl", "crawl, push out", "float", "float, relative tolerance"])
def test_compiled_steps_equal_numpy_steps(dim, scene):
    # floating, the compiled path runs all iterations of a step in one call
    if dim == 2:
        mesh, up, gravity = caterpillar(nx=24, ny=12), 1, [0.0, -9.8]
    else:
        mesh, up, gravity = creature(cell=0.2), 2, [0.0, 0.0, -9.8]
    ground = float(mesh.p[up].min()) - 0.02
    if not scene.startswith("crawl"):
        gravity = ground = None
    rtol = 1e-3 if "relative" in scene else 0.0
    contact = dict(n_contacts=12, contact_model="reference", push_out=1.0 if "push out" in scene else 0.0)
    contact = {} if ground is None else contact  # contact settings without a ground are refused
    sims = [
        ModalMuscle.from_mesh(
            mesh,
            n_muscles=3,
            n_weights=5,
            n_clusters=8,
            mu=1e5,
            rho=1e3,
            h=0.01,
            gravity=gravity,
            ground=ground,
            backend=acc,
            rtol=rtol,
            **contact,
        )
        for acc in ("numpy", "numba")
    ]
    assert [s.backend_used for s in sims] == ["numpy", "numba"]
    states = [s.rest_state()[:2] for s in sims]
    for i in range(60):
        a = 0.5 * sims[0].ceilings * np.sin(2 * np.pi * (i * 0.01 / np.array([0.5, 0.7, 0.9]) + [0, 0.3, 0.6]))
        for k, sim in enumerate(sims):
            z, z_dot = states[k]
            z_next = sim.step(z, z_dot, a)
            states[k] = (z_next, (z_next - z) / sim.h)
        assert sims[0].iterations == sims[1].iterations
    z_numpy, z_numba = states[0][0], states[1][0]
    assert np.abs(z_numba - z_numpy).max() <= 1e-9 * np.abs(z_numpy).max()


def test_asking_for_numba_without_it(monkeypatch):
    monkeypatch.setattr(_accel, "AVAILABLE", False)
    with pytest.raises(ValueError, match=r"backend='numba' needs numba"):
        ModalMuscle.from_mesh(caterpillar(nx=12, ny=6), n_muscles=1, n_weights=2, n_clusters=3, backend="numba")
    sim = ModalMuscle.from_mesh(caterpillar(nx=12, ny=6), n_muscles=1, n_weights=2, n_clusters=3)
    assert sim.backend_used == "numpy"


def test_polar_rotations_unchanged_by_accelerator():
    # the public function is numpy-only and exact
    F = np.diag([1.0, 2.0, 3.0])[None]
    np.testing.assert_allclose(polar_rotations(F)[0], np.eye(3), atol=1e-14)


if _accel.AVAILABLE:
    from hypothesis import given, settings
    from hypothesis import strategies as st

    @settings(max_examples=100, deadline=None)
    @given(st.integers(0, 2**32 - 1), st.sampled_from(["random", "inverted", "rank_deficient", "tiny", "huge"]))
    def test_property_compiled_kernel_any_batch(seed, kind):
        kernels = _accel.kernels()
        rng = np.random.default_rng(seed)
        F = rng.standard_normal((12, 3, 3))
        if kind == "inverted":
            F[:, :, 0] *= -np.sign(np.linalg.det(F))[:, None]
        elif kind == "rank_deficient":
            F[:, :, 2] = F[:, :, 0] * rng.standard_normal(12)[:, None]
        elif kind == "tiny":
            F *= 1e-200
        elif kind == "huge":
            F *= 1e200
        F9 = F.reshape(-1, 9)
        warm = None if seed % 2 else rng.standard_normal((12, 4))
        R, _ = kernels.rotations3(F9, warm)
        R3 = R.reshape(-1, 3, 3)
        assert np.all(np.isfinite(R))
        np.testing.assert_allclose(np.linalg.det(R3), 1.0, atol=1e-12)
        best = np.einsum("ij,ij->i", rotations3_flat(F9), F9)
        assert np.all(np.einsum("ij,ij->i", R, F9) >= best - 1e-10 * np.abs(F9).max(axis=1))
