"""Drive the live window as a user would, from events, and print what happened as JSON.

    python tests/play_window_driver.py SCENE      (SCENE: a .toml file or "default")

Run by tests/test_play.py in a subprocess with DISPLAY set (Xvfb). Mouse and
key events go to the window's interactor, so they pass through the slider,
button and key handlers exactly as real input does; time is a fake clock
moving 1/40 s a frame, so the run does not depend on the machine's speed.
"""

from __future__ import annotations

import json
import sys

import numpy as np

FRAME = 1 / 40


class FakeClock:
    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


def main(target: str) -> dict:
    from skfem_modal.play import Player, _simulator
    from skfem_modal.play_view import PlayView

    sim, gait, _, ramp = _simulator(None if target == "default" else target, None)
    clock = FakeClock()
    player = Player(sim, gait, ramp=ramp, clock=clock)
    view = PlayView(player, window_size=(960, 600))
    plotter = view.plotter
    plotter.show(interactive_update=True, auto_close=False)
    interactor = plotter.iren.interactor
    renderer = plotter.renderer

    def frames(n):
        for _ in range(n):
            clock.now += FRAME
            player.frame()
            view.draw()
            view.render()

    def mouse(event, x, y):
        interactor.SetEventInformation(int(round(x)), int(round(y)), 0, 0, "\0", 0)
        interactor.InvokeEvent(event)

    def key(sym, code):
        interactor.SetKeySym(sym)
        interactor.SetKeyCode(code)
        interactor.InvokeEvent("KeyPressEvent")
        interactor.InvokeEvent("CharEvent")

    def drag_slider(k, fraction):
        """Press on the knob (at zero: the middle), move a fraction of the half-length, release."""
        rep = view.sliders[k].GetRepresentation()
        x1, y1 = rep.GetPoint1Coordinate().GetComputedDisplayValue(renderer)
        x2, _ = rep.GetPoint2Coordinate().GetComputedDisplayValue(renderer)
        middle = (x1 + x2) / 2
        mouse("LeftButtonPressEvent", middle, y1)
        for step in np.linspace(0, 1, 6)[1:]:
            mouse("MouseMoveEvent", middle + step * fraction * (x2 - x1) / 2, y1)
        mouse("LeftButtonReleaseEvent", middle + fraction * (x2 - x1) / 2, y1)

    def click(name):
        x, y, size = view.button_boxes[name]
        mouse("MouseMoveEvent", x + size / 2, y + size / 2)  # a button takes a click only when hovered
        mouse("LeftButtonPressEvent", x + size / 2, y + size / 2)
        mouse("LeftButtonReleaseEvent", x + size / 2, y + size / 2)

    frames(2)
    drags = []
    for k, fraction in ((0, 0.6), (sim.n_muscles - 1, -0.6)):
        view.reset()
        frames(1)
        drag_slider(k, fraction)
        amplitudes = []
        for _ in range(40):
            frames(1)
            amplitudes.append(float(player.amplitudes()[k]))
        drags.append(
            {
                "fraction": fraction,
                "range": float(player.ranges[k]),
                "slider": float(player.sliders[k]),
                "widget": float(view.sliders[k].GetRepresentation().GetValue()),
                "gait_on": player.gait_on,
                "amplitudes": amplitudes,
            }
        )
    keys = {}
    key("r", "r")
    frames(1)
    keys["r_time"] = player.t
    keys["r_sliders"] = float(np.abs(player.sliders).max())
    keys["r_widgets"] = max(abs(w.GetRepresentation().GetValue()) for w in view.sliders)
    key("g", "g")
    keys["g"] = player.gait_on
    key("space", " ")
    keys["space"] = player.paused
    paused_at = player.t
    frames(5)
    keys["paused_time_moved"] = player.t != paused_at
    key("space", " ")
    frames(10)
    click("gait")
    keys["clicked_gait"] = player.gait_on
    frames(5)
    click("reset")
    keys["clicked_reset_time"] = player.t
    key("g", "g")
    frames(40)
    image = view.screenshot().astype(float)
    body = np.abs(image - [0x3F, 0x8F, 0x63]).max(axis=2) < 60
    white = (image > 250).all(axis=2)
    # the live loop ends when q is pressed (here in its seventh frame)
    frame = player.frame
    count = []

    def frame_then_quit():
        count.append(1)
        if len(count) == 7:
            key("q", "q")
        return frame()

    player.frame = frame_then_quit
    keys["quit_frames"] = view.run()["frames"]
    keys["after_quit_std"] = float(view.screenshot().std())  # --screenshot still saves the last frame
    view.close()
    return {
        "drags": drags,
        "keys": keys,
        "screenshot": {
            "shape": list(image.shape),
            "std": float(image.std()),
            "body_fraction": float(body.mean()),
            "background_fraction": float(white.mean()),
        },
    }


if __name__ == "__main__":
    print(json.dumps(main(sys.argv[1])))
