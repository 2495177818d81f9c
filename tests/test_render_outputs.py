"""What ``skfem-modal render`` writes and refuses: picture sizes, broken frames, streamed animations, the stills."""

import os
import shutil
import weakref

import numpy as np
import pytest
from ci import unavailable
from test_first_use import SMALL_RUN

from skfem_modal import plot
from skfem_modal.cli import main

pytest.importorskip("matplotlib", reason="matplotlib is in the plot extra")
from PIL import Image  # noqa: E402  (pillow comes with matplotlib)

# a 2D body on the ground, 21 frames
SCENE = SMALL_RUN + "[gravity]\nacceleration = [0.0, -9.8]\n[ground]\noffset = 0.0\n"


def needs_gl():
    if not plot.gl_available():
        unavailable("no off-screen OpenGL here: pyvista cannot render")


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory):
    base = tmp_path_factory.mktemp("render")
    scene = base / "scene.toml"
    scene.write_text(SCENE)
    out = base / "run"
    assert main(["run", str(scene), "--out", str(out), "-q"]) == 0
    assert len(os.listdir(out / "frames")) == 21
    return scene, out


@pytest.fixture()
def run_copy(finished_run, tmp_path):
    """A copy of the finished run that a test may break or render into."""
    shutil.copytree(finished_run[1], tmp_path / "run")
    return tmp_path / "run"


def exit_code(argv):
    """The command's exit code, a usage error's (argparse exits) included."""
    try:
        return main(argv)
    except SystemExit as stop:
        return stop.code


def pixels(path):
    return np.asarray(Image.open(path).convert("RGB")).astype(int)


def gif_frames(path):
    gif = Image.open(path)
    frames = []
    for k in range(gif.n_frames):
        gif.seek(k)
        frames.append(np.asarray(gif.convert("RGB")).astype(int))
    return frames


@pytest.mark.parametrize(
    "argv",
    [
        ["--size", "20000x200", "--backend", "pyvista"],  # pyvista: blank frames beyond 16384 here
        ["--size", "70000x100", "--backend", "matplotlib"],  # matplotlib: an OverflowError
        ["--size", "100000x100000"],  # a MemoryError or an abort
        ["--size", "8193x16"],
        ["--size", "16x8193"],
        ["--size", "15x100"],
    ],
)
def test_sizes_beyond_what_the_backends_draw_are_refused_before_any_work(run_copy, tmp_path, capsys, argv):
    before = sorted(os.listdir(run_copy))
    assert exit_code(["render", str(run_copy), *argv]) == 2
    err = capsys.readouterr().err
    assert "argument --size" in err and "each side must be 16 to 8192 pixels" in err and "Traceback" not in err
    assert sorted(os.listdir(run_copy)) == before
    # and from run --render, before the run starts
    scene = tmp_path / "scene.toml"
    scene.write_text(SCENE)
    assert exit_code(["run", str(scene), "--out", str(tmp_path / "new"), "--render", *argv]) == 2
    assert "each side must be 16 to 8192 pixels" in capsys.readouterr().err
    assert not (tmp_path / "new").exists()


def test_the_library_refuses_the_same_sizes(run_copy):
    with pytest.raises(ValueError, match="size 20000x200: each side must be 16 to 8192 pixels"):
        plot.render_run(run_copy, size=(20000, 200))
    with pytest.raises(ValueError, match="size 333x333: an mp4 needs an even width and height"):
        plot.render_run(run_copy, size=(333, 333), fmt="mp4")
    assert not (run_copy / "com.png").exists()


@pytest.mark.parametrize("backend", ["matplotlib", "pyvista"])
def test_the_largest_side_allowed_is_drawn(run_copy, backend):
    if backend == "pyvista":
        needs_gl()
    assert main(["render", str(run_copy), "-q", "--backend", backend, "--size", "8192x64", "--max-frames", "2"]) == 0
    image = pixels(run_copy / "last_frame.png")
    assert image.shape == (64, 8192, 3)
    # a picture, not one colour: the body's colours are there (far from every grey)
    assert (np.ptp(image, axis=2) > 40).sum() > 50


