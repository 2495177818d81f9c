"""Scenes: a TOML file (or a dict) that names a mesh, a material, muscles and effects.

A scene is validated completely before any computation: every key is checked
for spelling, type and range, and an error names the key, the value and what
was expected. Sections ``gravity``, ``ground``, ``pinned`` and ``damping`` are
*effects*: present, they are built into the simulator; absent, they cost
nothing. ``docs/scenes.md`` lists every key (it is generated from
:data:`SCHEMA`; see :func:`schema_markdown`).
"""

from __future__ import annotations

import copy
import csv
import math
import os
import re
import tomllib
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .checks import _clear_of_ground, _pulled_to_ground, nothing_free
from .contact import (
    ALLOWANCE,
    DEFAULT_CONTACTS,
    LEAST_ALLOWANCE,
    MODEL_SETTINGS,
    MOST_ALLOWANCE,
    THIN_WORDS,
    checked_allowance,
)
from .mesh import (
    _CONDITION,
    BUILTIN_SHAPES,
    SIZE_RANGE,
    builtin_mesh,
    load_mesh,
    mirror,
    normalize_and_center,
    normalizing_transform,
    shape_parameter_problems,
    shape_parameters,
    vertices_where,
)
from .muscles import _sine, shortest_period
from .solver import MAX_ITERATIONS, TOL
from .units import ScaleWarning, float_range_problems, scale_mismatch, up_axis
from .values import is_finite_real

__all__ = [
    "SceneError",
    "Scene",
    "SCHEMA",
    "DEFAULT_SCENE",
    "PATH_KEYS",
    "resolve_paths",
    "read_scene_file",
    "schema_markdown",
]


class SceneError(ValueError):
    """A scene that cannot be run; the message lists every problem found, by key."""


@dataclass(frozen=True)
class Key:
    """One scene key: its type, default, meaning and units.

    Attributes
    ----------
    kind : str
        The value's type, as the file gives it: ``"float"``, ``"int"``, ``"bool"``, ``"str"``, ``"floats"``,
        ``"ints"``, ``"strs"`` (lists of them), ``"table"`` or ``"int|all"`` (an integer or the string
        ``"all"``).
    default : object
        The value when the key is absent or null (None: no default).
    doc : str
        What the key means (markdown), for the scene reference (:func:`schema_markdown`).
    units : str
        Its units, for the reference ("": none said).
    check : callable, optional
        ``check(value)`` of a value of the right kind: None when it is allowed, else what was expected
        (e.g. ``"a positive number"``), said in the error.
    required : bool
        The key must be given (absent or null is an error).
    """

    kind: str  # float, int, bool, str, floats, ints, strs, table, int|all
    default: Any
    doc: str
    units: str = ""
    check: Callable[[Any], str | None] | None = None
    required: bool = False


def _positive(v):
    return None if v > 0 else "a positive number"


def _non_negative(v):
    return None if v >= 0 else "a number >= 0"


def _unit_interval(v):
    return None if 0 <= v <= 1 else "a number in [0, 1]"


def _iterations(v):
    return None if 1 <= v <= MAX_ITERATIONS else f"an integer from 1 to {MAX_ITERATIONS}"


def _some(v):
    return None if len(v) else "at least one condition"


def _allowance(v):
    try:
        checked_allowance(v)  # the contact's own rule
    except ValueError:
        return f"a number from {LEAST_ALLOWANCE:g} (less is lost in round-off) to {MOST_ALLOWANCE:g}"
    return None


def _at_least_one(v):
    return None if v >= 1 else "an integer >= 1"


def _shape_name(v):
    return None if v in BUILTIN_SHAPES else f"one of {sorted(BUILTIN_SHAPES)}"


def _signs(v):
    return None if all(s in (-1, 1) for s in v) else "a list of +1 and -1"


def _positive_list(v):
    return None if all(x > 0 for x in v) else "a list of positive numbers"


def _contacts(v):
    if v == "all" or (isinstance(v, int) and not isinstance(v, bool) and v >= 1):
        return None
    return 'an integer >= 1 or "all"'


