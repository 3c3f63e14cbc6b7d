r"""Calibration of observer gains from data: the noise level, derivative bounds, and the default gain rules.

Arrays only (no Gymnasium, no MuJoCo): :func:`smo_gym.differentiate` calibrates from the recorded signal itself,
the Gymnasium wrapper from a rollout of its environment (``smo_gym.wrappers.sensing``); both turn the numbers
into gains with :func:`default_observer`.

Noise level
-----------
The ``n``-th difference :math:`\Delta^n y_k = \sum_{j=0}^{n} (-1)^j \binom{n}{j} y_{k-j}` of white noise of standard
deviation :math:`\sigma` has standard deviation :math:`\sigma\sqrt{\binom{2n}{n}}` (the sum of the squared
binomial coefficients), while a smooth signal contributes only :math:`\tau^n f^{(n)}`. :func:`noise_std` takes the
median absolute deviation of :math:`\Delta^n y` (robust to the rare large differences of impacts and outliers),
scales it to a standard deviation (1.4826 for Gaussian data) and divides by :math:`\sqrt{\binom{2n}{n}}`
(Donoho and Johnstone 1994 use the same robust scale on wavelet coefficients).

Derivative bounds
-----------------
An order-``r`` differentiator needs a bound on :math:`|f^{(r+1)}|` (:func:`bound_order`). A difference quotient
at the sampling step is dominated by the noise (its noise grows like :math:`\tau^{-r}`), so
:func:`derivative_bound` uses the lag-``s`` difference :math:`\Delta_s^r y / (s\tau)^r` (the ``r``-th difference
of the signal decimated by ``s``, at every phase) and doubles ``s`` until the noise part, at most
:math:`3\sigma\sqrt{\binom{2r}{r}}/(s\tau)^r`, is below a quarter of the difference quotient's ``quantile`` (so
that the noise inflates the bound by a few per cent only). The bound is
``safety`` times that quantile, per channel, as the wrapper does with its rollout: a high quantile rather than the
maximum, since impacts produce rare impulsive peaks that a maximum would turn into a huge, noise-amplifying gain,
and a safety factor for what the sample did not show. Decimation averages the derivative over ``s r`` samples,
which lowers narrow peaks: the price of separating them from noise. The lags stop at a span of half the record; a
channel whose derivative no lag shows above the noise gets the quotient at the last one: mostly noise, a bound on
the safe side.

Worst cases and typical levels
------------------------------
Gains answer two different questions. A sliding-mode differentiator is exact only while its ``lipschitz``
parameter bounds :math:`|f^{(r)}|` everywhere [Lev03], so it needs the *worst case* above. A Kalman filter's process
noise is the spectral density of the noise that drives its model [BSL01]: with the jerk of the constant-acceleration
model white of density ``q``, the acceleration changes by a variance ``q tau`` per sample, so the *typical* (RMS)
jerk ``J`` at the sampling step gives :math:`q = J^2\tau`. Tuned from the worst case instead, a Kalman filter
trusts the measurements about as much as a backward difference does. :class:`Calibration` holds both, per
channel, with the sensor's noise level and quantization step; :func:`derivative_rms` estimates the typical level
from noisy samples as :func:`derivative_bound` does the worst case (the mean square of the lag-``s`` quotient
minus its known noise part).

Floors
------
A level of zero would make a gain zero or a formula divide by it (a constant channel, a noise-free one), so levels
are raised to floors: for the wrapper's joints (radians and metres) :data:`BOUND_FLOOR` for the derivative levels
(and a Kalman filter's prior) and :data:`NOISE_FLOOR` for the noise level. A recorded signal comes in any units,
and floors fixed in one unit act on its small-amplitude records only (a micrometre vibration in metres: its noise
level raised a thousandfold, its estimated velocity off by more than its amplitude), so
:func:`calibration_of_signal` takes them relative to each channel's velocity bound ``V``: ``BOUND_FLOOR * V``
(times one second, the wrapper's floor for a joint moving at 1 rad/s) for the derivative levels and
:data:`RECORD_NOISE_FLOOR` ``* V * tau`` for the noise level, a billionth of the largest motion in one sample: below
any sensor that is not noise-free, and above the rounding of the samples themselves unless the record's values are
ten million times its motion in one sample. A record multiplied by ``c`` is then calibrated to levels multiplied by
``c``. Measured on noise-free sums of sines, cubics and constants at 1 and 10 ms (every family, velocity RMSE after
0.5 s) against a millionth: the Kalman filters' error 0.03-0.68 times as large, the high-gain families' 0.82-0.97
times, ``"auto"``'s 0.5 times on the cubic at 1 ms, and no family's larger but at a constant's rounding (1e-10). (A
millionth was the floor while the Kalman filters' covariance recursion needed it: in double precision it lost its
positivity below a measurement variance of about 1e-15 times the predicted one, which their U-D factors do not.)

On records longer than :data:`MAX_SAMPLES` (:math:`2^{17}`) differences, medians and quantiles are taken over that
many differences drawn at random with a fixed seed (deterministic, and a fraction of the cost on long records).

References
----------
.. [BSL01] Y. Bar-Shalom, X. R. Li and T. Kirubarajan, *Estimation with Applications to Tracking and
   Navigation*, Wiley 2001, section 6.2.3 (continuous white-noise jerk model).
.. [DJ94] D. L. Donoho and I. M. Johnstone, "Ideal spatial adaptation by wavelet shrinkage", Biometrika 81(3),
   1994 (the median absolute deviation as the noise scale of high-pass coefficients).
.. [Lev03] A. Levant, "Higher-order sliding modes, differentiation and output-feedback control",
   Int. J. Control 76(9-10), 2003 (the differentiators' gains from a bound on the next derivative).
"""

