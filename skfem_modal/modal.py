"""Linear modal analysis: modes, rigid motions, sign convention, frequencies, ceilings.

The modes solve ``K d = lambda M d`` for the linear elasticity stiffness ``K``
and the mass ``M`` of :mod:`skfem_modal.fem`, with
:func:`scipy.sparse.linalg.eigsh` in shift-invert mode about a small negative
shift: a free body's ``K`` is singular, so a zero shift factors a singular
matrix, while any shift below zero keeps ``K - sigma M`` positive definite and
still targets the lowest eigenvalues.

Results are made deterministic, so they are the same on every machine and do
not depend on the element order:

* the rigid modes of a free body are the canonical rigid motions (translations
  along each axis, then rotations about the part's centroid, per connected
  part), mass-orthonormalised in that order; then the hinges (pieces of a
  part that touch at a vertex or edge turning against each other), found
  from the geometry by :mod:`skfem_modal.motions`, in a basis fixed by a
  generic weight;
* within a group of repeated eigenvalues (symmetric shapes) the basis is fixed
  by diagonalising a generic, position-dependent weight on the group;
* each mode's sign makes its largest entry positive (the lowest DOF index
  among entries within 1e-6 of the largest magnitude).
"""

from __future__ import annotations

import warnings

import numpy as np

from .eigen import eigenpairs_by_part, generic_weight, sign_convention
from .fem import (
    ELEMENTS,
    _lame,
    _mass,
    _positive,
    _stiffness,
    element_volumes,
    node_positions,
    vector_dofs,
    vertex_jacobian,
)
from .mesh import check_mesh, connected_labels, validated
from .motions import (
    _hinge_motions,
    _node_parts,
    _rigid_motions,
    fixed_nodes,
    hinge_count,
    rigid_mode_count,
    rigid_motions,
)
from .units import outside_stacklevel
from .values import is_whole, positive_number

__all__ = [
    "linear_modal_analysis",
    "rigid_motions",
    "rigid_mode_count",
    "hinge_count",
    "muscle_count_problem",
    "fixed_nodes",
    "natural_frequencies",
    "actuation_limits",
    "ceilings_of_gradients",
    "muscle_modes",
    "mode_sign_convention",
]


def mode_sign_convention(modes) -> np.ndarray:
    """Modes with deterministic signs: each column flipped so its largest entry is positive.

    :func:`skfem_modal.eigen.sign_convention`, its input checked.

    Parameters
    ----------
    modes : array_like, shape (n_dofs, k)
        One mode a column, finite.

    Returns
    -------
    modes : ndarray, shape (n_dofs, k)
        A copy with signs fixed.

    Raises
    ------
    ValueError
        Not two-dimensional (one mode is a column), or not finite.

    Examples
    --------
    >>> mode_sign_convention(np.array([[1.0, 0.5], [-2.0, 0.25]])).tolist()
    [[-1.0, 0.5], [2.0, 0.25]]
    """
    checked = np.asarray(modes, dtype=np.float64)
    if not np.isfinite(checked).all():  # (NaN came back as NaN)
        raise ValueError("modes must be finite")
    return sign_convention(checked)


def muscle_count_problem(mesh, n_muscles: int, pinned=None) -> str | None:
    """Why ``n_muscles`` muscles do not fit this mesh (a phrase after the count), or None when they do.

    The muscles are the modes after the rigid ones, so at most the free
    degrees of freedom less the rigid motions (:func:`rigid_mode_count`, per
    part and respecting the pins) fit: the rule :func:`muscle_modes` and a
    scene's ``muscles.count`` check share.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    n_muscles : int
    pinned : array_like of int, shape (k,), optional
        Clamped vertices.

    Returns
    -------
    str or None
        The phrase (to follow the count in a message), or None.

    Examples
    --------
    >>> from skfem_modal.mesh import beam2d
    >>> muscle_count_problem(beam2d(nx=2, ny=1), 4) is None
    True
    >>> muscle_count_problem(beam2d(nx=2, ny=1), 10)
    'is too many for the 12 degrees of freedom of the mesh less its 3 rigid motions: at most 9'
    """
    dim = mesh.p.shape[0]
    n_pinned = 0 if pinned is None else fixed_nodes(mesh, pinned).size
    free = dim * (mesh.p.shape[1] - n_pinned)
    n_rigid = rigid_mode_count(mesh, pinned)
    if n_muscles <= free - n_rigid:
        return None
    where = "the pins leave free" if n_pinned else "of the mesh"
    fits = free - n_rigid
    return f"is too many for the {free} degrees of freedom {where} less its {n_rigid} rigid motions: at most {fits}"


