"""The precompute limits BLAS threads while its two threads run, and restores them after."""

import sys

import pytest
from ci import unavailable

from skfem_modal.mesh import beam2d
from skfem_modal.sim import ModalMuscle
from skfem_modal.threads import limited_blas_threads, openblas_threads

threadpoolctl = pytest.importorskip("threadpoolctl", reason="threadpoolctl is in the fast extra")


@pytest.fixture()
def two_blas_threads():
    """Every BLAS library at 2 threads (whatever the environment says), as on a 2-core machine by default."""
    with threadpoolctl.threadpool_limits(limits=2, user_api="blas"):
        if not openblas_threads() or set(openblas_threads()) != {2}:
            unavailable(f"cannot give OpenBLAS 2 threads here: {openblas_threads()}")
        yield


@pytest.mark.parametrize("way", ["threadpoolctl", "fallback"])
def test_the_limit_holds_inside_and_is_undone_after(two_blas_threads, monkeypatch, way):
    if way == "fallback":
        monkeypatch.setitem(sys.modules, "threadpoolctl", None)  # as without the package
    with limited_blas_threads(1):
        assert set(openblas_threads()) == {1}
    assert set(openblas_threads()) == {2}
    with limited_blas_threads(None):
        assert set(openblas_threads()) == {2}


@pytest.mark.parametrize("limit, inside", [(1, {1}), (None, {2})])
def test_every_precompute_stage_runs_with_the_limit(two_blas_threads, limit, inside):
    seen = {}

    def stage(name):
        seen[name] = set(openblas_threads())

    ModalMuscle.from_mesh(
        beam2d(2.0, 0.5, 8, 2), n_muscles=1, n_weights=3, n_clusters=4, progress=stage, blas_threads=limit
    )
    assert len(seen) >= 4 and all(v == inside for v in seen.values()), seen
    assert set(openblas_threads()) == {2}
