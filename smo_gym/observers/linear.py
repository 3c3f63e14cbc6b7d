r"""Linear estimators: the high-gain observer, and the baselines a user would otherwise pick.

References
----------
.. [AMPT18] D. Astolfi, L. Marconi, L. Praly and A. R. Teel, "Low-power peaking-free high-gain observers",
   Automatica 98, 2018, eq. (2).
.. [BSL01] Y. Bar-Shalom, X. R. Li and T. Kirubarajan, *Estimation with Applications to Tracking and
   Navigation*, Wiley 2001, section 6.2.3 (continuous white-noise jerk model).
.. [Lju99] L. Ljung, *System Identification: Theory for the User*, 2nd ed., Prentice Hall 1999, chapter 7
   (prediction-error methods).
"""

from __future__ import annotations

import math
import sys
from typing import NamedTuple

import numpy as np

from .._validation import (
    as_real_array,
    check_int_in_range,
    check_keywords,
    check_positive,
    check_positive_array,
    check_positive_parameter,
)
from ..design.gains import binomial_coefficients
from . import _kernels
from .base import Observer
from .registry import register_observer


def _high_gain_rule(cls, calibration, order, kwargs):
    r""":meth:`HighGain.from_bounds` per channel, :math:`\ell = (L/\epsilon)^{1/n}` with each channel's bound and
    noise level (floored like every noise level a formula divides by)."""
    kw = dict(kwargs)
    bound, noise = calibration.bound(order), calibration.noise_levels
    return cls.from_bounds(calibration.dt, bound, noise, order=kw.pop("order", 1), **kw)


def _initial_std(initial_std) -> tuple:
    """The prior standard deviations (velocity, acceleration) of a constant-acceleration filter at reset, checked:
    each one number (kept a ``float``) or one per channel (an array, broadcast against the measurement at reset)."""
    if not isinstance(initial_std, (tuple, list, np.ndarray)) or len(initial_std) != 2:
        raise TypeError(
            f"expected initial_std to be a pair (velocity std, acceleration std), actual value: {initial_std!r}"
        )
    return tuple(check_positive_parameter(f"initial_std[{i}]", value) for i, value in enumerate(initial_std))


class _Prior(NamedTuple):
    """The prior variances of a constant-acceleration filter at reset, and what they were made from."""

    shape: tuple[int, ...]
    """The shape of the measurements they are for."""
    initial_std: tuple
    """The filter's ``initial_std`` they were made from (the object itself)."""
    variances: tuple[np.ndarray, np.ndarray]
    """Of velocity and acceleration, each ``(prod(shape),)``: one per flat row of measurements."""


def _prior_variances(initial_std: tuple, shape: tuple[int, ...], kept: _Prior | None = None) -> _Prior:
    """The prior (:class:`_Prior`) of ``initial_std`` (a pair, each one number or one per channel) for measurements of
    ``shape``: ``kept`` itself if it was made from the same object for the same shape.

    Every episode restarts the filter with them, and checking and broadcasting them again each time made a restart
    4.6 times as long (:class:`KalmanCA`, three channels with a prior each: 39 us against 8.5 us; the IMM estimator
    43 us against 17.5 us). A new ``initial_std`` (a new object) is checked again."""
    if kept is not None and kept.shape == shape and kept.initial_std is initial_std:
        return kept
    variances = tuple(Observer._per_channel(f"initial_std[{i}]", s, shape) ** 2 for i, s in enumerate(initial_std))
    return _Prior(shape, initial_std, variances)


def _huber(huber) -> float | None:
    """Huber's threshold of a constant-acceleration filter (None: the Kalman filter's linear update), checked."""
    return None if huber is None else check_positive("huber", huber)


