"""Where a step's time goes: each operation of an iteration timed alone.

    python benchmarks/profile_step.py

For the three scenes of bench_step.py (numpy path; the numba path runs a
floating step's iterations in one compiled call), the operations of one
local/global iteration and of the per-step set-up are each timed in a tight
loop on the simulator's own arrays, and set against the measured step. The
sum of the parts times the iteration count should come close to the step:
what is left is Python's own overhead between the calls.
"""

from __future__ import annotations

import os
import platform
import sys
import time
import timeit

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bench_step  # noqa: E402

from skfem_modal._kron3 import EYE16, HORN_BLOCK, QQ_TO_BLOCK_TRACE  # noqa: E402
from skfem_modal.muscles import sine_gait  # noqa: E402
from skfem_modal.rotations import certify_levels, next_squarings  # noqa: E402


def us(func, number=2000):
    return min(timeit.repeat(func, number=number, repeat=5)) / number * 1e6


def build(scene):
    return bench_step.build(scene, "numpy")


def run(sim, scene, steps=None):
    """Step through the scene; returns the median step in us, the mean iterations and a mid-run state."""
    z, z_dot, _ = sim.rest_state()
    amp, per, ph = scene["gait"]
    times, its, mid = [], [], None
    steps = steps or scene["steps"]
    for i in range(steps):
        a = sine_gait(i * sim.h, amp, per, ph)
        start = time.perf_counter()
        z_next = sim.step(z, z_dot, a)
        times.append(time.perf_counter() - start)
        its.append(sim.iterations)
        z_dot, z = (z_next - z) / sim.h, z_next
        if i == steps // 2:
            mid = (z.copy(), z_dot.copy(), a)
    return float(np.median(times) * 1e6), float(np.mean(its)), mid


def parts_2d(sim, z, z_dot, a):
    _, _, G, W = sim._step_ops
    c = sim._K_inertia @ (z + sim.h * z_dot) + sim._c_ext
    if sim._contact is not None:
        c = np.concatenate([c, sim._contact.Je @ c])
    cs = (G @ z).reshape(-1, 2)
    y = c + W @ cs.ravel()
    iterates = [z + 1e-3 * k for k in range(sim.max_iter + 1)]

    def normalise():
        norm = np.hypot(cs[:, 0], cs[:, 1])
        np.count_nonzero(norm)
        return cs / norm[:, None]

    def batch_test():
        steps = np.diff(np.array(iterates), axis=0)
        change2 = np.einsum("ij,ij->i", steps, steps)
        return np.count_nonzero(~(change2 >= sim._tol2))

    iteration = {
        "G z (rotation features)": lambda: G @ z,
        "normalise (c, s): hypot, check, divide": normalise,
        "W (c, s) + c": lambda: c + W @ cs.ravel(),
    }
    if sim._contact is not None:
        contact = sim._contact
        contact.start_step(z)
        iteration["contact projection"] = lambda: contact.correct(y)
    per_step = {
        "activation: operator rows": lambda: sim._set_activation(a),
        "right-hand side c": lambda: sim._K_inertia @ (z + sim.h * z_dot) + sim._c_ext,
        f"stopping test of {sim.max_iter} iterations, one batch": batch_test,
    }
    return iteration, per_step


def parts_3d(sim, z, z_dot, a):
    """The Kronecker-form step (skinning bases; see skfem_modal/_kron3.py)."""
    kr = sim._kron
    sim.step(z, z_dot, a)  # the buffers hold this step
    K, n, s, k = kr.K, kr.n, kr.squarings, sim.iterations
    Z_old, Z_new, F16, P0, P16, R, R16, squarings = kr._views[0]
    RT, RT16, trace = kr.RT, kr.RT[:, :16], kr.RT[:, 16:]

    def power():
        for operands in squarings[s]:
            np.matmul(*operands)

    def activation():
        np.dot(a, kr.A_all, kr.A_product)
        np.add(kr.A_product[: kr.A0.size], kr.A0, kr.Yt_active)
        np.add(kr.A_product[kr.A0.size :].reshape(K, -1), kr.WA0, kr.Wt_active)

    def right_hand_side():
        kr.C_input[:K] = z.reshape(K, 3)
        kr.C_input[K : 2 * K] = z_dot.reshape(K, 3)
        np.matmul(kr.C_operator, kr.C_input, kr.C_slot)
        kr.Z[0, :K, :3] = z.reshape(K, 3)

    def batch_test():
        steps = (kr.Z[1:k] - kr.Z[: k - 1]).reshape(k - 1, 1, -1)
        return np.matmul(steps, steps.transpose(0, 2, 1)).ravel().min()

    def certificate():
        levels = kr.levels_by_level[: s + 1, : k * n]
        np.matmul(kr.powers_by_level[1 : s + 1, : k * n], EYE16, levels[1:])
        return next_squarings(certify_levels(levels)[2])

    iteration = {
        "Y Z: the clusters' F (Kronecker form)": lambda: np.dot(kr.Yt, Z_old, kr.F),
        "Horn matrices and shifts": lambda: np.dot(F16, HORN_BLOCK, P0),
        f"{s} squarings of {n} 4x4 matrices": power,
        "R and traces from the last power": lambda: np.dot(P16[s], QQ_TO_BLOCK_TRACE, RT),
        "divide by the traces": lambda: np.divide(RT16, trace, R16),
        "V R^T + C (the global step)": lambda: np.dot(kr.Wt, R, Z_new),
    }
    per_step = {
        "activation: operator rows and columns": activation,
        "right-hand side C, z in": right_hand_side,
        f"stopping test of {k - 1} iterations, one batch": batch_test,
        f"certificate of {k} iterations' rotations": certificate,
    }
    return iteration, per_step


def main():
    print(
        f"# {platform.node()}, {os.cpu_count()} cores, python {platform.python_version()}, numpy {np.__version__}, "
        f"{time.strftime('%Y-%m-%d')}, OMP_NUM_THREADS={os.environ['OMP_NUM_THREADS']}, numpy path"
    )
    for scene in bench_step.scenes():
        sim = build(scene)
        step_us, iterations, (z, z_dot, a) = run(sim, scene)
        parts = parts_2d if sim.dim == 2 else parts_3d
        iteration, per_step = parts(sim, z, z_dot, a)
        print(f"\n{scene['name']}: step {step_us:.1f} us, {iterations:.2f} iterations a step")
        total_iter = 0.0
        for name, func in iteration.items():
            t = us(func)
            total_iter += t
            print(f"  per iteration  {name:42s} {t:7.2f} us")
        total_step = 0.0
        for name, func in per_step.items():
            t = us(func)
            total_step += t
            print(f"  per step       {name:42s} {t:7.2f} us")
        parts_total = total_iter * iterations + total_step
        print(
            f"  parts: {total_iter:.1f} us x {iterations:.2f} iterations + {total_step:.1f} us = {parts_total:.0f} us "
            f"of {step_us:.0f} us ({100 * parts_total / step_us:.0f} %)"
        )


if __name__ == "__main__":
    main()
