"""Rotation clusters: placed where the subspace's modes rotate the elements differently (issue 20)."""

import numpy as np
import pytest
from test_any_mesh import TWO_PARTS

import skfem_modal as sm
from skfem_modal.clusters import rotation_clusters
from skfem_modal.mesh import connected_parts
from skfem_modal.scene import Scene, SceneError
from skfem_modal.sim import ModalMuscle
from skfem_modal.subspace import mass_orthonormalize, skinning_eigenmodes


def subspace(mesh, weights=4):
    _, _, B = skinning_eigenmodes(mesh, weights)
    return mass_orthonormalize(B, sm.mass_matrix(mesh))


def test_labels_are_complete_and_reproducible():
    mesh = sm.caterpillar(nx=20, ny=10)
    B, mass = subspace(mesh), np.ones(mesh.p.size)
    labels = rotation_clusters(mesh, B, 12, mass=mass, stiffness=1.0, seed=0)
    assert labels.shape == (mesh.t.shape[1],) and sorted(np.unique(labels).tolist()) == list(range(12))
    np.testing.assert_array_equal(labels, rotation_clusters(mesh, B, 12, mass=mass, stiffness=1.0, seed=0))
    assert not np.array_equal(labels, rotation_clusters(mesh, B, 12, mass=mass, stiffness=1.0, seed=3))
    # a uniform stiffness or density scale changes nothing (the modes and the k-means are scale-free)
    np.testing.assert_array_equal(labels, rotation_clusters(mesh, B, 12, mass=7 * mass, stiffness=1e5, seed=0))
    every = rotation_clusters(mesh, B, mesh.t.shape[1], mass=mass, stiffness=1.0)
    np.testing.assert_array_equal(every, np.arange(mesh.t.shape[1]))
    with pytest.raises(ValueError, match=r"k \(the number of clusters\) must be in 1\.\."):
        rotation_clusters(mesh, B, 0, mass=mass, stiffness=1.0)
    with pytest.raises(ValueError, match="B must be finite with shape"):
        rotation_clusters(mesh, B[:-2], 4, mass=mass, stiffness=1.0)
    with pytest.raises(ValueError, match="stiffness must be positive"):
        rotation_clusters(mesh, B, 4, mass=mass, stiffness=-1.0)
    with pytest.raises(ValueError, match=r"mass must be positive and finite with shape \(326,\)"):
        rotation_clusters(mesh, B, 4, mass=mass[:-1], stiffness=1.0)


@pytest.mark.parametrize("name", TWO_PARTS)
def test_no_rotation_cluster_spans_two_bodies(name):
    mesh = TWO_PARTS[name]()
    labels = rotation_clusters(mesh, subspace(mesh, 6), 9, mass=np.ones(mesh.p.size), stiffness=1.0)
    element_part = connected_parts(mesh)[mesh.t[0]]
    assert sorted(np.unique(labels).tolist()) == list(range(9))
    for c in range(9):
        assert np.unique(element_part[labels == c]).size == 1


@pytest.mark.parametrize("dim, counts", [(2, (4, 16)), (3, (8,))], ids=["2D", "3D"])
def test_rotation_clusters_buy_more_accuracy_per_cluster(dim, counts):
    # Against the same subspace with a rotation per element (what clusters
    # approximate), converged steps. Measured (2D, 4 and 16 clusters): 19 % and
    # 3.5 % off with clusters of the weights, 7.7 % and 2.2 % with rotation
    # clusters; 3D, 8 clusters: 11.7 % and 7.5 %.
    mesh = sm.caterpillar(nx=30, ny=12) if dim == 2 else sm.creature(cell=0.3)
    kw = dict(n_muscles=2, n_weights=4, mu=1e5, rho=1e3, h=0.02 if dim == 2 else 0.01)
    base = sm.ModalMuscle.from_mesh(mesh, n_clusters=4, **kw)

    def trajectory(labels):
        sim = ModalMuscle(mesh, base.B, base.D, labels, mu=1e5, gamma=1e5, rho=1e3, h=base.h, tol=0.0, rtol=1e-9,
                          max_iter=500, warm_start=True)  # fmt: skip
        z, z_dot, _ = sim.rest_state()
        states = []
        for i in range(50):
            a = 0.8 * sim.ceilings * np.sin(2 * np.pi * (i * sim.h / np.array([0.5, 0.7]) + [0.0, 0.3]))
            z, z_dot = sim.step(z, z_dot, a, velocity=True)
            states.append(z)
        return np.array(states)

    truth = trajectory(np.arange(mesh.t.shape[1]))
    error = lambda labels: np.linalg.norm(trajectory(labels) - truth) / np.linalg.norm(truth - truth[0])  # noqa: E731
    for k in counts:
        by_weights = sm.ModalMuscle.from_mesh(mesh, n_clusters=k, **kw)
        by_rotations = sm.ModalMuscle.from_mesh(mesh, n_clusters=k, cluster_by="rotations", **kw)
        np.testing.assert_array_equal(by_rotations.B, base.B)
        assert error(by_rotations.labels) < 0.7 * error(by_weights.labels), k


