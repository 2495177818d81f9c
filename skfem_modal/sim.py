"""ModalMuscle: the reduced modal-muscle simulator, and the step loop.

Positions are ``x = B z``. One time step of length ``h`` minimises, over the
next ``z``, the energy

    E(z) = |z - y|^2_{B^T M B} / (2 h^2)                     inertia (implicit Euler), y = z0 + h v0
         + sum_e mu vol_e / 2 |F_e(z) - R_c(e)|^2             passive ARAP, one rotation per cluster
         + sum_e gamma vol_e / 2 |F_e(z) - R_a(e) Y_e(a)|^2   muscles: the clustered plastic-stretch target
         - z^T B^T f_g                                        gravity

plus pins and damping when asked for, by block-coordinate descent (local
rotations, global solve; :mod:`skfem_modal.solver`), ground contact
projecting each global solution. The pieces:

* the space of the unknowns (:mod:`skfem_modal.space`),
* the effects, each contributing its terms (:mod:`skfem_modal.effects`,
  :mod:`skfem_modal.contact`): only those a simulator is given are built and
  stepped, so a floating body never runs contact code,
* the model (:mod:`skfem_modal.model`): their operators at a time step, factored once,
* the driver and its backends (:mod:`skfem_modal.solver`).

:class:`ModalMuscle` holds them and its settings: assigning ``h``,
``max_iter``, ``tol``, ``rtol``, ``etol``, ``warm_start``, ``acceleration``, ``backend``, ``gravity``, ``ground``,
``up``, ``contact_model``, ``friction``, ``allowance``, ``exact_friction``, ``stickiness``, ``push_out``,
``pin_stiffness``, ``damping_mass``, ``damping_stiffness`` or ``max_s`` takes effect at the next step, rebuilding
only what depends on it; ``mesh``, ``B``, ``D``, ``labels``,
``active_labels``, ``mu``, ``gamma``, ``rho``, ``pinned`` and
``contact_vertices`` shape the precomputed operators and are read-only.
"""

from __future__ import annotations

import inspect
import sys
import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from functools import partial

import numpy as np

from .checks import (
    _acceleration_name,
    _array,
    _axis,
    _backend_name,
    _basis,
    _clear_of_ground,
    _contact_settings,
    _count,
    _fits_float64,
    _fraction,
    _gravity_and_up,
    _ground,
    _labels,
    _muscle_modes,
    _nonnegative,
    _pins,
    _positive_scalar,
    _pulled_to_ground,
    _vertex_field,
)
from .contact import (
    ALLOWANCE,
    DEFAULT_CONTACTS,
    GROUND_DURING_A_RUN,
    THIN_WORDS,
    CoulombContact,
    ReferenceContact,
    checked_allowance,
)
from .effects import Damping, Elasticity, Gravity, Inertia, Muscles, Pins
from .fem import _lumped_p1, _positive
from .ingredients import ingredients, timed
from .mesh import _signed_measures, boundary_vertices, check_mesh, sample_boundary, validated
from .modal import muscle_modes
from .model import Model
from .solver import MAX_ITERATIONS, TOL, LocalGlobal, SimulationError, make_backends
from .space import FullSpace, Subspace
from .threads import checked_thread_count, limited_blas_threads
from .units import outside_stacklevel, up_axis, warn_scale
from .values import checked_flag, checked_state, is_whole

__all__ = ["ModalMuscle", "SimulationError", "muscle_modes", "simulate", "StepRecord"]


def _driver(max_iter, tol, rtol, etol, warm_start, acceleration, full_space) -> LocalGlobal:
    """The local/global driver of these limits, each checked."""
    return LocalGlobal(
        _iterations(max_iter),
        _nonnegative(tol, "tol"),
        _nonnegative(rtol, "rtol"),
        etol=_nonnegative(etol, "etol"),
        warm_start=checked_flag(warm_start, "warm_start"),
        acceleration=_acceleration_name(acceleration, full_space),
    )


def _iterations(value) -> int:
    """``max_iter`` checked: a positive integer, at most :data:`MAX_ITERATIONS`."""
    count = _count(value, "max_iter")
    if count > MAX_ITERATIONS:
        raise ValueError(
            f"max_iter must be at most {MAX_ITERATIONS} (a backend keeps each iteration of a step), got {count}"
        )
    return count


def _element_weights(mesh, mu, gamma, rho):
    """Passive and muscle stiffness times element volume, and density per element, each shape (nT,), checked."""
    nT = mesh.t.shape[1]
    vol = np.abs(_signed_measures(mesh.p, mesh.t))
    return (
        _positive(mu, nT, "mu") * vol,
        _positive(gamma, nT, "gamma", allow_zero=True) * vol,
        _positive(rho, nT, "rho"),
    )


def _allowance(settings: dict) -> float:
    """How deep a body may start in the ground under a contact model's settings (``_contact_settings``)."""
    return settings.get("allowance", ALLOWANCE)


def _model_contact_vertices(mesh, model: str, default: dict | None):
    """The contact model's own default vertices when from_mesh chose them by default, else None (kept).

    ``default``: how from_mesh chose them (its ``contact_candidates``), or None. A simulator built
    with ``n_contacts``, or directly with ``contact_vertices`` or all boundary vertices, keeps its
    vertices whatever the model.
    """
    if default is None:
        return None
    return np.unique(sample_boundary(mesh, DEFAULT_CONTACTS[model], **default))  # ascending, as the constructor's


def _non_finite_as_given(**state) -> None:
    """Raise a SimulationError naming the part of a state given non-finite (a failed step's cause), if one is."""
    for name, value in state.items():
        if not np.all(np.isfinite(value)):
            raise SimulationError(f"the state is non-finite as given: {name} holds NaN or infinity") from None


def _real(value, name: str) -> np.ndarray:
    """``value`` as a float array; a complex one is refused (casting would drop its imaginary part)."""
    if np.iscomplexobj(value):
        raise ValueError(f"{name} must be real, got complex values")
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):  # (numpy's "could not convert string to float: 'abc'" named nothing)
        shown = repr(value) if len(repr(value)) <= 80 else repr(value)[:80] + "..."
        raise TypeError(f"{name} must be numbers, got {shown}") from None


def _checked_activation(a, m: int) -> np.ndarray:
    """Muscle activations checked: shape (m,) (a number for one muscle), finite; None: zero (the muscles at rest)."""
    if a is None:
        return np.zeros(m)
    if m == 0:
        if np.size(a):
            raise ValueError(f"this simulator has no muscles; got {np.size(a)} activations")
        return np.zeros(0)
    a = _real(a, "activation")
    if a.ndim > 1:  # (a column or a table flattened could be read in another order than meant)
        raise ValueError(f"activation must have one value per muscle ({m}), shape ({m},), got shape {a.shape}")
    if a.size != m:
        raise ValueError(f"activation must have one value per muscle ({m}), got {a.size}")
    a = a.reshape(m)
    if not np.isfinite(a).all():  # the method: half the cost of np.all's dispatch, every step
        raise ValueError(f"activation must be finite, got {a.tolist()}")
    return a


#: the contact effect of each model
_CONTACTS = {"coulomb": CoulombContact, "reference": ReferenceContact}


def _contact_effect(space, settings: dict, vertices, ground: float, up: int):
    """The contact effect of a contact model's settings (``_contact_settings``)."""
    settings = dict(settings)
    return _CONTACTS[settings.pop("model")](space, vertices, ground, up, **settings)


