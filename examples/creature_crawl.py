"""A 3D four-legged creature of tetrahedra walking on the ground with its modes as muscles.

    python examples/creature_crawl.py [OUT_DIR]

Writes OUT_DIR/creature.pvd for ParaView and prints how far it walked and how
far its feet ever went below the ground.
"""

import sys

import numpy as np

import skfem_modal as sm
from skfem_modal.export import FrameWriter
from skfem_modal.muscles import sine_gait
from skfem_modal.sim import ModalMuscle

out = sys.argv[1] if len(sys.argv) > 1 else "out/creature_crawl"
mesh = sm.creature()  # body slab on four legs, z up, feet at z = 0
ground = -0.05
sim = ModalMuscle.from_mesh(
    mesh,
    n_muscles=4,
    n_weights=8,
    n_clusters=20,
    mu=1e5,
    rho=1e3,
    h=0.01,
    gravity=[0.0, 0.0, -9.8],
    ground=ground,
    friction=0.5,  # Coulomb: no vertex over 0.02 % of the size below the ground; feet stick or slip
)
print("effects:", ", ".join(sim.effects), f"| subspace {sim.B.shape[1]}, {sim.n_clusters} clusters")

amplitudes = np.full(4, 0.4) * sim.ceilings
periods = [1.0, 0.8, 0.6, 0.9]
phases = [0.0, 0.25, 0.5, 0.75]

z, z_dot, _ = sim.rest_state()
start = sim.com(z)
lowest = np.inf
with FrameWriter(out, mesh, name="creature", cell_data={"cluster": sim.labels}) as frames:
    for i in range(400):
        t = i * sim.h
        a = sine_gait(t, amplitudes, periods, phases)
        z_next = sim.step(z, z_dot, a)
        z_dot, z = (z_next - z) / sim.h, z_next
        lowest = min(lowest, sim.positions(z)[:, 2].min())  # every vertex
        if i % 4 == 0:
            frames.write(t + sim.h, sim.positions(z), field_data={"activation": a})
travel = sim.com(z) - start
print(f"centre of mass travel: {np.round(travel, 3)} (horizontal {np.linalg.norm(travel[:2]):.3f})")
print(f"deepest vertex below the ground: {max(0.0, ground - lowest):.2e}")
print(f"wrote {frames.pvd_path} ({frames.count} frames)")
