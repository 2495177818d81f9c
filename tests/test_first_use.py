"""What a first-time user meets on the command line: errors, exit codes, output folders, help."""

import json
import os
import re
import subprocess
import sys
import textwrap

import meshio
import numpy as np
import pytest

import skfem_modal as sm
from skfem_modal.cli import main
from skfem_modal.run import run_scene
from skfem_modal.scene import Scene, SceneError

DOCS = os.path.join(os.path.dirname(__file__), "..", "docs")

SMALL_RUN = """
[mesh]
shape = "beam2d"
params = { length = 2.0, height = 0.5, nx = 8, ny = 2 }
[subspace]
weights = 3
clusters = 4
[muscles]
count = 1
[muscles.gait]
amplitude = [0.5]
period = [0.5]
[time]
step = 0.01
steps = 20
"""


@pytest.fixture()
def small_scene(tmp_path):
    path = tmp_path / "small.toml"
    path.write_text(SMALL_RUN)
    return path


def garbage_files(tmp_path):
    garbage = tmp_path / "garbage.msh"
    garbage.write_text("garbage\n")
    empty = tmp_path / "nocells.vtu"
    meshio.write(empty, meshio.Mesh(np.random.default_rng(1).random((5, 3)), []))
    unknown = tmp_path / "points.xyz"  # meshio's raw "Could not deduce file format" before
    unknown.write_text("0 0 0\n")
    return garbage, empty, unknown


@pytest.mark.parametrize("command", ["modes", "info"])
def test_unreadable_mesh_files_exit_2_with_one_line(tmp_path, capsys, command):
    reasons = ["as ansys, gmsh", "Inconsistent data!", "no mesh format has the extension '.xyz'; meshio reads .avs"]
    for path, reason in zip(garbage_files(tmp_path), reasons):
        assert main([command, str(path), *(["--out", str(tmp_path / "m.vtu")] if command == "modes" else [])]) == 2
        out, err = capsys.readouterr()
        assert out == "" and err.count("\n") == 1, err
        assert err.startswith(f"skfem-modal {command}: error: cannot read mesh '{path}': ") and reason in err
    assert not (tmp_path / "m.vtu").exists()


