"""Units and axes: the up axis from gravity, and the mesh's size against the material's length scales.

Nothing in skfem_modal assumes SI units, but a mesh and a material must agree:
an outline traced from an image is often 1000 or more pixels across, and a
material meant for a body 2 units long then makes it collapse under its own
weight. :func:`scale_mismatch` says so before any work, naming both lengths.
The other way round, a body small for its material at the time step (an
elastic wave crossing much of it in one step) turns only slowly in the
local/global iterations: said the same way.
"""

from __future__ import annotations

import math
import os
import sys
import warnings

import numpy as np

from .mesh import body_size, part_boxes
from .values import is_whole

__all__ = [
    "up_axis",
    "ScaleWarning",
    "material_length_scales",
    "scale_mismatch",
    "far_from_origin",
    "warn_scale",
    "float_range_problems",
]

_AXES = "xyz"

#: A mesh this many times larger than a material's length scale is reported.
FAR = 10.0

#: A body across which an elastic wave travels more than this fraction of its size in one
#: time step is reported: the iterations turn it too slowly (measured, a spinning unit square's
#: spin kept over half a second: 98 % at 0.16, 90 % at 0.2, 61 % at 0.25, 18 % at 0.32, none at 0.63).
CROSSING = 0.2
#: Steps of a run that is not short: one barely moving its body in fewer is blamed on its length, not its units.
SHORT_RUN = 100


class ScaleWarning(UserWarning):
    """The mesh's size and the material's length scale are far apart (wrong units?)."""


def _vector(values) -> str:
    return "[" + ", ".join(f"{float(v):g}" for v in values) + "]"


def up_axis(gravity, dim: int, up: int | None = None, ground: bool = True) -> int:
    """The index of the up axis: the one given, or the one gravity pulls down along.

    Without ``up``, the up axis is the axis of gravity's largest component
    (the first on ties), which must point down (negative); without gravity
    it is the last axis (y in 2D, z in 3D). Gravity that has no component
    along ``-up`` would never pull a body onto a ground below it: an error
    naming both. Without a ground (``ground=False``) any gravity goes: a
    floating body stands on nothing (the up axis is then the one given, the
    one gravity pulls down along, or the last).

    Parameters
    ----------
    gravity : array_like, shape (dim,), or None
        Gravitational acceleration.
    dim : int
        2 or 3.
    up : int, optional
        An axis index in ``0..dim-1``.
    ground : bool
        Whether there is a ground for gravity to pull the body onto.

    Returns
    -------
    up : int

    Raises
    ------
    ValueError
        ``up`` out of range, or gravity with no component along ``-up``.

    Examples
    --------
    >>> up_axis([0.0, -9.8, 0.0], 3)  # a y-up 3D mesh
    1
    >>> up_axis(None, 3)
    2
    >>> up_axis([0.0, -9.8, 0.0], 3, up=2)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    ValueError: gravity [0, -9.8, 0] has no component along -z, but the up axis is z (up = 2): give up = 1 (y)...
    >>> up_axis([8.49, -4.9], 2)  # an incline steeper than 45 degrees  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    ValueError: gravity [8.49, -4.9] pulls most along +x, so the up axis is not the one it pulls along: give it...
    >>> up_axis([8.49, -4.9], 2, up=1)
    1
    >>> up_axis([9.8, 0.0], 2, ground=False)  # a floating body falling along +x
    1
    """
    if dim not in (2, 3):
        raise ValueError(f"dim must be 2 or 3, got {dim!r}")
    if up is not None and (not is_whole(up) or not 0 <= up < dim):
        raise ValueError(f"up must be an axis index in 0..{dim - 1}, got {up!r}")
    g = None if gravity is None else np.asarray(gravity, dtype=np.float64).ravel()
    if g is not None and g.shape != (dim,):
        raise ValueError(f"gravity must have {dim} components, got {g.size}")
    if g is not None and not np.isfinite(g).all():
        raise ValueError(f"gravity must be finite, got {g.tolist()}")
    if g is None or not np.any(g):
        return dim - 1 if up is None else int(up)
    down = int(np.argmax(np.abs(g)))
    if not ground:
        return int(up) if up is not None else down if g[down] < 0 else dim - 1
    if up is None:
        if g[down] > 0:
            below = int(np.argmin(g))
            if g[below] < 0:  # a steep incline: the ground's axis has the smaller pull
                raise ValueError(
                    f"gravity {_vector(g)} pulls most along +{_AXES[down]}, so the up axis is not the one it "
                    f"pulls along: give it (up = {below} for {_AXES[below]}, which it pulls down along), or "
                    f"gravity along -{_AXES[down]}"
                )
            # (mirroring the mesh alone changes nothing here: the gravity is what must turn)
            raise ValueError(
                f"gravity {_vector(g)} pulls along +{_AXES[down]}, so no axis points up against it onto a "
                f"ground: give gravity along -{_AXES[down]} (if the mesh is upside down too, as an outline "
                f'traced in image coordinates with y down is, also mirror it: mesh.flip = ["{_AXES[down]}"] '
                "in a scene, skfem_modal.mirror in Python)"
            )
        return down
    if not g[up] < 0:
        below = int(np.argmin(g))  # the axis gravity pulls down along the most (an incline's need not be the largest)
        hint = f"give up = {below} ({_AXES[below]}), or " if g[below] < 0 else ""
        raise ValueError(
            f"gravity {_vector(g)} has no component along -{_AXES[up]}, but the up axis is {_AXES[up]} "
            f"(up = {up}): {hint}give a gravity that pulls along -{_AXES[up]}"
        )
    return int(up)


