"""The pyvista window of :mod:`skfem_modal.play`: the body, the ground, sliders, buttons, keys.

Everything that simulates lives in :class:`~skfem_modal.play.Player`; this
module only draws it and forwards the user's input to it. Built for frame
rate under software rendering (Mesa's llvmpipe): the body is one actor made
once whose points are overwritten in place each frame (a 3D body draws its
boundary triangles only), no multisampling (it costs llvmpipe four times the
frame), and the status text changes a few times a second, not every frame.
"""

from __future__ import annotations

import time

import numpy as np

from .camera import Camera

__all__ = ["PlayView", "KEYS"]

#: Keys of the live window and what they do.
KEYS = {"space": "pause / resume", "r": "reset", "g": "gait on / off", "q": "quit"}

_BODY = "#3f8f63"
_GROUND = "#d9d9d9"
_GROUND_LINES = "#a6a6a6"
#: Fraction of the window width the sliders take, on the left; the body is framed right of it.
_PANEL = 0.27
_STATUS_EVERY = 0.25  # seconds between status-line updates
# seconds between slider moves while the gait drives them: each move redraws four text labels,
# which costs software rendering a third of the frame when done every frame
_GAIT_SLIDERS_EVERY = 1 / 15


def _surface_triangles(mesh) -> np.ndarray:
    """The triangles to draw, shape (f, 3): all of a 2D mesh, the boundary facets of a 3D one."""
    if mesh.p.shape[0] == 2:
        return mesh.t.T
    return mesh.facets[:, mesh.boundary_facets()].T


def _grid_cell(extent: float) -> float:
    """A round cell size (1, 2 or 5 times a power of ten) near a sixth of ``extent``."""
    target = extent / 6
    power = 10 ** np.floor(np.log10(target))
    return float(power * max(f for f in (1, 2, 5) if f * power <= target))


def _ground_meshes(pv, dim: int, up: int, height: float, cell: float, half_cells: int):
    """The ground as a fill and grid lines ``cell`` apart, centred at the origin of the horizontal axes
    (the view moves it under the body).

    A 3D ground is a square of the plane; a 2D one a band two cells deep below
    the ground line. The lines show the travel when the camera follows the
    body; they are drawn as a few long lines over one quad, not as the edges
    of many cells (which costs software rendering a pass over every cell).

    Returns
    -------
    fill, lines : pyvista.PolyData
    """
    half = half_cells * cell
    ticks = cell * np.arange(-half_cells, half_cells + 1)
    # the lines sit a hair off the fill, on the camera's side, so the two never fight over depth
    lift = 1e-3 * cell
    if dim == 2:
        across = 0 if up == 1 else 1
        corners = np.zeros((4, 3))
        corners[:, across] = [-half, half, half, -half]
        corners[:, up] = [height - 2 * cell, height - 2 * cell, height, height]
        ends = np.zeros((len(ticks) + 1, 2, 3))
        ends[:-1, :, across] = ticks[:, None]
        ends[:-1, :, up] = [height - 2 * cell, height]
        ends[-1, :, across] = [-half, half]
        ends[-1, :, up] = height
        ends[..., 2] = lift
    else:
        a, b = (k for k in range(3) if k != up)
        corners = np.zeros((4, 3))
        corners[:, a] = [-half, half, half, -half]
        corners[:, b] = [-half, -half, half, half]
        corners[:, up] = height
        n = len(ticks)
        ends = np.zeros((2 * n, 2, 3))
        ends[:n, :, a] = ticks[:, None]
        ends[:n, :, b] = [-half, half]
        ends[n:, :, b] = ticks[:, None]
        ends[n:, :, a] = [-half, half]
        ends[..., up] = height + lift
    fill = pv.PolyData(corners, np.array([4, 0, 1, 2, 3]))
    count = len(ends)
    segments = np.column_stack([np.full(count, 2), np.arange(2 * count).reshape(-1, 2)])
    lines = pv.PolyData(ends.reshape(-1, 3), lines=segments.ravel())
    return fill, lines


