"""Scenes: validation with clear errors, effects built only when named."""

import copy
import pathlib
import warnings

import numpy as np
import pytest

from skfem_modal.contact import CoulombContact, ReferenceContact
from skfem_modal.muscles import sine_gait
from skfem_modal.run import run_scene
from skfem_modal.scene import DEFAULT_SCENE, SCHEMA, Scene, SceneError, schema_markdown

EXAMPLES = pathlib.Path(__file__).resolve().parents[1] / "examples"
DOCS = pathlib.Path(__file__).resolve().parents[1] / "docs"


def scene_with(**changes):
    data = copy.deepcopy(DEFAULT_SCENE)
    for path, value in changes.items():
        keys = path.split("__")
        target = data
        for k in keys[:-1]:
            target = target.setdefault(k, {})
        if value is None:
            target.pop(keys[-1], None)
        else:
            target[keys[-1]] = value
    return data


def test_default_scene_is_the_tutorial_crawl():
    scene = Scene.default()
    assert scene.effects == ("elasticity", "inertia", "muscles", "gravity", "contact")
    assert scene.n_steps == 450 and scene.h == 0.01
    # the tutorial's floor: 0.15 below the feet, which it prints as "ground at y = -0.720"
    assert scene.ground_height() == pytest.approx(float(scene.mesh.p[1].min()) - 0.15, abs=1e-15)
    assert round(scene.ground_height(), 3) == -0.720
    assert scene.material() == {"mu": 1e6, "gamma": 1e6, "lam": 1e6, "rho": 1e3}
    expected = np.array([0.45, 0.35, 0.25, 0.15]) * np.sin(2 * np.pi * np.array([0.0, 0.25, 0.5, 0.1]))
    np.testing.assert_allclose(scene.activation_fractions(0.0), expected)


