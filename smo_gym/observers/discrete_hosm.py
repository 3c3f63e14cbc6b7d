r"""Discrete-time HOSM-inspired observer of Wetzlinger, Reichhartinger and Horn, arbitrary order.

For a system in the observability form (27)-(28) with sampled output :math:`y_k = \xi_{1,k}`,

.. math::
    \dot\xi_i = \xi_{i+1} + \gamma_i(\xi_1,\dots,\xi_i,u) + \delta_i,\quad i < n,\qquad
    \dot\xi_n = \gamma_n(\xi,u) + \delta_n,

the observer (33) is the one-step predictor

.. math::
    \hat\xi_{k+1} = \mathbf A\hat\xi_k + \mathbf B\begin{bmatrix}\gamma_1(y_k,u_k)\\
    \mathrm{sat}_{L_{\gamma_2}}\hat\gamma_2(y_k,\hat\xi_{2,k},u_k)\\ \vdots\\
    \mathrm{sat}_{L_{\gamma_n}}\hat\gamma_n(y_k,\hat\xi_{2,k},\dots,\hat\xi_{n,k},u_k)\end{bmatrix}
    + \tilde{\mathbf l}(z_n(\sigma_{1,k}))\,\sigma_{1,k},\qquad \sigma_{1,k} = y_k - \hat\xi_{1,k},

with the Taylor matrices :math:`\mathbf A_{ij} = h^{j-i}/(j-i)!` (31), :math:`\mathbf B_{ij} = h^{j-i+1}/(j-i+1)!`
(32), and the gain of Ackermann's formula (35),
:math:`\tilde{\mathbf l}(z) = (\mathbf A - z\mathbf I)^n\mathcal O^{-1}e_n`, which places all ``n`` eigenvalues of
the error matrix :math:`\mathbf A - \tilde{\mathbf l}\mathbf c^T` at the state-dependent
:math:`z_n(\sigma_{1,k})` of the semi-implicit mapping (15) or the matching mapping (16):

.. math::
    z_s(e) = \frac{|e|^{1/n}}{hp_1\mu|e| + |e|^{1/n} + hp_1},\qquad
    z_m(e) = \exp\Big(-hp_1\frac{1 + \mu|e|}{|e|^{1/n}}\Big).

Without model terms it is the differentiator of section 3.1 discretised by (15)/(16), and the recursion is the
compiled eigenvalue-map step (:func:`smo_gym.observers._kernels.eigmap_channel_step`), the one
:class:`smo_gym.observers.Levant` runs with ``discretization="semi-implicit"`` / ``"matching"``. The two report
different things from the same state: ``Levant`` the prediction moved back to the sample time,
:math:`e^{-hN}\hat\xi_{k+1} = \mathbf A^{-1}\hat\xi_{k+1}`, this class the predictor :math:`\hat\xi_{k+1}` itself,
as the paper does (a parameter of the step says which). The functions below evaluate the paper's matrices and
maps in NumPy for analysis and tests; the observer does not call them per sample.

References
----------
.. [WRH] M. Wetzlinger, M. Reichhartinger and M. Horn, "Higher order sliding mode inspired nonlinear
   discrete-time observer", eqs. (15), (16), (24), (31)-(41), (51)-(52), section 6.
.. [KR19] S. Koch and M. Reichhartinger, "Discrete-time equivalents of the super-twisting algorithm",
   Automatica 107, 2019 (the matching mapping).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from functools import lru_cache

import numpy as np

from .._validation import (
    as_real_array,
    check_choice,
    check_int_in_range,
    check_keywords,
    check_nonnegative,
    check_positive_array,
)
from . import _kernels
from .base import Observer, checked_input
from .differentiators import _pack_eigmap, eigenvalue_map_rate, eigenvalue_mapping_vectors, taylor_matrix
from .registry import register_observer

__all__ = [
    "DiscreteTimeHOSM",
    "ackermann_gain",
    "canonical_error_matrix",
    "canonical_error_step",
    "eigenvalue_mapping",
    "input_matrix",
    "lyapunov_decrease_matrix",
    "max_eigenvalue",
    "paper_lyapunov_q",
    "perturbation_bounds",
    "printed_third_order_gain",
    "proven_eigenvalue_bound",
    "rate_for_max_eigenvalue",
    "stability_threshold",
]

MAPPINGS = ("semi-implicit", "matching")
#: the system order ``n`` of a :class:`DiscreteTimeHOSM` built without one (value, velocity and acceleration)
DEFAULT_N = 3
#: the largest system order ``n`` accepted
MAX_N = 10


def eigenvalue_mapping(sigma, dt: float, p1, mu: float, n: int, mapping: str = "semi-implicit") -> np.ndarray:
    r"""The state-dependent discrete eigenvalue :math:`z_n(\sigma)`, (15) or (16); :math:`z_n(0) = 0`.

    NumPy reference of the maps, for analysis, tests and :attr:`DiscreteTimeHOSM.eigenvalue`; the observer's step
    evaluates them compiled (:func:`smo_gym.observers._kernels.eigenvalue_map`: the same operations, with its own
    cube root and ``exp``, equal to a few ulp).

    Parameters
    ----------
    sigma : array_like
        Output error :math:`\sigma_{1,k}` (any shape).
    dt, p1, mu : float (``p1`` may be an array broadcasting with ``sigma``)
    n : int
        System order (the root :math:`|\sigma|^{1/n}`).
    mapping : {"semi-implicit", "matching"}
    """
    a = np.abs(np.asarray(sigma, dtype=float))
    root = a ** (1.0 / n)
    hp = dt * np.asarray(p1, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        if mapping == "semi-implicit":
            z = root / (hp * mu * a + root + hp)
        else:
            z = np.exp(-hp * (1.0 + mu * a) / root)
    return np.where(a > 0.0, z, 0.0)


def max_eigenvalue(n: int, dt: float, p1: float, mu: float, mapping: str = "semi-implicit") -> float:
    r"""Largest value of the mapping over :math:`\sigma`, attained at :math:`|\sigma| = 1/(\mu(n-1))`.

    .. math:: z_{s,\max} = \frac{n-1}{n-1 + n(\mu(n-1))^{1/n}hp_1},\qquad
              z_{m,\max} = \exp\Big(-hp_1\frac{n}{n-1}(\mu(n-1))^{1/n}\Big).

    The stability proofs of section 5 need :math:`z_{\max} < z^*` with :math:`z^* = 1/\sqrt2` (n = 2, (62)) and
    0.4985816 (n = 3, (70)), both derived by :func:`proven_eigenvalue_bound`; :func:`stability_threshold` turns
    that into the smallest :math:`hp_1`.

    Notes
    -----
    Errata of Section 5 found by deriving it (each checked in ``tests/test_discrete_hosm.py``):

    * (52): the printed :math:`z_{m,\max} = \exp(-hp_1n(\mu(n-1))^{1/n})` lacks the factor :math:`1/(n-1)`;
      evaluating (16) at its maximiser :math:`1/(\mu(n-1))` gives :math:`\exp(-hp_1\frac{n}{n-1}(\mu(n-1))^{1/n})`
      (the two agree for ``n = 2`` only). The paper's own (72) follows the corrected form.
    * (71): the printed threshold :math:`hp_1 > (2 - 0.9972)/(3\sqrt[3]{2\mu})` (0.265 for :math:`\mu = 1`) reads
      :math:`2 - 2z^*` where inverting (51) gives :math:`2/z^* - 2`: :math:`hp_1 > (2/z^* - 2)/(3\sqrt[3]{2\mu})`
      (0.532 for :math:`\mu = 1`). Section 6's :math:`p_1 = 30,\ h = 0.01,\ \mu = 1` ("chosen such that (71)
      is fulfilled") has :math:`z_{\max} = 0.638 > z^*`: outside the proven region (it converges in simulation;
      the condition is sufficient, and conservative: the unperturbed error converges from every tested initial
      error for :math:`hp_1` a hundred times smaller).
    * (68c)-(68d): the printed :math:`m_1, m_2` are twice the entries of :math:`\mathbf M(z_3)` (the coefficients
      of the cross terms of :math:`\mathbf e^T\mathbf M\mathbf e`), and in (68e) the factor :math:`1/16` applies
      to the whole expression; (69) is nevertheless what the correct :math:`\mathbf M` gives.
    * (48) prints :math:`\mathbf A_o^T\mathbf P\mathbf A_o^T`; the difference of the quadratic forms is
      :math:`\mathbf A_o^T\mathbf P\mathbf A_o - \mathbf P`.
    """
    n = check_int_in_range("n", n, 2, 64)
    q = (mu * (n - 1)) ** (1.0 / n) * dt * p1
    if mapping == "semi-implicit":
        return (n - 1) / (n - 1 + n * q)
    return float(np.exp(-n / (n - 1) * q))


def _char_coefficients(z, n: int) -> np.ndarray:
    r""":math:`\Phi_1..\Phi_n` of (24), :math:`(s - z)^n = s^n + \Phi_n s^{n-1} + \dots + \Phi_1`:
    :math:`\Phi_i = \binom{n}{i-1}(-z)^{n-i+1}`; shape ``z.shape + (n,)``."""
    z = np.asarray(z, dtype=float)[..., None]
    i = np.arange(1, n + 1)
    binom = np.array([math.comb(n, k - 1) for k in i], dtype=float)
    return binom * (-z) ** (n - i + 1)


def canonical_error_matrix(z: float, n: int) -> np.ndarray:
    r"""The error matrix :math:`\mathbf A_o(z)` of (23) in observable canonical form, shape ``(n, n)``:
    :math:`\mathbf A_L` (43) (ones below the diagonal) with last column :math:`-(\Phi_1, \ldots, \Phi_n)` of (24)."""
    A = np.eye(n, k=-1)
    A[:, -1] = -_char_coefficients(z, n)
    return A


def canonical_error_step(e, dt: float, p1: float, mu: float, mapping: str = "semi-implicit") -> np.ndarray:
    r"""One step of the unperturbed error dynamics (22), :math:`\mathbf e_{k+1} = \mathbf A_o(z_n(e_{n,k}))\mathbf e_k`,
    batched: ``e`` of shape ``(..., n)``, the eigenvalue (15) or (16) of the measured error :math:`e_{n,k}`.

    The observer's own error (in the Taylor coordinates of (31)) is this one after a constant change of coordinates
    :math:`\mathbf e = \mathbf S\boldsymbol\sigma` with :math:`e_n = \sigma_1` (Section 5).
    """
    e = np.asarray(e, dtype=float)
    n = e.shape[-1]
    z = eigenvalue_mapping(e[..., -1], dt, p1, mu, n, mapping)
    new = np.zeros_like(e)
    new[..., 1:] = e[..., :-1]
    return new - _char_coefficients(z, n) * e[..., -1:]


def paper_lyapunov_q(n: int) -> np.ndarray:
    r"""The matrix :math:`\mathbf Q` the proofs of Section 5 use: (59) for ``n = 2``, (67) for ``n = 3``.

    These are the paper's choices (positive semi-definite, :math:`\mathbf Q_{n-1} \succ 0`); other orders need a
    ``Q`` of the caller's (Theorem 1 admits any with :math:`\mathbf Q_{n-1} \succ 0`).
    """
    if n == 2:
        r2 = np.sqrt(2.0)
        return np.array([[2.0, r2], [r2, 1.0]])
    if n == 3:
        return np.array([[4.0, 2.0, 1.0], [2.0, 5.0, 4.0], [1.0, 4.0, 53.0 / 16.0]])
    raise ValueError(f"expected n = 2 or 3 (the orders the paper gives Q for), actual value: {n!r}")


def lyapunov_decrease_matrix(z: float, n: int, Q=None) -> tuple[np.ndarray, np.ndarray]:
    r"""``(P, M(z))`` of the proof of Theorem 1: :math:`\mathbf P` solves (46),
    :math:`\mathbf A_L^T\mathbf P\mathbf A_L - \mathbf P = -\mathbf Q`, and
    :math:`\Delta V_k = -\mathbf e_k^T\mathbf M(z)\mathbf e_k` with
    :math:`\mathbf M(z) = \mathbf P - \mathbf A_o(z)^T\mathbf P\mathbf A_o(z)` (48) (the printed (48) has
    :math:`\mathbf A_o^T` twice, a typo). ``Q`` defaults to :func:`paper_lyapunov_q`.

    :math:`\mathbf P` is the finite sum :math:`\sum_{j<n}(\mathbf A_L^T)^j\mathbf Q\mathbf A_L^j`
    (:math:`\mathbf A_L` is nilpotent); for ``n = 2, 3`` it is (58) and (66).
    """
    Q = paper_lyapunov_q(n) if Q is None else np.asarray(Q, dtype=float)
    if Q.shape != (n, n) or not np.allclose(Q, Q.T):
        raise ValueError(f"expected a symmetric Q of shape ({n}, {n}), actual value: {Q!r}")
    AL = np.eye(n, k=-1)
    P = np.zeros((n, n))
    Aj = np.eye(n)
    for _ in range(n):
        P += Aj.T @ Q @ Aj
        Aj = AL @ Aj
    Ao = canonical_error_matrix(z, n)
    return P, P - Ao.T @ P @ Ao


def proven_eigenvalue_bound(n: int, Q=None) -> float:
    r""":math:`z^*` of Section 5, derived: the first :math:`z > 0` at which :math:`\det\mathbf M(z) = 0`.

    For :math:`0 < z < z^*` the matrix :math:`\mathbf M(z)` of :func:`lyapunov_decrease_matrix` is positive definite
    (its leading block :math:`\mathbf Q_{n-1}` is constant and positive definite, so positivity is the sign of the
    determinant, a polynomial in ``z`` vanishing at 0 where :math:`\mathbf M(0) = \mathbf Q` is singular), hence
    :math:`\Delta V_k < 0` whenever every eigenvalue the mapping takes is below :math:`z^*`. With the paper's ``Q``:
    :math:`1/\sqrt2` for ``n = 2`` ((61)-(62)) and 0.4985816 for ``n = 3`` ((69)-(70), printed 0.498582).

    The root is bracketed on a grid of 1000 points of (0, 1] and refined by bisection to 1e-15.
    """
    n = check_int_in_range("n", n, 2, MAX_N)
    Q = paper_lyapunov_q(n) if Q is None else np.asarray(Q, dtype=float)
    if np.min(np.linalg.eigvalsh(Q[:-1, :-1])) <= 0:
        raise ValueError(f"expected Q with a positive definite leading block Q_(n-1), actual value: {Q!r}")

    def det(z):
        return np.linalg.det(lyapunov_decrease_matrix(z, n, Q)[1])

    grid = np.linspace(0.0, 1.0, 1001)[1:]
    values = np.array([det(z) for z in grid])
    bad = np.flatnonzero(values <= 0.0)
    if bad.size == 0:
        return 1.0
    if bad[0] == 0:
        raise ValueError(f"expected M(z) > 0 for small z > 0 with this Q, actual value: det M({grid[0]}) <= 0")
    lo, hi = grid[bad[0] - 1], grid[bad[0]]
    while hi - lo > 1e-15:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if det(mid) > 0.0 else (lo, mid)
    return float(lo)


@lru_cache(maxsize=8)
def _paper_eigenvalue_bound(n: int) -> float:
    """:func:`proven_eigenvalue_bound` with the paper's ``Q`` (cached)."""
    return proven_eigenvalue_bound(n)


