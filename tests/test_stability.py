"""Hard cases stay numerically stable (the cases are in hard_cases.py)."""

import hard_cases as H
import numpy as np
import pytest

from skfem_modal.contact import ALLOWANCE

# stated tolerances, relative to the body's size (2 units here): the reference contact's at its
# points, the Coulomb contact's at every boundary vertex
PENETRATION_TOL = 1e-6
COM_DRIFT_TOL = 1e-8
ENERGY_GROWTH_TOL = 1e-9

FAST = [name for name in H.CASES if name != "10,000 steps"]


def check(out, penetration_tol=PENETRATION_TOL):
    assert out["finite"]
    assert out["identical_rerun"], "a second run must give identical results"
    if "energy_growth" in out:
        assert out["energy_growth"] <= ENERGY_GROWTH_TOL
    if "com_drift" in out:
        assert out["com_drift"] <= COM_DRIFT_TOL
    if "penetration_after_contact" in out:
        assert out["penetration_after_contact"] <= penetration_tol


@pytest.mark.parametrize("name", FAST)
def test_hard_case(name):
    out = H.case(name)
    penetration_tol = ALLOWANCE if "Coulomb" in name else PENETRATION_TOL
    check(out, penetration_tol)
    if name.startswith("slivers"):
        assert out["max_aspect_ratio"] >= 100
    if name.startswith("elements inverted"):
        assert out["inverted_at_start"] > 0 and out["inverted_at_end"] == 0
    if name.startswith("drop") or name.startswith("material"):
        assert out["worst_penetration"] <= penetration_tol  # the position contact never lets a point in


@pytest.mark.slow
def test_ten_thousand_steps():
    check(H.case("10,000 steps"))


@pytest.mark.parametrize("scale", [1e-3, 1e3])
def test_same_motion_at_every_scale(scale):
    base = H.scaled_motion(1.0)
    scaled = H.scaled_motion(scale)
    assert np.abs(scaled - base).max() <= 1e-9 * np.abs(base).max()


def test_real_blow_up_is_reported_with_its_step():
    from skfem_modal.sim import SimulationError

    sim = H.build(H.small_caterpillar())
    z, z_dot, a = sim.rest_state()
    with pytest.raises(SimulationError, match="non-finite"):
        for _ in range(5):
            z_next = sim.step(z, z_dot, np.full(sim.n_muscles, 1e300))
            z_dot, z = (z_next - z) / sim.h, z_next
