"""What accuracy costs in time: the reduced simulator against the full-space reference.

A reduced simulation trades accuracy for speed in several ways at once: the
subspace size (skinning weights), the rotation clusters (how many, and what
they are made from), the local/global iterations (a fixed count, or a
relative tolerance on the change or the energy; a warm start; accelerated
iterates), the mesh resolution. A
study runs the scene's full-space reference (:mod:`skfem_modal.reference`,
every DOF, one rotation per element, iterated to 1e-10) once per mesh, then
the reduced simulator over sweeps of those settings, each run a task on a
:class:`concurrent.futures.Executor` (a local process pool, or a
dask.distributed cluster), and reports error against milliseconds per step.

Error measures, all relative (dimensionless):

* ``trajectory_error``: ``sqrt(sum_t |u(t) - u_ref(t)|_M^2 / sum_t |u_ref(t)|_M^2)``
  with ``u`` the displacement from rest and ``|.|_M`` the mass norm;
* ``subspace_error``: the same for the best the subspace can do, the
  mass-orthogonal projection of the reference onto ``B``; and
  ``solver_error``, the distance from the reduced run to that projection
  (clusters and iterations), in the same units: floating, the first bounds
  what any solver in that subspace could reach, the second is what this one
  loses; on a ground or with pins the projection need not be a motion the
  subspace can make there (it may go through the ground), so neither is so;
* ``com_error``: largest distance between the two centres of mass, over the
  body's size (each body's own, for a mesh of several);
* ``worst_vertex_error``: largest distance of any vertex at any step, over the
  size of the body it is in.

A reference that does not move (its largest vertex displacement below
:data:`STILL` of its body's size) is refused: errors relative to its motion
would be round-off over round-off.

The modal part compares P1 and P2 natural frequencies of a clamped beam with
Euler-Bernoulli theory and with a refined P2 mesh, with their solve times.
"""

from __future__ import annotations

import copy
import csv
import inspect
import json
import logging
import os
import platform
import time
import warnings
from concurrent.futures import Executor, ProcessPoolExecutor

import numpy as np

from .export import written_whole
from .interrupts import QuietSpawnContext, exit_with_parent
from .mesh import connected_labels, part_sizes, shape_parameter_problems
from .outputs import clear_earlier_study, made_folder, remove_if_empty
from .sim import simulate
from .threads import limited_blas_threads
from .values import is_finite_real, is_whole

__all__ = [
    "PRESETS",
    "FLOATING_CATERPILLAR",
    "trajectory_errors",
    "resolution_scene",
    "run_reference",
    "run_reduced",
    "modal_convergence",
    "pareto_front",
    "recommend",
    "make_executor",
    "checked_executor",
    "WorkersLost",
    "lost_workers",
    "checked_workers",
    "dask_client",
    "run_study",
]

#: Sweeps, one setting at a time around the scene's own (its weights, clusters, iterations), and
#: the faster iterations: ``warm`` (iteration counts with a warm start), ``etol`` (with a warm
#: start), ``warm_clusters`` (cluster counts, by weights and by rotations, warm start and 20
#: iterations: near convergence, so the clusters' own accuracy shows), ``acceleration``
#: ((method, iterations), warm start), ``warm_grid`` ((weights, clusters, cluster_by, iterations), a
#: warm start, and for iterations None ``rtol`` 1e-4: a scale-free rule that takes about 10
#: iterations in 2D, 6 in 3D).
PRESETS = {
    "quick": dict(
        steps=100,
        weights=[3, 5, 8, 12],
        clusters=[5, 10, 20, 40],
        iterations=[2, 5, 10, 20],
        rtol=[1e-1, 1e-2, 1e-3],
        warm=[5, 10, 20],
        etol=[1e-3, 1e-5, 1e-7],
        warm_clusters=[10, 20, 40, 80],
        acceleration=[("anderson", 5), ("anderson", 10), ("newton", 3), ("newton", 5)],
        warm_grid=[
            (8, 20, "rotations", None),
            (8, 30, "rotations", 10),
            (8, 30, "rotations", None),
            (8, 40, "weights", 5),
            (8, 40, "weights", 10),
            (8, 40, "weights", None),
            (12, 40, "weights", None),
            (12, 80, "weights", None),
            (16, 80, "weights", 10),
            (16, 80, "weights", None),
            (16, 160, "weights", None),
        ],
        resolution=[0.5, 1.0],
        grid=[],
        modal=[(40, 1), (80, 2), (160, 4)],
        timing_rounds=2,
    ),
    "full": dict(
        steps=200,
        weights=[2, 3, 5, 8, 12, 16, 24],
        clusters=[1, 5, 10, 20, 40, 80, 160],
        iterations=[1, 2, 5, 10, 20, 50],
        rtol=[1e-1, 3e-2, 1e-2, 3e-3, 1e-3],
        warm=[2, 3, 5, 10, 20],
        etol=[1e-3, 1e-4, 1e-5, 1e-6, 1e-7],
        warm_clusters=[5, 10, 20, 40, 80, 160],
        acceleration=[("anderson", 5), ("anderson", 10), ("anderson", 20), ("newton", 2), ("newton", 3), ("newton", 5)],
        warm_grid=[(8, c, "rotations", None) for c in (20, 30, 40)]
        + [(8, 30, "rotations", 10), (8, 40, "weights", 5), (8, 40, "weights", 10), (16, 80, "weights", 10)]
        + [(w, c, "weights", None) for w in (8, 12, 16) for c in (40, 80, 160)],
        resolution=[0.5, 1.0, 1.5],
        grid=[(w, c) for w in (5, 8, 12, 16) for c in (10, 20, 40, 80)],
        modal=[(40, 1), (80, 2), (160, 4), (320, 8)],
        timing_rounds=5,
    ),
}

#: The default study scene: the tutorial's floating caterpillar (smooth motion, so
#: errors measure approximation, not the chaos of contact).
FLOATING_CATERPILLAR = {
    "name": "caterpillar floating",
    "mesh": {"shape": "caterpillar"},
    "material": {"mu": 1e5, "rho": 1e3},
    "subspace": {"weights": 8, "clusters": 20, "seed": 0},
    "muscles": {
        "count": 4,
        "gait": {"amplitude": [0.9, 0.6, 0.0, 0.0], "period": [1.0, 0.7, 1.0, 1.0], "phase": [0.0, 0.25, 0.0, 0.0]},
    },
    "time": {"step": 0.02, "steps": 180},
}


