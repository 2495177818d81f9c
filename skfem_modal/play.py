"""Play: a simulator driven live, by sliders (one per muscle) or by its gait.

:class:`Player` is the simulation side of the live window and needs no
window: the state, the sliders' activations, the gait toggle, pause, reset
and the clock that makes simulated time follow wall-clock time (several steps
in a frame when a frame takes longer than a step). Tests drive it with a fake
clock. :mod:`skfem_modal.play_view` draws it with pyvista;
:func:`play` puts the two together and :func:`play_problem` says, before any
window is opened, what is missing to open one.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections import deque

import numpy as np

from .muscles import checked_ramp, gait_ramp
from .outputs import check_output_file
from .values import is_finite_real, is_whole

__all__ = ["Player", "PlayError", "play", "play_problem", "slider_ranges", "virtual_display", "window_size_problem"]


_RECENT = 60  # frames the frame rate and the step time are measured over
#: The smallest window: room for the status line (about 520 pixels of text), the buttons under it and the sliders
#: (at 200 x 150 the sliders were gone and the buttons lay over the body and the status line)
MIN_WINDOW = (560, 360)


def window_size_problem(size) -> str | None:
    """What is wrong with a window size (width, height) in pixels, or None.

    ``size``: a pair of integers; each side at least :data:`MIN_WINDOW`'s and at most
    :data:`~skfem_modal.plot.MAX_PICTURE_SIDE`. The problem, when there is one, is a sentence
    naming the size and the bounds.

    >>> window_size_problem((960, 600)) is None
    True
    >>> window_size_problem((16, 16))
    'window size must be at least 560 x 360 pixels (and at most 8192 a side), got 16 x 16'
    >>> window_size_problem((960.5, 600))
    'window size must be two whole numbers of pixels (width, height), got (960.5, 600)'
    """
    from .plot import MAX_PICTURE_SIDE

    if not (isinstance(size, (tuple, list)) and len(size) == 2 and all(map(is_whole, size))):
        return f"window size must be two whole numbers of pixels (width, height), got {size!r}"
    width, height = (int(v) for v in size)
    if width < MIN_WINDOW[0] or height < MIN_WINDOW[1] or max(width, height) > MAX_PICTURE_SIDE:
        return (
            f"window size must be at least {MIN_WINDOW[0]} x {MIN_WINDOW[1]} pixels (and at most "
            f"{MAX_PICTURE_SIDE} a side), got {width} x {height}"
        )
    return None


class PlayError(RuntimeError):
    """The live window cannot open here; the message says what to install or set."""


def slider_ranges(ceilings) -> np.ndarray:
    """The half-width of each muscle's slider: its ceiling, or 1 where it has none.

    Parameters
    ----------
    ceilings : array_like, shape (m,)
        Amplitude ceilings of the muscles (``sim.ceilings``); ``inf`` marks a
        muscle that stretches nothing, which has no natural range.

    Returns
    -------
    ranges : ndarray, shape (m,)
        Each slider spans ``[-range, +range]`` in mode-amplitude units.
    """
    ceilings = np.asarray(ceilings, dtype=float)
    return np.where(np.isfinite(ceilings) & (ceilings > 0), ceilings, 1.0)


class Player:
    """A simulator stepped in wall-clock time, its muscles set by sliders or a gait.

    Parameters
    ----------
    sim : skfem_modal.sim.ModalMuscle
        Only its public API is used: ``reset``, ``rest_state``, ``step``, ``positions``,
        ``com``, ``muscle_amplitudes``, ``ceilings``, ``h``, ``n_muscles``.
    gait : callable, optional
        ``gait(t) -> a``, activations of shape (m,) at simulated time ``t``.
        Without one, the gait cannot be switched on.
    gait_on : bool
        Start with the gait driving the muscles (ignored without a gait).
    ramp : float
        Time over which the gait, switched on (:meth:`toggle_gait`), takes over from
        the activations in effect then, by the smoothstep of
        :func:`~skfem_modal.muscles.gait_ramp` (0: at once). A scene's gait brings
        its own ramp from rest at the start; :func:`play` passes a scene's ramp here too.
    clock : callable
        Wall-clock seconds (``time.perf_counter``); tests pass a fake one.
    max_lag : float
        At most this much simulated time is owed at once (or one step, if
        ``sim.h`` is longer): after a stall (a window being dragged, a first
        step that compiles) the simulation skips ahead instead of racing to
        catch up.
    step_budget : float
        Wall-clock seconds of stepping per frame, at most. When the steps that
        real time asks for take longer, the rest is dropped (``behind`` is
        set): the simulation runs slower than real time but the window stays
        responsive.

    Attributes
    ----------
    z, z_dot : ndarray, shape (r,)
        The reduced state.
    t : float
        Simulated time since the last reset.
    n_steps : int
        Steps since the last reset.
    sliders : ndarray, shape (m,)
        The sliders' activations in mode-amplitude units, within ``+-ranges``.
    ranges : ndarray, shape (m,)
        Half-width of each slider (:func:`slider_ranges` of the ceilings), widened to the
        gait's activations where a gait goes past a ceiling.
    gait_on, paused : bool
    steps : int
        Steps taken in the last frame.
    behind : bool
        The last frame dropped simulated time (stepping was slower than real time).
    fps : float
        Frames per second over the last 60 frames.
    step_ms : float
        Wall-clock milliseconds per step: the median over the last 60 frames that stepped.
    step_seconds : float
        Wall-clock seconds spent stepping in the last frame.
    message : str
        The last thing worth telling the user ("" when nothing; a reset clears it).
    """

    def __init__(
        self,
        sim,
        gait=None,
        *,
        gait_on: bool = True,
        ramp: float = 0.0,
        clock=time.perf_counter,
        max_lag: float = 0.25,
        step_budget: float = 0.05,
    ):
        if not (max_lag > 0 and step_budget > 0):
            raise ValueError(f"max_lag and step_budget must be positive, got {max_lag} and {step_budget}")
        if gait is not None and not callable(gait):
            raise TypeError(f"gait must be a callable gait(t) -> activations, got {type(gait).__name__}")
        self.sim = sim
        self.gait = gait
        self.clock = clock
        self.max_lag = float(max_lag)
        self.step_budget = float(step_budget)
        self.ranges = slider_ranges(sim.ceilings)
        self.gait_on = bool(gait_on) and gait is not None
        self.ramp = checked_ramp(ramp)
        self._takeover = None  # (time, activations) where the gait was switched on, while it ramps in
        self.paused = False
        self._intervals = deque(maxlen=_RECENT)
        self._step_times = deque(maxlen=_RECENT)
        self._frame_steps = deque(maxlen=_RECENT)
        self.message = ""
        self.reset()

    # ------------------------------------------------------------ controls
    def reset(self) -> None:
        """The body back at rest, time to zero, sliders to zero (gait and pause stay).

        The simulator forgets what its earlier steps left (the contact's vertices, the iterations'
        warm starts), so a reset player repeats itself whatever ran the simulator before.
        """
        self.sim.reset()
        self.z, self.z_dot, _ = self.sim.rest_state()
        self.n_steps = 0
        self.sliders = np.zeros(self.sim.n_muscles)
        self.steps = 0
        self.step_seconds = 0.0
        self.behind = False
        self._owed = 0.0
        self._last = None
        self._takeover = None
        self.message = ""

    def set_slider(self, k: int, value: float) -> None:
        """Set muscle ``k``'s slider (clipped to its range); the sliders take over from the gait.

        Parameters
        ----------
        k : int
            The muscle, from 0 to m - 1.
        value : float
            The activation, in mode-amplitude units; clipped to ``[-ranges[k], ranges[k]]``.

        Raises
        ------
        ValueError
            ``k`` is not a muscle's index, or ``value`` is not finite.
        """
        m = self.sim.n_muscles
        if not (is_whole(k) and 0 <= k < m):  # (not a bool: True would be muscle 1)
            raise ValueError(f"slider index must be an integer in [0, {m}), got {k!r}")
        if not is_finite_real(value):  # (float() would take "0.5" and True)
            raise ValueError(f"slider {k} value must be a finite number, got {value!r}")
        value = float(value)
        self.sliders[k] = np.clip(value, -self.ranges[k], self.ranges[k])
        self.gait_on, self._takeover = False, None

    def toggle_gait(self) -> bool:
        """Switch the gait on or off (stays off without a gait); returns the new state."""
        if self.gait is None:
            self.message = "no gait to switch on"
            return False
        # from the activations in effect, over the ramp: a body at rest is not kicked by a gait mid-stroke
        self._takeover = None if self.gait_on or not self.ramp else (self.t, self.activation())
        self.gait_on = not self.gait_on
        return self.gait_on

    def toggle_pause(self) -> bool:
        """Pause or resume; time paused is not owed afterwards. Returns the new state."""
        self.paused = not self.paused
        self._last = None
        return self.paused

    def activation(self) -> np.ndarray:
        """The activations in effect now, shape (m,): the gait's at ``t``, or the sliders'.

        A gait just switched on is blended in from what was in effect then, over ``ramp``.
        """
        if not self.gait_on:
            return self.sliders.copy()
        a = np.asarray(self.gait(self.t), dtype=float)
        if self._takeover is not None:
            since, start = self._takeover
            share = gait_ramp(self.t - since, self.ramp)
            if share < 1.0:
                return start + share * (a - start)
            self._takeover = None
        return a

    # --------------------------------------------------------------- stats
    @property
    def t(self) -> float:
        """Simulated time since the last reset: steps times ``h``, as a scene's run counts it."""
        return self.n_steps * self.sim.h

    @property
    def fps(self) -> float:
        """Frames per second over the last 60 frames (0 before two frames)."""
        return len(self._intervals) / sum(self._intervals) if self._intervals else 0.0

    @property
    def steps_per_frame(self) -> float:
        """Steps a frame over the last 60 unpaused frames (0 before any); below 1 when frames outpace steps."""
        return float(np.mean(self._frame_steps)) if self._frame_steps else 0.0

    @property
    def step_ms(self) -> float:
        """Median wall-clock milliseconds of a step over the last 60 frames that stepped (0 before any)."""
        return 1e3 * float(np.median(self._step_times)) if self._step_times else 0.0

    # --------------------------------------------------------------- state
    def positions(self) -> np.ndarray:
        """Vertex positions now, shape (n, dim)."""
        return self.sim.positions(self.z)

    def com(self) -> np.ndarray:
        """Centre of mass now, shape (dim,)."""
        return self.sim.com(self.z)

    def amplitudes(self) -> np.ndarray:
        """Realised modal amplitude of each muscle now, shape (m,)."""
        return self.sim.muscle_amplitudes(self.z)

    # ---------------------------------------------------------------- time
    def frame(self) -> int:
        """Advance simulated time by the wall-clock time since the last frame.

        Takes as many steps of ``sim.h`` as that time holds (the remainder
        is owed to the next frame), within ``max_lag`` and ``step_budget``.

        Returns
        -------
        steps : int
            Steps taken (0 when paused or when less than a step is owed).
        """
        now = self.clock()
        elapsed = 0.0 if self._last is None else now - self._last
        self._last = now
        if elapsed > 0:
            self._intervals.append(elapsed)
        self.steps = 0
        self.step_seconds = 0.0
        if self.paused:
            return 0
        h = self.sim.h
        # a step longer than max_lag is owed whole: capped at max_lag, it never came due (h = 0.3 never stepped)
        self._owed = min(self._owed + elapsed, max(self.max_lag, h))
        # the tolerance keeps a frame of exactly k steps from taking k - 1
        wanted = int(np.floor(self._owed / h + 1e-9))
        start = self.clock()
        from .sim import SimulationError

        try:
            while self.steps < wanted and (self.steps == 0 or self.clock() - start < self.step_budget):
                self.step()
        except SimulationError as err:
            t = self.t
            self.reset()
            self.message = f"the simulation failed at t = {t:.3f} ({err}); reset to rest"
            return 0
        self.behind = self.steps < wanted
        self._owed = 0.0 if self.behind else self._owed - self.steps * h
        self._frame_steps.append(self.steps)
        if self.steps:
            self.step_seconds = self.clock() - start
            self._step_times.append(self.step_seconds / self.steps)
        return self.steps

    def step(self) -> None:
        """One step of ``sim.h`` with the activations in effect, whatever the clock says."""
        a = self.activation()
        if self.gait_on:  # a gait past a muscle's ceiling widens its slider, which shows the activation in effect
            np.maximum(self.ranges, np.abs(a), out=self.ranges)
        z_next = self.sim.step(self.z, self.z_dot, a)
        self.z_dot = (z_next - self.z) / self.sim.h
        self.z = z_next
        self.n_steps += 1
        self.steps += 1


