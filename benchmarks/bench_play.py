"""Frames per second of the live window (skfem-modal play) under Xvfb and off-screen.

    flock -x /tmp/skfem_cpu.lock python benchmarks/bench_play.py [--frames 600] [--rounds 3] [--variants]

Needs Xvfb (Debian: apt-get install xvfb) and Mesa (software rendering,
llvmpipe); starts its own virtual display. Each run is a fresh process
running the scripted mode (``play(..., frames=N)``: the gait on, simulated
time following the wall clock) on the caterpillar (the default scene) and
the 3D creature (examples/creature_crawl.toml), in a 960 x 600 window, the
scenes and modes taking turns round after round. Prints each run's mean
frames per second and the medians of one frame's parts (a step, copying the
state into the scene, rendering), then an empty window's render time: the
floor software rendering and presenting the frame set. ``--variants`` also
times, under Xvfb, the window with each of the choices made for speed undone
(pyvista's default 8x multisampling, its five-light kit, the ground drawn as
the edges of its cells, the sliders following the gait every frame), after
the other tables are printed; a variant that fails is reported on stderr, the
others still run, and the script exits non-zero at the end.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from machine import machine_line  # noqa: E402
from options import at_least  # noqa: E402

from skfem_modal.play import virtual_display  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SCENES = {"caterpillar (default)": None, "creature (3D)": str(ROOT / "examples" / "creature_crawl.toml")}

PLAY = """
import json, sys
from skfem_modal.play import play
stats = play(None if sys.argv[1] == "-" else sys.argv[1], frames=int(sys.argv[2]), off_screen=sys.argv[3] == "1",
             say=lambda *a: None)
print(json.dumps(stats))
"""

VARIANT = """
import json, sys
import numpy as np
import pyvista as pv
from skfem_modal import play_view
from skfem_modal.play import Player, _simulator
from skfem_modal.play_view import PlayView
sim, gait, _, ramp = _simulator(None if sys.argv[1] == "-" else sys.argv[1], None)
sim.step(*sim.rest_state())
variant = sys.argv[3]
if variant == "sliders follow the gait every frame":
    play_view._GAIT_SLIDERS_EVERY = 0.0
view = PlayView(Player(sim, gait, ramp=ramp), window_size=(960, 600))
if variant == "8x multisampling (pyvista's default)":
    view.plotter.render_window.SetMultiSamples(8)
if variant == "five-light kit (pyvista's default)":
    view.plotter.enable_lightkit()
if variant == "ground as the edges of its cells" and view.ground_actors:
    for actor in view.ground_actors:
        view.plotter.remove_actor(actor)
    fill = view.ground_actors[0].GetMapper().GetInput()
    lo, hi = np.array(fill.GetBounds()).reshape(3, 2).T
    axes = [np.arange(a, b + view.ground_cell / 2, view.ground_cell) if b > a else [a] for a, b in zip(lo, hi)]
    grid = pv.StructuredGrid(*np.meshgrid(*axes, indexing="ij"))
    view.ground_actors = [view.plotter.add_mesh(grid, color="#d9d9d9", show_edges=True, edge_color="#a6a6a6",
                                                lighting=False, reset_camera=False)]
stats = view.run(int(sys.argv[2]))
view.close()
print(json.dumps(stats))
"""

VARIANTS = [
    "as shipped",
    "8x multisampling (pyvista's default)",
    "five-light kit (pyvista's default)",
    "ground as the edges of its cells",
    "sliders follow the gait every frame",
]

EMPTY = """
import json, sys, time
import numpy as np
from skfem_modal.plot import _headless_vtk
off = sys.argv[1] == "1"
if off:
    _headless_vtk()
import pyvista as pv
theme = pv.themes.DocumentTheme()
theme.multi_samples = 0
theme.anti_aliasing = None
plotter = pv.Plotter(off_screen=off, window_size=[960, 600], theme=theme)
if not off:
    plotter.show(interactive_update=True, auto_close=False)