from __future__ import annotations

import inspect
from collections.abc import Mapping
from dataclasses import dataclass, field
from math import comb, log

import numpy as np

from ._validation import (
    as_real_array,
    check_int_at_least,
    check_int_in_range,
    check_nonnegative,
    check_positive,
    check_positive_array,
    check_real_in_range,
    did_you_mean,
)
from .observers import FAMILIES, OBSERVERS, Observer, make_observer

__all__ = [
    "Calibration",
    "bound_order",
    "calibration_from_velocities",
    "calibration_of_signal",
    "default_observer",
    "derivative_bound",
    "derivative_rms",
    "needs_calibration",
    "noise_std",
    "quantization_step",
]

#: median absolute deviation -> standard deviation of a Gaussian, 1 / Phi^-1(3/4)
MAD_TO_STD = 1.482602218505602
#: smallest noise level a gain formula divides by, for the wrapper's joints (module notes, "Floors")
NOISE_FLOOR = 1e-6
#: a recorded signal's smallest noise level, relative to its largest motion in one sample (module notes, "Floors")
RECORD_NOISE_FLOOR = 1e-9
#: smallest derivative level, for the wrapper's joints (a record's: times its velocity bound): a constant channel
#: still gets a positive gain
BOUND_FLOOR = 1e-3
#: longer records are calibrated on this many differences drawn at random (see :func:`_lag_difference`)
MAX_SAMPLES = 2**17


def _time_series(y, name: str = "y") -> np.ndarray:
    """``y`` as a C-ordered float64 array of shape ``(T, ...)`` with ``T >= 1``, at least one channel and finite
    entries (one memory layout: the levels are means, whose sums NumPy orders by the layout, and a level one ulp
    apart can move a sliding-mode recursion visibly)."""
    arr = np.ascontiguousarray(as_real_array(name, y))  # complex, bool or date values are refused, not converted
    if arr.ndim == 0 or arr.shape[0] == 0 or arr.size == 0:
        raise ValueError(
            f"expected {name} with shape (T, ...), T >= 1 and at least one channel, actual value: shape {arr.shape}"
        )
    if not np.isfinite(arr).all():
        index = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
        raise ValueError(f"expected finite values in {name}, actual value: {arr[index]!r} at index {index}")
    return arr


def _check_step(dt: float, T: int, r: int) -> None:
    """The lag quotients divide by ``(s dt)^r`` for lags ``s`` from 1 to the record's length ``T``: refuse a ``dt``
    for which that power leaves the float range (it would overflow, or divide by zero)."""
    if not (r * log(dt) > -700.0 and r * log(T * dt) < 700.0):
        raise ValueError(
            f"expected dt for which (lag dt)^{r} is a float for every lag of the {T} samples, actual value: {dt!r}"
        )


def _lag_difference(y: np.ndarray, order: int, lag: int) -> np.ndarray:
    r""":math:`\Delta_s^r y` along axis 0 (``r = order``, ``s = lag``), at every sample or at a random subset.

    Row ``k`` is :math:`\sum_j (-1)^{r-j}\binom{r}{j} y_{k + j s}`, for ``k < T - r s``. Records with more than
    :data:`MAX_SAMPLES` such rows give that many rows drawn at random (a fixed seed, so the calibration is
    deterministic): the median and the quantiles taken from them estimate those of all rows with a standard error
    of order :math:`1/\sqrt{131072}`, at a fraction of the cost (a random rather than a regular subset, which a
    periodic signal could alias).
    """
    n = y.shape[0] - order * lag
    if n > MAX_SAMPLES:
        rows = np.sort(np.random.default_rng(0).integers(0, n, MAX_SAMPLES))  # sorted: gathered in memory order
        parts = [np.take(y, rows + j * lag, axis=0) for j in range(order + 1)]
    else:
        parts = [y[j * lag : j * lag + n] for j in range(order + 1)]
    with np.errstate(over="ignore", invalid="ignore"):
        for _ in range(order):
            parts = [b - a for a, b in zip(parts[:-1], parts[1:], strict=True)]
    if not np.isfinite(parts[0]).all():  # finite samples near the float limit: their differences overflow
        raise ValueError(
            f"expected samples whose differences of order {order} are finite, actual value: largest |y| "
            f"{np.max(np.abs(y)):.3g}; rescale the signal"
        )
    return parts[0]


def _first_clear_lag(y: np.ndarray, r: int, dt: float, statistic) -> np.ndarray:
    r"""A statistic of the lag-``s`` difference quotient at the first lag ``s = 1, 2, 4, ...`` where the noise no
    longer hides it, per channel (:func:`derivative_bound`, :func:`derivative_rms`).

    ``statistic(diff, step) -> (value, clear)`` receives :math:`\Delta_s^r y` and :math:`s\tau` and returns
    the value per channel and whether the noise part is small enough there. Lags double until every channel is
    clear or the next lag would average over more than half of the record; a channel never clear gets the value
    at the last lag. (Stopped at an eighth, a slow cubic's jerk under noise 1e-3 to 1e-2 was never clear, and its
    bound, 11 to 284 times the true one, mostly noise: ``scripts/bench_signals.py``; at half it shows, 2.1 to 6
    times, the safety factor 2 included.)
    """
    T = y.shape[0]
    result = np.full(y.shape[1:], np.nan)
    lag = 1
    while True:
        value, clear = statistic(_lag_difference(y, r, lag), lag * dt)
        settled = np.isnan(result) & clear
        result[settled] = value[settled]
        if 2 * lag * r > T // 2 or not np.isnan(result).any():
            break
        lag *= 2
    return np.where(np.isnan(result), value, result)


