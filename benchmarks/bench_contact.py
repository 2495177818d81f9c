"""What ground contact costs per step, against the same body floating, side by side.

    python benchmarks/bench_contact.py [--steps 300] [--settle 50] [--repeat 5] [--only seal ...]

Three scenes, each on the default install's path (backend "numpy"), one BLAS
thread:

  * caterpillar: the tutorial's 2D crawl (README / the built-in scene: mu =
    1e6, h = 0.01, ground 0.15 below the body, its gait)
  * creature:    examples/creature_crawl.toml (3D, z up, the built-in shape)
  * seal:        ../shared/meshes/seal.mesh (38689 tetrahedra, y up),
                 normalised as examples/seal_crawl.toml, with its settings

and for each, two motions (``still``: no activation, the body lies on the
ground; ``gait``: the scene's gait) by four set-ups built from the same scene
(so the same subspace, clusters and muscles):

  * floating:      no gravity, no ground
  * coulomb 0.5:   gravity, the Coulomb contact (the default), friction 0.5
  * coulomb 0.5 sets: the same with ``exact_friction = false``: the friction
                   the active set fixed, not made exact at the end of a step
  * coulomb 0.0:   the same, frictionless
  * reference:     gravity, the reference contact (30 sampled points)

All set-ups of a scene take turns every 10 steps through each run, so all see
the machine's fast and slow spells alike; the first step of a turn, on the
caches the others evicted, is left out of every statistic below (as in
bench_step.py). A run is ``--settle`` steps (the
body lands) then ``--steps`` timed steps; ``--repeat`` runs, each from the rest
state; each set-up's best run (lowest median) is printed. Columns: median and
p90 ms per step (``sim.step`` alone), the ratio of the median to the floating
set-up's with the same motion, iterations per step, vertices the contact held
(``sim.model.contact.active_count`` after each step: mean and most), and the
worst penetration over the whole run (settling included) of any boundary
vertex, ``sim.penetration(z)`` over the body's largest extent, in %.

A second table splits the Coulomb set-ups' timed steps (the best runs') into
those that made no active-set pass (every projection kept its last sets,
checked) and the others: their share, median ms and ratio to the floating
median, and the passes per step (counted in the same runs, by a wrapper of
``SetOperator.diagnose`` that adds a fraction of a microsecond a pass).

A third table says where the Coulomb contact's time goes: one more run of
each friction with the gait, the contact's methods timed by wrappers (so a
little slower). Per step: the projections (one per global solution), the
active-set passes (small solves), the operators made for them (the rest
found in the step's cache), the time of one projection, the step's
iterations run again (a vertex missed deep below, or a backend refusing the
step), the step and the contact's share of it, and of that the exact Coulomb solve at
the end of a step (``exact ms``: the last projection made again with exact
friction where a slide's friction was not straight against its motion). A fourth its memory: the
pushes ``H^-1 B_row^T`` it keeps (``_pushes``: boundary vertices x dim x
subspace doubles, allocated when the system is bound, a row filled when
first needed: "rows made" is what is filled) and the most its cache of
operators held at the end of a step, with the picked vertices' rows, pushes
and reach they are gathered from, against the bound boundary vertices x dim
x subspace size x 8 bytes.

A fifth table says what the contact's allowance (how far below the ground a
vertex may end a step, of the body's size: ``[ground] allowance``) costs: the
gait with friction 0.5 at allowances 2e-4 (the default), 5e-4 and 1e-3 (the
most), taking turns every 10 steps, best of ``--repeat`` runs by the mean:
mean and median ms per step against the floating gait's, the share of steps
whose iterations ran again for a vertex they missed (``reruns``), and the
worst depth of any vertex in %.
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
from options import at_least  # noqa: E402

from skfem_modal._contact_sets import SetOperator  # noqa: E402
from skfem_modal.scene import DEFAULT_SCENE, Scene  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
EXAMPLES = os.path.join(HERE, "..", "examples")
SEAL = os.path.join(HERE, "..", "..", "shared", "meshes", "seal.mesh")
BLOCK = 10  # steps a set-up runs before the next one takes its turn
SETUPS = ("floating", "coulomb 0.5", "coulomb 0.5 sets", "coulomb 0.0", "reference")
COULOMB = SETUPS[1:4]
ALLOWANCES = (2e-4, 5e-4, 1e-3)  # the fifth table's: the default, and up to the most one may choose
MOTIONS = ("still", "gait")
# the second table's columns (header, decimals): per step, but the time of one projection
TIME_COLUMNS = [
    ("projections", 1),
    ("passes", 1),
    ("operators", 1),
    ("us/projection", 0),
    ("redone", 3),
    ("step ms", 3),
    ("contact ms", 3),
    ("exact ms", 3),
]


# active-set passes so far (each a check of a set's solve: SetOperator.diagnose), counted while timing
PASSES = [0]


def _counting(diagnose):
    def counted(self, *args, **kwargs):
        PASSES[0] += 1
        return diagnose(self, *args, **kwargs)

    return counted


def _toml(name):
    with open(os.path.join(EXAMPLES, name), "rb") as f:
        return tomllib.load(f)


def scene_dicts():
    """The three scenes as scene dicts (the TOML keys), each with a ground and gravity."""
    seal = _toml("seal_crawl.toml")
    seal["mesh"] = {"file": os.path.abspath(SEAL), "normalize": True}
    return {
        "caterpillar": copy.deepcopy(DEFAULT_SCENE),
        "creature": _toml("creature_crawl.toml"),
        "seal": seal,
    }


def variant(data, setup):
    """The scene ``data`` with its gravity and ground as ``setup`` says."""
    data = copy.deepcopy(data)
    offset = data["ground"].get("offset", 0.0)
    if setup == "floating":
        del data["gravity"], data["ground"]
    elif setup == "reference":
        data["ground"] = {"offset": offset, "model": "reference", "contacts": 30}
    else:
        data["ground"] = {"offset": offset, "friction": float(setup.split()[1])}
        if setup.endswith("sets"):
            data["ground"]["exact_friction"] = False
    return data


def run(sim, activation, steps, size, record):
    """Step ``sim`` from rest; yield after each step, appending to ``record``'s lists."""
    sim.reset()
    z, z_dot, _ = sim.rest_state()
    contact = sim.model.contact
    for i in range(steps):
        a = activation(i * sim.h)
        before = PASSES[0]
        clock = time.perf_counter()
        z_next, z_dot = sim.step(z, z_dot, a, velocity=True)
        record["seconds"].append(time.perf_counter() - clock)
        record["passes"].append(PASSES[0] - before)
        record["iterations"].append(sim.iterations)
        record["held"].append(0 if contact is None else contact.active_count)
        record["depth"].append(sim.penetration(z_next) / size)
        z = z_next
        yield


