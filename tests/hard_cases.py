"""Hard scenes for the stability tests and for docs/stability.md.

Each case builds a simulator and an initial state, runs it, and reports what
the tests check: finiteness, the most energy a step gained without input, centre-of-mass
drift when floating, penetration of the contact points after contact
resolves, and whether a second run gives identical results.
``python scripts/stability_report.py`` prints these numbers as a table.
"""

from __future__ import annotations

import numpy as np

import skfem_modal as sm
from skfem_modal.muscles import sine_gait
from skfem_modal.sim import ModalMuscle

GAIT = dict(periods=[1.0, 0.7, 0.9], phases=[0.0, 0.25, 0.6])


def small_caterpillar():
    return sm.caterpillar(nx=24, ny=12)


def sliver_mesh():
    """A 2D block whose middle column of cells is squashed to aspect ratio 200."""
    base = sm.beam2d(2.0, 1.0, 8, 4)
    x = base.p.copy()
    column = np.isclose(x[0], 1.0)
    x[0, column] = 0.75 + 0.25 / 200  # the cells between x = 0.75 and the column are slivers
    return sm.make_mesh(x.T, base.t.T)


def aspect_ratios(mesh) -> np.ndarray:
    """Longest edge over the element's height (2 area / longest edge) in 2D."""
    from skfem_modal.mesh import _longest_edges, _signed_measures

    longest = _longest_edges(mesh.p, mesh.t)
    return longest**2 / (2 * np.abs(_signed_measures(mesh.p, mesh.t)))


def build(mesh, *, mu=1e5, rho=1e3, h=0.01, muscles=3, gravity=False, ground=None, coulomb=False, **kw):
    """A simulator of a hard case: the reference contact at 20 points, pushing out, or the Coulomb one."""
    dim = mesh.p.shape[0]
    g = ([0.0] * (dim - 1) + [-9.8]) if gravity else None
    contact = dict(contact_model="coulomb") if coulomb else dict(n_contacts=20, contact_model="reference", push_out=1.0)
    contact = {} if ground is None else contact  # contact settings without a ground are refused
    reduction = dict(n_muscles=muscles, n_weights=6, n_clusters=10)
    return ModalMuscle.from_mesh(mesh, **reduction, mu=mu, rho=rho, h=h, gravity=g, ground=ground, **contact, **kw)


def run(sim, steps, *, amplitude=0.0, z0=None, z_dot0=None):
    """Step a simulator; amplitude is a fraction of the muscles' ceilings (0: no input)."""
    z, z_dot, _ = sim.rest_state()
    z = z if z0 is None else z0
    z_dot = z_dot if z_dot0 is None else z_dot0
    m = sim.n_muscles
    amps = amplitude * sim.ceilings
    zs, coms, energies, lowest, iterations = [z], [sim.com(z)], [sim.mechanical_energy(z, z_dot)], [], []
    up = sim.up
    for i in range(steps):
        a = sine_gait(i * sim.h, amps, GAIT["periods"][:m], GAIT["phases"][:m]) if amplitude else np.zeros(m)
        z_next = sim.step(z, z_dot, a)
        z_dot, z = (z_next - z) / sim.h, z_next
        zs.append(z)
        coms.append(sim.com(z))
        energies.append(sim.mechanical_energy(z, z_dot))
        iterations.append(sim.iterations)
        if sim.ground is not None:
            lowest.append(float(sim.contact_positions(z)[:, up].min()))
    return dict(
        z=np.array(zs), com=np.array(coms), energy=np.array(energies), lowest=np.array(lowest), iterations=iterations
    )


def velocity(sim, v) -> np.ndarray:
    """Reduced velocity of a uniform velocity vector ``v`` (all vertices)."""
    n = sim.mesh.p.shape[1]
    return sim.coordinates(np.tile(np.asarray(v, float), n))


def outcome(result, *, floating=False, no_input=False, ground=None, size=1.0) -> dict:
    """The numbers the tests check, for one run."""
    out = {"finite": bool(np.all(np.isfinite(result["z"])))}
    if no_input:
        # the most one step gained, of the energy's largest magnitude (a dropped body starts at its
        # highest energy: a gain after landing would not show as the energy rising above the start)
        e = result["energy"]
        scale = max(np.abs(e).max(), 1e-300)
        out["energy_growth"] = float(max(0.0, np.diff(e).max() / scale)) if e.size > 1 else 0.0
    if floating:
        out["com_drift"] = float(np.abs(result["com"] - result["com"][0]).max() / size)
    if ground is not None:
        lowest = result["lowest"]
        touched = np.flatnonzero(lowest - ground < 1e-3 * size)
        after = lowest[touched[0] + 2 :] if touched.size else lowest[:0]
        out["penetration_after_contact"] = float(max(0.0, (ground - after.min()) / size)) if after.size else 0.0
        out["worst_penetration"] = float(max(0.0, (ground - lowest.min()) / size))
    return out


