"""Runs whose motion is not physical for their scene are reported, physical ones are not."""

import copy
import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from skfem_modal.cli import main
from skfem_modal.mesh import beam2d
from skfem_modal.monitor import PUSH_LIMIT, CeilingWarning, MotionMonitor, MotionWarning
from skfem_modal.run import run_scene
from skfem_modal.scene import DEFAULT_SCENE, Scene
from skfem_modal.sim import ModalMuscle, SimulationError


@pytest.fixture(scope="module")
def beam_sim():
    return ModalMuscle.from_mesh(beam2d(2.0, 0.5, 8, 2), n_muscles=1, n_weights=3, n_clusters=4, h=0.01)


def state_of(sim, positions):
    """The reduced state whose positions are ``positions`` (affine maps of the rest shape are in the subspace)."""
    z = np.linalg.lstsq(sim.B, np.ravel(positions), rcond=None)[0]
    np.testing.assert_allclose(sim.positions(z), positions, atol=1e-12)
    return z


def test_spread_and_push_of_made_up_states(beam_sim):
    sim = beam_sim
    rest = sim.mesh.p.T
    monitor = MotionMonitor(sim, gravity=[0.0, -9.8])
    assert monitor.size == pytest.approx(2.0)
    # a translation is no deformation; a free fall step is no push
    g_step = 0.01**2 * np.array([0.0, -9.8])
    monitor.update(1, state_of(sim, rest + g_step))
    monitor.update(2, state_of(sim, rest + 3 * g_step))
    assert monitor.spread_ratio == pytest.approx([1.0, 1.0], abs=1e-12)
    assert monitor.push == pytest.approx(0.0, abs=1e-12)
    # then the body stops dead: the ground's push is the fall it stopped, 3 g h^2 (in body sizes)
    monitor.update(3, state_of(sim, rest + 3 * g_step))
    assert monitor.push == pytest.approx(3 * 9.8e-4 / 2.0, rel=1e-9)
    assert monitor.finish()["physical"]
    # swelling 4 times about the centre
    centre = rest.mean(axis=0)
    monitor.update(4, state_of(sim, centre + 4 * (rest - centre)))
    assert monitor.spread_ratio[1] == pytest.approx(4.0, rel=1e-9)
    with pytest.warns(MotionWarning) as record:
        report = monitor.finish()
    assert [str(w.message) for w in record] == [
        "from step 4 (t = 0.04) the body grew to 4 times its rest size: no force in this scene deforms it so far",
        "neither the muscles' ceilings nor the material's weight explain it: the time step h = 0.01 may be too large "
        "for this scene (try a smaller time.step); if a smaller one does the same, the scene asks more than the "
        "elements can take (several muscles at once, a violent landing)",
    ]
    assert not report["physical"] and report["first_problem_step"] == {"spread": 4}


def test_muscles_beyond_their_ceilings_are_blamed_not_the_time_step(beam_sim):
    sim = beam_sim
    rest = sim.mesh.p.T
    monitor = MotionMonitor(sim)
    monitor.update(1, state_of(sim, rest), sim.ceilings * 1.0)  # at the ceiling: not beyond
    assert "ceilings" not in monitor.first_problem_step
    monitor.update(2, state_of(sim, rest), -20.0 * sim.ceilings)
    centre = rest.mean(axis=0)
    monitor.update(3, state_of(sim, centre + 4 * (rest - centre)), 20.0 * sim.ceilings)
    with pytest.warns(MotionWarning) as record:
        report = monitor.finish()
    assert [w.category for w in record] == [CeilingWarning, MotionWarning, MotionWarning]
    assert [str(w.message) for w in record] == [
        "from step 2 (t = 0.02) the muscles were driven up to 20 times their ceilings (an activation beyond 1 asks "
        "an element to deform by more than muscles.max_s)",
        "from step 3 (t = 0.03) the body grew to 4 times its rest size",
        "the muscles, driven beyond their ceilings, cause it: keep the activations (muscles.gait.amplitude, "
        "muscles.table) within [-1, 1] of the ceilings, or raise muscles.max_s",
    ]
    assert report["largest_ceiling_fraction"] == pytest.approx(20.0)
    assert not report["physical"] and report["first_problem_step"] == {"ceilings": 2, "spread": 3}


AMPLITUDE = (
    "[mesh]\nshape = 'box3d'\nparams = {{ nx = 3, ny = 3, nz = 3 }}\n[subspace]\nweights = 4\nclusters = 4\n"
    "[muscles]\ncount = 2\n"
    "[muscles.gait]\namplitude = [{a}, 0.5]\nperiod = [0.1, 0.1]\n[time]\nstep = 0.001\nsteps = 40\n"
)


