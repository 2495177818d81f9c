"""The tutorial's caterpillar crawling under gravity on the ground.

    python examples/caterpillar_crawl.py [OUT_DIR]

Writes OUT_DIR/crawl.pvd (every 5th of 450 frames) for ParaView and prints
the centre-of-mass travel: -4.438 in x, height in [-0.130, 0.244], as the
reference implementation.
"""

import sys

import numpy as np

import skfem_modal as sm
from skfem_modal.export import FrameWriter
from skfem_modal.muscles import sine_gait
from skfem_modal.sim import ModalMuscle

out = sys.argv[1] if len(sys.argv) > 1 else "out/caterpillar_crawl"
mesh = sm.caterpillar()
ground = mesh.p[1].min() - 0.15  # the floor just below the feet: it drops, lands, crawls
sim = ModalMuscle.from_mesh(
    mesh,
    n_muscles=4,
    muscle_signs=[1, -1, -1, 1],  # the tutorial's mode signs (crawl direction depends on them)
    n_weights=8,
    n_clusters=20,
    mu=1e6,
    rho=1e3,
    h=0.01,
    gravity=[0.0, -9.8],
    ground=ground,
    contact_model="reference",  # the tutorial's contact: its numbers, to the last digit
    n_contacts=30,
)
print("effects:", ", ".join(sim.effects))

# the gait: amplitude (fraction of each muscle's ceiling), period (s), phase (periods)
amplitudes = np.array([0.45, 0.35, 0.25, 0.15]) * sim.ceilings
periods = [1.2, 0.8, 1.0, 0.6]
phases = [0.0, 0.25, 0.5, 0.1]

z, z_dot, a = sim.rest_state()
com = []
with FrameWriter(out, mesh, name="crawl", cell_data={"cluster": sim.labels}) as frames:
    for i in range(450):
        t = i * sim.h
        a = sine_gait(t, amplitudes, periods, phases)
        z_next = sim.step(z, z_dot, a)
        z_dot, z = (z_next - z) / sim.h, z_next
        com.append(sim.com(z))
        if i % 5 == 0:  # full positions only for the frames written out
            frames.write(t + sim.h, sim.positions(z), field_data={"activation": a})
com = np.array(com)
print(f"centre of mass travel in x: {com[-1, 0] - com[0, 0]:+.3f}")
print(f"centre of mass height in [{com[:, 1].min():.3f}, {com[:, 1].max():.3f}] (ground at {ground:.3f})")
print(f"wrote {frames.pvd_path} ({frames.count} frames)")
