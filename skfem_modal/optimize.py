"""Gait search with CMA-ES, its rollouts on an Executor (a local pool or dask).

The search space is, per muscle, the gait's amplitude (a fraction of the
muscle's ceiling, in [0, amplitude_max]), period (in [period_min,
period_max]) and phase (in [0, 1], as a fraction of the period), each
rescaled to [0, 1] for CMA-ES (the ``cma`` package). A rollout runs the
scene without output for the search's number of steps and scores the gait
(:mod:`skfem_modal.rollouts`): the objective ``travel`` maximises the centre
of mass's travel along a direction, ``aligned`` (the modal-muscle paper's)
that travel times the worst alignment of the body's forward axis with the
direction; both lose a tipping penalty once the body's up axis tilts past a
limit (60 degrees by default).

Travel over ground contact is chaotic: a gait 1 % away from a good one can
travel a fraction as far. With ``samples = K > 1`` a candidate's fitness is
the mean over K rollouts, the gait itself and K - 1 copies with every
amplitude and period scaled by ``1 + jitter * N(0, 1)`` and every phase
shifted by ``jitter * N(0, 1)`` (the draws fixed by the seed, the generation
and the candidate), so the search prefers gaits that keep working near
where they were found.

The scene's simulator is built once, here, and sent once to each worker
(:class:`~skfem_modal.rollouts.Rollouts`). Every generation writes the
checkpoint (the CMA-ES state, numpy's random state, the history), then
``history.csv`` and the best gait so far as a playable scene
(``best_gait.toml``), each file replaced whole. ``resume=True`` continues an
interrupted search exactly where an uninterrupted one would be; an existing
search is never replaced unless asked (``overwrite=True``), and a search
never shares its folder with a run or a study. Ctrl-C stops the workers,
keeps the last generation's checkpoint and raises :class:`SearchInterrupted`;
workers lost (a process killed, the dask scheduler gone) raise
:class:`SearchWorkersLost`, the checkpoint kept the same way. The same seed
gives the same result on any number of workers, on the local pool or on
dask, whatever the BLAS threads of the calling process.
"""

from __future__ import annotations

import contextlib
import csv
import hashlib
import json
import math
import os
import pickle
import re
import time
import warnings

import numpy as np

from .checks import _nonnegative, _positive_scalar
from .export import written_whole
from .interrupts import signals_ignored
from .monitor import CeilingWarning
from .outputs import SEARCH_FILES, TRANSFER_FILE, check_output_folder, listed, made_folder, remove_if_empty
from .rollouts import OBJECTIVES, Rollouts, Trial, rollout_steps, unit_direction
from .run import Progress
from .study import WorkersLost, checked_executor, checked_workers
from .threads import checked_thread_count
from .values import is_whole

__all__ = [
    "GaitSpace",
    "SearchInterrupted",
    "SearchStop",
    "SearchWorkersLost",
    "read_checkpoint",
    "run_search",
    "scene_fingerprint",
    "scene_to_toml",
    "SEARCH_FILES",
    "SEED_MAX",
]

#: The keys of the first four :data:`SEARCH_FILES`' paths in :func:`run_search`'s result.
_PATH_NAMES = ("checkpoint", "history_csv", "best_scene", "plot")
#: The largest seed: CMA-ES seeds numpy's generator (below 2**32) with the seed plus one (0 would mean the clock).
SEED_MAX = 2**32 - 2


class SearchStop(BaseException):
    """A stopped search, and what it kept (the base of its stops: Ctrl-C, workers lost).

    Attributes
    ----------
    generations : int
        Generations finished and checkpointed (0: none, and no checkpoint).
    total : int
        Generations asked for.
    out_dir : str
    """

    def _kept(self, generations: int, total: int, out_dir: str, earlier_kept: bool = False) -> str:
        """Record what was kept; in words, what the checkpoint holds (``earlier_kept``: the search this one
        was to replace is still there, untouched)."""
        self.generations, self.total, self.out_dir = generations, total, out_dir
        if generations:
            return f"the checkpoint in {out_dir} holds generation {generations}"
        if earlier_kept:
            return f"no generation was finished, so the earlier search in {out_dir} is kept as it was"
        return f"no generation was finished, so nothing was checkpointed in {out_dir}: there is nothing to resume"


class SearchInterrupted(SearchStop, KeyboardInterrupt):
    """Ctrl-C stopped a search; its checkpoint holds every finished generation (:class:`SearchStop`).

    Parameters
    ----------
    generations : int
        Generations finished and checkpointed (0: none, and no checkpoint).
    total : int
        Generations asked for.
    out_dir : str
        The search's folder.
    earlier_kept : bool
        The search this one was to replace is still there, untouched (no generation was finished).
    """

    def __init__(self, generations: int, total: int, out_dir: str, earlier_kept: bool = False):
        kept = self._kept(generations, total, out_dir, earlier_kept)
        done = f"after generation {generations}" if generations else "in generation 1"
        super().__init__(f"interrupted {done} of {total}; {kept}")


class SearchWorkersLost(SearchStop, WorkersLost):
    """The search's workers were lost (a process killed, the dask scheduler gone); its checkpoint is kept
    (:class:`SearchStop`).

    Parameters
    ----------
    reason : str
        What happened to the workers, in words (:func:`~skfem_modal.study.lost_workers`).
    generations : int
        Generations finished and checkpointed (0: none, and no checkpoint).
    total : int
        Generations asked for.
    out_dir : str
        The search's folder.
    earlier_kept : bool
        The search this one was to replace is still there, untouched (no generation was finished).
    """

    def __init__(self, reason: str, generations: int, total: int, out_dir: str, earlier_kept: bool = False):
        kept = self._kept(generations, total, out_dir, earlier_kept)
        super().__init__(f"the search lost its workers in generation {generations + 1} of {total}: {reason}; {kept}")


