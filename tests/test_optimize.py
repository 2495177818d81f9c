"""Gait search: deterministic, resumable, the same on a dask cluster as on the local pool."""

import copy
import csv
import json
import os
import pickle
import signal
import subprocess
import sys
import time
import tomllib

import numpy as np
import pytest

from skfem_modal.cli import _direction, _resume_command, main
from skfem_modal.optimize import GaitSpace, run_search, scene_to_toml
from skfem_modal.rollouts import Trial, body_rotation_rows
from skfem_modal.rotations import polar_rotations
from skfem_modal.run import run_scene
from skfem_modal.scene import DEFAULT_SCENE, Scene

pytest.importorskip("cma", reason="cma is in the optimize extra")

TINY = copy.deepcopy(DEFAULT_SCENE)
TINY["mesh"] = {"shape": "caterpillar", "params": {"nx": 24, "ny": 12}}
TINY["subspace"] = {"weights": 6, "clusters": 10}

# the examples' 3D creature, coarse: 408 tetrahedra, z up
CREATURE = {
    "name": "coarse creature",
    "mesh": {"shape": "creature", "params": {"cell": 0.2}},
    "subspace": {"weights": 4, "clusters": 6},
    "muscles": {"count": 3, "gait": {"amplitude": [0.4, 0.4, 0.4], "period": [1.0, 0.8, 0.6]}},
    "time": {"step": 0.01, "steps": 40},
    "gravity": {"acceleration": [0.0, 0.0, -9.8]},
    "ground": {"offset": 0.05, "model": "reference", "contacts": 20, "push_out": 1.0, "stickiness": 0.7},
}


def search(out, **kw):
    return run_search(TINY, out, generations=2, popsize=4, seed=3, steps=60, **kw)


@pytest.fixture(scope="module")
def local(tmp_path_factory):
    return search(tmp_path_factory.mktemp("local"), workers=2)


def test_gait_space_round_trip():
    space = GaitSpace(2, amplitude_max=0.8, period_min=0.5, period_max=1.5)
    gait = {"amplitude": [0.4, 0.8], "period": [0.5, 1.0], "phase": [0.25, 0.0]}
    np.testing.assert_allclose(space.point(gait), [0.5, 1.0, 0.0, 0.5, 0.25, 0.0])
    back = space.gait(space.point(gait))
    for key in gait:
        assert back[key] == pytest.approx(gait[key])
    with pytest.raises(ValueError, match="period_min < period_max"):
        GaitSpace(2, period_min=2.0, period_max=1.0)


def test_search_writes_a_playable_best_gait(local, tmp_path):
    assert local["generations"] == 2 and local["rollouts"] == 9  # the gait it starts from is scored too
    best = local["best"]
    assert local["start"]["generation"] == 0 and local["start"]["gait"] == TINY["muscles"]["gait"]
    assert best["fitness"] == max(h["best_fitness"] for h in [local["start"]] + local["history"])
    # the best gait scene file plays, and travels what the search measured
    data = tomllib.loads(open(local["best_scene"]).read())
    for key in best["gait"]:
        assert data["muscles"]["gait"][key] == pytest.approx(best["gait"][key], rel=1e-15)
    summary = run_scene(Scene.from_dict(data), None)
    assert summary["com"]["travel"][0] == pytest.approx(best["travel"], rel=1e-9, abs=1e-12)
    rows = list(csv.DictReader(open(local["history_csv"])))
    assert len(rows) == 2
    for row, h in zip(rows, local["history"]):  # plain numbers, read back exactly
        assert float(row["best_fitness"]) == h["best_fitness"] and float(row["sigma"]) == h["sigma"]
        assert float(row["best_alignment"]) == h["best_alignment"] and 0.0 <= h["best_alignment"] <= 1.0
        assert json.loads(row["best_gait"]) == h["gait"]
    assert os.path.isfile(local["plot"])


def test_a_scenes_ramp_is_searched_with_and_kept_in_the_best_gait(tmp_path):
    ramped = copy.deepcopy(TINY)
    ramped["muscles"]["gait"]["ramp"] = 0.3
    result = run_search(ramped, tmp_path, generations=1, popsize=3, seed=3, steps=60)
    best = result["best"]
    data = tomllib.loads(open(result["best_scene"]).read())
    assert data["muscles"]["gait"]["ramp"] == 0.3
    summary = run_scene(Scene.from_dict(data), None)
    assert summary["com"]["travel"][0] == pytest.approx(best["travel"], rel=1e-9, abs=1e-12)
    # the ramp acted: the same gait from full stroke at once goes elsewhere
    trial = Trial.from_scene(TINY, steps=60, direction=[1.0, 0.0])
    assert trial.ramp == 0.0
    assert abs(trial.run(best["gait"])["travel"] - best["travel"]) > 1e-3 * abs(best["travel"])
    # a gait's own ramp goes before its trial's
    assert trial.run({**best["gait"], "ramp": 0.3})["travel"] == pytest.approx(best["travel"], rel=1e-12)


