"""Offline differentiation of recorded signals with the online observers' recursions."""

from __future__ import annotations

import copy
import dataclasses
import inspect

import numpy as np

from . import calibration
from ._validation import as_real_array, check_keywords, check_positive
from .observers import KalmanCA, Observer, make_observer
from .observers.base import check_wrap
from .observers.linear import calibrated_prior, white_jerk_density

__all__ = ["differentiate"]


@check_keywords
def differentiate(y, dt, observer=None, *, method=None, axis=0, start=None, **params):
    r"""Estimate a sampled signal and its derivatives with an observer, causally, sample by sample.

    Parameters
    ----------
    y : array_like
        The samples, uniformly spaced by ``dt`` along ``axis``; every other index is an independent channel.
    dt : float
        Sampling step, ``> 0``.
    observer : str or Observer, optional
        An observer name of :data:`smo_gym.observers.OBSERVERS` (``"levant"``, ``"super-twisting"``,
        ``"high-gain"``, ``"kalman-ca"``, ...; the names of the Gymnasium wrapper), or an observer object whose
        ``dt`` equals ``dt`` (a copy is run; ``params`` must then be empty). Default ``"auto"``: per channel
        the backward difference or the constant-acceleration Kalman filter with its process noise fitted to ``y``
        (:meth:`KalmanCA.fit <smo_gym.observers.KalmanCA.fit>`), whichever the calibration predicts more
        accurate (:func:`smo_gym.selection.auto_observer`; it takes no parameter but ``wrap`` and ``huber``: for a
        sensor that makes gross errors, ``huber=3`` gives its Kalman filter Huber's robust update,
        :class:`KalmanCA <smo_gym.observers.KalmanCA>`'s ``huber``, in the fit as in the result).
    method : str, optional
        Alias of ``observer`` (the former name of this argument); give one of them.
    axis : int, optional
        The time axis of ``y``. Default 0.
    start : {"kalman", "measurement"}, optional
        How the recursion starts. ``"measurement"``: at the first sample, every derivative at zero (what ``reset``
        and ``update`` give online). ``"kalman"``: from the estimate of the constant-acceleration Kalman filter
        calibrated from ``y`` once its prior is forgotten (see Notes). Default: ``"kalman"`` when the gains are
        calibrated from ``y`` and the family's first estimates hinge on its initial derivatives
        (:attr:`Observer.self_starting <smo_gym.observers.Observer.self_starting>` false: the sliding-mode,
        high-gain and alpha-beta families), else ``"measurement"``.
    **params
        Constructor arguments of the observer (``order``, ``lipschitz``, ``discretization``, ``wrap``, ...). Gains
        that are not given are calibrated from ``y`` itself (see Notes).

    Returns
    -------
    ndarray, shape ``y.shape + (order + 1,)`` (``y.shape + (2,)`` for ``"auto"``)
        ``out[..., i]`` is the estimate of the ``i``-th derivative, with time along ``axis`` as in ``y``: the
        estimate at a sample uses that sample and the earlier ones only (with ``start="measurement"``, the same
        numbers ``update`` returns online). With ``wrap``, the value estimate ``out[..., 0]`` of a wrapped channel
        is the continuous (unwrapped) angle.

    Raises
    ------
    ValueError
        An unknown observer name, parameter of it (``params`` are the observer's settings, checked as the names of
        :data:`~smo_gym.observers.OBSERVERS` and the wrapper's ``observer_kwargs`` are) or ``start``, an empty or
        non-finite ``y``, ``dt <= 0``, or an observer object with another step.
    TypeError
        ``y`` not numeric, both ``observer`` and ``method``, or an observer object together with ``params``.
    DivergenceError
        The observer's state became non-finite (an explicit scheme at too large a step).

    See Also
    --------
    smo_gym.observers.Observer.run : the same recursion on an observer you keep.
    smo_gym.calibration.default_observer : the gain rules.

    Notes
    -----
    Calibration, as the Gymnasium wrapper does from a rollout, but from the data: when ``params`` leaves gains
    unset (:func:`smo_gym.calibration.needs_calibration`), the noise level :math:`\hat\sigma` of every channel is
    estimated from the median absolute deviation of the fourth difference of ``y``
    (:func:`smo_gym.calibration.noise_std`), and the bound ``L`` of the derivative the observer needs
    (:func:`smo_gym.calibration.bound_order`: acceleration for super-twisting, ``order + 1`` for Levant's
    differentiator) is twice the 99th percentile of a difference quotient taken at the smallest decimation at
    which it rises well above the noise (:func:`smo_gym.calibration.derivative_bound`); its typical (RMS) level
    is the mean square of that quotient (clipped at twice its 99th percentile: rare gross errors do not make the
    level) less its noise part (:func:`smo_gym.calibration.derivative_rms`). The gains
    then follow :func:`smo_gym.calibration.default_observer`: ``lipschitz = L`` per channel for the sliding-mode
    differentiators, :math:`\ell = (L/\hat\sigma)^{1/(order+1)}` for ``"high-gain"``, ``q = J^2 dt`` from the
    typical jerk ``J`` and :math:`r = \hat\sigma^2` per channel for ``"kalman-ca"``. Wrapped channels are
    unwrapped (``numpy.unwrap``) for the calibration only. Given gains cost nothing: the calibration then does not
    run.

    Start. A differentiator started at rest converges in a time that grows as its gain falls (Levant 2003): on a
    slow signal, with the small bound a calibration rightly finds, its first estimates are wrong for seconds (a
    cubic over 20 s, ``scripts/bench_signals.py``: the filtering differentiator's largest velocity error after 2 s
    was 0.33-0.40, its RMSE 8 to 190 times the Kalman filter's). The constant-acceleration Kalman filter has no
    such transient: its wide prior (the record's own velocity and acceleration bounds,
    :func:`smo_gym.calibration.calibration_of_signal`) makes its first estimates least-squares fits. With
    ``start="kalman"`` that filter, calibrated from ``y`` (:meth:`KalmanCA.from_levels
    <smo_gym.observers.KalmanCA.from_levels>`), gives the first ``m + 1`` estimates, ``m`` the updates until its
    velocity's standard deviation is within a factor 2 of its steady state (:meth:`KalmanCA.settling_samples
    <smo_gym.observers.KalmanCA.settling_samples>`: 2.5 time constants of the filter; the results hardly depend on
    the factor: on that benchmark 2, 1.1 and 1.01 gave the same RMSE but where the filter is the worse estimator,
    and there a longer start costs); at sample ``m`` the observer is reset at the filter's estimate (value, velocity
    and acceleration, as many as it has; higher derivatives are 0 until then, and start from 0) and runs on from
    there. Still causal. ``m`` is the slowest channel's, and the prior the widest: those two couple the channels
    of one call (a channel's estimates then differ from its own call's, within the start's transient).

    Units. The estimates scale with ``y`` (a record in counts or in metres of a micrometre vibration gives the
    same velocities in counts/s or m/s): every level of the calibration scales with the record, its floors too
    (relative to the record's velocity bound, :mod:`smo_gym.calibration`, "Floors"), and so do the weights of the
    uniform families' terms of positive homogeneity degree, whose dimension is a power of the signal's
    (``"ured"``, ``"uniform-levant"``, ``"discrete-hosm"``, ``"ilf-fixed"``: scaled by the calibration's
    :attr:`~smo_gym.calibration.Calibration.unit`, the record's velocity bound times one second).

    The result of the sliding-mode observers depends on the gains: a calibration from the data cannot know
    bounds the record does not show, and the Lipschitz bounds of the theory (Levant 2003) assume the worst case.
    Pass ``lipschitz`` (or the gains of your observer) when you know them.

    References
    ----------
    A. Levant, "Higher-order sliding modes, differentiation and output-feedback control", Int. J. Control
    76(9-10), 2003.

    Examples
    --------
    >>> import numpy as np, smo_gym
    >>> t = np.arange(0, 10, 1e-3)
    >>> z = smo_gym.differentiate(np.sin(t), 1e-3, observer="levant", order=2, lipschitz=1.0)
    >>> z.shape
    (10000, 3)
    >>> bool(abs(z[-1, 1] - np.cos(t[-1])) < 1e-4)
    True

    With no gains, calibrated from the data (here with noise of standard deviation 1e-4):

    >>> y = np.sin(t) + 1e-4 * np.random.default_rng(0).standard_normal(t.size)
    >>> z = smo_gym.differentiate(y, 1e-3, observer="kalman-ca")
    >>> bool(np.sqrt(np.mean((z[2000:, 1] - np.cos(t[2000:])) ** 2)) < 0.05)
    True
    """
    if method is not None:
        if observer is not None:
            raise TypeError(
                f"expected observer or its alias method, not both, actual value: observer={observer!r}, "
                f"method={method!r}"
            )
        observer = method
    observer = "auto" if observer is None else observer
    dt = check_positive("dt", dt)
    y = as_real_array("y", y)
    if y.ndim == 0:
        raise ValueError(f"expected y with a time axis, actual value: a scalar {float(y)!r}")
    if isinstance(axis, bool) or not isinstance(axis, (int, np.integer)) or not -y.ndim <= axis < y.ndim:
        raise ValueError(f"expected axis in [{-y.ndim}, {y.ndim - 1}], actual value: {axis!r}")
    axis = int(axis) % y.ndim
    if axis:
        y = np.moveaxis(y, axis, 0)
    if y.shape[0] == 0:
        raise ValueError(f"expected y with T >= 1 samples along axis {axis}, actual value: shape {y.shape}")
    squeeze = y.ndim == 1
    if squeeze:
        y = y[:, None]
    if y.size == 0:  # before any calibration: the observers refuse empty channels in the same words
        raise ValueError(
            f"expected y with at least one channel and no empty batch dimension, actual value: shape {y.shape}"
        )
    if not (start is None or (isinstance(start, str) and start in ("kalman", "measurement"))):
        raise ValueError(f"expected start to be 'kalman' or 'measurement', actual value: {start!r}")
    obs, found = _build(observer, dt, y, params, with_jerk=start != "measurement")
    if start is None:
        start = "kalman" if found is not None and not obs.self_starting else "measurement"
    out = _run_from_kalman(obs, y, dt, found) if start == "kalman" else _run(obs, y)
    if isinstance(observer, str) and observer == "auto":  # value and velocity: what every choice estimates
        out = out[..., :2]
    if squeeze:
        out = out[:, 0]
    return np.moveaxis(out, 0, axis) if axis else out