# -------------------------------------------------------------- environment
def _xlib():
    """libX11 through ctypes (open and close a display), or None when it is not installed."""
    name = ctypes.util.find_library("X11")
    if name is None:
        return None
    x11 = ctypes.CDLL(name)
    x11.XOpenDisplay.restype = ctypes.c_void_p
    x11.XOpenDisplay.argtypes = [ctypes.c_char_p]
    x11.XCloseDisplay.argtypes = [ctypes.c_void_p]
    int_p = ctypes.POINTER(ctypes.c_int)
    x11.XQueryExtension.argtypes = [ctypes.c_void_p, ctypes.c_char_p, int_p, int_p, int_p]
    return x11


def _x_display_error(display: str) -> str | None:
    """Why the X display cannot be opened, or None when it can (asked of libX11 itself)."""
    x11 = _xlib()
    if x11 is None:
        return "libX11 is not installed (Debian: apt-get install libx11-6)"
    handle = x11.XOpenDisplay(display.encode())
    if not handle:
        return f"cannot open the X display DISPLAY={display!r} (is an X server running there?)"
    codes = [ctypes.c_int() for _ in range(3)]
    # VTK's window needs OpenGL on the display (GLX): without it the process died of a segmentation fault
    glx = x11.XQueryExtension(handle, b"GLX", *(ctypes.byref(code) for code in codes))
    x11.XCloseDisplay(handle)
    if not glx:
        return (
            f"the X display DISPLAY={display!r} has no OpenGL (its GLX extension is missing, as over ssh -X or "
            "a VNC server without it)"
        )
    return None