def test_a_replay_rolls_a_gait_out_with_its_scenes_ramp():
    """An audit: replay() rolled a searched gait (no ramp of its own) out at full stroke from the start."""
    from skfem_modal.transfer import replay

    ramped = copy.deepcopy(TINY)
    ramped["muscles"]["gait"]["ramp"] = 0.3
    gait = {key: TINY["muscles"]["gait"][key] for key in ("amplitude", "period", "phase")}
    rows = replay(ramped, gait, steps=30, direction=[1.0, 0.0], full_space_limit=0)
    searched = Trial.from_scene(ramped, steps=30, direction=[1.0, 0.0]).run(gait)["travel"]
    assert rows[0]["setting"] == "as searched" and rows[0]["travel"] == pytest.approx(searched, rel=1e-12)
    plain = Trial.from_scene(TINY, steps=30, direction=[1.0, 0.0]).run(gait)["travel"]
    assert abs(plain - searched) > 1e-3 * abs(searched)


def test_precompute_built_once_and_sent_to_each_worker(local):
    for h in local["history"]:
        assert h["built"] == 0  # no worker built a simulator: the search's own was sent
        assert h["received"] == 1  # and each worker unpickled it once
        assert 1 <= len(h["workers"]) <= 2


def test_same_seed_same_result(local, tmp_path):
    again = search(tmp_path, workers=1)
    assert again["best"] == local["best"]
    assert [h["best_fitness"] for h in again["history"]] == [h["best_fitness"] for h in local["history"]]


def test_killed_and_resumed_ends_where_an_uninterrupted_search_ends(local, tmp_path, capsys):
    first = search(tmp_path, workers=1, stop_after=1)
    assert first["generations"] == 1 and first["rollouts"] == 5
    assert len(list(csv.DictReader(open(first["history_csv"])))) == 1  # written after each generation
    resumed = search(tmp_path, workers=1, resume=True, progress=True)
    assert resumed["generations"] == 2
    assert resumed["rollouts"] == 9  # counted over the whole search
    assert [h["best_fitness"] for h in resumed["history"]] == [h["best_fitness"] for h in local["history"]]
    assert resumed["best"] == local["best"]
    # the progress count went on from the checkpoint's generation
    err = capsys.readouterr().err
    assert "1/2" in err and "0/2" not in err


def test_resuming_with_fewer_generations_than_done_says_how_many_it_has(tmp_path, capsys, monkeypatch):
    search(tmp_path, workers=1)
    before = {name: (tmp_path / name).read_bytes() for name in ("checkpoint.pkl", "history.csv", "best_gait.toml")}
    assert before["best_gait.toml"].endswith(b"\n") and not before["best_gait.toml"].endswith(b"\n\n")
    from skfem_modal import optimize

    monkeypatch.setattr(optimize.Trial, "from_scene", lambda *a, **k: pytest.fail("the precompute started"))
    with pytest.raises(ValueError, match=r"already has 2 generations, more than the 1 asked .*more than 2 to extend"):
        run_search(TINY, tmp_path, generations=1, popsize=4, seed=3, steps=60, resume=True)
    assert {name: (tmp_path / name).read_bytes() for name in before} == before  # nothing touched
    monkeypatch.undo()
    scene, out = tmp_path / "tiny.toml", tmp_path / "cli"
    scene.write_text(optimize.scene_to_toml(TINY))
    args = ["optimize", str(scene), "--popsize", "4", "--seed", "3", "--steps", "60", "--out", str(out), "-q"]
    assert main([*args, "--generations", "2"]) == 0
    assert main([*args, "--generations", "1", "--resume"]) == 2
    assert f"the search in {out} already has 2 generations, more than the 1 asked" in capsys.readouterr().err