def white_jerk_density(dt: float, jerk_rms) -> np.ndarray:
    r"""The white-jerk density :math:`q = J^2\tau` of a typical (RMS) jerk ``J`` at the sampling step ``tau``
    (:meth:`KalmanCA.from_levels`), per channel; a typed error unless it is finite and positive."""
    dt = check_positive("dt", dt)
    jerk = check_positive_array("jerk_rms", jerk_rms)
    with np.errstate(over="ignore"):
        q = jerk**2 * dt
    if not (np.all(np.isfinite(q)) and np.all(q > 0)):
        raise ValueError(f"expected jerk_rms whose square times dt is finite and positive, actual value: {jerk_rms!r}")
    return q


#: factors on a process noise among which :meth:`KalmanCA.fit` chooses (``10**-1 .. 10**3.5``)
FIT_FACTORS = 10.0 ** np.arange(-1.0, 3.51, 0.5)

#: values per chunk of the record :meth:`KalmanCA.fit` runs a filter on (its memory stays bounded)
FIT_CHUNK = 2**18

#: updates per time constant of the constant-acceleration Kalman filter until its velocity's standard deviation is
#: within a factor 2 of its steady state (:meth:`KalmanCA.settling_samples`)
SETTLING_TIME_CONSTANTS = 2.54