def noise_std(y, *, order: int = 4) -> np.ndarray:
    r"""Robust estimate of the standard deviation of white measurement noise, per channel.

    .. math::
        \hat\sigma = \frac{1.4826\,\mathrm{median}_k\bigl|\Delta^n y_k - \mathrm{median}(\Delta^n y)\bigr|}
        {\sqrt{\binom{2n}{n}}}

    Parameters
    ----------
    y : array_like, shape (T, ...)
        Samples along axis 0; every trailing index is a channel.
    order : int
        ``n``, the order of the difference (3 or 4 suit signals sampled fast against their bandwidth: the
        signal's share :math:`\tau^n f^{(n)}` is then far below the noise). ``T > n`` is required.

    Returns
    -------
    ndarray, shape (...)
        :math:`\hat\sigma` per channel (0 for noise-free polynomial data of degree below ``n``).

    Notes
    -----
    Gaussian noise is estimated without bias. Other distributions are biased by the ratio of their difference's
    MAD to standard deviation against the Gaussian's: uniform noise (bounded, the sliding-mode setting) and
    dithered quantization come out about 6 % high (measured with ``n = 3`` and ``4``). A quantized signal that
    stands still in most samples is a staircase whose differences are mostly zero: the median then misses the
    quantization error, so the estimate is floored at the rounding error of one count, :math:`\Delta/\sqrt{12}`,
    with :math:`\Delta` the step of the lattice its samples lie on (:func:`quantization_step`).
    """
    n = check_int_in_range("order", order, 1, 16)
    y = _time_series(y)
    if y.shape[0] <= n:
        raise ValueError(f"expected more than order = {n} samples, actual value: {y.shape[0]}")
    d = _lag_difference(y, n, 1)
    mad = np.median(np.abs(d - np.median(d, axis=0)), axis=0)
    return np.maximum(MAD_TO_STD * mad / np.sqrt(comb(2 * n, n)), _staircase_std(y))


def _staircase_std(y: np.ndarray) -> np.ndarray:
    r"""Floor of the noise level of quantized channels that stand still in most samples.

    Such a record is a staircase: most first differences are exactly zero, so the median of every difference misses
    the quantization error. Where more than half of them are zero, the error of rounding to one count
    :math:`\Delta` has the standard deviation :math:`\Delta/\sqrt{12}`; other channels get 0. The count is the
    step of the lattice the samples lie on (:func:`quantization_step`), not a typical move: a joint that rests
    most of the time and moves by several counts per sample in between is no noisier than a slow one. With too
    few moves to show the lattice, the median of the nonzero differences stands in for it.
    """
    d = np.abs(np.diff(y, axis=0)).reshape(y.shape[0] - 1, -1)
    floor = np.zeros(d.shape[1])
    stairs = np.flatnonzero(np.mean(d == 0.0, axis=0) > 0.5)
    if stairs.size:
        lattice = quantization_step(y.reshape(y.shape[0], -1)[:, stairs])
        for c, count in zip(stairs, lattice, strict=True):
            steps = d[d[:, c] > 0.0, c]
            if steps.size:
                floor[c] = (count if count > 0.0 else np.median(steps)) / np.sqrt(12.0)
    return floor.reshape(y.shape[1:])


def quantization_step(y, *, tolerance: float = 1e-6, share: float = 0.99, minimum: int = 20) -> np.ndarray:
    r"""The quantization step of a recorded signal, per channel, or 0 where the samples are not on a lattice.

    A quantized channel takes values :math:`y_k = c + n_k\Delta` with integers :math:`n_k`, so every difference
    :math:`y_k - y_{k-1}` is a multiple of :math:`\Delta` and the smallest nonzero one is :math:`\Delta` itself as
    soon as the signal ever moves by one count. The estimate is that smallest difference where at least
    ``share`` of the nonzero differences (and ``minimum`` of them) are multiples of it within ``tolerance``
    (relative: the rounding error of the stored values); noise on top of the quantization, or none at all, gives
    differences that are not, and the estimate 0.

    Parameters
    ----------
    y : array_like, shape (T, ...)
        Samples along axis 0; every trailing index is a channel.

    Returns
    -------
    ndarray, shape (...)
    """
    tolerance = check_nonnegative("tolerance", tolerance)
    share = check_real_in_range("share", share, 0.0, 1.0, low_open=True)
    minimum = check_int_at_least("minimum", minimum, 1)
    y = _time_series(y)
    with np.errstate(over="ignore"):
        d = np.abs(np.diff(y, axis=0)).reshape(y.shape[0] - 1, y[0].size)  # (T - 1, channels), T = 1 too
    if not np.isfinite(d).all():
        raise ValueError(
            f"expected samples whose differences are finite, actual value: largest |y| {np.max(np.abs(y)):.3g}; "
            "rescale the signal"
        )
    step = np.zeros(d.shape[1])
    for c in range(d.shape[1]):
        moves = d[d[:, c] > 0.0, c]
        if moves.size < minimum:
            continue
        q = moves.min()
        ratio = moves / q
        if np.mean(np.abs(ratio - np.round(ratio)) <= tolerance * np.maximum(ratio, 1.0)) >= share:
            step[c] = q
    return step.reshape(y.shape[1:])