def trajectory_errors(x, x_ref, mass, rest, size, dim, B=None, parts=None) -> dict:
    """Error measures of a trajectory against the reference.

    Parameters
    ----------
    x, x_ref : ndarray, shape (T, n * dim)
        Positions over time (interleaved), same steps.
    mass : ndarray, shape (n * dim,)
        Lumped masses per DOF.
    rest : ndarray, shape (n * dim,)
    size : float or ndarray, shape (n,)
        Body size (largest extent) for the absolute measures; for a mesh of several bodies, each
        vertex's own body's (:func:`~skfem_modal.mesh.part_sizes`).
    dim : int
    B : ndarray, shape (n * dim, r), optional
        The subspace, for the best achievable (projection) error.
    parts : ndarray of int, shape (n,), optional
        Each vertex's body (:func:`~skfem_modal.mesh.connected_labels`): the centre of mass of each,
        over its own size (default: one body).

    Returns
    -------
    errors : dict
        ``trajectory_error``, ``com_error``, ``worst_vertex_error`` and, with
        ``B``, ``subspace_error`` and ``solver_error``.

    Examples
    --------
    >>> x = np.array([[0.0, 0.0], [1.0, 0.0]])
    >>> e = trajectory_errors(x * 1.1, x, np.ones(2), np.zeros(2), 1.0, 2)
    >>> round(e["trajectory_error"], 12), round(e["worst_vertex_error"], 12)
    (0.1, 0.1)
    """
    u_ref = x_ref - rest
    norm = np.sqrt(np.sum(mass * u_ref**2))
    norm = norm if norm > 0 else 1.0
    diff = x - x_ref
    out = {"trajectory_error": float(np.sqrt(np.sum(mass * diff**2)) / norm)}
    m_nodes = mass[::dim]
    sizes = np.broadcast_to(np.asarray(size, dtype=float), m_nodes.shape)
    parts = np.zeros(m_nodes.size, int) if parts is None else np.asarray(parts)

    def com(X, part):
        m = np.where(parts == part, m_nodes, 0.0)
        return (X.reshape(X.shape[0], -1, dim) * m[None, :, None]).sum(axis=1) / m.sum()

    # each body's centre and vertices over its own size: two bodies far apart are not one of their span
    out["com_error"] = max(
        float(np.linalg.norm(com(x, part) - com(x_ref, part), axis=1).max() / sizes[parts == part][0])
        for part in np.unique(parts)
    )
    out["worst_vertex_error"] = float((np.linalg.norm(diff.reshape(diff.shape[0], -1, dim), axis=2) / sizes).max())
    if B is not None:
        MB = mass[:, None] * B
        coef = np.linalg.solve(B.T @ MB, MB.T @ x_ref.T)
        proj = (B @ coef).T
        out["subspace_error"] = float(np.sqrt(np.sum(mass * (proj - x_ref) ** 2)) / norm)
        out["solver_error"] = float(np.sqrt(np.sum(mass * (x - proj) ** 2)) / norm)
    return out


def _shape_defaults(shape: str) -> dict:
    from .mesh import BUILTIN_SHAPES

    return {k: v.default for k, v in inspect.signature(BUILTIN_SHAPES[shape]).parameters.items()}


def resolution_scene(data: dict, factor: float) -> dict:
    """A copy of a scene dict whose built-in mesh is ``factor`` times finer (1: unchanged).

    Grid counts are scaled (the caterpillar's vertices per side, the beams'
    cells), the creature's cell size divided. Mesh files cannot be refined:
    ``ValueError``.

    Parameters
    ----------
    data : dict
        The scene (its TOML keys); not changed.
    factor : float
        Positive refinement factor (0.5: half as fine). Scaled counts are rounded, at least 2
        vertices a side for the caterpillar and 1 cell for the beams.

    Returns
    -------
    data : dict
        A deep copy, ``mesh.params`` holding the scaled parameters (the grid counts or ``cell``,
        and those the scene gave).

    Raises
    ------
    ValueError
        The scene's mesh is a file (and ``factor`` is not 1), ``factor`` is not a positive number, or
        the shape or a parameter is unknown or of the wrong type (named).
    """
    if not (is_finite_real(factor) and factor > 0.0):
        raise ValueError(f"a resolution factor must be a positive number (0.5: half as fine), got {factor!r}")
    data = copy.deepcopy(data)
    if factor == 1.0:
        return data
    mesh = data.setdefault("mesh", {})
    if mesh.get("file"):
        raise ValueError("a mesh from a file has no resolution to change; sweep resolutions with a built-in shape")
    shape = mesh.get("shape") or "caterpillar"
    # (an unknown shape or parameter named before any work: a typo's key was dropped, its value lost)
    problems = shape_parameter_problems(shape, mesh.get("params", {}))
    if problems:
        raise ValueError(f"shape {shape!r}: " + "; ".join(f"parameter {key}: {text}" for key, text in problems))
    params = {**_shape_defaults(shape), **mesh.get("params", {})}
    if shape == "caterpillar":
        for key in ("nx", "ny"):
            params[key] = max(2, int(round((params[key] - 1) * factor)) + 1)
    elif shape == "creature":
        params["cell"] = params["cell"] / factor
    else:
        for key in ("nx", "ny", "nz"):
            if key in params:
                params[key] = max(1, int(round(params[key] * factor)))
    keep = {k: v for k, v in params.items() if k in mesh.get("params", {}) or k in ("nx", "ny", "nz", "cell")}
    mesh["params"] = {k: v for k, v in keep.items() if k in _shape_defaults(shape)}
    return data


def _steps_scene(data: dict, steps: int) -> dict:
    data = copy.deepcopy(data)
    data.setdefault("time", {})
    data["time"].pop("duration", None)
    data["time"]["steps"] = steps
    return data


def run_reference(data: dict, base_dir: str | None, steps: int) -> dict:
    """Run a scene's full-space reference.

    Parameters
    ----------
    data : dict
        The scene (its TOML keys).
    base_dir : str or None
        Where its relative paths start.
    steps : int
        Steps to run.

    Returns
    -------
    reference : dict
        ``x`` (steps + 1, n * dim) positions, ``seconds_per_step``, ``iterations`` mean,
        ``vertices``, ``max_iterations``, ``steps``; ``unsettled_steps``: the steps that used every
        iteration without meeting the stopping rule, and ``unsettled_change`` the largest
        last change of one of them, a root mean square over the nodes, relative to the body's size
        (0 when every step settled); ``largest_motion``: the largest displacement of a vertex from
        rest, over its body's size.
    """
    from .scene import Scene

    scene = Scene.from_dict(_steps_scene(data, steps), base_dir=base_dir)
    ref = scene.build_reference()
    x = ref.rest_state()[0]
    xs, its, changes = [x], [], []
    clock = time.perf_counter()
    for record in simulate(ref, steps, _gait(scene, ref)):
        xs.append(record.z)
        its.append(record.iterations)
        changes.append(record.change)
    seconds = (time.perf_counter() - clock) / steps
    # a step that used every iteration did not meet the rule: the reference is off by about its last change,
    # said as a root mean square over the nodes, over the body's size (an audit: the residual, already
    # relative to the step's motion, had been divided by the size again, 0.31 for a 1.2 % last move)
    capped = np.asarray(its) >= ref.max_iter
    parts = connected_labels(scene.mesh)
    sizes = part_sizes(scene.mesh, parts)
    dim, n = scene.mesh.p.shape
    rms_change = np.asarray(changes)[capped] / np.sqrt(xs[0].size / dim) / float(np.mean(sizes))
    vertices = np.array(xs)[:, : n * dim].reshape(len(xs), n, dim)
    largest_motion = float((np.linalg.norm(vertices - vertices[0], axis=2) / sizes).max())
    return {
        "x": np.array(xs),
        "seconds_per_step": seconds,
        "iterations": float(np.mean(its)),
        "vertices": int(scene.mesh.p.shape[1]),
        "max_iterations": int(ref.max_iter),
        "steps": int(steps),
        "unsettled_steps": int(np.count_nonzero(capped)),
        "unsettled_change": float(max(rms_change, default=0.0)),
        "largest_motion": largest_motion,
    }


def _gait(scene, sim):
    """The scene's activation as a function of time, for :func:`~skfem_modal.sim.simulate`."""
    ceilings = sim.ceilings
    return lambda t: scene.activation(t, ceilings)