def test_scene_with_an_unreadable_mesh_file_exits_2(tmp_path, capsys):
    garbage, _, _ = garbage_files(tmp_path)
    scene = tmp_path / "s.toml"
    scene.write_text(f'[mesh]\nfile = "{garbage.name}"\n')
    assert main(["run", str(scene), "--out", str(tmp_path / "out"), "-q"]) == 2
    assert "mesh: cannot read mesh" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_render_without_the_plot_extra_says_what_to_install(tmp_path, capsys, small_scene, monkeypatch):
    out = tmp_path / "run"
    assert main(["run", str(small_scene), "--out", str(out), "-q"]) == 0
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # as without the plot extra
    for argv in (["render", str(out)], ["run", str(small_scene), "--out", str(tmp_path / "r2"), "--render", "-q"]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert "cannot render: matplotlib not installed: pip install 'skfem_modal[plot]'" in err
        assert "Traceback" not in err
    assert not (tmp_path / "r2").exists()  # checked before the run started
    assert not (out / "com.png").exists()


def test_mp4_without_an_ffmpeg_plugin_fails_before_drawing(tmp_path, capsys, small_scene, monkeypatch):
    imageio = pytest.importorskip("imageio.v2", reason="imageio is in the plot extra")
    out = tmp_path / "run"
    assert main(["run", str(small_scene), "--out", str(out), "-q"]) == 0
    before = sorted(os.listdir(out))

    def no_backend(*args, **kwargs):  # what imageio says without ffmpeg or pyav
        raise ValueError("Could not find a backend to open `x.mp4`` with iomode `wI`.")

    monkeypatch.setattr(imageio, "mimwrite", no_backend)
    assert main(["render", str(out), "--format", "mp4", "--backend", "matplotlib"]) == 2
    assert "pip install 'imageio[ffmpeg]', or use --format gif" in capsys.readouterr().err
    assert sorted(os.listdir(out)) == before  # no picture drawn or overwritten


def test_an_earlier_run_is_refused_or_replaced_never_mixed(tmp_path, capsys, small_scene):
    out = tmp_path / "out"
    assert main(["run", str(small_scene), "--out", str(out), "-q", "--every", "1"]) == 0
    assert len(os.listdir(out / "frames")) == 21
    (out / "animation.gif").write_bytes(b"GIF89a")  # as a render of the first run leaves
    (out / "notes.txt").write_text("mine")
    (out / "frames" / "mine.vtu").write_text("mine")
    first = (out / "summary.json").read_text()

    assert main(["run", str(small_scene), "--out", str(out), "-q", "--every", "10"]) == 2
    err = capsys.readouterr().err
    assert "holds an earlier run (amplitudes.csv, animation.gif, com.csv, frames.pvd, summary.json, 21 frames)" in err
    assert "pass --overwrite" in err
    assert (out / "summary.json").read_text() == first and len(os.listdir(out / "frames")) == 22

    assert main(["run", str(small_scene), "--out", str(out), "-q", "--every", "10", "--overwrite"]) == 0
    assert sorted(os.listdir(out)) == ["amplitudes.csv", "com.csv", "frames", "frames.pvd", "notes.txt", "summary.json"]
    assert sorted(os.listdir(out / "frames")) == ["frame_00000.vtu", "frame_00001.vtu", "frame_00002.vtu", "mine.vtu"]
    assert (out / "notes.txt").read_text() == "mine"
    assert json.loads((out / "summary.json").read_text())["frames"]["count"] == 3
    # the library call refuses too, naming its own way to overwrite
    with pytest.raises(FileExistsError, match="pass overwrite=True"):
        run_scene(Scene.from_toml(small_scene), out)


def test_a_frames_folder_that_cannot_be_written_is_refused_before_anything_is_removed(
    tmp_path, capsys, small_scene, monkeypatch
):
    """An audit (as a user, frames/ made read-only): the run crashed with a traceback, and --overwrite had
    already removed the earlier run's tables, losing it."""
    import tempfile

    out = tmp_path / "out"
    assert main(["run", str(small_scene), "--out", str(out), "-q"]) == 0
    before = sorted(os.listdir(out)), sorted(os.listdir(out / "frames"))
    made = tempfile.mkdtemp

    def refused_in_frames(*args, dir=None, **kwargs):  # as a folder this user cannot write (root writes any)
        if os.path.basename(dir) == "frames":
            raise PermissionError(13, "Permission denied")
        return made(*args, dir=dir, **kwargs)

    monkeypatch.setattr(tempfile, "mkdtemp", refused_in_frames)
    assert main(["run", str(small_scene), "--out", str(out), "-q", "--overwrite"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"skfem-modal run: error: the output folder's frames {str(out / 'frames')!r} cannot be")
    assert "Traceback" not in err and (sorted(os.listdir(out)), sorted(os.listdir(out / "frames"))) == before


def test_the_cleaner_knows_every_file_a_run_and_render_write(tmp_path, small_scene, capsys):
    from skfem_modal.outputs import earlier_run

    out = tmp_path / "out"
    assert main(["run", str(small_scene), "--out", str(out), "--render", "--backend", "matplotlib"]) == 0
    said = capsys.readouterr().out.splitlines()  # what was written, then what was drawn (the first left out)
    assert said[-2].startswith(f"wrote {out}/frames.pvd (") and said[-1].startswith("rendered with matplotlib: ")
    assert main(["render", str(out), "-q", "--backend", "matplotlib", "--max-frames", "2", "--size", "320x180"]) == 0
    written = sorted(str(p) for p in out.rglob("*") if p.is_file())
    assert len(written) == 21 + 4 + 5 and earlier_run(out) == written
    from PIL import Image

    assert Image.open(out / "last_frame.png").size == (320, 180)


@pytest.mark.parametrize("umask, mode", [(0o022, 0o644), (0o077, 0o600)])
def test_written_files_follow_the_umask(tmp_path, small_scene, umask, mode):
    old = os.umask(umask)
    try:
        assert main(["run", str(small_scene), "--out", str(tmp_path / "out"), "-q"]) == 0
        assert main(["modes", "beam2d:nx=4,ny=1", "-q", "--out", str(tmp_path / "modes.vtu")]) == 0
    finally:
        os.umask(old)
    files = [tmp_path / "modes.vtu", *(tmp_path / "out").iterdir(), *(tmp_path / "out" / "frames").iterdir()]
    modes = {p.name: oct(p.stat().st_mode & 0o777) for p in files if p.is_file()}
    assert set(modes.values()) == {oct(mode)}, modes


def test_fewer_modes_than_rigid_motions(tmp_path, capsys, cat_mesh):
    values, modes = sm.linear_modal_analysis(cat_mesh, 2)
    assert values.shape == (2,) and np.abs(values).max() < 1e-10
    # the canonical rigid motions: a translation along x, then along y
    u = modes.reshape(-1, 2, 2)
    np.testing.assert_allclose(u[:, 0, 0], u[0, 0, 0])
    np.testing.assert_allclose(u[:, 1, 0], 0.0, atol=1e-12)
    np.testing.assert_allclose(u[:, 1, 1], u[0, 1, 1])
    np.testing.assert_allclose(u[:, 0, 1], 0.0, atol=1e-12)
    assert main(["modes", "-k", "2", "--out", str(tmp_path / "m.vtu")]) == 0
    text = capsys.readouterr().out
    assert "all 2 are rigid motions: ask for more than 3 (-k) to see elastic modes" in text
    assert len(meshio.read(tmp_path / "m.vtu").point_data) == 2


def test_modes_defaults_to_six_elastic_modes_in_3d(tmp_path, capsys):
    assert main(["modes", "creature:cell=0.2", "--out", str(tmp_path / "m.vtu")]) == 0
    kinds = [line.split()[-1] for line in capsys.readouterr().out.splitlines() if line.endswith(("rigid", "elastic"))]
    assert kinds == ["rigid"] * 6 + ["elastic"] * 6


def test_shape_parameters_are_named_and_defaulted_in_scenes():
    with pytest.raises(SceneError, match=r"mesh.params.nx: expected an integer, got 'a' \(str\)"):
        Scene.from_dict({"mesh": {"shape": "caterpillar", "params": {"nx": "a"}}, "muscles": {"count": 0}})
    scene = Scene.from_dict({"mesh": {"shape": "box3d"}, "muscles": {"count": 1}})
    assert scene.mesh.t.shape[1] == 6 * 8**3


def test_a_closed_pipe_ends_quietly():
    # the reader is gone before anything is written: the write meets a closed pipe
    proc = subprocess.Popen(
        [sys.executable, "-m", "skfem_modal.cli", "info", "--scene-reference"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    proc.stdout.close()
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 141
    assert err == ""


def test_quiet_run_prints_nothing(tmp_path, capsys, small_scene):
    assert main(["run", str(small_scene), "--out", str(tmp_path / "out"), "-q"]) == 0
    assert capsys.readouterr() == ("", "")


@pytest.mark.parametrize("every", ["0", "-3", "1.5"])
def test_every_must_be_a_positive_integer(tmp_path, capsys, small_scene, every):
    with pytest.raises(SystemExit) as info:
        main(["run", str(small_scene), "--out", str(tmp_path / "out"), "--every", every])
    assert info.value.code == 2
    assert f"argument --every: expected a positive integer, got '{every}'" in capsys.readouterr().err
    with pytest.raises(ValueError, match="every must be a positive integer, got 0"):
        run_scene(Scene.from_toml(small_scene), None, every=0)


def test_the_scene_page_error_sample_is_what_the_command_prints(tmp_path, capsys, monkeypatch):
    text = open(os.path.join(DOCS, "scenes.md")).read()
    toml = re.search(r"This `broken.toml`\n\n```toml\n(.*?)```", text, re.S).group(1)
    shown = re.search(r"    \$ skfem-modal run broken.toml\n((?:    .*\n)+)", text).group(1)
    (tmp_path / "broken.toml").write_text(toml)
    monkeypatch.chdir(tmp_path)
    assert main(["run", "broken.toml"]) == 2
    assert capsys.readouterr().err == textwrap.dedent(shown)


def test_problems_that_need_the_mesh_come_with_the_others():
    data = {
        "mesh": {"shape": "caterpillar", "params": {"nx": 20, "ny": 10}},
        "time": {"step": "fast"},
        "gravity": {"acceleration": [0.0, 0.0, -9.8]},
        "muscles": {"count": 2, "gait": {"amplitude": [0.1, 0.1], "period": [1.0]}},
        "meshes": 1,
    }
    with pytest.raises(SceneError) as info:
        Scene.from_dict(data)
    lines = str(info.value).splitlines()
    assert lines[0] == "4 problem(s) in the scene:"
    assert sorted(line.strip() for line in lines[1:]) == [
        "gravity.acceleration: expected 2 values for this 2D mesh, got 3",
        "meshes: unknown key; expected one of name, mesh, material, subspace, muscles, time, gravity, ground, "
        "pinned, damping, output",
        "muscles.gait.period: expected 2 values (muscles.count), got 1",
        "time.step: expected a finite number, got 'fast' (str)",
    ]


def test_empty_damping_is_an_error_that_says_what_is_missing():
    base = {"mesh": {"shape": "beam2d", "params": {"nx": 8, "ny": 2}}, "muscles": {"count": 0}}
    for damping in ({}, {"mass": 0.0, "stiffness": 0.0}):
        with pytest.raises(SceneError, match=r"damping: expected mass \(1 / time\) or stiffness \(time\) above 0"):
            Scene.from_dict({**base, "damping": damping})
    assert Scene.from_dict({**base, "damping": {"stiffness": 0.01}}).effects == ("elasticity", "inertia", "damping")


def test_version_and_defaults_in_help(capsys):
    with pytest.raises(SystemExit) as info:
        main(["--version"])
    assert info.value.code == 0 and capsys.readouterr().out == f"skfem-modal {sm.__version__}\n"
    helps = {}
    for command in ("modes", "optimize", "play"):
        with pytest.raises(SystemExit):
            main([command, "--help"])
        helps[command] = " ".join(capsys.readouterr().out.split())
    for shown in ("(default: P1)", "(default: lumped for P1, consistent for P2", "ceilings (default: 2.0)"):
        assert shown in helps["modes"]
    for shown in (
        "generations (default: 20)",
        "generation (at least 2) (default: 12)",
        "(default: 0.3 2.0)",
        "ceiling (default: 1.0)",
        "(0 to 4294967294) (default: 0)",  # a default of 0 was left unsaid (0 == False; an audit)
    ):
        assert shown in helps["optimize"]
    # said as the option takes it (it said "960 600", which --size refuses)
    assert "window size in pixels (default: 960x600)" in helps["play"]


def test_the_cleaner_knows_frames_past_the_99999th(tmp_path):
    """The writer names frame 100000 ``frame_100000.vtu``: an overwrite removes it too (five digits left it stale)."""
    from skfem_modal.outputs import earlier_run

    frames = tmp_path / "frames"
    frames.mkdir()
    names = [
        "frame_00000.vtu",
        "frame_99999.vtu",
        "frame_100000.vtu",
        "frame_1234567.vtu",
        ".frame_100000.0123abcd.vtu",
    ]
    for name in names + ["frame_1.vtu", "frame_100000.vtu.bak", "mine.vtu"]:
        (frames / name).write_text("")
    assert earlier_run(tmp_path) == sorted(str(frames / name) for name in names)
