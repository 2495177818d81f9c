"""Gait search with CMA-ES, its rollouts on an Executor (a local pool or dask).

The search space is, per muscle, the gait's amplitude (a fraction of the
muscle's ceiling, in [0, amplitude_max]), period (in [period_min,
period_max]) and phase (in [0, 1], as a fraction of the period), each
rescaled to [0, 1] for CMA-ES (the ``cma`` package). A rollout runs the scene
without output for the search's number of steps; the fitness to maximise is

    fitness = travel - tip_penalty,
    travel = (final centre of mass - initial) . direction,
    tip_penalty = tip_weight * body size * max(0, max_t tilt(t) - tip_limit) / pi,

where ``tilt(t)`` is the angle between the body's up axis, rotated by the
body's overall rotation (the closest rotation to ``sum_i m_i x_i (X_i - C)^T``),
and the world's up axis. With the defaults (limit 60 degrees, weight 10) a
creature that ends upside down loses several body lengths of travel, so
tipping over never pays.

Travel over ground contact is chaotic: a gait 1 % away from a good one can
travel a fraction as far. With ``samples = K > 1`` a candidate's fitness is
the mean over K rollouts, the gait itself and K - 1 copies with every
amplitude and period scaled by ``1 + jitter * N(0, 1)`` and every phase
shifted by ``jitter * N(0, 1)`` (the draws fixed by the seed, the generation
and the candidate), so the search prefers gaits that keep working near
where they were found.

Each rollout is a task; every worker process builds the scene's simulator
once (precompute once per worker, then reused by all its rollouts). Each
generation is checkpointed (the CMA-ES state, numpy's random state, the
history) so ``resume=True`` continues an interrupted search exactly where an
uninterrupted one would be. The same seed gives the same result.
"""

from __future__ import annotations

import csv
import hashlib
import json
import os
import pickle
import time

import numpy as np

from .run import Progress

__all__ = ["GaitSpace", "rollout", "run_search", "scene_to_toml"]

# rollouts of one worker process reuse its simulators: {scene key: (scene, sim, tilt operator)}
_WORKER_SIMS: dict = {}
_WORKER_BUILDS = 0


class GaitSpace:
    """The map between CMA-ES's unit cube and gait parameters.

    Parameters
    ----------
    n_muscles : int
    amplitude_max : float
        Largest amplitude, as a fraction of the ceilings.
    period_min, period_max : float
        Period range (time units).
    """

    def __init__(self, n_muscles: int, amplitude_max: float = 1.0, period_min: float = 0.3, period_max: float = 2.0):
        if n_muscles < 1:
            raise ValueError("a gait search needs at least one muscle")
        if not 0 < period_min < period_max:
            raise ValueError(f"need 0 < period_min < period_max, got {period_min} and {period_max}")
        if not amplitude_max > 0:
            raise ValueError(f"amplitude_max must be positive, got {amplitude_max}")
        self.m = n_muscles
        self.amplitude_max = float(amplitude_max)
        self.period_min, self.period_max = float(period_min), float(period_max)

    def gait(self, u) -> dict:
        """Gait parameters of a point of the unit cube (3 m values)."""
        u = np.clip(np.asarray(u, dtype=np.float64), 0.0, 1.0)
        m = self.m
        return {
            "amplitude": (u[:m] * self.amplitude_max).tolist(),
            "period": (self.period_min + u[m : 2 * m] * (self.period_max - self.period_min)).tolist(),
            "phase": u[2 * m :].tolist(),
        }

    def point(self, gait: dict) -> np.ndarray:
        """The unit-cube point of a gait (clipped into the box)."""
        amp = np.asarray(gait["amplitude"], float) / self.amplitude_max
        per = (np.asarray(gait["period"], float) - self.period_min) / (self.period_max - self.period_min)
        phase = np.asarray(gait.get("phase") or np.zeros(self.m), float) % 1.0
        return np.clip(np.concatenate([amp, per, phase]), 0.0, 1.0)


def _scene_key(data: dict, base_dir) -> str:
    return hashlib.sha256(json.dumps([data, base_dir], sort_keys=True, default=str).encode()).hexdigest()


def _worker_sim(data: dict, base_dir):
    """This process's simulator for a scene, built on first use."""
    global _WORKER_BUILDS
    key = _scene_key(data, base_dir)
    if key not in _WORKER_SIMS:
        from .scene import Scene

        scene = Scene.from_dict(data, base_dir=base_dir)
        sim = scene.build()
        # the body's overall rotation is polar(sum_i m_i x_i (X_i - C)^T): linear in z
        dim, n = sim.mesh.p.shape
        m = sim.mass[::dim]
        X = sim.mesh.p.T
        C = (m[:, None] * X).sum(axis=0) / m.sum()
        W = m[:, None] * (X - C)  # (n, dim)
        Bv = sim.B.reshape(n, dim, -1)
        tilt = np.einsum("nk,nir->ikr", W, Bv).reshape(dim * dim, -1)
        _WORKER_SIMS[key] = (scene, sim, tilt)
        _WORKER_BUILDS += 1
    return _WORKER_SIMS[key]


