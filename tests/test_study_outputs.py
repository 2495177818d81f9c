"""A study's folder is its own (refused, replaced or kept apart from a run), and its rows are settings that applied."""

import json
import os

import pytest

from skfem_modal import study
from skfem_modal.cli import main
from skfem_modal.outputs import earlier_study

TINY = dict(
    steps=10,
    weights=[4],
    clusters=[8],
    iterations=[3],
    rtol=[],
    warm=[3],
    etol=[],
    warm_clusters=[],
    acceleration=[("anderson", 3)],
    warm_grid=[(4, 8, "weights", 3)],
    resolution=[1.0],
    grid=[],
    modal=[(20, 1)],
    timing_rounds=1,
)
SMALL = {"shape": "caterpillar", "params": {"nx": 16, "ny": 8}}
FLOATING = dict(study.FLOATING_CATERPILLAR, mesh=SMALL)
GROUND = {"gravity": {"acceleration": [0.0, -9.8]}, "ground": {"offset": 0.05}}


@pytest.fixture
def tiny(monkeypatch):
    monkeypatch.setitem(study.PRESETS, "tiny", TINY)
    monkeypatch.setitem(study.PRESETS, "quick", TINY)  # the command's --quick, made fast


@pytest.mark.parametrize(
    "extra, labels, left_out",
    [
        (
            {},
            ["base", "weights=4", "clusters=8", "iterations=3", "warm,iterations=3", "warm,anderson,iterations=3",
             "warm,iterations=3,weights=4,clusters=8"],
            {},
        ),
        (
            {**GROUND, "ground": {**GROUND["ground"], "model": "coulomb"}},
            ["base", "weights=4", "clusters=8", "iterations=3", "warm,iterations=3",
             "warm,iterations=3,weights=4,clusters=8"],
            {"acceleration": "Anderson and Newton iterations have no effect under ground contact"},
        ),
        (
            {**GROUND, "ground": {**GROUND["ground"], "model": "reference"}},
            ["base", "weights=4", "clusters=8", "iterations=3", "iterations=3,weights=4,clusters=8"],
            {
                "acceleration": "Anderson and Newton iterations have no effect under ground contact",
                "warm_start": "a warm start has no effect under the reference contact",
            },
        ),
    ],
)  # fmt: skip
def test_a_study_runs_only_settings_that_apply_to_its_scene(tmp_path, tiny, extra, labels, left_out):
    report = study.run_study({**FLOATING, **extra}, tmp_path, preset="tiny")
    assert [r["label"] for r in report["rows"]] == labels
    assert report["left_out"] == left_out
    assert {r["acceleration"] for r in report["rows"]} <= ({"none", "anderson"} if not extra else {"none"})
    if "warm_start" in left_out:
        assert not any(r["warm_start"] for r in report["rows"])
    text = (tmp_path / "study.md").read_text()
    assert ("Not run for this scene: " + "; ".join(left_out.values())) in text if left_out else "Not run" not in text
    # on the ground, the rows are single runs of a branching motion: said beside the recommendation (an audit)
    chaotic = "a row can stand far from its sweep's trend"
    assert (
        (chaotic in report["recommendation"][-1])
        if extra
        else not any(chaotic in line for line in report["recommendation"])
    )
    assert (chaotic in text) == bool(extra)
    # on the ground the reference's projection onto the subspace can go through it: no bound (an audit: "the
    # subspace alone allows 1.2 %" on the creature's crawl, every row 22 to 73 %)
    bound = any("(the subspace alone allows" in line for line in report["recommendation"])
    not_bound = any("% off, not a bound here: the ground or the pins" in line for line in report["recommendation"])
    assert (bound, not_bound) == ((False, True) if extra else (True, False))
    meta = json.loads((tmp_path / "study.json").read_text())["meta"]
    assert meta["left_out"] == left_out
    # the reference contact's rule goes round between sets of held points: its full-space reference never
    # settles (every step of this one stopped at 5000 iterations, its nodes moving 1.2 % of the size at the
    # last), and the report says so first; the others settle (the Coulomb contact's in 39 iterations a step).
    # An audit: the study called it "iterated to 1e-10" and reported errors against it.
    unsettled = meta["references"]["1.0"]["unsettled_steps"]
    said = "The full-space reference did not settle in"
    if "warm_start" in left_out:
        assert unsettled == 10 and meta["references"]["1.0"]["unsettled_change"] > 0.01
        # each resolution's own steps (the two had been added up: "112 steps" of a study of 100; an audit)
        assert report["recommendation"][0].startswith(f"{said} 10 of its 10 steps at resolution 1")
        assert ": they stopped at 5000 iterations" in report["recommendation"][0]
        assert "10 steps did not settle (stopped at 5000 iterations" in text
    else:
        assert unsettled == 0 and not any(said in line for line in report["recommendation"])
        assert "did not settle" not in text


