"""Shared fixtures: the tutorial's caterpillar and the reference numbers."""

import signal

import numpy as np
import pytest

from skfem_modal import caterpillar

# ../shared/reference/README.md: numbers SimKit 0.1.8 produces on the tutorial's scene
REFERENCE = {
    "vertices": 1719,
    "triangles": 3058,
    "area": 1.3429951690821,
    "eigenvalues_3_6": np.array([0.124939824, 0.304251026, 0.374627004, 0.853441268]),
    "skinning_eigenvalues": np.array(
        [0.0, 1.12203495, 2.88155382, 3.64628783, 7.7777972, 8.9861157, 13.812334, 23.088929]
    ),
    "ceilings_3_6": np.array([0.4804847, 0.3935627, 0.2975196, 0.2482976]),
    # x-displacement of vertex 0 in the tutorial's modes 3-6
    "mode_signs_3_6": np.array([1.0, -1.0, -1.0, 1.0]),
    "crawl_com_dx": -4.438,
    "crawl_com_y_range": (-0.130, 0.244),
}


@pytest.fixture(scope="session", autouse=True)
def ctrl_c_as_in_a_terminal():
    """Ctrl-C raises KeyboardInterrupt here and in the processes the tests start.

    A suite started in the background by a shell without job control (``pytest &``
    in a script) inherits SIGINT ignored, and so would every search a test
    interrupts: the Ctrl-C tests would wait for runs that never hear it.
    """
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    yield


@pytest.fixture(scope="session")
def reference():
    return REFERENCE


@pytest.fixture(scope="session")
def cat_mesh():
    return caterpillar()


#: A small caterpillar crawling on the ground with Coulomb friction, two muscles (150 steps).
COULOMB_CRAWL = {
    "mesh": {"shape": "caterpillar", "params": {"nx": 28, "ny": 14}},
    "material": {"mu": 1e6, "gamma": 1e6, "rho": 1e3},
    "subspace": {"weights": 4, "clusters": 8},
    "muscles": {"count": 2},
    "time": {"step": 0.01, "steps": 150},
    "gravity": {"acceleration": [0.0, -9.8]},
    "ground": {"offset": 0.1, "friction": 0.5},
}


def die():
    """A task that kills the worker process running it (SIGKILL, as the out-of-memory killer does)."""
    import os
    import signal

    os.kill(os.getpid(), signal.SIGKILL)


@pytest.fixture
def killing_pools():
    """``kill(make_executor, after)``: a ``make_executor`` whose local pools lose a worker, SIGKILLed while it runs
    a task (:func:`die`), when their task number ``after`` (from 0) is submitted; the pools are closed after the test.

    The task waits until the pool has seen the worker die: a death the pool has not yet seen races the tasks
    after it (measured: the tasks of a 2-worker pool went on in the other worker).
    """
    import itertools

    made = []

    def kill(make_executor, after: int):
        def make(*args, **kwargs):
            pool, close = make_executor(*args, **kwargs)
            submit, count = pool.submit, itertools.count()

            def submitted(fn, *a, **k):
                if next(count) == after:
                    submit(die).exception(timeout=60)  # once the pool has seen it die
                return submit(fn, *a, **k)

            pool.submit = submitted
            made.append(close)
            return pool, close

        return make

    yield kill
    for close in made:
        close()
