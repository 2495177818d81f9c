"""Precompute time with and without the BLAS thread limit, idle and beside a busy process.

    python benchmarks/bench_blas_threads.py [--runs 10] [--cases small creature default]

The precompute runs the modal analysis in a second thread beside the rest;
both call BLAS, and OpenBLAS starts a thread per core for each caller. This
measures what a user sees: each run is a fresh process (as a ``skfem-modal
run``) timing its first ``scene.build()``, in the user's default environment
(``OPENBLAS_NUM_THREADS`` and ``OMP_NUM_THREADS`` unset, unlike the other
benchmarks). Three ways, interleaved run by run:

- ``no limit``: ``blas_threads=None`` (what the package did before);
- ``threadpoolctl``: the default, with threadpoolctl installed;
- ``fallback``: the default without threadpoolctl (OpenBLAS's own setter).

Twice: on an idle machine, and beside one busy process (a pure-Python loop,
as another user's job on a 2-core machine). Prints median, min, max and
max/min of each.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

import numpy as np
from machine import machine_line
from options import at_least

CASES = {
    "small": {"mesh": {"shape": "caterpillar", "params": {"nx": 18, "ny": 14}}},  # 218 vertices
    "creature": {
        "mesh": {"shape": "creature", "params": {"cell": 0.2}},  # 182 vertices, 3D
        "gravity": {"acceleration": [0.0, 0.0, -9.8]},
    },
    "default": {},  # the tutorial's caterpillar, 1719 vertices
}

BUILD = r"""
import json, sys, time
if sys.argv[2] == "fallback":
    sys.modules["threadpoolctl"] = None  # as without the package
from skfem_modal.scene import DEFAULT_SCENE, Scene
from skfem_modal.sim import ModalMuscle
changes = json.loads(sys.argv[1])
scene = Scene.from_dict({**DEFAULT_SCENE, **changes})
if sys.argv[2] == "no limit":
    build = ModalMuscle.from_mesh
    ModalMuscle.from_mesh = lambda *a, **k: build(*a, **{**k, "blas_threads": None})
clock = time.perf_counter()
scene.build()
print(json.dumps({"seconds": time.perf_counter() - clock}))
"""

WAYS = ("no limit", "threadpoolctl", "fallback")


def build_seconds(case: dict, way: str) -> float:
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}
    out = subprocess.run(
        [sys.executable, "-c", BUILD, json.dumps(case), way], capture_output=True, text=True, env=env, check=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])["seconds"]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=at_least(1), default=10)
    parser.add_argument("--cases", nargs="*", default=list(CASES), choices=list(CASES))
    args = parser.parse_args()
    try:
        import threadpoolctl  # noqa: F401
    except ImportError:
        sys.exit("needs threadpoolctl for the 'threadpoolctl' way: pip install threadpoolctl")
    print(
        machine_line(
            "first scene.build() of a fresh process", f"{args.runs} runs each", "BLAS/OpenMP thread variables unset"
        )
    )
    for load in ("idle", "beside a busy process"):
        busy = subprocess.Popen([sys.executable, "-c", "while True: pass"]) if load != "idle" else None
        try:
            for name in args.cases:
                times = {way: [] for way in WAYS}
                for _ in range(args.runs):
                    for way in WAYS:
                        times[way].append(build_seconds(CASES[name], way))
                for way in WAYS:
                    t = np.array(times[way])
                    print(
                        f"{load:22s} {name:9s} {way:14s} median {np.median(t):6.3f} s  min {t.min():6.3f}  "
                        f"max {t.max():6.3f}  max/min {t.max() / t.min():5.2f}"
                    )
                sys.stdout.flush()
        finally:
            if busy is not None:
                busy.kill()
                busy.wait()


if __name__ == "__main__":
    main()
