"""Counts the mesh cannot take (clusters, weights, muscles, seed, contact candidates) are refused by key
before any work, by ``run`` and ``info`` alike, with the simulator's own rule (one rule in one place)."""

import numpy as np
import pytest

import skfem_modal as sm
from skfem_modal import ingredients as ingredients_module
from skfem_modal.cli import main
from skfem_modal.ingredients import count_problems
from skfem_modal.modal import muscle_count_problem
from skfem_modal.scene import Scene, SceneError
from skfem_modal.sim import ModalMuscle

BOX = '[mesh]\nshape = "box3d"\nparams = { nx = 2, ny = 2, nz = 2 }\n[time]\nsteps = 2\n'  # 27 vertices, 48 tets


def soup(nx=4):
    """A triangle soup: every triangle of a square with its own three vertices (no vertex shared)."""
    mesh = sm.beam2d(length=1.0, height=1.0, nx=nx, ny=nx)
    points = mesh.p[:, mesh.t.T.ravel()]
    return type(mesh)(points, np.arange(points.shape[1]).reshape(-1, 3).T)


@pytest.fixture
def no_precompute(monkeypatch):
    """Any precompute fails the test: the checks must come first."""

    def refused(*args, **kwargs):
        raise AssertionError("the precompute started")

    monkeypatch.setattr(ModalMuscle, "from_mesh", classmethod(refused))
    monkeypatch.setattr(ingredients_module, "skinning_eigenmodes", refused)
    monkeypatch.setattr(ingredients_module, "muscle_modes", refused)


@pytest.mark.parametrize(
    "text, said",
    [
        ("[muscles]\ncount = 2\n[subspace]\nactive_clusters = 100\n", "subspace.active_clusters: 100 must be in 1..48"),
        ("[muscles]\ncount = 2\n[subspace]\nclusters = 49\n", "subspace.clusters: 49 must be in 1..48"),
        ("[muscles]\ncount = 2\n[subspace]\nseed = -1\n", "subspace.seed: -1 must be an integer in 0..4294967295"),
        ("[muscles]\ncount = 2\n[subspace]\nseed = 4294967296\n", "subspace.seed: 4294967296 must be an integer in 0"),
        ("[muscles]\ncount = 2\n[subspace]\ncluster_weights = 100\n", "subspace.cluster_weights: 100 must be in 1..26"),
        ("[muscles]\ncount = 2\n[subspace]\nweights = 27\n", "subspace.weights: 27 must be in 1..26"),
        (
            '[muscles]\ncount = 2\n[gravity]\nacceleration = [0, 0, -9.8]\n[ground]\ncontacts_where = ["z > 100"]\n',
            "ground.contacts_where: ['z > 100'] select no boundary vertex of the mesh",
        ),
        ("[muscles]\ncount = 76\n", "muscles.count: 76 is too many for the 81 degrees of freedom of the mesh less"),
    ],
)
def test_run_and_info_refuse_by_key_before_any_work(tmp_path, capsys, no_precompute, text, said):
    path = tmp_path / "scene.toml"
    path.write_text(BOX + text)
    for command in (["info", str(path)], ["run", str(path), "--out", str(tmp_path / "out"), "--quiet"]):
        assert main(command) == 2
        assert said in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_the_muscle_count_rule_is_the_librarys_own():
    mesh = sm.box3d(2, 2, 2)  # 81 DOFs, 6 rigid motions: 75 muscles fit, as from_mesh's modal analysis finds
    assert sm.muscle_modes(mesh, 75).shape == (81, 75)
    with pytest.raises(ValueError, match="n_muscles: 76 is too many for the 81 degrees of freedom"):
        sm.muscle_modes(mesh, 76)
    Scene.from_dict({"mesh": {"shape": "box3d", "params": {"nx": 2, "ny": 2, "nz": 2}}, "muscles": {"count": 75}})
    # pinned: the clamped body has no rigid motion, and the pins' DOFs are gone
    pins = {"where": ["x == min"]}  # 9 vertices: 54 DOFs left
    data = {"mesh": {"shape": "box3d", "params": {"nx": 2, "ny": 2, "nz": 2}}, "pinned": pins}
    Scene.from_dict({**data, "muscles": {"count": 54}})
    with pytest.raises(SceneError, match="muscles.count: 55 is too many for the 54 degrees of freedom the pins"):
        Scene.from_dict({**data, "muscles": {"count": 55}})


def test_several_parts_count_their_rigid_motions():
    one = sm.box3d(1, 1, 1)
    two = type(one)(np.hstack([one.p, one.p + [[3.0], [0.0], [0.0]]]), np.hstack([one.t, one.t + one.p.shape[1]]))
    assert sm.rigid_mode_count(two) == 12
    fits = two.p.size - 12
    assert sm.muscle_modes(two, fits).shape[1] == fits
    assert muscle_count_problem(two, fits + 1).endswith(f"less its 12 rigid motions: at most {fits}")