def _new_contact(sim, setting, vertices=None, settings=None, **changes) -> None:
    """A simulator's fresh contact on its ground: its settings changed, or ``settings`` (and ``vertices``, if given).

    Checked first: a refused one changes nothing.
    """
    contact = sim._model.contact
    if contact is None:
        raise AttributeError(f"{setting}: this simulator has no ground (build it with ground=...)")
    settings = {**sim._contact, **changes} if settings is None else settings
    _clear_of_ground(sim._mesh, contact.ground, sim._up, _allowance(settings))  # a smaller allowance
    sim._contact = settings
    if vertices is not None:
        sim._contact_vertices = vertices
    _put_contact(sim, contact.vertices if vertices is None else vertices, contact.ground, setting)


def _put_contact(sim, vertices, ground, setting=None) -> None:
    """Put in a fresh contact of the current settings (what one kept from earlier steps was about the old).

    ``setting``: the one assigned, when it replaces a contact: a run goes on with the new one.
    """
    contact = _contact_effect(sim._space, sim._contact, vertices, ground, sim._up)
    if setting is not None and sim._model.contact is not None:
        contact.follow(sim._model.contact, setting)
    sim._model.replace(contact)
    sim._rebuild()


def _read_only(value):
    """An array the simulator holds, as a read-only view (other values as they are).

    Changed in place, it would have said what the steps no longer use (``sim.gravity[1] *= 2`` read
    -19.6 while the steps fell at -9.8), or broken them (``sim.contact_vertices[:] = 0``).
    """
    if not isinstance(value, np.ndarray):
        return value
    view = value.view()
    view.flags.writeable = False
    return view


def _kept(value):
    """A material parameter as given, an array copied (the caller's, changed later, is not the simulator's)."""
    return np.array(value, dtype=np.float64) if np.ndim(value) else value


def _fixed(name: str, doc: str):
    """A read-only setting: reading gives the value, assigning explains why it cannot change."""

    def get(self):
        return _read_only(getattr(self, "_" + name))

    def refuse(self, value):
        raise AttributeError(
            f"{name} is fixed when a simulator is built (the precomputed operators depend on it); build a new one"
        )

    refuse.fixed = True  # for the list of settings one can assign (_nearest_setting)
    return property(get, refuse, doc=doc)


def _driver_setting(name: str, check, doc: str):
    """A live setting the local/global driver holds: assigning checks it, and the next step uses it."""

    def get(self):
        return getattr(self._solver, name)

    def put(self, value):
        setattr(self._solver, name, check(value, name))

    return property(get, put, doc=doc)


def _contact_setting(name: str, model: str, check, doc: str):
    """A live setting of one contact model (None under the other): assigning puts in a fresh contact."""

    def get(self):
        return self._contact.get(name)

    def put(self, value):
        value = check(value, name)
        if self._contact["model"] != model:
            raise AttributeError(
                f"{name} is a setting of contact_model='{model}'; this simulator uses "
                f"contact_model='{self._contact['model']}'"
            )
        if value == self._contact.get(name):  # (a fresh contact forgets what it held: a 3D crawl moved 4e-4)
            return
        _new_contact(self, name, **{name: value})

    return property(get, put, doc=doc)


def _damping_setting(name: str, coefficient: str, doc: str):
    """A Rayleigh damping coefficient (0 without damping): assigning adds, changes or removes the damping."""

    def get(self):
        damping = self._model.named.get("damping")
        return 0.0 if damping is None else getattr(damping, coefficient)

    def put(self, value):
        coefficients = {"damping_mass": self.damping_mass, "damping_stiffness": self.damping_stiffness}
        coefficients[name] = _nonnegative(value, name)
        damping = (coefficients["damping_mass"], coefficients["damping_stiffness"])
        _fits_float64(self._mesh, self._mu, self._gamma, self._rho, self.h, self.gravity, damping)
        self._damp(*damping)
        if name == "damping_stiffness":  # (it stiffens each step: the iterations may lag, as at a large h)
            _warn_of_step(self)

    return property(get, put, doc=doc)


def _from_mesh(
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
    n_contacts: int | str | None = None,
    contact_candidates=None,
    up=None,
    contact_model="coulomb",
    friction=None,
    allowance=None,
    exact_friction=None,
    stickiness=None,
    push_out=None,
    pinned=None,
    pin_stiffness=None,
    damping_mass=0.0,
    damping_stiffness=0.0,
    n_active_clusters: int = 1,
    max_iter=10,
    tol=TOL,
    rtol=0.0,
    etol=0.0,
    warm_start=False,
    acceleration="none",
    cluster_by="weights",
    max_s=2.0,
    seed: int = 0,
    progress=None,
    backend="auto",
    parallel: bool = True,
    blas_threads: int | None = 1,
):
    """Build every ingredient from a mesh and a few numbers: muscles, subspace, clusters, contact vertices.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
        Rest shape, in its own units (:mod:`skfem_modal.units` warns of a size the material
        cannot hold up).
    n_muscles : int
        Muscles: the lowest linear modes without the rigid ones (material ``mu``, ``lam``,
        ``rho``), in the deterministic sign convention of
        :func:`~skfem_modal.linear_modal_analysis`; with ``pinned`` vertices, the modes of the
        body clamped there.
    muscle_signs : array_like of +1 or -1, shape (n_muscles,), optional
        Each muscle mode multiplied by its sign.
    n_weights : int
        Skinning eigenmodes of the subspace (mass-orthonormalised).
    cluster_weights : int, optional
        The first this many weights are clustered (default ``n_weights``).
    n_clusters : int
        Passive rotation clusters: spectral clusters of the weights (``seed``).
    mu, gamma, lam, rho : float
        Passive stiffness, muscle stiffness (default ``mu``), the modal analysis's Lame
        ``lam`` (default ``mu``) and density; see :class:`ModalMuscle`.
    h : float
        Time step.
    gravity : array_like, shape (dim,), optional
        Gravitational acceleration; None: no gravity.
    ground : float, optional
        Height of the ground plane along ``up``; None: no ground.
    n_contacts : int or "all", optional
        With a ``ground``: that many boundary vertices by farthest-point sampling, or all of
        them (default: every boundary vertex with the ``coulomb`` contact, 30 with the
        ``reference`` one, as its tutorial).
    contact_candidates : array_like of int, shape (k,), optional
        The vertices the contact vertices are chosen among.
    up : int, optional
        Index of the up axis (default: the axis gravity pulls down along).
    contact_model, friction, allowance, exact_friction, stickiness, push_out
        The contact's model and settings, as for :class:`ModalMuscle`.
    pinned : array_like of int, shape (k,), optional
        Vertices held at their rest positions.
    pin_stiffness, damping_mass, damping_stiffness, max_iter, tol, rtol, etol, warm_start, acceleration, backend
        As for :class:`ModalMuscle`.
    n_active_clusters : int
        Muscle rotation clusters: spectral clusters, at least one per connected part of the mesh
        (so separate bodies turn apart).
    cluster_by : {"weights", "rotations"}
        ``weights``: spectral clusters of the skinning weights; ``rotations``: by how the
        subspace's lowest modes rotate the elements
        (:func:`~skfem_modal.clusters.rotation_clusters`: more accuracy per cluster where few
        are used).
    max_s : float
        The muscles' amplitude ceilings (:class:`ModalMuscle`).
    seed : int
        Seed of the clustering.
    progress : callable or bool, optional
        ``progress(stage)`` is called before each stage (True: each stage printed to stderr).
    parallel : bool
        Run the modal analysis in a second thread beside the subspace and clusters (the results
        do not change).
    blas_threads : int or None
        Threads each BLAS call may use meanwhile (None: as the BLAS library is set), so that the
        two threads do not oversubscribe the cores (:mod:`skfem_modal.threads`).

    Returns
    -------
    sim : ModalMuscle
        With ``sim.timings`` covering these stages too.
    """
    # each argument goes by name to the stage that takes it: ingredients, then the constructor (the settings)
    arguments = {name: value for name, value in locals().items() if name not in ("cls", "mesh")}
    arguments["gamma"] = mu if gamma is None else gamma
    # settings used late are checked before any work
    if n_contacts is not None and not (isinstance(n_contacts, str) and n_contacts == "all"):
        _count(n_contacts, "n_contacts")
    _backend_name(backend)
    _acceleration_name(acceleration)
    checked_flag(warm_start, "warm_start")
    checked_flag(parallel, "parallel")
    settings = _contact_settings(contact_model, friction, stickiness, push_out, allowance, exact_friction)
    contact = dict(contact_model=contact_model, friction=friction, allowance=allowance, exact_friction=exact_friction,
                   stickiness=stickiness, push_out=push_out)  # fmt: skip
    _ground(ground, 0, n_contacts=n_contacts, contact_candidates=contact_candidates, **contact)
    say = _stage_reporter(progress)
    damping = _nonnegative(damping_mass, "damping_mass"), _nonnegative(damping_stiffness, "damping_stiffness")
    blas_threads = checked_thread_count(blas_threads)
    with limited_blas_threads(blas_threads), validated(mesh), ThreadPoolExecutor(max_workers=1) as pool:
        _fits_float64(mesh, mu, gamma, rho, h, gravity, damping)
        warn_scale(mesh, mu, rho, gravity, h=h, stacklevel=2, damping_stiffness=damping[1])  # the caller of from_mesh
        if ground is not None:
            g, axis = _gravity_and_up(gravity, up, mesh.p.shape[0])
            _pulled_to_ground(g, ground, axis)
            _clear_of_ground(mesh, float(_array(ground, (), "ground")), axis, _allowance(settings))
        if pinned is not None:  # named as given (the modal analysis would say 'fixed')
            arguments["pinned"] = _pins(pinned, None, mesh.p.shape[1])[0]
        made = ingredients(mesh, pool if parallel else None, say, **_taken_by(ingredients, arguments))
        say("simulator set-up")
        placed = dict(active_labels=made.active_labels, contact_vertices=made.contact_vertices)
        sim = cls(mesh, made.B, made.muscles, made.labels, **placed, **_taken_by(ModalMuscle.__init__, arguments))
    if n_contacts is None:
        # the contact vertices are the model's default: another model (or a ground put in later) takes its own
        sim._default_contacts = {"candidates": contact_candidates}
    sim.timings = {**made.timings, **sim.timings}
    sim.weights = made.weights
    return sim


