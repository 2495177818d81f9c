"""The benchmark scripts keep running (tiny settings): a benchmark that rots measures nothing."""

import os
import subprocess
import sys

from skfem_modal.contact import ALLOWANCE

HERE = os.path.dirname(os.path.abspath(__file__))
BENCHMARKS = os.path.join(HERE, "..", "benchmarks")


def bench(script, *args):
    """What a benchmark script prints, run with ``args``."""
    argv = [sys.executable, os.path.join(BENCHMARKS, script), *args]
    return subprocess.run(argv, capture_output=True, text=True, check=True, timeout=600).stdout


def test_bench_contact_runs_and_its_rows_hold_the_ground():
    out = bench(
        "bench_contact.py", "--only", "caterpillar", "creature", "--steps", "20", "--settle", "10", "--repeat", "1"
    )
    rows = [line.split() for line in out.splitlines() if line.split()[:1] in (["caterpillar"], ["creature"])]
    table = [r for r in rows if r[1] in ("still", "gait")]  # the first table: scene, motion, contact, ...
    by_contact = {name: [r for r in table if r[2] == name] for name in ("floating", "coulomb", "reference")}
    # scenes x motions; coulomb with friction 0.5 and 0
    assert [len(by_contact[name]) for name in ("floating", "coulomb", "reference")] == [4, 8, 4]
    assert all(r[5] == "1.0x" for r in by_contact["floating"])
    for r in by_contact["coulomb"]:
        assert float(r[-1]) <= 100 * ALLOWANCE  # depth %: every vertex, the whole run
    assert "where the Coulomb contact's time goes" in out and "memory of the Coulomb contact" in out


def test_bench_render_runs_and_prints_peak_memory():
    out = bench("bench_render.py", "--sizes", "64x64", "--few", "2", "--every", "90", "--backends", "matplotlib")
    assert "the built-in crawl: 6 frames" in out
    (row,) = [line.split() for line in out.splitlines() if line.startswith("matplotlib")]
    assert row[1] == "64x64" and 50 < float(row[2]) < 2000 and 0.8 < float(row[4]) < 1.5
