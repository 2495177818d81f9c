"""Pictures of runs: one camera and colour range for a whole run, the ground a floor for any up axis."""

import json
import shutil

import meshio
import numpy as np
import pytest
from ci import unavailable

from skfem_modal.camera import Camera, deformation, frame_windows, grid_spacing, up_vector
from skfem_modal.cli import main

pytest.importorskip("matplotlib", reason="matplotlib is in the plot extra")
from PIL import Image  # noqa: E402  (pillow comes with matplotlib)

VIRIDIS_0 = np.array([68, 1, 84])  # the colour of zero deformation


def test_up_follows_the_ground_then_gravity():
    def summary(dim, ground=None, gravity=None):
        return {"mesh": {"dim": dim}, "scene": {"ground": ground, "gravity": gravity and {"acceleration": gravity}}}

    np.testing.assert_array_equal(up_vector(summary(3, ground={"up": 1})), [0, 1, 0])
    np.testing.assert_array_equal(up_vector(summary(3, gravity=[0.0, -9.8, 0.0])), [0, 1, 0])
    np.testing.assert_array_equal(up_vector(summary(2, gravity=[0.0, 9.8])), [0, -1])  # y-down image outlines
    np.testing.assert_array_equal(up_vector(summary(3)), [0, 0, 1])
    # both: the ground's up axis, not gravity's (an incline: gravity tilted 30 degrees off -y)
    np.testing.assert_array_equal(up_vector(summary(2, ground={"up": 1}, gravity=[4.9, -8.49])), [0, 1])
    np.testing.assert_array_equal(up_vector(summary(3, ground={"up": 2}, gravity=[0.0, -9.8, 0.0])), [0, 0, 1])
    # an incline whose ground.up gravity chose (null in the scene): the axis the run recorded, not gravity's
    # own tilted direction, which drew the floor tilted and the body 1.1 of its sizes below it
    incline = summary(2, ground={"up": None}, gravity=[-5.0, -8.43])
    np.testing.assert_array_equal(up_vector(incline), [0, 1])  # an older run: gravity's largest component
    np.testing.assert_array_equal(up_vector({**incline, "settings": {"up": 1}}), [0, 1])
    np.testing.assert_array_equal(
        up_vector({**summary(3, ground={}, gravity=[-9.0, 0.5, -2.0]), "settings": {"up": 0}}), [1, 0, 0]
    )


@pytest.mark.parametrize("up", [[0, 0, 1], [0, 1, 0], [1, 0, 0]])
def test_3d_camera_keeps_up_up_and_looks_down(up):
    cam = Camera.looking_at(np.array(up, float), 3)
    basis = np.stack([cam.right, cam.screen_up, cam.towards])
    np.testing.assert_allclose(basis @ basis.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(basis) == pytest.approx(1.0)
    assert cam.right @ up == pytest.approx(0.0, abs=1e-12)  # the floor's horizon is level
    assert cam.screen_up @ up == pytest.approx(np.cos(np.radians(20.0)))  # up is drawn upwards
    assert cam.towards @ up == pytest.approx(np.sin(np.radians(20.0)))  # seen from above


def test_deformation_leaves_out_rigid_motion():
    rng = np.random.default_rng(3)
    rest = rng.random((30, 3))
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.linalg.det(q))
    assert deformation(rest, rest @ q.T + [5.0, -2.0, 1.0]).max() < 1e-12
    # a uniform stretch by 1.5 about the centre: every vertex is 0.5 of its distance from it off
    centre = rest.mean(axis=0)
    np.testing.assert_allclose(
        deformation(rest, centre + 1.5 * (rest - centre)), 0.5 * np.linalg.norm(rest - centre, axis=1), rtol=1e-12
    )


