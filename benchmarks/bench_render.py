"""Peak memory and time of ``skfem-modal render``: does memory stay one frame's, however many frames?

    flock -x /tmp/skfem_cpu.lock python benchmarks/bench_render.py [--sizes 1280x720 3840x2160] [--few 5]
                                       [--every 5] [--backends matplotlib pyvista]

Runs the built-in crawl once (91 frames; ``--every`` K: a frame every K steps)
into a scratch folder, then renders
it in a fresh process for each backend (matplotlib; pyvista where off-screen
OpenGL works, left out with a note on stderr elsewhere) and size, with every
frame in the animation and with only ``--few``, side by side. Prints each render's peak resident memory (the
process's own ``ru_maxrss``, from ``wait4``) and wall time, and the ratio of
peak memory with every frame to peak memory with a few: about 1 when frames
are streamed to the animation writer one at a time, about frames / few
when they are held.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from machine import machine_line  # noqa: E402
from options import at_least, by  # noqa: E402

from skfem_modal.plot import gl_available  # noqa: E402

CLI = "import sys; from skfem_modal.cli import main; sys.exit(main(sys.argv[1:]))"


def render(run_dir: str, backend: str, size: str, max_frames: int) -> tuple[float, float]:
    """One render in a fresh process: (peak resident memory in MB, wall seconds)."""
    argv = [sys.executable, "-c", CLI, "render", run_dir, "-q", "--backend", backend, "--size", size]
    argv += ["--max-frames", str(max_frames)]
    start = time.perf_counter()
    process = subprocess.Popen(argv)
    _, status, usage = os.wait4(process.pid, 0)
    seconds = time.perf_counter() - start
    process.returncode = os.waitstatus_to_exitcode(status)
    if process.returncode:
        raise SystemExit(f"render failed ({process.returncode}): {' '.join(argv)}")
    return usage.ru_maxrss / 1024.0, seconds  # ru_maxrss is in KB on Linux


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--sizes", nargs="+", type=by("WIDTH", "HEIGHT"), default=[(1280, 720), (3840, 2160)], metavar="WIDTHxHEIGHT"
    )
    parser.add_argument("--few", type=at_least(1), default=5, help="frames of the small animation")
    parser.add_argument("--every", type=at_least(1), default=5, help="a frame every K steps of the crawl's 450")
    parser.add_argument("--backends", nargs="+", choices=["matplotlib", "pyvista"], default=["matplotlib", "pyvista"])
    args = parser.parse_args()
    print(machine_line())
    backends = list(args.backends)
    if "pyvista" in backends and not gl_available():
        # said, not silently dropped: the table would look as if pyvista had never been asked for
        print("bench_render: pyvista left out: off-screen OpenGL does not work here", file=sys.stderr)
        backends.remove("pyvista")
    with tempfile.TemporaryDirectory() as scratch:
        run_dir = os.path.join(scratch, "crawl")
        run = [sys.executable, "-c", CLI, "run", "--out", run_dir, "--every", str(args.every), "-q"]
        subprocess.run(run, check=True)
        frames = len(os.listdir(os.path.join(run_dir, "frames")))
        print(f"the built-in crawl: {frames} frames; renders with all of them against renders with {args.few}")
        print(f"{'backend':<11} {'size':>10} {'MB, all':>9} {'MB, few':>9} {'ratio':>6} {'s, all':>8} {'s, few':>7}")
        for backend in backends:
            for width, height in args.sizes:
                size = f"{width}x{height}"
                every, every_s = render(run_dir, backend, size, frames)
                few, few_s = render(run_dir, backend, size, args.few)
                memory = f"{every:>9.0f} {few:>9.0f} {every / few:>6.2f}"
                print(f"{backend:<11} {size:>10} {memory} {every_s:>8.1f} {few_s:>7.1f}")


if __name__ == "__main__":
    main()