def case(name: str, repeat: int = 2) -> dict:
    """Run one hard case (twice, to compare) and return its outcome."""
    runs = [CASES[name]() for _ in range(repeat)]
    result, checks = runs[0]
    checks = dict(checks)
    checks["identical_rerun"] = all(np.array_equal(r["z"], result["z"]) for r, _ in runs[1:])
    return checks


def _slivers():
    mesh = sliver_mesh()
    sim = build(mesh)
    result = run(sim, 300, amplitude=0.8)
    return result, {**outcome(result, floating=True, size=2.0), "max_aspect_ratio": float(aspect_ratios(mesh).max())}


def _inverted_start():
    mesh = small_caterpillar()
    sim = build(mesh)
    x = mesh.p.T.copy()
    left = x[:, 0] < -0.5
    x[left, 0] = -1.0 - x[left, 0]  # fold the left end over itself: its elements are inverted
    z0 = sim.coordinates(x)
    J = sm.deformation_jacobian(mesh)
    det = lambda z: np.linalg.det((J @ (sim.B @ z)).reshape(-1, 2, 2))  # noqa: E731
    result = run(sim, 400, z0=z0)
    out = outcome(result, floating=True, no_input=True, size=2.0)
    out["inverted_at_start"] = int((det(z0) < 0).sum())
    out["inverted_at_end"] = int((det(result["z"][-1]) < 0).sum())
    return result, out


def _material(factor, coulomb=False):
    def make():
        mesh = small_caterpillar()
        ground = float(mesh.p[1].min()) - 0.3
        sim = build(mesh, mu=1e6 * factor, gravity=True, ground=ground, coulomb=coulomb)
        result = run(sim, 300)
        return result, outcome(result, no_input=True, ground=ground, size=2.0)

    return make


def _large_step(coulomb=False):
    def make():
        mesh = small_caterpillar()
        ground = float(mesh.p[1].min()) - 0.15
        sim = build(mesh, mu=1e6, h=0.1, gravity=True, ground=ground, coulomb=coulomb)
        result = run(sim, 200, amplitude=0.5)
        return result, outcome(result, ground=ground, size=2.0)

    return make


def _strong_activation():
    mesh = small_caterpillar()
    sim = build(mesh)
    result = run(sim, 300, amplitude=3.0)
    return result, outcome(result, floating=True, size=2.0)


def _drop(dim, coulomb=False):
    def make():
        mesh = small_caterpillar() if dim == 2 else sm.creature(cell=0.2)
        up = dim - 1
        ground = float(mesh.p[up].min()) - 2.0
        sim = build(mesh, gravity=True, ground=ground, coulomb=coulomb)
        v = np.zeros(dim)
        v[up] = -10.0
        result = run(sim, 300, z_dot0=velocity(sim, v))
        return result, outcome(result, no_input=True, ground=ground, size=2.0)

    return make


def _long_run():
    mesh = small_caterpillar()
    sim = build(mesh)
    result = run(sim, 10_000, amplitude=0.6)
    return result, outcome(result, floating=True, size=2.0)


CASES = {
    "slivers (aspect ratio 200)": _slivers,
    "elements inverted at the start": _inverted_start,
    "material 1e4 times stiffer": _material(1e4),
    "material 1e3 times softer": _material(1e-3),
    "material 1e4 times stiffer (Coulomb contact)": _material(1e4, coulomb=True),
    "material 1e3 times softer (Coulomb contact)": _material(1e-3, coulomb=True),
    "time step 0.1": _large_step(),
    "time step 0.1 (Coulomb contact)": _large_step(coulomb=True),
    "activations at 3 times the ceiling": _strong_activation,
    "drop at 10 units/s from 2 units up (2D)": _drop(2),
    "drop at 10 units/s from 2 units up (3D)": _drop(3),
    "drop at 10 units/s from 2 units up (2D, Coulomb contact)": _drop(2, coulomb=True),
    "drop at 10 units/s from 2 units up (3D, Coulomb contact)": _drop(3, coulomb=True),
    "10,000 steps": _long_run,
}


def scaled_motion(scale: float, contact_model: str, steps: int = 200):
    """Vertex trajectories of a crawl at a coordinate scale, divided by the scale, and its iterations a step.

    Lengths times ``s`` with density and time unchanged: stiffness (stress)
    times ``s^2`` and gravity times ``s`` give the same motion, scaled. The
    stopping rule is the default's (a fraction of the body's size), so the
    iterations are the same too.
    """
    mesh = small_caterpillar()
    mesh = type(mesh)(mesh.p * scale, mesh.t.copy(), sort_t=False)
    ground = (float(mesh.p[1].min()) / scale - 0.15) * scale
    sim = ModalMuscle.from_mesh(
        mesh,
        n_muscles=3,
        n_weights=6,
        n_clusters=10,
        mu=1e5 * scale**2,
        rho=1e3,
        h=0.01,
        gravity=[0.0, -9.8 * scale],
        ground=ground,
        n_contacts=20,
        contact_model=contact_model,
        **(dict(push_out=1.0) if contact_model == "reference" else {}),
    )
    result = run(sim, steps, amplitude=0.5)
    return np.array([sim.positions(z) for z in result["z"][::20]]) / scale, result["iterations"]
