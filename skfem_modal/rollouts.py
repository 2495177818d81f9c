"""Gait rollouts: one gait run and scored, and workers that run many on one shared precompute.

A :class:`Trial` is a built simulator with a rollout length and a scoring
rule. Its score of a gait (amplitude, period and phase per muscle) is
measured on the whole run:

    travel      = (c(T) - c(0)) . d
    alignment   = max(0, min_t  d . R(t) d)
    tilt(t)     = angle between R(t) e_up and e_up
    tip_penalty = tip_weight * size * max(0, max_t tilt(t) - tip_limit) / pi

with ``c`` the centre of mass, ``d`` the unit travel direction (any vector;
in 3D usually a horizontal one), ``size`` the body's largest extent and
``R(t)`` the body's overall rotation: the closest rotation to
``sum_i m_i x_i(t) (X_i - C)^T`` (the identity at rest), read off the state at
every step (it is linear in the unknowns). Two objectives:

``travel``
    ``fitness = travel - tip_penalty``.
``aligned`` (the modal-muscle paper's: forward displacement times forward alignment)
    ``fitness = travel * alignment - tip_penalty`` when ``travel > 0``, else
    ``travel - tip_penalty``. The body's own axis ``d`` must keep pointing
    along ``d`` all the way: a gait that turns, rolls over its nose or
    tumbles scores in proportion to its worst moment (turned by 90 degrees
    or more, nothing). Backward travel is not scaled, so a gait cannot make
    a backward run look better by also turning.

A rollout that goes non-finite scores ``-1000 size``.

Workers. :class:`Rollouts` runs the gaits of one trial on an executor and
sends the trial's precompute (the pickled simulator: the backends are
rebuilt on arrival) once to each worker: the local process pool's
initializer reads it from a temporary file (removed when the pool closes;
not sent as the start-up arguments, which a worker dying before reading
them left the search waiting on for good), a dask cluster as one scattered object, the
pickled bytes (every worker holds one copy; the first task a worker runs
unpickles it, the others find it unpickled: scattered as a simulator, a
task racing the broadcast had it unpickled twice). Any other executor gets
the scene instead and each of its worker processes builds the simulator
once. Workers use ``blas_threads`` BLAS threads each (default one: the processes share the
cores, and a result does not depend on where it ran). The local pool's
workers ignore SIGINT, so Ctrl-C reaches the search alone, which stops them.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import signal
import tempfile
import threading
import time
import uuid
import warnings
import weakref
from contextlib import contextmanager

import numpy as np

from .checks import _nonnegative
from .interrupts import exit_with_parent
from .mesh import body_size
from .monitor import MotionMonitor
from .muscles import checked_ramp, shortest_period, sine_gait
from .rotations import polar_rotations
from .sim import SimulationError, simulate
from .study import WorkersLost, checked_executor, dask_client, lost_workers, make_executor
from .threads import checked_thread_count, limited_blas_threads
from .values import is_whole

__all__ = ["OBJECTIVES", "MAX_ROLLOUT_STEPS", "Trial", "Rollouts", "rollout", "rollout_steps", "body_rotation_rows"]

#: Times a search scatters its trial again after dask lost it with its workers, at most.
_RESCATTERS = 3
#: How long a search waits for a worker to scatter its trial to again.
_WORKERS_BACK_SECONDS = 10.0

#: The objectives a :class:`Trial` scores with.
OBJECTIVES = ("travel", "aligned")

# this process's trials, by key, and how many it received (unpickled) or built
_TRIALS: dict = {}
# a long-lived worker (dask's) keeps the trials of its last few searches, not of every one it served
_KEPT_TRIALS = 3
_COUNTS = {"received": 0, "built": 0}
_BLAS_LIMIT: list = []  # the open thread limit of this worker process (kept open while it lives)
_TASK_LIMIT: list = []  # in a worker of the caller's: the limit of the tasks running, then one entry each
_TASK_LIMIT_LOCK = threading.Lock()


#: Steps a rollout may have at most: it keeps each step's state (a million steps of 100 coordinates: 0.8 GB).
MAX_ROLLOUT_STEPS = 1_000_000


def rollout_steps(steps) -> int:
    """A rollout's length, checked: a positive integer up to :data:`MAX_ROLLOUT_STEPS`.

    ``steps``: the length asked for, a Python or numpy integer (not a bool, nor a float however whole).
    Returns it as an int; anything else is a ``ValueError`` naming it.
    """
    if not is_whole(steps) or steps < 1:
        raise ValueError(f"steps must be a positive integer, got {steps!r}")
    if steps > MAX_ROLLOUT_STEPS:  # 2e10 asked a worker for 596 GiB
        raise ValueError(
            f"steps: {steps} is more than {MAX_ROLLOUT_STEPS:.0e} steps a rollout (it keeps every step's "
            "state): give fewer"
        )
    return int(steps)


def unit_direction(direction, dim: int) -> np.ndarray:
    """A travel direction made a unit vector (shape (dim,); None: +x), or a ValueError naming what it got.

    Parameters
    ----------
    direction : array_like, shape (dim,), or None
        Any non-zero, finite vector.
    dim : int
        The scene's dimension (2 or 3).

    Returns
    -------
    direction : ndarray, shape (dim,)
    """
    if not (is_whole(dim) and dim in (2, 3)):
        raise ValueError(f"dim must be 2 or 3, the scene's dimension, got {dim!r}")
    try:
        vector = np.eye(dim)[0] if direction is None else np.asarray(direction, dtype=float)
    except (TypeError, ValueError):
        vector = None
    if vector is None or vector.shape != (dim,) or not np.all(np.isfinite(vector)) or not np.any(vector):
        raise ValueError(f"direction must be a non-zero, finite vector of {dim} values, got {direction!r}")
    biggest = float(np.abs(vector).max())
    if not 1e-150 < biggest < 1e150:  # its norm would overflow (1e308, 1e308) or underflow (1e-320, 0): scaled first
        vector = vector / biggest
    return vector / np.linalg.norm(vector)


def body_rotation_rows(sim) -> np.ndarray:
    """The map from a state to ``sum_i m_i x_i (X_i - C)^T`` (row-major), whose polar part is the body's rotation.

    Computed without BLAS (``einsum``'s own loops): a threaded BLAS sums in
    an order that depends on its thread count, and these rows, made in the
    search's own process, score every rollout of it, so the search would
    depend on the calling shell's thread settings.

    Parameters
    ----------
    sim : ModalMuscle or FullSpaceSimulator

    Returns
    -------
    rows : ndarray, shape (dim * dim, r)
    """
    dim, n = sim.mesh.p.shape
    m = sim.mass[::dim]
    X = sim.mesh.p.T
    W = m[:, None] * (X - (m @ X) / m.sum())  # (n, dim)
    if sim.B is None:
        rows = np.zeros((dim * dim, n * dim))
        for i in range(dim):
            rows[i * dim : (i + 1) * dim, i::dim] = W.T
        return rows
    # row (i, j) is sum_k W[k, j] B[k dim + i]
    return np.einsum("kj,kic->ijc", W, np.asarray(sim.B).reshape(n, dim, -1)).reshape(dim * dim, -1)


class Trial:
    """A simulator, a rollout length and a scoring rule: runs a gait and scores it.

    Parameters
    ----------
    sim : ModalMuscle or FullSpaceSimulator
    steps : int
        Rollout length.
    direction : array_like, shape (dim,)
        Travel direction (normalised here).
    objective : {"travel", "aligned"}
        See the module docs.
    tip_limit : float
        Tilt (radians) beyond which the tipping penalty starts.
    tip_weight : float
        Body sizes lost per half turn of tilt beyond the limit.
    ramp : float
        Time over which a gait's amplitudes grow from zero (:func:`~skfem_modal.muscles.sine_gait`),
        for gaits that do not give their own (:meth:`from_scene`: the scene's ``muscles.gait.ramp``).

    Examples
    --------
    >>> from skfem_modal import ModalMuscle, caterpillar
    >>> sim = ModalMuscle.from_mesh(caterpillar(nx=12, ny=6), n_muscles=1, n_weights=2, n_clusters=3)
    >>> trial = Trial(sim, 5, [1.0, 0.0])
    >>> score = trial.run({"amplitude": [0.2], "period": [1.0], "phase": [0.0]})
    >>> score["finite"], round(score["alignment"], 6)
    (True, 1.0)
    """

    def __init__(
        self, sim, steps: int, direction, objective: str = "travel", tip_limit=np.pi / 3, tip_weight=10.0, ramp=0.0
    ):
        if objective not in OBJECTIVES:
            raise ValueError(f"objective must be one of {', '.join(OBJECTIVES)}, got {objective!r}")
        rollout_steps(steps)
        self.sim = sim
        self.steps = int(steps)
        self.direction = unit_direction(direction, sim.dim)
        self.objective = objective
        self.tip_limit, self.tip_weight = _nonnegative(tip_limit, "tip_limit"), _nonnegative(tip_weight, "tip_weight")
        self.ramp = checked_ramp(ramp, "the trial's ramp")
        self.size = body_size(sim.mesh)
        self.rotation_rows = body_rotation_rows(sim)
        # a gait that blows the body up (finite) would score by how far it flung it
        self.monitor = MotionMonitor(sim, sim.gravity)
        self._lock = threading.Lock()

    @classmethod
    def from_scene(cls, data: dict, base_dir=None, *, backend: str = "auto", **settings) -> Trial:
        """Build a scene's simulator and the trial on it (``settings``: as for the constructor).

        The trial's ``ramp`` is the scene's (``muscles.gait.ramp``, 0 without a gait), unless given.

        Parameters
        ----------
        data : dict
            The scene (its TOML keys).
        base_dir : str, optional
            Where the scene's relative paths start (default: the current directory).
        backend : {"auto", "numpy", "numba", "plain"}
            The simulator's backend (:meth:`~skfem_modal.scene.Scene.build`).
        **settings
            ``steps`` and ``direction`` (both required), and ``objective``, ``tip_limit``, ``tip_weight``
            and ``ramp`` (optional), as for :class:`Trial`.

        Returns
        -------
        trial : Trial
        """
        from .scene import Scene

        scene = Scene.from_dict(data, base_dir=base_dir)
        trial = cls(scene.build(backend=backend), **{"ramp": scene.ramp, **settings})
        _COUNTS["built"] += 1
        return trial

    def __getstate__(self):
        state = self.__dict__.copy()
        state.pop("_lock")
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._lock = threading.Lock()
        _COUNTS["received"] += 1

    def run(self, gait: dict) -> dict:
        """Run a gait from rest and score it.

        Parameters
        ----------
        gait : dict
            ``amplitude`` (fractions of the ceilings), ``period``, ``phase``:
            one value per muscle each; ``ramp`` (optional, a time): the
            trial's when not given.

        Returns
        -------
        score : dict
            ``fitness``, ``travel``, ``alignment``, ``max_tilt`` (radians),
            ``penalty``, ``finite`` (False: the run went non-finite, the
            measures are NaN), ``physical`` (False: it went non-finite, or
            its body spread, was pushed or folded through itself beyond what
            the motion monitor allows, :meth:`MotionMonitor.run_problems`) and
            ``mean_iterations`` (local/global, a step). A run that is not
            physical scores ``fitness`` -1000 body sizes, whatever it
            travelled: a gait that flings a body apart must not win.
        """
        sim = self.sim
        for key in ("amplitude", "period", "phase"):  # (a single amplitude was stretched to every muscle)
            if key not in gait:
                raise ValueError(f"the gait has no {key!r}: a gait has an amplitude, a period and a phase per muscle")
            if np.ndim(gait[key]) != 1 or len(gait[key]) != sim.n_muscles:
                raise ValueError(
                    f"the gait's {key} must have one value per muscle ({sim.n_muscles}), got {gait[key]!r}"
                )
        amplitudes = np.asarray(gait["amplitude"], float) * sim.ceilings
        periods, phases = gait["period"], gait["phase"]
        ramp = checked_ramp(gait["ramp"], "the gait's ramp") if "ramp" in gait else self.ramp
        z = sim.rest_state()[0]
        frames = np.empty((self.steps + 1, self.rotation_rows.shape[0]))
        frames[0] = self.rotation_rows @ z
        states = np.empty((self.steps + 1, z.size))
        states[0] = z
        start = sim.com(z)
        iterations = 0
        fail = -1e3 * self.size
        with self._lock:  # a dask worker may run several tasks at once on its one copy
            sim.reset()  # each rollout as a new simulator's: the same on any worker, and in a replay
            try:
                for record in simulate(sim, self.steps, lambda t: sine_gait(t, amplitudes, periods, phases, ramp)):
                    frames[record.step] = self.rotation_rows @ record.z
                    states[record.step] = record.z
                    iterations += record.iterations
            except SimulationError:
                nan = float("nan")
                return {
                    "fitness": fail,
                    "travel": nan,
                    "alignment": nan,
                    "max_tilt": nan,
                    "penalty": nan,
                    "finite": False,
                    "physical": False,
                    "mean_iterations": nan,
                }
        score = self.score(sim.com(states[-1]) - start, frames)
        score["physical"] = not self.monitor.run_problems(states, shortest_period(amplitudes, periods), sim.positions)
        if not score["physical"]:
            score["fitness"] = fail
        return {**score, "mean_iterations": iterations / self.steps}

    def score(self, displacement, frames) -> dict:
        """Score a run from its centre of mass's displacement and its body frames.

        Parameters
        ----------
        displacement : ndarray, shape (dim,)
        frames : ndarray, shape (T, dim * dim)
            ``body_rotation_rows @ z`` of each state.

        Returns
        -------
        dict
            ``fitness`` (the objective's gain less the tipping penalty), ``travel`` (along the
            direction), ``alignment`` (the body's worst alignment with the direction, in [0, 1]),
            ``max_tilt`` (radians), ``penalty`` and ``finite`` (True).
        """
        dim, up, d = self.sim.dim, self.sim.up, self.direction
        R = polar_rotations(frames.reshape(-1, dim, dim))
        max_tilt = float(np.arccos(np.clip(R[:, up, up], -1.0, 1.0)).max())
        alignment = max(0.0, float(np.einsum("i,tij,j->t", d, R, d).min()))
        travel = float(displacement @ d)
        penalty = self.tip_weight * self.size * max(0.0, max_tilt - self.tip_limit) / np.pi
        gain = travel * alignment if self.objective == "aligned" and travel > 0 else travel
        return {
            "fitness": gain - penalty,
            "travel": travel,
            "alignment": alignment,
            "max_tilt": max_tilt,
            "penalty": penalty,
            "finite": True,
        }


def _limit_blas(threads) -> None:
    """Limit the BLAS threads of a worker process of the search's own pool for as long as it lives."""
    if threads is not None and not _BLAS_LIMIT:
        limit = limited_blas_threads(threads)
        limit.__enter__()
        _BLAS_LIMIT.append(limit)


@contextmanager
def _task_blas_limit(task: dict):
    """The BLAS limit for one task: ``blas_threads`` while it runs in a worker of the caller's executor (a
    dask worker, a pool of the caller's: left as they were after it); none in the search's own pool (limited
    for its life) or in the search's own process (threads of its executor: the caller's settings).

    The limit is the process's: tasks running at once in one worker's threads share it, set by the first
    to start and lifted by the last to end (each setting and lifting its own, one task's end lifted the
    limit under another still running, whose sums then took another order).
    """
    threads = task.get("blas_threads")
    if threads is None or _BLAS_LIMIT or os.getpid() == task.get("parent"):
        yield
        return
    with _TASK_LIMIT_LOCK:
        if not _TASK_LIMIT:
            limit = limited_blas_threads(threads)
            limit.__enter__()
            _TASK_LIMIT.append(limit)
        _TASK_LIMIT.append(None)  # one entry a running task, after the limit
    try:
        yield
    finally:
        with _TASK_LIMIT_LOCK:
            _TASK_LIMIT.pop()
            if len(_TASK_LIMIT) == 1:
                _TASK_LIMIT.pop().__exit__(None, None, None)


def _install(key: str, payload_path: str, blas_threads) -> None:
    """Pool initializer: keep the trial (read from the file the parent wrote), one BLAS thread, leave Ctrl-C
    to the parent, no warnings.

    A gait that diverges would warn of overflows from each worker, raw; its
    score (-1000 sizes) says it already.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    warnings.simplefilter("ignore")
    exit_with_parent()
    _limit_blas(blas_threads)
    with open(payload_path, "rb") as f:
        _TRIALS[key] = pickle.load(f)


def _remove_quietly(path: str) -> None:
    with contextlib.suppress(OSError):
        os.remove(path)


def _payload_file(trial) -> str:
    """The pickled trial in a temporary file of its own, for the pool's workers to read as they start.

    Not the pool's start-up arguments: those go down a pipe to each new process, which the parent
    writes while it holds the pipe's other end (CPython's spawn), so a worker that died before
    reading them (the seal's 46 MB) left the search blocked on the write for good, Ctrl-C held.
    """
    handle, path = tempfile.mkstemp(prefix="skfem_modal-trial-", suffix=".pickle")
    with os.fdopen(handle, "wb") as f:
        pickle.dump(trial, f, protocol=pickle.HIGHEST_PROTOCOL)
    return path


def rollout(task: dict) -> dict:
    """Run one gait of a trial (an executor's task: plain data in and out).

    ``task``: ``trial`` (the key of a trial), ``gait``, ``blas_threads``,
    ``parent`` (the search's process id: its own threads are left as they
    are), and, for a process that holds no trial of that key yet, ``payload``
    (the pickled trial, as dask workers get it) or ``recipe`` (the scene and
    settings to build it from), or neither.

    Returns
    -------
    score : dict
        :meth:`Trial.run`'s, with this worker's ``pid`` and how many trials
        it has ``received`` and ``built``.
    """
    key = task["trial"]
    with _task_blas_limit(task):
        if key not in _TRIALS:
            if task.get("payload") is not None:
                _TRIALS[key] = pickle.loads(task["payload"])
            elif task.get("recipe") is not None:
                _TRIALS[key] = Trial.from_scene(**task["recipe"])
            else:
                raise RuntimeError("this worker holds no trial of that key and was sent no scene to build it from")
            while len(_TRIALS) > _KEPT_TRIALS:
                del _TRIALS[next(iter(_TRIALS))]  # the oldest
        score = _TRIALS[key].run(task["gait"])
    score.update(pid=os.getpid(), **_COUNTS)
    return score


class Rollouts:
    """Runs gaits of one trial on an executor, the precompute sent once to each worker.

    Parameters
    ----------
    trial : Trial
    workers : int
        Processes of the local pool (when neither ``scheduler`` nor ``executor``).
    scheduler : str, optional
        Address of a dask.distributed scheduler.
    executor : concurrent.futures.Executor, optional
        An executor of the caller's (not shut down here). A dask client's
        gets the trial scattered; any other gets ``recipe`` with each task.
    recipe : dict, optional
        ``Trial.from_scene`` arguments that rebuild the trial (needed with
        an executor that is not dask's).
    blas_threads : int or None
        BLAS threads per worker (None: as the worker's libraries are set).

    Attributes
    ----------
    startup_seconds : float
        Pickling and starting the pool (or scattering).
    """

    def __init__(self, trial, *, workers=1, scheduler=None, executor=None, recipe=None, blas_threads=1):
        clock = time.perf_counter()
        self._close, self._scattered, self._payload, self._lost_payloads = None, None, None, 0
        self._remove_payload = None
        self.blas_threads = checked_thread_count(blas_threads)
        executor = checked_executor(executor)
        client = dask_client(executor)
        self.recipe = None
        if executor is not None and client is None:
            if recipe is None:
                raise ValueError("an executor that is not dask's needs the recipe to build the trial in its workers")
            self.executor, self.handle, self.recipe = executor, uuid.uuid4().hex, recipe
        elif executor is not None or scheduler:
            if executor is None:
                executor, self._close = make_executor(workers, scheduler)
                client = dask_client(executor)
            self.executor, self.handle = executor, uuid.uuid4().hex
            self._payload = pickle.dumps(trial, protocol=pickle.HIGHEST_PROTOCOL)
            self._scattered = client.scatter(self._payload, broadcast=True, hash=False)
        else:
            self.handle = uuid.uuid4().hex
            path = _payload_file(trial)
            self._remove_payload = weakref.finalize(self, _remove_quietly, path)  # at close, or at exit
            self.executor, self._close = make_executor(
                workers,
                None,
                initializer=_install,
                initargs=(self.handle, path, self.blas_threads),
                quiet_interrupts=True,
            )
        self.startup_seconds = time.perf_counter() - clock

    def map(self, gaits) -> list[dict]:
        """Run and score each gait (in order): :func:`rollout`'s results.

        Parameters
        ----------
        gaits : list of dict
            Gaits as :meth:`Trial.run` takes them.

        Returns
        -------
        scores : list of dict
            One a gait, in the same order.

        Raises
        ------
        skfem_modal.study.WorkersLost
            The executor lost its workers (:func:`~skfem_modal.study.lost_workers` says how).
        TypeError
            ``gaits`` is not a list of dicts (before any task is sent).
        """
        if not (isinstance(gaits, (list, tuple)) and all(isinstance(gait, dict) for gait in gaits)):
            raise TypeError(f"gaits must be a list of gait dicts (amplitude, period, phase), got {gaits!r:.80}")
        tasks = [
            {
                "trial": self.handle,
                "gait": gait,
                "blas_threads": self.blas_threads,
                "parent": os.getpid(),
                "recipe": self.recipe,
                "payload": self._scattered,
            }
            for gait in gaits
        ]
        try:
            return list(self.executor.map(rollout, tasks))
        except Exception as error:
            if self._scatter_again(error):
                return self.map(gaits)  # (a rollout is deterministic: the same results as without the loss)
            said = lost_workers(error, self.executor)
            if said is None:
                raise
            raise WorkersLost(said) from error

    def _scatter_again(self, error) -> bool:
        """The scattered trial lost with the workers that held it while others live: scatter it again.

        dask loses scattered data whose holders all died (a killed worker whose copy was the only one
        confirmed, or every worker restarted by its nanny), and cancels the tasks that need it; the
        search stopped there (1 of 4 tries of an audit's, one of two workers killed).
        """
        client = dask_client(self.executor)
        if client is None or self._scattered is None or self._lost_payloads >= _RESCATTERS:
            return False
        if lost_workers(error, self.executor) is None or client.status != "running":
            return False
        self._lost_payloads += 1
        try:  # (workers restarted by their nannies come back in seconds)
            client.wait_for_workers(1, timeout=_WORKERS_BACK_SECONDS)
            self._scattered = client.scatter(self._payload, broadcast=True, hash=False)
        except Exception:  # none came back (a TimeoutError), or the one counted died too ('No valid workers')
            return False
        return True

    def close(self, cancel: bool = False) -> None:
        """Stop what was started here (``cancel``: drop the tasks not yet running)."""
        if self._scattered is not None:
            self._scattered.release()
            self._scattered = None
        if self._close is not None:
            close, self._close = self._close, None
            close(cancel)
        if self._remove_payload is not None:  # (the pool's workers have read it, or are gone)
            self._remove_payload()

    def __enter__(self):
        return self

    def __exit__(self, kind, value, traceback):
        self.close(cancel=kind is not None)