def test_scene_key_cluster_by():
    scene = Scene.from_dict({"mesh": {"shape": "caterpillar", "params": {"nx": 16, "ny": 8}},
                             "subspace": {"clusters": 6, "cluster_by": "rotations"}, "time": {"steps": 2}})  # fmt: skip
    sim = scene.build()
    expected = rotation_clusters(sim.mesh, sim.B, 6, mass=sim.mass, stiffness=scene.material()["mu"])
    np.testing.assert_array_equal(sim.labels, expected)
    with pytest.raises(SceneError, match="subspace.cluster_by.*'weights' or 'rotations'"):
        Scene.from_dict({"subspace": {"cluster_by": "modes"}})
    with pytest.raises(ValueError, match="cluster_by must be one of 'weights', 'rotations', got 'modes'"):
        sm.ModalMuscle.from_mesh(sm.caterpillar(nx=8, ny=4), cluster_by="modes")


def test_weights_that_cannot_tell_a_parts_elements_apart_split_it_by_position():
    # two parts, two skinning weights: each weight is constant on a part, so k-means++ on them divided by
    # zero (a RuntimeWarning) and gave each part a cluster of 1 element and one of all the rest
    import warnings

    from skfem_modal.clusters import spectral_clusters

    one = sm.caterpillar(nx=16, ny=8)
    n = one.p.shape[1]
    two = sm.make_mesh(np.hstack([one.p, one.p + [[3.0], [0.0]]]).T, np.hstack([one.t, one.t + n]).T)
    _, weights, _ = skinning_eigenmodes(two, 2)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        labels = spectral_clusters(two, weights, 4)
    sizes = np.bincount(labels)
    assert sizes.size == 4 and sizes.min() > 0.2 * one.t.shape[1]  # halves of each part, not 1 and the rest
    assert np.unique(labels[: one.t.shape[1]]).size == 2  # and no cluster spans the two parts


def test_a_small_part_gets_its_share_of_the_clusters_by_volume():
    """By element count, a copy a fiftieth the size, as finely meshed, took half of them (an audit: the body's
    error then that of half its clusters, 4.4e-3 against 9.7e-4)."""
    from skfem_modal.clusters import spectral_clusters

    one = sm.caterpillar(nx=16, ny=8)
    n, nT = one.p.shape[1], one.t.shape[1]
    small = one.p * 0.02 + [[3.0], [0.0]]
    two = sm.make_mesh(np.hstack([one.p, small]).T, np.hstack([one.t, one.t + n]).T)
    _, weights, B = skinning_eigenmodes(two, 4)
    for labels in (
        spectral_clusters(two, weights, 20),
        rotation_clusters(two, B, 20, mass=np.ones(two.p.size), stiffness=1.0),
    ):
        assert np.unique(labels[:nT]).size == 19 and np.unique(labels[nT:]).size == 1
    # equal parts share them equally, whatever their element counts
    coarse = sm.caterpillar(nx=8, ny=4)
    same = sm.make_mesh(np.hstack([one.p, coarse.p + [[3.0], [0.0]]]).T, np.hstack([one.t, coarse.t + n]).T)
    _, weights, _ = skinning_eigenmodes(same, 4)
    labels = spectral_clusters(same, weights, 20)
    assert np.unique(labels[:nT]).size == 10 and np.unique(labels[nT:]).size == 10