def test_an_existing_search_is_never_replaced_silently(local, tmp_path):
    search(tmp_path, workers=1, stop_after=1)
    before = open(tmp_path / "checkpoint.pkl", "rb").read()
    with pytest.raises(FileExistsError, match="--resume .* --overwrite"):
        search(tmp_path, workers=1)
    assert open(tmp_path / "checkpoint.pkl", "rb").read() == before
    # settings that would change the search are refused by name
    with pytest.raises(ValueError, match=r"popsize \(--popsize\): 4 then, 5 now"):
        run_search(TINY, tmp_path, generations=2, popsize=5, seed=3, steps=60, resume=True)
    with pytest.raises(ValueError, match="objective"):
        search(tmp_path, resume=True, objective="aligned")
    # as given, not as kept (radians, a list of the box's bounds; an audit)
    with pytest.raises(ValueError, match=r"tip_limit_degrees \(--tip-limit\): 60\.0 then, 50\.0 now\)"):
        search(tmp_path, resume=True, tip_limit_degrees=50.0)
    box = GaitSpace(4, amplitude_max=0.5)
    with pytest.raises(ValueError, match=r"\(amplitude_max \(--amplitude-max\): 1\.0 then, 0\.5 now\)"):
        search(tmp_path, resume=True, space=box)
    box = GaitSpace(4, period_min=0.4)
    with pytest.raises(ValueError, match=r"\(period range \(--period-range\): \[0\.3, 2\.0\] then, \[0\.4, 2\.0\] now"):
        search(tmp_path, resume=True, space=box)
    # a scene key changed is named (it said two hashes); its name alone may change
    stepped = copy.deepcopy(TINY)
    stepped["time"] = {**stepped.get("time", {}), "step": 0.02}
    with pytest.raises(ValueError, match=r"\(scene key time.step: 0.01 then, 0.02 now\)"):
        run_search(stepped, tmp_path, generations=2, popsize=4, seed=3, steps=60, resume=True)
    renamed = {**copy.deepcopy(TINY), "name": "the same crawl, renamed"}
    assert run_search(renamed, tmp_path, generations=2, popsize=4, seed=3, steps=60, resume=True)["generations"] == 2
    with pytest.raises(ValueError, match="exclude each other"):
        search(tmp_path, resume=True, overwrite=True)
    with pytest.raises(FileNotFoundError, match="no search to resume"):
        search(tmp_path / "empty", resume=True)
    with pytest.raises(ValueError, match="steps must be a positive integer"):
        run_search(TINY, tmp_path / "bad", generations=1, popsize=2, steps=-3)
    with pytest.raises(ValueError, match="tip_weight must be non-negative"):
        search(tmp_path / "bad", tip_weight=-1.0)
    assert not (tmp_path / "bad").exists()  # refused before anything was written
    # --overwrite starts again: the same as a search in an empty folder
    again = search(tmp_path, workers=1, overwrite=True)
    assert again["generations"] == 2 and again["rollouts"] == 9
    assert again["best"] == local["best"]


@pytest.mark.slow
def test_dask_local_cluster_gives_the_local_pool_result(local, tmp_path):
    distributed = pytest.importorskip("dask.distributed", reason="dask is in the distributed extra")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True) as cluster:
        remote = search(tmp_path / "a", scheduler=cluster.scheduler_address)
        with distributed.Client(cluster) as client:  # an executor of the caller's: the trial is scattered too
            again = search(tmp_path / "b", executor=client.get_executor())
    for count, result in enumerate((remote, again), start=1):
        assert result["best"] == local["best"]
        assert [h["best_fitness"] for h in result["history"]] == [h["best_fitness"] for h in local["history"]]
        # each worker received each search's simulator once, and built none
        assert [(h["built"], h["received"]) for h in result["history"]] == [(0, count)] * 2, result["history"]


def test_any_executor_builds_the_simulator_once_per_worker(local, tmp_path):
    from concurrent.futures import ThreadPoolExecutor

    from skfem_modal import rollouts

    before = rollouts._COUNTS["built"]
    with ThreadPoolExecutor(1) as pool:  # not dask's: its worker (here, this process) builds from the scene, once
        result = search(tmp_path, executor=pool)
    assert result["best"] == local["best"]
    assert [h["built"] - before for h in result["history"]] == [2, 2]  # the search's own build, and the worker's


def test_scene_toml_round_trip():
    text = scene_to_toml(TINY)
    assert tomllib.loads(text) == json.loads(json.dumps(TINY))
    # keys that are not bare are quoted (a space made invalid TOML, a dot a table); numpy's bools; None left out
    odd = {"name": "x", "a b": 1, "a.b": np.bool_(True), "mesh": {"params": {"nx": 3, "ny": None}}, "g": {"s.t": {}}}
    expected = {"name": "x", "a b": 1, "a.b": True, "mesh": {"params": {"nx": 3}}, "g": {"s.t": {}}}
    assert tomllib.loads(scene_to_toml(odd)) == expected
    with pytest.raises(TypeError, match="cannot write NoneType to TOML"):
        scene_to_toml({"muscles": {"signs": [1, None]}})