def _stage_reporter(progress):
    """``progress`` as a function of a stage's name: a callable, True (printed to stderr), or None/False."""
    if progress is None or progress is False:
        return lambda stage: None
    if progress is True:
        return lambda stage: print(f"  {stage}", file=sys.stderr, flush=True)
    if not callable(progress):
        raise TypeError(f"progress must be a callable of a stage's name, True or None, got {progress!r}")
    return progress


#: The public attributes a simulator sets itself (its settings are properties)
_ATTRIBUTES = frozenset({"timings", "iterations", "weights"})
# settings named as elsewhere
_ALIASES = {"dt": "h", "time_step": "h", "timestep": "h", "step_size": "h", "iterations_max": "max_iter"}


def live_settings(cls) -> list[str]:
    """The settings of a simulator class one can assign (live ones), sorted by name."""
    kinds = {a: getattr(cls, a) for a in dir(cls) if not a.startswith("_")}
    return sorted(
        a
        for a, kind in kinds.items()
        if isinstance(kind, property) and not getattr(kind.fset, "fixed", kind.fset is None)
    )


def _nearest_setting(cls, name: str) -> str:
    """'': or a hint naming the settings of ``cls`` a misspelt ``name`` may mean."""
    import difflib

    settings = live_settings(cls)
    near = [_ALIASES[name]] if name in _ALIASES else difflib.get_close_matches(name, settings, n=3)
    if near:
        return f": did you mean {' or '.join(map(repr, near))}?"
    return f"; the settings one can assign are {', '.join(settings)}"


def _warn_of_step(sim) -> None:
    """Warn of what a simulator's time step (assigned, or its damping's) makes of it: lagging iterations
    (:func:`~skfem_modal.units.warn_scale`), pins given a stiffness far above the default (which follows
    ``1 / h^2``; a given one does not)."""
    beta = sim.damping_stiffness
    warn_scale(sim.mesh, sim._mu, sim._rho, h=sim.h, stacklevel=outside_stacklevel(), damping_stiffness=beta)
    _warn_stiff_pins(sim.model.named.get("pinned"), sim.h)


#: Pins this many times stiffer than their default stop the iterations converging (see _warn_stiff_pins).
_STIFFEST_PINS = 1e3


def _warn_stiff_pins(pins, h: float) -> None:
    """Warn when pins given a stiffness (``pins``: the model's Pins effect, or None) are far stiffer than the default.

    The iterations then stop short of converging, with no error: a cantilever's sag at 10 iterations a
    step was the default's up to 320 times it, 5 % off at 3e4 times, four times off at 3e7.
    """
    if pins is None or pins.given_stiffness is None:
        return
    default = pins.default_stiffness(h)
    if pins.given_stiffness > _STIFFEST_PINS * default:
        warnings.warn(
            f"the pins' stiffness {pins.given_stiffness:.3g} is {pins.given_stiffness / default:.2g} times their "
            f"default at this time step ({default:.3g}): the local/global iterations stop short of converging "
            "with pins this stiff (a cantilever's sag was 5 % off at 3e4 times the default, four times off at "
            "3e7), and nothing else says so. Leave the stiffness out (the default held a cantilever's pins to "
            "6e-6 with its tip 0.1 down), or check the motion with more iterations (max_iter)",
            UserWarning,
            stacklevel=outside_stacklevel(),
        )


def _warn_if_idle(solver, contact, *settings) -> None:
    """Warn of each of ``settings`` (``acceleration``, ``warm_start``) that is on but does nothing under ``contact``.

    A setting that does nothing must say so: ``solver`` is the simulator's driver, ``contact`` its
    model's contact effect (None: no ground, every setting works).
    """
    model = None if contact is None else contact.model
    acceleration = solver.acceleration if "acceleration" in settings else "none"
    for message in idle_settings(acceleration, "warm_start" in settings and solver.warm_start, model):
        warnings.warn(message, UserWarning, stacklevel=outside_stacklevel())


def idle_settings(acceleration: str, warm_start: bool, contact_model: str | None) -> list[str]:
    """Why each of the solver's settings that is on does nothing under a contact model, one message each.

    Parameters
    ----------
    acceleration : str
        ``none``, ``anderson`` or ``newton``.
    warm_start : bool
    contact_model : {"coulomb", "reference"} or None
        None: no ground (every setting works).

    Returns
    -------
    list of str
        Empty when every setting on works.
    """
    if contact_model is None:
        return []
    reads_iterates = _CONTACTS[contact_model].reads_iterates
    said = []
    if acceleration != "none":
        said.append(
            f"acceleration={acceleration!r} has no effect under ground contact (a projection, not "
            "an energy, holds the body up, so no accelerated iterate can be checked): the iterations stay plain"
            + ("" if reads_iterates else "; warm_start=True speeds them up there (docs/contact.md)")
        )
    if warm_start and reads_iterates:
        said.append(
            "warm_start=True has no effect under the reference contact (its rule reads the iterates, so they "
            "start from the step's start state): the iterations are those without it; contact_model='coulomb' "
            "warm-starts them (docs/contact.md)"
        )
    return said