#: The mass matrix of each element's modes by default: the one its frequencies converge fastest with
#: (docs/accuracy.md: P2 with the lumped mass converges at second order, consistent at fourth)
DEFAULT_MASS = {"P1": "lumped", "P2": "consistent"}


def linear_modal_analysis(
    mesh,
    k: int,
    *,
    mu=1.0,
    lam=1.0,
    rho=1.0,
    fixed=None,
    mass: str | None = None,
    element: str = "P1",
):
    """Lowest ``k`` linear vibration modes, ``K d = lambda M d``.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    k : int
        Number of modes, including rigid ones.
    mu, lam : float or ndarray of shape (nT,)
        Lame parameters of the stiffness.
    rho : float or ndarray of shape (nT,)
        Density of the mass matrix.
    fixed : array_like of int, shape (k,), or of bool, shape (n,), optional
        Pinned vertices: their DOFs are eliminated and the modes are zero there
        (with P2, also the edge nodes between two pinned vertices).
    mass : {"lumped", "consistent"}, optional
        The mass matrix (default: :data:`DEFAULT_MASS` of the element, the one its frequencies converge
        fastest with: lumped for P1, as the simulator's; consistent for P2, whose frequencies the
        lumped mass takes from fourth order to second, 0.0016 % against 0.00014 % off on a clamped
        beam of 320 x 8 cells).
    element : {"P1", "P2"}

    Returns
    -------
    eigenvalues : ndarray, shape (k,)
        Ascending squared angular frequencies; the rigid motions, then the
        hinges, come first, with eigenvalue 0 exactly (known from the
        geometry, not computed: their ``d^T K d`` is round-off).
    modes : ndarray, shape (n_nodes * dim, k)
        Mass-orthonormal (``modes.T @ M @ modes = I``), interleaved vertex-major,
        with the deterministic signs and bases described in the module docs.

    Examples
    --------
    >>> from skfem_modal.mesh import caterpillar
    >>> vals, modes = linear_modal_analysis(caterpillar(), 7)
    >>> modes.shape
    (3438, 7)
    >>> [round(float(v), 6) for v in vals[3:]]
    [0.12494, 0.304251, 0.374627, 0.853441]
    """
    check_mesh(mesh)
    if element not in ELEMENTS:
        raise ValueError(f"element must be one of {ELEMENTS}, got {element!r}")
    mass = DEFAULT_MASS.get(element) if mass is None else mass
    if mass not in ("lumped", "consistent"):
        raise ValueError(f"mass must be 'lumped' or 'consistent', got {mass!r}")
    if not is_whole(k):
        raise TypeError(f"k must be an integer, got {type(k).__name__}")
    from .checks import _fits_float64  # here: checks imports the simulator's modules, which import this one

    _fits_float64(mesh, mu, 0.0, rho)  # the eigenvalues scale as mu / rho: no infinite or vanishing ones
    dim = mesh.p.shape[0]
    K = _stiffness(mesh, mu, lam, element)
    M = M_all = _mass(mesh, rho, mass == "lumped", element, True)
    n_dofs = K.shape[0]
    pinned = fixed_nodes(mesh, fixed, element) if fixed is not None else np.zeros(0, np.int64)
    free = np.setdiff1d(np.arange(n_dofs), vector_dofs(pinned, dim))
    if free.size == 0:
        raise ValueError(f"fixed: pins all {mesh.p.shape[1]} vertices: no degree of freedom is left free, so no mode")
    if not 1 <= k <= free.size:
        raise ValueError(f"k must be in 1..{free.size} (the number of free DOFs), got {k}")
    if free.size < n_dofs:
        K = K[free][:, free]
        M = M[free][:, free]
    Kf, Mf = K, M

    # known from the geometry, mass-orthonormal part by part: the rigid motions, then (when elastic modes
    # are asked for) the hinges; a pinned DOF's row is zero in each
    n_rigid = rigid_mode_count(mesh, fixed) if element == "P1" else _rigid_motions(mesh, fixed, element).shape[1]
    known = _rigid_motions(mesh, fixed, element, None if k > n_rigid else k, M_all)
    if k > n_rigid:
        known = np.hstack([known, _hinge_motions(mesh, fixed, element, M_all)])
    known = known[free]
    n_known = known.shape[1]
    values = np.zeros(k)  # the known motions' stay 0
    vectors = np.zeros((free.size, k))
    stop = min(n_known, k)
    vectors[:, :stop] = known[:, :stop]
    if k > n_known:
        weight = generic_weight(node_positions(mesh, element)).reshape(-1)[free]
        part_of_row = np.repeat(_node_parts(mesh, element), dim)[free]
        ev, evec = eigenpairs_by_part(Kf, Mf, known, k - n_known, weight, dim, part_of_row)
        values[n_known:], vectors[:, n_known:] = ev, evec
        _check_elastic(ev, stiffness_scale(mesh, mu, lam, rho), n_known)
    if stop > n_rigid:
        besides = (
            f"the {n_rigid} rigid motions the pins leave"
            if fixed is not None
            else f"the mesh's {n_rigid} rigid motions"
        )
        warnings.warn(
            f"{stop - n_rigid} modes have zero stiffness besides {besides}: parts joined at a single vertex or "
            f"edge act as hinges ({n_known - n_rigid} in all)",
            RuntimeWarning,
            stacklevel=2,
        )
    vectors = sign_convention(vectors)
    modes = np.zeros((n_dofs, k))
    modes[free] = vectors
    return values[:k], modes


