"""Gait search at its edges: scenes read from anywhere, lost workers, stops, bad options, shared folders, transfer."""

import copy
import csv
import os
import pickle
import shutil
import signal
import socket
import subprocess
import sys
import textwrap
import time
import tomllib
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import COULOMB_CRAWL, die

import skfem_modal as sm
from skfem_modal import optimize, rollouts, study
from skfem_modal.cli import _joined_signed_values, main
from skfem_modal.interrupts import QuietSpawnContext
from skfem_modal.monitor import CeilingWarning
from skfem_modal.optimize import GaitSpace, SearchInterrupted, SearchWorkersLost, run_search, scene_to_toml
from skfem_modal.run import run_scene
from skfem_modal.scene import DEFAULT_SCENE, Scene

pytest.importorskip("cma", reason="cma is in the optimize extra")

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"

TINY = copy.deepcopy(DEFAULT_SCENE)
TINY["mesh"] = {"shape": "caterpillar", "params": {"nx": 24, "ny": 12}}
TINY["subspace"] = {"weights": 6, "clusters": 10}
QUICK = ["--popsize", "2", "--steps", "20", "--workers", "1", "-q"]


def search(out, data=TINY, **kw):
    return run_search(data, out, **{"generations": 2, "popsize": 4, "seed": 3, "steps": 60, **kw})


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    return search(tmp_path_factory.mktemp("uninterrupted"), workers=1)


@pytest.fixture
def tiny_scene(tmp_path):
    path = tmp_path / "tiny.toml"
    path.write_text(scene_to_toml(TINY))
    return str(path)


# ------------------------------------------------------------ the scene's files


def test_a_scene_with_a_table_is_searched_from_any_folder(tmp_path, monkeypatch, capsys):
    """examples/beam_pinned.toml names beam_steer.csv beside it: found from another working directory."""
    monkeypatch.chdir(tmp_path)
    args = ["optimize", str(EXAMPLES / "beam_pinned.toml"), "--generations", "1", "--direction", "y", "--out", "bp"]
    assert main([*args, *QUICK]) == 0, capsys.readouterr().err
    best = tomllib.loads((tmp_path / "bp" / "best_gait.toml").read_text())
    assert "table" not in best["muscles"] and len(best["muscles"]["gait"]["amplitude"]) == 2  # the gait replaces it
    state = optimize.read_checkpoint(str(tmp_path / "bp" / "checkpoint.pkl"))
    travel = max([state["start"]] + state["history"], key=lambda row: row["best_fitness"])["best_travel"]
    assert run_scene(Scene.from_dict(best), None)["com"]["travel"][1] == pytest.approx(travel, rel=1e-9, abs=1e-12)
    # without the table beside the scene: refused, naming it, before any folder is made
    shutil.copy(EXAMPLES / "beam_pinned.toml", tmp_path / "lonely.toml")
    assert main(["optimize", str(tmp_path / "lonely.toml"), "--out", "lonely", *QUICK]) == 2
    assert f"muscles.table: no such file {str(tmp_path / 'beam_steer.csv')!r}" in capsys.readouterr().err
    assert not (tmp_path / "lonely").exists()


def test_a_search_that_fails_to_build_writes_nothing(tmp_path, monkeypatch):
    (tmp_path / "old").mkdir()
    search(tmp_path / "old", workers=1, generations=1)
    before = {p.name: p.read_bytes() for p in (tmp_path / "old").iterdir()}

    def fail(*args, **kwargs):
        raise ValueError("the precompute failed")

    monkeypatch.setattr(optimize.Trial, "from_scene", fail)
    for out, flags in ((tmp_path / "new", {}), (tmp_path / "old", {"overwrite": True})):
        with pytest.raises(ValueError, match="the precompute failed"):
            search(out, **flags)
    assert not (tmp_path / "new").exists()
    assert {p.name: p.read_bytes() for p in (tmp_path / "old").iterdir()} == before  # the search replaced is intact


# ------------------------------------------------------------ workers lost, stops


