"""Pictures of a finished run: centre of mass, modal amplitudes, frames, an animation.

An optional extra (``pip install skfem_modal[plot]``): matplotlib always, and
pyvista for nicer frames where an OpenGL backend works. Whether it works is
probed in a subprocess, because a missing GL can crash the process that tries;
without it everything is drawn with matplotlib.
"""

from __future__ import annotations

import contextlib
import csv
import functools
import io
import itertools
import json
import os
import re
import subprocess
import sys
from dataclasses import dataclass

import numpy as np

from .camera import ELEVATION, Camera, deformation, frame_windows, grid_spacing, up_vector
from .export import pad3, written_whole
from .outputs import check_writable

__all__ = [
    "read_run",
    "gl_available",
    "render_problems",
    "picture_size_problem",
    "plot_com",
    "plot_amplitudes",
    "render_run",
]

#: Smallest and largest side of a picture in pixels. Measured (2026-11-23,
#: Mesa llvmpipe): pyvista renders blank pictures beyond 16384 pixels a
#: side (OpenGL's largest off-screen buffer here; 8192 on some GPUs),
#: matplotlib's Agg refuses 65536, and one 8192 x 8192 frame is 200 MB of
#: RGB already; 8192 covers 8K video (7680 x 4320).
MIN_PICTURE_SIDE, MAX_PICTURE_SIDE = 16, 8192


def picture_size_problem(size, fmt: str = "gif") -> str | None:
    """What is wrong with a picture size for :func:`render_run`, or None.

    Parameters
    ----------
    size : (int, int)
        Width and height in pixels.
    fmt : {"gif", "mp4"}
        An mp4 (H.264 in yuv420p, what players read) needs an even width and height.

    Returns
    -------
    problem : str or None
        The size (``WxH``) and what was expected.

    Examples
    --------
    >>> picture_size_problem((1280, 720)) is None
    True
    >>> picture_size_problem((20000, 200))
    '20000x200: each side must be 16 to 8192 pixels'
    >>> picture_size_problem((333, 333), "mp4")
    '333x333: an mp4 needs an even width and height (H.264 in yuv420p): try 334x334, or the gif format'
    """
    width, height = (int(v) for v in size)
    if not (MIN_PICTURE_SIDE <= min(width, height) and max(width, height) <= MAX_PICTURE_SIDE):
        return f"{width}x{height}: each side must be {MIN_PICTURE_SIDE} to {MAX_PICTURE_SIDE} pixels"
    if fmt == "mp4" and (width % 2 or height % 2):
        even = f"{width + width % 2}x{height + height % 2}"
        why = "an mp4 needs an even width and height (H.264 in yuv420p)"
        return f"{width}x{height}: {why}: try {even}, or the gif format"
    return None


def read_run(run_dir) -> dict:
    """Read what a run wrote.

    Parameters
    ----------
    run_dir : str or path-like
        A run's output folder (``skfem-modal run``, :func:`~skfem_modal.run.run_scene`): its
        ``summary.json``, ``com.csv``, ``amplitudes.csv`` and ``frames.pvd``.

    Returns
    -------
    run : dict
        ``summary`` (dict), ``com`` (times (k,), values (k, dim)),
        ``amplitudes`` (times, commanded (k, m), realised (k, m)),
        ``frames`` (list of (time, path)); ``k`` is the steps plus one (the rest state).

    Raises
    ------
    FileNotFoundError
        One of those files is missing.
    ValueError
        A file that is not what a run writes: ``summary.json`` not JSON, a table cut in a row or holding
        something other than numbers, or a table or ``frames.pvd`` whose length disagrees with the summary's
        steps or frames (the message names the file).
    """
    run_dir = os.fspath(run_dir)
    path = os.path.join(run_dir, "summary.json")
    try:
        with open(path, encoding="utf-8") as f:
            summary = json.load(f)
    except (json.JSONDecodeError, UnicodeDecodeError) as err:  # (the latter named no file)
        raise ValueError(f"cannot read {path}: {err} (not the JSON a run writes: cut or edited?)") from None
    if not isinstance(summary, dict):  # (a JSON list was taken)
        raise ValueError(f"cannot read {path}: not the JSON a run writes (an object of its keys), got {summary!r:.60}")
    # a row a step (and the rest state): a file cut short says fewer
    expected = summary.get("steps_completed", summary.get("steps")) if isinstance(summary, dict) else None

    def table(name):
        where = os.path.join(run_dir, name)
        with open(where, newline="") as f:
            text = f.read()
        if not text.endswith("\n"):  # a run ends every row: the last one was cut (its number too, maybe)
            raise ValueError(f"{where} ends in the middle of a row: cut or edited? (run it again)")
        rows = list(csv.reader(io.StringIO(text)))
        try:
            data = np.array([[float(v) for v in row] for row in rows[1:]]).reshape(-1, len(rows[0]))
        except ValueError:
            raise ValueError(f"{where} holds rows that are not {len(rows[0])} numbers: cut or edited?") from None
        if isinstance(expected, int) and data.shape[0] != expected + 1:
            raise ValueError(
                f"{where} holds {data.shape[0]} rows, where summary.json's {expected} steps make {expected + 1}: "
                "the run's files are cut or from another run (run it again)"
            )
        return rows[0], data

    _, com = table("com.csv")
    header, amp = table("amplitudes.csv")
    m = (len(header) - 1) // 2
    with open(os.path.join(run_dir, "frames.pvd")) as f:
        pvd = f.read()
    frames = [
        (float(t), os.path.join(run_dir, f)) for t, f in re.findall(r'timestep="([^"]+)"[^>]*file="([^"]+)"', pvd)
    ]
    written = (summary.get("frames") or {}).get("count") if isinstance(summary, dict) else None
    if isinstance(written, int) and len(frames) != written:
        raise ValueError(
            f"{os.path.join(run_dir, 'frames.pvd')} lists {len(frames)} frames, where summary.json says the run "
            f"wrote {written}: the run's files are cut or from another run (run it again)"
        )
    return {
        "summary": summary,
        "com": (com[:, 0], com[:, 1:]),
        "amplitudes": (amp[:, 0], amp[:, 1 : 1 + m], amp[:, 1 + m :]),
        "frames": frames,
    }


