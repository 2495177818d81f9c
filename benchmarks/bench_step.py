"""Per-step speed against the reference implementation, side by side, same inputs.

    python benchmarks/bench_step.py [--repeat 5] [--tutorial PATH] [--only float crawl 3d seal seal-drop]

Scenes (all with 10 local/global iterations a step, the reference's default):
  * float:     the tutorial's floating caterpillar (180 steps, h = 0.02)
  * crawl:     the tutorial's crawl with gravity and 30 ground contacts (450 steps, h = 0.01)
  * 3d:        the 24000-tetrahedron box (40 x 10 x 10), 8 skinning weights (96
               coordinates), 20 clusters, 4 muscles, floating (100 steps, h = 0.01)
  * seal:      a real creature, ../shared/meshes/seal.mesh (9996 vertices, 38689
               tetrahedra, y up), 8 weights, 20 clusters, 4 muscles, floating
               (100 steps, h = 0.01)
  * seal-drop: the same seal dropped onto the ground under gravity (along -y,
               the reference's up axis) with 30 contact points (150 steps)

The reference (SimKit 0.1.8 and the tutorial's ModalMuscle class, see
reference_impl.py) and skfem_modal get the same B, D, clusters, contact
vertices and gravity, and the trajectories are compared: the relative
difference of z over the whole run must stay below 1e-8, so the speed is not
bought with a different answer (the script exits non-zero after the table,
naming the scene, when it does not). Prints per-step median and p90 for each
implementation (numpy, and numba when installed) over all steps of
``--repeat`` runs, and the ratios. The implementations take turns every 10
steps all through each run, so that all of them see the machine's fast and
slow spells alike (whole runs one after another landed in different spells
and moved the ratios by up to 2x); not every step, since the reference's
large working set would evict ours from the caches between steps, which no
real run does. Even every 10 steps, the first step of a turn runs on the
caches the other evicted (the dropped seal: ours 354 to 416 us against 204
to 221 for the turn's later steps, the reference 3.4 to 3.5 ms against 3.1
to 3.2; 2026-11-27): the median, p90 and ratios are over the other steps,
and the column ``1st of turn`` gives the median of those first steps.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import reference_impl  # noqa: E402
from machine import machine_line  # noqa: E402
from options import at_least  # noqa: E402

import skfem_modal as sm  # noqa: E402
from skfem_modal import _accel  # noqa: E402
from skfem_modal.clusters import spectral_clusters  # noqa: E402
from skfem_modal.muscles import sine_gait  # noqa: E402
from skfem_modal.sim import ModalMuscle  # noqa: E402
from skfem_modal.subspace import mass_orthonormalize, skinning_eigenmodes  # noqa: E402


def inputs(mesh, n_muscles, n_weights=8, n_clusters=20):
    dim = mesh.p.shape[0]
    n_rigid = 3 if dim == 2 else 6
    _, modes = sm.linear_modal_analysis(mesh, n_rigid + n_muscles)
    D = modes[:, n_rigid:]
    if dim == 2:  # the tutorial's mode signs
        D = D * (np.array([1.0, -1.0, -1.0, 1.0]) * np.sign(D[0]))
    _, W, B = skinning_eigenmodes(mesh, n_weights)
    B = mass_orthonormalize(B, sm.mass_matrix(mesh))
    labels = spectral_clusters(mesh, W, n_clusters, seed=0)
    return D, B, labels, sm.actuation_limits(mesh, D)


SEAL = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "shared", "meshes", "seal.mesh")
SCENE_NAMES = ("float", "crawl", "3d", "seal", "seal-drop")
# the most relative difference of our trajectory from the reference's (max over z and the run, over max |z|)
TOLERANCE = 1e-8


def scenes(only=None):
    """The scenes named in ``only`` (all of :data:`SCENE_NAMES` when empty), their inputs made."""
    unknown = sorted(set(only or ()) - set(SCENE_NAMES))
    if unknown:
        raise ValueError(f"unknown scenes {unknown}: the scenes are {', '.join(SCENE_NAMES)}")
    wanted = lambda name: not only or name in only  # noqa: E731
    cat = sm.caterpillar()
    D, B, labels, ceilings = inputs(cat, 4)
    X = cat.p.T
    boundary = sm.boundary_vertices(cat)
    contacts = boundary[sm.farthest_point_sampling(X[boundary], 30)]
    ground = float(X[:, 1].min()) - 0.15
    found = []
    if wanted("3d"):
        box = sm.box3d(40, 10, 10, (4.0, 1.0, 1.0))
        D3, B3, labels3, ceilings3 = inputs(box, 4)
        found.append(
            dict(
                name="3d",
                mesh=box,
                B=B3,
                D=D3,
                labels=labels3,
                mu=1e5,
                h=0.01,
                steps=100,
                gait=(0.4 * ceilings3, [1.0, 0.8, 0.6, 0.9], [0.0, 0.25, 0.5, 0.75]),
            )
        )
    if wanted("seal") or wanted("seal-drop"):
        seal = sm.load_mesh(SEAL)
        Ds, Bs, labels_s, ceilings_s = inputs(seal, 4)
        common = dict(mesh=seal, B=Bs, D=Ds, labels=labels_s, mu=1e5, h=0.01)
        gait = (0.4 * ceilings_s, [1.0, 0.8, 0.6, 0.9], [0.0, 0.25, 0.5, 0.75])
        X = seal.p.T
        boundary = sm.boundary_vertices(seal)
        found += [
            dict(name="seal", steps=100, gait=gait, **common),
            dict(
                name="seal-drop",
                steps=150,
                gait=gait,
                gravity=[0.0, -9.8, 0.0],
                contacts=boundary[sm.farthest_point_sampling(X[boundary], 30)],
                ground=float(X[:, 1].min()) - 0.05,
                **common,
            ),
        ]
    return [
        s
        for s in [
            dict(
                name="float",
                mesh=cat,
                B=B,
                D=D,
                labels=labels,
                mu=1e5,
                h=0.02,
                steps=180,
                gait=(np.array([0.9, 0.6, 0.0, 0.0]) * ceilings, [1.0, 0.7, 1.0, 1.0], [0.0, 0.25, 0.0, 0.0]),
            ),
            dict(
                name="crawl",
                mesh=cat,
                B=B,
                D=D,
                labels=labels,
                mu=1e6,
                h=0.01,
                steps=450,
                gravity=[0.0, -9.8],
                contacts=contacts,
                ground=ground,
                gait=(np.array([0.45, 0.35, 0.25, 0.15]) * ceilings, [1.2, 0.8, 1.0, 0.6], [0.0, 0.25, 0.5, 0.1]),
            ),
        ]
        + found
        if wanted(s["name"])
    ]


def build(scene, backend):
    """Our simulator on the scene's inputs (up: the reference's axis 1), stopping as the reference."""
    sim = ModalMuscle(
        scene["mesh"],
        scene["B"],
        scene["D"],
        scene["labels"],
        mu=scene["mu"],
        gamma=scene["mu"],
        rho=1e3,
        h=scene["h"],
        gravity=scene.get("gravity"),
        contact_vertices=scene.get("contacts"),
        ground=scene.get("ground"),
        up=1,
        # the reference's own contact rule: the trajectories are compared
        contact_model="reference" if scene.get("contacts") is not None else "coulomb",
        backend=backend,
    )
    # the reference's stopping rule, an absolute 1e-6 on z (ours is a fraction of the body's size)
    sim.tol = 1e-6 / sim.motion_scale
    return sim


def steps_ours(scene, backend):
    """Our simulator on the scene: yields (seconds, z) per step."""
    sim = build(scene, backend)
    z, z_dot, _ = sim.rest_state()
    sim.step(z, z_dot, np.zeros(sim.n_muscles))  # compile / warm up
    amp, per, ph = scene["gait"]
    for i in range(scene["steps"]):
        a = sine_gait(i * sim.h, amp, per, ph)
        start = time.perf_counter()
        z_next = sim.step(z, z_dot, a)
        elapsed = time.perf_counter() - start
        z_dot, z = (z_next - z) / sim.h, z_next
        yield elapsed, z


def steps_reference(scene, RefModalMuscle):
    """The reference on the same inputs: yields (seconds, z) per step."""
    import scipy.sparse as sps  # noqa: F401
    import simkit as sk

    mesh = scene["mesh"]
    X = np.ascontiguousarray(mesh.p.T)
    T = reference_impl.oriented(X, np.ascontiguousarray(mesh.t.T))
    dim = X.shape[1]
    D = np.hstack([scene["D"], X.reshape(-1, 1)])
    kwargs = {}
    if scene.get("gravity") is not None:
        # SimKit's gravity and ground act along axis 1 (y up, in 2D and 3D)
        g = scene["B"].T @ sk.gravity_force(X, T, a=scene["gravity"][1], rho=1e3).reshape(-1, 1)
        plane = np.zeros((dim, 1))
        plane[1] = scene["ground"]
        kwargs = dict(b0=-g, contact=True, cI=scene["contacts"], plane_pos=plane, alpha=1.0)
    sim = RefModalMuscle(
        X,
        T,
        scene["B"],
        D,
        scene["labels"],
        np.zeros(T.shape[0]),
        mu=scene["mu"],
        gamma=scene["mu"],
        rho=1e3,
        h=scene["h"],
        max_iter=10,
        **kwargs,
    )
    z, z_dot, a = sim.rest_state(X)
    amp, per, ph = scene["gait"]
    for i in range(scene["steps"]):
        a[:-1, 0] = sine_gait(i * scene["h"], amp, per, ph)
        start = time.perf_counter()
        z_next = sim.step(z, z_dot, a)
        elapsed = time.perf_counter() - start
        z_dot, z = (z_next - z) / scene["h"], z_next
        yield elapsed, z.ravel()


BLOCK = 10  # steps an implementation runs before the next one takes its turn


def stats(times):
    ms = np.array(times) * 1e3
    return float(np.median(ms)), float(np.percentile(ms, 90))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=at_least(1), default=5, help="whole runs of each scene, all steps pooled")
    parser.add_argument("--tutorial", default=reference_impl.DEFAULT_TUTORIAL)
    parser.add_argument("--only", nargs="*", choices=SCENE_NAMES, help="scene names to run (default: all)")
    args = parser.parse_args()
    missing = reference_impl.available(args.tutorial)
    Ref = None if missing else reference_impl.load_modal_muscle(args.tutorial)
    print(machine_line(f"numba {'yes' if _accel.AVAILABLE else 'no'}"))
    if missing:
        print(f"# reference not run: {missing}")
    impls = ["numpy"] + (["numba"] if _accel.AVAILABLE else [])
    print(
        f"{'scene':9s} {'implementation':16s} {'median ms':>9s} {'p90 ms':>8s} {'ratio':>7s}  "
        f"{'max rel. diff of z':>18s} {'1st of turn':>13s}"
    )
    differs = []  # "scene implementation: difference" off the reference by more than TOLERANCE
    for scene in scenes(args.only):
        # the implementations take turns every BLOCK steps through the whole
        # run, repeated: all of them see the machine's fast and slow spells
        # alike (whole runs one after the other can land in different spells),
        # and a block is long enough that none runs on a cache the other evicted
        times, cold = {}, {}
        trajectories = {}
        for _ in range(args.repeat):
            runs = {"reference": steps_reference(scene, Ref)} if Ref else {}
            runs.update({impl: steps_ours(scene, impl) for impl in impls})
            zs = {name: [] for name in runs}
            while runs:
                for name in list(runs):
                    for turn_step in range(BLOCK):
                        try:
                            elapsed, z = next(runs[name])
                        except StopIteration:
                            del runs[name]
                            break
                        # a turn's first step runs on the caches the other implementation evicted
                        (cold if turn_step == 0 else times).setdefault(name, []).append(elapsed)
                        zs[name].append(z)
            trajectories = {name: np.array(z) for name, z in zs.items()}
        best = {name: stats(t) for name, t in times.items()}
        ref_med = best["reference"][0] if "reference" in best else None
        for name, (med, p90) in best.items():
            ratio = "" if ref_med is None or name == "reference" else f"{ref_med / med:6.1f}x"
            diff = ""
            if "reference" in trajectories and name != "reference":
                zr = trajectories["reference"]
                relative = np.abs(trajectories[name] - zr).max() / np.abs(zr).max()
                diff = f"{relative:.1e}"
                if not relative <= TOLERANCE:  # (NaN too)
                    differs.append(f"{scene['name']} {name}: {diff}")
            first = np.median(cold[name]) * 1e3
            print(f"{scene['name']:9s} {name:16s} {med:9.3f} {p90:8.3f} {ratio:>7s}  {diff:>18s} {first:13.3f}")
        sys.stdout.flush()
    # after the whole table: the speeds are still worth reading, but not as a pass
    if differs:
        sys.exit(
            f"bench_step: the trajectory differs from the reference's by more than {TOLERANCE:.0e} "
            f"(max |z - z_ref| / max |z_ref|): {'; '.join(differs)}"
        )


if __name__ == "__main__":
    main()