def test_a_killed_pool_worker_stops_the_search_which_resumes_exactly(uninterrupted, tmp_path):
    """A worker SIGKILLed (the out-of-memory killer) between generations: one error, the checkpoint kept."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        search(tmp_path, executor=pool, stop_after=1)
        pool.submit(die).exception(timeout=60)  # the worker is killed while it runs a task
        with pytest.raises(SearchWorkersLost) as lost:
            search(tmp_path, executor=pool, resume=True)
    assert lost.value.generations == 1 and lost.value.total == 2
    assert str(lost.value) == (
        "the search lost its workers in generation 2 of 2: a worker process of the local pool died (killed: by "
        f"the out-of-memory killer, say); the checkpoint in {tmp_path} holds generation 1"
    )
    assert optimize.read_checkpoint(str(tmp_path / "checkpoint.pkl"))["generation"] == 1
    assert len((tmp_path / "history.csv").read_text().splitlines()) == 2  # the files match the checkpoint
    resumed = search(tmp_path, workers=1, resume=True)
    assert [h["best_fitness"] for h in resumed["history"]] == [h["best_fitness"] for h in uninterrupted["history"]]
    assert resumed["best"] == uninterrupted["best"]


def test_the_command_says_how_to_resume_a_search_that_lost_its_workers(tiny_scene, tmp_path, capsys, killing_pools):
    out = tmp_path / "s"
    args = ["optimize", tiny_scene, "--generations", "3", "--popsize", "4", "--steps", "60", "--seed", "3"]
    args += ["--out", str(out), "-q"]
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(
            rollouts, "make_executor", killing_pools(study.make_executor, after=5)
        )  # in generation 2 (after the start and generation 1)
        assert main(args) == 4
    err = capsys.readouterr().err
    assert err == (
        "skfem-modal optimize: the search lost its workers in generation 2 of 3: a worker process of the local "
        f"pool died (killed: by the out-of-memory killer, say); the checkpoint in {out} holds generation 1\n"
        f"resume it with: skfem-modal {' '.join(args)} --resume\n"
    )
    assert main([*args, "--resume"]) == 0
    fresh = tmp_path / "fresh"
    assert main([*args[:-3], "--out", str(fresh), "-q"]) == 0
    resumed, uninterrupted = (
        [r.split(",")[:8] for r in (d / "history.csv").read_text().splitlines()] for d in [out, fresh]
    )
    assert len(resumed) == 4 and resumed == uninterrupted  # every number but the wall time
    # lost in the first generation: nothing to resume, and no --resume said
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(rollouts, "make_executor", killing_pools(study.make_executor, after=0))
        assert main([*args[:-3], "--out", str(tmp_path / "first"), "-q"]) == 4
    err = capsys.readouterr().err
    assert "in generation 1 of 3" in err and "nothing was checkpointed" in err and "--resume" not in err
    assert "start it again with: skfem-modal optimize" in err and not (tmp_path / "first" / "checkpoint.pkl").exists()


@pytest.mark.parametrize(
    "error, said",
    [
        ("scheduler-connection-lost", "the connection to the dask scheduler was lost"),
        ("already forgotten", "the dask cluster cancelled the tasks (already forgotten: its workers died"),
        ("killed", "dask workers died running a task"),
        ("own", None),
    ],
)
def test_what_dask_says_of_lost_workers(error, said):
    distributed = pytest.importorskip("distributed", reason="dask is in the distributed extra")
    from distributed.client import FutureCancelledError

    raised = {
        "killed": distributed.KilledWorker("rollout-1", SimpleNamespace(address="tcp://127.0.0.1:1234"), 3),
        "own": RuntimeError("a task's own error"),
    }.get(error) or FutureCancelledError("rollout-1", error)
    found = study.lost_workers(raised)
    assert found is None if said is None else found.startswith(said)


@pytest.mark.parametrize("status, said", [("running", "the dask cluster cancelled"), ("closed", "the connection")])
def test_tasks_cancelled_for_no_reason_are_a_lost_scheduler_once_the_client_gave_up(status, said):
    """Tasks submitted while the client tried to reconnect are cancelled with reason 'unknown' when it gives up."""
    pytest.importorskip("distributed", reason="dask is in the distributed extra")
    from distributed.client import FutureCancelledError

    executor = type("ClientExecutor", (), {"__module__": "distributed.cfexecutor"})()
    executor._client = SimpleNamespace(status=status)
    assert study.lost_workers(FutureCancelledError("rollout-1", None), executor).startswith(said)


def test_ctrl_c_in_the_first_generation_says_nothing_was_checkpointed(tiny_scene, tmp_path, capsys, monkeypatch):
    def interrupted(*args):
        raise KeyboardInterrupt

    monkeypatch.setattr(optimize, "_generation", interrupted)
    with pytest.raises(SearchInterrupted) as stop:
        search(tmp_path / "lib", workers=1)
    assert stop.value.generations == 0
    assert str(stop.value) == (
        f"interrupted in generation 1 of 2; no generation was finished, so nothing was checkpointed in "
        f"{tmp_path / 'lib'}: there is nothing to resume"
    )
    args = ["optimize", tiny_scene, "--generations", "30", "--out", str(tmp_path / "cli"), *QUICK]
    assert main(args) == 130
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith("skfem-modal optimize: interrupted in generation 1 of 30; no generation was finished")
    assert err[1] == f"start it again with: skfem-modal {' '.join(args)}"
    assert not (tmp_path / "cli").exists() and not (tmp_path / "lib").exists()  # the folders it made: gone


@pytest.mark.parametrize("again", [False, True])
def test_ctrl_c_while_the_last_generation_is_drawn_says_what_the_checkpoint_holds(tmp_path, monkeypatch, again):
    """A stop while fitness.png was drawn, after the last generation: a bare "interrupted", no resume line, no
    picture. ``again``: a second Ctrl-C while the stop draws it again (an audit: 0.05 s after the first, it lost
    fitness.png and the lines saying how to resume)."""
    draw = optimize._write_plot
    calls = []

    def interrupted(*args):
        calls.append(args)
        if len(calls) == 1:
            raise KeyboardInterrupt
        if again:
            signal.raise_signal(signal.SIGINT)
        draw(*args)

    monkeypatch.setattr(optimize, "_write_plot", interrupted)
    with pytest.raises(SearchInterrupted) as stop:
        search(tmp_path, workers=1)
    assert stop.value.generations == 2 and "2 of 2" in str(stop.value)
    assert len(calls) == 2 and (tmp_path / "fitness.png").exists()  # drawn again from the checkpoint
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # given back


def test_ctrl_c_before_the_first_checkpoint_of_an_overwrite_keeps_the_earlier_search(tmp_path, monkeypatch):
    """--overwrite removed the earlier search's files as it started: a Ctrl-C in its first generation left
    nothing to resume (an audit). They are kept until the new search's first checkpoint."""
    out = tmp_path / "s"
    search(out, workers=1, generations=1)
    before = {path.name: path.read_bytes() for path in out.iterdir()}
    assert "checkpoint.pkl" in before and "fitness.png" in before
    generation = optimize._generation

    def interrupted(*args):
        raise KeyboardInterrupt

    monkeypatch.setattr(optimize, "_generation", interrupted)
    with pytest.raises(SearchInterrupted) as stop:
        search(out, workers=1, overwrite=True, seed=4)
    assert str(stop.value) == (
        f"interrupted in generation 1 of 2; no generation was finished, so the earlier search in {out} is kept "
        "as it was"
    )
    assert stop.value.generations == 0
    assert {path.name: path.read_bytes() for path in out.iterdir()} == before
    # the earlier search resumes; once a new one checkpoints, what it did not write over is gone
    monkeypatch.setattr(optimize, "_generation", generation)
    assert search(out, workers=1, resume=True)["generations"] == 2
    (out / "transfer.csv").write_text("stale")
    monkeypatch.setattr(optimize, "_write_plot", lambda *args: None)
    search(out, workers=1, overwrite=True, seed=4, generations=1)
    assert sorted(path.name for path in out.iterdir()) == ["best_gait.toml", "checkpoint.pkl", "history.csv"]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