@contextlib.contextmanager
def _display_held():
    """Hold a connection to ``DISPLAY`` open for the block (nothing without X).

    An X server resets when its last client leaves (Xvfb and xvfb-run's do,
    unless started with ``-noreset``), and drops a client that connects while
    it resets: VTK's window then crashes the process ("bad X server
    connection"). With this connection open, the check before the window and
    VTK's own connections never leave the server without clients.
    """
    x11 = _xlib() if sys.platform.startswith("linux") else None
    handle = x11.XOpenDisplay(os.environ.get("DISPLAY", "").encode()) if x11 is not None else None
    try:
        yield
    finally:
        if handle:
            x11.XCloseDisplay(handle)


def play_problem(off_screen: bool = False) -> str | None:
    """What stops the live window from opening here, or None when nothing does.

    Checked without opening a window in this process (a VTK window without
    a display can end the process instead of raising): pyvista importable;
    off-screen, that off-screen OpenGL renders (probed in a subprocess, see
    :func:`skfem_modal.plot.gl_available`); else no off-screen-only VTK window
    class asked for (``VTK_DEFAULT_OPENGL_WINDOW``) and, on Linux, an X
    display ``DISPLAY`` that opens.

    Parameters
    ----------
    off_screen : bool
        Whether the window would be rendered off-screen (``--off-screen``): then only pyvista and
        off-screen OpenGL are needed, no display.

    Returns
    -------
    problem : str or None
        A message saying what to install or set.
    """
    try:
        import pyvista  # noqa: F401
    except ImportError as err:
        return f"the live window needs pyvista: pip install 'skfem_modal[plot]' ({err})"
    if off_screen:
        from . import plot

        if plot.gl_available():
            return None
        return (
            "off-screen rendering does not work here: install Mesa's EGL (Debian: apt-get install libegl1 "
            "libgl1-mesa-dri) or open a window under a virtual display (xvfb-run -a skfem-modal play ...)"
        )
    if sys.platform.startswith("linux"):
        display = os.environ.get("DISPLAY", "")
        hint = (
            "; open it on a desktop, under a virtual display (Debian: apt-get install xvfb, then "
            "xvfb-run -a skfem-modal play ...), or render off-screen with --off-screen --frames N"
        )
        if not display:
            return "no display: DISPLAY is not set" + hint
        problem = _x_display_error(display)
        if problem is not None:
            return problem + hint
    window_class = os.environ.get("VTK_DEFAULT_OPENGL_WINDOW", "")
    if window_class in ("vtkEGLRenderWindow", "vtkOSOpenGLRenderWindow"):
        return (
            f"VTK_DEFAULT_OPENGL_WINDOW={window_class} renders off-screen only: unset it to open a window, "
            "or render off-screen with --off-screen --frames N"
        )
    return None