def test_a_study_of_a_mesh_file_says_it_sweeps_no_resolutions(tmp_path, tiny, monkeypatch):
    """The sweep of mesh resolutions needs a built-in shape: left out, and said so (it was silent; an audit)."""
    import meshio

    from skfem_modal.mesh import caterpillar

    mesh = caterpillar(nx=16, ny=8)
    meshio.write(tmp_path / "cat.vtu", meshio.Mesh(mesh.p.T, [("triangle", mesh.t.T)]))
    monkeypatch.setitem(study.PRESETS, "tiny", {**TINY, "resolution": [0.5, 1.0]})
    report = study.run_study({**FLOATING, "mesh": {"file": str(tmp_path / "cat.vtu")}}, tmp_path / "s", preset="tiny")
    assert report["left_out"] == {
        "resolution": "the mesh resolution sweep, which needs a built-in shape (a mesh file has one)"
    }
    assert not any(r["label"].startswith("resolution") for r in report["rows"])
    text = (tmp_path / "s" / "study.md").read_text()
    said = "Not run for this scene: the mesh resolution sweep, which needs a built-in shape (a mesh file has one)."
    assert said in text


def test_a_study_with_pins_says_what_only_more_weights_reduce(tmp_path, tiny):
    """The pins' hold on a small subspace counted as solver error; clusters and iterations barely move it."""
    report = study.run_study({**FLOATING, "pinned": {"where": ["x == min"]}}, tmp_path, preset="tiny")
    assert report["recommendation"][-1].startswith("With pins, part of what the table calls solver error")
    assert "compare the weights sweep" in (tmp_path / "study.md").read_text()


def test_the_study_command_refuses_replaces_and_keeps_apart(tmp_path, tiny, capsys):
    out = tmp_path / "study"
    assert main(["study", "--quick", "--out", str(out)]) == 0
    said = capsys.readouterr().out.splitlines()
    names = ["study.md", "study.csv", "modal.csv", "study.json", "pareto.png"]
    assert said[-1] == "wrote " + ", ".join(str(out / n) for n in names)
    assert sorted(os.listdir(out)) == sorted(names)  # whole files, no temporary ones left
    (out / "notes.txt").write_text("mine")
    first = (out / "study.json").read_text()

    assert main(["study", "--quick", "--out", str(out), "-q"]) == 2
    err = capsys.readouterr().err
    assert err == (
        f"skfem-modal study: error: {str(out)!r} holds an earlier study (modal.csv, pareto.png, study.csv, "
        "study.json, study.md); pass --overwrite to replace it (only its files are removed) or choose another "
        "directory\n"
    )
    assert (out / "study.json").read_text() == first
    with pytest.raises(FileExistsError, match="pass overwrite=True"):
        study.run_study(FLOATING, out, preset="tiny")

    (out / "study.md").unlink()  # a study that left fewer files is replaced all the same
    assert main(["study", "--quick", "--out", str(out), "-q", "--overwrite"]) == 0
    assert sorted(os.listdir(out)) == sorted(names + ["notes.txt"]) and (out / "notes.txt").read_text() == "mine"
    assert json.loads((out / "study.json").read_text())["meta"]["date"]

    # a run's folder and a study's are kept apart, whichever comes first, --overwrite or not
    run_dir = tmp_path / "run"
    scene = tmp_path / "scene.toml"
    scene.write_text(
        "[mesh]\nshape = 'caterpillar'\nparams = { nx = 16, ny = 8 }\n[muscles]\ncount = 1\n[time]\nsteps = 2\n"
    )
    assert main(["run", str(scene), "--out", str(run_dir), "-q"]) == 0
    for flags in ([], ["--overwrite"]):
        assert main(["study", "--quick", "--out", str(run_dir), "-q", *flags]) == 2
        assert "holds a run (amplitudes.csv, com.csv, frames.pvd, summary.json, 3 frames): a study there" in (
            capsys.readouterr().err
        )
        assert main(["run", str(scene), "--out", str(out), "-q", *flags]) == 2
        assert "holds a study (modal.csv, pareto.png, study.csv, study.json, study.md): a run there" in (
            capsys.readouterr().err
        )
    assert not any(n.startswith("study") for n in os.listdir(run_dir)) and not (out / "summary.json").exists()