def rollout(task: dict) -> dict:
    """Run one gait without output (a task for an executor: plain data in and out).

    ``task``: ``scene`` (dict), ``base_dir``, ``steps``, ``gait`` (amplitude,
    period, phase lists), ``direction`` (unit vector), ``tip_limit`` (radians),
    ``tip_weight``.

    Returns
    -------
    result : dict
        ``fitness``, ``travel``, ``penalty``, ``max_tilt`` (radians),
        ``finite``, the worker ``pid`` and how many simulators it has built.
    """
    from .muscles import sine_gait
    from .rotations import polar_rotations
    from .sim import SimulationError, simulate

    scene, sim, tilt_op = _worker_sim(task["scene"], task["base_dir"])
    dim, up = sim.dim, sim.up
    gait = task["gait"]
    amps = np.asarray(gait["amplitude"]) * sim.ceilings
    z = sim.rest_state()[0]
    start = sim.com(z)
    max_tilt, finite = 0.0, True
    try:
        for record in simulate(sim, task["steps"], lambda t: sine_gait(t, amps, gait["period"], gait["phase"])):
            z = record.z
            if record.step % 5 == 0:
                R = polar_rotations((tilt_op @ z).reshape(1, dim, dim))[0]
                max_tilt = max(max_tilt, float(np.arccos(np.clip(R[up, up], -1.0, 1.0))))
    except SimulationError:
        finite = False
    size = float(np.ptp(sim.mesh.p, axis=1).max())
    if not finite:
        return {
            "fitness": -1e3 * size,
            "travel": float("nan"),
            "penalty": float("nan"),
            "max_tilt": float("nan"),
            "finite": False,
            "pid": os.getpid(),
            "builds": _WORKER_BUILDS,
        }
    travel = float((sim.com(z) - start) @ np.asarray(task["direction"], float))
    penalty = float(task["tip_weight"] * size * max(0.0, max_tilt - task["tip_limit"]) / np.pi)
    return {
        "fitness": travel - penalty,
        "travel": travel,
        "penalty": penalty,
        "max_tilt": max_tilt,
        "finite": True,
        "pid": os.getpid(),
        "builds": _WORKER_BUILDS,
    }


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items()) + " }"
    raise TypeError(f"cannot write {type(value).__name__} to TOML")


def scene_to_toml(data: dict) -> str:
    """A scene dict as TOML text (tables for sections, inline tables below that).

    Examples
    --------
    >>> print(scene_to_toml({"name": "x", "time": {"step": 0.01}, "muscles": {"gait": {"period": [1.0]}}}))
    name = "x"
    <BLANKLINE>
    [time]
    step = 0.01
    <BLANKLINE>
    [muscles]
    <BLANKLINE>
    [muscles.gait]
    period = [1.0]
    <BLANKLINE>
    """
    lines = []
    for key, value in data.items():
        if not isinstance(value, dict) and value is not None:
            lines.append(f"{key} = {_toml_value(value)}")

    def table(name, body):
        lines.append("")
        lines.append(f"[{name}]")
        subs = []
        for key, value in body.items():
            if value is None:
                continue
            if isinstance(value, dict) and key != "params" and key != "box":
                subs.append((key, value))
            else:
                lines.append(f"{key} = {_toml_value(value)}")
        for key, value in subs:
            table(f"{name}.{key}", value)

    for key, value in data.items():
        if isinstance(value, dict):
            table(key, value)
    return "\n".join(lines) + "\n"


def _write_atomic(path: str, writer) -> None:
    tmp = path + ".tmp"
    with open(tmp, "wb") as f:
        writer(f)
    os.replace(tmp, path)


