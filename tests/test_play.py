"""Play: the controller without a window (fake clock), the window under Xvfb, and the errors.

The window tests start their own Xvfb and drive the window in a subprocess
(``tests/play_window_driver.py``), so that a GL failure cannot take pytest
down with it. They are skipped only where Xvfb is not installed, and never
in CI (``CI`` set), where a missing Xvfb fails them.
"""

from __future__ import annotations

import ctypes
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from ci import unavailable

from skfem_modal.cli import main
from skfem_modal.play import Player, PlayError, play, play_problem, slider_ranges, virtual_display
from skfem_modal.scene import DEFAULT_SCENE, Scene
from skfem_modal.sim import SimulationError

HERE = Path(__file__).parent
EXAMPLES = HERE.parent / "examples"
MESHES = HERE.parent.parent / "shared" / "meshes"


class FakeClock:
    """Wall-clock time that moves only when told to (and, optionally, with each step taken)."""

    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


@pytest.fixture(scope="module")
def crawl():
    scene = Scene.default()
    return scene, scene.build()


@pytest.fixture(scope="module")
def creature():
    scene = Scene.from_toml(EXAMPLES / "creature_crawl.toml")
    return scene, scene.build()


def scene_gait(scene, sim):
    return lambda t: scene.activation(t, sim.ceilings)


# ------------------------------------------------------------------ the clock
def test_simulated_time_follows_the_wall_clock(crawl):
    scene, sim = crawl
    clock = FakeClock()
    player = Player(sim, scene_gait(*crawl), clock=clock)
    assert player.frame() == 0  # the first frame only starts the clock
    taken = []
    for _ in range(40):
        clock.now += 0.035  # frames slower than a step (h = 0.01)
        taken.append(player.frame())
    # 3 or 4 steps a frame, the remainder carried: simulated time trails wall time by less than a step
    assert set(taken) == {3, 4}
    assert 40 * 0.035 - sim.h < player.t <= 40 * 0.035 + 1e-12
    assert sum(taken) == 140
    # frames of exactly one step take exactly one (no round-off skips)
    for _ in range(25):
        clock.now += sim.h
        assert player.frame() == 1
    # frames faster than a step: a step every third frame
    steps = []
    for _ in range(30):
        clock.now += sim.h / 3
        steps.append(player.frame())
    assert sum(steps) == 10 and max(steps) == 1
    # the status line's steps a frame: the mean of the last 60 frames (5 slow ones, 25 of a step, 30 of a third)
    assert player.steps_per_frame == pytest.approx((sum(taken[-5:]) + 25 + 10) / 60)


def test_a_stall_is_skipped_not_raced(crawl):
    clock = FakeClock()
    player = Player(crawl[1], clock=clock, max_lag=0.25)
    player.frame()
    clock.now += 7.0  # the window was dragged for seven seconds
    assert player.frame() == 25  # max_lag / h, not 700
    assert not player.behind


def test_slow_steps_drop_time_and_keep_the_window_responsive(crawl):
    scene, sim = crawl
    clock = FakeClock()
    cost = [0.02]

    class SlowSim:
        """The simulator, each step taking ``cost`` seconds of (fake) wall-clock time."""

        def __getattr__(self, name):
            return getattr(sim, name)

        def step(self, z, z_dot, a):
            clock.now += cost[0]
            return sim.step(z, z_dot, a)

    player = Player(SlowSim(), clock=clock, step_budget=0.05, max_lag=0.25)
    player.frame()
    clock.now += 0.1  # ten steps owed
    assert player.frame() == 3  # 0, 20 and 40 ms into the budget; then 60 ms > 50 ms
    assert player.behind
    assert player.step_ms == pytest.approx(20.0)
    cost[0] = 0.0
    clock.now += 0.01
    # owed: the 60 ms spent stepping and these 10 ms, not the 70 ms dropped before
    assert player.frame() == 7
    assert not player.behind


def test_pause_stops_time_and_is_not_owed_afterwards(crawl):
    clock = FakeClock()
    player = Player(crawl[1], clock=clock)
    player.frame()
    clock.now += 0.05
    assert player.frame() == 5
    assert player.toggle_pause()
    for _ in range(10):
        clock.now += 0.05
        assert player.frame() == 0
    assert player.t == pytest.approx(0.05)
    assert not player.toggle_pause()
    player.frame()
    clock.now += 0.02
    assert player.frame() == 2
    assert player.t == pytest.approx(0.07)


def test_frame_rate_and_step_time_are_measured(crawl):
    clock = FakeClock()
    player = Player(crawl[1], clock=clock)
    for _ in range(100):
        player.frame()
        clock.now += 1 / 50
    assert player.fps == pytest.approx(50.0)
    assert player.step_ms == 0.0  # the fake clock does not move while stepping