def stiffness_scale(mesh, mu=1.0, lam=1.0, rho=1.0) -> float:
    """The scale of a mesh's highest eigenvalues: ``(2 mu + lam) / (rho l^2)``, the median over elements.

    ``l`` is an element's size (its measure to the power ``1 / dim``); ``mu``, ``lam``, ``rho``
    floats or arrays of shape (nT,). Round-off in the eigenvalues is relative to it.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    mu, lam : float or ndarray, shape (nT,)
        The Lame parameters, per element or for all.
    rho : float or ndarray, shape (nT,)
        The density, per element or for all.

    Returns
    -------
    scale : float

    Raises
    ------
    TypeError, MeshError
        A mesh that cannot be used (:func:`~skfem_modal.mesh.check_mesh`).
    ValueError
        A material that is not elastic: ``mu`` or ``rho`` not positive, or a bulk modulus
        ``lam + 2 mu / dim`` not positive (the error names the element).
    """
    volumes = element_volumes(mesh)  # (the mesh checked first)
    mu, lam = _lame(mesh, mu, lam)
    rho = _positive(rho, mesh.t.shape[1], "rho")
    size_squared = volumes ** (2.0 / mesh.p.shape[0])
    return float(np.median((2.0 * mu + lam) / (rho * size_squared)))


def _check_elastic(values, scale: float, n_known: int) -> None:
    """Refuse elastic eigenvalues negative beyond round-off (1e-12 of ``scale``, :func:`stiffness_scale`)."""
    negative = values < -1e-12 * scale
    if np.any(negative):
        i = int(np.flatnonzero(negative)[0])
        raise FloatingPointError(
            f"elastic mode {n_known + i} came out with eigenvalue {values[i]:.6g}, negative beyond round-off "
            f"(of the highest eigenvalues' scale, {scale:.6g}): the stiffness is not positive semi-definite "
            "to float64's precision"
        )


def natural_frequencies(eigenvalues) -> np.ndarray:
    """Natural frequencies in Hz, ``sqrt(lambda) / (2 pi)``.

    Negative eigenvalues give 0 (a rigid mode's round-off; :func:`linear_modal_analysis` refuses
    one negative beyond round-off, which this function has no scale to tell); NaN is refused
    (ValueError).

    Parameters
    ----------
    eigenvalues : array_like, shape (k,)

    Returns
    -------
    frequencies : ndarray, shape (k,)

    Examples
    --------
    >>> natural_frequencies([(2 * np.pi) ** 2, -1e-15]).tolist()
    [1.0, 0.0]
    """
    vals = np.asarray(eigenvalues)
    if vals.dtype.kind not in "biuf":  # (None, strings: NaN or a numpy message that names nothing)
        raise TypeError(f"eigenvalues must be numbers, got {eigenvalues!r}")
    vals = vals.astype(np.float64)
    if np.isnan(vals).any():  # would pass as a frequency (infinity is one: beyond float64)
        raise ValueError(f"eigenvalues must be numbers, got NaN at {np.flatnonzero(np.isnan(vals))[:10].tolist()}")
    return np.sqrt(np.clip(vals, 0.0, None)) / (2.0 * np.pi)


