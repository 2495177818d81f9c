"""Gait transfer: a searched gait replayed with more accurate settings, and how much of its travel survives.

A gait search optimises against the simulator it runs: a reduced one (a few
skinning weights, rotation clusters, a fixed number of local/global
iterations). :func:`replay` runs the same gait, from rest, for the same
number of steps, scored the same way (:class:`~skfem_modal.rollouts.Trial`),
with settings up a ladder of accuracy:

* as searched (the search's own rollout, bit for bit);
* 5 times the iterations a step;
* 4 times the rotation clusters, 5 times the iterations;
* twice the skinning weights, 4 times the clusters, 5 times the iterations;
* the full space (every DOF, one rotation per element, iterated to a
  tight tolerance), when the mesh has at most ``full_space_limit`` elements;
* for a built-in shape, a copy at half the resolution, reduced as searched
  and, within ``full_space_limit`` elements too, in the full space (the full
  space of a large mesh costs minutes).

``survives`` is each replay's travel along the searched direction over the
size of the search's own travel (its absolute value): 1 means the replay
travels as far as the search's, along the direction, 0 not at all, a
negative value backwards, whatever the sign of the search's own travel (a
search that found no gait going forward has -1 as searched).
"""

from __future__ import annotations

import copy
import csv
import os
import time

import numpy as np

from .export import written_whole
from .outputs import TRANSFER_FILE
from .rollouts import Trial

__all__ = ["LADDER", "replay", "transfer_search"]

#: The reduced settings a gait is replayed with: (label, factors on weights, clusters, iterations).
LADDER = (
    ("as searched", {}),
    ("iterations x5", {"iterations": 5}),
    ("clusters x4, iterations x5", {"clusters": 4, "iterations": 5}),
    ("weights x2, clusters x4, iterations x5", {"weights": 2, "clusters": 4, "iterations": 5}),
)


def _scaled(data: dict, config: dict, n_elements: int, factors: dict) -> dict:
    """A copy of a scene dict with its weights, clusters and iterations multiplied."""
    data = copy.deepcopy(data)
    subspace = data.setdefault("subspace", {})
    if "weights" in factors:
        subspace["weights"] = config["subspace"]["weights"] * factors["weights"]
    if "clusters" in factors:
        subspace["clusters"] = min(config["subspace"]["clusters"] * factors["clusters"], n_elements)
    if "iterations" in factors:
        data.setdefault("time", {})["iterations"] = config["time"]["iterations"] * factors["iterations"]
    return data


def replay(
    data: dict,
    gait: dict,
    *,
    steps: int,
    direction,
    objective: str = "travel",
    tip_limit: float = np.pi / 3,
    tip_weight: float = 10.0,
    base_dir: str | None = None,
    full_space_limit: int = 10_000,
    full_space_rtol: float = 1e-8,
    progress=None,
    skipped: list | None = None,
) -> list[dict]:
    """Replay a gait up the ladder of accuracy (module docs).

    Parameters
    ----------
    data : dict
        The scene the gait was searched in.
    gait : dict
        ``amplitude`` (fractions of the ceilings), ``period``, ``phase``.
    steps : int
    direction : array_like, shape (dim,)
    objective, tip_limit, tip_weight :
        As for :class:`~skfem_modal.rollouts.Trial`.
    base_dir : str, optional
        Where the scene's relative paths start.
    full_space_limit : int
        Largest mesh (elements) replayed in the full space.
    full_space_rtol : float
        The full space's stopping rule (relative change per iteration; at most 2000 iterations a step).
    progress : callable, optional
        Called with each setting's label before it runs.
    skipped : list, optional
        Gets a sentence for each full-space replay left out (its mesh over ``full_space_limit``).

    Returns
    -------
    rows : list of dict
        Per setting: ``setting``, ``space`` (reduced or full), ``elements``,
        ``coordinates``, ``clusters``, ``iterations`` (at most, a step),
        ``mean_iterations``, ``travel``, ``alignment``, ``max_tilt_degrees``, ``tipped`` (whether the body
        tilted past ``tip_limit``: its travel is a tumble's, its fitness penalised), ``fitness``,
        ``physical`` (whether the replay's motion was: a travel that is not, of a body torn apart or gone
        non-finite, says nothing of the gait), ``survives`` (travel over the size of the first row's:
        module docs) and ``seconds``.
    """
    from .scene import Scene
    from .study import resolution_scene

    say = progress or (lambda label: None)
    scene = Scene.from_dict(data, base_dir=base_dir)
    if scene.config["ground"] is None and scene.config["pinned"] is None:
        raise ValueError(
            "the searched scene has no ground and no pins: no gait carries the body anywhere, so its travel "
            "is round-off and what survives of it means nothing"
        )
    n_elements = scene.mesh.t.shape[1]
    settings = {"steps": steps, "direction": direction, "objective": objective}
    settings.update(tip_limit=tip_limit, tip_weight=tip_weight)
    plans = [(label, _scaled(data, scene.config, n_elements, f), "reduced") for label, f in LADDER]
    skipped = [] if skipped is None else skipped

    def full_space(label, variant, elements):
        if elements <= full_space_limit:
            plans.append((label, variant, "full"))
        else:
            skipped.append(
                f"{label}: not replayed, {elements} elements, more than the full-space limit {full_space_limit}"
            )

    full_space("full space", data, n_elements)
    if not scene.config["mesh"]["file"]:
        coarse = resolution_scene(data, 0.5)
        plans.append(("half resolution, as searched", coarse, "reduced"))
        full_space("half resolution, full space", coarse, Scene.from_dict(coarse, base_dir=base_dir).mesh.t.shape[1])
    rows = []
    for label, variant, space in plans:
        say(label)
        clock = time.perf_counter()
        built = Scene.from_dict(variant, base_dir=base_dir)
        sim = built.build() if space == "reduced" else built.build_reference(rtol=full_space_rtol, max_iter=2000)
        score = Trial(sim, ramp=built.ramp, **settings).run(gait)  # the scene's ramp, unless the gait has its own
        rows.append(
            {
                "setting": label,
                "space": space,
                "elements": int(built.mesh.t.shape[1]),
                "coordinates": int(sim.rest_state()[0].size),
                "clusters": int(sim.n_clusters),
                "iterations": int(sim.max_iter),
                "mean_iterations": score["mean_iterations"],
                "travel": score["travel"],
                "alignment": score["alignment"],
                "max_tilt_degrees": float(np.degrees(score["max_tilt"])),
                "tipped": bool(score["max_tilt"] > tip_limit),
                "fitness": score["fitness"],
                "physical": bool(score["physical"]),
                "seconds": time.perf_counter() - clock,
            }
        )
    first = rows[0]["travel"]
    for row in rows:
        row["survives"] = row["travel"] / abs(first) if first else float("nan")
    return rows


