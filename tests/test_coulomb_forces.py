"""The exact Coulomb solve of a few vertices (``coulomb_forces``): its conditions, its Jacobian, the frictionless QP."""

import numpy as np
import pytest
from scipy.optimize import nnls

from skfem_modal._contact_sets import Aims, Picked, _AlartCurnier, compliance_matrix, coulomb_forces, pyramid_projection


def problem(rng, q, dim):
    """A random contact problem like the picked vertices': rows that depend on each other, a compliance of 1e-3."""
    size = q * dim
    A = rng.standard_normal((size, size // 2 + 1))
    W = A @ A.T
    W += 1e-3 * np.trace(W) / size * np.eye(size)
    return W, rng.standard_normal(size)


def split(values, dim, up):
    """A vertex-major vector as (heights (q,), tangents (q, dim - 1))."""
    values = values.reshape(-1, dim)
    return values[:, up], np.delete(values, up, axis=1)


@pytest.mark.parametrize("dim, up", [(2, 1), (3, 2), (3, 0)])
@pytest.mark.parametrize("friction", [0.0, 0.3, 1.0])
def test_the_forces_meet_coulombs_conditions(dim, up, friction):
    rng = np.random.default_rng(dim + 10 * up + int(10 * friction))
    solved = 0
    for _ in range(40):
        W, free = problem(rng, int(rng.integers(1, 20)), dim)
        lam = coulomb_forces(W, free, dim, up, friction, 1e-12)
        if lam is None:  # (random problems with friction 1 are harder than the ground's: a few do not converge)
            continue
        solved += 1
        scale = np.abs(lam).max()
        normal, tangential = split(lam, dim, up)
        height, slide = split(free + W @ lam, dim, up)
        assert normal.min() >= -1e-12 * scale and height.min() >= -1e-10
        assert np.abs(normal * height).max() <= 1e-10 * scale  # touching, or let go
        force, moved = np.linalg.norm(tangential, axis=1), np.linalg.norm(slide, axis=1)
        assert np.all(force <= friction * normal + 1e-10 * scale)  # within the cone
        sliding = (moved > 1e-9) & (normal > 1e-9 * scale)
        assert np.allclose(force[sliding], friction * normal[sliding], rtol=1e-9, atol=1e-10 * scale)
        if friction and np.count_nonzero(sliding):  # straight against the slide
            against = -np.einsum("ij,ij->i", tangential[sliding], slide[sliding]) / (force * moved)[sliding]
            assert against.min() >= 1.0 - 1e-9
    assert solved >= 30


def test_a_slide_is_held_back_by_friction_times_the_push():
    # one vertex in 3D pressed 2 into the ground and moving (3, 4) along it, each row moved 1 by a unit
    # force: the ground pushes it out (2), and friction 0.5 (1) takes 1 off its slide of 5, straight back
    lam = coulomb_forces(np.eye(3), np.array([3.0, 4.0, -2.0]), 3, 2, 0.5, 1e-14)
    assert lam == pytest.approx([-0.6, -0.8, 2.0], abs=1e-14)
    # with friction 3 (6 > 5) it sticks: the tangential force takes the whole slide
    assert coulomb_forces(np.eye(3), np.array([3.0, 4.0, -2.0]), 3, 2, 3.0, 1e-14) == pytest.approx([-3, -4, 2])


def test_without_friction_the_forces_are_the_least_change_that_keeps_every_height_up():
    # frictionless, the heights' forces minimise 1/2 N K N + N free_n over N >= 0 (K the heights' rows of W):
    # a non-negative least squares problem, by scipy's NNLS
    rng = np.random.default_rng(7)
    for _ in range(10):
        W, free = problem(rng, 12, 3)
        lam = coulomb_forces(W, free, 3, 2, 0.0, 1e-13)
        heights = np.arange(2, free.size, 3)
        K = W[np.ix_(heights, heights)]
        L = np.linalg.cholesky(K)
        expected, _ = nnls(L.T, -np.linalg.solve(L, free[heights]))
        assert lam[heights] == pytest.approx(expected, rel=1e-8, abs=1e-10 * expected.max())
        assert np.abs(np.delete(lam, heights)).max() <= 1e-14 * lam.max()  # no friction


def test_the_jacobian_is_the_functions_derivative():
    rng = np.random.default_rng(3)
    for dim in (2, 3):
        W, free = problem(rng, 5, dim)
        W += np.eye(W.shape[0])  # away from the kinks: every vertex clearly touching, let go, stuck or sliding
        evaluate = _AlartCurnier(W, free, dim, 0.7)
        for _ in range(5):
            lam = 3.0 * rng.standard_normal(free.size)
            value, jacobian = evaluate(lam)
            step, numeric = 1e-7, np.empty_like(jacobian)
            for k in range(free.size):
                e = np.zeros(free.size)
                e[k] = step
                numeric[:, k] = (evaluate(lam + e)[0] - evaluate(lam - e)[0]) / (2 * step)
            assert np.abs(jacobian - numeric).max() <= 1e-6 * max(1.0, np.abs(jacobian).max())


def test_a_start_near_the_answer_takes_fewer_newton_steps():
    rng = np.random.default_rng(11)
    W, free = problem(rng, 10, 3)
    lam = coulomb_forces(W, free, 3, 2, 0.5, 1e-12)
    again = coulomb_forces(W, free, 3, 2, 0.5, 1e-12, start=lam, iterations=1)  # at most one step from it
    assert again is not None and again == pytest.approx(lam, rel=1e-9, abs=1e-12 * np.abs(lam).max())


def test_the_pyramid_fallback_and_the_exact_solve_agree_without_friction():
    # two solvers of the same frictionless projection: NNLS on the generators' least-distance problem, and
    # the semismooth Newton method on Alart and Curnier's function
    rng = np.random.default_rng(5)
    dim, up, p, r = 3, 2, 10, 24
    J = rng.standard_normal((p * dim, r))
    A = rng.standard_normal((r, r))
    H = A @ A.T + r * np.eye(r)
    pushes = np.linalg.solve(H, J.T).T
    picked = Picked(J, pushes, dim, up, 1e-3 * np.einsum("ij,ij->i", J, pushes).mean())
    z_t = rng.standard_normal(r)
    x_t = picked.positions(z_t)
    target = x_t + 0.5 * rng.standard_normal(p * dim)  # some heights below their targets, some above
    picked.aim(x_t, target, target[up::dim])
    z = np.empty(r)
    near = np.ones(p, bool)
    normal = pyramid_projection(picked, near, ~near, x_t, z_t, z, 0.0, Aims(target, 0, np.inf))
    W = compliance_matrix(picked, np.arange(p * dim))
    lam = coulomb_forces(W, x_t - target, dim, up, 0.0, 1e-13)
    assert 0 < np.count_nonzero(normal) < p  # some pushed, some not
    assert normal == pytest.approx(lam[up::dim], rel=1e-9, abs=1e-12 * normal.max())
    assert z == pytest.approx(z_t + lam @ picked.pushes, rel=1e-9, abs=1e-12)