#: Every key a scene may hold, by section. Sections marked as effects are
#: optional tables; their presence switches the effect on.
SCHEMA: dict[str, Any] = {
    "name": Key("str", "scene", "A name for the scene, copied to summary.json."),
    "mesh": {
        "shape": Key(
            "str",
            None,
            "Built-in shape: caterpillar, beam2d, beam3d, box3d or creature "
            "(default caterpillar when no file is given).",
            check=_shape_name,
        ),
        "file": Key(
            "str",
            None,
            "Mesh file (any format meshio reads), relative to the scene file. "
            "Triangles make a 2D body (flat in x-y; flat in x-z or y-z, they are read as x-y from the other "
            "two axes, so z becomes y), tetrahedra a 3D one (quadratic `triangle6` / `tetra10` by their "
            "corners, with a warning that curved edges become straight); other cells of the body's dimension "
            "beside them (quads, hexahedra, prisms) are an error, as leaving them out would leave holes; "
            "vertices no element uses are dropped, with a warning naming them.",
        ),
        "params": Key(
            "table",
            {},
            "Parameters of the built-in shape, e.g. `{ nx = 280, ny = 136 }`; each has a default "
            "(see Built-in shapes below).",
        ),
        "flip": Key(
            "strs",
            None,
            'Mirror the mesh along these axes first, e.g. ["y"] for an outline traced in image coordinates (y down). '
            "A mode's sign makes its largest entry positive, so a mirrored (or turned) mesh can get some muscles "
            "with the other sign, and the same gait is then not the mirror image of the unflipped body's (the "
            "caterpillar crawl of examples/ travels +0.475 in x; flipped in x, +2.86 with its signs, and "
            "-0.475, the mirror image, only with each of its muscles.signs negated): set signs to match.",
            check=lambda v: None if all(a in ("x", "y", "z") for a in v) else 'a list of "x", "y", "z"',
        ),
        "merge": Key(
            "bool",
            False,
            "Merge the file's coincident vertices (closer than 1e-9 of the mesh's size) into one: a triangle soup "
            "(OBJ and STL exports repeat each vertex for every element using it) becomes one connected body. "
            "Without it, loading such a file warns how many vertices coincide.",
        ),
        "normalize": Key(
            "bool",
            False,
            "Centre the mesh at its vertex mean and scale its largest extent to 2 (for meshes in other "
            "units, e.g. pixels: a warning says when the mesh's size and the material's length scale are far "
            "apart; and for a mesh whose centre is over 1000 of its sizes from the origin, where the round-off "
            "of its coordinates moves a body at rest).",
        ),
        "scale": Key(
            "float",
            1.0,
            "Multiply every coordinate by this factor (after normalising). The scene's other lengths, and a run's "
            "outputs, are of the mesh so placed ([units](#units)).",
            "length",
            _positive,
        ),
    },
    "material": {
        "mu": Key(
            "float",
            None,
            "Passive (ARAP) stiffness: the energy mu / 2 |F - R|^2 per volume, which in small strains is a "
            "material of Young's modulus mu and Poisson's ratio 0 (shear modulus mu / 2). The linear (muscle) "
            "modes take it as the Lame mu, with lam, as the reference does. Default 1e5, or young.",
            "stress",
            _positive,
        ),
        "gamma": Key(
            "float",
            None,
            "Muscle stiffness (default: mu). At zero activation the muscles too hold the body to its rest "
            "shape, turned by only subspace.active_clusters rotations (1: one for the whole body), so they "
            "stiffen it in bending: a cantilever (mu = 1e9, 2 muscles at rest) sagged 13 times less than "
            "without muscles.",
            "stress",
            _non_negative,
        ),
        "lam": Key(
            "float",
            None,
            "First Lame parameter of the linear (muscle) modes only: the simulated material has no volume term "
            "(default: mu; from young and poisson, lambda scaled as mu is, so the modes keep their shapes). "
            "Above -2 mu / dim (a positive bulk modulus: a negative Poisson's ratio has a negative lam).",
            "stress",
            None,
        ),
        "young": Key(
            "float",
            None,
            "Young's modulus E (with poisson, instead of mu and lam): mu = E, so small strains stretch and bend "
            "as E does (with Poisson's ratio 0) where no muscles add their own stiffness (gamma); poisson "
            "shapes the linear (muscle) modes.",
            "stress",
            _positive,
        ),
        "poisson": Key(
            "float",
            None,
            "Poisson's ratio, in (-1, 0.5), and at most 0.499999995 (lam at most 1e8 mu: nearer 0.5 the shear "
            "stiffness that sets the lowest modes drowns in the round-off of the volume's).",
            "",
            lambda v: None if -1 < v < 0.5 else "a number in (-1, 0.5)",
        ),
        "rho": Key("float", 1e3, "Density.", "mass / volume", _positive),
    },
    "subspace": {
        "weights": Key(
            "int",
            8,
            "Skinning eigenmodes; the subspace has weights x (dim + 1) x dim coordinates.",
            check=_at_least_one,
        ),
        "clusters": Key("int", 20, "Rotation clusters of elements for the passive energy.", check=_at_least_one),
        "cluster_weights": Key(
            "int",
            None,
            "Cluster on the first this many skinning weights (default: weights), so clusters stay the same "
            "while the subspace size changes (with cluster_by = `rotations`, the muscles' clusters only: "
            "warned where that changes nothing).",
            check=_at_least_one,
        ),
        "active_clusters": Key("int", 1, "Rotation clusters for the muscle energy.", check=_at_least_one),
        "cluster_by": Key(
            "str",
            "weights",
            "What the passive clusters are made from: `weights` (spectral clusters of the skinning weights) or "
            "`rotations` (by how the subspace's lowest modes rotate the elements: more accuracy per cluster "
            "where few are used).",
            check=lambda v: None if v in ("weights", "rotations") else "'weights' or 'rotations'",
        ),
        "seed": Key("int", 0, "Seed of the k-means clustering (same seed, same clusters)."),
    },
    "muscles": {
        "count": Key(
            "int",
            4,
            "Muscles: the lowest linear modes after the rigid ones (with pinned "
            "vertices, the modes of the clamped body). 0 for none, as in a scene without a [muscles] section.",
            check=lambda v: None if v >= 0 else "an integer >= 0",
        ),
        "signs": Key(
            "ints",
            None,
            "Flip muscles: +1 or -1 each (modes have a deterministic sign; "
            "the caterpillar tutorial's gait uses [1, -1, -1, 1]).",
            check=_signs,
        ),
        "max_s": Key(
            "float",
            2.0,
            "Amplitude ceilings: a mode scaled by its ceiling changes some "
            "element's deformation gradient by max_s (Frobenius norm).",
            "",
            _positive,
        ),
        "table": Key(
            "str",
            None,
            "CSV file of activations over time (instead of gait), relative to the scene file: a header, then "
            "rows `time, a_1, ..., a_count`, each a fraction of the muscle's ceiling (beyond 1: a warning, as for "
            "the gait); linearly interpolated, held after the last row, and before the first (a warning says so "
            "when the first row is not at t = 0).",
        ),
        "gait": {
            "_optional": True,
            "amplitude": Key(
                "floats",
                None,
                "Per muscle: amplitude as a fraction of its ceiling. Beyond 1 (or -1) the muscle asks an element to "
                "deform by more than max_s: the run warns (CeilingWarning, in the terminal and summary.json's "
                "motion.warnings) and the motion monitor blames the muscles for what follows.",
                "",
                required=True,
            ),
            "period": Key("floats", None, "Per muscle: period.", "time", _positive_list, required=True),
            "phase": Key("floats", None, "Per muscle: phase, as a fraction of the period (default 0).", "periods"),
            "ramp": Key(
                "float",
                0.0,
                "Time over which the amplitudes grow from zero at the start (a smoothstep: its rate is zero "
                "at both ends), so that muscles starting mid-stroke do not kick a body at rest: the examples' "
                "creature made stiff (mu = 1e7) rose 5.8 times its height in its first second at h = 0.01 "
                "without one, 0.18 times with ramp = 1. "
                "0: full amplitude from the start (the tutorial's gait).",
                "time",
                _non_negative,
            ),
        },
    },
    "time": {
        "step": Key("float", 0.01, "Time step h.", "time", _positive),
        "duration": Key(
            "float",
            None,
            "Simulated time (default 4.5, or from steps); not a whole number of steps, it is rounded up to the "
            "next whole step, with a warning naming both keys.",
            "time",
            _positive,
        ),
        "steps": Key("int", None, "Number of steps (instead of duration).", check=_at_least_one),
        "iterations": Key("int", 10, "Local/global iterations per step, at most.", check=_iterations),
        "tol": Key(
            "float",
            TOL,
            "Stop a step's iterations when the last one moved the body by less than tol of its size "
            "(0: always run all iterations; use 0 for vibrations, damping and slow motions, whose steps the "
            "default stops after one or two iterations, damping them: docs/accuracy.md).",
            "",
            _non_negative,
        ),
        "rtol": Key(
            "float",
            0.0,
            "Also stop when the change of z is below rtol times the step's motion (0: off).",
            "",
            _non_negative,
        ),
        "etol": Key(
            "float",
            0.0,
            "Also stop when the step energy changed by at most etol times its change since the step's first "
            "iterate (0: off; evaluates the energy at every iterate).",
            "",
            _non_negative,
        ),
        "warm_start": Key(
            "bool",
            False,
            "Start each step's iterations from the inertial prediction z + h z_dot (the same answer in fewer "
            "iterations; with Coulomb friction the slides' directions settle along the iterations, so a nearby "
            "one: docs/accuracy.md; not under the reference contact model, whose rule reads the iterates: there "
            "it does nothing, and a warning says so).",
        ),
        "acceleration": Key(
            "str",
            "none",
            "Accelerated iterations: `none`, `anderson` or `newton` (fewer iterations, more work each; "
            "not under contact, where a warning says so; docs/accuracy.md).",
            check=lambda v: None if v in ("none", "anderson", "newton") else "'none', 'anderson' or 'newton'",
        ),
    },
    "gravity": {
        "_effect": True,
        "acceleration": Key(
            "floats", None, "Gravitational acceleration vector, one value per axis.", "length / time^2", required=True
        ),
    },
    "ground": {
        "_effect": True,
        "height": Key(
            "float",
            None,
            "Height of the ground plane along the up axis (at most the contact's allowance, 2e-4 of the body's size "
            f"by default, or of {THIN_WORDS}, above its lowest point: a body starting deeper "
            "would be flung out).",
            "length",
        ),
        "offset": Key(
            "float",
            None,
            "Instead of height: put the ground this far below the mesh's lowest point (default 0).",
            "length",
            _non_negative,
        ),
        "up": Key(
            "int",
            None,
            "Index of the up axis (default: the axis gravity pulls down along; without gravity the last, "
            "y in 2D, z in 3D). Gravity must have a component along -up: a zero gravity.acceleration with a "
            "ground is an error (remove [gravity] for none).",
        ),
        "model": Key(
            "str",
            "coulomb",
            '"coulomb" (the default): no vertex ever ends a step below the ground, and Coulomb friction '
            'holds the touching ones. "reference": the reference implementation\'s rule, velocities only at '
            "sampled contact points (vertices can end inside the ground), kept to reproduce its numbers.",
            check=lambda v: None if v in ("coulomb", "reference") else 'one of "coulomb", "reference"',
        ),
        "friction": Key(
            "float",
            None,
            'Coulomb coefficient (model "coulomb"; default 0.5): a touching vertex sticks while the tangential '
            "force it takes is at most this times its normal force, and slides against its motion otherwise.",
            "",
            _non_negative,
        ),
        "allowance": Key(
            "float",
            None,
            'How far below the ground a vertex may end a step, a share of the body\'s size (model "coulomb"; '
            f"default {ALLOWANCE:g}, from {LEAST_ALLOWANCE:g} to {MOST_ALLOWANCE:g}), or of {THIN_WORDS} if less. "
            "Larger is cheaper: fewer steps run their iterations again for a vertex they missed (docs/contact.md, "
            "what the allowance costs).",
            "",
            _allowance,
        ),
        "exact_friction": Key(
            "bool",
            None,
            'Model "coulomb" only (default true): each step\'s sliding vertices end with exact Coulomb friction, '
            "straight against their slides. false keeps the friction the active set fixed as each vertex started "
            "to slide (degrees off the slide, at most 90), for a cheaper step with friction (docs/contact.md, what "
            "it costs). 3D only: in 2D a slide has one direction, and its friction is exact either way (false is "
            "warned of).",
        ),
        "contacts": Key(
            "int|all",
            None,
            "Contact vertices: that many boundary vertices by farthest-point sampling, or all of them "
            '(default "all" with model "coulomb", 30 with "reference", as its tutorial). More than there are '
            "gives all of them: `skfem-modal info` and summary.json's sizes.contact_points say how many.",
            check=_contacts,
        ),
        "contacts_where": Key(
            "strs",
            None,
            "Take the contact vertices only among the boundary vertices where one of these conditions "
            'holds, e.g. ["z <= 0.1"] for the feet.',
            check=_some,
        ),
        "stickiness": Key(
            "float",
            None,
            'Model "reference" only (default 1): 1 removes the tangential velocity of contacting points, '
            "0 lets them slide freely.",
            "",
            _unit_interval,
        ),
        "push_out": Key(
            "float",
            None,
            'Model "reference" only (default 0: velocity only, points can end inside the ground). > 0: '
            "contact points may not end a step below the ground, and one inside climbs out by this fraction "
            "of its depth per step (1: in one step).",
            "",
            _unit_interval,
        ),
    },
    "pinned": {
        "_effect": True,
        "where": Key(
            "strs",
            None,
            'Conditions selecting the pinned vertices, e.g. ["x <= 0.01"] or '
            '["x == min"] (a vertex satisfying any one is pinned).',
            check=_some,
        ),
        "box": Key("table", None, "Instead of where: `{ min = [...], max = [...] }`, pin the vertices inside."),
        "stiffness": Key(
            "float",
            None,
            "Pin spring stiffness (default: 1e3 x the system's own stiffness scale).",
            "force / length",
            _positive,
        ),
    },
    "damping": {
        "_effect": True,
        "mass": Key(
            "float",
            0.0,
            "Mass-proportional Rayleigh damping alpha (damps all motion, like drag).",
            "1 / time",
            _non_negative,
        ),
        "stiffness": Key(
            "float",
            0.0,
            "Stiffness-proportional damping beta (damps the rate of deformation). Corotated: rigid motion, "
            "turning included, goes undamped; near rest it is Rayleigh damping beta K, a mode of frequency "
            "omega damped with the ratio beta omega / 2 (with converged steps: time.tol = 0 for a slow "
            "vibration). It stiffens each step by 1 + beta / h: where that "
            "makes an elastic wave cross more than 0.2 of the body a step (warned), the iterations turn it too "
            "slowly and a spin is damped after all (beta = 1, h = 0.005: stopped dead at 10 iterations a step; "
            "kept with warm_start or 50 iterations).",
            "time",
            _non_negative,
        ),
    },
    "output": {
        "every": Key("int", 1, "Write every k-th frame (the command's --every overrides).", check=_at_least_one),
    },
}

