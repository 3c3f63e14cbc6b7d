r"""Two constant-acceleration Kalman filters mixed by the interacting multiple model (IMM) algorithm.

A joint of a robot under a policy alternates between smooth stretches and bursts of large jerk (a new command, a
contact). One constant-acceleration Kalman filter (:class:`~smo_gym.observers.KalmanCA`) tuned for the bursts
trusts the samples too much on the smooth stretches (its velocity is then about a three-point difference, noisier
than a backward difference); tuned for the smooth stretches it lags in the bursts. The IMM estimator of Blom and
Bar-Shalom (1988) runs both models and weighs them by how well each predicted the last samples: mode ``j`` has the
white-jerk density :math:`q_j` (:math:`q_1 = \rho q`, :math:`q_2 = q`), the modes switch as a Markov chain that
stays in its mode with probability :math:`p`, and each sample:

1. *mixing*: with the predicted mode probabilities :math:`\bar c_j = \sum_i p_{ij}\mu_i` and the mixing weights
   :math:`\mu_{i|j} = p_{ij}\mu_i/\bar c_j`, each filter restarts from
   :math:`\hat x^0_j = \sum_i \mu_{i|j}\hat x_i` and
   :math:`P^0_j = \sum_i \mu_{i|j}\bigl(P_i + (\hat x_i - \hat x^0_j)(\hat x_i - \hat x^0_j)^T\bigr)`, which for two
   modes is :math:`\mu_{1|j}P_1 + \mu_{2|j}P_2 + \mu_{1|j}\mu_{2|j}\,d d^T`, :math:`d = \hat x_1 - \hat x_2`;
2. *filtering*: each filter predicts and updates with its :math:`q_j` (the steps of :class:`KalmanCA`), with the
   innovation :math:`\nu_j` and its variance :math:`S_j = P^-_{j,00} + r`;
3. *mode probabilities*: :math:`\mu_j \propto \bar c_j\,\mathcal N(\nu_j; 0, S_j)` (computed from the
   log-likelihoods, so that a sample far outside both predictions does not underflow to 0/0);
4. *output*: :math:`\hat x = \sum_j \mu_j\hat x_j` (value, velocity, acceleration at the sample time).

With :math:`\rho = 1` both modes are the same filter and the output is :class:`KalmanCA`'s.

Gross errors (``huber=c``). The Kalman update moves the estimate in proportion to the innovation, and the normal
likelihood of a wrong sample is far larger in the fast mode: one glitch throws the estimate and the mode. With
``huber``, each mode updates as :class:`KalmanCA` does with the same option (Huber's function: an innovation
beyond ``c`` standard deviations counts as ``c`` of them, Masreliez and Martin 1977), and such a sample's likelihood
in each mode is that of an innovation of exactly ``c`` standard deviations, so that it says nothing of the mode
but through :math:`S_j`; unless the previous innovation was beyond the bound too (two in a row are a change of
motion, taken whole), or the smooth mode's recent innovations were beyond its bound far more often than Gaussian
ones are (:class:`KalmanCA`'s Notes: the motion keeps leaving the smooth model, and clipping would keep the
estimate from switching to the fast mode). On ``scripts/bench_accuracy.py``'s ``outliers`` sensor (a noisy 12-bit
encoder, one sample in a thousand off by ~0.1) at the physics rate it has the smallest velocity RMSE of five of six
Gymnasium tasks (Walker2d 0.38 against 0.81 for super-twisting and 2.3 for the IMM estimator); under uniform random
actions with precise sensors it trails the IMM estimator (up to 4x at the physics rate), and ``"auto"`` keeps it
where its trials show it wins.

Defaults. ``q`` is :class:`KalmanCA`'s calibration (:meth:`KalmanIMM.from_levels`: the typical jerk at the
sampling step), the smooth mode has :math:`\rho = 0.01` of it and the chain stays with :math:`p = 0.99`: best or
within 1 % of the best, under both motions, of the combinations tried on Hopper-v5 (12-bit encoder, env rate:
:math:`\rho` = 0.01 or 0.001 with the fast mode at ``q``, 0.01 with it at ``10 q``; :math:`p` = 0.95 or 0.99),
then checked on six more (environment, sensor, rate) settings of
``scripts/bench_accuracy.py``'s rollouts: against the better of a backward difference and :class:`KalmanCA`,
0.58-1.01 times its velocity RMSE under low-passed random actions, and within 2.3 % of it under uniform random
ones but on HalfCheetah at the physics rate (1.34, as :class:`KalmanCA`: there the backward difference is exact,
MuJoCo's Euler step). ``scripts/bench_accuracy.py`` shows every row. A wider check, on the 18 rows of that
script with a non-ideal sensor at the physics rate and a seed its tables do not use (``--seed 1``), over
:math:`\rho` in {0.001, 0.003, 0.01, 0.03} and :math:`p` in {0.95, 0.99, 0.995}: under low-passed actions the
defaults' geometric mean of the RMSE ratio to the backward difference is 0.532, the best setting's 0.525
(:math:`\rho = 0.003`, :math:`p = 0.99`), the worst 0.592; under uniform random actions every setting is at
0.718 within 0.05 %.

References
----------
.. [BB88] H. A. P. Blom and Y. Bar-Shalom, "The interacting multiple model algorithm for systems with Markovian
   switching coefficients", IEEE Transactions on Automatic Control 33(8), 1988.
.. [BSL01] Y. Bar-Shalom, X. R. Li and T. Kirubarajan, "Estimation with Applications to Tracking and Navigation",
   Wiley, 2001: section 6.2.3 (the white-jerk model, as :class:`~smo_gym.observers.KalmanCA`) and chapter 11 (the
   IMM estimator).
.. [MM77] C. J. Masreliez and R. D. Martin, "Robust Bayesian estimation for the linear model and robustifying the
   Kalman filter", IEEE Transactions on Automatic Control 22(3), 1977.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .._validation import check_keywords, check_positive, check_positive_parameter
from . import _kernels
from .base import Observer
from .linear import _huber, _initial_std, _kalman_rule, _prior_variances, white_jerk_density
from .registry import register_observer

__all__ = ["KalmanIMM", "imm_ca_step"]

# state columns: the output (value, velocity, acceleration), the innovation, then per mode its mean (3) and the U-D
# factors of its covariance (6: U01, U02, U12, D0, D1, D2, as in :func:`smo_gym.observers._kernels.kalman_ca_rows`),
# then the two mode probabilities, then the share of the smooth mode's innovations beyond Huber's bound
# (:func:`smo_gym.observers._kernels.huber_rate`)
_OUT, _INNOVATION, _MODES, _MU, _RATE = 0, 3, 4, 22, 24
_WIDTH = 25
# parameter columns: dt, q of the smooth mode, q of the other, r, the probability of staying in a mode, Huber's c
_H, _Q_LOW, _Q_HIGH, _R, _STAY, _HUBER = range(6)


@njit(cache=True, error_model="numpy")
def _mix(s, wa, wb, d0, d1, d2, out, o):
    """``out[o:o + 9]`` = the mixed mean ``wa xa + wb xb`` and the factors of the mixed covariance
    ``wa Pa + wb Pb + wa wb d d^T`` (:func:`~smo_gym.observers._kernels.ud_of_sum`, without forming it) of the two
    mode blocks of the state row ``s``, ``d = xa - xb``."""
    a, b = _MODES, _MODES + 9
    for i in range(3):
        out[o + i] = wa * s[a + i] + wb * s[b + i]
    U = _kernels.ud_of_sum(
        s[a + 3], s[a + 4], s[a + 5], wa * s[a + 6], wa * s[a + 7], wa * s[a + 8],
        s[b + 3], s[b + 4], s[b + 5], wb * s[b + 6], wb * s[b + 7], wb * s[b + 8],
        d0, d1, d2, wa * wb,
    )  # fmt: skip
    for i in range(6):
        out[o + 3 + i] = U[i]


@njit(cache=True, error_model="numpy")
def _mode_update(s_new, o, y, dt, q, r, huber, previous, rate):
    """Filter the mixed mode block ``s_new[o:o + 9]`` in place with the sample ``y`` (:class:`KalmanCA`'s
    prediction and update with the density ``q`` and Huber's threshold ``huber``, the ``previous`` innovation and
    the ``rate`` of innovations beyond the bound deciding whether it clips); returns its innovation, its
    log-likelihood (that of an innovation at the bound where it clips) and its innovation variance."""
    m = _kernels.kalman_ca_prior_factors(
        s_new[o + 3], s_new[o + 4], s_new[o + 5], s_new[o + 6], s_new[o + 7], s_new[o + 8], dt, q
    )
    P = _kernels.kalman_ca_posterior_factors(m[0], m[1], m[2], m[3], m[4], m[5], r)
    variance = P[9]
    limit = _kernels.huber_limit(huber, variance, previous, rate)
    x0, x1, x2, nu = _kernels.kalman_ca_mean(s_new[o], s_new[o + 1], s_new[o + 2], y, dt, P[6], P[7], P[8], limit)
    s_new[o], s_new[o + 1], s_new[o + 2] = x0, x1, x2
    for i in range(6):
        s_new[o + 3 + i] = P[i]
    u = min(abs(nu), limit) / math.sqrt(variance)  # a suspected gross error tells no mode
    return nu, -0.5 * (u * u + math.log(variance)), variance


@njit(cache=True, error_model="numpy")
def imm_ca_step(s, y, params, s_new):
    r"""One IMM step of the two constant-acceleration filters (module notes), state row ``s`` into ``s_new``.

    Returns the innovation of the mixed prediction, :math:`y - \sum_j \bar c_j \hat x^-_{j,0}`.
    """
    dt, r, stay = params[_H], params[_R], params[_STAY]
    mu_a, mu_b = s[_MU], s[_MU + 1]
    c_a = stay * mu_a + (1.0 - stay) * mu_b  # predicted mode probabilities
    c_b = 1.0 - c_a
    a, b = _MODES, _MODES + 9
    d0, d1, d2 = s[a] - s[b], s[a + 1] - s[b + 1], s[a + 2] - s[b + 2]
    _mix(s, stay * mu_a / c_a, (1.0 - stay) * mu_b / c_a, d0, d1, d2, s_new, a)
    _mix(s, (1.0 - stay) * mu_a / c_b, stay * mu_b / c_b, d0, d1, d2, s_new, b)
    huber, previous, rate = params[_HUBER], s[_INNOVATION], s[_RATE]
    nu_a, like_a, variance_a = _mode_update(s_new, a, y, dt, params[_Q_LOW], r, huber, previous, rate)
    nu_b, like_b, _ = _mode_update(s_new, b, y, dt, params[_Q_HIGH], r, huber, previous, rate)
    # whether the motion keeps leaving the smooth mode's model: its innovations' share beyond the bound (then
    # clipping would keep the estimate from switching to the fast mode when it should)
    s_new[_RATE] = _kernels.huber_rate(rate, nu_a, huber, variance_a)
    top = max(like_a, like_b)
    w_a = c_a * math.exp(like_a - top)
    w_b = c_b * math.exp(like_b - top)
    mu_a = w_a / (w_a + w_b)
    s_new[_MU], s_new[_MU + 1] = mu_a, 1.0 - mu_a
    for i in range(3):
        s_new[_OUT + i] = mu_a * s_new[a + i] + (1.0 - mu_a) * s_new[b + i]
    return c_a * nu_a + c_b * nu_b


@njit(cache=True, error_model="numpy")
def imm_ca_rows(state, y, params, new_state, out, shared):
    """:func:`imm_ca_step` on every channel (``shared``: one parameter row for every channel)."""
    for c in range(y.shape[0]):
        pc = 0 if shared else c  # the parameter row of channel c
        new_state[c, _INNOVATION] = imm_ca_step(state[c], y[c], params[pc], new_state[c])
        for i in range(3):
            out[c, i] = new_state[c, _OUT + i]
    return _kernels._check_state(new_state, out)


# the step, its mixing and its mode update link _kernels' filter halves: their cache goes when those change
_STEP = _kernels.register_step(imm_ca_rows, helpers=(_mix, _mode_update, imm_ca_step))


@register_observer(
    "kalman-imm",
    steps=(_STEP,),
    bound=3,
    calibrate=_kalman_rule,  # KalmanCA's: from_levels with the typical jerk and the measurement variance
    given=(("process_noise", "measurement_noise"),),
    examples=(
        dict(process_noise=50.0, measurement_noise=1e-6),
        dict(process_noise=50.0, measurement_noise=1e-6, smooth_ratio=0.1, stay=0.9),
        dict(process_noise=50.0, measurement_noise=1e-6, huber=3.0),
    ),
)
class KalmanIMM(Observer):
    r"""Two constant-acceleration Kalman filters, a smooth one and a fast one, mixed by the IMM algorithm
    ([BB88]; module notes).

    Parameters
    ----------
    dt : float
        Sampling step.
    process_noise : float or array_like
        ``q`` [units^2 / s^5], the white-jerk density of the fast mode (:class:`~smo_gym.observers.KalmanCA`'s
        ``process_noise``), per channel or one for all.
    measurement_noise : float or array_like
        ``r``, the variance of the measurement noise [units^2], per channel or one for all.
    smooth_ratio : float
        :math:`\rho` in ``(0, 1]``: the smooth mode's density is :math:`\rho q`. 1 gives :class:`KalmanCA`.
    stay : float
        :math:`p` in ``(0, 1)``: the probability that the motion stays in its mode from one sample to the next.
    initial_std : tuple of 2 floats or array_like
        Prior standard deviations of velocity and acceleration at reset in both modes (the value's is
        ``sqrt(r)``), each one for all channels or one per channel; the modes start equally likely.
    huber : float, optional
        Huber's threshold ``c > 0`` for sensors with gross errors, in both modes (as
        :class:`~smo_gym.observers.KalmanCA`'s); a sample the modes clip weighs them as an innovation of exactly
        ``c`` standard deviations would, so that one wrong sample does not throw the estimate into the fast mode
        (module notes). Default None.
    discretization : {"exact"}
        Both filters are the exact discretization of the constant-acceleration model.
    wrap : bool or array_like of bool, optional
        Channels measured as angles modulo ``2 pi`` (see :class:`~smo_gym.observers.Observer`).
    """

    discretizations = ("exact",)
    reports_instant = True
    self_starting = True  # each mode starts from KalmanCA's prior
    _prior = None  # made at the first reset, kept while the shape and initial_std are (KalmanCA's)

    @check_keywords
    def __init__(
        self,
        dt: float,
        process_noise,
        measurement_noise,
        *,
        smooth_ratio: float = 0.01,
        stay: float = 0.99,
        initial_std: tuple[float, float] = (10.0, 100.0),
        huber: float | None = None,
        discretization: str | None = None,
        wrap=None,
    ):
        super().__init__(dt, 2, discretization, wrap)
        self.process_noise = check_positive_parameter("process_noise", process_noise)
        self.measurement_noise = check_positive_parameter("measurement_noise", measurement_noise)
        self.smooth_ratio = check_positive("smooth_ratio", smooth_ratio)
        if self.smooth_ratio > 1.0:
            raise ValueError(f"expected smooth_ratio in (0, 1], actual value: {smooth_ratio!r}")
        self.stay = check_positive("stay", stay)
        if self.stay >= 1.0:
            raise ValueError(f"expected stay in (0, 1), actual value: {stay!r}")
        self.initial_std = _initial_std(initial_std)
        self.huber = _huber(huber)

    @classmethod
    @check_keywords
    def from_levels(cls, dt: float, jerk_rms, measurement_variance, **kwargs) -> KalmanIMM:
        r"""The fast mode's ``q`` from the typical (RMS) jerk ``J`` at the sampling step, :math:`q = J^2\tau`, as
        :meth:`KalmanCA.from_levels <smo_gym.observers.KalmanCA.from_levels>` sets it."""
        return cls(dt, white_jerk_density(dt, jerk_rms), measurement_variance, **kwargs)

    @property
    def _kernel(self):
        return _STEP.kernel

    def _state_width(self):
        return _WIDTH

    def _innovation_column(self):
        return _INNOVATION

    def _channel_params(self, shape):
        q = self._per_channel("process_noise", self.process_noise, shape)
        r = self._per_channel("measurement_noise", self.measurement_noise, shape)
        n = q.shape[0]
        huber = math.inf if self.huber is None else self.huber
        return np.column_stack(
            [np.full(n, self.dt), self.smooth_ratio * q, q, r, np.full(n, self.stay), np.full(n, huber)]
        )

    def _initial_state(self, y0, params):
        state = np.zeros((y0.shape[0], _WIDTH))
        state[:, _OUT] = y0
        self._prior = _prior_variances(self.initial_std, self._shape, self._prior)
        velocity, acceleration = self._prior.variances
        for o in (_MODES, _MODES + 9):
            state[:, o] = y0
            state[:, o + 6] = params[:, _R]  # P = diag(r, initial_std**2): U = I, D = its diagonal
            state[:, o + 7] = velocity
            state[:, o + 8] = acceleration
        state[:, _MU : _MU + 2] = 0.5
        return state

    def _load_estimate(self, state, x0, params):
        """A reset with derivatives starts both modes (and the output) at the given estimate."""
        m = x0.shape[1]
        for o in (_OUT, _MODES, _MODES + 9):
            state[:, o : o + m] = x0

    @property
    def mode_probabilities(self) -> np.ndarray:
        """The probability of the smooth and of the fast mode after the last sample, shape ``(..., n_channels, 2)``."""
        self._require_reset()
        return self._state[:, _MU : _MU + 2].reshape(self._shape + (2,)).copy()

    def __repr__(self) -> str:
        wrap = "" if self.wrap is None else f", wrap={self.wrap!r}"
        huber = "" if self.huber is None else f", huber={self.huber}"
        return (
            f"{type(self).__name__}(dt={self.dt}, smooth_ratio={self.smooth_ratio}, stay={self.stay}{huber}, "
            f"discretization={self.discretization!r}{wrap})"
        )
