"""Compiled kernels (numba) for the per-iteration rotations; imported on first use.

See :mod:`skfem_modal._accel`. The methods are those of
:mod:`skfem_modal.rotations` (2D closed form; 3D Horn quaternion, here by
Rayleigh quotient iteration from the previous rotation, with the squaring
method as the fallback), compiled so a step does not pay numpy's per-call
overhead.
"""

import numba
import numpy as np


@numba.njit(cache=True, fastmath=False)
def normalize_cs(cs):  # pragma: no cover - compiled
    """In place: each row (c, s) scaled to unit length; (0, 0) becomes (1, 0)."""
    for k in range(cs.shape[0]):
        c = cs[k, 0]
        s = cs[k, 1]
        n = np.hypot(c, s)
        if n == 0.0:
            cs[k, 0] = 1.0
            cs[k, 1] = 0.0
        else:
            cs[k, 0] = c / n
            cs[k, 1] = s / n
    return cs


@numba.njit(cache=True, fastmath=False)
def _solve4(A, b, x, M):  # pragma: no cover - compiled
    """x = A^{-1} b for a 4x4 A (partial pivoting, M a 4x5 scratch); False if singular."""
    for i in range(4):
        for j in range(4):
            M[i, j] = A[i, j]
        M[i, 4] = b[i]
    for col in range(4):
        piv = col
        for i in range(col + 1, 4):
            if abs(M[i, col]) > abs(M[piv, col]):
                piv = i
        if M[piv, col] == 0.0:
            return False
        if piv != col:
            for j in range(5):
                M[col, j], M[piv, j] = M[piv, j], M[col, j]
        for i in range(col + 1, 4):
            f = M[i, col] / M[col, col]
            for j in range(col, 5):
                M[i, j] -= f * M[col, j]
    for i in range(3, -1, -1):
        acc = M[i, 4]
        for j in range(i + 1, 4):
            acc -= M[i, j] * x[j]
        x[i] = acc / M[i, i]
    return True


@numba.njit(cache=True, fastmath=False)
def _rayleigh(N, q, Nq):  # pragma: no cover - compiled
    """For a unit q: the Rayleigh quotient q.N q and the squared residual |N q - (q.N q) q|^2."""
    rq = 0.0
    for i in range(4):
        acc = 0.0
        for k in range(4):
            acc += N[i, k] * q[k]
        Nq[i] = acc
        rq += q[i] * acc
    res = 0.0
    for i in range(4):
        d = Nq[i] - rq * q[i]
        res += d * d
    return rq, res


@numba.njit(cache=True, fastmath=False)
def _certified(N, q, size, fro, Nq):  # pragma: no cover - compiled
    """Is q (unit) the top eigenvector of N to round-off? Returns (ok, rayleigh)."""
    rq, res = _rayleigh(N, q, Nq)
    # an eigenvalue above |F| can only be the top one (the second is at
    # most the largest singular value)
    return res <= (1e-12 * size) ** 2 and rq > fro * (1.0 + 1e-12), rq


