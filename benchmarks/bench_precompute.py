"""Precompute time and peak memory against the reference implementation.

    python benchmarks/bench_precompute.py [--sizes 26k 103k box] [--no-reference]

Everything a crawling scene needs before its first step: linear modes (4
muscles), skinning eigenmodes (8 weights), mass orthonormalisation, 20
clusters, 30 contact points and the simulator set-up with gravity and ground
contact. Each implementation runs in a fresh process (so peak memory is its
own: ``ru_maxrss`` of that process, which includes the interpreter and
imports); stage timings come from inside. The reference is SimKit 0.1.8 with
the tutorial's pipeline and ModalMuscle class (see reference_impl.py).

Cases: the caterpillar refined to 25975 vertices (nx=280, ny=136) and to
102915 vertices (nx=560, ny=272), and the 24000-tetrahedron box (floating);
at the paper's scale, real y-up creatures from ../shared/meshes, normalised
and crawling: the elephant (29011 tetrahedra), the seal (38689), the
elephant refined at every fourth element (99965) and everywhere (232088;
not run unless named: the reference takes a minute and 7 GB there). Each case's mesh is made
the same way for both implementations (``case_mesh``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

# one BLAS thread, as the other benchmarks, for this process and so for its children (they inherit it)
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from machine import machine_line  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))

SHARED = os.path.join(HERE, "..", "..", "shared", "meshes")

CASES = {
    "26k": dict(shape="caterpillar", params=dict(nx=280, ny=136), crawl=True),
    "103k": dict(shape="caterpillar", params=dict(nx=560, ny=272), crawl=True),
    "box": dict(shape="box3d", params=dict(nx=40, ny=10, nz=10, size=(4.0, 1.0, 1.0)), crawl=False),
    "elephant": dict(file="elephant.mesh", refine_every=0, crawl=True, up=1),
    "seal": dict(file="seal.mesh", refine_every=0, crawl=True, up=1),
    "100k": dict(file="elephant.mesh", refine_every=4, crawl=True, up=1),
    "232k": dict(file="elephant.mesh", refine_every=1, crawl=True, up=1),
}
DEFAULT = ["26k", "103k", "box", "seal", "100k"]


def case_mesh(case: dict, shared: str = SHARED):
    """The case's mesh: a built-in shape, or a real mesh file refined (every k-th element) and normalised."""
    import numpy as np

    from skfem_modal.mesh import builtin_mesh, load_mesh, normalize_and_center

    if "file" not in case:
        return builtin_mesh(case["shape"], **case["params"])
    mesh = load_mesh(os.path.join(shared, case["file"]))
    if case["refine_every"] == 1:
        mesh = mesh.refined()  # every tetrahedron into 8
    elif case["refine_every"]:
        mesh = mesh.refined(np.arange(0, mesh.t.shape[1], case["refine_every"]))
    return normalize_and_center(mesh)


