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

import csv
import json
import os
import platform
import sys
import time

import numpy as np

from .export import FrameWriter, atomic_path
from .mesh import mesh_summary
from .monitor import MotionMonitor
from .outputs import clear_earlier_run
from .sim import SimulationError, simulate

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
        self.count += n
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.update(n)
        elif self.count >= self._next:
            self._print()
            # a terminal line is rewritten in place; a log file gets a line a tenth of the way
            self._next += max(1, self.total // (20 if self._tty else 10))

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
    tmp = atomic_path(path)
    with open(tmp, "w") as f:
        json.dump(data, f, indent=2, default=_jsonable)
        f.write("\n")
    os.replace(tmp, path)


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
        A simulator already built from this scene (its precompute is reused).
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
        If the state goes non-finite (the outputs so far are kept).
    FileExistsError
        ``out_dir`` holds an earlier run and ``overwrite`` is false (before any work).

    Warns
    -----
    MotionWarning
        The run completed, but its motion is not physical for the scene
        (see :mod:`skfem_modal.monitor`); ``summary["motion"]`` says why.
    """
    every = scene.config["output"]["every"] if every is None else every
    if isinstance(every, bool) or not isinstance(every, (int, np.integer)) or every < 1:
        raise ValueError(f"every must be a positive integer, got {every!r}")
    if out_dir is not None:
        clear_earlier_run(out_dir, overwrite)
    started = time.perf_counter()
    if sim is None:
        sim = scene.build(progress=_stage_printer(progress))
    precompute = time.perf_counter() - started
    mesh = sim.mesh
    h, n_steps, dim = sim.h, scene.n_steps, sim.dim
    m = sim.n_muscles
    ground = sim.ground
    summary = {
        "skfem_modal": _version(),
        "python": platform.python_version(),
        "scene": scene.to_dict(),
        "mesh": mesh_summary(mesh),
        "effects": list(sim.effects),
        "sizes": {
            "dofs": int(mesh.p.size),
            "subspace": int(sim.B.shape[1]),
            "clusters": int(sim.n_clusters),
            "active_clusters": int(sim.n_active_clusters),
            "muscles": int(m),
            "contact_points": int(sim.contact_vertices.size),
            "pinned_vertices": int(sim.pinned.size),
        },
        "muscle_ceilings": sim.ceilings,
        "timings": {"precompute_s": dict(sim.timings), "precompute_total_s": precompute},
        "steps": n_steps,
        "h": h,
        "status": "running",
    }

    writers = {}
    frames = None
    if out_dir is not None:
        out_dir = os.fspath(out_dir)
        os.makedirs(out_dir, exist_ok=True)
        cell_data = {"cluster": sim.labels, "muscle_cluster": sim.active_labels}
        frames = FrameWriter(out_dir, mesh, name="frames", cell_data=cell_data)
        com_file = open(os.path.join(out_dir, "com.csv"), "w", newline="")
        amp_file = open(os.path.join(out_dir, "amplitudes.csv"), "w", newline="")
        writers = {"com": (com_file, csv.writer(com_file)), "amp": (amp_file, csv.writer(amp_file))}
        writers["com"][1].writerow(["time"] + ["xyz"[k] for k in range(dim)])
        writers["amp"][1].writerow(
            ["time"] + [f"commanded_{k}" for k in range(m)] + [f"realised_{k}" for k in range(m)]
        )

    z, z_dot, a = sim.rest_state()
    start_com = sim.com(z)
    monitor = MotionMonitor(sim, None if scene.config["gravity"] is None else scene.config["gravity"]["acceleration"])
    coms = [start_com]
    step_seconds, iterations, residuals = [], [], []
    worst_penetration = 0.0
    worst_pin = 0.0
    rest = mesh.p.T

    def record(step: int, z, a):
        nonlocal worst_pin
        t = step * h
        com = sim.com(z)
        if writers:
            writers["com"][1].writerow([repr(t)] + [repr(float(c)) for c in com])
            if m:
                writers["amp"][1].writerow(
                    [repr(t)] + [repr(float(v)) for v in a] + [repr(float(v)) for v in sim.muscle_amplitudes(z)]
                )
        if frames is not None and step % every == 0:
            # full positions only for frames that are written out
            x = sim.positions(z)
            if sim.pinned.size:
                worst_pin = max(worst_pin, float(np.abs(x[sim.pinned] - rest[sim.pinned]).max()))
            frames.write(t, x, field_data={"activation": a} if m else None)
        return com

    bar = Progress(n_steps, "steps", enabled=progress)
    status, error = "completed", None
    step = 0
    ceilings = sim.ceilings
    activation = (lambda t: scene.activation(t, ceilings)) if m else None
    try:
        record(0, z, a)
        for done in simulate(sim, n_steps, activation):
            step = done.step
            step_seconds.append(done.seconds)
            iterations.append(done.iterations)
            residuals.append(done.residual)
            if ground is not None:
                # every boundary vertex, every step: the deepest any went below the ground
                worst_penetration = max(worst_penetration, sim.penetration(done.z))
            coms.append(record(step, done.z, done.a))
            monitor.update(step, done.z)
            bar.update()
    except SimulationError as err:
        step = err.step or step + 1
        status, error = "failed", {"step": step, "time": step * h, "message": str(err)}
        raise SimulationError(f"{err.message} (t = {step * h:g}; outputs so far kept)", step=step) from None
    except KeyboardInterrupt:
        status, error = "interrupted", {"step": step, "time": step * h}
        raise
    finally:
        bar.close()
        coms = np.array(coms)
        steps_done = len(step_seconds)
        it = np.array(iterations, dtype=int)
        summary.update(
            {
                "status": status,
                "error": error,
                "steps_completed": steps_done,
                "motion": monitor.finish(),
                "timings": {
                    **summary["timings"],
                    "steps_total_s": float(np.sum(step_seconds)),
                    "step_ms": _stats_ms(step_seconds),
                    "wall_s": time.perf_counter() - started,
                },
                "iterations": {
                    "mean": float(it.mean()) if it.size else 0.0,
                    "min": int(it.min()) if it.size else 0,
                    "max": int(it.max()) if it.size else 0,
                    "histogram": {str(k): int(v) for k, v in zip(*np.unique(it, return_counts=True))},
                    "residual": _residual_stats(residuals),
                },
                "com": {
                    "start": coms[0],
                    "end": coms[-1],
                    "travel": coms[-1] - coms[0],
                    "distance": float(np.linalg.norm(coms[-1] - coms[0])),
                    "min": coms.min(axis=0),
                    "max": coms.max(axis=0),
                },
                "ground": None
                if ground is None
                else {
                    "height": ground,
                    "model": sim.contact_model,
                    "worst_penetration": worst_penetration,
                    "worst_penetration_relative": worst_penetration / float(np.ptp(mesh.p, axis=1).max()),
                },
                "pinned": None if not sim.pinned.size or frames is None else {"worst_drift_written_frames": worst_pin},
                "frames": None
                if frames is None
                else {
                    "count": frames.count,
                    "every": every,
                    "pvd": "frames.pvd",
                    "times": [frames.times[0], frames.times[-1]],
                },
            }
        )
        if frames is not None:
            frames.close()
            for f, _ in writers.values():
                f.close()
            _write_json(os.path.join(out_dir, "summary.json"), summary)
    return summary


def _version() -> str:
    from . import __version__

    return __version__
