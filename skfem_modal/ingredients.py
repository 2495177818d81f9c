"""From a mesh to a simulator's ingredients, the pipeline behind :meth:`~skfem_modal.sim.ModalMuscle.from_mesh`.

modal analysis (the muscles, in a second thread when given one) -> skinning
subspace -> rotation clusters -> contact vertices. Each stage is a function
of its own; :func:`ingredients` runs them in order, timing each.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

from .clusters import CLUSTER_BY, cluster_count_problem, rotation_clusters, seed_problem, spectral_clusters
from .contact import DEFAULT_CONTACTS
from .fem import _lumped_p1, _mass, _positive, scalar_basis
from .mesh import connected_parts, sample_boundary
from .modal import muscle_count_problem, muscle_modes
from .modal import muscle_signs as checked_signs
from .subspace import mass_orthonormalize, skinning_eigenmodes, weight_count_problem
from .values import is_whole

__all__ = ["Ingredients", "ingredients", "skinning_subspace", "element_clusters", "count_problems"]


def timed(timings: dict, stage: str, make):
    """``make()``, its wall time added to ``timings[stage]``.

    Parameters
    ----------
    timings : dict
        Seconds by stage name; changed in place.
    stage : str
        The stage's name: its seconds are added to those already there (0 if none).
    make : callable
        Called with no arguments.

    Returns
    -------
    made : object
        What ``make()`` returned.
    """
    clock = time.perf_counter()
    made = make()
    timings[stage] = timings.get(stage, 0.0) + time.perf_counter() - clock
    return made


def skinning_subspace(mesh, n_weights: int, cluster_weights: int | None = None, timings: dict | None = None):
    """The skinning-eigenmode subspace, mass-orthonormalised, and its weights.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
        With ``n`` vertices in ``dim`` dimensions.
    n_weights : int
        Skinning weights spanning the subspace.
    cluster_weights : int, optional
        Weights to compute for clustering (default ``n_weights``); more than
        ``n_weights`` are computed but not spanned.
    timings : dict, optional
        Gets the seconds of the ``skinning_eigenmodes`` and ``orthonormalize`` stages.

    Returns
    -------
    weights : ndarray, shape (n, max(n_weights, cluster_weights))
    B : ndarray, shape (n * dim, n_weights * (dim + 1) * dim)
        Mass-orthonormal basis: positions are ``B @ z``.
    """
    timings = {} if timings is None else timings
    dim = mesh.p.shape[0]
    k = max(n_weights, cluster_weights or n_weights)
    _, weights, B = timed(timings, "skinning_eigenmodes", lambda: skinning_eigenmodes(mesh, k))
    if k > n_weights:
        B = B[:, : n_weights * (dim + 1) * dim]
    orthonormal = lambda: mass_orthonormalize(B, _mass(mesh, 1.0, True, "P1", True), overwrite=True)
    B = timed(timings, "orthonormalize", orthonormal)
    return weights, B


def element_clusters(
    mesh, B, weights, n_clusters: int, *, n_active_clusters=1, cluster_by="weights", mu=1e5, rho=1e3, seed=0
):
    """Passive and active rotation clusters of the elements.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
        With ``nT`` elements.
    B : ndarray, shape (n * dim, r)
        The subspace (what ``cluster_by="rotations"`` clusters by).
    weights : ndarray, shape (n, k)
        Skinning weights (what ``cluster_by="weights"`` and the active clusters cluster by).
    n_clusters : int
        Passive clusters.
    n_active_clusters : int
        Muscle clusters, raised to one per connected part of the mesh (separate
        bodies never share a muscle rotation).
    cluster_by : {"weights", "rotations"}
        Spectral clusters of the weights, or
        :func:`~skfem_modal.clusters.rotation_clusters` (mass density ``rho``,
        stiffness ``mu``).
    mu, rho : float or ndarray, shape (nT,)
    seed : int

    Returns
    -------
    labels : ndarray of int, shape (nT,)
        Passive cluster of each element.
    active_labels : ndarray of int, shape (nT,), or None
        Muscle cluster of each element; None for one cluster.
    """
    if cluster_by == "rotations":
        dim, nT = mesh.p.shape[0], mesh.t.shape[1]
        mass = np.repeat(_lumped_p1(mesh, _positive(rho, nT, "rho")), dim)
        labels = rotation_clusters(mesh, B, n_clusters, mass=mass, stiffness=mu, seed=seed)
    else:
        labels = spectral_clusters(mesh, weights, n_clusters, seed=seed)
    return labels, active_clusters(mesh, weights, n_active_clusters, seed)


def active_clusters(mesh, weights, n_active_clusters: int = 1, seed: int = 0):
    """The muscle clusters of the elements (shape (nT,)), or None for one: at least one per connected part.

    Separate bodies never share a muscle rotation.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
        With ``n`` vertices and ``nT`` elements.
    weights : ndarray, shape (n, k)
        The skinning weights the clusters are spectral clusters of (:func:`element_clusters`' ``weights``).
    n_active_clusters : int
        Muscle clusters asked for, raised to the mesh's number of connected parts.
    seed : int
        Seed of the spectral clustering.

    Returns
    -------
    active_labels : ndarray of int, shape (nT,), or None
        Muscle cluster of each element; None for one cluster.
    """
    n_active = max(n_active_clusters, int(connected_parts(mesh).max()) + 1)
    return spectral_clusters(mesh, weights, n_active, seed=seed) if n_active > 1 else None


def count_problems(
    mesh, *, n_muscles, pinned, n_weights, cluster_weights, n_clusters, n_active_clusters, seed, contact_candidates
) -> list[tuple[str, str]]:
    """The counts this mesh cannot take, before any work: the one rule :func:`ingredients` and scenes share.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    n_muscles, pinned, n_weights, cluster_weights, n_clusters, n_active_clusters, seed, contact_candidates :
        As for :meth:`~skfem_modal.sim.ModalMuscle.from_mesh` (None: not given).

    Returns
    -------
    problems : list of (str, str)
        The argument's name and what is wrong, a clause after its value
        (``f"{name}: {value} {clause}"``), e.g. ``("n_clusters", "must be in 1..100 (the number of elements)")``.
    """
    n_vertices, n_elements = mesh.p.shape[1], mesh.t.shape[1]
    n_parts = int(connected_parts(mesh).max()) + 1
    counts = dict(n_muscles=n_muscles, n_weights=n_weights, cluster_weights=cluster_weights, n_clusters=n_clusters,
                  n_active_clusters=n_active_clusters)  # fmt: skip
    problems = [
        (name, f"(a {type(value).__name__}) must be an integer")
        for name, value in counts.items()
        if value is not None and (not is_whole(value))
    ]
    if problems:  # the rules below compare numbers
        return problems
    if n_muscles:
        problem = muscle_count_problem(mesh, n_muscles, pinned)
        if problem:
            problems.append(("n_muscles", problem))
    checks = (
        ("n_weights", n_weights, lambda k: weight_count_problem(n_vertices, n_parts, k)),
        ("cluster_weights", cluster_weights, lambda k: weight_count_problem(n_vertices, n_parts, k)),
        ("n_clusters", n_clusters, lambda k: cluster_count_problem(n_elements, n_parts, k)),
        # the active clusters are raised to one per part, so only the elements bound them
        ("n_active_clusters", n_active_clusters, lambda k: cluster_count_problem(n_elements, 1, k)),
        ("seed", seed, seed_problem),
    )
    for name, value, rule in checks:
        problem = None if value is None else rule(value)
        if problem:
            problems.append((name, f"must be {problem}"))
    if contact_candidates is not None:
        indices = np.asarray(contact_candidates).ravel()
        nothing = "select no boundary vertex of the mesh: nothing could touch the ground"
        if not indices.size:  # of no dtype in particular
            problems.append(("contact_candidates", nothing))
            return problems
        outside = indices[(indices < 0) | (indices >= n_vertices)] if np.issubdtype(indices.dtype, np.integer) else None
        if outside is None or outside.size:
            shown = "not integers" if outside is None else f"got {', '.join(map(str, outside[:5]))}"
            problems.append(("contact_candidates", f"must be vertex indices 0..{n_vertices - 1} ({shown})"))
            return problems
        try:
            sample_boundary(mesh, None, contact_candidates)
        except ValueError:
            problems.append(("contact_candidates", nothing))
    return problems


class Ingredients(NamedTuple):
    """What :func:`ingredients` makes: the simulator's inputs and the stages' timings.

    Attributes
    ----------
    B : ndarray, shape (n * dim, r)
    muscles : callable
        ``muscles()`` gives the muscle modes, shape (n * dim, m), waiting for
        the modal analysis if it still runs (its seconds go to ``timings``).
    labels, active_labels : ndarray of int, shape (nT,)
        ``active_labels`` None for one muscle cluster.
    contact_vertices : ndarray of int, shape (p,), or None
    weights : ndarray, shape (n, n_weights)
    timings : dict
    """

    B: np.ndarray
    muscles: object
    labels: np.ndarray
    active_labels: np.ndarray | None
    contact_vertices: np.ndarray | None
    weights: np.ndarray
    timings: dict


def ingredients(
    mesh,
    pool=None,
    say=None,
    *,
    n_muscles,
    muscle_signs,
    n_weights,
    cluster_weights,
    n_clusters,
    n_active_clusters,
    cluster_by,
    mu,
    lam,
    rho,
    pinned,
    seed,
    ground,
    n_contacts,
    contact_candidates,
    contact_model,
):
    """Every ingredient of a simulator from a mesh: :meth:`~skfem_modal.sim.ModalMuscle.from_mesh`'s stages.

    The keyword arguments, every one required, are those of :meth:`~skfem_modal.sim.ModalMuscle.from_mesh`
    (which passes them on by name, its defaults filled in), of the types it takes.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
        Already checked (inside :func:`~skfem_modal.mesh.validated`).
    pool : concurrent.futures.Executor, optional
        Runs the modal analysis beside the other stages; None: first, here.
        It must stay open until ``muscles()`` was called.
    say : callable, optional
        ``say(stage)`` before each stage.
    n_muscles, muscle_signs, pinned :
        The muscles: the modal analysis's lowest modes without the rigid ones (of the body clamped at the
        ``pinned`` vertices, None: none), each multiplied by its sign (``muscle_signs`` None: as the modes
        come).
    mu, lam, rho :
        The modal analysis's material (``lam`` None: ``mu``); ``mu`` and ``rho`` also weigh the clusters
        by rotations.
    n_weights, cluster_weights :
        The subspace's skinning weights, and those computed for clustering (:func:`skinning_subspace`).
    n_clusters, n_active_clusters, cluster_by, seed :
        The passive and muscle rotation clusters (:func:`element_clusters`).
    ground, n_contacts, contact_candidates, contact_model :
        The contact vertices, sampled only with a ``ground`` (its height not used here): ``n_contacts``
        boundary vertices (``"all"``: every one; None: the ``contact_model``'s default,
        :data:`~skfem_modal.contact.DEFAULT_CONTACTS`) among ``contact_candidates`` (None: every boundary
        vertex).

    Returns
    -------
    Ingredients

    Raises
    ------
    ValueError
        An unknown ``cluster_by``, ``muscle_signs`` that are not ``n_muscles`` values of +1 or -1, or
        counts this mesh cannot take (:func:`count_problems`, every one named).
    """
    if cluster_by not in CLUSTER_BY:
        raise ValueError(f"cluster_by must be one of {', '.join(map(repr, CLUSTER_BY))}, got {cluster_by!r}")
    signs = checked_signs(muscle_signs, n_muscles)
    counts = dict(n_weights=n_weights, cluster_weights=cluster_weights, n_clusters=n_clusters)
    problems = count_problems(
        mesh,
        n_muscles=n_muscles,
        pinned=pinned,
        **counts,
        n_active_clusters=n_active_clusters,
        seed=seed,
        contact_candidates=contact_candidates if ground is not None else None,
    )
    if problems:
        values = {**counts, "n_muscles": n_muscles, "n_active_clusters": n_active_clusters, "seed": seed}
        values["contact_candidates"] = f"{np.size(contact_candidates)} vertices"
        said = [f"{name}: {values[name]} {clause}" for name, clause in problems]
        raise ValueError("; ".join(said))
    say = say or (lambda stage: None)
    timings = {}
    # scikit-fem caches mesh data on first use; build it here, before the two threads read it
    scalar_basis(mesh)
    if n_contacts is None:
        n_contacts = DEFAULT_CONTACTS[contact_model]
    count = None if isinstance(n_contacts, str) else n_contacts  # "all": sample_boundary's None
    contacts = sample_boundary(mesh, count, contact_candidates) if ground is not None else None

    def modes():
        clock = time.perf_counter()
        found = muscle_modes(mesh, n_muscles, mu=mu, lam=lam, rho=rho, pinned=pinned)
        return found, time.perf_counter() - clock

    # the modal analysis (one sparse factorisation and back-solves, in compiled
    # code that releases the GIL) runs first, beside the rest in a second
    # thread when there is one: little else is in memory yet
    say("modal analysis" + (" (in a second thread)" if pool is not None else ""))
    if pool is not None:
        modal = pool.submit(modes).result
    else:
        found = modes()
        modal = lambda: found
    say("skinning eigenmodes")
    weights, B = skinning_subspace(mesh, n_weights, cluster_weights, timings)
    say("clusters")
    cw = weights[:, : cluster_weights or n_weights]
    options = dict(n_active_clusters=n_active_clusters, cluster_by=cluster_by, mu=mu, rho=rho, seed=seed)
    labels, active = timed(timings, "clusters", lambda: element_clusters(mesh, B, cw, n_clusters, **options))

    def muscles():
        D, timings["modal_analysis"] = modal()
        return D if signs is None else D * signs

    return Ingredients(B, muscles, labels, active, contacts, weights[:, :n_weights], timings)