def run_reduced(task: dict) -> dict:
    """One reduced run of a study (a task for an executor; plain data in and out).

    ``task`` holds ``scene`` (a dict), ``base_dir``, ``steps``, ``overrides``
    (weights, clusters, iterations, rtol), ``sweep`` and ``label``, and
    ``reference`` (the reference's positions) or None.
    """
    scene = _reduced_scene(task)
    clock = time.perf_counter()
    sim = scene.build()
    precompute = time.perf_counter() - clock
    z, z_dot, _ = sim.rest_state()
    sim.step(z, z_dot, np.zeros(sim.n_muscles))  # warm up (compiled kernels)
    zs, times, its, residuals = [z], [], [], []
    for record in simulate(sim, task["steps"], _gait(scene, sim)):
        times.append(record.seconds)
        its.append(record.iterations)
        residuals.append(record.residual)
        zs.append(record.z)
    row = {
        "sweep": task["sweep"],
        "label": task["label"],
        "resolution": task.get("resolution", 1.0),
        "vertices": int(sim.mesh.p.shape[1]),
        "weights": scene.config["subspace"]["weights"],
        "cluster_weights": scene.config["subspace"]["cluster_weights"] or scene.config["subspace"]["weights"],
        "subspace": int(sim.B.shape[1]),
        "clusters": int(sim.n_clusters),
        "cluster_by": scene.config["subspace"]["cluster_by"],
        "max_iterations": sim.max_iter,
        "rtol": sim.rtol,
        "etol": sim.etol,
        "warm_start": sim.warm_start,
        "acceleration": sim.acceleration,
        "iterations_mean": float(np.mean(its)),
        "residual_median": float(np.median(residuals)),
        "precompute_s": precompute,
        "step_ms": float(np.median(times) * 1e3),
        "backend": sim.backend_used,
    }
    if task.get("reference") is not None:
        x = np.array(zs) @ sim.B.T
        mass = sim.mass
        parts = connected_labels(sim.mesh)
        sizes = part_sizes(sim.mesh, parts)
        row.update(
            trajectory_errors(x, task["reference"], mass, sim.mesh.p.T.ravel(), sizes, sim.dim, B=sim.B, parts=parts)
        )
    return row


def time_steps(tasks: list[dict], *, rounds: int = 3, steps: int = 60) -> list[float]:
    """Milliseconds per step of each task's simulator, timed fairly against each other.

    A shared machine has fast and slow spells lasting seconds, longer than
    one run: timing each run once would compare spells, not settings. Here
    every simulator is built first; then ``rounds`` times, one after another,
    each one runs ``steps`` steps of its gait; a simulator's time is the
    lowest of its per-round medians.

    Parameters
    ----------
    tasks : list of dict
        As for :func:`run_reduced` (``reference`` is not used).
    rounds : int
        Rounds of timing: each simulator's time is the lowest of its rounds' medians.
    steps : int
        Steps each simulator runs in a round (after one step of warm-up).

    Returns
    -------
    ms : list of float, one per task

    Raises
    ------
    ValueError
        ``rounds`` or ``steps`` not a whole number >= 1 (nothing timed would read as infinitely slow).
    """
    for name, value in (("rounds", rounds), ("steps", steps)):
        if not (is_whole(value) and value >= 1):
            raise ValueError(f"{name} must be a whole number >= 1, got {value!r}")
    built = []
    for task in tasks:
        scene = _reduced_scene(task)
        sim = scene.build()
        built.append((sim, _gait(scene, sim)))
    best = [np.inf] * len(tasks)
    # one BLAS thread, as the benchmarks time: a step's products are small, and on a busy machine idle
    # BLAS threads made some settings 8 times slower than their neighbours, bending the front
    with limited_blas_threads(1):
        for _ in range(rounds):
            for k, (sim, gait) in enumerate(built):
                z, z_dot, _ = sim.rest_state()
                sim.step(z, z_dot, gait(0.0))  # warm up
                times = [record.seconds for record in simulate(sim, steps, gait)]
                best[k] = min(best[k], float(np.median(times) * 1e3))
    return best


def _left_out(ground: dict | None, mesh_file: bool = False) -> dict:
    """The settings a study leaves out for a scene with this ground (validated ``[ground]``), and why.

    Under ground contact no accelerated iterate is taken (a projection, not an
    energy, holds the body up); under the reference contact no warm start
    either (its rule reads where each iterate came from). A row with them
    would be a plain run under another label. A mesh from a file has one
    resolution: no sweep of resolutions.
    """
    left = {}
    if mesh_file:
        left["resolution"] = "the mesh resolution sweep, which needs a built-in shape (a mesh file has one)"
    if ground is None:
        return left
    left["acceleration"] = "Anderson and Newton iterations have no effect under ground contact"
    if ground["model"] == "reference":
        left["warm_start"] = "a warm start has no effect under the reference contact"
    return left


def _sweeps(cfg: dict, base: dict, resolutions, left_out=()) -> list:
    """The runs of a study: ``(sweep, label, overrides, resolution)`` each, without the settings ``left_out``.

    Without a warm start the sweeps that add one to others run without it
    (labels without ``warm,``), and the sweep of iteration counts with a warm
    start, the same runs as without, is dropped.
    """
    base_weights, base_clusters = base.get("weights", 8), base.get("clusters", 20)
    warm = {} if "warm_start" in left_out else {"warm_start": True}
    if not warm:
        cfg = {**cfg, "warm": [], "acceleration": []}
    if "acceleration" in left_out:
        cfg = {**cfg, "acceleration": []}
    tasks = [("base", "base", {}, 1.0)]
    tasks += [("weights", f"weights={w}", {"weights": w}, 1.0) for w in cfg["weights"] if w != base_weights]
    tasks += [("clusters", f"clusters={c}", {"clusters": c}, 1.0) for c in cfg["clusters"] if c != base_clusters]
    tasks += [("iterations", f"iterations={k}", {"iterations": k}, 1.0) for k in cfg["iterations"]]
    tasks += [("rtol", f"rtol={t:g}", {"rtol": t}, 1.0) for t in cfg["rtol"]]
    tasks += [("warm", f"warm,iterations={k}", {**warm, "iterations": k}, 1.0) for k in cfg.get("warm", [])]
    tasks += [("etol", f"warm,etol={t:g}", {**warm, "etol": t}, 1.0) for t in cfg.get("etol", [])]
    for by in ("weights", "rotations"):
        tasks += [
            (f"clusters by {by}", f"warm,clusters={c},by={by},iterations=20",
             {**warm, "clusters": c, "cluster_by": by, "iterations": 20}, 1.0)
            for c in cfg.get("warm_clusters", [])
        ]  # fmt: skip
    tasks += [
        ("acceleration", f"warm,{method},iterations={k}", {**warm, "acceleration": method, "iterations": k}, 1.0)
        for method, k in cfg.get("acceleration", [])
    ]
    for w, c, by, k in cfg.get("warm_grid", []):
        stop = {"rtol": 1e-4} if k is None else {"iterations": k}
        label = f"warm,{'rtol=1e-4' if k is None else f'iterations={k}'},weights={w},clusters={c}"
        label += ",by=rotations" if by == "rotations" else ""
        tasks.append(("warm grid", label, {**warm, **stop, "weights": w, "clusters": c, "cluster_by": by}, 1.0))
    tasks += [("grid", f"weights={w},clusters={c}", {"weights": w, "clusters": c}, 1.0) for w, c in cfg["grid"]]
    tasks += [("resolution", f"resolution={f:g}", {}, f) for f in resolutions if f != 1.0]
    if not warm:
        tasks = [(sweep, label.replace("warm,", ""), over, f) for sweep, label, over, f in tasks]
    return tasks