def _end_with_parent() -> None:
    """In the child: be sent SIGTERM when the parent ends, even killed before it could stop the child."""
    libc = ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True)
    libc.prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


@contextlib.contextmanager
def virtual_display(size=(1280, 800)):
    """Run an Xvfb virtual display for the ``with`` block, with ``DISPLAY`` pointing at it.

    Xvfb picks a free display number itself (``-displayfd``) and does not
    reset when its last client leaves (``-noreset``: a client connecting
    during a reset is dropped); the server is stopped and ``DISPLAY``
    restored afterwards (on Linux the server also ends with this process if
    it is killed first).

    Parameters
    ----------
    size : (int, int)
        Width and height of the virtual screen in pixels (24-bit colour).

    Yields
    ------
    display : str
        The display's name, e.g. ``":1"``.

    Raises
    ------
    PlayError
        When Xvfb is not installed or does not start, or ended while the block ran (with what it
        wrote; an error in the block gets that as a note).
    """
    if shutil.which("Xvfb") is None:
        raise PlayError("Xvfb is not installed (Debian: apt-get install xvfb)")
    read, write = os.pipe()
    log = tempfile.TemporaryFile()  # the server's own messages, for a report of why it failed
    server = subprocess.Popen(
        ["Xvfb", "-displayfd", str(write), "-screen", "0", f"{size[0]}x{size[1]}x24", "-nolisten", "tcp", "-noreset"],
        pass_fds=(write,),
        stdout=subprocess.DEVNULL,
        stderr=log,
        preexec_fn=_end_with_parent if sys.platform.startswith("linux") else None,
    )
    os.close(write)
    try:
        with os.fdopen(read) as pipe:
            number = pipe.readline().strip()
        if not number:
            raise PlayError(f"Xvfb did not start (exit code {server.wait(timeout=10)}){_said(log)}")
        previous = os.environ.get("DISPLAY")
        os.environ["DISPLAY"] = f":{number}"
        try:
            yield os.environ["DISPLAY"]
        except BaseException as err:
            if server.poll() is not None:  # the block's trouble may be the server's
                err.add_note(f"Xvfb on :{number} had ended (exit code {server.returncode}){_said(log)}")
            raise
        finally:
            if previous is None:
                os.environ.pop("DISPLAY", None)
            else:
                os.environ["DISPLAY"] = previous
        if server.poll() is not None:
            raise PlayError(f"Xvfb on :{number} ended while in use (exit code {server.returncode}){_said(log)}")
    finally:
        server.terminate()
        try:
            server.wait(timeout=10)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait()
        log.close()