# ----------------------------------------------------------- gait and sliders
def test_the_gait_steps_as_a_scene_run_does(crawl):
    """With the gait on, frame after frame, the state is the scene's own loop bit for bit."""
    scene, sim = crawl
    clock = FakeClock()
    player = Player(sim, scene_gait(scene, sim), clock=clock)
    player.frame()
    for _ in range(30):
        clock.now += 2 * sim.h
        player.frame()
    z, z_dot, _ = sim.rest_state()
    for i in range(60):
        z_next = sim.step(z, z_dot, scene.activation(i * sim.h, sim.ceilings))
        z_dot, z = (z_next - z) / sim.h, z_next
    np.testing.assert_array_equal(player.z, z)
    np.testing.assert_array_equal(player.z_dot, z_dot)
    np.testing.assert_array_equal(player.activation(), scene.activation(60 * sim.h, sim.ceilings))


def slider_response(sim, k, fraction, seconds=1.0):
    """Realised amplitudes, frame by frame (40 frames a second), with slider k at fraction of its range."""
    clock = FakeClock()
    player = Player(sim, clock=clock)
    target = fraction * player.ranges[k]
    player.set_slider(k, target)
    player.frame()
    amplitudes = []
    for _ in range(int(seconds * 40)):
        clock.now += 1 / 40
        player.frame()
        amplitudes.append(player.amplitudes())
    return target, np.array(amplitudes)


@pytest.mark.parametrize("name", ["crawl", "creature"])
def test_a_slider_moves_the_body_into_its_mode(name, request):
    """Each muscle's slider, either sign: the realised amplitude takes the slider's sign, grows toward it, dominates."""
    _, sim = request.getfixturevalue(name)
    for k in range(sim.n_muscles):
        for fraction in (0.5, -0.5):
            target, amplitudes = slider_response(sim, k, fraction)
            relative = amplitudes[:, k] / target
            assert abs(amplitudes[0, k]) < abs(amplitudes[-1, k])  # grows from rest
            assert 0.3 < relative[-1] < 1.1  # toward the slider; contact and elasticity hold it back
            assert np.all(relative[4:] > 0.25)  # and stays there, with the slider's sign
            others = np.delete(amplitudes[-1], k)
            assert abs(amplitudes[-1, k]) > 2 * np.abs(others).max()  # the body takes this mode, not another


def test_sliders_clip_to_their_ceiling_and_take_over_from_the_gait(crawl):
    scene, sim = crawl
    player = Player(sim, scene_gait(scene, sim), clock=FakeClock())
    assert player.gait_on
    np.testing.assert_allclose(player.ranges, sim.ceilings)
    player.set_slider(2, 1e9)
    assert player.sliders[2] == sim.ceilings[2]
    assert not player.gait_on
    np.testing.assert_array_equal(player.activation(), [0.0, 0.0, sim.ceilings[2], 0.0])
    assert player.toggle_gait()
    np.testing.assert_array_equal(player.activation(), scene.activation(0.0, sim.ceilings))


def test_a_gait_switched_on_takes_over_over_the_scenes_ramp(crawl):
    """From the sliders' activations to the gait's by the smoothstep over the ramp: no kick mid-stroke."""
    scene, sim = crawl
    clock = FakeClock()
    player = Player(sim, scene_gait(scene, sim), gait_on=False, ramp=0.4, clock=clock)
    player.set_slider(1, 0.5 * sim.ceilings[1])
    sliders = player.activation()
    player.frame()

    def until(t):  # frames of two steps each (h = 0.01)
        while player.t < t - 1e-9:
            clock.now += 2 * sim.h
            player.frame()
        assert player.t == pytest.approx(t)

    until(0.5)
    switched = player.t
    assert player.toggle_gait()
    np.testing.assert_array_equal(player.activation(), sliders)  # continuous where it was switched on
    for share, after in ((0.5, 0.2), (1.0, 0.4), (1.0, 0.7)):
        until(switched + after)
        gait = scene.activation(player.t, sim.ceilings)
        np.testing.assert_allclose(player.activation(), sliders + share * (gait - sliders), rtol=1e-12, atol=1e-15)
    # off, and on again: it takes over from the sliders anew; without a ramp, at once
    assert not player.toggle_gait() and player.toggle_gait()
    np.testing.assert_array_equal(player.activation(), sliders)
    np.testing.assert_array_equal(
        Player(sim, scene_gait(scene, sim), clock=FakeClock()).activation(), scene.activation(0.0, sim.ceilings)
    )


def test_reset_puts_the_body_at_rest(creature):
    scene, sim = creature
    clock = FakeClock()
    player = Player(sim, scene_gait(scene, sim), clock=clock)
    player.frame()
    player.set_slider(0, -1.0)
    clock.now += 0.2
    player.frame()
    assert player.t == pytest.approx(0.2) and np.abs(player.z - sim.rest_state()[0]).max() > 1e-3
    player.reset()
    np.testing.assert_array_equal(player.z, sim.rest_state()[0])
    np.testing.assert_array_equal(player.z_dot, 0.0)
    assert player.t == 0.0 and not player.sliders.any()
    np.testing.assert_allclose(player.positions(), sim.mesh.p.T, atol=1e-9)


def test_slider_ranges_without_a_ceiling():
    np.testing.assert_array_equal(slider_ranges([0.5, np.inf, 0.0]), [0.5, 1.0, 1.0])