def _tasks(cfg: dict, data: dict, scenes: dict, base_dir, left_out=()) -> list[dict]:
    """The runs of a study as tasks for :func:`run_reduced` (the reference is added as they go out)."""
    return [
        {
            "scene": scenes[f],
            "base_dir": base_dir,
            "steps": cfg["steps"],
            "overrides": over,
            "sweep": sweep,
            "label": label,
            "resolution": f,
        }
        for sweep, label, over, f in _sweeps(cfg, data.get("subspace", {}), list(scenes), left_out)
    ]


def _reduced_scene(task: dict):
    """The scene of a study task: the base scene with the task's overrides."""
    from .scene import Scene

    data = _steps_scene(task["scene"], task["steps"])
    over = task["overrides"]
    if "weights" in over:
        sub = data.setdefault("subspace", {})
        # the clusters stay those of the scene's own weights: only the subspace changes
        sub.setdefault("cluster_weights", sub.get("weights", 8))
        sub["weights"] = over["weights"]
    if "clusters" in over:
        data.setdefault("subspace", {})["clusters"] = over["clusters"]
    if "cluster_by" in over:
        data.setdefault("subspace", {})["cluster_by"] = over["cluster_by"]
    time_ = data.setdefault("time", {})
    if "iterations" in over:
        time_.update(iterations=over["iterations"], tol=0.0, rtol=0.0)
    for key in ("rtol", "etol"):
        if key in over:
            time_.update(iterations=100, tol=0.0, **{key: over[key]})
    time_.update({key: over[key] for key in ("warm_start", "acceleration") if key in over})
    return Scene.from_dict(data, base_dir=task["base_dir"])


def modal_convergence(cases=((40, 1), (80, 2), (160, 4)), length=40.0, height=1.0) -> list[dict]:
    """P1 against P2 frequencies of a clamped 2D beam (nu = 0), with solve times.

    The beam is slender (40 x 1) so that Euler-Bernoulli theory itself is
    good to about 0.3 % (shear deformation) for the first two frequencies.

    Errors of the first two bending frequencies against Euler-Bernoulli, and of
    the first four against the finest P2 mesh (twice the last case).

    Parameters
    ----------
    cases : sequence of (int, int)
        Cells along and across the beam (:func:`~skfem_modal.mesh.beam2d`'s ``nx``, ``ny``) of each
        mesh, coarsest first: the reference is P2 on twice the last.
    length, height : float
        The beam's size; it is clamped at ``x == min``. Young's modulus and density are 1.

    Returns
    -------
    rows : list of dict
        Two a case (P1, then P2): ``element``, ``cells`` (``"NXxNY"``), ``dofs``, ``seconds`` (the
        eigen solve's), ``error_vs_euler_bernoulli`` and ``error_vs_refined_p2`` (largest relative
        frequency errors).

    Raises
    ------
    ValueError
        ``cases`` is not a non-empty list of (nx, ny) pairs of whole numbers >= 1.
    """
    from .mesh import beam2d, vertices_where
    from .modal import linear_modal_analysis

    beta = np.array([1.8751040687119611, 4.6940911329739180])
    omega_eb = beta**2 * np.sqrt(height**2 / (12 * length**4))  # E = 1, rho = 1

    def solve(nx, ny, element):
        mesh = beam2d(length, height, nx, ny)
        clock = time.perf_counter()
        values, modes = linear_modal_analysis(
            mesh, 4, mu=0.5, lam=0.0, rho=1.0, fixed=vertices_where(mesh, "x == min"), element=element
        )
        return np.sqrt(values), time.perf_counter() - clock, modes.shape[0]

    given = cases
    cases = [tuple(case) for case in cases] if isinstance(cases, (list, tuple)) else None
    if not cases or not all(len(case) == 2 and all(is_whole(n) and n >= 1 for n in case) for case in cases):
        raise ValueError(f"cases must be a non-empty list of (nx, ny) pairs of whole numbers >= 1, got {given!r}")
    nx, ny = cases[-1]
    fine, _, _ = solve(2 * nx, 2 * ny, "P2")
    rows = []
    for nx, ny in cases:
        for element in ("P1", "P2"):
            omega, seconds, dofs = solve(nx, ny, element)
            rows.append(
                {
                    "element": element,
                    "cells": f"{nx}x{ny}",
                    "dofs": int(dofs),
                    "seconds": seconds,
                    "error_vs_euler_bernoulli": float(np.abs(omega[:2] / omega_eb - 1).max()),
                    "error_vs_refined_p2": float(np.abs(omega / fine - 1).max()),
                }
            )
    return rows


def pareto_front(rows, cost="step_ms", error="trajectory_error") -> list[int]:
    """Indices of the rows no other row beats in both cost and error, by cost.

    Parameters
    ----------
    rows : list of dict
        Study rows (:func:`run_reduced`'s, with their timings), each holding ``cost`` and ``error``.
    cost, error : str
        The keys of the cost and the error, both lower-is-better.

    Returns
    -------
    front : list of int
        Indices into ``rows``, cheapest first (of rows of equal cost, the one with the lowest error).

    Examples
    --------
    >>> pareto_front([{"step_ms": 1, "trajectory_error": 0.5}, {"step_ms": 2, "trajectory_error": 0.6},
    ...               {"step_ms": 3, "trajectory_error": 0.1}])
    [0, 2]
    """
    order = sorted(range(len(rows)), key=lambda i: (rows[i][cost], rows[i][error]))
    front, best = [], np.inf
    for i in order:
        if rows[i][error] < best:
            front.append(i)
            best = rows[i][error]
    return front


def _describe(row) -> str:
    if row.get("etol"):
        it = f"etol {row['etol']:g}"
    elif row["rtol"]:
        it = f"rtol {row['rtol']:g}"
    else:
        it = f"{row['max_iterations']} iterations"
    by = " by rotation" if row.get("cluster_by") == "rotations" else ""
    how = ["a warm start"] if row.get("warm_start") else []
    if row.get("acceleration", "none") != "none":
        how.append(row["acceleration"])
    extra = f" ({', '.join(how)})" if how else ""
    return f"{row['weights']} weights, {row['clusters']} clusters{by} and {it}{extra}"


def _percent(fraction: float) -> str:
    """A fraction as a percentage to read against thresholds: 10.36 % is "10.4", not "10" (nor "1e+02")."""
    percent = 100.0 * fraction
    return f"{percent:.1f}" if abs(percent) >= 1.0 else f"{percent:.2g}"