def test_a_disk_full_while_a_study_writes_its_tables_is_named(tmp_path, tiny, capsys, monkeypatch):
    # a full disk said "error: [Errno 28] No space left on device" (exit 2, "bad input") without the file
    opened = open

    def no_room(path, *args, **kwargs):
        if os.fspath(path).endswith(".csv"):  # the first table written: study.csv, by a hidden name
            raise OSError(28, "No space left on device")
        return opened(path, *args, **kwargs)

    monkeypatch.setattr(study, "open", no_room, raising=False)
    out = tmp_path / "study"
    assert main(["study", "--quick", "--out", str(out), "-q"]) == 5
    err = capsys.readouterr().err
    assert err == f"skfem-modal study: outputs failed: could not write {out / 'study.csv'}: No space left on device\n"
    assert not any(name.endswith(".csv") for name in os.listdir(out))  # no part of it, no temporary file


def test_a_study_says_when_its_length_is_not_the_scenes(tmp_path, tiny, capsys):
    """An audit: a scene's [time] steps = 60 was studied over the preset's 100 steps without a word."""
    from skfem_modal.optimize import scene_to_toml

    for name, time, said in [("seven", {"time": {"step": 0.02, "steps": 7}}, True), ("free", {}, False)]:
        scene = tmp_path / f"{name}.toml"
        scene.write_text(scene_to_toml({**{k: v for k, v in FLOATING.items() if k != "time"}, **time}))
        assert main(["study", str(scene), "--quick", "--out", str(tmp_path / name)]) == 0
        out = capsys.readouterr().out
        assert ("each run is the quick study's 10 steps, not the scene's 7: a study compares settings" in out) == said
        assert json.loads((tmp_path / name / "study.json").read_text())["meta"]["steps"] == 10


def test_the_study_command_says_warnings_once_in_its_own_words(tmp_path, tiny, capfd):
    # a step large for the body: the ScaleWarning comes from the workers' builds too, which say nothing raw
    # (a period of 1.3: with 1.0 every step read the gait at a zero, and the body never moved)
    scene = tmp_path / "scene.toml"
    scene.write_text(
        "[mesh]\nshape = 'caterpillar'\nparams = { nx = 16, ny = 8 }\n[material]\nmu = 1e5\nrho = 1e3\n"
        "[muscles]\ncount = 1\n[muscles.gait]\namplitude = [0.5]\nperiod = [1.3]\n[time]\nstep = 0.5\nsteps = 4\n"
    )
    assert main(["study", str(scene), "--quick", "--out", str(tmp_path / "study"), "-q"]) == 0
    err = capfd.readouterr().err.splitlines()
    assert err and all(line.startswith("skfem-modal study: warning: mesh 'caterpillar' is 2") for line in err), err
    assert len(set(err)) == len(err)  # each said once


@pytest.mark.parametrize("after", [0, 1])  # a reference's worker killed, or the reduced runs'
def test_a_study_that_loses_its_workers_says_so_in_one_line(tmp_path, tiny, capsys, monkeypatch, killing_pools, after):
    monkeypatch.setattr(study, "make_executor", killing_pools(study.make_executor, after=after))
    out = tmp_path / "study"
    assert main(["study", "--quick", "--out", str(out), "--workers", "2"]) == 4
    err = capsys.readouterr().err
    assert err == (
        "skfem-modal study: the study lost its workers: a worker process of the local pool died (killed: by the "
        "out-of-memory killer, say); a study keeps no checkpoint: run it again\n"
    )
    assert earlier_study(out) == []  # nothing half written


