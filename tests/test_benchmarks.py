"""The benchmark scripts keep running (tiny settings): a benchmark that rots measures nothing."""

import os
import subprocess
import sys

from skfem_modal.contact import ALLOWANCE

HERE = os.path.dirname(os.path.abspath(__file__))
BENCHMARKS = os.path.join(HERE, "..", "benchmarks")


def test_bench_contact_runs_and_its_rows_hold_the_ground():
    out = subprocess.run(
        [
            sys.executable,
            os.path.join(BENCHMARKS, "bench_contact.py"),
            "--only",
            "caterpillar",
            "creature",
            "--steps",
            "20",
            "--settle",
            "10",
            "--repeat",
            "1",
        ],
        capture_output=True,
        text=True,
        check=True,
        timeout=600,
    ).stdout
    rows = [line.split() for line in out.splitlines() if line.split()[:1] in (["caterpillar"], ["creature"])]
    table = [r for r in rows if r[1] in ("still", "gait")]  # the first table: scene, motion, contact, ...
    by_contact = {name: [r for r in table if r[2] == name] for name in ("floating", "coulomb", "reference")}
    # scenes x motions; coulomb with friction 0.5 and 0
    assert [len(by_contact[name]) for name in ("floating", "coulomb", "reference")] == [4, 8, 4]
    assert all(r[5] == "1.0x" for r in by_contact["floating"])
    for r in by_contact["coulomb"]:
        assert float(r[-1]) <= 100 * ALLOWANCE  # depth %: every vertex, the whole run
    assert "where the Coulomb contact's time goes" in out and "memory of the Coulomb contact" in out