@pytest.mark.parametrize("amplitude", [20.0, -5.0, 1.5])
def test_a_gait_beyond_the_ceilings_is_said_once_in_the_terminal_and_the_summary(tmp_path, capsys, amplitude):
    path = tmp_path / "amp.toml"
    path.write_text(AMPLITUDE.format(a=amplitude))
    assert main(["run", str(path), "--out", str(tmp_path / "out"), "-q"]) == 0
    err = capsys.readouterr().err.splitlines()
    said = [line for line in err if "times their ceilings" in line]
    assert len(said) == 1 and said[0].startswith("skfem-modal run: warning: from step ")
    assert not any("time.step" in line for line in err)  # the muscles cause it, not the step
    motion = json.loads((tmp_path / "out" / "summary.json").read_text())["motion"]
    assert motion["largest_ceiling_fraction"] == pytest.approx(abs(amplitude), rel=1e-3)
    assert sum("times their ceilings" in text for text in motion["warnings"]) == 1


def test_a_gait_within_the_ceilings_says_nothing_of_them(tmp_path, capsys):
    path = tmp_path / "amp.toml"
    path.write_text(AMPLITUDE.format(a=1.0))
    assert main(["run", str(path), "--out", str(tmp_path / "out"), "-q"]) == 0
    assert "ceilings" not in capsys.readouterr().err
    motion = json.loads((tmp_path / "out" / "summary.json").read_text())["motion"]
    assert motion["physical"] and motion["warnings"] == [] and 0.99 < motion["largest_ceiling_fraction"] <= 1.0 + 1e-12


HUGE_STEP = (
    "[time]\nstep = {h}\nsteps = 20\n[mesh]\nshape = 'caterpillar'\n[material]\nmu = 1e6\n"
    "[muscles]\ncount = 4\n[muscles.gait]\namplitude = [0.45, 0.35, 0.25, 0.15]\n"
    "period = [1.2, 0.8, 1.0, 0.6]\n[gravity]\nacceleration = [0.0, -9.8]\n[ground]\noffset = 0.15\n"
)


def test_a_huge_time_step_is_reported_in_the_terminal_and_the_summary(tmp_path, capsys):
    path = tmp_path / "huge_step.toml"
    path.write_text(HUGE_STEP.format(h=1e3))
    assert main(["run", str(path), "--out", str(tmp_path / "out"), "-q"]) == 0
    scale, *err = capsys.readouterr().err.splitlines()
    # the scene's ScaleWarning first, said by the command as its own warnings are
    assert scale.startswith("skfem-modal run: warning: mesh 'caterpillar' is 2 length units across, and an elastic")
    assert err == [
        "skfem-modal run: warning: the gait's shortest period (0.6) is at most two time steps (h = 1000): the "
        "muscles are sampled at aliased phases, not as the gait asks; a time.step of at most 0.03 (twenty a period) "
        "resolves it"
    ]
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["status"] == "completed"
    motion = summary["motion"]
    assert not motion["physical"] and motion["first_problem_step"] == {"gait": 1}
    # the Coulomb contact holds the body's weight, 4.9e6 body sizes of free fall a step: no push (it was
    # reported as one, "moved the centre of mass 4.9e6 body sizes")
    assert motion["largest_push_body_sizes"] < PUSH_LIMIT
    # the library warns too; the reference contact lets the body through the ground, a push
    data = copy.deepcopy(DEFAULT_SCENE)
    data["time"] = {"step": 1e3, "steps": 20}
    with pytest.warns(MotionWarning, match="forces other than gravity moved the centre of mass up to 2.72 body sizes"):
        motion = run_scene(Scene.from_dict(data), None)["motion"]
    assert {"gait", "push", "sink"} <= set(motion["first_problem_step"])