def timed_steps(record, settle):
    """``record``'s lists at the timed steps: after ``settle``, without each turn's first step (cold caches)."""
    steps = np.arange(settle, len(record["seconds"]))
    steps = steps[steps % BLOCK != 0]
    return {key: np.asarray(values)[steps] for key, values in record.items()}


def interleaved(runs):
    """Advance every run ``BLOCK`` steps at a time, in turn, to the end."""
    runs = list(runs)
    while runs:
        for each in list(runs):
            for _ in range(BLOCK):
                if next(each, StopIteration) is StopIteration:
                    runs.remove(each)
                    break


def build(data):
    scene = Scene.from_dict(data, base_dir=EXAMPLES)
    return scene, scene.build(backend="numpy")


def timed(name, data, args):
    """The table's rows of one scene: every set-up and motion, interleaved, best of ``--repeat``."""
    built = {setup: build(variant(data, setup)) for setup in SETUPS}
    size = float(np.ptp(built["floating"][0].mesh.p, axis=1).max())
    best = {}
    for _ in range(args.repeat):
        records, runs = {}, []
        for setup, (scene, sim) in built.items():
            for motion in MOTIONS:
                zero = np.zeros(sim.n_muscles)
                activation = (lambda t, s=scene, m=sim: s.activation(t, m.ceilings)) if motion == "gait" else None
                record = records[setup, motion] = {k: [] for k in ("seconds", "iterations", "held", "depth", "passes")}
                runs.append(run(sim, activation or (lambda t, z=zero: z), args.settle + args.steps, size, record))
        # one simulator per set-up steps both motions: each run resets it, so they go one after the other
        for motion in MOTIONS:
            interleaved(r for r, key in zip(runs, records) if key[1] == motion)
        for key, record in records.items():
            timed_record = timed_steps(record, args.settle)
            ms = timed_record["seconds"] * 1e3
            row = dict(
                median=float(np.median(ms)),
                p90=float(np.percentile(ms, 90)),
                iterations=float(np.mean(timed_record["iterations"])),
                held=timed_record["held"],
                depth=100.0 * max(record["depth"]),
                ms=ms,
                passes=timed_record["passes"],
            )
            if key not in best or row["median"] < best[key]["median"]:
                best[key] = row
    for motion in MOTIONS:
        floating = best["floating", motion]["median"]
        for setup in SETUPS:
            row = best[setup, motion]
            held = row["held"]
            print(
                f"{name:12s} {motion:6s} {setup:16s} {row['median']:9.3f} {row['p90']:8.3f} "
                f"{row['median'] / floating:7.1f}x {row['iterations']:6.2f} "
                f"{held.mean():7.1f} {held.max():5d} {row['depth']:8.3f}"
            )
        sys.stdout.flush()
    return built, best


