"""Rollouts per second of the gait search, with 1 and 2 worker processes.

    python benchmarks/bench_optimize.py [--rollouts 24] [--steps 450]

Each rollout is the tutorial's crawl scene run without output for ``--steps``
steps with a random gait; every worker builds the simulator once (its
precompute is counted, as in a real search) and reuses it.
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
    parser.add_argument("--rollouts", type=int, default=24)
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
    print(f"{'workers':>7s} {'seconds':>8s} {'rollouts/s':>10s} {'speed-up':>8s}")
    base = None
    for workers in (1, 2):
        executor, close = make_executor(workers)
        try:
            start = time.perf_counter()
            results = list(executor.map(rollout, tasks))
            seconds = time.perf_counter() - start
        finally:
            close()
        assert all(r["finite"] for r in results)
        rate = args.rollouts / seconds
        base = base or rate
        print(f"{workers:7d} {seconds:8.2f} {rate:10.2f} {rate / base:8.2f}")


if __name__ == "__main__":
    main()