@pytest.mark.parametrize(
    "changes, message",
    [
        (dict(ground__hieght=1.0), r"ground.hieght: unknown key; expected one of height, offset"),
        (dict(time__step="fast"), r"time.step: expected a finite number, got 'fast' \(str\)"),
        (dict(time__step=-0.01), r"time.step: expected a positive number, got -0.01"),
        (dict(ground__stickiness=1.5), r"ground.stickiness: expected a number in \[0, 1\], got 1.5"),
        (
            dict(ground__allowance=0.005),
            r"ground.allowance: expected a number from 1e-10 \(less is lost in round-off\) to 0.001, got 0.005",
        ),
        (dict(ground__allowance=0.0), r"ground.allowance: expected a number from 1e-10 .* to 0.001, got 0.0"),
        (dict(ground__allowance=1e-16), r"ground.allowance: expected a number from 1e-10 .* to 0.001, got 1e-16"),
        (
            dict(ground__model="reference", ground__allowance=1e-3),
            r"ground.allowance: a setting of the other contact model, not of model = 'reference'",
        ),
        (
            dict(ground__model="reference", ground__exact_friction=False),
            r"ground.exact_friction: a setting of the other contact model, not of model = 'reference'",
        ),
        (dict(ground__exact_friction="no"), r"ground.exact_friction: expected true or false"),
        (dict(subspace__weights=2.5), r"subspace.weights: expected an integer, got 2.5"),
        (
            dict(mesh__shape=None, mesh__params=None, mesh__file="nowhere.msh"),
            r"mesh.file: no such file '.*nowhere.msh'",
        ),
        (
            dict(mesh__shape="blob"),
            r"mesh.shape: expected one of \['beam2d', 'beam3d', 'box3d', 'caterpillar', 'creature'\], got 'blob'",
        ),
        (
            dict(gravity__acceleration=[0.0, 0.0, -9.8]),
            r"gravity.acceleration: expected 2 values for this 2D mesh, got 3",
        ),
        (dict(muscles__gait__period=[1.0, 1.0]), r"muscles.gait.period: expected 4 values \(muscles.count\), got 2"),
        (dict(muscles__signs=[1, -1, 2, 1]), r"muscles.signs: expected a list of \+1 and -1, got \[1, -1, 2, 1\]"),
        (dict(mesh__params={"nx": 0}), r"mesh: caterpillar: nx and ny must be at least 2"),
        (dict(pinned={"where": ["q < 1"]}), r"pinned.where: cannot use 'q < 1'"),
        # a [pinned] section saying neither which vertices nor where crashed the checks after naming it
        (dict(pinned={}), r"1 problem\(s\) in the scene:\n  pinned: give where \(conditions\) or box, exactly one$"),
        (dict(pinned={"stiffness": 1.0}), r"pinned: give where \(conditions\) or box, exactly one$"),
        (dict(pinned={"where": []}), r"pinned.where: expected at least one condition, got \[\]"),
        (dict(ground__contacts_where=[]), r"ground.contacts_where: expected at least one condition, got \[\]"),
        # caught by the simulator only after the precompute, naming its own argument
        (dict(time__iterations=10**6), r"time.iterations: expected an integer from 1 to 100000, got 1000000"),
        (dict(ground__contacts=0), r"ground.contacts: expected an integer >= 1 or \"all\", got 0"),
        (dict(muscles__gait__amplitude=None), r"muscles.gait.amplitude: required"),
        (dict(muscles__gait__ramp=-0.5), r"muscles.gait.ramp: expected a number >= 0, got -0.5"),
        # ran without a word, the muscles commanded and nothing moving
        (dict(material__gamma=0.0), r"material.gamma: 0 leaves the 4 muscles without any force; give gamma > 0"),
        # said three times as "expected 0 values"
        (dict(muscles__count=0, muscles__signs=None), r"1 problem\(s\).*\n  muscles.gait: a gait for no muscles \("),
        (dict(time__duration=2.0), r"time: give duration or steps, not both"),
        (
            dict(ground__offset=None, ground__height=0.0),
            r"ground.height: the body starts inside the ground: its lowest vertex \(y = -0.570099\) is 0.5701 "
            r"\(28.5 % of its size\) below the ground at 0",
        ),
    ],
)
def test_scene_errors_name_key_value_and_expectation(changes, message):
    with pytest.raises(SceneError, match=message):
        Scene.from_dict(scene_with(**changes))


def test_a_ramped_gait_is_the_scenes_gait_from_the_ramp_on():
    plain, ramped = Scene.default(), Scene.from_dict(scene_with(muscles__gait__ramp=0.4))
    ceilings = np.array([2.0, 3.0, 5.0, 7.0])
    assert not np.any(ramped.activation(0.0, ceilings)) and not np.any(ramped.activation_fractions(0.0))
    np.testing.assert_allclose(ramped.activation(0.2, ceilings), 0.5 * plain.activation(0.2, ceilings), rtol=1e-15)
    for t in (0.4, 0.63, 2.0):  # bit for bit: a ramp that is over changes nothing
        np.testing.assert_array_equal(ramped.activation(t, ceilings), plain.activation(t, ceilings))
        np.testing.assert_array_equal(ramped.activation_fractions(t), plain.activation_fractions(t))
    # and a script's sine_gait with the same ramp steps bit for bit the same as the scene
    gait = ramped.config["muscles"]["gait"]
    for t in (0.1, 0.3, 0.5):
        amplitudes = np.asarray(gait["amplitude"]) * ceilings
        np.testing.assert_array_equal(
            ramped.activation(t, ceilings), sine_gait(t, amplitudes, gait["period"], gait["phase"], gait["ramp"])
        )


def test_all_errors_are_reported_at_once():
    with pytest.raises(SceneError) as info:
        Scene.from_dict(scene_with(time__step=0, ground__stickiness=-1, extra=3))
    text = str(info.value)
    assert (
        "3 problem(s)" in text and "extra: unknown key" in text and "time.step" in text and "ground.stickiness" in text
    )


