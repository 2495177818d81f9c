"""Faster local/global iterations, side by side: warm starts, Anderson, Newton (issue 20).

    python benchmarks/bench_iterations.py [--rounds 5] [--steps 100]

For each scene, every setting steps the same simulator (its settings
assigned live) through the same gait: iterations per step, milliseconds per
step (the lowest per-round median of ``--rounds`` rounds taken in turn, so
all see the machine's fast and slow spells alike), the ratio to the first
setting of the scene, and the trajectory's distance from the converged one
(``off converged``: the Euclidean norm of the difference of z, all steps
together, over that of the converged trajectory's z from its first step's,
the distance it moved): how far from converged the setting stops.

Scenes:
  * caterpillar: the study's floating caterpillar (1719 vertices, 8 weights, 20 clusters, h = 0.02)
  * caterpillar stiff: the same, ten times stiffer (mu = 1e6, the tutorial crawl's):
    the plain iteration converges slowly
  * creature: the 3D creature of examples/creature_float.toml (1180 vertices, 8 weights, 20 clusters)
  * caterpillar full space, creature full space: every DOF, a rotation per element (the
    study's references), to 1e-10
"""

from __future__ import annotations

import argparse
import copy
import os
import sys
import tomllib

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from machine import machine_line  # noqa: E402
from options import at_least  # noqa: E402

from skfem_modal import _accel  # noqa: E402
from skfem_modal.scene import Scene  # noqa: E402
from skfem_modal.sim import simulate  # noqa: E402
from skfem_modal.study import FLOATING_CATERPILLAR  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
CREATURE = os.path.join(HERE, "..", "examples", "creature_float.toml")

PLAIN = dict(warm_start=False, acceleration="none")
WARM = dict(PLAIN, warm_start=True)


def until(rtol):
    """Iterate until the relative change is below ``rtol``."""
    return dict(max_iter=5000, tol=0.0, rtol=rtol)


SUBSPACE_SETTINGS = [
    ("plain, 10 iterations (the default)", dict(PLAIN, max_iter=10, tol=1e-6, rtol=0.0)),
    ("warm start, 10 iterations", dict(WARM, max_iter=10, tol=0.0, rtol=0.0)),
    ("plain, rtol 1e-6", dict(PLAIN, **until(1e-6))),
    ("warm start, rtol 1e-6", dict(WARM, **until(1e-6))),
    ("warm start + anderson, rtol 1e-6", dict(WARM, acceleration="anderson", **until(1e-6))),
    ("warm start + newton, rtol 1e-6", dict(WARM, acceleration="newton", **until(1e-6))),
]
FULL_SETTINGS = [
    ("plain, rtol 1e-10 (the study's reference)", dict(PLAIN, **until(1e-10))),
    ("warm start, rtol 1e-10", dict(WARM, **until(1e-10))),
    ("warm start + anderson, rtol 1e-10", dict(WARM, acceleration="anderson", **until(1e-10))),
]


def scenes():
    stiff = copy.deepcopy(FLOATING_CATERPILLAR)
    stiff["material"]["mu"] = 1e6
    with open(CREATURE, "rb") as f:
        creature = tomllib.load(f)
    for name, data, full in [
        ("caterpillar", FLOATING_CATERPILLAR, False),
        ("caterpillar stiff", stiff, False),
        ("creature", creature, False),
        ("caterpillar full space", FLOATING_CATERPILLAR, True),
        ("creature full space", creature, True),
    ]:
        scene = Scene.from_dict(data, base_dir=os.path.dirname(CREATURE))
        sim = scene.build_reference() if full else scene.build()
        yield name, scene, sim, FULL_SETTINGS if full else SUBSPACE_SETTINGS


def run(sim, gait, settings, steps):
    for key, value in settings.items():
        setattr(sim, key, value)
    z, z_dot, _ = sim.rest_state()
    sim.step(z, z_dot, gait(0.0))  # compiled kernels, caches
    states, seconds, iterations = [], [], []
    for record in simulate(sim, steps, gait):
        states.append(record.z)
        seconds.append(record.seconds)
        iterations.append(record.iterations)
    return np.array(states), np.median(seconds) * 1e3, float(np.mean(iterations))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rounds", type=at_least(1), default=5)
    parser.add_argument("--steps", type=at_least(2, "the distance moved is measured from the first step"), default=100)
    args = parser.parse_args()
    print(machine_line(f"numba {'yes' if _accel.AVAILABLE else 'no'}", f"{args.steps} steps, {args.rounds} rounds"))
    print(f"{'scene':24s} {'setting':42s} {'iterations':>10s} {'ms/step':>9s} {'ratio':>7s} {'off converged':>14s}")
    for name, scene, sim, settings in scenes():
        gait = lambda t, sim=sim, scene=scene: scene.activation(t, sim.ceilings)  # noqa: E731
        converged, _, _ = run(sim, gait, dict(PLAIN, max_iter=20000, tol=0.0, rtol=1e-12), args.steps)
        motion = np.linalg.norm(converged - converged[0])
        best = {label: np.inf for label, _ in settings}
        found = {}
        for _ in range(args.rounds):
            for label, setting in settings:
                states, ms, its = run(sim, gait, setting, args.steps)
                best[label] = min(best[label], ms)
                found[label] = (its, np.linalg.norm(states - converged) / motion)
        first = best[settings[0][0]]
        for label, _ in settings:
            its, off = found[label]
            print(f"{name:24s} {label:42s} {its:10.1f} {best[label]:9.4f} {best[label] / first:6.2f}x {off:14.1e}")
        sys.stdout.flush()


if __name__ == "__main__":
    main()