#: the shortest record whose Kalman process noise ``"auto"`` fits (:meth:`KalmanCA.fit`); shorter ones keep the
#: level calibrated from the differences
MIN_FIT_SAMPLES = 64


def _build(observer, dt: float, y: np.ndarray, params: dict, with_jerk: bool) -> tuple[Observer, object]:
    """The observer to run on ``y`` (T, ...), a copy of an object or a named one with calibrated gains, and the
    :class:`~smo_gym.calibration.Calibration` of ``y`` its gains came from (None: nothing was calibrated); with
    ``with_jerk`` that calibration also has the typical jerk the Kalman start needs."""
    if isinstance(observer, Observer):
        if params:
            raise TypeError(f"expected no observer parameters with an observer object, actual value: {params!r}")
        if not np.isclose(observer.dt, dt, rtol=1e-9, atol=0.0):
            raise ValueError(
                f"expected an observer with dt equal to the sampling step {dt}, actual value: {observer.dt}"
            )
        return copy.deepcopy(observer), None
    if isinstance(observer, str) and observer == "auto":
        from .selection import _check_kwargs, auto_observer, candidate_orders, select

        params = _check_kwargs(params, allowed=("wrap", "huber"))
        huber = params.pop("huber", None)
        kalman = "kalman-ca" if huber is None else f"kalman-ca:huber={check_positive('huber', huber)!r}"
        sample = _unwrapped(_finite_for_calibration(y), params.get("wrap"))
        found = calibration.calibration_of_signal(sample, dt, candidate_orders())
        # chosen on the levels' predictions (the fitted filter's own model is no guide where the fit inflates q to
        # follow a fast signal), built with the fitted process noise where the Kalman filter is chosen
        selection = select(found, candidates=("finite-difference", kalman), observer_kwargs=params)
        if kalman in (selection.candidates[k] for k in selection.choice):
            found = _with_fitted_jerk(found, sample, huber)
        return auto_observer(found, observer_kwargs=params, selection=selection), found
    if not calibration.needs_calibration(observer, params):  # also rejects unknown names, listing the known
        return make_observer(observer, dt=dt, **params), None
    sample = _unwrapped(_finite_for_calibration(y), params.get("wrap"))
    orders = {calibration.bound_order(observer, params)} | ({3} if with_jerk else set())
    found = calibration.calibration_of_signal(sample, dt, sorted(orders))
    return calibration.default_observer(observer, found, params), found