class _GroundSettings:
    """A simulator's ground and its contact: the settings of them, live (see :class:`ModalMuscle`).

    They replace the contact effect (a fresh one of the new settings, which goes on with a run) and
    check first what they would make of the body's place against the ground.
    """

    @property
    def contact_model(self) -> str:
        """``coulomb`` (every vertex above the ground, Coulomb friction) or ``reference`` (the tutorial's).

        A model switched back to takes the settings it had (``friction``, ``allowance``, ...).
        """
        return self._contact["model"]

    @contact_model.setter
    def contact_model(self, value) -> None:
        settings = _contact_settings(value, None, None, None)
        if settings["model"] == self._contact["model"]:
            return  # the model it has: its settings (friction, allowance, ...) stay
        earlier = getattr(self, "_contact_earlier", {})
        self._contact_earlier = {**earlier, self._contact["model"]: self._contact}
        settings = earlier.get(settings["model"], settings)
        if self._model.contact is None:
            self._contact = settings
            return
        vertices = _model_contact_vertices(self._mesh, value, self._default_contacts)
        _new_contact(self, "contact_model", vertices, settings)
        _warn_if_idle(self._solver, self._model.contact, "warm_start")

    friction = _contact_setting(
        "friction",
        "coulomb",
        _nonnegative,
        "Coulomb coefficient of the ground (``contact_model='coulomb'``; None otherwise).",
    )
    allowance = _contact_setting(
        "allowance",
        "coulomb",
        checked_allowance,
        f"How far below the ground a vertex may end a step, of the body's size, or of {THIN_WORDS} "
        "(``contact_model='coulomb'``; None otherwise).",
    )
    exact_friction = _contact_setting(
        "exact_friction",
        "coulomb",
        checked_flag,
        "Whether a step's sliding vertices end with exact Coulomb friction, straight against their slides "
        "(``contact_model='coulomb'``; None otherwise).",
    )
    stickiness = _contact_setting(
        "stickiness",
        "reference",
        _fraction,
        "Fraction of a contact point's tangential velocity removed (``contact_model='reference'``; None otherwise).",
    )
    push_out = _contact_setting(
        "push_out",
        "reference",
        _fraction,
        "Fraction of a contact point's penetration undone per step (``contact_model='reference'``; None otherwise).",
    )

    def penetration(self, z, relative: bool = False) -> float:
        """Depth of the lowest boundary vertex below the ground, for a state ``z`` (0 without a ground).

        Parameters
        ----------
        z : ndarray, shape (r,)
        relative : bool
            The deepest relative to the size of the vertex's own connected part (in a mesh of
            several bodies, each as large as itself: :func:`~skfem_modal.mesh.part_sizes`).

        Returns
        -------
        float
        """
        z = self._state(z)
        contact = self._model.contact
        relative = checked_flag(relative, "relative")  # ("yes" would be true)
        return 0.0 if contact is None else contact.penetration(z, relative)

    @property
    def ground(self):
        """Height of the ground along ``up``, or None (assigning moves it; None removes it)."""
        contact = self._model.contact
        return None if contact is None else contact.ground

    @ground.setter
    def ground(self, value) -> None:
        if value is None:
            self._model.remove("contact")
            self._contact_vertices = np.zeros(0, np.int64)
            self._rebuild()
            return
        value = float(_array(value, (), "ground"))
        if value == self.ground:  # the same ground: the contact, and what it holds, stay
            return
        _pulled_to_ground(self.gravity, value, self._up)  # (a floating body's gravity may pull any way)
        # during a run under the Coulomb contact, the state the next step starts from is checked by that step
        # (its start); the rest shape says nothing of a body that has moved (one risen 5 sizes was refused a
        # ground just below it). Before a run, and under the reference contact (its feet sink anyway): at rest
        running = self._stepped and self._contact["model"] == "coulomb"
        if not running:
            _clear_of_ground(self._mesh, value, self._up, _allowance(self._contact))
        contact = self._model.contact
        if contact is None:
            default = _model_contact_vertices(self._mesh, self._contact["model"], self._default_contacts)
            self._contact_vertices = boundary_vertices(self._mesh) if default is None else default
        _put_contact(self, self._contact_vertices if contact is None else contact.vertices, value, "ground")
        if running and contact is None:  # (one replaced says so itself: follow)
            self._model.contact.replaced_for = GROUND_DURING_A_RUN.format(setting="ground")
        if contact is None:
            _warn_if_idle(self._solver, self._model.contact, "acceleration", "warm_start")

    @property
    def up(self) -> int:
        """Index of the up axis."""
        return self._up

    @up.setter
    def up(self, value) -> None:
        value = _axis(value, self.dim)
        if value == self._up:  # (as the ground's)
            return
        if self.gravity is not None:
            up_axis(self.gravity, self.dim, value, self.ground is not None)  # gravity must pull down along it
        _clear_of_ground(self._mesh, self.ground, value, _allowance(self._contact))
        self._up = value
        if self._model.contact is not None:
            _new_contact(self, "up")


