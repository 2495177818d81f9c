"""Batched closest proper rotations (the rotation factor of the polar decomposition).

For each matrix ``F`` the rotation ``R`` in SO(dim) maximising ``tr(R^T F)``:
the ``U diag(1, ..., det(U V^T)) V^T`` of an SVD ``F = U S V^T``. It is a proper
rotation (det = +1) for every input, inverted (det F < 0), rank-deficient and
zero matrices included, and never NaN for finite input.

Per-call cost matters more than flops here (the simulator calls this on a
couple of dozen tiny matrices, ten times a step), so both paths use a handful
of whole-batch numpy operations and no per-matrix LAPACK calls:

* 2D: closed form, ``R = [[c, -s], [s, c]]`` with ``(c, s)`` the normalised
  ``(F00 + F11, F10 - F01)``.
* 3D: Horn's quaternion form: ``tr(R(q)^T F) = q^T N(F) q`` for unit
  quaternions ``q``, with ``N`` a symmetric 4x4 matrix linear in ``F``, so the
  rotation is the dominant eigenvector of ``N``. Its eigenvalues are the signed
  sums of the singular values (``s1 + s2 + s3`` on top when det F > 0); after
  a shift by ``|F|/sqrt(2)`` the top one dominates all others in magnitude by
  a factor of at least about 1.25, and eight squarings (a 256th power) leave
  the others at ``0.8**256 ~ 1e-25``. Matrices where that is not enough (a
  nearly degenerate rotation: its residual as an eigenvector is checked) are
  finished with LAPACK's ``eigh``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["polar_rotations", "rotations2_flat", "rotations3_flat"]

_SQUARINGS = 8
_EYE4 = np.eye(4)

# N(F) as a linear map of row-major F (9 values) to row-major N (16 values)
_HORN = np.zeros((9, 16))
for (_i, _j), _terms in {
    (0, 0): [(0, 1), (4, 1), (8, 1)],
    (0, 1): [(7, 1), (5, -1)],
    (0, 2): [(2, 1), (6, -1)],
    (0, 3): [(3, 1), (1, -1)],
    (1, 1): [(0, 1), (4, -1), (8, -1)],
    (1, 2): [(1, 1), (3, 1)],
    (1, 3): [(2, 1), (6, 1)],
    (2, 2): [(0, -1), (4, 1), (8, -1)],
    (2, 3): [(5, 1), (7, 1)],
    (3, 3): [(0, -1), (4, -1), (8, 1)],
}.items():
    for _f, _s in _terms:
        _HORN[_f, 4 * _i + _j] = _s
        _HORN[_f, 4 * _j + _i] = _s

# R(q) (row-major, 9 values) as a linear map of the outer product q q^T (16 values)
_QUAT_TO_R = np.zeros((16, 9))
for _k, _terms in enumerate(
    [
        [(0, 0, 1), (1, 1, 1), (2, 2, -1), (3, 3, -1)],  # R00 = a2 + b2 - c2 - d2
        [(1, 2, 2), (0, 3, -2)],  # R01 = 2(bc - ad)
        [(1, 3, 2), (0, 2, 2)],  # R02 = 2(bd + ac)
        [(1, 2, 2), (0, 3, 2)],  # R10 = 2(bc + ad)
        [(0, 0, 1), (1, 1, -1), (2, 2, 1), (3, 3, -1)],  # R11
        [(2, 3, 2), (0, 1, -2)],  # R12 = 2(cd - ab)
        [(1, 3, 2), (0, 2, -2)],  # R20 = 2(bd - ac)
        [(2, 3, 2), (0, 1, 2)],  # R21 = 2(cd + ab)
        [(0, 0, 1), (1, 1, -1), (2, 2, -1), (3, 3, 1)],  # R22
    ]
):
    for _a, _b, _s in _terms:
        _QUAT_TO_R[4 * _a + _b, _k] += _s

_ROT2 = np.array([[1.0, 0.0, 0.0, 1.0], [0.0, -1.0, 1.0, 0.0]])  # (c, s) -> [c, -s, s, c]
_CS2 = np.array([[1.0, 0.0], [0.0, -1.0], [0.0, 1.0], [1.0, 0.0]])  # F -> (F00 + F11, F10 - F01)


def rotations2_flat(F4: np.ndarray) -> np.ndarray:
    """2D closest rotations of row-major matrices, shape (n, 4) -> (n, 4)."""
    cs = F4 @ _CS2
    norm = np.hypot(cs[:, 0], cs[:, 1])
    zero = norm == 0.0
    if zero.any():
        # the zero matrix has every rotation as a maximiser; take the identity
        cs[zero, 0] = 1.0
        norm[zero] = 1.0
    cs /= norm[:, None]
    return cs @ _ROT2


def _quaternions(F9: np.ndarray) -> np.ndarray:
    """Dominant unit eigenvectors of Horn's N(F), shape (n, 9) -> (n, 4)."""
    n = F9.shape[0]
    # the rotation does not change with a positive scale: bring entries to
    # [-1, 1] so neither squares nor powers can overflow or underflow
    big = np.abs(F9).max(axis=1)
    big[big == 0.0] = 1.0  # F = 0: N = 0 and every quaternion is optimal
    F9 = F9 / big[:, None]
    N = (F9 @ _HORN).reshape(n, 4, 4)
    fro = np.sqrt((F9 * F9).sum(axis=1))
    fro[fro == 0.0] = 1.0
    # Shift by c = |F|/sqrt(2): the unwanted eigenvalues move towards zero and
    # all stay below the top one in magnitude (c exceeds the smallest singular
    # value, even for inverted F), by a ratio of at most about 0.8. Then scale
    # the top eigenvalue into [0.5, 1] so powers neither overflow nor underflow.
    P = N + (fro / np.sqrt(2.0))[:, None, None] * _EYE4
    P /= (2.45 * fro)[:, None, None]
    for _ in range(_SQUARINGS):
        P = P @ P
    # P is now close to s q q^T: its column with the largest diagonal is along q
    col = np.argmax(P.reshape(n, 16)[:, ::5], axis=1)
    q = P[np.arange(n), :, col]
    norm = np.sqrt((q * q).sum(axis=1))
    bad = ~(norm > 1e-150)
    q /= np.where(bad, 1.0, norm)[:, None]
    # converged when q is an eigenvector of N: |N q - (q.N q) q| small
    Nq = (N @ q[:, :, None])[:, :, 0]
    residual = Nq - (q * Nq).sum(axis=1)[:, None] * q
    bad |= (residual * residual).sum(axis=1) > (1e-12 * fro) ** 2
    if bad.any():
        _, vectors = np.linalg.eigh(N[bad])
        q[bad] = vectors[:, :, -1]
    return q