def stability_threshold(n: int, mu: float, mapping: str = "semi-implicit", Q=None) -> float:
    r"""The smallest :math:`hp_1` proven to give global asymptotic stability (Section 5), derived: the value at which
    :func:`max_eigenvalue` equals :func:`proven_eigenvalue_bound`.

    With :math:`q = (\mu(n-1))^{1/n}hp_1`, :math:`z_{s,\max} = (n-1)/(n-1+nq)` and
    :math:`z_{m,\max} = e^{-nq/(n-1)}`, so :math:`z_{\max} < z^*` if and only if

    .. math:: hp_1 > \frac{(n-1)(1/z^* - 1)}{n(\mu(n-1))^{1/n}}\ \text{(15)},\qquad
              hp_1 > \frac{-(n-1)\ln z^*}{n(\mu(n-1))^{1/n}}\ \text{(16)}.

    For ``n = 2`` these are (63) and (64); for ``n = 3``, (72) and, instead of the printed (71),
    :math:`(2/z^* - 2)/(3\sqrt[3]{2\mu})` (see Notes of :func:`max_eigenvalue`).
    """
    n = check_int_in_range("n", n, 2, MAX_N)
    z_star = _paper_eigenvalue_bound(n) if Q is None else proven_eigenvalue_bound(n, Q)
    return rate_for_max_eigenvalue(z_star, n, mu, mapping)