def actuation_limits(mesh, modes, max_s: float = 2.0, element: str | None = None) -> np.ndarray:
    """Per-mode amplitude ceilings for modal muscles.

    Ceiling ``a_k = max_s / max_e |J_e d_k|_F``: scaling mode ``d_k`` by
    ``a_k`` makes the largest deformation-gradient change anywhere (at an
    element's vertex, for P2) have Frobenius norm ``max_s``. Modes with no deformation (rigid translations)
    have no ceiling (``inf``).

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    modes : ndarray, shape (n_nodes * dim, m)
    max_s : float
        Largest allowed gradient change, > 0.
    element : {"P1", "P2"}, optional
        Inferred from the number of rows when omitted.

    Returns
    -------
    ceilings : ndarray, shape (m,)
    """
    check_mesh(mesh)
    max_s = positive_number(max_s, "max_s")
    D = np.asarray(modes, dtype=np.float64)
    if D.ndim == 1:
        D = D[:, None]
    dim, n = mesh.p.shape
    if element is None:
        rows = {e: node_positions(mesh, e).size for e in ELEMENTS}
        if D.ndim != 2 or D.shape[0] not in rows.values():
            shapes = " or ".join(f"({count}, m) for {e}" for e, count in rows.items())
            raise ValueError(f"modes must have shape {shapes} on this mesh, got {D.shape}")
        element = "P1" if D.shape[0] == n * dim else "P2"
    n_rows = node_positions(mesh, element).size
    if D.ndim != 2 or D.shape[0] != n_rows:
        raise ValueError(f"modes must have shape ({n_rows}, m) for {element} on this mesh, got {D.shape}")
    if not np.all(np.isfinite(D)):
        raise ValueError("modes must be finite")
    # at the vertices, where a P2 gradient peaks (at the quadrature points P2 ceilings were up to 24 % high)
    J = vertex_jacobian(mesh, element)
    ceilings = ceilings_of_gradients(J @ D, dim, max_s)
    # a translation's gradients are round-off, not a deformation (the seal's: 1e-13, a ceiling of 1.7e13):
    # below 1e-10 of the largest gradient a mode of its size could make, none
    reach = float(abs(J).sum(axis=1).max()) * np.abs(D).max(axis=0, initial=0.0)
    with np.errstate(divide="ignore"):
        ceilings[max_s / ceilings <= 1e-10 * reach] = np.inf
    return ceilings


def ceilings_of_gradients(JD, dim: int, max_s: float = 2.0) -> np.ndarray:
    """:func:`actuation_limits` from the modes' gradient changes ``JD = J @ D``.

    Parameters
    ----------
    JD : ndarray, shape (nT * nq * dim * dim, m)
    dim : int
    max_s : float

    Returns
    -------
    ceilings : ndarray, shape (m,)
        ``max_s / max_e |(J D_k)_e|_F``, ``inf`` for modes that do not deform.
    """
    largest = np.sqrt((JD.reshape(-1, dim * dim, JD.shape[1]) ** 2).sum(axis=1)).max(axis=0, initial=0.0)
    with np.errstate(divide="ignore"):
        return np.where(largest > 0, max_s / np.where(largest > 0, largest, 1.0), np.inf)