def material_length_scales(
    mu: float, rho: float, gravity=None, duration: float | None = None, h=None, damping_stiffness: float = 0.0
) -> dict:
    """Lengths a material sets, against which a mesh's size is judged.

    ``weight``: ``mu / (rho |g|)``, the size at which a body's own weight
    strains it by 100 % (present with gravity). ``waves``: ``sqrt(mu / rho)``
    times ``duration``, how far an elastic wave travels in the whole run: a
    body much larger than this cannot respond to its muscles in time.
    ``step``: ``sqrt(mu / rho) h``, how far it travels in one time step: the
    local/global iterations turn a body much smaller than ``step /``
    :data:`CROSSING` too slowly, so its rotations lag.

    Parameters
    ----------
    mu, rho : float
        Stiffness (the ARAP mu: Young's modulus at Poisson's ratio 0) and density.
    gravity : array_like, optional
    duration : float, optional
        Simulated time.
    h : float, optional
        Time step.
    damping_stiffness : float
        Stiffness-proportional damping ``beta``: a step's system holds the stiffness times
        ``1 + beta / h``, and ``step`` grows with its square root.

    Returns
    -------
    scales : dict
        ``{"weight": float, "waves": float, "step": float}``, only the keys that apply.

    Examples
    --------
    >>> material_length_scales(1e5, 1e3, [0.0, -10.0])
    {'weight': 10.0}
    """
    scales = {}
    if gravity is not None:
        g = float(np.hypot.reduce(np.asarray(gravity, dtype=np.float64)))  # a norm that does not overflow
        if g > 0:
            scales["weight"] = float(mu) / (float(rho) * g)
    speed = float(np.sqrt(float(mu) / float(rho)))
    if duration is not None:
        scales["waves"] = speed * float(duration)
    if h is not None:
        scales["step"] = speed * float(h) * math.sqrt(1.0 + float(damping_stiffness) / float(h))
    return scales