#: The built-in scene: the tutorial's caterpillar crawling on the ground.
DEFAULT_SCENE: dict[str, Any] = {
    "name": "caterpillar crawl (the tutorial's scene)",
    "mesh": {"shape": "caterpillar", "params": {}},
    "material": {"mu": 1e6, "gamma": 1e6, "rho": 1e3},
    "subspace": {"weights": 8, "clusters": 20, "seed": 0},
    "muscles": {
        "count": 4,
        "signs": [1, -1, -1, 1],
        "gait": {"amplitude": [0.45, 0.35, 0.25, 0.15], "period": [1.2, 0.8, 1.0, 0.6], "phase": [0.0, 0.25, 0.5, 0.1]},
    },
    "time": {"step": 0.01, "steps": 450},
    "gravity": {"acceleration": [0.0, -9.8]},
    "ground": {"offset": 0.15, "model": "reference", "stickiness": 1.0, "contacts": 30},
    "output": {"every": 5},
}


def read_scene_file(path) -> dict:
    """A scene file's tables, unvalidated (:meth:`Scene.from_toml` validates them).

    Parameters
    ----------
    path : str or path-like
        A scene file: TOML in UTF-8 (a byte-order mark is skipped).

    Returns
    -------
    data : dict
        The file's tables, as :mod:`tomllib` reads them.

    Raises
    ------
    FileNotFoundError
        No such file.
    IsADirectoryError
        ``path`` is a folder.
    SceneError
        Not UTF-8, or not valid TOML; the message names the file and where.
    """
    path = os.fspath(path)
    if os.path.isdir(path):
        raise IsADirectoryError(f"scene file {path!r} is a folder: give the .toml file in it")
    if not os.path.isfile(path):
        raise FileNotFoundError(f"scene file not found: {path!r}")
    suffix = os.path.splitext(path)[1].lower()
    hint = (
        f" (a {suffix} file is not a scene: to simulate a mesh, write a scene whose [mesh] file names it, "
        "see docs/scenes.md)"
        if suffix != ".toml"
        else ""
    )
    with open(path, "rb") as f:
        data = f.read()
    try:
        text = data.decode("utf-8-sig")  # (a byte-order mark, as some editors write, is skipped)
    except UnicodeDecodeError as err:
        raise SceneError(
            f"{path}: not UTF-8 text (byte {err.start} is {data[err.start : err.start + 1]!r}): a scene file is "
            f"TOML in UTF-8; save it as UTF-8{hint}"
        ) from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise SceneError(f"{path}: not valid TOML: {err}{hint}") from None


#: The full-space reference's absolute stop: changes of this fraction of the body's size are round-off.
REFERENCE_FLOOR = 1e-13

#: The keys whose values are file paths, relative to the scene file's folder (section, key).
PATH_KEYS = (("mesh", "file"), ("muscles", "table"))


def resolve_paths(data: dict, base_dir: str | None = None) -> dict:
    """A copy of a scene dict whose file paths (:data:`PATH_KEYS`) are absolute, so it reads the same from anywhere.

    Parameters
    ----------
    data : dict
        A scene, as the TOML file's tables.
    base_dir : str, optional
        Where its relative paths start: the scene file's folder (default: the current directory).

    Returns
    -------
    data : dict
        A deep copy; values that are not strings are left for validation to name.

    Examples
    --------
    >>> resolve_paths({"mesh": {"file": "seal.mesh"}}, "/scenes")["mesh"]["file"]
    '/scenes/seal.mesh'
    >>> resolve_paths({"muscles": {"table": "/data/steer.csv"}}, "/scenes")["muscles"]["table"]
    '/data/steer.csv'
    """
    data = copy.deepcopy(data)
    base_dir = os.path.abspath(base_dir or os.getcwd())
    for section, key in PATH_KEYS:
        table = data.get(section) if isinstance(data, dict) else None
        if isinstance(table, dict) and isinstance(table.get(key), str):
            table[key] = os.path.join(base_dir, table[key])  # an absolute path stays as it is
    return data


#: The simulated time of a scene that gives neither time.duration nor time.steps.
DEFAULT_DURATION = 4.5
#: Steps a scene may run, at most (at a millisecond a step, more than a day)
MAX_STEPS = 100_000_000
#: A duration within this fraction of a whole number of steps is that number (0.1 / 0.01 is 10.000000000000002).
_WHOLE = 1e-9


def _steps_covering(duration: float, step: float) -> int:
    """The fewest steps of ``step`` that reach ``duration`` (a whole number up to round-off is kept)."""
    nearest = round(duration / step)
    if abs(nearest * step - duration) <= _WHOLE * duration:
        return max(1, int(nearest))
    return max(1, math.ceil(duration / step))


_DIM_OF_SHAPE = {"caterpillar": 2, "beam2d": 2, "beam3d": 3, "box3d": 3, "creature": 3}


def _type_name(value) -> str:
    return type(value).__name__


def _coerce(kind: str, value, path: str, errors: list[str]):
    """The value as the key's kind, or record an error."""

    def bad(expected):
        errors.append(f"{path}: expected {expected}, got {value!r} ({_type_name(value)})")
        return None

    # numpy's numbers and arrays are a script's numbers and lists
    if isinstance(value, np.generic):
        value = value.item()
    elif isinstance(value, (tuple, np.ndarray)) and kind in ("floats", "ints", "strs"):
        value = np.asarray(value).tolist() if isinstance(value, np.ndarray) else list(value)
        value = [v.item() if isinstance(v, np.generic) else v for v in value]

    is_number = isinstance(value, (int, float)) and not isinstance(value, bool)
    if kind == "float":
        if not is_number or not is_finite_real(value):
            return bad("a finite number")
        return float(value)
    if kind == "int":
        if isinstance(value, bool) or not isinstance(value, int):
            return bad("an integer")
        return value
    if kind == "bool":
        return value if isinstance(value, bool) else bad("true or false")
    if kind == "str":
        return value if isinstance(value, str) else bad("a string")
    if kind == "int|all":
        return (
            value
            if (value == "all" or (isinstance(value, int) and not isinstance(value, bool)))
            else bad('an integer or "all"')
        )
    if kind in ("floats", "ints", "strs"):
        items = value if isinstance(value, list) else None
        if items is None:
            return bad("a list")
        if kind == "floats":
            if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and is_finite_real(v) for v in items):
                return bad("a list of finite numbers")
            return [float(v) for v in items]
        if kind == "ints":
            if not all(isinstance(v, int) and not isinstance(v, bool) for v in items):
                return bad("a list of integers")
            return list(items)
        if not all(isinstance(v, str) for v in items):
            return bad("a list of strings")
        return list(items)
    if kind == "table":
        return value if isinstance(value, dict) else bad("a table")
    raise AssertionError(kind)


