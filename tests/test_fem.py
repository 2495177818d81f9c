import numpy as np
import pytest
import scipy.sparse as sps
from skfem import Basis, BilinearForm, ElementTetP1, ElementTetP2, ElementTriP1, ElementTriP2, ElementVector, asm
from skfem.helpers import dot
from skfem.models.elasticity import linear_elasticity

from skfem_modal import (
    beam2d,
    box3d,
    caterpillar,
    creature,
    deformation_jacobian,
    element_volumes,
    gravity_force,
    lame_parameters,
    mass_matrix,
    node_positions,
    quadrature_volumes,
    stiffness_matrix,
)
from skfem_modal.fem import scalar_basis

ELEMENT = {
    (2, "P1"): ElementTriP1,
    (2, "P2"): ElementTriP2,
    (3, "P1"): ElementTetP1,
    (3, "P2"): ElementTetP2,
}
MESHES = {
    "caterpillar": lambda: caterpillar(nx=20, ny=10),
    "creature": lambda: creature(cell=0.2),
}
CASES = [(name, el) for name in MESHES for el in ("P1", "P2")]


@pytest.fixture(scope="module", params=CASES, ids=[f"{n}-{e}" for n, e in CASES])
def case(request):
    name, element = request.param
    mesh = MESHES[name]()
    dim = mesh.p.shape[0]
    return mesh, element, ELEMENT[(dim, element)]


def rel(a, b):
    return abs(a - b).max() / abs(b).max()


@BilinearForm
def vector_mass(u, v, w):
    return dot(u, v)


def test_stiffness_equals_scikit_fem_linear_elasticity(case):
    mesh, element, cls = case
    mu = np.linspace(0.5, 2.0, mesh.t.shape[1])
    ref = asm(linear_elasticity(Lambda=0.7, Mu=1.3), Basis(mesh, ElementVector(cls())))
    assert rel(stiffness_matrix(mesh, mu=1.3, lam=0.7, element=element), ref) < 1e-13

    # per-element material against scikit-fem with element-wise parameters
    @BilinearForm
    def varying(u, v, w):
        from skfem.helpers import ddot, sym_grad, trace

        eu, ev = sym_grad(u), sym_grad(v)
        return 2 * w["mu"] * ddot(eu, ev) + 0.7 * trace(eu) * trace(ev)

    vb = Basis(mesh, ElementVector(cls()))
    ref_var = asm(varying, vb, mu=np.repeat(mu[:, None], vb.X.shape[1], axis=1))
    assert rel(stiffness_matrix(mesh, mu=mu, lam=0.7, element=element), ref_var) < 1e-13


def test_stiffness_equals_jacobian_sandwich(case):
    mesh, element, _ = case
    dim = mesh.p.shape[0]
    J = deformation_jacobian(mesh, element)
    dx = quadrature_volumes(mesh, element).ravel()
    eye = np.eye(dim)
    C = (
        1.3 * (np.einsum("ik,jl->ijkl", eye, eye) + np.einsum("il,jk->ijkl", eye, eye))
        + 0.7 * np.einsum("ij,kl->ijkl", eye, eye)
    ).reshape(dim * dim, dim * dim)
    # build vol x C independently: a dense block per quadrature point
    blocks = sps.block_diag([w * C for w in dx], format="csr")
    assert rel(stiffness_matrix(mesh, mu=1.3, lam=0.7, element=element), J.T @ blocks @ J) < 1e-13


def test_consistent_mass_equals_scikit_fem(case):
    mesh, element, cls = case
    ref = asm(vector_mass, Basis(mesh, ElementVector(cls()), intorder=4))
    M = mass_matrix(mesh, rho=2.5, lumped=False, element=element)
    assert rel(M, 2.5 * ref) < 1e-13
    Ms = mass_matrix(mesh, rho=2.5, lumped=False, element=element, vector=False)
    assert Ms.shape[0] * mesh.p.shape[0] == M.shape[0]


def test_lumped_mass(case):
    mesh, element, _ = case
    dim = mesh.p.shape[0]
    consistent = mass_matrix(mesh, rho=2.0, lumped=False, element=element)
    lumped = mass_matrix(mesh, rho=2.0, lumped=True, element=element).diagonal()
    total = 2.0 * element_volumes(mesh).sum() * dim
    assert lumped.sum() == pytest.approx(total, rel=1e-13)
    assert lumped.min() > 0
    if element == "P1":
        np.testing.assert_allclose(lumped, np.asarray(consistent.sum(axis=1)).ravel(), rtol=1e-13)
    else:
        # P2 row sums are not positive at vertices, which is why P2 uses HRZ lumping
        assert np.asarray(consistent.sum(axis=1)).min() <= 1e-15


def test_jacobian_of_rest_is_identity_and_affine_maps_are_exact(case):
    mesh, element, _ = case
    dim = mesh.p.shape[0]
    J = deformation_jacobian(mesh, element)
    x = node_positions(mesh, element)
    F = (J @ x.ravel()).reshape(-1, dim, dim)
    np.testing.assert_allclose(F, np.broadcast_to(np.eye(dim), F.shape), atol=1e-12)
    A = np.random.default_rng(3).standard_normal((dim, dim))
    b = np.arange(dim) + 0.5
    F = (J @ (x @ A.T + b).ravel()).reshape(-1, dim, dim)
    np.testing.assert_allclose(F, np.broadcast_to(A, F.shape), atol=1e-11)