def recommend(rows, thresholds=(0.01, 0.02, 0.05, 0.10, 0.20), constrained: bool = False) -> list[str]:
    """Plain sentences: the cheapest setting within each error threshold, and the defaults.

    Parameters
    ----------
    rows : list of dict
        Study rows (:func:`run_reduced`'s, with ``step_ms``); only those at resolution 1 with a
        ``trajectory_error`` count. The ``base`` row, when there is one, is said first, then the
        runs of its sweeps with twice its weights (failing that, more) and twice its clusters.
    thresholds : sequence of float
        Trajectory errors (fractions: 0.01 is 1 %), increasing: a threshold whose fastest setting
        is the previous one's says so in a short sentence.
    constrained : bool
        The scene has a ground or pins: the projection of the reference onto the subspace need
        not be a motion the subspace can make there, so it bounds nothing and is not said as a bound.

    Returns
    -------
    lines : list of str
        One sentence a line.
    """
    same = [r for r in rows if r["resolution"] == 1.0 and "trajectory_error" in r]
    lines = []
    base = next((r for r in same if r["sweep"] == "base"), None)
    if base:
        # under a ground or pins the projection may go through the ground or pull the pins: no bound (an
        # audit: "the subspace alone allows 1.2 %" on the creature's crawl, whose rows fell with weights only)
        alone = (
            f"the reference's projection onto the subspace is {_percent(base['subspace_error'])} % off, not a "
            "bound here: the ground or the pins keep the subspace from following it"
            if constrained
            else f"the subspace alone allows {_percent(base['subspace_error'])} %"
        )
        lines.append(
            f"{_describe(base)} give {_percent(base['trajectory_error'])} % trajectory error at "
            f"{base['step_ms']:.3g} ms per step ({alone})."
        )
        for key, label in (("weights", "weights"), ("clusters", "clusters")):
            double = [r for r in same if r["sweep"] == key and r[key] == 2 * base[key]]
            if not double and key == "weights":
                double = [r for r in same if r["sweep"] == key and r[key] > base[key]]
            if double:
                r = double[0]
                lines.append(
                    f"{r[key]} {label} instead of {base[key]}: {_percent(r['trajectory_error'])} % at "
                    f"{r['step_ms']:.3g} ms per step."
                )
    fastest = None
    for limit in thresholds:
        within = [r for r in same if r["trajectory_error"] <= limit]
        if within and min(within, key=lambda r: r["step_ms"]) is fastest:
            lines.append(f"Within {100 * limit:g} % trajectory error: the same setting (none faster stays within it).")
        elif within:
            r = fastest = min(within, key=lambda r: r["step_ms"])
            times = f" ({r['step_ms'] / base['step_ms']:.2g} times the base's)" if base else ""
            lines.append(
                f"Within {100 * limit:g} % trajectory error, the fastest setting measured is {_describe(r)}: "
                f"{_percent(r['trajectory_error'])} % at {r['step_ms']:.3g} ms per step{times}."
            )
        else:
            lines.append(f"No setting measured reaches {100 * limit:g} % trajectory error.")
    return lines


#: A reference whose vertices all move less than this share of their body's size is refused (a body at
#: rest: its round-off, 1e-11 of the size, made every row's error 21 %).
STILL = 1e-9


# said of a scene with a ground (an audit: on the ghost's crawl rtol 0.01 gave 9.7 %, 0.001 gave 22.5 %)
_CHAOTIC = (
    "On the ground these are errors of single runs of a motion that branches where a contact is made a step "
    "sooner or later: a row can stand far from its sweep's trend (a tighter setting with a larger error). Read "
    "the trends, and check a chosen setting on a few gaits or starts before relying on it."
)


# said of a scene with pins (an audit of examples/beam_pinned.toml: 35.6 % at 10 weights, 6.3 % at 16;
# 26-36 % whatever the clusters and iterations)
_PINNED = (
    "With pins, part of what the table calls solver error is the pins' stiff hold on a small subspace "
    "(locking), which more clusters or iterations barely reduce: compare the weights sweep."
)


def _quiet_worker() -> None:
    """Pool initializer: no warnings from the workers (raw, once per process); the caller says them.

    The calling process builds and steps every setting's simulator again for
    the timings (:func:`time_steps`), so each warning is said there, once, in
    the caller's words (the command line's ``skfem-modal study: warning: ...``).
    """
    warnings.simplefilter("ignore")
    exit_with_parent()


def make_executor(
    workers: int = 1, scheduler: str | None = None, *, initializer=None, initargs=(), quiet_interrupts: bool = False
):
    """The executor a study (or a gait search) runs on.

    Parameters
    ----------
    workers : int
        Processes of the local pool.
    scheduler : str, optional
        Address of a dask.distributed scheduler (``tcp://host:8786``): then
        its executor (needs the ``distributed`` extra).
    initializer : callable, optional
        Called with ``initargs`` in each local pool process as it starts.
    initargs : tuple
        The initializer's arguments (pickled once per process).
    quiet_interrupts : bool
        The local pool's processes start with Ctrl-C blocked, left to the
        caller (:class:`~skfem_modal.interrupts.QuietSpawnContext`).

    Returns
    -------
    executor : concurrent.futures.Executor
    close : callable
        ``close(cancel=False)`` shuts down what was started (``cancel``:
        no task is waited for: the local pool's running ones are stopped).

    Raises
    ------
    ValueError
        No dask scheduler answers at ``scheduler`` (or dask is not installed).
    WorkersLost
        The scheduler has no worker, and none joins within :data:`WORKERS_JOIN_SECONDS`.
    """
    if scheduler:
        try:
            from dask.distributed import Client
        except ImportError:
            raise ValueError("--scheduler needs dask.distributed: pip install 'skfem_modal[distributed]'") from None
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, ValueError, TypeError) as err:  # no port, no such host, nothing answering
            raise ValueError(f"--scheduler {scheduler}: no dask scheduler answers there ({err})") from None
        try:  # (without workers a search failed with dask's raw "No valid workers found", a study waited silently)
            client.wait_for_workers(1, timeout=WORKERS_JOIN_SECONDS)
        except TimeoutError:
            client.close()
            raise WorkersLost(
                f"--scheduler {scheduler}: the dask scheduler has no workers (none joined in "
                f"{WORKERS_JOIN_SECONDS:g} s): start some (dask worker {scheduler})"
            ) from None

        # A lost scheduler makes the client's sender log its closed connection,
        # traceback and all, at INFO level; the search names the loss itself.
        batched = logging.getLogger("distributed.batched")
        batched_level = batched.level
        batched.setLevel(logging.WARNING)

        def close_client(cancel=False):
            # stopping on an error: a lost scheduler's reconnection, cancelled here, would log a raw traceback
            logger = logging.getLogger("distributed.client")
            level = logger.level
            if cancel:
                logger.setLevel(logging.CRITICAL)
            try:
                client.close()
            finally:
                logger.setLevel(level)
                batched.setLevel(batched_level)

        return client.get_executor(), close_client
    import multiprocessing

    # Each worker process gets one BLAS thread, as dask's workers do: the
    # processes share the cores, and a result does not depend on the executor
    # (threaded BLAS sums in another order). Workers start when tasks come,
    # so the setting holds until the pool is closed.
    saved = {name: os.environ.get(name) for name in _ONE_THREAD}
    os.environ.update({name: "1" for name in _ONE_THREAD})
    pool = ProcessPoolExecutor(
        max_workers=workers,
        mp_context=QuietSpawnContext() if quiet_interrupts else multiprocessing.get_context("spawn"),
        initializer=initializer,
        initargs=initargs,
    )

    def close(cancel=False):
        try:
            if cancel:
                # a stop: the tasks running are dropped too (waiting for them, a study stopped by a signal
                # to its own process ran its elephant reference 200 s on)
                running = list((pool._processes or {}).values())
                pool.shutdown(wait=False, cancel_futures=True)
                for process in running:
                    process.terminate()
                for process in running:
                    process.join(timeout=10.0)
            else:
                pool.shutdown()
        finally:
            for name, value in saved.items():
                if value is None:
                    os.environ.pop(name, None)
                else:
                    os.environ[name] = value

    return pool, close


_ONE_THREAD = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")