def _headless_vtk() -> None:
    # Without an X display VTK first tries X, warns "bad X server connection"
    # and only then falls back to EGL: ask for EGL straight away (a choice the
    # user made in the environment wins)
    if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")


@functools.lru_cache(maxsize=1)
def gl_available() -> bool:
    """Whether pyvista can render off-screen here (probed in a subprocess)."""
    _headless_vtk()
    probe = (
        "import pyvista as pv\n"
        "p = pv.Plotter(off_screen=True, window_size=(64, 64))\n"
        "p.add_mesh(pv.Sphere())\n"
        "img = p.screenshot(return_img=True)\n"
        "assert img.std() > 0\n"
    )
    try:
        result = subprocess.run([sys.executable, "-c", probe], capture_output=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired):
        return False
    return result.returncode == 0


def render_problems(backend: str = "auto", fmt: str = "gif") -> list[str]:
    """What stops :func:`render_run` here, checked before any drawing.

    Parameters
    ----------
    backend : {"auto", "pyvista", "matplotlib"}
    fmt : {"gif", "mp4"}

    Returns
    -------
    problems : list of str
        Each names what is missing and how to get it; empty when rendering can go ahead.
    """
    problems = []
    missing = []
    for module, package in (("matplotlib", "matplotlib"), ("PIL", "pillow")):
        try:
            __import__(module)
        except ImportError:
            missing.append(package)
    if missing:
        problems.append(f"{' and '.join(missing)} not installed: pip install 'skfem_modal[plot]'")
    if backend == "pyvista":
        try:
            import pyvista  # noqa: F401
        except ImportError:
            problems.append("pyvista is not installed: pip install 'skfem_modal[plot]', or use --backend matplotlib")
        else:
            if not gl_available():
                problems.append(
                    "pyvista cannot render off-screen here (no working OpenGL): use --backend matplotlib, or "
                    "install Mesa's EGL (Debian: apt-get install libegl1 libgl1-mesa-dri)"
                )
    if fmt == "mp4":
        problem = _mp4_problem()
        if problem:
            problems.append(problem)
    return problems


def _mp4_problem() -> str | None:
    """Why an mp4 cannot be written here (a two-frame trial in a scratch folder), or None."""
    import tempfile

    try:
        import imageio.v2 as imageio
    except ImportError:
        return "writing mp4 needs imageio with ffmpeg: pip install 'imageio[ffmpeg]', or use --format gif"
    with tempfile.TemporaryDirectory() as scratch:
        try:
            imageio.mimwrite(os.path.join(scratch, "trial.mp4"), [np.zeros((16, 16, 3), np.uint8)] * 2, fps=10)
        except Exception:  # imageio names no single error for a missing plugin
            return "writing mp4 needs an ffmpeg plugin for imageio: pip install 'imageio[ffmpeg]', or use --format gif"
    return None


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_com(run, path) -> str:
    """Centre of mass over time (each axis), with the ground height.

    Parameters
    ----------
    run : dict
        A run, as :func:`read_run` reads it.
    path : str or path-like
        The picture to write (e.g. ``com.png``; matplotlib picks the format from the suffix).

    Returns
    -------
    path : str
    """
    plt = _pyplot()
    t, com = run["com"]
    dim = com.shape[1]
    summary = run["summary"]
    # the axis the ground's height is along, as the run had it (a scene's ground.up is null when gravity says it)
    up = (summary.get("settings") or {}).get("up")
    fig, axes = plt.subplots(dim, 1, figsize=(7, 1.8 * dim + 0.6), sharex=True)
    for k, ax in enumerate(np.atleast_1d(axes)):
        ax.plot(t, com[:, k], color=f"C{k}")
        ax.set_ylabel(f"COM {'xyz'[k]}")
        ax.grid(alpha=0.3)
        if summary.get("ground") and k == up:
            ax.axhline(summary["ground"]["height"], color="0.5", ls="--", lw=1, label="ground")
            ax.legend(fontsize=8)
    np.atleast_1d(axes)[-1].set_xlabel("time")
    fig.suptitle(f"centre of mass: {summary['scene'].get('name', '')}", fontsize=10)
    fig.tight_layout()
    _save_figure(plt, fig, path)
    return os.fspath(path)