class ModalMuscle(_GroundSettings):
    """Reduced modal-muscle dynamics in a subspace (or on every DOF), in 2D or 3D.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
        Rest shape.
    B : ndarray, shape (n * dim, r), or None
        Subspace: positions are ``B @ z``. It must contain the rest pose (a
        skinning basis does). None: every DOF is an unknown (the full-space
        reference, :class:`~skfem_modal.reference.FullSpaceSimulator`).
    D : ndarray, shape (n * dim, m), None, or a callable returning one
        Muscle modes (displacements, without the rest pose). ``None`` or
        ``m = 0``: no muscles. A callable is called once the passive
        operators are built (so a modal analysis can run meanwhile).
    labels : ndarray of int, shape (nT,)
        Passive rotation cluster of each element.
    mu : float or ndarray of shape (nT,)
        Passive (ARAP) stiffness: the energy ``mu / 2 |F - R|^2`` per volume,
        in small strains a material of Young's modulus ``mu`` and Poisson's
        ratio 0 (shear modulus ``mu / 2``).
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
    contact_vertices : array_like of int, shape (k,), optional
        Vertices that can touch the ground (default with a ground: all boundary vertices).
    ground : float, optional
        Height of the ground plane along ``up``; ``None``: no ground.
    up : int, optional
        Index of the up axis; default: the axis gravity pulls down along
        (:func:`~skfem_modal.units.up_axis`), the last without gravity.
    contact_model : {"coulomb", "reference"}
        ``coulomb`` (the default): no vertex ends a step below the ground, and
        Coulomb friction holds the touching ones
        (:class:`~skfem_modal.contact.CoulombContact`). ``reference``: the
        reference implementation's velocity rule at the contact vertices,
        which lets vertices end inside the ground (for its numbers).
    friction : float, optional
        ``coulomb`` only: the Coulomb coefficient, >= 0 (default 0.5).
    allowance : float, optional
        ``coulomb`` only: how far below the ground a vertex may end a step, a
        share of the body's size in [1e-10, 0.001] (default 2e-4), or of
        :data:`~skfem_modal.contact.THIN` times a thin part's thickness if less
        (:func:`~skfem_modal.contact.allowance_lengths`); larger is cheaper.
    exact_friction : bool, optional
        ``coulomb`` only (default True): each step's last projection is made
        again with exact Coulomb friction where a slide's friction is not
        straight against its motion. False keeps the active set's friction,
        fixed as each vertex starts to slide (degrees off the slide), for a
        cheaper step with friction (docs/contact.md, what it costs).
    stickiness : float, optional
        ``reference`` only, in [0, 1]: 1 (the default) removes the tangential
        velocity of contacting points, 0 lets them slide freely.
    push_out : float, optional
        ``reference`` only, in [0, 1]: fraction of a contact point's
        penetration undone per step (default 0, the reference behaviour).
    pinned : array_like of int, shape (k,), optional
        Vertices held at their rest positions by stiff springs
        ``pin_stiffness / 2 |x_i - X_i|^2`` (in the subspace a pin is as exact
        as the basis allows).
    pin_stiffness : float, optional
        Spring stiffness; default 1e3 times the larger of the mean passive
        stiffness and the mean vertex mass over ``h^2`` per DOF.
    damping_mass, damping_stiffness : float
        Damping: ``alpha = damping_mass`` (1/time) damps all motion, like drag,
        with the dissipation ``alpha (z - z0)^T BMB (z - z0) / 2h``;
        ``beta = damping_stiffness`` (time) damps the rate of deformation,
        corotated: each element's change of its departure from its cluster's
        rotation, so rigid motion, turning included, goes undamped (a free spin
        keeps its momentum as without damping), and near rest it is Rayleigh
        damping ``beta K`` with ``K`` the elastic Hessian: a mode of frequency
        ``omega`` has the damping ratio ``beta omega / 2``. See
        :class:`~skfem_modal.effects.Damping`.
    max_iter : int
        Local/global iterations per step, at most.
    tol : float
        Stop when the last iteration moved the body by less than ``tol`` of
        its size (of a mesh of several bodies, the least body's:
        :func:`~skfem_modal.model.motion_scale`):
        ``|z_k - z_{k-1}| < tol * motion_scale`` (the same in any
        units; the reference's rule, an absolute ``1e-6`` on ``z``, is
        ``tol = 1e-6 / sim.motion_scale``); 0 runs exactly ``max_iter``
        iterations.
    rtol : float
        Also stop when ``|z_k - z_{k-1}| <= rtol |z_k - z_start|``: the last
        change is small compared with this step's motion. 0 disables.
    etol : float
        Also stop when the step energy changed by at most ``etol`` times
        what it has changed since the step's first iterate. 0 disables; else
        the energy is evaluated at every iterate (about the cost of an
        iteration in numpy).
    warm_start : bool
        Start each step's iterations from the inertial prediction
        ``z + h z_dot`` instead of ``z`` (not under the reference contact,
        whose rule reads the iterates): the same fixed point, reached in
        fewer iterations when the motion is smooth; a rolling body's
        rotation is not lagged (docs/contact.md).
    acceleration : {"none", "anderson", "newton"}
        Accelerated iterates (:mod:`~skfem_modal.acceleration`; not under
        contact, where a warning says so), each kept only when its step energy is at most that of the
        plain iterate it replaces: ``anderson`` extrapolates from the last
        iterates, ``newton`` (a subspace only) takes a Newton step with the
        exact Hessian of the rotation terms. They take far fewer iterations,
        but each costs two energy evaluations and some numpy calls more: a
        saving only where plain iterations are slow to converge and costly
        (docs/accuracy.md has the measurements).
    backend : {"auto", "numpy", "numba", "plain"}
        Who does the iterations' arithmetic (:func:`~skfem_modal.solver.make_backends`;
        the same step to round-off; over a run with ground contact, whose touch, stick and
        slip decisions amplify round-off as any contact simulation's do, the paths can drift
        apart: a creature started touching the ground, 1e-2 of its size after 50 steps).
        ``auto`` uses numba when it is installed, but numpy's Kronecker form for 3D
        skinning subspaces from 20 clusters on, counting the muscles' own (faster there:
        ``benchmarks/bench_backends.py``).
    max_s : float
        The muscles' amplitude ceilings: a mode scaled by its ceiling changes
        some element's deformation gradient by ``max_s`` (Frobenius norm).

    Attributes
    ----------
    iterations : int
        Local/global iterations of the last step.
    effects : tuple of str
        The effects this simulator holds and steps, in order.
    timings : dict
        Seconds spent in each precompute stage.
    ceilings : ndarray, shape (m,)
        Amplitude ceilings of the muscles.
    mass : ndarray, shape (n * dim,)
        Lumped mass per DOF.
    """

    _stepped = False  # a run is under way (a step since the build or the last reset)
    mesh = _fixed("mesh", "The rest mesh.")
    B = _fixed("B", "The subspace basis, shape (n * dim, r) (None on every DOF).")
    D = _fixed("D", "The muscle modes, shape (n * dim, m).")
    labels = _fixed("labels", "Passive rotation cluster of each element, shape (nT,).")
    active_labels = _fixed("active_labels", "Muscle rotation cluster of each element, shape (nT,).")
    mu = _fixed("mu", "Passive stiffness.")
    dim = _fixed("dim", "The dimension, 2 or 3.")
    mass = _fixed("mass", "Lumped vertex masses, one per DOF, shape (n * dim,) (from rho).")
    gamma = _fixed("gamma", "Muscle stiffness.")
    rho = _fixed("rho", "Density.")
    pinned = _fixed("pinned", "Pinned vertices (empty without pins).")
    n_muscles = _fixed("n_muscles", "The number of muscles.")
    n_clusters = _fixed("n_clusters", "The number of passive rotation clusters.")
    n_active_clusters = _fixed("n_active_clusters", "The number of muscle rotation clusters (0 without muscles).")
    contact_vertices = _fixed("contact_vertices", "Contact vertices (empty without a ground).")

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
        contact_model="coulomb",
        friction=None,
        allowance=None,
        exact_friction=None,
        stickiness=None,
        push_out=None,
        pinned=None,
        pin_stiffness=None,
        damping_mass=0.0,
        damping_stiffness=0.0,
        max_iter=10,
        tol=TOL,
        rtol=0.0,
        etol=0.0,
        warm_start=False,
        acceleration="none",
        backend="auto",
        max_s=2.0,
    ):
        clock = time.perf_counter()
        check_mesh(mesh)
        dim, n = mesh.p.shape
        nT = mesh.t.shape[1]
        B = None if B is None else _basis(B, mesh.p.T.ravel())
        D = D if callable(D) else _muscle_modes(D, n * dim)  # a callable: called once the passive operators are built
        labels = _labels(labels, nT, "labels")
        active_labels = np.zeros(nT, np.int64) if active_labels is None else _labels(active_labels, nT, "active_labels")
        h = _positive_scalar(h, "h")
        damping = _nonnegative(damping_mass, "damping_mass"), _nonnegative(damping_stiffness, "damping_stiffness")
        _fits_float64(mesh, mu, gamma, rho, h, gravity, damping)
        self._solver = _driver(max_iter, tol, rtol, etol, warm_start, acceleration, full_space=B is None)
        self._backend = _backend_name(backend)
        gravity, self._up = _gravity_and_up(gravity, up, dim, ground is not None)
        self._contact = _contact_settings(contact_model, friction, stickiness, push_out, allowance, exact_friction)
        max_s = _positive_scalar(max_s, "max_s")
        pinned, pin_stiffness = _pins(pinned, pin_stiffness, n)
        contact = dict(contact_model=contact_model, friction=friction, allowance=allowance,
                       exact_friction=exact_friction, stickiness=stickiness, push_out=push_out)  # fmt: skip
        ground, contact_vertices = _ground(ground, n, contact_vertices, **contact)
        _pulled_to_ground(gravity, ground, self._up)
        _clear_of_ground(mesh, ground, self._up, _allowance(self._contact))
        w_mu, w_gamma, rho_e = _element_weights(mesh, mu, gamma, rho)
        self._mesh, self._B, self._labels, self._active_labels = mesh, B, labels, active_labels
        self._mu, self._gamma, self._rho = _kept(mu), _kept(gamma), _kept(rho)
        self._dim, self._mass = dim, np.repeat(_lumped_p1(mesh, rho_e), dim)
        self._mass.flags.writeable = False  # the effects were built from it: changed in place, only some would follow
        self._space = Subspace(mesh, B) if B is not None else FullSpace(mesh)
        self.timings = {"validate": time.perf_counter() - clock}
        self._build(h, D, w_mu, w_gamma, max_s, gravity, pinned, pin_stiffness, damping, ground, contact_vertices)
        self._n_muscles = self._D.shape[1]
        self._n_clusters = self._model.elasticity.n_clusters
        self._n_active_clusters = int(active_labels.max()) + 1 if self._n_muscles else 0
        self.iterations = 0
        self._default_contacts = None  # see from_mesh and _model_contact_vertices
        _warn_if_idle(self._solver, self._model.contact, "acceleration", "warm_start")

    def _build(self, h, D, w_mu, w_gamma, max_s, gravity, pinned, pin_stiffness, damping, ground, contact_vertices):
        """Make the effects in order (calling ``D`` if a callable), the model and the backends, each stage timed."""
        space, mass, stage = self._space, self.mass, partial(timed, self.timings)
        elasticity = stage("elasticity", lambda: Elasticity(space, w_mu, self._labels))
        inertia = stage("inertia", lambda: Inertia(space, mass))
        self._D = stage("waiting_for_modal_analysis", lambda: _muscle_modes(D(), space.N)) if callable(D) else D
        D = self._D
        effects = [elasticity, inertia]
        if D.shape[1]:
            effects.append(stage("muscles", lambda: Muscles(space, D, w_gamma, self._active_labels, mass, max_s)))
        if gravity is not None:
            effects.append(stage("gravity", lambda: Gravity(space, mass, gravity)))
        self._pinned = np.zeros(0, np.int64) if pinned is None else pinned
        if pinned is not None:
            scale = (_passive_diagonal(space, w_mu), float(mass.mean()))
            effects.append(stage("pinned", lambda: Pins(space, pinned, pin_stiffness, scale)))
        if any(damping):
            effects.append(Damping(inertia, elasticity, *damping))
        self._contact_vertices = np.zeros(0, np.int64)
        if ground is not None:
            self._contact_vertices = boundary_vertices(self._mesh) if contact_vertices is None else contact_vertices
            contact = lambda: _contact_effect(space, self._contact, self._contact_vertices, ground, self._up)
            effects.append(stage("contact", contact))
        self._model = stage("system", lambda: Model(space, effects, h))
        _warn_stiff_pins(self._model.named.get("pinned"), h)
        stage("backends", self._rebuild)
        self._com = space.com_rows(mass)

    def __setattr__(self, name, value):
        # every setting is a property (live, or read-only and raising): a misspelt one would otherwise
        # become a new attribute that changes nothing (sim.dt = 0.5 left h as it was)
        if not (name.startswith("_") or name in _ATTRIBUTES or hasattr(type(self), name)):
            raise AttributeError(f"{type(self).__name__} has no setting {name!r}{_nearest_setting(type(self), name)}")
        super().__setattr__(name, value)

    def __getstate__(self):
        # the backends are buffers and views made from the model: rebuilt on arrival, with what the next
        # step takes from the last (warm starts, shifts: without them a 3D run went on 1e-16 off)
        state = self.__dict__.copy()
        state["_carried"] = [(backend.name, backend.carried()) for backend in state.pop("_backends")]
        return state

    def __setstate__(self, state):
        carried = state.pop("_carried", [])
        self.__dict__.update(state)
        self._rebuild()
        for backend, (name, taken) in zip(self._backends, carried):
            if backend.name == name:
                backend.carry(taken)

    # -------------------------------------------------------------- settings
    @property
    def model(self) -> Model:
        """The precomputed operators and effects (:class:`~skfem_modal.model.Model`; read-only)."""
        return self._model

    @property
    def solver(self) -> LocalGlobal:
        """The local/global driver (its ``batch`` flag and ``predicted`` count; the limits are settings here)."""
        return self._solver

    def _rebuild(self) -> None:
        """New backends after the model or the driver's limits changed."""
        self._backends = make_backends(self._model, self._backend, self._solver.max_iter)
        self._solver.bind(self._model)

    def reset(self) -> None:
        """Forget what earlier steps leave for the next (the iteration count to batch, the rotations' warm starts).

        Without ground contact results do not depend on it beyond round-off. The Coulomb
        contact keeps the vertices it looked at for the next steps, and another choice holds
        the body up as well but not identically (within its allowance: a step differed by up
        to 9e-4 of the size); contact-rich runs are chaotic besides. So a run that must repeat
        bit for bit (a gait search's rollout, replayed from its scene file) starts from here,
        as a new simulator does.
        """
        self._solver.forget_prediction()
        self._stepped = False
        if self._model.contact is not None:
            self._model.contact.forget()
        self._rebuild()

    @property
    def effects(self) -> tuple:
        """The effects this simulator holds and steps, in order (read-only)."""
        return tuple(e.name for e in self._model.effects)

    @property
    def h(self) -> float:
        """Time step; assigning re-factors the system (the reductions are kept)."""
        return self._model.h

    @h.setter
    def h(self, value) -> None:
        value = _positive_scalar(value, "h")
        damping = (self.damping_mass, self.damping_stiffness)
        _fits_float64(self._mesh, self._mu, self._gamma, self._rho, value, self.gravity, damping)
        self._model.retime(value)
        self._rebuild()
        _warn_of_step(self)

    @property
    def max_iter(self) -> int:
        """Local/global iterations per step, at most."""
        return self._solver.max_iter

    @max_iter.setter
    def max_iter(self, value) -> None:
        self._solver.max_iter = _iterations(value)
        # the backends' buffers are sized by it; what the contact and the run hold stays (a reset here made a
        # later ground be judged on the rest shape, not where the body was, and changed a 3D crawl by 4e-4)
        self._solver.predicted = min(self._solver.predicted, self._solver.max_iter)
        self._rebuild()

    tol = _driver_setting(
        "tol", _nonnegative, "Stopping tolerance: the last iteration's change of ``z`` over ``motion_scale`` (0: off)."
    )
    rtol = _driver_setting("rtol", _nonnegative, "Relative stopping tolerance (0: off).")
    etol = _driver_setting(
        "etol", _nonnegative, "Relative energy-change tolerance (0: off; costs an energy evaluation per iteration)."
    )

    @property
    def warm_start(self) -> bool:
        """Start each step's iterations from the inertial prediction ``z + h z_dot`` (not under reference contact)."""
        return self._solver.warm_start

    @warm_start.setter
    def warm_start(self, value) -> None:
        self._solver.warm_start = checked_flag(value, "warm_start")
        _warn_if_idle(self._solver, self._model.contact, "warm_start")

    @property
    def acceleration(self) -> str:
        """Accelerated iterates: ``none``, ``anderson`` or ``newton`` (:mod:`~skfem_modal.acceleration`)."""
        return self._solver.acceleration

    @acceleration.setter
    def acceleration(self, value) -> None:
        self._solver.acceleration = _acceleration_name(value, full_space=self._B is None)
        _warn_if_idle(self._solver, self._model.contact, "acceleration")

    @property
    def residual(self) -> float:
        """The last step's residual: its last change ``|z_k - z_(k-1)|`` (``tol`` tests it over ``motion_scale``)."""
        return self._solver.change

    @property
    def motion_scale(self) -> float:
        """The length of a change of ``z`` that moves the body's vertices by its size (mass-weighted RMS)."""
        return self._model.scale

    @property
    def backend(self) -> str:
        """The backend asked for (``auto``, ``numpy``, ``numba`` or ``plain``)."""
        return self._backend

    @backend.setter
    def backend(self, value) -> None:
        self._backend = _backend_name(value)
        self._rebuild()

    @property
    def backend_used(self) -> str:
        """The backend that steps: ``numpy``, ``numba`` or ``plain``."""
        return self._backends[0].name.split()[0]

    @property
    def backends(self) -> tuple:
        """The backends in use: the one that steps, then its exact fallback if it has one (read-only)."""
        return tuple(self._backends)

    @property
    def gravity(self):
        """Gravitational acceleration, shape (dim,), or None; assigning adds, changes or removes it."""
        effect = self._model.named.get("gravity")
        return None if effect is None else _read_only(effect.acceleration)

    @gravity.setter
    def gravity(self, value) -> None:
        if value is None:
            self._model.remove("gravity")
        else:
            value = _array(value, (self.dim,), "gravity")
            up_axis(value, self.dim, self._up, self.ground is not None)  # pulls down along up onto a ground
            _pulled_to_ground(value, self.ground, self._up)
            self._model.replace(Gravity(self._space, self.mass, value))
        self._rebuild()

    @property
    def pin_stiffness(self):
        """The pins' spring stiffness at the current time step (None without pins); assigning None gives back
        the default, which follows the time step (a value read and assigned back stays at it)."""
        pins = self._model.named.get("pinned")
        return None if pins is None else pins.stiffness(self.h)

    @pin_stiffness.setter
    def pin_stiffness(self, value) -> None:
        pins = self._model.named.get("pinned")
        if pins is None:
            raise AttributeError("pin_stiffness: this simulator has no pinned vertices (build it with pinned=...)")
        given = None if value is None else _positive_scalar(value, "pin_stiffness")
        old, pins.given_stiffness = pins.given_stiffness, given
        self._model.assemble_or_undo(lambda: setattr(pins, "given_stiffness", old))
        self._rebuild()
        _warn_stiff_pins(pins, self.h)

    def _damp(self, alpha: float, beta: float) -> None:
        """Rayleigh damping with these coefficients (none when both are 0)."""
        if alpha or beta:
            self._model.replace(Damping(self._model.inertia, self._model.elasticity, alpha, beta))
        elif "damping" in self._model.named:
            self._model.remove("damping")
        self._rebuild()

    damping_mass = _damping_setting(
        "damping_mass", "mass_coefficient", "Mass-proportional Rayleigh damping alpha (1 / time)."
    )
    damping_stiffness = _damping_setting(
        "damping_stiffness", "stiffness_coefficient", "Stiffness-proportional Rayleigh damping beta (time)."
    )

    @property
    def max_s(self):
        """The muscles' ceiling rule (None without muscles); assigning recomputes :attr:`ceilings`."""
        muscles = self._model.muscles
        return None if muscles is None else muscles.max_s

    @max_s.setter
    def max_s(self, value) -> None:
        if self._model.muscles is None:
            raise AttributeError("max_s: this simulator has no muscles")
        self._model.muscles.max_s = _positive_scalar(value, "max_s")

    @property
    def ceilings(self) -> np.ndarray:
        """Amplitude ceilings of the muscles, shape (m,)."""
        muscles = self._model.muscles
        return _read_only(np.zeros(0) if muscles is None else muscles.ceilings)

    # ----------------------------------------------------------------- state
    def rest_state(self):
        """The rest state: ``(z, z_dot, a)``.

        Returns
        -------
        z : ndarray, shape (r,)
            Mass-weighted projection of the rest positions onto the space.
        z_dot : ndarray, shape (r,)
            Zeros.
        a : ndarray, shape (m,)
            Zero activation, one value per muscle.
        """
        z = self._model.rest.copy()
        return z, np.zeros_like(z), np.zeros(self.n_muscles)

    def coordinates(self, x) -> np.ndarray:
        """Mass-weighted least-squares coordinates of a full field (positions or velocities).

        Parameters
        ----------
        x : ndarray, shape (n, dim) or (n * dim,)

        Returns
        -------
        z : ndarray, shape (r,)
        """
        return self._space.coordinates(_vertex_field(x, *self._mesh.p.shape[::-1]), self.mass)

    def _state(self, z, name: str = "z") -> np.ndarray:
        """A state or velocity as a float array, checked to have shape (r,)."""
        return checked_state(z, self._space.r, name)

    def positions(self, z) -> np.ndarray:
        """Vertex positions of a state ``z``, shape (r,): returns shape (n, dim)."""
        return self._space.positions(self._state(z))

    def com(self, z) -> np.ndarray:
        """Centre of mass of a state ``z``, shape (r,), read straight from it: returns shape (dim,)."""
        return self._com @ self._state(z)

    @property
    def com_rows(self) -> np.ndarray:
        """The centre of mass as a linear map of the state (``com(z) = com_rows @ z``), shape (dim, r), read-only."""
        rows = self._com.view()
        rows.flags.writeable = False
        return rows

    def muscle_amplitudes(self, z) -> np.ndarray:
        """Realised modal amplitudes: the mass-weighted projection of the displacement on each muscle.

        For a free body the displacement from its rest shape moved by its best rigid
        motion (mass-weighted, Kabsch), so that turning or travelling is not read as
        muscle action; for one its pins hold in place (no rigid motion left: two pins
        in 2D, three not in a line in 3D) the displacement from the rest shape. Each
        body of a mesh of several by its own rule.

        Parameters
        ----------
        z : ndarray, shape (r,)

        Returns
        -------
        amplitudes : ndarray, shape (m,)
        """
        muscles = self._model.muscles
        if muscles is None:
            return np.zeros(0)
        return muscles.amplitudes(self._state(z), self.pinned)

    def contact_positions(self, z) -> np.ndarray:
        """Positions of the contact vertices in a state ``z`` (r,), shape (p, dim) (empty without a ground)."""
        contact = self._model.contact
        return np.zeros((0, self.dim)) if contact is None else contact.positions(self._state(z))

    # ------------------------------------------------------------------ step
    def _activation(self, a) -> np.ndarray:
        """The muscles' activation checked, shape (m,); None: zero (the muscles at rest)."""
        return _checked_activation(a, self._n_muscles)

    def step(self, z, z_dot, a=None, *, velocity: bool = False):
        """Advance one time step.

        Parameters
        ----------
        z, z_dot : ndarray, shape (r,)
            Position and velocity at the start of the step.
        a : ndarray, shape (m,), optional
            Muscle activations during the step (None: zero, the muscles at rest).
        velocity : bool
            Also return the new velocity ``(z_next - z) / h``.

        Returns
        -------
        z_next : ndarray, shape (r,)
        z_dot_next : ndarray, shape (r,)
            Only with ``velocity=True``.

        Raises
        ------
        SimulationError
            If the state becomes non-finite.
        """
        z, z_dot = _real(z, "z"), _real(z_dot, "z_dot")
        r = self._space.r
        if velocity is not True and velocity is not False:  # (a bool: "yes" would be true)
            checked_flag(velocity, "velocity")
        if z.shape != (r,) or z_dot.shape != (r,):
            raise ValueError(f"z and z_dot must have shape ({r},), got {z.shape} and {z_dot.shape}")
        a = self._activation(a)
        # overflow in a blown-up state is reported as a SimulationError, not as warnings
        with np.errstate(over="ignore", invalid="ignore"):
            try:
                z_next, self.iterations = self._solver.step(self._backends, z, z_dot, a, self._model.contact)
            except np.linalg.LinAlgError as err:  # (a contact's correction at a huge step, say): the step's trouble
                raise SimulationError(f"the step's linear algebra failed: {err} (time step h = {self.h:g})") from err
            except SimulationError:
                _non_finite_as_given(z=z, z_dot=z_dot)  # the caller's, not the step's (checked only then)
                raise
        self._stepped = True
        if velocity:
            return z_next, (z_next - z) / self._model.h
        return z_next

    # ---------------------------------------------------------------- energy
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
        z_next, z, z_dot = self._state(z_next, "z_next"), self._state(z), self._state(z_dot, "z_dot")
        return self._model.energy(z_next, z, z_dot, a, checked_flag(gradient, "gradient"))

    def mechanical_energy(self, z, z_dot) -> float:
        """Kinetic plus potential energy of a state, the muscles at rest.

        ``1/2 z_dot^T BMB z_dot`` plus the elastic energy (passive, and the
        muscles' with zero activation, rotations optimal), the pins' and the
        gravitational potential. Without input (zero activation) implicit
        Euler and damping only remove energy, and the Coulomb contact does in
        the stability tests (a 3D beam settling on the ground at h = 0.01 has
        steps that gain up to 0.03 % of what its fall released). The reference
        contact can add energy (it constrains velocities at sampled points;
        with ``push_out`` it moves them onto the ground by least squares): a
        caterpillar dropped at h = 0.1 with ``push_out = 1`` ended with 173
        times the energy it started with.

        Parameters
        ----------
        z, z_dot : ndarray, shape (r,)

        Returns
        -------
        E : float
        """
        z = self._state(z)
        return self.kinetic_energy(z_dot) + self.energy(z, z, np.zeros_like(z), np.zeros(self.n_muscles))

    def kinetic_energy(self, z_dot) -> float:
        """The kinetic energy of a velocity ``z_dot``, shape (r,): ``1/2 z_dot^T B^T M B z_dot``."""
        v = self._state(z_dot, "z_dot")
        return 0.5 * float(v @ (self._model.inertia.mass_matrix @ v))

    # ----------------------------------------------------------- convenience
    # the set-up pipeline (ingredients, then the constructor) lives beside the class
    from_mesh = classmethod(_from_mesh)


