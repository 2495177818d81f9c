"""Edges of a run's inputs and outputs: an output path that is a file, a duration that is not a whole number of
steps, a disk filling up."""

import json
import warnings

import numpy as np
import pytest

from skfem_modal.cli import main
from skfem_modal.run import run_scene
from skfem_modal.scene import Scene

SCENE = "[mesh]\nshape = 'caterpillar'\nparams = { nx = 20, ny = 10 }\n[muscles]\ncount = 1\n[time]\nstep = 0.01\n"


def test_an_output_path_that_is_a_file_is_named(tmp_path, capsys):
    scene = tmp_path / "scene.toml"
    scene.write_text(SCENE + "steps = 2\n")
    taken = tmp_path / "taken"
    taken.write_text("mine")
    for out, said in (
        (taken, f"the output folder {str(taken)!r} is a file, not a folder"),
        (taken / "run", f"the output folder {str(taken / 'run')!r} cannot be made: {str(taken)!r} is a file"),
    ):
        for flags in ([], ["--overwrite"]):
            assert main(["run", str(scene), "--out", str(out), "-q", *flags]) == 2
            err = capsys.readouterr().err
            assert said in err and "Errno" not in err
    assert taken.read_text() == "mine"  # never removed, even with --overwrite
    with pytest.raises(FileExistsError, match="is a file, not a folder"):
        run_scene(Scene.from_toml(scene), taken)
    # a file where the run writes its frames: named, before any work (it said "[Errno 17] File exists")
    folder = tmp_path / "out"
    folder.mkdir()
    (folder / "frames").write_text("mine")
    for flags in ([], ["--overwrite"]):
        assert main(["run", str(scene), "--out", str(folder), "-q", *flags]) == 2
        err = capsys.readouterr().err
        assert f"the output folder {str(folder)!r} holds a file named 'frames', where a run writes" in err
        assert sorted(p.name for p in folder.iterdir()) == ["frames"]


@pytest.mark.parametrize("command", [["run"], ["study", "--quick"], ["optimize", "--generations", "1"]])
@pytest.mark.parametrize("out", ["", "  "])
def test_an_output_folder_without_a_name_is_refused_before_any_work(tmp_path, capsys, monkeypatch, command, out):
    """An audit: ``--out ""`` ran the whole precompute, then said "[Errno 2] No such file or directory: ''"."""
    monkeypatch.chdir(tmp_path)
    assert main([*command, "--out", out, "-q"]) == 2
    err = capsys.readouterr().err
    assert err.endswith(f"error: the output folder {out!r} has no name: give a folder's name\n")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "duration, steps, warned",
    [(0.025, 3, True), (0.1, 10, False), (0.3, 30, False), (0.0201, 3, True), (0.005, 1, True)],
)
def test_a_duration_between_steps_is_rounded_up_with_a_warning_naming_both_keys(tmp_path, duration, steps, warned):
    path = tmp_path / "scene.toml"
    path.write_text(SCENE + f"duration = {duration!r}\n")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = Scene.from_toml(path)
    assert scene.n_steps == steps and scene.n_steps * scene.h >= duration * (1 - 1e-9)
    said = [str(w.message) for w in caught if str(w.message).startswith("time.duration = ")]
    if warned:
        assert said == [
            f"time.duration = {duration!r} is not a whole number of time.step = 0.01: running {steps} steps, to "
            f"t = {steps * 0.01:g} (the duration rounded up to a whole step; give time.steps for an exact count)"
        ]
    else:
        assert said == []


def test_a_folder_given_as_the_scene_is_named_a_folder(tmp_path, capsys):
    from skfem_modal.cli import main

    assert main(["run", str(tmp_path)]) == 2  # it said 'scene file not found'
    assert f"scene file {str(tmp_path)!r} is a folder: give the .toml file in it" in capsys.readouterr().err


SMALL_GROUND = {
    "mesh": {"shape": "caterpillar", "params": {"nx": 20, "ny": 10}},
    "muscles": {"count": 2},
    "time": {"steps": 4},
    "gravity": {"acceleration": [0.0, -9.8]},
    "ground": {},
}


def test_run_scene_refuses_a_simulator_built_from_another_scene():
    scene = Scene.from_dict(SMALL_GROUND)
    other = Scene.from_dict({**SMALL_GROUND, "mesh": {"shape": "caterpillar", "params": {"nx": 10, "ny": 5}}})
    with pytest.raises(ValueError, match=r"sim was not built from this scene: its mesh has \d+ vertices in 2D"):
        run_scene(scene, None, sim=other.build())
    more_muscles = Scene.from_dict({**SMALL_GROUND, "muscles": {"count": 3}})
    with pytest.raises(ValueError, match="it has 3 muscles, the scene 2 \\(muscles.count\\)"):
        run_scene(scene, None, sim=more_muscles.build())


