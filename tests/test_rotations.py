"""Batched closest rotations: exact against the SVD, proper for every input."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from skfem_modal.rotations import polar_rotations


def svd_rotation(F):
    U, _, Vt = np.linalg.svd(F)
    d = np.sign(np.linalg.det(U @ Vt))
    U[..., :, -1] *= d[..., None]
    return U @ Vt


def objective(R, F):
    return np.einsum("...ij,...ij->...", R, F)


def check_proper(R, dim):
    np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(dim), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    assert np.all(np.isfinite(R))


@pytest.mark.parametrize("dim", [2, 3])
def test_matches_svd_on_random_batches(dim):
    rng = np.random.default_rng(dim)
    F = rng.standard_normal((500, dim, dim))
    R = polar_rotations(F)
    check_proper(R, dim)
    # the maximum of tr(R^T F) over SO(dim) is unique here, and reached
    np.testing.assert_allclose(objective(R, F), objective(svd_rotation(F), F), rtol=1e-12)
    np.testing.assert_allclose(R, svd_rotation(F), atol=1e-9)


@pytest.mark.parametrize("dim", [2, 3])
def test_rotation_times_stretch_gives_the_rotation(dim):
    rng = np.random.default_rng(10 + dim)
    Q = svd_rotation(rng.standard_normal((200, dim, dim)))
    S = rng.standard_normal((200, dim, dim))
    S = S @ np.swapaxes(S, -1, -2) + 0.1 * np.eye(dim)
    np.testing.assert_allclose(polar_rotations(Q @ S), Q, atol=1e-10)


@pytest.mark.parametrize("dim", [2, 3])
def test_adversarial_matrices(dim):
    eye = np.eye(dim)
    flip = np.diag([1.0] * (dim - 1) + [-1.0])
    rank1 = np.outer(np.arange(1, dim + 1), np.ones(dim)).astype(float)
    F = np.stack([np.zeros((dim, dim)), eye, -eye, flip, rank1, 1e-300 * flip, 1e300 * flip, np.ones((dim, dim))])
    R = polar_rotations(F)
    check_proper(R, dim)
    np.testing.assert_allclose(R[0], eye)  # zero: the identity
    np.testing.assert_allclose(R[1], eye, atol=1e-14)
    # every result is a maximiser
    gap = objective(svd_rotation(F), F) - objective(R, F)
    assert np.all(gap <= 1e-12 * np.abs(F).max(axis=(1, 2)))


finite = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False, allow_subnormal=False)


@settings(max_examples=200, deadline=None)
@given(
    st.tuples(st.integers(1, 8), st.sampled_from([2, 3])).flatmap(
        lambda shape: arrays(np.float64, (shape[0], shape[1], shape[1]), elements=finite)
    )
)
def test_property_any_finite_batch(F):
    dim = F.shape[-1]
    R = polar_rotations(F)
    check_proper(R, dim)
    best = objective(svd_rotation(F), F)
    scale = np.abs(F).max(axis=(1, 2)) + 1e-300
    assert np.all(objective(R, F) >= best - 1e-9 * scale)


@settings(max_examples=100, deadline=None)
@given(
    st.sampled_from([2, 3]),
    st.integers(0, 2**32 - 1),
    st.sampled_from(["inverted", "rank_deficient", "tiny", "huge"]),
)
def test_property_adversarial_batches(dim, seed, kind):
    rng = np.random.default_rng(seed)
    F = rng.standard_normal((16, dim, dim))
    if kind == "inverted":
        F[:, :, 0] *= -np.sign(np.linalg.det(F))[:, None]
    elif kind == "rank_deficient":
        F[:, :, -1] = F[:, :, 0] * rng.standard_normal(16)[:, None]
    elif kind == "tiny":
        F *= 1e-200
    else:
        F *= 1e200
    R = polar_rotations(F)
    check_proper(R, dim)
    best = objective(svd_rotation(F), F)
    assert np.all(objective(R, F) >= best - 1e-10 * np.abs(F).max(axis=(1, 2)))


def test_shape_errors():
    with pytest.raises(ValueError, match=r"expected matrices of shape \(..., d, d\)"):
        polar_rotations(np.zeros((4, 2, 3)))
    assert polar_rotations(np.zeros((0, 3, 3))).shape == (0, 3, 3)