def test_a_converged_search_stops_and_says_so(tmp_path, capsys):
    """A long search's step size fell until its candidates were NaN, and it ended as bad input (exit 2)."""
    from skfem_modal.transfer import transfer_search

    result = run_search(TINY, tmp_path, generations=5, popsize=4, seed=3, steps=20, sigma0=1e-12, workers=1)
    assert result["converged"] and result["generations"] == 1 and result["history"][0]["sigma"] < 1e-11
    assert transfer_search(tmp_path, full_space_limit=0)["unfinished"] is None  # finished, not stopped
    scene = tmp_path / "tiny.toml"
    scene.write_text(scene_to_toml(TINY))
    argv = ["optimize", str(scene), "--out", str(tmp_path / "cli"), "--generations", "3", "--popsize", "4"]
    assert main(argv + ["--steps", "20", "--sigma0", "1e-12", "--workers", "1"]) == 0
    assert "converged after 1 of 3 generations: CMA-ES's steps fell below 1e-11" in capsys.readouterr().out


def test_cli_optimize(tmp_path, capsys):
    scene = tmp_path / "tiny.toml"
    scene.write_text(scene_to_toml(TINY))
    args = ["optimize", str(scene), "--generations", "1", "--popsize", "3", "--steps", "30"]
    args += ["--out", str(tmp_path / "out"), "--workers", "1", "--quiet"]
    assert main(args) == 0
    assert (tmp_path / "out" / "best_gait.toml").exists()
    # a second run into the same folder is refused, --overwrite starts again
    assert main(args) == 2
    assert "holds a search" in capsys.readouterr().err
    assert main(args + ["--overwrite"]) == 0
    with pytest.raises(SystemExit) as usage:  # argparse: not both
        main(args + ["--overwrite", "--resume"])
    assert usage.value.code == 2 and "not allowed with argument --overwrite" in capsys.readouterr().err
    assert main(["optimize", str(scene), "--direction", "w", "--out", str(tmp_path / "o2")]) == 2
    assert "--direction must be x, y or z" in capsys.readouterr().err
    assert main(["optimize", str(scene), "--direction", "0,0,1", "--out", str(tmp_path / "o2")]) == 2
    assert "2 comma-separated numbers" in capsys.readouterr().err


def test_directions_any_axis_or_vector():
    assert _direction("-z", 3).tolist() == [0.0, 0.0, -1.0]
    assert _direction("1, 0, -1", 3).tolist() == [1.0, 0.0, -1.0]
    with pytest.raises(ValueError, match="not an axis of this 2D scene"):
        _direction("z", 2)
    with pytest.raises(ValueError, match="not all zero"):
        _direction("0,0", 2)
    assert _resume_command(["optimize", "a b.toml", "--overwrite", "--out", "s"]) == (
        "skfem-modal optimize 'a b.toml' --out s --resume"
    )


def test_local_pool_workers_use_one_blas_thread(monkeypatch):
    from skfem_modal.study import make_executor

    monkeypatch.setenv("OMP_NUM_THREADS", "4")
    monkeypatch.delenv("MKL_NUM_THREADS", raising=False)
    pool, close = make_executor(1)
    try:
        assert pool.submit(os.getenv, "OMP_NUM_THREADS").result() == "1"
        assert pool.submit(os.getenv, "MKL_NUM_THREADS").result() == "1"
    finally:
        close()
    assert os.environ["OMP_NUM_THREADS"] == "4" and "MKL_NUM_THREADS" not in os.environ


def test_samples_average_jittered_copies(tmp_path):
    result = search(tmp_path / "a", workers=1, samples=3, jitter=0.02)
    assert result["rollouts"] == 3 + 2 * 4 * 3  # the gait it starts from, then two generations
    best = result["best"]
    # the best gait's own rollout is the travel reported; the fitness is the mean of its samples
    data = tomllib.loads(open(result["best_scene"]).read())
    summary = run_scene(Scene.from_dict(data), None)
    assert summary["com"]["travel"][0] == pytest.approx(best["travel"], rel=1e-9, abs=1e-12)
    assert best["travel_spread"] > 0.0
    assert best["fitness"] != pytest.approx(best["travel"], rel=1e-12)
    again = search(tmp_path / "b", workers=1, samples=3, jitter=0.02)
    assert again["best"] == best
    with pytest.raises(ValueError, match=r"samples \(--samples\): 3 then, 2 now"):
        search(tmp_path / "a", workers=1, samples=2, jitter=0.02, resume=True)
    with pytest.raises(ValueError, match="samples must be a positive integer"):
        search(tmp_path / "c", samples=0)


