"""Where a step's time goes: the driver's calls into the backend, each timed alone.

    python benchmarks/profile_step.py [--only float crawl 3d seal seal-drop] [--backend numpy]

For the scenes of bench_step.py, each simulator is first run into the middle
of its gait; then, on that state, the pieces of one step are each timed in a
tight loop through the backend interface (skfem_modal/solver.py): the
contact's start of step, ``start`` (the step's constant and the activation),
``iterate`` over all the step's iterations (with the contact's projections),
in batches of at most the backend's ``max_batch`` as the driver runs them
(one iteration a call for the plain backend), the driver's stopping test of
each batch, ``finish`` (the 3D certificate) and ``result``. Their sum
against the whole ``sim.step`` leaves the driver's own Python overhead. Nothing here reaches into a backend's buffers.
"""

from __future__ import annotations

import argparse
import os
import sys
import timeit

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bench_step  # noqa: E402
import options  # noqa: E402
from machine import machine_line  # noqa: E402

from skfem_modal.muscles import sine_gait  # noqa: E402


def us(func, number=500):
    return min(timeit.repeat(func, number=number, repeat=5)) / number * 1e6


def iterate(backend, k, contact, batches=None):
    """Run ``k`` iterations in calls of at most ``backend.max_batch``, as the driver does.

    Each call's rows are appended to ``batches`` when it is given (copies: a backend may hand back
    the same buffer each call, as the plain backend does), for the stopping tests.
    """
    done = 0
    while done < k:
        count = min(backend.max_batch, k - done)
        rows = backend.iterate(count, contact)
        if batches is not None:
            batches.append(rows.copy())
        done += count


def profile(scene, backend_name):
    sim = bench_step.build(scene, backend_name)
    amp, per, ph = scene["gait"]
    z, z_dot, _ = sim.rest_state()
    middle = scene["steps"] // 2
    for i in range(middle):
        z, z_dot = sim.step(z, z_dot, sine_gait(i * sim.h, amp, per, ph), velocity=True)
    a = sine_gait(middle * sim.h, amp, per, ph)
    backend, driver, contact = sim.backends[0], sim.solver, sim.model.contact
    sim.step(z, z_dot, a)
    k = sim.iterations

    def start():
        if contact is not None:
            contact.start_step(z, z_dot)
        backend.start(z, z_dot, a)

    start()
    batches = []
    iterate(backend, k, contact, batches)

    def stopping_tests():
        for rows in batches:
            driver._first_stop(rows, backend.start_row())

    parts = {
        "contact start": us(lambda: contact.start_step(z, z_dot)) if contact is not None else 0.0,
        "start": us(lambda: backend.start(z, z_dot, a)),
        f"iterate x {k}": us(lambda: (start(), iterate(backend, k, contact))) - us(start),
        f"stopping test x {len(batches)}": us(stopping_tests),
        "finish": us(lambda: (backend.start(z, z_dot, a), iterate(backend, k, contact), backend.finish(k)))
        - us(lambda: (backend.start(z, z_dot, a), iterate(backend, k, contact))),
        "result": us(lambda: backend.result(k)),
    }
    whole = us(lambda: sim.step(z, z_dot, a))
    calls = f"{len(batches)} call{'s' * (len(batches) > 1)}"
    print(f"## {scene['name']}: {backend.name}, {k} iterations in {calls}, step {whole:.1f} us")
    for name, value in parts.items():
        print(f"    {name:18s} {value:8.1f} us")
    print(f"    {'driver, Python':18s} {whole - sum(parts.values()):8.1f} us  (the rest of sim.step)")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="*", choices=bench_step.SCENE_NAMES, help="scene names (default: all)")
    parser.add_argument(
        "--backend", type=options.backend, default="numpy", help="numpy (default), numba, plain or auto"
    )
    args = parser.parse_args()
    print(machine_line())
    for scene in bench_step.scenes(args.only):
        profile(scene, args.backend)


if __name__ == "__main__":
    main()
