"""Edges of a run's inputs: an output path that is a file, a duration that is not a whole number of steps."""

import warnings

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
