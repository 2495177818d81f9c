"""ModalMuscle: the reduced modal-muscle simulator.

Positions are ``x = B z``. One time step of length ``h`` minimises, over the
next ``z``, the energy

    E(z) = |z - y|^2_{B^T M B} / (2 h^2)                     inertia (implicit Euler), y = z0 + h v0
         + sum_e mu vol_e / 2 |F_e(z) - R_c(e)|^2             passive ARAP, one rotation per cluster
         + sum_e gamma vol_e / 2 |F_e(z) - R_a(e) Y_e(a)|^2   muscles: the clustered plastic-stretch target
         - z^T B^T f_g                                        gravity

by block-coordinate descent: the *local* step sets every cluster rotation to
the closest rotation of its weighted gradient sum (a polar decomposition), the
*global* step solves ``H z = BMB y / h^2 + A(a)^T vec(R) + B^T f_g`` with the
constant ``H`` (factored once). Ground contact, when present, projects each
global solution (see :mod:`skfem_modal.contact`); it is the only effect that
can break the monotone decrease of ``E``.

Only the effects a simulator is given are built and stepped: a floating body
has no contact or gravity operators and its step never calls contact code.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.linalg as sla

from . import _accel
from ._fast import dot
from ._kron3 import KroneckerStep3
from ._step2 import NumpyStep2
from .contact import GroundContact
from .fem import _gravity, _jacobian, _mass, _positive, scalar_basis, vector_dofs
from .mesh import _signed_measures, boundary_vertices, check_mesh, sample_boundary, validated
from .muscles import cluster_sum_operator, muscle_target_constants, muscle_target_operator
from .rotations import (
    HORN,
    HORN_SHIFTED,
    QQ_TO_R_TRACE,
    QUAT_TO_R,
    ROT2,
    SHIFT,
    certify_dominant,
    dominant_quaternions,
    rotations2_flat,
    rotations3_flat,
    squarings_for,
)
from .subspace import com_operator, mass_orthonormalize, project, skinning_eigenmodes
from .threads import limited_blas_threads

__all__ = ["ModalMuscle", "SimulationError", "muscle_modes"]


class SimulationError(RuntimeError):
    """The simulation went non-finite; ``step`` is the step number when known."""

    def __init__(self, message: str, step: int | None = None):
        super().__init__(message if step is None else f"step {step}: {message}")
        self.step = step


def _array(value, shape, name, *, dtype=np.float64):
    arr = np.asarray(value)
    if not np.issubdtype(arr.dtype, np.number):
        raise TypeError(f"{name} must be numeric, got dtype {arr.dtype}")
    arr = arr.astype(dtype, copy=False)
    if arr.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    return arr


def _positive_scalar(value, name, *, allow_zero=False):
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a number, got {value!r}") from None
    if not np.isfinite(v) or (v < 0 if allow_zero else v <= 0):
        raise ValueError(f"{name} must be {'non-negative' if allow_zero else 'positive'} and finite, got {value!r}")
    return v


def _labels(value, nT, name):
    arr = np.asarray(value)
    if arr.shape != (nT,):
        raise ValueError(f"{name} must have one label per element, shape ({nT},), got {arr.shape}")
    if arr.size and not np.issubdtype(arr.dtype, np.integer):
        if np.issubdtype(arr.dtype, np.floating) and np.all(arr == np.round(arr)):
            arr = arr.astype(np.int64)
        else:
            raise TypeError(f"{name} must be integers, got dtype {arr.dtype}")
    if arr.min() < 0:
        raise ValueError(f"{name} must be non-negative, got {arr.min()}")
    return arr.astype(np.int64)


def muscle_modes(mesh, n_muscles: int, *, mu=1.0, lam=None, rho=1.0, pinned=None, signs=None) -> np.ndarray:
    """The muscles of a body: its lowest linear modes without the rigid ones.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    n_muscles : int
    mu, lam, rho : float or ndarray of shape (nT,)
        Material of the modal analysis (``lam`` defaults to ``mu``).
    pinned : array_like of int, optional
        Clamped vertices: then the modes of the clamped body (no rigid ones).
    signs : array_like of +1 / -1, shape (n_muscles,), optional
        Flip muscles (the modes' own signs follow
        :func:`~skfem_modal.eigen.sign_convention`).

    Returns
    -------
    D : ndarray, shape (n * dim, n_muscles)
    """
    from .modal import linear_modal_analysis, rigid_mode_count

    if not n_muscles:
        return np.zeros((mesh.p.size, 0))
    n_rigid = rigid_mode_count(mesh, pinned)
    _, found = linear_modal_analysis(
        mesh, n_rigid + n_muscles, mu=mu, lam=mu if lam is None else lam, rho=rho, fixed=pinned
    )
    D = found[:, n_rigid:]
    return D if signs is None else D * np.asarray(signs, dtype=np.float64)


class _MatrixSolve:
    """``X -> H^{-1} X`` with a precomputed dense inverse (picklable, unlike a lambda)."""

    def __init__(self, H_inv: np.ndarray):
        self.H_inv = H_inv

    def __call__(self, X: np.ndarray) -> np.ndarray:
        return self.H_inv @ X


def _muscle_modes(D, N: int) -> np.ndarray:
    """Muscle modes as a checked (N, m) array."""
    if D is None:
        return np.zeros((N, 0))
    D = np.asarray(D, dtype=np.float64)
    if D.ndim == 1:
        D = D[:, None]
    if D.ndim != 2 or D.shape[0] != N:
        raise ValueError(f"D must have shape ({N}, m) for this mesh, got {D.shape}")
    if not np.all(np.isfinite(D)):
        raise ValueError("D must be finite")
    return D


def _p1_gradients(mesh) -> np.ndarray:
    """P1 basis gradients per element, shape (dim + 1, dim, nT)."""
    basis = scalar_basis(mesh, "P1")
    return np.stack([phi[0].grad[..., 0] for phi in basis.basis])


def _laplacian_hessian(mesh, grads, weights, B) -> np.ndarray:
    """``B^T J^T diag(w) J B`` as ``sum_i B_i^T L_w B_i`` (``L_w`` the weighted scalar Laplacian)."""
    import scipy.sparse as sps

    dim, n = mesh.p.shape
    t = mesh.t
    # L_w[a, b] = sum_e w_e grad(phi_a) . grad(phi_b)
    vals = np.einsum("ake,bke->abe", grads, grads) * weights
    rows = np.broadcast_to(t[:, None, :], vals.shape).ravel()
    cols = np.broadcast_to(t[None, :, :], vals.shape).ravel()
    L = sps.csr_matrix((vals.ravel(), (rows, cols)), shape=(n, n))
    Bv = B.reshape(n, dim, -1)
    r = B.shape[1]
    H = np.zeros((r, r))
    # a few columns at a time: the temporaries stay near 16 MB on any mesh
    width = max(1, int(1e6 // max(n, 1)))
    for i in range(dim):
        for start in range(0, r, width):
            block = np.ascontiguousarray(Bv[:, i, start : start + width])
            H[:, start : start + width] += Bv[:, i].T @ (L @ block)
    return (H + H.T) / 2


def _gram(B, weights) -> np.ndarray:
    """``B^T diag(w) B``, a few rows at a time (no copy of ``B``)."""
    N, r = B.shape
    out = np.zeros((r, r))
    rows = max(1, int(2e6 // max(r, 1)))
    for start in range(0, N, rows):
        Bc = B[start : start + rows]
        out += (Bc * weights[start : start + rows, None]).T @ Bc
    return (out + out.T) / 2


def _through(TJ, B) -> np.ndarray:
    """``TJ @ B`` for a sparse ``TJ`` with few rows.

    Densified a few rows at a time (a dense product is twice as fast as the
    sparse one here), so the dense copy stays near 16 MB on any mesh.
    """
    TJ = TJ.tocsr()
    rows, N = TJ.shape
    out = np.empty((rows, B.shape[1]))
    chunk = max(1, int(2e6 // max(N, 1)))
    for start in range(0, rows, chunk):
        out[start : start + chunk] = TJ[start : start + chunk].toarray() @ B
    return out


class ModalMuscle:
    """Reduced modal-muscle dynamics in a subspace, in 2D or 3D.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
        Rest shape.
    B : ndarray, shape (n * dim, r)
        Subspace: positions are ``B @ z``. It must contain the rest pose (a
        skinning basis does).
    D : ndarray, shape (n * dim, m), or None
        Muscle modes (displacements, without the rest pose: the rest pose is
        added here). ``None`` or ``m = 0``: no muscles.
    labels : ndarray of int, shape (nT,)
        Passive rotation cluster of each element.
    mu : float or ndarray of shape (nT,)
        Passive (ARAP) stiffness.
    gamma : float or ndarray of shape (nT,)
        Muscle stiffness.
    rho : float or ndarray of shape (nT,)
        Density (lumped mass).
    h : float
        Time step.
    active_labels : ndarray of int, shape (nT,), optional
        Muscle rotation cluster of each element; default one cluster.
    gravity : array_like, shape (dim,), optional
        Gravitational acceleration; ``None``: no gravity.
    contact_vertices : array_like of int, optional
        Vertices that touch the ground (default with a ground: all boundary vertices).
    ground : float, optional
        Height of the ground plane along ``up``; ``None``: no ground.
    up : int, optional
        Index of the up axis (default: the last).
    stickiness : float
        In [0, 1]: 1 removes the tangential velocity of contacting points (the
        reference behaviour), 0 lets them slide freely.
    push_out : float
        In [0, 1]: fraction of a contact point's penetration undone per step (0:
        none, the reference behaviour).
    pinned : array_like of int, optional
        Vertices held at their rest positions by stiff springs
        ``pin_stiffness / 2 |x_i - X_i|^2`` (in the subspace a pin is as exact
        as the basis allows).
    pin_stiffness : float, optional
        Spring stiffness; default 1e3 times the larger of the mean passive
        stiffness and the mean vertex mass over ``h^2`` per DOF.
    damping_mass, damping_stiffness : float
        Rayleigh damping: the dissipation ``(z - z0)^T (alpha BMB + beta H) (z - z0) / 2h``
        with ``alpha = damping_mass`` (1/time, damps all motion, like drag)
        and ``beta = damping_stiffness`` (time, damps deformation; ``H`` the
        passive Hessian at rest).
    max_iter : int
        Local/global iterations per step, at most.
    tol : float
        Stop when ``|z_k - z_{k-1}| < tol`` (the reference rule); 0 runs
        exactly ``max_iter`` iterations.
    rtol : float
        Also stop when ``|z_k - z_{k-1}| <= rtol |z_k - z_start|``: the last
        change is small compared with this step's motion. 0 disables.
    accelerator : {"auto", "numpy", "numba"}
        The per-iteration rotations in numpy, or compiled with numba (the
        ``fast`` extra; same method, same results to round-off). ``auto``
        uses numba when it is installed.

    Attributes
    ----------
    iterations : int
        Local/global iterations of the last step.
    effects : tuple of str
        The effects this simulator holds and steps.
    timings : dict
        Seconds spent in each precompute stage.
    ceilings : ndarray, shape (m,)
        Amplitude ceilings of the muscles (``max_s = 2``).
    """

    def __init__(
        self,
        mesh,
        B,
        D,
        labels,
        *,
        mu,
        gamma,
        rho,
        h,
        active_labels=None,
        gravity=None,
        contact_vertices=None,
        ground=None,
        up=None,
        stickiness=1.0,
        push_out=0.0,
        pinned=None,
        pin_stiffness=None,
        damping_mass=0.0,
        damping_stiffness=0.0,
        max_iter=10,
        tol=1e-6,
        rtol=0.0,
        accelerator="auto",
    ):
        clock = time.perf_counter()
        check_mesh(mesh)
        dim, n = mesh.p.shape
        nT = mesh.t.shape[1]
        N = n * dim
        B = np.asarray(B, dtype=np.float64)
        if B.ndim != 2 or B.shape[0] != N or B.shape[1] < 1:
            raise ValueError(f"B must have shape ({N}, r) for this mesh, got {B.shape}")
        if not np.all(np.isfinite(B)):
            raise ValueError("B must be finite")
        r = B.shape[1]
        # D may be a callable that produces the modes: it is called once the
        # passive operators are built, so an expensive modal analysis can
        # run meanwhile (from_mesh does that)
        pending = D if callable(D) else None
        if pending is None:
            D = _muscle_modes(D, N)
        labels = _labels(labels, nT, "labels")
        active_labels = np.zeros(nT, np.int64) if active_labels is None else _labels(active_labels, nT, "active_labels")
        self.h = _positive_scalar(h, "h")
        if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 1:
            raise ValueError(f"max_iter must be a positive integer, got {max_iter!r}")
        self.max_iter = int(max_iter)
        self._tol2 = _positive_scalar(tol, "tol", allow_zero=True) ** 2
        self.rtol = _positive_scalar(rtol, "rtol", allow_zero=True)
        if accelerator not in ("auto", "numpy", "numba"):
            raise ValueError(f"accelerator must be 'auto', 'numpy' or 'numba', got {accelerator!r}")
        if accelerator == "numba" and not _accel.AVAILABLE:
            raise ValueError("accelerator='numba' needs numba: pip install 'skfem_modal[fast]'")
        self.accelerator = "numba" if accelerator != "numpy" and _accel.AVAILABLE else "numpy"
        self._accel = None  # the compiled kernels, loaded at the first step
        up = dim - 1 if up is None else up
        if isinstance(up, bool) or not isinstance(up, (int, np.integer)) or not 0 <= up < dim:
            raise ValueError(f"up must be an axis index in 0..{dim - 1}, got {up!r}")
        self.up = int(up)
        stickiness = _positive_scalar(stickiness, "stickiness", allow_zero=True)
        push_out = _positive_scalar(push_out, "push_out", allow_zero=True)
        if stickiness > 1 or push_out > 1:
            raise ValueError(f"stickiness and push_out must be in [0, 1], got {stickiness} and {push_out}")
        damping_mass = _positive_scalar(damping_mass, "damping_mass", allow_zero=True)
        damping_stiffness = _positive_scalar(damping_stiffness, "damping_stiffness", allow_zero=True)
        if pinned is not None:
            pinned = np.unique(np.asarray(pinned))
            if pinned.size == 0 or not np.issubdtype(pinned.dtype, np.integer):
                raise ValueError("pinned must be a non-empty array of vertex indices")
            if pinned[0] < 0 or pinned[-1] >= n:
                raise ValueError(f"pinned vertex indices must be in 0..{n - 1}")
        if pin_stiffness is not None:
            pin_stiffness = _positive_scalar(pin_stiffness, "pin_stiffness")
        if gravity is not None:
            gravity = _array(gravity, (dim,), "gravity")
        if ground is not None:
            ground = float(_array(ground, (), "ground"))
        if contact_vertices is not None and ground is None:
            raise ValueError("contact_vertices need a ground height (ground=...)")
        vol = np.abs(_signed_measures(mesh.p, mesh.t))
        w_mu = _positive(mu, nT, "mu") * vol
        w_gamma = _positive(gamma, nT, "gamma", allow_zero=True) * vol
        rho_e = _positive(rho, nT, "rho")
        self.mesh, self.B = mesh, B
        self.dim = dim
        self.labels, self.active_labels = labels, active_labels
        self.timings = {"validate": time.perf_counter() - clock}

        clock = time.perf_counter()
        J = _jacobian(mesh, "P1")
        M = _mass(mesh, rho_e, True, "P1", True)
        self._M = M
        self.BMB = _gram(B, M.diagonal())  # M is lumped: diagonal
        self.timings["mass"] = time.perf_counter() - clock

        # passive ARAP: cluster sums of mu vol F, and its Hessian B^T J^T (mu vol) J B
        clock = time.perf_counter()
        dd = dim * dim
        # cluster sums of w F (passive rotations, muscle targets): sparse maps
        # of vec(F), taken through J and B; and the Hessians B^T J^T w J B,
        # which are B^T (L_w x I) B for the w-weighted scalar Laplacian L_w
        grads = _p1_gradients(mesh)
        Gp = _through(cluster_sum_operator(labels, w_mu, dim) @ J, B)
        H_el = _laplacian_hessian(mesh, grads, w_mu, B)
        if pending is not None:
            wait = time.perf_counter()
            D = _muscle_modes(pending(), N)
            self.timings["waiting_for_muscles"] = time.perf_counter() - wait
        m = D.shape[1]
        self.D = D
        self.dim, self.n_muscles = dim, m
        products = [Gp]
        if m:
            products.append(_through(muscle_target_operator(J, D, active_labels, w_gamma, dim) @ J, B))
        self.timings["reduced operators"] = time.perf_counter() - clock

        clock = time.perf_counter()
        if m:
            self._A = products[1].reshape(m + 1, -1, r)
            self._H_act = _laplacian_hessian(mesh, grads, w_gamma, B)
            self._active_consts = muscle_target_constants(J, D, w_gamma, dim)
            JD = (J @ D).reshape(nT, dd, m)
            largest = np.sqrt((JD**2).sum(axis=1)).max(axis=0)
            with np.errstate(divide="ignore"):
                self.ceilings = np.where(largest > 0, 2.0 / np.where(largest > 0, largest, 1.0), np.inf)
            DM = D.T @ M
            self._amp_scale = 1.0 / np.einsum("mi,im->m", DM, D)
            self._amp_B = (DM @ B) * self._amp_scale[:, None]
            self._amp_rest = (DM @ mesh.p.T.ravel()) * self._amp_scale
        else:
            self._A = np.zeros((0, 0, r))
            self._H_act = np.zeros((r, r))
            self.ceilings = np.zeros(0)
        self.timings["muscles"] = time.perf_counter() - clock

        clock = time.perf_counter()
        h = self.h
        H = H_el + self._H_act + self.BMB / h**2
        # constant extra terms: pins (springs to rest) and Rayleigh damping
        self._pin_rhs = np.zeros(r)
        self._pin_H = np.zeros((r, r))
        self.pinned = np.zeros(0, np.int64) if pinned is None else pinned
        if pinned is not None:
            if pin_stiffness is None:
                # mean diagonal of the passive Hessian J^T W J, per DOF
                row_norms = np.asarray(J.multiply(J).sum(axis=1)).ravel()
                passive_diag = float(np.repeat(w_mu, dd) @ row_norms) / N
                mass_diag = float(M.diagonal().mean()) / h**2
                pin_stiffness = 1e3 * max(passive_diag, mass_diag)
            Bs = B[vector_dofs(pinned, dim)]
            self._pin_H = pin_stiffness * (Bs.T @ Bs)
            self._pin_rhs = pin_stiffness * (Bs.T @ mesh.p.T[pinned].ravel())
            self._pin_const = 0.5 * pin_stiffness * float((mesh.p.T[pinned] ** 2).sum())
            H = H + self._pin_H
        self.pin_stiffness = pin_stiffness
        self._damping = damping_mass * self.BMB + damping_stiffness * H_el
        self.damping_mass, self.damping_stiffness = damping_mass, damping_stiffness
        damped = bool(damping_mass or damping_stiffness)
        if damped:
            H = H + self._damping / h
        H = (H + H.T) / 2
        try:
            chol = sla.cho_factor(H)
        except np.linalg.LinAlgError:
            raise ValueError(
                "the reduced system matrix is not positive definite: check that B has full column rank"
            ) from None
        H_inv = sla.cho_solve(chol, np.eye(r))
        self._H_el = H_el
        self._H_inv = H_inv
        # the start-of-step part of the right-hand side: c = P_z z + P_v z_dot + c_ext
        self._K_inertia = H_inv @ self.BMB / h**2
        self._P_z = H_inv @ (self.BMB / h**2 + self._damping / h) if damped else None
        self._P_v = H_inv @ self.BMB / h if damped else None
        nc = Gp.shape[0] // dd
        na = self._A.shape[1] // dd if m else 0
        self.n_clusters, self.n_active_clusters = nc, na
        # G stacks the passive and active cluster operators; W = H^-1 G^T
        self._G = np.empty(((nc + na) * dd, r))
        self._G[: nc * dd] = Gp
        self._W = np.empty((r, (nc + na) * dd))
        self._W[:, : nc * dd] = H_inv @ Gp.T
        if m:
            self._WA = np.einsum("rs,kcs->krc", H_inv, self._A)
            self._G[nc * dd :] = self._A[0]
            self._W[:, nc * dd :] = self._WA[0]
        if dim == 2:
            # The 2D step works on the rotation *features* (c, s) = (F00 + F11,
            # F10 - F01), linear in F, and R is linear in (c, s): folding both
            # maps into G and W saves two products per iteration. (In 3D,
            # Horn's 16 entries would make the products larger than F's 9.)
            self._Gf = self._to_features(self._G)
            self._Wf = self._to_rotations(self._W)
            if m:
                self._Af = np.stack([self._to_features(Ak) for Ak in self._A])
                self._WAf = np.stack([self._to_rotations(Wk) for Wk in self._WA])
        self._q = None  # 3D, compiled: the last quaternions, a warm start for the next ones
        # 3D, numpy: each cluster's power-method shift and the squarings, both
        # from the last step's matrices
        self._shift = None
        self._squarings = 4
        self._batched = self.max_iter  # iterations of the last 2D step (see _step2)
        self._rest_const = 0.5 * dim * float(w_mu.sum())
        self.timings["factor"] = time.perf_counter() - clock

        clock = time.perf_counter()
        effects = ["elasticity", "inertia"]
        if m:
            effects.append("muscles")
        self._f_ext = np.zeros(r)
        if gravity is not None:
            self._f_ext = B.T @ _gravity(mesh, gravity, rho_e)
            effects.append("gravity")
        if pinned is not None:
            effects.append("pinned")
        if damped:
            effects.append("damping")
        self._c_ext = H_inv @ (self._f_ext + self._pin_rhs)
        self.gravity = gravity
        self._contact = None
        self.ground = ground
        self.contact_vertices = np.zeros(0, np.int64)
        if ground is not None:
            if contact_vertices is None:
                cv = boundary_vertices(mesh)
            else:
                cv = np.asarray(contact_vertices)
                if cv.size == 0 or not np.issubdtype(cv.dtype, np.integer):
                    raise ValueError("contact_vertices must be a non-empty array of vertex indices")
                cv = np.unique(cv)
                if cv[0] < 0 or cv[-1] >= n:
                    raise ValueError(f"contact_vertices must be in 0..{n - 1}")
            self.contact_vertices = cv
            self._contact = GroundContact(
                B[vector_dofs(cv, dim)], _MatrixSolve(H_inv), self.h, dim, self.up, ground, stickiness, push_out
            )
            effects.append("contact")
        self.stickiness, self.push_out = stickiness, push_out
        # the operators the step uses: rotation features in 2D, F itself in 3D
        # (Horn's matrix has 16 entries to F's 9: the products are cheaper in F)
        if dim == 3:
            G_step, W_step, A_step, WA_step = self._G, self._W.copy(), self._A, self._WA
            if self.accelerator == "numpy":
                rest_scale = self._rest_scale(nc + na)
                G_step, A_step = self._shifted_operators(nc, na, rest_scale)
        else:
            G_step, W_step = self._Gf, self._Wf
            A_step, WA_step = (self._Af, self._WAf) if m else (None, None)
        if self._contact is not None:
            # the global solve also yields the contact positions: stack their rows
            Je = self._contact.Je
            W_step = np.vstack([W_step, Je @ W_step])
            if m:
                WA_step = np.concatenate([WA_step, np.einsum("pr,krc->kpc", Je, WA_step)], axis=1)
        self._step_ops = (A_step, WA_step, np.ascontiguousarray(G_step), np.ascontiguousarray(W_step))
        self._activation_views = {}
        # 2D, numpy or with contact: the iterations on buffers made once (see
        # _step2); its W (with the step's constant as one more column) is the
        # one the muscle columns are written into. (With numba and no
        # contact one compiled call runs all iterations instead.)
        self._step2 = None
        if dim == 2 and (self.accelerator == "numpy" or self._contact is not None):
            Pz = self._K_inertia if self._P_z is None else self._P_z
            Pv = h * self._K_inertia if self._P_v is None else self._P_v
            C_operator = np.hstack([Pz, Pv, self._c_ext[:, None]])
            if self._contact is not None:
                C_operator = np.vstack([C_operator, self._contact.Je @ C_operator])
            self._step2 = NumpyStep2(self._step_ops[2], self._step_ops[3], C_operator, self.max_iter)
            self._step_ops = self._step_ops[:3] + (self._step2.W,)
        # 3D, numpy, no contact: the step in Kronecker form when the subspace
        # moves x, y and z alike (skinning bases do); None otherwise
        self._kron = None
        if dim == 3 and self.accelerator == "numpy" and self._contact is None:
            Pz = self._K_inertia if self._P_z is None else self._P_z
            Pv = h * self._K_inertia if self._P_v is None else self._P_v
            self._kron = KroneckerStep3.build(
                self._G,
                self._W,
                self._A if m else None,
                self._WA if m else None,
                Pz,
                Pv,
                self._c_ext,
                rest_scale,
                na,
                self.max_iter,
            )
        self.effects = tuple(effects)
        self._com = com_operator(mesh, B, rho_e)
        self._rotations = rotations2_flat if dim == 2 else rotations3_flat
        self.iterations = 0
        self._state_shape = (self.B.shape[1],)
        self.timings["effects"] = time.perf_counter() - clock

    @property
    def tol(self) -> float:
        """Absolute stopping tolerance on the change of ``z`` between iterations."""
        return float(np.sqrt(self._tol2))

    @tol.setter
    def tol(self, value) -> None:
        self._tol2 = _positive_scalar(value, "tol", allow_zero=True) ** 2

    def _shifted_operators(self, nc: int, na: int, w: np.ndarray):
        """3D, numpy: cluster operators that give ``(F / w, s)`` per cluster.

        ``w`` is the cluster's ``|F|`` at rest (so entries stay near 1 and
        powers of Horn's matrix neither overflow nor underflow), ``s`` the
        power method's shift, fed by a trailing 1 appended to ``z`` (its
        entries are written each step). Returns ``G`` (clusters x 10, r + 1)
        and the muscle operators ``A`` (m + 1, active clusters x 10, r + 1).
        """
        r = self.B.shape[1]
        n = nc + na
        G = np.zeros((n, 10, r + 1))
        G[:, :9, :r] = self._G.reshape(n, 9, r) / w[:, None, None]
        m = self.n_muscles
        A = None
        if m:
            A = np.zeros((m + 1, na, 10, r + 1))
            A[:, :, :9, :r] = self._A.reshape(m + 1, na, 9, r) / w[nc:, None, None]
            A = A.reshape(m + 1, na * 10, r + 1)
        return G.reshape(n * 10, r + 1), A

    def _rest_scale(self, n: int) -> np.ndarray:
        """3D: each cluster's ``|F|`` at rest (1 where it is 0), shape (n,)."""
        rest = (self._G @ project(self.mesh.p.T, self.B, self._M)).reshape(n, 9)
        w = np.sqrt(np.einsum("ij,ij->i", rest, rest))
        return np.where(w > 0.0, w, 1.0)

    def _to_features(self, G: np.ndarray) -> np.ndarray:
        """Cluster rows of ``F`` (dd each) -> rows of features (nf each)."""
        blocks = G.reshape(-1, 4, G.shape[-1])
        return np.einsum("fj,kjr->kfr", ROT2, blocks).reshape(-1, G.shape[-1])

    def _to_rotations(self, W: np.ndarray) -> np.ndarray:
        """Cluster columns acting on ``vec(R)`` -> columns acting on rotation parameters."""
        blocks = W.reshape(W.shape[0], -1, 4)
        return np.einsum("rkj,pj->rkp", blocks, ROT2).reshape(W.shape[0], -1)

    # ------------------------------------------------------------------ state
    def rest_state(self):
        """The rest state: ``(z, z_dot, a)``.

        Returns
        -------
        z : ndarray, shape (r,)
            Mass-weighted projection of the rest positions onto ``B``.
        z_dot : ndarray, shape (r,)
            Zeros.
        a : ndarray, shape (m,)
            Zero activation, one value per muscle.
        """
        z = project(self.mesh.p.T, self.B, self._M)
        return z, np.zeros_like(z), np.zeros(self.n_muscles)

    def positions(self, z) -> np.ndarray:
        """Vertex positions of a reduced state, shape (n, dim)."""
        return (self.B @ np.asarray(z, float)).reshape(-1, self.dim)

    def com(self, z) -> np.ndarray:
        """Centre of mass of a reduced state, shape (dim,), read straight from ``z``."""
        return self._com @ np.asarray(z, float)

    def muscle_amplitudes(self, z) -> np.ndarray:
        """Realised modal amplitudes: the mass-weighted projection of ``B z - X`` on each muscle.

        Returns
        -------
        amplitudes : ndarray, shape (m,)
        """
        if not self.n_muscles:
            return np.zeros(0)
        return self._amp_B @ np.asarray(z, float) - self._amp_rest

    def contact_positions(self, z) -> np.ndarray:
        """Positions of the contact vertices, shape (p, dim) (empty without a ground)."""
        if self._contact is None:
            return np.zeros((0, self.dim))
        return self._contact.positions(np.asarray(z, float))

    # ------------------------------------------------------------------- step
    def _activation(self, a) -> np.ndarray:
        if self.n_muscles == 0:
            if a is not None and np.size(a):
                raise ValueError(f"this simulator has no muscles; got {np.size(a)} activations")
            return np.zeros(0)
        a = np.asarray(a, dtype=np.float64).ravel()
        if a.shape != (self.n_muscles,):
            raise ValueError(f"activation must have one value per muscle ({self.n_muscles}), got {a.size}")
        return a

    def _set_activation(self, a: np.ndarray, features: bool = True) -> None:
        """Write the muscle rows of the operators for activation ``a``."""
        if not self.n_muscles:
            return
        views = self._activation_views.get(features)
        if views is None:
            if features:
                A, WA, G, W = self._step_ops
            else:
                A, WA, G, W = self._A, self._WA, self._G, self._W
            m = A.shape[0] - 1
            rows = G.shape[0] - A.shape[1]
            cols = W.shape[1] - WA.shape[2]
            # both operators are affine in a: one product for the rows and
            # the columns together, then the constant parts
            A1 = np.hstack([A[1:].reshape(m, -1), WA[1:].reshape(m, -1)])
            product = np.empty(A1.shape[1])
            split = A[0].size
            views = (
                A1,
                product,
                product[:split].reshape(A[0].shape),
                product[split:].reshape(WA[0].shape),
                A[0].copy(),
                WA[0].copy(),
                G[rows:],
                W[:, cols:],
            )
            self._activation_views[features] = views
        A1, product, A_part, WA_part, A0, WA0, G_rows, W_cols = views
        dot(a, A1, product)
        np.add(A_part, A0, out=G_rows)
        np.add(WA_part, WA0, out=W_cols)

    def step(self, z, z_dot, a=None) -> np.ndarray:
        """Advance one time step.

        Parameters
        ----------
        z, z_dot : ndarray, shape (r,)
            Reduced position and velocity at the start of the step.
        a : ndarray, shape (m,)
            Muscle activations during the step.

        Returns
        -------
        z_next : ndarray, shape (r,)

        Raises
        ------
        SimulationError
            If the state becomes non-finite.
        """
        z = np.asarray(z, dtype=np.float64)
        z_dot = np.asarray(z_dot, dtype=np.float64)
        if z.shape != self._state_shape or z_dot.shape != self._state_shape:
            raise ValueError(f"z and z_dot must have shape {self._state_shape}, got {z.shape} and {z_dot.shape}")
        a = self._activation(a)
        # overflow in a blown-up state is reported as a SimulationError, not as warnings
        with np.errstate(over="ignore", invalid="ignore"):
            return self._advance(z, z_dot, a)

    def _advance(self, z, z_dot, a):
        """One step on validated input; returns ``z_next`` and sets ``iterations``."""
        if self._kron is not None:
            result = self._kron.step(z, z_dot, a, self._tol2, self.rtol)
            if result is not None:
                z_next, self.iterations = result
                return z_next
            # a rotation failed its certificate (or the state blew up): the
            # step is redone below, each rotation checked as it is made
        self._set_activation(a)
        if self._accel is None and self.accelerator == "numba":
            self._accel = _accel.kernels()
        if self._step2 is not None:
            unchecked = 0 if self.rtol else self._batched
            normalize = self._accel.normalize_cs if self._accel is not None else None
            result = self._step2.step(z, z_dot, self._contact, self._tol2, unchecked, self._stop, normalize)
            if result is None:
                raise SimulationError("the state became non-finite")
            z_next, self.iterations = result
            self._batched = self.iterations
            return z_next
        if self._P_z is None:
            c = self._K_inertia @ (z + self.h * z_dot) + self._c_ext
        else:
            c = self._P_z @ z + self._P_v @ z_dot + self._c_ext
        contact = self._contact
        if contact is not None:
            contact.start_step(z)
            c = np.concatenate([c, contact.Je @ c])
        if self.dim == 2:
            z_next, self.iterations = self._iterate2(c, z, contact)
        else:
            z_next, self.iterations = self._iterate3(c, z, contact)
        return z_next

    def _stop(self, change2: float, z_next, z_start) -> bool:
        """The relative stopping rule; raises on a non-finite state.

        Called when the absolute rule (``change2 < tol**2``, checked inline)
        did not stop the iterations.
        """
        if not change2 < np.inf:
            raise SimulationError("the state became non-finite")
        if self.rtol:
            motion = z_next - z_start
            return change2 <= self.rtol**2 * (motion @ motion)
        return False

    def _loop(self, c, z, contact, local):
        """Local/global iterations in Python: ``z = c + W local(z)`` until a stopping rule holds.

        ``local(z)`` returns the rotation parameters the step's ``W`` acts on
        (``vec(R)`` in 3D), flat. (The 2D steps run in :mod:`._step2`, or
        compiled.)
        """
        W = self._step_ops[3]
        tol2, r = self._tol2, z.size
        z_iter = z
        for it in range(1, self.max_iter + 1):
            y = c + W @ local(z_iter)
            if contact is not None:
                y = contact.correct(y)
            z_next = y[:r]
            diff = z_next - z_iter
            change2 = diff @ diff
            z_iter = z_next
            if change2 < tol2 or self._stop(change2, z_next, z):
                return z_iter, it
        return z_iter, self.max_iter

    def _iterate2(self, c, z, contact):
        """2D, compiled, no contact: all iterations in one call."""
        z_next, it, status = self._accel.iterate2(
            self._step_ops[2], self._step_ops[3], c, z, self.max_iter, self._tol2, self.rtol**2
        )
        if status == 2:
            raise SimulationError("the state became non-finite")
        return z_next, it

    def _iterate3(self, c, z, contact):
        if self._accel is not None:
            return self._iterate3_compiled(c, z, contact)
        # the Kronecker step hands back only the steps it could not certify
        result = None if self._kron is not None else self._iterate3_squarings(c, z, contact)
        if result is None:
            # some rotation was not certified: redo the step, each rotation checked as it is made
            result = self._iterate3_checked(c, z, contact)
        return result

    def _shift_from(self, F10: np.ndarray) -> None:
        """Each cluster's shift ``|N(F)| / (2 sqrt 2)``, from its rows ``(F / w, s)``, shape (n, 10)."""
        F9 = F10[:, :9]
        self._shift = SHIFT * 2.0 * np.sqrt(np.einsum("ij,ij->i", F9, F9))

    def _iterate3_squarings(self, c, z, contact):
        """3D iterations with uncertified rotations, certified together at the end.

        Each rotation is the top eigenvector of the shifted Horn matrix ``P``,
        read off ``P^(2^k)`` normalised by its trace (``q q^T`` up to
        ``ratio^(2^k)``), with ``k`` from the ratio of the last step's
        matrices. One batched check at the end (:func:`certify_dominant`)
        accepts all rotations of the step or none (then returns None). This
        takes a dozen numpy calls an iteration where certifying each rotation
        as it is made takes three dozen.
        """
        _, _, G, W = self._step_ops
        r = z.size
        n = G.shape[0] // 10
        z_iter = np.empty(r + 1)
        z_iter[:r] = z
        z_iter[r] = 1.0
        if self._shift is None:
            G[9::10, r] = 0.0
            self._shift_from((G @ z_iter).reshape(n, 10))
        G[9::10, r] = self._shift
        P0s = np.empty((self.max_iter, n, 16))
        Rs = np.empty((self.max_iter, n, 9))
        z_next = np.empty(r + 1)
        z_next[r] = 1.0
        tol2, squarings = self._tol2, self._squarings
        for it in range(self.max_iter):
            P = np.matmul((G @ z_iter).reshape(n, 10), HORN_SHIFTED, out=P0s[it]).reshape(n, 4, 4)
            for _ in range(squarings):
                P = P @ P
            RT = P.reshape(n, 16) @ QQ_TO_R_TRACE
            R = np.divide(RT[:, :9], RT[:, 9:], out=Rs[it])
            y = W @ R.reshape(-1)
            y += c
            if contact is not None:
                y = contact.correct(y)
            z_next[:r] = y[:r]
            diff = z_next[:r] - z_iter[:r]
            change2 = diff @ diff
            z_iter, z_next = z_next, z_iter
            if change2 < tol2:
                break
            if not change2 < np.inf:
                # an uncertified rotation may be what went wrong: the checked path decides
                self._shift = None
                return None
            if self._stop(change2, z_iter[:r], z):
                break
        k = it + 1
        ok, ratio = certify_dominant(P0s[:k].reshape(-1, 16), Rs[:k].reshape(-1, 9), squarings)
        if not ok:
            self._squarings = min(squarings + 1, 8)
            self._shift = None
            return None
        # with a margin: the matrices change from step to step, and a miss costs a redone step
        self._squarings = squarings_for(min(1.25 * ratio, 1.0))
        # the next step's shifts, from the last matrices: |N|^2 = |P|^2 - 4 s^2 (N has zero trace)
        last = P0s[it]
        self._shift = SHIFT * np.sqrt(np.maximum(np.einsum("ij,ij->i", last, last) - 4 * self._shift**2, 0.0))
        return z_iter[:r].copy(), k

    def _iterate3_checked(self, c, z, contact):
        """3D iterations, each rotation certified as it is made (the robust path)."""
        r = z.size
        G = self._step_ops[2]
        n = G.shape[0] // 10
        G_F = G[:, :r]  # without the shift column: rows give (F / w, 0), the same rotations
        state = {"q": None}

        def local(z_iter):
            F10 = (G_F @ z_iter).reshape(n, 10)
            q = state["q"] = dominant_quaternions((F10[:, :9] @ HORN).reshape(n, 4, 4), state["q"])
            state["F10"] = F10
            return ((q[:, :, None] * q[:, None, :]).reshape(n, 16) @ QUAT_TO_R).ravel()

        result = self._loop(c, z, contact, local)
        self._shift_from(state["F10"])
        return result

    def _iterate3_compiled(self, c, z, contact):
        G, W = self._step_ops[2:]
        if contact is None:
            # all iterations in one call; a rotation the kernel cannot certify
            # sends the step to the loop below, which finishes it with numpy
            warm = self._q is not None
            q = self._q.copy() if warm else np.zeros((G.shape[0] // 9, 4))
            z_next, it, status = self._accel.iterate3(G, W, c, z, q, warm, self.max_iter, self._tol2, self.rtol**2)
            if status == 2:
                raise SimulationError("the state became non-finite")
            if status == 0:
                self._q = q
                return z_next, it
        rotations3 = self._accel.rotations3

        def local(z_iter):
            R, self._q = rotations3((G @ z_iter).reshape(-1, 9), self._q)
            return R.ravel()

        return self._loop(c, z, contact, local)

    # ----------------------------------------------------------------- energy
    def energy(self, z_next, z, z_dot, a=None, gradient: bool = False):
        """The energy one step minimises, at ``z_next`` (rotations optimal).

        Contact is not part of it (it is a projection, not an energy).

        Parameters
        ----------
        z_next : ndarray, shape (r,)
            Candidate end-of-step state.
        z, z_dot : ndarray, shape (r,)
            Start-of-step state.
        a : ndarray, shape (m,)
        gradient : bool
            Also return the gradient with respect to ``z_next``.

        Returns
        -------
        E : float
        grad : ndarray, shape (r,)
            Only with ``gradient=True``.
        """
        a = self._activation(a)
        self._set_activation(a, features=False)
        x = np.asarray(z_next, float)
        y = np.asarray(z, float) + self.h * np.asarray(z_dot, float)
        S = self._G @ x
        R = self._rotations(S.reshape(-1, self.dim * self.dim)).ravel()
        d = x - y
        H_elastic = self._H_el + self._H_act + self._pin_H
        v = x - np.asarray(z, float)
        E = (
            d @ self.BMB @ d / (2 * self.h**2)
            + v @ self._damping @ v / (2 * self.h)
            + 0.5 * x @ H_elastic @ x
            - R @ S
            + self._rest_const
            - x @ (self._f_ext + self._pin_rhs)
        )
        if self.pinned.size:
            E += self._pin_const
        if self.n_muscles:
            c0, c1, Q = self._active_consts
            E += c0 + c1 @ a + a @ Q @ a
        if not gradient:
            return float(E)
        grad = (
            self.BMB @ d / self.h**2
            + self._damping @ v / self.h
            + H_elastic @ x
            - self._G.T @ R
            - self._f_ext
            - self._pin_rhs
        )
        return float(E), grad

    def mechanical_energy(self, z, z_dot) -> float:
        """Kinetic plus potential energy of a state, the muscles at rest.

        ``1/2 z_dot^T BMB z_dot`` plus the elastic energy (passive, and the
        muscles' with zero activation, rotations optimal), the pins' and the
        gravitational potential ``-z^T B^T f_g``. Without input (zero
        activation) implicit Euler, damping and contact only remove energy,
        so this does not grow over a run: the stability tests check it.

        Parameters
        ----------
        z, z_dot : ndarray, shape (r,)

        Returns
        -------
        E : float
        """
        z = np.asarray(z, float)
        v = np.asarray(z_dot, float)
        return 0.5 * float(v @ self.BMB @ v) + self.energy(z, z, np.zeros_like(z), np.zeros(self.n_muscles))

    # ------------------------------------------------------------ convenience
    @classmethod
    def from_mesh(
        cls,
        mesh,
        *,
        n_muscles: int = 4,
        muscle_signs=None,
        n_weights: int = 8,
        cluster_weights: int | None = None,
        n_clusters: int = 20,
        mu=1e5,
        gamma=None,
        lam=None,
        rho=1e3,
        h=0.02,
        gravity=None,
        ground=None,
        n_contacts: int | None = 30,
        contact_candidates=None,
        up=None,
        stickiness=1.0,
        push_out=0.0,
        pinned=None,
        pin_stiffness=None,
        damping_mass=0.0,
        damping_stiffness=0.0,
        n_active_clusters: int = 1,
        max_iter=10,
        tol=1e-6,
        rtol=0.0,
        seed: int = 0,
        progress=None,
        accelerator="auto",
        parallel: bool = True,
        blas_threads: int | None = 1,
    ):
        """Build every ingredient from a mesh and a few numbers.

        Muscles are the lowest linear modes without the rigid ones (material
        ``mu``, ``lam`` (default ``mu``), ``rho``), in the deterministic sign
        convention of :func:`~skfem_modal.linear_modal_analysis`, each
        multiplied by ``muscle_signs[k]`` (+1 or -1) if given; the subspace is
        ``n_weights`` skinning eigenmodes, mass-orthonormalised; passive
        clusters are spectral clusters of the weights (``seed``); one active
        cluster (or ``n_active_clusters`` spectral clusters), clustering
        on the first ``cluster_weights`` weights (default ``n_weights``); with a
        ``ground``, ``n_contacts`` boundary vertices by farthest-point sampling
        (all boundary vertices if ``n_contacts`` is None). With ``pinned``
        vertices the muscles are the modes of the body clamped there.
        ``progress(stage)``, if given, is called before each stage. With
        ``parallel`` the modal analysis runs in a second thread beside the
        subspace and clusters (the results do not change). Each BLAS call
        uses at most ``blas_threads`` threads meanwhile (``None``: as the
        BLAS library is set), so the two threads do not oversubscribe the
        cores (:mod:`skfem_modal.threads`).

        Returns
        -------
        sim : ModalMuscle
            With ``sim.timings`` covering these stages too.
        """
        from concurrent.futures import ThreadPoolExecutor

        from .clusters import spectral_clusters

        # arguments used late are checked before any work
        if accelerator not in ("auto", "numpy", "numba"):
            raise ValueError(f"accelerator must be 'auto', 'numpy' or 'numba', got {accelerator!r}")
        if accelerator == "numba" and not _accel.AVAILABLE:
            raise ValueError("accelerator='numba' needs numba: pip install 'skfem_modal[fast]'")
        signs = None
        if muscle_signs is not None and n_muscles:
            signs = np.asarray(muscle_signs, dtype=np.float64)
            if signs.shape != (n_muscles,) or not np.all(np.abs(signs) == 1):
                raise ValueError(f"muscle_signs must be {n_muscles} values of +1 or -1, got {muscle_signs!r}")
        say = progress or (lambda stage: None)
        timings = {}
        with limited_blas_threads(blas_threads), validated(mesh), ThreadPoolExecutor(max_workers=1) as pool:
            # scikit-fem caches mesh data on first use; build it here, before
            # the two threads read it
            scalar_basis(mesh)
            contacts = sample_boundary(mesh, n_contacts, contact_candidates) if ground is not None else None

            def modes():
                clock = time.perf_counter()
                found = muscle_modes(mesh, n_muscles, mu=mu, lam=lam, rho=rho, pinned=pinned)
                return found, time.perf_counter() - clock

            # the modal analysis (one sparse factorisation and back-solves, in
            # compiled code that releases the GIL) runs first, beside the rest
            # in a second thread when parallel: little else is in memory yet
            say("modal analysis" + (" (in a second thread)" if parallel else ""))
            modal = pool.submit(modes) if parallel else None
            found = None if parallel else modes()
            clock = time.perf_counter()
            say("skinning eigenmodes")
            k = max(n_weights, cluster_weights or n_weights)
            _, weights, B = skinning_eigenmodes(mesh, k)
            if k > n_weights:
                B = B[:, : n_weights * (mesh.p.shape[0] + 1) * mesh.p.shape[0]]
            timings["skinning_eigenmodes"] = time.perf_counter() - clock
            clock = time.perf_counter()
            say("orthonormalise")
            B = mass_orthonormalize(B, _mass(mesh, 1.0, True, "P1", True), overwrite=True)
            timings["orthonormalize"] = time.perf_counter() - clock
            clock = time.perf_counter()
            say("clusters")
            cw = weights[:, : cluster_weights or n_weights]
            labels = spectral_clusters(mesh, cw, n_clusters, seed=seed)
            active = None
            if n_active_clusters > 1:
                active = spectral_clusters(mesh, cw, n_active_clusters, seed=seed)
            timings["clusters"] = time.perf_counter() - clock

            def muscles():
                # called by the constructor once the passive operators are built
                D, timings["modal_analysis"] = modal.result() if parallel else found
                return D if signs is None else D * signs

            say("simulator set-up")
            sim = cls(
                mesh,
                B,
                muscles,
                labels,
                mu=mu,
                gamma=mu if gamma is None else gamma,
                rho=rho,
                h=h,
                active_labels=active,
                gravity=gravity,
                contact_vertices=contacts,
                ground=ground,
                up=up,
                stickiness=stickiness,
                push_out=push_out,
                pinned=pinned,
                pin_stiffness=pin_stiffness,
                damping_mass=damping_mass,
                damping_stiffness=damping_stiffness,
                max_iter=max_iter,
                tol=tol,
                rtol=rtol,
                accelerator=accelerator,
            )
        sim.timings = {**timings, **sim.timings}
        sim.weights = weights[:, :n_weights]
        return sim