def derivative_bound(
    y,
    dt: float,
    derivative: int,
    *,
    noise=None,
    quantile: float = 0.99,
    safety: float = 2.0,
    floor=BOUND_FLOOR,
) -> np.ndarray:
    r"""Bound on :math:`|f^{(r)}|` per channel from noisy samples of ``f`` (module notes).

    For lags ``s = 1, 2, 4, ...`` the difference quotients :math:`D_s = |\Delta_s^r y|/(s\tau)^r` are formed and the
    first ``s`` with :math:`3\hat\sigma\sqrt{\binom{2r}{r}}/(s\tau)^r \le \tfrac14\,Q_q(D_s)` is kept (each channel
    its own ``s``); the bound is :math:`\max(\text{safety}\cdot Q_q(D_s),\ \text{floor})`.

    Parameters
    ----------
    y : array_like, shape (T, ...)
        Samples along axis 0; every trailing index is a channel.
    dt : float
        Sampling step ``tau``.
    derivative : int
        ``r >= 1`` (2: acceleration, 3: jerk; :func:`bound_order` says which an observer needs).
    noise : float or array_like, optional
        :math:`\hat\sigma` per channel; default :func:`noise_std` of ``y``.
    quantile : float
        ``q`` in (0, 1]; 0.99 as the wrapper.
    safety : float
        Factor ``> 0`` on the quantile; 2 as the wrapper.
    floor : float or array_like
        Smallest bound returned, one or one per channel (a constant channel gets a positive gain).

    Returns
    -------
    ndarray, shape (...)
        The bound per channel.
    """
    dt = check_positive("dt", dt)
    r = check_int_in_range("derivative", derivative, 1, 8)
    safety = check_positive("safety", safety)
    floor = check_positive_array("floor", floor)
    if isinstance(quantile, bool) or not isinstance(quantile, (int, float, np.number)) or not 0.0 < quantile <= 1.0:
        raise ValueError(f"expected quantile in (0, 1], actual value: {quantile!r}")
    y = _time_series(y)
    T = y.shape[0]
    if r >= T:
        raise ValueError(f"expected more than derivative = {r} samples, actual value: {T}")
    _check_step(dt, T, r)
    sigma, floor = _noise_per_channel(noise, y), _per_channel("floor", floor, y)
    gain = 3.0 * np.sqrt(comb(2 * r, r))  # the noise part of D_s, about three of its standard deviations

    def quantile_of(diff, step):
        q = np.quantile(np.abs(diff), quantile, axis=0) / step**r
        return q, gain * sigma / step**r <= 0.25 * q

    # channels whose noise never fell below the quantile (no visible signal): the smoothest quotient seen
    result = _first_clear_lag(y, r, dt, quantile_of)
    with np.errstate(over="ignore"):
        bound = np.maximum(safety * result, floor)
    if not np.all(np.isfinite(bound)):
        raise ValueError(
            f"expected samples whose derivative of order {r} has a finite bound at dt={dt}, actual value: the "
            f"bound overflows ({np.max(result):.3g} before the safety factor {safety}); rescale the signal"
        )
    return bound


def _noise_per_channel(noise, y: np.ndarray) -> np.ndarray:
    """``noise`` (default :func:`noise_std` of ``y``) checked and broadcast to the channel shape of ``y``."""
    if noise is None:
        return noise_std(y) if y.shape[0] > 4 else np.zeros(y.shape[1:])  # four samples cannot show the noise
    sigma = as_real_array("noise", noise)
    if not np.all(np.isfinite(sigma) & (sigma >= 0.0)):
        raise ValueError(f"expected noise >= 0 and finite everywhere, actual value: {noise!r}")
    return _per_channel("noise", sigma, y)