window = plotter.render_window
times = []
for _ in range(300):
    start = time.perf_counter()
    window.Render()
    times.append(time.perf_counter() - start)
plotter.close()
print(json.dumps({"render_ms": 1e3 * float(np.median(times[20:]))}))
"""


def run(code, args, off_screen):
    env = dict(os.environ)
    if off_screen:
        env.pop("DISPLAY", None)  # off-screen as on a machine without one: EGL
    env.pop("VTK_DEFAULT_OPENGL_WINDOW", None)
    result = subprocess.run(
        [sys.executable, "-c", code, *args], capture_output=True, text=True, env=env, timeout=600, check=False
    )
    if result.returncode:
        raise RuntimeError(f"{args}: exit {result.returncode}\n{result.stderr[-2000:]}")
    return json.loads(result.stdout.strip().splitlines()[-1])


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=at_least(1), default=600)
    parser.add_argument("--rounds", type=at_least(1), default=3)
    parser.add_argument("--variants", action="store_true", help="also time the choices made for speed undone")
    args = parser.parse_args()
    modes = {"Xvfb window": False, "off-screen (EGL)": True}
    runs = {(scene, mode): [] for scene in SCENES for mode in modes}
    failed = []  # "scene: variant" of each variant run that failed (why: on stderr, as it fails)
    with virtual_display() as display:
        for _ in range(args.rounds):
            for scene, path in SCENES.items():
                for mode, off in modes.items():
                    stats = run(PLAY, ["-" if path is None else path, str(args.frames), "1" if off else "0"], off)
                    runs[scene, mode].append(stats)
        empty = {mode: run(EMPTY, ["1" if off else "0"], off)["render_ms"] for mode, off in modes.items()}
        # printed before the variants: a variant that fails cannot lose what was measured
        print_runs(display, args.frames, runs, empty)
        variants = {(scene, v): [] for scene in SCENES for v in VARIANTS} if args.variants else {}
        for _ in range(args.rounds if args.variants else 0):
            for scene, path in SCENES.items():
                for variant in VARIANTS:
                    try:
                        stats = run(VARIANT, ["-" if path is None else path, str(args.frames), variant], False)
                    except RuntimeError as error:
                        print(f"bench_play: {scene}, variant {variant!r} failed: {error}", file=sys.stderr)
                        failed.append(f"{scene}: {variant}")
                        continue
                    variants[scene, variant].append(stats)
    if variants:
        print()
        print("| scene (Xvfb window) | variant | mean frames/s, each run | median render ms, each run |")
        print("|---|---|---|---|")
        for (scene, variant), stats in variants.items():
            fps = ", ".join(f"{s['fps']:.1f}" for s in stats) or "failed"
            render = ", ".join(f"{s['render_ms']:.2f}" for s in stats) or "failed"
            print(f"| {scene} | {variant} | {fps} | {render} |")
    if failed:
        sys.exit(f"bench_play: {len(failed)} variant run(s) failed: {'; '.join(failed)}")


def print_runs(display, frames, runs, empty):
    """The first tables: each scene and mode's runs, and the empty window's render time."""
    print(machine_line(f"Xvfb {display}", f"{frames} frames a run, window 960 x 600"))
    print("| scene | rendering | mean frames/s, each run | median run | step ms | steps/frame | draw ms | render ms |")
    print("|---|---|---|---|---|---|---|---|")
    for (scene, mode), stats in runs.items():
        fps = [s["fps"] for s in stats]
        middle = stats[int(np.argsort(fps)[len(fps) // 2])]
        print(
            f"| {scene} | {mode} | {', '.join(f'{f:.1f}' for f in fps)} | {middle['fps']:.1f} | "
            f"{middle['step_ms']:.3f} | {middle['steps'] / middle['frames']:.2f} | {middle['draw_ms']:.3f} | "
            f"{middle['render_ms']:.2f} |"
        )
    print()
    print("empty 960 x 600 window, median render ms: " + ", ".join(f"{m} {v:.2f}" for m, v in empty.items()))
    sys.stdout.flush()


if __name__ == "__main__":
    main()