def test_volumes_equal_scikit_fem_measure():
    for mesh in (caterpillar(nx=20, ny=10), creature(cell=0.2)):
        vol = element_volumes(mesh)
        np.testing.assert_allclose(vol, scalar_basis(mesh, "P2", intorder=2).dx.sum(axis=1), rtol=1e-13)
        np.testing.assert_allclose(quadrature_volumes(mesh, "P1")[:, 0], vol, rtol=1e-13)


def test_gravity_force_sums_to_weight():
    mesh = box3d(3, 2, 2, (3.0, 2.0, 2.0))
    f = gravity_force(mesh, [0.0, 0.0, -9.8], rho=1e3).reshape(-1, 3)
    np.testing.assert_allclose(f.sum(axis=0), [0.0, 0.0, -9.8 * 1e3 * 12.0], rtol=1e-13)
    M = mass_matrix(mesh, rho=1e3)
    np.testing.assert_allclose(f.ravel(), M @ np.tile([0.0, 0.0, -9.8], mesh.p.shape[1]), rtol=1e-13)
    with pytest.raises(ValueError, match="gravity must be a finite vector of length 3"):
        gravity_force(mesh, [0.0, -9.8])


def test_stiffness_kernel_is_the_rigid_motions():
    mesh = beam2d(4.0, 1.0, 8, 2)
    K = stiffness_matrix(mesh, mu=1.0, lam=2.0)
    x, y = mesh.p
    rotation = np.column_stack([-y, x]).ravel()
    translation = np.column_stack([np.ones_like(x), np.zeros_like(x)]).ravel()
    assert abs(K @ rotation).max() < 1e-12
    assert abs(K @ translation).max() < 1e-12
    stretch = np.column_stack([x, np.zeros_like(x)]).ravel()
    # a uniform stretch eps_xx = 1 stores energy (2 mu + lam)/2 * area
    assert stretch @ K @ stretch / 2 == pytest.approx((2 * 1.0 + 2.0) / 2 * 4.0, rel=1e-12)


def test_lame_parameters():
    mu, lam = lame_parameters(1e6, 0.3)
    assert mu == pytest.approx(1e6 / 2.6)
    assert lam == pytest.approx(1e6 * 0.3 / (1.3 * 0.4))
    with pytest.raises(ValueError, match="Poisson's ratio must be in"):
        lame_parameters(1.0, 0.5)
    with pytest.raises(ValueError, match="Young's modulus must be positive"):
        lame_parameters(-1.0, 0.3)


def test_material_checks_name_the_parameter():
    mesh = beam2d(1.0, 1.0, 2, 2)
    with pytest.raises(ValueError, match="mu must be positive, got -1.0"):
        stiffness_matrix(mesh, mu=-1.0)
    with pytest.raises(ValueError, match=r"rho must be a scalar or have shape \(8,\)"):
        mass_matrix(mesh, rho=np.ones(3))
    with pytest.raises(ValueError, match="rho must be positive, got 0.0 at elements"):
        mass_matrix(mesh, rho=np.r_[np.ones(7), 0.0])
    with pytest.raises(ValueError, match="element must be one of"):
        stiffness_matrix(mesh, element="P3")


@pytest.mark.parametrize("dim", [2, 3])
def test_a_negative_poissons_ratio_is_a_material_with_a_negative_lam(dim):
    # nu = -0.5 (auxetic) gives lam = -E/2 < 0, a positive bulk modulus: it was refused ("lam must be
    # non-negative"), naming a parameter the user never gave
    from skfem_modal import beam3d, linear_modal_analysis

    mesh = beam2d(4.0, 1.0, 8, 2) if dim == 2 else beam3d(4.0, 1.0, 1.0, 8, 2, 2)
    mu, lam = lame_parameters(1e5, -0.5)
    assert lam == pytest.approx(-1e5 / 2)
    K = stiffness_matrix(mesh, mu=mu, lam=lam)
    assert np.linalg.eigvalsh(K.toarray()).min() > -1e-9 * abs(K).max()  # positive semi-definite
    values, _ = linear_modal_analysis(mesh, 3 * (dim - 1) + 2, mu=mu, lam=lam)
    assert values[-1] > 0
    # below the bound the bulk modulus is negative: named, with the bound
    with pytest.raises(ValueError, match=rf"lam must be above -2 mu / {dim} \(a positive bulk modulus"):
        stiffness_matrix(mesh, mu=1.0, lam=-1.0)


@pytest.mark.parametrize("flags", [dict(lumped=None), dict(lumped="yes"), dict(vector="no")])
def test_mass_matrix_flags_are_true_or_false(flags):
    # read by truthiness before: lumped=None gave the consistent matrix, vector="no" the vector one
    with pytest.raises(TypeError, match=r"(lumped|vector) must be True or False, got"):
        mass_matrix(beam2d(1.0, 1.0, 2, 2), **flags)
