"""Checks of a simulator's arguments and settings: each gives the value to use or a clear error naming it.

Used by :class:`~skfem_modal.sim.ModalMuscle`'s constructor (before any work),
its setters and :meth:`~skfem_modal.sim.ModalMuscle.from_mesh`, so every
setting is checked by one function wherever it is given.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sps

from .acceleration import ACCELERATIONS
from .contact import ALLOWANCE, MODEL_SETTINGS, MODELS, THIN_WORDS, allowance_lengths, checked_allowance, thin
from .fem import _positive
from .mesh import connected_labels, part_sizes
from .solver import BACKENDS
from .units import float_range_problems, up_axis
from .values import checked_flag, is_whole
from .values import positive_number as _positive_scalar


def _array(value, shape, name):
    arr = np.asarray(value)
    if not np.issubdtype(arr.dtype, np.number):
        raise TypeError(f"{name} must be numeric, got dtype {arr.dtype}")
    if np.issubdtype(arr.dtype, np.complexfloating):  # (numpy drops the imaginary part with a warning)
        raise TypeError(f"{name} must be real, got complex values {arr.tolist()}")
    arr = arr.astype(np.float64)  # a copy: the caller's array, changed later, would not be the simulator's
    if arr.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    return arr


def _fraction(value, name):
    v = _positive_scalar(value, name, allow_zero=True)
    if v > 1:
        raise ValueError(f"{name} must be in [0, 1], got {value!r}")
    return v


def _count(value, name):
    if not is_whole(value) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


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


def _vertices(value, n, name):
    """Vertex indices (unique, ascending), from indices or a boolean mask of the ``n`` vertices."""
    arr = np.asarray(value)
    if arr.dtype == bool:
        if arr.shape != (n,):
            raise ValueError(f"{name} as a boolean mask must have one value per vertex, shape ({n},), got {arr.shape}")
        arr = np.flatnonzero(arr)
        if not arr.size:
            raise ValueError(f"{name}: the mask selects no vertex")
    arr = np.unique(arr)
    if arr.size == 0 or not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"{name} must be a non-empty array of vertex indices (or a boolean mask), got {value!r}")
    if arr[0] < 0 or arr[-1] >= n:
        raise ValueError(f"{name} must be vertex indices in 0..{n - 1}, got {arr[0]}..{arr[-1]}")
    return arr.astype(np.int64)


def _axis(value, dim):
    if not is_whole(value) or not 0 <= value < dim:
        raise ValueError(f"up must be an axis index in 0..{dim - 1}, got {value!r}")
    return int(value)


def _acceleration_name(value, full_space=False):
    if value not in ACCELERATIONS:
        raise ValueError(f"acceleration must be one of {', '.join(map(repr, ACCELERATIONS))}, got {value!r}")
    if value == "newton" and full_space:
        raise ValueError(
            "acceleration='newton' needs a subspace (its system has a row per cluster rotation); "
            "on every DOF use 'anderson'"
        )
    return value


def _backend_name(value):
    if value not in BACKENDS:
        raise ValueError(f"backend must be one of {', '.join(map(repr, BACKENDS))}, got {value!r}")
    if value == "numba":
        from . import _accel

        if not _accel.AVAILABLE:
            raise ValueError("backend='numba' needs numba: pip install 'skfem_modal[fast]'")
    return value


def _contact_settings(model, friction, stickiness, push_out, allowance=None, exact_friction=None) -> dict:
    """A contact model's settings, checked: each model takes only its own."""
    if model not in MODELS:
        raise ValueError(f"contact_model must be one of {', '.join(map(repr, MODELS))}, got {model!r}")
    given = dict(
        friction=friction, allowance=allowance, exact_friction=exact_friction, stickiness=stickiness, push_out=push_out
    )
    other = "reference" if model == "coulomb" else "coulomb"
    foreign = [name for name in MODEL_SETTINGS[other] if given[name] is not None]
    if model == "coulomb":
        if foreign:
            raise ValueError(
                f"{' and '.join(foreign)}: settings of contact_model='reference', not of 'coulomb' "
                "(which keeps every vertex above the ground and has friction)"
            )
        friction = 0.5 if friction is None else _positive_scalar(friction, "friction", allow_zero=True)
        allowance = ALLOWANCE if allowance is None else checked_allowance(allowance)
        exact = True if exact_friction is None else checked_flag(exact_friction, "exact_friction")
        return {"model": model, "friction": friction, "allowance": allowance, "exact_friction": exact}
    if foreign:
        raise ValueError(
            f"{' and '.join(foreign)}: {'a setting' if len(foreign) == 1 else 'settings'} of contact_model='coulomb', "
            "not of 'reference' (which has "
            "stickiness and push_out instead, and lets vertices end inside the ground)"
        )
    return {
        "model": model,
        "stickiness": 1.0 if stickiness is None else _fraction(stickiness, "stickiness"),
        "push_out": 0.0 if push_out is None else _fraction(push_out, "push_out"),
    }