def _validate_table(schema: dict, data, path: str, errors: list[str]) -> dict:
    if not isinstance(data, dict):
        errors.append(f"{path or 'scene'}: expected a table, got {data!r}")
        return _validate_table(schema, {}, path, [])  # its defaults: the checks across keys read them
    out = {}
    known = [k for k in schema if not k.startswith("_")]
    for key in data:
        if key not in known:
            where = f"{path}.{key}" if path else key
            errors.append(f"{where}: unknown key; expected one of {', '.join(known)}")
    for key in known:
        spec = schema[key]
        where = f"{path}.{key}" if path else key
        if isinstance(spec, dict):
            optional = spec.get("_effect") or spec.get("_optional")
            if optional and data.get(key) is None:  # absent, or null as summary.json writes an absent one
                out[key] = None
            elif key in data:
                out[key] = _validate_table(spec, data[key], where, errors)
            else:
                out[key] = _validate_table(spec, {}, where, errors)
            continue
        if data.get(key) is None:  # absent, or null (a dict's or summary.json's way to say so)
            if spec.required:
                errors.append(f"{where}: required")
            out[key] = spec.default
            continue
        value = _coerce(spec.kind, data[key], where, errors)
        if value is not None and spec.check is not None:
            problem = spec.check(value)
            if problem:
                errors.append(f"{where}: expected {problem}, got {data[key]!r}")
                value = None
        out[key] = value
    return out


def _all_numbers(cells) -> bool:
    """Whether every non-blank cell of a CSV row is a number."""
    filled = [cell for cell in cells if cell.strip()]
    try:
        [float(cell) for cell in filled]
    except ValueError:
        return False
    return bool(filled)


def _read_table(path: str, count: int, errors: list[str]):
    """Activation table: (times (k,), values (k, count)), or None with an error recorded."""
    where = "muscles.table"
    if not os.path.isfile(path):
        errors.append(f"{where}: no such file {path!r}")
        return None
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            return _parse_table(f, path, count, errors, where)
    except UnicodeDecodeError as err:
        errors.append(f"{where}: {path!r} is not UTF-8 text (byte {err.start}): save the table as UTF-8 CSV")
        return None


def _parse_table(f, path: str, count: int, errors: list[str], where: str):
    """:func:`_read_table`'s reading of the open file ``f`` (``where``: the key that names it, for the errors)."""
    rows = []
    reader = csv.reader(f)
    header = next(reader, None)
    if header is None:
        errors.append(f"{where}: {path!r} is empty")
        return None
    if _all_numbers(header):  # read as the header, the first row of values would be lost
        errors.append(
            f"{where}: {path!r} line 1 holds numbers, not a header: the table's first line names its "
            f"columns (e.g. time,{','.join(f'a{k + 1}' for k in range(count))})"
        )
        return None
    for line, row in enumerate(reader, start=2):
        if not any(cell.strip() for cell in row):
            continue
        if len(row) != count + 1:
            errors.append(
                f"{where}: {path!r} line {line} has {len(row)} columns, expected {count + 1} (time and one per muscle)"
            )
            return None
        try:
            rows.append([float(cell) for cell in row])
        except ValueError:
            errors.append(f"{where}: {path!r} line {line} holds a value that is not a number: {row}")
            return None
    if not rows:
        errors.append(f"{where}: {path!r} has no rows after its header")
        return None
    data = np.array(rows)
    if not np.all(np.isfinite(data)):
        errors.append(f"{where}: {path!r} holds non-finite values")
        return None
    if np.any(np.diff(data[:, 0]) <= 0):
        errors.append(f"{where}: {path!r} times must increase strictly")
        return None
    return data[:, 0], data[:, 1:]


