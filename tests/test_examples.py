"""The example scripts run and write what they promise."""

import pathlib
import re
import subprocess
import sys

import meshio
import pytest

EXAMPLES = pathlib.Path(__file__).resolve().parents[1] / "examples"


def run_example(name, out):
    result = subprocess.run(
        [sys.executable, str(EXAMPLES / name), str(out)], capture_output=True, text=True, timeout=600
    )
    assert result.returncode == 0, result.stderr
    return result.stdout


def test_caterpillar_crawl_example(tmp_path):
    text = run_example("caterpillar_crawl.py", tmp_path)
    assert "centre of mass travel in x: -4.438" in text
    assert "centre of mass height in [-0.130, 0.244]" in text
    pvd = (tmp_path / "crawl.pvd").read_text()
    assert pvd.count("<DataSet") == 90
    frame = meshio.read(tmp_path / "crawl" / "frame_00089.vtu")
    assert frame.point_data["displacement"].shape == (1719, 3)


def test_caterpillar_float_example(tmp_path):
    text = run_example("caterpillar_float.py", tmp_path)
    drift = float(re.search(r"drift over 180 steps: (\S+)", text).group(1))
    assert drift < 1e-8
    assert (tmp_path / "float.pvd").read_text().count("<DataSet") == 60


@pytest.mark.slow
def test_creature_crawl_example(tmp_path):
    text = run_example("creature_crawl.py", tmp_path)
    horizontal = float(re.search(r"horizontal (\S+)\)", text).group(1))
    depth = float(re.search(r"deepest vertex below the ground: (\S+)", text).group(1))
    assert horizontal > 0.1 and depth < 0.01
    frame = meshio.read(tmp_path / "creature" / "frame_00000.vtu")
    assert "tetra" in frame.cells_dict


def test_searched_gait_travels_what_docs_optimize_says():
    # the gait of examples/caterpillar_crawl_searched.toml, found by the search in docs/optimize.md
    from skfem_modal.run import run_scene
    from skfem_modal.scene import Scene

    summary = run_scene(Scene.from_toml(EXAMPLES / "caterpillar_crawl_searched.toml"), None)
    assert summary["com"]["travel"][0] == pytest.approx(-14.966, abs=1e-3)
    assert summary["ground"]["model"] == "reference" and summary["ground"]["worst_penetration_relative"] < 0.05