#: How long a dask scheduler may take to have a worker, at most, before the work is refused
WORKERS_JOIN_SECONDS = 30.0


class WorkersLost(RuntimeError):
    """An executor lost its workers (a process killed, the dask scheduler gone): the tasks they had are lost."""


def checked_workers(workers) -> int:
    """The number of local worker processes, checked: a whole number of at least 1.

    Checked before any work (0 was numpy's "max_workers must be greater than 0" after the precompute,
    2.5 a TypeError from the pool, True taken as 1).

    Parameters
    ----------
    workers : int

    Returns
    -------
    int

    Raises
    ------
    TypeError, ValueError
        Not a whole number (bools included), or below 1.
    """
    if not is_whole(workers):
        raise TypeError(f"workers must be a whole number of processes, got {workers!r}")
    if workers < 1:
        raise ValueError(f"workers must be at least 1, got {workers}")
    return int(workers)


def checked_executor(executor):
    """An executor given by a caller, as one whose ``submit`` and ``map`` give results: or a clear error.

    A dask ``Client`` is taken as ``client.get_executor()`` (its own ``map`` gives futures, not results:
    a search failed after all its rollouts); anything without ``submit`` and ``map`` (a dask
    ``LocalCluster``, say) is refused before any work.

    Parameters
    ----------
    executor : concurrent.futures.Executor, dask Client or None

    Returns
    -------
    concurrent.futures.Executor or None
        ``executor`` itself, a dask client's ``get_executor()``, or None (None given).

    Raises
    ------
    TypeError
        Anything else, naming its type.

    Examples
    --------
    >>> from concurrent.futures import ThreadPoolExecutor
    >>> with ThreadPoolExecutor(1) as pool:
    ...     checked_executor(pool) is pool
    True
    >>> checked_executor("tcp://host:8786")
    Traceback (most recent call last):
    ...
    TypeError: executor must be a concurrent.futures.Executor or a dask Client, got a str (an address: scheduler=)
    """
    if executor is None or isinstance(executor, Executor):
        return executor
    kind = type(executor)
    if callable(getattr(executor, "get_executor", None)):  # a dask Client, or a subclass of one's own
        return executor.get_executor()
    from_dask = any(k.__module__.startswith("distributed") for k in kind.__mro__)
    if not from_dask and all(callable(getattr(executor, name, None)) for name in ("submit", "map")):
        return executor  # an executor of its own kind, duck-typed as concurrent.futures' are
    hint = {"str": " (an address: scheduler=)", "LocalCluster": " (pass dask.distributed.Client(cluster))"}
    raise TypeError(
        f"executor must be a concurrent.futures.Executor or a dask Client, got a {kind.__name__}"
        + hint.get(kind.__name__, "")
    )


def dask_client(executor):
    """The dask client behind an executor (``client.get_executor()``), or None for any other executor.

    ``executor``: any executor, or None (then None).

    Examples
    --------
    >>> from concurrent.futures import ThreadPoolExecutor
    >>> dask_client(ThreadPoolExecutor(1)) is None
    True
    """
    if executor is None or not type(executor).__module__.startswith("distributed"):
        return None
    return getattr(executor, "_client", None)


def lost_workers(error: BaseException, executor=None) -> str | None:
    """What ``error``, raised by an executor's task, says happened to the workers, in words; None for other errors.

    A local pool's worker process that dies (killed by the out-of-memory
    killer, say) breaks the pool (``BrokenProcessPool``); a dask cluster
    cancels the tasks of a lost scheduler connection, and of data that died
    with its workers (``FutureCancelledError``), and gives up on a task that
    killed its workers (``KilledWorker``).

    Parameters
    ----------
    error : BaseException
    executor : concurrent.futures.Executor, optional
        The executor that ran the task: a dask client no longer connected
        to its scheduler tells a lost scheduler (the tasks submitted while
        it tried to reconnect are cancelled with no reason when it gives up).

    Returns
    -------
    str or None

    Examples
    --------
    >>> from concurrent.futures.process import BrokenProcessPool
    >>> lost_workers(BrokenProcessPool("A process in the process pool was terminated abruptly"))
    'a worker process of the local pool died (killed: by the out-of-memory killer, say)'
    >>> lost_workers(ValueError("a task's own error")) is None
    True
    """
    from concurrent.futures import BrokenExecutor, CancelledError

    dask = type(error).__module__.split(".")[0] == "distributed"
    if isinstance(error, BrokenExecutor):
        return "a worker process of the local pool died (killed: by the out-of-memory killer, say)"
    reason = getattr(error, "reason", None)
    client = dask_client(executor)
    disconnected = client is not None and client.status != "running"
    lost = reason == "scheduler-connection-lost" or type(error).__name__ == "CommClosedError"
    if dask and (lost or (isinstance(error, CancelledError) and disconnected)):
        return "the connection to the dask scheduler was lost"
    if dask and isinstance(error, CancelledError):
        return f"the dask cluster cancelled the tasks ({reason}: its workers died, and the data they held)"
    if dask and type(error).__name__ == "KilledWorker":
        return "dask workers died running a task, each worker that took it in turn (KilledWorker)"
    return None


def run_study(
    data: dict,
    out_dir,
    *,
    preset: str = "quick",
    base_dir: str | None = None,
    executor: Executor | None = None,
    workers: int = 1,
    scheduler: str | None = None,
    progress: bool = False,
    overwrite: bool = False,
    how: str = "overwrite=True",
) -> dict:
    """Run an accuracy/cost study of a scene and write its report.

    Parameters
    ----------
    data : dict
        The scene (as a dict, e.g. ``FLOATING_CATERPILLAR``).
    out_dir : str or path-like
    preset : {"quick", "full"}
    base_dir : str, optional
        Where the scene's relative paths start.
    executor : concurrent.futures.Executor, optional
        Default: :func:`make_executor` with ``workers`` / ``scheduler``.
    workers : int
        Processes of the default local pool.
    scheduler : str, optional
        Address of a dask scheduler (``tcp://host:8786``) whose workers run the settings.
    progress : bool
        Print a line per finished run.
    overwrite : bool
        Replace an earlier study in ``out_dir`` (only its files,
        :data:`~skfem_modal.outputs.STUDY_FILES`, are removed); without it an
        earlier study there is an error.
    how : str
        How the caller asks to overwrite, for that error (e.g. ``--overwrite``).

    Returns
    -------
    report : dict
        ``rows``, ``modal``, ``pareto`` (indices), ``recommendation`` (sentences),
        ``left_out`` (settings not run, and why) and the paths written
        (``csv``, ``modal_csv``, ``json``, ``markdown``, and ``png`` when
        matplotlib is there), each file written whole or not at all.

    Raises
    ------
    FileExistsError
        Before any work: ``out_dir`` holds an earlier study and ``overwrite``
        is false, or it holds a run or a gait search (whatever ``overwrite``).
    WorkersLost
        The executor lost its workers (:func:`lost_workers`); nothing is written.
    """
    if preset not in PRESETS:
        raise ValueError(f"preset must be one of {sorted(PRESETS)}, got {preset!r}")
    from .scene import Scene

    scene = Scene.from_dict(data, base_dir=base_dir)  # every error before any work
    cfg = PRESETS[preset]
    out_dir = os.fspath(out_dir)
    executor = checked_executor(executor)  # (after the earlier study was removed, it lost that study)
    workers = checked_workers(workers)
    clear_earlier_study(out_dir, overwrite, how=how)
    left_out = _left_out(scene.config["ground"], mesh_file=bool(data.get("mesh", {}).get("file")))
    say = print if progress else (lambda *a, **k: None)
    given = data.get("time") or {}
    if ("steps" in given or "duration" in given) and scene.n_steps != cfg["steps"]:
        # (a scene's [time] was replaced without a word: a user's 60 steps studied as 100)
        say(
            f"each run is the {preset} study's {cfg['steps']} steps, not the scene's {scene.n_steps}: a study "
            "compares settings over the same motion, its preset's length"
        )
    close = None
    if executor is None:  # a scheduler that does not answer: before the folder is made
        executor, close = make_executor(workers, scheduler, initializer=None if scheduler else _quiet_worker)
    started = time.perf_counter()
    stopped = True  # until the runs are done: an interrupt or an error does not wait for the others
    made = None
    try:
        made = made_folder(out_dir)
        references, rows, modal_rows = _study_runs(executor, cfg, data, base_dir, left_out, say)
        stopped = False
    except BaseException as error:
        remove_if_empty(out_dir, made)  # nothing is written until the runs are done
        said = lost_workers(error, executor) if isinstance(error, Exception) else None
        if said is None:
            raise
        raise WorkersLost(f"the study lost its workers: {said}; a study keeps no checkpoint: run it again") from None
    finally:
        if close is not None:
            close(cancel=stopped)
    meta = {
        "scene": data.get("name", "scene"),
        "preset": preset,
        "steps": cfg["steps"],
        "machine": f"{platform.node()}, {os.cpu_count()} cores, python {platform.python_version()}",
        "date": time.strftime("%Y-%m-%d"),
        "seconds": time.perf_counter() - started,
        "timing_rounds": cfg["timing_rounds"],
        "references": {str(f): {k: v for k, v in r.items() if k != "x"} for f, r in references.items()},
        "left_out": left_out,
    }
    return _report(out_dir, scene, references, rows, modal_rows, meta)