def test_windows_stand_still_for_small_motion_and_follow_long_crawls():
    body = np.array([[0.0, 0.0], [2.0, 1.0]])
    wiggle = np.array([body + [0.05 * np.sin(k), 0.0] for k in range(20)])
    centres, half = frame_windows(wiggle, 16 / 9, follow_vertically=False)
    assert np.ptp(centres, axis=0).max() == 0.0 and half > 0.5
    crawl = np.array([body + [-0.4 * k, 0.0] for k in range(40)])  # 16 body lengths to the left
    centres, half = frame_windows(crawl, 16 / 9, follow_vertically=False)
    width = half * 16 / 9
    assert half < 1.5  # the same scale as a body that does not travel
    assert np.all(np.diff(centres[:, 0]) <= 0) and np.ptp(centres[:, 1]) == 0.0
    # the body is inside every frame's window, with room to spare
    assert np.all(crawl[:, 0, 0] > centres[:, 0] - width) and np.all(crawl[:, 1, 0] < centres[:, 0] + width)
    assert grid_spacing(2.0) == 0.5 and grid_spacing(300.0) == 100.0


@pytest.fixture(scope="module")
def creature_runs(tmp_path_factory):
    """A z-up creature run, and the same run turned so y is up (every frame and the scene)."""
    base = tmp_path_factory.mktemp("pictures")
    scene = base / "creature.toml"
    scene.write_text(
        "[mesh]\nshape = 'creature'\nparams = { cell = 0.2 }\n[muscles]\ncount = 2\n"
        "[muscles.gait]\namplitude = [0.05, 0.05]\nperiod = [1.0, 0.7]\n[time]\nstep = 0.01\nsteps = 20\n"
        "[gravity]\nacceleration = [0.0, 0.0, -9.8]\n[ground]\noffset = 0.0\n[output]\nevery = 10\n"
    )
    z_up = base / "z_up"
    assert main(["run", str(scene), "--out", str(z_up), "-q"]) == 0
    y_up = base / "y_up"
    shutil.copytree(z_up, y_up)
    turn = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # z to y, y to -z
    for path in (y_up / "frames").iterdir():
        frame = meshio.read(path)
        frame.points = frame.points @ turn.T
        frame.point_data["displacement"] = frame.point_data["displacement"] @ turn.T
        meshio.write(path, frame)
    summary = json.loads((y_up / "summary.json").read_text())
    summary["scene"]["ground"]["up"] = summary["settings"]["up"] = 1
    summary["scene"]["gravity"]["acceleration"] = [0.0, -9.8, 0.0]
    (y_up / "summary.json").write_text(json.dumps(summary))
    return z_up, y_up


def frames_of(run_dir):
    gif = Image.open(run_dir / "animation.gif")
    frames = []
    for k in range(gif.n_frames):
        gif.seek(k)
        frames.append(np.asarray(gif.convert("RGB")).astype(int))
    return frames


def body_box(image):
    """Pixel rows and columns of the body: pixels far from every grey (floor, lines, shadow, white)."""
    top = 60  # below the time
    rows, cols = np.nonzero(np.ptp(image[top:, : int(0.86 * image.shape[1])], axis=2) > 12)
    return top + rows.min(), top + rows.max(), cols.min(), cols.max()


@pytest.mark.parametrize("backend", ["matplotlib", "pyvista"])
def test_y_up_and_z_up_scenes_are_drawn_alike(creature_runs, backend):
    if backend == "pyvista":
        from skfem_modal.plot import gl_available

        if not gl_available():
            unavailable("no off-screen OpenGL here: pyvista cannot render")
    images = []
    for run in creature_runs:
        assert main(["render", str(run), "--backend", backend, "-q"]) == 0
        images.append(np.asarray(Image.open(run / "last_frame.png")).astype(int))
    z_up, y_up = images
    assert z_up.shape == (720, 1280, 3)  # the default size
    assert np.abs(z_up - y_up).mean() < 0.5
    # the floor (light grey) fills the bottom of the picture: the ground is under the body, not a wall
    bottom = z_up[-40:, :900]
    assert np.all(np.ptp(bottom, axis=2) < 8) and 200 < bottom.mean() < 250