@pytest.mark.parametrize("killed", ["workers", "scheduler"])
def test_a_dask_search_that_loses_its_cluster_says_how_to_resume(tiny_scene, tmp_path, killed):
    """Every dask worker SIGKILLed, or the scheduler: one error, exit code 4, and --resume ends as uninterrupted."""
    distributed = pytest.importorskip("distributed", reason="dask is in the distributed extra")
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    address = f"tcp://127.0.0.1:{_free_port()}"
    quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL, "start_new_session": True, "env": env}
    scheduler = subprocess.Popen(
        [sys.executable, "-m", "distributed.cli.dask_scheduler", "--port", address.rsplit(":", 1)[1]]
        + ["--no-dashboard"],
        **quiet,
    )
    workers = subprocess.Popen(
        [sys.executable, "-m", "distributed.cli.dask_worker", address, "--nworkers", "2", "--nthreads", "1"]
        + ["--no-dashboard"],
        **quiet,
    )
    out = tmp_path / "s"
    args = ["optimize", tiny_scene, "--generations", "200", "--popsize", "4", "--steps", "60", "--seed", "3"]
    args += ["--out", str(out), "--scheduler", address, "-q"]
    try:
        with distributed.Client(address, timeout=60) as client:  # the cluster is up before the search starts
            client.wait_for_workers(2, timeout=60)
        search = subprocess.Popen(
            [sys.executable, "-m", "skfem_modal.cli", *args], stderr=subprocess.PIPE, text=True, env=env
        )
        deadline = time.time() + 120
        while time.time() < deadline and not (out / "history.csv").exists() and search.poll() is None:
            time.sleep(0.2)
        time.sleep(0.5)
        os.killpg((workers if killed == "workers" else scheduler).pid, signal.SIGKILL)
        _, err = search.communicate(timeout=120)
    finally:
        for process in (workers, scheduler):
            try:
                os.killpg(process.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            process.wait()
    lines = [line for line in err.splitlines() if " - distributed." not in line]  # dask's own log lines
    assert search.returncode == 4 and "Traceback" not in err, err
    with open(out / "checkpoint.pkl", "rb") as f:
        done = pickle.load(f)["generation"]
    reason = "the connection to the dask scheduler was lost" if killed == "scheduler" else "the dask cluster"
    assert lines[0].startswith(f"skfem-modal optimize: the search lost its workers in generation {done + 1} of 200")
    assert reason in lines[0] and lines[0].endswith(f"the checkpoint in {out} holds generation {done}")
    assert lines[1:] == [f"resume it with: skfem-modal {' '.join(args)} --resume"]
    # the checkpoint resumes, here on the local pool, to the uninterrupted search's end
    resumed = run_search(TINY, out, generations=done + 1, popsize=4, seed=3, steps=60, workers=1, resume=True)
    fresh = run_search(TINY, tmp_path / "fresh", generations=done + 1, popsize=4, seed=3, steps=60, workers=1)
    assert [h["best_fitness"] for h in resumed["history"]] == [h["best_fitness"] for h in fresh["history"]]


# ------------------------------------------------------------ seeds, numbers, directions


@pytest.mark.parametrize("seed", ["-1", "-5", "4294967295"])
def test_seeds_outside_what_cma_takes_deterministically_are_refused(tiny_scene, tmp_path, capsys, seed):
    with pytest.raises(SystemExit) as usage:
        main(["optimize", tiny_scene, "--seed", seed, "--out", str(tmp_path / "s")])
    assert usage.value.code == 2
    assert f"argument --seed: expected an integer from 0 to 4294967294, got {seed!r}" in capsys.readouterr().err
    with pytest.raises(ValueError, match=f"seed must be an integer from 0 to 4294967294, got {int(seed)}"):
        search(tmp_path / "s", seed=int(seed))
    assert not (tmp_path / "s").exists()


def test_the_largest_seed_gives_the_same_search_twice(tmp_path):
    runs = [search(tmp_path / name, seed=optimize.SEED_MAX, generations=1, popsize=2, workers=1) for name in "ab"]
    assert runs[0]["best"] == runs[1]["best"] and runs[0]["history"][0]["sigma"] == runs[1]["history"][0]["sigma"]


def test_body_rotation_rows_do_not_depend_on_the_blas_threads(cat_mesh):
    """Made in the search's own process, whose threads the calling shell sets: 2 threads summed in another order."""
    threadpoolctl = pytest.importorskip("threadpoolctl")
    n = cat_mesh.p.shape[1]
    rng = np.random.default_rng(0)
    mass = np.repeat(rng.uniform(0.5, 1.5, n), 2)
    sim = SimpleNamespace(mesh=cat_mesh, mass=mass, B=rng.standard_normal((2 * n, 48)))
    rows = {}
    for threads in (1, 2):
        with threadpoolctl.threadpool_limits(threads):
            rows[threads] = rollouts.body_rotation_rows(sim)
    assert np.array_equal(rows[1], rows[2])  # threaded BLAS: 34 to 52 of these 192 entries differed, by up to 1.4e-14
    full = rollouts.body_rotation_rows(SimpleNamespace(mesh=cat_mesh, mass=sim.mass, B=None))
    np.testing.assert_allclose(rows[1], full @ sim.B, rtol=0, atol=1e-12 * np.abs(full).sum(1).max())


@pytest.mark.parametrize(
    "option, values, said",
    [
        ("--period-range", ["0.3", "inf"], "argument --period-range: expected a positive finite number, got 'inf'"),
        ("--period-range", ["nan", "2"], "argument --period-range: expected a positive finite number, got 'nan'"),
        ("--amplitude-max", ["inf"], "argument --amplitude-max: expected a positive finite number, got 'inf'"),
        ("--amplitude-max", ["0"], "argument --amplitude-max: expected a positive finite number, got '0'"),
        ("--tip-limit", ["inf"], "argument --tip-limit: expected a finite number >= 0, got 'inf'"),
        ("--tip-weight", ["-1"], "argument --tip-weight: expected a finite number >= 0, got '-1'"),
        ("--jitter", ["nan"], "argument --jitter: expected a finite number >= 0, got 'nan'"),
        # named as the option, before the search's banner (said "jitter"/"popsize", after it; an audit)
        ("--jitter", ["0.5"], "argument --jitter: expected a number in [0, 0.5), got '0.5'"),
        ("--popsize", ["1"], "argument --popsize: expected at least 2 (CMA-ES ranks the candidates), got '1'"),
    ],
)
def test_option_values_are_finite_before_any_work(tiny_scene, tmp_path, capsys, option, values, said):
    with pytest.raises(SystemExit) as usage:
        main(["optimize", tiny_scene, option, *values, "--out", str(tmp_path / "s")])
    out = capsys.readouterr()
    assert usage.value.code == 2 and said in out.err and out.out == ""
    assert not (tmp_path / "s").exists()


def test_a_search_refused_by_the_library_is_said_without_its_banner(tmp_path, capsys):
    """The banner ("CMA-ES over ...") came before the error, as if the search had begun (an audit)."""
    scene = tmp_path / "float.toml"
    scene.write_text('[mesh]\nshape = "caterpillar"\n[mesh.params]\nnx = 16\nny = 8\n[muscles]\ncount = 2\n')
    assert main(["optimize", str(scene), "--generations", "1", "--out", str(tmp_path / "s")]) == 2
    out = capsys.readouterr()
    assert out.out == "" and "the scene has no ground and no pins" in out.err
    assert not (tmp_path / "s").exists()


def test_a_gait_space_is_finite_and_warns_beyond_the_ceilings():
    with pytest.raises(ValueError, match="period_max must be a finite number, got inf"):
        GaitSpace(2, period_max=np.inf)
    with pytest.raises(ValueError, match="amplitude_max must be a finite number, got nan"):
        GaitSpace(2, amplitude_max=np.nan)
    with pytest.warns(CeilingWarning, match="up to 1e[+]08 times their ceilings: an activation beyond 1 asks"):
        GaitSpace(2, amplitude_max=1e8)


def test_the_command_warns_of_amplitudes_beyond_the_ceilings(tiny_scene, tmp_path, capsys):
    args = ["optimize", tiny_scene, "--amplitude-max", "2", "--generations", "1", "--out", str(tmp_path / "s")]
    assert main([*args, *QUICK]) == 0
    err = capsys.readouterr().err
    assert err.startswith(
        "skfem-modal optimize: warning: amplitude_max = 2 lets the search drive the muscles up to 2 times their "
        "ceilings: an activation beyond 1 asks an element to deform by more than muscles.max_s"
    )


def test_a_direction_with_a_sign_is_its_value(tiny_scene, tmp_path, capsys):
    assert _joined_signed_values(["optimize", "--direction", "-x", "--out", "-o"]) == [
        "optimize",
        "--direction=-x",
        "--out",
        "-o",
    ]
    assert _joined_signed_values(["--direction", "-1,0", "--direction", "--quiet"]) == [
        "--direction=-1,0",
        "--direction",
        "--quiet",
    ]
    for direction, said in (("-x", "[-1.0, 0.0]"), ("-1,0.5", "[-1.0, 0.5]"), ("-.5,-2", "[-0.5, -2.0]")):
        args = ["optimize", tiny_scene, "--direction", direction, "--generations", "1", "--popsize", "2"]
        assert main([*args, "--steps", "10", "--workers", "1", "--out", str(tmp_path / direction)]) == 0
        assert f"(travel along {said})" in capsys.readouterr().out


# ------------------------------------------------------------ output folders


def test_a_resumed_search_that_goes_on_drops_the_transfer_of_its_old_best(tmp_path):
    search(tmp_path, workers=1, generations=1)
    (tmp_path / "transfer.csv").write_text("setting,travel\nas searched,0.1\n")
    search(tmp_path, workers=1, generations=1, resume=True)  # no new generation: the replay still stands
    assert (tmp_path / "transfer.csv").exists()
    went_on = search(tmp_path, workers=1, resume=True)
    # dropped when the new generation found a better gait, kept when the replay is still of the best one
    assert (tmp_path / "transfer.csv").exists() == (went_on["best"]["generation"] != 2)


def test_a_resumed_search_whose_best_stays_keeps_its_transfer(tmp_path):
    """Removed on every resume though the best gait had not changed (an audit)."""
    space, kw = GaitSpace(4, amplitude_max=0.01), dict(popsize=2, seed=3, steps=40, workers=1, direction=[-1.0, 0.0])
    run_search(TINY, tmp_path, generations=1, space=space, **kw)
    (tmp_path / "transfer.csv").write_text("setting,travel\nas searched,0.1\n")
    result = run_search(TINY, tmp_path, generations=2, space=space, resume=True, **kw)
    assert result["best"]["generation"] == 0  # the crawl it started from, which candidates this small never beat
    assert (tmp_path / "transfer.csv").exists()


def test_a_search_run_and_study_never_share_a_folder(tiny_scene, tmp_path, capsys):
    searched, ran, studied = tmp_path / "search", tmp_path / "run", tmp_path / "study"
    assert main(["optimize", tiny_scene, "--generations", "1", "--out", str(searched), *QUICK]) == 0
    short = tmp_path / "short.toml"
    short.write_text(scene_to_toml({**TINY, "time": {"step": 0.01, "steps": 2}}))
    assert main(["run", str(short), "--out", str(ran), "-q"]) == 0
    studied.mkdir()
    (studied / "study.json").write_text("{}")
    for flags in ([], ["--overwrite"], ["--resume"]):
        for other, kind in ((ran, "run"), (studied, "study")):
            assert main(["optimize", tiny_scene, "--generations", "1", "--out", str(other), *QUICK, *flags]) == 2
            assert f"{str(other)!r} holds a {kind} (" in capsys.readouterr().err
    for flags in ([], ["--overwrite"]):
        assert main(["run", tiny_scene, "--out", str(searched), "-q", *flags]) == 2
        assert "holds a search (best_gait.toml, checkpoint.pkl, fitness.png, history.csv): a run there" in (
            capsys.readouterr().err
        )
        assert main(["study", tiny_scene, "--out", str(searched), "-q", *flags]) == 2
        assert "holds a search (best_gait.toml, checkpoint.pkl, fitness.png, history.csv): a study there" in (
            capsys.readouterr().err
        )
    assert sorted(os.listdir(searched)) == ["best_gait.toml", "checkpoint.pkl", "fitness.png", "history.csv"]
    # a search's files without its checkpoint are a search all the same: replaced only when asked
    (searched / "checkpoint.pkl").unlink()
    assert main(["optimize", tiny_scene, "--generations", "1", "--out", str(searched), *QUICK]) == 2
    err = capsys.readouterr().err
    assert "holds a search (best_gait.toml, fitness.png, history.csv): start again with --overwrite" in err
    assert "--resume" not in err


# ------------------------------------------------------------ transfer


@pytest.fixture(scope="module")
def backwards(tmp_path_factory):
    """A search towards +x of the caterpillar, which crawls towards -x: its best travel is negative."""
    out = tmp_path_factory.mktemp("backwards")
    found = run_search(TINY, out, generations=1, popsize=2, seed=0, steps=60, workers=1)
    assert found["best"]["travel"] < 0
    return out, found


def test_transfer_names_the_file_it_cannot_read(backwards, tmp_path, capsys):
    from skfem_modal.transfer import transfer_search

    out = tmp_path / "copy"
    shutil.copytree(backwards[0], out)
    good = (out / "checkpoint.pkl").read_bytes()
    (out / "checkpoint.pkl").write_text("garbage\n")
    checkpoint = str(out / "checkpoint.pkl")
    with pytest.raises(ValueError, match=f"^{checkpoint} is not a search checkpoint that can be read"):
        transfer_search(out)
    assert main(["transfer", str(out), "-q"]) == 2
    assert f"skfem-modal transfer: error: {checkpoint} is not a search checkpoint" in capsys.readouterr().err
    (out / "checkpoint.pkl").write_bytes(good)
    (out / "best_gait.toml").write_text((out / "best_gait.toml").read_text().replace("[muscles.gait]", "[muscles.gait"))
    assert main(["transfer", str(out), "-q"]) == 2
    assert f"skfem-modal transfer: error: {out / 'best_gait.toml'}: not valid TOML:" in capsys.readouterr().err
    (out / "checkpoint.pkl").write_bytes(good[: len(good) // 2])
    with pytest.raises(ValueError, match=f"^{checkpoint} is not a search checkpoint that can be read"):  # --resume too
        search(out, resume=True, generations=1, popsize=2, seed=0)


def test_transfer_prints_the_tilt_and_survives_means_the_same_for_a_backward_search(backwards, capsys):
    out, found = backwards
    assert main(["transfer", str(out), "--full-space-limit", "1"]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert printed[0].endswith("| travel | survives | alignment | largest tilt | s |")
    with open(out / "transfer.csv") as f:
        rows = list(csv.DictReader(f))
    searched = float(rows[0]["travel"])
    assert searched == found["best"]["travel"] < 0 and float(rows[0]["survives"]) == -1.0
    for row, line in zip(rows, printed[2:]):
        assert float(row["survives"]) == pytest.approx(float(row["travel"]) / -searched, rel=1e-15)  # along +x
        assert f"| {float(row['max_tilt_degrees']):.1f} |" in line
        # a replay that tipped past the search's limit (60 degrees) says so beside its survives (an audit: a
        # replay tilted 104 to 180 degrees showed survives 3.9 to 8.1 with nothing beside it)
        tipped = float(row["max_tilt_degrees"]) > 60.0
        assert (row["tipped"] == "True") == tipped and ("(tipped over) |" in line) == tipped
    assert f"the search's own travel is {searched:.4g}, backwards" in printed[-2]


def test_transfer_marks_the_replays_that_tipped_past_the_search_s_limit(backwards, tmp_path, capsys):
    # the same search with a tip limit below its own rollout's largest tilt: every replay that tilted more says so
    out = tmp_path / "copy"
    shutil.copytree(backwards[0], out)
    state = pickle.loads((out / "checkpoint.pkl").read_bytes())
    state["settings"]["tip_limit"] = 1e-3  # radians: the crawl tilts more (0.1 degrees)
    (out / "checkpoint.pkl").write_bytes(pickle.dumps(state))
    assert main(["transfer", str(out), "--full-space-limit", "1"]) == 0
    printed = capsys.readouterr().out.splitlines()
    rows = list(csv.DictReader(open(out / "transfer.csv")))
    limit = np.degrees(1e-3)
    assert rows[0]["tipped"] == "True" and "(tipped over) |" in printed[2]
    for row, line in zip(rows, printed[2:]):
        tipped = float(row["max_tilt_degrees"]) > limit
        assert (row["tipped"] == "True") == tipped and ("(tipped over) |" in line) == tipped
    assert f"tipped over: the body tilted more than the search's tip limit ({limit:.4g} degrees)" in "\n".join(printed)


@pytest.mark.parametrize("command", ["study", "optimize"])
def test_a_scheduler_address_that_does_not_answer_is_named_and_leaves_no_folder(command, tmp_path, capsys):
    # dask's bare 'missing port number in address' and an empty output folder left behind before
    out = tmp_path / "out"
    extra = ["--quick"] if command == "study" else ["--generations", "1", "--popsize", "3"]
    assert main([command, *extra, "--scheduler", "bogus", "--out", str(out)]) == 2
    assert "--scheduler bogus: no dask scheduler answers there (missing port number" in capsys.readouterr().err
    assert not out.exists()


def test_a_gait_that_flings_the_body_apart_scores_as_a_failed_rollout():
    """A finite blow-up scored by how far it flung the body: amplitude 1e12 gave fitness +8.8e11, and a
    search with --amplitude-max 30 returned a gait that tore the body to 3.5 times its size (an audit)."""
    trial = rollouts.Trial.from_scene(COULOMB_CRAWL, steps=80, direction=[1.0, 0.0])
    scores = {
        amplitude: trial.run({"amplitude": [amplitude] * 2, "period": [1.0, 0.8], "phase": [0.0, 0.25]})
        for amplitude in (0.4, 30.0, 1e12)
    }
    assert scores[0.4]["physical"] and abs(scores[0.4]["fitness"] - scores[0.4]["travel"]) < 1e-12
    for amplitude in (30.0, 1e12):
        score = scores[amplitude]
        assert score["finite"] and not score["physical"] and score["fitness"] == -1e3 * trial.size
        assert abs(score["travel"]) > 5.0  # it did fling it (1.3e11 at 1e12)
    # the rollout's check at its end finds what the run's monitor finds step by step
    sim = trial.sim
    for amplitude in (0.4, 30.0):
        monitor = type(trial.monitor)(sim, sim.gravity)
        sim.reset()
        z = sim.rest_state()[0]
        states = [z]
        gait = lambda t, a=amplitude: sm.sine_gait(t, a * sim.ceilings, [1.0, 0.8], [0.0, 0.25])  # noqa: E731
        for record in sm.simulate(sim, 80, gait):
            monitor.update(record.step, record.z)
            states.append(record.z)
        found = {k: v for k, v in monitor.first_problem_step.items() if k in ("push", "spread")}
        assert trial.monitor.run_problems(np.array(states)) == found
        assert bool(found) == (amplitude == 30.0)


def test_a_search_never_returns_a_gait_worse_than_the_one_it_started_from(tmp_path):
    """The scene's own gait was never scored: two generations in a box that excluded it returned a gait of
    fitness 1.2 from one of 15 (an audit). It is scored first, as generation 0, and kept if none beats it."""
    data = copy.deepcopy(TINY)
    data["muscles"]["gait"] = {"amplitude": [0.45, 0.35, 0.25, 0.15], "period": [1.2, 0.8, 1.0, 0.6],
                               "phase": [0.0, 0.25, 0.5, 0.1]}  # fmt: skip
    space = GaitSpace(4, amplitude_max=0.01)  # candidates that barely move
    result = run_search(
        data, tmp_path / "s", generations=1, popsize=2, seed=3, steps=40, space=space, workers=1, direction=[-1.0, 0.0]
    )
    own = rollouts.Trial.from_scene(data, steps=40, direction=[-1.0, 0.0]).run(data["muscles"]["gait"])
    best = result["best"]
    assert best["generation"] == 0 and best["gait"] == data["muscles"]["gait"]
    assert best["fitness"] == own["fitness"] and best["travel"] == own["travel"]
    assert best["fitness"] > result["history"][0]["best_fitness"]  # no candidate did better
    assert result["rollouts"] == 3  # the start, then the generation's two
    saved = tomllib.loads((tmp_path / "s" / "best_gait.toml").read_text())
    assert saved["muscles"]["gait"] == data["muscles"]["gait"] and "the gait it started from" in saved["name"]


def test_counts_are_whole_and_a_rollout_s_length_bounded_before_any_work(tmp_path, tiny_scene, capsys):
    """2.5 generations ran 3; --steps 2e10 failed in a worker asking 596 GiB, raw, with a folder left (an audit)."""
    for kw, said in (
        ({"generations": 2.5}, "generations must be an integer of at least 1, got 2.5"),
        ({"popsize": 4.5}, "popsize must be an integer of at least 2, got 4.5"),
        ({"steps": 2 * 10**10}, "steps: 20000000000 is more than 1e[+]06 steps a rollout"),
    ):
        with pytest.raises(ValueError, match=said):
            run_search(TINY, tmp_path / "s", **{"generations": 1, "popsize": 2, "steps": 20, **kw})
    assert main(["optimize", tiny_scene, "--steps", "20000000000", "--out", str(tmp_path / "s"), "-q"]) == 2
    assert "steps: 20000000000 is more than 1e+06 steps a rollout" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()


def _children(pid: int) -> list[int]:
    listed = subprocess.run(["ps", "-o", "pid=", "--ppid", str(pid)], capture_output=True, text=True).stdout
    return [int(p) for p in listed.split()]


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0]
    except FileNotFoundError:
        return False
    return state != "Z"  # a zombie has ended (its parent, now init, reaps it)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc and ps --ppid")
def test_a_search_killed_outright_leaves_no_worker_behind(tmp_path, tiny_scene):
    """SIGKILL of the search: its pool workers were handed to init and held 191 MB each for good (an audit)."""
    args = ["optimize", tiny_scene, "--generations", "200", "--popsize", "4", "--steps", "60", "--workers", "2"]
    search = subprocess.Popen([sys.executable, "-m", "skfem_modal.cli", *args, "--out", str(tmp_path / "s"), "-q"])
    try:
        deadline = time.time() + 120
        while time.time() < deadline and not (tmp_path / "s" / "history.csv").exists():
            time.sleep(0.2)
        workers = [pid for pid in _children(search.pid) if "spawn_main" in Path(f"/proc/{pid}/cmdline").read_text()]
        assert len(workers) == 2
    finally:
        search.kill()
        search.wait()
    deadline = time.time() + 10
    while time.time() < deadline and any(_alive(pid) for pid in workers):
        time.sleep(0.2)
    assert not any(_alive(pid) for pid in workers)


def test_a_search_s_workers_start_with_ctrl_c_left_to_it():
    """A Ctrl-C while a worker still imported numpy printed its traceback (an audit): it starts with SIGINT blocked."""
    with ProcessPoolExecutor(1, mp_context=QuietSpawnContext()) as pool:
        blocked = pool.submit(signal.pthread_sigmask, signal.SIG_BLOCK, []).result(timeout=60)
    assert signal.SIGINT in blocked
    assert signal.SIGINT not in signal.pthread_sigmask(signal.SIG_BLOCK, [])  # the caller's own is as it was


def test_the_printed_command_knows_an_abbreviated_option():
    """argparse takes --overw for --overwrite: the resume command kept it beside --resume, refused (an audit)."""
    from skfem_modal.cli import _next_command

    argv = ["optimize", "a.toml", "--overw", "--out", "s", "-q"]
    assert _next_command(argv, 2) == "resume it with: skfem-modal optimize a.toml --out s -q --resume"
    assert _next_command(["optimize", "--res", "-q"], 0) == "start it again with: skfem-modal optimize -q"
    assert _next_command(["optimize", "--res", "-q"], 1) == "resume it with: skfem-modal optimize --res -q"


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="needs /proc, which refuses new folders")
@pytest.mark.parametrize("command", [["run"], ["study", "--quick"], ["optimize", "--generations", "1"]])
def test_an_output_folder_nothing_can_be_written_in_is_named_before_any_work(command, capsys):
    """Found only when the folder was made: a search's after its precompute, naming only the path (an audit)."""
    assert main([*command, "--out", "/proc/skfem_modal_out", "-q"]) == 2
    err = capsys.readouterr().err
    assert f"skfem-modal {command[0]}: error: the output folder '/proc/skfem_modal_out' cannot be written: " in err
    assert "'/proc' refuses a new folder" in err


class _Counted:
    """A stand-in trial: what a rollout needs of one (``run``), cheap to pickle."""

    def __init__(self, name):
        self.name = name

    def run(self, gait):
        return {"fitness": float(len(self.name)), "trial": self.name}


def test_a_worker_unpickles_a_sent_trial_once_and_keeps_its_last_three(monkeypatch):
    """A dask worker gets the pickled trial with every task: unpickled at the first, found after; a long-lived
    worker serving many searches keeps the last 3 (it kept every one: a search's simulator is tens of MB)."""
    import pickle

    monkeypatch.setattr(rollouts, "_TRIALS", {})
    loads = []
    unpickle = pickle.loads
    monkeypatch.setattr(pickle, "loads", lambda data: loads.append(data) or unpickle(data))
    for name in ("a", "bb", "ccc", "dddd"):
        payload = pickle.dumps(_Counted(name))
        for _ in range(3):
            score = rollouts.rollout({"trial": f"key-{name}", "gait": {}, "payload": payload, "recipe": None})
            assert score["trial"] == name and score["fitness"] == len(name)
    assert len(loads) == 4  # once per trial, not per task
    assert list(rollouts._TRIALS) == ["key-bb", "key-ccc", "key-dddd"]  # the oldest went
    with pytest.raises(RuntimeError, match="holds no trial of that key and was sent no scene"):
        rollouts.rollout({"trial": "key-a", "gait": {}, "payload": None, "recipe": None})


def test_a_gait_of_the_wrong_length_a_non_whole_space_and_stop_after_are_refused(tmp_path):
    """An audit: one amplitude for four muscles was stretched to all four; GaitSpace(2.0) failed later on a
    slice; stop_after=0 died in max() of an empty sequence."""
    import copy

    from skfem_modal.optimize import GaitSpace, run_search
    from skfem_modal.rollouts import Trial
    from skfem_modal.scene import DEFAULT_SCENE

    tiny = copy.deepcopy(DEFAULT_SCENE)
    tiny["mesh"] = {"shape": "caterpillar", "params": {"nx": 12, "ny": 6}}
    tiny["subspace"] = {"weights": 3, "clusters": 4}
    trial = Trial.from_scene(tiny, steps=5, direction=[1.0, 0.0])
    gait = {"amplitude": [0.45], "period": [1.0] * 4, "phase": [0.0] * 4}
    with pytest.raises(ValueError, match=r"the gait's amplitude must have one value per muscle \(4\), got \[0.45\]"):
        trial.run(gait)
    with pytest.raises(ValueError, match="a whole number of muscles, at least one, got 2.0"):
        GaitSpace(2.0)
    for stop_after in (0, -1, 1.5):
        with pytest.raises(
            ValueError, match=f"stop_after must be a positive whole number of generations, got {stop_after}"
        ):
            run_search(tiny, tmp_path / "s", generations=2, popsize=3, steps=5, stop_after=stop_after)
    assert not (tmp_path / "s").exists()


# ------------------------------------------------------------ executors and settings of the caller's


def test_an_executor_that_is_no_executor_is_refused_before_any_work(tmp_path):
    """An audit: a dask LocalCluster passed as the executor failed after the precompute (it has no map)."""
    LocalCluster = type("LocalCluster", (), {"__module__": "distributed.deploy.local"})
    for executor, said in (
        (LocalCluster(), r"got a LocalCluster \(pass dask.distributed.Client\(cluster\)\)"),
        ("tcp://127.0.0.1:8786", r"got a str \(an address: scheduler=\)"),
    ):
        with pytest.raises(TypeError, match=said):
            search(tmp_path / "out", executor=executor)
        with pytest.raises(TypeError, match=said):
            study.run_study(study.FLOATING_CATERPILLAR, tmp_path / "study", executor=executor)
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("threads", ["x", 0, -1, True, 1.5, 10**400])
def test_blas_threads_are_a_whole_number_checked_before_any_work(tmp_path, threads):
    """An audit: blas_threads='x' was reported as the workers lost; 0 was taken; 10**400 failed in ctypes."""
    said = f"blas_threads must be None or a whole number of threads from 1 to 2147483647, got {threads!r}"
    with pytest.raises(ValueError, match=said):
        search(tmp_path / "out", blas_threads=threads)
    assert not (tmp_path / "out").exists()


def test_a_search_that_fails_in_its_first_generation_leaves_no_empty_folder(tmp_path, monkeypatch):
    from concurrent.futures import ThreadPoolExecutor

    def fail(self, gait):
        raise RuntimeError("a rollout failed")

    monkeypatch.setattr(rollouts.Trial, "run", fail)
    with ThreadPoolExecutor(1) as pool, pytest.raises(RuntimeError, match="a rollout failed"):
        search(tmp_path / "new", executor=pool)
    assert not (tmp_path / "new").exists()


def _openblas_threads():
    from skfem_modal.threads import openblas_threads

    return openblas_threads()


def _two_blas_threads():
    from skfem_modal.threads import _loaded_openblas

    for library in _loaded_openblas():
        library.set(2)


def test_the_workers_of_a_callers_pool_keep_their_blas_threads(tmp_path, uninterrupted):
    """An audit: the search left the workers of the caller's own pool at one BLAS thread for good."""
    import multiprocessing

    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("fork"), initializer=_two_blas_threads) as pool:
        before = pool.submit(_openblas_threads).result()
        result = search(tmp_path, executor=pool, blas_threads=1)
        after = pool.submit(_openblas_threads).result()
    assert before and set(before) == {2}
    assert after == before
    assert result["best"] == uninterrupted["best"]  # the rollouts themselves ran with one thread, as the pool's


def test_trial_settings_are_checked_by_name(cat_mesh):
    sim = sm.ModalMuscle.from_mesh(cat_mesh, n_muscles=2, n_weights=2, n_clusters=3)
    for settings, error, said in (
        ({"tip_limit": -0.1}, ValueError, "tip_limit must be non-negative and finite, got -0.1"),
        ({"tip_weight": float("nan")}, ValueError, "tip_weight must be non-negative and finite, got nan"),
        ({"tip_weight": "10"}, TypeError, "tip_weight must be a number, got '10'"),
        ({"direction": [np.inf, 0.0]}, ValueError, r"direction must be a non-zero, finite vector of 2 values"),
        ({"direction": "x"}, ValueError, r"direction must be a non-zero, finite vector of 2 values, got 'x'"),
    ):
        with pytest.raises(error, match=said):
            rollouts.Trial(sim, 5, **{"direction": [1.0, 0.0], **settings})
    trial = rollouts.Trial(sim, 5, [1.0, 0.0])
    with pytest.raises(ValueError, match="the gait has no 'phase'"):
        trial.run({"amplitude": [0.1, 0.1], "period": [1.0, 1.0]})


def test_a_gait_space_checks_the_lengths_it_maps():
    space = GaitSpace(2)
    with pytest.raises(ValueError, match=r"3 x 2 values \(amplitudes, periods, phases\): 5"):
        space.gait(np.zeros(5))
    with pytest.raises(ValueError, match=r"the gait's period must have one value per muscle \(2\), got \[1.0\]"):
        space.point({"amplitude": [0.1, 0.2], "period": [1.0], "phase": [0.0, 0.5]})
    with pytest.raises(ValueError, match="the gait has no 'period'"):
        space.point({"amplitude": [0.1, 0.2]})
    gait = {"amplitude": [0.1, 0.2], "period": [1.0, 1.5], "phase": [0.0, 0.5]}
    back = space.gait(space.point(gait))
    assert {key: pytest.approx(value, abs=1e-15) for key, value in gait.items()} == back
    assert space.point({"amplitude": [0.1, 0.2], "period": [1.0, 1.5], "phase": None})[4:] == pytest.approx([0, 0])


@pytest.mark.parametrize(
    "setting, value, error, said",
    [
        ("sigma0", "0.2", TypeError, "sigma0 must be a number, got '0.2'"),
        ("jitter", "0.01", TypeError, "jitter must be a number, got '0.01'"),
        ("tip_limit_degrees", "60", TypeError, "tip_limit_degrees must be a number, got '60'"),
    ],
)
def test_search_settings_given_as_text_are_refused_by_name(tmp_path, setting, value, error, said):
    with pytest.raises(error, match=said):
        search(tmp_path / "out", **{setting: value})
    assert not (tmp_path / "out").exists()


def test_a_searched_scene_searched_again_is_named_by_its_last_search(tmp_path):
    """An audit: searching best_gait.toml again named it 'crawl (best gait of ...) (best gait of ...)'."""
    search(tmp_path / "first", generations=1, popsize=2, steps=20)
    searched = tomllib.loads((tmp_path / "first" / "best_gait.toml").read_text())
    assert searched["name"].startswith(f"{TINY.get('name', 'scene')} (best gait of 1 generations: ")
    search(tmp_path / "again", data=searched, generations=1, popsize=2, steps=20)
    name = tomllib.loads((tmp_path / "again" / "best_gait.toml").read_text())["name"]
    assert name.count("(best gait of") == 1 and name.startswith(TINY.get("name", "scene") + " (best gait of 1 ")


def test_tasks_running_at_once_in_a_callers_worker_share_one_blas_limit():
    """The limit is the process's: with each task setting and lifting its own, the first task to end lifted
    it under the second, still running."""
    from skfem_modal.threads import _loaded_openblas, openblas_threads

    # two threads in every OpenBLAS (a shell of OPENBLAS_NUM_THREADS=1 would hide the limit), by OpenBLAS's own
    # setter: a threadpoolctl limit held by this thread kept other threads' limits from taking effect
    libraries = _loaded_openblas()
    counts = [library.get() for library in libraries]
    try:
        for library in libraries:
            library.set(2)
        _share_one_limit(openblas_threads())
    finally:
        for library, count in zip(libraries, counts):
            library.set(count)


def _share_one_limit(before):
    import threading

    from skfem_modal.threads import openblas_threads

    assert before and min(before) == 2, "OpenBLAS with two threads to see a limit of one"
    task = {"blas_threads": 1, "parent": -1}  # (not this process: a worker of the caller's)
    first_in, first_out, seen = threading.Event(), threading.Event(), []

    def first():
        with rollouts._task_blas_limit(task):
            first_in.set()
            first_out.wait(10)

    worker = threading.Thread(target=first)
    worker.start()
    first_in.wait(10)
    with rollouts._task_blas_limit(task):
        first_out.set()
        worker.join(10)  # the first task ended while this one runs
        seen.append(openblas_threads())
    assert seen == [[1] * len(before)] and openblas_threads() == before


def test_a_search_and_a_transfer_without_cma_name_the_extra_before_any_work(tmp_path, tiny_scene, capsys, monkeypatch):
    """A new-user trial: without the optimize extra, optimize printed its banner, then a traceback (exit 1);
    transfer called the checkpoint unreadable."""
    search(tmp_path / "done", generations=1, popsize=2, steps=20)  # a search made with cma
    monkeypatch.setitem(sys.modules, "cma", None)  # and now without it
    args = ["optimize", tiny_scene, "--generations", "1", "--out", str(tmp_path / "s")] + QUICK
    assert main(args) == 2
    out = capsys.readouterr()
    assert out.out == "" and "needs the optimize extra: pip install 'skfem_modal[optimize]'" in out.err
    assert "Traceback" not in out.err and not (tmp_path / "s").exists()
    assert main(["transfer", str(tmp_path / "done")]) == 2
    err = capsys.readouterr().err
    assert "a search checkpoint holds CMA-ES's state, which needs the optimize extra" in err


def test_review_edges_of_executors_threads_and_folders(tmp_path, monkeypatch):
    """A review: a numpy integer thread count passed the check, then broke the pool ('workers lost'); a study
    refused its executor only after removing the earlier study it was to replace; a failed search into
    a/b/c left a/ behind."""
    result = search(tmp_path / "int64", generations=1, popsize=2, steps=20, workers=1, blas_threads=np.int64(1))
    assert result["generations"] == 1
    earlier = tmp_path / "study"
    earlier.mkdir()
    for name in ("study.csv", "study.md", "study.json", "modal.csv"):
        (earlier / name).write_text("kept")
    with pytest.raises(TypeError, match="got a str"):
        study.run_study(study.FLOATING_CATERPILLAR, earlier, executor="tcp://127.0.0.1:8786", overwrite=True)
    assert sorted(p.name for p in earlier.iterdir()) == ["modal.csv", "study.csv", "study.json", "study.md"]
    from concurrent.futures import ThreadPoolExecutor

    def fail(self, gait):
        raise RuntimeError("a rollout failed")

    monkeypatch.setattr(rollouts.Trial, "run", fail)
    with ThreadPoolExecutor(1) as pool, pytest.raises(RuntimeError, match="a rollout failed"):
        search(tmp_path / "a" / "b" / "c", executor=pool)
    assert not (tmp_path / "a").exists()


def test_negative_numbers_are_values_of_any_option(capsys):
    """A review: joining after any option swallowed a flag's positional and broke '--'; and an option of two
    values took no negative number in scientific notation (``--period-range -1e3 2``: 'expected 2 arguments')."""
    from skfem_modal.cli import build_parser

    parser = build_parser()
    args = parser.parse_args(_joined_signed_values(["modes", "--young", "-1e6", "--merge", "-1e0"]))
    assert (args.young, args.merge, args.mesh) == (-1e6, True, "-1e0")  # a flag's next word stays a positional
    args = parser.parse_args(["modes", "--", "-2e0"])
    assert args.mesh == "-2e0"
    for args, said in (
        (["--period-range", "-1e3", "2"], "argument --period-range: expected a positive finite number, got '-1e3'"),
        (["--seed", "-inf"], "argument --seed: expected an integer from 0 to 4294967294, got '-inf'"),
        (["--seed", "-Infinity"], "argument --seed: expected an integer from 0 to 4294967294, got '-Infinity'"),
    ):
        with pytest.raises(SystemExit) as stopped:
            main(["optimize", *args, "--out", "never"])
        assert stopped.value.code == 2 and said in capsys.readouterr().err


def test_a_stop_during_the_precompute_says_what_there_is_to_resume(tmp_path, monkeypatch):
    """A new user's trial: Ctrl-C after the search announced itself, during its precompute, said only
    'interrupted'; now what a stop says anywhere else (nothing checkpointed, nothing to resume)."""

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(rollouts.Trial, "from_scene", interrupted)
    with pytest.raises(optimize.SearchInterrupted, match="nothing was checkpointed in .*: there is nothing to resume"):
        search(tmp_path / "s", workers=1)
    assert not (tmp_path / "s").exists()


def test_a_search_none_of_whose_gaits_move_physically_says_so_and_fails(tmp_path, capsys, monkeypatch):
    """An audit: every rollout non-finite, the search said "best: travel nan (fitness -2000) in the gait it
    started from" and exited 0; transfer then showed unphysical replays as "survives 8.00"."""
    data = copy.deepcopy(TINY)
    data["muscles"]["gait"]["amplitude"] = [1e299] * 4
    scene = tmp_path / "blows_up.toml"
    scene.write_text(scene_to_toml(data))
    out = tmp_path / "search"
    argv = ["optimize", str(scene), "--generations", "1", "--amplitude-max", "1e300", "--out", str(out), *QUICK]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # (the amplitude's own warning)
        assert main(argv) == 3
    err = capsys.readouterr().err.splitlines()
    assert err[-1] == (
        "skfem-modal optimize: no gait moved the body physically: every one of the 3 rollouts, the start gait's "
        f"included, went non-finite or tore the body apart (the motion monitor's rules); {out / 'best_gait.toml'} "
        "holds the start gait, which failed too: give the scene a gait that runs, or search smaller amplitudes "
        "(--amplitude-max)"
    )
    with open(out / "history.csv") as f:
        (row,) = list(csv.DictReader(f))
    assert float(row["best_physical"]) == 0.0 and float(row["best_fitness"]) < -100
    # transfer: a replay that is not physical shows no survival figure
    import skfem_modal.transfer as transfer

    rows = [
        {"setting": label, "elements": 1, "coordinates": 2, "clusters": 3, "iterations": 10, "mean_iterations": 9.0,
         "travel": travel, "survives": travel / 0.7, "alignment": 0.0, "max_tilt_degrees": 1.0, "seconds": 0.1,
         "physical": physical}
        for label, travel, physical in (("as searched", 0.7, False), ("full space", 5.6, False))
    ]  # fmt: skip
    replayed = {"rows": rows, "not_replayed": [], "csv": "transfer.csv", "unfinished": None}
    monkeypatch.setattr(transfer, "transfer_search", lambda *args, **kwargs: replayed)
    assert main(["transfer", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "| 5.6 | not physical |" in printed and "8.00" not in printed
    assert "the searched gait's own replay is not physical" in printed


def test_the_fitness_plot_counts_the_gait_the_search_started_from(tmp_path, monkeypatch):
    """An audit: the search returned its start gait (fitness 0.078) while the plot's best so far read -0.322."""
    import matplotlib.axes

    drawn = {}
    real = matplotlib.axes.Axes.plot

    def seen(self, *args, **kwargs):
        drawn[kwargs.get("label")] = list(args[1])
        return real(self, *args, **kwargs)

    monkeypatch.setattr(matplotlib.axes.Axes, "plot", seen)
    rows = [{"generation": g, "best_fitness": f, "mean_fitness": f - 1.0} for g, f in ((1, -0.322), (2, -0.031))]
    state = {"history": rows, "start": {"generation": 0, "best_fitness": 0.078}}
    optimize._write_plot(str(tmp_path / "fitness.png"), state, "travel")
    assert drawn["best so far"] == [0.078, 0.078, 0.078] and drawn["the gait it started from"] == [0.078]
    assert (tmp_path / "fitness.png").stat().st_size > 0


@pytest.mark.parametrize("workers, error", [(0, ValueError), (2.5, TypeError), ("2", TypeError), (True, TypeError)])
def test_workers_are_checked_before_the_search_or_the_study_says_or_does_anything(tmp_path, workers, error):
    """An audit: 0 was refused by the pool after the precompute, 2.5 and "2" by Python's own messages, True ran."""

    def announced():
        raise AssertionError("announced before its settings were checked")

    with pytest.raises(error, match="workers must be"):
        run_search(TINY, tmp_path / "search", generations=1, popsize=2, workers=workers, announce=announced)
    with pytest.raises(error, match="workers must be"):
        study.run_study(TINY, tmp_path / "study", workers=workers)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("command", ["study", "optimize"])
def test_a_scheduler_without_workers_is_named_and_leaves_no_folder(command, tmp_path, capsys, monkeypatch):
    """An audit: a search said dask's raw "No valid workers found" (exit 2), a study waited for ever, silent."""
    distributed = pytest.importorskip("distributed", reason="dask.distributed is in the distributed extra")
    monkeypatch.setattr(study, "WORKERS_JOIN_SECONDS", 1.0)
    out = tmp_path / "out"
    extra = ["--quick"] if command == "study" else ["--generations", "1", "--popsize", "3"]
    with distributed.LocalCluster(n_workers=0, processes=False, dashboard_address=None) as cluster:
        address = cluster.scheduler_address
        assert main([command, *extra, "--scheduler", address, "--out", str(out), "-q"]) == 4
    err = capsys.readouterr().err
    assert f"--scheduler {address}: the dask scheduler has no workers (none joined in 1 s)" in err
    assert not out.exists()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_a_worker_whose_parent_died_before_it_watched_for_it_ends_too(tmp_path):
    """A pool worker still importing when its search was killed took init for its parent and stayed for good
    (CI's loaded second pass): it watches the process that started it."""
    script = tmp_path / "orphan.py"
    script.write_text(
        textwrap.dedent(
            """
            import multiprocessing, os, sys, time
            from skfem_modal.interrupts import exit_with_parent

            def worker():
                time.sleep(1.5)  # still starting when its parent dies
                exit_with_parent(poll=0.1)
                time.sleep(60)

            if __name__ == "__main__":
                child = multiprocessing.get_context("spawn").Process(target=worker)
                child.start()
                print(child.pid, flush=True)
                os._exit(0)  # killed outright: nothing shuts the child down
            """
        )
    )
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=60)
    child = int(done.stdout.split()[0])
    deadline = time.time() + 30
    while time.time() < deadline and _alive(child):
        time.sleep(0.1)
    assert not _alive(child)