def test_a_failed_step_resets_and_says_so(crawl):
    _, sim = crawl

    class Failing:
        def __getattr__(self, name):
            return getattr(sim, name)

        def step(self, z, z_dot, a):
            raise SimulationError("the state became non-finite")

    clock = FakeClock()
    player = Player(Failing(), clock=clock)
    player.set_slider(1, 0.3)
    player.frame()
    clock.now += 0.05
    assert player.frame() == 0
    assert "failed at t = 0.000" in player.message and "non-finite" in player.message
    assert player.t == 0.0 and not player.sliders.any()
    player.reset()  # the user's reset: the message goes (it had stayed on the status line for good)
    assert player.message == ""


@pytest.mark.parametrize("h", [1e-4, 0.1, 0.3])
def test_tiny_and_large_steps_keep_real_time(h):
    # (a step longer than max_lag, 0.25 s, never came due: an audit)
    data = {**DEFAULT_SCENE, "time": {"step": h, "steps": int(round(1.0 / h))}}  # a second, as played
    sim = Scene.from_dict(data).build()
    clock = FakeClock()
    player = Player(sim, clock=clock, step_budget=10.0)
    player.frame()
    taken = 0
    for _ in range(60):
        clock.now += 1 / 60
        taken += player.frame()
    assert taken == int(round(1.0 / h))
    assert player.t == pytest.approx(1.0, abs=h)
    assert np.isfinite(player.positions()).all()


def test_a_simulator_without_muscles_or_gait(cat_mesh):
    from skfem_modal.sim import ModalMuscle

    sim = ModalMuscle.from_mesh(cat_mesh, n_muscles=0, n_weights=2, n_clusters=3, mu=1e5, rho=1e3, h=0.01)
    clock = FakeClock()
    player = Player(sim, clock=clock)
    assert not player.gait_on and not player.toggle_gait()
    assert player.message == "no gait to switch on"
    assert player.activation().shape == (0,)
    player.frame()
    clock.now += 0.1
    assert player.frame() == 10


# ---------------------------------------------------------------- bad input
def test_bad_controls_are_named(crawl):
    _, sim = crawl
    player = Player(sim)
    with pytest.raises(ValueError, match=r"slider index must be an integer in \[0, 4\), got 4"):
        player.set_slider(4, 0.1)
    with pytest.raises(ValueError, match=r"slider index must be an integer in \[0, 4\), got True"):
        player.set_slider(True, 0.1)  # (a bool is an int to Python: it moved muscle 1)
    with pytest.raises(ValueError, match="slider 1 value must be a finite number, got nan"):
        player.set_slider(1, float("nan"))
    for bad in ("abc", None, 10**400, True, "0.5"):  # (float() took "0.5" and True; 10**400 overflowed)
        with pytest.raises(ValueError, match=r"slider 1 value must be a finite number, got "):
            player.set_slider(1, bad)
    with pytest.raises(TypeError, match="gait must be a callable"):
        Player(sim, gait=[0.1, 0.2])
    with pytest.raises(ValueError, match="max_lag and step_budget must be positive"):
        Player(sim, max_lag=0.0)


@pytest.mark.parametrize("gait_on", [True, False])
def test_scripted_play_starts_with_the_gait_or_the_sliders_as_asked(crawl, monkeypatch, gait_on):
    # --no-gait with --frames was ignored: the gait drove the muscles anyway
    import skfem_modal.play as play_module
    import skfem_modal.play_view as view_module

    scene, _ = crawl
    started = {}

    class Window:  # what the window would do with the player, without one
        def __init__(self, player, **kwargs):
            started["gait_on"] = player.gait_on
            self.player = player

        def run(self, frames):
            for _ in range(frames):
                self.player.step()
            return dict(frames=frames, seconds=1.0, fps=frames, step_ms=0.0, draw_ms=0.0, render_ms=0.0,
                        steps=frames, sim_time=self.player.t)  # fmt: skip

        def close(self):
            started["sliders"] = self.player.activation().tolist()

    monkeypatch.setattr(play_module, "play_problem", lambda off_screen: None)
    monkeypatch.setattr(view_module, "PlayView", Window)
    play(scene, gait_on=gait_on, frames=5, say=lambda line: None)
    assert started["gait_on"] is gait_on
    assert bool(np.abs(started["sliders"]).max() > 0.0) == gait_on  # the gait's activations, or the sliders at zero


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"frames": 0}, "frames must be a positive integer, got 0"),
        ({"off_screen": True}, "off-screen play needs a number of frames"),
        ({"frames": 2, "screenshot": "shot.jpg"}, "screenshot shot.jpg: expected a .png file"),
        # found after all the frames were played, before (an audit)
        ({"frames": 2, "screenshot": "/proc/shot.png"}, "screenshot /proc/shot.png: /proc is not a folder this user"),
        ({"frames": 2, "window_size": (100, 80)}, "window size must be at least 560 x 360"),
    ],
)
def test_bad_play_options_fail_before_any_window(kwargs, message):
    with pytest.raises(ValueError, match=message):
        play(**kwargs)


