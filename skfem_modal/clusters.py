"""Clusters of elements: groups that share one rotation in the simulator.

Each cluster gets one best-fit rotation per local step instead of one per
element. Two ways to choose them:

* :func:`spectral_clusters`: elements with similar skinning weights move
  alike, so k-means on the weights (averaged onto elements) gives compact
  clusters that deform coherently;
* :func:`rotation_clusters`: a shared rotation costs energy where the
  elements' own rotations differ, so k-means on how the subspace's lowest
  vibration modes rotate each element (weighted by the element's stiffness)
  puts more clusters where rotation varies most.
"""

from __future__ import annotations

import warnings

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sps
from scipy.cluster.vq import kmeans2

from .mesh import _signed_measures, check_mesh, connected_parts
from .values import is_whole

__all__ = ["average_onto_elements", "spectral_clusters", "rotation_clusters", "CLUSTER_BY"]

#: What a simulator's clusters can be made from (``cluster_by``).
CLUSTER_BY = ("weights", "rotations")


def average_onto_elements(mesh, values) -> np.ndarray:
    """Plain mean of per-vertex values over each element's vertices.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    values : ndarray, shape (n,) or (n, k)

    Returns
    -------
    element_values : ndarray, shape (nT,) or (nT, k)
    """
    values = np.asarray(values, dtype=np.float64)
    if values.shape[0] != mesh.p.shape[1]:
        raise ValueError(f"values need one row per vertex ({mesh.p.shape[1]}), got {values.shape[0]}")
    out = values[mesh.t[0]].copy()
    for corner in mesh.t[1:]:
        out += values[corner]
    return out / mesh.t.shape[0]


def _fill_empty(points: np.ndarray, labels: np.ndarray, k: int) -> np.ndarray:
    """Give every empty cluster one element, deterministically.

    The largest cluster gives up its element farthest from its centroid (the
    first such on ties), until no cluster is empty.
    """
    labels = labels.copy()
    while True:
        counts = np.bincount(labels, minlength=k)
        empty = np.nonzero(counts == 0)[0]
        if empty.size == 0:
            return labels
        donor = int(np.argmax(counts))
        members = np.nonzero(labels == donor)[0]
        centre = points[members].mean(axis=0)
        far = members[np.argmax(((points[members] - centre) ** 2).sum(axis=1))]
        labels[far] = empty[0]


def spectral_clusters(mesh, weights, k: int, seed: int = 0) -> np.ndarray:
    """Cluster the elements by their skinning weights.

    The weights are averaged onto elements (plain mean of the vertices) and
    clustered with scipy's ``kmeans2(..., k, seed=seed, minit='++')``; any
    cluster k-means leaves empty receives the element farthest from the centre
    of the largest cluster. ``k`` equal to the number of elements gives one
    cluster per element.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    weights : ndarray, shape (n, m)
        Per-vertex weights, e.g. from :func:`~skfem_modal.skinning_eigenmodes`.
    k : int
        Number of clusters, ``1 <= k <= nT``.
    seed : int
        Seed of the k-means++ initialisation; the same seed gives the same labels.

    Returns
    -------
    labels : ndarray of int, shape (nT,)
        Cluster of each element, every value in ``0..k-1`` used.
    """
    check_mesh(mesh)
    _check_count(k, mesh.t.shape[1], seed)
    W = np.asarray(weights, dtype=np.float64)
    if W.ndim == 1:
        W = W[:, None]
    if W.shape[0] != mesh.p.shape[1] or not np.all(np.isfinite(W)):
        raise ValueError(f"weights must be finite with shape ({mesh.p.shape[1]}, m), got {W.shape}")
    points = average_onto_elements(mesh, W)

    def cluster(inside, count):
        # weights that tell fewer of a part's elements apart than it has clusters (a part's own weights are
        # constant on it when there are as many as parts: scipy's k-means++ then divided by zero and left
        # one element in a cluster) split it by position instead
        if _distinct(points[inside]) < count:
            return _kmeans(mesh.p[:, mesh.t[:, inside]].mean(axis=1).T, count, seed)
        return _kmeans(points[inside], count, seed)

    return _per_part(mesh, np.arange(mesh.t.shape[1]), k, cluster)


