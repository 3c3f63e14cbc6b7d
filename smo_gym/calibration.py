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
which lowers narrow peaks: the price of separating them from noise.

On records longer than :data:`MAX_SAMPLES` (:math:`2^{17}`) differences, medians and quantiles are taken over that
many differences drawn at random with a fixed seed (deterministic, and a fraction of the cost on long records).

References
----------
.. [DJ94] D. L. Donoho and I. M. Johnstone, "Ideal spatial adaptation by wavelet shrinkage", Biometrika 81(3),
   1994 (the median absolute deviation as the noise scale of high-pass coefficients).
.. [Lev03] A. Levant, "Higher-order sliding modes, differentiation and output-feedback control",
   Int. J. Control 76(9-10), 2003 (the differentiators' gains from a bound on the next derivative).
"""

from __future__ import annotations

from math import comb

import numpy as np

from ._validation import check_int_in_range, check_positive, did_you_mean
from .observers import FAMILIES, OBSERVERS, Observer, make_observer

__all__ = [
    "bound_order",
    "default_observer",
    "derivative_bound",
    "needs_calibration",
    "noise_std",
]

#: median absolute deviation -> standard deviation of a Gaussian, 1 / Phi^-1(3/4)
MAD_TO_STD = 1.482602218505602
#: smallest noise level a gain formula divides by (the wrapper's floor)
NOISE_FLOOR = 1e-6
#: smallest derivative bound (the wrapper's floor): a constant channel still gets a positive gain
BOUND_FLOOR = 1e-3
#: longer records are calibrated on this many differences drawn at random (see :func:`_lag_difference`)
MAX_SAMPLES = 2**17


def _time_series(y, name: str = "y") -> np.ndarray:
    """``y`` as a float64 array of shape ``(T, ...)`` with ``T >= 1`` and finite entries."""
    try:
        arr = np.asarray(y, dtype=np.float64)
    except (TypeError, ValueError):
        raise TypeError(f"expected {name} to be an array of real numbers, actual value: {y!r}") from None
    if arr.ndim == 0 or arr.shape[0] == 0:
        raise ValueError(f"expected {name} with shape (T, ...) and T >= 1, actual value: shape {arr.shape}")
    if not np.isfinite(arr).all():
        index = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
        raise ValueError(f"expected finite values in {name}, actual value: {arr[index]!r} at index {index}")
    return arr


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
    for _ in range(order):
        parts = [b - a for a, b in zip(parts[:-1], parts[1:], strict=True)]
    return parts[0]


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
    moves by less than one count in most samples is a staircase whose differences are mostly zero: the median
    then misses the quantization error, and the estimate is low.
    """
    n = check_int_in_range("order", order, 1, 16)
    y = _time_series(y)
    if y.shape[0] <= n:
        raise ValueError(f"expected more than order = {n} samples, actual value: {y.shape[0]}")
    d = _lag_difference(y, n, 1)
    mad = np.median(np.abs(d - np.median(d, axis=0)), axis=0)
    return MAD_TO_STD * mad / np.sqrt(comb(2 * n, n))


def derivative_bound(
    y,
    dt: float,
    derivative: int,
    *,
    noise=None,
    quantile: float = 0.99,
    safety: float = 2.0,
    floor: float = BOUND_FLOOR,
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
    floor : float
        Smallest bound returned (a constant channel gets a positive gain).

    Returns
    -------
    ndarray, shape (...)
        The bound per channel.
    """
    dt = check_positive("dt", dt)
    r = check_int_in_range("derivative", derivative, 1, 8)
    safety = check_positive("safety", safety)
    floor = check_positive("floor", floor)
    if isinstance(quantile, bool) or not isinstance(quantile, (int, float, np.number)) or not 0.0 < quantile <= 1.0:
        raise ValueError(f"expected quantile in (0, 1], actual value: {quantile!r}")
    y = _time_series(y)
    T = y.shape[0]
    if r >= T:
        raise ValueError(f"expected more than derivative = {r} samples, actual value: {T}")
    if noise is None:
        sigma = noise_std(y) if T > 4 else np.zeros(y.shape[1:])  # four samples cannot show the noise
    else:
        sigma = np.asarray(noise, dtype=np.float64)
        if not np.all(np.isfinite(sigma) & (sigma >= 0.0)):
            raise ValueError(f"expected noise >= 0 and finite everywhere, actual value: {noise!r}")
        try:
            sigma = np.broadcast_to(sigma, y.shape[1:])
        except ValueError:
            raise ValueError(
                f"expected noise broadcastable to the channel shape {y.shape[1:]}, actual value: shape {sigma.shape}"
            ) from None
    gain = 3.0 * np.sqrt(comb(2 * r, r))  # the noise part of D_s, about three of its standard deviations
    result = np.full(y.shape[1:], np.nan)
    lag = 1
    while True:
        q = np.quantile(np.abs(_lag_difference(y, r, lag)), quantile, axis=0) / (lag * dt) ** r
        settled = np.isnan(result) & (gain * sigma / (lag * dt) ** r <= 0.25 * q)
        result[settled] = q[settled]
        last = 2 * lag * r > T // 8  # the next lag would average over more than an eighth of the record
        if last or not np.isnan(result).any():
            break
        lag *= 2
    # channels whose noise never fell below the quantile (no visible signal): the smoothest quotient seen
    result = np.where(np.isnan(result), q, result)
    with np.errstate(over="ignore"):
        bound = np.maximum(safety * result, floor)
    if not np.all(np.isfinite(bound)):
        raise ValueError(
            f"expected samples whose derivative of order {r} has a finite bound at dt={dt}, actual value: the "
            f"bound overflows ({np.max(result):.3g} before the safety factor {safety}); rescale the signal"
        )
    return bound


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


def default_observer(name: str, dt: float, bounds, noise_std, observer_kwargs: dict | None = None) -> Observer:
    r"""An observer of :data:`smo_gym.observers.OBSERVERS` with gains from calibrated bounds and noise.

    Parameters
    ----------
    name : str
    dt : float
        Sampling step.
    bounds : array_like, shape (...)
        Per-channel bound on the derivative :func:`bound_order` names (acceleration or jerk).
    noise_std : array_like, shape (...)
        Per-channel standard deviation of the measurement noise (its mean, floored at ``1e-6``, enters the
        formulas that divide by it).
    observer_kwargs : dict, optional
        Constructor arguments; they override anything calibrated.

    Returns
    -------
    Observer

    Notes
    -----
    Each family registers its gain rule (:attr:`Family.calibrate <smo_gym.observers.Family.calibrate>`). With
    ``L`` the bound and :math:`\epsilon` the noise level:

    * sliding-mode differentiators (a ``lipschitz`` parameter): ``lipschitz = bounds`` per channel [Lev03];
    * ``"high-gain"``: :meth:`HighGain.from_bounds <smo_gym.observers.HighGain.from_bounds>`,
      :math:`\ell = (L/\epsilon)^{1/n}` with the largest ``L`` (``n = order + 1``, the balance of the
      :math:`L/\ell^{n-1}` and :math:`\ell\epsilon` velocity errors);
    * ``"kalman-ca"``: :meth:`KalmanCA.from_bounds <smo_gym.observers.KalmanCA.from_bounds>`, ``q = L^2/tau``
      with the largest acceleration bound, ``r`` from the noise;
    * ``"switched-gain"`` (``disturbance`` and ``noise`` parameters): the largest ``L`` and :math:`\epsilon`;
    * ``"low-power-high-gain"`` (a required ``gain``): the same balance :math:`\ell = (L/\epsilon)^{1/n}`;
    * finite differences need nothing.
    """
    family = _family(name)
    kw = dict(observer_kwargs or {})
    valid = list(family.parameters)
    for key in kw:  # a misspelled gain would otherwise be calibrated over silently, or reported as a missing one
        if key not in valid:
            raise ValueError(
                f"unknown parameter {key!r} of {family.cls.__name__}: expected one of {', '.join(valid)}, "
                f"actual value: {key}={kw[key]!r}{did_you_mean(key, valid)}"
            )
    try:
        if family.needs_calibration(kw):
            noise = float(max(np.mean(noise_std), NOISE_FLOOR))
            return family.calibrate(family.cls, dt, np.asarray(bounds, dtype=float), noise, kw)
        return family.cls(dt=dt, **kw)
    except TypeError as exc:
        raise ValueError(
            f"expected observer_kwargs completing the parameters of {family.cls.__name__} (no default gains are known "
            f"for it), actual value: {observer_kwargs!r} ({exc})"
        ) from None