# ---------------------------------------------------------------- scoring


def _rotation(axis, angle):
    """The rotation by ``angle`` about a unit ``axis`` (Rodrigues)."""
    k = np.asarray(axis, float)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


@pytest.fixture(scope="module")
def creature_sim():
    return Scene.from_dict(CREATURE).build()


def test_body_rotation_is_read_off_the_state_exactly(creature_sim):
    sim = creature_sim
    R = _rotation([0.36, 0.48, 0.8], 0.7)
    X = sim.mesh.p.T
    z = sim.coordinates((X - X.mean(0)) @ R.T + [0.3, -0.2, 0.5])  # the basis holds every affine map
    for rows, state in ((body_rotation_rows(sim), z), (body_rotation_rows(_full_space(sim)), sim.positions(z))):
        found = polar_rotations((rows @ np.ravel(state)).reshape(3, 3))
        np.testing.assert_allclose(found, R, atol=1e-10)


def _full_space(sim):
    from skfem_modal.reference import FullSpaceSimulator

    return FullSpaceSimulator(sim.mesh, sim.D, mu=1e5, gamma=1e5, rho=1e3, h=0.01)


def test_scores_of_a_turn_and_a_roll(creature_sim):
    """Alignment is the worst cosine of the forward axis's turn; the tilt penalty grows past the limit."""
    sim = creature_sim
    rest = body_rotation_rows(sim) @ sim.rest_state()[0]
    trial = Trial(sim, 10, [1.0, 0.0, 0.0], objective="aligned")
    frames = lambda R: np.array([rest, (R @ rest.reshape(3, 3)).ravel(), rest])  # noqa: E731
    yaw = trial.score(np.array([0.8, 0.1, 0.0]), frames(_rotation([0, 0, 1], np.radians(30))))
    assert yaw["alignment"] == pytest.approx(np.cos(np.radians(30)), rel=1e-12)
    assert yaw["max_tilt"] == pytest.approx(0.0, abs=1e-7) and yaw["penalty"] == 0.0
    assert yaw["fitness"] == pytest.approx(0.8 * np.cos(np.radians(30)), rel=1e-12)
    roll = trial.score(np.array([0.8, 0.0, 0.0]), frames(_rotation([1, 0, 0], np.radians(70))))
    assert roll["alignment"] == pytest.approx(1.0, rel=1e-12)  # rolling about the forward axis keeps it aligned
    assert roll["max_tilt"] == pytest.approx(np.radians(70), rel=1e-9)
    size = 2.0  # the creature's length
    assert roll["penalty"] == pytest.approx(10.0 * size * 10.0 / 180.0, rel=1e-9)
    assert roll["fitness"] == pytest.approx(0.8 - roll["penalty"], rel=1e-12)
    back = trial.score(np.array([-0.5, 0.0, 0.0]), frames(_rotation([0, 0, 1], np.radians(120))))
    assert back["alignment"] == 0.0 and back["fitness"] == pytest.approx(-0.5)  # backward travel is not scaled
    travel = Trial(sim, 10, [1.0, 0.0, 0.0]).score(np.array([0.8, 0.1, 0.0]), frames(np.eye(3)))
    assert travel["fitness"] == pytest.approx(0.8)


def test_a_3d_search_along_any_direction_replays(tmp_path):
    """The paper's objective on a 3D creature, towards -y: the best gait's scene replays its travel."""
    result = run_search(
        CREATURE, tmp_path, generations=2, popsize=3, seed=1, direction=[0.0, -1.0, 0.0], objective="aligned"
    )
    best = result["best"]
    assert 0.0 < best["alignment"] <= 1.0
    summary = run_scene(Scene.from_dict(tomllib.loads(open(result["best_scene"]).read())), None)
    assert -summary["com"]["travel"][1] == pytest.approx(best["travel"], rel=1e-9, abs=1e-12)
    gain = best["travel"] * best["alignment"] if best["travel"] > 0 else best["travel"]
    assert best["fitness"] <= gain + 1e-15
    if best["max_tilt_degrees"] <= 60.0:  # no tipping penalty
        assert best["fitness"] == pytest.approx(gain, rel=1e-12)