def test_from_mesh_refuses_counts_before_its_precompute(monkeypatch, no_precompute):
    monkeypatch.undo()  # keep from_mesh itself, refuse only its stages
    for name in ("skinning_eigenmodes", "muscle_modes"):
        monkeypatch.setattr(ingredients_module, name, lambda *a, **k: pytest.fail("the precompute started"))
    mesh = sm.box3d(2, 2, 2)
    with pytest.raises(ValueError, match=r"n_active_clusters: 100 must be in 1..48 .*; seed: -1 must be"):
        ModalMuscle.from_mesh(mesh, n_muscles=2, n_weights=4, n_clusters=4, n_active_clusters=100, seed=-1)


def test_count_problems_of_a_soup_name_its_parts():
    problems = dict(
        count_problems(
            soup(),
            n_muscles=2,
            pinned=None,
            n_weights=8,
            cluster_weights=None,
            n_clusters=20,
            n_active_clusters=1,
            seed=0,
            contact_candidates=None,
        )
    )
    assert "at least the mesh's 32 separate parts" in problems["n_weights"]
    assert "at least the mesh's 32 separate parts" in problems["n_clusters"]
    assert set(problems) == {"n_weights", "n_clusters"}


def test_a_triangle_soup_is_said_and_merged(tmp_path):
    import meshio

    loose = soup()  # 32 triangles, 96 vertices, 25 distinct positions
    path = tmp_path / "soup.obj"
    meshio.write_points_cells(str(path), np.vstack([loose.p, np.zeros(loose.p.shape[1])]).T, [("triangle", loose.t.T)])
    with pytest.warns(UserWarning, match=r"71 of its 96 vertices coincide .*only 25 distinct.* 32 separate part"):
        as_is = sm.load_mesh(path)
    assert as_is.p.shape[1] == 96
    merged = sm.load_mesh(path, merge=True)
    assert merged.p.shape == (2, 25) and merged.t.shape == (3, 32)
    assert sm.rigid_mode_count(merged) == 3
    np.testing.assert_allclose(np.sort(merged.p[0]), np.sort(sm.beam2d(1.0, 1.0, 4, 4).p[0]))
    data = {"mesh": {"file": str(path), "merge": True}, "muscles": {"count": 2}}
    assert Scene.from_dict(data).mesh.p.shape[1] == 25
    with pytest.raises(SceneError, match="mesh.merge: only for mesh files"):
        Scene.from_dict({"mesh": {"shape": "beam2d", "merge": True}})


def test_modes_and_info_merge_a_triangle_soup_on_the_command_line(tmp_path, capsys):
    import meshio

    loose = soup()
    path = tmp_path / "soup.obj"
    meshio.write_points_cells(str(path), np.vstack([loose.p, np.zeros(loose.p.shape[1])]).T, [("triangle", loose.t.T)])
    out = tmp_path / "modes.vtu"
    assert main(["modes", str(path), "-k", "5", "--out", str(out)]) == 0
    said = capsys.readouterr()
    assert "96 vertices" in said.out and "96 rigid motions (32 connected part(s))" in said.out  # 32 loose triangles
    assert "a triangle soup" in said.err and "--merge on the command line" in said.err
    assert main(["modes", str(path), "--merge", "-k", "5", "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert "25 vertices, 32 triangle elements" in said and "3 rigid motions (1 connected part(s))" in said
    assert main(["info", str(path), "--merge"]) == 0
    assert "mesh: 25 vertices, 32 triangle elements" in capsys.readouterr().out
    assert main(["modes", "beam2d", "--merge"]) == 2
    assert "--merge is for mesh files; beam2d is a built-in shape" in capsys.readouterr().err
    assert main(["info", "--merge"]) == 2
    assert "--merge is for mesh files; a scene merges" in capsys.readouterr().err


def test_modes_without_k_fits_a_small_mesh_and_asks_for_k_on_a_soup(tmp_path, capsys):
    import meshio

    # 8 DOFs: the default (the rigid motions and 6 elastic modes) asked for 9 and failed
    assert main(["modes", "caterpillar:nx=2,ny=2", "--out", str(tmp_path / "small.vtu")]) == 0
    assert "8 modes in" in capsys.readouterr().out
    loose = soup(8)  # 128 triangles, none sharing a vertex: 384 rigid motions before any elastic mode
    path = tmp_path / "soup.obj"
    meshio.write_points_cells(str(path), np.vstack([loose.p, np.zeros(loose.p.shape[1])]).T, [("triangle", loose.t.T)])
    assert main(["modes", str(path), "--out", str(tmp_path / "m.vtu")]) == 2
    err = capsys.readouterr().err
    assert "falls into 128 separate parts: their 384 rigid motions come before any elastic mode" in err
    assert "--merge" in err
    assert main(["modes", str(path), "-k", "4", "--out", str(tmp_path / "m.vtu")]) == 0