def test_the_recommendations_print_errors_as_they_compare_with_the_thresholds():
    # 10.36 % printed as "10 %" read as within 10 %; 120 % as "1.2e+02 %"
    base = dict(resolution=1.0, sweep="base", weights=8, clusters=20, max_iterations=10, rtol=0.0, step_ms=0.08,
                trajectory_error=0.071, subspace_error=0.0063)  # fmt: skip
    faster = {**base, "sweep": "iterations", "max_iterations": 5, "step_ms": 0.0713, "trajectory_error": 0.1036}
    wild = {**base, "sweep": "iterations", "max_iterations": 1, "step_ms": 0.05, "trajectory_error": 1.2}
    lines = study.recommend([base, faster, wild], thresholds=(0.10, 0.20, 2.0))
    assert lines[0].startswith("8 weights, 20 clusters and 10 iterations give 7.1 % trajectory error at 0.08 ms")
    assert "(the subspace alone allows 0.63 %)" in lines[0]
    assert lines[1].endswith("7.1 % at 0.08 ms per step (1 times the base's).")  # not the 10.4 % row
    assert lines[2].endswith("5 iterations: 10.4 % at 0.0713 ms per step (0.89 times the base's).")
    assert lines[3].endswith("1 iterations: 120.0 % at 0.05 ms per step (0.62 times the base's).")
    # a looser threshold the same setting answers is said in a word (two identical lines read as a slip)
    lines = study.recommend([base, faster], thresholds=(0.10, 0.20, 0.50))
    assert lines[2].endswith("5 iterations: 10.4 % at 0.0713 ms per step (0.89 times the base's).")
    assert lines[3] == "Within 50 % trajectory error: the same setting (none faster stays within it)."


# run in a process of its own, as a command's: the suite's earlier pools and signal handling stay out of it
_STOPPED_POOL = """
import os, pathlib, sys, time
from skfem_modal import study

def running(pid):
    # (is_alive() can say True of a worker the pool's own thread reaped first: ask the system)
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    stat = pathlib.Path(f"/proc/{pid}/stat")
    return not (stat.exists() and stat.read_text().split(")")[-1].split()[0] == "Z")

def nap(seconds, started=None):
    if started is not None:
        pathlib.Path(started).write_text("running")
    time.sleep(seconds)
    return seconds

if __name__ == "__main__":
    started = pathlib.Path(sys.argv[1])
    executor, close = study.make_executor(workers=1)
    executor.submit(nap, 60.0, str(started))
    deadline = time.time() + 60
    while not started.exists() and time.time() < deadline:  # running in the worker, not only handed to it
        time.sleep(0.05)
    (process,) = executor._processes.values()
    clock = time.perf_counter()
    close(cancel=True)
    print(f"stopped after {time.perf_counter() - clock:.3f} s, alive {running(process.pid)}")
    executor, close = study.make_executor(workers=1)
    done = executor.submit(nap, 0.2)
    close()  # a plain close waits for the tasks, as before
    print(f"waited for {done.result(timeout=0)}")
"""


def test_a_stopped_local_pool_stops_its_running_tasks_too(tmp_path):
    # closing for a stop waited for the task running: a study signalled to stop ran a reference 200 s on
    import subprocess
    import sys

    script = tmp_path / "stop.py"
    script.write_text(_STOPPED_POOL)
    done = subprocess.run([sys.executable, str(script), str(tmp_path / "started")], capture_output=True, text=True,
                          timeout=120)  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    stopped, waited = done.stdout.splitlines()
    assert stopped.endswith("alive False") and float(stopped.split()[2]) < 10.0
    assert waited == "waited for 0.2"