@pytest.mark.parametrize("backend", ["matplotlib", "pyvista"])
@pytest.mark.parametrize("size", [(16, 16), (1280, 16), (16, 720)])
def test_the_smallest_sides_allowed_are_drawn(run_copy, backend, size):
    """matplotlib's text at 16 x 16 was under a pixel high: FreeType's 'invalid ppem value', a traceback (an audit)."""
    if backend == "pyvista":
        needs_gl()
    argv = ["render", str(run_copy), "-q", "--backend", backend, "--size", "{}x{}".format(*size), "--max-frames", "2"]
    assert main(argv) == 0
    assert pixels(run_copy / "last_frame.png").shape == (size[1], size[0], 3)


@pytest.mark.parametrize("damage", ["summary", "summary bytes", "summary list", "cut rows", "cut number", "cut series"])
def test_a_broken_summary_or_cut_table_is_named_in_one_line(run_copy, capsys, damage):
    # a broken summary.json gave json's own message without the file; a com.csv cut to its first rows drew;
    # a frames.pvd cut to its first frames drew them, the last of them as the run's last frame
    summary, com, pvd = run_copy / "summary.json", run_copy / "com.csv", run_copy / "frames.pvd"
    if damage == "summary":
        summary.write_text(summary.read_text()[:40])
    elif damage == "summary bytes":  # not UTF-8: a UnicodeDecodeError that named no file
        summary.write_bytes(b"\xff\xfe" + summary.read_bytes())
    elif damage == "summary list":  # JSON, but not a run's (it was taken)
        summary.write_text("[1]")
    elif damage == "cut series":
        pvd.write_text(pvd.read_text()[:400])
    else:
        text = com.read_text()
        com.write_text(text[: text.index("\n", text.index("\n") + 1) + 1] if damage == "cut rows" else text[:-8])
    before = sorted(os.listdir(run_copy))
    assert main(["render", str(run_copy), "--backend", "matplotlib"]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    expected = {
        "summary": f"cannot read {summary}: ",
        "summary bytes": f"cannot read {summary}: ",
        "summary list": f"cannot read {summary}: not the JSON a run writes (an object of its keys), got [1]",
        "cut rows": f"{com} holds 1 rows, where summary.json's",
        "cut number": f"{com} ends in the middle of a row",
        "cut series": f"{pvd} lists 3 frames, where summary.json says the run wrote",
    }
    assert expected[damage] in err
    assert sorted(os.listdir(run_copy)) == before


@pytest.mark.parametrize("damage", ["missing", "truncated", "not a frame", "another time"])
def test_a_missing_or_broken_frame_is_named_in_one_line(run_copy, capsys, damage):
    frame = run_copy / "frames" / "frame_00004.vtu"
    if damage == "another time":  # a frame of another run of the same mesh (its cells and rest shape) was drawn
        shutil.copyfile(run_copy / "frames" / "frame_00001.vtu", frame)
    elif damage == "missing":
        frame.unlink()
    elif damage == "truncated":
        frame.write_bytes(frame.read_bytes()[: frame.stat().st_size // 2])
    else:  # a readable .vtu without the displacement a frame has
        import meshio

        mesh = meshio.read(frame)
        mesh.point_data = {}
        meshio.write(frame, mesh)
    before = sorted(os.listdir(run_copy))
    assert main(["render", str(run_copy), "--backend", "matplotlib"]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert err.startswith("skfem-modal render: error: ") and f"{str(frame)!r}" in err
    expected = {
        "missing": "(listed in frames.pvd) is missing",
        "truncated": "cannot read frame file",
        "not a frame": "is not a frame of a run",
        "another time": "frames.pvd lists it at",
    }
    assert expected[damage] in err
    assert sorted(os.listdir(run_copy)) == before  # nothing drawn


def test_a_missing_frame_the_animation_leaves_out_is_named_too(run_copy, capsys):
    """An audit: with --max-frames below the frames listed, a deleted frame it did not draw went unseen."""
    for k in (1, 3):
        (run_copy / "frames" / f"frame_0000{k}.vtu").unlink()
    before = sorted(os.listdir(run_copy))
    assert main(["render", str(run_copy), "--backend", "matplotlib", "--max-frames", "2"]) == 2
    err = capsys.readouterr().err
    assert err == (
        f"skfem-modal render: error: frame file {str(run_copy / 'frames' / 'frame_00001.vtu')!r} (listed in "
        "frames.pvd) is missing, and 1 more\n"
    )
    assert sorted(os.listdir(run_copy)) == before


def test_frames_go_to_the_animation_one_at_a_time(run_copy, monkeypatch):
    """Each frame is written as soon as it is drawn and nothing keeps it: memory is one frame's, not all of them."""
    drawn, alive_when_written = [], []
    draw = plot._matplotlib_frames

    def watched(*args):
        for image in draw(*args):
            drawn.append(weakref.ref(image))
            yield image

    append = plot._GifStream.append_data

    def written(self, image):
        alive_when_written.append((len(drawn), sum(ref() is not None for ref in drawn)))
        append(self, image)

    monkeypatch.setattr(plot, "_matplotlib_frames", watched)
    monkeypatch.setattr(plot._GifStream, "append_data", written)
    plot.render_run(run_copy, backend="matplotlib", size=(160, 90))
    assert len(drawn) == 21
    # when frame k is written, k + 1 frames have been drawn (no more) and only that one is held
    assert alive_when_written == [(k + 1, 1) for k in range(21)]
    assert len(gif_frames(run_copy / "animation.gif")) == 21


def test_the_streamed_gif_holds_every_frame_as_drawn(run_copy):
    plot.render_run(run_copy, backend="matplotlib", size=(320, 180), fps=20)
    gif = Image.open(run_copy / "animation.gif")
    assert gif.n_frames == 21 and gif.size == (320, 180)
    assert gif.info["loop"] == 0 and gif.info["duration"] == 50
    frames = gif_frames(run_copy / "animation.gif")
    # the first and last frames are the stills, to the 256 colours a GIF frame has
    assert np.abs(frames[0] - pixels(run_copy / "first_frame.png")).mean() < 1.5
    assert np.abs(frames[-1] - pixels(run_copy / "last_frame.png")).mean() < 1.5
    assert np.abs(frames[-1] - frames[0]).mean() > 1.0  # the body moved


def test_last_frame_is_the_runs_last_whatever_max_frames(run_copy):
    assert main(["render", str(run_copy), "-q", "--backend", "matplotlib", "--max-frames", "2"]) == 0
    first, last = pixels(run_copy / "first_frame.png"), pixels(run_copy / "last_frame.png")
    assert len(gif_frames(run_copy / "animation.gif")) == 2
    assert main(["render", str(run_copy), "-q", "--backend", "matplotlib", "--max-frames", "1"]) == 0
    # the same frames drawn (0 and 20) through the same camera: the same pictures
    np.testing.assert_array_equal(pixels(run_copy / "first_frame.png"), first)
    np.testing.assert_array_equal(pixels(run_copy / "last_frame.png"), last)
    assert np.abs(last - first).mean() > 1.0
    (only,) = gif_frames(run_copy / "animation.gif")
    assert np.abs(only - first).mean() < 1.5  # the one-frame animation is the first frame
    # the colours, camera and scale are the whole run's, whatever is drawn (a new user's trial: with 2 frames
    # drawn the colour bar topped out at the last frame's deformation, and the body was drawn larger)
    assert main(["render", str(run_copy), "-q", "--backend", "matplotlib", "--max-frames", "21"]) == 0
    np.testing.assert_array_equal(pixels(run_copy / "first_frame.png"), first)
    np.testing.assert_array_equal(pixels(run_copy / "last_frame.png"), last)


@pytest.mark.parametrize("size", [(1158, 652), (334, 334)])
def test_mp4_keeps_the_size_given(run_copy, capfd, size):
    pytest.importorskip("imageio_ffmpeg", reason="imageio's ffmpeg plugin (pip install 'imageio[ffmpeg]')")
    import imageio.v2 as imageio

    argv = ["render", str(run_copy), "-q", "--backend", "matplotlib", "--format", "mp4", "--max-frames", "5"]
    assert main([*argv, "--size", f"{size[0]}x{size[1]}"]) == 0
    assert capfd.readouterr().err == ""  # no word from imageio or ffmpeg about resizing
    reader = imageio.get_reader(run_copy / "animation.mp4")
    assert reader.get_meta_data()["size"] == size  # not rounded to a multiple of 16
    frames = list(reader.iter_data())
    reader.close()
    assert len(frames) == 5 and frames[0].shape == (size[1], size[0], 3)
    assert np.abs(frames[-1].astype(int) - pixels(run_copy / "last_frame.png")).mean() < 4.0  # lossy


@pytest.mark.parametrize("size", ["1157x651", "333x333", "1158x651"])
def test_mp4_refuses_odd_sizes_naming_the_even_one(run_copy, capsys, size):
    before = sorted(os.listdir(run_copy))
    assert main(["render", str(run_copy), "--format", "mp4", "--size", size]) == 2
    err = capsys.readouterr().err
    w, h = (int(v) for v in size.split("x"))
    assert err == (
        f"skfem-modal render: error: --size {size}: an mp4 needs an even width and height (H.264 in yuv420p): "
        f"try {w + w % 2}x{h + h % 2}, or the gif format\n"
    )
    assert sorted(os.listdir(run_copy)) == before


def colour_bar_text_rows(image):
    """Rows of the colour bar's title and of its top label: (first, last) of each run of dark rows above the bar."""
    bar = image[:, int(0.86 * image.shape[1]) :]
    top = int(np.argmax((np.ptp(bar, axis=2) > 60).any(axis=1)))  # the bar's first row
    dark = (bar.max(axis=2) < 110)[: top + 20].any(axis=1)
    rows = np.flatnonzero(dark)
    return [(int(r[0]), int(r[-1])) for r in np.split(rows, np.flatnonzero(np.diff(rows) > 1) + 1)]


@pytest.mark.parametrize("backend", ["matplotlib", "pyvista"])
def test_the_floor_goes_on_behind_the_colour_bar(run_copy, backend):
    if backend == "pyvista":
        needs_gl()
    assert main(["render", str(run_copy), "-q", "--backend", backend, "--max-frames", "2"]) == 0
    image = pixels(run_copy / "first_frame.png")
    # below the ground, right of the colour bar: the floor's grey as under the body, not white
    corner = image[-30:, -60:]
    assert np.ptp(corner, axis=2).max() < 8 and 200 < corner.mean() < 245
    if backend == "pyvista":  # the bar's title clear of its top value
        title, label = colour_bar_text_rows(image)[:2]
        assert label[0] - title[1] > 6


def time_text_width(image):
    """Columns of the time's text (black on the white sky) in the picture's top left corner."""
    h, w = image.shape[:2]
    corner = image[: h // 8, : w // 4]
    columns = np.flatnonzero((corner.max(axis=2) < 80).any(axis=0))
    return columns.max() - columns.min() + 1


@pytest.mark.parametrize("backend", ["matplotlib", "pyvista"])
def test_text_grows_with_the_picture(run_copy, backend):
    # at 4K the time and the colour bar read as they do at the default size, not a third as tall
    if backend == "pyvista":
        needs_gl()
    widths = {}
    for size in [(1280, 720), (2560, 1440), (3840, 1440)]:  # the last: as tall as 2560x1440, wider
        w, h = size
        argv = ["render", str(run_copy), "-q", "--backend", backend, "--max-frames", "1", "--size", f"{w}x{h}"]
        assert main(argv) == 0
        image = pixels(run_copy / "last_frame.png")
        assert image.shape == (h, w, 3)
        widths[size] = time_text_width(image)
    assert widths[(1280, 720)] >= 50  # "t = 0.200"
    assert abs(widths[(2560, 1440)] / widths[(1280, 720)] - 2.0) < 0.15
    assert abs(widths[(3840, 1440)] - widths[(2560, 1440)]) <= 2


def test_the_centre_of_mass_plot_draws_the_ground_on_its_own_axis(tmp_path, monkeypatch):
    """An audit: a 3D body with y up (gravity says it) had its ground line drawn on the z panel.

    And a run without muscles reads back: its amplitudes.csv held a header and no rows, which render refused.
    """
    import matplotlib.figure

    scene = tmp_path / "scene.toml"
    scene.write_text(
        'mesh = { shape = "creature", params = { cell = 0.2 } }\nsubspace = { weights = 3, clusters = 4 }\n'
        "muscles = { count = 0 }\ntime = { step = 0.01, steps = 4 }\n"
        "gravity = { acceleration = [0.0, -9.8, 0.0] }\nground = { offset = 0.0 }\n"
    )
    assert main(["run", str(scene), "--out", str(tmp_path / "run"), "-q"]) == 0
    panels = []

    def saved(fig, *args, **kwargs):  # what each panel holds: its lines' labels and heights
        panels.extend({line.get_label(): line.get_ydata()[0] for line in ax.get_lines()} for ax in fig.axes)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", saved)
    run = plot.read_run(tmp_path / "run")
    np.testing.assert_allclose(run["amplitudes"][0], [0.0, 0.01, 0.02, 0.03, 0.04], rtol=1e-15)
    assert run["amplitudes"][1].shape == run["amplitudes"][2].shape == (5, 0)
    plot.plot_com(run, tmp_path / "com.png")
    assert [("ground" in lines) for lines in panels] == [False, True, False]
    assert panels[1]["ground"] == run["summary"]["ground"]["height"]


def test_a_disk_full_while_rendering_is_named_and_leaves_no_part_of_the_file(run_copy, capsys, monkeypatch):
    # a full disk said "error: [Errno 28] No space left on device" (exit 2, "bad input") without the file
    def fills_up(self, image):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(plot._GifStream, "append_data", fills_up)
    before = sorted(os.listdir(run_copy))
    assert main(["render", str(run_copy), "--backend", "matplotlib", "--max-frames", "2", "-q"]) == 5
    err = capsys.readouterr().err
    said = f"could not write {run_copy / 'animation.gif'}: No space left on device"
    assert err == f"skfem-modal render: outputs failed: {said}\n"
    made = set(os.listdir(run_copy)) - set(before)
    assert made and all(name.endswith(".png") for name in made)  # the stills drawn before, whole
    assert "animation.gif" not in made  # no part of the animation, no hidden temporary file


@pytest.mark.parametrize("picture", ["plot", "still"])
def test_a_disk_full_while_drawing_a_picture_leaves_none_of_it(run_copy, capsys, monkeypatch, picture):
    """An audit: a plot or still cut short by a full disk was left truncated, and the message named no file."""
    import matplotlib.figure
    from PIL import Image

    def half_then_full(self, path, *args, **kwargs):
        with open(path, "wb") as f:
            f.write(b"\x89PNG half")
        raise OSError(28, "No space left on device")

    if picture == "plot":
        monkeypatch.setattr(matplotlib.figure.Figure, "savefig", half_then_full)
    else:
        monkeypatch.setattr(Image.Image, "save", half_then_full)
    before = sorted(os.listdir(run_copy))
    assert main(["render", str(run_copy), "--backend", "matplotlib", "--max-frames", "2", "-q"]) == 5
    err = capsys.readouterr().err
    assert err.startswith(f"skfem-modal render: outputs failed: could not write {run_copy}{os.sep}")
    named = err.split("could not write ")[1].split(": No space left on device")[0]
    assert named.endswith(".png") and not os.path.exists(named)
    made = sorted(set(os.listdir(run_copy)) - set(before))
    assert all(not name.startswith(".") for name in made)  # no hidden temporary file left
    for name in made:  # what was drawn before the disk filled is whole
        assert Image.open(run_copy / name).size[0] > 0


def test_a_run_folder_that_refuses_pictures_is_named_before_any_frame_is_read(run_copy, capsys, monkeypatch):
    """An audit: render read every frame of a run in a read-only folder, then failed at its first picture."""
    import tempfile

    read = []
    monkeypatch.setattr(plot, "_read_frame", lambda *args: read.append(args))

    def refused(*args, dir=None, **kwargs):
        raise PermissionError(30, "Read-only file system")

    monkeypatch.setattr(tempfile, "mkdtemp", refused)
    assert main(["render", str(run_copy), "--backend", "matplotlib", "-q"]) == 2
    err = capsys.readouterr().err
    assert err == (
        f"skfem-modal render: error: the run folder {str(run_copy)!r} cannot be written: {str(run_copy)!r} refuses "
        "a new folder (Read-only file system); copy the run to a folder that can be written and render it there\n"
    )
    assert read == []
