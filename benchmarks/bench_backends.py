"""Which fast backend steps faster: numba's compiled iterations or numpy's (2D buffers, 3D Kronecker form).

    python benchmarks/bench_backends.py [--steps 200] [--sizes 4x10 8x10 8x20 16x60]

``backend="auto"`` takes numba when it is installed, except in 3D from
``solver.KRONECKER_OVER_NUMBA`` clusters on, where numpy's Kronecker form
(when the subspace has it) is the faster one; this measures where that
holds. Scenes: the seal (``../shared/meshes/seal.mesh``, 38689 tetrahedra,
normalised, floating, as examples/seal_crawl.toml but for gravity and ground)
with ``weights x clusters`` skinning weights and clusters (the subspace has
12 coordinates a weight), and the 2D caterpillar of the default scene,
floating. Each is built once per backend from the same scene (the same
subspace, clusters and muscles) and both step the scene's gait, taking turns
every 10 steps; the median step of each (the first 20 steps left out: numba
compiles at its first step) and what ``auto`` chooses are printed. Needs
numba (the ``fast`` extra). One BLAS thread.
"""

from __future__ import annotations

import argparse
import copy
import os
import sys
import time
import tomllib

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from machine import machine_line  # noqa: E402
from options import NUMBA_MISSING, at_least, by  # noqa: E402

from skfem_modal import _accel  # noqa: E402
from skfem_modal.scene import DEFAULT_SCENE, Scene  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
EXAMPLES = os.path.join(HERE, "..", "examples")
SEAL = os.path.join(HERE, "..", "..", "shared", "meshes", "seal.mesh")
BLOCK = 10  # steps a backend runs before the other takes its turn
SKIPPED = 20  # first steps left out of the medians (numba compiles its kernels at the first)


def seal(weights, clusters):
    """The seal's example scene, floating, with ``weights`` skinning weights and ``clusters`` clusters."""
    with open(os.path.join(EXAMPLES, "seal_crawl.toml"), "rb") as f:
        data = tomllib.load(f)
    data["mesh"] = {"file": os.path.abspath(SEAL), "normalize": True}
    data["subspace"] = {"weights": weights, "clusters": clusters}
    del data["gravity"], data["ground"]
    return data


def caterpillar():
    """The default scene's caterpillar, floating."""
    data = copy.deepcopy(DEFAULT_SCENE)
    data.pop("gravity", None)
    data.pop("ground", None)
    return data


def medians(data, steps):
    """Median ms a step of each backend, interleaved, and the backend ``auto`` picks."""
    scene = Scene.from_dict(data, base_dir=EXAMPLES)
    sims = {name: scene.build(backend=name) for name in ("numba", "numpy")}
    states = {name: sim.rest_state()[:2] for name, sim in sims.items()}
    seconds = {name: [] for name in sims}
    for first in range(0, steps, BLOCK):
        for name, sim in sims.items():
            z, z_dot = states[name]
            for i in range(first, min(first + BLOCK, steps)):
                a = scene.activation(i * sim.h, sim.ceilings)
                clock = time.perf_counter()
                z, z_dot = sim.step(z, z_dot, a, velocity=True)
                seconds[name].append(time.perf_counter() - clock)
            states[name] = (z, z_dot)
    sim = sims["numpy"]
    sim.backend = "auto"  # a live setting: the backends made again, nothing else
    typical = {name: 1e3 * float(np.median(s[SKIPPED:])) for name, s in seconds.items()}
    return typical, sim.backend_used, sim.model.space.r


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--steps", type=at_least(SKIPPED + 1, f"the first {SKIPPED} steps are left out of the medians"), default=200
    )
    parser.add_argument("--sizes", nargs="*", type=by("WEIGHTS", "CLUSTERS"), metavar="WEIGHTSxCLUSTERS",
                        default=[(4, 10), (8, 10), (6, 15), (8, 20), (12, 40), (16, 60)],
                        help="the seal's weights x clusters")  # fmt: skip
    args = parser.parse_args()
    if not _accel.AVAILABLE:
        sys.exit(f"bench_backends needs numba: {NUMBA_MISSING}")
    import numba

    print(machine_line(f"numba {numba.__version__}", f"{args.steps} steps, median after the first {SKIPPED}"))
    print(f"{'scene':22s} {'r':>4s} {'numba ms':>9s} {'numpy ms':>9s} {'numpy/numba':>12s}  auto")
    cases = [("caterpillar (2D)", caterpillar())]
    for weights, clusters in args.sizes:
        cases.append((f"seal {weights} w x {clusters} cl", seal(weights, clusters)))
    for label, data in cases:
        times, auto, r = medians(data, args.steps)
        ratio = times["numpy"] / times["numba"]
        print(f"{label:22s} {r:4d} {times['numba']:9.3f} {times['numpy']:9.3f} {ratio:12.2f}  {auto}", flush=True)


if __name__ == "__main__":
    main()