def run_search(
    data: dict,
    out_dir,
    *,
    generations: int,
    popsize: int,
    seed: int = 0,
    steps: int | None = None,
    base_dir: str | None = None,
    direction=None,
    space: GaitSpace | None = None,
    sigma0: float = 0.2,
    tip_limit_degrees: float = 60.0,
    tip_weight: float = 10.0,
    samples: int = 1,
    jitter: float = 0.01,
    resume: bool = False,
    executor=None,
    workers: int = 1,
    scheduler: str | None = None,
    progress: bool = False,
    stop_after: int | None = None,
) -> dict:
    """Search the gait that travels furthest, with CMA-ES.

    Parameters
    ----------
    data : dict
        The scene (its muscles, material, effects; its gait is the start).
    out_dir : str or path-like
        Checkpoint, history, best gait scene and plot go here.
    generations, popsize : int
    seed : int
        The same seed gives the same search.
    steps : int, optional
        Rollout length (default: the scene's).
    base_dir : str, optional
        Where the scene's relative paths start.
    direction : array_like, shape (dim,), optional
        Travel direction (default +x).
    space : GaitSpace, optional
        Bounds of the search (default: amplitudes up to 1, periods 0.3 to 2).
    sigma0 : float
        CMA-ES initial step in the unit cube.
    tip_limit_degrees, tip_weight : float
        The tipping penalty (see the module docs).
    samples : int
        Rollouts per candidate; more than one averages over jittered copies
        of its gait (see the module docs).
    jitter : float
        Relative size of those copies' changes.
    resume : bool
        Continue from the checkpoint in ``out_dir``.
    executor : concurrent.futures.Executor, optional
        Default: :func:`skfem_modal.study.make_executor` with ``workers`` / ``scheduler``.
    stop_after : int, optional
        Stop after this many generations of this call (to test resuming).

    Returns
    -------
    result : dict
        ``best`` (gait, fitness, travel: the gait's own rollout, and
        ``travel_spread``, the standard deviation over its samples),
        ``history`` (rows), ``generations``
        done, ``rollouts``, ``seconds``, and the paths ``history_csv``,
        ``best_scene`` (``best_gait.toml``) and ``plot`` (``fitness.png``).
    """
    import cma

    from .scene import Scene
    from .study import make_executor

    scene = Scene.from_dict(data, base_dir=base_dir)  # every scene error first
    m = scene.config["muscles"]["count"]
    space = space or GaitSpace(m)
    if space.m != m:
        raise ValueError(f"the search space has {space.m} muscles, the scene {m}")
    if generations < 1 or popsize < 2:
        raise ValueError(f"need generations >= 1 and popsize >= 2, got {generations} and {popsize}")
    if isinstance(samples, bool) or not isinstance(samples, (int, np.integer)) or samples < 1:
        raise ValueError(f"samples must be a positive integer, got {samples!r}")
    if not 0.0 <= jitter < 0.5:
        raise ValueError(f"jitter must be in [0, 0.5), got {jitter!r}")
    dim = scene.dim
    direction = np.eye(dim)[0] if direction is None else np.asarray(direction, float)
    if direction.shape != (dim,) or not np.linalg.norm(direction) > 0:
        raise ValueError(f"direction must be a non-zero vector of {dim} values")
    direction = direction / np.linalg.norm(direction)
    steps = steps or scene.n_steps
    out_dir = os.fspath(out_dir)
    os.makedirs(out_dir, exist_ok=True)
    checkpoint = os.path.join(out_dir, "checkpoint.pkl")
    # relative paths in the scene are resolved for the workers and the best-gait file
    data = json.loads(json.dumps(data))
    if data.get("mesh", {}).get("file") and base_dir:
        data["mesh"]["file"] = os.path.join(base_dir, data["mesh"]["file"])

    if resume and os.path.isfile(checkpoint):
        with open(checkpoint, "rb") as f:
            state = pickle.load(f)
        made = (state["seed"], state["popsize"], state["steps"], state.get("samples", 1), state.get("jitter", jitter))
        if made != (seed, popsize, steps, samples, jitter):
            raise ValueError("the checkpoint was made with another seed, popsize, rollout length, samples or jitter")
        es, history, done = state["es"], state["history"], state["generation"]
        np.random.set_state(state["numpy_random"])
    else:
        gait = scene.config["muscles"]["gait"]
        x0 = space.point(gait) if gait is not None else np.full(3 * m, 0.5)
        # cma seeds numpy's global generator (seed 0 would mean "time": shift by one)
        es = cma.CMAEvolutionStrategy(
            x0.tolist(), sigma0, {"popsize": popsize, "seed": seed + 1, "bounds": [0.0, 1.0], "verbose": -9}
        )
        history, done = [], 0

    own = executor is None
    close = None
    if own:
        executor, close = make_executor(workers, scheduler)
    bar = Progress(generations, "generations", enabled=progress)
    bar.update(done)
    started = time.perf_counter()
    rollouts = 0
    try:
        this_call = 0
        while done < generations and (stop_after is None or this_call < stop_after):
            points = es.ask()
            gaits = [space.gait(u) for u in points]
            tasks = [
                {
                    "scene": data,
                    "base_dir": base_dir,
                    "steps": steps,
                    "gait": gait if k == 0 else _jittered(gait, jitter, (seed, done, i, k)),
                    "direction": direction.tolist(),
                    "tip_limit": float(np.radians(tip_limit_degrees)),
                    "tip_weight": tip_weight,
                }
                for i, gait in enumerate(gaits)
                for k in range(samples)
            ]
            flat = list(executor.map(rollout, tasks))
            rollouts += len(flat)
            results = [flat[i * samples : (i + 1) * samples] for i in range(len(points))]
            fitness = [float(np.mean([r["fitness"] for r in group])) for group in results]
            es.tell(points, [-f for f in fitness])  # CMA-ES minimises
            done += 1
            this_call += 1
            best = int(np.argmax(fitness))
            history.append(
                {
                    "generation": done,
                    "best_fitness": fitness[best],
                    "best_travel": results[best][0]["travel"],
                    "best_travel_spread": float(np.std([r["travel"] for r in results[best]])),
                    "mean_fitness": float(np.mean(fitness)),
                    "sigma": float(es.sigma),
                    "gait": gaits[best],
                    "workers": sorted({r["pid"] for r in flat}),
                    "builds": max(r["builds"] for r in flat),
                }
            )
            state = {
                "es": es,
                "history": history,
                "generation": done,
                "seed": seed,
                "popsize": popsize,
                "steps": steps,
                "samples": samples,
                "jitter": jitter,
                "numpy_random": np.random.get_state(),
            }
            _write_atomic(checkpoint, lambda f, s=state: pickle.dump(s, f))
            bar.update()
    finally:
        bar.close()
        if own and close is not None:
            close()
    overall = max(history, key=lambda h: h["best_fitness"])
    result = {
        "best": {
            "gait": overall["gait"],
            "fitness": overall["best_fitness"],
            "travel": overall["best_travel"],
            "travel_spread": overall.get("best_travel_spread", 0.0),
            "generation": overall["generation"],
        },
        "history": history,
        "generations": done,
        "rollouts": rollouts,
        "seconds": time.perf_counter() - started,
    }
    result.update(_write_search(out_dir, data, steps, history, overall))
    return result