@pytest.mark.parametrize("section", [k for k in SCHEMA if not k.startswith("_") and isinstance(SCHEMA[k], dict)])
def test_a_section_that_is_not_a_table_is_one_named_error(section):
    data = {"mesh": {"shape": "caterpillar"}, section: 3}
    with pytest.raises(SceneError) as caught:
        Scene.from_dict(data)
    assert str(caught.value).splitlines()[1:] == [f"  {section}: expected a table, got 3"]


def test_a_scenes_configuration_loads_back():
    # summary.json keeps the scene as to_dict() gives it: absent keys and sections as null
    for scene in (Scene.default(), Scene.from_toml(EXAMPLES / "creature_crawl.toml")):
        data = scene.to_dict()
        assert data.pop("source") == scene.source
        again = Scene.from_dict(data, base_dir=str(EXAMPLES))
        assert again.config == scene.config


def test_toml_errors(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[time\nstep = 1\n")
    with pytest.raises(SceneError, match="not valid TOML") as refused:
        Scene.from_toml(bad)
    assert "is not a scene" not in str(refused.value)
    # a mesh given where a scene goes (skfem-modal run seal.mesh) said only "not valid TOML" (an audit)
    with pytest.raises(SceneError, match=r"not valid TOML: .*\(a \.mesh file is not a scene: to simulate a mesh, "):
        (tmp_path / "seal.mesh").write_text("MeshVersionFormatted 2\nDimension 3\nVertices\n")
        Scene.from_toml(tmp_path / "seal.mesh")
    with pytest.raises(FileNotFoundError, match="scene file not found"):
        Scene.from_toml(tmp_path / "missing.toml")
    good = tmp_path / "s.toml"
    good.write_text('[mesh]\nfile = "m.vtu"\n')
    with pytest.raises(SceneError, match=r"(?s)s.toml: 1 problem.*mesh.file: no such file '.*m.vtu'"):
        Scene.from_toml(good)


def test_floating_scene_holds_no_contact_or_gravity(monkeypatch):
    scene = Scene.from_toml(EXAMPLES / "caterpillar_float.toml")
    assert scene.effects == ("elasticity", "inertia", "muscles")
    sim = scene.build()
    assert sim.effects == ("elasticity", "inertia", "muscles")
    assert sim.ground is None and sim.gravity is None and sim.contact_vertices.size == 0

    def forbidden(*args, **kwargs):
        raise AssertionError("contact code called in a floating scene")

    for model in (CoulombContact, ReferenceContact):
        monkeypatch.setattr(model, "project", forbidden)
        monkeypatch.setattr(model, "start_step", forbidden)
    summary = run_scene(scene, None, sim=sim)
    assert summary["status"] == "completed" and summary["ground"] is None
    assert np.abs(summary["com"]["travel"]).max() < 1e-8


def test_effects_follow_the_sections():
    base = scene_with(gravity=None, ground=None)
    assert Scene.from_dict(base).effects == ("elasticity", "inertia", "muscles")
    with_damping = dict(base, damping={"mass": 0.5})
    scene = Scene.from_dict(with_damping)
    assert scene.effects == ("elasticity", "inertia", "muscles", "damping")
    assert scene.build().effects == scene.effects
    none = dict(base, muscles={"count": 0})
    assert Scene.from_dict(none).build().effects == ("elasticity", "inertia")


def test_activation_table_is_interpolated(tmp_path):
    (tmp_path / "acts.csv").write_text("time,a,b\n0,0,0\n1,1,-1\n2,1,0.5\n")
    data = scene_with(muscles__count=2, muscles__signs=None, muscles__gait=None, muscles__table="acts.csv")
    scene = Scene.from_dict(data, base_dir=str(tmp_path))
    np.testing.assert_allclose(scene.activation_fractions(0.5), [0.5, -0.5])
    np.testing.assert_allclose(scene.activation_fractions(1.5), [1.0, -0.25])
    np.testing.assert_allclose(scene.activation_fractions(9.0), [1.0, 0.5])  # held after the end
    (tmp_path / "short.csv").write_text("time,a\n0,0\n")
    data["muscles"]["table"] = "short.csv"
    with pytest.raises(SceneError, match=r"short.csv' line 2 has 2 columns, expected 3"):
        Scene.from_dict(data, base_dir=str(tmp_path))
    # no header: its first row was read as one and lost (activation 0.2 at t = 0 where the file says 0.1)
    (tmp_path / "bare.csv").write_text("0,0.1,0.1\n1,0.2,0.2\n")
    data["muscles"]["table"] = "bare.csv"
    with pytest.raises(SceneError, match=r"bare.csv' line 1 holds numbers, not a header: .*\(e.g. time,a1,a2\)"):
        Scene.from_dict(data, base_dir=str(tmp_path))


def test_pinned_beam_stays_pinned_and_moves():
    scene = Scene.from_toml(EXAMPLES / "beam_pinned.toml")
    sim = scene.build()
    assert sim.effects == ("elasticity", "inertia", "muscles", "pinned", "damping")
    clamp = scene.pinned_vertices()
    assert clamp.size == 5 and np.all(scene.mesh.p[0, clamp] == 0.0)
    summary = run_scene(scene, None, sim=sim)
    # the clamp holds within 0.1 % of the beam's length while the tip swings
    assert summary["pinned"] is None  # not written: no frames without an output directory
    z, z_dot, _ = sim.rest_state()
    x_max_tip, drift = 0.0, 0.0
    tip = np.argmax(scene.mesh.p[0])
    for i in range(200):
        a = scene.activation(i * sim.h, sim.ceilings)
        z_next = sim.step(z, z_dot, a)
        z_dot, z = (z_next - z) / sim.h, z_next
        x = sim.positions(z)
        drift = max(drift, np.abs(x[clamp] - scene.mesh.p.T[clamp]).max())
        x_max_tip = max(x_max_tip, abs(x[tip, 1] - scene.mesh.p[1, tip]))
    assert drift < 4e-3
    assert x_max_tip > 0.2


def test_damping_removes_energy():
    base = scene_with(gravity=None, ground=None, muscles={"count": 0}, time={"step": 0.01, "steps": 100})
    results = {}
    for alpha in (0.0, 2.0):
        scene = Scene.from_dict(dict(base, damping={"mass": alpha}) if alpha else base)
        sim = scene.build()
        z, _, _ = sim.rest_state()
        z_dot = np.random.default_rng(0).standard_normal(z.size) * 0.05
        for _ in range(100):
            z_next = sim.step(z, z_dot, None)
            z_dot, z = (z_next - z) / sim.h, z_next
        results[alpha] = sim.kinetic_energy(z_dot)
    assert results[2.0] < 0.5 * results[0.0]


def test_scene_reference_documents_every_key():
    text = (DOCS / "scenes.md").read_text()
    assert schema_markdown() in text, "docs/scenes.md is stale: run python scripts/update_scene_reference.py"

    def leaves(spec, prefix):
        for key, value in spec.items():
            if key.startswith("_"):
                continue
            if isinstance(value, dict):
                assert f"`[{prefix}{key}]`" in text
                yield from leaves(value, f"{prefix}{key}.")
            else:
                yield key

    for key in leaves(SCHEMA, ""):
        assert f"| `{key}` |" in text


@pytest.mark.parametrize(
    "name", ["caterpillar_crawl", "caterpillar_crawl_searched", "caterpillar_float", "creature_crawl", "beam_pinned"]
)
def test_example_scenes_validate(name):
    scene = Scene.from_toml(EXAMPLES / f"{name}.toml")
    assert scene.n_steps >= 100


def test_a_runs_scene_builds_again_and_numpy_numbers_are_numbers(tmp_path):
    # Scene.to_dict (summary.json's scene) held 'source', refused as an unknown key; np.int64 counts
    # were 'expected an integer', arrays and tuples 'expected a list'
    scene = Scene.from_dict(DEFAULT_SCENE)
    again = Scene.from_dict(scene.to_dict())
    assert again.config == scene.config and again.source == scene.source
    data = {
        "mesh": {"shape": "caterpillar"},
        "muscles": {"count": np.int64(2), "gait": {"amplitude": np.array([0.1, 0.2]), "period": (1.0, np.float64(2))}},
    }
    muscles = Scene.from_dict(data).config["muscles"]
    assert muscles["count"] == 2 and type(muscles["count"]) is int
    assert muscles["gait"]["amplitude"] == [0.1, 0.2] and muscles["gait"]["period"] == [1.0, 2.0]


@pytest.mark.parametrize("given", ["scene.toml", {"mesh": {"shape": "caterpillar"}}])
def test_run_scene_names_what_it_takes(given):
    with pytest.raises(TypeError, match=r"run_scene takes a Scene, got (str|dict): Scene.from_toml\(path\)"):
        run_scene(given, None)


def test_a_run_of_billions_of_steps_is_named():
    # time.step = 1e-9 made 4.5e9 steps with the default duration, days of running, without a word
    with pytest.raises(SceneError, match=r"time: time.step = 1e-09 over 4.5 makes 4.5e\+09 steps, more than 1e\+08"):
        Scene.from_dict({"mesh": {"shape": "caterpillar"}, "time": {"step": 1e-9}})
    with pytest.raises(SceneError, match=r"time: time.steps makes 1e\+09 steps"):
        Scene.from_dict({"mesh": {"shape": "caterpillar"}, "time": {"steps": 10**9}})


def test_a_scene_file_not_in_utf8_is_named_and_one_with_a_byte_order_mark_reads(tmp_path):
    latin = tmp_path / "latin.toml"
    latin.write_bytes('name = "café"\n'.encode("latin-1"))
    with pytest.raises(SceneError, match=r"latin.toml: not UTF-8 text \(byte 11"):
        Scene.from_toml(latin)
    marked = tmp_path / "marked.toml"
    marked.write_bytes(b"\xef\xbb\xbf" + b'name = "marked"\n')
    assert Scene.from_toml(marked).config["name"] == "marked"
    table = tmp_path / "gait.csv"
    table.write_bytes("time,a1\n0,0.1\n1,é\n".encode("latin-1"))
    scene = tmp_path / "table.toml"
    scene.write_text('[muscles]\ncount = 1\ntable = "gait.csv"\n')
    with pytest.raises(SceneError, match=r"muscles.table: '.*gait.csv' is not UTF-8 text"):
        Scene.from_toml(scene)


def test_muscle_settings_without_muscles_are_said_to_change_nothing(tmp_path):
    """An audit: gamma, lam, active_clusters, max_s with muscles.count = 0 ran bit-identically, without a word."""
    table = tmp_path / "gait.csv"
    table.write_text("time,a1\n0,0.1\n1,0.2\n")
    data = {
        "mesh": {"shape": "caterpillar", "params": {"nx": 10, "ny": 5}},
        "material": {"gamma": 5e5, "lam": 3e5},
        "subspace": {"active_clusters": 3},
        "muscles": {"count": 0, "max_s": 1.0, "table": str(table)},
    }
    with pytest.warns(UserWarning, match="muscles.count = 0") as caught:
        Scene.from_dict(data)
    said = str(caught[0].message)
    for key in ("material.gamma", "material.lam", "muscles.table", "subspace.active_clusters", "muscles.max_s"):
        assert key in said
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        Scene.from_dict({"mesh": {"shape": "caterpillar", "params": {"nx": 10, "ny": 5}}, "muscles": {"count": 0}})


def test_scene_file_edges_found_by_an_audit_are_named(tmp_path):
    """A malformed number in a condition, a scale beyond float64, integers beyond a float: each named by its key
    with the scene's other problems (they were a bare float() error, the mesh's own message, a traceback)."""
    from skfem_modal.scene import SceneError

    def problems(text):
        path = tmp_path / "scene.toml"
        path.write_text(text)
        with pytest.raises(SceneError) as error:
            Scene.from_toml(path)
        return str(error.value)

    said = problems('[mesh]\nshape = "beam2d"\n[time]\nstep = -1\n[pinned]\nwhere = ["x <= 1.2.3"]\n')
    assert "time.step: expected a positive number" in said and "pinned.where: cannot use 'x <= 1.2.3'" in said
    said = problems('[mesh]\nshape = "box3d"\nscale = 1e305\n[time]\nstep = -1\n')
    assert "time.step" in said and "mesh.scale = 1e+305: makes the mesh 1e+305 across" in said
    huge = "1" + "0" * 400
    assert "time: time.steps makes over 1e300 steps" in problems(f'[mesh]\nshape = "beam2d"\n[time]\nsteps = {huge}\n')
    box = f'[mesh]\nshape = "beam2d"\n[pinned]\nbox = {{ min = [-{huge}, -1], max = [0.1, 5] }}\n'
    assert "pinned.box: expected { min = [2 finite numbers]" in problems(box)
    said = problems(
        '[mesh]\nshape = "caterpillar"\n[gravity]\nacceleration = [0, -9.8]\n[ground]\ncontacts_where = ["z <= 0"]\n'
    )
    assert "expected e.g. 'y <= 0.1' with an axis of this 2D mesh" in said


def test_a_table_that_starts_after_0_is_warned_of(tmp_path):
    """An audit: a table starting at t = 2 was held from t = 0, kicking a body at rest at its first step, unsaid."""
    (tmp_path / "late.csv").write_text("time,a\n2,0.5\n3,0.5\n")
    (tmp_path / "scene.toml").write_text('[mesh]\nshape = "beam2d"\n[muscles]\ncount = 1\ntable = "late.csv"\n')
    with pytest.warns(UserWarning, match=r"muscles.table 'late.csv' starts at t = 2, not 0: its first row is held"):
        Scene.from_toml(tmp_path / "scene.toml")
    (tmp_path / "late.csv").write_text("time,a\n0,0\n3,0.5\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        Scene.from_toml(tmp_path / "scene.toml")


def test_settings_that_change_nothing_in_the_scene_are_warned_of():
    """An audit: ground.exact_friction = false in 2D (a slide there has one direction) and subspace.cluster_weights
    with passive clusters by rotations (one muscle cluster) changed positions by exactly 0.0, unsaid."""
    ground = {"offset": 0.15, "model": "coulomb", "exact_friction": False}
    with pytest.warns(UserWarning, match="ground.exact_friction = false changes nothing in 2D"):
        Scene.from_dict(scene_with(ground=ground))
    rotations = scene_with(subspace__cluster_by="rotations", subspace__cluster_weights=4)
    with pytest.warns(UserWarning, match="cluster_weights = 4: .* so it shapes nothing here"):
        Scene.from_dict(rotations)
    rotations["subspace"]["active_clusters"] = 3
    with pytest.warns(UserWarning, match="so it shapes the muscles' clusters only"):
        Scene.from_dict(rotations)
    with pytest.warns(UserWarning, match=r"gravity.acceleration is zero: the gravity effect does nothing"):
        Scene.from_dict(scene_with(gravity__acceleration=[0.0, 0.0], ground=None))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # where they do something, nothing is said
        Scene.from_dict(scene_with(ground={**ground, "exact_friction": True}))
        Scene.from_dict(scene_with(subspace__cluster_weights=4))
