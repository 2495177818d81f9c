"""A run's records agree about its last step: interrupted (Ctrl-C, SIGTERM), failed or ending between frames."""

import csv
import json
import signal
import subprocess
import sys
import textwrap

import meshio
import numpy as np
import pytest

import skfem_modal.export as export
from skfem_modal.cli import main
from skfem_modal.run import run_scene
from skfem_modal.scene import Scene
from skfem_modal.sim import SimulationError

FLOATING = {
    "name": "small floating caterpillar",
    "mesh": {"shape": "caterpillar", "params": {"nx": 20, "ny": 10}},
    "material": {"mu": 1e5, "rho": 1e3},
    "subspace": {"weights": 4, "clusters": 6},
    "muscles": {"count": 2, "gait": {"amplitude": [0.9, 0.6], "period": [1.0, 0.7], "phase": [0.0, 0.25]}},
    "time": {"step": 0.02, "steps": 30},
    "output": {"every": 5},
}


def records(out):
    """summary.json, the com.csv and amplitudes.csv rows (header dropped) and the frames' times of a run folder."""
    summary = json.loads((out / "summary.json").read_text())
    com = list(csv.reader(open(out / "com.csv")))[1:]
    amplitudes = list(csv.reader(open(out / "amplitudes.csv")))[1:]
    times = [float(meshio.read(f).field_data["time"][0]) for f in sorted((out / "frames").glob("frame_*.vtu"))]
    return summary, com, amplitudes, times


def assert_all_end_at(out, step, h=0.02):
    summary, com, amplitudes, times = records(out)
    assert summary["steps_completed"] == step
    assert len(com) == len(amplitudes) == step + 1
    assert float(com[-1][0]) == float(amplitudes[-1][0]) == step * h
    assert [float(v) for v in com[-1][1:]] == summary["com"]["end"]  # the same float, written with repr
    assert times[-1] == summary["frames"]["times"][-1] == step * h
    assert summary["frames"]["count"] == len(times)
    return summary, times


def interrupt_at(monkeypatch, time, how):
    """Make the frame at ``time`` be interrupted while it is written: ``how(time)`` runs inside its write."""
    write = export.FrameWriter.write

    def interrupted(self, t, x, **options):
        if t >= time - 1e-12:
            how(t)
        return write(self, t, x, **options)

    monkeypatch.setattr(export.FrameWriter, "write", interrupted)


def test_ctrl_c_while_a_frame_is_written_waits_for_the_steps_records(tmp_path, monkeypatch):
    # a real SIGINT at step 10's frame: the frame, both rows and the summary's counts all get step 10
    sent = []

    def ctrl_c(t):
        if not sent:
            sent.append(t)
            signal.raise_signal(signal.SIGINT)

    interrupt_at(monkeypatch, 0.2, ctrl_c)
    with pytest.raises(KeyboardInterrupt):
        run_scene(Scene.from_dict(FLOATING), tmp_path)
    summary, times = assert_all_end_at(tmp_path, 10)
    assert summary["status"] == "interrupted" and summary["error"] == {"step": 10, "time": 0.2}
    assert times == [0.0, 0.1, 0.2]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # given back


@pytest.mark.parametrize("when", ["frames", "tables"])
def test_ctrl_c_as_a_run_makes_its_files_leaves_no_folder_it_made(tmp_path, monkeypatch, when):
    """An audit: a Ctrl-C in the fifth of a second after the run made its folder left it, empty."""
    if when == "frames":

        def interrupted(*args, **kwargs):
            raise KeyboardInterrupt

        monkeypatch.setattr(export.FrameWriter, "__init__", interrupted)
    else:
        import skfem_modal.run as run

        real_open = open

        def interrupted(path, *args, **kwargs):
            if str(path).endswith("amplitudes.csv"):
                raise KeyboardInterrupt
            return real_open(path, *args, **kwargs)

        monkeypatch.setattr(run, "open", interrupted, raising=False)
    scene = Scene.from_dict(FLOATING)
    with pytest.raises(KeyboardInterrupt):
        run_scene(scene, tmp_path / "made" / "run")
    assert list(tmp_path.iterdir()) == []  # neither the run's folder nor the parent it made