def _study_runs(executor, cfg: dict, data: dict, base_dir, left_out: dict, say):
    """A study's runs: ``(references by resolution, rows of the reduced runs, modal convergence rows)``.

    The reduced runs' step times are taken again here, each setting in turn in this process: fairly
    against each other (the runs may have shared the machine, or run on other machines).
    """
    resolutions = cfg["resolution"] if not data.get("mesh", {}).get("file") else [1.0]
    scenes = {f: resolution_scene(data, f) for f in resolutions}
    references = _run_references(executor, scenes, base_dir, cfg["steps"], say)
    tasks = _tasks(cfg, data, scenes, base_dir, left_out)
    rows = _run_reduced_all(executor, tasks, references, say)
    for row, ms in zip(rows, time_steps(tasks, rounds=cfg["timing_rounds"])):
        row["step_ms"] = ms
    say("step times, each setting in turn in this process:")
    for row in rows:
        say(f"{row['label']:28s} {row['step_ms']:8.3f} ms")
    return references, rows, modal_convergence(tuple(cfg["modal"]))


def _report(out_dir: str, scene, references: dict, rows: list, modal_rows: list, meta: dict) -> dict:
    """The study's Pareto front and recommendation, written with its tables and plots; :func:`run_study`'s result."""
    same = [i for i, r in enumerate(rows) if r["resolution"] == 1.0]
    front = [same[i] for i in pareto_front([rows[i] for i in same])]
    ground = scene.config["ground"]
    lines = recommend(rows, constrained=ground is not None or scene.config["pinned"] is not None)
    unsettled = _unsettled(references, None if ground is None else ground["model"])
    if unsettled:
        lines.insert(0, unsettled)
    if scene.config["ground"] is not None:
        lines.append(_CHAOTIC)
    if scene.config["pinned"] is not None:
        lines.append(_PINNED)
    paths = _write_report(out_dir, rows, modal_rows, front, lines, meta)
    return {
        "rows": rows,
        "modal": modal_rows,
        "pareto": front,
        "recommendation": lines,
        "left_out": meta["left_out"],
        "meta": meta,
        **paths,
    }


def _run_references(executor, scenes: dict, base_dir, steps: int, say) -> dict:
    """The full-space reference of each resolution's scene (:func:`run_reference`), all submitted at once."""
    futures = {f: executor.submit(run_reference, scene, base_dir, steps) for f, scene in scenes.items()}
    references = {}
    for f, future in futures.items():
        ref = references[f] = future.result()
        say(f"reference at resolution {f:g}: {_reference_line(ref)}")
        if not ref["largest_motion"] >= STILL:
            raise ValueError(
                f"the scene's body does not move in the reference run at resolution {f:g}: no vertex moved more "
                f"than {ref['largest_motion']:.2g} of its body's size in {ref['steps']} steps, so errors relative "
                "to its motion would be round-off over round-off (an audit: 21 % in every row). Give the scene "
                "something to do: a gait (muscles.gait), gravity, or more steps"
            )
    return references


def _run_reduced_all(executor, tasks: list, references: dict, say) -> list[dict]:
    """The rows of the study's reduced runs, each against the reference at its resolution."""
    futures = [executor.submit(run_reduced, {**t, "reference": references[t["resolution"]]["x"]}) for t in tasks]
    rows = []
    for future in futures:
        rows.append(future.result())
        say(f"{rows[-1]['label']:28s} {100 * rows[-1]['trajectory_error']:8.3f} % error")
    return rows


_COLUMNS = [
    "sweep", "label", "resolution", "vertices", "weights", "cluster_weights", "subspace", "clusters", "cluster_by",
    "max_iterations", "rtol", "etol", "warm_start", "acceleration", "iterations_mean", "residual_median",
    "precompute_s", "step_ms", "trajectory_error", "subspace_error", "solver_error", "com_error",
    "worst_vertex_error", "backend",
]  # fmt: skip


def _write_whole(path: str, write) -> str:
    """``write(f)`` into a temporary file beside ``path``, renamed onto it when complete; returns ``path``."""
    with written_whole(path) as tmp, open(tmp, "w", newline="") as f:
        write(f)
    return path


def _table(rows, columns):
    """A writer of ``rows`` (dicts) as a CSV table with these columns."""

    def write(f):
        writer = csv.DictWriter(f, fieldnames=columns)
        writer.writeheader()
        writer.writerows({k: r.get(k) for k in columns} for r in rows)

    return write


def _reference_line(ref: dict) -> str:
    """What a reference run was (:func:`run_reference`): its size, iterations and time, and whether it settled."""
    line = (
        f"{ref['vertices']} vertices, {ref['iterations']:.0f} iterations a step, "
        f"{1e3 * ref['seconds_per_step']:.1f} ms a step"
    )
    if ref["unsettled_steps"]:
        line += (
            f"; {ref['unsettled_steps']} steps did not settle (stopped at {ref['max_iterations']} iterations, "
            f"last change up to {100 * ref['unsettled_change']:.2g} % of the size, root mean square over the nodes)"
        )
    return line