def rate_for_max_eigenvalue(z_max: float, n: int, mu: float, mapping: str = "semi-implicit") -> float:
    r"""The :math:`hp_1` at which :func:`max_eigenvalue` equals ``z_max`` (``0 < z_max < 1``): the inverse of (51) and
    of the corrected (52), :math:`(n-1)(1/z_{\max} - 1)/(n(\mu(n-1))^{1/n})` and
    :math:`-(n-1)\ln z_{\max}/(n(\mu(n-1))^{1/n})`."""
    n = check_int_in_range("n", n, 2, MAX_N)
    mu = check_nonnegative("mu", mu)
    if mu == 0:
        raise ValueError(f"expected mu > 0 (the maximum of the mapping is at 1/(mu (n-1))), actual value: {mu!r}")
    check_choice("mapping", mapping, MAPPINGS)
    if not 0.0 < z_max < 1.0:
        raise ValueError(f"expected 0 < z_max < 1, actual value: {z_max!r}")
    scale = n * (mu * (n - 1)) ** (1.0 / n)
    if mapping == "semi-implicit":
        return (n - 1) * (1.0 / z_max - 1.0) / scale
    return -(n - 1) * math.log(z_max) / scale


def input_matrix(n: int, dt: float) -> np.ndarray:
    r"""The matrix (32), :math:`\mathbf B_{ij} = h^{j-i+1}/(j-i+1)!` for ``j >= i``, shape ``(n, n)``."""
    B = np.zeros((n, n))
    for i in range(n):
        fac = dt
        for j in range(i, n):
            B[i, j] = fac
            fac *= dt / (j - i + 2)
    return B