def _muscle_modes(D, N: int) -> np.ndarray:
    """Muscle modes as a checked (N, m) array."""
    if D is None:
        return np.zeros((N, 0))
    D = np.array(D, dtype=np.float64)  # (a copy, as B)
    if D.ndim == 1:
        D = D[:, None]
    if D.ndim != 2 or D.shape[0] != N:
        raise ValueError(f"D must have shape ({N}, m) for this mesh, got {D.shape}")
    if not np.all(np.isfinite(D)):
        raise ValueError("D must be finite")
    return D


def _nonnegative(value, name):
    """A number >= 0 and finite."""
    return _positive_scalar(value, name, allow_zero=True)


def _vertex_field(x, n: int, dim: int, name: str = "x") -> np.ndarray:
    """A field of one value per vertex coordinate, shape (n, dim) or (n dim,), checked finite, as floats."""
    x = np.asarray(x, dtype=np.float64)
    if x.shape not in ((n, dim), (n * dim,)):
        raise ValueError(f"{name} must have shape ({n}, {dim}) or ({n * dim},), one value per vertex, got {x.shape}")
    if not np.isfinite(x).all():
        raise ValueError(f"{name} must be finite")
    return x


def _basis(B, rest) -> np.ndarray:
    """A subspace basis as a checked (N, r) array (a sparse one made dense: the subspace is dense).

    ``rest`` (N,): the rest positions, interleaved, which ``B``'s columns must span.
    """
    N = rest.size
    B = B.toarray() if sps.issparse(B) else B
    B = np.array(B, dtype=np.float64)  # a copy: the caller's array, changed later, would not be the simulator's
    if B.ndim != 2 or B.shape[0] != N or B.shape[1] < 1:
        raise ValueError(f"B must have shape ({N}, r) for this mesh, got {B.shape}")
    if not np.all(np.isfinite(B)):
        raise ValueError("B must be finite")
    _spans_rest(B, rest)
    return B


def _spans_rest(B, rest) -> None:
    """Refuse a basis whose columns do not span the rest positions: its states could not be at rest.

    The coefficients are fitted on a few spread rows (four a column) and checked on all, a product of
    ``B``'s size; only when that misses (those rows may not tell the columns apart) on all rows. The
    columns are fitted at unit length (an affine basis of a body 1e-9 across has columns 1e9 apart).
    A square basis spans everything it can: its rank is checked with the model's mass matrix.
    """
    N, r = B.shape
    if r >= N:
        return
    reach = max(float(np.abs(rest).max(initial=0.0)), float(np.ptp(rest.reshape(-1, 1)))) or 1.0
    lengths = np.sqrt(np.einsum("ij,ij->j", B, B))
    lengths[lengths == 0.0] = 1.0
    for rows in (np.unique(np.linspace(0, N - 1, min(N, 4 * r)).astype(np.int64)), slice(None)):
        coefficients = np.linalg.lstsq(B[rows] / lengths, rest[rows], rcond=None)[0] / lengths
        miss = float(np.abs(B @ coefficients - rest).max())
        if miss <= 1e-8 * reach:
            return
    raise ValueError(
        f"B's columns do not span the rest pose: the closest B z is {miss:.3g} from the mesh's positions at some "
        f"vertex ({miss / reach:.3g} of the largest coordinate); a subspace must hold the body at rest (a skinning "
        "basis does: lbs_basis, skinning_eigenmodes, and mass_orthonormalize of either)"
    )


def _gravity_and_up(gravity, up, dim: int, ground: bool = True):
    """Gravity, shape (dim,), or None, and the up axis it pulls down along (or the one given), checked.

    ``ground``: whether there is one (without, any gravity goes: :func:`~skfem_modal.units.up_axis`).
    """
    if up is not None:
        up = _axis(up, dim)
    if gravity is not None:
        gravity = _array(gravity, (dim,), "gravity")
    return gravity, up_axis(gravity, dim, up, ground)


def nothing_free(held: int, n: int, name: str, fewer: str) -> str | None:
    """Why holding ``held`` of a mesh's ``n`` vertices in place (as ``name`` does) leaves nothing to move, or None.

    Parameters
    ----------
    held : int
        How many distinct vertices are held.
    n : int
        The mesh's number of vertices.
    name : str
        What holds them, to start the message (e.g. ``"pinned"``).
    fewer : str
        What to do instead, in the message's closing parentheses (e.g. ``"pin fewer"``).

    Returns
    -------
    problem : str or None
        A sentence when ``held >= n``, else None.
    """
    return f"{name} holds all {n} vertices of the mesh: nothing is left free to move ({fewer})" if held >= n else None


def _pins(pinned, pin_stiffness, n: int):
    """Pinned vertices, shape (p,), or None, and their stiffness (None: the default), checked."""
    pinned = None if pinned is None else _vertices(pinned, n, "pinned")
    problem = None if pinned is None else nothing_free(pinned.size, n, "pinned", "pin fewer")
    if problem:
        raise ValueError(problem)
    return pinned, None if pin_stiffness is None else _positive_scalar(pin_stiffness, "pin_stiffness")