def _with_fitted_jerk(found, y: np.ndarray, huber: float | None = None):
    """``found`` with its typical jerk replaced by the white-jerk level whose Kalman filter (with Huber's threshold
    ``huber``) predicts ``y`` best (:meth:`KalmanCA.fit <smo_gym.observers.KalmanCA.fit>`): the Kalman candidate of
    ``"auto"`` is built from it, and its predicted error is that filter's. Records too short to fit keep the level
    from the differences."""
    if y.shape[0] < MIN_FIT_SAMPLES:
        return found
    white, prior = white_jerk_density(found.dt, found.rms(3)), calibrated_prior(found)  # as it will be built
    fitted = KalmanCA.fit(y, found.dt, found.measurement_variance, white, huber=huber, **prior).process_noise
    return dataclasses.replace(found, typical={**found.typical, 3: np.sqrt(fitted / found.dt)})


def _run(obs: Observer, y: np.ndarray) -> np.ndarray:
    """``obs`` reset at ``y[0]`` and run on the rest: its estimates, shape ``y.shape + (order + 1,)``."""
    first = obs.reset(y[0])
    out = np.empty((y.shape[0],) + first.shape)
    out[0] = first
    _run_into(obs, y[1:], out[1:])
    return out


def _run_into(obs: Observer, y: np.ndarray, out: np.ndarray) -> None:
    """``obs.run(y)`` written into ``out``."""
    if "out" in inspect.signature(obs.run).parameters:
        obs.run(y, out=out)  # written in place: no second copy of a possibly large result
    else:  # an observer whose run() takes other arguments (the model-based ones) allocates its result
        out[:] = obs.run(y)


