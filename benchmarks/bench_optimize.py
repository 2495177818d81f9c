"""Rollouts per second of the gait search, with 1 and 2 worker processes, on a real creature.

    python benchmarks/bench_optimize.py [--scene examples/seal_crawl.toml] [--rollouts 64] [--steps 300]

The scene's simulator is built once here (the seal: 38689 tetrahedra) and
sent once to each worker, as a search does (:class:`skfem_modal.rollouts.Rollouts`);
each rollout runs ``--steps`` steps of a random gait and is scored. Two
rates per row: "with start-up" counts everything from an empty pool
(process start, imports, receiving the simulator: what a search pays once);
"steady" is a second batch on the warm pool, what every later generation
runs at. The last row is the way before the precompute was shared: every
worker builds the simulator itself from the scene. Every row must give the
same scores (asserted). Run it alone (``flock -x /tmp/skfem_cpu.lock``).
"""

from __future__ import annotations

import argparse
import os
import time
import tomllib
import warnings

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from machine import machine_line  # noqa: E402
from options import at_least  # noqa: E402

from skfem_modal.optimize import GaitSpace  # noqa: E402
from skfem_modal.rollouts import Rollouts, Trial  # noqa: E402
from skfem_modal.scene import Scene  # noqa: E402
from skfem_modal.study import make_executor  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default=os.path.join(HERE, "..", "examples", "seal_crawl.toml"))
    parser.add_argument("--rollouts", type=at_least(1), default=64)
    parser.add_argument("--steps", type=at_least(1), default=300)
    args = parser.parse_args()
    if not os.path.isfile(args.scene):
        parser.error(f"argument --scene: expected a scene file (TOML), got {args.scene!r}: no such file")
    with open(args.scene, "rb") as f:
        data = tomllib.load(f)
    base_dir = os.path.dirname(os.path.abspath(args.scene))
    if data.get("mesh", {}).get("file"):
        data["mesh"]["file"] = os.path.join(base_dir, data["mesh"]["file"])
    with warnings.catch_warnings():  # the scene's warnings, if any, come with the trial's build below
        warnings.simplefilter("ignore")
        settings = _settings(Scene.from_dict(data, base_dir=base_dir), args.steps)
    clock = time.perf_counter()
    trial = Trial.from_scene(data, **settings)
    precompute = time.perf_counter() - clock
    space = GaitSpace(trial.sim.n_muscles)
    rng = np.random.default_rng(0)
    gaits = [space.gait(rng.random(3 * space.m)) for _ in range(args.rollouts)]
    sim = trial.sim
    print(
        machine_line(
            f"{args.rollouts} rollouts of {args.steps} steps, {os.path.basename(args.scene)} "
            f"({sim.mesh.t.shape[1]} elements, {sim.B.shape[1]} coordinates, backend {sim.backend_used})",
            f"precompute {precompute:.2f} s, once",
        )
    )
    print(
        f"{'workers':>28s} {'start-up s':>10s} {'rollouts/s with start-up':>24s} "
        f"{'steady rollouts/s':>17s} {'speed-up':>8s}"
    )
    base, scores, rates = None, None, {}
    rows = [(1, "shared"), (2, "shared"), (2, "each builds")]
    for workers, how in rows:
        if how == "shared":
            rollouts = Rollouts(trial, workers=workers)
        else:
            executor, close = make_executor(workers)
            recipe = {"data": data, **settings}
            rollouts = Rollouts(trial, executor=executor, recipe=recipe)
        try:
            start = time.perf_counter()
            first = rollouts.map(gaits)
            cold = time.perf_counter() - start + rollouts.startup_seconds
            start = time.perf_counter()
            second = rollouts.map(gaits)
            warm = time.perf_counter() - start
        finally:
            rollouts.close()
            if how != "shared":
                close()
        found = [r["fitness"] for r in first]
        assert all(r["finite"] for r in first + second)
        assert found == [r["fitness"] for r in second]
        assert scores is None or found == scores, "the scores depend on the workers"
        scores = found
        steady = args.rollouts / warm
        base = base or steady
        rates[workers, how] = steady
        label = f"{workers} ({'precompute sent' if how == 'shared' else 'each worker builds'})"
        print(f"{label:>28s} {cold - warm:10.2f} {args.rollouts / cold:24.2f} {steady:17.2f} {steady / base:8.2f}")
    budget = 200 * 16
    print(f"# the paper's budget, {budget} rollouts, at the 2-worker steady rate: {budget / rates[2, 'shared']:.0f} s")


def _settings(scene: Scene, steps: int) -> dict:
    """Rollout length and a travel direction along the scene's first horizontal axis (not its up axis).

    Parameters
    ----------
    scene : skfem_modal.scene.Scene
        The scene, whose mesh gives the dimension (a floating scene has no gravity to tell it).
    steps : int
        Steps a rollout.

    Returns
    -------
    settings : dict
        ``steps`` and ``direction``, for :class:`skfem_modal.rollouts.Trial`.
    """
    axis = next(i for i in range(scene.dim) if i != scene.up)
    return {"steps": steps, "direction": np.eye(scene.dim)[axis].tolist()}


if __name__ == "__main__":
    main()