def ackermann_gain(z, n: int, dt: float) -> np.ndarray:
    r"""Ackermann's formula (35) evaluated directly: :math:`(\mathbf A - z\mathbf I)^n\mathcal O^{-1}e_n`.

    Reference implementation (matrix powers) of what the observer evaluates as a polynomial in ``z``
    (:func:`smo_gym.observers.differentiators.eigenvalue_mapping_vectors`). ``z`` scalar; returns shape ``(n,)``.
    """
    A = taylor_matrix(n, dt)
    O = np.vstack([np.linalg.matrix_power(A, i)[0] for i in range(n)])
    e_n = np.zeros(n)
    e_n[-1] = 1.0
    return np.linalg.matrix_power(A - z * np.eye(n), n) @ np.linalg.solve(O, e_n)


def printed_third_order_gain(z, dt: float) -> np.ndarray:
    r"""The third-order gain as printed in (79)-(82) of Wetzlinger et al. (kept only to show that it is wrong).

    .. math:: \mathbf l = \big(\Phi_1 + 1,\ \Phi_2/h,\ \Phi_3/h^2\big),\quad \Phi_1 = 3z-2,\quad
              \Phi_2 = -\tfrac12z^3 - \tfrac32z^2 + \tfrac92z - \tfrac52,\quad \Phi_3 = z^3 - 3z^2 + 3z - 1.

    With it, :math:`\mathbf A - \mathbf l\mathbf c^T` does not have the triple eigenvalue ``z`` and is unstable
    (checked in the tests); use :func:`ackermann_gain`.
    """
    p1 = 3 * z - 2
    p2 = -0.5 * z**3 - 1.5 * z**2 + 4.5 * z - 2.5
    p3 = z**3 - 3 * z**2 + 3 * z - 1
    return np.array([p1 + 1, p2 / dt, p3 / dt**2])