@dataclass
class Scene:
    """A validated scene and the mesh it names.

    Build with :meth:`from_toml`, :meth:`from_dict` or :meth:`default`; the
    constructor checks everything (types, ranges, files, the mesh itself,
    lengths that depend on the mesh's dimension) and raises one
    :class:`SceneError` listing every problem.

    Attributes
    ----------
    config : dict
        Every key, defaults filled in (effects absent are ``None``).
    mesh : skfem.MeshTri or skfem.MeshTet
    source : str
        Where the scene came from (a path, or "built-in").
    placement : dict
        Where ``mesh.normalize`` and ``mesh.scale`` put the mesh read: its vertices at
        ``factor * (x - centre)`` of where the file (or shape) has them, after ``mesh.flip``
        (``centre``: a list of dim floats). Every length of the scene and of a run's outputs is
        of the mesh so placed.
    """

    config: dict
    mesh: Any = field(repr=False)
    source: str = "dict"
    _table: Any = field(default=None, repr=False)
    placement: dict = field(default_factory=dict)

    # ------------------------------------------------------------ loading
    @classmethod
    def from_toml(cls, path) -> Scene:
        """Load and validate the scene file (TOML) at ``path``, a :class:`Scene`; its paths are read from its folder."""
        path = os.fspath(path)
        return cls.from_dict(read_scene_file(path), base_dir=os.path.dirname(os.path.abspath(path)), source=path)

    @classmethod
    def default(cls) -> Scene:
        """The built-in scene: the tutorial's caterpillar crawl."""
        return cls.from_dict(DEFAULT_SCENE, source="built-in")

    @classmethod
    def from_dict(cls, data: dict, base_dir: str | None = None, source: str = "dict") -> Scene:
        """Validate a scene given as nested dicts (the same keys as the TOML file).

        Parameters
        ----------
        data : dict
            The scene's sections and keys (docs/scenes.md).
        base_dir : str, optional
            Where its file paths are read from (default: the current directory;
            :func:`resolve_paths`); they are held absolute in ``config``.
        source : str
            What the scene came from, for messages; :meth:`to_dict`'s ``source`` key is
            taken instead (a run's ``summary.json`` scene builds again).

        Returns
        -------
        scene : Scene

        Raises
        ------
        SceneError
            Naming every key with a problem, one a line, before anything is built.
        """
        errors: list[str] = []
        if isinstance(data, dict) and "source" in data:
            data = dict(data)
            given = data.pop("source")
            if not isinstance(given, str):  # (any value was taken, and dropped, without a word)
                errors.append(f"source: expected the path the scene was read from (a string), got {given!r}")
            source = given if source == "dict" and isinstance(given, str) else source
        config = _validate_table(SCHEMA, resolve_paths(data, base_dir), "", errors)
        if isinstance(data, dict) and data.get("muscles") is None:
            # an effect the scene does not name is not simulated (4 muscles at rest stiffened such a body)
            config["muscles"]["count"] = 0
        mesh, placement = None, {}
        table = None
        # every problem at once: the mesh is built when its own keys are right,
        # and the checks across keys run whatever else is wrong
        if not any(e.split(":", 1)[0].split(".", 1)[0] == "mesh" for e in errors):
            mesh, placement = _build_mesh(config["mesh"], errors)
        _check_cross(config, mesh, errors)
        muscles = config["muscles"]
        if muscles["table"] is not None and muscles["count"]:  # (without muscles: said by unused_warning)
            table = _read_table(muscles["table"], muscles["count"], errors)
        if errors:
            head = f"{source}: " if source not in ("dict", "built-in") else ""
            raise SceneError(f"{head}{len(errors)} problem(s) in the scene:\n  " + "\n  ".join(errors))
        scene = cls(config=config, mesh=mesh, source=source, _table=table, placement=placement)
        message = scene.scale_warning()
        if message:
            warnings.warn(message, ScaleWarning, stacklevel=2)
        for message in (
            scene.duration_warning(),
            scene.table_warning(),
            scene.unused_warning(),
            *scene.idle_warnings(),
        ):
            if message:
                warnings.warn(message, UserWarning, stacklevel=2)
        return scene

    # ---------------------------------------------------------- properties
    @property
    def dim(self) -> int:
        """The mesh's dimension, 2 or 3."""
        return self.mesh.p.shape[0]

    @property
    def h(self) -> float:
        """The time step (``time.step``)."""
        return self.config["time"]["step"]

    @property
    def n_steps(self) -> int:
        """``time.steps``, or enough steps of ``time.step`` to cover ``time.duration`` (rounded up)."""
        t = self.config["time"]
        if t["steps"] is not None:
            return t["steps"]
        return _steps_covering(DEFAULT_DURATION if t["duration"] is None else t["duration"], t["step"])

    def duration_warning(self) -> str | None:
        """Why the run is longer than ``time.duration`` (not a whole number of steps), or None."""
        t = self.config["time"]
        if t["steps"] is not None or t["duration"] is None:
            return None
        n = self.n_steps
        if n * t["step"] - t["duration"] <= _WHOLE * t["duration"]:
            return None
        return (
            f"time.duration = {t['duration']!r} is not a whole number of time.step = {t['step']!r}: running "
            f"{n} steps, to t = {n * t['step']:g} (the duration rounded up to a whole step; give time.steps "
            "for an exact count)"
        )

    def table_warning(self) -> str | None:
        """Why the muscles' table acts before its first row's time (it does not start at 0), or None.

        The first row is held from t = 0: a body at rest gets it at once (an audit: a table starting
        at t = 2 kicked the body at its first step, unsaid).
        """
        if self._table is None or not self._table[0][0] > 0.0:
            return None
        times = self._table[0]
        return (
            f"muscles.table {os.path.basename(self.config['muscles']['table'])!r} starts at t = {times[0]:g}, not 0: "
            "its first row is held from t = 0, so the muscles take it at the first step (add a row at t = 0 to "
            "start from rest)"
        )

    def idle_warnings(self) -> list[str]:
        """Why each of ``time.warm_start`` and ``time.acceleration`` that is on does nothing under the scene's ground;
        and settings given that change nothing in this scene (``ground.exact_friction = false`` in 2D,
        ``subspace.cluster_weights`` with passive clusters by rotations, a zero ``gravity.acceleration``).

        The simulator says the same as it is built (:func:`~skfem_modal.sim.idle_settings`); the scene says it
        to a command that builds none (``skfem-modal info``).
        """
        from .sim import idle_settings

        c = self.config
        model = None if c["ground"] is None else c["ground"]["model"]
        said = idle_settings(c["time"]["acceleration"], c["time"]["warm_start"], model)
        # settings that change nothing in this scene (an audit: both were silently ignored)
        if self.dim == 2 and c["ground"] is not None and c["ground"]["exact_friction"] is False:
            said.append(
                "ground.exact_friction = false changes nothing in 2D: a slide has one direction along the ground, "
                "and its friction is exact either way"
            )
        if c["gravity"] is not None and not np.any(c["gravity"]["acceleration"]):
            said.append("gravity.acceleration is zero: the gravity effect does nothing (leave [gravity] out)")
        sub = c["subspace"]
        if sub["cluster_by"] == "rotations" and sub["cluster_weights"] is not None:
            muscle_clusters = c["muscles"]["count"] and sub["active_clusters"] > 1
            said.append(
                f'subspace.cluster_weights = {sub["cluster_weights"]}: with cluster_by = "rotations" the passive '
                "clusters come from the modes' rotations, so it shapes "
                + ("the muscles' clusters only" if muscle_clusters else "nothing here (one muscle cluster, or none)")
            )
        return said

    def unused_warning(self) -> str | None:
        """Which muscle settings a scene without muscles (``muscles.count = 0``) gives for nothing, or None."""
        c = self.config
        if c["muscles"]["count"] != 0:
            return None
        given = [f"material.{k}" for k in ("gamma", "lam") if c["material"][k] is not None]
        given += [f"muscles.{k}" for k in ("signs", "gait", "table") if c["muscles"][k] is not None]
        for section, key in (("subspace", "active_clusters"), ("muscles", "max_s")):
            if c[section][key] != SCHEMA[section][key].default:
                given.append(f"{section}.{key}")
        if not given:
            return None
        return (
            f"muscles.count = 0: the scene has no muscles, so {', '.join(given)} "
            f"{'changes' if len(given) == 1 else 'change'} nothing (give muscles.count to use them)"
        )

    @property
    def effects(self) -> tuple:
        """The effects the scene names, in the simulator's order."""
        names = ["elasticity", "inertia"]
        if self.config["muscles"]["count"]:
            names.append("muscles")
        # the model's order: contact last (info said it before the pins and damping)
        for key in ("gravity", "pinned", "damping", "ground"):
            if self.config[key] is not None:
                names.append("contact" if key == "ground" else key)
        return tuple(names)

    def material(self) -> dict:
        """``mu``, ``gamma``, ``lam``, ``rho`` with defaults resolved."""
        return _material(self.config["material"])

    def scale_warning(self) -> str | None:
        """Why the mesh's size and the material's length scales are far apart (wrong units?), or None.

        See :func:`~skfem_modal.units.scale_mismatch`; :meth:`from_dict` warns
        with it (:class:`~skfem_modal.units.ScaleWarning`).
        """
        spec = self.config["mesh"]
        name = os.path.basename(spec["file"]) if spec["file"] else (spec["shape"] or "caterpillar")
        gravity = self.config["gravity"]
        mat = self.material()
        return scale_mismatch(
            self.mesh,
            mat["mu"],
            mat["rho"],
            None if gravity is None else gravity["acceleration"],
            self.n_steps * self.h,
            what=f"mesh {name!r}",
            h=self.h,
            damping_stiffness=(self.config["damping"] or {}).get("stiffness") or 0.0,
        )

    def ground_height(self) -> float | None:
        """The ground's height along :attr:`up`: ``ground.height``, or ``ground.offset`` below the lowest vertex.

        None without a ground.
        """
        g = self.config["ground"]
        if g is None:
            return None
        if g["height"] is not None:
            return g["height"]
        return float(self.mesh.p[self.up].min()) - (g["offset"] or 0.0)

    @property
    def up(self) -> int:
        """The up axis: ``ground.up``, or the axis gravity pulls down along (:func:`~skfem_modal.units.up_axis`)."""
        g = self.config["ground"]
        gravity = self.config["gravity"]
        acceleration = None if gravity is None else gravity["acceleration"]
        return up_axis(acceleration, self.dim, None if g is None else g["up"], ground=g is not None)

    def contact_candidates(self) -> np.ndarray | None:
        """The vertices ``ground.contacts_where`` selects, shape (k,), or None (without it: every vertex)."""
        g = self.config["ground"]
        if g is None or g["contacts_where"] is None:
            return None
        return _candidates(g["contacts_where"], self.mesh)

    def contact_vertices(self) -> np.ndarray | None:
        """The contact vertices the simulator will use (as :meth:`build` samples them), or None without a ground.

        ``ground.contacts`` larger than the boundary vertices available (those
        where ``contacts_where`` holds, if given) gives all of them.

        Returns
        -------
        vertices : ndarray of int, shape (k,), or None
        """
        if self.config["ground"] is None:
            return None
        from .mesh import sample_boundary

        return sample_boundary(self.mesh, self.contact_count(), self.contact_candidates())

    def pinned_vertices(self) -> np.ndarray | None:
        """The pinned vertices (``[pinned]``), shape (k,), or None without pins."""
        p = self.config["pinned"]
        if p is None:
            return None
        return _pinned(p, self.mesh)

    # ------------------------------------------------------------ building
    def effect_settings(self) -> dict:
        """The material and effect arguments the reduced simulator and the reference share.

        Returns
        -------
        settings : dict
            Keyword arguments of :class:`~skfem_modal.sim.ModalMuscle` (and
            :class:`~skfem_modal.reference.FullSpaceSimulator`): ``mu``,
            ``gamma``, ``rho``, ``h``, ``gravity``, ``ground``, ``up``,
            ``contact_model``, ``friction``, ``allowance``, ``exact_friction``,
            ``stickiness``, ``push_out``, ``pinned``, ``pin_stiffness``,
            ``damping_mass``, ``damping_stiffness``, ``max_s``.
        """
        c = self.config
        mat = self.material()
        ground = c["ground"]
        damping = c["damping"] or {"mass": 0.0, "stiffness": 0.0}
        return dict(
            mu=mat["mu"],
            gamma=mat["gamma"],
            rho=mat["rho"],
            h=self.h,
            gravity=None if c["gravity"] is None else c["gravity"]["acceleration"],
            ground=self.ground_height(),
            up=self.up,
            contact_model="coulomb" if ground is None else ground["model"],
            friction=None if ground is None else ground["friction"],
            allowance=None if ground is None else ground["allowance"],
            exact_friction=None if ground is None else ground["exact_friction"],
            stickiness=None if ground is None else ground["stickiness"],
            push_out=None if ground is None else ground["push_out"],
            pinned=self.pinned_vertices(),
            pin_stiffness=None if c["pinned"] is None else c["pinned"]["stiffness"],
            damping_mass=damping["mass"],
            damping_stiffness=damping["stiffness"],
            max_s=c["muscles"]["max_s"],
        )

    def contact_count(self) -> int | None:
        """Contact vertices to sample (None: every boundary vertex); None without a ground too."""
        ground = self.config["ground"]
        if ground is None or ground["contacts"] == "all":
            return None
        if ground["contacts"] is None:
            return DEFAULT_CONTACTS[ground["model"]]
        return ground["contacts"]

    def build(self, progress=None, backend: str = "auto"):
        """The simulator holding exactly the effects this scene names.

        Parameters
        ----------
        progress : callable, optional
            Called with the name of each precompute stage.
        backend : {"auto", "numpy", "numba", "plain"}

        Returns
        -------
        sim : skfem_modal.sim.ModalMuscle
        """
        from .sim import ModalMuscle

        c = self.config
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ScaleWarning)  # said when the scene was loaded, as are these
            for message in self.idle_warnings():
                warnings.filterwarnings("ignore", message=re.escape(message), category=UserWarning)
            return ModalMuscle.from_mesh(
                self.mesh,
                n_muscles=c["muscles"]["count"],
                muscle_signs=c["muscles"]["signs"],
                n_weights=c["subspace"]["weights"],
                cluster_weights=c["subspace"]["cluster_weights"],
                n_clusters=c["subspace"]["clusters"],
                n_active_clusters=c["subspace"]["active_clusters"],
                seed=c["subspace"]["seed"],
                lam=self.material()["lam"],
                # not asked for (None): the model's default, which a switch of model then follows
                n_contacts=None if c["ground"] is None else c["ground"]["contacts"],
                contact_candidates=self.contact_candidates(),
                max_iter=c["time"]["iterations"],
                tol=c["time"]["tol"],
                rtol=c["time"]["rtol"],
                etol=c["time"]["etol"],
                warm_start=c["time"]["warm_start"],
                acceleration=c["time"]["acceleration"],
                cluster_by=c["subspace"]["cluster_by"],
                progress=progress,
                backend=backend,
                **self.effect_settings(),
            )

    def build_reference(self, rtol: float = 1e-10, max_iter: int = 5000):
        """The full-space simulator of this scene: every DOF, one rotation per element.

        Same muscles (the scene's modes and signs, and the muscle clusters :meth:`build`
        makes: one per connected part at least), material, effects and contact points
        (sampled as :meth:`build` does), iterated to ``rtol`` (or to round-off,
        :data:`REFERENCE_FLOOR` of the body's size, for a step that barely moves).

        Parameters
        ----------
        rtol : float
            A step stops when its last change is below ``rtol`` times its motion.
        max_iter : int
            Iterations a step, at most.

        Returns
        -------
        ref : skfem_modal.reference.FullSpaceSimulator
        """
        from .ingredients import active_clusters, skinning_subspace
        from .mesh import connected_labels
        from .modal import muscle_modes
        from .reference import FullSpaceSimulator

        c = self.config
        sub = c["subspace"]
        active = None
        several = max(sub["active_clusters"], int(connected_labels(self.mesh).max()) + 1) > 1
        if c["muscles"]["count"] and several:
            # the reduced model's muscle clusters (a mesh of two bodies has two: with one, the reference's
            # muscles were another model's, and a study's error 12.5 % where it is 4.3 %)
            weights = skinning_subspace(self.mesh, sub["weights"], sub["cluster_weights"])[0]
            weights = weights[:, : sub["cluster_weights"] or sub["weights"]]  # what build clusters by
            active = active_clusters(self.mesh, weights, sub["active_clusters"], sub["seed"])
        mat = self.material()
        settings = self.effect_settings()
        D = muscle_modes(
            self.mesh,
            c["muscles"]["count"],
            mu=mat["mu"],
            lam=mat["lam"],
            rho=mat["rho"],
            pinned=settings["pinned"],
            signs=c["muscles"]["signs"] if c["muscles"]["count"] else None,
        )
        return FullSpaceSimulator(
            self.mesh,
            D,
            active_labels=active,
            contact_vertices=self.contact_vertices(),
            max_iter=max_iter,
            # round-off's floor: a step that does not move (at rest, no muscles yet) met no relative rule
            # and ran all 5000 iterations at a change of 1e-16, reported as not settled (an audit)
            tol=REFERENCE_FLOOR,
            rtol=rtol,
            **settings,
        )

    @property
    def ramp(self) -> float:
        """Time over which the gait's amplitudes grow from zero (``muscles.gait.ramp``; 0 without a gait)."""
        gait = self.config["muscles"]["gait"]
        return 0.0 if gait is None else float(gait["ramp"])

    def activation(self, t: float, ceilings) -> np.ndarray:
        """Muscle activations at time ``t`` in mode-amplitude units, shape (count,).

        The same arithmetic as :func:`~skfem_modal.muscles.sine_gait` with
        amplitudes ``fraction * ceiling``, so a scene and a script that use
        ``sine_gait`` step bit for bit the same (contact-rich motion is chaotic:
        round-off differences grow).

        Parameters
        ----------
        t : float
            Time.
        ceilings : ndarray, shape (count,)
            The muscles' amplitude ceilings (``sim.ceilings``).

        Returns
        -------
        a : ndarray, shape (count,)
        """
        muscles = self.config["muscles"]
        gait = muscles["gait"]
        if self._table is None and gait is not None and muscles["count"]:
            phase = np.zeros(muscles["count"]) if gait["phase"] is None else gait["phase"]
            amplitudes = np.asarray(gait["amplitude"], dtype=np.float64) * ceilings
            return _sine(
                t,
                amplitudes,
                np.asarray(gait["period"], dtype=np.float64),
                np.asarray(phase, dtype=np.float64),
                gait["ramp"],
            )
        return self.activation_fractions(t) * ceilings

    def shortest_period(self) -> float | None:
        """The shortest period of the sine gait's moving muscles (amplitude not 0), or None (no such gait)."""
        muscles = self.config["muscles"]
        gait = muscles["gait"]
        if self._table is not None or gait is None or not muscles["count"]:
            return None
        return shortest_period(gait["amplitude"], gait["period"])

    def activation_fractions(self, t: float) -> np.ndarray:
        """Muscle activations at time ``t`` as fractions of the ceilings, shape (count,)."""
        muscles = self.config["muscles"]
        m = muscles["count"]
        if self._table is not None:
            times, values = self._table
            return np.array([np.interp(t, times, values[:, k]) for k in range(m)])
        gait = muscles["gait"]
        if gait is None or m == 0:
            return np.zeros(m)
        phase = np.zeros(m) if gait["phase"] is None else gait["phase"]
        return _sine(t, np.asarray(gait["amplitude"]), np.asarray(gait["period"]), np.asarray(phase), gait["ramp"])

    def to_dict(self) -> dict:
        """The validated configuration, JSON-ready (for summary.json): a copy, to change for a variant."""
        return copy.deepcopy({"source": self.source, **self.config})  # (its tables were the scene's own)