@numba.njit(cache=True, fastmath=False)
def _top_quaternion(N, q0, warm, out, work):  # pragma: no cover - compiled
    """Dominant eigenvector of one symmetric 4x4 Horn matrix.

    Rayleigh quotient iteration from the warm start (cubic convergence,
    certified by the residual and by the eigenvalue exceeding |F|); the
    squaring method of rotations.py when that does not certify.
    """
    total = 0.0
    for i in range(4):
        for j in range(4):
            total += N[i, j] * N[i, j]
    size = 1.225 * np.sqrt(total)
    fro = 0.5 * np.sqrt(total)
    if total == 0.0:
        out[0], out[1], out[2], out[3] = 1.0, 0.0, 0.0, 0.0
        return True
    q = work[0, :4]
    x = work[1, :4]
    Nq = work[2, :4]
    M = work[3:7, :5]
    A = work[7:11, :4]
    P = work[11:15, :4]
    T = work[15:19, :4]
    if warm:
        for i in range(4):
            q[i] = q0[i]
    else:
        q[0], q[1], q[2], q[3] = 1.0, 0.0, 0.0, 0.0
    nrm = np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if nrm > 0.0:
        for i in range(4):
            q[i] /= nrm
        for _ in range(4):
            ok, rq = _certified(N, q, size, fro, Nq)
            if ok:
                for i in range(4):
                    out[i] = q[i]
                return True
            for i in range(4):
                for j in range(4):
                    A[i, j] = N[i, j]
                A[i, i] -= rq
            if not _solve4(A, q, x, M):
                break  # q is an exact eigenvector: certified above or not the top
            nrm = np.sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2] + x[3] * x[3])
            if not nrm > 0.0 or nrm == np.inf:
                break
            for i in range(4):
                q[i] = x[i] / nrm
    # fallback: powers of the shifted, scaled matrix (see rotations.py)
    inv = 1.0 / size
    shift = 1.0 / (np.sqrt(2.0) * 2.45)
    for i in range(4):
        for j in range(4):
            P[i, j] = N[i, j] * inv
        P[i, i] += shift
    for _ in range(8):
        for i in range(4):
            for j in range(4):
                acc = 0.0
                for k in range(4):
                    acc += P[i, k] * P[k, j]
                T[i, j] = acc
        for i in range(4):
            for j in range(4):
                P[i, j] = T[i, j]
    col = 0
    for i in range(1, 4):
        if P[i, i] > P[col, col]:
            col = i
    nrm = 0.0
    for i in range(4):
        out[i] = P[i, col]
        nrm += out[i] * out[i]
    nrm = np.sqrt(nrm)
    for i in range(4):
        out[i] /= nrm + 1e-300
    _, res = _rayleigh(N, out, Nq)
    return res <= (1e-12 * size) ** 2 and nrm > 1e-150


@numba.njit(cache=True, fastmath=False, inline="always")
def _closest_rotation(F, k, q, warm, R, N, g, out, work):  # pragma: no cover - compiled
    """Closest rotation number ``k``: ``F[9k:9k+9]`` (row-major) -> ``R[9k:9k+9]`` and ``q[k]``.

    ``q[k]`` is read as the warm start when ``warm``; ``N``, ``g``, ``out``
    and ``work`` are scratch (indices, not slices: no array views are made
    in the innermost loop). Returns whether the quaternion was certified.
    """
    o = 9 * k
    # the rotation does not change with a positive scale: entries in [-1, 1]
    # so that no square can overflow or underflow
    big = 0.0
    for i in range(9):
        big = max(big, abs(F[o + i]))
    scale = 1.0 / big if big > 0.0 else 1.0
    for i in range(9):
        g[i] = F[o + i] * scale
    # Horn's matrix: tr(R(q)^T F) = q^T N q
    N[0, 0] = g[0] + g[4] + g[8]
    N[1, 1] = g[0] - g[4] - g[8]
    N[2, 2] = -g[0] + g[4] - g[8]
    N[3, 3] = -g[0] - g[4] + g[8]
    N[0, 1] = N[1, 0] = g[7] - g[5]
    N[0, 2] = N[2, 0] = g[2] - g[6]
    N[0, 3] = N[3, 0] = g[3] - g[1]
    N[1, 2] = N[2, 1] = g[1] + g[3]
    N[1, 3] = N[3, 1] = g[2] + g[6]
    N[2, 3] = N[3, 2] = g[5] + g[7]
    ok = _top_quaternion(N, q[k], warm, out, work)
    a, b, c, d = out[0], out[1], out[2], out[3]
    q[k, 0], q[k, 1], q[k, 2], q[k, 3] = a, b, c, d
    R[o + 0] = a * a + b * b - c * c - d * d
    R[o + 1] = 2.0 * (b * c - a * d)
    R[o + 2] = 2.0 * (b * d + a * c)
    R[o + 3] = 2.0 * (b * c + a * d)
    R[o + 4] = a * a - b * b + c * c - d * d
    R[o + 5] = 2.0 * (c * d - a * b)
    R[o + 6] = 2.0 * (b * d - a * c)
    R[o + 7] = 2.0 * (c * d + a * b)
    R[o + 8] = a * a - b * b - c * c + d * d
    return ok