def without_passes(name, best):
    """The second table's rows: the Coulomb contact's steps that made no active-set pass, against those that did."""
    for motion in MOTIONS:
        floating = best["floating", motion]["median"]
        for setup in COULOMB:
            row = best[setup, motion]
            none = row["passes"] == 0
            cells = []
            for chosen in (none, ~none):
                median = float(np.median(row["ms"][chosen])) if np.any(chosen) else float("nan")
                cells.append(f"{100 * np.mean(chosen):6.1f}% {median:9.3f} {median / floating:7.1f}x")
            print(f"{name:12s} {motion:6s} {setup:16s} " + "   ".join(cells) + f" {row['passes'].mean():7.2f}")


class _Timer:
    """Wraps methods of an instance (or of a class, until :meth:`restore`): how often and how long they ran."""

    def __init__(self, owner, names):
        self.calls = dict.fromkeys(names, 0)
        self.seconds = dict.fromkeys(names, 0.0)
        self.owner, self.originals = owner, {name: getattr(owner, name) for name in names}
        for name in names:
            setattr(owner, name, self._wrap(name, getattr(owner, name)))

    def restore(self):
        for name, method in self.originals.items():
            setattr(self.owner, name, method)

    def _wrap(self, name, method):
        def wrapped(*args, **kwargs):
            clock = time.perf_counter()
            try:
                return method(*args, **kwargs)
            finally:
                self.calls[name] += 1
                self.seconds[name] += time.perf_counter() - clock

        return wrapped


def where_the_time_goes(name, scene, sim, steps):
    """A gait run of the Coulomb contact with its methods timed; the third and fourth tables' rows."""
    sim.reset()
    contact = sim.model.contact
    # a pass of the active set is one check of a set's solve, saying who breaks it
    passes = _Timer(SetOperator, ["diagnose"])
    top = _Timer(contact, ["start_step", "project", "missed", "finish_step"])
    exact = _Timer(contact, ["_polish"])  # (within finish_step)
    made = [0]
    operator = contact._operator

    def counted(*args):
        kept = list(contact._operators.values())
        found = operator(*args)
        made[0] += not any(found is each for each in kept)
        return found

    contact._operator = counted
    z, z_dot, _ = sim.rest_state()
    total, most_cache = 0.0, 0
    for i in range(steps):
        clock = time.perf_counter()
        z, z_dot = sim.step(z, z_dot, scene.activation(i * sim.h, sim.ceilings), velocity=True)
        total += time.perf_counter() - clock
        cache = sum(op.nbytes for op in contact._operators.values())
        cache += contact.sets.nbytes if contact.picked.size else 0  # the pick's pushes and reach
        most_cache = max(most_cache, cache)
    passes.restore()
    in_contact = sum(top.seconds.values())
    per_step = [
        top.calls["project"] / steps,
        passes.calls["diagnose"] / steps,
        made[0] / steps,
        1e6 * top.seconds["project"] / max(top.calls["project"], 1),
        (top.calls["start_step"] - steps) / steps,  # start_step: once per attempt at a step
        1e3 * total / steps,
        1e3 * in_contact / steps,
        1e3 * exact.seconds["_polish"] / steps,
    ]
    print(f"{name:20s} " + " ".join(f"{v:>{len(c)}.{d}f}" for v, (c, d) in zip(per_step, TIME_COLUMNS)), end="")
    print(f" {100 * in_contact / total:6.1f}%")
    return most_cache


def allowance_rows(name, data, floating, args):
    """The fifth table's rows: the gait with friction 0.5 at each allowance, taking turns, best of ``--repeat``."""
    built = {}
    for allowance in ALLOWANCES:
        chosen = variant(data, "coulomb 0.5")
        chosen["ground"]["allowance"] = allowance
        scene, sim = build(chosen)
        reruns = [0]
        missed = sim.model.contact.missed

        def counted(z, missed=missed, reruns=reruns):
            found = missed(z)
            reruns[0] += found
            return found

        sim.model.contact.missed = counted
        built[allowance] = scene, sim, reruns
    size = float(np.ptp(built[ALLOWANCES[0]][0].mesh.p, axis=1).max())
    best = {}
    for _ in range(args.repeat):
        records, runs = {}, []
        for allowance, (scene, sim, reruns) in built.items():
            reruns[0] = 0
            record = records[allowance] = {k: [] for k in ("seconds", "iterations", "held", "depth", "passes")}
            activation = lambda t, s=scene, m=sim: s.activation(t, m.ceilings)  # noqa: E731
            runs.append(run(sim, activation, args.settle + args.steps, size, record))
        interleaved(runs)
        for allowance, record in records.items():
            ms = timed_steps(record, args.settle)["seconds"] * 1e3
            row = dict(mean=float(ms.mean()), median=float(np.median(ms)), depth=100.0 * max(record["depth"]))
            row["reruns"] = built[allowance][2][0] / (args.settle + args.steps)
            if allowance not in best or row["mean"] < best[allowance]["mean"]:
                best[allowance] = row
    for allowance, row in best.items():
        print(
            f"{name:12s} {allowance:9.0e} {row['mean']:8.3f} {row['mean'] / floating.mean():7.1f}x "
            f"{row['median']:9.3f} {row['median'] / np.median(floating):7.1f}x {row['reruns']:7.3f} {row['depth']:8.3f}"
        )