def test_an_error_inside_a_frame_leaves_every_record_at_the_step_before(tmp_path, monkeypatch):
    # raised by the frame writer itself (not a signal): step 10 is in no record, step 9 is in all, its frame too
    def fail(t):
        raise KeyboardInterrupt

    interrupt_at(monkeypatch, 0.2, fail)
    with pytest.raises(KeyboardInterrupt):
        run_scene(Scene.from_dict(FLOATING), tmp_path)
    summary, times = assert_all_end_at(tmp_path, 9)
    assert summary["error"] == {"step": 9, "time": 9 * 0.02}
    assert times == [0.0, 0.1, 0.18]


@pytest.mark.parametrize(
    "every, frame_steps", [(7, [0, 7, 14, 21, 28, 30]), (1000, [0, 30]), (5, list(range(0, 31, 5)))]
)
def test_the_last_step_is_always_a_frame(tmp_path, every, frame_steps):
    run_scene(Scene.from_dict(FLOATING), tmp_path, every=every)
    summary, times = assert_all_end_at(tmp_path, 30)
    np.testing.assert_allclose(times, np.array(frame_steps) * 0.02, rtol=0, atol=1e-15)
    assert summary["frames"]["every"] == every


CATERPILLAR_30_STEPS = (
    "[mesh]\nshape = 'caterpillar'\nparams = { nx = 20, ny = 10 }\n[material]\nmu = 1e5\nrho = 1e3\n"
    "[subspace]\nweights = 4\nclusters = 6\n[muscles]\ncount = 2\n[muscles.gait]\namplitude = [0.9, 0.6]\n"
    "period = [1.0, 0.7]\n[time]\nstep = 0.02\nsteps = 30\n[output]\nevery = 5\n"
)


#: a SIGTERM as the frame at t = 0.2 is written
TERMINATED_AT_02 = """
import skfem_modal.export as export
write = export.FrameWriter.write
def terminated(self, t, x, **options):
    if abs(t - 0.2) < 1e-12:
        os.kill(os.getpid(), signal.SIGTERM)
    return write(self, t, x, **options)
export.FrameWriter.write = terminated
"""


def run_console(tmp_path, prelude: str):
    """The console script run on the 30-step caterpillar into ``tmp_path / "out"``, after ``prelude`` (Python)."""
    (tmp_path / "scene.toml").write_text(CATERPILLAR_30_STEPS)
    argv = ["skfem-modal", "run", str(tmp_path / "scene.toml"), "--out", str(tmp_path / "out"), "-q"]
    script = (
        "import os, signal, sys\n"
        + textwrap.dedent(prelude)
        + (f"sys.argv = {argv!r}\nfrom skfem_modal._entry import main\nsys.exit(main())\n")
    )
    return subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)


def test_sigterm_stops_a_command_run_like_ctrl_c(tmp_path):
    # timeout(1) sends SIGTERM: the run stops cleanly, its summary says interrupted, its files agree
    done = run_console(tmp_path, TERMINATED_AT_02)
    assert done.returncode == 130, done.stderr
    assert done.stderr.strip().splitlines()[-1] == "skfem-modal run: terminated (SIGTERM)"
    summary, _ = assert_all_end_at(tmp_path / "out", 10)
    assert summary["status"] == "interrupted"


