import meshio
import numpy as np
import pytest
import scipy.sparse.linalg as spla

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
    # modes transposed: the shapes of both elements named (it said 'for P2')
    with pytest.raises(ValueError, match=r"\(3438, k\) for P1 or \(\d+, k\) for P2 on this mesh, got \(2, 3438\)"):
        export_modes(tmp_path / "x.vtu", cat_mesh, np.zeros((2, 3438)))
    # VTU XML in a .vtk file (the command refused it, the function wrote it)
    for name in ("x.vtk", "x"):
        with pytest.raises(ValueError, match=r"export_modes writes VTK XML \(.vtu\)"):
            export_modes(tmp_path / name, cat_mesh, np.zeros((3438, 1)))
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


def test_cli_modes_refuses_what_it_cannot_write_before_any_work(tmp_path, capsys, monkeypatch):
    import skfem_modal.modal

    def never(*args, **kwargs):
        raise AssertionError("the modes were computed")

    monkeypatch.setattr(skfem_modal.modal, "linear_modal_analysis", never)
    cases = [
        (["--out", str(tmp_path / "a.vtk")], "expected a .vtu file"),
        (["--out", str(tmp_path)], "is a directory; give a file name"),
        (["--young", "1", "--poisson", "0.3", "--mu", "2"], "both give the material: give one pair"),
        # a read-only file system: os.access says yes to root there, so the folder is tried
        (["--out", "/sys/modes.vtu"], "/sys is not a folder this user can write in"),
    ]
    for extra, message in cases:
        assert main(["modes", "beam2d", *extra]) == 2
        assert message in capsys.readouterr().err
    for value in ("0", "-1", "inf"):
        with pytest.raises(SystemExit) as exit_:
            main(["modes", "beam2d", "--max-s", value])
        assert exit_.value.code == 2
        assert "argument --max-s: expected a positive finite number" in capsys.readouterr().err
    assert main(["modes", "examples/seal_crawl.toml"]) == 2
    assert "is a scene; this command takes a mesh" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_cli_modes_labels_a_hinge_and_prints_no_frequency_for_round_off(tmp_path, capsys):
    from test_modal import _hinged_squares

    path = tmp_path / "hinged.vtu"
    mesh = _hinged_squares()
    meshio.write(path, meshio.Mesh(mesh.p.T, [("triangle", mesh.t.T)]))
    assert main(["modes", str(path), "--fix", "x == min", "-k", "3", "--out", str(tmp_path / "m.vtu")]) == 0
    printed = capsys.readouterr()
    assert "warning: 1 modes have zero stiffness besides the 0 rigid motions the pins leave" in printed.err
    rows = [line.split() for line in printed.out.splitlines() if line.split()[-1:] in (["hinge"], ["elastic"])]
    assert [r[-1] for r in rows] == ["hinge", "elastic", "elastic"]
    assert float(rows[0][2]) == 0.0 and float(rows[1][2]) > 0.0


def test_cli_modes_without_k_gives_six_elastic_modes_past_the_hinges(tmp_path, capsys):
    # the coarse caterpillar's 4 hinges took the slots of 4 elastic modes: 3 rigid, 4 hinges, 2 elastic
    assert main(["modes", "caterpillar:nx=8,ny=5", "--out", str(tmp_path / "m.vtu")]) == 0
    kinds = [line.split()[-1] for line in capsys.readouterr().out.splitlines() if line.split()[-1:] and
             line.split()[-1] in ("rigid", "hinge", "elastic")]  # fmt: skip
    assert kinds == ["rigid"] * 3 + ["hinge"] * 4 + ["elastic"] * 6


def test_a_scene_is_known_by_its_suffix_in_any_case(tmp_path, capsys):
    upper = tmp_path / "CREATURE.TOML"
    upper.write_text(open("examples/creature_crawl.toml").read())
    assert main(["info", str(upper)]) == 0
    assert "scene: creature crawl" in capsys.readouterr().out
    assert main(["modes", str(upper)]) == 2
    assert "is a scene; this command takes a mesh" in capsys.readouterr().err


def test_a_shape_spec_takes_a_list_and_refuses_a_parameter_twice(capsys):
    # 'box3d:size=[1,2,3]' said "must be a number, got '[1'"; 'nx=5,nx=6' took the last silently
    assert main(["info", "box3d:nx=4,size=[1,2,3],ny=2"]) == 0
    assert "bounds: [0.0, 0.0, 0.0] .. [1.0, 2.0, 3.0]" in capsys.readouterr().out
    assert main(["info", "caterpillar:nx=5,nx=6"]) == 2
    assert "mesh parameter 'nx' is given twice in 'caterpillar:nx=5,nx=6'" in capsys.readouterr().err