def scale_mismatch(
    mesh,
    mu: float,
    rho: float,
    gravity=None,
    duration: float | None = None,
    what: str = "mesh",
    h=None,
    damping_stiffness: float = 0.0,
):
    """Why the mesh's size and the material's length scales are far apart, or None.

    Reported when the mesh's largest extent is more than :data:`FAR` times a
    length of :func:`material_length_scales` (``weight``, ``waves``), or
    less than its ``step`` over :data:`CROSSING`; else when its centre is too
    far from the origin for its size (:func:`far_from_origin`).

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    mu, rho, gravity, duration, h, damping_stiffness
        See :func:`material_length_scales`.
    what : str
        How to name the mesh.

    Returns
    -------
    message : str or None

    Examples
    --------
    >>> from skfem_modal.mesh import beam2d
    >>> pixels = beam2d(1600.0, 900.0, 4, 2)  # an outline in pixel units
    >>> print(scale_mismatch(pixels, 1e5, 1e3, [0.0, -9.8]))  # doctest: +NORMALIZE_WHITESPACE
    mesh is 1600 length units across, 157x the material's length scale 10.2 (mu / (rho |g|), the
    size its own weight strains by 100 %): it would collapse under its own weight. Is it in other
    units (pixels)? Normalise it (mesh.normalize = true in a scene, skfem_modal.normalize_and_center
    in Python: largest extent 2), scale it (mesh.scale), or give a stiffer material.
    >>> scale_mismatch(pixels, 1e5, 1e3) is None  # no gravity, no duration: nothing to compare
    True
    >>> print(scale_mismatch(beam2d(1.0, 1.0, 2, 2), 1e6, 1e3, h=0.02))  # doctest: +NORMALIZE_WHITESPACE
    mesh is 1 length units across, and an elastic wave crosses 0.63 of it in one time step (sqrt(mu / rho)
    h = 0.632, above 0.2): the local/global iterations turn it too slowly, so its rotations lag and a
    spinning or tipping body slows down unphysically (a unit square with mu = 1e6 and h = 0.02 lost all its
    spin in half a second), and a step on the ground can gain energy (a caterpillar with mu = 1e6 landing at
    h = 0.3: 0.5 % in a step with 10 iterations, none with 30). Use a smaller time step (h <= 0.0063 here),
    more iterations (max_iter), or warm_start = true (not under the reference contact; it follows a spinning
    or rolling body, not a stiff one tipping over a corner, whose steps can then gain energy, nor friction
    stopping a spin: a block spun on the ground turned 2.2 times as far as converged).
    """
    for name, value in (("mu", mu), ("rho", rho)):
        value = np.asarray(value, dtype=np.float64)
        if not (value.size and np.all(np.isfinite(value)) and np.all(value > 0)):
            raise ValueError(f"{name} must be positive and finite, got {value.tolist()}")
    if not (isinstance(damping_stiffness, (int, float, np.number)) and 0 <= damping_stiffness < math.inf):
        raise ValueError(f"damping_stiffness must be non-negative and finite, got {damping_stiffness!r}")
    body_size(mesh)  # (its points checked)
    sizes, _ = _bodies(mesh)
    # a mesh of several bodies: the largest is what its weight or a run's waves are measured by (not the
    # gaps between them), the smallest what a step's elastic wave crosses (a copy 1/1000 the size of a
    # body beside it was not warned, and drifted as when warned alone: an audit)
    size, what_large, what_small = sizes.max(), what, what
    if sizes.size > 1:
        what_large, what_small = f"{what}'s largest body", f"{what}'s smallest body"
    scales = material_length_scales(mu, rho, gravity, duration, h, damping_stiffness)
    step = scales.pop("step", None)
    meaning = {
        "weight": ("mu / (rho |g|), the size its own weight strains by 100 %", "collapse under its own weight"),
        "waves": ("sqrt(mu / rho) x duration, how far an elastic wave travels in the run", "barely move in the run"),
    }
    for key, length in scales.items():
        if size > FAR * length:
            definition, effect = meaning[key]
            # a short run (a step or two) barely moves any body: no sign of other units when a run of
            # SHORT_RUN steps would move it
            short = key == "waves" and step is not None and size <= FAR * SHORT_RUN * step
            cause = (
                f"The run is short ({float(duration):.3g} time units): run longer (time.duration or time.steps), "
                "or if the mesh is in other units (pixels), normalise it"
                if short
                else "Is it in other units (pixels)? Normalise it"
            )
            ratio = size / length if length > 0.0 else math.inf
            return (
                f"{what_large} is {size:.4g} length units across, {ratio:.3g}x the material's length scale "
                f"{length:.3g} ({definition}): it would {effect}. {cause} "
                "(mesh.normalize = true in a scene, skfem_modal.normalize_and_center in Python: largest extent 2), "
                "scale it (mesh.scale), or give a stiffer material."
            )
    size = sizes.min()
    if step is not None and step > CROSSING * size:
        damped = (
            f" with the stiffness damping's 1 + beta / h = {1.0 + damping_stiffness / float(h):.3g} times the "
            "stiffness (a damped spin at 10 iterations a step was stopped dead)"
            if damping_stiffness
            else ""
        )
        crossing = "sqrt(mu (1 + beta / h) / rho) h" if damping_stiffness else "sqrt(mu / rho) h"
        return (
            f"{what_small} is {size:.4g} length units across, and an elastic wave crosses {step / size:.2g} of it in "
            f"one time step{damped} ({crossing} = {step:.3g}, above {CROSSING}): the local/global iterations turn it "
            "too slowly, so its rotations lag and a spinning or tipping body slows down unphysically (a unit square "
            "with mu = 1e6 and h = 0.02 lost all its spin in half a second), and a step on the ground can gain "
            "energy (a caterpillar with mu = 1e6 landing at h = 0.3: 0.5 % in a step with 10 iterations, none with "
            f"30). Use a smaller time step{' or damping' if damping_stiffness else ''} "
            f"(h <= {_two_digits_down(_largest_step(size, mu, rho, damping_stiffness)):.2g} here"
            f"{', at this damping' if damping_stiffness else ''}), more iterations "
            "(max_iter), or warm_start = true (not under the reference "
            "contact; it follows a spinning or rolling body, not a stiff one tipping over a corner, whose steps can "
            "then gain energy, nor friction stopping a spin: a block spun on the ground turned 2.2 times as far as "
            "converged)."
        )
    return far_from_origin(mesh, what)


