r"""Switched-gain high-gain differentiator with fixed-time convergence (Efimov et al. 2017).

The observer (4) of Efimov, Polyakov, Levant and Perruquetti for the canonical form (2), model-free
(:math:`\varphi = g = 0`, an integrator chain, so it differentiates a measured signal):

.. math::
    \dot{\hat x} = A\hat x + \mu_i M_i^{-1} l\,(y - c^T M_i \hat x),\qquad
    M_i = \mathrm{diag}(\mu_i^{1-k})_{k=1}^n,\quad t\in[t_i, t_{i+1}),

i.e. a high-gain observer with gain vector :math:`(\mu_i l_1, \mu_i^2 l_2, \ldots, \mu_i^n l_n)` whose high gain
:math:`\mu_i` is switched by a supervisor:

* dwell times (7): :math:`t_{i+1} = t_i + T_i`,
  :math:`T_i = -\frac{2}{\kappa\mu_i}\ln\bigl(\sqrt{\lambda_{\min}(P)/\lambda_{\max}(P)}\,\mu_i^{1-n}/q\bigr)`;
* gains (8)/(9): :math:`\mu_{i+1} = q^\alpha\mu_i` (``mu0 = 1`` is (8), ``mu0 > 1`` is (9));
* noise-aware stop (Section 5.2): the acceleration stops at the first ``i*`` with
  :math:`\mu_{i^*+1} \ge \mu_{\max}` or :math:`T_{i^*+1} \le T_{\min}`; at :math:`t_{i^*+1}` the gain is reset to
  :math:`\mu_{\min}` (Remark 9), the value minimising the asymptotic error bound
  :math:`r(\mu) = (\rho_d\mu^{-1}D + \mu^{n-1}\rho_v V)/\sqrt{\kappa\lambda_{\min}(P)}`;
* optional re-acceleration (end of Section 5.2): once settled, if the output prediction error exceeds
  ``restart_threshold`` the schedule restarts from ``mu0``.

Every channel has its own supervisor (its own ``i``, ``mu_i`` and clock).

Discretization
--------------
``"implicit"`` (only choice): the implicit Euler step (11) solved with Sherman-Morrison,

.. math::
    \hat x_k = O_{\mu}^{-1}\bigl(\hat x_{k-1} + h\mu M^{-1} l\,y_k\bigr),\quad
    O_\mu = I - hA + h\mu M^{-1} l c^T,\quad
    O_\mu^{-1} = S - \frac{S g c^T S}{1 + c^T S g},\ S = (I - hA)^{-1},\ g = h\mu M^{-1} l.

:math:`S` is the upper-triangular matrix :math:`S_{ij} = h^{j-i}` (``j >= i``), applied by back substitution, so a
step costs :math:`O(n)`. The step is stable for every :math:`\mu h` (the implicit Euler map of a Hurwitz matrix).
Sample timing. The paper writes (11) with :math:`y(h\ell)` in place of :math:`y(h(\ell+1))` "to ensure
causality": its estimate at :math:`t_{\ell+1}` uses samples up to :math:`t_\ell`, a one-sample delay. Here
``update(y_k)`` returns the estimate at :math:`t_k` from samples up to :math:`t_k` (the implicit Euler step
without that delay); the paper's recursion is ``update(y_{k-1})``, i.e. the same observer fed the samples one step
late (``scripts/reproduce_efimov2017.py`` does so to reproduce Section 6: the delay changes the peak errors there
by up to 8 %). In both, the gain used over :math:`[t_k, t_{k+1}]` is the one in force at :math:`t_k`, and the
supervisor's clock advances by ``h`` per sample.

References
----------
.. [EPLP17] D. Efimov, A. Polyakov, A. Levant and W. Perruquetti, "Switched gain differentiator with fixed-time
   convergence", Proc. 20th IFAC World Congress, Toulouse, 2017.
.. [AK09] J. H. Ahrens and H. K. Khalil, "High-gain observers in the presence of measurement noise: a
   switched-gain approach", Automatica 45(4), 2009.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .._validation import (
    as_real_array,
    check_bool,
    check_int_in_range,
    check_keywords,
    check_positive,
    check_real_in_range,
)
from . import _kernels
from .base import Observer
from .registry import register_observer


def _disturbance_rule(cls, calibration, order, kwargs):
    """``disturbance`` = the largest calibrated bound, ``noise`` = the noise level (unless given)."""
    kw = dict(kwargs)
    kw.setdefault("disturbance", float(np.max(calibration.bound(order))))
    kw.setdefault("noise", calibration.noise_level)
    return cls(dt=calibration.dt, **kw)


__all__ = [
    "SwitchedGain",
    "convergence_time_bound",
    "dwell_time",
    "noise_optimal_gains",
    "switching_schedule",
]

CACHE = True

# state row: [xhat (m), innovation, elapsed, mu, T_i, phase, i]
# params row: [dt, kappa, s, q**alpha, mu0, mu_max, T_min, mu_reset, restart, supervise, l (m), q]
_P_DT, _P_KAPPA, _P_S, _P_RATIO, _P_MU0, _P_MUMAX, _P_TMIN, _P_MURESET, _P_RESTART, _P_SUPERVISE = range(10)
_P_L = 10


# ----------------------------------------------------------------------------------------------------------------
# pure maths
# ----------------------------------------------------------------------------------------------------------------
def dwell_time(mu, n: int, kappa: float, eig_ratio: float, q: float):
    r"""Dwell time (7): :math:`T(\mu) = -\frac{2}{\kappa\mu}\ln\bigl(s\,\mu^{1-n}/q\bigr)`,
    :math:`s = \sqrt{\lambda_{\min}(P)/\lambda_{\max}(P)}` (``eig_ratio``).

    It is the time after which the bound of Corollary 5, :math:`\mu^{n-1} s^{-1} e^{-\kappa\mu T/2}`, equals
    :math:`1/q`: the estimation error has contracted by ``q`` before the gain is raised.

    Notes
    -----
    The printed (7) draws the square root over :math:`s^2\mu^{1-n}/q`; the derivation from Corollary 5 and the
    convergence-time bound :math:`\bar T_0` of Theorem 6 (which is the sum of these :math:`T_i`, and which the
    paper evaluates to 9.11 in Section 6) both put it over the eigenvalue ratio only. We implement the latter.
    """
    mu = np.asarray(mu, dtype=float)
    return -2.0 / (kappa * mu) * np.log(eig_ratio * mu ** (1.0 - n) / q)


@njit(cache=CACHE)
def _dwell(mu, n, kappa, s, q):
    return -2.0 / (kappa * mu) * math.log(s * mu ** (1.0 - n) / q)


def convergence_time_bound(n: int, kappa: float, eig_ratio: float, q: float, alpha: float) -> float:
    r"""Fixed-time bound of Theorem 6 (``mu0 = 1``):

    .. math:: \bar T_0 = -\frac{2}{\kappa}\frac{q^\alpha}{q^\alpha - 1}
              \ln\Bigl(s\, q^{\frac{\alpha(1-n)}{q^\alpha-1} - 1}\Bigr) = \sum_{i\ge 0} T(q^{\alpha i}).
    """
    qa = q**alpha
    return float(-2.0 / kappa * qa / (qa - 1.0) * np.log(eig_ratio * q ** (alpha * (1 - n) / (qa - 1.0) - 1.0)))


def noise_optimal_gains(
    n: int, rho_d: float, rho_v: float, disturbance: float, noise: float, mu_ref: float = 1.0
) -> tuple[float, float]:
    r"""``(mu_min, mu_max)`` of Section 5.2 for the bounds ``D`` (``disturbance``) and ``V`` (``noise``).

    .. math::
        r(\mu) \propto \rho_d D\mu^{-1} + \rho_v V\mu^{n-1},\qquad
        \mu_{\min} = \Bigl(\frac{1}{n-1}\frac{\rho_d D}{\rho_v V}\Bigr)^{1/n},\qquad
        r(\mu_{\max}) = r(\mu_{\mathrm{ref}}),\ \mu_{\max} > \mu_{\min}.

    ``mu_ref`` is the gain whose asymptotic accuracy must not be degraded (``1`` in the paper, :math:`\mu_0` of
    (8)). For ``n = 2`` and ``mu_ref = 1``: :math:`\mu_{\min} = \sqrt{\rho_d D/(\rho_v V)}`,
    :math:`\mu_{\max} = \rho_d D/(\rho_v V)`.

    Raises
    ------
    ValueError
        If condition (10), :math:`\rho_d D > (n-1)\rho_v V`, fails (then :math:`\mu_{\min} \le 1`), or if
        ``mu_ref >= mu_min`` (no larger root).
    """
    n = check_int_in_range("n", n, 2, 10)
    a = check_positive("rho_d", rho_d) * check_positive("disturbance", disturbance)
    b = check_positive("rho_v", rho_v) * check_positive("noise", noise)
    mu_ref = check_positive("mu_ref", mu_ref)
    if not a > (n - 1) * b:
        raise ValueError(
            f"expected rho_d*D > (n-1)*rho_v*V (condition (10) of Efimov et al. 2017), "
            f"actual value: {a} <= {(n - 1) * b}"
        )
    mu_min = (a / ((n - 1) * b)) ** (1.0 / n)
    if mu_ref >= mu_min:
        raise ValueError(f"expected mu_ref < mu_min = {mu_min}, actual value: {mu_ref}")

    def r(mu):
        return a / mu + b * mu ** (n - 1)

    target = r(mu_ref)
    hi = mu_min * 2.0
    while r(hi) < target and np.isfinite(hi):
        hi *= 2.0
    from scipy.optimize import brentq  # lazy: scipy.optimize costs ~0.4 s of `import smo_gym`

    try:
        mu_max = brentq(lambda mu: r(mu) - target, mu_min, hi, xtol=1e-12, rtol=1e-14)
    except ValueError:  # r at the ends has no sign change left in floating point: the bounds' ratio is extreme
        raise ValueError(
            f"expected disturbance and noise bounds whose gains are floats, actual value: rho_d*D = {a!r}, "
            f"rho_v*V = {b!r} (mu_min = {mu_min!r})"
        ) from None
    return float(mu_min), float(mu_max)


def switching_schedule(
    n: int,
    kappa: float,
    eig_ratio: float,
    q: float = 2.0,
    alpha: float = 1.0,
    mu0: float = 1.0,
    mu_max: float = np.inf,
    T_min: float = 0.0,
    mu_reset: float | None = None,
    max_switches: int = 200,
) -> list[tuple[float, float]]:
    r"""Planned continuous-time schedule ``[(t_i, mu_i), ...]`` of (7), (9) with the stop of Section 5.2.

    The last entry is the reset :math:`(t_{i^*+1}, \mu_{\mathrm{reset}})` (Remark 9); omitted when
    ``mu_reset`` is None and the schedule simply stops at :math:`\mu_{i^*}`. ``i*`` is ``len(result) - 2`` with a
    reset. The sampled observer switches at the first sample at or after each :math:`t_i`.
    """
    ratio = q**alpha
    out = [(0.0, float(mu0))]
    t, mu = 0.0, float(mu0)
    for _ in range(max_switches):
        T = float(dwell_time(mu, n, kappa, eig_ratio, q))
        t += T
        mu_next = mu * ratio
        if mu_next >= mu_max or float(dwell_time(mu_next, n, kappa, eig_ratio, q)) <= T_min:
            if mu_reset is not None:
                out.append((t, float(mu_reset)))
            return out
        mu = mu_next
        out.append((t, mu))
    return out


# ----------------------------------------------------------------------------------------------------------------
# compiled recursion
# ----------------------------------------------------------------------------------------------------------------
@njit(cache=CACHE)
def switched_gain_channel_step(x, y, params, m, x_new, out_row):
    r"""One implicit Euler step (11) at the current gain, then the supervisor (7)-(9), Section 5.2, Remark 9.

    ``x`` is the state row ``[xhat (m), innovation, elapsed, mu, T_i, phase, i]``; ``phase`` is 0 while
    accelerating and 1 once settled (stopped and reset, or fixed gain). Returns the prior output error
    :math:`y_k - (\hat x_{1,k-1} + h\hat x_{2,k-1})`.
    """
    h = params[_P_DT]
    mu = x[m + 2]
    # gain g = h mu M^{-1} l = h (mu l_1, mu^2 l_2, ..., mu^n l_n)
    # v = S (xhat + g y), u = S g with S = (I - hA)^{-1}: back substitution v_i = w_i + h v_{i+1}
    v_next = 0.0
    u_next = 0.0
    for i in range(m - 1, -1, -1):
        gi = h * params[_P_L + i] * mu ** (i + 1)
        v_next = x[i] + gi * y + h * v_next
        u_next = gi + h * u_next
        x_new[i] = v_next  # v_i for now
        out_row[i] = u_next  # u_i for now
    # Sherman-Morrison: xhat = v - u (c^T v) / (1 + c^T u)
    coef = x_new[0] / (1.0 + out_row[0])
    for i in range(m):
        x_new[i] = x_new[i] - out_row[i] * coef
        out_row[i] = x_new[i]
    innovation = y - x[0] - h * x[1]
    # ---- supervisor ----------------------------------------------------------------------------------------
    elapsed = x[m + 1] + h
    T = x[m + 3]
    phase = x[m + 4]
    count = x[m + 5]
    if params[_P_SUPERVISE] != 0.0:
        n = float(m)
        kappa = params[_P_KAPPA]
        s = params[_P_S]
        ratio = params[_P_RATIO]  # q**alpha of (9)
        q = params[_P_L + m]  # q of (7)
        if phase == 0.0:
            # switch at the first sample at or after t_{i+1} = t_i + T_i (a relative tolerance absorbs rounding)
            while elapsed >= T - 1e-9 * h:
                elapsed -= T
                count += 1.0
                mu_next = mu * ratio
                T_next = _dwell(mu_next, n, kappa, s, q)
                if mu_next >= params[_P_MUMAX] or T_next <= params[_P_TMIN]:
                    phase = 1.0  # stop (Section 5.2) and reset (Remark 9)
                    mu = params[_P_MURESET]
                    T = 0.0  # no dwell once settled (the state must stay finite)
                    elapsed = 0.0
                    break
                mu = mu_next
                T = T_next
        elif abs(innovation) > params[_P_RESTART]:
            # re-acceleration: the measured part of the error grew, restart the schedule (end of Section 5.2),
            # unless mu0 itself already violates the stop conditions (as at reset)
            T0 = _dwell(params[_P_MU0], n, kappa, s, q)
            if params[_P_MU0] < params[_P_MUMAX] and params[_P_TMIN] < T0:
                phase = 0.0
                mu = params[_P_MU0]
                T = T0
                elapsed = 0.0
                count = 0.0
    x_new[m + 1] = elapsed
    x_new[m + 2] = mu
    x_new[m + 3] = T
    x_new[m + 4] = phase
    x_new[m + 5] = count
    return innovation


@njit(cache=CACHE)
def switched_gain_rows(state, y, params, new_state, out, shared):
    """:func:`switched_gain_channel_step` on every channel (``shared``: one parameter row for every channel)."""
    m = out.shape[1]
    for c in range(y.shape[0]):
        pc = 0 if shared else c  # the parameter row of channel c
        new_state[c, m] = switched_gain_channel_step(state[c], y[c], params[pc], m, new_state[c], out[c])
    return _kernels._check_state(new_state, out)


# the channel step links _kernels' functions: its cache goes with the row kernel's when those change
switched_gain = _kernels.register_step(switched_gain_rows, helpers=(switched_gain_channel_step,))
switched_gain_kernel = switched_gain.kernel


# ----------------------------------------------------------------------------------------------------------------
# class
# ----------------------------------------------------------------------------------------------------------------
@register_observer(
    "switched-gain",
    steps=(switched_gain_rows,),
    calibrate=_disturbance_rule,
    given=(("disturbance", "noise"),),
    examples=(dict(order=1, mu0=20.0, supervise=False, gain=[2.0, 1.0]), dict(order=2, disturbance=5.0, noise=1e-4)),
)
class SwitchedGain(Observer):
    r"""Switched-gain differentiator of Efimov et al. 2017: observer (4) with the supervisor (7)-(9) and Remark 9.

    Parameters
    ----------
    dt : float
        Sampling step ``h``.
    order : int
        Derivatives estimated; the canonical form has ``n = order + 1`` states (``1 <= order <= 9``).
    gain : array_like, shape (order + 1,), optional
        The vector ``l`` of Assumption 1. Default: :func:`smo_gym.design.switched_gain_lmi` with
        ``kappa, rho_d, rho_v`` (maximising :math:`\lambda_{\min}(P)`).
    P : array_like, shape (order + 1, order + 1), optional
        Its Lyapunov matrix; required with ``gain`` when ``supervise`` (the dwell times use its eigenvalues).
    kappa, rho_d, rho_v : float
        The LMI specification (Assumption 1, Remark 2); ``kappa`` also enters the dwell times (7).
    q, alpha : float
        Tuning of (7)-(9): :math:`q > 1`, :math:`0 < \alpha \le 1/(n-1)` (Theorem 6); default ``q = 2``,
        ``alpha = 1/(n-1)`` (``alpha = 1`` for ``order = 1``, as in Section 6).
    mu0 : float, optional
        Initial gain :math:`\mu_0 \ge 1` ((8) for 1, (9) above 1). With ``supervise=False`` the fixed gain.
        Default: :math:`\mu_{\min}` when ``disturbance`` and ``noise`` are given (Section 6 starts at
        :math:`\mu_0 = 10 \approx \mu_{\min} = 10.42`: start at the asymptotically best gain, accelerate, come
        back), else 1.
    disturbance, noise : float, optional
        Bounds ``D`` on :math:`|f^{(n)}|` and ``V`` on the noise; when both are given, ``mu_min`` and ``mu_max`` of
        Section 5.2 are computed (:func:`noise_optimal_gains`) unless given explicitly.
    mu_max : float, optional
        Stop accelerating before the gain would reach it (default: computed, else no bound).
    mu_min : float, optional
        Gain after the stop (Remark 9; default: computed, else ``mu0``).
    T_min : float, optional
        Stop when the next dwell time would be ``<= T_min`` (default ``3 * dt``, as in Section 6).
    supervise : bool, default True
        ``False``: observer (4) with the fixed gain ``mu0`` (the comparison of Section 6).
    restart_threshold : float, optional
        Once settled, restart the schedule when :math:`|y_k - \hat x_{1,k-1} - h\hat x_{2,k-1}|` exceeds it.
    discretization : {"implicit"}
    wrap : bool or array_like of bool, optional
        Channels measured as angles modulo ``2 pi`` (see :class:`~smo_gym.observers.Observer`).

    Attributes
    ----------
    gain : ndarray, shape (n,)
        ``l``.
    certificate : SwitchedGainCertificate or None
        The LMI certificate when the gain was designed here.
    mu : ndarray, shape (..., n_channels)
        The current gain of every channel.
    switch_count : ndarray of int, shape (..., n_channels)
        Switches since the (last) start of the schedule.
    settled : ndarray of bool, shape (..., n_channels)
        Whether the channel has stopped accelerating.

    Examples
    --------
    >>> import numpy as np
    >>> from smo_gym.observers import SwitchedGain
    >>> obs = SwitchedGain(dt=1e-3, order=1, mu0=10.0, disturbance=1 + np.pi**2, noise=0.1)
    >>> round(obs.mu_min, 2), round(obs.mu_max, 2)
    (10.43, 108.7)
    """

    discretizations = ("implicit",)

    @check_keywords
    def __init__(
        self,
        dt: float,
        order: int = 1,
        *,
        gain=None,
        P=None,
        kappa: float = 1.0,
        rho_d: float = 1.0,
        rho_v: float = 1.0,
        q: float = 2.0,
        alpha: float | None = None,
        mu0: float | None = None,
        disturbance: float | None = None,
        noise: float | None = None,
        mu_max: float | None = None,
        mu_min: float | None = None,
        T_min: float | None = None,
        supervise: bool = True,
        restart_threshold: float | None = None,
        discretization: str | None = None,
        wrap=None,
    ):
        order = check_int_in_range("order", order, 1, 9)
        super().__init__(dt, order, discretization, wrap)
        n = order + 1
        self.kappa = check_positive("kappa", kappa)
        # weights of the LMI's disturbance and noise rows, which square them: their squares must be floats
        self.rho_d = check_real_in_range("rho_d", rho_d, 0.0, 1e150, low_open=True)
        self.rho_v = check_real_in_range("rho_v", rho_v, 0.0, 1e150, low_open=True)
        self.q = check_positive("q", q)
        if self.q <= 1.0:
            raise ValueError(f"expected q > 1, actual value: {q!r}")
        self.alpha = 1.0 / (n - 1) if alpha is None else check_positive("alpha", alpha)
        if self.alpha > 1.0 / (n - 1) + 1e-12:
            raise ValueError(
                f"expected 0 < alpha <= 1/(n-1) = {1.0 / (n - 1):.6g} (Theorem 6), actual value: {alpha!r}"
            )
        if mu0 is not None:
            check_positive("mu0", mu0)
            if mu0 < 1.0:
                raise ValueError(f"expected mu0 >= 1, actual value: {mu0!r}")
        self.supervise = check_bool("supervise", supervise)
        self.certificate = None
        if gain is None:
            if P is not None:
                raise ValueError("expected P only together with gain, actual value: P given without gain")
            from ..design.lmi import switched_gain_lmi

            l, P, self.certificate = switched_gain_lmi(n, self.kappa, self.rho_d, self.rho_v)
        else:
            l = as_real_array("gain", gain)
            if l.shape != (n,) or not np.all(np.isfinite(l)):
                raise ValueError(f"expected gain with shape ({n},) and finite entries, actual value: {gain!r}")
            if np.any(np.linalg.eigvals(np.eye(n, k=1) - np.outer(l, np.eye(n)[0])).real >= 0):
                raise ValueError(f"expected a gain l with A - l c^T Hurwitz, actual value: {l}")
            if P is None and self.supervise:
                raise ValueError("expected P (the Lyapunov matrix of the gain) when supervise=True, actual value: None")
        self.gain = np.asarray(l, dtype=float)
        if P is not None:
            P = as_real_array("P", P)
            if P.shape != (n, n) or not np.all(np.isfinite(P)):
                raise ValueError(f"expected P with shape ({n}, {n}) and finite entries, actual value: {P!r}")
            eig = np.linalg.eigvalsh(0.5 * (P + P.T))
            if eig[0] <= 0:
                raise ValueError(f"expected P > 0, actual value: eigenvalues {eig}")
            self.P = P
            self.eig_ratio = float(np.sqrt(eig[0] / eig[-1]))
        else:
            self.P = None
            self.eig_ratio = 1.0
        self.disturbance = None if disturbance is None else check_positive("disturbance", disturbance)
        self.noise = None if noise is None else check_positive("noise", noise)
        computed = (None, None)
        if self.disturbance is not None and self.noise is not None:
            computed = noise_optimal_gains(n, self.rho_d, self.rho_v, self.disturbance, self.noise)
        elif (disturbance is None) != (noise is None):
            raise ValueError("expected both disturbance and noise, or neither, actual value: only one given")
        self.mu0 = check_positive("mu0", mu0) if mu0 is not None else computed[0] if computed[0] is not None else 1.0
        self.mu_min = (
            check_positive("mu_min", mu_min)
            if mu_min is not None
            else computed[0]
            if computed[0] is not None
            else self.mu0
        )
        self.mu_max = (
            check_positive("mu_max", mu_max)
            if mu_max is not None
            else computed[1]
            if computed[1] is not None
            else np.inf
        )
        if not self.mu_min <= self.mu_max or not self.mu0 <= self.mu_max:  # the schedule would climb past mu_max
            raise ValueError(
                f"expected mu_min and mu0 <= mu_max, actual value: mu_min={self.mu_min!r}, mu0={self.mu0!r}, "
                f"mu_max={self.mu_max!r}"
            )
        self.T_min = 3.0 * self.dt if T_min is None else check_positive("T_min", T_min)
        self.restart_threshold = (
            np.inf if restart_threshold is None else check_positive("restart_threshold", restart_threshold)
        )

    # ---- schedule helpers -------------------------------------------------------------------------------------
    def schedule(self) -> list[tuple[float, float]]:
        """The planned continuous-time schedule ``[(t_i, mu_i), ...]`` (see :func:`switching_schedule`)."""
        if not self.supervise:
            return [(0.0, self.mu0)]
        return switching_schedule(
            self.order + 1,
            self.kappa,
            self.eig_ratio,
            self.q,
            self.alpha,
            self.mu0,
            self.mu_max,
            self.T_min,
            self.mu_min,
        )

    def convergence_time_bound(self) -> float:
        r""":math:`\bar T_0` of Theorem 6 for these ``kappa, P, q, alpha`` (the bound assumes ``mu0 = 1``)."""
        return convergence_time_bound(self.order + 1, self.kappa, self.eig_ratio, self.q, self.alpha)

    # ---- Observer plumbing ------------------------------------------------------------------------------------
    @property
    def _kernel(self):
        return switched_gain_kernel

    def _state_width(self) -> int:
        return self.order + 7

    def _channel_params(self, shape):
        m = self.order + 1
        row = np.empty(_P_L + m + 1)
        row[_P_DT] = self.dt
        row[_P_KAPPA] = self.kappa
        row[_P_S] = self.eig_ratio
        row[_P_RATIO] = self.q**self.alpha
        row[_P_MU0] = self.mu0
        row[_P_MUMAX] = self.mu_max
        row[_P_TMIN] = self.T_min
        row[_P_MURESET] = self.mu_min
        row[_P_RESTART] = self.restart_threshold
        row[_P_SUPERVISE] = 1.0 if self.supervise else 0.0
        row[_P_L : _P_L + m] = self.gain
        row[_P_L + m] = self.q
        return np.broadcast_to(row, (int(np.prod(shape)), row.size)).copy()

    def _initial_state(self, y0, params):
        m = self.order + 1
        state = np.zeros((y0.shape[0], self._state_width()))
        state[:, 0] = y0
        mu = self.mu0
        T = float(dwell_time(mu, m, self.kappa, self.eig_ratio, self.q)) if self.supervise else 0.0
        phase = 0.0 if self.supervise else 1.0
        if self.supervise and (mu >= self.mu_max or self.T_min >= T):
            mu, T, phase = self.mu_min, 0.0, 1.0
        state[:, m + 2] = mu
        state[:, m + 3] = T
        state[:, m + 4] = phase
        return state

    # ---- diagnostics ------------------------------------------------------------------------------------------
    def _column(self, j: int) -> np.ndarray:
        self._require_reset()
        return self._state[:, self.order + 1 + j].reshape(self._shape)

    @property
    def mu(self) -> np.ndarray:
        """Current gain ``mu_i`` of every channel, shape ``(..., n_channels)``."""
        return self._column(2).copy()

    @property
    def switch_count(self) -> np.ndarray:
        """Switches since the start of the schedule, shape ``(..., n_channels)``."""
        return self._column(5).astype(int)

    @property
    def settled(self) -> np.ndarray:
        """Whether each channel has stopped accelerating (or never accelerates), shape ``(..., n_channels)``."""
        return self._column(4) != 0.0

    def __repr__(self) -> str:
        return (
            f"SwitchedGain(dt={self.dt}, order={self.order}, mu0={self.mu0}, q={self.q}, alpha={self.alpha}, "
            f"mu_min={self.mu_min:.4g}, mu_max={self.mu_max:.4g}, supervise={self.supervise})"
        )