def _per_channel(name: str, value: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``value`` broadcast to the channel shape of ``y``, or a ``ValueError`` naming both shapes."""
    try:
        return np.broadcast_to(value, y.shape[1:])
    except ValueError:
        raise ValueError(
            f"expected {name} broadcastable to the channel shape {y.shape[1:]}, actual value: shape {value.shape}"
        ) from None


#: :func:`derivative_rms` clips the difference quotients at :data:`WINSOR_FACTOR` times this quantile of them:
#: robust to gross errors in up to 1 % of them
WINSOR_QUANTILE = 0.99
#: the factor on that quantile, :func:`derivative_bound`'s safety factor: beyond the worst-case bound is not the signal
WINSOR_FACTOR = 2.0


def derivative_rms(y, dt: float, derivative: int, *, noise=None, floor=BOUND_FLOOR) -> np.ndarray:
    r"""Typical (root-mean-square) level of :math:`f^{(r)}` per channel from noisy samples of ``f``.

    White noise of standard deviation :math:`\sigma` adds :math:`\sigma^2\binom{2r}{r}/(s\tau)^{2r}` to the mean
    square of the lag-``s`` difference quotient :math:`\Delta_s^r y/(s\tau)^r`. For ``s = 1, 2, 4, ...`` the first
    lag at which that part is at most a quarter of the mean square is kept (each channel its own ``s``, as in
    :func:`derivative_bound`), and the level is :math:`\sqrt{\overline{D_s^2} - \sigma^2\binom{2r}{r}/(s\tau)^{2r}}`,
    floored at ``floor``.

    The mean square is taken of the quotients clipped at :data:`WINSOR_FACTOR` times their :data:`WINSOR_QUANTILE`
    quantile (the worst-case bound of :func:`derivative_bound`: beyond it is not the signal), so that a sensor's
    rare gross errors (each one enters ``r + 1`` differences) do not make the level: one wrong sample in a
    thousand made the jerk level of a sum of sines 10**6 times too large, and the Kalman filter built from it
    followed every error. Clean data is not clipped: Gaussian quotients exceed twice their 99th percentile with
    probability 3e-7, smooth motion's bounded ones never. (Clipping at the percentile itself biased noise-dominated
    levels: 2 % less mean square minus the whole noise part halved the cubic's jerk level in
    ``scripts/bench_signals.py``.)

    Parameters
    ----------
    y : array_like, shape (T, ...)
        Samples along axis 0; every trailing index is a channel.
    dt : float
        Sampling step ``tau``.
    derivative : int
        ``r >= 1``.
    noise : float or array_like, optional
        :math:`\sigma` per channel; default :func:`noise_std` of ``y``.
    floor : float or array_like
        Smallest level returned, one or one per channel.

    Returns
    -------
    ndarray, shape (...)
    """
    dt = check_positive("dt", dt)
    r = check_int_in_range("derivative", derivative, 1, 8)
    floor = check_positive_array("floor", floor)
    y = _time_series(y)
    T = y.shape[0]
    if r >= T:
        raise ValueError(f"expected more than derivative = {r} samples, actual value: {T}")
    _check_step(dt, T, 2 * r)  # the mean square divides by (s dt)^(2r)
    sigma, floor = _noise_per_channel(noise, y), _per_channel("floor", floor, y)
    noise_factor = sigma**2 * comb(2 * r, r)

    def mean_square_of(diff, step):
        quotient = np.abs(diff) / step**r
        clipped = np.minimum(quotient, WINSOR_FACTOR * np.quantile(quotient, WINSOR_QUANTILE, axis=0))
        mean_square, noise_part = np.mean(clipped**2, axis=0), noise_factor / step ** (2 * r)
        return mean_square - noise_part, noise_part <= 0.25 * mean_square

    with np.errstate(over="ignore", invalid="ignore"):
        result = _first_clear_lag(y, r, dt, mean_square_of)
        level = np.maximum(np.sqrt(np.maximum(result, 0.0)), floor)
    if not np.all(np.isfinite(level)):
        raise ValueError(
            f"expected samples whose derivative of order {r} has a finite mean square at dt={dt}, actual value: "
            "it overflows; rescale the signal"
        )
    return level


def _frozen(name: str, value, shape: tuple[int, ...] | None, infinite: bool = False) -> np.ndarray:
    """``value`` as a read-only float64 array of ``shape`` (or its own shape), >= 0 and finite (or ``inf`` too)."""
    arr = as_real_array(name, value, copy=True)  # a typed error for strings, complex numbers, ragged nestings
    if shape is not None:
        try:
            arr = np.array(np.broadcast_to(arr, shape))
        except ValueError:
            raise ValueError(f"expected {name} of the channel shape {shape}, actual value: shape {arr.shape}") from None
    if not np.all((np.isfinite(arr) | (infinite & (arr == np.inf))) & (arr >= 0.0)):
        raise ValueError(f"expected {name} finite and >= 0 everywhere, actual value: {value!r}")
    arr.flags.writeable = False
    return arr


@dataclass(frozen=True)
class Calibration:
    r"""What observer gains need to know about the signals they differentiate, per channel (module notes).

    Made by :func:`calibration_of_signal` (a recorded signal, :func:`smo_gym.differentiate`) or
    :func:`calibration_from_velocities` (the wrapper's rollouts of its environment); read by every family's gain rule
    through :func:`default_observer`.

    Attributes
    ----------
    dt : float
        The sampling step ``tau``.
    bounds : mapping of int to ndarray, shape (...)
        Worst case: ``bounds[r]`` bounds :math:`|f^{(r)}|` (a high quantile times a safety factor), what
        sliding-mode gains need.
    typical : mapping of int to ndarray, shape (...)
        Typical level: ``typical[r]`` is the RMS of :math:`f^{(r)}` at the sampling step, what linear and Kalman
        gains need.
    noise : ndarray, shape (...)
        Standard deviation of the measurement's random error (noise and quantization together; ``inf`` is kept
        for a sensor model whose variance overflows).
    resolution : ndarray, shape (...)
        The quantization step (0 where there is none).
    noise_floor : ndarray, shape (...)
        The smallest noise level the gain formulas use (:attr:`noise_levels`): :data:`NOISE_FLOOR` for the
        wrapper's joints, :data:`RECORD_NOISE_FLOOR` times a recorded signal's largest motion in one sample
        (module notes, "Floors").
    unit : ndarray, shape (...)
        The size of one unit of the signal, for the weights whose dimension is a power of it (the high-degree terms
        of URED, the uniform Levant differentiator, the eigenvalue-map HOSM and the implicit-Lyapunov-function
        differentiators): 1 for the wrapper's joints
        (radians, metres), a recorded signal's velocity bound times one second, so that its estimates do not
        depend on its units.
    initial : mapping of int to ndarray, shape (...)
        Where the signals start: ``initial[r] > 0`` is the RMS of :math:`f^{(r)}` at the first sample of an episode
        (1: the velocity, 2: the acceleration), over the episodes of a rollout; what a Kalman filter's prior needs
        (:func:`default_observer`). For a recorded signal, whose start is unknown, the bounds of those derivatives
        (:func:`calibration_of_signal`): a prior as wide as anything the signal does, in its own units.
    """

    dt: float
    bounds: Mapping[int, np.ndarray]
    typical: Mapping[int, np.ndarray]
    noise: np.ndarray
    resolution: np.ndarray = field(default=0.0)
    initial: Mapping[int, np.ndarray] = field(default_factory=dict)
    noise_floor: np.ndarray = field(default=NOISE_FLOOR)
    unit: np.ndarray = field(default=1.0)

    def __post_init__(self):
        object.__setattr__(self, "dt", check_positive("dt", self.dt))
        for name in ("bounds", "typical", "initial"):
            levels = getattr(self, name)
            if not isinstance(levels, Mapping):
                raise TypeError(f"expected {name} as a mapping of derivative order to array, actual value: {levels!r}")
        # the channel shape: the noise's, or the levels' where the noise is one number for all channels
        # (a sensor model whose variance overflows says inf; its first measurement is refused, not its calibration)
        noise = _frozen("noise", self.noise, None, infinite=True)
        levels = [np.shape(v) for v in (*self.bounds.values(), *self.typical.values())]
        shape = noise.shape if noise.ndim or not levels else levels[0]
        object.__setattr__(self, "noise", _frozen("noise", noise, shape, infinite=True))
        object.__setattr__(self, "resolution", _frozen("resolution", self.resolution, shape))
        object.__setattr__(self, "noise_floor", _frozen("noise_floor", self.noise_floor, shape))
        object.__setattr__(self, "unit", _frozen("unit", self.unit, shape))
        for name in ("noise_floor", "unit"):
            if not np.all(getattr(self, name) > 0.0):
                raise ValueError(f"expected {name} > 0 everywhere, actual value: {getattr(self, name)!r}")
        for name in ("bounds", "typical", "initial"):
            levels = getattr(self, name)
            frozen = {
                check_int_in_range(f"{name} order", r, 1, 8): _frozen(f"{name}[{r}]", v, shape)
                for r, v in levels.items()
            }
            object.__setattr__(self, name, frozen)
        if not all(np.all(level > 0.0) for level in self.initial.values()):
            raise ValueError(f"expected initial levels > 0 (a Kalman filter's prior), actual value: {self.initial!r}")

    def bound(self, order: int) -> np.ndarray:
        """Worst-case bound on :math:`|f^{(r)}|` per channel, ``r = order``."""
        return self._level(self.bounds, "bounds", order)

    def rms(self, order: int) -> np.ndarray:
        """Typical (RMS) level of :math:`f^{(r)}` per channel, ``r = order``."""
        return self._level(self.typical, "typical", order)

    @staticmethod
    def _level(levels: Mapping[int, np.ndarray], name: str, order: int) -> np.ndarray:
        if order not in levels:
            raise ValueError(
                f"expected a calibration with {name} of derivative order {order}, actual value: orders {sorted(levels)}"
            )
        return levels[order]

    def as_rows(self, orders) -> np.ndarray:
        """The levels as the rows of one array (the wrappers' cache stores it): ``bound(r)`` and ``rms(r)`` for each
        ``r`` of ``orders``, then ``initial[1]`` and ``initial[2]`` (NaN where unknown); shape
        ``(2 len(orders) + 2, ...)``. :meth:`from_rows` is its inverse."""
        start = [self.initial.get(r, np.full(self.noise.shape, np.nan)) for r in (1, 2)]
        return np.stack([*(level for r in orders for level in (self.bound(r), self.rms(r))), *start])

    @classmethod
    def from_rows(cls, rows, orders, dt: float, noise, resolution=0.0) -> Calibration:
        """The calibration whose :meth:`as_rows` ``(orders)`` are ``rows``, with the sensor's ``noise`` and
        ``resolution``."""
        rows, n = as_real_array("rows", rows), 2 * len(orders)
        if rows.ndim != 2 or rows.shape[0] not in (n, n + 2):  # + the two rows of initial levels, when known
            raise ValueError(
                f"expected rows of shape ({n} or {n + 2}, channels) for orders {list(orders)}, actual value: shape "
                f"{rows.shape}"
            )
        bounds, typical = dict(zip(orders, rows[:n:2], strict=True)), dict(zip(orders, rows[1:n:2], strict=True))
        initial = dict(enumerate(rows[n:], 1)) if np.isfinite(rows[n:]).all() else {}
        return cls(dt, bounds, typical, noise, resolution, initial)

    @property
    def noise_level(self) -> float:
        """The mean noise level over channels, floored at the mean :attr:`noise_floor` (for formulas that divide by
        it)."""
        return float(max(np.mean(self.noise), np.mean(self.noise_floor)))

    @property
    def noise_levels(self) -> np.ndarray:
        """The noise level per channel, floored at :attr:`noise_floor` (for gain formulas that divide by it)."""
        return np.maximum(self.noise, self.noise_floor)

    @property
    def measurement_variance(self) -> np.ndarray:
        """Variance of the measurement error per channel, the square of :attr:`noise_levels`."""
        return self.noise_levels**2


def calibration_of_signal(
    y, dt: float, orders, *, noise=None, resolution=None, quantile: float = 0.99, safety: float = 2.0
) -> Calibration:
    """The :class:`Calibration` of a recorded signal ``y`` (T, ...): :func:`derivative_bound` and :func:`derivative_rms`
    of each derivative order in ``orders``, with the noise level ``noise`` (default :func:`noise_std` of ``y``) and the
    quantization step ``resolution`` (default :func:`quantization_step` of ``y``: the sensor is unknown), with floors
    relative to each channel's velocity bound (module notes, "Floors"). A typical level of order ``r >= 3`` of which the
    record gives no estimate (:func:`derivative_rms` at its floor: the noise hides it, and the mean square of the
    difference quotient less its noise part is not above the floor's square) continues the two below it,
    ``rms(r-1)**2/rms(r-2)``: their ratio is the signal's frequency, and for a sine the result is exact. Where that
    difference is above it, it is kept: an unbiased estimate, if a noisy one. Records of ``r`` samples or fewer get the
    floors for order ``r``. Its :attr:`~Calibration.initial` levels, a Kalman filter's prior, are the bounds of the
    velocity and the acceleration: where the record starts is unknown, and a prior of fixed size would be narrow in
    large units (a velocity of 1e5 counts/s against a prior of 10) and keep the filter's first estimates from being the
    least-squares fits its settling time assumes."""
    y = _time_series(y)
    sigma = _noise_per_channel(noise, y)
    if np.max(sigma) > 1e150:  # its square, the measurement variance, would overflow (and every level after it)
        raise ValueError(
            f"expected a record whose noise level squares to a finite number (below 1e150), actual value: a noise "
            f"level of {float(np.max(sigma)):.3g}; rescale the record"
        )
    if resolution is None:
        resolution = quantization_step(y) if y.shape[0] > 1 else 0.0
    orders = [_bound_order(r) for r in orders]
    bounds, typical, velocity = {}, {}, None
    if y.shape[0] > 1:  # the velocity bound unfloored: the floors' unit
        velocity = derivative_bound(y, dt, 1, noise=sigma, quantile=quantile, safety=safety, floor=_TINY)
    speed = _floor_speed(velocity, y.shape[1:])
    floor = BOUND_FLOOR * speed
    for r in sorted({*orders, 1, 2}):
        if y.shape[0] <= r:
            bounds[r] = typical[r] = floor
            continue
        if r == 1:
            bounds[r] = np.maximum(velocity, floor)
        else:
            bounds[r] = derivative_bound(y, dt, r, noise=sigma, quantile=quantile, safety=safety, floor=floor)
        typical[r] = derivative_rms(y, dt, r, noise=sigma, floor=floor)
        if r >= 3 and {r - 1, r - 2} <= typical.keys():
            # no estimate (derivative_rms at its floor: the noise hides the level): the next term of the two
            # levels below, whose ratio is the signal's frequency (exact for a sine)
            unseen = typical[r] <= floor
            typical[r] = np.where(unseen, np.maximum(floor, typical[r - 1] ** 2 / typical[r - 2]), typical[r])
    initial = {r: bounds[r] for r in (1, 2)}
    noise_floor = RECORD_NOISE_FLOOR * speed * dt
    return Calibration(dt, bounds, typical, sigma, resolution, initial, noise_floor, speed * 1.0)


#: the smallest positive float64, the floor under which no level is taken as it is
_TINY = float(np.finfo(float).tiny)


def _floor_speed(velocity: np.ndarray | None, shape: tuple[int, ...]) -> np.ndarray:
    """The speed the floors of a record are relative to (module notes, "Floors"): its ``velocity`` bound per
    channel, in units per second; a channel that does not move takes the largest of the record, a record that does
    not move (or of one sample) 1."""
    if velocity is None:
        return np.ones(shape)
    largest = float(np.max(velocity))
    moves = velocity > 1e3 * _TINY  # a bound at the tiny floor is no motion
    return np.where(moves, velocity, largest if largest > 1e3 * _TINY else 1.0)


def _bound_order(r) -> int:
    """A derivative order a calibration can bound, 1 to 8 (an observer of order ``n`` needs ``n + 1`` of them)."""
    try:
        return check_int_in_range("order", r, 1, 8)
    except ValueError:
        raise ValueError(
            f"expected derivative orders in [1, 8] to bound (the gains of an observer of order n bound the "
            f"derivative n + 1, so n <= 7), actual value: {r!r}"
        ) from None


def calibration_from_velocities(
    episodes, dt: float, orders, *, noise, resolution=0.0, quantile: float = 0.99, safety: float = 2.0
) -> Calibration:
    r"""The :class:`Calibration` of joints whose velocities were sampled without noise (a simulator's rollouts).

    ``episodes`` holds arrays ``(T_i, nv)`` of the velocity sampled every ``dt``; backward differences give
    :math:`f^{(r)}` for each ``r`` in ``orders``. ``bounds[r] = safety * quantile(|f^(r)|)`` and ``typical[r]`` its
    RMS, per dof. Dofs that never moved (a pushed object, a goal) get the largest value of the model: they may be
    hit later, and a tiny gain would never catch up. Every value is floored at :data:`BOUND_FLOOR`. ``noise`` and
    ``resolution`` (per dof) are the sensor's. ``initial`` holds the RMS over episodes of the first velocity and
    of the first backward difference of it (episodes of two samples or more), floored at :data:`BOUND_FLOOR` too.
    """
    dt = check_positive("dt", dt)
    safety = check_positive("safety", safety)
    quantile = check_real_in_range("quantile", quantile, 0.0, 1.0, low_open=True)
    if not isinstance(episodes, (list, tuple)):
        raise TypeError(f"expected episodes to be a list of arrays (T_i, nv), actual value: {episodes!r:.80}")
    episodes = [as_real_array("episodes", V) for V in episodes]
    shapes = {V.shape[1:] for V in episodes}
    if (
        not episodes
        or any(V.ndim != 2 for V in episodes)
        or len(shapes) != 1
        or not np.isfinite(np.concatenate(episodes)).all()
    ):
        raise ValueError(
            "expected episodes to be finite arrays (T_i, nv) of the same nv, actual value: shapes "
            f"{[V.shape for V in episodes][:5]}"
        )
    bounds, typical = {}, {}
    starts = [V for V in episodes if len(V) >= 2]
    initial = (
        {
            1: np.maximum(np.sqrt(np.mean([V[0] ** 2 for V in starts], axis=0)), BOUND_FLOOR),
            2: np.maximum(np.sqrt(np.mean([((V[1] - V[0]) / dt) ** 2 for V in starts], axis=0)), BOUND_FLOOR),
        }
        if starts
        else {}
    )
    for r in sorted(set(orders)):
        r = _bound_order(r)
        diffs = [np.diff(V, n=r - 1, axis=0) / dt ** (r - 1) for V in episodes if len(V) >= r]
        if not diffs:
            raise ValueError(
                f"expected a rollout long enough to calibrate, actual value: {len(episodes)} episode(s) "
                f"shorter than {r} samples"
            )
        D = np.abs(np.concatenate(diffs, axis=0))
        levels = (safety * np.quantile(D, quantile, axis=0), np.sqrt(np.mean(D**2, axis=0)))
        for store, level in zip((bounds, typical), levels, strict=True):
            untouched = level <= 1e-6 * max(float(np.max(level)), 1e-300)
            level[untouched] = np.max(level)
            store[r] = np.maximum(level, BOUND_FLOOR)
    return Calibration(dt, bounds, typical, noise, resolution, initial)


# ----------------------------------------------------------------------------------------------------------------
# default gains
# ----------------------------------------------------------------------------------------------------------------
def _family(name: str):
    """The registered model-free family ``name``, or the ``ValueError`` of :func:`make_observer` listing them."""
    if not isinstance(name, str) or name not in OBSERVERS:
        make_observer(name)  # raises the ValueError that lists the valid names
    return FAMILIES[name]


def bound_order(name: str, observer_kwargs: dict | None = None) -> int:
    """Order of the derivative an observer's gain must bound (2 = acceleration, 3 = jerk), as its family
    registers it (:meth:`Family.bound_order <smo_gym.observers.Family.bound_order>`): a fixed order (super-twisting,
    URED and the constant-acceleration Kalman filter bound the acceleration; finite differences need no bound and
    say 2), else ``order + 1`` with ``order`` from ``observer_kwargs`` or the constructor's default."""
    return _family(name).bound_order(observer_kwargs)


def needs_calibration(name: str, observer_kwargs: dict | None = None) -> bool:
    """Whether :func:`default_observer` takes any gain of ``name`` from the bounds or the noise, given these
    constructor arguments (False when they already set every gain)."""
    return _family(name).needs_calibration(dict(observer_kwargs or {}))


def default_observer(name: str, calibration: Calibration, observer_kwargs: dict | None = None) -> Observer:
    r"""An observer of :data:`smo_gym.observers.OBSERVERS` with gains from a :class:`Calibration`.

    Parameters
    ----------
    name : str
    calibration : Calibration
        Of the signals it will differentiate, with the derivative order :func:`bound_order` names.
    observer_kwargs : dict, optional
        Constructor arguments; they override anything calibrated.

    Returns
    -------
    Observer

    Notes
    -----
    Each family registers its gain rule (:attr:`Family.calibrate <smo_gym.observers.Family.calibrate>`), called
    with the calibration and the family's derivative order ``r``. With ``L`` the worst-case bound of order ``r``,
    ``J`` the typical level and :math:`\epsilon` the noise level:

    * sliding-mode differentiators (a ``lipschitz`` parameter): ``lipschitz = L`` per channel [Lev03];
    * ``"high-gain"``: :meth:`HighGain.from_bounds <smo_gym.observers.HighGain.from_bounds>`,
      :math:`\ell = (L/\epsilon)^{1/n}` with the largest ``L`` (``n = order + 1``, the balance of the
      :math:`L/\ell^{n-1}` and :math:`\ell\epsilon` velocity errors);
    * ``"kalman-ca"``: :meth:`KalmanCA.from_levels <smo_gym.observers.KalmanCA.from_levels>`, ``q = J^2 tau``
      per channel from the typical jerk (``r = 3``), ``r`` the measurement variance [BSL01];
    * ``"switched-gain"`` (``disturbance`` and ``noise`` parameters): the largest ``L`` and :math:`\epsilon`;
    * ``"low-power-high-gain"`` (a required ``gain``): the same balance :math:`\ell = (L/\epsilon)^{1/n}`;
    * finite differences need nothing.
    """
    if not isinstance(calibration, Calibration):
        raise TypeError(f"expected a Calibration, actual value: {calibration!r:.80}")
    family = _family(name)
    kw = dict(observer_kwargs or {})
    valid = list(family.parameters)
    for key in kw:  # a misspelled gain would otherwise be calibrated over silently, or reported as a missing one
        if key not in valid:
            raise ValueError(
                f"unknown parameter {key!r} of {family.cls.__name__}: expected one of {', '.join(valid)}, "
                f"actual value: {key}={kw[key]!r}{did_you_mean(key, valid)}"
            )
    if family.needs_calibration(kw):
        return family.calibrate(family.cls, calibration, family.bound_order(kw), kw)
    try:  # only a missing argument is this message's case: a refused value keeps its own error
        inspect.signature(family.cls).bind(dt=calibration.dt, **kw)
    except TypeError as exc:
        raise ValueError(
            f"expected observer_kwargs completing the parameters of {family.cls.__name__} (no default gains are known "
            f"for it), actual value: {observer_kwargs!r} ({exc})"
        ) from None
    return family.cls(dt=calibration.dt, **kw)