def perturbation_bounds(L_gamma, L_delta, measured_only=None) -> np.ndarray:
    r"""Bounds on the disturbance :math:`\mathbf d_k` of the error dynamics (36), from (40)-(41).

    .. math:: |d_1| \le L_{\delta_1},\qquad |d_i| \le 2L_{\gamma_i} + L_{\delta_i},\quad i \ge 2,

    and :math:`|d_i| \le L_{\delta_i}` when :math:`\gamma_i` depends on the measured output and the input only
    (then the observer uses it exactly).

    Parameters
    ----------
    L_gamma, L_delta : array_like, shape (n,)
        Bounds of the model terms and of the perturbations (``L_gamma[0]`` is ignored: :math:`\gamma_1` is exact).
    measured_only : array_like of bool, shape (n,), optional
        Channels whose :math:`\gamma_i` depends only on ``(y, u)``.
    """
    Lg = np.asarray(L_gamma, dtype=float)
    Ld = np.asarray(L_delta, dtype=float)
    if Lg.shape != Ld.shape or Lg.ndim != 1:
        raise ValueError(f"expected L_gamma and L_delta of equal shape (n,), actual value: {Lg.shape}, {Ld.shape}")
    if np.any(Lg < 0) or np.any(Ld < 0):
        raise ValueError(f"expected non-negative bounds, actual value: L_gamma={Lg}, L_delta={Ld}")
    exact = np.zeros(Lg.shape, dtype=bool) if measured_only is None else np.asarray(measured_only, dtype=bool)
    exact = exact.copy()
    exact[0] = True
    return np.where(exact, Ld, 2.0 * Lg + Ld)


def _estimated_derivatives(kwargs: dict) -> int:
    """The registry's order of a :class:`DiscreteTimeHOSM`: ``n - 1`` derivatives of a system of order ``n``."""
    return check_int_in_range("n", kwargs["n"], 2, MAX_N) - 1


def _rate_rule(cls, calibration, order, kwargs):
    r""":math:`p_1 = (1.1 L)^{1/n}` per channel from the calibrated bound :math:`L \ge |f^{(n)}|`, the rate
    ``Levant(discretization="semi-implicit")`` takes by default
    (:func:`~smo_gym.observers.differentiators.eigenvalue_map_rate`), and :math:`\mu` one over the largest
    :attr:`~smo_gym.calibration.Calibration.unit` (its dimension is 1/[y]; one number for all channels), unless
    given."""
    n = check_int_in_range("n", kwargs.get("n", DEFAULT_N), 2, MAX_N)
    kwargs = {"mu": 1.0 / float(np.max(calibration.unit)), **kwargs}  # mu has the dimension 1/[y]
    return cls(dt=calibration.dt, **kwargs, p1=eigenvalue_map_rate(calibration.bound(order), n))