@numba.njit(cache=True, fastmath=False)
def _rotation_kernel(F, q, warm, R, ok):  # pragma: no cover - compiled
    """Rotations of flat row-major matrices ``F`` (9 n) into flat ``R`` (9 n)."""
    N = np.empty((4, 4))
    out = np.empty(4)
    work = np.empty((19, 5))
    g = np.empty(9)
    for k in range(q.shape[0]):
        ok[k] = _closest_rotation(F, k, q, warm, R, N, g, out, work)


def rotations3(F9, q):
    """Closest rotations of row-major 3x3 matrices, warm-started.

    Parameters
    ----------
    F9 : ndarray, shape (n, 9)
    q : ndarray, shape (n, 4) or None
        Quaternions of the previous rotations (updated in place), or None.

    Returns
    -------
    R9 : ndarray, shape (n, 9)
    q : ndarray, shape (n, 4)
    """
    n = F9.shape[0]
    warm = q is not None
    if q is None:
        q = np.zeros((n, 4))
    R = np.empty((n, 9))
    ok = np.empty(n, dtype=np.bool_)
    _rotation_kernel(np.ascontiguousarray(F9).reshape(-1), q, warm, R.reshape(-1), ok)
    if not ok.all():
        from .rotations import rotations3_flat

        bad = ~ok
        R[bad] = rotations3_flat(F9[bad])
    return R, q


@numba.njit(cache=True, fastmath=False)
def run3(G, W, c, Y, first, count, q, warm):  # pragma: no cover - compiled
    """Local/global iterations of a 3D step, into rows ``first + 1 ..`` of ``Y``.

    ``F = G z`` (9 rows a cluster), the rotations by :func:`_top_quaternion`
    (warm-started from ``q``, updated in place), ``z = c + W vec(R)``.

    Returns
    -------
    done : int
        Iterations made: ``count``, or fewer when a rotation could not be
        certified (the caller makes that iteration another way).
    """
    n = G.shape[0] // 9
    N = np.empty((4, 4))
    out = np.empty(4)
    work = np.empty((19, 5))
    g = np.empty(9)
    R = np.empty(n * 9)
    for i in range(count):
        it = first + 1 + i
        F = np.dot(G, Y[it - 1])
        for k in range(n):
            if not _closest_rotation(F, k, q, warm or i > 0, R, N, g, out, work):
                return i
        Y[it] = c + np.dot(W, R)
    return count


@numba.njit(cache=True, fastmath=False)
def run2(G, W_c, Y, first, count):  # pragma: no cover - compiled
    """Local/global iterations of a 2D step, into rows ``first + 1 ..`` of ``Y``.

    ``(c, s) = G z`` (2 rows a cluster), normalised, ``z = W_c [(c, s); 1]``
    (the step's constant is ``W_c``'s last column).
    """
    pairs = G.shape[0]
    cs1 = np.ones(pairs + 1)
    for it in range(first + 1, first + count + 1):
        cs = np.dot(G, Y[it - 1])
        for k in range(pairs // 2):
            x = cs[2 * k]
            y = cs[2 * k + 1]
            nrm = np.hypot(x, y)
            if nrm == 0.0:
                cs1[2 * k] = 1.0
                cs1[2 * k + 1] = 0.0
            else:
                cs1[2 * k] = x / nrm
                cs1[2 * k + 1] = y / nrm
        Y[it] = np.dot(W_c, cs1)
