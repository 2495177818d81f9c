"""Modal muscles: the clustered plastic-stretch target and gait signals.

Activating muscle amplitudes ``a`` asks every element to take the deformation
gradient of the rest shape pushed along the muscle modes,
``Y_e(a) = I + sum_m a_m (J D_m)_e``, up to a rotation shared by the element's
active cluster. The active energy is

    E_a(z, R) = sum_e gamma_e vol_e / 2 |F_e(z) - R_c(e) Y_e(a)|^2 ,

minimised over the rotations by ``R_c = polar(sum_{e in c} w_e F_e Y_e^T)``
(``w_e = gamma_e vol_e``). Both that cluster sum and the force it produces are
linear in ``z`` and in ``a``, through one operator per muscle:

    A(a) = A_0 + sum_m a_m A_m ,   (A(a) z)_c = sum_{e in c} w_e F_e(z) Y_e(a)^T ,

and the force on ``z`` is ``A(a)^T vec(R)``. This module builds the ``A_m``.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sps

from .values import is_finite_real

__all__ = [
    "shortest_period",
    "checked_ramp",
    "cluster_sum_operator",
    "gait_ramp",
    "muscle_target_operator",
    "muscle_target_constants",
    "sine_gait",
]


def cluster_sum_operator(labels, weights, dim: int, n_clusters: int | None = None) -> sps.csr_matrix:
    """Weighted sums of per-element deformation gradients over clusters.

    Parameters
    ----------
    labels : ndarray of int, shape (nT,)
    weights : ndarray, shape (nT,)
        ``w_e``, e.g. ``mu * vol``.
    dim : int
    n_clusters : int, optional
        Default ``labels.max() + 1``.

    Returns
    -------
    S : scipy.sparse.csr_matrix, shape (n_clusters * dim * dim, nT * dim * dim)
        ``(S @ vecF)`` holds ``sum_{e in c} w_e F_e`` row-major per cluster.
    """
    labels = np.asarray(labels)
    nc = int(labels.max()) + 1 if n_clusters is None else n_clusters
    P = sps.csr_matrix((np.asarray(weights, float), (labels, np.arange(labels.size))), shape=(nc, labels.size))
    return sps.kron(P, sps.identity(dim * dim), format="csr")


def muscle_target_operator(JD, labels, weights, dim: int):
    """The sparse map from per-element gradients to the active cluster sums.

    Row ``(k, c, i, j)`` of the result applied to ``vec(F)`` is
    ``sum_{e in c} w_e (F_e Y^k_e^T)[i, j]`` with ``Y^0_e = I`` and
    ``Y^k_e = (J D_k)_e``: stacked for the rest target (``k = 0``) and each
    muscle.

    Parameters
    ----------
    JD : ndarray, shape (nT * dim * dim, m)
        The muscle modes' deformation-gradient changes ``J @ D``.
    labels : ndarray of int, shape (nT,)
        Active cluster of each element.
    weights : ndarray, shape (nT,)
        ``gamma * vol``.
    dim : int

    Returns
    -------
    T : scipy.sparse.csr_matrix, shape ((m + 1) * n_active * dim^2, nT * dim^2)
    """
    labels = np.asarray(labels)
    nT = labels.size
    na = int(labels.max()) + 1
    dd = dim * dim
    m = JD.shape[1]
    G = JD.reshape(nT, dim, dim, m)  # per element, per muscle: (J D_m)_e
    # row (c, i, j) <- column (e, i, k) with value w_e G^m_e[j, k]
    e, i, j, k = np.meshgrid(np.arange(nT), np.arange(dim), np.arange(dim), np.arange(dim), indexing="ij")
    rows = ((labels[e] * dim + i) * dim + j).ravel()
    cols = ((e * dim + i) * dim + k).ravel()
    blocks = [cluster_sum_operator(labels, weights, dim, na)]
    we = weights[e]
    for mm in range(m):
        vals = (we * G[e, j, k, mm]).ravel()
        blocks.append(sps.csr_matrix((vals, (rows, cols)), shape=(na * dd, nT * dd)))
    return sps.vstack(blocks, format="csr")


def muscle_target_constants(JD, weights, dim: int):
    """Constant part of the active energy: ``1/2 sum_e w_e |Y_e(a)|^2``.

    Parameters
    ----------
    JD : ndarray, shape (nT * dim * dim, m)
    weights : ndarray, shape (nT,)
    dim : int

    Returns
    -------
    c0 : float
        ``1/2 dim sum_e w_e``.
    c1 : ndarray, shape (m,)
        ``sum_e w_e tr((J D_m)_e)``.
    Q : ndarray, shape (m, m)
        ``1/2 sum_e w_e (J D_m)_e : (J D_n)_e``; the constant is
        ``c0 + c1 @ a + a @ Q @ a``.
    """
    nT = np.asarray(weights).size
    m = JD.shape[1]
    G = JD.reshape(nT, dim * dim, m)
    c0 = 0.5 * dim * float(np.sum(weights))
    trace = G[:, :: dim + 1, :].sum(axis=1)  # (nT, m)
    c1 = weights @ trace
    Q = 0.5 * np.einsum("e,eim,ein->mn", weights, G, G)
    return c0, c1, Q


def sine_gait(t, amplitudes, periods, phases, ramp=0.0) -> np.ndarray:
    """Sinusoidal muscle activations ``a_m(t) = r(t) A_m sin(2 pi (t / T_m + phi_m))``.

    ``r(t)`` (:func:`gait_ramp`) grows from 0 at ``t = 0`` to 1 at ``t = ramp``
    and stays 1; ``ramp = 0`` (the default) leaves it 1 throughout.

    Parameters
    ----------
    t : float
        Time.
    amplitudes, periods, phases : array_like, shape (m,)
        Amplitude (in the muscle's units: multiply ceiling fractions by the
        ceilings first), period (same time unit as ``t``, > 0) and phase (in
        periods).
    ramp : float
        Time over which the amplitudes grow from zero (>= 0, same unit as ``t``).

    Returns
    -------
    a : ndarray, shape (m,)

    Examples
    --------
    >>> sine_gait(0.25, [2.0], [1.0], [0.0]).tolist()
    [2.0]
    >>> sine_gait(0.25, [2.0], [1.0], [0.0], ramp=0.5).tolist()  # half way up the ramp
    [1.0]
    """
    try:
        values = [np.asarray(v, dtype=np.float64) for v in (amplitudes, periods, phases)]
    except (TypeError, ValueError):
        raise ValueError(
            f"amplitudes, periods and phases must be numbers, got {amplitudes!r}, {periods!r}, {phases!r}"
        ) from None
    amplitudes, periods, phases = values
    if not amplitudes.shape == periods.shape == phases.shape:
        raise ValueError(
            f"amplitudes, periods and phases must have one value per muscle each, got shapes "
            f"{amplitudes.shape}, {periods.shape} and {phases.shape}"
        )
    if not np.all(periods > 0.0):  # NaN too
        raise ValueError(f"periods must be positive, got {periods.tolist()}")
    ramp = checked_ramp(ramp)
    a = _sine(t, amplitudes, periods, phases, ramp)
    if not np.all(np.isfinite(a)):
        raise ValueError(
            f"the gait must be finite: amplitudes {amplitudes.tolist()}, phases {phases.tolist()}, t {t!r}"
        )
    return a


def shortest_period(amplitudes, periods) -> float | None:
    """The shortest period of a sine gait's moving muscles (amplitude not 0), or None if none moves.

    Parameters
    ----------
    amplitudes, periods : array_like of float, shape (m,)
        Each muscle's amplitude and period (:func:`sine_gait`).

    Returns
    -------
    period : float or None

    Raises
    ------
    ValueError
        The two do not have one value per muscle each.

    Examples
    --------
    >>> shortest_period([0.2, 0.0, 0.1], [1.0, 0.1, 0.5])
    0.5
    """
    amplitudes, periods = np.asarray(amplitudes, dtype=np.float64), np.asarray(periods, dtype=np.float64)
    if amplitudes.ndim != 1 or amplitudes.shape != periods.shape:
        raise ValueError(
            f"a gait needs one amplitude and one period per muscle, got shapes {amplitudes.shape} and {periods.shape}"
        )
    moving = periods[amplitudes != 0.0]
    return float(moving.min()) if moving.size else None


def checked_ramp(value, name: str = "ramp") -> float:
    """A gait's ramp (:func:`gait_ramp`) as a float, checked to be a time >= 0.

    Parameters
    ----------
    value : int or float
        The ramp time: a Python or numpy number (not a bool), finite and >= 0.
    name : str
        How to name it in the message.

    Returns
    -------
    ramp : float

    Raises
    ------
    ValueError
        Naming ``name``, if it is not a finite number >= 0.
    """
    if not (is_finite_real(value) and value >= 0.0):  # NaN too
        raise ValueError(f"{name} must be a time >= 0, got {value!r}")
    return float(value)


def gait_ramp(t, ramp: float):
    """How much of a gait's amplitude is on at time ``t`` (float or array): from 0 at ``t = 0`` to 1 at ``ramp``.

    The smoothstep ``3 u^2 - 2 u^3`` of ``u = t / ramp``: its slope is zero at both ends, so the
    muscles start, and reach full stroke, without a jerk. 1 from ``ramp`` on, and throughout when
    ``ramp`` is 0; 0 before ``t = 0``.

    >>> gait_ramp(0.0, 1.0), gait_ramp(0.5, 1.0), gait_ramp(2.0, 1.0), gait_ramp(0.0, 0.0)
    (0.0, 0.5, 1.0, 1.0)
    """
    if not ramp:
        return 1.0 if np.ndim(t) == 0 else np.ones(np.shape(t))
    u = np.clip(np.asarray(t, dtype=np.float64) / ramp, 0.0, 1.0)  # (NaN stays NaN: sine_gait says so)
    share = u * u * (3.0 - 2.0 * u)
    return float(share) if share.ndim == 0 else share


def _sine(t, amplitudes, periods, phases, ramp=0.0):
    # sine_gait's arithmetic without its checks, for a scene that checked its gait once
    a = amplitudes * np.sin(2.0 * np.pi * (t / periods + phases))
    return a * gait_ramp(t, ramp) if ramp else a  # (times exactly 1 from the ramp on: the same bits)