def constant_acceleration_model(dt: float, process_noise: float) -> tuple[np.ndarray, np.ndarray]:
    r"""The transition matrix :math:`e^{\tau N}` and the process covariance ``Q`` of the constant-acceleration
    model (states: value, velocity, acceleration) driven by white jerk of density ``process_noise`` [BSL01]."""
    F = np.array([[1.0, dt, dt**2 / 2], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
    Q = process_noise * np.array(
        [[dt**5 / 20, dt**4 / 8, dt**3 / 6], [dt**4 / 8, dt**3 / 3, dt**2 / 2], [dt**3 / 6, dt**2 / 2, dt]]
    )
    return F, Q


def steady_state_covariance(dt: float, process_noise: float, measurement_noise: float) -> np.ndarray:
    """The steady-state posterior covariance (3, 3) of the constant-acceleration Kalman filter, from the discrete
    algebraic Riccati equation of its prediction covariance [BSL01].

    Raises
    ------
    numpy.linalg.LinAlgError, ValueError
        The Riccati equation has no stabilizing solution at these levels (scipy's words).
    """
    from scipy.linalg import solve_discrete_are

    # the equation is homogeneous in (Q, r, P): solved with r = 1, in units of the measurement noise, so that a
    # signal in small or large units (levels of 1e-40) does not reach scipy's balancing, which fails on them
    F, Q = constant_acceleration_model(dt, process_noise / measurement_noise)
    H = np.array([[1.0, 0.0, 0.0]])
    prior = solve_discrete_are(F.T, H.T, Q, np.eye(1))
    gain = prior @ H.T / (H @ prior @ H.T + 1.0)
    return measurement_noise * ((np.eye(3) - gain @ H) @ prior)


def _covariance_from_factors(factors) -> np.ndarray:
    r"""The covariances :math:`P = UDU^T` (N, 3, 3) of the constant-acceleration filters' factors ``factors``
    (N, 6), rows ``(U01, U02, U12, D0, D1, D2)`` (``U`` unit upper triangular, ``D`` diagonal)."""
    factors = np.asarray(factors)
    U = np.zeros((factors.shape[0], 3, 3))
    U[:, [0, 1, 2], [0, 1, 2]] = 1.0
    U[:, [0, 0, 1], [1, 2, 2]] = factors[:, :3]
    return np.einsum("nik,nk,njk->nij", U, factors[:, 3:], U)


def calibrated_prior(calibration) -> dict:
    """``{"initial_std": (velocity std, acceleration std)}``, a Kalman filter's prior at reset, per channel, from
    :attr:`Calibration.initial <smo_gym.calibration.Calibration.initial>` (where a rollout's episodes start, or a
    recorded signal's derivative bounds), or ``{}`` where that is not known (the constructor's default).

    Per channel, not the largest over channels (as it was): a joint whose episodes start gently beside one driven
    hard (InvertedDoublePendulum-v5's cart and hinges, acceleration levels 24 to 63 at the physics rate; Walker2d's
    torso height 18 and feet 1,000) took the hard one's prior, and its first estimates after each reset trusted the
    first differences as the acceleration of a fast start (1.6 times the first backward difference on
    InvertedDoublePendulum). ``scripts/bench_accuracy.py``: ``auto`` 0.517 -> 0.514 of the backward difference's
    RMSE over the 18 real-sensor physics rows (0.710 under uniform random actions, as before),
    InvertedDoublePendulum's physics-rate rows 0.3-10 % better; one row 4 % worse (Hopper, ideal sensor, env rate,
    where the trials now prove the IMM estimator on two joints that the evaluated rollouts do not bear out), no
    other of either policy by more than 0.7 %."""
    if not calibration.initial:
        return {}
    return {"initial_std": tuple(np.array(calibration.initial[r], dtype=float) for r in (1, 2))}


def _kalman_rule(cls, calibration, order, kwargs):
    """:meth:`KalmanCA.from_levels` per channel: the typical jerk (``order`` 3) and the measurement variance; the
    prior at reset (``initial_std``, unless given) from :func:`calibrated_prior`. A ``process_noise`` or
    ``measurement_noise`` given is kept, the other calibrated."""
    kwargs = {**calibrated_prior(calibration), **kwargs}
    q = kwargs.pop("process_noise", None)
    r = kwargs.pop("measurement_noise", None)
    if q is None:
        q = white_jerk_density(calibration.dt, calibration.rms(order))
    return cls(calibration.dt, q, calibration.measurement_variance if r is None else r, **kwargs)


__all__ = [
    "FIT_FACTORS",
    "SETTLING_TIME_CONSTANTS",
    "FiniteDifference",
    "HighGain",
    "KalmanCA",
    "constant_acceleration_model",
    "steady_state_covariance",
    "white_jerk_density",
]


@register_observer(
    "high-gain",
    steps=(_kernels.linear_rows,),
    calibrate=_high_gain_rule,
    given=(("gain",),),
    examples=(dict(gain=30.0, order=2), dict(gain=30.0, order=1, discretization="euler")),
)
class HighGain(Observer):
    r"""The standard linear high-gain observer of an integrator chain (Astolfi et al. 2018, eq. (2)).

    With ``n = order + 1`` states, :math:`D(\ell) = \mathrm{diag}(\ell, \ell^2, \ldots, \ell^n)` and
    ``K = (k_1, ..., k_n)`` making :math:`s^n + k_1 s^{n-1} + \dots + k_n` Hurwitz,

    .. math:: \dot{\hat x} = N\hat x + D(\ell) K (y - \hat x_1),

    ``N`` the shift matrix (the model-free case :math:`\varphi = 0` of (2)). The error eigenvalues are
    :math:`\ell` times the roots of that polynomial; for a bound ``L`` on :math:`|f^{(n)}|` and noise ``eps`` the
    derivative errors are :math:`O(L/\ell^{n-i})` plus :math:`O(\ell^{i}\epsilon)`, and the transient peak of
    :math:`\hat x_i` grows like :math:`\ell^{i-1}` (peaking).

    Parameters
    ----------
    dt : float
    gain : float or array_like
        The high gain ``ell > 0`` (1/s); an array is one gain per channel (broadcast to the measurement's shape).
    order : int
        Derivatives estimated (``1 <= order <= 9``).
    coefficients : array_like, shape (order + 1,), optional
        ``K``; default the binomial coefficients of ``(s + 1)^n`` (all error poles at ``-ell``).
    discretization : {"implicit", "euler"}
        ``"implicit"`` (default): backward Euler, stable for every ``ell * tau``; a current estimator.
        ``"euler"``: forward Euler in predictor form, unstable once ``ell * tau`` exceeds about 2/k_1.
    wrap : bool or array_like of bool, optional
        Channels measured as angles modulo ``2 pi`` (see :class:`~smo_gym.observers.Observer`).
    """

    discretizations = ("implicit", "euler")

    @check_keywords
    def __init__(
        self, dt: float, gain, order: int = 1, *, coefficients=None, discretization: str | None = None, wrap=None
    ):
        order = check_int_in_range("order", order, 1, 9)
        super().__init__(dt, order, discretization, wrap)
        self.gain = check_positive_parameter("gain", gain)
        n = order + 1
        if coefficients is None:
            coefficients = binomial_coefficients(n)
        coefficients = as_real_array("coefficients", coefficients)
        if coefficients.shape != (n,) or not np.isfinite(coefficients).all():
            raise ValueError(f"expected finite coefficients with shape ({n},), actual value: {coefficients!r}")
        if np.any(np.roots(np.concatenate([[1.0], coefficients])).real >= 0):
            raise ValueError(f"expected coefficients of a Hurwitz polynomial, actual value: {coefficients}")
        self.coefficients = coefficients
        for gain in np.unique(self.gain):  # fail at construction, not at reset, if the discrete matrices overflow
            self._discrete_row(float(gain))

    @classmethod
    @check_keywords
    def from_bounds(cls, dt: float, lipschitz, noise, order: int = 1, **kwargs) -> HighGain:
        r"""Gain balancing the two error terms of the first derivative: :math:`\ell = (L/\epsilon)^{1/(n)}`.

        ``lipschitz`` bounds :math:`|f^{(n)}|`, ``noise`` is the measurement noise amplitude; scalars or arrays
        (one per channel, broadcast together: a gain per channel).
        """
        L, eps = check_positive_array("lipschitz", lipschitz), check_positive_array("noise", noise)
        order = check_int_in_range("order", order, 1, 9)
        return cls(dt, (L / eps) ** (1.0 / (order + 1)), order, **kwargs)

    def system_matrices(self, gain: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Continuous-time error-injection form ``(A - H c^T, H)`` with ``H = D(ell) K``, at ``gain`` (default: this
        observer's, if it is one number)."""
        if gain is None:
            if np.ndim(self.gain):
                raise ValueError(f"expected a gain for an observer with one per channel, actual value: {gain!r}")
            gain = self.gain
        n = self.order + 1
        H = self.coefficients * check_positive("gain", gain) ** np.arange(1, n + 1)
        A = np.eye(n, k=1)
        A[:, 0] -= H
        return A, H

    @property
    def _kernel(self):
        return _kernels.linear_kernel

    def _predicts(self):
        return self.discretization == "euler"

    def _discrete_row(self, gain: float) -> np.ndarray:
        """The kernel's parameter row ``[F, g, R]`` of the chosen discretization for a channel of gain ``gain``."""
        n, dt = self.order + 1, self.dt
        with np.errstate(over="ignore", invalid="ignore"):  # overflow is reported below, as a bad gain
            A, H = self.system_matrices(gain)
            try:
                if self.discretization == "implicit":
                    # (I - dt (A - H c^T)) x_k = x_{k-1} + dt H y_k
                    M = np.linalg.inv(np.eye(n) - dt * A)
                    F, g, R = M, dt * M @ H, np.eye(n)
                else:
                    # predictor x_{k+1} = x_k + dt((N - H c^T) x_k + H y_k); report exp(-dt N) x_{k+1}
                    F, g = np.eye(n) + dt * A, dt * H
                    from scipy.linalg import expm  # lazy: scipy.linalg costs ~0.4 s of `import smo_gym`

                    R = expm(-dt * np.eye(n, k=1))
                row = np.concatenate([F.ravel(), g, R.ravel()])
            except (np.linalg.LinAlgError, ValueError):
                row = np.array([np.nan])
        if not np.isfinite(row).all():
            raise ValueError(
                f"expected gain, coefficients and dt giving finite injection gains k_i gain^i and a "
                f"finite discrete step, actual value: gain={gain!r}, dt={self.dt!r}"
            )
        return row

    def _channel_params(self, shape):
        return self._rows_per_value("gain", self.gain, shape, self._discrete_row)


@register_observer(
    "finite-difference",
    steps=(_kernels.finite_difference_rows,),
    bound=2,
    examples=(dict(order=1), dict(order=2)),
)
class FiniteDifference(Observer):
    r"""Backward finite differences: :math:`\hat v_k = (y_k - y_{k-1})/\tau`, and (``order=2``)
    :math:`\hat a_k = (\hat v_k - \hat v_{k-1})/\tau`.

    The baseline: velocity error :math:`O(\tau \max|\ddot f|) + O(2\epsilon/\tau)` with noise ``eps``.

    Parameters
    ----------
    dt : float
    order : {1, 2}
    wrap : bool or array_like of bool, optional
        Channels measured as angles modulo ``2 pi`` (see :class:`~smo_gym.observers.Observer`).
    """

    discretizations = ("backward",)
    self_starting = True  # a difference of the last samples

    @check_keywords
    def __init__(self, dt: float, order: int = 1, *, discretization: str | None = None, wrap=None):
        super().__init__(dt, check_int_in_range("order", order, 1, 2), discretization, wrap)

    @property
    def _kernel(self):
        return _kernels.finite_difference_kernel

    def _state_width(self):
        return self.order + 3  # estimates, innovation, samples since reset

    def _load_estimate(self, state, x0, params):
        super()._load_estimate(state, x0, params)
        # a given velocity is a previous difference: the next acceleration differentiates it (as after one sample)
        state[:, self.order + 2] = 1.0

    def _channel_params(self, shape):
        return np.full((int(np.prod(shape)), 1), self.dt)


@register_observer(
    "kalman-ca",
    steps=(_kernels.kalman_ca_rows,),
    bound=3,
    calibrate=_kalman_rule,
    given=(("process_noise", "measurement_noise"),),
    examples=(
        dict(process_noise=50.0, measurement_noise=1e-6),
        dict(process_noise=50.0, measurement_noise=1e-6, huber=3.0),
    ),
)
class KalmanCA(Observer):
    r"""Constant-acceleration Kalman filter per channel (states: value, velocity, acceleration).

    Process model: continuous white-noise jerk of spectral density ``q`` [BSL01], measurement
    :math:`y_k = x_{1,k} + v_k,\ v_k \sim \mathcal N(0, r)`:

    .. math::
        x_{k+1} = e^{\tau N} x_k + w_k,\quad
        Q = q\begin{bmatrix}\tau^5/20 & \tau^4/8 & \tau^3/6\\ \tau^4/8 & \tau^3/3 & \tau^2/2\\
        \tau^3/6 & \tau^2/2 & \tau\end{bmatrix}.

    Parameters
    ----------
    dt : float
    process_noise : float or array_like
        ``q`` [units^2 / s^5], per channel or one for all.
    measurement_noise : float or array_like
        ``r``, the variance of the measurement noise [units^2], per channel or one for all.
    initial_std : tuple of 2 floats or array_like
        Prior standard deviations of velocity and acceleration at reset (the value's is ``sqrt(r)``), each one for
        all channels or one per channel, also when ``reset`` is given initial derivatives (the prior mean). The
        calibrated gains of the wrappers set them per channel from where their episodes start
        (:attr:`Calibration.initial <smo_gym.calibration.Calibration.initial>`, :func:`calibrated_prior`).
    huber : float, optional
        Huber's threshold ``c > 0`` for sensors with gross errors: an innovation beyond ``c`` of its standard
        deviations :math:`\sqrt S` (:math:`S = c^\top P^- c + r`) moves the estimate as one of exactly ``c`` would
        (see Notes). Default None: the Kalman filter.
    wrap : bool or array_like of bool, optional
        Channels measured as angles modulo ``2 pi`` (see :class:`~smo_gym.observers.Observer`).

    Attributes
    ----------
    output_error : the last innovation ``y - x1^-``.

    Notes
    -----
    The covariance is carried in U-D factors, :math:`P = UDU^T` (Bierman's measurement update and Thornton's time
    update, [Bie77]; :mod:`smo_gym.observers._kernels`), which only add positive terms to ``D``: the textbook
    recursion :math:`P^+ = P^- - Kc^TP^-` subtracts nearly equal numbers where ``r`` is small against the predicted
    variance, and below a ratio of about 1e-15 loses the covariance's positivity in double precision (``r = 4e-22``
    with the default prior at 1 ms). The factors keep it positive and, measured against that recursion in 60-digit
    arithmetic at such ratios, within 1e-8 of its size (1e-15 at moderate ones).

    With ``huber`` the update is Masreliez and Martin's robust one [MM77]: :math:`x^+ = x^- + K\psi(\nu)`,
    :math:`\psi(\nu) = \max(-c\sqrt S, \min(\nu, c\sqrt S))`. One wrong sample then moves the velocity by at most
    :math:`k_1 c\sqrt S` however wrong it is, where the Kalman filter moves it in proportion (a glitch of 1 rad at
    10 ms: by ~50 rad/s). The covariance recursion is the Kalman filter's, independent of the measurements; theirs
    scales the gain's effect on it by :math:`E\,\psi' = 2\Phi(c) - 1` under Gaussian noise (0.9973 at ``c = 3``),
    which is left out. A gross error is a single sample, a change of motion the model did not expect (an impact)
    is not, and a filter that clips every such innovation follows the impact by at most :math:`k_1 c\sqrt S` per
    sample and can lose the motion for good (measured on HalfCheetah: RMSE 1e5). So the clip applies only where the
    previous innovation was within the bound (two beyond it in a row are taken whole: an impact costs one sample),
    and it is suspended while the share of recent innovations beyond the bound (an exponential average over ~100
    samples, the last column of the state) exceeds the Gaussian share :math:`\operatorname{erfc}(c/\sqrt 2)` by
    more than 5 %: where the model does not fit the motion at all (uniform random actions at the physics rate, the
    acceleration jumping every few samples) clipping only delays it
    (:func:`~smo_gym.observers._kernels.huber_limit`). Still, where the motion changes abruptly every few samples
    and the sensor is precise, the robust filter trails the Kalman filter (``scripts/bench_accuracy.py --smoothing
    0``); choose it for sensors that make gross errors, as ``"auto"`` does from its trials.

    References
    ----------
    .. [Bie77] G. J. Bierman, *Factorization Methods for Discrete Sequential Estimation*, Academic Press 1977
       (with C. L. Thornton's modified weighted Gram-Schmidt time update, 1976).
    .. [MM77] C. J. Masreliez and R. D. Martin, "Robust Bayesian estimation for the linear model and robustifying
       the Kalman filter", IEEE Transactions on Automatic Control 22(3), 1977.
    """

    discretizations = ("exact",)
    reports_instant = True  # the exact discretization of the constant-acceleration model
    self_starting = True  # its prior covariance makes the first estimates least-squares fits
    _prior: _Prior | None = None  # made at the first reset, kept while the shape and initial_std are

    @check_keywords
    def __init__(
        self,
        dt: float,
        process_noise: float,
        measurement_noise: float,
        *,
        initial_std: tuple[float, float] = (10.0, 100.0),
        huber: float | None = None,
        discretization: str | None = None,
        wrap=None,
    ):
        super().__init__(dt, 2, discretization, wrap)
        self.process_noise = check_positive_parameter("process_noise", process_noise)
        self.measurement_noise = check_positive_parameter("measurement_noise", measurement_noise)
        self.initial_std = _initial_std(initial_std)
        self.huber = _huber(huber)

    @classmethod
    @check_keywords
    def from_levels(cls, dt: float, jerk_rms, measurement_variance, **kwargs) -> KalmanCA:
        r"""Set ``q`` per channel from the typical (RMS) jerk ``J`` at the sampling step: :math:`q = J^2\tau`.

        With the jerk white of density ``q``, the acceleration changes by a variance :math:`q\tau` per sample;
        ``J`` is the RMS of the acceleration's change per sample divided by :math:`\tau` [BSL01]. A worst-case bound
        in its place makes the filter trust the measurements about as much as a backward difference does.
        ``measurement_variance`` is ``r`` (noise variance plus :math:`\Delta^2/12` for quantization).
        """
        return cls(dt, white_jerk_density(dt, jerk_rms), measurement_variance, **kwargs)

    @classmethod
    def fit(cls, y, dt: float, measurement_variance, process_noise, *, factors=FIT_FACTORS, **kwargs) -> KalmanCA:
        r"""The filter whose process noise predicts the record ``y`` best, per channel: among ``process_noise`` times
        each of ``factors``, the one of smallest mean squared innovation (one-step prediction error)
        :math:`\nu_k = y_k - (\hat x_{k-1} + \tau \hat v_{k-1} + \tfrac{\tau^2}{2} \hat a_{k-1})`, after the start
        (:meth:`settling_samples` of the smallest): the prediction-error method of system identification [Lju99],
        which for a correctly specified model is consistent, and needs no truth.

        Why: the white-jerk density of :meth:`from_levels` fits a jerk that changes from one sample to the next
        (impacts), and is far too small for a smooth one. A jerk that stays put over the filter's memory of ``N``
        samples moves the acceleration ``N`` times as far as white jerk of the same level, and ``N`` is 10 to 1,000
        at fast sampling. On ``scripts/bench_signals.py``'s sums of sines, chirp and cubic the fit chooses factors
        of about 3 to 3,000; its velocity RMSE is at or below that of the best common factor in hindsight on 33 of
        the 36 rows (it chooses per channel) and within 18 % of it on the others (sines at 1 ms with noise 1e-3:
        0.0194, as the best factor, against 0.0539 from the levels).

        Parameters
        ----------
        y : array_like, shape (T, ...)
            The record, ``T >= 3``; every trailing index is a channel.
        dt : float
        measurement_variance : float or array_like
            ``r`` per channel (or one for all).
        process_noise : float or array_like
            The ``q`` the factors scale (:func:`white_jerk_density` of the typical jerk, say).
        factors : array_like
            Positive factors, one or more.
        **kwargs
            Constructor arguments of the filters (``initial_std``, ``wrap``: the innovations of wrapped channels
            are taken modulo ``2 pi``).

        Returns
        -------
        KalmanCA
            With the chosen ``q`` per channel.
        """
        dt = check_positive("dt", dt)
        y = as_real_array("y", y)
        if y.ndim < 1 or y.shape[0] < 3 or not np.isfinite(y).all():
            raise ValueError(f"expected a finite record y (T, ...) with T >= 3 samples, actual value: shape {y.shape}")
        factors = check_positive_array("factors", factors).reshape(-1)
        q0 = np.broadcast_to(check_positive_array("process_noise", process_noise), y.shape[1:])
        wrapped = kwargs.get("wrap")
        wrapped = None if wrapped is None else np.broadcast_to(np.asarray(wrapped, dtype=bool), y.shape[1:])
        slowest = cls(dt, q0 * factors.min(), measurement_variance, **kwargs)  # the longest start
        start = slowest.settling_samples(limit=(y.shape[0] - 1) // 2)
        predict = constant_acceleration_model(dt, 0.0)[0][0]  # the value row of e^{tau N}: one-step prediction
        T, chunk = y.shape[0], max(1, FIT_CHUNK // max(1, int(np.prod(y.shape[1:]))))
        best_error, best_q = np.full(y.shape[1:], np.inf), q0 * factors[0]
        for factor in factors:
            candidate = cls(dt, q0 * factor, measurement_variance, **kwargs)
            last, total = candidate.reset(y[0]), np.zeros(y.shape[1:])
            for begin in range(1, T, chunk):  # in chunks: memory bounded for any record length
                end = min(begin + chunk, T)
                estimates = candidate.run(y[begin:end])
                previous = np.concatenate([last[None], estimates[:-1]])  # the estimate before each sample
                last = estimates[-1]
                first = max(begin, start + 1)  # innovations after the start only
                if first < end:
                    innovation = y[first:end] - previous[first - begin :] @ predict
                    if wrapped is not None:
                        innovation = np.where(wrapped, np.mod(innovation + np.pi, 2 * np.pi) - np.pi, innovation)
                    total += np.sum(innovation**2, axis=0)
            error = total / (T - 1 - start)
            better = error < best_error
            best_error, best_q = np.where(better, error, best_error), np.where(better, q0 * factor, best_q)
        return cls(dt, best_q, measurement_variance, **kwargs)

    @property
    def _kernel(self):
        return _kernels.kalman_ca_kernel

    def _state_width(self):
        return 11  # estimates, covariance factors, innovation, share of innovations beyond Huber's bound

    def _innovation_column(self):
        return 9

    def _channel_params(self, shape):
        q = self._per_channel("process_noise", self.process_noise, shape)
        r = self._per_channel("measurement_noise", self.measurement_noise, shape)
        huber = math.inf if self.huber is None else self.huber
        return np.column_stack([np.full(q.shape, self.dt), q, r, np.full(q.shape, huber)])

    def _initial_state(self, y0, params):
        state = np.zeros((y0.shape[0], 11))
        state[:, 0] = y0
        state[:, 6] = params[:, 2]  # P = diag(r, initial_std**2): U = I, D = its diagonal
        self._prior = _prior_variances(self.initial_std, self._shape, self._prior)
        state[:, 7], state[:, 8] = self._prior.variances
        return state

    def __repr__(self) -> str:
        text = super().__repr__()
        return text if self.huber is None else f"{text[:-1]}, huber={self.huber})"

    @property
    def covariance(self) -> np.ndarray:
        """Posterior covariance of each channel, shape ``(..., n_channels, 3, 3)``."""
        self._require_reset()
        return _covariance_from_factors(self._state[:, 3:9]).reshape(self._shape + (3, 3))

    def settling_samples(self, limit: int | None = None) -> int:
        r"""The number of updates after ``reset`` until the velocity's posterior standard deviation is within a
        factor 2 of its steady state on every channel: the prior forgotten, the filter as good as it gets.

        In units of the step and of the noise the covariance recursion has one parameter,
        :math:`\rho = q\tau^5 / r`, and it does not depend on the measurements. From a wide prior (the first
        estimates least-squares fits) the count is :data:`SETTLING_TIME_CONSTANTS` times the filter's time constant
        :math:`\rho^{-1/6}` samples (:math:`(r\tau/q)^{1/6}` seconds: the inverse bandwidth of the continuous
        filter with noise density :math:`r\tau`), at least 2. The constant is measured on the recursion: 2.50 to
        2.54 for :math:`\rho` between 1e-24 and 1e-6, exact as :math:`\rho \to 0`, where the recursion is
        self-similar (``k -> lambda k``, ``rho -> rho / lambda**6``); for :math:`\rho \ge 10^{-4}` (a few samples)
        the count is at most one sample above the recursion's.

        Parameters
        ----------
        limit : int, optional
            The most it returns (a record's length).

        Returns
        -------
        int
        """
        q, r = (np.ravel(a).astype(float) for a in np.broadcast_arrays(self.process_noise, self.measurement_noise))
        log_count = (
            math.log(SETTLING_TIME_CONSTANTS) + float(np.max(np.log(r) - np.log(q))) / 6 - 5 / 6 * math.log(self.dt)
        )
        most = sys.maxsize if limit is None else check_int_in_range("limit", limit, 0, sys.maxsize)
        count = sys.maxsize if log_count >= math.log(sys.maxsize) else max(2, math.ceil(math.exp(log_count)))
        return min(count, most)
