"""The benchmark scripts keep running (tiny settings): a benchmark that rots measures nothing."""

import importlib.util
import os
import subprocess
import sys

import pytest
from ci import unavailable

from skfem_modal.contact import ALLOWANCE, MOST_ALLOWANCE

HERE = os.path.dirname(os.path.abspath(__file__))
BENCHMARKS = os.path.join(HERE, "..", "benchmarks")
SHARED = os.path.join(HERE, "..", "..", "shared", "meshes")
TUTORIAL = os.path.join(HERE, "..", "..", "shared", "reference", "modal_muscles_tutorial.txt")


def bench(script, *args):
    """What a benchmark script prints, run with ``args``."""
    argv = [sys.executable, os.path.join(BENCHMARKS, script), *args]
    return subprocess.run(argv, capture_output=True, text=True, check=True, timeout=600).stdout


def test_bench_contact_runs_and_its_rows_hold_the_ground():
    out = bench(
        "bench_contact.py", "--only", "caterpillar", "creature", "--steps", "20", "--settle", "10", "--repeat", "1"
    )
    # (the set-up "coulomb 0.5 sets", exact_friction = false, read as one "coulomb" row of friction "0.5sets")
    tables = [[line.replace(" sets", "sets").split() for line in part.splitlines()[2:]] for part in out.split("\n\n")]
    table = tables[0]  # scene, motion, contact, ...
    by_contact = {name: [r for r in table if r[2] == name] for name in ("floating", "coulomb", "reference")}
    # scenes x motions; coulomb with friction 0.5 (exact and not) and 0
    assert [len(by_contact[name]) for name in ("floating", "coulomb", "reference")] == [4, 12, 4]
    assert sorted({r[3] for r in by_contact["coulomb"]}) == ["0.0", "0.5", "0.5sets"]
    assert all(r[5] == "1.0x" for r in by_contact["floating"])
    for r in by_contact["coulomb"]:
        assert float(r[-1]) <= 100 * ALLOWANCE  # depth %: every vertex, the whole run
    # the Coulomb set-ups' steps without an active-set pass and the others: shares of all the timed steps
    without = tables[1]
    assert "steps without an active-set pass" in out.split("\n\n")[1] and len(without) == 12
    for r in without:
        assert float(r[4].rstrip("%")) + float(r[7].rstrip("%")) == pytest.approx(100.0, abs=0.11)
    # crawling with friction, the passes are counted (the creature's gait changes its sets in most steps)
    (creature,) = [r for r in without if r[:4] == ["creature", "gait", "coulomb", "0.5"]]
    assert float(creature[-1]) > 0.5 and float(creature[7].rstrip("%")) > 20.0
    assert "where the Coulomb contact's time goes" in out and "memory of the Coulomb contact" in out
    # what the allowance costs: each scene at each allowance, every vertex within it
    assert "what the allowance costs" in out.split("\n\n")[4]
    allowances = tables[4]
    expected = [(scene, a) for scene in ("caterpillar", "creature") for a in (ALLOWANCE, 5e-4, MOST_ALLOWANCE)]
    assert [(r[0], float(r[1])) for r in allowances] == expected
    for r in allowances:
        assert 0.0 <= float(r[-2]) <= 1.0 and float(r[-1]) <= 100 * float(r[1])  # reruns a step; depth %


def test_bench_render_runs_and_prints_peak_memory():
    out = bench("bench_render.py", "--sizes", "64x64", "--few", "2", "--every", "90", "--backends", "matplotlib")
    assert "the built-in crawl: 6 frames" in out
    (row,) = [line.split() for line in out.splitlines() if line.startswith("matplotlib")]
    assert row[1] == "64x64" and 50 < float(row[2]) < 2000 and 0.8 < float(row[4]) < 1.5


@pytest.mark.skipif(not os.path.isdir(SHARED), reason=f"the real meshes are not at {SHARED}")
def test_bench_backends_runs_and_says_what_auto_takes():
    from skfem_modal import _accel

    argv = [sys.executable, os.path.join(BENCHMARKS, "bench_backends.py"), "--steps", "30", "--sizes", "4x10", "8x20"]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=600)
    if not _accel.AVAILABLE:  # the default install: it says what it needs
        assert done.returncode != 0 and "needs numba" in done.stderr
        return
    assert done.returncode == 0, done.stderr
    rows = {line[:22].strip(): line.split() for line in done.stdout.splitlines()[2:]}
    assert list(rows) == ["caterpillar (2D)", "seal 4 w x 10 cl", "seal 8 w x 20 cl"]
    assert [row[-1] for row in rows.values()] == ["numba", "numba", "numpy"]  # auto: numpy in 3D from 20 clusters
    assert [int(row[-5]) for row in rows.values()] == [48, 48, 96]  # the subspace: 12 coordinates a weight in 3D


def test_bench_recorded_states_runs_and_prints_a_time_per_scene():
    out = bench("bench_recorded_states.py", "float")
    name, time, unit, *_ = out.split()
    assert (name, unit) == ("float", "us") and 0.0 < float(time) < 1e5
    assert "(36 states, numpy)" in out  # every 5th of the float scene's 180 steps


@pytest.mark.skipif(not os.path.isdir(SHARED), reason=f"the real meshes are not at {SHARED}")
def test_bench_frames_runs_and_our_frames_read_back():
    out = bench("bench_frames.py", "--frames", "2")
    rows = {tuple(line.split()[:2]): line.split()[2:] for line in out.splitlines()[2:]}
    assert set(rows) == {(mesh, writer) for mesh in ("seal", "caterpillar") for writer in ("ours", "meshio")}
    assert all(0.0 < float(ms) and 0.0 < float(mb) for ms, mb in rows.values())


