"""Symmetric and multi-part meshes through every stage: weights, modes, clusters, muscles, simulator, study.

scikit-fem's symmetric meshes have repeated eigenvalues (a disk's, a square's,
a ball's); two separate bodies in one mesh have two constants in the
Laplacian's null space and twelve rigid motions in 3D. Each stage must give
the same answer whatever the solver returns inside a repeated group.
"""

import meshio
import numpy as np
import pytest
import scipy.special as sps_special
from skfem import MeshTet, MeshTri

from skfem_modal import linear_modal_analysis
from skfem_modal.clusters import spectral_clusters
from skfem_modal.contact import ALLOWANCE
from skfem_modal.eigen import canonical_eigenpairs, generic_weight
from skfem_modal.fem import mass_matrix
from skfem_modal.mesh import connected_parts
from skfem_modal.scene import Scene
from skfem_modal.sim import ModalMuscle
from skfem_modal.subspace import laplacian, skinning_eigenmodes


def two_parts(mesh, shift):
    """The mesh and a copy moved by ``shift``: two separate bodies."""
    p = np.hstack([mesh.p, mesh.p + np.asarray(shift, float)[:, None]])
    t = np.hstack([mesh.t, mesh.t + mesh.p.shape[1]])
    return type(mesh)(p, t)


def cube(n=5):
    return MeshTet.init_tensor(*[np.linspace(0.0, 1.0, n + 1)] * 3)


SYMMETRIC = {
    "circle": lambda: MeshTri.init_circle(4),
    "symmetric square": lambda: MeshTri.init_symmetric().refined(4),
    "cube": cube,
    "ball": lambda: MeshTet.init_ball(2),
}
TWO_PARTS = {
    "two squares": lambda: two_parts(MeshTri.init_symmetric().refined(3), [1.5, 0.0]),
    "two cubes": lambda: two_parts(cube(3), [0.0, 0.0, 1.5]),
}
ALL = {**SYMMETRIC, **TWO_PARTS}


def permuted(mesh, seed=0):
    """The same mesh with its vertices renumbered: (mesh, new index of each old vertex)."""
    n = mesh.p.shape[1]
    order = np.random.default_rng(seed).permutation(n)  # new vertex i is old vertex order[i]
    new_index = np.empty(n, dtype=np.int64)
    new_index[order] = np.arange(n)
    return type(mesh)(mesh.p[:, order], new_index[mesh.t]), new_index


def lumped(mesh):
    return mass_matrix(mesh, rho=1.0, lumped=True, vector=False)


def same_up_to_sign(A, B, tol):
    """Columns equal up to each column's sign (the sign rule breaks exact ties by DOF order)."""
    signs = np.where(np.einsum("ij,ij->j", A, B) < 0, -1.0, 1.0)
    return np.abs(A - B * signs).max() <= tol * np.abs(A).max()


def deformation(x, X):
    """Largest distance of ``x`` from ``X`` moved by the best rigid motion (a body may turn)."""
    xc, Xc = x - x.mean(axis=0), X - X.mean(axis=0)
    U, _, Vt = np.linalg.svd(xc.T @ Xc)
    R = U @ Vt
    return float(np.abs(xc - Xc @ R.T).max())


@pytest.mark.parametrize("name", ALL)
def test_skinning_weights_solve_the_eigenproblem_and_are_mass_orthonormal(name):
    mesh = ALL[name]()
    values, W, B = skinning_eigenmodes(mesh, 8)
    L, M = laplacian(mesh), lumped(mesh)
    assert np.abs(W.T @ (M @ W) - np.eye(8)).max() < 1e-10
    residual = L @ W - (M @ W) * values
    assert np.abs(residual).max() < 1e-8 * max(1.0, values.max())
    assert B.shape == (mesh.p.size, 8 * (mesh.p.shape[0] + 1) * mesh.p.shape[0])
    assert np.all(np.diff(values) >= -1e-9)


