"""Every cell written for VTK is positively oriented, so ParaView integrates volumes and areas right.

scikit-fem sorts each element's vertex indices, which turns about half the
elements of its meshes (and of the built-in shapes) inside out for VTK: the
built-in creature has 2232 of its 4464 tetrahedra negative, and ParaView's
*Integrate Variables* or pyvista's ``volume`` then sums to about zero instead
of 0.744.
"""

import pathlib

import meshio
import numpy as np
import pytest

import skfem_modal as sm
from skfem_modal.cli import main
from skfem_modal.export import FrameWriter, vtk_cells
from skfem_modal.mesh import load_mesh
from skfem_modal.run import run_scene
from skfem_modal.scene import Scene

SHARED = pathlib.Path(__file__).resolve().parents[2] / "shared" / "meshes"

# VTK's quadratic cells: corners, then the midpoints of these corner pairs
VTK_EDGES = {
    "triangle6": [(0, 1), (1, 2), (2, 0)],
    "tetra10": [(0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3)],
}


def signed_measures(points, cells, dim):
    """Signed area (seen from +z) or volume of each cell, from its first dim + 1 nodes."""
    corners = points[cells[:, : dim + 1], :dim]  # (nT, dim + 1, dim)
    return np.linalg.det(corners[:, 1:] - corners[:, :1]) / (2.0 if dim == 2 else 6.0)


def written_cells(path):
    """The one cell block of a written .vtu: its type, nodes, and the points."""
    back = meshio.read(path)
    ((cell_type, cells),) = back.cells_dict.items()
    return cell_type, cells, back.points


def assert_positive_and_whole(path, dim, measure):
    cell_type, cells, points = written_cells(path)
    signed = signed_measures(points, cells, dim)
    assert signed.min() > 0.0, f"{(signed <= 0).sum()} of {len(cells)} cells inside out"
    assert signed.sum() == pytest.approx(measure, rel=1e-12)
    for k, (a, b) in enumerate(VTK_EDGES.get(cell_type, [])):  # edge nodes follow their swapped corners
        np.testing.assert_allclose(
            points[cells[:, dim + 1 + k]], (points[cells[:, a]] + points[cells[:, b]]) / 2, atol=1e-12
        )
    if dim == 3:  # VTK itself agrees (it sums signed volumes of the cells as written)
        pv = pytest.importorskip("pyvista", reason="pyvista is in the plot extra")
        assert pv.read(path).volume == pytest.approx(measure, rel=1e-9)
    return cell_type


def measure_of(mesh):
    return float(np.abs(sm.mesh._signed_measures(mesh.p, mesh.t)).sum())


@pytest.mark.parametrize("element", ["P1", "P2"])
@pytest.mark.parametrize("shape", ["caterpillar", "creature"])
def test_modes_files_hold_positive_cells_that_sum_to_the_mesh(tmp_path, shape, element):
    mesh = sm.caterpillar() if shape == "caterpillar" else sm.creature(cell=0.2)
    dim = mesh.p.shape[0]
    negative = (sm.mesh._signed_measures(mesh.p, mesh.t) < 0).sum()
    assert 0.3 * mesh.t.shape[1] < negative < 0.7 * mesh.t.shape[1]  # scikit-fem's sorting: the case at hand
    t_before = mesh.t.copy()
    values, modes = sm.linear_modal_analysis(mesh, 4, element=element)
    path = tmp_path / "modes.vtu"
    sm.export_modes(path, mesh, modes, values, element=element)
    expected = {("P1", 2): "triangle", ("P1", 3): "tetra", ("P2", 2): "triangle6", ("P2", 3): "tetra10"}
    assert assert_positive_and_whole(path, dim, measure_of(mesh)) == expected[element, dim]
    np.testing.assert_array_equal(mesh.t, t_before)  # the mesh in memory is left as it was


def test_the_modes_command_writes_positive_quadratic_tetrahedra(tmp_path):
    out = tmp_path / "modes.vtu"
    assert main(["modes", "creature", "--element", "P2", "-k", "7", "--out", str(out), "-q"]) == 0
    assert assert_positive_and_whole(out, 3, 0.744) == "tetra10"


@pytest.mark.parametrize(
    "data, dim",
    [
        ({"mesh": {"shape": "caterpillar"}}, 2),
        ({"mesh": {"shape": "creature", "params": {"cell": 0.2}}, "gravity": {"acceleration": [0, 0, -9.8]}}, 3),
    ],
    ids=["2d", "3d"],
)
def test_run_frames_hold_positive_cells(tmp_path, data, dim):
    scene = Scene.from_dict(
        {
            **data,
            "time": {"step": 0.02, "steps": 10},
            "output": {"every": 5},
            "muscles": {"count": 2, "gait": {"amplitude": [0.5, 0.5], "period": [0.5, 0.4]}},
        }
    )
    t_before = scene.mesh.t.copy()
    run_scene(scene, tmp_path)
    frames = sorted((tmp_path / "frames").glob("frame_*.vtu"))
    assert len(frames) == 3
    # frame 0 is the rest shape: its cells sum to the mesh's measure exactly
    assert_positive_and_whole(frames[0], dim, measure_of(scene.mesh))
    for path in frames[1:]:  # moved frames (the muscles swell the body): still every cell positive
        _, cells, points = written_cells(path)
        signed = signed_measures(points, cells, dim)
        assert signed.min() > 0.0 and signed.sum() != pytest.approx(measure_of(scene.mesh), rel=1e-3)
        if dim == 3:
            pv = pytest.importorskip("pyvista", reason="pyvista is in the plot extra")
            assert pv.read(path).volume == pytest.approx(signed.sum(), rel=1e-9)
    np.testing.assert_array_equal(scene.mesh.t, t_before)


@pytest.mark.skipif(not SHARED.is_dir(), reason=f"the real meshes are not at {SHARED}")
def test_meshes_already_positive_are_written_in_their_own_order(tmp_path):
    seal = load_mesh(SHARED / "seal.mesh")  # 38689 tetrahedra, all positive in the file
    assert (sm.mesh._signed_measures(seal.p, seal.t) > 0).all()
    cell_type, cells = vtk_cells(seal)
    assert cell_type == "tetra"
    np.testing.assert_array_equal(cells, seal.t.T)
    with FrameWriter(tmp_path, seal) as frames:
        path = frames.write(0.0, seal.p.T)
    np.testing.assert_array_equal(written_cells(path)[1], seal.t.T)
