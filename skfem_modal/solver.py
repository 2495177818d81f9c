"""The local/global driver: one stopping rule over interchangeable backends.

A step minimises the energy of :mod:`skfem_modal.model` by block-coordinate
descent: the *local* step sets every cluster rotation to the closest
rotation of its rows ``S(u)`` (a polar decomposition), the *global* step
solves ``H u = rhs + G^T vec(R)`` with the constant, factored ``H``, and
ground contact, when present, projects each global solution. One driver,
:class:`LocalGlobal`, runs these iterations and applies the one stopping
rule: stop at the first iteration ``k`` with

    |u_k - u_(k-1)| < tol L    or    |u_k - u_(k-1)| <= rtol |u_k - u_start|
                               or    E(u_(k-1)) - E(u_k) <= etol (E(u_0) - E(u_k)),

(``u_start`` the step's start state, ``u_0`` the first iterate's input, ``E``
the step energy), after at most ``max_iter``; a non-finite iterate is an
error. ``L`` is the model's ``scale``, the change of ``u`` that moves the
body by its size: ``tol`` is a fraction of the body's size, the same in any
units and for any body (the reference's absolute ``1e-6`` on ``u`` lets a
body measured in centimetres stop after one iteration). The last change
``|u_k - u_(k-1)|`` is the step's *residual* (the plain iteration's step
there: ``H^-1`` times the energy's gradient).

Faster convergence to the same point, each off by default
(:mod:`skfem_modal.acceleration`): ``warm_start`` starts the iterations from
the inertial prediction ``u + h v`` instead of ``u``; ``acceleration``
(``"anderson"`` or ``"newton"``) makes the iterations one at a time and
hands the backend an accelerated iterate whenever its energy is no higher
than that of the plain iterate it replaces. Under contact (a projection,
not an energy) the iterations are not accelerated; they are warm-started
unless the contact's rule reads the iterates (``contact.reads_iterates``:
the reference model's does).

A *backend* does the arithmetic of the iterations and owns its buffers; the
driver calls:

``start(z, z_dot, a)``
    set up a step (its constant part and the muscles' activation);
``start_row()``
    the start state as a row of the backend's choosing;
``restart(z)``
    continue from ``z`` (shape (r,)) instead of the last iterate: the next
    ``iterate`` starts from it and returns it as its first row. The driver
    hands over warm starts and accelerated iterates this way;
``iterate(count, contact)``
    run ``count`` iterations, the contact (or None) projecting each global
    solution (``contact.project(z, watched)``, where a backend may compute
    ``watched = contact.watch @ z`` within its own products, and keep both
    in one state vector it describes by a :class:`StateLayout`:
    ``contact.project(state, watched, layout)``); return the
    last iterate before them and the ``count`` new ones as rows, shape
    (count + 1, q), whose differences have the norms of the differences of
    the ``z``'s;
``finish(k)``
    the step stopped after ``k`` iterations (None: it went non-finite):
    True accepts it; a backend whose rotations are not *exact* may check
    them here and refuse, and the driver redoes the step with the next
    backend;
``result(k)``
    ``z_k``, a new array of shape (r,);
``carried()`` and ``carry(state)``
    what the next step takes from the last (warm starts, shifts), as a dict, and
    taking it back: a simulator pickled mid-run goes on as it would have.

``max_batch`` says how many iterations one ``iterate`` call may run. The
driver runs as many as the last step took without looking (they seldom
change from step to step), then tests them in one batch: the same answer as
testing each in turn.

Backends (chosen by :func:`make_backends`): :class:`PlainBackend` here (any
space and dimension, every rotation exact; the full-space reference and the
fallback of the others), and in their own modules the fast ones: 2D numpy
(:mod:`skfem_modal._step2`), 3D numpy in Kronecker form with a certificate
(:mod:`skfem_modal._kron3`), and numba-compiled iterations
(:mod:`skfem_modal._compiled`).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sps

from . import _accel
from ._fast import dot
from .rotations import closest_rotations3, rotations2_flat

__all__ = [
    "LocalGlobal",
    "PlainBackend",
    "ActivationRows",
    "StateLayout",
    "SimulationError",
    "make_backends",
    "BACKENDS",
]

# A step whose contact missed vertices that ended below the ground is run again, seeing them, up to
# this many times; what is still below after that is held up at its end (a kick: velocity d / h).
_RUNS_FOR_MISSED = 2

#: Backend names a simulator accepts.
BACKENDS = ("auto", "numpy", "numba", "plain")

#: Iterations a first step (or one after a reset) runs before its first stopping test, at most; later
#: steps batch as many as the step before took. (All of max_iter: 5000 iterations where 6 would do.)
FIRST_BATCH = 16

#: The default ``tol``: iterations stop when a step's last one moved the body by
#: less than this fraction of its size (about the reference's absolute 1e-6 on
#: the tutorial's caterpillar, whose ``scale`` is 2.32).
TOL = 5e-7


class SimulationError(RuntimeError):
    """The simulation went non-finite: ``message`` says how; ``step`` is the step number when known."""

    def __init__(self, message: str, step: int | None = None):
        super().__init__(message if step is None else f"step {step}: {message}")
        self.message, self.step = message, step


class StateLayout:
    """Where a backend keeps an iterate's ``z`` and the contact's watched values, in one flat state vector.

    A contact that watches (``contact.watch``) corrects such a state in place with corrections it
    makes once for the layout, so the backend copies nothing in or out.

    Parameters
    ----------
    size : int
        Length of the state vector.
    z_index : ndarray of int, shape (r,)
        ``z = state[z_index]``.
    watched_index : ndarray of int, shape (p,)
        ``contact.watch @ z = state[watched_index]``.
    one_index : int
        An entry of the state that always holds 1 (a contact's constant terms ride on it).
    """

    def __init__(self, size, z_index, watched_index, one_index):
        self.size, self.z_index, self.watched_index = int(size), np.asarray(z_index), np.asarray(watched_index)
        self.one_index = int(one_index)


class ActivationRows:
    """Writes operators that are affine in the activation, ``X(a) = X_0 + sum_k a_k X_k``.

    Parameters
    ----------
    pairs : list of (ndarray of shape (m + 1, ...), ndarray view)
        Each operator's stack ``[X_0, X_1, ..., X_m]`` and where ``X(a)``
        goes. One product serves all of them.
    """

    def __init__(self, pairs):
        m = pairs[0][0].shape[0] - 1
        self.varying = np.hstack([np.asarray(stack[1:]).reshape(m, -1) for stack, _ in pairs])
        self.product = np.empty(self.varying.shape[1])
        self.parts = []
        offset = 0
        for stack, destination in pairs:
            size = stack[0].size
            part = self.product[offset : offset + size].reshape(destination.shape)
            self.parts.append((part, np.array(stack[0]).reshape(destination.shape), destination))
            offset += size

    def write(self, a) -> None:
        """Write ``X(a)`` of each operator into its destination, for the activation ``a`` (m,)."""
        dot(a, self.varying, self.product)
        for part, constant, destination in self.parts:
            np.add(part, constant, out=destination)


class PlainBackend:
    """Iterations in plain numpy, one a call, every rotation exact; any space, 2D or 3D.

    2D rotations in closed form, 3D ones from Horn's quaternion
    (:func:`~skfem_modal.rotations.closest_rotations3`, warm-started within
    a step and checked as eigenvectors). In a subspace the global step is
    ``z = c + [W | W_A(a)] vec(R)``; in the full space a sparse back-solve.
    Its methods are the backend interface the driver calls (the module docstring).

    Parameters
    ----------
    model : Model
        The operators it steps (:class:`~skfem_modal.model.Model`).
    """

    name = "plain"
    max_batch = 1
    exact = True

    def __init__(self, model):
        self.model = model
        space = model.space
        self.dim, self.dense = space.dim, space.dense
        self.dd = self.dim * self.dim
        self.rows_buffer = self.cols_buffer = None
        self.activation = None
        if self.dense:
            G, W = model.G, model.W
            self.rows_buffer = np.vstack([G] + ([model.A[0]] if model.A is not None else []))
            self.cols_buffer = np.hstack([W] + ([model.WA[0]] if model.A is not None else []))
            if model.A is not None and model.n_muscles:
                nG = G.shape[0]
                self.activation = ActivationRows(
                    [(model.A, self.rows_buffer[nG:]), (model.WA, self.cols_buffer[:, nG:])]
                )
        self.Y = np.empty((2, space.r))
        self.n_passive = model.G.shape[0]
        self.offset = None

    def start(self, z, z_dot, a) -> None:
        """Set up a step from ``z``, ``z_dot`` (r,) under the activation ``a`` (m,)."""
        model = self.model
        self.c = model.constant(z, z_dot)
        if self.dense:
            if self.activation is not None:
                self.activation.write(a)
            self.rows = self.rows_buffer
        else:
            blocks = [model.G] + ([model.muscles.rows_for(a)] if model.muscles is not None else [])
            self.rows = sps.vstack(blocks, format="csr")
        self.offset = None
        terms = model.start_terms(z)
        if terms is not None:
            offset, shift = terms
            self.c = self.c + shift
            self.offset = np.zeros(self.rows.shape[0])
            self.offset[: self.n_passive] = offset
        self.z0 = np.array(z, dtype=float)
        self.Y[1] = self.z0
        self.q = None
        self.k = 0

    def start_row(self):
        """The step's start state, shape (r,)."""
        return self.z0

    def restart(self, z) -> None:
        """Continue from ``z`` (r,) instead of the last iterate."""
        self.Y[1] = z

    def rotations(self, S):
        """The closest rotations of the clusters' ``S`` (row-major, flat), flat like it."""
        if self.dim == 2:
            return rotations2_flat(S.reshape(-1, 4))
        R, self.q = closest_rotations3(S.reshape(-1, 9), self.q)
        return R

    def arguments(self, z):
        """The clusters' matrices whose closest rotations an iteration from ``z`` takes, flat (clusters dd,)."""
        S = self.rows @ z
        return S if self.offset is None else S + self.offset

    def iterate(self, count, contact):
        """One iteration (``count`` is at most :attr:`max_batch`, 1), ``contact`` (or None) projecting it.

        Returns the last iterate and the new one as rows, shape (2, r).
        """
        self.Y[0] = self.Y[1]
        z = self.Y[0]
        R = self.rotations(self.arguments(z)).ravel()
        if self.dense:
            z_next = self.c + self.cols_buffer @ R
        else:
            if self.model.rotation_scale != 1.0:  # (a subspace has it in cols_buffer)
                R = R.copy()
                R[: self.n_passive] *= self.model.rotation_scale
            z_next = self.c + self.model.system.solve(self.rows.T @ R)
        if contact is not None:
            contact.project(z_next)
        self.Y[1] = z_next
        self.k += 1
        return self.Y

    def finish(self, k) -> bool:
        """Accept the step stopped after ``k`` iterations: True (every rotation is exact)."""
        return True

    def result(self, k):
        """``z_k``, the step's result after ``k`` iterations, a new array of shape (r,)."""
        return self.Y[1].copy()

    def carried(self) -> dict:
        """What the next step takes from the last: nothing, each step starts its rotations afresh.

        Returns
        -------
        state : dict
            Empty.
        """
        return {}

    def carry(self, state: dict) -> None:
        """Take what :meth:`carried` gave (nothing, here).

        Parameters
        ----------
        state : dict
        """


class LocalGlobal:
    """The local/global driver and its stopping rule.

    Parameters
    ----------
    max_iter : int
        Iterations a step, at most.
    tol, rtol, etol : float
        The stopping rule (module docstring); 0 switches a test off. ``tol``
        is a fraction of the body's size (of the bound model's ``scale``).
        ``etol`` evaluates the step energy at every iterate.
    batch : bool
        Run the iterations the last step took before testing them (the same
        answer; False tests each as it is made).
    warm_start : bool
        Start each step's iterations from the inertial prediction ``u + h v``.
    acceleration : {"none", "anderson", "newton"}
        Hand the backend accelerated iterates (:mod:`skfem_modal.acceleration`).
    memory : int
        Anderson's history.

    Warm starts, energies and accelerations need the model: :meth:`bind`.

    Attributes
    ----------
    predicted : int
        Iterations of the last step.
    redone : int
        Steps a backend refused (its rotations failed their check), redone by the next.
    accepted, refused : int
        Accelerated iterates kept, and refused for their energy (all steps).
    """

    def __init__(self, max_iter=10, tol=TOL, rtol=0.0, batch=True, *, etol=0.0, warm_start=False,
                 acceleration="none", memory=5):  # fmt: skip
        self.max_iter, self.tol, self.rtol, self.etol, self.batch = max_iter, tol, rtol, etol, batch
        self.warm_start, self.memory = warm_start, memory
        self.forget_prediction()
        self.redone = self.accepted = self.refused = 0
        self._change2 = 0.0
        self.model = None
        self.scale = 1.0  # of u, the model's (bind)
        self._acceleration = acceleration
        self._helpers = None
        self._work = {}

    def bind(self, model) -> None:
        """Step ``model`` (a :class:`~skfem_modal.model.Model`; after it changed: its energy and accelerator are
        made again when needed)."""
        self.model = model
        self.scale = model.scale
        self._helpers = None

    @property
    def acceleration(self) -> str:
        """``none``, ``anderson`` or ``newton``."""
        return self._acceleration

    @acceleration.setter
    def acceleration(self, value) -> None:
        self._acceleration = value
        self._helpers = None

    def __getstate__(self):
        # the energy and the accelerator are made from the model on demand
        return {**self.__dict__, "_helpers": None}

    def _energy_and_accelerator(self):
        if self._helpers is None:
            from .acceleration import StepEnergy, make_accelerator

            self._helpers = (StepEnergy(self.model), make_accelerator(self._acceleration, self.model, self.memory))
        return self._helpers

    def step(self, backends, z, z_dot, a, contact=None):
        """One step from ``(z, z_dot)``: ``(z_next, iterations)``.

        Each backend in turn until one accepts the step (the last must be exact).

        Parameters
        ----------
        backends : list
            From :func:`make_backends`: the fast one first, an exact one last.
        z, z_dot : ndarray, shape (r,)
        a : ndarray, shape (m,)
        contact : Effect, optional
            The model's contact, which projects each global solution.

        Returns
        -------
        z_next : ndarray, shape (r,)
        iterations : int

        Raises
        ------
        SimulationError
            If the state becomes non-finite.
        """
        found = self._attempt(backends, z, z_dot, a, contact)
        if contact is not None:
            for _ in range(_RUNS_FOR_MISSED):
                if not contact.missed(found[0]):
                    break
                # the contact looked at too few vertices (one ended deep below the ground): again, with it
                found = self._attempt(backends, z, z_dot, a, contact)
            contact.finish_step(found[0])
        return found

    def _attempt(self, backends, z, z_dot, a, contact):
        """The step's iterations, by each backend in turn until one accepts them."""
        for tried, backend in enumerate(backends):
            if contact is not None:
                contact.start_step(z, z_dot, again=tried > 0)
            backend.start(z, z_dot, a)
            start = backend.start_row()
            if self.warm_start and not (contact is not None and contact.reads_iterates):
                start = start.copy()
                backend.restart(z + self.model.h * z_dot)
            energy = accelerator = None
            if self.etol or (self._acceleration != "none" and contact is None):
                energy, accelerator = self._energy_and_accelerator()
                energy.start(z, z_dot, a)
                if contact is not None:
                    accelerator = None
            if accelerator is not None:
                found = self._run_accelerated(backend, start, energy, accelerator)
            else:
                found = self._run(backend, contact, start, energy)
            if found is not None:
                return found
            self.redone += 1
        raise AssertionError("the last backend must accept every step")

    def _run(self, backend, contact, start, energy):
        """Plain iterations, in batches; with ``energy``, the energy of every iterate for ``etol``."""
        done, limit, batch = 0, self.max_iter, min(backend.max_batch, self.predicted if self.batch else 1)
        energies = None if energy is None else np.array([energy(backend.result(0))])
        first = None if energy is None else energies[0]
        while True:
            count = min(limit - done, max(1, batch - done))
            rows = backend.iterate(count, contact)
            if energy is not None:
                new = [energy(backend.result(done + j)) for j in range(1, count + 1)]
                energies = np.array([energies[-1]] + new)
            hit = self._first_stop(rows, start, energies, first)
            done += count
            if hit:
                break
            if done == limit:
                hit = count
                break
        return self._finish(backend, done - count + hit if hit > 0 else hit)

    def _run_accelerated(self, backend, start, energy, accelerator):
        """One iteration at a time; after each, an accelerated iterate if its energy is no higher.

        A proposal made from ``x`` and its plain iterate ``g`` replaces ``g``
        (handed to the backend) only when its step energy is at most that of
        ``g`` (to round-off); otherwise ``g`` is kept and the accelerator's history
        forgotten. So every iterate is at least as low as the plain one it
        replaces, and the energies of the results fall with the iterations.
        """
        accelerator.reset()
        x = backend.result(0)
        E = first = energy(x)
        local = energy.S, energy.R
        done = 0
        while True:
            rows = backend.iterate(1, None)
            done += 1
            g = backend.result(done)
            proposal = None
            if done < self.max_iter and np.all(np.isfinite(g)):
                proposal = accelerator.propose(x, g, energy, local)
            E_g = energy(g)
            local_g = energy.S, energy.R
            hit = self._first_stop(rows, start, np.array([E, E_g]), first)
            if hit or done == self.max_iter:
                return self._finish(backend, done if hit >= 0 else -1)
            if proposal is not None:
                E_p = energy(proposal)
                # no higher, to round-off: refusing a converged proposal over round-off restarts the accelerator
                if E_p <= E_g + energy.round_off:
                    backend.restart(proposal)
                    self.accepted += 1
                    x, E, local = proposal, E_p, (energy.S, energy.R)
                    continue
                self.refused += 1
                accelerator.reset()
            x, E, local = g, E_g, local_g

    def forget_prediction(self) -> None:
        """The next step's first batch as a first step's: ``max_iter``, at most :data:`FIRST_BATCH`."""
        self.predicted = min(self.max_iter, FIRST_BATCH)

    def _finish(self, backend, k):
        """Hand the step's outcome to the backend: ``(z_k, k)``, or None if it refuses (k < 0: non-finite)."""
        if k < 0:
            if backend.exact:
                raise SimulationError("the state became non-finite")
            backend.finish(None)
            return None
        if not backend.finish(k):
            return None
        self.predicted = k
        return backend.result(k), k

    def _first_stop(self, rows, start, energies=None, first=None) -> int:
        """The first row (1-based) that stops, negative if it is non-finite, 0 if none.

        ``energies``: of the rows (for ``etol``), ``first`` that of the step's first iterate's input.
        """
        count, q = rows.shape[0] - 1, rows.shape[1]
        work = self._work.get(q)
        if work is None or work[0].shape[0] < count:
            size = max(count, self.max_iter)
            work = self._work[q] = (np.empty((size, q)), np.ones(q), np.empty(size), np.ones(size))
        steps, ones, change2 = work[0][:count], work[1], work[2][:count]
        np.subtract(rows[1:], rows[:-1], steps)
        np.multiply(steps, steps, steps)
        dot(steps, ones, change2)
        if not dot(change2, work[3][:count]) < np.inf:
            # some change is not finite: that is an error, unless an earlier iteration stopped
            first_bad = int(np.argmin(change2 < np.inf))
            stopped = self._stops(change2[:first_bad], rows[: first_bad + 1], start, work, energies, first)
            return stopped if stopped else -(first_bad + 1)
        return self._stops(change2, rows, start, work, energies, first)

    def _stops(self, change2, rows, start, work, energies, first) -> int:
        """The first of finite changes (1-based) that meets the stopping rule, 0 if none."""
        stop = change2 < (self.tol * self.scale) ** 2
        if self.rtol:
            motion = np.subtract(rows[1:], start, work[0][: change2.size])
            np.multiply(motion, motion, motion)
            stop |= change2 <= self.rtol**2 * dot(motion, work[1])
        if energies is not None and self.etol:
            E = energies[: change2.size + 1]
            stop |= np.abs(E[:-1] - E[1:]) <= self.etol * np.abs(first - E[1:])
        if not np.count_nonzero(stop):
            if change2.size:
                self._change2 = change2[-1]
            return 0
        hit = int(stop.argmax()) + 1
        self._change2 = change2[hit - 1]
        return hit

    @property
    def change(self) -> float:
        """The last step's residual: its last change ``|u_k - u_(k-1)|``."""
        return math.sqrt(self._change2)


#: Iterations a step may take, at most: a backend keeps every iterate of a step (about 20 kB each for the
#: 3D numpy backend with 20 clusters: a billion asked for 179 GiB at the first step)
MAX_ITERATIONS = 100_000


#: in 3D, from this many rotations a step (clusters, the elasticity's and the muscles' own) on, the numpy
#: step in Kronecker form is faster than the compiled one (benchmarks/bench_backends.py, the seal floating:
#: 21 rotations 0.112 against 0.126 ms a step, 61 0.213 against 0.522; 16 0.096 against 0.090, 11 0.086
#: against 0.073): ``auto`` takes it there
KRONECKER_OVER_NUMBA = 20


def make_backends(model, name: str, max_iter: int) -> list:
    """The backends a simulator steps with: the fast one first, an exact fallback last.

    Parameters
    ----------
    model : Model
    name : {"auto", "numpy", "numba", "plain"}
        ``auto``: numba when installed, numpy otherwise; but in 3D with at least
        :data:`KRONECKER_OVER_NUMBA` clusters (the elasticity's and the muscles'
        own: rotations a step), numpy's Kronecker form where the subspace has it
        (faster there). ``numpy``: 2D buffers (:mod:`._step2`);
        3D in Kronecker form when the subspace moves x, y and z alike (skinning
        bases do; :mod:`._kron3`), plain otherwise. ``numba``: compiled
        iterations (the ``fast`` extra). ``plain``: one iteration at a time,
        every rotation exact (the reference for the others).
    max_iter : int

    Returns
    -------
    list
        The backends to try in turn, each built for ``model``: one whose rotations are exact, or the
        Kronecker form followed by the :class:`PlainBackend` that redoes a step it refuses.
    """
    dense_3d = model.space.dense and model.space.dim == 3
    plain = PlainBackend(model)
    if name == "auto":
        name = "numba" if _accel.AVAILABLE else "numpy"
        if name == "numba" and dense_3d and _clusters(model) >= KRONECKER_OVER_NUMBA:
            found = _kronecker(model, max_iter, plain)
            if found is not None:
                return found
    if name == "plain" or not model.space.dense:
        return [plain]
    if name == "numba":
        from ._compiled import compiled_backend

        return [compiled_backend(model, max_iter)]
    if not dense_3d:
        from ._step2 import Step2Backend

        return [Step2Backend(model, max_iter)]
    return _kronecker(model, max_iter, plain) or [plain]


def _clusters(model) -> int:
    """The model's clusters, the elasticity's and the muscles' own: its rotations a step (9 rows each in 3D)."""
    return (model.G.shape[0] + (model.A.shape[1] if model.A is not None else 0)) // 9


def _kronecker(model, max_iter, plain):
    """``[Kronecker form, plain]`` for a 3D model whose operators factor so, else None."""
    from ._kron3 import KroneckerBackend

    kron = KroneckerBackend.build(model, max_iter)
    return None if kron is None else [kron, plain]
