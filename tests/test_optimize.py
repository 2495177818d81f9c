"""Gait search: deterministic, resumable, the same on a dask cluster as on the local pool."""

import copy
import csv
import json
import tomllib

import numpy as np
import pytest

from skfem_modal.cli import main
from skfem_modal.optimize import GaitSpace, run_search, scene_to_toml
from skfem_modal.run import run_scene
from skfem_modal.scene import DEFAULT_SCENE, Scene

pytest.importorskip("cma", reason="cma is in the optimize extra")

TINY = copy.deepcopy(DEFAULT_SCENE)
TINY["mesh"] = {"shape": "caterpillar", "params": {"nx": 24, "ny": 12}}
TINY["subspace"] = {"weights": 6, "clusters": 10}


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
    assert local["generations"] == 2 and local["rollouts"] == 8
    best = local["best"]
    assert best["fitness"] == max(h["best_fitness"] for h in local["history"])
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


def test_precompute_once_per_worker(local):
    for h in local["history"]:
        assert h["builds"] == 1  # each worker built its simulator once
        assert 1 <= len(h["workers"]) <= 2


def test_same_seed_same_result(local, tmp_path):
    again = search(tmp_path, workers=1)
    assert again["best"] == local["best"]
    assert [h["best_fitness"] for h in again["history"]] == [h["best_fitness"] for h in local["history"]]


def test_killed_and_resumed_ends_where_an_uninterrupted_search_ends(local, tmp_path):
    first = search(tmp_path, workers=1, stop_after=1)
    assert first["generations"] == 1
    resumed = search(tmp_path, workers=1, resume=True)
    assert resumed["generations"] == 2
    assert [h["best_fitness"] for h in resumed["history"]] == [h["best_fitness"] for h in local["history"]]
    assert resumed["best"] == local["best"]


@pytest.mark.slow
def test_dask_local_cluster_gives_the_local_pool_result(local, tmp_path):
    distributed = pytest.importorskip("dask.distributed", reason="dask is in the distributed extra")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True) as cluster:
        remote = search(tmp_path, scheduler=cluster.scheduler_address)
    assert remote["best"] == local["best"]
    assert [h["best_fitness"] for h in remote["history"]] == [h["best_fitness"] for h in local["history"]]
    assert all(h["builds"] == 1 for h in remote["history"])


def test_scene_toml_round_trip():
    text = scene_to_toml(TINY)
    assert tomllib.loads(text) == json.loads(json.dumps(TINY))


def test_cli_optimize(tmp_path, capsys):
    scene = tmp_path / "tiny.toml"
    scene.write_text(scene_to_toml(TINY))
    code = main(
        [
            "optimize",
            str(scene),
            "--generations",
            "1",
            "--popsize",
            "3",
            "--steps",
            "30",
            "--out",
            str(tmp_path / "out"),
            "--workers",
            "1",
            "--quiet",
        ]
    )
    assert code == 0
    assert (tmp_path / "out" / "best_gait.toml").exists()
    assert main(["optimize", str(scene), "--direction", "w", "--out", str(tmp_path / "o2")]) == 2
    assert "--direction must be x, y or z" in capsys.readouterr().err


def test_local_pool_workers_use_one_blas_thread(monkeypatch):
    import os

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
    assert result["rollouts"] == 2 * 4 * 3
    best = result["best"]
    # the best gait's own rollout is the travel reported; the fitness is the mean of its samples
    data = tomllib.loads(open(result["best_scene"]).read())
    summary = run_scene(Scene.from_dict(data), None)
    assert summary["com"]["travel"][0] == pytest.approx(best["travel"], rel=1e-9, abs=1e-12)
    assert best["travel_spread"] > 0.0
    assert best["fitness"] != pytest.approx(best["travel"], rel=1e-12)
    again = search(tmp_path / "b", workers=1, samples=3, jitter=0.02)
    assert again["best"] == best
    with pytest.raises(ValueError, match="samples or jitter"):
        search(tmp_path / "a", workers=1, samples=2, jitter=0.02, resume=True)
    with pytest.raises(ValueError, match="samples must be a positive integer"):
        search(tmp_path / "c", samples=0)