def test_disk_square_and_ball_eigenvalues_are_the_analytic_ones_with_their_multiplicity():
    # Neumann Laplacian: unit disk (j'_{1,1})^2 twice; unit square pi^2 twice;
    # unit ball (first root of j_1')^2 three times (the ball mesh is only
    # nearly symmetric, so its three are close, not equal)
    disk, _, _ = skinning_eigenmodes(SYMMETRIC["circle"](), 4)
    j11 = sps_special.jnp_zeros(1, 1)[0]
    assert disk[1] == disk[2]  # one repeated group, made exactly equal
    assert disk[1] == pytest.approx(j11**2, rel=2e-3)
    square, _, _ = skinning_eigenmodes(SYMMETRIC["symmetric square"](), 4)
    assert square[1] == square[2] and square[1] == pytest.approx(np.pi**2, rel=3e-3)
    assert square[3] == pytest.approx(2 * np.pi**2, rel=1e-2)
    ball, _, _ = skinning_eigenmodes(SYMMETRIC["ball"](), 4)
    from scipy.optimize import brentq

    root = brentq(lambda x: sps_special.spherical_jn(1, x, derivative=True), 1.5, 2.5)  # 2.0816
    assert np.allclose(ball[1:4], root**2, rtol=0.05)


@pytest.mark.parametrize("name", ALL)
@pytest.mark.parametrize("k", [7, 8])
def test_weights_do_not_depend_on_the_vertex_order(name, k):
    # k = 7 cuts the circle's and the squares' last repeated pair: the kept
    # vector must still be the same one
    mesh = ALL[name]()
    n_parts = int(connected_parts(mesh).max()) + 1
    _, W, _ = skinning_eigenmodes(mesh, k)
    other, new_index = permuted(mesh)
    _, W2, _ = skinning_eigenmodes(other, k)
    W2 = W2[new_index]
    # parts are numbered by their first vertex: the constant weights come in that order
    parts_first = sorted(map(tuple, np.round(W[:, :n_parts].T, 12)))
    assert parts_first == sorted(map(tuple, np.round(W2[:, :n_parts].T, 12)))
    assert same_up_to_sign(W[:, n_parts:], W2[:, n_parts:], 1e-7)


@pytest.mark.parametrize("name", ["circle", "cube", "ball"])
def test_modes_do_not_depend_on_the_vertex_order(name):
    mesh = ALL[name]()
    dim = mesh.p.shape[0]
    k = 3 * (dim - 1) + 8  # the rigid motions and eight more
    values, modes = linear_modal_analysis(mesh, k)
    other, new_index = permuted(mesh, seed=1)
    values2, modes2 = linear_modal_analysis(other, k)
    assert np.allclose(values2, values, rtol=1e-9, atol=1e-9 * values.max())
    dofs = (new_index[:, None] * dim + np.arange(dim)).ravel()
    assert same_up_to_sign(modes, modes2[dofs], 1e-6)


def test_a_group_cut_by_k_is_solved_whole_before_its_basis_is_fixed():
    mesh = SYMMETRIC["circle"]()
    L, M = laplacian(mesh), lumped(mesh)
    w = generic_weight(mesh.p.T, 1)
    constant = np.full((mesh.p.shape[1], 1), 1.0 / np.sqrt(M.diagonal().sum()))
    one, v1 = canonical_eigenpairs(L, M, 1, w, null=constant)  # the first of a pair
    two, v2 = canonical_eigenpairs(L, M, 2, w, null=constant)
    assert two[0] == two[1] == one[0]
    assert np.abs(v1[:, 0] - v2[:, 0]).max() < 1e-10


@pytest.mark.parametrize("name", TWO_PARTS)
def test_two_parts_get_a_constant_weight_each_and_clusters_of_their_own(name):
    mesh = TWO_PARTS[name]()
    parts = connected_parts(mesh)
    values, W, _ = skinning_eigenmodes(mesh, 8)
    assert np.abs(values[:2]).max() < 1e-10
    for part in range(2):
        inside = parts == part
        assert np.ptp(W[inside, part]) < 1e-12 and np.abs(W[~inside, part]).max() == 0.0
    labels = spectral_clusters(mesh, W, 9)
    element_part = parts[mesh.t[0]]
    assert sorted(np.unique(labels).tolist()) == list(range(9))
    for c in range(9):
        assert np.unique(element_part[labels == c]).size == 1  # no cluster spans both bodies
    assert np.bincount(element_part[np.unique(labels, return_index=True)[1]]).tolist() in ([5, 4], [4, 5])
    with pytest.raises(ValueError, match="at least the mesh's 2 separate parts"):
        skinning_eigenmodes(mesh, 1)
    with pytest.raises(ValueError, match="at least the mesh's 2 separate parts"):
        spectral_clusters(mesh, W, 1)