def test_a_modal_analysis_that_fails_numerically_says_so_without_a_traceback(tmp_path, capsys, monkeypatch):
    """A plate 1e-5 thin, and an eigen solve that stalls (20 identical squares: ARPACK found 0 of 7), ended in raw
    tracebacks, exit code 1 (an audit): a numerical failure, exit code 3, in one line."""
    args = ["modes", "box3d:nx=3,ny=3,nz=1,size=[1,1,1e-5]", "--element", "P2", "--mu", "0.5", "--lam", "0"]
    assert main([*args, "--out", str(tmp_path / "m.vtu"), "-q"]) == 3
    err = capsys.readouterr().err
    assert err.startswith("skfem-modal modes: numerical failure: elastic mode 6 came out with eigenvalue -")
    assert "negative beyond round-off" in err and err.count("\n") == 1

    def stalled(*args, **kwargs):
        raise spla.ArpackNoConvergence("ARPACK error -1: No convergence", np.zeros(0), np.zeros((0, 0)))

    monkeypatch.setattr(spla, "eigsh", stalled)
    assert main(["modes", "box3d:nx=8,ny=8,nz=8", "-k", "12", "--out", str(tmp_path / "s.vtu"), "-q"]) == 3
    assert capsys.readouterr().err == (
        "skfem-modal modes: numerical failure: the eigen solver (ARPACK) found 0 of 7 modes before giving up: many "
        "nearly equal frequencies (a mesh of many identical separate parts) or a very thin body make shift-invert "
        "Lanczos stall; ask for fewer modes, or analyse the parts one at a time\n"
    )
    assert not (tmp_path / "s.vtu").exists()


@pytest.mark.parametrize("module", ["numpy", "scipy.sparse", "skfem"])
def test_ctrl_c_while_the_command_line_loads_is_said_without_a_traceback(module):
    # the console script imported numpy, scipy and scikit-fem (most of a second) before main() could catch
    # a Ctrl-C: a traceback through the imports (an audit). The process sends itself SIGINT as the import
    # of `module` begins (a Ctrl-C after a fixed sleep landed, on a fast machine, after the command had
    # finished: a flaky test)
    import subprocess
    import sys

    script = (
        "import os, signal, sys\n"
        "class Interrupt:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        f"        if name == {module!r}:\n"
        "            os.kill(os.getpid(), signal.SIGINT)\n"
        "sys.meta_path.insert(0, Interrupt())\n"
        "from skfem_modal._entry import main\n"
        "sys.exit(main())\n"
    )
    argv = [sys.executable, "-c", script, "info", "caterpillar"]
    process = subprocess.run(argv, capture_output=True, text=True, timeout=60)
    out, err = process.stdout, process.stderr
    assert process.returncode == 130 and "Traceback" not in err
    assert out == ""  # stopped before the command ran
    assert err.rstrip().endswith("interrupted") and err.count("\n") == 1


def test_run_refuses_picture_options_without_render(tmp_path, capsys):
    """An audit: run --size 321x240 --format mp4 without --render exited 0, drew nothing and said nothing."""
    out = tmp_path / "out"
    assert main(["run", "--out", str(out), "-q", "--size", "321x240", "--format", "mp4"]) == 2
    err = capsys.readouterr().err
    assert "--format, --size set the pictures, which run draws only with --render" in err
    assert not out.exists()  # before any work


def test_frames_and_vtu_files_refuse_data_they_cannot_write_before_writing(tmp_path):
    """Our own VTU writer (not meshio's): data of another kind is named, before any file or folder."""
    import os

    from skfem_modal import beam2d
    from skfem_modal.export import FrameWriter, write_vtu

    mesh = beam2d(nx=2, ny=1)
    nT = mesh.t.shape[1]
    with pytest.raises(ValueError, match=r"data 'label': expected numbers .* got <U1 of shape \(\d+,\)"):
        FrameWriter(tmp_path / "run", mesh, cell_data={"label": np.array(["a"] * nT)})
    with pytest.raises(ValueError, match=r"cell data 'short' needs one value per element \(\d+\)"):
        FrameWriter(tmp_path / "run", mesh, cell_data={"short": np.zeros(nT - 1)})
    assert not os.path.exists(tmp_path / "run")
    with pytest.raises(ValueError, match="cell type 'quad': expected one of triangle, tetra, triangle6, tetra10"):
        write_vtu(tmp_path / "q.vtu", mesh.p.T, "quad", np.zeros((1, 4), int))
    path = tmp_path / "ok.vtu"
    flags, labels = {"flag": mesh.p[0] > 0.5}, {"k": np.arange(nT)}
    write_vtu(path, mesh.p.T, "triangle", mesh.t.T, point_data=flags, cell_data=labels)
    back = meshio.read(path)  # a boolean as 0 and 1, the integers as they were
    np.testing.assert_array_equal(back.point_data["flag"], (mesh.p[0] > 0.5).astype(np.uint8))
    np.testing.assert_array_equal(back.cell_data["k"][0], np.arange(nT))
    assert sorted(os.listdir(tmp_path)) == ["ok.vtu"]


