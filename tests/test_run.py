"""Runs write readable ParaView series, CSVs and a summary; failures keep what was done."""

import csv
import json
import re

import meshio
import numpy as np
import pytest

from skfem_modal import _accel
from skfem_modal.cli import main
from skfem_modal.run import run_scene
from skfem_modal.scene import DEFAULT_SCENE, Scene
from skfem_modal.sim import SimulationError


@pytest.fixture(scope="module")
def default_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("default_run")
    assert main(["run", "--out", str(out), "--quiet"]) == 0
    return out


def pvd_entries(path):
    return [(t, f) for t, f in re.findall(r'timestep="([^"]+)"[^>]*file="([^"]+)"', path.read_text())]


def test_default_run_writes_every_file(default_run, reference):
    names = sorted(p.name for p in default_run.iterdir())
    assert names == ["amplitudes.csv", "com.csv", "frames", "frames.pvd", "summary.json"]
    summary = json.loads((default_run / "summary.json").read_text())
    assert summary["status"] == "completed" and summary["steps_completed"] == 450
    assert summary["effects"] == ["elasticity", "inertia", "muscles", "gravity", "contact"]
    assert summary["backend"] == ("numba" if _accel.AVAILABLE else "numpy")  # auto, in 2D
    assert summary["com"]["travel"][0] == pytest.approx(reference["crawl_com_dx"], abs=0.01)
    assert summary["sizes"] == {
        "dofs": 3438,
        "subspace": 48,
        "clusters": 20,
        "active_clusters": 1,
        "muscles": 4,
        "contact_points": 30,
        "pinned_vertices": 0,
    }
    for stage in ("modal_analysis", "skinning_eigenmodes", "orthonormalize", "clusters", "system"):
        assert summary["timings"]["precompute_s"][stage] >= 0
    step, first = summary["timings"]["step_ms"], summary["timings"]["first_step_ms"]
    assert 0 < step["median"] <= step["p90"]
    # the first step (numba's kernels load in it) apart, the other 449 in the statistics
    assert first > 0 and summary["timings"]["steps_total_s"] * 1e3 == pytest.approx(first + 449 * step["mean"])
    assert summary["iterations"]["max"] <= 10 and sum(summary["iterations"]["histogram"].values()) == 450
    # the tutorial's reference contact lets feet sink: the report covers every vertex, every step
    assert summary["ground"]["model"] == "reference" and summary["ground"]["allowance"] is None
    assert summary["ground"]["friction"] is None and summary["ground"]["exact_friction"] is None
    assert 0.01 < summary["ground"]["worst_penetration_relative"] < 0.05
    assert summary["scene"]["name"] == DEFAULT_SCENE["name"]


def test_frames_read_back_with_meshio(default_run):
    entries = pvd_entries(default_run / "frames.pvd")
    assert len(entries) == 91  # every 5th of 450 steps, and the start
    times = [float(t) for t, _ in entries]
    np.testing.assert_array_equal(times, [k * 5 * 0.01 for k in range(91)])  # written exactly
    last = meshio.read(default_run / entries[-1][1])
    assert last.points.shape == (1719, 3) and np.all(last.points[:, 2] == 0)
    assert last.point_data["displacement"].shape == (1719, 3)
    assert last.cell_data["cluster"][0].shape == (3058,)
    assert set(last.cell_data["cluster"][0]) == set(range(20))
    assert last.field_data["activation"].shape == (4,)
    assert last.field_data["time"][0] == times[-1]
    first = meshio.read(default_run / entries[0][1])
    np.testing.assert_allclose(first.point_data["displacement"], 0.0, atol=1e-12)
    # the rest positions plus the displacement are the points
    np.testing.assert_allclose(last.points - last.point_data["displacement"], first.points, atol=1e-12)


def test_frames_read_back_with_pyvista(default_run):
    pv = pytest.importorskip("pyvista", reason="pyvista is in the plot extra")
    reader = pv.get_reader(str(default_run / "frames.pvd"))
    assert len(reader.time_values) == 91
    assert reader.time_values[-1] == pytest.approx(4.5)
    reader.set_active_time_value(reader.time_values[10])
    block = reader.read()
    grid = block[0]
    assert grid.n_points == 1719 and grid.n_cells == 3058
    assert grid.point_data["displacement"].shape == (1719, 3)
    assert "cluster" in grid.cell_data


def test_csv_outputs(default_run):
    rows = list(csv.reader(open(default_run / "com.csv")))
    assert rows[0] == ["time", "x", "y"] and len(rows) == 452
    assert float(rows[-1][0]) == 4.5
    summary = json.loads((default_run / "summary.json").read_text())
    np.testing.assert_allclose([float(v) for v in rows[-1][1:]], summary["com"]["end"])
    amp = list(csv.reader(open(default_run / "amplitudes.csv")))
    assert amp[0] == ["time"] + [f"commanded_{k}" for k in range(4)] + [f"realised_{k}" for k in range(4)]
    data = np.array(amp[1:], dtype=float)
    # the commanded amplitudes are the gait times the ceilings
    ceilings = np.array(summary["muscle_ceilings"])
    t = data[1:, 0] - 0.01
    gait = np.array([0.45, 0.35, 0.25, 0.15]) * np.sin(
        2 * np.pi * (t[:, None] / [1.2, 0.8, 1.0, 0.6] + [0, 0.25, 0.5, 0.1])
    )
    np.testing.assert_allclose(data[1:, 1:5], gait * ceilings, rtol=1e-12, atol=1e-12)