def muscle_modes(mesh, n_muscles: int, *, mu=1.0, lam=None, rho=1.0, pinned=None, signs=None) -> np.ndarray:
    """The muscles of a body: its lowest linear modes without the rigid ones.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    n_muscles : int
    mu, lam, rho : float or ndarray of shape (nT,)
        Material of the modal analysis (``lam`` defaults to ``mu``).
    pinned : array_like of int, shape (k,), optional
        Clamped vertices: then the modes of the clamped body (no rigid ones).
    signs : array_like of +1 / -1, shape (n_muscles,), optional
        Flip muscles (the modes' own signs follow
        :func:`~skfem_modal.eigen.sign_convention`).

    Returns
    -------
    D : ndarray, shape (n * dim, n_muscles)
    """
    if not is_whole(n_muscles) or n_muscles < 0:
        raise ValueError(f"n_muscles must be an integer >= 0, got {n_muscles!r}")
    with validated(mesh):  # checked here, once: the modal analysis's own check returns at once
        if not n_muscles:
            return np.zeros((mesh.p.size, 0))
        signs = muscle_signs(signs, n_muscles, "signs")
        problem = muscle_count_problem(mesh, n_muscles, pinned)
        if problem:
            raise ValueError(f"n_muscles: {n_muscles} {problem}")
        n_rigid = rigid_mode_count(mesh, pinned)
        _, found = linear_modal_analysis(
            mesh, n_rigid + n_muscles, mu=mu, lam=mu if lam is None else lam, rho=rho, fixed=pinned
        )
    D = found[:, n_rigid:]
    _warn_of_parts_without_muscles(mesh, D, rho, pinned)
    return D if signs is None else D * signs


def _warn_of_parts_without_muscles(mesh, D, rho, pinned=None) -> None:
    """Warn when a body of a mesh of several holding a tenth of its free mass or more gets no muscle.

    The muscles are the lowest modes of the whole mesh: a thin plate beside a creature took all four
    (an audit), and a gait written for the creature drove the plate. Pinned vertices are no mass a
    muscle could move (a body pinned whole is an obstacle).
    """
    parts = connected_labels(mesh)
    if parts.max() == 0 or not D.shape[1]:
        return
    dim = mesh.p.shape[0]
    mass = _mass(mesh, rho, True, "P1", False).diagonal().copy()  # (n,)
    if pinned is not None:
        mass[fixed_nodes(mesh, pinned)] = 0.0
    weight = np.bincount(parts, weights=mass) / mass.sum()
    # each muscle's share of its (mass-weighted) motion on each part
    moved = np.stack([np.bincount(parts, weights=mass * (D[a::dim] ** 2)[:, k]) for a in range(dim) for k in
                      range(D.shape[1])]).reshape(dim, D.shape[1], -1).sum(axis=0)  # fmt: skip
    share = moved / moved.sum(axis=1, keepdims=True)  # (m, parts)
    idle = np.flatnonzero((weight >= 0.1) & (share.max(axis=0) < 0.01))
    if idle.size:
        which = ", ".join(f"body {q} ({100 * weight[q]:.0f} % of the free mass)" for q in idle)
        warnings.warn(
            f"the mesh's {parts.max() + 1} bodies share its {D.shape[1]} muscles, the lowest modes of the whole "
            f"mesh, and {which} gets none of them (the softest body's modes come first): a gait moves only the "
            "others; simulate the bodies apart to give each its own muscles",
            UserWarning,
            stacklevel=outside_stacklevel(),
        )


def muscle_signs(signs, n_muscles: int, name: str = "muscle_signs"):
    """Muscles' signs checked: an array of +-1, shape (n_muscles,), or None (as the modes come).

    Parameters
    ----------
    signs : array_like of +1 / -1, shape (n_muscles,), or None
        The signs to check; None keeps the modes' own signs.
    n_muscles : int
        The number of muscles: with none, any ``signs`` give None.
    name : str
        The argument's name, for the error message.

    Returns
    -------
    signs : ndarray of float, shape (n_muscles,), or None

    Raises
    ------
    ValueError
        Not ``n_muscles`` values of +1 or -1 (``name`` says which argument).
    """
    if signs is None or not n_muscles:
        return None
    try:  # (a string, a dict or a ragged list is no array of numbers: the same message names the argument)
        values = np.asarray(signs) if not isinstance(signs, (str, dict)) else np.zeros(0)
    except (TypeError, ValueError):
        values = np.zeros(0)
    # numbers only: True and "1" are not signs (they were taken as +1)
    values = values.astype(np.float64) if values.dtype.kind in "iuf" else np.zeros(0)
    if values.shape != (n_muscles,) or not np.all(np.abs(values) == 1):
        raise ValueError(f"{name} must be {n_muscles} values of +1 or -1, got {signs!r}")
    return values