#: A body whose centre is more than this many of its sizes from the origin is reported (:func:`far_from_origin`).
FAR_FROM_ORIGIN = 1000.0


def far_from_origin(mesh, what: str = "mesh") -> str | None:
    """Why a mesh's coordinates are too far from the origin for its size, or None.

    A step's deformation gradients and energies are differences of coordinates: their round-off
    grows with the distance from the origin, not with the body. Measured on the caterpillar
    (size 2) floating at rest, without gravity, moved along x and y by 1000 of its sizes: its
    mechanical energy at rest read -1.6 instead of 0 and its centre drifted 2.1e-5 of its size
    in 10 s; by 1e4 sizes 63 and 8.4e-5; by 5e5 sizes 4.6e5 and 1.2 % (drifting ever faster).

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
        Its points are checked (:func:`~skfem_modal.mesh.check_points`).
    what : str
        How to name the mesh in the message.

    Returns
    -------
    problem : str or None
        A paragraph when the centre of the mesh's bounding box is more than :data:`FAR_FROM_ORIGIN` of its
        sizes (:func:`~skfem_modal.mesh.body_size`) from the origin, else None.

    Raises
    ------
    TypeError, MeshError
        Points that cannot be used (:func:`~skfem_modal.mesh.check_points`).

    Examples
    --------
    >>> from skfem_modal.mesh import beam2d
    >>> beam = beam2d(2.0, 0.5, 4, 2)
    >>> far_from_origin(beam) is None
    True
    >>> print(far_from_origin(type(beam)(beam.p + 1e5, beam.t)))  # doctest: +NORMALIZE_WHITESPACE
    mesh's centre is 7.07e+04 of its sizes (2) from the origin, more than 1000: a step's deformation
    gradients and energies are differences of coordinates that large, and their round-off grows with
    the distance (a body moved by 1e4 sizes along x and y, floating at rest, read an energy of 63 instead
    of 0 and drifted 8.4e-5 of its size in 10 s). Move it near the origin (mesh.normalize = true in a scene,
    skfem_modal.normalize_and_center in Python, or subtract its centre).
    """
    body_size(mesh, what=what)  # (its points checked)
    sizes, centres = _bodies(mesh)  # each body's own: a small one far out is no nearer for a large one
    distances = np.linalg.norm(centres, axis=1) / np.where(sizes > 0.0, sizes, np.inf)
    far = int(np.argmax(distances))
    distance, size = float(distances[far]), float(sizes[far])
    if not distance > FAR_FROM_ORIGIN:
        return None
    whose = f"{what}'s" if sizes.size == 1 else f"{what}'s body {far} (of {sizes.size}): its"
    # (centring a mesh of several bodies cannot bring a small one far from the others near the origin)
    remedy = (
        "Move it near the origin (mesh.normalize = true in a scene, skfem_modal.normalize_and_center in Python, or "
        "subtract its centre)."
        if sizes.size == 1
        else "Move the bodies nearer each other (centring the whole mesh leaves a small body far from the others "
        "as far in its own sizes), or simulate that body apart."
    )
    return (
        f"{whose} centre is {distance:.3g} of its sizes ({size:.4g}) from the origin, more than "
        f"{FAR_FROM_ORIGIN:g}: a step's deformation gradients and energies are differences of coordinates that "
        "large, and their round-off grows with the distance (a body moved by 1e4 sizes along x and y, floating at "
        f"rest, read an energy of 63 instead of 0 and drifted 8.4e-5 of its size in 10 s). {remedy}"
    )