def _jittered(gait: dict, jitter: float, key) -> dict:
    """A copy of a gait with amplitudes and periods scaled, phases shifted, by ``jitter`` N(0, 1) draws."""
    rng = np.random.default_rng(list(key))
    m = len(gait["amplitude"])
    scale = 1.0 + jitter * rng.standard_normal((2, m))
    return {
        "amplitude": (np.asarray(gait["amplitude"]) * scale[0]).tolist(),
        "period": (np.asarray(gait["period"]) * np.abs(scale[1])).tolist(),
        "phase": ((np.asarray(gait["phase"]) + jitter * rng.standard_normal(m)) % 1.0).tolist(),
    }


def _write_search(out_dir, data, steps, history, overall) -> dict:
    paths = {"history_csv": os.path.join(out_dir, "history.csv")}
    with open(paths["history_csv"], "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(
            ["generation", "best_fitness", "best_travel", "best_travel_spread", "mean_fitness", "sigma", "best_gait"]
        )
        for h in history:
            writer.writerow(
                [
                    h["generation"],
                    repr(float(h["best_fitness"])),
                    repr(float(h["best_travel"])),
                    repr(float(h.get("best_travel_spread", 0.0))),
                    repr(float(h["mean_fitness"])),
                    repr(float(h["sigma"])),
                    json.dumps(h["gait"]),
                ]
            )
    best = json.loads(json.dumps(data))
    best["name"] = f"{data.get('name', 'scene')} (best gait found, travel {overall['best_travel']:.4g})"
    best.setdefault("muscles", {})["gait"] = overall["gait"]
    best["muscles"].pop("table", None)
    best.setdefault("time", {}).pop("duration", None)
    best["time"]["steps"] = steps
    paths["best_scene"] = os.path.join(out_dir, "best_gait.toml")
    with open(paths["best_scene"], "w") as f:
        f.write(scene_to_toml(best))
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(6, 3.5))
        g = [h["generation"] for h in history]
        ax.plot(g, [h["best_fitness"] for h in history], "o-", label="best of the generation")
        ax.plot(g, [h["mean_fitness"] for h in history], "s--", label="mean of the generation")
        ax.plot(g, np.maximum.accumulate([h["best_fitness"] for h in history]), "k-", lw=1, label="best so far")
        ax.set_xlabel("generation")
        ax.set_ylabel("fitness (travel - tipping penalty)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        paths["plot"] = os.path.join(out_dir, "fitness.png")
        fig.savefig(paths["plot"], dpi=110)
        plt.close(fig)
    except ImportError:
        pass
    return paths
