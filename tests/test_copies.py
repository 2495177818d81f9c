"""Simulators can be pickled and deep-copied (for process pools and checkpoints), and a copy steps as the original."""

import copy
import pickle

import numpy as np
import skfem

import skfem_modal as sm


def steps(sim, n=4):
    z, z_dot, a = sim.rest_state()
    for _ in range(n):
        z, z_dot = sim.step(z, z_dot, a, velocity=True)
    return z


def test_the_full_space_simulator_pickles_and_deep_copies():
    mesh = skfem.MeshTri.init_tensor(np.linspace(0, 1, 5), np.linspace(0, 1, 5))
    sim = sm.FullSpaceSimulator(mesh, None, mu=1e5, gamma=1e5, rho=1e3, h=0.01, gravity=[0.0, -9.8])
    expected = steps(sim)
    assert np.abs(expected - sim.rest_state()[0]).max() > 1e-4  # it falls: the steps do something
    for clone in (copy.deepcopy(sim), pickle.loads(pickle.dumps(sim))):
        np.testing.assert_allclose(steps(clone), expected, rtol=0, atol=1e-12)