def test_pinned_drift_is_the_largest_distance_over_the_written_frames(tmp_path):
    data = {
        "mesh": {"shape": "beam2d", "params": {"length": 4.0, "height": 0.4, "nx": 20, "ny": 2}},
        "material": {"mu": 1e4, "rho": 1e3},
        "subspace": {"weights": 5, "clusters": 6},
        "muscles": {"count": 1, "gait": {"amplitude": [0.8], "period": [0.4]}},
        "time": {"step": 0.01, "steps": 40},
        "pinned": {"where": ["x == min"]},
        "output": {"every": 4},
    }
    scene = Scene.from_dict(data)
    run_scene(scene, tmp_path)
    summary = json.loads((tmp_path / "summary.json").read_text())
    pinned = scene.pinned_vertices()
    offsets = np.array(
        [meshio.read(f).point_data["displacement"][pinned, :2] for f in sorted((tmp_path / "frames").glob("*.vtu"))]
    )
    distance = np.linalg.norm(offsets, axis=2).max()
    assert summary["pinned"]["worst_drift_written_frames"] == pytest.approx(distance, rel=1e-12)
    assert distance > 1.01 * np.abs(offsets).max()  # a distance, not the largest coordinate offset
    # after every step too, the same as a run writing every frame reads off its frames
    run_scene(scene, tmp_path / "all", every=1)
    offsets = np.array(
        [meshio.read(f).point_data["displacement"][pinned, :2] for f in sorted((tmp_path / "all" / "frames").glob("*"))]
    )
    assert summary["pinned"]["worst_drift"] == pytest.approx(np.linalg.norm(offsets, axis=2).max(), rel=1e-9)
    assert summary["pinned"]["worst_drift"] > distance


def test_a_failed_run_names_what_the_monitor_saw_of_the_failing_step(tmp_path, capsys):
    # the first muscle asks 1e300 of its ceiling; at t = 0 the sine is 0, so step 2 (t = 0.02..0.04) fails
    data = {**FLOATING, "muscles": {**FLOATING["muscles"], "gait": {**FLOATING["muscles"]["gait"]}}}
    data["muscles"]["gait"]["amplitude"] = [1e300, 0.6]
    fraction = 1e300 * np.sin(2 * np.pi * 0.02)  # the failing step's activation, over the ceiling
    said = f"the muscles were driven up to {fraction:.3g} times their ceilings"
    failed = r"^step 2: the state became non-finite \(t = 0.04; outputs so far kept\)"
    with pytest.raises(SimulationError, match=failed):
        run_scene(Scene.from_dict(data), tmp_path / "py")
    summary = json.loads((tmp_path / "py" / "summary.json").read_text())
    motion = summary["motion"]
    assert summary["status"] == "failed" and summary["error"]["step"] == 2 and summary["steps_completed"] == 1
    assert said == "the muscles were driven up to 1.25e+299 times their ceilings"
    assert said in summary["error"]["message"]
    assert motion["physical"] is False and motion["first_problem_step"] == {"ceilings": 2, "non_finite": 2}
    assert motion["largest_ceiling_fraction"] == pytest.approx(fraction, rel=1e-9)
    assert motion["warnings"][1] == "at step 2 (t = 0.04) the state became non-finite"
    assert "keep the activations (muscles.gait.amplitude, muscles.table) within [-1, 1]" in motion["warnings"][2]
    scene = tmp_path / "scene.toml"
    scene.write_text(
        "[mesh]\nshape = 'caterpillar'\nparams = { nx = 20, ny = 10 }\n[material]\nmu = 1e5\nrho = 1e3\n"
        "[muscles]\ncount = 1\n[muscles.gait]\namplitude = [1e300]\nperiod = [1.0]\n[time]\nstep = 0.02\nsteps = 5\n"
    )
    assert main(["run", str(scene), "--out", str(tmp_path / "cli"), "-q"]) == 3
    err = capsys.readouterr().err
    assert err.startswith("skfem-modal run: simulation failed: step 2: the state became non-finite (t = 0.04")
    assert said in err