def memory_row(name, sim, most_cache):
    contact = sim.model.contact
    boundary, dim, r = contact.vertices.size, contact.dim, sim.model.space.r
    bound = boundary * dim * r * 8
    made = int(np.count_nonzero(contact._made))
    print(
        f"{name:20s} {boundary:9d} {dim:3d} {r:4d} {bound / 1e6:9.2f} {contact._pushes.nbytes / 1e6:9.2f} "
        f"{made * r * 8 / 1e6:9.3f} {most_cache / 1e6:9.3f} {(contact._pushes.nbytes + most_cache) / bound:7.3f}"
    )


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    # two timed steps: one of them at least is not a turn's first, which every statistic leaves out
    parser.add_argument(
        "--steps", type=at_least(2, "a turn's first step is left out"), default=300, help="timed steps a run"
    )
    parser.add_argument("--settle", type=at_least(0), default=50, help="steps before the timed ones (landing)")
    parser.add_argument("--repeat", type=at_least(1), default=5, help="runs of each set-up; the best is printed")
    every_scene = scene_dicts()
    parser.add_argument("--only", nargs="*", choices=list(every_scene), help="scenes to run (default: all)")
    args = parser.parse_args()
    print(
        machine_line("backend numpy", f"{args.settle} settling + {args.steps} timed steps, best of {args.repeat} runs")
    )
    print(
        f"{'scene':12s} {'motion':6s} {'contact':16s} {'median ms':>9s} {'p90 ms':>8s} {'x float':>8s} "
        f"{'iter':>6s} {'held':>7s} {'most':>5s} {'depth %':>8s}"
    )
    scenes = {k: v for k, v in every_scene.items() if not args.only or k in args.only}
    coulomb, bests = {}, {}
    diagnose = SetOperator.diagnose
    SetOperator.diagnose = _counting(diagnose)
    try:
        for name, data in scenes.items():
            built, bests[name] = timed(name, data, args)
            for setup in COULOMB:
                coulomb[f"{name} {setup.split(maxsplit=1)[1]}"] = built[setup]
            del built
    finally:
        SetOperator.diagnose = diagnose
    print("\n# the Coulomb contact's steps without an active-set pass (every projection kept its sets), and the others")
    print(
        f"{'scene':12s} {'motion':6s} {'contact':16s} {'no pass':>7s} {'median ms':>9s} {'x float':>8s}   "
        f"{'passes':>7s} {'median ms':>9s} {'x float':>8s} {'passes/step':>7s}"
    )
    for name, best in bests.items():
        without_passes(name, best)
    print("\n# where the Coulomb contact's time goes (gait; its methods timed by wrappers), per step")
    print(f"{'scene, friction':20s} " + " ".join(c for c, _ in TIME_COLUMNS) + f" {'share':>7s}")
    caches = {
        name: where_the_time_goes(name, scene, sim, args.settle + args.steps) for name, (scene, sim) in coulomb.items()
    }
    print("\n# memory of the Coulomb contact (MB); bound: boundary vertices x dim x subspace x 8 bytes")
    print(
        f"{'scene, friction':20s} {'boundary':>9s} {'dim':>3s} {'r':>4s} {'bound':>9s} {'pushes':>9s} "
        f"{'rows made':>9s} {'operators':>9s} {'/ bound':>7s}"
    )
    for name, (_, sim) in coulomb.items():
        memory_row(name, sim, caches[name])
    del coulomb, caches
    print("\n# what the allowance costs: the gait with friction 0.5, the allowances taking turns, best mean of runs")
    print(
        f"{'scene':12s} {'allowance':>9s} {'mean ms':>8s} {'x float':>8s} {'median ms':>9s} {'x float':>8s} "
        f"{'reruns':>7s} {'depth %':>8s}"
    )
    for name, data in scenes.items():
        allowance_rows(name, data, bests[name]["floating", "gait"]["ms"], args)


if __name__ == "__main__":
    main()
