import meshio
import numpy as np
import pytest

from skfem_modal import beam3d, export_modes, linear_modal_analysis, natural_frequencies, vertices_where
from skfem_modal.cli import main
from skfem_modal.fem import node_positions


def test_export_modes_p1_2d(tmp_path, cat_mesh):
    values, modes = linear_modal_analysis(cat_mesh, 7)
    path = tmp_path / "out" / "modes.vtu"
    export_modes(path, cat_mesh, modes, values)
    back = meshio.read(path)
    assert back.points.shape == (1719, 3)
    np.testing.assert_array_equal(back.points[:, 2], 0.0)
    assert back.cells_dict["triangle"].shape == (3058, 3)
    assert sorted(back.point_data) == [f"mode_{i:02d}" for i in range(7)]
    m3 = back.point_data["mode_03"]
    assert m3.shape == (1719, 3)
    np.testing.assert_allclose(m3[:, :2].ravel(), modes[:, 3])
    np.testing.assert_array_equal(m3[:, 2], 0.0)
    np.testing.assert_allclose(back.field_data["eigenvalues"], values)
    np.testing.assert_allclose(back.field_data["frequency_hz"], natural_frequencies(values))
    # nothing but the file itself is left in the directory
    assert [p.name for p in path.parent.iterdir()] == ["modes.vtu"]


def test_export_modes_p2_3d_uses_quadratic_cells(tmp_path):
    mesh = beam3d(4.0, 1.0, 1.0, 4, 1, 1)
    values, modes = linear_modal_analysis(mesh, 3, fixed=vertices_where(mesh, "x == min"), element="P2")
    path = tmp_path / "p2.vtu"
    export_modes(path, mesh, modes, values)
    back = meshio.read(path)
    cells = back.cells_dict["tetra10"]
    assert cells.shape == (mesh.t.shape[1], 10)
    pts = back.points
    np.testing.assert_allclose(pts, node_positions(mesh, "P2"))
    # VTK order: corners, then midpoints of (0,1), (1,2), (0,2), (0,3), (1,3), (2,3)
    pairs = [(0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3)]
    for k, (a, b) in enumerate(pairs):
        np.testing.assert_allclose(pts[cells[:, 4 + k]], (pts[cells[:, a]] + pts[cells[:, b]]) / 2, atol=1e-12)
    np.testing.assert_allclose(back.point_data["mode_00"].ravel(), modes[:, 0])


def test_export_rejects_wrong_shapes(tmp_path, cat_mesh):
    with pytest.raises(ValueError, match=r"modes must have shape \(3438, k\) for P1"):
        export_modes(tmp_path / "x.vtu", cat_mesh, np.zeros((3437, 2)), element="P1")
    with pytest.raises(ValueError, match="non-finite"):
        export_modes(tmp_path / "x.vtu", cat_mesh, np.full((3438, 1), np.nan))
    assert not list(tmp_path.iterdir())


def test_cli_modes_default_caterpillar(tmp_path, capsys, reference):
    out = tmp_path / "modes.vtu"
    assert main(["modes", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "1719 vertices, 3058 triangle elements" in text
    assert "3 rigid motions" in text
    for value in reference["eigenvalues_3_6"]:
        assert f"{value:.8e}"[:9] in text
    back = meshio.read(out)
    assert len(back.point_data) == 9  # the 3 rigid motions and 6 elastic modes
    rows = [line.split() for line in text.splitlines() if line.split()[-1:] in (["rigid"], ["elastic"])]
    assert [r[-1] for r in rows] == ["rigid"] * 3 + ["elastic"] * 6
    # a rigid motion has no ceiling; the elastic ones are the tutorial's
    assert [r[3] for r in rows[:3]] == ["-"] * 3
    np.testing.assert_allclose(
        [float(r[3]) for r in rows[3:7]], reference["ceilings_3_6"], rtol=1e-5
    )  # printed to 6 digits


def test_cli_modes_mesh_file_and_clamp(tmp_path, capsys):
    mesh = beam3d(4.0, 1.0, 1.0, 8, 2, 2)
    path = tmp_path / "beam.vtu"
    meshio.write(path, meshio.Mesh(mesh.p.T, [("tetra", mesh.t.T)]))
    out = tmp_path / "beam_modes.vtu"
    code = main(
        ["modes", str(path), "-k", "4", "--young", "1e3", "--poisson", "0.3", "--fix", "x == min", "--out", str(out)]
    )
    assert code == 0
    assert "0 rigid motions" in capsys.readouterr().out
    assert meshio.read(out).point_data["mode_00"].shape == (mesh.p.shape[1], 3)


def test_cli_bad_input_exit_code(tmp_path, capsys):
    assert main(["modes", str(tmp_path / "nope.msh")]) == 2
    assert "mesh file not found" in capsys.readouterr().err
    assert main(["modes", "caterpillar:nx=abc"]) == 2
    assert "mesh parameter 'nx' must be a number" in capsys.readouterr().err
    assert main(["modes", "--young", "1.0"]) == 2
    assert "--young and --poisson go together" in capsys.readouterr().err
    assert main(["modes", "beam2d", "--fix", "x < -5"]) == 2
    assert "selects no vertex" in capsys.readouterr().err