def test_the_command_prints_every_warning_in_its_own_words(tmp_path, capsys):
    # the library's UserWarning (a duration rounded up) comes out as the motion warnings do, no file or source line
    scene = tmp_path / "scene.toml"
    scene.write_text(
        "[mesh]\nshape = 'caterpillar'\nparams = { nx = 20, ny = 10 }\n[muscles]\ncount = 1\n"
        "[time]\nstep = 0.01\nduration = 0.025\n"
    )
    assert main(["run", str(scene), "--out", str(tmp_path / "out"), "-q"]) == 0
    assert capsys.readouterr().err.splitlines() == [
        "skfem-modal run: warning: time.duration = 0.025 is not a whole number of time.step = 0.01: running 3 "
        "steps, to t = 0.03 (the duration rounded up to a whole step; give time.steps for an exact count)"
    ]


@pytest.mark.filterwarnings("ignore::skfem_modal.units.ScaleWarning")  # (one step of a long beam)
@pytest.mark.parametrize("normalize, scale", [(True, 3.0), (False, 0.5), (True, 1.0)])
def test_the_summary_says_where_normalize_and_scale_put_the_mesh(tmp_path, normalize, scale):
    """An audit: a normalised mesh's frames were in other units than its file, and nothing said which."""
    from skfem_modal.mesh import beam2d

    beam = {"shape": "beam2d", "params": {"length": 10.0, "height": 1.0, "nx": 10, "ny": 2}}
    mesh = {**beam, "normalize": normalize, "scale": scale}
    scene = Scene.from_dict({**FLOATING, "mesh": mesh, "muscles": {"count": 0}, "time": {"step": 0.02, "steps": 1}})
    summary = run_scene(scene, tmp_path / "out")
    placement = summary["mesh"]["placement"]
    centre, factor = ([5.0, 0.5], 0.2 * scale) if normalize else ([0.0, 0.0], scale)
    np.testing.assert_allclose(placement["centre"], centre, rtol=1e-15)
    assert placement["factor"] == pytest.approx(factor, rel=1e-15)
    first = meshio.read(tmp_path / "out" / "frames" / "frame_00000.vtu")
    in_file = beam2d(10.0, 1.0, 10, 2).p.T  # where the shape has its vertices
    np.testing.assert_allclose(first.points[:, :2], factor * (in_file - centre), atol=1e-14)
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["mesh"]["placement"] == placement


def test_ctrl_c_while_the_last_records_are_written_says_the_run_is_whole(tmp_path):
    """An audit: a Ctrl-C as the last frame was written said "interrupted" (130) beside a summary saying completed."""
    done = run_console(
        tmp_path,
        """
        import skfem_modal.run as run
        measured = run._measured
        def interrupted(*args):  # inside the summary's last write, whose signals wait until it is whole
            os.kill(os.getpid(), signal.SIGINT)
            return measured(*args)
        run._measured = interrupted
        """,
    )
    assert done.returncode == 130, done.stderr
    assert done.stderr.strip().splitlines() == [
        "skfem-modal run: interrupted after the last step: the run is whole (summary.json says completed); "
        "the closing lines skipped"
    ]
    summary, _ = assert_all_end_at(tmp_path / "out", 30)
    assert summary["status"] == "completed" and summary["error"] is None


def test_a_second_sigterm_while_the_first_stops_the_run_keeps_its_exit_code(tmp_path):
    """An audit: two SIGTERMs 10 ms apart ended the process by the second (exit 143), not with 130."""
    done = run_console(
        tmp_path,
        TERMINATED_AT_02
        + textwrap.dedent(
            """
        class Again:  # the second as the first one's stop is said
            def __init__(self, stream):
                self.stream = stream
            def write(self, text):
                if "terminated" in text:
                    os.kill(os.getpid(), signal.SIGTERM)
                return self.stream.write(text)
            def __getattr__(self, name):
                return getattr(self.stream, name)
        sys.stderr = Again(sys.stderr)
        """
        ),
    )
    assert done.returncode == 130, done.stderr
    summary, _ = assert_all_end_at(tmp_path / "out", 10)
    assert summary["status"] == "interrupted"