def _unsettled(references: dict, contact_model: str | None) -> str | None:
    """A sentence for the recommendation when a reference run did not settle, else None.

    ``contact_model``: the scene's ground contact model (None without a ground), for the likely cause.
    """
    worst = max(references.values(), key=lambda ref: ref["unsettled_change"])
    if not worst["unsettled_steps"]:
        return None
    # each resolution's reference has its own steps (the errors are measured against one of them)
    runs = [(f, ref) for f, ref in sorted(references.items(), reverse=True) if ref["unsettled_steps"]]
    steps = ", ".join(
        f"{ref['unsettled_steps']} of its {ref['steps']} steps at resolution {float(f):g}" for f, ref in runs
    )
    if contact_model == "reference":
        why = (
            "The reference contact model can do this: each iterate picks the points it holds, and the "
            "iterations can go round between sets."
        )
    else:
        why = (
            "Local/global iterations on every element converge slowly for a stiff body or a large time step: "
            "a smaller step (time.step) settles sooner."
        )
    return (
        f"The full-space reference did not settle in {steps}: they stopped at {worst['max_iterations']} "
        f"iterations with a last change of up to {100 * worst['unsettled_change']:.2g} % of the body's size (root "
        f"mean square over the nodes), so it is itself off by about that much and errors near it say little. ({why})"
    )


def _write_report(out_dir, rows, modal_rows, front, lines, meta) -> dict:
    """The study's files, each written whole: ``csv``, ``modal_csv``, ``json``, ``markdown``, ``png``."""
    paths = {}
    paths["csv"] = _write_whole(os.path.join(out_dir, "study.csv"), _table(rows, _COLUMNS))
    paths["modal_csv"] = _write_whole(os.path.join(out_dir, "modal.csv"), _table(modal_rows, list(modal_rows[0])))
    report = {"meta": meta, "rows": rows, "modal": modal_rows, "pareto": front, "recommendation": lines}
    paths["json"] = _write_whole(os.path.join(out_dir, "study.json"), lambda f: json.dump(report, f, indent=2))
    md = [f"# Accuracy and cost: {meta['scene']}", ""]
    md.append(
        f"{meta['preset']} study, {meta['steps']} steps, {meta['machine']}, {meta['date']}; "
        f"{meta['seconds']:.0f} s in all."
    )
    md.append("")
    for f, ref in meta["references"].items():
        md.append(f"- full-space reference at resolution {f}: {_reference_line(ref)}")
    if meta["left_out"]:
        plain = {"acceleration", "warm_start"} & set(meta["left_out"])
        why = " (rows with them would be plain runs under another label)" if plain else ""
        md += ["", "Not run for this scene: " + "; ".join(meta["left_out"].values()) + why + "."]
    md += ["", "## Recommendation", ""] + [f"- {line}" for line in lines]
    md += ["", "## Error against milliseconds per step", ""]
    md.append(
        f"ms/step: each setting's simulator runs 60 steps in turn with all the others, {meta['timing_rounds']} "
        "rounds, in one process; its time is the lowest of its per-round medians (a shared machine has slow "
        "spells longer than one run). Errors are over the whole run, against the full-space reference at the "
        "same resolution."
    )
    md.append("")
    md.append(
        "| run | vertices | subspace | clusters | iterations/step | residual | precompute s | ms/step | trajectory % "
        "| subspace % | solver % | COM | worst vertex | Pareto |"
    )
    md.append("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for i, r in enumerate(rows):
        md.append(
            f"| {r['label']} | {r['vertices']} | {r['subspace']} | {r['clusters']} | {r['iterations_mean']:.1f} "
            f"| {r['residual_median']:.1e} | {r['precompute_s']:.2f} | {r['step_ms']:.3f} "
            f"| {100 * r['trajectory_error']:.3g} "
            f"| {100 * r['subspace_error']:.3g} | {100 * r['solver_error']:.3g} | {r['com_error']:.1e} "
            f"| {r['worst_vertex_error']:.1e} | {'*' if i in front else ''} |"
        )
    md += ["", "## Modal frequencies: P1 against P2 (clamped beam 40 x 1, nu = 0)", ""]
    md.append("| element | cells | DOFs | seconds | error vs Euler-Bernoulli | error vs refined P2 |")
    md.append("|---|---|---|---|---|---|")
    for r in modal_rows:
        md.append(
            f"| {r['element']} | {r['cells']} | {r['dofs']} | {r['seconds']:.3f} "
            f"| {100 * r['error_vs_euler_bernoulli']:.3g} % | {100 * r['error_vs_refined_p2']:.3g} % |"
        )
    paths["markdown"] = _write_whole(os.path.join(out_dir, "study.md"), lambda f: f.write("\n".join(md) + "\n"))
    try:
        paths["png"] = _plot(out_dir, rows, front, meta)
    except ImportError:
        pass
    return paths


def _plot(out_dir, rows, front, meta) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    # the front's settings are long and crowd each other near the knee: numbered on the plot, spelt out beside it
    fig, (ax, key) = plt.subplots(1, 2, figsize=(10.5, 4.8), gridspec_kw={"width_ratios": [2.2, 1.0]})
    markers = {
        "base": "*",
        "weights": "o",
        "clusters": "s",
        "iterations": "^",
        "rtol": "v",
        "warm": "P",
        "etol": "X",
        "clusters by weights": "s",
        "clusters by rotations": "p",
        "acceleration": "h",
        "warm grid": "d",
        "grid": ".",
        "resolution": "D",
    }
    for sweep, marker in markers.items():
        pts = [r for r in rows if r["sweep"] == sweep]
        if pts:
            ax.scatter(
                [r["step_ms"] for r in pts],
                [100 * r["trajectory_error"] for r in pts],
                marker=marker,
                s=60 if sweep == "base" else 30,
                # other meshes, each against its own reference: not on the front (it compares one mesh's settings)
                label="resolution (own reference)" if sweep == "resolution" else sweep,
            )
    f = sorted(front, key=lambda i: rows[i]["step_ms"])
    ax.plot(
        [rows[i]["step_ms"] for i in f],
        [100 * rows[i]["trajectory_error"] for i in f],
        "k--",
        lw=1,
        label="Pareto front",
    )
    for number, i in enumerate(f, 1):
        ax.annotate(
            str(number),
            (rows[i]["step_ms"], 100 * rows[i]["trajectory_error"]),
            fontsize=7,
            xytext=(4, 2),
            textcoords="offset points",
        )
    ax.set_xlabel("milliseconds per step")
    ax.set_ylabel("trajectory error (%)")
    plain = FuncFormatter(lambda value, _: f"{value:g}")
    ax.set_xscale("log")  # the accelerated iterations cost ten times more: the front would be squeezed
    ax.set_yscale("log")
    for axis in (ax.xaxis, ax.yaxis):
        # labels at 1, 2 and 5 of each decade, as plain numbers: matplotlib's 2x10^-2 labels ran into each other
        axis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
        axis.set_major_formatter(plain)
        axis.set_minor_formatter(NullFormatter())
    ax.set_title(f"{meta['scene']}: accuracy against cost", fontsize=10)
    ax.grid(alpha=0.3, which="both")
    key.axis("off")
    key.legend(*ax.get_legend_handles_labels(), loc="lower left", fontsize=7, ncol=2)  # beside: not over the points
    lines = [f"{number:2d}  {rows[i]['label']}" for number, i in enumerate(f, 1)]
    # above the legend's 7 rows whatever the front's length (a 30-point front ran into it at 7 points)
    fontsize = min(7.0, 150.0 / (len(lines) + 1))
    key.text(0.0, 1.0, "Pareto front\n" + "\n".join(lines), va="top", ha="left", fontsize=fontsize, family="monospace")
    fig.tight_layout()
    path = os.path.join(out_dir, "pareto.png")
    try:
        with written_whole(path) as tmp:
            fig.savefig(tmp, dpi=120, format="png")
    finally:
        plt.close(fig)
    return path