OURS = r"""
import json, resource, sys, time
import numpy as np
sys.path.insert(0, sys.argv[2])
from bench_precompute import case_mesh
from skfem_modal.sim import ModalMuscle
case = json.loads(sys.argv[1])
mesh = case_mesh(case)
dim = mesh.p.shape[0]
up = case.get("up", dim - 1)
gravity = [0.0] * dim
gravity[up] = -9.8
clock = time.perf_counter()
kwargs = dict(gravity=gravity, ground=float(mesh.p[up].min()) - 0.15, up=up) if case["crawl"] else {}
sim = ModalMuscle.from_mesh(mesh, n_muscles=4, n_weights=8, n_clusters=20, mu=1e6, rho=1e3, h=0.01,
                            parallel=case["parallel"], **kwargs)
total = time.perf_counter() - clock
print(json.dumps({"total": total, "stages": sim.timings, "elements": int(mesh.t.shape[1]),
                  "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""

REFERENCE = r"""
import json, resource, sys, time, warnings
import numpy as np, scipy.sparse as sps
sys.path.insert(0, sys.argv[2])
import reference_impl
import simkit as sk
from bench_precompute import case_mesh
ModalMuscle = reference_impl.load_modal_muscle(sys.argv[3])
warnings.filterwarnings("ignore"); np.seterr(all="ignore")
case = json.loads(sys.argv[1])
mesh = case_mesh(case)
X = np.ascontiguousarray(mesh.p.T)
T = reference_impl.oriented(X, np.ascontiguousarray(mesh.t.T))
n, dim = X.shape
n_rigid = 3 if dim == 2 else 6
stages = {}
clock = time.perf_counter(); start = clock
E, D = sk.linear_modal_analysis(X, T, n_rigid + 4)
stages["modal_analysis"] = time.perf_counter() - clock; clock = time.perf_counter()
W, _E, B = sk.skinning_eigenmodes(X, T, 8)
stages["skinning_eigenmodes"] = time.perf_counter() - clock; clock = time.perf_counter()
B = sk.orthonormalize(B, M=sps.kron(sk.massmatrix(X, T), sps.identity(dim)))
stages["orthonormalize"] = time.perf_counter() - clock; clock = time.perf_counter()
_cI, _cW, l = sk.spectral_cubature(X, T, W, 20, return_labels=True)
stages["clusters"] = time.perf_counter() - clock; clock = time.perf_counter()
Dms = np.hstack([D[:, n_rigid:], X.reshape(-1, 1)])
kwargs = {}
if case["crawl"]:
    # boundary vertices: on facets (edges, triangles) of one element
    f = np.sort(np.vstack([np.delete(T, i, axis=1) for i in range(T.shape[1])]), axis=1)
    uniq, cnt = np.unique(f, axis=0, return_counts=True)
    bv = np.unique(uniq[cnt == 1])
    cI = bv[sk.farthest_point_sampling(X[bv, :], 30)]
    g = B.T @ sk.gravity_force(X, T, a=-9.8, rho=1e3).reshape(-1, 1)
    plane = np.zeros((dim, 1)); plane[1] = X[:, 1].min() - 0.15  # SimKit: y up, gravity along -y
    kwargs = dict(b0=-g, contact=True, cI=cI, plane_pos=plane, alpha=1.0)
    stages["contacts"] = time.perf_counter() - clock; clock = time.perf_counter()
sim = ModalMuscle(X, T, B, Dms, l, np.zeros(T.shape[0]), mu=1e6, gamma=1e6, rho=1e3, h=0.01, **kwargs)
stages["setup"] = time.perf_counter() - clock
print(json.dumps({"total": time.perf_counter() - start, "stages": stages, "elements": int(mesh.t.shape[1]),
                  "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def run(code, *args):
    out = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=3600)
    if out.returncode != 0:
        return {"error": out.stderr.strip().splitlines()[-1] if out.stderr.strip() else "failed"}
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    sys.path.insert(0, HERE)
    import reference_impl

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="*", default=DEFAULT, choices=list(CASES))
    parser.add_argument("--no-reference", action="store_true")
    parser.add_argument("--tutorial", default=reference_impl.DEFAULT_TUTORIAL)
    args = parser.parse_args()
    missing = None if not args.no_reference else "--no-reference"
    missing = missing or reference_impl.available(args.tutorial)
    print(machine_line())
    if missing:
        print(f"# reference not run: {missing}")
    failed = []  # "case implementation" of each run that failed
    for name in args.sizes:
        case = CASES[name]
        results = {}
        for label, parallel in (("ours (2 threads)", True), ("ours (1 thread)", False)):
            results[label] = run(OURS, json.dumps({**case, "parallel": parallel}), HERE)
        if not missing:
            results["reference"] = run(REFERENCE, json.dumps(case), HERE, args.tutorial)
        ref = results.get("reference", {}).get("total")
        for label, res in results.items():
            if "error" in res:
                print(f"{name:5s} {label:18s} failed: {res['error']}")
                failed.append(f"{name} {label}")
                continue
            ratio = f"{ref / res['total']:5.2f}x" if ref and label != "reference" else ""
            stages = ", ".join(f"{k} {v:.2f}" for k, v in res["stages"].items() if v >= 0.01)
            print(
                f"{name:5s} {res['elements']:7d} el. {label:18s} total {res['total']:7.2f} s {ratio:>7s}  "
                f"peak {res['peak_mb']:7.0f} MB   [{stages}]"
            )
        sys.stdout.flush()
    # after every case: one failure does not hide the others' numbers, nor pass for a result
    if failed:
        sys.exit(f"bench_precompute: {len(failed)} run(s) failed (see the table): {'; '.join(failed)}")


if __name__ == "__main__":
    main()
