"""One version of the step against another: sim.step timed on states recorded from a scene's run.

    python benchmarks/bench_recorded_states.py [SCENE ...]      (scenes of bench_step.py; default seal-drop)

For A/B comparisons of a change to the step, run against two checkouts in
turn (``PYTHONPATH=CHECKOUT``), several times each. Every 5th state of the
scene's run is recorded; ``sim.step`` is then timed on each recorded state
by the minimum over 15 repeats of 20 steps, and the mean of those minima is
printed in microseconds. The minimum of repeats on fixed inputs moves far
less with this VM's fast and slow spells than a run's median step (see
docs/performance.md), so changes of a few percent show; it says nothing of
the ratio to the reference, which bench_step.py measures.
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

from skfem_modal.muscles import sine_gait  # noqa: E402


def recorded_states(scene, sim, every=5):
    """Every ``every``-th ``(z, z_dot, a)`` of the scene's run from rest."""
    amp, per, ph = scene["gait"]
    z, z_dot, _ = sim.rest_state()
    states = []
    for i in range(scene["steps"]):
        a = sine_gait(i * sim.h, amp, per, ph)
        if i % every == 0:
            states.append((z, z_dot, a))
        z, z_dot = sim.step(z, z_dot, a, velocity=True)
    return states


def mean_least_step_us(sim, states, number=20, repeat=15) -> float:
    total = 0.0
    for state in states:
        sim.step(*state)
        total += min(timeit.repeat(lambda state=state: sim.step(*state), number=number, repeat=repeat)) / number
    return total / len(states) * 1e6


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "scenes",
        nargs="*",
        type=options.one_of(bench_step.SCENE_NAMES),
        default=["seal-drop"],
        metavar="SCENE",
        help=f"{', '.join(bench_step.SCENE_NAMES)} (default: seal-drop)",
    )
    parser.add_argument(
        "--backend", type=options.backend, default="numpy", help="numpy (default), numba, plain or auto"
    )
    args = parser.parse_args()
    for scene in bench_step.scenes(args.scenes):
        sim = bench_step.build(scene, args.backend)
        states = recorded_states(scene, sim)
        print(f"{scene['name']:10s} {mean_least_step_us(sim, states):8.1f} us  ({len(states)} states, {args.backend})")


if __name__ == "__main__":
    main()
