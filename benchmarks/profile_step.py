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

from skfem_modal._fast import dot, squared_changes  # noqa: E402
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
    """The 2D numpy step (see skfem_modal/_step2.py), on its own buffers."""
    st = sim._step2
    sim.step(z, z_dot, a)  # the buffers hold this step
    k = sim.iterations
    contact = sim._contact

    def right_hand_side():
        np.copyto(st.C_z, z)
        np.copyto(st.C_z_dot, z_dot)
        np.matmul(st.C_operator, st.C_input, st.c)
        np.copyto(st.z_rows[0], z)

    def normalise():
        np.hypot(st.cos, st.sin, st.norm)
        zero = np.count_nonzero(st.norm) < st.n
        np.divide(st.cs, st.norm_column, st.cs)
        return zero

    def batch_test():
        change2 = squared_changes(st.Z, k, st.steps, st.ones, st.change2)
        return np.count_nonzero(~(change2 >= sim._tol2))

    y = st.Y[k].copy()
    iteration = {
        "G z (rotation features)": lambda: dot(st.G, st.z_rows[k - 1], st.cs_flat),
        "normalise (c, s): hypot, check, divide": normalise,
        "[W | c] [(c, s); 1]": lambda: dot(st.W_c, st.cs_1, y),
    }
    if contact is not None:
        contact.start_step(z)
        iteration["contact projection"] = lambda: contact.correct(y)
    per_step = {
        "activation: operator rows": lambda: sim._set_activation(a),
        "right-hand side c, z in": right_hand_side,
        f"stopping test of {k} iterations, one batch": batch_test,
    }
    if contact is not None:
        per_step["contact: start of step"] = lambda: contact.start_step(z)
    return iteration, per_step


def parts_3d(sim, z, z_dot, a):
    """The Kronecker-form step (skinning bases; see skfem_modal/_kron3.py)."""
    kr = sim._kron
    sim.step(z, z_dot, a)  # the buffers hold this step
    n, s, k = kr.n, kr.squarings, sim.iterations
    Z_old, Z_new, P0, P_last, R, R16, squarings = kr._views[s][0]

    def power():
        for P, P_squared in squarings:
            np.matmul(P, P, P_squared)

    def activation():
        dot(a, kr.A_all, kr.A_product)
        np.add(kr.A_rows, kr.A0, kr.Yt_active)
        np.add(kr.A_columns, kr.WA0, kr.Wt_active)

    def right_hand_side():
        np.copyto(kr.C_z, z)
        np.copyto(kr.C_z_dot, z_dot)
        np.matmul(kr.C_operator, kr.C_input, kr.C_slot)
        np.copyto(kr.Z0, kr.C_z_block)

    def batch_test():
        change2 = squared_changes(kr.Z_rows, k, kr.steps, kr.ones, kr.change2)
        hits = change2 < sim._tol2
        return hits[int(hits.argmax())]

    def certificate():
        powers, traces = kr._trace_rows[s]
        dot(powers, EYE16, traces)
        rho = certify_levels(kr.levels[: s + 1, :k], top_bound=1.05**2)[2]
        next_squarings(rho)

    iteration = {
        "Y Z: the clusters' F (Kronecker form)": lambda: dot(kr.Yt, Z_old, kr.F),
        "Horn matrices and shifts": lambda: dot(kr.F16, HORN_BLOCK, P0),
        f"{s} squarings of {n} 4x4 matrices": power,
        "R and traces from the last power": lambda: dot(P_last, QQ_TO_BLOCK_TRACE, kr.RT),
        "divide by the traces": lambda: np.divide(kr.RT16, kr.trace, R16),
        "V R^T + C (the global step)": lambda: dot(kr.Wt, R, Z_new),
    }
    per_step = {
        "activation: operator rows and columns": activation,
        "right-hand side C, z in": right_hand_side,
        f"stopping test of {k} iterations, one batch": batch_test,
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