def _bodies(mesh) -> tuple[np.ndarray, np.ndarray]:
    """Each connected part's size (its largest extent, (parts,)) and bounding-box centre, (parts, dim)."""
    low, high = part_boxes(mesh)
    return (high - low).max(axis=1), 0.5 * (low + high)


def _largest_step(size: float, mu: float, rho: float, damping_stiffness: float = 0.0) -> float:
    """The largest ``h`` whose ``step`` (:func:`material_length_scales`) is :data:`CROSSING` of ``size``.

    ``(mu / rho) (h^2 + beta h) = (CROSSING size)^2``, solved for ``h`` (without cancellation).
    """
    X = (CROSSING * size) ** 2 * float(rho) / float(mu)
    beta = float(damping_stiffness)
    return 2.0 * X / (beta + math.hypot(beta, 2.0 * math.sqrt(X)))  # (hypot: a beta of 1e300 squared overflowed)


def _two_digits_down(value: float) -> float:
    """``value`` > 0 to two significant digits, rounded down (a bound advised is one that holds).

    >>> _two_digits_down(0.01996), _two_digits_down(0.013)
    (0.019, 0.013)
    """
    if not 0.0 < value < math.inf:  # (a step that underflowed: said as it is)
        return value
    exponent = math.floor(math.log10(value)) - 1
    digits = math.floor(value / 10.0**exponent * (1 + 1e-12))
    return float(f"{digits}e{exponent}")  # (read from its decimals: 13 * 10^-3 is 0.013000000000000001)


_PACKAGE = os.path.dirname(os.path.abspath(__file__)) + os.sep


def outside_stacklevel() -> int:
    """The ``stacklevel`` that makes a warning issued by the caller name the first line outside this package.

    For warnings of what a user did (assigned a setting, say): however many of the package's frames
    stand between (a property setter behind ``__setattr__``), the warning points at the user's line.
    """
    frame, level = sys._getframe(1), 1
    while frame is not None and frame.f_code.co_filename.startswith(_PACKAGE):
        frame, level = frame.f_back, level + 1
    return level