class GaitSpace:
    """The map between CMA-ES's unit cube and gait parameters.

    Parameters
    ----------
    n_muscles : int
    amplitude_max : float
        Largest amplitude, as a fraction of the ceilings.
    period_min, period_max : float
        Period range (time units).
    """

    def __init__(self, n_muscles: int, amplitude_max: float = 1.0, period_min: float = 0.3, period_max: float = 2.0):
        if not is_whole(n_muscles) or n_muscles < 1:
            raise ValueError(
                f"a gait search needs a whole number of muscles, at least one, got {n_muscles!r} (a scene's "
                "muscles.count; a scene without a [muscles] section has none)"
            )
        for name, value in (("amplitude_max", amplitude_max), ("period_min", period_min), ("period_max", period_max)):
            if isinstance(value, bool) or not isinstance(value, (int, float, np.number)) or not np.isfinite(value):
                raise ValueError(f"{name} must be a finite number, got {value!r}")
        if not 0 < period_min < period_max:
            raise ValueError(f"need 0 < period_min < period_max, got {period_min} and {period_max}")
        if not amplitude_max > 0:
            raise ValueError(f"amplitude_max must be positive, got {amplitude_max}")
        if amplitude_max > 1:
            warnings.warn(
                f"amplitude_max = {amplitude_max:g} lets the search drive the muscles up to {amplitude_max:g} times "
                "their ceilings: an activation beyond 1 asks an element to deform by more than muscles.max_s, and a "
                "gait found there may swell the body out of shape (skfem-modal run on it warns, and says in "
                "summary.json whether the motion was physical)",
                CeilingWarning,
                stacklevel=2,
            )
        self.m = n_muscles
        self.amplitude_max = float(amplitude_max)
        self.period_min, self.period_max = float(period_min), float(period_max)

    def gait(self, u) -> dict:
        """Gait parameters of a point ``u`` of the unit cube (array_like, shape (3 m,): amplitudes, periods,
        phases, each rescaled to [0, 1]; clipped into the cube first).

        Returns
        -------
        gait : dict
            ``amplitude`` (fractions of the ceilings), ``period`` and ``phase`` (fractions of the period):
            lists of m floats.

        Raises
        ------
        ValueError
            ``u`` is not 3 m finite values.
        """
        m = self.m
        u = np.asarray(u, dtype=np.float64)
        if u.shape != (3 * m,):
            raise ValueError(f"a point of this gait space has 3 x {m} values (amplitudes, periods, phases): {u.size}")
        if not np.isfinite(u).all():
            raise ValueError(f"a point of the gait space must be finite, got {u.tolist()}")
        u = np.clip(u, 0.0, 1.0)
        return {
            "amplitude": (u[:m] * self.amplitude_max).tolist(),
            "period": (self.period_min + u[m : 2 * m] * (self.period_max - self.period_min)).tolist(),
            "phase": u[2 * m :].tolist(),
        }

    def point(self, gait: dict) -> np.ndarray:
        """The unit-cube point of a gait (clipped into the box; no ``phase``: zeros).

        ``gait``: a dict of ``amplitude``, ``period`` and optionally ``phase`` (None or absent: zeros), m
        values each, as :meth:`gait` gives and a scene's ``muscles.gait`` holds; phases are taken modulo 1.
        Returns an ndarray, shape (3 m,).

        Raises
        ------
        TypeError
            ``gait`` is not a dict.
        ValueError
            A key missing, or not m values.
        """
        if not isinstance(gait, dict):
            raise TypeError(f"a gait is a dict of amplitude, period and phase, got {gait!r:.80}")
        for key in ("amplitude", "period"):
            if key not in gait:
                raise ValueError(f"the gait has no {key!r} (a gait has amplitude, period and phase)")
        values = {key: np.asarray(gait[key], float) for key in ("amplitude", "period")}
        phase = gait.get("phase")  # (None in a scene's gait that gives none)
        values["phase"] = np.zeros(self.m) if phase is None else np.asarray(phase, float)
        for key, value in values.items():
            if value.shape != (self.m,):
                raise ValueError(f"the gait's {key} must have one value per muscle ({self.m}), got {value.tolist()}")
        amp = values["amplitude"] / self.amplitude_max
        per = (values["period"] - self.period_min) / (self.period_max - self.period_min)
        phase = values["phase"] % 1.0
        return np.clip(np.concatenate([amp, per, phase]), 0.0, 1.0)


def _toml_key(key) -> str:
    """A key as TOML writes it: bare where it may be, else quoted (a space or a dot would change what it says)."""
    if not isinstance(key, str):
        raise TypeError(f"TOML keys are strings, got {key!r}")
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else json.dumps(key)


def _toml_value(value) -> str:
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{_toml_key(k)} = {_toml_value(v)}" for k, v in value.items() if v is not None) + " }"
    raise TypeError(f"cannot write {type(value).__name__} to TOML")


