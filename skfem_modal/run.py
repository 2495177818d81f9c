"""Running a scene: the step loop and what it records.

A run streams everything to disk as it goes (frames, centre of mass, modal
amplitudes) and writes ``summary.json`` at the end, or when it fails: a
non-finite state raises :class:`~skfem_modal.sim.SimulationError` with the step
number, after the frames so far and a summary saying what happened are on disk.

Output directory::

    frames.pvd            ParaView time series (open this)
    frames/frame_*.vtu    one file per written frame: points, displacement,
                          cluster labels; field data time and activations
    com.csv               time, centre of mass
    amplitudes.csv        time, commanded and realised modal amplitudes per muscle
    summary.json          scene, sizes, timings, iterations, travel, penetration, status
"""

from __future__ import annotations

import contextlib
import csv
import json
import os
import platform
import sys
import time

import numpy as np

from .export import FrameWriter, written_whole
from .interrupts import HeldSignals
from .mesh import mesh_summary
from .monitor import MotionMonitor
from .outputs import FRAMES_DIR, OutputError, clear_earlier_run, made_folder, remove_if_empty
from .scene import Scene
from .sim import SimulationError, live_settings, simulate
from .units import material_length_scales
from .values import is_whole

__all__ = ["run_scene", "Progress"]


class Progress:
    """A progress bar: tqdm when installed, otherwise a plain line on stderr.

    Parameters
    ----------
    total : int
    desc : str
    enabled : bool
    initial : int
        Already done (a resumed job continues its count).
    unit : str
        What is counted, for tqdm's rate.
    """

    def __init__(self, total: int, desc: str, enabled: bool = True, initial: int = 0, unit: str = "step"):
        self.enabled = enabled
        self.total = total
        self.desc = desc
        self.count = initial
        self._bar = None
        self._next = 0
        self._tty = sys.stderr.isatty()
        self._printed = -1
        if not enabled:
            return
        try:
            from tqdm import tqdm

            self._bar = tqdm(total=total, initial=initial, desc=desc, unit=unit, file=sys.stderr, leave=False)
        except ImportError:
            self._bar = None

    def update(self, n: int = 1) -> None:
        """Count ``n`` more done (int); without tqdm the line is printed again every twentieth of ``total`` on a
        terminal, every tenth in a log."""
        self.count += n
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.update(n)
        elif self.count >= self._next:
            self._print()
            # a terminal line is rewritten in place; a log file gets a line a tenth of the way
            # (from the count printed: a resumed job's count starts far past 0)
            self._next = self.count + max(1, self.total // (20 if self._tty else 10))

    def _print(self) -> None:
        end = "" if self._tty else "\n"
        print(
            f"\r{self.desc}: {self.count}/{self.total}" if self._tty else f"{self.desc}: {self.count}/{self.total}",
            end=end,
            file=sys.stderr,
            flush=True,
        )
        self._printed = self.count

    def close(self) -> None:
        """End the bar: tqdm's is cleared; the plain line shows the last count, and a terminal's ends its line."""
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.close()
            return
        if self._printed != self.count:
            self._print()
        if self._tty:
            print(file=sys.stderr, flush=True)


def _stage_printer(enabled: bool):
    if not enabled:
        return None

    def say(stage: str) -> None:
        print(f"  precompute: {stage}", file=sys.stderr, flush=True)

    return say


def _write_json(path: str, data: dict) -> None:
    with written_whole(path) as tmp, open(tmp, "w") as f:
        json.dump(data, f, indent=2, default=_jsonable)
        f.write("\n")


def _jsonable(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def _residual_stats(residuals) -> dict:
    """Median, 90th percentile and largest of the steps' relative residuals (zeros without steps)."""
    values = np.asarray(residuals, dtype=float)
    if not values.size:
        return {"median": 0.0, "p90": 0.0, "max": 0.0}
    return {
        "median": float(np.median(values)),
        "p90": float(np.percentile(values, 90)),
        "max": float(values.max()),
    }


def _stats_ms(seconds: list[float]) -> dict:
    if not seconds:
        return {}
    ms = np.asarray(seconds) * 1e3
    return {
        "median": float(np.median(ms)),
        "p90": float(np.percentile(ms, 90)),
        "mean": float(ms.mean()),
        "max": float(ms.max()),
    }


def run_scene(
    scene, out_dir=None, *, every: int | None = None, progress: bool = False, sim=None, overwrite: bool = False
) -> dict:
    """Run a scene.

    Parameters
    ----------
    scene : skfem_modal.scene.Scene
    out_dir : str or path-like, optional
        Where to write the outputs; ``None`` writes nothing (a rollout).
    every : int, optional
        Write every k-th frame (default: the scene's ``output.every``).
    progress : bool
        Show the precompute stages and a progress bar.
    sim : skfem_modal.sim.ModalMuscle, optional
        A simulator already built from this scene (its precompute is reused; it is reset first,
        :meth:`~skfem_modal.sim.ModalMuscle.reset`, so the run is the scene's run whatever the
        simulator ran before).
    overwrite : bool
        Remove an earlier run's files from ``out_dir`` first (other files
        stay); without it, an earlier run there is an error.

    Returns
    -------
    summary : dict
        What ``summary.json`` holds.

    Raises
    ------
    SimulationError
        If the state goes non-finite (the outputs so far are kept, up to the
        last step done); the message adds what the motion monitor saw of the
        failing step (e.g. activations beyond the ceilings).
    KeyboardInterrupt
        On Ctrl-C (or SIGTERM under the command line), once ``summary.json``
        says ``interrupted`` and every file ends at the last step done.
    FileExistsError
        ``out_dir`` holds an earlier run and ``overwrite`` is false (before any work).
    OutputError
        A file could not be written as the run went (a disk full): the message names it and the
        step; ``summary.json`` says ``failed`` with that message, if there was room for it.

    Warns
    -----
    MotionWarning
        The run completed, but its motion is not physical for the scene
        (see :mod:`skfem_modal.monitor`); ``summary["motion"]`` says why.
    """
    if not isinstance(scene, Scene):
        raise TypeError(
            f"run_scene takes a Scene, got {type(scene).__name__}: "
            "Scene.from_toml(path) or Scene.from_dict(data) makes one"
        )
    every = scene.config["output"]["every"] if every is None else every
    if not is_whole(every) or every < 1:
        raise ValueError(f"every must be a positive integer, got {every!r}")
    if out_dir is not None:
        clear_earlier_run(out_dir, overwrite)
    if sim is not None:
        _check_built_from(scene, sim)
        # a run from rest, as a new simulator's: the Coulomb contact's memory of the last run changed a 3D
        # crawl run twice on one simulator by 2e-4 of its travel (an audit)
        sim.reset()
    started = time.perf_counter()
    if sim is None:
        sim = scene.build(progress=_stage_printer(progress))
    summary = _summary_start(scene, sim, precompute=time.perf_counter() - started)
    gravity = scene.config["gravity"]
    log = {"com": [], "seconds": [], "iterations": [], "residuals": [], "penetration": 0.0, "relative": 0.0}
    log["sunk"] = 0.0  # the deepest of what each vertex's allowance is a share of (contact.boundary_lengths)
    log["last"] = None  # (step, z) of the last state recorded
    g = None if gravity is None else gravity["acceleration"]
    material = scene.material()
    weight = material_length_scales(np.mean(material["mu"]), np.mean(material["rho"]), g).get("weight")
    log["monitor"] = MotionMonitor(sim, g, weight_scale=weight, gait_period=scene.shortest_period())
    files = None if out_dir is None else _RunFiles(os.fspath(out_dir), sim, every, log["monitor"])
    bar = Progress(scene.n_steps, "steps", enabled=progress)
    status, error, failure = "completed", None, None
    with HeldSignals() as held:
        try:
            _run_steps(scene, sim, log, files, bar, held)
        except SimulationError as err:
            step = err.step or len(log["seconds"]) + 1
            # the monitor never saw the failing step: what it was commanded may say why it failed
            failing = scene.activation((step - 1) * sim.h, sim.ceilings) if sim.n_muscles else None
            log["monitor"].failed(step, failing)
            status, error = "failed", {"step": step, "time": step * sim.h, "message": err.message}
        except KeyboardInterrupt:
            status, error = "interrupted", {"step": len(log["seconds"]), "time": len(log["seconds"]) * sim.h}
            raise
        except BaseException as err:
            step = len(log["seconds"]) + 1
            status, error = "failed", {"step": step, "time": step * sim.h, "message": f"{type(err).__name__}: {err}"}
            raise
        finally:
            with held.hold():  # the summary is written whole, whatever arrives meanwhile
                bar.close()
                try:
                    _check_last_state(sim, log, files)
                except OutputError as err:  # the last frame: the run's failure, unless it failed already
                    if status == "completed":
                        done = len(log["seconds"])
                        status, failure = "failed", err
                        error = {"step": done, "time": done * sim.h, "message": f"OutputError: {err}"}
                motion = log["monitor"].finish(warn=status != "failed")
                if "non_finite" in motion["first_problem_step"]:
                    # the error names the cause the monitor sees (the non-finite state it says already)
                    causes = "".join(f"; {text}" for text in motion["warnings"] if "non-finite" not in text)
                    error["message"] = f"{error['message']} (t = {error['time']:g}; outputs so far kept){causes}"
                    failure = SimulationError(error["message"], step=error["step"])
                    error["message"] = str(failure)
                summary.update(status=status, error=error, steps_completed=len(log["seconds"]), motion=motion)
                # the first step apart: it also loads numba's compiled kernels (about 0.3 s) and fills caches
                first, rest = log["seconds"][:1], log["seconds"][1:] or log["seconds"]
                summary["timings"].update(
                    steps_total_s=float(np.sum(log["seconds"])),
                    first_step_ms=float(first[0] * 1e3) if first else None,
                    step_ms=_stats_ms(rest),
                    wall_s=time.perf_counter() - started,
                )
                summary.update(_measured(sim, log))
                if files is None:
                    summary.update(pinned=None, frames=None)
                else:
                    files.close(summary)
    if failure is not None:
        raise failure
    return summary


def _check_built_from(scene, sim) -> None:
    """Refuse a simulator that was not built from ``scene`` (another mesh, or other muscles), naming the difference."""
    mesh, theirs = scene.mesh, sim.mesh
    if theirs.p.shape != mesh.p.shape or theirs.t.shape != mesh.t.shape or not np.array_equal(theirs.p, mesh.p):
        raise ValueError(
            f"sim was not built from this scene: its mesh has {theirs.p.shape[1]} vertices in {theirs.p.shape[0]}D "
            f"and {theirs.t.shape[1]} elements, the scene's {mesh.p.shape[1]} in {mesh.p.shape[0]}D and "
            f"{mesh.t.shape[1]}{'' if theirs.p.shape != mesh.p.shape else ' (or they lie elsewhere)'}: "
            "build it with scene.build()"
        )
    if sim.n_muscles != scene.config["muscles"]["count"]:
        raise ValueError(
            f"sim was not built from this scene: it has {sim.n_muscles} muscles, the scene "
            f"{scene.config['muscles']['count']} (muscles.count): build it with scene.build()"
        )


def _live_settings(sim) -> dict:
    """The simulator's settings as the run used them (a simulator handed to run_scene may differ from its scene)."""
    values = {name: getattr(sim, name) for name in live_settings(type(sim))}
    return {name: value.tolist() if isinstance(value, np.ndarray) else value for name, value in values.items()}


def _source(scene) -> str:
    """Where the scene came from: its file's absolute path (the summary is read from elsewhere), or how it was made."""
    return os.path.abspath(scene.source) if os.path.isfile(scene.source) else scene.source


def _summary_start(scene, sim, precompute: float) -> dict:
    """What a run's summary says before its first step: the scene, its sizes, the precompute."""
    return {
        "skfem_modal": _version(),
        "python": platform.python_version(),
        "scene": {**scene.to_dict(), "source": _source(scene)},
        "material": scene.material(),
        "mesh": {**mesh_summary(sim.mesh), "placement": scene.placement},
        "effects": list(sim.effects),
        "backend": sim.backend_used,
        "sizes": {
            "dofs": int(sim.mesh.p.size),
            "subspace": int(sim.B.shape[1]),
            "clusters": int(sim.n_clusters),
            "active_clusters": int(sim.n_active_clusters),
            "muscles": int(sim.n_muscles),
            "contact_points": int(sim.contact_vertices.size),
            "pinned_vertices": int(sim.pinned.size),
        },
        "muscle_ceilings": sim.ceilings,
        "timings": {"precompute_s": dict(sim.timings), "precompute_total_s": precompute},
        "steps": scene.n_steps,
        "h": sim.h,
        "settings": _live_settings(sim),
        "status": "running",
    }


def _run_steps(scene, sim, log: dict, files, bar: Progress, held: HeldSignals) -> None:
    """The step loop: the scene's steps from rest, each recorded in ``files`` and ``log`` as it ends.

    A step's records are written whole: a signal meanwhile waits for them (``held``).
    """
    ceilings = sim.ceilings
    activation = (lambda t: scene.activation(t, ceilings)) if sim.n_muscles else None
    z, _, a = sim.rest_state()
    with held.hold():
        _record(sim, log, files, 0, z, a)
    for done in simulate(sim, scene.n_steps, activation):
        with held.hold():
            _record(sim, log, files, done.step, done.z, done.a, done)
        bar.update()


def _check_last_state(sim, log: dict, files) -> None:
    """The monitor's element check of the last state done (the frames written were checked as written)."""
    if files is not None:
        files.frame_last()
    elif log["last"] is not None:
        step, z = log["last"]
        log["monitor"].check_elements(step, sim.positions(z))


def _record(sim, log: dict, files, step: int, z, a, done=None) -> None:
    """The state after ``step`` steps: into ``files`` first (its frame, its rows), then into ``log``.

    An error while writing the files leaves the log, and so the summary, at the step before.
    """
    com = sim.com(z)
    relative = depth = sunk = 0.0
    clearance = None
    contact = sim.model.contact
    if done is not None and contact is not None:
        depths = contact.depths(z)  # every boundary vertex: one pass for all four
        clearance = -contact.deepest_of_each_body(depths)  # each body's lowest vertex above the ground
        depth = max(0.0, -float(clearance.min()))
        relative = max(0.0, float((depths / contact.boundary_sizes).max()))  # of each vertex's own part
        sunk = max(0.0, float((depths / contact.boundary_lengths).max()))  # of what its allowance is a share of
    if files is not None:
        files.write(step, z, a, com)
    log["com"].append(com)
    log["last"] = (step, z)
    if done is not None:
        log["seconds"].append(done.seconds)
        log["iterations"].append(done.iterations)
        log["residuals"].append(done.residual)
        # every boundary vertex, every step: the deepest any went below the ground
        log["penetration"] = max(log["penetration"], depth)
        log["relative"] = max(log["relative"], relative)
        log["sunk"] = max(log["sunk"], sunk)
        if log["monitor"].update(step, z, a, clearance, *((relative, sunk) if contact is not None else ())):
            log["monitor"].check_elements(step, sim.positions(z))  # a state after a jolt (a frame: checked already)


def _measured(sim, log: dict) -> dict:
    """The summary's iterations, centre of mass and ground entries, from a run's log."""
    coms = np.array(log["com"])
    it = np.array(log["iterations"], dtype=int)
    ground = None
    if sim.ground is not None:
        monitor = log["monitor"]  # every vertex of the frames written and of the last state
        ground = {
            "height": sim.ground,
            "model": sim.contact_model,
            "allowance": sim.allowance,  # None under the reference contact, as friction and exact_friction
            "friction": sim.friction,
            "exact_friction": sim.exact_friction,
            "worst_penetration": max(log["penetration"], monitor.deepest_vertex),
            "worst_penetration_relative": max(log["relative"], monitor.deepest_vertex_relative),  # of its own part
            # how much of its own allowance the deepest boundary vertex used (a thin part's is of its thickness)
            "worst_penetration_of_allowance": None if sim.allowance is None else log["sunk"] / sim.allowance,
        }
    return {
        "iterations": {
            "mean": float(it.mean()) if it.size else 0.0,
            "min": int(it.min()) if it.size else 0,
            "max": int(it.max()) if it.size else 0,
            "histogram": {str(k): int(v) for k, v in zip(*np.unique(it, return_counts=True))},
            "residual": _residual_stats(log["residuals"]),
        },
        "com": None  # (a run that failed writing its rest state: the error says why, not an IndexError)
        if not len(coms)
        else {
            "start": coms[0],
            "end": coms[-1],
            "travel": coms[-1] - coms[0],
            "distance": float(np.linalg.norm(coms[-1] - coms[0])),
            "min": coms.min(axis=0),
            "max": coms.max(axis=0),
        },
        "ground": ground,
    }


class _RunFiles:
    """The files a run streams to as it goes: frames, ``com.csv``, ``amplitudes.csv``; ``summary.json`` at close.

    A write that fails (a disk full) raises :class:`~skfem_modal.outputs.OutputError` naming the file; after it
    nothing more is written but ``summary.json``, if there is room for it.
    """

    def __init__(self, out_dir: str, sim, every: int, monitor):
        self._made = made_folder(out_dir)  # removed again, with the parents it took, if the run cannot start
        self.out_dir, self.sim, self.every = out_dir, sim, every
        self.monitor = monitor  # the run's MotionMonitor: it counts the elements inside out in each frame
        self._last = None  # (step, z, a) of the last step written
        self._framed = None  # the step of the last frame written
        self.failed = False
        self.frames, self._files = None, []
        try:
            cell_data = {"cluster": sim.labels, "muscle_cluster": sim.active_labels}
            self.frames = FrameWriter(out_dir, sim.mesh, name="frames", cell_data=cell_data)
            for name in ("com.csv", "amplitudes.csv"):
                self._files.append(open(os.path.join(out_dir, name), "w", newline=""))
            self.com, self.amplitudes = (csv.writer(f) for f in self._files)
            m = sim.n_muscles
            self.com.writerow(["time"] + ["xyz"[k] for k in range(sim.dim)])
            self.amplitudes.writerow(
                ["time"] + [f"commanded_{k}" for k in range(m)] + [f"realised_{k}" for k in range(m)]
            )
            for f in self._files:
                f.flush()
        except BaseException as err:  # (a Ctrl-C here too: it left the folder the run had just made)
            self._remove_started()
            if not isinstance(err, OSError):
                raise
            raise OutputError(
                f"could not write {err.filename or out_dir}: {err.strerror or err}; nothing was run"
            ) from None

    def _remove_started(self) -> None:
        """Close and remove what a run that could not start had written (nothing half-written is left)."""
        for handle in [self.frames, *self._files]:
            if handle is not None:
                with contextlib.suppress(OSError):
                    handle.close()
        names = [os.path.join(self.out_dir, name) for name in ("frames.pvd", "com.csv", "amplitudes.csv")]
        for path in names + [os.path.join(self.out_dir, FRAMES_DIR)]:
            with contextlib.suppress(OSError):  # (a folder: only if empty)
                os.rmdir(path) if os.path.isdir(path) else os.remove(path)
        remove_if_empty(self.out_dir, self._made)

    def _failure(self, err: OSError, step: int, where: str) -> OutputError:
        """The error a failed write raises: the file, why, the step, and where the frames end."""
        self.failed = True
        framed = f"t = {self.frames.times[-1]:g}" if self.frames.times else "none written"
        return OutputError(
            f"could not write {err.filename or where}: {err.strerror or err} (at step {step}, "
            f"t = {step * self.sim.h:g}); the frames end at {framed}, and com.csv and amplitudes.csv may end "
            "within a row"
        )

    def write(self, step: int, z, a, com) -> None:
        """One step's frame (every ``every`` steps), then its rows."""
        sim = self.sim
        try:
            if step % self.every == 0:
                self._frame(step, z, a)
            t = step * sim.h
            self.com.writerow([repr(t)] + [repr(float(c)) for c in com])
            # (a row a step without muscles too: the table's times are the run's, as render reads them)
            realised = sim.muscle_amplitudes(z) if sim.n_muscles else ()
            self.amplitudes.writerow([repr(t)] + [repr(float(v)) for v in a] + [repr(float(v)) for v in realised])
            if step % self.every == 0:
                for f in self._files:  # the tables on disk reach at least the last frame
                    f.flush()
        except OSError as err:
            raise self._failure(err, step, "com.csv or amplitudes.csv") from None
        self._last = (step, z, a)

    def _frame(self, step: int, z, a) -> None:
        """The frame of the state after ``step`` steps (full positions only for frames written)."""
        sim = self.sim
        x = sim.positions(z)
        self.monitor.check_elements(step, x)
        self.frames.write(step * sim.h, x, field_data={"activation": a} if sim.n_muscles else None)
        self._framed = step

    def frame_last(self) -> None:
        """The last step's frame, if ``every`` skipped it: the frames then end at the last step done."""
        if self._last is not None and self._last[0] != self._framed and not self.failed:
            try:
                self._frame(*self._last)
            except OSError as err:
                raise self._failure(err, self._last[0], "the last frame") from None

    def close(self, summary: dict) -> None:
        """Close the files (the last step's frame written if it was not); write ``summary.json``.

        The frames, the tables and the summary then all end at the last step done. Closing a table
        that cannot be written whole (its last rows) fails the run: the summary says so, if it can.
        """
        self.frame_last()
        frames = self.frames
        drift = {"worst_drift": self.monitor.pin_drift, "worst_drift_written_frames": self.monitor.pin_drift_checked}
        pinned = drift if self.sim.pinned.size else None
        times = [frames.times[0], frames.times[-1]] if frames.times else None
        summary.update(
            pinned=pinned, frames={"count": frames.count, "every": self.every, "pvd": "frames.pvd", "times": times}
        )
        failure = None
        for handle, name in [(frames, "frames.pvd"), *zip(self._files, ("com.csv", "amplitudes.csv"))]:
            try:
                handle.close()
            except OSError as err:
                if not self.failed:
                    step = self._last[0] if self._last is not None else 0
                    failure = self._failure(err, step, os.path.join(self.out_dir, name))
                    summary.update(status="failed", error={"step": step, "time": step * self.sim.h,
                                                           "message": f"OutputError: {failure}"})  # fmt: skip
        try:
            _write_json(os.path.join(self.out_dir, "summary.json"), summary)
        except OSError as err:
            if not self.failed:
                raise self._failure(err, summary["steps_completed"], "summary.json") from None
            # (after a failed write the summary is tried still, it is small; the first error says why)
        if failure is not None:
            raise failure


def _version() -> str:
    from . import __version__

    return __version__