def warn_scale(
    mesh, mu, rho, gravity=None, duration=None, what: str = "mesh", h=None, stacklevel: int = 2, damping_stiffness=0.0
) -> None:
    """Warn (:class:`ScaleWarning`) with :func:`scale_mismatch`'s message, if any.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    mu, rho : float or ndarray, shape (nT,)
        Stiffness and density; per element, their means are compared.
    gravity : array_like, shape (dim,), optional
    duration : float, optional
        The run's simulated time.
    what : str
        What the message calls the body.
    h : float, optional
        The time step.
    stacklevel : int
        As for :func:`warnings.warn`, counted from the caller.
    damping_stiffness : float
        The stiffness-proportional damping coefficient (time).
    """
    message = scale_mismatch(
        mesh, float(np.mean(mu)), float(np.mean(rho)), gravity, duration, what, h, float(damping_stiffness)
    )
    if message:
        warnings.warn(message, ScaleWarning, stacklevel=stacklevel + 1)


def float_range_problems(
    mesh, *, mu, rho, h=None, gravity=None, gamma=None, damping_mass=0.0, damping_stiffness=0.0, free=False
) -> list[tuple[tuple[str, ...], str]]:
    """What the simulator's operators could not hold in float64, by the arguments that make it so.

    The operators scale as: the time step's square ``h^2`` and its inverse;
    the vertex masses ``rho |e|`` (``|e|`` an element's measure, ``l =
    |e|^(1/dim)`` its size); the stiffness ``mu |e| / l^2`` (and ``gamma
    |e| / l^2``, the muscles'); the modes' squared angular frequencies ``mu /
    (rho l^2)``; the inertia operator ``rho |e| / h^2``; the weights ``rho
    |e| |g|``. Each must be a normal float64, between the smallest normal
    number (about 2.2e-308: below it, digits are lost and then everything
    is 0) and the largest (about 1.8e308: above it, infinity), over the
    mesh's smallest and largest elements.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    mu, rho : float or ndarray, shape (nT,)
        Positive and finite (checked elsewhere).
    h : float, optional
    gravity : array_like, shape (dim,), optional
    gamma : float or ndarray, shape (nT,), optional
    damping_mass, damping_stiffness : float
        Rayleigh damping's coefficients (0: none): with ``h``, its operators
        ``damping_mass x vertex mass / h`` and ``damping_stiffness x stiffness / h``.
    free : bool
        A body nothing pins: with ``h``, its inertia must also be told from its stiffness in
        float64 (the largest inertia, vertex mass / h^2, above :data:`LEAST_INERTIA_SHARE` of the largest
        stiffness), or its rigid motions are lost to round-off.

    Returns
    -------
    problems : list of (names, text)
        ``names``: the arguments that set the quantity (``"mu"``, ``"rho"``,
        ``"h"``, ``"gravity"``, ``"gamma"``); ``text``: which quantity, its
        value and which way it leaves the range; the first for each set of
        names. Empty when all fit.

    Examples
    --------
    >>> from skfem_modal.mesh import caterpillar
    >>> float_range_problems(caterpillar(nx=10, ny=5), mu=1e5, rho=1e3, h=0.01)
    []
    >>> float_range_problems(caterpillar(nx=10, ny=5), mu=1e5, rho=1e3, h=1e300)[0]
    (('h',), 'the time step squared, h^2, would be 1e+600: beyond float64 (above 1.8e+308)')
    """
    from .mesh import _signed_measures

    dim = mesh.p.shape[0]
    # each quantity as the interval of its log10 over the mesh's elements: sums of intervals
    measure = _log_span(np.abs(_signed_measures(mesh.p, mesh.t)))
    size = measure / dim
    mass = _log_span(rho) + measure
    quantities = [
        (("rho",), "the vertex masses, rho x element measure", mass),
        (("mu",), "the stiffness, mu x element size^(dim - 2)", _log_span(mu) + (dim - 2) * size),
        (
            ("mu", "rho"),
            "the modes' squared angular frequencies, mu / (rho x element size^2)",
            _log_span(mu) - (_log_span(rho) + 2 * size)[::-1],
        ),
    ]
    if gamma is not None and np.any(np.asarray(gamma) > 0):
        positive = np.asarray(gamma)[np.asarray(gamma) > 0]
        quantities.append(
            (
                ("gamma",),
                "the muscles' stiffness, gamma x element size^(dim - 2)",
                _log_span(positive) + (dim - 2) * size,
            )
        )
    if h is not None:
        step = _log_span(h)
        quantities += [
            (("h",), "the time step squared, h^2", 2 * step),
            (("h",), "the inverse of the time step squared, 1 / h^2", -2 * step),
            (("rho", "h"), "the inertia operator, vertex mass / h^2", mass - 2 * step),
        ]
        if damping_mass > 0:
            damped = _log_span(damping_mass) + mass - step
            quantities.append((("damping_mass", "rho", "h"), "the damping, damping_mass x vertex mass / h", damped))
        if damping_stiffness > 0:
            damped = _log_span(damping_stiffness) + _log_span(mu) + (dim - 2) * size - step
            quantities.append(
                (("damping_stiffness", "mu", "h"), "the damping, damping_stiffness x stiffness / h", damped)
            )
    g = np.zeros(1) if gravity is None else np.abs(np.asarray(gravity, dtype=np.float64))
    if g.max() > 0:
        g_log = np.log10(g.max()) + 0.5 * np.log10(np.sum((g / g.max()) ** 2))  # |g| without squaring 1e308
        quantities.append((("rho", "gravity"), "the weights, vertex mass x |gravity|", mass + g_log))
    info = np.finfo(np.float64)
    problems = _inertia_problems(mu, gamma, mass, size, dim, h) if free and h is not None else []
    for names, what, (lo, hi) in quantities:
        if any(names == named for named, _ in problems):
            continue  # one problem per set of arguments: the first says what to change
        if hi > np.log10(info.max):
            problems.append((names, f"{what}, would be 1e+{hi:.0f}: beyond float64 (above {info.max:.2g})"))
        elif lo < np.log10(info.tiny):
            problems.append((names, f"{what}, would be 1e{lo:.0f}: beyond float64 (below {info.tiny:.2g})"))
    return problems


