"""The Python examples of the README and docs run as written and do what they say."""

import math
import os
import re

import meshio
import numpy as np

from skfem_modal.cli import main

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), os.pardir)


def python_blocks(name):
    text = open(os.path.join(ROOT, name), encoding="utf-8").read()
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


def run_block(code, name):
    namespace = {}
    exec(compile(code, name, "exec"), namespace)
    return namespace


def test_readme_python_example(tmp_path, monkeypatch, capsys):
    (code,) = python_blocks("README.md")
    monkeypatch.chdir(tmp_path)  # it writes modes.vtu
    namespace = run_block(code, "README.md")
    printed = capsys.readouterr().out.splitlines()
    # the eigenvalues its comment quotes: the tutorial's modes 3-6
    quoted = [float(v) for v in re.search(r"# \[([0-9. ]+)\]", code).group(1).split()]
    shown = [float(v) for v in printed[0].strip("[]").split()]
    np.testing.assert_allclose(shown, quoted, rtol=1e-5)
    assert printed[1] == "3" and printed[2] == "4"  # rigid motions; hinges of the coarse caterpillar
    assert "('elasticity', 'inertia', 'muscles', 'gravity', 'contact')" in printed
    sim, z = namespace["sim"], namespace["z"]
    travel = sim.com(z) - sim.com(sim.rest_state()[0])
    assert abs(travel[0] - (-4.438)) < 0.01
    quoted = re.search(r"# \[([-0-9. ]+)\], the centre of mass: moved by \[([-0-9., ]+)\]", code)
    np.testing.assert_allclose(sim.com(z), [float(v) for v in quoted.group(1).split()], atol=1e-5)
    np.testing.assert_allclose(travel, [float(v) for v in quoted.group(2).split(",")], atol=1e-4)
    assert namespace["x"].shape == (1719, 2)
    assert (tmp_path / "modes.vtu").is_file()
    # a warm-started floating step stopped by rtol: its relative residual is within rtol
    assert printed[-1] == "True" and namespace["record"].residual <= 1e-4


def test_getting_started_python_example(tmp_path, monkeypatch, capsys):
    (code,) = python_blocks("docs/getting_started.md")
    assert '"examples/creature_crawl.toml"' in code and '"creature_run"' in code
    monkeypatch.chdir(ROOT)
    code = code.replace('"creature_run"', repr(str(tmp_path / "creature_run")))
    namespace = run_block(code, "getting_started.md")
    summary = namespace["summary"]
    printed = capsys.readouterr().out.strip()
    travel = [float(v) for v in re.match(r"\[(.*)\] ", printed).group(1).replace(",", " ").split()]
    np.testing.assert_allclose(travel, summary["com"]["travel"], rtol=1e-6)
    # the creature walks (0.53 along -x, a quarter of its length) under gravity and ground contact
    assert summary["status"] == "completed" and len(travel) == 3 and abs(travel[0]) > 0.1
    step_ms = summary["timings"]["step_ms"]["median"]
    assert math.isfinite(step_ms) and step_ms > 0
    assert (tmp_path / "creature_run" / "frames.pvd").is_file()
    z, z_dot, a = namespace["z"], namespace["z_dot"], namespace["a"]
    assert z.shape == z_dot.shape == (namespace["sim"].B.shape[1],) and a.shape == (4,)


def test_play_md_python_example_without_its_windows_prints_what_it_quotes(monkeypatch, capsys):
    """docs/play.md's controller (no window: the lines that open one are left out) prints the amplitudes quoted."""
    (code,) = python_blocks("docs/play.md")
    windowless = "\n".join(line for line in code.splitlines() if not line.startswith("play("))
    assert "player = Player(sim)" in windowless
    monkeypatch.chdir(ROOT)
    run_block(windowless, "play.md")
    quoted = [float(v) for v in re.search(r"# \[([-0-9. ]+)\]", code).group(1).split()]
    shown = [float(v) for v in capsys.readouterr().out.strip().strip("[]").split()]
    np.testing.assert_allclose(shown, quoted, atol=1e-4)


def test_outputs_python_example(tmp_path, monkeypatch):
    (code,) = python_blocks("docs/outputs.md")
    monkeypatch.chdir(tmp_path)
    assert main(["run", "--out", "out", "--quiet"]) == 0
    namespace = run_block(code, "outputs.md")
    frame, grid, run = namespace["frame"], namespace["grid"], namespace["run"]
    assert frame.point_data["displacement"].shape == (1719, 3)
    assert float(np.ravel(frame.field_data["time"])[0]) == 4.5  # every 5th step written: the last
    # the time series' last frame is the run's last state
    assert namespace["reader"].time_values[-1] == 4.5
    last = meshio.read(run["frames"][-1][1])
    np.testing.assert_array_equal(grid.point_data["displacement"], last.point_data["displacement"])
    times, com = run["com"]
    assert times[-1] == 4.5 and com.shape == (451, 2)


def test_readme_scene_file_is_a_valid_scene_of_what_it_says(tmp_path, capsys):
    import tomllib

    from skfem_modal.scene import Scene

    (text,) = re.findall(r"```toml\n(# my_scene.toml.*?)```", open(os.path.join(ROOT, "README.md")).read(), re.S)
    scene = Scene.from_dict(tomllib.loads(text))
    assert scene.effects == ("elasticity", "inertia", "muscles", "gravity", "contact")
    assert scene.config["muscles"]["gait"]["ramp"] == 0.5 and not any(scene.activation_fractions(0.0))
    (tmp_path / "my_scene.toml").write_text(text)
    assert main(["info", str(tmp_path / "my_scene.toml")]) == 0
    assert "phases [0.0, 0.25, 0.5, 0.75], ramped in over 0.5\n" in capsys.readouterr().out


def test_cli_md_huge_step_warnings_are_what_a_run_says(tmp_path):
    """docs/cli.md shows the built-in scene's warnings at step = 0.5, 20 steps: a run says exactly those."""
    import copy
    import warnings

    from skfem_modal.run import run_scene
    from skfem_modal.scene import DEFAULT_SCENE, Scene

    text = open(os.path.join(ROOT, "docs", "cli.md"), encoding="utf-8").read()
    prefix = "    skfem-modal run: warning: "
    shown = [line[len(prefix) :] for line in text.splitlines() if line.startswith(prefix)]
    shown = [line for line in shown if "(t = 0.5)" in line or "h = 0.5" in line]
    data = copy.deepcopy(DEFAULT_SCENE)
    data["time"] = {"step": 0.5, "steps": 20}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # (the command prints them as 'skfem-modal run: warning: ...')
        motion = run_scene(Scene.from_dict(data), tmp_path / "out")["motion"]
    assert len(shown) == 4 and motion["warnings"] == shown