def test_the_summary_says_the_settings_a_handed_simulator_ran_with():
    """A simulator assigned h and friction after its build runs with them: the summary says so, beside the scene."""
    scene = Scene.from_dict(SMALL_GROUND)
    sim = scene.build()
    sim.h, sim.friction = 0.005, 0.0
    summary = run_scene(scene, None, sim=sim)
    assert summary["settings"]["h"] == summary["h"] == 0.005 and summary["settings"]["friction"] == 0.0
    assert summary["scene"]["time"]["step"] == 0.01 and summary["scene"]["ground"]["friction"] is None  # (0.5)
    assert summary["settings"]["contact_model"] == "coulomb" and summary["settings"]["gravity"] == [0.0, -9.8]


def test_the_summary_says_the_material_simulated():
    """summary.json's scene keeps the keys as given (mu null by default): its material block resolves them."""
    scene = Scene.from_dict({**SMALL_GROUND, "material": {"young": 2e5, "poisson": 0.25, "rho": 900.0}})
    summary = run_scene(scene, None)
    assert summary["scene"]["material"]["mu"] is None
    assert summary["material"]["mu"] == summary["material"]["gamma"] == 2e5 and summary["material"]["rho"] == 900.0
    assert summary["material"]["lam"] == pytest.approx(2e5)  # Lame (8e4, 8e4), lambda scaled as mu


def _disk_full_at(frame: str, tmp_path, monkeypatch):
    """A 30-step scene whose frame file ``frame`` cannot be written (no space left)."""
    from skfem_modal import export

    scene = tmp_path / "scene.toml"
    scene.write_text(SCENE + "steps = 30\n")
    write = export.VtuPiece.write

    def fills_up(self, path, *args):
        if path.endswith(frame):
            raise OSError(28, "No space left on device")
        return write(self, path, *args)

    monkeypatch.setattr(export.VtuPiece, "write", fills_up)
    return scene


def test_a_disk_filling_up_during_a_run_is_named_and_the_summary_says_so(tmp_path, capsys, monkeypatch):
    # a full disk said "error: [Errno 28] No space left on device" (exit 2, "bad input") and left no summary.json:
    # the last frame was tried again as the run closed, and that failure replaced the first
    scene = _disk_full_at("frame_00003.vtu", tmp_path, monkeypatch)
    out = tmp_path / "run"
    assert main(["run", str(scene), "--out", str(out), "-q", "--every", "5"]) == 5
    err = capsys.readouterr().err
    frame = str(out / "frames" / "frame_00003.vtu")
    said = f"could not write {frame}: No space left on device (at step 15, t = 0.15); the frames end at t = 0.1, and"
    assert f"skfem-modal run: outputs failed: {said}" in err and "Errno" not in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed" and said in summary["error"]["message"]
    assert summary["steps_completed"] == 14 and summary["frames"]["times"] == [0.0, 0.1]
    assert np.loadtxt(out / "com.csv", delimiter=",", skiprows=1)[-1, 0] == pytest.approx(0.14)
    assert sorted(p.name for p in (out / "frames").iterdir()) == [f"frame_0000{k}.vtu" for k in range(3)]


def test_a_disk_full_at_the_last_frame_or_before_the_first_fails_the_run_plainly(tmp_path, capsys, monkeypatch):
    # the last frame (written as the run closes) raised a plain OSError: exit 2, no summary.json
    from skfem_modal import run

    scene = _disk_full_at("frame_00002.vtu", tmp_path, monkeypatch)
    out = tmp_path / "last"
    assert main(["run", str(scene), "--out", str(out), "-q", "--every", "20"]) == 5
    assert "frame_00002.vtu: No space left on device (at step 30, t = 0.3); the frames end at t = 0.2" in (
        capsys.readouterr().err
    )
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed" and summary["steps_completed"] == 30
    # a table that cannot be made: nothing run, nothing left
    opened = open

    def no_room(path, *args, **kwargs):
        if str(path).endswith("amplitudes.csv"):
            raise OSError(28, "No space left on device", str(path))
        return opened(path, *args, **kwargs)

    monkeypatch.setattr(run, "open", no_room, raising=False)
    out = tmp_path / "none"
    assert main(["run", str(scene), "--out", str(out), "-q"]) == 5
    assert "amplitudes.csv: No space left on device; nothing was run" in capsys.readouterr().err
    assert not out.exists()  # the folder the run made, too
    out.mkdir()
    assert main(["run", str(scene), "--out", str(out), "-q"]) == 5
    assert out.is_dir() and list(out.iterdir()) == []  # a folder given, kept