@pytest.mark.parametrize("name", ALL)
def test_the_simulator_keeps_each_bodys_centre_of_mass_when_floating(name):
    mesh = ALL[name]()
    parts = connected_parts(mesh)
    mass = lumped(mesh).diagonal()
    sim = ModalMuscle.from_mesh(mesh, n_muscles=4, n_clusters=8, h=0.01)
    z, z_dot, _ = sim.rest_state()

    def part_centres(z):
        x = sim.positions(z)
        return np.array([mass[parts == k] @ x[parts == k] / mass[parts == k].sum() for k in range(parts.max() + 1)])

    start = part_centres(z)
    size = float(np.ptp(mesh.p, axis=1).max())
    deformed = 0.0
    for i in range(60):
        a = 0.4 * sim.ceilings * np.sin(0.3 * i + np.arange(sim.n_muscles))
        z_next = sim.step(z, z_dot, a)
        z_dot, z = (z_next - z) / sim.h, z_next
        x = sim.positions(z)
        deformed = max(deformed, max(deformation(x[parts == k], mesh.p.T[parts == k]) for k in range(parts.max() + 1)))
    assert np.all(np.isfinite(z))
    assert np.abs(part_centres(z) - start).max() < 1e-10 * size
    assert 1e-2 * size < deformed < 0.5 * size  # the muscles bend each body, nothing blows up


@pytest.mark.parametrize("name", ["symmetric square", "two cubes"])
def test_a_scene_on_such_a_mesh_file_falls_and_lands(name, tmp_path):
    mesh = ALL[name]()
    dim = mesh.p.shape[0]
    path = tmp_path / "body.vtu"
    meshio.write(path, meshio.Mesh(mesh.p.T, [("triangle" if dim == 2 else "tetra", mesh.t.T)]))
    gravity = [0.0] * dim
    gravity[1] = -9.8  # y up, in 3D too
    scene = Scene.from_dict(
        {
            "mesh": {"file": str(path)},
            "material": {"mu": 1e5},
            "subspace": {"clusters": 8},
            "time": {"step": 0.01, "steps": 80},
            "gravity": {"acceleration": gravity},
            "ground": {"offset": 0.1},
        }
    )
    assert scene.up == 1
    from skfem_modal.run import run_scene

    summary = run_scene(scene, None)
    low = summary["com"]["min"][1] - summary["com"]["start"][1]
    # dropped 0.1, it lands and stays: the centre of mass is between 0.1 and 0.3 lower
    assert -0.3 < low < -0.09
    assert summary["ground"]["worst_penetration_relative"] <= ALLOWANCE  # the Coulomb contact's


def test_a_short_study_on_two_bodies(tmp_path):
    from skfem_modal import study

    mesh = TWO_PARTS["two squares"]()
    path = tmp_path / "two.vtu"
    meshio.write(path, meshio.Mesh(mesh.p.T, [("triangle", mesh.t.T)]))
    data = {
        "mesh": {"file": str(path)},
        "material": {"mu": 1e4},
        "subspace": {"weights": 6, "clusters": 8},
        "time": {"step": 0.01},
        "muscles": {"count": 4, "gait": {"amplitude": [0.3] * 4, "period": [0.5, 0.6, 0.7, 0.8]}},
    }
    reference = study.run_reference(data, None, 40)
    rows = [
        study.run_reduced(
            {
                "scene": data,
                "base_dir": None,
                "steps": 40,
                "reference": reference["x"],
                "sweep": "weights",
                "label": f"weights={w}",
                "overrides": {"weights": w},
            }
        )
        for w in (2, 6)
    ]
    errors = [row["trajectory_error"] for row in rows]
    # two constant weights: each body moves only affinely; six follow the reference closer
    assert np.all(np.isfinite(errors)) and errors[1] < errors[0] < 1.0
    assert rows[0]["subspace"] == 2 * 3 * 2 and rows[1]["subspace"] == 6 * 3 * 2
