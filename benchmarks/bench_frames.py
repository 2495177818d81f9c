"""Writing a run's frames: ours (constant parts encoded once) against meshio's VTU writer, side by side.

    python benchmarks/bench_frames.py [--frames 10]

The seal (9996 vertices, 38689 tetrahedra) and the tutorial's caterpillar
(1719 vertices): each frame the positions, the displacement, two cell arrays
(clusters) and the field data a run writes. Prints milliseconds a frame (the
minimum over 3 rounds) and the file size, and checks that meshio reads our
frame back to the same numbers.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import meshio  # noqa: E402
import numpy as np  # noqa: E402
from machine import machine_line  # noqa: E402
from options import at_least  # noqa: E402

import skfem_modal as sm  # noqa: E402
from skfem_modal.export import FrameWriter, pad3, vtk_cells  # noqa: E402

SEAL = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "shared", "meshes", "seal.mesh")


def per_frame(write, frames: int) -> float:
    best = np.inf
    for _ in range(3):
        start = time.perf_counter()
        for k in range(frames):
            write(k)
        best = min(best, (time.perf_counter() - start) / frames)
    return best * 1e3


def compare(name, mesh, frames: int, rng) -> None:
    """Ours and meshio's on the same states of one mesh: a row each."""
    nT = mesh.t.shape[1]
    clusters = {"cluster": rng.integers(0, 20, nT), "muscle_cluster": np.zeros(nT, dtype=np.int64)}
    rest = mesh.p.T
    states = [rest + 1e-3 * rng.standard_normal(rest.shape) for _ in range(frames)]
    cell_type, cells = vtk_cells(mesh)
    with tempfile.TemporaryDirectory() as tmp:
        with FrameWriter(tmp, mesh, cell_data=clusters) as ours:
            activation = {"activation": [0.1, 0.2]}
            ms = per_frame(lambda k: ours.write(0.01 * ours.count, states[k], field_data=activation), frames)
        path = os.path.join(tmp, "frames", "frame_00000.vtu")
        back = meshio.read(path)
        assert np.array_equal(back.points, pad3(states[0])) and np.array_equal(back.cells[0].data, cells)
        assert np.array_equal(back.cell_data["cluster"][0], clusters["cluster"])
        print(f"{name:12s} {'ours':8s} {ms:9.1f} {os.path.getsize(path) / 1e6:9.2f}")

        def theirs(k):
            point_data = {"displacement": pad3(states[k] - rest)}
            cell_data = {key: [value] for key, value in clusters.items()}
            grid = meshio.Mesh(pad3(states[k]), [(cell_type, cells)], point_data=point_data, cell_data=cell_data)
            meshio.write(os.path.join(tmp, "meshio.vtu"), grid, file_format="vtu")

        ms = per_frame(theirs, frames)
        print(f"{name:12s} {'meshio':8s} {ms:9.1f} {os.path.getsize(os.path.join(tmp, 'meshio.vtu')) / 1e6:9.2f}")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=at_least(1), default=10)
    args = parser.parse_args()
    print(machine_line(f"meshio {meshio.__version__}"))
    print(f"{'mesh':12s} {'writer':8s} {'ms/frame':>9s} {'MB/frame':>9s}")
    rng = np.random.default_rng(0)
    for name, mesh in (("seal", sm.load_mesh(SEAL)), ("caterpillar", sm.caterpillar())):
        compare(name, mesh, args.frames, rng)


if __name__ == "__main__":
    main()