def _material(m: dict) -> dict:
    """``mu``, ``gamma``, ``lam``, ``rho`` of a validated [material] section, defaults resolved.

    From ``young`` and ``poisson``: ``mu = E``, the ARAP stiffness whose small strains are those of Young's
    modulus E (with Poisson's ratio 0, all ARAP has), and ``lam`` the Lame lambda times ``E / mu_Lame``, so
    that the linear modes made with ``(mu, lam)`` have the shapes of ``(mu_Lame, lambda)``.
    """
    if m["young"] is not None:
        from .fem import lame_parameters

        shear, lam = lame_parameters(m["young"], m["poisson"])
        mu, lam = m["young"], lam * m["young"] / shear
    else:
        mu = 1e5 if m["mu"] is None else m["mu"]
        lam = mu if m["lam"] is None else m["lam"]
    gamma = mu if m["gamma"] is None else m["gamma"]
    return {"mu": mu, "gamma": gamma, "lam": lam, "rho": m["rho"]}


def _check_bulk_modulus(config: dict, mesh, errors: list[str]) -> None:
    """A ``material.lam`` (or ``poisson``) given must leave the modes' material elastic (the stiffness's own check)."""
    from .fem import _lame

    given = config["material"]
    material = _material(given)
    key = "lam" if given["lam"] is not None else "poisson" if given["poisson"] is not None else None
    if key is not None:  # (lam from poisson, scaled as mu is: a ratio near 0.5 makes it too large for mu)
        try:
            _lame(mesh, material["mu"], material["lam"])
        except ValueError as err:
            errors.append(f"material.{key} = {_toml_value(given[key])}: {err}")