def test_a_body_resting_on_the_ground_at_a_large_step_is_not_pushed(tmp_path):
    """A new user's trial: a box resting at h = 0.5 was "moved 2.52 body sizes in one step", not physical.

    It only lay there: the ground held its weight against a step of free fall (g h^2 = 2.45).
    """
    scene = _held_box(  # (the box of test_what_holds_the_weight_is_no_push, finer and softer: the trial's)
        mesh={"shape": "box3d", "params": {"nx": 6, "ny": 6, "nz": 3, "size": [1.0, 1.0, 0.5]}},
        material={"mu": 1e4, "rho": 1e3},
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error", MotionWarning)
        summary = run_scene(scene, tmp_path / "box")
    motion = summary["motion"]
    assert motion["physical"] and motion["largest_push_body_sizes"] < 0.1
    com = np.loadtxt(tmp_path / "box" / "com.csv", delimiter=",", skiprows=1)
    assert np.abs(np.diff(com[-5:, 1:], axis=0)).max() < 1e-6  # it rests


GHOST = Path(__file__).resolve().parents[2] / "shared" / "meshes" / "ghost.obj"


def test_a_body_too_soft_for_its_weight_is_blamed_on_the_material_not_the_time_step(tmp_path, capsys):
    """A ghost of mu = 1e-3 turns inside out under its weight at any step: the advice names the material."""
    path = tmp_path / "soft.toml"
    path.write_text(
        f'[mesh]\nfile = "{GHOST}"\nnormalize = true\n[material]\nmu = 1e-3\n[muscles]\ncount = 4\n'
        "[time]\nsteps = 100\n[gravity]\nacceleration = [0.0, -9.8]\n[ground]\noffset = 0.05\n"
    )
    assert main(["run", str(path), "--out", str(tmp_path / "out"), "-q"]) == 0
    scale, spread, inverted, blame = capsys.readouterr().err.splitlines()
    assert "it would collapse under its own weight" in scale  # the scene's ScaleWarning, before the run
    assert spread.endswith("the body grew to 4.31 times its rest size")  # (not 'no force deforms it so far')
    assert "of the elements were inside out, up to" in inverted
    assert inverted.endswith("so vertices inside it may be below the ground while its boundary is not")
    assert "smaller time.step" not in blame and blame.startswith(
        "skfem-modal run: warning: the material is too soft to carry the body's own weight (the body is 1.96e+07 "
        "times mu / (rho |g|) = 1.02e-07"
    )
    motion = json.loads((tmp_path / "out" / "summary.json").read_text())["motion"]
    assert not motion["physical"] and motion["warnings"][-1] == blame.removeprefix("skfem-modal run: warning: ")


def test_a_time_step_that_leaves_a_free_body_undetermined_is_refused_before_any_work(tmp_path, capsys):
    # at h = 1e6 the inertia (mass / h^2) is 1e-17 of the stiffness: rigid motions are lost to round-off;
    # the scene's check says so by the elements (1e-18 there), before the precompute
    path = tmp_path / "huge_step.toml"
    path.write_text(HUGE_STEP.format(h=1e6))
    assert main(["run", str(path), "--out", str(tmp_path / "out"), "-q"]) == 2
    err = capsys.readouterr().err
    assert "material.mu = 1000000.0 and material.rho = 1000.0 and time.step = 1000000.0: the inertia" in err
    assert "would be 1e-18 of the stiffness" in err and "singular to working precision" in err
    assert "use a smaller time step" in err and "precompute" not in err
    assert not (tmp_path / "out").exists()
    # a step 10 times shorter passes the estimate (1e-16), and the assembled system says why it cannot be solved
    path.write_text(HUGE_STEP.format(h=1e5))
    assert main(["run", str(path), "--out", str(tmp_path / "out"), "-q"]) == 2
    err = capsys.readouterr().err
    assert "singular to working precision: with h = 100000 the inertia term" in err and "use a smaller time step" in err
    assert not (tmp_path / "out" / "summary.json").exists()


def test_physical_runs_are_quiet(default_crawl_summary):
    motion = default_crawl_summary["motion"]
    assert motion["physical"] and motion["warnings"] == []
    # the crawl bends by tens of percent and the ground pushes it a hundredth of its size a step at most
    assert 0.75 < motion["spread_ratio"][0] <= 1.0 <= motion["spread_ratio"][1] < 1.25
    assert 1e-3 < motion["largest_push_body_sizes"] < 0.05


def test_floating_bodies_keep_their_momentum():
    scene = Scene.from_dict(
        {
            "mesh": {"shape": "beam2d", "params": {"length": 2.0, "height": 0.5, "nx": 8, "ny": 2}},
            "subspace": {"weights": 3, "clusters": 4},
            "muscles": {"count": 2, "gait": {"amplitude": [0.8, 0.8], "period": [0.3, 0.2]}},
            "gravity": {"acceleration": [0.0, -9.8]},
            "time": {"step": 0.01, "steps": 100},
        }
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error", MotionWarning)
        motion = run_scene(scene, None)["motion"]
    # muscles and elasticity are internal forces: the centre of mass falls freely, to round-off
    assert motion["largest_push_body_sizes"] < 1e-12
    assert motion["spread_ratio"][1] > 1.01  # the muscles did deform it


@pytest.fixture(scope="module")
def default_crawl_summary():
    with warnings.catch_warnings():
        warnings.simplefilter("error", MotionWarning)
        return run_scene(Scene.default(), None)


def _ground_scene(model, step=0.3, steps=10, **ground):
    """A caterpillar without muscles dropped from 0.05 above the ground."""
    return Scene.from_dict(
        {
            "mesh": {"shape": "caterpillar", "params": {"nx": 24, "ny": 12}},
            "subspace": {"weights": 6, "clusters": 8},
            "muscles": {"count": 0},
            "gravity": {"acceleration": [0.0, -9.8]},
            "ground": {"model": model, "offset": 0.05, **ground},
            "time": {"step": step, "steps": steps},
        }
    )


def test_a_body_held_in_the_air_by_the_contact_is_reported_hovering(tmp_path, capsys):
    """The reference contact at h = 0.3 keeps its points where each step started them, 0.05 above the ground.

    The run said "completed", physical, with nothing under the body (issue: the caterpillar never lands).
    """
    with pytest.warns(MotionWarning, match=r"from step 1 \(t = 0.3\) the body stayed in the air, 0.025 body sizes"):
        motion = run_scene(_ground_scene("reference"), None)["motion"]
    assert not motion["physical"] and motion["first_problem_step"] == {"hover": 1}
    # the Coulomb contact lands it at the same step: nothing said
    with warnings.catch_warnings():
        warnings.simplefilter("error", MotionWarning)
        landed = run_scene(_ground_scene("coulomb"), None)["motion"]
    # the ground stopped a fall of 0.44 sizes after 0.025: holding the weight is no push, nor the landing here
    assert landed["physical"] and landed["largest_push_body_sizes"] < 0.05


def test_a_body_pinned_in_the_air_or_falling_through_drag_is_not_hovering():
    rest = beam2d(2.0, 0.5, 8, 2).p.T
    for kw in ({"pinned": [0, 1]}, {"damping_mass": 50.0}):
        sim = ModalMuscle.from_mesh(beam2d(2.0, 0.5, 8, 2), n_muscles=1, n_weights=3, n_clusters=4, h=0.01, **kw)
        monitor = MotionMonitor(sim, gravity=[0.0, -9.8])
        for step in range(1, 10):  # held still, 0.1 above the ground, against gravity
            monitor.update(step, state_of(sim, rest), clearance=0.1)
        assert monitor.finish(warn=False)["first_problem_step"] == {}
    # the same for a free body is hovering, from its first still step; a body on the ground is not
    sim = ModalMuscle.from_mesh(beam2d(2.0, 0.5, 8, 2), n_muscles=1, n_weights=3, n_clusters=4, h=0.01)
    for clearance, expected in ((0.1, {"hover": 1}), (1e-4, {})):
        monitor = MotionMonitor(sim, gravity=[0.0, -9.8])
        for step in range(1, 10):
            monitor.update(step, state_of(sim, rest), clearance=clearance)
        assert monitor.finish(warn=False)["first_problem_step"] == expected


def test_a_body_sinking_through_the_ground_between_its_contact_candidates_is_reported():
    # three candidates let a caterpillar fall through the ground (118 % of its size with one), reported as physical
    with pytest.warns(MotionWarning) as caught:
        summary = run_scene(_ground_scene("coulomb", 0.01, 60, contacts=3), None)
    motion, ground = summary["motion"], summary["ground"]
    assert not motion["physical"] and set(motion["first_problem_step"]) == {"sink"}
    assert motion["deepest_body_sizes"] == ground["worst_penetration_relative"] > 0.1
    (text,) = [str(w.message) for w in caught if "into the ground" in str(w.message)]
    assert "deeper than the Coulomb contact's allowance (0.0002): it holds only its contact candidates (3 of" in text
    assert 'take them all (ground.contacts = "all", the default)' in text
    # every boundary vertex a candidate (the default): held, nothing said
    with warnings.catch_warnings():
        warnings.simplefilter("error", MotionWarning)
        held = run_scene(_ground_scene("coulomb", 0.01, 60), None)["motion"]
    assert held["physical"] and 0.0 < held["deepest_body_sizes"] <= 2e-4


def test_a_thin_body_sinking_deeper_than_its_thickness_allows_is_reported():
    # a 30:1 strip held at its ends only sags between them: its allowance is 2e-4 of 3 times its thickness (6e-4),
    # but the motion check compared the depth with 2e-4 of its length (6e-3): 0.011 deep was "physical"
    scene = {
        "mesh": {"shape": "beam2d", "params": {"length": 30.0, "height": 1.0, "nx": 60, "ny": 2}},
        "material": {"mu": 1e10, "rho": 1e3},
        "subspace": {"weights": 8, "clusters": 16},
        "muscles": {"count": 0},
        "gravity": {"acceleration": [0.0, -9.81]},
        "time": {"step": 0.01, "steps": 200},
        "ground": {"offset": 0.0, "contacts_where": ["x <= 0.5", "x >= 29.5"]},
    }
    with pytest.warns(MotionWarning) as caught:
        summary = run_scene(Scene.from_dict(scene), None)
    motion = summary["motion"]
    assert not motion["physical"] and set(motion["first_problem_step"]) == {"sink"}
    assert 2 * 6e-4 < summary["ground"]["worst_penetration"] < 2 * 6e-3  # between the two limits
    of_allowance = summary["ground"]["worst_penetration"] / 6e-4  # (its boundary: the deepest is on it)
    assert summary["ground"]["worst_penetration_of_allowance"] == pytest.approx(of_allowance, rel=1e-9)
    (text,) = [str(w.message) for w in caught if "into the ground" in str(w.message)]
    assert "deeper than the Coulomb contact's allowance (0.0002 of its size, or of 3 times a thin part's " in text


def test_the_reference_contacts_feet_may_sink_a_little_but_not_a_quarter_of_the_body():
    monitor_of = lambda summary: summary["motion"]  # noqa: E731
    # its 30 points at h = 0.01: the feet sink a few percent by design, not reported
    with warnings.catch_warnings():
        warnings.simplefilter("error", MotionWarning)
        small = monitor_of(run_scene(_ground_scene("reference", 0.01, 60), None))
    assert small["physical"] and 0.0 < small["deepest_body_sizes"] < 0.25
    # four points (the corners of the bottom): the belly between them goes through
    with pytest.warns(MotionWarning, match=r"the reference contact holds only its sampled points"):
        deep = monitor_of(run_scene(_ground_scene("reference", 0.01, 60, contacts=4), None))
    assert not deep["physical"] and "sink" in deep["first_problem_step"] and deep["deepest_body_sizes"] > 0.25


def test_the_reference_contact_at_a_huge_step_is_reported_not_crashed():
    # at h = 1000 a new contact set's Gram matrix underflowed (1e-319): 'Singular matrix', exit 2, outputs written
    scene = Scene.from_dict(
        {
            "mesh": {"shape": "creature"},
            "muscles": {"count": 4, "gait": {"amplitude": [0.4] * 4, "period": [1.0, 0.8, 0.6, 0.9]}},
            "time": {"step": 1000.0, "steps": 10},
            "gravity": {"acceleration": [0.0, 0.0, -9.8]},
            "ground": {"model": "reference"},
        }
    )
    with pytest.warns(MotionWarning, match=r"the time step h = 1000 may be too large for this scene"):
        summary = run_scene(scene, None)
    assert summary["status"] == "completed" and not summary["motion"]["physical"]
    # (what else it reports at h = 1000 turns on round-off: sinking went with the modes' last digits)
    assert "push" in summary["motion"]["first_problem_step"]


def test_a_steps_failing_linear_algebra_is_a_simulation_error_naming_it(beam_sim, monkeypatch):
    sim = ModalMuscle.from_mesh(beam2d(2.0, 0.5, 8, 2), n_muscles=1, n_weights=3, n_clusters=4, h=0.01,
                                gravity=[0.0, -9.8], ground=-0.3, contact_model="reference")  # fmt: skip

    def singular(*args, **kwargs):
        raise np.linalg.LinAlgError("Singular matrix")

    monkeypatch.setattr(sim.model.contact, "project", singular)
    z, z_dot, _ = sim.rest_state()
    failed = r"the step's linear algebra failed: Singular matrix \(time step h = 0.01\)"
    with pytest.raises(SimulationError, match=failed):
        sim.step(z, z_dot)


def _soft_box(mu, steps):
    return {
        "mesh": {"shape": "box3d"},
        "material": {"mu": mu},
        "muscles": {"count": 0},
        "gravity": {"acceleration": [0.0, -9.81, 0.0]},
        "ground": {"offset": 0.0},
        "time": {"steps": steps, "step": 0.01},
    }


def test_a_body_turned_inside_out_is_reported_though_its_boundary_holds_the_ground(tmp_path):
    """A box of mu = 3e3 (3.3 times mu / (rho g)) folds under its weight (an audit: 1502 of 3072 tetrahedra
    inverted, a vertex 3.9 % of its size below the ground, while summary.json said physical, no warnings)."""
    with pytest.warns(MotionWarning, match="of the elements were inside out"):
        summary = run_scene(Scene.from_dict(_soft_box(3e3, 60)), tmp_path / "soft", every=10)
    motion = summary["motion"]
    assert not motion["physical"] and motion["inverted_elements"] > 300
    assert motion["first_problem_step"]["inverted"] % 10 == 0  # found in a frame written
    assert "too soft to carry the body's own weight" in motion["warnings"][-1]
    # the depth reported covers every vertex of the frames (it said 1.9e-4, the boundary's, where an
    # inner vertex was 8.4e-2 below)
    import meshio

    from skfem_modal.plot import read_run

    paths = [path for _, path in read_run(tmp_path / "soft")["frames"]]
    deepest = max(float(-meshio.read(path).points[:, 1].min()) for path in paths)  # the ground at 0
    assert summary["ground"]["worst_penetration"] == pytest.approx(deepest, rel=1e-12)
    # and so does the motion's, the same number (it was the boundary's after each step, 100 times less)
    assert motion["deepest_body_sizes"] == summary["ground"]["worst_penetration_relative"] > 0.05
    # a stiff one does not fold; and without files the last state is checked (the soft one folds there too)
    with warnings.catch_warnings():
        warnings.simplefilter("error", MotionWarning)
        stiff = run_scene(Scene.from_dict(_soft_box(3e5, 60)), None)["motion"]
    assert stiff["physical"] and stiff["inverted_elements"] == 0
    with pytest.warns(MotionWarning, match="of the elements were inside out"):
        assert run_scene(Scene.from_dict(_soft_box(3e3, 60)), None)["motion"]["inverted_elements"] > 300


def _hard_landing():
    """A unit square dropped from 100 sizes at h = 0.02: at 44 m/s it folds through itself for a few steps."""
    return {
        "mesh": {"shape": "beam2d", "params": {"length": 1.0, "height": 1.0, "nx": 8, "ny": 8}},
        "material": {"mu": 1e5},
        "muscles": {"count": 0},
        "gravity": {"acceleration": [0.0, -9.8]},
        "ground": {"offset": 100.0},
        "time": {"steps": 240, "step": 0.02},
    }


@pytest.mark.parametrize("every", [None, 5])
def test_a_body_folded_between_the_frames_by_a_hard_landing_is_reported(tmp_path, every):
    """An audit: 48 % of the square's triangles inside out for a few steps after it landed, between the frames
    written (every 5 steps, or none), and the run said physical: the states after a jolt are checked too."""
    out = None if every is None else tmp_path / "run"
    with pytest.warns(MotionWarning, match="of the elements were inside out"):
        summary = run_scene(Scene.from_dict(_hard_landing()), out, every=every or 1)
    motion = summary["motion"]
    assert not motion["physical"] and motion["inverted_elements"] > 0.3 * 128
    assert motion["first_problem_step"]["inverted"] == 226  # the landing, t = 4.52 (not a frame written)
    assert summary["ground"]["worst_penetration_relative"] > 0.5  # an inner vertex, through the folded elements
    # a rollout (states kept, no frames) finds it too, given the positions; its last state is unfolded
    sim = Scene.from_dict(_hard_landing()).build()
    z, z_dot, _ = sim.rest_state()
    states = [z]
    for _ in range(240):
        z, z_dot = sim.step(z, z_dot, velocity=True)
        states.append(z)
    monitor = MotionMonitor(sim, [0.0, -9.8])
    assert monitor.run_problems(np.array(states), None, sim.positions) == {"inverted": 226}
    assert monitor._inverted(sim.positions(states[-1])) == 0


def test_a_hard_landing_at_a_small_time_step_is_a_jolt_too():
    """An audit: per step, the same landing at h = 0.001 was 0.0033 of JOLT's 0.01, and the square folded through
    itself between the frames written unreported: summed over the time a wave crosses the body, it is a jolt."""
    data = _hard_landing()
    data["time"] = {"steps": 4700, "step": 0.001}  # it lands at t = 4.52
    with pytest.warns(MotionWarning, match="of the elements were inside out"):
        summary = run_scene(Scene.from_dict(data), None)
    motion = summary["motion"]
    assert not motion["physical"] and 4520 <= motion["first_problem_step"]["inverted"] <= 4560
    # a rollout's check of its kept states finds it as well
    sim = Scene.from_dict(data).build()
    z, z_dot, _ = sim.rest_state()
    states = [z]
    for _ in range(4700):
        z, z_dot = sim.step(z, z_dot, velocity=True)
        states.append(z)
    found = MotionMonitor(sim, [0.0, -9.8]).run_problems(np.array(states), None, sim.positions)
    assert 4520 <= found["inverted"] <= 4560


def test_the_examples_crawls_are_not_jolted():
    """The states after a jolt cost a check of every element: a crawl's steps are not jolts (0.002 of JOLT's 0.01)."""
    scene = Scene.from_dict(copy.deepcopy(DEFAULT_SCENE))
    sim = scene.build()
    monitor = MotionMonitor(sim, scene.config["gravity"]["acceleration"])
    z, z_dot, _ = sim.rest_state()
    jolted = []
    for step in range(1, 201):
        a = scene.activation(step * sim.h, sim.ceilings)
        z, z_dot = sim.step(z, z_dot, a, velocity=True)
        jolted.append(monitor.update(step, z, a))
    assert not any(jolted)


def test_a_floating_body_turned_inside_out_is_not_told_of_a_ground():
    """An audit: the warning of a floating body folded through itself spoke of vertices below the ground."""
    scene = _soft_box(3e3, 30)
    del scene["ground"]
    scene["gravity"] = None
    scene = {key: value for key, value in scene.items() if value is not None}
    scene["muscles"] = {"count": 2, "gait": {"amplitude": [60.0, -60.0], "period": [0.3, 0.2]}}
    with pytest.warns(MotionWarning) as caught:
        summary = run_scene(Scene.from_dict(scene), None)
    inverted = [w for w in summary["motion"]["warnings"] if "were inside out" in w]
    assert inverted and inverted[0].endswith("the body folded through itself")
    assert not any("ground" in str(w.message) for w in caught)


def test_pins_that_let_go_are_reported(tmp_path):
    """An audit: pins of stiffness 1e-6 let a pinned beam fall 80 units, reported as physical, no warning."""
    import tomllib
    from pathlib import Path

    example = Path(__file__).resolve().parent.parent / "examples" / "beam_pinned.toml"
    data = tomllib.loads(example.read_text())
    data["muscles"].pop("table", None)
    data["gravity"] = {"acceleration": [0.0, -9.8]}
    data["time"] = {"step": 0.01, "steps": 60}
    held = run_scene(Scene.from_dict(data), tmp_path / "held", every=10)
    size = held["motion"]["body_size"]
    assert held["motion"]["physical"] and held["pinned"]["worst_drift_written_frames"] < 4e-4 * size
    data["pinned"]["stiffness"] = 1e-6
    with pytest.warns(MotionWarning, match=r"the pinned vertices drifted from their pins, up to .* the pins let go"):
        loose = run_scene(Scene.from_dict(data), tmp_path / "loose", every=10)
    assert not loose["motion"]["physical"] and loose["pinned"]["worst_drift_written_frames"] > 0.01 * size
    # read every step, not in the frames written only (with frames every 600 steps an audit's pins let go unsaid)
    with pytest.warns(MotionWarning, match=r"the pinned vertices drifted"):
        unwritten = run_scene(Scene.from_dict(data), tmp_path / "unwritten", every=1000)
    first = loose["motion"]["first_problem_step"]["pins"]
    assert unwritten["motion"]["first_problem_step"]["pins"] == first and first % 10 != 0


def test_the_motions_depth_is_the_summarys(tmp_path):
    """A new user's trial: a box starting 1e-4 into the ground (within the allowance) had the ground's
    worst_penetration_relative 1.0e-4 but the motion's deepest_body_sizes 5e-5, the start left out."""
    scene = Scene.from_dict(
        {
            "mesh": {"shape": "box3d"},
            "muscles": {"count": 0},
            "time": {"steps": 50},
            "gravity": {"acceleration": [0.0, 0.0, -9.8]},
            "ground": {"height": 1e-4},
        }
    )
    summary = run_scene(scene, tmp_path / "run")
    deepest = summary["ground"]["worst_penetration_relative"]
    assert summary["motion"]["deepest_body_sizes"] == deepest == pytest.approx(1e-4, rel=1e-9)


def _held_box(**changes):
    data = {
        "mesh": {"shape": "box3d", "params": {"nx": 4, "ny": 4, "nz": 2, "size": [1.0, 1.0, 0.5]}},
        "material": {"mu": 1e6, "rho": 1e3},
        "muscles": {"count": 0},
        "time": {"step": 0.5, "steps": 10},
        "gravity": {"acceleration": [0.0, 0.0, -9.8]},
        "ground": {"offset": 0.0},
    }
    data.update(changes)
    return Scene.from_dict({key: value for key, value in data.items() if value is not None})


@pytest.mark.parametrize(
    "changes",
    [
        {"ground": None, "damping": {"mass": 50.0}},  # falling at its drag's terminal speed
        {"ground": {"height": -1e4}, "damping": {"mass": 50.0}},  # the same over a ground it never reaches
        {"ground": None, "pinned": {"where": ["x == min"]}},
        {"ground": {"height": -1e4}, "pinned": {"where": ["x == min"]}},
        {"gravity": {"acceleration": [4.9, 0.0, -8.487]}, "ground": {"offset": 0.0, "friction": 0.0}},  # sliding
    ],
)
def test_what_holds_the_weight_is_no_push(changes, tmp_path):
    """A review: the ground's exemption held whether or not the body touched it (drag over a far ground was
    physical, without one not), and on a slope it left the normal force's share across gravity (1.06 body
    sizes, 'not resolved'). Pins, drag and a ground under the body all hold the weight: no push."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MotionWarning)
        motion = run_scene(_held_box(**changes), tmp_path / "run")["motion"]
    assert motion["physical"] and motion["largest_push_body_sizes"] < 0.01, motion["first_problem_step"]


def test_a_rollout_whose_step_aliases_its_gait_is_not_physical():
    """A review: the searches' rollouts skipped the gait check, so a search could pick a gait that run refuses."""
    from skfem_modal.rollouts import Trial

    trial = Trial.from_scene(copy.deepcopy(DEFAULT_SCENE), steps=20, direction=[-1.0, 0.0])
    gait = {"amplitude": [0.2] * 4, "phase": [0.0] * 4}
    assert not trial.run({**gait, "period": [0.015] * 4})["physical"]  # 1.5 steps a period
    assert trial.run({**gait, "period": [0.5] * 4})["physical"]


def test_the_run_line_says_whose_share_of_the_allowance_it_prints(tmp_path, capsys):
    # "deepest any vertex went below the ground: 0.345 (17 % ...; 25.3 % of its allowance)" paired the depth of
    # any vertex (one inside a body folded through itself) with the share of the deepest boundary vertex
    path = tmp_path / "drop.toml"
    path.write_text(
        '[mesh]\nshape = "caterpillar"\nparams = { nx = 24, ny = 12 }\n[subspace]\nweights = 6\nclusters = 8\n'
        "[muscles]\ncount = 0\n[gravity]\nacceleration = [0.0, -9.8]\n[ground]\noffset = 0.05\n"
        "[time]\nstep = 0.01\nsteps = 40\n"
    )
    assert main(["run", str(path), "--out", str(tmp_path / "out")]) == 0
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    share = 100 * summary["ground"]["worst_penetration_of_allowance"]
    assert 1.0 < share <= 100.0  # landed, held
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("deepest any vertex"))
    assert f"; the deepest boundary vertex {share:.3g} % of its allowance)" in line


@pytest.mark.parametrize("offset", [0.0, 1e4, 1e8])
def test_a_body_far_from_the_origin_has_its_own_spread(offset):
    """An audit: a box 1e8 from the origin had a spread of 0 at rest (E[x^2] - mean^2 cancels), and its run
    stopped on a division by zero (exit 1)."""
    from skfem import MeshTet

    box = MeshTet.init_tensor(np.linspace(0, 2, 5), np.linspace(0, 1, 3), np.linspace(0, 0.5, 3))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # (far from the origin: warned)
        sim = ModalMuscle.from_mesh(MeshTet(box.p + offset, box.t), n_muscles=1, n_weights=3, n_clusters=4, h=0.01)
    monitor = MotionMonitor(sim)
    x = box.p.T - box.p.T.mean(axis=0)
    exact = np.sqrt((x**2).sum(axis=1).mean())  # 0.8416
    assert monitor.rest_spread == pytest.approx(exact, rel=1e-12 if offset < 1e6 else 1e-6)
    z, _, _ = sim.rest_state()
    assert not monitor.update(1, z) and monitor.finish()["physical"]


def two_squares(big=2, small=2, gap=3.0):
    """A unit square and a second one ``gap`` to its right, refined ``big`` and ``small`` times: two bodies."""
    from skfem import MeshTri

    a, b = MeshTri.init_sqsymmetric().refined(big), MeshTri.init_sqsymmetric().refined(small)
    return MeshTri(np.hstack([a.p, b.p + [[gap], [0.0]]]), np.hstack([a.t, b.t + a.p.shape[1]]))


def test_each_body_of_a_mesh_is_watched_alone_for_spread_hovering_and_folding():
    """An audit: two squares, one pinned and one falling, "grew to 9.02 times their rest size"; pins on one body
    kept the other, free, from being seen hovering; a small square with 52 % of its triangles inside out beside a
    large one went unreported (1 % of the whole mesh's)."""
    mesh = two_squares()
    left = np.flatnonzero(mesh.p[0] <= 1.0)
    sim = ModalMuscle.from_mesh(mesh, n_muscles=0, n_weights=4, n_clusters=4, h=0.01, pinned=left)
    rest = mesh.p.T
    right = mesh.p[0] > 1.0
    monitor = MotionMonitor(sim, gravity=[0.0, -9.8])
    for step in range(1, 10):  # the free square falls 5 sizes: each body keeps its spread
        fallen = rest - [0.0, 5.0 * step / 9] * right[:, None]
        monitor.update(step, state_of(sim, fallen))
    report = monitor.finish(warn=False)
    assert report["first_problem_step"] == {} and report["spread_ratio"] == pytest.approx([1.0, 1.0], abs=1e-9)
    # held still 0.1 above the ground: the pinned square is held, the free one hovers
    monitor = MotionMonitor(sim, gravity=[0.0, -9.8])
    for step in range(1, 10):
        monitor.update(step, state_of(sim, rest), clearance=np.array([0.1, 0.1]))
    assert monitor.finish(warn=False)["first_problem_step"] == {"hover": 1}
    # the small square of a mesh of 8224 triangles turned inside out (its 32): a body folded
    mesh = two_squares(big=5, small=1)
    sim = ModalMuscle.from_mesh(mesh, n_muscles=0, n_weights=4, n_clusters=4, h=0.01)
    small = mesh.p[0] > 1.0
    mirrored = mesh.p.T.copy()
    mirrored[small, 0] = 7.0 - mirrored[small, 0]
    monitor = MotionMonitor(sim)
    assert monitor.check_elements(1, mirrored) == 32 and 32 < 0.01 * mesh.t.shape[1]
    report = monitor.finish(warn=False)
    assert report["first_problem_step"] == {"inverted": 1}
    assert "more than 1 % of the elements of a body of the mesh were inside out" in report["warnings"][0]


def test_a_gait_of_exactly_two_steps_a_period_is_aliased(beam_sim):
    # read at the same two phases each period: a plain sine at its zeros (an audit: h = 0.3, period 0.6, the
    # muscle commanded 1.7e-15 and reported physical)
    for period, expected in ((0.02, {"gait": 1}), (0.0201, {})):
        assert MotionMonitor(beam_sim, gait_period=period).finish(warn=False)["first_problem_step"] == expected
