"""The numba backends: iterations compiled (the ``fast`` extra).

Without contact, all the iterations a call asks for run in one compiled call
(:func:`skfem_modal._kernels.run2` / ``run3``); with contact, one iteration
a call, the projection in between. In 2D the buffers are those of the numpy
backend (:class:`~skfem_modal._step2.Step2Backend`), with the pairs
normalised by a compiled kernel. In 3D every rotation is certified as it is
made (a Rayleigh quotient iteration from the last rotation); one that is not
is made by numpy (:func:`~skfem_modal.rotations.closest_rotations3`).
The kernels are imported (and compiled, or loaded from numba's cache) at the
first step.
"""

from __future__ import annotations

import numpy as np

from . import _accel
from ._step2 import Step2Backend
from .rotations import closest_rotations3
from .solver import ActivationRows

__all__ = ["compiled_backend", "Compiled2Backend", "Compiled3Backend"]


def compiled_backend(model, max_iter):
    """The compiled backend of a model in a subspace, 2D or 3D."""
    if not _accel.AVAILABLE:
        raise ValueError("backend='numba' needs numba: pip install 'skfem_modal[fast]'")
    return (Compiled2Backend if model.space.dim == 2 else Compiled3Backend)(model, max_iter)


class Compiled2Backend(Step2Backend):
    """The 2D iterations compiled: one call for a batch without contact."""

    name = "numba"

    def __init__(self, model, max_iter):
        super().__init__(model, max_iter)
        self.kernels = None

    def start(self, z, z_dot, a) -> None:
        if self.kernels is None:
            self.kernels = _accel.kernels()
            self.normalize = self.kernels.normalize_cs
        super().start(z, z_dot, a)

    def iterate(self, count, contact):
        if contact is not None:
            return super().iterate(count, contact)
        first = self.k
        self.kernels.run2(self.G, self.W_c, self.Y, first, count)
        self.k = first + count
        return self.Z[first : self.k + 1]


class Compiled3Backend:
    """The 3D iterations compiled, every rotation certified as it is made."""

    name = "numba"
    exact = True

    def __init__(self, model, max_iter):
        muscles = model.A is not None
        r = model.space.r
        # with the corotated damping an iterate is [z, 1], and G's column of the 1 holds the offset
        self.start_terms = model.start_terms if model.corotated is not None else None
        one = int(self.start_terms is not None)
        G = np.vstack([model.G] + ([model.A[0]] if muscles else []))
        W = np.hstack([model.W] + ([model.WA[0]] if muscles else []))
        self.G, self.W = np.zeros((G.shape[0], r + one)), np.zeros((r + one, W.shape[1]))
        self.G[:, :r], self.W[:r] = G, W
        self.passive_offset = self.G[: model.G.shape[0], r] if one else None
        self.activation = None
        if muscles and model.n_muscles:
            rows = model.G.shape[0]
            self.activation = ActivationRows([(model.A, self.G[rows:, :r]), (model.WA, self.W[:r, rows:])])
        self.C = np.ascontiguousarray(model.C)
        self.r = r
        self.input = np.ones(2 * r + 1)
        self.c = np.ones(r + one)
        self.max_batch = max_iter
        self.Y = np.ones((max_iter + 1, r + one))
        self.Z = self.Y[:, :r]
        self.q = np.zeros((self.G.shape[0] // 9, 4))  # the last rotations: warm starts
        self.warm = False
        self.kernels = None
        self.k = 0

    def start(self, z, z_dot, a) -> None:
        if self.kernels is None:
            self.kernels = _accel.kernels()
        if self.activation is not None:
            self.activation.write(a)
        r = self.r
        self.input[:r], self.input[r : 2 * r] = z, z_dot
        self.c[:r] = self.C @ self.input
        if self.start_terms is not None:
            offset, shift = self.start_terms(z)
            self.passive_offset[:] = offset
            self.c[:r] += shift
        self.Z[0] = z
        self.k = 0

    def start_row(self):
        return self.Y[0]

    def restart(self, z) -> None:
        np.copyto(self.Z[self.k], z)

    def _run(self, first, count) -> None:
        """Iterations ``first + 1 .. first + count``; any a kernel cannot certify made by numpy."""
        done = 0
        while done < count:
            done += self.kernels.run3(self.G, self.W, self.c, self.Y, first + done, count - done, self.q, self.warm)
            self.warm = self.warm or done > 0
            if done < count:
                it = first + done + 1
                R, self.q = closest_rotations3((self.G @ self.Y[it - 1]).reshape(-1, 9), self.q if self.warm else None)
                self.Y[it] = self.c + self.W @ R.ravel()
                self.warm = True
                done += 1

    def iterate(self, count, contact):
        first = self.k
        if contact is None:
            self._run(first, count)
        else:
            for it in range(first + 1, first + count + 1):
                self._run(it - 1, 1)
                contact.project(self.Z[it])
        self.k = first + count
        return self.Y[first : self.k + 1]

    def finish(self, k) -> bool:
        return True

    def result(self, k):
        return self.Z[k].copy()

    def carried(self) -> dict:
        """The last rotations, the next step's warm starts."""
        return {"q": self.q.copy(), "warm": self.warm}

    def carry(self, state: dict) -> None:
        """Take :meth:`carried`'s, if it is for as many rotations."""
        if state.get("q") is not None and state["q"].shape == self.q.shape:
            self.q[:], self.warm = state["q"], state["warm"]
