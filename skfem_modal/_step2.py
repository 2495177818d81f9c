"""The 2D numpy step: local/global iterations on preallocated buffers.

In 2D a cluster's rotation is its feature pair ``(c, s) = (F00 + F11,
F10 - F01)`` scaled to unit length, and both maps are folded into the
operators: ``G`` takes ``z`` to every cluster's ``(c, s)``, ``W`` takes the
unit pairs back to ``z`` (followed by the contact points' positions when the
scene has a ground). An iteration is then five numpy calls on buffers made
once: ``G z``, the pairs' lengths, a check for zero length, the division
(or one compiled call for these three, with the accelerator), and
``[W | c] [(c, s); 1]``, the step's constant ``c`` riding along as one
more column of ``W`` (written once a step, from ``z`` and ``z_dot`` by one
product). The stopping rule is applied as in
:meth:`skfem_modal.sim.ModalMuscle._loop`: the iterations the last step
took run unchecked and are then tested in one batch on the stored iterates,
which gives the answer of testing each in turn.
"""

from __future__ import annotations

import numpy as np

from ._fast import dot, squared_changes

__all__ = ["NumpyStep2"]


class NumpyStep2:
    """Buffers of the 2D numpy step.

    Parameters
    ----------
    G : ndarray, shape (2 n, r)
        Rotation features of the ``n`` clusters from ``z``. Kept by
        reference: the simulator writes the muscle rows into it.
    W : ndarray, shape (q, 2 n)
        ``z`` (``q = r``), or ``z`` and the contact positions (``q = r + p
        dim``), from the unit pairs. Copied into :attr:`W`, which the
        simulator must write the muscle columns into from then on.
    C_operator : ndarray, shape (q, 2 r + 1)
        The step's constant: ``c = C_operator @ [z, z_dot, 1]``.
    max_iter : int
    """

    def __init__(self, G, W, C_operator, max_iter):
        q, two_n = W.shape
        r = G.shape[1]
        if C_operator.shape != (q, 2 * r + 1) or G.shape[0] != two_n:
            raise ValueError(f"NumpyStep2: G {G.shape}, W {W.shape} and C {C_operator.shape} do not fit together")
        self.G, self.r, self.n, self.max_iter = G, r, two_n // 2, max_iter
        self.W_c = np.empty((q, two_n + 1))
        self.W_c[:, :two_n] = W
        self.W = self.W_c[:, :two_n]
        self.c = self.W_c[:, two_n]
        self.C_operator = np.ascontiguousarray(C_operator)
        self.C_input = np.ones(2 * r + 1)
        self.C_z, self.C_z_dot = self.C_input[:r], self.C_input[r : 2 * r]
        self.cs_1 = np.ones(two_n + 1)  # the unit pairs, then a 1 for c
        self.cs_flat = self.cs_1[:two_n]
        self.cs = self.cs_flat.reshape(-1, 2)
        self.cos, self.sin = self.cs[:, 0], self.cs[:, 1]
        self.norm = np.empty(self.n)
        self.norm_column = self.norm[:, None]
        self.Y = np.empty((max_iter + 1, q))  # iterates: z, then the contact positions
        self.Z = self.Y[:, :r]
        self.z_rows = list(self.Z)
        self.steps = np.empty((max_iter, r))
        self.change2 = np.empty(max_iter)
        self.ones = np.ones(r)
        self.diff = np.empty(r)

    def step(self, z, z_dot, contact, tol2, unchecked, stop_rule, normalize=None):
        """One step from ``(z, z_dot)``; the muscle rows and columns are set.

        Parameters
        ----------
        z, z_dot : ndarray, shape (r,)
        contact : GroundContact or None
            Its ``start_step`` is called here.
        tol2 : float
            Stop when ``|z_k - z_(k-1)|^2 < tol2``.
        unchecked : int
            Iterations to run before the stopping rule is applied to all of
            them at once (0: test each as it is made).
        stop_rule : callable
            ``stop_rule(change2, z_k, z)`` for the iterations tested one by
            one when the absolute rule did not stop them: True to stop; it
            raises on a non-finite state.
        normalize : callable, optional
            Scales the rows of an (n, 2) array to unit length in place, (0, 0)
            to (1, 0): a compiled kernel; numpy calls when None.

        Returns
        -------
        (z_next, iterations), or None when the state became non-finite
        within the unchecked iterations.
        """
        np.copyto(self.C_z, z)
        np.copyto(self.C_z_dot, z_dot)
        np.matmul(self.C_operator, self.C_input, self.c)  # a strided column: matmul
        z_rows, Y = self.z_rows, self.Y
        np.copyto(z_rows[0], z)
        if contact is not None:
            contact.start_step(z)
        G, W_c, cs_1, cs_flat, cs = self.G, self.W_c, self.cs_1, self.cs_flat, self.cs
        cos, sin, norm, norm_column, n = self.cos, self.sin, self.norm, self.norm_column, self.n
        hypot, divide, count_nonzero = np.hypot, np.divide, np.count_nonzero
        z_iter = z
        for it in range(1, self.max_iter + 1):
            dot(G, z_iter, cs_flat)
            if normalize is not None:
                normalize(cs)
            else:
                hypot(cos, sin, norm)
                if count_nonzero(norm) < n:
                    # a zero target: every rotation is optimal, take the identity
                    zero = norm == 0.0
                    cs[zero] = (1.0, 0.0)
                    norm[zero] = 1.0
                divide(cs, norm_column, cs)
            y = Y[it]
            dot(W_c, cs_1, y)
            if contact is not None:
                contact.correct(y, in_place=True)
            z_next = z_rows[it]
            if it <= unchecked:
                z_iter = z_next
                if it == unchecked:
                    change2 = squared_changes(self.Z, it, self.steps, self.ones, self.change2)
                    stopped = ~(change2 >= tol2)  # converged, or not finite
                    if count_nonzero(stopped):
                        k = int(stopped.argmax())
                        if not change2[k] < tol2:
                            return None
                        return z_rows[k + 1].copy(), k + 1
                continue
            np.subtract(z_next, z_iter, self.diff)
            change2 = float(dot(self.diff, self.diff))
            z_iter = z_next
            if change2 < tol2 or stop_rule(change2, z_next, z):
                break
        return z_iter.copy(), it
