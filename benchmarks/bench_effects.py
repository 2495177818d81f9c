"""What each effect costs per step: the caterpillar with effects added one at a time.

    python benchmarks/bench_effects.py [--steps 300]

Every configuration is a scene that names only its effects; the simulator
builds and steps only those. Prints the per-step median and p90 (microseconds,
the step alone, the first 20 steps left out) and the iterations per step.
"""

from __future__ import annotations

import argparse
import copy
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from machine import machine_line  # noqa: E402
from options import at_least  # noqa: E402

from skfem_modal.scene import DEFAULT_SCENE, Scene  # noqa: E402

BASE = {
    "name": "effects",
    "mesh": {"shape": "caterpillar"},
    "material": {"mu": 1e6, "rho": 1e3},
    "muscles": {"count": 0},
    "time": {"step": 0.01, "steps": 300},
}
MUSCLES = copy.deepcopy(DEFAULT_SCENE["muscles"])
SKIPPED = 20  # first steps left out of the statistics (the first builds caches, numba compiles)

CONFIGS = [
    ("elasticity + inertia", {}),
    ("+ muscles", {"muscles": MUSCLES}),
    ("+ muscles + gravity", {"muscles": MUSCLES, "gravity": {"acceleration": [0.0, -9.8]}}),
    (
        "+ muscles + gravity + ground (Coulomb)",
        {"muscles": MUSCLES, "gravity": {"acceleration": [0.0, -9.8]}, "ground": {"offset": 0.15, "model": "coulomb"}},
    ),
    ("+ muscles + pinned", {"muscles": MUSCLES, "pinned": {"where": ["y == min"]}}),
    ("+ muscles + damping (mass)", {"muscles": MUSCLES, "damping": {"mass": 0.5}}),
    # the corotated stiffness damping: the start rotations and the offset, each step
    ("+ muscles + damping (stiffness)", {"muscles": MUSCLES, "damping": {"stiffness": 0.001}}),
]


def measure(scene, steps):
    sim = scene.build()
    z, z_dot, _ = sim.rest_state()
    times, iterations = [], []
    for i in range(steps):
        a = scene.activation(i * sim.h, sim.ceilings) if sim.n_muscles else None
        start = time.perf_counter()
        z_next = sim.step(z, z_dot, a)
        times.append(time.perf_counter() - start)
        iterations.append(sim.iterations)
        z_dot, z = (z_next - z) / sim.h, z_next
    t = np.array(times[SKIPPED:]) * 1e6
    return sim.effects, np.median(t), np.percentile(t, 90), np.mean(iterations)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--steps", type=at_least(SKIPPED + 1, f"the first {SKIPPED} steps are left out of the statistics"), default=300
    )
    args = parser.parse_args()
    print(machine_line())
    print(f"{'configuration':40s} {'effects held':58s} {'median us':>9s} {'p90 us':>8s} {'iter':>5s}")
    for name, extra in CONFIGS:
        scene = Scene.from_dict({**BASE, **extra, "time": {"step": 0.01, "steps": args.steps}})
        effects, med, p90, it = measure(scene, args.steps)
        print(f"{name:40s} {', '.join(effects):58s} {med:9.1f} {p90:8.1f} {it:5.2f}")


if __name__ == "__main__":
    main()