def scene_to_toml(data: dict) -> str:
    """A scene dict as TOML text (tables for sections, inline tables below that).

    ``data``: a scene, as its TOML file's tables (keys whose values are None are left out; ``params``
    and ``box`` are written as inline tables; a key that is not bare, with a space or a dot say, is
    quoted). Values are bools, numbers, strings, lists and dicts of them (Python's or numpy's); anything
    else (None in a list too) is a ``TypeError``.

    Examples
    --------
    >>> print(scene_to_toml({"name": "x", "time": {"step": 0.01}, "muscles": {"gait": {"period": [1.0]}}}))
    name = "x"
    <BLANKLINE>
    [time]
    step = 0.01
    <BLANKLINE>
    [muscles]
    <BLANKLINE>
    [muscles.gait]
    period = [1.0]
    <BLANKLINE>
    """
    lines = []
    for key, value in data.items():
        if not isinstance(value, dict) and value is not None:
            lines.append(f"{_toml_key(key)} = {_toml_value(value)}")

    def table(name, body):
        lines.append("")
        lines.append(f"[{'.'.join(map(_toml_key, name))}]")
        subs = []
        for key, value in body.items():
            if value is None:
                continue
            if isinstance(value, dict) and key != "params" and key != "box":
                subs.append((key, value))
            else:
                lines.append(f"{_toml_key(key)} = {_toml_value(value)}")
        for key, value in subs:
            table(name + (key,), value)

    for key, value in data.items():
        if isinstance(value, dict):
            table((key,), value)
    return "\n".join(lines) + "\n"


def _write_atomic(path: str, writer, mode: str = "wb") -> None:
    """Write a file whole or not at all (a reader or an interruption never sees half of it)."""
    with written_whole(path) as tmp, open(tmp, mode, **({} if "b" in mode else {"newline": ""})) as f:
        writer(f)


#: What a search needs that the default install lacks.
CMA_NEEDED = "which needs the optimize extra: pip install 'skfem_modal[optimize]'"


