"""Modal analysis speed: skfem_modal and, when installed, SimKit, in one run.

    python benchmarks/bench_modal.py [--repeat 5]

Cases (issue targets in brackets):
  * caterpillar refined to 25975 vertices (nx=280, ny=136), 7 modes
    [at most half of SimKit's time; SimKit reference: 1.70 s]
  * 3D box of 24000 tetrahedra (40 x 10 x 10 cells), 10 modes [at most 1.5 s]

Prints the median and min of each, the ratio, and the lowest elastic
eigenvalues, so the comparison is of equal answers: when the elastic
eigenvalues differ from SimKit's (relative 1e-6), the script exits non-zero
after the table, naming the case. Install SimKit with
``pip install -e '.[bench]'``; without it only our times are printed.
Run with one BLAS thread for comparable numbers (OMP_NUM_THREADS=1).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import sys  # noqa: E402

import numpy as np  # noqa: E402
from machine import machine_line  # noqa: E402
from options import at_least  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from skfem_modal import box3d, caterpillar, linear_modal_analysis  # noqa: E402

RTOL = 1e-6  # the most relative difference of an elastic eigenvalue from SimKit's


def cases():
    """``(name, mesh, modes, rigid modes)`` of each case timed."""
    return [
        ("caterpillar 25975 vertices, 7 modes", caterpillar(nx=280, ny=136), 7, 3),
        ("box 4961 vertices / 24000 tets, 10 modes", box3d(40, 10, 10, (4.0, 1.0, 1.0)), 10, 6),
    ]


def timed(func, repeat):
    times, result = [], None
    for _ in range(repeat):
        start = time.perf_counter()
        result = func()
        times.append(time.perf_counter() - start)
    return times, result


def simkit_modal(mesh, k):
    import warnings

    import simkit as sk
    from reference_impl import oriented

    warnings.filterwarnings("ignore")
    X = np.ascontiguousarray(mesh.p.T)
    T = oriented(X, np.ascontiguousarray(mesh.t.T))  # SimKit's volumes are signed
    return lambda: sk.linear_modal_analysis(X, T, k)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=at_least(1), default=5)
    parser.add_argument("--no-simkit", action="store_true", help="time only skfem_modal")
    args = parser.parse_args()
    try:
        import simkit  # noqa: F401

        have_simkit = not args.no_simkit
    except ImportError:
        have_simkit = False
    print(machine_line())
    differs = []  # the cases whose eigenvalues are not SimKit's
    print(f"{'case':42s} {'impl':10s} {'median s':>9s} {'min s':>7s} {'ratio':>6s}  lowest elastic eigenvalues")
    for name, mesh, k, n_rigid in cases():
        ours, (values, _) = timed(lambda mesh=mesh, k=k: linear_modal_analysis(mesh, k), args.repeat)
        ours_med = statistics.median(ours)
        print(
            f"{name:42s} {'ours':10s} {ours_med:9.3f} {min(ours):7.3f} {'':>6s}  "
            f"{np.round(values[n_rigid : n_rigid + 3], 6)}"
        )
        if have_simkit:
            ref, (ref_values, _) = timed(simkit_modal(mesh, k), min(args.repeat, 3))
            ref_med = statistics.median(ref)
            ref_values = np.sort(ref_values)
            valid = np.allclose(ref_values[n_rigid:], values[n_rigid:], rtol=RTOL)
            print(
                f"{'':42s} {'SimKit':10s} {ref_med:9.3f} {min(ref):7.3f} {ref_med / ours_med:6.2f}  "
                f"{np.round(ref_values[n_rigid : n_rigid + 3], 6)}{'' if valid else '  (differs)'}"
            )
            if not valid:
                differs.append(name)
        sys.stdout.flush()
    # after the whole table: a time is only comparable with SimKit's for the same answer
    if differs:
        sys.exit(f"bench_modal: the elastic eigenvalues differ from SimKit's (rtol {RTOL:.0e}): {'; '.join(differs)}")


if __name__ == "__main__":
    main()
