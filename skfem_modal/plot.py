"""Pictures of a finished run: centre of mass, modal amplitudes, frames, an animation.

An optional extra (``pip install skfem_modal[plot]``): matplotlib always, and
pyvista for nicer frames where an OpenGL backend works. Whether it works is
probed in a subprocess, because a missing GL can crash the process that tries;
without it everything is drawn with matplotlib.
"""

from __future__ import annotations

import csv
import functools
import json
import os
import re
import subprocess
import sys

import numpy as np

__all__ = ["read_run", "gl_available", "render_problems", "plot_com", "plot_amplitudes", "render_run"]


def read_run(run_dir) -> dict:
    """Read what a run wrote.

    Returns
    -------
    run : dict
        ``summary`` (dict), ``com`` (times (k,), values (k, dim)),
        ``amplitudes`` (times, commanded (k, m), realised (k, m)),
        ``frames`` (list of (time, path)).
    """
    run_dir = os.fspath(run_dir)
    with open(os.path.join(run_dir, "summary.json")) as f:
        summary = json.load(f)

    def table(name):
        with open(os.path.join(run_dir, name), newline="") as f:
            rows = list(csv.reader(f))
        data = np.array([[float(v) for v in row] for row in rows[1:]]) if len(rows) > 1 else np.zeros((0, len(rows[0])))
        return rows[0], data

    _, com = table("com.csv")
    header, amp = table("amplitudes.csv")
    m = (len(header) - 1) // 2
    pvd = open(os.path.join(run_dir, "frames.pvd")).read()
    frames = [
        (float(t), os.path.join(run_dir, f)) for t, f in re.findall(r'timestep="([^"]+)"[^>]*file="([^"]+)"', pvd)
    ]
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
    for module, package in (("matplotlib", "matplotlib"), ("PIL", "pillow")):
        try:
            __import__(module)
        except ImportError:
            problems.append(f"{package} is not installed: pip install 'skfem_modal[plot]'")
    if backend == "pyvista":
        try:
            import pyvista  # noqa: F401
        except ImportError:
            problems.append("pyvista is not installed: pip install 'skfem_modal[plot]', or use --backend matplotlib")
        else:
            if not gl_available():
                problems.append("pyvista cannot render off-screen here (no working OpenGL): use --backend matplotlib")
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
    """Centre of mass over time (each axis), with the ground height."""
    plt = _pyplot()
    t, com = run["com"]
    dim = com.shape[1]
    summary = run["summary"]
    up = summary["scene"]["ground"]["up"] if summary["scene"].get("ground") else None
    up = dim - 1 if up is None else up
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
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return os.fspath(path)


def plot_amplitudes(run, path) -> str:
    """Commanded (dashed) and realised (solid) modal amplitudes per muscle."""
    plt = _pyplot()
    t, commanded, realised = run["amplitudes"]
    fig, ax = plt.subplots(figsize=(7, 3.2))
    for k in range(commanded.shape[1]):
        ax.plot(t, realised[:, k], color=f"C{k}", lw=1.6, label=f"muscle {k} realised")
        ax.plot(t, commanded[:, k], color=f"C{k}", lw=1.0, ls="--", alpha=0.8, label=f"muscle {k} commanded")
    ax.set_xlabel("time")
    ax.set_ylabel("modal amplitude")
    ax.grid(alpha=0.3)
    if commanded.shape[1]:
        ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return os.fspath(path)


def _read_frame(path):
    import meshio

    m = meshio.read(path)
    cells = m.cells_dict.get("triangle")
    if cells is not None:
        return m.points[:, :2], cells, 2
    return m.points, m.cells_dict["tetra"], 3


def _surface(tets):
    faces = np.sort(np.vstack([tets[:, [0, 1, 2]], tets[:, [0, 1, 3]], tets[:, [0, 2, 3]], tets[:, [1, 2, 3]]]), axis=1)
    uniq, counts = np.unique(faces, axis=0, return_counts=True)
    return uniq[counts == 1]


def _matplotlib_frames(frames, ground, up, size=(640, 360)):
    """RGB images of the frames, drawn with matplotlib."""
    plt = _pyplot()
    points = [_read_frame(p) for _, p in frames]
    allx = np.vstack([x for x, _, _ in points])
    lo, hi = allx.min(axis=0), allx.max(axis=0)
    pad = 0.08 * (hi - lo).max()
    images = []
    for (t, _), (x, cells, dim) in zip(frames, points):
        fig = plt.figure(figsize=(size[0] / 100, size[1] / 100), dpi=100)
        if dim == 2:
            ax = fig.add_subplot(111)
            if ground is not None:
                ax.axhspan(lo[1] - pad, ground, color="0.88")
                ax.axhline(ground, color="0.5", lw=1)
            ax.triplot(x[:, 0], x[:, 1], cells, color="C2", lw=0.4)
            ax.set_xlim(lo[0] - pad, hi[0] + pad)
            ax.set_ylim(lo[1] - pad, hi[1] + pad)
            ax.set_aspect("equal")
        else:
            from mpl_toolkits.mplot3d.art3d import Poly3DCollection

            ax = fig.add_subplot(111, projection="3d")
            faces = _surface(cells)
            ax.add_collection3d(Poly3DCollection(x[faces], facecolor="C2", edgecolor="k", linewidths=0.1, alpha=0.9))
            for k, (a, b) in enumerate(zip(lo, hi)):
                getattr(ax, f"set_{'xyz'[k]}lim")(a - pad, b + pad)
            ax.set_box_aspect(tuple(hi - lo + 2 * pad))
        ax.set_title(f"t = {t:.3f}", fontsize=9)
        ax.set_axis_off()
        fig.canvas.draw()
        images.append(np.asarray(fig.canvas.buffer_rgba())[:, :, :3].copy())
        plt.close(fig)
    return images


