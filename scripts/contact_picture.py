"""The caterpillar's feet on the ground, the reference contact beside the Coulomb one (docs/contact.md).

    python scripts/contact_picture.py [--out docs/img/contact_feet.png]

The built-in default scene (the tutorial's crawl, the ground 0.15 below the body) run
twice, the same gait, once with ``contact_model="reference"`` (30 sampled
contact points, velocities only) and once with the default Coulomb contact
(friction 0.5). The picture shows both at the step where the reference's
feet are deepest in the ground, zoomed on the lower part of the body: the
ground line, the vertices below it in red, and each one's depth (of the
body's largest extent) in its title. Needs matplotlib (the ``plot`` extra),
no GL.
"""

from __future__ import annotations

import argparse
import copy
import os

import numpy as np

import skfem_modal as sm
from skfem_modal.contact import ALLOWANCE
from skfem_modal.scene import DEFAULT_SCENE, Scene

OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "docs", "img", "contact_feet.png")
MODELS = ("reference", "coulomb")
RED = "#d62728"


def crawl(model):
    """The built-in default scene (the tutorial's crawl) with a contact model: the simulator and its states.

    Returns
    -------
    sim : ModalMuscle
    states : ndarray, shape (steps + 1, r)
    """
    data = copy.deepcopy(DEFAULT_SCENE)
    if model != data["ground"]["model"]:
        data["ground"] = {"offset": data["ground"]["offset"], "model": model}
    scene = Scene.from_dict(data)
    sim = scene.build()
    gait = lambda t: scene.activation(t, sim.ceilings)  # noqa: E731
    states = [sim.rest_state()[0]] + [record.z for record in sm.simulate(sim, scene.n_steps, gait)]
    return sim, np.array(states)


def draw(ax, mesh, sim, z, size, window):
    """One panel: the body at state ``z`` in the box ``window`` ((x0, x1), (y0, y1)), below-ground vertices red."""
    from matplotlib.tri import Triangulation

    x = sim.positions(z)
    ground = sim.ground
    (x0, x1), (y0, y1) = window
    ax.axhspan(y0 - 1.0, ground, color="#e9dfcf", zorder=0)
    ax.axhline(ground, color="#6b5a44", lw=1.6, zorder=1)
    tri = Triangulation(x[:, 0], x[:, 1], mesh.t.T)
    ax.tripcolor(tri, np.zeros(x.shape[0]), cmap="Greens", vmin=-1.0, vmax=1.5, shading="flat", zorder=2)
    ax.triplot(tri, color="#2f5d3a", lw=0.25, alpha=0.6, zorder=3)
    below = x[:, 1] < ground - 1e-9
    ax.scatter(x[below, 0], x[below, 1], s=16, color=RED, zorder=4, linewidths=0)
    depth = max(0.0, ground - x[:, 1].min()) / size
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    for spine in ax.spines.values():
        spine.set_color("0.7")
    return depth, int(np.count_nonzero(below))


def percent(fraction) -> str:
    """A fraction of the body's size as a percentage, with two significant digits when it is tiny."""
    return f"{100 * fraction:.2f} %" if fraction >= 1e-4 else f"{100 * fraction:.1g} %"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=OUT)
    args = parser.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = {model: crawl(model) for model in MODELS}
    mesh = runs["reference"][0].mesh
    size = float(np.ptp(mesh.p, axis=1).max())
    sim, states = runs["reference"]
    depths = np.array([sim.penetration(z) for z in states])
    step = int(np.argmax(depths))
    deepest = int(np.argmin(sim.positions(states[step])[:, 1]))  # the reference's deepest vertex: its foot
    fig, axes = plt.subplots(1, 2, figsize=(12, 3.5), dpi=120)
    for ax, model in zip(axes, MODELS):
        sim, states = runs[model]
        middle = sim.positions(states[step])[deepest, 0]
        # around that foot in both runs, the same size of box
        window = ((middle - 0.4 * size, middle + 0.4 * size), (sim.ground - 0.06 * size, sim.ground + 0.26 * size))
        depth, count = draw(ax, mesh, sim, states[step], size, window)
        label = (
            "reference (30 contact points)" if model == "reference" else "Coulomb, the default (every boundary vertex)"
        )
        within = f" (allowed {100 * ALLOWANCE:g} %)" if depth <= ALLOWANCE else ""
        vertices = "vertex" if count == 1 else "vertices"
        ax.set_title(
            f"{label}\n{count} {vertices} below the ground, deepest {percent(depth)} of the size{within}",
            fontsize=10.5,
        )
    axes[0].scatter([], [], s=16, color=RED, label="a vertex below the ground")
    axes[0].legend(loc="upper left", fontsize=9, frameon=False)
    h = runs["reference"][0].h
    fig.suptitle(f"The tutorial's caterpillar crawl at t = {step * h:.2f} s, where the reference's feet are deepest")
    fig.tight_layout()
    fig.savefig(args.out, bbox_inches="tight", pad_inches=0.08)
    print(f"step {step} (t = {step * sim.h:.2f} s): wrote {args.out}")


if __name__ == "__main__":
    main()