def run_script(code, *args):
    """``code`` run with the benchmarks importable and ``args`` as its ``sys.argv[1:]``: the finished process."""
    prelude = f"import sys; sys.path.insert(0, {BENCHMARKS!r}); sys.argv[1:] = {list(args)!r}\n"
    argv = [sys.executable, "-c", prelude + code]
    return subprocess.run(argv, capture_output=True, text=True, timeout=600)


# a mistyped name or a count too small for the statistics: refused by the parser, naming the option and what works
REFUSALS = [
    ("bench_step.py", ["--only", "flaot"], "argument --only: invalid choice: 'flaot' (choose from 'float', 'crawl'"),
    ("bench_step.py", ["--repeat", "0"], "argument --repeat: must be at least 1, got 0"),
    ("profile_step.py", ["--only", "sael"], "argument --only: invalid choice: 'sael'"),
    ("profile_step.py", ["--backend", "numpyy"], "argument --backend: invalid choice: 'numpyy'"),
    ("bench_recorded_states.py", ["sealdrop"], "argument SCENE: invalid choice: 'sealdrop' (choose from 'float'"),
    ("bench_contact.py", ["--only", "sael"], "argument --only: invalid choice: 'sael' (choose from 'caterpillar'"),
    ("bench_contact.py", ["--steps", "1", "--settle", "10"], "argument --steps: must be at least 2"),
    ("bench_contact.py", ["--repeat", "0"], "argument --repeat: must be at least 1, got 0"),
    ("bench_backends.py", ["--steps", "20"], "argument --steps: must be at least 21 (the first 20 steps"),
    ("bench_backends.py", ["--sizes", "4-10"], "argument --sizes: expected WEIGHTSxCLUSTERS, two positive integers"),
    ("bench_effects.py", ["--steps", "10"], "argument --steps: must be at least 21"),
    ("bench_modal.py", ["--repeat", "0"], "argument --repeat: must be at least 1, got 0"),
    ("bench_frames.py", ["--frames", "0"], "argument --frames: must be at least 1, got 0"),
    ("bench_blas_threads.py", ["--cases", "smal"], "argument --cases: invalid choice: 'smal'"),
    ("bench_scaling.py", ["--bogus"], "unrecognized arguments: --bogus"),
    ("bench_iterations.py", ["--steps", "1"], "argument --steps: must be at least 2"),
    ("bench_render.py", ["--sizes", "320-240"], "argument --sizes: expected WIDTHxHEIGHT"),
]


@pytest.mark.parametrize("script, args, message", REFUSALS, ids=[f"{s} {' '.join(a)}" for s, a, _ in REFUSALS])
def test_a_benchmark_refuses_what_cannot_work_before_any_work(script, args, message):
    argv = [sys.executable, os.path.join(BENCHMARKS, script), *args]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and message in done.stderr, done.stderr
    assert done.stdout == ""  # not even the machine line: nothing ran


def test_bench_scaling_has_a_help():
    out = bench("bench_scaling.py", "--help")
    assert "--steps" in out and "--only" in out


WRONG_STEP = """
import bench_step
build = bench_step.build
def wrong(scene, backend):
    sim = build(scene, backend)
    step = sim.step
    sim.step = lambda *a, **k: step(*a, **k) * 1.01  # a wrong answer, however fast
    return sim
bench_step.build = wrong
bench_step.main()
"""


def needs_simkit():
    """Skip here without SimKit (the ``bench`` extra, which ``test`` installs); in CI, fail.

    Found, not imported: SimKit loads cvxopt, whose own OpenBLAS (a third one in this process) the thread
    tests then found at one thread.
    """
    if importlib.util.find_spec("simkit") is None:
        unavailable("SimKit is not installed (pip install -e '.[bench]')")


def test_bench_step_prints_its_table_then_fails_when_the_trajectory_is_not_the_references():
    if not os.path.isfile(TUTORIAL):
        unavailable(f"the reference's tutorial is not at {TUTORIAL}")
    needs_simkit()
    done = run_script(WRONG_STEP, "--only", "float", "--repeat", "1")
    assert done.returncode == 1, done.stderr
    rows = [line.split() for line in done.stdout.splitlines()[2:]]
    assert [row[:2] for row in rows][:2] == [["float", "reference"], ["float", "numpy"]]
    assert "differs from the reference's by more than 1e-08" in done.stderr and "float numpy: " in done.stderr


WRONG_MODES = """
import bench_modal
from skfem_modal import caterpillar
bench_modal.cases = lambda: [("small caterpillar", caterpillar(nx=16, ny=8), 7, 3)]
right = bench_modal.linear_modal_analysis
def wrong(mesh, k):
    values, modes = right(mesh, k)
    return 1.01 * values, modes
bench_modal.linear_modal_analysis = wrong
bench_modal.main()
"""


def test_bench_modal_prints_its_table_then_fails_when_the_eigenvalues_are_not_simkits():
    needs_simkit()
    done = run_script(WRONG_MODES, "--repeat", "1")
    assert done.returncode == 1, done.stderr
    assert "(differs)" in done.stdout
    assert "the elastic eigenvalues differ from SimKit's (rtol 1e-06): small caterpillar" in done.stderr