def rotation_clusters(mesh, B, k: int, *, mass, stiffness, modes: int = 8, seed: int = 0) -> np.ndarray:
    """Cluster the elements by how the subspace's lowest vibration modes rotate them.

    The subspace's modes are those of the as-rigid-as-possible energy
    linearised at rest (``sum_e w_e |sym grad u|^2``, rigid motions free)
    against the mass: ``(B^T K B) phi = lambda (B^T M B) phi``. Mode ``j``
    rotates element ``e`` by the skew part ``theta_e(phi_j)`` of its
    gradient; at equal energy its amplitude goes as ``1 / sqrt(lambda_j)``.
    Two elements sharing a rotation cost ``w_e |theta_e - theta_c|^2`` of
    energy, so the clusters are a k-means of the points
    ``theta_e(phi_j) / sqrt(lambda_j)``, ``j = 1..modes`` (the rigid modes
    left out), each element weighted by ``w_e``: where rotation varies most,
    clusters are smallest. A cluster never spans two separate parts of the
    mesh (:func:`spectral_clusters` splits them the same way).

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    B : ndarray, shape (n * dim, r)
        The subspace (interleaved rows).
    k : int
        Number of clusters, ``1 <= k <= nT``.
    mass : ndarray, shape (n * dim,)
        Lumped mass per DOF.
    stiffness : float or ndarray of shape (nT,)
        ``mu`` per element (the weights are ``mu * volume``).
    modes : int
        Modes after the rigid ones (fewer if the subspace has fewer).
    seed : int
        Seed of the weighted k-means++ initialisation.

    Returns
    -------
    labels : ndarray of int, shape (nT,)
        Cluster of each element, every value in ``0..k-1`` used.
    """
    from .fem import _jacobian, _positive

    check_mesh(mesh)
    dim, n = mesh.p.shape
    nT = mesh.t.shape[1]
    _check_count(k, nT, seed)
    B = np.asarray(B, dtype=np.float64)
    if B.ndim != 2 or B.shape[0] != n * dim or not np.all(np.isfinite(B)):
        raise ValueError(f"B must be finite with shape ({n * dim}, r) for this mesh, got {B.shape}")
    mass = np.asarray(mass, dtype=np.float64)
    if mass.shape != (n * dim,) or not np.all(mass > 0) or not np.all(np.isfinite(mass)):
        raise ValueError(f"mass must be positive and finite with shape ({n * dim},), got shape {mass.shape}")
    weights = _positive(stiffness, nT, "stiffness") * np.abs(_signed_measures(mesh.p, mesh.t))
    J = _jacobian(mesh, "P1")
    dd = dim * dim
    # the projector onto the symmetric part of a row-major F, per element
    sym = 0.5 * (np.eye(dd) + np.eye(dd)[[dim * (i % dim) + i // dim for i in range(dd)]])
    K_B = J.T @ (sps.kron(sps.diags(weights), sps.csr_matrix(sym)) @ (J @ B))
    K = B.T @ K_B
    M = B.T @ (mass[:, None] * B)
    lam, phi = sla.eigh(0.5 * (K + K.T), M)
    deforming = np.nonzero(lam > 1e-10 * max(lam[-1], 0.0))[0][:modes]
    if deforming.size == 0:
        # nothing in the subspace deforms (rigid motions only): compact clusters around element centres
        centres = mesh.p[:, mesh.t].mean(axis=1).T
        return _per_part(mesh, centres, k, lambda points, count: _kmeans(points, count, seed))
    grads = (J @ (B @ (phi[:, deforming] / np.sqrt(lam[deforming])))).reshape(nT, dim, dim, -1)
    # the infinitesimal rotation: the skew part's entries below the diagonal (2D) or its axial vector (3D)
    rows, cols = ([1], [0]) if dim == 2 else ([2, 0, 1], [1, 2, 0])
    points = 0.5 * (grads - grads.transpose(0, 2, 1, 3))[:, rows, cols].reshape(nT, -1)

    def cluster(inside, count):
        return _weighted_kmeans(points[inside], weights[inside], count, seed)

    return _per_part(mesh, np.arange(nT), k, cluster)


def cluster_count_problem(n_elements: int, n_parts: int, k: int) -> str | None:
    """What ``k`` rotation clusters must be on a mesh (a phrase after "must be"), or None when they fit.

    At most one per element, and at least one per connected part (a cluster
    shares one rotation, so it cannot span two parts): the rule of
    :func:`spectral_clusters` and :func:`rotation_clusters` and a scene's
    ``subspace.clusters`` and ``subspace.active_clusters`` checks.

    Parameters
    ----------
    n_elements : int
        The mesh's number of elements.
    n_parts : int
        Its number of connected parts (:func:`~skfem_modal.mesh.connected_parts`); 1 where clusters may
        span parts (the active clusters, raised to one per part later).
    k : int
        The number of clusters asked for, a whole number (checked by the caller).

    Returns
    -------
    problem : str or None

    Examples
    --------
    >>> cluster_count_problem(100, 1, 20) is None
    True
    >>> cluster_count_problem(100, 1, 1000)
    'in 1..100 (the number of elements)'
    """
    if not 1 <= k <= n_elements:
        return f"in 1..{n_elements} (the number of elements)"
    if k < n_parts:
        return (
            f"at least the mesh's {n_parts} separate parts (a cluster shares one rotation, so it cannot span two parts)"
        )
    return None


def seed_problem(seed) -> str | None:
    """What a k-means ``seed`` must be (a phrase after "must be"), or None: scipy's ``kmeans2`` takes 0..2**32 - 1.

    ``seed``: any value; a Python or numpy integer (not a bool) in that range fits.
    """
    if not is_whole(seed) or not 0 <= seed < 2**32:
        return "an integer in 0..4294967295 (2**32 - 1)"
    return None


def _check_count(k, nT, seed) -> None:
    problem = seed_problem(seed)
    if problem:
        raise ValueError(f"seed must be {problem}, got {seed!r}")
    if not is_whole(k):
        raise TypeError(f"k (the number of clusters) must be an integer, got {type(k).__name__}")
    if not 1 <= k <= nT:
        raise ValueError(f"k (the number of clusters) must be {cluster_count_problem(nT, 1, k)}, got {k}")


def _per_part(mesh, items, k: int, cluster) -> np.ndarray:
    """``cluster(items, count)`` on each connected part of the mesh, with its share of the ``k`` clusters."""
    nT = mesh.t.shape[1]
    parts = connected_parts(mesh)[mesh.t[0]]
    n_parts = int(parts.max()) + 1
    if n_parts == 1:
        return cluster(items, k)
    # a rotation cluster never spans two separate parts: each part gets its share of the clusters (by its
    # volume, at least one, at most its element count) and its own k-means. By element count, a copy of a
    # body a fiftieth its size, as finely meshed, took half the body's clusters (an audit: the body's error
    # that of half its clusters)
    problem = cluster_count_problem(nT, n_parts, k)
    if problem:
        raise ValueError(f"k (the number of clusters) must be {problem}, got {k}")
    volumes = np.bincount(parts, weights=np.abs(_signed_measures(mesh.p, mesh.t)), minlength=n_parts)
    shares = _shares(volumes, np.bincount(parts, minlength=n_parts), k)
    labels = np.empty(nT, dtype=np.int64)
    offset = 0
    for part in range(n_parts):
        inside = np.nonzero(parts == part)[0]
        labels[inside] = offset + cluster(items[inside], int(shares[part]))
        offset += int(shares[part])
    return labels


def _weighted_kmeans(points: np.ndarray, weights: np.ndarray, k: int, seed: int, rounds: int = 100) -> np.ndarray:
    """Labels of a k-means of weighted points (weighted k-means++ start, Lloyd rounds); no cluster empty."""
    n = points.shape[0]
    if k == n:
        return np.arange(k, dtype=np.int64)
    if k == 1:
        return np.zeros(n, dtype=np.int64)
    rng = np.random.default_rng(seed)
    w = weights / weights.sum()
    centres = np.empty((k, points.shape[1]))
    centres[0] = points[rng.choice(n, p=w)]
    nearest = np.einsum("ij,ij->i", points - centres[0], points - centres[0])
    for j in range(1, k):
        odds = w * nearest
        total = odds.sum()
        pick = rng.choice(n, p=odds / total) if total > 0 else int(rng.integers(n))
        centres[j] = points[pick]
        nearest = np.minimum(nearest, np.einsum("ij,ij->i", points - centres[j], points - centres[j]))
    labels = None
    squares = np.einsum("ij,ij->i", points, points)
    for _ in range(rounds):
        distance = squares[:, None] - 2.0 * points @ centres.T + np.einsum("ij,ij->i", centres, centres)[None, :]
        new = distance.argmin(axis=1)
        if labels is not None and np.array_equal(new, labels):
            break
        labels = new
        mass = np.bincount(labels, weights=weights, minlength=k)
        sums = np.stack([np.bincount(labels, weights=weights * p, minlength=k) for p in points.T], axis=1)
        filled = mass > 0
        centres[filled] = sums[filled] / mass[filled, None]
    return _fill_empty(points, labels.astype(np.int64), k)


def _distinct(points: np.ndarray) -> int:
    """How many rows of ``points`` differ by more than round-off (a billionth of their largest entry)."""
    scale = np.abs(points).max(initial=0.0) or 1.0
    return np.unique(np.round(points / scale, 9), axis=0).shape[0]


def _kmeans(points: np.ndarray, k: int, seed: int) -> np.ndarray:
    """k-means++ labels of the rows of ``points`` (``1 <= k <= len(points)``), no cluster empty."""
    if k == points.shape[0]:
        return np.arange(k, dtype=np.int64)
    if k == 1:
        return np.zeros(points.shape[0], dtype=np.int64)
    with warnings.catch_warnings():
        # empty clusters are repaired below
        warnings.filterwarnings("ignore", message="One of the clusters is empty")
        _, labels = kmeans2(points, k, seed=seed, minit="++")
    return _fill_empty(points, labels.astype(np.int64), k)


def _shares(volumes: np.ndarray, caps: np.ndarray, k: int) -> np.ndarray:
    """Split ``k`` clusters over parts: in proportion to their ``volumes``, at least 1, at most ``caps`` (elements).

    Largest remainders first, ties to the lower part index, so the split is deterministic.
    """
    ideal = k * volumes / volumes.sum()
    shares = np.clip(np.floor(ideal).astype(np.int64), 1, caps)
    while shares.sum() < k:
        room = np.where(shares < caps, ideal - shares, -np.inf)
        shares[int(np.argmax(room))] += 1
    while shares.sum() > k:
        excess = np.where(shares > 1, shares - ideal, -np.inf)
        shares[int(np.argmax(excess))] -= 1
    return shares
