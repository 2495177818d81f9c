"""Rollouts per second of the gait search, with 1 and 2 worker processes.

    python benchmarks/bench_optimize.py [--rollouts 96] [--steps 450]

Each rollout is the tutorial's crawl scene run without output for ``--steps``
steps with a random gait; every worker builds the simulator once and reuses
it. Two rates: "with start-up" counts everything from an empty pool (process
start, imports, the one precompute per worker, as a search pays once);
"steady" is a second batch on the warm pool, what every later generation of
a search runs at.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from skfem_modal.optimize import GaitSpace, rollout  # noqa: E402
from skfem_modal.scene import DEFAULT_SCENE  # noqa: E402
from skfem_modal.study import make_executor  # noqa: E402


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rollouts", type=int, default=96)
    parser.add_argument("--steps", type=int, default=450)
    args = parser.parse_args()
    space = GaitSpace(4)
    rng = np.random.default_rng(0)
    tasks = [
        {
            "scene": DEFAULT_SCENE,
            "base_dir": None,
            "steps": args.steps,
            "gait": space.gait(rng.random(12)),
            "direction": [1.0, 0.0],
            "tip_limit": np.radians(60.0),
            "tip_weight": 10.0,
        }
        for _ in range(args.rollouts)
    ]
    print(
        f"# {platform.node()}, {os.cpu_count()} cores, {time.strftime('%Y-%m-%d')}; {args.rollouts} rollouts of "
        f"{args.steps} steps, the caterpillar crawl"
    )
    print(
        f"{'workers':>7s} {'start-up s':>10s} {'rollouts/s with start-up':>24s} "
        f"{'steady rollouts/s':>17s} {'speed-up':>8s}"
    )
    base = None
    for workers in (1, 2):
        executor, close = make_executor(workers)
        try:
            start = time.perf_counter()
            first = list(executor.map(rollout, tasks))
            cold = time.perf_counter() - start
            start = time.perf_counter()
            second = list(executor.map(rollout, tasks))
            warm = time.perf_counter() - start
        finally:
            close()
        assert all(r["finite"] for r in first + second)
        assert [r["fitness"] for r in first] == [r["fitness"] for r in second]
        steady = args.rollouts / warm
        base = base or steady
        startup = cold - warm
        print(f"{workers:7d} {startup:10.2f} {args.rollouts / cold:24.2f} {steady:17.2f} {steady / base:8.2f}")


if __name__ == "__main__":
    main()