def test_a_study_interrupted_stops_its_pool_without_waiting(tmp_path, tiny, monkeypatch):
    closed = []
    made = study.make_executor

    def recording(*args, **kwargs):
        executor, close = made(*args, **kwargs)
        return executor, lambda cancel=False: (closed.append(cancel), close(cancel))

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(study, "make_executor", recording)
    monkeypatch.setattr(study, "_run_references", interrupted)
    with pytest.raises(KeyboardInterrupt):
        study.run_study(FLOATING, tmp_path / "s", preset="tiny")
    assert closed == [True]


def test_a_reference_that_does_not_settle_says_its_last_change_in_lengths(tmp_path):
    # the reference contact's full space goes round between sets: every step stops at max_iter. Its last change,
    # z_k - z_(k-1), as the study says it (root mean square over the nodes, over the size), against one made here
    # by stepping the same state with one iteration fewer (an audit: the residual, already relative to the
    # step's motion, had been divided by the size again: 31 % for a largest vertex move of 1.2 %)
    import numpy as np

    from skfem_modal.scene import Scene
    from skfem_modal.sim import simulate

    data = {**FLOATING, **GROUND, "ground": {**GROUND["ground"], "model": "reference"}}
    ref = study.run_reference(data, None, 3)
    assert ref["unsettled_steps"] == 3
    scene = Scene.from_dict({**data, "time": {**data["time"], "steps": 3}})
    sim = scene.build_reference()
    records = list(simulate(sim, 3, lambda t: scene.activation(t, sim.ceilings)))
    changes = []
    for before, record in zip([None] + records[:-1], records):
        z, z_dot = (sim.rest_state()[:2]) if before is None else (before.z, before.z_dot)
        sim.max_iter = ref["max_iterations"] - 1
        last_but_one = sim.step(z, z_dot, record.a)
        sim.max_iter = ref["max_iterations"]
        np.testing.assert_array_equal(sim.step(z, z_dot, record.a), record.z)
        changes.append(np.linalg.norm(record.z - last_but_one))
    nodes, size = records[0].z.size / 2, float(np.ptp(scene.mesh.p, axis=1).max())
    assert ref["unsettled_change"] == pytest.approx(max(changes) / np.sqrt(nodes) / size, rel=1e-9)
    assert 1e-4 < ref["unsettled_change"] < 0.05


def test_a_study_of_a_body_that_does_not_move_is_refused(tmp_path, tiny):
    # no gait, no gravity: the reference moves by round-off, and every row had read 21 % error (an audit)
    data = {**FLOATING, "muscles": {**FLOATING["muscles"], "gait": None}}
    out = tmp_path / "study"
    with pytest.raises(ValueError, match="the scene's body does not move in the reference run at resolution 1: no "
                       "vertex moved more than .* of its body's size in 10 steps"):  # fmt: skip
        study.run_study(data, out, preset="tiny")
    assert not out.exists()  # nothing half written


def test_errors_on_a_mesh_of_two_bodies_are_each_body_s_own(tmp_path):
    # a 2 x 0.4 bar and a body 28 away: a vertex's error over its own body's size, not the pair's span (an audit:
    # 3.1e-3 where the bar's own error was 4.7e-2)
    import numpy as np

    rest = np.array([[0.0, 0.0], [2.0, 0.0], [28.0, 0.0], [28.5, 0.0]])
    x_ref = rest + [[0.0, 0.1], [0.0, 0.1], [0.0, 0.0], [0.0, 0.0]]
    x = x_ref + [[0.0, 0.02], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0]]
    parts = np.array([0, 0, 1, 1])
    sizes = np.array([2.0, 2.0, 0.5, 0.5])
    errors = study.trajectory_errors(x.ravel()[None], x_ref.ravel()[None], np.ones(8), rest.ravel(), sizes, 2,
                                     parts=parts)  # fmt: skip
    assert errors["worst_vertex_error"] == pytest.approx(0.02 / 2.0)
    assert errors["com_error"] == pytest.approx(0.01 / 2.0)  # the bar's centre moved by half its vertex's 0.02
    single = study.trajectory_errors(x.ravel()[None], x_ref.ravel()[None], np.ones(8), rest.ravel(), 28.5, 2)
    assert single["worst_vertex_error"] == pytest.approx(0.02 / 28.5)
