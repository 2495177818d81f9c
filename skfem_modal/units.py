"""Units and axes: the up axis from gravity, and the mesh's size against the material's length scales.

Nothing in skfem_modal assumes SI units, but a mesh and a material must agree:
an outline traced from an image is often 1000 or more pixels across, and a
material meant for a body 2 units long then makes it collapse under its own
weight. :func:`scale_mismatch` says so before any work, naming both lengths.
"""

from __future__ import annotations

import warnings

import numpy as np

__all__ = ["up_axis", "ScaleWarning", "material_length_scales", "scale_mismatch", "warn_scale"]

_AXES = "xyz"

#: A mesh this many times larger than a material's length scale is reported.
FAR = 10.0


class ScaleWarning(UserWarning):
    """The mesh's size and the material's length scale are far apart (wrong units?)."""


def _vector(values) -> str:
    return "[" + ", ".join(f"{float(v):g}" for v in values) + "]"


def up_axis(gravity, dim: int, up: int | None = None) -> int:
    """The index of the up axis: the one given, or the one gravity pulls down along.

    Without ``up``, the up axis is the axis of gravity's largest component
    (the first on ties), which must point down (negative); without gravity
    it is the last axis (y in 2D, z in 3D). Gravity that has no component
    along ``-up`` would never pull a body onto a ground below it: an error
    naming both.

    Parameters
    ----------
    gravity : array_like, shape (dim,), or None
        Gravitational acceleration.
    dim : int
        2 or 3.
    up : int, optional
        An axis index in ``0..dim-1``.

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
    """
    if dim not in (2, 3):
        raise ValueError(f"dim must be 2 or 3, got {dim!r}")
    if up is not None and (isinstance(up, bool) or not isinstance(up, (int, np.integer)) or not 0 <= up < dim):
        raise ValueError(f"up must be an axis index in 0..{dim - 1}, got {up!r}")
    g = None if gravity is None else np.asarray(gravity, dtype=np.float64).ravel()
    if g is not None and g.shape != (dim,):
        raise ValueError(f"gravity must have {dim} components, got {g.size}")
    if g is None or not np.any(g):
        return dim - 1 if up is None else int(up)
    down = int(np.argmax(np.abs(g)))
    if up is None:
        if g[down] > 0:
            raise ValueError(
                f"gravity {_vector(g)} pulls along +{_AXES[down]}, so no axis points up against it: give "
                f"gravity along -{_AXES[down]} (for an outline traced in image coordinates, y down, mirror "
                'the mesh first: mesh.flip = ["y"] in a scene, skfem_modal.mirror in Python)'
            )
        return down
    if not g[up] < 0:
        hint = f"give up = {down} ({_AXES[down]})" if g[down] < 0 else f"mirror the mesh along {_AXES[down]}"
        raise ValueError(
            f"gravity {_vector(g)} has no component along -{_AXES[up]}, but the up axis is {_AXES[up]} "
            f"(up = {up}): {hint}, or a gravity that pulls along -{_AXES[up]}"
        )
    return int(up)


def material_length_scales(mu: float, rho: float, gravity=None, duration: float | None = None) -> dict:
    """Lengths a material sets, against which a mesh's size is judged.

    ``weight``: ``mu / (rho |g|)``, the size at which a body's own weight
    strains it by 100 % (present with gravity). ``waves``: ``sqrt(mu / rho)``
    times ``duration``, how far an elastic wave travels in the whole run: a
    body much larger than this cannot respond to its muscles in time.

    Parameters
    ----------
    mu, rho : float
        Shear modulus and density.
    gravity : array_like, optional
    duration : float, optional
        Simulated time.

    Returns
    -------
    scales : dict
        ``{"weight": float, "waves": float}``, only the keys that apply.

    Examples
    --------
    >>> material_length_scales(1e5, 1e3, [0.0, -10.0])
    {'weight': 10.0}
    """
    scales = {}
    if gravity is not None:
        g = float(np.linalg.norm(np.asarray(gravity, dtype=np.float64)))
        if g > 0:
            scales["weight"] = float(mu) / (float(rho) * g)
    if duration is not None:
        scales["waves"] = float(np.sqrt(float(mu) / float(rho))) * float(duration)
    return scales


def scale_mismatch(mesh, mu: float, rho: float, gravity=None, duration: float | None = None, what: str = "mesh"):
    """Why the mesh's size and the material's length scales are far apart, or None.

    Reported when the mesh's largest extent is more than :data:`FAR` times a
    length of :func:`material_length_scales`.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    mu, rho, gravity, duration
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
    """
    size = float(np.ptp(mesh.p, axis=1).max())
    scales = material_length_scales(mu, rho, gravity, duration)
    meaning = {
        "weight": ("mu / (rho |g|), the size its own weight strains by 100 %", "collapse under its own weight"),
        "waves": ("sqrt(mu / rho) x duration, how far an elastic wave travels in the run", "barely move in the run"),
    }
    for key, length in scales.items():
        if size > FAR * length:
            definition, effect = meaning[key]
            return (
                f"{what} is {size:.4g} length units across, {size / length:.3g}x the material's length scale "
                f"{length:.3g} ({definition}): it would {effect}. Is it in other units (pixels)? Normalise it "
                "(mesh.normalize = true in a scene, skfem_modal.normalize_and_center in Python: largest extent 2), "
                "scale it (mesh.scale), or give a stiffer material."
            )
    return None


def warn_scale(mesh, mu: float, rho: float, gravity=None, duration: float | None = None, what: str = "mesh") -> None:
    """Warn (:class:`ScaleWarning`) with :func:`scale_mismatch`'s message, if any."""
    message = scale_mismatch(mesh, mu, rho, gravity, duration, what)
    if message:
        warnings.warn(message, ScaleWarning, stacklevel=2)