def _check_float_range(config: dict, mesh, gravity, errors: list[str]) -> None:
    """The material, time step and gravity must make operators float64 can hold on this mesh, named by key."""
    m = config["material"]
    material = _material(m)
    young = m["young"] is not None
    keys = {
        "mu": ("material.young", m["young"]) if young else ("material.mu", material["mu"]),
        "gamma": ("material.gamma", m["gamma"]),
        "rho": ("material.rho", material["rho"]),
        "h": ("time.step", config["time"]["step"]),
        "gravity": ("gravity.acceleration", gravity),
    }
    problems = float_range_problems(
        mesh,
        mu=material["mu"],
        rho=material["rho"],
        h=config["time"]["step"],
        gravity=gravity,
        gamma=m["gamma"],
        free=config["pinned"] is None,
    )
    for names, text in problems:
        said = " and ".join(f"{keys[n][0]} = {_toml_value(keys[n][1])}" for n in names)
        errors.append(f"{said}: {text} on this mesh")


def _build_mesh(spec: dict, errors: list[str]):
    """The scene's mesh, read and placed, and its placement (:class:`Scene`); (None, {}) when it has problems."""
    mesh = _read_mesh(spec, errors)
    if mesh is None:
        return None, {}
    centre, factor = np.zeros(mesh.p.shape[0]), 1.0
    if spec["normalize"]:
        centre, factor = normalizing_transform(mesh)
        mesh = normalize_and_center(mesh)
    if spec["scale"] != 1.0:
        # named by the key that did it, with the scene's other problems (it was the mesh's own bare message)
        scale = float(spec["scale"])  # (Python floats: an overflow is inf, without numpy's warnings)
        size, farthest = float(np.ptp(mesh.p, axis=1).max()) * scale, float(np.abs(mesh.p).max()) * scale
        if not (SIZE_RANGE[0] <= size and farthest <= SIZE_RANGE[1]):
            errors.append(
                f"mesh.scale = {_toml_value(spec['scale'])}: makes the mesh {size:.3g} across, with coordinates up "
                f"to {farthest:.3g}, outside the {SIZE_RANGE[0]:g} to {SIZE_RANGE[1]:g} its operators fit in float64"
            )
            return None, {}
        mesh = type(mesh)(mesh.p * spec["scale"], mesh.t.copy(), sort_t=False)
    return mesh, {"centre": centre.tolist(), "factor": factor * spec["scale"]}


def _read_mesh(spec: dict, errors: list[str]):
    """The mesh a scene's file or shape names, flipped as it says; None when it has problems."""
    if spec["shape"] is not None and spec["file"] is not None:
        errors.append("mesh: give either shape or file, not both")
        return None
    try:
        if spec["file"] is not None:
            if spec["params"]:
                errors.append("mesh.params: only for built-in shapes, not with mesh.file")
                return None
            path = spec["file"]  # absolute: resolve_paths
            if not os.path.isfile(path):
                what = "a folder, not a mesh file" if os.path.isdir(path) else "no such file"
                errors.append(f"mesh.file: {what} {path!r}")
                return None
            mesh = load_mesh(path, merge=spec["merge"])
        else:
            if spec["merge"]:
                errors.append("mesh.merge: only for mesh files, not built-in shapes (they share their vertices)")
                return None
            shape = spec["shape"] or "caterpillar"
            problems = shape_parameter_problems(shape, spec["params"])
            if problems:
                errors.extend(f"mesh.params.{key}: {text}" for key, text in problems)
                return None
            mesh = builtin_mesh(shape, **spec["params"])
    except (ValueError, TypeError) as err:
        errors.append(f"mesh: {err}")
        return None
    if spec["flip"]:
        if any("xyz".index(axis) >= mesh.p.shape[0] for axis in spec["flip"]):
            errors.append(f"mesh.flip: expected axes of this {mesh.p.shape[0]}D mesh, got {spec['flip']!r}")
            return None
        mesh = mirror(mesh, spec["flip"])
    return mesh


def _pinned(spec: dict, mesh) -> np.ndarray:
    if spec["where"] is not None:
        return np.unique(np.concatenate([vertices_where(mesh, cond) for cond in spec["where"]]))
    box = spec["box"]
    lo, hi = np.asarray(box["min"], float), np.asarray(box["max"], float)
    inside = np.all((mesh.p.T >= lo) & (mesh.p.T <= hi), axis=1)
    return np.nonzero(inside)[0]


def _candidates(conditions: list[str], mesh) -> np.ndarray:
    """The vertices where any of ``ground.contacts_where``'s conditions holds."""
    return np.unique(np.concatenate([vertices_where(mesh, cond) for cond in conditions]))


def _bad_condition(cond: str, dim: int) -> bool:
    match = _CONDITION.match(cond)
    return match is None or "xyz".index(match.group(1)) >= dim


def _check_cross(config: dict, mesh, errors: list[str]) -> None:
    """Checks that involve several keys or the mesh (skipped where a key involved is already wrong)."""
    flagged = {e.split(":", 1)[0] for e in errors}

    def valid(*paths):
        # a key is wrong when it or a section holding it was flagged
        return not any(p.rsplit(".", depth)[0] in flagged for p in paths for depth in range(p.count(".") + 1))

    mat = config["material"]
    if valid("material.young", "material.poisson") and (mat["young"] is None) != (mat["poisson"] is None):
        errors.append("material: young and poisson go together")
    if mat["young"] is not None and (mat["mu"] is not None or mat["lam"] is not None):
        errors.append("material: give mu (and lam) or young and poisson, not both")
    muscles = config["muscles"]
    m = muscles["count"]
    if mat["gamma"] == 0.0 and m:  # (muscles that pull with no force: a setting that would do nothing)
        errors.append(
            f"material.gamma: 0 leaves the {m} muscles without any force; give gamma > 0 (default: mu), or "
            "muscles.count = 0 for a passive body"
        )
    if m is not None and muscles["signs"] is not None and len(muscles["signs"]) != m:
        errors.append(f"muscles.signs: expected {m} values (muscles.count), got {len(muscles['signs'])}")
    gait = muscles["gait"]
    if gait is not None and muscles["table"] is not None:
        errors.append("muscles: give a gait or a table, not both")
    if gait is not None and m == 0:
        errors.append("muscles.gait: a gait for no muscles (muscles.count = 0): remove [muscles.gait], or give a count")
    elif gait is not None and m is not None:
        for key in ("amplitude", "period", "phase"):
            if gait[key] is not None and len(gait[key]) != m:
                errors.append(f"muscles.gait.{key}: expected {m} values (muscles.count), got {len(gait[key])}")
    t = config["time"]
    if t["steps"] is not None and t["duration"] is not None:
        errors.append("time: give duration or steps, not both")
    elif valid("time.step", "time.duration", "time.steps"):
        duration = DEFAULT_DURATION if t["duration"] is None else t["duration"]
        count = t["steps"] if t["steps"] is not None else duration / t["step"]
        if count > MAX_STEPS:  # a step of 1e-9 meant 4.5e9 steps, days of running, without a word
            what = "time.steps" if t["steps"] is not None else f"time.step = {t['step']:g} over {duration:g}"
            made = f"{count:.3g}" if count < 1e300 else "over 1e300"  # (an integer beyond a float: no format)
            errors.append(f"time: {what} makes {made} steps, more than {MAX_STEPS:.0e}: give a larger step")
    ground = config["ground"]
    if ground is not None and ground["height"] is not None and ground["offset"] is not None:
        errors.append("ground: give height or offset, not both")
    if ground is not None and valid("ground.model"):
        # each contact model takes only its own settings: none is silently ignored
        other = "reference" if ground["model"] == "coulomb" else "coulomb"
        for key in MODEL_SETTINGS[other]:
            if ground[key] is not None:
                errors.append(
                    f"ground.{key}: a setting of the other contact model, not of model = {ground['model']!r} "
                    f"(set ground.model = {'reference' if ground['model'] == 'coulomb' else 'coulomb'!r} to use it)"
                )
    damping = config["damping"]
    if (
        damping is not None
        and valid("damping.mass", "damping.stiffness")
        and not (damping["mass"] or damping["stiffness"])
    ):
        errors.append(
            "damping: expected mass (1 / time) or stiffness (time) above 0: a [damping] section switches damping "
            "on, so say how much (or remove the section)"
        )
    pinned = config["pinned"]
    if (
        pinned is not None
        and valid("pinned.where", "pinned.box")
        and (pinned["where"] is None) == (pinned["box"] is None)
    ):
        errors.append("pinned: give where (conditions) or box, exactly one")
    if mesh is None:
        return
    _check_against_mesh(config, mesh, errors, valid)


