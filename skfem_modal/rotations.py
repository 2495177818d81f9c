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

import math

import numpy as np

__all__ = [
    "polar_rotations",
    "rotations2_flat",
    "rotations3_flat",
    "closest_rotations3",
    "dominant_quaternions",
    "certify_squarings",
    "certify_levels",
    "next_squarings",
    "HORN",
    "QUAT_TO_R",
    "ROT2",
]

_SQUARINGS = 8
# from a good guess (the previous iteration's rotation) fewer are enough
_WARM_SQUARINGS = 5
_EYE4 = np.eye(4)
_SHIFT = np.eye(4) / (np.sqrt(2.0) * 2.45)

# N(F) as a linear map of row-major F (9 values) to row-major N (16 values)
HORN = np.zeros((9, 16))
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
        HORN[_f, 4 * _i + _j] = _s
        HORN[_f, 4 * _j + _i] = _s

# R(q) (row-major, 9 values) as a linear map of the outer product q q^T (16 values)
QUAT_TO_R = np.zeros((16, 9))
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
        QUAT_TO_R[4 * _a + _b, _k] += _s

ROT2 = np.array([[1.0, 0.0, 0.0, 1.0], [0.0, -1.0, 1.0, 0.0]])  # (c, s) -> [c, -s, s, c]
CS2 = np.array([[1.0, 0.0], [0.0, -1.0], [0.0, 1.0], [1.0, 0.0]])  # F -> (F00 + F11, F10 - F01)


def rotations2_flat(F4: np.ndarray) -> np.ndarray:
    """2D closest rotations of row-major matrices, shape (n, 4) -> (n, 4).

    ``F4``: ndarray of float, shape (n, 4), each row a 2 x 2 matrix ``[F00, F01, F10, F11]`` (not changed).
    Where every rotation is a maximiser (``F00 + F11 = F10 - F01 = 0``: the zero matrix, among others) the
    identity.
    """
    cs = F4 @ CS2
    norm = np.hypot(cs[:, 0], cs[:, 1])
    zero = norm == 0.0
    if np.count_nonzero(zero):
        # the zero matrix has every rotation as a maximiser; take the identity
        cs[zero, 0] = 1.0
        norm[zero] = 1.0
    cs /= norm[:, None]
    return cs @ ROT2


def dominant_quaternions(N: np.ndarray, q0: np.ndarray | None = None) -> np.ndarray:
    """Unit eigenvectors of the largest eigenvalue of symmetric 4x4 Horn matrices.

    Parameters
    ----------
    N : ndarray, shape (n, 4, 4)
        Horn matrices ``N(F)`` (symmetric, zero trace).
    q0 : ndarray, shape (n, 4), optional
        A guess (e.g. the previous solution): then fewer squarings are needed.

    Returns
    -------
    q : ndarray, shape (n, 4)
        The rotation's quaternion (its sign is arbitrary).
    """
    n = N.shape[0]
    N16 = N.reshape(n, 16)
    # |N|_F = 2 |F|_F. Scale by it (so powers neither overflow nor underflow)
    # and shift by |F|/sqrt(2): then the top eigenvalue dominates all others in
    # magnitude, by at least ~1.25, and lies in [0.5, 1]. The tiny term keeps
    # F = 0 (every rotation optimal) finite.
    size = 1.225 * np.sqrt(np.einsum("ij,ij->i", N16, N16))
    P = N * (1.0 / (size + 1e-300))[:, None, None]
    P += _SHIFT
    for _ in range(_WARM_SQUARINGS if q0 is not None else _SQUARINGS):
        P = P @ P
    if q0 is not None:
        q = np.einsum("nij,nj->ni", P, q0)
    else:
        # P is now close to s q q^T: its column with the largest diagonal is along q
        col = np.argmax(P.reshape(n, 16)[:, ::5], axis=1)
        q = P[np.arange(n), :, col]
    q *= (1.0 / (np.sqrt(np.einsum("ij,ij->i", q, q)) + 1e-300))[:, None]
    # converged when q is an eigenvector of N, |N q - (q.N q) q| ~ 0, of the
    # top eigenvalue: one above |N| / 2 can only be the top one (a vector
    # exactly along another eigenvector, which the powers cannot leave, has
    # a lower one and goes to eigh)
    Nq = np.einsum("nij,nj->ni", N, q)
    rayleigh = np.einsum("ij,ij->i", q, Nq)
    Nq -= rayleigh[:, None] * q
    bad = np.einsum("ij,ij->i", Nq, Nq) > (1e-12 * size) ** 2
    bad |= ~(rayleigh > size / 2.45 * (1.0 + 1e-12))
    bad &= (size > 0.0) & (size < np.inf)  # F = 0: any rotation; non-finite: the caller reports it
    if bad.any():
        _, vectors = np.linalg.eigh(N[bad])
        q[bad] = vectors[:, :, -1]
    return q