def _pyvista_frames(frames, ground, up, size=(640, 360)):
    """RGB images of the frames, rendered off-screen with pyvista."""
    _headless_vtk()
    import pyvista as pv

    meshes = [pv.read(p) for _, p in frames]
    bounds = np.array([m.bounds for m in meshes])
    lo = bounds[:, ::2].min(axis=0)
    hi = bounds[:, 1::2].max(axis=0)
    dim = 2 if np.allclose(lo[2], hi[2]) else 3
    plotter = pv.Plotter(off_screen=True, window_size=size)
    images = []
    for (t, _), mesh in zip(frames, meshes):
        plotter.clear()
        mag = np.linalg.norm(mesh.point_data["displacement"], axis=1)
        plotter.add_mesh(mesh, scalars=mag, cmap="viridis", show_scalar_bar=False)
        if ground is not None:
            if dim == 2:
                plotter.add_mesh(pv.Line((lo[0] - 1, ground, 0), (hi[0] + 1, ground, 0)), color="gray", line_width=3)
            else:
                centre = [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2]
                centre[up] = ground
                normal = [0, 0, 0]
                normal[up] = 1
                extent = float((hi - lo).max()) * 1.5
                plotter.add_mesh(
                    pv.Plane(center=centre, direction=normal, i_size=extent, j_size=extent), color="lightgray"
                )
        plotter.add_text(f"t = {t:.3f}", font_size=10)
        if dim == 2:
            plotter.view_xy()
        else:
            plotter.view_isometric()
        plotter.reset_camera(bounds=(lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]))
        images.append(plotter.screenshot(return_img=True)[:, :, :3].copy())
    plotter.close()
    return images


def _save_png(image, path):
    from PIL import Image

    Image.fromarray(image).save(path)
    return os.fspath(path)


def _save_animation(images, path, fps: int):
    from PIL import Image

    if os.fspath(path).endswith(".gif"):
        frames = [Image.fromarray(im) for im in images]
        frames[0].save(path, save_all=True, append_images=frames[1:], duration=int(1000 / fps), loop=0)
        return os.fspath(path)
    import imageio.v2 as imageio

    imageio.mimwrite(path, images, fps=fps)
    return os.fspath(path)


def render_run(run_dir, *, backend: str = "auto", fmt: str = "gif", max_frames: int = 120, fps: int = 20) -> dict:
    """Pictures and an animation of a finished run, written into its directory.

    Parameters
    ----------
    run_dir : str or path-like
        A directory written by ``skfem-modal run``.
    backend : {"auto", "pyvista", "matplotlib"}
        ``auto`` uses pyvista when off-screen OpenGL works here.
    fmt : {"gif", "mp4"}
    max_frames : int
        At most this many frames in the animation (evenly spaced).
    fps : int

    Returns
    -------
    written : dict
        ``backend`` used and the path of each picture.
    """
    if backend not in ("auto", "pyvista", "matplotlib"):
        raise ValueError(f"backend must be auto, pyvista or matplotlib, got {backend!r}")
    if fmt not in ("gif", "mp4"):
        raise ValueError(f"format must be gif or mp4, got {fmt!r}")
    run_dir = os.fspath(run_dir)
    if not os.path.isfile(os.path.join(run_dir, "summary.json")):
        raise FileNotFoundError(f"{run_dir!r} is not a run directory (no summary.json)")
    problems = render_problems(backend, fmt)
    if problems:
        raise ImportError("cannot render: " + "; ".join(problems))
    run = read_run(run_dir)
    if not run["frames"]:
        raise ValueError(f"{run_dir!r} holds no frames")
    if backend == "auto":
        backend = "pyvista" if gl_available() else "matplotlib"
    summary = run["summary"]
    ground = summary["ground"]["height"] if summary.get("ground") else None
    scene_ground = summary["scene"].get("ground") or {}
    dim = summary["mesh"]["dim"]
    up = dim - 1 if scene_ground.get("up") is None else scene_ground["up"]
    draw = _pyvista_frames if backend == "pyvista" else _matplotlib_frames
    written = {"backend": backend}
    written["com"] = plot_com(run, os.path.join(run_dir, "com.png"))
    if summary["sizes"]["muscles"]:
        written["amplitudes"] = plot_amplitudes(run, os.path.join(run_dir, "amplitudes.png"))
    frames = run["frames"]
    pick = np.unique(np.linspace(0, len(frames) - 1, min(max_frames, len(frames))).round().astype(int))
    images = draw([frames[i] for i in pick], ground, up)
    written["first_frame"] = _save_png(images[0], os.path.join(run_dir, "first_frame.png"))
    written["last_frame"] = _save_png(images[-1], os.path.join(run_dir, "last_frame.png"))
    written["animation"] = _save_animation(images, os.path.join(run_dir, f"animation.{fmt}"), fps)
    return written
