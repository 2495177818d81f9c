"""Spectral clustering of elements: groups that share one rotation in the simulator.

Elements with similar skinning weights move alike, so k-means on the weights
(averaged onto elements) gives compact clusters that deform coherently. Each
cluster then gets one best-fit rotation per local step instead of one per
element.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.cluster.vq import kmeans2

from .mesh import check_mesh, connected_parts

__all__ = ["average_onto_elements", "spectral_clusters"]


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
    nT = mesh.t.shape[1]
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)):
        raise TypeError(f"k (the number of clusters) must be an integer, got {type(k).__name__}")
    if not 1 <= k <= nT:
        raise ValueError(f"k (the number of clusters) must be in 1..{nT} (the number of elements), got {k}")
    W = np.asarray(weights, dtype=np.float64)
    if W.ndim == 1:
        W = W[:, None]
    if W.shape[0] != mesh.p.shape[1] or not np.all(np.isfinite(W)):
        raise ValueError(f"weights must be finite with shape ({mesh.p.shape[1]}, m), got {W.shape}")
    points = average_onto_elements(mesh, W)
    parts = connected_parts(mesh)[mesh.t[0]]
    n_parts = int(parts.max()) + 1
    if n_parts == 1:
        return _kmeans(points, k, seed)
    # a rotation cluster never spans two separate parts: each part gets its
    # share of the clusters (by element count, at least one) and its own k-means
    sizes = np.bincount(parts, minlength=n_parts)
    if k < n_parts:
        raise ValueError(
            f"k (the number of clusters) must be at least the mesh's {n_parts} separate parts "
            f"(a cluster shares one rotation, so it cannot span two parts), got {k}"
        )
    shares = _shares(sizes, k)
    labels = np.empty(nT, dtype=np.int64)
    offset = 0
    for part in range(n_parts):
        inside = np.nonzero(parts == part)[0]
        labels[inside] = offset + _kmeans(points[inside], int(shares[part]), seed)
        offset += int(shares[part])
    return labels


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


def _shares(sizes: np.ndarray, k: int) -> np.ndarray:
    """Split ``k`` clusters over parts of ``sizes`` elements: proportional, at least 1, at most the size.

    Largest remainders first, ties to the lower part index, so the split is deterministic.
    """
    ideal = k * sizes / sizes.sum()
    shares = np.clip(np.floor(ideal).astype(np.int64), 1, sizes)
    while shares.sum() < k:
        room = np.where(shares < sizes, ideal - shares, -np.inf)
        shares[int(np.argmax(room))] += 1
    while shares.sum() > k:
        excess = np.where(shares > 1, shares - ideal, -np.inf)
        shares[int(np.argmax(excess))] -= 1
    return shares