@pytest.mark.slow
def test_ctrl_c_leaves_a_checkpoint_and_says_how_to_resume(tmp_path):
    """Ctrl-C (SIGINT to the whole process group, as a terminal sends it) on the default install's code path."""
    scene = tmp_path / "tiny.toml"
    scene.write_text(scene_to_toml(TINY))
    out = tmp_path / "out"
    args = ["optimize", str(scene), "--generations", "200", "--popsize", "4", "--steps", "60", "--seed", "3"]
    args += ["--out", str(out), "--workers", "2"]
    env = {**os.environ, "SKFEM_MODAL_NUMBA": "0", "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "skfem_modal.cli", *args],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    deadline = time.time() + 120
    while time.time() < deadline and not (out / "history.csv").exists():
        time.sleep(0.2)
    time.sleep(0.5)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "Traceback" not in err  # the workers ignore SIGINT; the search stops them
    assert f"resume it with: skfem-modal {' '.join(args)} --resume" in err
    with open(out / "checkpoint.pkl", "rb") as f:
        state = pickle.load(f)
    done = state["generation"]
    rows = list(csv.DictReader(open(out / "history.csv")))
    assert 1 <= done < 200 and len(rows) == done  # the files agree with the checkpoint
    best_name = tomllib.loads(open(out / "best_gait.toml").read())["name"]
    assert f"best gait of {done} generations" in best_name
    # resuming ends where an uninterrupted search ends (the same environment: no numba)
    check = (
        "import sys; from skfem_modal.optimize import run_search; import tomllib;"
        "d = tomllib.load(open(sys.argv[1], 'rb'));"
        "r = run_search(d, sys.argv[2], generations=int(sys.argv[3]), popsize=4, seed=3, steps=60,"
        " direction=[1.0, 0.0], resume=sys.argv[4] == '1', base_dir=sys.argv[5]);"
        "print(repr([h['best_fitness'] for h in r['history']]))"
    )
    runs = [
        subprocess.run(
            [sys.executable, "-c", check, str(scene), str(folder), str(done + 1), flag, str(tmp_path)],
            env=env,
            capture_output=True,
            text=True,
            check=True,
        ).stdout
        for folder, flag in ((out, "1"), (tmp_path / "fresh", "0"))
    ]
    assert runs[0] == runs[1] and len(eval(runs[0])) == done + 1


def test_a_rollout_does_not_depend_on_the_rollouts_before(creature_sim):
    """Each rollout starts as a new simulator (warm starts forgotten): bit for bit the same on any worker."""
    trial = Trial(creature_sim, 40, [1.0, 0.0, 0.0])
    gaits = [{"amplitude": [a, 0.5, 0.3], "period": [0.5, 0.7, 0.9], "phase": [0.0, 0.3, 0.6]} for a in (0.6, 0.2)]
    first = trial.run(gaits[0])
    trial.run(gaits[1])
    assert trial.run(gaits[0]) == first
    fresh = Trial(Scene.from_dict(CREATURE).build(), 40, [1.0, 0.0, 0.0])
    assert fresh.run(gaits[0]) == first


# ---------------------------------------------------------------- transfer


def test_gait_transfer_replays_up_the_ladder(tmp_path, capsys):
    from skfem_modal.transfer import LADDER, transfer_search

    found = run_search(CREATURE, tmp_path, generations=1, popsize=3, seed=2, objective="aligned")
    result = transfer_search(tmp_path)
    rows = {r["setting"]: r for r in result["rows"]}
    assert list(rows)[: len(LADDER)] == [label for label, _ in LADDER]
    searched = rows["as searched"]
    assert searched["travel"] == found["best"]["travel"] and searched["survives"] == 1.0  # bit for bit
    assert (searched["elements"], searched["clusters"], searched["iterations"]) == (408, 6, 10)
    assert rows["clusters x4, iterations x5"]["clusters"] == 24 and rows["iterations x5"]["iterations"] == 50
    assert rows["weights x2, clusters x4, iterations x5"]["coordinates"] == 2 * searched["coordinates"]
    full = rows["full space"]
    assert (full["elements"], full["coordinates"], full["clusters"]) == (408, 182 * 3, 408)
    half = rows["half resolution, full space"]
    assert half["elements"] < 408 and half["space"] == "full"
    for row in rows.values():
        assert np.isfinite(row["travel"]) and row["survives"] == pytest.approx(row["travel"] / searched["travel"])
    # the full-space replay is the reference simulator's own run of the gait
    scene = Scene.from_dict(tomllib.loads(open(found["best_scene"]).read()))
    direct = Trial(scene.build_reference(rtol=1e-8, max_iter=2000), 40, [1.0, 0.0, 0.0], objective="aligned")
    assert direct.run(found["best"]["gait"])["travel"] == full["travel"]
    written = list(csv.DictReader(open(result["csv"])))
    assert [r["setting"] for r in written] == list(rows) and float(written[-1]["travel"]) == half["travel"]
    assert main(["transfer", str(tmp_path), "--full-space-limit", "100"]) == 0
    out = capsys.readouterr().out
    assert "| as searched | 408 |" in out and "| full space |" not in out  # over the limit: skipped, and said
    assert "full space: not replayed, 408 elements, more than the full-space limit 100 (--full-space-limit)" in out
    assert ("| half resolution, full space |" in out) == (half["elements"] <= 100)
    # the half-resolution copy's full space too, once it is over the limit (it ran whatever the limit)
    assert main(["transfer", str(tmp_path), "--full-space-limit", "1"]) == 0
    out = capsys.readouterr().out
    assert "| half resolution, as searched |" in out and "| full space |" not in out
    assert "| half resolution, full space |" not in out
    assert (
        f"half resolution, full space: not replayed, {half['elements']} elements, more than the full-space limit 1"
        in out
    )


def test_transfer_says_when_the_search_stopped_before_its_generations(tmp_path, capsys):
    """An audit: a search stopped after 3 of 14 generations was replayed without a word."""
    from skfem_modal.transfer import transfer_search

    run_search(CREATURE, tmp_path, generations=2, popsize=3, seed=2, objective="aligned", stop_after=1)
    result = transfer_search(tmp_path, full_space_limit=0)
    assert result["unfinished"].startswith("the search stopped after 1 of its 2 generations: this is its best so far")
    assert main(["transfer", str(tmp_path), "--full-space-limit", "1", "-q"]) == 0
    assert "skfem-modal transfer: warning: the search stopped after 1 of its 2 generations" in capsys.readouterr().err
    run_search(CREATURE, tmp_path, generations=2, popsize=3, seed=2, objective="aligned", resume=True)
    assert transfer_search(tmp_path, full_space_limit=0)["unfinished"] is None


def test_a_scene_without_a_ground_is_no_search_for_travel(tmp_path):
    # floating, a gait moves the centre of mass by round-off: the search ranked it, transfer divided it
    from skfem_modal.transfer import replay

    floating = {k: v for k, v in TINY.items() if k not in ("ground", "gravity")}
    with pytest.raises(ValueError, match="the scene has no ground and no pins: no gait can carry the body anywhere"):
        run_search(floating, tmp_path / "search", generations=1, popsize=3)
    assert not (tmp_path / "search").exists()
    with pytest.raises(ValueError, match="the searched scene has no ground and no pins"):
        replay(floating, {"amplitude": [0.1] * 4, "period": [1.0] * 4, "phase": [0.0] * 4}, steps=5, direction=[1, 0])


def test_a_resumed_search_is_the_same_scene_by_meaning_and_by_its_files(tmp_path):
    """An audit: a mesh file replaced under its name was resumed (two bodies in one search), and a default
    written out (ground.model) was refused as a change. The fingerprint is the validated scene and the
    contents of the files it names."""
    import meshio

    from skfem_modal import caterpillar
    from skfem_modal.optimize import scene_fingerprint
    from skfem_modal.scene import Scene

    body = tmp_path / "body.vtu"
    meshio.write(body, meshio.Mesh(caterpillar(nx=24, ny=12).p.T, [("triangle", caterpillar(nx=24, ny=12).t.T)]))
    data = {**copy.deepcopy(TINY), "mesh": {"file": str(body)}}
    before = scene_fingerprint(Scene.from_dict(data))
    written_out = copy.deepcopy(data)
    written_out["subspace"] = {**written_out["subspace"], "seed": 0}  # the default, written out
    assert scene_fingerprint(Scene.from_dict(written_out)) == before
    out = tmp_path / "search"
    run_search(data, out, generations=1, popsize=2, seed=3, steps=20, workers=1)
    run_search(written_out, out, generations=1, popsize=2, seed=3, steps=20, workers=1, resume=True)  # the same
    meshio.write(body, meshio.Mesh(caterpillar(nx=20, ny=10).p.T, [("triangle", caterpillar(nx=20, ny=10).t.T)]))
    after = scene_fingerprint(Scene.from_dict(data))
    assert after["contents"]["mesh.file"] != before["contents"]["mesh.file"] and after["mesh"] == before["mesh"]
    with pytest.raises(ValueError, match=r"scene key contents\.mesh\.file: '[0-9a-f]{64}' then, '[0-9a-f]{64}' now"):
        run_search(data, out, generations=2, popsize=2, seed=3, steps=20, workers=1, resume=True)


def test_a_resumed_search_in_a_new_process_says_none_of_cma_s_own_warnings(tmp_path, recwarn):
    """cma keeps its verbosity (-9 here) in a module global: a resumed search of 2 candidates in a new process
    printed "1 special injected samples with popsize 2, popsize 3 will be used" (and used 2; an audit)."""
    import cma.utilities.utils as cma_utils

    out = tmp_path / "search"
    run_search(copy.deepcopy(TINY), out, generations=1, popsize=2, seed=3, steps=10, workers=1)
    made, cma_utils.global_verbosity = cma_utils.global_verbosity, 1  # as a new process has it
    try:
        run_search(copy.deepcopy(TINY), out, generations=2, popsize=2, seed=3, steps=10, workers=1, resume=True)
    finally:
        cma_utils.global_verbosity = made
    assert [str(w.message) for w in recwarn if "cma" in w.filename] == []


@pytest.mark.slow
def test_rollouts_go_on_when_dask_loses_the_scattered_trial():
    """An audit: one of two workers killed stopped a search (1 in 4 tries): dask lost the scattered trial
    with it. Here every worker is killed (their nannies start new ones, which hold nothing): the trial is
    scattered again and the rollouts give what they gave before."""
    distributed = pytest.importorskip("dask.distributed", reason="dask is in the distributed extra")
    from skfem_modal.rollouts import Rollouts

    trial = Trial(Scene.from_dict(TINY).build(), 30, [1.0, 0.0])
    gaits = [{"amplitude": [a, 0.3, 0.2, 0.1], "period": [1.0, 0.8, 0.6, 0.9], "phase": [0.0] * 4} for a in (0.2, 0.5)]
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True) as cluster:
        with distributed.Client(cluster) as client, Rollouts(trial, scheduler=cluster.scheduler_address) as rollouts:
            first = rollouts.map(gaits)
            killed = set(client.run(os.getpid).values())
            for pid in killed:
                os.kill(pid, signal.SIGKILL)
            deadline = time.time() + 60
            while time.time() < deadline:  # the nannies' new workers, none of them the killed
                workers = client.scheduler_info()["workers"]
                if len(workers) == 2 and killed.isdisjoint(w.get("pid") for w in workers.values()):
                    break
                time.sleep(0.2)
            again = rollouts.map(gaits)
    scores = [{k: v for k, v in score.items() if k not in ("pid", "received", "built")} for score in first]
    assert [{k: v for k, v in score.items() if k not in ("pid", "received", "built")} for score in again] == scores
    assert killed.isdisjoint(score["pid"] for score in again)  # the new workers ran them