def _ground(ground, n: int, contact_vertices=None, **contact):
    """The ground's height or None, and the contact vertices given or None, checked.

    ``contact``: the other contact arguments by name, None where not given
    (``contact_model`` is given when not the default ``"coulomb"``). Any of
    them, or ``contact_vertices``, without a ground is an error naming it:
    nothing would use it.
    """
    if ground is None:
        contact["contact_vertices"] = contact_vertices
        given = [
            name if np.ndim(value) else f"{name}={value!r}"
            for name, value in contact.items()
            if value is not None and (name, value) != ("contact_model", "coulomb")
        ]
        if given:
            what, them = ("a contact setting", "it") if len(given) == 1 else ("contact settings", "them")
            raise ValueError(
                f"{', '.join(given)}: {what}, but there is no ground (ground=..., its height along the up axis) "
                f"and nothing else uses {them}: give a ground or leave {them} out"
            )
        return None, None
    ground = float(_array(ground, (), "ground"))
    return ground, None if contact_vertices is None else _vertices(contact_vertices, n, "contact_vertices")


def _fits_float64(mesh, mu, gamma, rho, h=None, gravity=None, damping=(0.0, 0.0)) -> None:
    """The material, time step and gravity checked, then checked to make operators float64 can hold.

    See :func:`~skfem_modal.units.float_range_problems`; the error names
    the arguments (and their values) that take a quantity out of range.
    """
    nT = mesh.t.shape[1]
    mu, rho = _positive(mu, nT, "mu"), _positive(rho, nT, "rho")
    gamma = _positive(mu if gamma is None else gamma, nT, "gamma", allow_zero=True)
    h = None if h is None else _positive_scalar(h, "h")
    gravity = None if gravity is None else _array(gravity, (mesh.p.shape[0],), "gravity")
    a, b = damping
    problems = float_range_problems(
        mesh, mu=mu, rho=rho, h=h, gravity=gravity, gamma=gamma, damping_mass=a, damping_stiffness=b
    )
    if problems:
        values = dict(mu=mu, gamma=gamma, rho=rho, h=h, gravity=gravity, damping_mass=a, damping_stiffness=b)
        raise ValueError(
            "; ".join(f"{', '.join(_named(n, values[n]) for n in names)}: {text}" for names, text in problems)
            + " on this mesh"
        )


def _named(name: str, value) -> str:
    """``name = value`` for a message; a per-element array by its range."""
    value = np.asarray(value)
    if value.ndim and value.size > 1 and name != "gravity":
        return f"{name} = {value.min():g}..{value.max():g}" if value.min() != value.max() else f"{name} = {value[0]:g}"
    if name == "gravity":
        return f"gravity = [{', '.join(f'{v:g}' for v in value)}]"
    return f"{name} = {float(value):g}"


def _pulled_to_ground(gravity, ground, up: int) -> None:
    """Raise if a ground is given with a gravity that has no component along ``-up`` (nothing pulls the body onto it).

    ``gravity=None`` (no gravity at all) is allowed with a ground; an explicit zero or sideways one is a mistake.
    """
    if ground is not None and gravity is not None and not np.asarray(gravity, float)[up] < 0.0:
        raise ValueError(
            f"gravity {np.asarray(gravity, float).tolist()} has no component along -{'xyz'[up]} (up = {up}), so "
            f"nothing pulls the body onto the ground: give a gravity along -{'xyz'[up]}, or none at all (a ground "
            "without gravity is allowed)"
        )


def _clear_of_ground(mesh, ground, up: int, allowance: float = ALLOWANCE) -> None:
    """Raise if the body starts deeper inside the ground than the contact's allowance (of its size, or thickness).

    A contact that finds a body deep in the ground pushes it out within a step or two, with
    the energy of a spring compressed that far: the body is flung into the air (a ghost
    started 30 % of its size deep rose 1.6 sizes, its energy from -54 to 2.5e5; a caterpillar
    0.8 % deep gained 82 times its energy in the first step at h = 0.001).
    """
    if ground is None:
        return
    labels = connected_labels(mesh)
    sizes, lengths = part_sizes(mesh, labels), allowance_lengths(mesh, labels)  # each part as large as itself
    depths = ground - mesh.p[up]
    deepest = int(np.argmax(depths / lengths))
    if depths[deepest] > allowance * lengths[deepest]:
        lowest, depth = float(mesh.p[up, deepest]), float(depths[deepest])
        which = "its lowest vertex" if lowest == mesh.p[up].min() else f"vertex {deepest} (of another part)"
        allowed = f"{100 * allowance:.3g} % of its size"
        if thin(lengths[deepest], sizes[deepest]):
            allowed = f"{100 * allowance:.3g} % of {THIN_WORDS} ({allowance * lengths[deepest]:.3g})"
        raise ValueError(
            f"the body starts inside the ground: {which} ({'xyz'[up]} = {lowest:.6g}) is {depth:.4g} "
            f"({100 * depth / sizes[deepest]:.3g} % of its size) below the ground at {ground:.6g}, more than "
            f"{allowed}; the contact would fling it out. Put the ground at or below "
            "the body's lowest point (a scene's [ground] offset >= 0)"
        )