def test_a_negative_number_in_scientific_notation_is_an_option_value(tmp_path, capsys):
    """An audit: ``--young -1e6`` was read as an unknown option ('expected one argument'), not refused by name."""
    from skfem_modal.cli import main

    assert main(["modes", "--young", "-1e6", "--poisson", "0.3", "-k", "3", "--out", str(tmp_path / "m.vtu")]) == 2
    assert "Young's modulus must be positive and finite, got -1000000.0" in capsys.readouterr().err
    assert main(["modes", "--young", "1e6", "--poisson", "-2.5e-1", "-k", "7", "--out", str(tmp_path / "m.vtu")]) == 0
    assert (tmp_path / "m.vtu").exists()


@pytest.mark.parametrize(
    "option, said", [("--rho", "expected a positive finite number"), ("--mu", "expected a positive finite number")]
)
def test_modes_names_a_bad_material_option_before_reading_the_mesh(option, said, capsys):
    """A new user's trial: --rho 0 was refused as 'rho must be positive' after the seal's mesh was read."""
    from skfem_modal.cli import main

    for value in ("0", "nan"):
        with pytest.raises(SystemExit) as usage:
            main(["modes", "no_such_mesh.msh", option, value])  # the mesh is never read
        assert usage.value.code == 2
        assert f"argument {option}: {said}, got '{value}'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["modes", "no_such_mesh.msh", "--lam", "inf"])
    assert "argument --lam: expected a finite number, got 'inf'" in capsys.readouterr().err


@pytest.mark.parametrize(
    "argv, said",
    [
        (["run", "--every", "0"], "skfem-modal run: error: argument --every: expected a positive integer, got '0'"),
        (["modes", "-k", "0"], "skfem-modal modes: error: argument -k: expected a positive integer, got '0'"),
        (["run", "--bogus"], "skfem-modal run: error: unrecognized arguments: --bogus"),
        (["--bogus", "run"], "skfem-modal: error: unrecognized arguments: --bogus"),
        (["bogus"], "skfem-modal: error: argument command: invalid choice: 'bogus'"),
        # no command at all: the unknown option is the news (it said only that a command is required)
        (["--bogus"], "skfem-modal: error: unrecognized arguments: --bogus"),
        ([], "skfem-modal: error: the following arguments are required: command"),
    ],
)
def test_option_errors_are_one_line_naming_the_command(argv, said, capsys):
    """An option argparse refuses is said in one line, as other bad input (not after a usage block)."""
    with pytest.raises(SystemExit) as refused:
        main(argv)
    err = capsys.readouterr().err
    assert refused.value.code == 2
    assert err.count("\n") == 1 and err.startswith(said)
    assert err.rstrip().endswith(f"(options: {said.split(':')[0]} --help)")


def test_a_mesh_specs_count_beyond_a_float_is_named(capsys):
    """(It was an OverflowError's traceback and exit 1.)"""
    assert main(["info", "beam2d:nx=" + "9" * 400]) == 2
    assert "skfem-modal info: error: beam2d: these parameters make about inf elements" in capsys.readouterr().err


def test_info_shows_a_tiny_mesh_s_bounds_and_the_effects_in_the_simulator_s_order(tmp_path, capsys):
    """An audit: a box 2e-6 across printed bounds of zeros (4 decimals); info listed contact before the pins."""
    import meshio

    from skfem_modal import box3d
    from skfem_modal.scene import Scene

    box = box3d(2, 2, 2)
    meshio.write(tmp_path / "tiny.vtu", meshio.Mesh(box.p.T * 2e-6, [("tetra", box.t.T)]))
    assert main(["info", str(tmp_path / "tiny.vtu")]) == 0
    assert "bounds: [0.0, 0.0, 0.0] .. [2e-06, 2e-06, 2e-06]" in capsys.readouterr().out
    scene = Scene.from_dict(
        {
            "mesh": {"shape": "beam2d", "params": {"nx": 8, "ny": 2}},
            "muscles": {"count": 1},
            "gravity": {"acceleration": [0.0, -9.8]},
            "ground": {"offset": 0.1},
            "pinned": {"where": ["x == min"]},
            "damping": {"mass": 0.5},
            "time": {"steps": 2},
        }
    )
    assert scene.effects == scene.build().effects == (
        "elasticity", "inertia", "muscles", "gravity", "pinned", "damping", "contact"
    )  # fmt: skip