def _cma():
    """The CMA-ES package, imported quietly (it warns of plots without matplotlib, which a search never draws)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            import cma
        except ModuleNotFoundError as error:
            if error.name != "cma":  # (a dependency of its own missing: said as it is)
                raise
            raise ValueError(f"the gait search runs CMA-ES, {CMA_NEEDED}") from None
    return cma


def read_checkpoint(path: str) -> dict:
    """A search's checkpoint: its state (the CMA-ES state, the history, the settings).

    Parameters
    ----------
    path : str
        The checkpoint file (``checkpoint.pkl`` in a search's folder).

    Returns
    -------
    state : dict
        ``generation`` (finished) and ``settings``, and the rest of what a search keeps:
        ``es`` (the CMA-ES state), ``history`` (a row a generation), ``rollouts``, ``seconds``,
        ``numpy_random``, ``scene_data`` (the scene searched), ``asked`` (generations asked for),
        ``start_gait`` and ``start`` (the start gait's own row, once the first generation rolled it out);
        ``settings`` is checked to be a dict of the search's settings, its values not.

    Raises
    ------
    OSError
        The file cannot be opened (``FileNotFoundError``: no such file).
    ValueError
        The file is not a checkpoint this version reads (damaged, or from an older version); the message names it.
    """
    try:
        with open(path, "rb") as f:
            state = pickle.load(f)
    except OSError:
        raise
    except ModuleNotFoundError as error:
        if error.name != "cma":
            raise ValueError(f"{path} is not a search checkpoint that can be read ({error})") from None
        # (said as the checkpoint's damage, without the install it needs)
        raise ValueError(f"{path}: a search checkpoint holds CMA-ES's state, {CMA_NEEDED}") from None
    except Exception as error:  # unpickling damaged bytes fails in any of a dozen ways
        said = f"{type(error).__name__}: {error}"
        raise ValueError(f"{path} is not a search checkpoint that can be read ({said})") from None
    if not (isinstance(state, dict) and isinstance(state.get("settings"), dict) and "generation" in state):
        raise ValueError(f"{path} is no search checkpoint of this version; start the search again with --overwrite")
    return state


def _scene_changes(then, now, prefix: str = "") -> list[tuple[str, object, object]]:
    """The keys (dotted) whose values differ between two scene dicts, with both values."""
    if not (isinstance(then, dict) and isinstance(now, dict)):
        return [] if then == now else [(prefix.rstrip("."), then, now)]
    changes = []
    for key in sorted(set(then) | set(now), key=str):
        changes += _scene_changes(then.get(key), now.get(key), f"{prefix}{key}.")
    return changes


def scene_fingerprint(scene) -> dict:
    """What makes a scene the same scene for a search: its validated keys, and the contents of the files it names.

    Defaults count as given (``model = "coulomb"`` written out is the same scene), and a mesh file or gait
    table replaced under the same name is another scene (``contents``: each file's SHA-256).

    Parameters
    ----------
    scene : Scene

    Returns
    -------
    fingerprint : dict
        JSON-ready.
    """
    config = json.loads(json.dumps(scene.config))
    contents = {}
    for section, key in (("mesh", "file"), ("muscles", "table")):
        path = (config.get(section) or {}).get(key)
        if path:
            with open(path, "rb") as f:
                contents[f"{section}.{key}"] = hashlib.sha256(f.read()).hexdigest()
    return {**config, "contents": contents}


#: A checkpoint's settings as a search is given them: run_search's argument and the command's option
_GIVEN_AS = {
    key: f"{key} (--{key.replace('_', '-')})"
    for key in ("seed", "popsize", "samples", "jitter", "sigma0", "steps", "direction", "objective", "tip_weight")
}


def _as_given(key: str, then, now) -> list[tuple[str, object, object]]:
    """A changed checkpoint setting as the user gives it: ``(name, then, now)`` rows (the tipping limit in
    degrees, the search box by its own options; they were named by their inner form, radians and a list)."""
    if key == "tip_limit" and then is not None:
        return [("tip_limit_degrees (--tip-limit)", round(math.degrees(then), 9), round(math.degrees(now), 9))]
    if key == "space" and then is not None:
        rows = [("amplitude_max (--amplitude-max)", then[0], now[0])] if then[0] != now[0] else []
        if then[1:] != now[1:]:
            rows.append(("period range (--period-range)", list(then[1:]), list(now[1:])))
        return rows
    return [(_GIVEN_AS.get(key, key), then, now)]


def _load_checkpoint(path: str, settings: dict, data: dict | None = None) -> dict:
    """A checkpoint's state, after checking it was made with these settings (and the scene ``data``, its
    :func:`scene_fingerprint`).

    The scene's name alone may change; another scene key changed is named with both values.
    """
    state = read_checkpoint(path)
    made = state["settings"]
    changed = [key for key in settings if made.get(key) != settings[key]]
    said = []
    if "scene" in changed and data is not None and "scene_data" in state:
        changed.remove("scene")
        data = json.loads(json.dumps(data))  # as kept (tuples as lists)
        scene = [change for change in _scene_changes(state["scene_data"], data) if change[0] != "name"]
        said = [f"scene key {key}: {then!r} then, {now!r} now" for key, then, now in scene]
        if not scene:  # renamed: the same search, under its new name from here on
            made["scene"], state["scene_data"] = settings["scene"], data
    for key in changed:
        said += [
            f"{name}: {then!r} then, {now!r} now" for name, then, now in _as_given(key, made.get(key), settings[key])
        ]
    if said:
        raise ValueError(f"the checkpoint in {os.path.dirname(path)} was made with other settings ({'; '.join(said)})")
    return state


def run_search(
    data: dict,
    out_dir,
    *,
    generations: int,
    popsize: int,
    seed: int = 0,
    steps: int | None = None,
    base_dir: str | None = None,
    direction=None,
    objective: str = "travel",
    space: GaitSpace | None = None,
    sigma0: float = 0.2,
    tip_limit_degrees: float = 60.0,
    tip_weight: float = 10.0,
    samples: int = 1,
    jitter: float = 0.01,
    resume: bool = False,
    overwrite: bool = False,
    executor=None,
    workers: int = 1,
    scheduler: str | None = None,
    blas_threads: int | None = 1,
    progress: bool = False,
    stop_after: int | None = None,
    announce=None,
) -> dict:
    """Search the gait that travels furthest, with CMA-ES.

    Parameters
    ----------
    data : dict
        The scene (its muscles, material, effects; its gait is the start).
    out_dir : str or path-like
        Checkpoint, history, best gait scene and plot go here.
    generations, popsize : int
        Generations (in all: a resumed search runs the rest; fewer than its checkpoint holds is an error,
        and as many runs none, rewriting its files) and candidates per generation.
    seed : int
        The same seed gives the same search; from 0 to :data:`SEED_MAX`.
    steps : int, optional
        Rollout length (default: the scene's).
    base_dir : str, optional
        Where the scene's relative paths start (:func:`~skfem_modal.scene.resolve_paths`; default: the
        current directory).
    direction : array_like, shape (dim,), optional
        Travel direction, any non-zero vector (default +x).
    objective : {"travel", "aligned"}
        ``travel``, or the paper's travel times alignment (:mod:`skfem_modal.rollouts`).
    space : GaitSpace, optional
        Bounds of the search (default: amplitudes up to 1, periods 0.3 to 2).
    sigma0 : float
        CMA-ES initial step in the unit cube.
    tip_limit_degrees, tip_weight : float
        The tipping penalty (:mod:`skfem_modal.rollouts`).
    samples : int
        Rollouts per candidate; more than one averages over jittered copies
        of its gait (see the module docs).
    jitter : float
        Relative size of those copies' changes.
    resume : bool
        Continue the search checkpointed in ``out_dir`` (made with the same
        settings; ``generations`` may differ).
    overwrite : bool
        Start a new search even if ``out_dir`` holds one (its files are replaced).
    executor : concurrent.futures.Executor, optional
        Default: a local process pool of ``workers`` or, with ``scheduler``,
        a dask cluster (:class:`~skfem_modal.rollouts.Rollouts`).
    workers : int
        Processes of the default local pool.
    scheduler : str, optional
        Address of a dask scheduler (``tcp://host:8786``) whose workers run the rollouts.
    blas_threads : int or None
        BLAS threads per worker.
    progress : bool
        Show a progress bar of the generations (a resumed search continues its count).
    stop_after : int, optional
        Stop after this many generations of this call (to test resuming).
    announce : callable, optional
        Called with no arguments once everything is checked, before any work
        (the command line says what it searches there: an error comes first).

    Returns
    -------
    result : dict
        ``best`` (``gait``, ``fitness``, ``travel``, ``alignment``,
        ``max_tilt_degrees``: the gait's own rollout; ``travel_spread``, the
        standard deviation over its samples; ``physical``, the share of its samples
        whose motion was physical; ``generation``), ``history``
        (rows), ``generations`` done (fewer than asked when ``converged``: CMA-ES's steps fell below
        1e-11 of the search box, its candidates one gait), ``rollouts`` and ``seconds`` (over the
        whole search, resumed parts included), ``precompute_seconds`` (this
        call's), and the paths ``checkpoint``, ``history_csv``,
        ``best_scene`` (``best_gait.toml``) and ``plot`` (``fitness.png``).

    Raises
    ------
    FileExistsError
        ``out_dir`` holds a search and neither ``resume`` nor ``overwrite`` was given; or it holds a run or a
        study, or is a file (whatever ``resume`` and ``overwrite``).
    SearchInterrupted
        On Ctrl-C, once the workers are stopped (the checkpoint holds every finished generation).
    SearchWorkersLost
        The executor lost its workers (a process killed, the dask scheduler gone): the checkpoint holds every
        finished generation, and ``resume=True`` continues exactly.

    Every check of the arguments, the scene and ``out_dir``, and the precompute, come before anything is
    written.
    """
    data, scene, space = _checked_scene(data, base_dir, space)
    _check_search(generations, popsize, sigma0, seed, stop_after, samples, jitter, blas_threads)
    executor = checked_executor(executor)
    workers = checked_workers(workers)
    trial_settings = _trial_settings(scene, steps, direction, objective, tip_limit_degrees, tip_weight)
    fingerprint = scene_fingerprint(scene)
    if resume and overwrite:
        raise ValueError("resume and overwrite exclude each other: continue the search, or start it again")
    out_dir = os.fspath(out_dir)
    paths = {name: os.path.join(out_dir, file) for name, file in zip(_PATH_NAMES, SEARCH_FILES)}
    own = {"seed": seed, "popsize": popsize, "samples": samples, "jitter": jitter, "sigma0": sigma0}
    settings = _search_settings(fingerprint, space, own, trial_settings)
    earlier, state = _earlier_search(out_dir, paths, settings, generations, fingerprint, resume, overwrite)
    if announce is not None:
        announce()
    bar, replacing, made = None, [], None
    try:  # (from the precompute on: a Ctrl-C after the announcement says what there is to resume)
        clock = time.perf_counter()
        trial = Trial.from_scene(data, **trial_settings)  # whatever fails here, fails before anything is written
        precompute = time.perf_counter() - clock
        recipe = {"data": data, "base_dir": None, **trial_settings}
        with Rollouts(
            trial, workers=workers, scheduler=scheduler, executor=executor, recipe=recipe, blas_threads=blas_threads
        ) as rollouts:  # a scheduler that does not answer: before the folder is made
            if state is None:
                state = _first_state(settings, space, scene.config["muscles"]["gait"], fingerprint)
                made = made_folder(out_dir)
                replacing = earlier  # until the new search's first checkpoint: a stop before it keeps them
            elif state["history"]:
                _write_outputs(paths, data, state)  # a resumed search's files match its checkpoint
            state["asked"] = generations  # (transfer tells a finished search from a stopped one)
            bar = Progress(generations, "generations", enabled=progress, initial=state["generation"], unit="gen")
            last = generations if stop_after is None else min(generations, state["generation"] + stop_after)
            while state["generation"] < last and not search_converged(state):
                state = _generation(state, rollouts, space)
                _save(paths, data, state)
                replacing = _remove_replaced(replacing, paths)
                bar.update()
        bar.close()
        # (within the try: a stop while it draws says, as any other, what the checkpoint holds)
        _write_plot(paths["plot"], state, objective)
    except KeyboardInterrupt:
        with signals_ignored():  # stopping already: a second Ctrl-C must not cut the plot and the resume's record
            done, kept = _stop(bar, out_dir, paths, data, objective, replacing, made)
        raise SearchInterrupted(done, generations, out_dir, kept) from None
    except WorkersLost as lost:
        done, kept = _stop(bar, out_dir, paths, data, objective, replacing, made)
        raise SearchWorkersLost(str(lost), done, generations, out_dir, kept) from lost
    except Exception:
        remove_if_empty(out_dir, made)
        raise
    return _result(state, paths, precompute)


def _checked_scene(data: dict, base_dir, space):
    """The scene of a search, its paths resolved, and the search space, checked: ``(data, scene, space)``."""
    from .scene import Scene, resolve_paths

    data = resolve_paths(data, base_dir)  # read the same by the workers and from best_gait.toml, from anywhere
    scene = Scene.from_dict(data)  # every scene error first
    if scene.config["ground"] is None and scene.config["pinned"] is None:
        # nothing to push against: a gait moves the centre of mass no more than round-off (or as gravity
        # does, the same for every gait); the search would rank noise
        raise ValueError(
            "the scene has no ground and no pins: no gait can carry the body anywhere (its centre of mass "
            "keeps its momentum), so a search for travel has nothing to find; add a [ground] section (and "
            "[gravity])"
        )
    m = scene.config["muscles"]["count"]
    space = space or GaitSpace(m)
    if space.m != m:
        raise ValueError(f"the search space has {space.m} muscles, the scene {m}")
    return data, scene, space


def _earlier_search(out_dir: str, paths: dict, settings: dict, generations: int, fingerprint: dict, resume, overwrite):
    """What ``out_dir`` holds, ``(earlier files, resumed state or None)``; refused if it may not be replaced."""
    earlier = check_output_folder(out_dir, "search")  # a file, a run or a study there: refused
    state = _resumed_state(out_dir, paths["checkpoint"], settings, generations, fingerprint) if resume else None
    if not resume and earlier and not overwrite:
        again = "continue it with --resume (resume=True) or " if os.path.isfile(paths["checkpoint"]) else ""
        raise FileExistsError(
            f"{out_dir} holds a search ({listed(out_dir, earlier)}): {again}start again with --overwrite "
            "(overwrite=True; only its files are replaced)"
        )
    return earlier, state


def _stop(bar, out_dir: str, paths: dict, data: dict, objective: str, replacing: list, made) -> tuple[int, bool]:
    """A search stopped (Ctrl-C, workers lost): its bar closed, its files as the checkpoint says (:func:`_stopped`)."""
    if bar:
        bar.close()
    done, kept = _stopped(paths, data, objective, replacing)
    remove_if_empty(out_dir, made)  # (the folder this search made stayed behind: an audit)
    return done, kept


def _search_settings(fingerprint: dict, space: GaitSpace, own: dict, trial_settings: dict) -> dict:
    """What a checkpoint is made with, and a resumed search must match: the scene's hash, the search's own
    settings (``own``), its space and the rollouts' settings."""
    scene_hash = hashlib.sha256(json.dumps(fingerprint, sort_keys=True).encode()).hexdigest()[:16]
    space_bounds = [space.amplitude_max, space.period_min, space.period_max]
    return {"scene": scene_hash, **own, "space": space_bounds, **trial_settings}


def _first_state(settings: dict, space: GaitSpace, gait, fingerprint: dict) -> dict:
    """A new search's state, started from the scene's ``gait`` (None: the middle of the space)."""
    start = space.point(gait) if gait is not None else np.full(3 * space.m, 0.5)
    state = _new_state(settings, start, fingerprint)
    state["start_gait"] = space.gait(start) if gait is None else _scene_gait(gait, space.m)
    return state


def _trial_settings(scene, steps, direction, objective: str, tip_limit_degrees: float, tip_weight: float) -> dict:
    """What a rollout is run and scored with (:class:`~skfem_modal.rollouts.Trial`'s settings), checked.

    ``steps`` defaults to the scene's, ``direction`` (default +x) is made a
    unit vector, the tipping penalty's limit goes into radians.
    """
    if objective not in OBJECTIVES:
        raise ValueError(f"objective must be one of {', '.join(OBJECTIVES)}, got {objective!r}")
    steps = scene.n_steps if steps is None else steps
    rollout_steps(steps)
    tip_limit_degrees = _nonnegative(tip_limit_degrees, "tip_limit_degrees")
    tip_weight = _nonnegative(tip_weight, "tip_weight")
    return {
        "steps": int(steps),
        "direction": unit_direction(direction, scene.dim).tolist(),
        "objective": objective,
        "tip_limit": float(np.radians(tip_limit_degrees)),
        "tip_weight": float(tip_weight),
    }


def _check_search(generations, popsize, sigma0, seed, stop_after, samples, jitter, blas_threads) -> None:
    """A search's own settings (not the scene's, not the rollouts'), each checked by name; and CMA-ES there
    (without it the search failed after its banner, with a traceback)."""
    _check_evolution(generations, popsize, sigma0)
    _check_seed(seed)
    _check_stop_after(stop_after)
    _check_samples(samples, jitter)
    checked_thread_count(blas_threads)
    _cma()


def _check_evolution(generations: int, popsize: int, sigma0: float) -> None:
    """CMA-ES's settings: at least a generation of at least two candidates, a positive first step."""
    for name, value, least in (("generations", generations, 1), ("popsize", popsize, 2)):
        # a fraction ran: 2.5 generations ran 3
        if not is_whole(value) or value < least:
            raise ValueError(f"{name} must be an integer of at least {least}, got {value!r}")
    _positive_scalar(sigma0, "sigma0")


def _check_seed(seed) -> None:
    """A seed CMA-ES takes deterministically: an integer from 0 to :data:`SEED_MAX`."""
    if not is_whole(seed) or not 0 <= seed <= SEED_MAX:
        raise ValueError(f"seed must be an integer from 0 to {SEED_MAX}, got {seed!r}")


def _check_stop_after(stop_after) -> None:
    """``stop_after``: None, or a positive whole number of generations (0 died in ``max`` of nothing)."""
    if stop_after is None:
        return
    if not is_whole(stop_after) or stop_after < 1:
        raise ValueError(f"stop_after must be a positive whole number of generations, got {stop_after!r}")


def _resumed_state(out_dir: str, checkpoint: str, settings: dict, generations: int, data: dict) -> dict:
    """The state of the search checkpointed in ``out_dir``, checked against these settings and generations."""
    if not os.path.isfile(checkpoint):
        raise FileNotFoundError(f"no search to resume: {checkpoint} does not exist")
    state = _load_checkpoint(checkpoint, settings, data)
    if state["generation"] > generations:
        raise ValueError(
            f"the search in {out_dir} already has {state['generation']} generations, more than the {generations} "
            f"asked (--generations; generations= in Python): ask for more than {state['generation']} to extend it, "
            f"or for {state['generation']} to resume it as it is"
        )
    np.random.set_state(state["numpy_random"])
    return state


@contextlib.contextmanager
def _as_made(es):
    """CMA-ES as quiet as its options made it (``verbose`` -9): cma keeps that in a module global, which an
    unpickled search in a new process does not have, and a resumed search printed cma's own warnings (a
    misleading "popsize 3 will be used" of a search of 2 candidates, which used 2)."""
    with warnings.catch_warnings():
        if es.opts["verbose"] < -2:  # (cma's own threshold for its warnings)
            warnings.filterwarnings("ignore", module=r"cma(\.|$)")
        yield


def _new_state(settings: dict, x0, data: dict) -> dict:
    """A new search's state: CMA-ES at ``x0``, seeded by the settings' seed; ``data`` the scene searched."""
    cma = _cma()

    # cma seeds numpy's global generator (seed 0 would mean "time": shift by one)
    options = {"popsize": settings["popsize"], "seed": settings["seed"] + 1, "bounds": [0.0, 1.0], "verbose": -9}
    es = cma.CMAEvolutionStrategy(x0.tolist(), settings["sigma0"], options)
    state = {"es": es, "history": [], "generation": 0, "rollouts": 0, "seconds": 0.0, "settings": settings}
    state["numpy_random"] = np.random.get_state()
    state["scene_data"] = json.loads(json.dumps(data))  # what a resume names the changes of
    return state


def _save(paths: dict, data: dict, state: dict) -> None:
    """The checkpoint of a search state, then the files that follow it (history.csv, best_gait.toml).

    A ``transfer.csv`` beside them replayed the best gait before this generation: it goes if
    this generation found a better one (kept otherwise: it was removed on every resume).
    """
    _write_atomic(paths["checkpoint"], lambda f: pickle.dump(state, f))
    _write_outputs(paths, data, state)
    stale = os.path.join(os.path.dirname(paths["checkpoint"]), TRANSFER_FILE)
    if _overall_best(state)["generation"] == state["generation"] and os.path.exists(stale):
        os.remove(stale)


def _remove_replaced(earlier: list, paths: dict) -> list:
    """After a new search's first checkpoint: the files of the search it replaces that it did not write
    over, removed; nothing is left to replace."""
    written = {paths["checkpoint"], paths["history_csv"], paths["best_scene"]}
    for path in earlier:
        if path not in written and os.path.exists(path):
            os.remove(path)
    return []


def _stopped(paths: dict, data: dict, objective: str, replacing: list) -> tuple[int, bool]:
    """After a stop: the generations checkpointed (0: none) and whether an earlier search was kept instead.

    A search replacing another that stops before its first checkpoint leaves the other as it was."""
    if replacing:
        return 0, True
    return _restore(paths, data, objective), False


def _restore(paths: dict, data: dict, objective: str) -> int:
    """After a stop, the files as the last checkpoint has them (whatever the moment); its generation (0: none)."""
    if not os.path.isfile(paths["checkpoint"]):
        return 0
    state = read_checkpoint(paths["checkpoint"])
    _write_outputs(paths, data, state)
    _write_plot(paths["plot"], state, objective)
    return state["generation"]


def _result(state: dict, paths: dict, precompute: float) -> dict:
    """What :func:`run_search` returns, from the last state."""
    overall = _overall_best(state)
    return {
        "best": {
            "gait": overall["gait"],
            "fitness": overall["best_fitness"],
            "travel": overall["best_travel"],
            "alignment": overall["best_alignment"],
            "max_tilt_degrees": overall["best_max_tilt_degrees"],
            "travel_spread": overall["best_travel_spread"],
            "physical": overall.get("best_physical", math.nan),
            "generation": overall["generation"],
        },
        "history": state["history"],
        "start": state.get("start"),
        "generations": state["generation"],
        "converged": search_converged(state),
        "rollouts": state["rollouts"],
        "seconds": state["seconds"],
        "precompute_seconds": precompute,
        **{k: v for k, v in paths.items() if k != "plot" or os.path.exists(v)},
    }


def search_converged(state: dict) -> bool:
    """Whether a search's ``state`` (:func:`read_checkpoint`) has converged: CMA-ES's steps have shrunk below
    ``1e-11`` of the unit cube in every direction (``tolx``).

    Its candidates are then one gait to 11 digits: more generations roll the same gait out again, and
    a long search (20000 generations of a small scene) went on until the step size underflowed and the
    candidates were NaN. A search that has not made a generation has not converged.
    """
    return bool(state["generation"]) and "tolx" in state["es"].stop()


def _roll_out(rollouts, gaits: list, settings: dict, done: int):
    """Each gait's rollouts: its own, then ``samples - 1`` jittered copies; their scores, and the fitness of each.

    ``done``: the generations done (the copies' draws are fixed by the seed, the generation and
    the gait's index).
    """
    samples, jitter, seed = (settings[key] for key in ("samples", "jitter", "seed"))
    tried = [
        gait if k == 0 else _jittered(gait, jitter, (seed, done, i, k))
        for i, gait in enumerate(gaits)
        for k in range(samples)
    ]
    flat = rollouts.map(tried)
    groups = [flat[i * samples : (i + 1) * samples] for i in range(len(gaits))]
    return groups, [float(np.mean([r["fitness"] for r in group])) for group in groups]


def _row(generation: int, gaits: list, groups: list, fitness: list) -> dict:
    """A history row: the best of ``gaits`` by ``fitness``, its own rollout's measures, and the workers'."""
    best = int(np.argmax(fitness))
    own = groups[best][0]
    flat = [r for group in groups for r in group]
    return {
        "generation": generation,
        "best_fitness": fitness[best],
        "best_travel": own["travel"],
        "best_alignment": own["alignment"],
        "best_max_tilt_degrees": float(np.degrees(own["max_tilt"])),
        "best_travel_spread": float(np.std([r["travel"] for r in groups[best]])),
        "best_physical": float(np.mean([r["physical"] for r in groups[best]])),
        "mean_fitness": float(np.mean(fitness)),
        "gait": gaits[best],
        "workers": sorted({r["pid"] for r in flat}),
        "received": max(r["received"] for r in flat),
        "built": max(r["built"] for r in flat),
    }


def _scene_gait(gait: dict, m: int) -> dict:
    """A scene's gait as a rollout takes it: ``m`` floats each (a phase not given is 0)."""
    phase = gait["phase"] if gait["phase"] is not None else [0.0] * m
    values = {"amplitude": gait["amplitude"], "period": gait["period"], "phase": phase}
    return {key: [float(v) for v in given] for key, given in values.items()}


def _generation(state: dict, rollouts, space: GaitSpace) -> dict:
    """One CMA-ES generation: ask, roll out, tell; the new state (the old one is left as it was).

    The first also scores the gait the search starts from (``start_gait``), rolled out with
    its candidates: it is a candidate too (``start``, a row of generation 0, not told to CMA-ES),
    so a search that finds nothing better returns it, never a worse gait than it was given (an
    audit: two generations in a box excluding the scene's own gait returned fitness 1.2 from 15).
    """
    clock = time.perf_counter()
    es = pickle.loads(pickle.dumps(state["es"]))  # an interruption leaves the state as checkpointed
    done = state["generation"]
    with _as_made(es):
        points = es.ask()
    gaits = [space.gait(u) for u in points]
    start = [state["start_gait"]] if state.get("start_gait") and not state.get("start") else []
    groups, fitness = _roll_out(rollouts, gaits + start, state["settings"], done)
    rolled = sum(len(group) for group in groups)
    extra = {}
    if start:
        extra["start"] = {**_row(0, start, groups[-1:], fitness[-1:]), "sigma": state["settings"]["sigma0"]}
        extra["start"]["seconds"] = 0.0  # timed with the generation
        groups, fitness = groups[:-1], fitness[:-1]
    with _as_made(es):
        es.tell(points, [-f for f in fitness])  # CMA-ES minimises
    row = {**_row(done + 1, gaits, groups, fitness), "sigma": float(es.sigma)}
    row["seconds"] = time.perf_counter() - clock
    return {
        **state,
        **extra,
        "es": es,
        "history": state["history"] + [row],
        "generation": done + 1,
        "rollouts": state["rollouts"] + rolled,
        "seconds": state["seconds"] + row["seconds"],
        "numpy_random": np.random.get_state(),
    }


def _check_samples(samples: int, jitter: float) -> None:
    """The rollouts of a candidate: a positive count; its copies' changes in [0, 0.5) (see :func:`_jittered`)."""
    if not is_whole(samples) or samples < 1:
        raise ValueError(f"samples must be a positive integer, got {samples!r}")
    if not _nonnegative(jitter, "jitter") < 0.5:
        raise ValueError(f"jitter must be in [0, 0.5), got {jitter!r}")


def _jittered(gait: dict, jitter: float, key) -> dict:
    """A copy of a gait with amplitudes and periods scaled, phases shifted, by ``jitter`` N(0, 1) draws."""
    rng = np.random.default_rng(list(key))
    m = len(gait["amplitude"])
    scale = 1.0 + jitter * rng.standard_normal((2, m))
    return {
        "amplitude": (np.asarray(gait["amplitude"]) * scale[0]).tolist(),
        "period": (np.asarray(gait["period"]) * np.abs(scale[1])).tolist(),
        "phase": ((np.asarray(gait["phase"]) + jitter * rng.standard_normal(m)) % 1.0).tolist(),
    }


def _overall_best(state: dict) -> dict:
    """The best row of a search: of its generations, or the gait it started from (generation 0) if none beat it."""
    start = [state["start"]] if state.get("start") else []  # (a checkpoint of an earlier version has none)
    return max(start + state["history"], key=lambda h: h["best_fitness"])


#: history.csv's columns (the last, the gait, as JSON)
HISTORY_COLUMNS = (
    "generation",
    "best_fitness",
    "best_travel",
    "best_alignment",
    "best_max_tilt_degrees",
    "best_travel_spread",
    "best_physical",
    "mean_fitness",
    "sigma",
    "seconds",
    "best_gait",
)


def _write_outputs(paths: dict, data: dict, state: dict) -> None:
    """history.csv and best_gait.toml (the best gait so far) of a search state, each replaced whole."""
    history = state["history"]

    def table(f):
        writer = csv.writer(f)
        writer.writerow(HISTORY_COLUMNS)
        for h in history:
            writer.writerow(
                [h["generation"]]
                + [repr(float(h.get(c, math.nan))) for c in HISTORY_COLUMNS[1:-1]]  # (an older checkpoint's rows)
                + [json.dumps(h["gait"])]
            )

    _write_atomic(paths["history_csv"], table, "w")
    overall = _overall_best(state)
    where = f"generation {overall['generation']}" if overall["generation"] else "the gait it started from"
    best = json.loads(json.dumps(data))
    # (a searched scene searched again: its name says only the last search)
    name = re.sub(r" \(best gait of [^()]*\)$", "", str(data.get("name", "scene")))
    travel = f"travel {overall['best_travel']:.4g}"
    best["name"] = f"{name} (best gait of {state['generation']} generations: {where}, {travel})"
    given = (data.get("muscles") or {}).get("gait") or {}
    # the scene's ramp is the searched gaits' too (the trial's): the best one replays with it
    ramp = {"ramp": given["ramp"]} if "ramp" in given else {}
    best.setdefault("muscles", {})["gait"] = {**overall["gait"], **ramp}
    best["muscles"].pop("table", None)
    best.setdefault("time", {}).pop("duration", None)
    best["time"]["steps"] = state["settings"]["steps"]
    _write_atomic(paths["best_scene"], lambda f: f.write(scene_to_toml(best)), "w")


def _write_plot(path: str, state: dict, objective: str) -> None:
    """fitness.png: the best and mean fitness of each generation, and the best so far, the gait the search
    started from counted (it is what the search returns when nothing beats it); needs matplotlib."""
    history = state["history"]
    if not history:
        return
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return
    fig, ax = plt.subplots(figsize=(6, 3.5))
    g = [h["generation"] for h in history]
    best = [h["best_fitness"] for h in history]
    ax.plot(g, best, ".-", label="best of the generation")
    ax.plot(g, [h["mean_fitness"] for h in history], "--", lw=1, label="mean of the generation")
    start = state.get("start")  # (a checkpoint of an earlier version has none)
    so_far = np.maximum.accumulate([start["best_fitness"]] + best if start else best)
    ax.plot([0] + g if start else g, so_far, "k-", lw=1.5, label="best so far")
    if start:
        ax.plot([0], [start["best_fitness"]], "ko", ms=4, label="the gait it started from")
    ax.set_xlabel("generation")
    ax.set_ylabel("fitness")
    said = "travel x alignment" if objective == "aligned" else "travel"
    ax.set_title(f"fitness = {said} - tipping penalty", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    try:
        with written_whole(path) as tmp:
            fig.savefig(tmp, dpi=110)
    finally:
        plt.close(fig)