def _check_against_mesh(config: dict, mesh, errors: list[str], valid) -> None:
    """Checks of lengths, axes and sizes that depend on the mesh."""
    dim = mesh.p.shape[0]
    acc = None
    if config["gravity"] is not None:
        acc = config["gravity"]["acceleration"]
        if acc is not None and len(acc) != dim:
            errors.append(f"gravity.acceleration: expected {dim} values for this {dim}D mesh, got {len(acc)}")
            acc = None
    ground = config["ground"]
    up = None if ground is None else ground["up"]
    if up is not None and not 0 <= up < dim:
        errors.append(f"ground.up: expected an axis index in 0..{dim - 1}, got {up}")
    else:
        try:
            up = up_axis(acc, dim, up, ground=ground is not None)
            if ground is not None:
                _pulled_to_ground(acc, ground, up)
        except ValueError as err:
            errors.append(f"gravity.acceleration and ground.up: {err}")
            up = None
        if up is not None and ground is not None and ground["height"] is not None and valid("ground.height"):
            try:
                chosen = ground["allowance"] is not None and ground["model"] == "coulomb" and valid("ground.allowance")
                _clear_of_ground(mesh, ground["height"], up, ground["allowance"] if chosen else ALLOWANCE)
            except ValueError as err:
                errors.append(f"ground.height: {err}")
    if ground is not None:
        for cond in ground["contacts_where"] or []:
            if _bad_condition(cond, dim):
                errors.append(
                    f"ground.contacts_where: cannot use {cond!r}; expected e.g. '{'xyz'[dim - 1]} <= 0.1' with an "
                    f"axis of this {dim}D mesh"
                )
    pinned = config["pinned"]
    if (
        pinned is not None
        and valid("pinned", "pinned.where", "pinned.box")
        and (pinned["where"] is None) != (pinned["box"] is None)  # (else said above)
    ):
        usable = True
        if pinned["where"] is not None:
            for cond in pinned["where"]:
                if _bad_condition(cond, dim):
                    usable = False
                    errors.append(
                        f"pinned.where: cannot use {cond!r}; expected e.g. 'x <= 0.01' or 'x == min' "
                        f"with an axis of this {dim}D mesh"
                    )
        else:
            box = pinned["box"]
            usable = (
                set(box) == {"min", "max"}
                and all(isinstance(box[k], list) and len(box[k]) == dim for k in ("min", "max"))
                and all(is_finite_real(v) for k in ("min", "max") for v in box[k])
            )
            if not usable:
                shown = repr(box) if len(repr(box)) <= 200 else repr(box)[:200] + "..."
                expected = f"{{ min = [{dim} finite numbers], max = [{dim} finite numbers] }}"
                errors.append(f"pinned.box: expected {expected}, got {shown}")
        selected = _pinned(pinned, mesh).size if usable else None
        if selected == 0:
            errors.append("pinned: the conditions select no vertex")
        elif selected and (everything := nothing_free(selected, mesh.p.shape[1], "pinned: the selection", "pin fewer")):
            errors.append(everything)
    if not any(e.startswith(("material", "time.step", "gravity")) for e in errors):
        _check_bulk_modulus(config, mesh, errors)
        _check_float_range(config, mesh, acc, errors)
    _check_counts(config, mesh, errors, valid)


def _check_counts(config: dict, mesh, errors: list[str], valid) -> None:
    """The counts the mesh cannot take, by key: the simulator's own rule (:func:`~.ingredients.count_problems`)."""
    from .ingredients import count_problems

    sub, ground, pinned = config["subspace"], config["ground"], config["pinned"]
    keys = {
        "n_muscles": ("muscles.count", config["muscles"]["count"]),
        "n_weights": ("subspace.weights", sub["weights"]),
        "cluster_weights": ("subspace.cluster_weights", sub["cluster_weights"]),
        "n_clusters": ("subspace.clusters", sub["clusters"]),
        "n_active_clusters": ("subspace.active_clusters", sub["active_clusters"]),
        "seed": ("subspace.seed", sub["seed"]),
    }
    pins_usable = (
        pinned is not None
        and valid("pinned", "pinned.where", "pinned.box")
        and not any(e.startswith("pinned") for e in errors)
    )
    where_usable = ground is not None and ground["contacts_where"] is not None and valid("ground.contacts_where")
    where_usable = where_usable and not any(e.startswith("ground.contacts_where") for e in errors)
    if pinned is not None and not pins_usable:
        del keys["n_muscles"]  # the pins decide how many fit: wait for them to be right
    arguments = {name: value if valid(key) else None for name, (key, value) in keys.items()}
    problems = count_problems(
        mesh,
        pinned=_pinned(pinned, mesh) if pins_usable else None,
        contact_candidates=_candidates(ground["contacts_where"], mesh) if where_usable else None,
        **{"n_muscles": None, **arguments},
    )
    for name, clause in problems:
        if name == "contact_candidates":
            errors.append(f"ground.contacts_where: {_toml_value(ground['contacts_where'])} {clause}")
        else:
            key, value = keys[name]
            errors.append(f"{key}: {value} {clause}")


def schema_markdown() -> str:
    """The scene file reference as markdown: every key, its default and units."""
    lines = []

    def table(section: dict, prefix: str):
        rows = []
        subs = []
        for key, spec in section.items():
            if key.startswith("_"):
                continue
            if isinstance(spec, dict):
                subs.append((key, spec))
                continue
            default = "required" if spec.required else ("-" if spec.default is None else f"`{spec.default!r}`")
            rows.append(f"| `{key}` | {spec.kind} | {default} | {spec.units or '-'} | {spec.doc} |")
        if rows:
            lines.append("| key | type | default | units | meaning |")
            lines.append("|---|---|---|---|---|")
            lines.extend(rows)
            lines.append("")
        for key, spec in subs:
            name = f"{prefix}.{key}" if prefix else key
            effect = (
                " (an effect: present switches it on)"
                if spec.get("_effect")
                else (" (optional)" if spec.get("_optional") else "")
            )
            lines.append(f"### `[{name}]`{effect}")
            lines.append("")
            table(spec, name)

    top = {k: v for k, v in SCHEMA.items() if not isinstance(v, dict)}
    lines.append("### top level")
    lines.append("")
    table(top, "")
    table({k: v for k, v in SCHEMA.items() if isinstance(v, dict)}, "")
    lines.extend(_shapes_markdown())
    return "\n".join(lines)


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (tuple, list)):
        return "[" + ", ".join(map(repr, value)) + "]"
    return repr(value)


def _shapes_markdown() -> list[str]:
    """The built-in shapes, each parameter with its default (from the shape functions)."""
    lines = [
        "### Built-in shapes (`mesh.shape`, `mesh.params`)",
        "",
        "Every parameter has a default; `params` changes any of them "
        "(`skfem-modal modes NAME:key=value,...` on the command line).",
        "",
        "| shape | parameters and defaults | what |",
        "|---|---|---|",
    ]
    for name, func in BUILTIN_SHAPES.items():
        params = ", ".join(f"`{k} = {_toml_value(v)}`" for k, v in shape_parameters(name).items())
        summary = func.__doc__.strip().splitlines()[0].replace("``", "`")
        lines.append(f"| `{name}` | {params} | {summary} |")
    lines.append("")
    return lines