class PlayView:
    """A pyvista window showing a :class:`~skfem_modal.play.Player`.

    Parameters
    ----------
    player : skfem_modal.play.Player
    off_screen : bool
        Render without a window (no input; for scripted runs).
    window_size : (int, int)
    follow : bool
        Move the camera with the centre of mass (the ground grid shows the travel).
    title : str
    """

    def __init__(self, player, *, off_screen=False, window_size=(960, 600), follow=True, title="skfem-modal play"):
        from .plot import _headless_vtk

        if off_screen:
            _headless_vtk()
        import pyvista as pv

        self.player = player
        self.follow = follow
        self.off_screen = off_screen
        sim = player.sim
        self.dim, self.up = sim.dim, sim.up
        theme = pv.themes.DocumentTheme()
        theme.multi_samples = 0
        theme.anti_aliasing = None
        theme.background = "white"
        # one light that follows the camera: each light is a term in every pixel's shading
        self.plotter = pv.Plotter(
            off_screen=off_screen, window_size=list(window_size), theme=theme, title=title, lighting="none"
        )
        self.plotter.add_light(pv.Light(light_type="headlight"))

        rest = sim.mesh.p.T
        points = np.zeros((rest.shape[0], 3))
        points[:, : self.dim] = player.positions()
        triangles = _surface_triangles(sim.mesh)
        cells = np.column_stack([np.full(len(triangles), 3), triangles]).ravel()
        self.body = pv.PolyData(points, cells)
        self._points = self.body.points  # a view of VTK's array: written in place each frame
        self.plotter.add_mesh(
            self.body,
            color=_BODY,
            smooth_shading=False,
            # a 2D body is flat and faces the camera: shading it would only darken it evenly
            lighting=self.dim == 3,
            ambient=0.25 if self.dim == 3 else 0.0,  # unlit, colour = ambient + diffuse
            reset_camera=False,
        )
        self.extent = float(np.ptp(rest, axis=0).max())
        self.ground_cell = None
        self.ground_actors = []
        if getattr(sim, "ground", None) is not None:
            self.ground_cell = _grid_cell(self.extent)
            half = int(np.ceil(3 * self.extent / self.ground_cell))
            fill, lines = _ground_meshes(pv, self.dim, self.up, float(sim.ground), self.ground_cell, half)
            self.ground_actors = [
                self.plotter.add_mesh(fill, color=_GROUND, lighting=False, reset_camera=False),
                self.plotter.add_mesh(lines, color=_GROUND_LINES, lighting=False, reset_camera=False),
            ]
        self._frame_camera()
        self._add_controls(pv, window_size)
        self._status_time = -np.inf
        self._sliders_time = -np.inf
        self._shown = {}

    # ------------------------------------------------------------ building
    def _frame_camera(self) -> None:
        """Fit the body right of the slider panel, looking along the ground (3D: from a side and above)."""
        camera = self.plotter.camera
        x = self._points
        lo, hi = x.min(axis=0), x.max(axis=0)
        pad = 0.25 * self.extent
        centre = (lo + hi) / 2
        e_up = np.eye(3)[self.up]
        # the centre of the view moves right of the slider panel
        camera.SetWindowCenter(-_PANEL, 0.0)
        camera.focal_point = centre
        if self.dim == 2:
            # the scene's up axis up the screen (x up: the body lies on its side otherwise), as render draws it
            view = Camera.looking_at(e_up[:2], 2)
            self.plotter.enable_parallel_projection()
            camera.position = centre + np.array([0.0, 0.0, 4.0 * self.extent])
            camera.up = view.screen_up
            width, height = self.plotter.window_size
            span = view.screen((hi - lo)[:2][None])[0]
            # half the height shown, so that the padded body fits the free part of the window
            camera.parallel_scale = 0.5 * max(
                (abs(span[1]) + 2 * pad) / 0.8, (abs(span[0]) + 2 * pad) * height / (width * (1 - _PANEL))
            )
            camera.clipping_range = (0.1 * self.extent, 10.0 * self.extent)
        else:
            # from where render's pictures look (a y-up body was seen from behind, walking leftwards)
            view = Camera.looking_at(e_up, 3)
            camera.position = centre + view.towards
            camera.up = view.screen_up
            bounds = np.column_stack([lo - pad, hi + pad]).ravel()
            self.plotter.renderer.ResetCamera(*bounds)
            camera.Zoom(1.1)
        self._anchor = self.player.com()
        self._place_ground(self._anchor)

    def _place_ground(self, com) -> None:
        """The ground's grid under ``com`` (dim,), snapped to its cells, so its lines show the travel."""
        if not self.ground_actors:
            return
        snap = np.zeros(3)
        snap[: self.dim] = np.round(com / self.ground_cell) * self.ground_cell
        snap[self.up] = 0.0
        for actor in self.ground_actors:
            actor.SetPosition(*snap)

    def _add_controls(self, pv, window_size) -> None:
        plotter = self.plotter
        player = self.player
        m = player.sim.n_muscles
        self.sliders = []
        self._listening = False
        spacing = min(0.13, 0.7 / max(m, 1))
        for k in range(m):
            y = 0.84 - k * spacing
            widget = plotter.add_slider_widget(
                lambda value, k=k: self._slider_moved(k, value),
                [-player.ranges[k], player.ranges[k]],
                value=0.0,
                title=f"muscle {k}",
                pointa=(0.03, y),
                pointb=(_PANEL - 0.02, y),
                interaction_event="always",
                style="modern",
                title_height=min(0.025, spacing / 4),
                fmt="%+.3g",
            )
            self.sliders.append(widget)
        width, height = window_size
        size = 26
        x = width - 180
        self.buttons = {}
        self.button_boxes = {}  # name -> (x, y, size) in pixels from the lower left
        for row, (name, label) in enumerate([("gait", "gait (g)"), ("pause", "pause (space)"), ("reset", "reset (r)")]):
            y = height - 66 - row * 38  # under the status line (it ran into the first button below 700 wide)
            self.button_boxes[name] = (x, y, size)
            self.buttons[name] = plotter.add_checkbox_button_widget(
                lambda state, name=name: self._button(name, state),
                value=self._button_state(name),
                position=(x, y),
                size=size,
                border_size=3,
                color_on="#3f8f63",
                color_off="#c8c8c8",
            )
            plotter.add_text(label, position=(x + size + 8, y + 5), font_size=9, color="black")
        self.status = plotter.add_text("", position=(10, height - 24), font_size=9, color="black")
        self._listening = True
        help_line = "   ".join(f"{key}: {what}" for key, what in KEYS.items())
        plotter.add_text(help_line, position=(10, 8), font_size=8, color="#555555")
        if not self.off_screen:
            if self.dim == 2:
                # a flat scene pans and zooms: the trackball (and pyvista's v, an isometric view) turned
                # it out of its plane, showing the body and the ground edge-on
                getattr(plotter, "enable_2d_style", plotter.enable_image_style)()  # (pyvista before 0.44: image's)
                plotter.clear_events_for_key("v")
            # after the interactor style's own handler (its "r" resets the camera to every actor)
            plotter.iren.interactor.AddObserver("CharEvent", self._key, -1.0)

    def _button_state(self, name: str) -> bool:
        return {"gait": self.player.gait_on, "pause": self.player.paused}.get(name, False)

    # -------------------------------------------------------------- input
    def _slider_moved(self, k: int, value: float) -> None:
        # pyvista calls back once as it makes the slider: not the user's doing
        if self._listening:
            self.player.set_slider(k, value)

    def _button(self, name: str, state) -> None:
        player = self.player
        if name == "reset":
            self.reset()
        elif name == "gait" and bool(state) != player.gait_on:
            player.toggle_gait()
        elif name == "pause" and bool(state) != player.paused:
            player.toggle_pause()

    def _key(self, interactor, _event) -> None:
        key = interactor.GetKeySym()
        if key == "space":
            self.player.toggle_pause()
        elif key in ("r", "R"):
            self.reset()
        elif key in ("g", "G"):
            self.player.toggle_gait()

    def reset(self) -> None:
        """The body at rest, sliders at zero, the camera framed on it again."""
        self.player.reset()
        self.draw()
        self._frame_camera()

    # ------------------------------------------------------------- drawing
    def draw(self, current: bool = False) -> None:
        """Copy the player's state into the scene: points, camera, ground, widgets, status.

        The status line and the sliders under the gait change a few times a
        second; ``current`` brings them up to date now (for a screenshot).
        """
        player = self.player
        self._points[:, : self.dim] = player.positions()
        self.body.GetPoints().Modified()
        if self.follow:
            com = player.com()
            shift = np.zeros(3)
            shift[: self.dim] = com - self._anchor
            shift[self.up] = 0.0
            if shift.any():
                camera = self.plotter.camera
                camera.position = np.add(camera.position, shift)
                camera.focal_point = np.add(camera.focal_point, shift)
                self._anchor = com
                self._place_ground(com)
        now = time.perf_counter()
        self._sync_buttons()
        if current or not player.gait_on or now - self._sliders_time >= _GAIT_SLIDERS_EVERY:
            self._sliders_time = now
            self._sync_sliders()
        if current or now - self._status_time >= _STATUS_EVERY:
            self._status_time = now
            self.status.SetInput(self._status_text())

    def _sync_buttons(self) -> None:
        """Buttons show the player's state (keys and reset change it behind their backs)."""
        shown = self._shown
        for name, widget in self.buttons.items():
            state = self._button_state(name)
            if shown.get(name) != state:
                widget.GetRepresentation().SetState(int(state))
                shown[name] = state

    def _sync_sliders(self) -> None:
        """Sliders show the activations in effect: the gait's while it drives the muscles."""
        player = self.player
        values = player.activation() if player.gait_on else player.sliders
        for k, widget in enumerate(self.sliders):
            if self._shown.get(("range", k)) != player.ranges[k]:  # a gait past the ceiling widened it
                widget.GetRepresentation().SetMinimumValue(-player.ranges[k])
                widget.GetRepresentation().SetMaximumValue(player.ranges[k])
                self._shown["range", k] = player.ranges[k]
            # a gait's zero crossing is round-off off zero (sin(pi) = 1.2e-16): shown as 0, not +1.31e-15
            value = float(values[k]) if abs(values[k]) > 1e-12 * player.ranges[k] else 0.0
            if self._shown.get(k) != value:
                widget.GetRepresentation().SetValue(value)
                self._shown[k] = value

    def _status_text(self) -> str:
        player = self.player
        state = "paused" if player.paused else ("gait" if player.gait_on else "sliders")
        text = (
            f"t = {player.t:7.2f}   {player.fps:5.1f} frames/s   step {player.step_ms:6.3f} ms"
            f" x {player.steps_per_frame:.1f}/frame   {state}" + ("   (slower than real time)" if player.behind else "")
        )
        return text + (f"\n{player.message}" if player.message else "")

    def render(self) -> None:
        """Draw the window now (the render window itself: pyvista's ``render`` skips unshown windows)."""
        self.plotter.render_window.Render()

    # ---------------------------------------------------------------- loop
    def run(self, frames: int | None = None) -> dict:
        """Frames until the window closes (q), or ``frames`` of them.

        Returns
        -------
        stats : dict
            ``frames``, ``seconds``, ``fps`` (mean), ``steps``, ``sim_time``;
            medians in milliseconds: ``step_ms`` (a step, per frame that
            stepped), ``draw_ms`` (copying the state into the scene),
            ``render_ms`` (drawing the window).
        """
        plotter = self.plotter
        player = self.player
        interactive = not self.off_screen
        if interactive:
            plotter.show(interactive_update=True, auto_close=False)
            interactor = plotter.iren.interactor
        else:
            self.render()
        phases = {"step": [], "draw": [], "render": []}
        steps = 0
        count = 0
        clock = time.perf_counter
        start = clock()
        while frames is None or count < frames:
            if interactive:
                interactor.ProcessEvents()
                if interactor.GetDone():
                    break
            if player.frame():
                steps += player.steps
                phases["step"].append(player.step_seconds / player.steps)
            drawing = clock()
            self.draw()
            rendering = clock()
            self.render()
            phases["draw"].append(rendering - drawing)
            phases["render"].append(clock() - rendering)
            count += 1
        seconds = clock() - start
        stats = {
            "frames": count,
            "seconds": seconds,
            "fps": count / seconds if seconds > 0 else 0.0,
            "steps": steps,
            "sim_time": player.t,
        }
        for name, values in phases.items():
            stats[f"{name}_ms"] = 1e3 * float(np.median(values)) if values else 0.0
        return stats

    def screenshot(self) -> np.ndarray:
        """The window's pixels now, shape (height, width, 3), uint8: status line and sliders up to date."""
        self.draw(current=True)
        self.render()
        return np.asarray(self.plotter.screenshot(return_img=True))[:, :, :3]

    def save_screenshot(self, path) -> str:
        """Save the window as a PNG at ``path`` (str or path-like; folders made as needed); returns the path (str)."""
        import os

        from .plot import _save_png

        path = os.fspath(path)
        folder = os.path.dirname(path)
        if folder:
            os.makedirs(folder, exist_ok=True)
        return _save_png(self.screenshot(), path)

    def close(self) -> None:
        """Close the window and free its resources."""
        self.plotter.close()