def plot_amplitudes(run, path) -> str:
    """Commanded (dashed) and realised (solid) modal amplitudes per muscle.

    One colour per muscle, all distinct however many there are
    (:func:`muscle_colours`); the legend, one entry per muscle and one per
    line style, sits outside the axes, beside the curves rather than on them.

    Parameters
    ----------
    run : dict
        A run, as :func:`read_run` reads it.
    path : str or path-like
        The picture to write (e.g. ``amplitudes.png``; matplotlib picks the format from the suffix).

    Returns
    -------
    path : str
    """
    plt = _pyplot()
    _save_figure(plt, amplitudes_figure(run), path)
    return os.fspath(path)


def _save_figure(plt, fig, path) -> None:
    """Save a matplotlib figure whole or not at all (a full disk left a picture cut short), and close it."""
    try:
        with written_whole(path) as partial:
            fig.savefig(partial, dpi=110)
    finally:
        plt.close(fig)


def amplitudes_figure(run):
    """The figure of :func:`plot_amplitudes` (a matplotlib Figure, not yet saved) of a ``run`` (:func:`read_run`)."""
    plt = _pyplot()
    from matplotlib.lines import Line2D

    t, commanded, realised = run["amplitudes"]
    m = commanded.shape[1]
    rows = 16  # legend entries per column
    columns = max(1, -(-(m + 2) // rows))
    fig, ax = plt.subplots(
        figsize=(7 + 1.3 * columns, 3.2 + 0.12 * max(0, min(m + 2, rows) - 10)), layout="constrained"
    )
    colours = muscle_colours(m)
    for k in range(m):
        ax.plot(t, realised[:, k], color=colours[k], lw=1.6)
        ax.plot(t, commanded[:, k], color=colours[k], lw=1.0, ls="--", alpha=0.8)
    ax.set_xlabel("time")
    ax.set_ylabel("modal amplitude")
    ax.grid(alpha=0.3)
    if m:
        handles = [Line2D([], [], color=colours[k], lw=3) for k in range(m)]
        handles += [Line2D([], [], color="0.3", lw=1.6), Line2D([], [], color="0.3", lw=1.0, ls="--")]
        labels = [f"muscle {k}" for k in range(m)] + ["realised", "commanded"]
        fig.legend(handles, labels, loc="outside right upper", fontsize=7, ncols=columns)
    return fig


def muscle_colours(m: int) -> np.ndarray:
    """One colour per muscle, all distinct: matplotlib's ten for up to ten, else evenly along turbo.

    ``m``: the number of muscles (0 or more).

    Returns
    -------
    colours : ndarray, shape (m, 4)
        RGBA.
    """
    plt = _pyplot()
    if m <= 10:
        return plt.get_cmap("tab10")(np.arange(m))
    return plt.get_cmap("turbo")(np.linspace(0.05, 0.95, m))


@dataclass
class _Frame:
    time: float
    points: np.ndarray  # (n, dim)
    rest: np.ndarray  # (n, dim)
    cells: np.ndarray  # (nT, dim + 1)
    deformation: np.ndarray  # (n,) distance from the best rigid motion of the rest shape (of its body's)
    parts: np.ndarray | None = None  # (n,) each vertex's body


def _read_frame(time: float, path: str, first: _Frame | None = None) -> _Frame:
    """One written frame; any file that is missing, unreadable or not a frame of this run is a ValueError naming it.

    Frames after ``first`` must have its cells and rest shape, and share its arrays (read once, held once).
    """
    from .mesh import _parts, _read_meshio

    if not os.path.isfile(path):
        raise FileNotFoundError(f"frame file {path!r} (listed in frames.pvd) is missing")
    m = _read_meshio(path, "frame file")
    kind = next((k for k in ("triangle", "tetra") if k in m.cells_dict), None)
    displacement = m.point_data.get("displacement")
    if kind is None or displacement is None or displacement.shape != m.points.shape:
        raise ValueError(
            f"frame file {path!r} is not a frame of a run: it needs triangle or tetrahedron cells "
            "and a 'displacement' for every point"
        )
    own_time = np.ravel(m.field_data.get("time", [time]))
    if own_time.size != 1 or not abs(float(own_time[0]) - time) <= 1e-9 * max(1.0, abs(time)):
        # (a frame of another run of the same mesh has its cells and rest shape)
        raise ValueError(
            f"frame file {path!r} is at time {own_time.tolist()}, frames.pvd lists it at {time:g}: "
            "not a frame of this run"
        )
    cells, dim = m.cells_dict[kind], 2 if kind == "triangle" else 3
    points = m.points[:, :dim]
    rest = points - displacement[:, :dim]
    if first is not None:
        if cells.shape != first.cells.shape or not np.array_equal(cells, first.cells):
            raise ValueError(f"frame file {path!r} has other cells than the run's first frame")
        if not np.allclose(rest, first.rest, rtol=0.0, atol=1e-9 * max(np.ptp(first.rest), 1.0)):
            raise ValueError(f"frame file {path!r} has another rest shape than the run's first frame")
        cells, rest = first.cells, first.rest
    parts = first.parts if first is not None else _parts(cells.T, points.shape[0])
    return _Frame(time, points, rest, cells, deformation(rest, points, parts), parts)


def _surface(tets):
    faces = np.sort(np.vstack([tets[:, [0, 1, 2]], tets[:, [0, 1, 3]], tets[:, [0, 2, 3]], tets[:, [1, 2, 3]]]), axis=1)
    uniq, counts = np.unique(faces, axis=0, return_counts=True)
    return uniq[counts == 1]


#: Colour map, colour bar title and label of the deformation colour.
CMAP = "viridis"
COLOUR_TITLE = "deformation"
COLOUR_LABEL = "deformation (distance from rigid motion)"
#: Share of the picture's width the drawing takes (the colour bar has the rest).
_DRAWING_WIDTH = 0.86
#: Font size of the colour bar's labels (pyvista), at the default size.
_BAR_LABEL_SIZE = 12
#: The default picture size, the one text and line sizes are chosen for.
DEFAULT_SIZE = (1280, 720)


#: matplotlib's smallest dpi: its smallest text (10 points) is then 1.4 pixels high
_MIN_DPI = 10.0


def _text_scale(size) -> float:
    """How much larger than at :data:`DEFAULT_SIZE` text and lines are drawn: a picture looks the same at any size."""
    return min(size[0] / DEFAULT_SIZE[0], size[1] / DEFAULT_SIZE[1])


def _points(value: float, scale: float) -> int:
    """A font size (pyvista takes whole points) scaled, at least 1."""
    return max(1, round(value * scale))


@dataclass
class _View:
    """Everything fixed for a whole animation: camera, windows, colour range, floor."""

    camera: Camera
    centres: np.ndarray  # (k, 2) screen centre of each frame's window
    half_height: float
    aspect: float
    vmax: float
    ground: float | None
    up: np.ndarray  # (dim,)
    dim: int
    spacing: float  # floor lines
    floor_lo: np.ndarray  # (dim,) the floor covers this box (ground height along up)
    floor_hi: np.ndarray

    def limits(self, k: int):
        """Screen box (lower left, upper right) of frame ``k``'s drawing window."""
        half = np.array([self.half_height * self.aspect, self.half_height])
        return self.centres[k] - half, self.centres[k] + half

    def picture_limits(self, k: int):
        """Screen box of frame ``k``'s whole picture: its window, continued right behind the colour bar."""
        lo, hi = self.limits(k)
        return lo, hi + [(hi[0] - lo[0]) * (1.0 / _DRAWING_WIDTH - 1.0), 0.0]


def _plan(frames, summary: dict, size, drawn) -> _View:
    """One camera, scale and colour range for every frame of a run (``frames``: an iterable of all of them),
    with the windows of those ``drawn`` (indices into them)."""
    frames = iter(frames)
    first = next(frames)
    dim = first.points.shape[1]
    up = up_vector(summary)
    camera = Camera.looking_at(up, dim)
    ground = summary["ground"]["height"] if summary.get("ground") else None
    boxes, deform, lows, highs = [], [], [], []
    for f in itertools.chain([first], frames):
        seen = f.points
        if ground is not None:  # the floor under the body is seen too
            seen = np.vstack([seen, _on_floor(f.points, up, ground)])
        screen = camera.screen(seen)
        boxes.append([screen.min(axis=0), screen.max(axis=0)])
        deform.append(f.deformation.max())
        lows.append(f.points.min(axis=0))
        highs.append(f.points.max(axis=0))
    aspect = _DRAWING_WIDTH * size[0] / size[1]
    centres, half_height = frame_windows(np.array(boxes), aspect, follow_vertically=dim == 3)
    body = float(np.ptp(first.rest, axis=0).max())
    lo, hi = np.min(lows, axis=0), np.max(highs, axis=0)
    # the floor fills every view: in 3D the far floor rises up the screen slowly, as sin(elevation)
    reach = 2.0 * half_height * max(aspect, 1.0 / np.sin(np.radians(ELEVATION)) if dim == 3 else 0.0)
    return _View(
        camera=camera,
        centres=centres[list(drawn)],
        half_height=half_height,
        aspect=aspect,
        # round-off of a body at rest never shows as colour
        vmax=max(float(np.max(deform)), 1e-3 * body),
        ground=ground,
        up=up,
        dim=dim,
        spacing=grid_spacing(body),
        floor_lo=lo - reach,
        floor_hi=hi + reach,
    )


def _floor_lines(view: _View) -> np.ndarray:
    """Floor grid lines (3D) or ticks along the ground (2D), world coordinates, shape (lines, 2, dim)."""
    up, g, s = view.up, view.ground, view.spacing
    if view.dim == 2:
        right = view.camera.right[:2]
        ticks = np.arange(np.floor(view.floor_lo @ np.abs(right) / s), np.ceil(view.floor_hi @ np.abs(right) / s) + 1)
        feet = np.outer(ticks * s, right) + g * up
        return np.stack([feet, feet - 0.25 * s * up], axis=1)
    axes = [a for a in np.eye(3) if abs(a @ up) < 0.5]
    lines = []
    for a, b in (axes, axes[::-1]):
        for k in np.arange(np.floor(view.floor_lo @ a / s), np.ceil(view.floor_hi @ a / s) + 1):
            start = k * s * a + (view.floor_lo @ b) * b
            end = k * s * a + (view.floor_hi @ b) * b
            lines.append([start - (start @ up - g) * up, end - (end @ up - g) * up])
    return np.array(lines)


def _on_floor(points, up, ground: float) -> np.ndarray:
    """Points (n, dim) moved straight down (along ``up``) onto the floor at height ``ground``."""
    return points - np.outer(points @ up - ground, up)


def _floor_corners(view: _View) -> np.ndarray:
    """The floor rectangle (3D), world coordinates, shape (4, 3)."""
    a, b = [x for x in np.eye(3) if abs(x @ view.up) < 0.5]
    lo, hi = view.floor_lo, view.floor_hi
    corners = np.array([(lo @ a) * a + (lo @ b) * b, (hi @ a) * a + (lo @ b) * b, (hi @ a) * a + (hi @ b) * b])
    corners = np.vstack([corners, (lo @ a) * a + (hi @ b) * b])
    return _on_floor(corners, view.up, view.ground)


def _time_labels(frames: list[_Frame]) -> list[str]:
    """``t = ...`` of each frame, with the fewest decimals (3 at least) that tell their times apart.

    >>> [label.split()[-1] for label in _time_labels([_Frame(t, *[None] * 4) for t in (0.0, 0.0002, 0.0004)])]
    ['0.0000', '0.0002', '0.0004']
    """
    times = [f.time for f in frames]
    for decimals in range(3, 10):
        labels = [f"t = {t:.{decimals}f}" for t in times]
        if len(set(labels)) == len(labels):
            return labels
    return [f"t = {t!r}" for t in times]


def _matplotlib_frames(frames: list[_Frame], view: _View, size):
    """RGB images of the frames, drawn with matplotlib through the view's camera.

    Yields
    ------
    image : ndarray of uint8, shape (height, width, 3)
        One frame at a time: only the one being drawn is held.
    """
    plt = _pyplot()
    from matplotlib.collections import LineCollection, PolyCollection
    from matplotlib.colors import Normalize
    from matplotlib.tri import Triangulation

    cmap = plt.get_cmap(CMAP)
    norm = Normalize(0.0, view.vmax)
    camera = view.camera
    faces = _surface(frames[0].cells) if view.dim == 3 else None
    light = camera.towards + 0.6 * camera.screen_up + 0.3 * camera.right
    light /= np.linalg.norm(light)
    # text and lines are in points: a dpi in proportion to the size keeps them in proportion too, but
    # not below what draws the smallest text a pixel high (FreeType refuses less: a 48 x 48 picture crashed)
    dpi = max(100.0 * _text_scale(size), _MIN_DPI)
    # matplotlib truncates inches * dpi to whole pixels: a hundredth of a pixel over keeps the size given
    inches = [pixels / dpi if int(pixels / dpi * dpi) == pixels else (pixels + 0.01) / dpi for pixels in size]
    fig = plt.figure(figsize=inches, dpi=dpi)
    try:
        labels = _time_labels(frames)
        for k, f in enumerate(frames):
            fig.clear()
            # the axes fill the picture, so the floor goes on behind the colour bar (as pyvista's does)
            ax = fig.add_axes([0.0, 0.0, 1.0, 1.0])
            lo, hi = view.picture_limits(k)
            if view.ground is not None:
                floor = camera.screen(_floor_lines(view).reshape(-1, view.dim)).reshape(-1, 2, 2)
                if view.dim == 2:
                    ax.axhspan(lo[1] - 1e9, view.ground, color="0.9", zorder=0)
                    ax.axhline(view.ground, color="0.45", lw=1.2, zorder=1)
                else:
                    ax.add_patch(plt.Polygon(camera.screen(_floor_corners(view)), color="0.92", zorder=0))
                ax.add_collection(LineCollection(floor, colors="0.6", linewidths=0.8, zorder=1))
            screen = camera.screen(f.points)
            values = f.deformation
            if view.dim == 3 and view.ground is not None:  # the body's shadow straight below: how high it is
                below = _on_floor(f.points, view.up, view.ground)[faces]
                shadow = camera.screen(below.reshape(-1, 3)).reshape(-1, 3, 2)
                ax.add_collection(PolyCollection(shadow, facecolors="0.75", edgecolors="none", zorder=1.5))
            if view.dim == 2:
                tri = Triangulation(screen[:, 0], screen[:, 1], f.cells)
                ax.tripcolor(tri, values, shading="gouraud", cmap=cmap, norm=norm, zorder=2)
                ax.triplot(tri, color="k", lw=0.15, alpha=0.35, zorder=3)
            else:
                corners = f.points[faces]  # (F, 3, 3)
                normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
                normal /= np.linalg.norm(normal, axis=1, keepdims=True) + 1e-300
                shade = 0.55 + 0.45 * np.abs(normal @ light)
                order = np.argsort(camera.depth(corners.mean(axis=1)))  # far first: nearer faces drawn over them
                colours = cmap(norm(values[faces].mean(axis=1)))[:, :3] * shade[:, None]
                polys = camera.screen(corners.reshape(-1, 3)).reshape(-1, 3, 2)
                ax.add_collection(PolyCollection(polys[order], facecolors=colours[order], edgecolors="none", zorder=2))
            ax.set_xlim(lo[0], hi[0])
            ax.set_ylim(lo[1], hi[1])
            ax.set_aspect("equal")
            ax.set_axis_off()
            ax.text(0.02 * _DRAWING_WIDTH, 0.96, labels[k], transform=ax.transAxes, fontsize=14, va="top")
            bar = fig.add_axes([_DRAWING_WIDTH + 0.02, 0.12, 0.018, 0.76])
            fig.colorbar(plt.cm.ScalarMappable(norm=norm, cmap=cmap), cax=bar).set_label(COLOUR_LABEL, fontsize=11)
            fig.canvas.draw()
            yield np.asarray(fig.canvas.buffer_rgba())[:, :, :3].copy()
    finally:
        plt.close(fig)


def _pyvista_frames(frames: list[_Frame], view: _View, size):
    """RGB images of the frames, rendered off-screen with pyvista through the view's camera.

    Yields
    ------
    image : ndarray of uint8, shape (height, width, 3)
        One frame at a time: only the one being rendered is held.
    """
    _headless_vtk()
    import pyvista as pv

    camera = view.camera
    dim = view.dim
    cells = frames[0].cells if dim == 2 else _surface(frames[0].cells)
    body = pv.PolyData.from_regular_faces(pad3(frames[0].points), cells)
    body.point_data["deformation"] = frames[0].deformation
    plotter = pv.Plotter(off_screen=True, window_size=list(size))
    scale = _text_scale(size)
    label_size = _points(_BAR_LABEL_SIZE, scale)
    plotter.set_background("white")
    plotter.add_mesh(
        body,
        scalars="deformation",
        cmap=CMAP,
        clim=(0.0, view.vmax),
        smooth_shading=dim == 3,
        scalar_bar_args={
            "title": COLOUR_TITLE,
            "vertical": True,
            "position_x": _DRAWING_WIDTH + 0.02,
            "position_y": 0.12,
            "height": 0.76,
            "width": 0.05,
            "color": "black",
            "title_font_size": _points(14, scale),
            "label_font_size": label_size,
        },
    )
    # VTK puts the title right on the top label: keep them a label's height apart
    plotter.scalar_bar.SetVerticalTitleSeparation(label_size)
    if view.ground is not None:
        lines = pad3(_floor_lines(view).reshape(-1, dim))
        plotter.add_mesh(pv.line_segments_from_points(lines), color="#999999", line_width=1.5 * scale, lighting=False)
        if dim == 2:
            lo = np.min([view.picture_limits(k)[0] for k in range(len(frames))], axis=0)
            hi = np.max([view.picture_limits(k)[1] for k in range(len(frames))], axis=0)
            right, up = camera.right[:2], view.up
            a = np.array([lo[0], hi[0]])
            ground = [pad3(np.outer(a, right) + w * up) for w in (view.ground, lo[1])]
            quad = np.vstack([ground[0], ground[1][::-1]]) - [0.0, 0.0, 1e-3 * view.spacing]
            plotter.add_mesh(pv.PolyData(quad, faces=[4, 0, 1, 2, 3]), color="#e6e6e6", lighting=False)
            plotter.add_mesh(pv.Line(*ground[0]), color="#737373", line_width=2 * scale, lighting=False)
        else:
            below = -1e-3 * view.spacing * view.up  # under the lines and the shadow
            floor = pv.PolyData(_floor_corners(view) + below, faces=[4, 0, 1, 2, 3])
            plotter.add_mesh(floor, color="#ebebeb", lighting=False)
            shadow = pv.PolyData.from_regular_faces(_on_floor(frames[0].points, view.up, view.ground), cells)
            plotter.add_mesh(shadow, color="#bfbfbf", lighting=False)
    corner = (round(20 * scale), size[1] - round(44 * scale))
    text = plotter.add_text("", position=corner, font_size=_points(14, scale), color="black")
    depth = float(np.median(camera.depth(pad3(frames[0].points))))
    try:
        labels = _time_labels(frames)
        for k, f in enumerate(frames):
            body.points = pad3(f.points)
            body.point_data["deformation"] = f.deformation
            if dim == 3:
                body.compute_normals(inplace=True, cell_normals=False, auto_orient_normals=False)
                if view.ground is not None:
                    shadow.points = _on_floor(f.points, view.up, view.ground)
            text.SetInput(labels[k])
            # the window's centre sits left of the picture's (the colour bar takes the right)
            u = view.centres[k, 0] + (0.5 - _DRAWING_WIDTH / 2) * 2.0 * view.half_height * size[0] / size[1]
            focal = u * camera.right + view.centres[k, 1] * camera.screen_up + depth * camera.towards
            plotter.camera.parallel_projection = True
            plotter.camera.focal_point = focal
            plotter.camera.position = focal + 4.0 * view.half_height * view.aspect * camera.towards
            plotter.camera.up = camera.screen_up
            plotter.camera.parallel_scale = view.half_height
            plotter.renderer.ResetCameraClippingRange()
            plotter.render()
            yield plotter.screenshot(return_img=True)[:, :, :3].copy()
    finally:
        plotter.close()


def _save_png(image, path):
    from PIL import Image

    with written_whole(path) as partial:  # whole or not at all
        Image.fromarray(image).save(partial)
    return os.fspath(path)


class _GifStream:
    """An animated GIF written one frame at a time (Pillow's own writer holds every frame until the end).

    Each frame gets its own 256 colours (Pillow's adaptive palette, as Pillow
    picks for a whole GIF) and the full picture; it loops forever.
    """

    def __init__(self, file, fps: int):
        self.file = file
        self.duration_ms = int(1000 / fps)
        self.count = 0

    def append_data(self, image: np.ndarray) -> None:
        from PIL import GifImagePlugin, Image

        frame = Image.fromarray(image).convert("P", palette=Image.Palette.ADAPTIVE)
        if self.count == 0:
            header, _ = GifImagePlugin.getheader(frame, info={"loop": 0, "duration": self.duration_ms})
            self.file.write(b"".join(header))
        for chunk in GifImagePlugin.getdata(frame, duration=self.duration_ms, include_color_table=True):
            self.file.write(chunk)
        self.count += 1

    def close(self) -> None:
        self.file.write(b";")  # the GIF trailer


@contextlib.contextmanager
def _animation_writer(path, fps: int):
    """A writer (``append_data(image)``) streaming frames to ``path`` (.gif or .mp4), written whole.

    An mp4 keeps the frames' size (imageio's ffmpeg writer would scale it to
    a multiple of 16 and say so); :func:`picture_size_problem` has refused
    the odd sizes H.264 in yuv420p cannot hold.
    """
    with written_whole(path) as partial:
        if os.fspath(path).endswith(".gif"):
            with open(partial, "wb") as file:
                writer = _GifStream(file, fps)
                yield writer
                writer.close()
        else:
            import imageio.v2 as imageio

            writer = imageio.get_writer(partial, fps=fps, macro_block_size=1)
            try:
                yield writer
            finally:
                writer.close()


def render_run(
    run_dir,
    *,
    backend: str = "auto",
    fmt: str = "gif",
    max_frames: int = 120,
    fps: int = 20,
    size: tuple[int, int] = DEFAULT_SIZE,
) -> dict:
    """Pictures and an animation of a finished run, written into its directory.

    Frames are coloured by deformation (distance from the best rigid motion
    of the rest shape) on one range for the whole run, with a colour bar; the
    camera keeps one scale for every frame and follows the body when its
    motion does not fit one view; the ground is drawn as a floor under the
    scene's up axis (see :mod:`skfem_modal.camera`).

    Parameters
    ----------
    run_dir : str or path-like
        A directory written by ``skfem-modal run``.
    backend : {"auto", "pyvista", "matplotlib"}
        ``auto`` uses pyvista when off-screen OpenGL works here.
    fmt : {"gif", "mp4"}
    max_frames : int
        At most this many frames in the animation (evenly spaced, the first
        and the last among them when it is 2 or more). ``first_frame.png``
        and ``last_frame.png`` are the run's first and last frames whatever it is.
    fps : int
    size : (int, int)
        Width and height of the frames in pixels, each from
        :data:`MIN_PICTURE_SIDE` to :data:`MAX_PICTURE_SIDE`; even for an
        mp4 (see :func:`picture_size_problem`). Text and lines grow with it,
        in proportion to :data:`DEFAULT_SIZE`: a picture looks the same at
        any size.

    Returns
    -------
    written : dict
        ``backend`` used and the path of each picture.

    Raises
    ------
    ImportError
        Something rendering needs is missing (said before any drawing, see
        :func:`render_problems`).
    ValueError
        A backend, format or size out of range; a frame file that cannot be
        read or is not a frame of this run (naming it, before any drawing).
    FileNotFoundError
        No run in ``run_dir``, or a frame file ``frames.pvd`` lists is missing.
    """
    if backend not in ("auto", "pyvista", "matplotlib"):
        raise ValueError(f"backend must be auto, pyvista or matplotlib, got {backend!r}")
    if fmt not in ("gif", "mp4"):
        raise ValueError(f"format must be gif or mp4, got {fmt!r}")
    if len(size) != 2:
        raise ValueError(f"size must be (width, height) in pixels, got {size!r}")
    problem = picture_size_problem(size, fmt)
    if problem:
        raise ValueError(f"size {problem}")
    run_dir = os.fspath(run_dir)
    if not os.path.isfile(os.path.join(run_dir, "summary.json")):
        raise FileNotFoundError(f"{run_dir!r} is not a run directory (no summary.json)")
    problems = render_problems(backend, fmt)
    if problems:
        raise ImportError("cannot render: " + "; ".join(problems))
    # before reading every frame (a read-only run folder was found only at the first picture)
    check_writable(run_dir, "the run folder", "copy the run to a folder that can be written and render it there")
    run = read_run(run_dir)
    if not run["frames"]:
        raise ValueError(f"{run_dir!r} holds no frames")
    if backend == "auto":
        backend = "pyvista" if gl_available() else "matplotlib"
    summary = run["summary"]
    listed = run["frames"]
    # every frame listed is there (a sampled animation read only those it draws: one deleted went unseen)
    missing = [path for _, path in listed if not os.path.isfile(path)]
    if missing:
        raise FileNotFoundError(
            f"frame file {missing[0]!r} (listed in frames.pvd) is missing"
            + (f", and {len(missing) - 1} more" if len(missing) > 1 else "")
        )
    last = len(listed) - 1
    animated = set(np.linspace(0, last, min(max_frames, len(listed))).round().astype(int).tolist())
    # the stills are always the run's first and last frames, whatever the animation holds
    drawn = sorted(animated | {0, last})
    size = (int(size[0]), int(size[1]))
    # the view is planned on every frame (its colour range, camera and scale the whole run's, whatever is
    # drawn: with two frames drawn the colours topped out at the last one's deformation); the drawn ones are kept
    frames = []

    def every_frame():
        first = _read_frame(*listed[0])
        for index, entry in enumerate(listed):
            frame = first if index == 0 else _read_frame(*entry, first=first)
            if index in drawn:
                frames.append(frame)
            yield frame

    view = _plan(every_frame(), summary, size, drawn)
    draw = _pyvista_frames if backend == "pyvista" else _matplotlib_frames
    written = {"backend": backend}
    written["com"] = plot_com(run, os.path.join(run_dir, "com.png"))
    if summary["sizes"]["muscles"]:
        written["amplitudes"] = plot_amplitudes(run, os.path.join(run_dir, "amplitudes.png"))
    stills = {"first_frame": 0, "last_frame": last}
    animation = os.path.join(run_dir, f"animation.{fmt}")
    with contextlib.closing(draw(frames, view, size)) as images, _animation_writer(animation, fps) as writer:
        for index, image in zip(drawn, images):
            if index in animated:
                writer.append_data(image)
            for name in (name for name, at in stills.items() if at == index):
                written[name] = _save_png(image, os.path.join(run_dir, f"{name}.png"))
    written["animation"] = animation
    return written