#: a free body's largest inertia (vertex mass / h^2) below this share of its largest stiffness is refused up front:
#: an estimate from the elements, within a few times the assembled system's own (the caterpillar with mu = 1e6 at
#: h = 1e5: 1e-16, the system's 2.4e-16), whose factoring fails below about 1e-15 (it succeeded at 2.4e-14); a
#: margin of 100 below that, so that what the estimate refuses the system could not have solved
LEAST_INERTIA_SHARE = 1e-17


def _inertia_problems(mu, gamma, mass, size, dim, h) -> list[tuple[tuple[str, ...], str]]:
    """A free body's inertia lost beside its stiffness (:func:`float_range_problems`' ``free``), or nothing.

    ``mass`` and ``size``: the log10 spans of the vertex masses and the element sizes.
    """
    muscles = gamma is not None and np.max(gamma) > np.max(mu)
    stiffness = np.log10(np.max(gamma if muscles else mu)) + (dim - 2) * size[1]  # mu x size^(dim - 2)
    inertia = mass[1] - 2 * np.log10(float(h))
    if inertia - stiffness >= np.log10(LEAST_INERTIA_SHARE):
        return []
    names = ("gamma" if muscles else "mu", "rho", "h")
    return [
        (
            names,
            f"the inertia, vertex mass / h^2 (up to 1e{inertia:.0f}), would be 1e{inertia - stiffness:.0f} of the "
            f"stiffness (up to 1e{stiffness:.0f}), below float64's round-off: the system matrix would be singular "
            "to working precision and a free body's rigid motions undetermined; use a smaller time step or a softer "
            "material, or pin the body",
        )
    ]


def _log_span(values) -> np.ndarray:
    """log10 of the smallest and the largest of some positive values, shape (2,)."""
    values = np.log10(np.asarray(values, dtype=np.float64))
    return np.array([values.min(), values.max()])
