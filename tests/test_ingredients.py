"""The stages of ModalMuscle.from_mesh as plain functions (skfem_modal.ingredients)."""

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from skfem_modal import ModalMuscle, caterpillar, mass_matrix
from skfem_modal.ingredients import element_clusters, ingredients, skinning_subspace
from skfem_modal.mesh import connected_parts
from skfem_modal.modal import muscle_signs


@pytest.fixture(scope="module")
def mesh():
    return caterpillar(nx=16, ny=8)


def test_skinning_subspace_is_mass_orthonormal_and_spans_only_n_weights(mesh):
    weights, B = skinning_subspace(mesh, 3, cluster_weights=5)
    n, dim = mesh.p.shape[1], mesh.p.shape[0]
    assert weights.shape == (n, 5)
    assert B.shape == (n * dim, 3 * (dim + 1) * dim)
    np.testing.assert_allclose(B.T @ (mass_matrix(mesh, 1.0) @ B), np.eye(B.shape[1]), atol=1e-10)
    # the rest pose is in the span (weights sum to a constant): its mass-weighted projection reproduces it
    X = mesh.p.T.ravel()
    rest = B @ (B.T @ (mass_matrix(mesh, 1.0) @ X))
    np.testing.assert_allclose(rest, X, atol=1e-9 * np.abs(X).max())


def test_separate_bodies_get_a_muscle_cluster_each(mesh):
    shifted = type(mesh)(np.hstack([mesh.p, mesh.p + [[5.0], [0.0]]]), np.hstack([mesh.t, mesh.t + mesh.p.shape[1]]))
    weights, B = skinning_subspace(shifted, 3)
    labels, active = element_clusters(shifted, B, weights, 6, n_active_clusters=1)
    parts = connected_parts(shifted)[shifted.t[0]]  # the part of each element (of its first vertex)
    assert np.unique(labels).size == 6
    assert active is not None and np.unique(active).size == 2
    for part in range(2):  # each part's elements are all in one active cluster, a different one per part
        assert np.unique(active[parts == part]).size == 1
    assert active[parts == 0][0] != active[parts == 1][0]


def test_one_body_one_muscle_cluster_is_none(mesh):
    weights, B = skinning_subspace(mesh, 3)
    assert element_clusters(mesh, B, weights, 4)[1] is None


def test_the_second_thread_changes_nothing_and_from_mesh_uses_these_ingredients(mesh):
    kw = dict(n_muscles=2, muscle_signs=[1, -1], n_weights=3, cluster_weights=None, n_clusters=5)
    kw |= dict(n_active_clusters=2, cluster_by="weights", mu=1e4, lam=None, rho=1e3, pinned=None, seed=0)
    kw |= dict(ground=float(mesh.p[1].min()), n_contacts=None, contact_candidates=None, contact_model="reference")
    alone = ingredients(mesh, **kw)
    with ThreadPoolExecutor(max_workers=1) as pool:
        beside = ingredients(mesh, pool, **kw)
        D = beside.muscles()

    def same(actual, expected, tol=1e-12):  # to round-off: BLAS threads may sum in another order
        np.testing.assert_allclose(actual, expected, rtol=0, atol=tol * np.abs(expected).max())

    # the modes are eigenvectors: their round-off is the matrix's over the gap to the next eigenvalue
    # (seen 2.4e-12 of the largest entry with two BLAS threads beside one)
    modes = 1e-10

    same(alone.muscles(), D, modes)
    assert D.shape == (mesh.p.size, 2) and "modal_analysis" in beside.timings
    same(alone.B, beside.B)
    np.testing.assert_array_equal(alone.labels, beside.labels)
    assert alone.contact_vertices.size == 30  # the reference contact's default count
    sim = ModalMuscle.from_mesh(mesh, **{k: v for k, v in kw.items() if k not in ("cluster_weights", "n_contacts")})
    same(sim.B, alone.B)
    same(sim.D, D, modes)
    np.testing.assert_array_equal(sim.labels, alone.labels)
    np.testing.assert_array_equal(sim.active_labels, alone.active_labels)
    np.testing.assert_array_equal(sim.contact_vertices, np.sort(alone.contact_vertices))


def test_bad_stage_arguments_are_refused_before_any_work(mesh):
    kw = dict(n_muscles=2, muscle_signs=None, n_weights=3, cluster_weights=None, n_clusters=5, n_active_clusters=1)
    kw |= dict(mu=1e4, lam=None, rho=1e3, pinned=None, seed=0, ground=None, n_contacts=None, contact_candidates=None)
    with pytest.raises(ValueError, match="cluster_by must be one of"):
        ingredients(mesh, cluster_by="colour", contact_model="coulomb", **kw)
    with pytest.raises(ValueError, match="muscle_signs must be 2 values of \\+1 or -1"):
        ingredients(mesh, cluster_by="weights", contact_model="coulomb", **{**kw, "muscle_signs": [1, 2]})
    # nothing numpy cannot make an array of gets past the same message (a dict, a ragged list, a string)
    for bad in ({"a": 1, "b": -1}, [[1], [1, -1]], "+-", [1, None], [True, True], ["1", "-1"]):
        with pytest.raises(ValueError, match="muscle_signs must be 2 values of \\+1 or -1"):
            muscle_signs(bad, 2)


def test_every_argument_of_from_mesh_reaches_a_stage():
    # from_mesh hands its arguments on by name: one that no stage takes would be silently ignored
    import inspect

    def names(function):
        return set(inspect.signature(function).parameters)

    handled_by_from_mesh = {"cls", "mesh", "progress", "parallel", "blas_threads"}
    taken = names(ingredients) | names(ModalMuscle.__init__) | handled_by_from_mesh
    assert names(ModalMuscle.from_mesh.__func__) - taken == set()
