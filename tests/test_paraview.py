"""ParaView itself opens a run: pvpython with paraview.simple reads the .pvd."""

import json
import shutil
import subprocess

import pytest
from ci import unavailable

from skfem_modal.run import run_scene
from skfem_modal.scene import Scene

PVPYTHON = shutil.which("pvpython")


@pytest.fixture(autouse=True)
def pvpython():
    if PVPYTHON is None:
        unavailable("ParaView's pvpython is not installed (Debian: paraview python3-paraview; .ci/run installs it)")


SCRIPT = """
import json, sys
from paraview.simple import IntegrateVariables, PVDReader, servermanager
reader = PVDReader(FileName=sys.argv[1])
reader.UpdatePipelineInformation()
times = list(reader.TimestepValues)
integral = IntegrateVariables(Input=reader)
integral.UpdatePipeline(times[0])
sums = servermanager.Fetch(integral).GetCellData()
rest_measure = sums.GetArray("Volume" if sums.GetArray("Volume") else "Area").GetValue(0)
reader.UpdatePipeline(times[-1])
info = reader.GetDataInformation()
print(json.dumps({
    "times": times,
    "points": info.GetNumberOfPoints(),
    "cells": info.GetNumberOfCells(),
    "point_arrays": list(reader.PointData.keys()),
    "cell_arrays": list(reader.CellData.keys()),
    "field_arrays": list(reader.FieldData.keys()),
    "displacement_range": list(reader.PointData["displacement"].GetRange(-1)),
    "rest_measure": rest_measure,
}))
"""


def open_in_paraview(pvd, tmp_path):
    script = tmp_path / "open.py"
    script.write_text(SCRIPT)
    result = subprocess.run([PVPYTHON, str(script), str(pvd)], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize(
    "data, points, cells",
    [
        (
            {
                "mesh": {"shape": "caterpillar"},
                "time": {"step": 0.02, "steps": 30},
                "output": {"every": 10},
                "muscles": {"count": 2, "gait": {"amplitude": [0.5, 0.5], "period": [0.5, 0.4]}},
            },
            1719,
            3058,
        ),
        (
            {
                "mesh": {"shape": "creature", "params": {"cell": 0.2}},
                "time": {"step": 0.02, "steps": 30},
                "output": {"every": 10},
                "muscles": {"count": 2, "gait": {"amplitude": [0.5, 0.5], "period": [0.5, 0.4]}},
            },
            None,
            None,
        ),
    ],
    ids=["2d", "3d"],
)
def test_paraview_opens_a_run(tmp_path, data, points, cells):
    scene = Scene.from_dict(data)
    run_scene(scene, tmp_path / "run")
    seen = open_in_paraview(tmp_path / "run" / "frames.pvd", tmp_path)
    assert seen["times"] == pytest.approx([0.0, 0.2, 0.4, 0.6])
    assert seen["points"] == (points or scene.mesh.p.shape[1])
    assert seen["cells"] == (cells or scene.mesh.t.shape[1])
    assert seen["point_arrays"] == ["displacement"]
    assert sorted(seen["cell_arrays"]) == ["cluster", "muscle_cluster"]
    assert sorted(seen["field_arrays"]) == ["activation", "time"]
    assert seen["displacement_range"][1] > 1e-3  # the last frame has moved
    # Integrate Variables sums the rest frame's cells to the body's area or volume (none written inside out)
    assert seen["rest_measure"] == pytest.approx(summary_measure(tmp_path / "run"), rel=1e-9)


def summary_measure(run_dir):
    return json.loads((run_dir / "summary.json").read_text())["mesh"]["measure"]