_from_mesh.__name__, _from_mesh.__qualname__ = "from_mesh", "ModalMuscle.from_mesh"


def _taken_by(function, arguments: dict) -> dict:
    """The arguments, by name, that ``function`` takes."""
    parameters = inspect.signature(function).parameters
    return {name: value for name, value in arguments.items() if name in parameters}


def _passive_diagonal(space, weights) -> float:
    """The mean diagonal of the passive Hessian ``J^T (w x I) J`` per DOF (the pins' default scale)."""
    J = space.J
    row_norms = np.asarray(J.multiply(J).sum(axis=1)).ravel()
    dd = space.dim * space.dim
    return float(np.repeat(weights, dd) @ row_norms) / space.N


class StepRecord:
    """One step of :func:`simulate`: its number, time, state, activation and cost.

    Its constructor takes the attributes in this order (``change`` and ``start`` optional).

    Attributes
    ----------
    step : int
        1-based.
    time : float
        Time at the end of the step.
    z, z_dot : ndarray, shape (r,)
        State at the end of the step.
    a : ndarray, shape (m,)
        Activation during the step.
    seconds : float
        Wall time of ``sim.step``.
    iterations : int
    change : float
        The step's last change ``|z_k - z_(k-1)|`` (``sim.residual``).
    start : ndarray, shape (r,)
        The state the step started from.
    """

    __slots__ = ("step", "time", "z", "z_dot", "a", "seconds", "iterations", "change", "start")

    def __init__(self, step, time, z, z_dot, a, seconds, iterations, change=0.0, start=None):
        self.step, self.time, self.z, self.z_dot = step, time, z, z_dot
        self.a, self.seconds, self.iterations, self.change, self.start = a, seconds, iterations, change, start

    @property
    def residual(self) -> float:
        """The last change over the step's motion ``|z_k - z|``: how far from converged it stopped.

        0 for a step that did not move beyond round-off of its state (or whose start is not known): a body
        at rest changed by 1.5e-16 over a motion of 1.5e-16, a residual of 1 (an audit).
        """
        if self.start is None:
            return 0.0
        motion = float(np.linalg.norm(self.z - self.start))
        still = motion <= 1e-13 * float(np.linalg.norm(self.z))
        return 0.0 if still else self.change / motion


