"""How precompute and step time scale: mesh size, subspace size, clusters, contact points.

    python benchmarks/bench_scaling.py [--steps 100] [--only mesh weights clusters contacts]

Step times are medians over ``--steps`` steps of the tutorial's scenes (floating, or
crawling for the contact points), numpy and, when installed, numba; precompute
is ``ModalMuscle.from_mesh`` in one thread.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from machine import machine_line  # noqa: E402
from options import at_least  # noqa: E402

import skfem_modal as sm  # noqa: E402
from skfem_modal import _accel  # noqa: E402
from skfem_modal.muscles import sine_gait  # noqa: E402
from skfem_modal.sim import ModalMuscle  # noqa: E402

GAIT = ([0.45, 0.35, 0.25, 0.15], [1.2, 0.8, 1.0, 0.6], [0.0, 0.25, 0.5, 0.1])
MESHES = [(35, 17), (70, 34), (140, 68), (280, 136)]  # the caterpillar's nx, ny of the mesh sweep


def step_ms(sim, steps=100):
    z, z_dot, _ = sim.rest_state()
    sim.step(z, z_dot, np.zeros(sim.n_muscles))
    amps = np.asarray(GAIT[0]) * sim.ceilings
    times = []
    for i in range(steps):
        a = sine_gait(i * sim.h, amps, GAIT[1], GAIT[2])
        start = time.perf_counter()
        z_next = sim.step(z, z_dot, a)
        times.append(time.perf_counter() - start)
        z_dot, z = (z_next - z) / sim.h, z_next
    return 1e3 * float(np.median(times))


def build(mesh, backend="numpy", **kw):
    kw = {"n_muscles": 4, "mu": 1e6, "rho": 1e3, "h": 0.01, "parallel": False, **kw}
    start = time.perf_counter()
    sim = ModalMuscle.from_mesh(mesh, backend=backend, **kw)
    return sim, time.perf_counter() - start


def row(label, steps, **kw):
    mesh = kw.pop("mesh", None) or sm.caterpillar()
    sim, pre = build(mesh, **kw)
    out = (
        f"| {label} | {mesh.p.shape[1]} | {sim.B.shape[1]} | {sim.n_clusters} | {sim.contact_vertices.size} "
        f"| {pre:.2f} | {step_ms(sim, steps):.3f} |"
    )
    if _accel.AVAILABLE:
        fast, _ = build(mesh, backend="numba", **kw)
        out += f" {step_ms(fast, steps):.3f} |"
    print(out, flush=True)


def crawls():
    """The contact points' sweep: the caterpillar crawling, ``(label, keywords of build)``."""
    mesh = sm.caterpillar()
    ground = float(mesh.p[1].min()) - 0.15
    for p in (10, 30, 100, 300):
        yield f"contacts={p} (crawl)", dict(mesh=mesh, gravity=[0.0, -9.8], ground=ground, n_contacts=p)


# each sweep: (label, keywords of build) of its rows, made when it runs (the meshes take a while)
SWEEPS = {
    "mesh": lambda: ((f"mesh nx={nx}", dict(mesh=sm.caterpillar(nx=nx, ny=ny))) for nx, ny in MESHES),
    "weights": lambda: ((f"weights={w}", dict(n_weights=w)) for w in (4, 8, 16, 24)),
    "clusters": lambda: ((f"clusters={c}", dict(n_clusters=c)) for c in (5, 20, 80, 320)),
    "contacts": crawls,
}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=at_least(1), default=100, help="steps a step time is the median of")
    parser.add_argument("--only", nargs="*", choices=list(SWEEPS), help="sweeps to run (default: all)")
    args = parser.parse_args()
    print(machine_line(f"median of {args.steps} steps"))
    print(
        "| sweep | vertices | subspace | clusters | contact points | precompute s | step ms (numpy) |"
        + (" step ms (numba) |" if _accel.AVAILABLE else "")
    )
    print("|---|---|---|---|---|---|---|" + ("---|" if _accel.AVAILABLE else ""))
    for name, sweep in SWEEPS.items():
        if not args.only or name in args.only:
            for label, kw in sweep():
                row(label, args.steps, **kw)


if __name__ == "__main__":
    main()