COLUMNS = (
    "setting",
    "space",
    "elements",
    "coordinates",
    "clusters",
    "iterations",
    "mean_iterations",
    "travel",
    "survives",
    "alignment",
    "max_tilt_degrees",
    "tipped",
    "fitness",
    "physical",
    "seconds",
)


def transfer_search(out_dir, *, full_space_limit: int = 10_000, progress=None) -> dict:
    """Replay a finished search's best gait up the ladder; write ``transfer.csv`` beside it.

    Parameters
    ----------
    out_dir : str or path-like
        A search's folder (``best_gait.toml`` and ``checkpoint.pkl``; an error names either one that cannot be
        read).
    full_space_limit : int
        Largest mesh (elements) replayed in the full space.
    progress : callable, optional
        Called with each setting's label.

    Returns
    -------
    result : dict
        ``rows`` (:func:`replay`'s), ``csv`` (the path written), ``not_replayed``: the full-space replays
        left out, each a sentence saying why (the mesh is over ``full_space_limit``), and ``unfinished``: a
        sentence when the search stopped before its generations were done (its best so far replayed), else None,
        and ``tip_limit_degrees``, the search's tip limit.
    """
    from .optimize import read_checkpoint, search_converged
    from .scene import Scene, read_scene_file

    out_dir = os.fspath(out_dir)
    scene_path, checkpoint = os.path.join(out_dir, "best_gait.toml"), os.path.join(out_dir, "checkpoint.pkl")
    for path in (scene_path, checkpoint):
        if not os.path.isfile(path):
            raise FileNotFoundError(f"{out_dir} holds no finished search: {path} is missing")
    state = read_checkpoint(checkpoint)
    settings = state["settings"]
    unfinished = None
    if state.get("asked", state["generation"]) > state["generation"] and not search_converged(state):
        unfinished = (
            f"the search stopped after {state['generation']} of its {state['asked']} generations: this is its best "
            "so far (continue it with optimize --resume)"
        )
    missing = [key for key in ("steps", "direction", "objective", "tip_limit", "tip_weight") if key not in settings]
    if missing:
        raise ValueError(f"{checkpoint} lacks the search's {', '.join(missing)}: it was written by an older version")
    data = read_scene_file(scene_path)
    scene = Scene.from_dict(data, base_dir=out_dir, source=scene_path)  # every problem named in the file's words
    gait = scene.config["muscles"]["gait"]
    if gait is None:
        raise ValueError(f"{scene_path} holds no muscles.gait: it is not a search's best gait")
    skipped = []
    rows = replay(
        data,
        {**gait, "phase": gait["phase"] or [0.0] * len(gait["amplitude"])},
        steps=settings["steps"],
        direction=settings["direction"],
        objective=settings["objective"],
        tip_limit=settings["tip_limit"],
        tip_weight=settings["tip_weight"],
        base_dir=out_dir,
        full_space_limit=full_space_limit,
        progress=progress,
        skipped=skipped,
    )
    path = os.path.join(out_dir, TRANSFER_FILE)
    with written_whole(path) as tmp, open(tmp, "w", newline="") as f:
        writer = csv.DictWriter(f, COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    return {
        "rows": rows,
        "csv": path,
        "not_replayed": skipped,
        "unfinished": unfinished,
        "tip_limit_degrees": float(np.degrees(settings["tip_limit"])),
    }
