r"""The sampled first-order differentiator with the best worst-case accuracy (Haimovich et al. 2021).

Setting. Samples :math:`y_k = f(t_k) + \eta_k`, :math:`t_k = kh`, with bounded noise :math:`|\eta_k| \le \epsilon`
and a bounded second derivative :math:`|f''| \le L`; nothing else is known of ``f``.

Every lag bounds the derivative. By Taylor's theorem with :math:`|f''| \le L`, the difference quotient over
``j`` samples is the derivative at :math:`t_k` up to :math:`Ljh/2`, and the noise moves it by at most
:math:`2\epsilon/(jh)`:

.. math::
    f'(t_k) \in \bigl[d_j - r_j,\ d_j + r_j\bigr],\qquad
    d_j = \frac{y_k - y_{k-j}}{jh},\qquad r_j = \frac{2\epsilon}{jh} + \frac{Ljh}{2},\qquad j = 1, \ldots, m.

The differentiator intersects these intervals over the window of ``m`` lags and reports the midpoint,

.. math::
    \hat v_k = \tfrac12(\ell_k + u_k),\qquad \ell_k = \max_{j \le m}(d_j - r_j),\quad
    u_k = \min_{j \le m}(d_j + r_j),\qquad |\hat v_k - f'(t_k)| \le \tfrac12(u_k - \ell_k) =: B_k,

so that :math:`B_k` (:attr:`WorstCaseOptimal.certified_bound`) is an error bound that holds at every sample for
every signal and noise within the assumptions, and is never larger than the best single lag's bound
:math:`E_m = \min_{j \le m} r_j`; the adversarial data :math:`f = -Lt^2/2`, :math:`\eta = -\epsilon` before
:math:`t_k` and :math:`+\epsilon` at :math:`t_k` make every lag interval :math:`[f',\ f' + 2r_j]`, so the error
meets :math:`E_m` there: it is this estimator's worst case. Only the constraints that pair the newest sample with
an earlier one are used: they have the closed form above and cost ``O(m)`` per channel and sample. Asking one
signal to fit all the window's samples at once narrows the interval on typical data (not in the worst case): this
is not the linear program of Haimovich et al. (2021), see "Relation to the cited papers" below.

Best worst-case accuracy. :math:`r_j` is smallest at the lag :math:`jh \approx 2\sqrt{\epsilon/L}`, so the
default window :math:`m = \lceil 2\sqrt{\epsilon/L}/h\rceil` holds it, and

.. math:: E_m = \min_{j \ge 1}\Bigl(\frac{2\epsilon}{jh} + \frac{Ljh}{2}\Bigr) \ge 2\sqrt{\epsilon L},
    \qquad E_m \to 2\sqrt{\epsilon L}\quad (h \to 0)

(with :math:`x = 2\sqrt{\epsilon/L}/h`, :math:`E_m = \sqrt{\epsilon L}\min_j(x/j + j/x)`: the excess is
:math:`O(1/x^2)`, 0.14 % at :math:`x = 6.3`). No *sampled* differentiator guarantees less than :math:`E_m` itself:
a signal :math:`\varphi` with :math:`|\varphi''| \le L`, :math:`|\varphi(t_k - jh)| \le \epsilon` at every past
sample and :math:`\varphi'(t_k) = E_m` exists (computed by a linear program in the tests, for ``x`` = 0, 0.3,
1.5, 3 and 28.3), so :math:`\pm\varphi` with noise :math:`\mp\varphi` give the same (zero) samples and derivatives
:math:`\pm E_m`: whatever a differentiator reports, it is off by :math:`E_m` on one of them. This estimator's worst
case is therefore the smallest possible. No differentiator, sampled or not, does better than the limit: two signals
:math:`f_1, f_2` with :math:`|f_i''| \le L` whose difference :math:`g = f_1 - f_2` stays within
:math:`\pm 2\epsilon` on the past (both then fit the same measurements) can reach :math:`g'(t_k) = 4\sqrt{\epsilon L}`:
:math:`g(t) = -2\epsilon + L(t - t_k + T)^2` on :math:`[t_k - T, t_k]`, :math:`T = 2\sqrt{\epsilon/L}`, constant
before. Whatever a differentiator reports, it is off by :math:`2\sqrt{\epsilon L}` on one of them (the fundamental
limitation that Seeber and Haimovich 2023 show; their sampled differentiator's bound also tends to it as
:math:`h \to 0`). Without noise the error is :math:`E_m = Lh/2`, the smallest any sampled differentiator can
guarantee (Seeber and Haimovich's quasi-exactness: parabolas of curvature :math:`\pm L` through the same samples
differ by :math:`Lh` in slope); for
:math:`h \ge \sqrt{2\epsilon/L}` the best lag is one sample: the backward difference is then worst-case optimal.

Unknown noise bound (``noise=None``). Aldana-López, Seeber, Haimovich and Gómez-Gutiérrez (2025) differentiate
with an unknown noise bound, as their reference implementation [OREdiff] shows (read to check this module, not
copied: it is GPL-3). The bound is estimated from the window: for three samples :math:`t_a < t_b < t_c = t_k`, the
chord through :math:`(t_a, y_a)` and :math:`(t_c, y_c)` misses :math:`y_b` by :math:`Q_{abc}`, of which at most
:math:`L(t_b - t_a)(t_c - t_b)/2` is the signal's curvature and at most :math:`2\epsilon` the noise, so

.. math::
    \hat\epsilon_k = \max\Bigl(0,\ \max_{k - W \le a < b < k} \tfrac12\bigl(|Q_{abk}|
        - \tfrac L2 (t_b - t_a)(t_k - t_b)\bigr)\Bigr) \le \epsilon

is the smallest noise bound the window's data allow: never above the true one. The derivative is then the
difference quotient over the one lag whose bound :math:`r_j` that estimate makes smallest (the linear adaptive
differentiator of [SH23]),

.. math::
    \hat v_k = d_{\hat\jmath_k},\qquad \hat\jmath_k = \min\bigl(W,\ \lceil 2\sqrt{\hat\epsilon_k/L}/h\rceil\bigr)
    \quad(1 \text{ where } \hat\epsilon_k = 0),

so its error is at most :math:`r_{\hat\jmath_k}` drawn with the true :math:`\epsilon`. [ASHG25]'s reference
implementation sizes the window from a known *upper* bound :math:`\bar\epsilon` of the noise,
:math:`W = \lceil\sqrt{2\bar\epsilon/(Lh^2)} + 1\rceil`, and draws :math:`2\sqrt{2\bar\epsilon L} + Lh/2` as the
worst-case error; the tests check that bound on adversarial noise (measured: at most 0.79 of it; up to 26 % above
the known-noise optimum :math:`2\sqrt{\epsilon L}`). Intersecting all lags' intervals drawn with
:math:`\hat\epsilon_k` instead, as with a known bound, is worse: intervals drawn too narrow pull the midpoint off
(measured: errors above that bound in three of the four settings of those tests; on noisy sines an RMSE up to
20 % larger, within 3 % elsewhere). The estimate forgets: an outlier or an impact raises it for ``W`` samples
only. The reference implementation's output filter (a rate limiter that makes the output Lipschitz continuous,
the subject of [ASHG25]) is not implemented: its rate is a parameter whose rule could not be read.

Relation to the cited papers. Only the abstracts of [HSAG21], [SH23] and [ASHG25] and the first paragraph of
the introduction of [ASHG25] could be read (stored copies of the papers' pages hold their beginning only, the
abstract of [HSAG21] came from an arXiv feed; queries tried: the arXiv numbers 2106.05320, 2111.12638 and
2404.05863 with "linear program", "window", "quasi-exact", "theorem", "noise bound estimate", "worst-case error
bound"), and the authors' reference implementation of [ASHG25] [OREdiff]. No equation, theorem or algorithm
statement of the papers was visible, so none is cited by number here. What the abstracts say (paraphrased), and
how this module stands:

* [HSAG21]: the differentiator solves a linear program built from the available samples, needs no tuning beyond
  the noise and second-derivative bounds, and has a tight worst-case error bound that is the best of all causal
  differentiators and is reached after a fixed number of samples. This estimator is **not** that linear program
  (its variables, constraints and output could not be read): it is the closed form of the pairwise lag constraints
  above. Its worst case is nevertheless the smallest a sampled differentiator can guarantee (previous paragraphs,
  checked numerically), reached once ``m`` samples have come: the worst-case accuracy the abstract claims. On
  typical data its interval is wider than the range of derivatives of all the signals consistent with the window
  (measured: :math:`B_k` 1.08 to 1.50 times that range's half-width over the last 60 samples, ``h = 1 ms``,
  ``L = 5``, :math:`\epsilon = 10^{-3}`), and an estimator using that range may err less there. The closed form
  of the paper's bound could not be read; in the setting here (uniform sampling, :math:`|f''| \le L`,
  :math:`|\eta| \le \epsilon`) a bound that is the best among causal differentiators equals :math:`E_m` with the
  default window.
* [SH23]: shows the smallest worst-case error causal differentiators can achieve, in continuous time and from
  samples, and calls quasi-exact the sampled differentiators with the lowest possible worst-case error without
  noise. The values :math:`2\sqrt{\epsilon L}` and :math:`Lh/2` are derived and checked here, not read there. The
  :math:`2\sqrt{2\bar\epsilon L}` of [ASHG25]'s reference implementation is the bound *without* a known noise
  bound; with one, :math:`2\sqrt{\epsilon L}` is attained (previous paragraphs).
* [ASHG25]: the noise is bounded by an unknown constant; the sampled differentiator is quasi-exact and keeps the
  optimal worst-case bound. The ``noise=None`` estimator above is its reference implementation's: the chord
  estimate and the adaptive lag (the same numbers, checked in the tests against a transcription of the
  equations), without the output filter.

References
----------
.. [HSAG21] H. Haimovich, R. Seeber, R. Aldana-López and D. Gómez-Gutiérrez, "Differentiator for noisy sampled
   signals with best worst-case accuracy", IEEE Control Systems Letters, 2021, doi:10.1109/LCSYS.2021.3087542.
.. [SH23] R. Seeber and H. Haimovich, "Optimal robust exact differentiation via linear adaptive techniques",
   Automatica, 2023 (arXiv:2111.12638).
.. [ASHG25] R. Aldana-López, R. Seeber, H. Haimovich and D. Gómez-Gutiérrez, "Optimal robust exact first-order
   differentiators with Lipschitz-continuous output", IEEE Transactions on Automatic Control, 2025,
   doi:10.1109/TAC.2025.3555481.
.. [OREdiff] R. Aldana-López, "OREdiff: optimal robust exact numerical differentiation scripts" (MATLAB and
   Python reference implementation of [ASHG25], GPL-3), https://github.com/RodrigoAldana/OREdiff.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .._validation import check_int_in_range, check_keywords, check_nonnegative_array, check_positive_array
from . import _kernels
from .base import Observer
from .registry import register_observer

__all__ = [
    "MAX_WINDOW",
    "WorstCaseOptimal",
    "best_worst_case_error",
    "bounded_noise",
    "chord_noise_bound",
    "default_window",
    "lag_interval",
]

#: the largest window (lags) of :class:`WorstCaseOptimal`: the state holds ``window + 1`` samples per channel
MAX_WINDOW = 4096
#: the window searched for the noise bound when ``noise=None`` and no ``window`` is given
DEFAULT_ESTIMATION_WINDOW = 32

# state columns: value, derivative, innovation, certified half-width (-1: none), noise bound used, samples held,
# then the last window + 1 samples, oldest first
_VALUE, _RATE, _INNOVATION, _HALF, _NOISE, _COUNT, _BUFFER = range(7)
# parameter columns: h, L, eps (-1: estimate it), window m
_H, _L, _EPS, _WINDOW = range(4)


@njit(cache=True, error_model="numpy")
def lag_interval(y_new: float, y_old: float, lag: int, dt: float, lipschitz: float, noise: float):
    r"""The interval ``(centre, half-width)`` that the samples ``lag`` steps apart give for :math:`f'(t_k)`
    (module notes): :math:`d_j = (y_k - y_{k-j})/(jh)` and :math:`r_j = 2\epsilon/(jh) + Ljh/2`."""
    span = lag * dt
    return (y_new - y_old) / span, 2.0 * noise / span + 0.5 * lipschitz * span


@njit(cache=True, error_model="numpy")
def chord_noise_bound(y_a: float, y_b: float, y_c: float, i: int, j: int, dt: float, lipschitz: float) -> float:
    r"""The noise bound that the samples :math:`y_a, y_b, y_c` at :math:`t_k - ih, t_k - jh, t_k` (``i > j >= 1``)
    require at least (module notes): :math:`\tfrac12(|Q| - L(i - j)jh^2/2)`, ``Q`` the miss of the chord."""
    chord = y_c - (y_c - y_a) * (j / i)
    return 0.5 * (abs(y_b - chord) - 0.5 * lipschitz * (i - j) * j * dt * dt)


@njit(cache=True, error_model="numpy")
def _channel_step(state, yc, prow, new_state, out, c):
    """One sample of one channel: shift the window, then intersect the lag intervals (a noise bound given), or
    estimate the noise bound and take the difference quotient over the lag it makes best (``noise=None``).
    Writes row ``c`` of ``new_state`` and ``out``; returns whether everything written is finite."""
    width = state.shape[1] - _BUFFER - 1  # lags the buffer holds
    dt, lipschitz, eps, window = prow[_H], prow[_L], prow[_EPS], int(prow[_WINDOW])
    for i in range(width):
        new_state[c, _BUFFER + i] = state[c, _BUFFER + i + 1]
    newest = _BUFFER + width
    new_state[c, newest] = yc
    held = state[c, _COUNT]  # samples before this one (1 after a reset)
    lags = int(min(held, window))  # lags available now
    if eps < 0.0:  # the smallest noise bound the window allows (chord misses of triples ending now)
        eps = 0.0
        for i in range(2, lags + 1):
            for j in range(1, i):
                eps = max(
                    eps, chord_noise_bound(new_state[c, newest - i], new_state[c, newest - j], yc, i, j, dt, lipschitz)
                )
        # the one lag whose bound the estimate makes smallest (Aldana-Lopez et al.'s adaptive backward difference)
        lag = min(lags, max(1, math.ceil(2.0 * math.sqrt(eps / lipschitz) / dt)))
        rate, half = lag_interval(yc, new_state[c, newest - lag], lag, dt, lipschitz, eps)
    else:
        low, high = -math.inf, math.inf
        for j in range(1, lags + 1):
            centre, half = lag_interval(yc, new_state[c, newest - j], j, dt, lipschitz, eps)
            low = max(low, centre - half)
            high = min(high, centre + half)
        rate = 0.5 * (low + high)
        # an empty intersection: the data contradict (eps, L) (an impact, an outlier): no certificate
        half = 0.5 * (high - low) if high >= low else -1.0
    new_state[c, _VALUE] = yc
    new_state[c, _RATE] = rate
    new_state[c, _INNOVATION] = yc - (state[c, _VALUE] + dt * state[c, _RATE])
    new_state[c, _HALF] = half
    new_state[c, _NOISE] = eps
    new_state[c, _COUNT] = min(held + 1.0, width + 1.0)
    out[c, 0] = yc
    out[c, 1] = rate
    return math.isfinite(rate) and math.isfinite(new_state[c, _INNOVATION]) and math.isfinite(new_state[c, _HALF])


@njit(cache=True, error_model="numpy")
def worst_case_rows(state, y, params, new_state, out, shared):
    """:func:`_channel_step` on every channel, in the calling convention of the registered steps
    (:func:`smo_gym.observers._kernels.register_step`: measurements known finite, ``out`` (N, 2), ``shared``: one
    parameter row for every channel); ``-2 - c`` for the first channel ``c`` that became non-finite, else ``-1``."""
    status = -1
    for c in range(y.shape[0]):
        if not _channel_step(state, y[c], params[0 if shared else c], new_state, out, c) and status == -1:
            status = -2 - c
    return status


_STEP = _kernels.register_step(worst_case_rows)


def best_worst_case_error(dt, lipschitz, noise, window=None):
    r""":math:`E_m = \min_{1 \le j \le m}\bigl(2\epsilon/(jh) + Ljh/2\bigr)`: the error that the best lag of the
    window guarantees, the worst case over all signals and noise of :class:`WorstCaseOptimal` (module notes).

    Broadcasts ``lipschitz`` and ``noise``; ``window`` ``m`` defaults to :func:`default_window`. It tends to
    :math:`2\sqrt{\epsilon L}` for :math:`h \to 0`, and is :math:`Lh/2` without noise.
    """
    lipschitz, noise = np.broadcast_arrays(np.asarray(lipschitz, float), np.asarray(noise, float))
    m = default_window(dt, lipschitz, noise) if window is None else np.broadcast_to(window, lipschitz.shape)
    j = np.arange(1, int(np.max(m)) + 1, dtype=float)
    r = 2.0 * noise[..., None] / (j * dt) + 0.5 * lipschitz[..., None] * j * dt
    return np.min(np.where(j <= np.asarray(m)[..., None], r, np.inf), axis=-1)


def default_window(dt, lipschitz, noise) -> np.ndarray:
    r"""The window :math:`m = \lceil 2\sqrt{\epsilon/L}/h\rceil` (at least 1, at most :data:`MAX_WINDOW`), which
    holds the lag of the smallest :math:`r_j` (module notes); an int array of the broadcast shape."""
    lipschitz, noise = np.broadcast_arrays(np.asarray(lipschitz, float), np.asarray(noise, float))
    lag = np.ceil(2.0 * np.sqrt(noise / lipschitz) / dt)
    return np.clip(np.nan_to_num(lag, nan=1.0, posinf=MAX_WINDOW), 1, MAX_WINDOW).astype(int)


def bounded_noise(std, resolution=0.0) -> np.ndarray:
    r"""A noise *bound* from a calibrated standard deviation: :math:`q/2 + 3\sqrt{\max(\sigma^2 - q^2/12, 0)}`.

    A bounded-noise method needs :math:`|\eta| \le \epsilon`, while :class:`smo_gym.calibration.Calibration` knows the
    standard deviation :math:`\sigma` of the measurement error, quantization (step ``q``, uniform, variance
    :math:`q^2/12`) included. The quantization error is bounded by :math:`q/2`; the rest is taken Gaussian and
    bounded at three standard deviations (exceeded by 0.27 % of the samples: the certificate of
    :class:`WorstCaseOptimal` then fails at a few samples, and the intervals' intersection reports it by an
    infinite bound where it empties).
    """
    std, resolution = np.broadcast_arrays(np.asarray(std, float), np.asarray(resolution, float))
    gaussian = np.sqrt(np.maximum(std**2 - resolution**2 / 12.0, 0.0))
    return 0.5 * resolution + 3.0 * gaussian


def _bounded_noise_rule(cls, calibration, order, kwargs):
    r"""``lipschitz`` = the worst-case bound of :math:`|f''|` per channel, ``noise`` = :func:`bounded_noise` of the
    calibrated standard deviation and quantization step per channel."""
    defaults = {
        "lipschitz": calibration.bound(order),
        "noise": bounded_noise(calibration.noise, calibration.resolution),
    }
    return cls(dt=calibration.dt, **{**defaults, **kwargs})


@register_observer(
    "worst-case-optimal",
    steps=(_STEP,),
    bound=2,
    calibrate=_bounded_noise_rule,
    given=(("lipschitz",),),
    examples=(dict(lipschitz=5.0, noise=1e-3), dict(lipschitz=5.0)),
)
class WorstCaseOptimal(Observer):
    r"""A sampled differentiator with the best worst-case accuracy ([HSAG21], [SH23]; module notes).

    It attains the smallest worst-case error any sampled differentiator can guarantee, the accuracy [HSAG21] claim
    for theirs, but it is not their linear program: the derivative is the midpoint of the intersection of the
    intervals that each lag ``j = 1..m`` of the window gives under :math:`|f''| \le L` and
    :math:`|\eta| \le \epsilon`; :attr:`certified_bound` is its half-width, an error bound valid at every sample
    (on typical data wider than the tightest the window allows). Without a noise bound (``noise=None``) it is
    [ASHG25]'s: the noise bound estimated from the window, and the difference quotient over the lag that estimate
    makes best. The value estimate is the measurement itself (nothing is filtered).

    Parameters
    ----------
    dt : float
        Sampling step ``h > 0``.
    lipschitz : float or array_like
        ``L >= |f''|``, per channel if an array.
    noise : float or array_like or None
        :math:`\epsilon \ge |\eta_k|`, the noise bound (not a standard deviation: :func:`bounded_noise` converts
        one), per channel if an array; 0 for exact samples. ``None``: estimated online from the window (the chord
        rule of [ASHG25], module notes).
    window : int, optional
        ``m``, the largest lag used (samples), in ``[1, MAX_WINDOW]``. Default: with ``noise``,
        :func:`default_window` per channel (the lag of the best single bound; more lags only narrow the
        intersection, at ``O(m)`` per sample); with ``noise=None``, :data:`DEFAULT_ESTIMATION_WINDOW`, the ``W``
        over which the noise bound is estimated (``O(W^2)`` per sample); [ASHG25] size it from an upper bound
        :math:`\bar\epsilon` of the noise, :math:`\lceil\sqrt{2\bar\epsilon/(Lh^2)} + 1\rceil`.
    discretization : {"exact"}
        The differentiator is a discrete-time estimator.
    wrap : bool or array_like of bool, optional
        Channels measured as angles modulo ``2 pi`` (see :class:`~smo_gym.observers.Observer`).

    Notes
    -----
    Until ``m`` samples have come after a reset, the lags available are used (after one sample, the backward
    difference). A reset with ``derivatives`` reports them at the reset sample only: the estimate depends on the
    window's samples alone. The step is a registered compiled step (:func:`worst_case_rows`): ``run``,
    ``differentiate`` and the wrappers call it once per block of samples. It costs ``O(m)`` per channel and sample
    with a noise bound and ``O(W^2)`` with ``noise=None`` (3,000 samples on eight channels: 3 ms and 30 ms).
    """

    discretizations = ("exact",)
    self_starting = True  # its estimate is a difference over the samples it holds

    @check_keywords
    def __init__(
        self,
        dt: float,
        lipschitz=1.0,
        noise=None,
        *,
        window: int | None = None,
        discretization: str | None = None,
        wrap=None,
    ):
        super().__init__(dt, 1, discretization, wrap)
        check_positive_array("lipschitz", lipschitz)  # validate now, not at reset
        if noise is not None:
            check_nonnegative_array("noise", noise)
        self.lipschitz, self.noise = lipschitz, noise
        self.window = None if window is None else check_int_in_range("window", window, 1, MAX_WINDOW)

    @property
    def _kernel(self):
        return _STEP.kernel

    def _channel_params(self, shape):
        lipschitz = self._per_channel("lipschitz", self.lipschitz, shape)
        if self.noise is None:
            eps = np.full(lipschitz.shape, -1.0)  # the step estimates it
            window = np.full(lipschitz.shape, self.window or DEFAULT_ESTIMATION_WINDOW)
        else:
            try:
                eps = np.broadcast_to(check_nonnegative_array("noise", self.noise), shape).reshape(-1)
            except ValueError:
                raise ValueError(
                    f"expected noise broadcastable to the measurement shape {shape}, actual value: shape "
                    f"{np.shape(self.noise)}"
                ) from None
            window = default_window(self.dt, lipschitz, eps) if self.window is None else np.full(eps.shape, self.window)
        return np.column_stack([np.full(lipschitz.shape, self.dt), lipschitz, eps, window.astype(float)])

    def _state_width(self) -> int:
        """Columns of the state: six scalars, then the last ``m + 1`` samples, ``m`` the largest window of any
        channel (what :meth:`_channel_params` gives them, from the same attributes)."""
        if self.window is not None:
            window = self.window
        elif self.noise is None:
            window = DEFAULT_ESTIMATION_WINDOW
        else:
            window = int(np.max(default_window(self.dt, self.lipschitz, self.noise)))
        return _BUFFER + window + 1

    def _initial_state(self, y0, params):
        """Value ``y0``, zero derivative, no certificate, one sample held (``y0``, the newest of the buffer)."""
        state = np.zeros((y0.shape[0], _BUFFER + int(np.max(params[:, _WINDOW])) + 1))
        state[:, _VALUE] = y0
        state[:, _HALF] = -1.0
        state[:, _NOISE] = np.maximum(params[:, _EPS], 0.0)
        state[:, _COUNT] = 1.0
        state[:, -1] = y0
        return state

    def _innovation_column(self) -> int:
        return _INNOVATION

    @property
    def certified_bound(self) -> np.ndarray:
        r"""The guaranteed error bound of the last derivative estimate, shape ``(..., n_channels)``: the half-width
        :math:`B_k` of the intersection (module notes). ``inf`` at a reset, and where the window's data contradict
        the bounds (the intersection is empty: an impact beyond ``L``, noise beyond :math:`\epsilon`). With
        ``noise=None`` it is the bound :math:`r_{\hat\jmath_k}` of the lag used, drawn with the estimated noise level:
        a certificate only if the noise is no larger.
        """
        self._require_reset()
        half = self._state[:, _HALF].reshape(self._shape)
        return np.where(half >= 0.0, half, np.inf)

    @property
    def noise_estimate(self) -> np.ndarray:
        r"""The noise bound the last update used, shape ``(..., n_channels)``: ``noise``, or with ``noise=None`` the
        estimate :math:`\hat\epsilon_k \le \epsilon` (module notes)."""
        self._require_reset()
        return self._state[:, _NOISE].reshape(self._shape).copy()

    def __repr__(self) -> str:
        wrap = "" if self.wrap is None else f", wrap={self.wrap!r}"
        window = "" if self.window is None else f", window={self.window}"
        return f"{type(self).__name__}(dt={self.dt}, lipschitz={self.lipschitz!r}, noise={self.noise!r}{window}{wrap})"