def closest_rotations3(F9: np.ndarray, q0: np.ndarray | None = None):
    """3D closest rotations of row-major matrices, with their quaternions.

    Parameters
    ----------
    F9 : ndarray, shape (n, 9)
    q0 : ndarray, shape (n, 4), optional
        Quaternions of nearby rotations (e.g. the last iteration's): a warm
        start, fewer squarings.

    Returns
    -------
    R9 : ndarray, shape (n, 9)
    q : ndarray, shape (n, 4)
    """
    # the rotation does not change with a positive scale: bring entries to
    # [-1, 1] so that no square can overflow or underflow
    big = np.abs(F9).max(axis=1)
    big[big == 0.0] = 1.0
    q = dominant_quaternions(((F9 / big[:, None]) @ HORN).reshape(-1, 4, 4), q0)
    return (q[:, :, None] * q[:, None, :]).reshape(-1, 16) @ QUAT_TO_R, q


def rotations3_flat(F9: np.ndarray) -> np.ndarray:
    """3D closest rotations of row-major matrices, shape (n, 9) -> (n, 9).

    ``F9``: ndarray of float, shape (n, 9), each row a 3 x 3 matrix (:func:`closest_rotations3` without its
    quaternions).
    """
    return closest_rotations3(F9)[0]


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


def certify_squarings(traces: np.ndarray, shift, tol: float = 1e-13):
    """Check rotations read off repeated squares of shifted Horn matrices, from traces.

    ``P = N + s I`` with ``N`` symmetric and traceless (a Horn matrix), and
    ``t_j = tr(P^(2^j))``, ``j = 1..k``. For ``j >= 1`` the power is positive
    semi-definite with eigenvalues ``mu_i = |lambda_i|^(2^j)``, and
    ``rho_j = 1 - t_(j+1) / t_j^2 = 2 sum_(i<l) mu_i mu_l / (sum mu)^2``
    (``t_(j+1)`` is ``|P^(2^j)|_F^2``) measures how far it is from rank one:
    the weight of the other eigenvalues next to the largest,
    ``eps_j = sum_(i>1) mu_i / mu_1``, is at most ``rho_j (1 + eps_j)^2 / 2``
    and close to ``rho_j / 2``; one more squaring squares it at least
    (``eps_(j+1) <= eps_j^2``). So the rotation read off ``P^(2^k)`` is the
    closest one to ``tol`` when ``rho_(k-1) <= 2 sqrt(tol)`` and the
    dominant eigenvalue is the top one. That holds when ``s > |N|_F / sqrt(12)``
    (for a traceless 4 x 4 matrix ``|lambda_min| - lambda_max <= |N|_F / sqrt(3)``),
    that is ``t_1 = |N|^2 + 4 s^2 < 16 s^2``. Non-finite values fail.

    Parameters
    ----------
    traces : ndarray, shape (k, ...)
        ``t_1 .. t_k`` for any number of matrices, ``k >= 2``.
    shift : float or ndarray, shape (...)
        Each matrix's ``s``.
    tol : float

    Returns
    -------
    ok : bool
        The weights are within ``tol``.
    top : bool
        The shift proves the dominant eigenvalue is the top one (if not, that
        is for the caller to check, e.g. ``tr(P P^(2^k)) > 0``).
    rho : list of float, length k - 1
        The largest ``rho_j`` over the matrices, ``j = 1..k-1``.

    Examples
    --------
    >>> N = np.diag([3.0, -0.8, -1.0, -1.2])  # traceless; |N| / sqrt(12) = 1.003
    >>> P = N + 1.1 * np.eye(4)
    >>> t = np.array([np.trace(np.linalg.matrix_power(P, 2**j)) for j in (1, 2, 3, 4)])
    >>> ok, top, rho = certify_squarings(t, 1.1)  # four squarings
    >>> bool(ok), bool(top), bool(rho[0] > rho[1] > rho[2] > 0)
    (True, True, True)
    >>> certify_squarings(t[:2], 1.1)[0]  # two are not enough
    False
    """
    traces = np.asarray(traces, dtype=np.float64)
    levels = np.empty((traces.shape[0] + 1,) + traces.shape[1:])
    levels[0] = 4.0 * np.asarray(shift)
    levels[1:] = traces
    return certify_levels(levels, tol)