def test_3d_run_files(tmp_path):
    data = {
        "mesh": {"shape": "creature", "params": {"cell": 0.2}},
        "muscles": {"count": 2, "gait": {"amplitude": [0.2, 0.2], "period": [0.5, 0.7]}},
        "time": {"step": 0.01, "steps": 20},
        "gravity": {"acceleration": [0.0, 0.0, -9.8]},
        "ground": {"offset": 0.0},
        "output": {"every": 10},
    }
    summary = run_scene(Scene.from_dict(data), tmp_path)
    assert summary["status"] == "completed"
    entries = pvd_entries(tmp_path / "frames.pvd")
    assert [float(t) for t, _ in entries] == [0.0, 0.1, 0.2]
    frame = meshio.read(tmp_path / entries[-1][1])
    assert "tetra" in frame.cells_dict and frame.points.shape[1] == 3
    assert frame.point_data["displacement"].shape == frame.points.shape
    assert list(csv.reader(open(tmp_path / "com.csv")))[0] == ["time", "x", "y", "z"]


def test_a_failing_run_keeps_its_frames_and_says_why(tmp_path, monkeypatch):
    scene = Scene.from_dict({**DEFAULT_SCENE, "time": {"step": 0.01, "steps": 50}, "output": {"every": 2}})
    sim = scene.build()
    real_step = sim.step
    calls = {"n": 0}

    def step(z, z_dot, a=None, **options):
        calls["n"] += 1
        if calls["n"] == 13:
            raise SimulationError("the state became non-finite")
        return real_step(z, z_dot, a, **options)

    monkeypatch.setattr(sim, "step", step)
    with pytest.raises(SimulationError, match=r"step 13: the state became non-finite") as info:
        run_scene(scene, tmp_path, sim=sim)
    assert info.value.step == 13
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["status"] == "failed"
    assert summary["error"]["step"] == 13 and summary["steps_completed"] == 12
    entries = pvd_entries(tmp_path / "frames.pvd")
    assert len(entries) == 7  # steps 0, 2, ..., 12
    for _, f in entries:
        assert meshio.read(tmp_path / f).points.shape == (1719, 3)


def test_cli_scene_error_exit_code(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("[ground]\nhieght = 1.0\n[time]\nstep = -1\n")
    assert main(["run", str(bad), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "ground.hieght: unknown key" in err and "time.step: expected a positive number, got -1" in err
    assert not (tmp_path / "out").exists()  # nothing started


def test_cli_info(capsys):
    assert main(["info"]) == 0
    text = capsys.readouterr().out
    assert "effects: elasticity, inertia, muscles, gravity, contact" in text
    assert "3438 DOFs, subspace 48, 20 clusters, 4 muscles" in text
    assert (
        "muscles: sine gait, amplitudes [0.45, 0.35, 0.25, 0.15] of the ceilings, periods [1.2, 0.8, 1.0, 0.6], "
        "phases [0.0, 0.25, 0.5, 0.1], at full amplitude from the start\n"
    ) in text
    assert main(["info", "creature"]) == 0
    assert "tetrahedron" in capsys.readouterr().out


def test_cli_info_says_what_drives_the_muscles(tmp_path, capsys):
    (tmp_path / "acts.csv").write_text("time,a\n0,0\n1,1\n")
    scene = 'mesh = { shape = "beam2d" }\nmuscles = { count = 1, %s }\n'
    for drive, said in [
        ('table = "acts.csv"', "muscles: the table "),
        ("gait = { amplitude = [0.3], period = [0.5], ramp = 2.0 }", "phases [0.0], ramped in over 2\n"),
    ]:
        (tmp_path / "s.toml").write_text(scene % drive)
        assert main(["info", str(tmp_path / "s.toml")]) == 0
        assert said in capsys.readouterr().out
    (tmp_path / "s.toml").write_text('mesh = { shape = "beam2d" }\nmuscles = { count = 1 }\n')
    assert main(["info", str(tmp_path / "s.toml")]) == 0
    assert "muscles: at rest (no gait, no table)\n" in capsys.readouterr().out


def test_cli_render_with_matplotlib(default_run, capsys):
    pytest.importorskip("matplotlib", reason="matplotlib is in the plot extra")
    assert main(["render", str(default_run), "--backend", "matplotlib", "--max-frames", "6"]) == 0
    for name in ("com.png", "amplitudes.png", "first_frame.png", "last_frame.png", "animation.gif"):
        assert (default_run / name).stat().st_size > 1000
    from PIL import Image

    gif = Image.open(default_run / "animation.gif")
    assert gif.n_frames == 6 and gif.size == (1280, 720)
    floor_rows = []
    for k in range(gif.n_frames):
        gif.seek(k)
        column = np.asarray(gif.convert("RGB")).astype(int)[:, 3]  # left edge: floor and sky only
        floor_rows.append(int(np.argmax(column.mean(axis=1) < 245)))
    # the camera follows the crawl sideways, but the ground stays put on screen
    assert 360 < floor_rows[0] < 700 and len(set(floor_rows)) == 1, floor_rows


def test_progress_without_tqdm_writes_lines_to_a_log(monkeypatch, capsys):
    import sys

    from skfem_modal.run import Progress

    monkeypatch.setitem(sys.modules, "tqdm", None)  # the fallback, as without the extra
    bar = Progress(45, "steps")
    for _ in range(45):
        bar.update()
    bar.close()
    lines = capsys.readouterr().err.splitlines()
    # not a terminal: whole lines, about one a tenth of the way, ending at the total
    assert "\r" not in "".join(lines)
    assert 10 <= len(lines) <= 14
    assert lines[-1] == "steps: 45/45"
    assert len(set(lines)) == len(lines)
    # a resumed job's count starts far past 0: a line a tenth of the way still (it printed every update)
    bar = Progress(100, "gen", initial=80)
    for _ in range(20):
        bar.update()
    bar.close()
    assert capsys.readouterr().err.splitlines() == ["gen: 81/100", "gen: 91/100", "gen: 100/100"]