def rotations3_flat(F9: np.ndarray) -> np.ndarray:
    """3D closest rotations of row-major matrices, shape (n, 9) -> (n, 9)."""
    q = _quaternions(F9)
    return (q[:, :, None] * q[:, None, :]).reshape(-1, 16) @ _QUAT_TO_R


def polar_rotations(F) -> np.ndarray:
    """Closest proper rotation to each matrix of a batch.

    Parameters
    ----------
    F : array_like, shape (..., dim, dim), dim 2 or 3
        Finite matrices.

    Returns
    -------
    R : ndarray, shape (..., dim, dim)
        ``argmax_{R in SO(dim)} tr(R^T F)``: orthogonal with det +1 for every
        input. Where the maximiser is not unique (zero or some rank-deficient
        matrices) one of the maximisers is returned (the identity for zero).

    Examples
    --------
    >>> R = polar_rotations(np.diag([2.0, -1.0]))  # an inverted matrix
    >>> np.round(R, 12).tolist(), float(np.linalg.det(R))
    ([[1.0, 0.0], [0.0, 1.0]], 1.0)
    >>> th = 0.3
    >>> Q = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])
    >>> bool(np.allclose(polar_rotations(Q @ np.diag([1.0, 2.0, 0.5])), Q))
    True
    """
    F = np.asarray(F, dtype=np.float64)
    if F.ndim < 2 or F.shape[-1] != F.shape[-2] or F.shape[-1] not in (2, 3):
        raise ValueError(f"polar_rotations: expected matrices of shape (..., d, d) with d 2 or 3, got {F.shape}")
    if F.size == 0:
        return F.copy()
    d = F.shape[-1]
    flat = F.reshape(-1, d * d)
    R = rotations2_flat(flat) if d == 2 else rotations3_flat(flat)
    return R.reshape(F.shape)