@pytest.mark.parametrize("backend", ["matplotlib", "pyvista"])
def test_every_frame_has_the_same_scale_and_colours(creature_runs, backend):
    if backend == "pyvista":
        from skfem_modal.plot import gl_available

        if not gl_available():
            unavailable("no off-screen OpenGL here: pyvista cannot render")
    run = creature_runs[0]
    assert main(["render", str(run), "--backend", backend, "-q"]) == 0
    frames = frames_of(run)
    assert len(frames) == 3
    boxes = np.array([body_box(f) for f in frames])
    widths = boxes[:, 3] - boxes[:, 2]
    # the body barely moves in 0.2 s: frame 0 is framed like the others (not zoomed out)
    assert np.ptp(widths) < 0.1 * widths.max()
    # frame 0 is at rest: every body pixel has the colour of zero deformation, no round-off noise
    r0, r1, c0, c1 = boxes[0]
    body = frames[0][r0 : r1 + 1, c0 : c1 + 1].reshape(-1, 3)
    body = body[np.ptp(body, axis=1) > 12]
    hue = body / np.maximum(body.max(axis=1, keepdims=True), 1)  # shading darkens, the hue stays
    close = np.linalg.norm(hue - VIRIDIS_0 / VIRIDIS_0.max(), axis=1) < 0.15
    assert close.mean() > 0.97
    # the last frame is deformed: colours along the bar
    last = frames[-1][boxes[-1, 0] : boxes[-1, 1] + 1, boxes[-1, 2] : boxes[-1, 3] + 1].reshape(-1, 3)
    last = last[np.ptp(last, axis=1) > 12]
    assert (np.linalg.norm(last / last.max(axis=1, keepdims=True) - VIRIDIS_0 / 84, axis=1) > 0.3).mean() > 0.2


@pytest.mark.parametrize("m, apart", [(4, 0.1), (12, 0.1), (30, 0.05)])
def test_amplitudes_tell_many_muscles_apart_and_keep_the_legend_off_the_curves(m, apart):
    pytest.importorskip("matplotlib")
    from skfem_modal.plot import amplitudes_figure

    t = np.linspace(0.0, 4.0, 200)
    commanded = np.array([0.3 * np.sin(2 * np.pi * t / (0.5 + 0.1 * k)) for k in range(m)]).T
    fig = amplitudes_figure({"amplitudes": (t, commanded, 0.8 * commanded)})
    (ax,) = fig.axes
    lines = ax.get_lines()
    assert len(lines) == 2 * m
    realised, dashed = lines[0::2], lines[1::2]
    colours = np.array([line.get_color()[:3] for line in realised])
    # every muscle its own colour: no two closer than a tenth of the RGB cube's side (a twentieth for 30)
    distances = np.linalg.norm(colours[:, None] - colours[None], axis=2) + np.eye(m)
    assert distances.min() > apart
    # commanded and realised told apart by line style, in the muscle's colour
    assert all(
        a.get_color() is b.get_color() or np.allclose(a.get_color(), b.get_color()) for a, b in zip(realised, dashed)
    )
    assert {line.get_linestyle() for line in realised} == {"-"} and {line.get_linestyle() for line in dashed} == {"--"}
    # one legend entry per muscle and one per line style, beside the axes, inside the picture
    (legend,) = fig.legends
    assert [text.get_text() for text in legend.get_texts()] == [f"muscle {k}" for k in range(m)] + [
        "realised",
        "commanded",
    ]
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    box, axes_box, figure_box = legend.get_window_extent(renderer), ax.get_window_extent(renderer), fig.bbox
    assert not box.overlaps(axes_box)
    assert box.x0 >= figure_box.x0 and box.x1 <= figure_box.x1 and box.y0 >= figure_box.y0 and box.y1 <= figure_box.y1
    import matplotlib.pyplot as plt

    plt.close(fig)