def _said(log) -> str:
    """What a server wrote to its log file (the last lines), as ': ...', or ''."""
    log.seek(0)
    text = log.read().decode(errors="replace").strip()
    return f": {text[-2000:]}" if text else ""


def play(
    target=None,
    *,
    gait=None,
    gait_on: bool = True,
    frames: int | None = None,
    screenshot=None,
    off_screen: bool = False,
    window_size=(960, 600),
    follow: bool = True,
    say=print,
) -> dict:
    """Open the live window on a scene or a simulator.

    Parameters
    ----------
    target : Scene, str, path-like or ModalMuscle, optional
        A scene, a scene file, or a built simulator (default: the built-in scene).
    gait : callable, optional
        ``gait(t) -> activations`` (shape (m,)); default: the scene's
        ``activation(t, sim.ceilings)``; a bare simulator has none.
    gait_on : bool
        Start with the gait driving the muscles (False: the sliders, at zero).
    frames : int, optional
        Scripted mode: draw this many frames, then close.
        Without it the window stays until closed (q or the window's button).
    screenshot : str or path-like, optional
        Save the last frame here (PNG).
    off_screen : bool
        Render without a window (EGL or OSMesa); needs ``frames``.
    window_size : (int, int)
    follow : bool
        Keep the camera on the centre of mass as the body travels.
    say : callable
        Where the summary line goes (``print``; a no-op for quiet).

    Returns
    -------
    stats : dict
        ``frames``, ``seconds``, ``fps`` (mean frames per second), ``steps``,
        ``sim_time``, and medians in ms: ``step_ms`` (a step), ``draw_ms``
        (copying the state into the scene), ``render_ms`` (drawing the window).

    Raises
    ------
    PlayError
        When no window can open here (the message says what to install or set).
    """
    if frames is not None and (not is_whole(frames) or frames < 1):
        raise ValueError(f"frames must be a positive integer, got {frames!r}")
    if off_screen and frames is None:
        raise ValueError("off-screen play needs a number of frames (--frames N): nothing can be seen or clicked")
    problem = window_size_problem(window_size)
    if problem:
        raise ValueError(problem)
    width, height = (int(v) for v in window_size)
    if screenshot is not None:
        check_output_file(screenshot, "screenshot", ".png", "play.png")
    target = _load(target)
    problem = play_problem(off_screen)
    if problem is not None:
        raise PlayError(problem)
    sim, gait, name, ramp = _simulator(target, gait)
    # the first step may compile (numba): before the window opens, not in its first frame
    sim.step(*sim.rest_state())
    player = Player(sim, gait, gait_on=gait_on, ramp=ramp)
    from .play_view import PlayView

    with contextlib.nullcontext() if off_screen else _display_held():
        view = PlayView(player, off_screen=off_screen, window_size=(width, height), follow=follow, title=name)
        try:
            stats = view.run(frames)
            if screenshot is not None:
                view.save_screenshot(screenshot)
        finally:
            view.close()
    say(
        f"{stats['frames']} frames in {stats['seconds']:.2f} s: mean {stats['fps']:.1f} frames per second; "
        f"median ms: step {stats['step_ms']:.3f}, draw {stats['draw_ms']:.3f}, render {stats['render_ms']:.2f}; "
        f"{stats['steps']} steps, simulated {stats['sim_time']:.2f} s"
        + (f"; wrote {os.fspath(screenshot)}" if screenshot is not None else "")
    )
    return stats


def _load(target):
    """A scene file or ``None`` loaded (and so checked) as a Scene; a Scene or simulator as given."""
    from .scene import Scene

    if target is None or isinstance(target, str | os.PathLike):
        return Scene.default() if target is None else Scene.from_toml(target)
    if isinstance(target, Scene) or all(
        hasattr(target, name) for name in ("step", "rest_state", "positions", "ceilings", "h")
    ):
        return target
    raise TypeError(f"play needs a Scene, a scene file or a simulator, got {type(target).__name__}")


def _simulator(target, gait):
    """``(sim, gait, name, ramp)`` from a scene, a scene file or a simulator; a scene's gait unless one is given.

    ``ramp``: the scene's gait's (0 for a simulator), for the gait switched on later (:class:`Player`).
    """
    from .scene import Scene

    target = _load(target)
    if not isinstance(target, Scene):
        return target, gait, "simulator", 0.0
    sim = target.build()
    if gait is None and sim.n_muscles:
        ceilings = sim.ceilings
        gait = lambda t: target.activation(t, ceilings)
    return sim, gait, target.config["name"], target.ramp