def simulate(sim, steps: int, activation=None, state=None):
    """Step a simulator: the one loop behind runs, studies and gait searches.

    Parameters
    ----------
    sim : ModalMuscle
    steps : int
    activation : callable or array_like, optional
        ``activation(t)`` gives the muscles' activation during the step that
        starts at time ``t``, shape (m,); an array, the same activation every
        step; None: zero.
    state : tuple of ndarray, shape (r,), optional
        ``(z, z_dot)`` to start from (``sim.rest_state()``'s three values do too: its zero
        activation is not used); default the rest state.

    Yields
    ------
    record : StepRecord
        After each step.

    Raises
    ------
    ValueError
        At the call, if ``steps`` is not an integer >= 0.
    SimulationError
        With the step number, if the state becomes non-finite.

    Examples
    --------
    >>> from skfem_modal import caterpillar
    >>> sim = ModalMuscle.from_mesh(caterpillar(nx=12, ny=6), n_muscles=1, n_weights=2, n_clusters=3)
    >>> last = None
    >>> for record in simulate(sim, 5, lambda t: 0.1 * sim.ceilings):
    ...     last = record
    >>> last.step, round(last.time, 12), last.z.shape == sim.rest_state()[0].shape
    (5, 0.1, True)
    """
    if not is_whole(steps) or steps < 0:
        raise ValueError(f"steps must be an integer >= 0, got {steps!r}")
    if state is None:
        state = sim.rest_state()
    if not isinstance(state, (tuple, list)) or len(state) not in (2, 3):
        raise ValueError("state must be (z, z_dot), e.g. sim.rest_state()[:2]")
    z, z_dot = sim._state(state[0]), sim._state(state[1], "z_dot")
    if activation is not None and not callable(activation):
        constant = _read_only(np.array(sim._activation(activation)))  # checked now, and the caller's no more
        activation = lambda t: constant  # noqa: E731
    return _steps(sim, int(steps), activation, z, z_dot)


def _steps(sim, steps: int, activation, z, z_dot):
    """The generator behind :func:`simulate` (its arguments checked at the call, not at the first step)."""
    zero = np.zeros(sim.n_muscles)
    # the time as start + k h since h was last assigned (a live setting): exactly i h while it is not
    h, start, since = sim.h, 0.0, 0
    for i in range(steps):
        if sim.h != h:
            start, since, h = start + since * h, 0, sim.h
        a = zero if activation is None else activation(start + since * h)
        clock = time.perf_counter()
        try:
            z_next, z_dot = sim.step(z, z_dot, a, velocity=True)
        except SimulationError as err:
            raise SimulationError(err.message, step=i + 1) from None
        seconds = time.perf_counter() - clock
        since += 1
        record = StepRecord(i + 1, start + since * h, z_next, z_dot, a, seconds, sim.iterations, sim.residual, z)
        z = z_next
        yield record