def certify_levels(levels: np.ndarray, tol: float = 1e-13, top_bound: float = 1.0):
    """:func:`certify_squarings` on ``[4 s, t_1, ..., t_k]`` stacked, shape (k + 1, ...).

    The ratios ``levels[j + 1] / levels[j]^2`` are ``t_1 / 16 s^2`` (below 1
    when the shift proves the top eigenvalue dominant) and ``1 - rho_j``: one
    division for both checks. For callers that keep the stack in a buffer;
    ``levels[0]`` may hold ``4 s / sqrt(top_bound)`` instead (the shift's
    proof is then ``t_1 / levels[0]^2 < top_bound``), which saves such a
    caller a multiplication.

    Parameters
    ----------
    levels : ndarray, shape (k + 1, ...)
        ``4 s`` (or ``4 s / sqrt(top_bound)``) and the traces ``t_1 .. t_k`` for any number of
        matrices, ``k >= 2``; not changed.
    tol : float
        As :func:`certify_squarings`'s.
    top_bound : float
        The bound ``t_1 / levels[0]^2`` must be below for ``top``.

    Returns
    -------
    ok, top : bool
    rho : list of float, length k - 1
        As :func:`certify_squarings` returns them.
    """
    # no errstate here (it costs as much as the arithmetic): a zero or
    # non-finite trace gives NaN or inf, which fail the comparisons
    ratios = np.square(levels[:-1])
    np.divide(levels[1:], ratios, out=ratios)
    # level 0's ratio is bounded above, the others below: with level 0's
    # negated, one reduction finds both (and plain floats from there on:
    # numpy scalars cost more than the arithmetic)
    np.negative(ratios[:1], out=ratios[:1])
    lowest = ratios.min(axis=tuple(range(1, ratios.ndim))).tolist()
    rho = [1.0 - x for x in lowest[1:]]
    ok = rho[-1] <= 2.0 * math.sqrt(tol)
    top = -lowest[0] < top_bound
    return ok, top, rho


def next_squarings(rho: np.ndarray, least: int = 2, most: int = 8, growth: float = 1.1, tol: float = 1e-13) -> int:
    """Squarings for the next, similar, matrices from this step's ``rho_j``, ``j = 1..k-1``.

    ``rho_j`` (:func:`certify_squarings`) scales like the ``2^j``-th power of
    the dominance ratio; ``growth`` allows that ratio to grow so much before
    the next step. One squaring fewer (``k - 1``) when ``rho_(k-2)`` would
    still pass, one more when ``rho_(k-1)`` is close to failing.

    Parameters
    ----------
    rho : ndarray, shape (k - 1,)
        This step's ``rho_j`` (the largest over the matrices), ``k`` its squarings.
    least, most : int
        The range of squarings.
    growth : float
    tol : float
        The certificate's tolerance.

    Returns
    -------
    int

    >>> next_squarings(np.array([1e-2, 1e-4, 6e-7])), next_squarings(np.array([1e-4, 1e-8, 1e-16]))
    (5, 3)
    >>> next_squarings(np.array([1e-3, 1e-6, 1e-12]))
    4
    """
    k = len(rho) + 1
    bound = 2.0 * math.sqrt(tol)
    if not rho[-1] <= bound / growth ** (2 ** (k - 1)):
        return min(k + 1, most)
    if k > least and rho[-2] <= bound / growth ** (2 ** (k - 2)):
        return k - 1
    return k