@register_observer(
    "discrete-hosm",
    steps=(_kernels.eigmap_rows,),
    calibrate=_rate_rule,
    given=(("p1",),),
    examples=(dict(n=3, p1=30.0), dict(n=2, p1=20.0, mu=0.5, discretization="matching")),
    order_from=_estimated_derivatives,
)
class DiscreteTimeHOSM(Observer):
    r"""Observer (33) of Wetzlinger et al. for ``n``-th order input-affine systems in observability form, batched.

    Every channel is an independent SISO system of order ``n`` with output :math:`y = \xi_1` (e.g. one joint:
    position, velocity, acceleration, ... for an integrator chain). Registered as ``"discrete-hosm"``: built by
    name (:func:`~smo_gym.observers.make_observer`, the wrapper, ``differentiate``, the command line) with ``p1``
    calibrated from a bound on :math:`|f^{(n)}|` when it is not given.

    Parameters
    ----------
    n : int
        System order (number of states, ``2 <= n <= 10``); the estimates are
        :math:`(\hat\xi_1, \ldots, \hat\xi_n)`, so ``order = n - 1``. Default 3.
    dt : float
        Sampling step ``h``.
    p1 : float or array_like
        Rate parameter :math:`p_1 > 0` (per channel if an array broadcastable to ``(..., n_channels)``). Required
        when the class is built directly.
    mu : float
        :math:`\mu \ge 0` (0: no uniform part).
    mapping : {"semi-implicit", "matching"}
        Eigenvalue mapping (15) or (16): the discretization (default ``"semi-implicit"``).
    gamma : sequence of ``n`` callables or None, optional
        Model terms :math:`\gamma_i`. Each is called as ``gamma[i](xi, u)`` with ``xi`` of shape
        ``(..., n_channels, n)`` (column 0 the *measurement* :math:`y_k`, columns ``1..`` the estimates
        :math:`\hat\xi_{2..n,k}`) and ``u`` the input as passed to :meth:`update` (or ``None``), and returns
        ``(..., n_channels)``. ``gamma[0]`` must depend on ``y`` and ``u`` only; ``None`` entries are zero.
    L_gamma : array_like, shape (n,), optional
        Saturation levels :math:`L_{\gamma_i}` of :math:`\hat\gamma_i`, ``i >= 2`` (``inf``: no saturation);
        ``L_gamma[0]`` is unused (:math:`\gamma_1` is not saturated in (33)). Required with ``gamma``.
    discretization : {"semi-implicit", "matching"}, optional
        The name every family gives this choice (``"discrete-hosm:discretization=matching"``): the same as
        ``mapping``; give one of them.
    wrap : bool or array_like of bool, optional
        Channels measured as angles modulo ``2 pi`` (see :class:`~smo_gym.observers.Observer`).

    Attributes
    ----------
    A, B : ndarray, shape (n, n)
        The matrices (31) and (32).

    Notes
    -----
    **What it reports.** ``update(y_k)`` returns the predictor :math:`\hat\xi_{k+1}` of (33), the estimate for
    the *next* sample time, as the paper writes the observer (:attr:`lead` is 1); the state is that predictor.
    ``reset(y0)`` reports at its own sample: :math:`\hat\xi_0 = (y_0, 0, \ldots, 0)`, or with ``derivatives``
    their values at :math:`t_0`, the state then being their prediction :math:`\mathbf A\hat x_0` for the next
    sample (every explicit family does the same). ``Levant(order=n - 1, discretization=mapping, p1=p1, mu=mu)``
    has the same state and reports :math:`\mathbf A^{-1}\hat\xi_{k+1}`, the estimate at :math:`t_k`.

    **Which code runs.** Without model terms (``gamma=None``) every path (``update``, ``run``, ``step``,
    :func:`~smo_gym.differentiate`, the wrapper's one-call path) runs the compiled eigenvalue-map step of the
    registry, :func:`smo_gym.observers._kernels.eigmap_channel_step`, the only implementation of the recursion.
    With model terms (Python callables) the step cannot be compiled: :meth:`update` calls that same compiled step,
    which gives :math:`\mathbf A\hat\xi_k + \tilde{\mathbf l}(z_n(\sigma_{1,k}))\sigma_{1,k}` (its map, gain and
    checks), and adds :math:`\mathbf B` times the terms in NumPy ((33) is linear in them); :meth:`run` loops over
    :meth:`update` in Python and :meth:`step` calls the terms with ``u = None``. Such an observer has no fused
    path (:func:`smo_gym.engine.fused.fusable` is false), and it pickles only if its callables do.

    Gains: Ackermann's formula (35) evaluated as :math:`\tilde{\mathbf l}(z) = \sum_{j=0}^n (-z)^{n-j}v_j` with
    :math:`v_j = \binom nj\mathbf A^j\mathcal O^{-1}e_n` (the binomial expansion of :math:`(\mathbf A - zI)^n`).
    The printed closed form (79)-(82) is not stable (see :func:`printed_third_order_gain`). The paper's section 5
    proves global asymptotic stability of the unperturbed error for ``n = 2, 3`` when :func:`max_eigenvalue` is
    below :math:`z^* = 1/\sqrt2` and 0.4985816 (derived by :func:`proven_eigenvalue_bound`, not hard-coded); a
    ``RuntimeWarning`` is not raised for other settings, but :meth:`stability_margin` reports :math:`z^* - z_{\max}`
    for ``n <= 3`` (:func:`stability_threshold` gives the corresponding smallest :math:`hp_1`).
    """

    discretizations = MAPPINGS
    lead = 1

    @check_keywords
    def __init__(
        self,
        n: int = DEFAULT_N,
        dt: float = 1e-3,
        p1=None,
        mu: float = 1.0,
        mapping: str | None = None,
        *,
        gamma: Sequence[Callable | None] | None = None,
        L_gamma=None,
        discretization: str | None = None,
        wrap=None,
    ):
        n = check_int_in_range("n", n, 2, MAX_N)
        if mapping is not None and discretization is not None:
            raise TypeError(
                f"expected mapping or its alias discretization, not both, actual value: mapping={mapping!r}, "
                f"discretization={discretization!r}"
            )
        if mapping is not None:  # checked under its own name (the base class says "discretization")
            check_choice("mapping", mapping, MAPPINGS)
        super().__init__(dt, n - 1, discretization if mapping is None else mapping, wrap)
        self.n = n
        self.mapping = self.discretization
        if p1 is None:
            raise ValueError(
                "expected p1 > 0, the rate of the eigenvalue mapping (calibrated when the observer is built by "
                "name), actual value: None"
            )
        check_positive_array("p1", p1)  # validate now, not at reset
        self.p1 = p1
        self.mu = check_nonnegative("mu", mu)
        if gamma is not None:
            if isinstance(gamma, (str, bytes)) or not hasattr(gamma, "__iter__"):
                raise TypeError(
                    f"expected gamma to be a sequence of {self.n} callables or None, actual value: {gamma!r}"
                )
            gamma = list(gamma)
            if len(gamma) != self.n:
                raise ValueError(
                    f"expected gamma with {self.n} entries (callables or None), actual value: {len(gamma)} entries"
                )
            for i, g in enumerate(gamma):
                if g is not None and not callable(g):
                    raise TypeError(f"expected gamma[{i}] callable or None, actual value: {g!r}")
            if L_gamma is None:
                raise ValueError("expected L_gamma (saturation levels) with gamma, actual value: None")
        if L_gamma is not None:
            L_gamma = as_real_array("L_gamma", L_gamma)
            if L_gamma.shape != (self.n,) or np.any(np.isnan(L_gamma)) or np.any(L_gamma[1:] < 0):
                raise ValueError(
                    f"expected L_gamma of shape ({self.n},) with entries >= 0 (inf allowed), actual value: {L_gamma!r}"
                )
        self.gamma, self.L_gamma = gamma, L_gamma
        with np.errstate(all="ignore"):  # an overflow is reported below
            self.A = taylor_matrix(self.n, self.dt)
            self.B = input_matrix(self.n, self.dt)
            try:
                self._V = eigenvalue_mapping_vectors(self.n, self.dt)  # (n + 1, n)
            except np.linalg.LinAlgError:  # dt^(n-1) underflows: a singular observability matrix
                self._V = np.full((self.n + 1, self.n), np.nan)
        if not (np.isfinite(self.A).all() and np.isfinite(self.B).all() and np.isfinite(self._V).all()):
            raise ValueError(
                f"expected dt giving finite matrices (31), (32) and (35) (dt^n representable), actual "
                f"value: {self.dt!r}"
            )

    # ---- the step ---------------------------------------------------------------------------------------------
    @property
    def _kernel(self):
        # the registered compiled step; with model terms the Python step around it (no fused or compiled offline
        # driver runs a Python callable: fusable() is false and Observer.step calls it as it is)
        return _kernels.eigmap_kernel if self.gamma is None else self._model_step

    def _predicts(self) -> bool:
        return True

    def _channel_params(self, shape):
        p1 = self._per_channel("p1", self.p1, shape)
        return _pack_eigmap(self.dt, p1, self.mu, self.discretization, self.n, predictor=True)

    def _model_step(self, state, y, params, new_state, out, u=None) -> int:
        r"""(33) with the model terms, in the calling convention of the batch kernels (``y`` flat ``(N,)``,
        ``out`` ``(N, n)``) plus the input ``u``; returns their status.

        (33) is linear in the model terms: the compiled step writes
        :math:`\mathbf A\hat\xi_k + \tilde{\mathbf l}(z_n(\sigma_{1,k}))\sigma_{1,k}` (and rejects a non-finite
        ``y``), then :math:`\mathbf B` times :meth:`model_terms` is added here.
        """
        status = _kernels.eigmap_kernel(state, y, params, new_state, out)
        if status != -1:
            return status
        n = self.n
        xi = state[:, :n].reshape(self._shape + (n,)).copy()
        xi[..., 0] = y.reshape(self._shape)  # gamma_i sees the measured xi_1 and the estimates of the others
        terms = self.model_terms(xi, u).reshape(-1, n)
        with np.errstate(all="ignore"):  # an overflow is reported by the status below, the state kept
            new_state[:, :n] += terms @ self.B.T
        out[:, :] = new_state[:, :n]  # the predictor, as the compiled step reports it here
        return _kernels._check_state(new_state, out)

    # ---- pure maths -------------------------------------------------------------------------------------------
    def gain(self, z) -> np.ndarray:
        r""":math:`\tilde{\mathbf l}(z)` of (35) for an array ``z``; shape ``z.shape + (n,)`` (Horner in ``-z``).

        For analysis (the step evaluates the same polynomial compiled, per sample)."""
        z = as_real_array("z", z)
        if not np.isfinite(z).all():
            raise ValueError(f"expected finite eigenvalues z, actual value: {z!r}")
        with np.errstate(over="ignore", invalid="ignore"):
            z = z[..., None]
            out = np.zeros(z.shape[:-1] + (self.n,))
            for j in range(self.n + 1):
                out = out * (-z) + self._V[j]
        if not np.isfinite(out).all():
            raise ValueError(f"expected eigenvalues z with a finite gain (|z| near 1 or below), actual value: {z!r}")
        return out

    @check_keywords
    def stability_margin(self, p1: float | None = None) -> float | None:
        """:math:`z^* - z_{\\max}` of section 5 (positive: inside the proven region), ``None`` for ``n > 3``."""
        if self.n > 3:
            return None
        p = float(np.min(check_positive_array("p1", self.p1 if p1 is None else p1)))
        return _paper_eigenvalue_bound(self.n) - max_eigenvalue(self.n, self.dt, p, self.mu, self.mapping)

    def model_terms(self, xi: np.ndarray, u) -> np.ndarray:
        r"""The vector multiplying :math:`\mathbf B` in (33): :math:`\gamma_1`, then the saturated
        :math:`\hat\gamma_i`."""
        out = np.zeros(xi.shape)
        if self.gamma is None:
            return out
        for i, g in enumerate(self.gamma):
            if g is None:
                continue
            val = as_real_array(f"gamma[{i}](xi, u)", g(xi, u))
            try:
                val = np.broadcast_to(val, xi.shape[:-1])
            except ValueError:
                raise ValueError(
                    f"expected gamma[{i}] to return shape {xi.shape[:-1]}, actual value: {val.shape}"
                ) from None
            if not np.isfinite(val).all():
                bad = tuple(int(j) for j in np.argwhere(~np.isfinite(val))[0])
                raise ValueError(
                    f"expected gamma[{i}] to return finite values, actual value: {val[bad]!r} at channel {bad[-1]}"
                )
            if i > 0:
                val = np.clip(val, -self.L_gamma[i], self.L_gamma[i])
            out[..., i] = val
        return out

    # ---- updates ----------------------------------------------------------------------------------------------
    def update(self, y, u=None) -> np.ndarray:
        r"""Process :math:`y_k` (and :math:`u_k`); returns the predictor :math:`\hat\xi_{k+1}`.

        Shape ``(..., n_channels, n)``. ``u`` is passed to the model terms (checked real and finite; unused
        without them). Raises ``RuntimeError`` before ``reset``, ``ValueError`` on a wrong shape or a non-finite
        sample or model term (state unchanged), ``DivergenceError`` if the new state is not finite (state
        unchanged).
        """
        u = checked_input(u)
        if self.gamma is None:
            return super().update(y)
        state = self._state
        if state is None:
            raise RuntimeError("expected reset(y0) before update(y), actual value: the observer was never reset")
        y = np.ascontiguousarray(self._as_measurement(y, "y"))
        if y.shape != self._shape:
            raise ValueError(f"expected y with shape {self._shape}, actual value: {y.shape}")
        measured = y.reshape(-1)
        flat = measured
        if self._period is not None:
            flat = np.empty_like(measured)
            _kernels.unwrap_measurement(measured, state, self._period, flat)
        new_state = np.empty_like(state)
        out = np.empty((flat.shape[0], self.n))
        status = self._model_step(state, flat, self._params, new_state, out, u)
        if status != -1:
            self._raise_status(status, y)
        self._state = new_state
        self._estimate = out.reshape(self._shape + (self.n,))
        self.n_updates += 1
        return self._estimate.copy()

    @check_keywords
    def run(self, Y, U=None, *, out: np.ndarray | None = None) -> np.ndarray:
        """Process ``Y`` of shape ``(T, ..., n_channels)`` (and the inputs ``U`` with leading ``T``); returns
        ``(T, ..., n)``, written into ``out`` if given (as :meth:`Observer.run`).

        All or nothing: if a sample is rejected, the observer keeps the state it had before the call. Without model
        terms the compiled offline driver runs (``U`` is checked and unused); with them, :meth:`update` in a loop.
        """
        if self._state is None:
            raise RuntimeError("expected reset(y0) before run(Y), actual value: the observer was never reset")
        Y = as_real_array("Y", Y)
        if U is not None:
            U = as_real_array("U", U)
            if U.ndim == 0 or Y.ndim == 0 or U.shape[0] != Y.shape[0]:
                raise ValueError(
                    f"expected U with one row per sample of Y (shape {Y.shape}), actual value: shape {U.shape}"
                )
            checked_input(U)
        if self.gamma is None:
            return super().run(Y, out=out)
        if Y.ndim == 0 or Y.shape[1:] != self._shape:
            raise ValueError(f"expected Y with shape (T, *{self._shape}), actual value: {Y.shape}")
        result = self._output_array(out, (Y.shape[0],) + self._estimate.shape, Y)
        saved = (self._state, self._estimate, self.n_updates)
        try:
            for t in range(Y.shape[0]):
                result[t] = self.update(Y[t], None if U is None else U[t])
        except BaseException:
            self._state, self._estimate, self.n_updates = saved
            raise
        return result

    # ---- diagnostics ------------------------------------------------------------------------------------------
    @property
    def eigenvalue(self) -> np.ndarray:
        r""":math:`z_n(\sigma_{1,k})` of the last update, shape ``(..., n_channels)`` (0 after a reset): (15) or
        (16) at :attr:`output_error`, evaluated by :func:`eigenvalue_mapping`."""
        sigma = self.output_error
        p1 = self._params[:, 1].reshape(self._shape)
        return eigenvalue_mapping(sigma, self.dt, p1, self.mu, self.n, self.mapping)

    def __repr__(self) -> str:
        wrap = "" if self.wrap is None else f", wrap={self.wrap!r}"
        return (
            f"DiscreteTimeHOSM(n={self.n}, dt={self.dt}, p1={self.p1!r}, mu={self.mu}, "
            f"mapping={self.mapping!r}, model={'yes' if self.gamma else 'no'}{wrap})"
        )