def _run_from_kalman(obs: Observer, y: np.ndarray, dt: float, found) -> np.ndarray:
    """``obs`` started from the calibrated Kalman filter's estimate once the filter's prior is forgotten
    (:func:`differentiate`, Notes): the filter's estimates up to that sample, the observer's after it."""
    if found is None or 3 not in found.typical:
        found = calibration.calibration_of_signal(_unwrapped(_finite_for_calibration(y), obs.wrap), dt, (3,))
    kalman = calibration.default_observer("kalman-ca", found, {"wrap": obs.wrap})
    m = kalman.settling_samples(limit=y.shape[0] - 1)
    head = _run(kalman, y[: m + 1])
    k = min(obs.order, 2)  # the derivatives both estimate
    first = obs.reset(head[m, ..., 0], derivatives=head[m, ..., 1 : k + 1])
    out = np.zeros((y.shape[0],) + first.shape)
    out[: m + 1, ..., : k + 1] = head[..., : k + 1]
    if m + 1 < y.shape[0]:
        _run_into(obs, y[m + 1 :], out[m + 1 :])
    return out


def _finite_for_calibration(y: np.ndarray) -> np.ndarray:
    """``y`` after checking it is finite (a calibration of non-finite samples would be meaningless)."""
    if not np.isfinite(y).all():
        index = tuple(int(i) for i in np.argwhere(~np.isfinite(y))[0])
        raise ValueError(
            f"expected finite samples to calibrate from, actual value: {y[index]!r} at sample "
            f"{index[0]}, channel {index[1:]}"
        )
    return y


def _unwrapped(y: np.ndarray, wrap) -> np.ndarray:
    """``y`` with its wrapped channels unwrapped along time (for the calibration only)."""
    wrap = check_wrap(wrap)
    if wrap is None or wrap is False:
        return y
    try:
        wrapped = np.broadcast_to(wrap, y.shape[1:])
    except ValueError:
        raise ValueError(
            f"expected wrap broadcastable to the channel shape {y.shape[1:]}, actual value: shape {np.shape(wrap)}"
        ) from None
    if not wrapped.any():
        return y
    return np.where(wrapped, np.unwrap(y, axis=0), y)
