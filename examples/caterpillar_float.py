"""The caterpillar floating in space, driven by its first two muscles.

    python examples/caterpillar_float.py [OUT_DIR]

No gravity and no ground: the body changes shape freely but its centre of mass
stays put (momentum is conserved). Writes OUT_DIR/float.pvd with the
displacement and the commanded activations, and prints the centre-of-mass
drift and the commanded versus realised modal amplitudes.
"""

import sys

import numpy as np

import skfem_modal as sm
from skfem_modal.export import FrameWriter
from skfem_modal.muscles import sine_gait
from skfem_modal.sim import ModalMuscle

out = sys.argv[1] if len(sys.argv) > 1 else "out/caterpillar_float"
mesh = sm.caterpillar()
sim = ModalMuscle.from_mesh(mesh, n_muscles=4, mu=1e5, rho=1e3, h=0.02)
print("effects:", ", ".join(sim.effects))  # elasticity, inertia, muscles: nothing else is built

amplitudes = np.array([0.9, 0.6, 0.0, 0.0]) * sim.ceilings
periods = [1.0, 0.7, 1.0, 1.0]
phases = [0.0, 0.25, 0.0, 0.0]

z, z_dot, _ = sim.rest_state()
start = sim.com(z)
with FrameWriter(out, mesh, name="float", cell_data={"cluster": sim.labels}) as frames:
    for i in range(180):
        t = i * sim.h
        a = sine_gait(t, amplitudes, periods, phases)
        z_next = sim.step(z, z_dot, a)
        z_dot, z = (z_next - z) / sim.h, z_next
        if i % 3 == 0:
            frames.write(t + sim.h, sim.positions(z), field_data={"activation": a})
        if i % 45 == 44:
            print(
                f"t={t + sim.h:4.2f}  commanded {np.round(a[:2], 3)}  "
                f"realised {np.round(sim.muscle_amplitudes(z)[:2], 3)}"
            )
print(f"centre of mass drift over {i + 1} steps: {np.abs(sim.com(z) - start).max():.1e}")
print(f"wrote {frames.pvd_path} ({frames.count} frames)")