@pytest.mark.slow
def test_a_dask_client_itself_serves_as_the_executor(local, tmp_path):
    """An audit: ``executor=Client(processes=False)`` ran every rollout, then failed ('Future' object is not
    subscriptable): a client's own map gives futures."""
    distributed = pytest.importorskip("dask.distributed", reason="dask is in the distributed extra")
    with distributed.Client(processes=False, n_workers=1, threads_per_worker=1, dashboard_address=None) as client:
        result = search(tmp_path, executor=client)
    assert result["best"] == local["best"]


def test_rollouts_name_gaits_that_are_no_list_of_gaits():
    """(A dict gave "string indices must be integers" from inside a task.)"""
    from skfem_modal.rollouts import Rollouts

    trial = Trial.from_scene(TINY, steps=5, direction=[1.0, 0.0])
    with Rollouts(trial, workers=1) as rollouts:
        for bad in (TINY["muscles"]["gait"], ["gait"]):
            with pytest.raises(TypeError, match="gaits must be a list of gait dicts"):
                rollouts.map(bad)
        (score,) = rollouts.map([TINY["muscles"]["gait"]])
    assert score["finite"] and np.isfinite(score["travel"])


def test_a_local_pool_reads_the_trial_from_a_file_not_its_start_up_pipe(monkeypatch):
    """An audit: the pickled simulator went to each new worker down its start-up pipe, which the search writes
    while holding the other end: a worker killed as it started left the search blocked there, Ctrl-C held."""
    import skfem_modal.rollouts as rollouts_module
    from skfem_modal.rollouts import Rollouts

    made = []
    real = rollouts_module.make_executor

    def seen(*args, **kwargs):
        made.append(kwargs["initargs"])
        return real(*args, **kwargs)

    monkeypatch.setattr(rollouts_module, "make_executor", seen)
    trial = Trial.from_scene(TINY, steps=5, direction=[1.0, 0.0])
    with Rollouts(trial, workers=1) as rollouts:
        (initargs,) = made
        assert len(pickle.dumps(initargs)) < 4096  # far below a pipe's 64 kB: the write cannot wait on the worker
        path = initargs[1]
        assert os.path.getsize(path) > 100_000  # the simulator is there
        (score,) = rollouts.map([TINY["muscles"]["gait"]])
    assert score["finite"] and not os.path.exists(path)  # removed with the pool