def test_play_checks_its_scene_before_anything_else(monkeypatch, tmp_path):
    monkeypatch.delenv("DISPLAY", raising=False)  # the scene's errors come first, display or not
    with pytest.raises(TypeError, match="play needs a Scene, a scene file or a simulator, got int"):
        play(3, frames=1)
    with pytest.raises(FileNotFoundError, match="scene file not found"):
        play(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[muscles]\ncount = -1\n")
    with pytest.raises(ValueError, match="muscles.count"):
        play(bad)


def test_without_pyvista_the_error_says_what_to_install(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "pyvista", None)
    assert "pip install 'skfem_modal[plot]'" in play_problem()
    with pytest.raises(PlayError, match=r"needs pyvista: pip install"):
        play(frames=1)
    assert main(["play", "--frames", "1"]) == 2
    assert "skfem-modal play: error: the live window needs pyvista" in capsys.readouterr().err


def test_without_a_display_the_error_says_what_to_set(monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("VTK_DEFAULT_OPENGL_WINDOW", raising=False)
    problem = play_problem()
    assert "DISPLAY is not set" in problem and "apt-get install xvfb" in problem and "--off-screen" in problem
    monkeypatch.setattr("skfem_modal.plot.gl_available", lambda: True)
    assert play_problem(off_screen=True) is None
    monkeypatch.setattr("skfem_modal.plot.gl_available", lambda: False)
    assert "off-screen rendering does not work here: install Mesa's EGL" in play_problem(off_screen=True)
    monkeypatch.setenv("DISPLAY", ":4321")
    assert "cannot open the X display DISPLAY=':4321'" in play_problem()
    assert main(["play", "--frames", "3"]) == 2
    assert "cannot open the X display" in capsys.readouterr().err


def test_a_display_without_opengl_is_named_before_any_window(monkeypatch, capsys):
    """An audit: on an X display without GLX (ssh -X, some VNC servers) the window died of a segmentation fault."""
    import shutil

    if shutil.which("Xvfb") is None:
        unavailable("Xvfb is not installed (Debian: apt-get install xvfb)")
    read, write = os.pipe()
    server = subprocess.Popen(
        ["Xvfb", "-displayfd", str(write), "-extension", "GLX", "-nolisten", "tcp", "-noreset"],
        pass_fds=(write,),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    os.close(write)
    try:
        with os.fdopen(read) as numbers:
            display = ":" + numbers.readline().strip()
        monkeypatch.setenv("DISPLAY", display)
        monkeypatch.delenv("VTK_DEFAULT_OPENGL_WINDOW", raising=False)
        assert f"the X display DISPLAY='{display}' has no OpenGL (its GLX extension is missing" in play_problem()
        assert main(["play", "--frames", "3"]) == 2
        assert "has no OpenGL" in capsys.readouterr().err
    finally:
        server.terminate()
        server.wait(timeout=30)


# ------------------------------------------------------- the window (Xvfb)
@pytest.fixture(scope="module")
def display():
    # other tests' off-screen renders ask VTK for EGL windows (plot._headless_vtk): not these
    window_class = os.environ.pop("VTK_DEFAULT_OPENGL_WINDOW", None)
    try:
        with virtual_display() as name:
            yield name
    except PlayError as err:
        unavailable(f"no virtual display: {err}")
    finally:
        if window_class is not None:
            os.environ["VTK_DEFAULT_OPENGL_WINDOW"] = window_class


def test_a_virtual_display_whose_server_ends_in_use_says_so(display):
    """A window test that lost its X server says that, with the server's exit code (not just 'bad X connection')."""

    def servers():
        children = Path(f"/proc/{os.getpid()}/task/{threading.get_native_id()}/children").read_text().split()
        return {int(pid) for pid in children if Path(f"/proc/{pid}/comm").read_text().strip() == "Xvfb"}

    before = servers()
    with pytest.raises(PlayError, match=r"Xvfb on :\d+ ended while in use \(exit code -9\)"):
        with virtual_display():  # a second server beside the module's
            (pid,) = servers() - before
            os.kill(pid, signal.SIGKILL)
            stat = Path(f"/proc/{pid}/stat")
            for _ in range(200):  # until it has died (a zombie, until virtual_display reaps it)
                if not stat.exists() or stat.read_text().split(")")[-1].split()[0] == "Z":
                    break
                time.sleep(0.01)
    assert os.environ["DISPLAY"] == display  # the module's display is back


class _RootNote:
    """A string property on an X display's root window, through its own connection each time.

    An X server that resets (its last client left) forgets it: what shows whether one did.
    """

    def __init__(self, display: str):
        from skfem_modal.play import _xlib

        x11, self.display = _xlib(), display.encode()
        handle = pointer = ctypes.c_void_p
        window = atom = ctypes.c_ulong  # X's XID and Atom
        long = ctypes.c_long
        x11.XDefaultRootWindow.restype = window
        x11.XDefaultRootWindow.argtypes = [handle]
        x11.XInternAtom.restype = atom
        x11.XInternAtom.argtypes = [handle, ctypes.c_char_p, ctypes.c_int]
        # (display, window, property, type, format, mode, data, count)
        x11.XChangeProperty.argtypes = [handle, window, atom, atom, ctypes.c_int, ctypes.c_int, ctypes.c_char_p]
        x11.XChangeProperty.argtypes += [ctypes.c_int]
        # (display, window, property, offset, length, delete, type, then five results by pointer)
        x11.XGetWindowProperty.argtypes = [handle, window, atom, long, long, ctypes.c_int, atom] + [pointer] * 5
        x11.XSync.argtypes = [handle, ctypes.c_int]
        x11.XFree.argtypes = [pointer]
        self.x11 = x11

    def _connect(self):
        for _ in range(100):  # a server resetting drops a client connecting meanwhile: try again
            handle = self.x11.XOpenDisplay(self.display)
            if handle:
                return handle, self.x11.XDefaultRootWindow(handle), self.x11.XInternAtom(handle, b"SKFEM_NOTE", 0)
            time.sleep(0.02)
        raise AssertionError(f"cannot open {self.display}")

    def write(self, text: str) -> None:
        x11 = self.x11
        handle, root, atom = self._connect()
        data = text.encode()
        x11.XChangeProperty(handle, root, atom, 31, 8, 0, data, len(data))  # XA_STRING, 8 bits, replace
        x11.XSync(handle, 0)
        x11.XCloseDisplay(handle)

    def read(self) -> str | None:
        ct, x11 = ctypes, self.x11
        handle, root, atom = self._connect()
        kind, bits, items, after, value = ct.c_ulong(), ct.c_int(), ct.c_ulong(), ct.c_ulong(), ct.c_void_p()
        x11.XGetWindowProperty(
            handle, root, atom, 0, 1024, 0, 0, *(ct.byref(v) for v in (kind, bits, items, after, value))
        )
        text = ct.string_at(value.value, items.value).decode() if value.value else None
        if value.value:
            x11.XFree(value)
        x11.XCloseDisplay(handle)
        return text


def test_the_virtual_display_does_not_reset_when_its_last_client_leaves(display):
    """A reset drops a client connecting meanwhile (VTK's window then crashes): our Xvfb never resets."""
    note = _RootNote(display)
    note.write("before")  # its connection was the last client: a resetting server forgets the note
    assert note.read() == "before"


def test_the_window_holds_the_display_so_a_resetting_server_cannot_reset(display, monkeypatch):
    """xvfb-run's Xvfb resets when its last client leaves: play holds a connection while its window lives.

    (``display``: Xvfb is there, as for every window test; this one starts a server of its own, as xvfb-run does.)
    """
    from skfem_modal.play import _display_held

    read, write = os.pipe()
    server = subprocess.Popen(
        ["Xvfb", "-displayfd", str(write), "-nolisten", "tcp"], pass_fds=(write,), stderr=subprocess.DEVNULL
    )
    os.close(write)
    try:
        with os.fdopen(read) as pipe:
            name = f":{pipe.readline().strip()}"
        monkeypatch.setenv("DISPLAY", name)
        note = _RootNote(name)
        with _display_held():
            note.write("held")
            assert note.read() == "held"
        note.write("let go")
        assert note.read() is None  # the server reset: the test can tell
    finally:
        server.terminate()
        server.wait(timeout=10)


def test_a_display_with_an_off_screen_window_class_is_refused(display, monkeypatch):
    assert play_problem() is None
    monkeypatch.setenv("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    assert "VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow renders off-screen only: unset it" in play_problem()


def run_driver(*args, env=None):
    result = subprocess.run(
        [sys.executable, str(HERE / "play_window_driver.py"), *args],
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
    )
    assert result.returncode == 0, f"exit code {result.returncode}, {_display_state()}: {result.stderr[-3000:]}"
    return json.loads(result.stdout.strip().splitlines()[-1])


def _display_state() -> str:
    """DISPLAY and whether its server's socket is there: what a window that could not connect was given."""
    display = os.environ.get("DISPLAY", "")
    socket = Path("/tmp/.X11-unix") / f"X{display.lstrip(':').split('.')[0]}"
    return f"DISPLAY={display!r} (socket {socket} {'there' if socket.exists() else 'missing'})"


@pytest.mark.parametrize("scene", ["default", str(EXAMPLES / "creature_crawl.toml")])
def test_window_sliders_keys_and_buttons_drive_the_body(display, scene):
    """A drag on a slider, keys and a button click go through the widgets into the simulation."""
    report = run_driver(scene)
    for drag in report["drags"]:
        # the drag set the slider where the mouse went, and the muscle's amplitude followed it
        assert np.sign(drag["slider"]) == np.sign(drag["fraction"])
        # the knob's travel ends short of the tube's ends: a drag moves the value a little further
        assert abs(drag["slider"] / drag["range"] - drag["fraction"]) < 0.2
        assert drag["widget"] == pytest.approx(drag["slider"])
        assert not drag["gait_on"]
        relative = np.array(drag["amplitudes"]) / drag["slider"]
        assert relative[0] < relative[-1] and relative[-1] > 0.3
    keys = report["keys"]
    assert keys["g"] is True  # back to the gait after the drags
    assert keys["space"] is True and keys["paused_time_moved"] is False
    assert keys["r_time"] == 0.0 and keys["r_sliders"] == 0.0 and keys["r_widgets"] == 0.0
    assert keys["clicked_gait"] is False  # the gait button switched the gait off
    assert keys["clicked_reset_time"] == 0.0
    assert keys["quit_frames"] == 7  # q ends the live loop after the frame it was pressed in
    assert keys["after_quit_std"] > 20
    picture = report["screenshot"]
    assert picture["shape"][:2] == [600, 960]
    assert picture["std"] > 20
    assert picture["body_fraction"] > 0.01  # the body's colour is on screen
    assert picture["background_fraction"] > 0.05  # the sky (a 3D ground fills most of the rest)


def check_png(path, width=960, height=600):
    from PIL import Image

    image = np.asarray(Image.open(path).convert("RGB")).astype(float)
    assert image.shape == (height, width, 3)
    assert image.std() > 20  # not blank
    body = np.abs(image - [0x3F, 0x8F, 0x63]).max(axis=2) < 60
    assert 0.01 < body.mean() < 0.6  # shaded, the body's colour is still recognisably green
    return image


def test_scripted_mode_prints_the_frame_rate_and_saves_the_last_frame(display, tmp_path):
    shot = tmp_path / "shots" / "play.png"
    result = subprocess.run(
        [sys.executable, "-m", "skfem_modal.cli", "play", "--frames", "40", "--screenshot", str(shot)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert "40 frames in" in result.stdout and "frames per second" in result.stdout
    fps = float(result.stdout.split("mean ")[1].split(" frames per second")[0])
    assert fps > 1.0
    check_png(shot)


def test_off_screen_without_a_display(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    shot = tmp_path / "off.png"
    result = subprocess.run(
        [sys.executable, "-m", "skfem_modal.cli", "play", str(EXAMPLES / "creature_crawl.toml")]
        + ["--off-screen", "--frames", "20", "--screenshot", str(shot)],
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
    )
    if "off-screen rendering does not work here" in result.stderr:
        unavailable(result.stderr.strip())  # no EGL or OSMesa on this machine: the error says what to install
    assert result.returncode == 0, result.stderr[-3000:]
    assert "20 frames in" in result.stdout
    check_png(shot)


def test_window_on_a_two_part_body(display, tmp_path):
    """Two separate bodies in one mesh, on a ground: drawn, stepped and framed together."""
    import meshio

    from skfem_modal import beam2d

    beam = beam2d(2.0, 0.5, 16, 4)
    points = np.vstack([beam.p.T, beam.p.T + [3.0, 0.0]])
    cells = np.vstack([beam.t.T, beam.t.T + beam.p.shape[1]])
    meshio.write(tmp_path / "two.vtu", meshio.Mesh(points, [("triangle", cells)]))
    scene = tmp_path / "two.toml"
    scene.write_text(
        '[mesh]\nfile = "two.vtu"\n[muscles]\ncount = 2\n'
        "[muscles.gait]\namplitude = [0.4, 0.4]\nperiod = [0.8, 0.5]\n"
        "[gravity]\nacceleration = [0.0, -9.8]\n[ground]\noffset = 0.05\n"
    )
    shot = tmp_path / "two.png"
    result = subprocess.run(
        [sys.executable, "-m", "skfem_modal.cli", "play", str(scene), "--frames", "30", "--screenshot", str(shot)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert "30 frames in" in result.stdout
    check_png(shot)


@pytest.mark.slow
@pytest.mark.parametrize("mesh, gravity", [("seal.mesh", [0.0, -9.8, 0.0]), ("ghost.obj", [0.0, -9.8])])
def test_window_on_real_meshes(display, tmp_path, mesh, gravity):
    """Users' meshes: pixel units (ghost, 2D) and a y-up 3D body (seal) on their ground."""
    scene = tmp_path / "scene.toml"
    scene.write_text(
        f'[mesh]\nfile = "{MESHES / mesh}"\nnormalize = true\n[muscles]\ncount = 3\n'
        "[muscles.gait]\namplitude = [0.3, 0.3, 0.3]\nperiod = [1.0, 0.7, 0.5]\n"
        f"[gravity]\nacceleration = {gravity}\n[ground]\noffset = 0.02\nup = 1\n"
    )
    shot = tmp_path / "shot.png"
    result = subprocess.run(
        [sys.executable, "-m", "skfem_modal.cli", "play", str(scene), "--frames", "30", "--screenshot", str(shot)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    check_png(shot)


def test_docs_play_python_example(display, tmp_path, monkeypatch, capsys):
    """docs/play.md's example runs as written (the scene path made absolute) and prints what it says."""
    import re

    (code,) = re.findall(r"```python\n(.*?)```", (HERE.parent / "docs" / "play.md").read_text(), flags=re.S)
    assert '"examples/creature_crawl.toml"' in code
    code = code.replace('"examples/creature_crawl.toml"', repr(str(EXAMPLES / "creature_crawl.toml")))
    monkeypatch.chdir(tmp_path)
    namespace = {}
    exec(compile(code, "play.md", "exec"), namespace)
    check_png(tmp_path / "creature.png")
    out = capsys.readouterr().out.splitlines()
    assert sum("120 frames in" in line for line in out) == 2
    quoted = [float(v) for v in re.search(r"# \[([-0-9. ]+)\]", code).group(1).split()]
    shown = namespace["player"].amplitudes() / namespace["sim"].ceilings
    np.testing.assert_allclose(shown, quoted, atol=1e-2)


SCREENSHOT_AFTER_FEW_FRAMES = """
import json, sys
import numpy as np
from skfem_modal import play_view
from skfem_modal.play import Player, _simulator
from skfem_modal.play_view import PlayView

# a machine fast enough that these frames all fall between two status updates: as fast as this gets
play_view._STATUS_EVERY = play_view._GAIT_SLIDERS_EVERY = 1e9

class Clock:
    now = 0.0
    def __call__(self):
        return self.now

clock = Clock()
sim, gait, _, _ = _simulator(None, None)
player = Player(sim, gait, clock=clock)
view = PlayView(player, window_size=(960, 600))
view.plotter.show(interactive_update=True, auto_close=False)
frames = []
for _ in range(3):  # 1/40 s a frame: the status line last changed at the first
    clock.now += 1 / 40
    player.frame()
    view.draw()
    view.render()
    frames.append(view.status.GetInput())
view.save_screenshot(sys.argv[1])
saved = view.status.GetInput()
sliders = [w.GetRepresentation().GetValue() for w in view.sliders]
# the status line as the last drawn frame showed it: what the picture held before
view.status.SetInput(frames[-1])
view.render()
np.save(sys.argv[2], np.asarray(view.plotter.screenshot(return_img=True))[:, :, :3])
print(json.dumps({"frames": frames, "saved": saved, "t": player.t, "steps": player.n_steps,
                  "expected": view._status_text(), "sliders": sliders,
                  "activation": player.activation().tolist()}))
"""


def test_the_screenshot_shows_the_last_frames_own_status(display, tmp_path):
    """After 3 frames the saved picture's status line and sliders are the last frame's, not the first's."""
    from PIL import Image

    shot, stale = tmp_path / "shot.png", tmp_path / "stale.npy"
    result = subprocess.run(
        [sys.executable, "-c", SCREENSHOT_AFTER_FEW_FRAMES, str(shot), str(stale)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert report["steps"] >= 2 and report["t"] > 0  # the frames stepped
    assert report["frames"][-1].startswith("t =    0.00")  # what the window showed, throttled
    assert report["saved"] == report["expected"]  # the picture's status: the state it shows
    assert report["saved"].startswith(f"t = {report['t']:7.2f}    40.0 frames/s")  # the fake clock: 1/40 s a frame
    np.testing.assert_allclose(report["sliders"], report["activation"], atol=1e-12)
    assert np.abs(report["activation"]).max() > 0  # the gait's sliders moved off +0
    picture = np.asarray(Image.open(shot).convert("RGB")).astype(int)
    status_rows = picture[:40] != np.load(stale)[:40]  # the top of the window: the status line
    assert status_rows.any(axis=2).mean() > 0.001  # the saved status line is not the stale one


def seen_in_window(script: str, tmp_path, scene_text: str) -> dict:
    """What ``script`` prints last (JSON) of a window on the scene ``scene_text``, run in a subprocess."""
    scene = tmp_path / "scene.toml"
    scene.write_text(scene_text)
    result = subprocess.run([sys.executable, "-c", script, str(scene)], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    return json.loads(result.stdout.strip().splitlines()[-1])


CAMERA_OF_A_Y_UP_BODY = """
import json, sys
import numpy as np
from skfem_modal.play import Player, _simulator
from skfem_modal.play_view import PlayView

sim, gait, _, _ = _simulator(sys.argv[1], None)
view = PlayView(Player(sim, gait), window_size=(960, 600))
camera = view.plotter.camera
print(json.dumps({"towards": (np.subtract(camera.position, camera.focal_point)).tolist(), "up": list(camera.up)}))
"""


def test_the_window_looks_at_a_y_up_body_from_the_front_as_render_does(display, tmp_path):
    """An audit: the seal and the elephant (y up) were seen from behind, walking leftwards, in the window."""
    from skfem_modal.camera import Camera

    seen = seen_in_window(
        CAMERA_OF_A_Y_UP_BODY,
        tmp_path,
        '[mesh]\nshape = "creature"\nparams = { cell = 0.2 }\n[subspace]\nweights = 3\nclusters = 4\n'
        "[muscles]\ncount = 1\n[gravity]\nacceleration = [0.0, -9.8, 0.0]\n[ground]\noffset = 0.0\n",
    )
    pictures = Camera.looking_at(np.array([0.0, 1.0, 0.0]), 3)  # render's, for y up
    towards = np.array(seen["towards"]) / np.linalg.norm(seen["towards"])
    np.testing.assert_allclose(towards, pictures.towards, atol=1e-12)
    np.testing.assert_allclose(seen["up"], pictures.screen_up, atol=1e-12)
    assert pictures.towards[2] > 0.5 and pictures.right[0] > 0.5  # from +z, x running right


WINDOW_OF_A_FAR_X_UP_2D_BODY = """
import json, sys
import numpy as np
from skfem_modal.play import Player, _simulator
from skfem_modal.play_view import PlayView

sim, gait, _, _ = _simulator(sys.argv[1], None)
view = PlayView(Player(sim, gait), window_size=(960, 600), follow=False)
camera = view.plotter.camera
seen = {"up": list(camera.up), "com": view.player.com().tolist(), "cell": view.ground_cell}
seen["ground"] = [list(actor.GetPosition()) for actor in view.ground_actors]
view.plotter.show(interactive_update=True, auto_close=False)
interactor = view.plotter.iren.interactor
def event(name, x, y):
    interactor.SetEventInformation(x, y, 0, 0, "\\0", 0, None)
    interactor.InvokeEvent(name)
event("MouseMoveEvent", 600, 300)
event("LeftButtonPressEvent", 600, 300)
for k in range(1, 20):  # a drag with the left button
    event("MouseMoveEvent", 600 + 10 * k, 300 + 4 * k)
    view.render()
event("LeftButtonReleaseEvent", 790, 376)
seen["dragged"] = list(camera.direction)
for _ in range(30):
    view.player.step()
view.draw(current=True)
seen["slider_max"] = view.sliders[0].GetRepresentation().GetMaximumValue()
seen["range"], seen["ceiling"] = float(view.player.ranges[0]), float(sim.ceilings[0])
print(json.dumps(seen))
"""


def test_the_window_of_a_flat_body_far_off_with_x_up(display, tmp_path):
    """An audit: a 2D body with x up lay on its side, the ground (drawn about the origin) was not under a body
    at (300, 50), a mouse drag turned the flat scene out of its plane, and a gait past a muscle's ceiling
    showed the ceiling on its slider."""
    import meshio

    from skfem_modal.camera import Camera
    from skfem_modal.mesh import caterpillar

    mesh = caterpillar()
    meshio.write(tmp_path / "far.vtu", meshio.Mesh(mesh.p.T + [300.0, 50.0], [("triangle", mesh.t.T)]))
    seen = seen_in_window(
        WINDOW_OF_A_FAR_X_UP_2D_BODY,
        tmp_path,
        '[mesh]\nfile = "far.vtu"\n[subspace]\nweights = 4\nclusters = 6\n[muscles]\ncount = 2\n'
        "[muscles.gait]\namplitude = [1.5, 0.4]\nperiod = [1.0, 0.8]\nphase = [0.25, 0.0]\n"
        "[gravity]\nacceleration = [-9.8, 0.0]\n[ground]\noffset = 0.0\n",
    )
    np.testing.assert_allclose(seen["up"], Camera.looking_at(np.array([1.0, 0.0]), 2).screen_up, atol=1e-12)
    assert seen["up"][0] == 1.0
    # the ground's grid under the body (snapped to its cells), along the ground: y here, x being up
    assert seen["ground"] and all(
        p == [0.0, round(seen["com"][1] / seen["cell"]) * seen["cell"], 0.0] for p in seen["ground"]
    )
    assert abs(seen["ground"][0][1] - 50.0) <= seen["cell"]
    np.testing.assert_allclose(seen["dragged"], [0.0, 0.0, -1.0], atol=1e-12)  # panned, still facing the plane
    assert seen["range"] > seen["ceiling"] and seen["slider_max"] == seen["range"]


@pytest.mark.parametrize("size", ["16x16", "559x600", "960x359", "8193x600"])
def test_the_command_refuses_the_window_sizes_play_refuses(size, capsys):
    """--size took 16 to 8192 a side (the pictures' range), then play refused below 200 x 150 (an audit), where
    the sliders were gone and the buttons lay over the status line (a new user's trial): now 560 x 360."""
    with pytest.raises(SystemExit) as usage:
        main(["play", "--size", size, "--frames", "2", "--off-screen"])
    assert usage.value.code == 2
    width, height = size.split("x")
    said = "argument --size: window size must be at least 560 x 360 pixels (and at most 8192 a side)"
    assert f"{said}, got {width} x {height}" in capsys.readouterr().err


def test_a_player_repeats_itself_whatever_ran_its_simulator_before(creature):
    # play(sim) then Player(sim) (docs/play.md): the Coulomb contact kept the vertices the earlier
    # steps looked at, so the player's first steps differed with how long the window had run
    scene, sim = creature

    def amplitudes_after_a_slider():
        player = Player(sim, clock=FakeClock())
        player.set_slider(2, 0.5 * sim.ceilings[2])
        for _ in range(40):
            player.step()
        return player.amplitudes()

    first = amplitudes_after_a_slider()
    z, z_dot, _ = sim.rest_state()
    for i in range(37):  # another user of the simulator, stopped anywhere
        z, z_dot = sim.step(z, z_dot, scene.activation(i * sim.h, sim.ceilings), velocity=True)
    np.testing.assert_array_equal(amplitudes_after_a_slider(), first)
    assert abs(first[2]) > 4 * np.abs(np.delete(first, 2)).max()  # the slider's muscle takes its mode
