r"""The constant-acceleration Kalman filter told when, and by how much, the control input changed.

A joint's acceleration jumps when its actuators' command does: at the first sample of every control period of a
stochastic policy (uniform random exploration, PPO's Gaussian actions), hardly at all under a smooth one. A filter
blind to the input has to choose between its constant-acceleration model, good on smooth motion and many samples
late after each jump, and trusting the measurements, a noisy backward difference; which choice was right depends
on the policy, which the filter does not know (the accuracy page measures that conflict). With the command known
the jump is predicted: to first order in the change of command :math:`\Delta u_k` at the start of the sample
interval ending at :math:`t_k`,

.. math::
    a(t_{k-1}^+) - a(t_{k-1}^-) \approx G\,\Delta u_k,\qquad G = M(q)^{-1}\,\partial\tau/\partial u,

the inverse inertia times the actuators' moment arms, which varies slowly with the configuration.
:class:`KalmanCAInput` is :class:`~smo_gym.observers.KalmanCA` (white jerk of density ``q``, measurement variance
``r``) whose acceleration estimate moves by the predicted jump :math:`G\Delta u_k` before each prediction, with its
variance widened by what the prediction misses, :math:`s\,\|\Delta u_k\|^2`:

.. math::
    \hat a_{k-1} \leftarrow \hat a_{k-1} + G\Delta u_k,\qquad P_{aa} \leftarrow P_{aa} + s\,\|\Delta u_k\|^2,

then the Kalman filter's prediction and update: a known input and an input-dependent process noise, the
textbook extension of the Kalman filter (Bar-Shalom, Li and Kirubarajan 2001, ch. 5). Where the command is
constant the filter is :class:`~smo_gym.observers.KalmanCA`; where it changes a little (a smooth policy) the jump
is small and so is the added variance.

:func:`fit_input_jumps` estimates ``G``, ``s`` and ``q`` from recorded episodes with their true velocities and
inputs (the calibration rollouts of :class:`~smo_gym.wrappers.EstimatedVelocity`): no model of the robot, only the
actions the wrapper sees anyway.

The channels are independent given the input: each is a Kalman filter of its own whose acceleration moves by its
own row of :math:`G\Delta u`. So the filter on some channels (:meth:`InputJumpFilter.of_channels`) estimates there
exactly what the whole filter does, and :class:`PerChannelInput` holds it beside observers of the measurements only
on the other channels: ``observer="auto"`` told the actions takes it on the joints where it wins
(:mod:`smo_gym.selection`).

References
----------
.. [BSL01] Y. Bar-Shalom, X. R. Li and T. Kirubarajan, *Estimation with Applications to Tracking and Navigation*,
   Wiley, 2001.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from numba import njit

from .._numba_cache import drop_stale
from .._validation import as_real_array, check_keywords
from . import _kernels
from .base import checked_input
from .composite import PerChannel
from .imm import _MODES, KalmanIMM
from .linear import KalmanCA, calibrated_prior
from .registry import register_observer

__all__ = [
    "InputJumpFilter",
    "InputJumpUpdates",
    "InputJumps",
    "JumpTarget",
    "KalmanCAInput",
    "KalmanIMMInput",
    "PerChannelInput",
    "fit_input_jumps",
]


class InputJumps(NamedTuple):
    """What :func:`fit_input_jumps` estimates (``n`` channels, ``m`` inputs)."""

    input_gain: np.ndarray
    """``G``, shape ``(n, m)``: the acceleration jump per unit change of each input."""
    jump_noise: np.ndarray
    """``s``, shape ``(n,)``: the variance of what ``G`` misses, per unit of :math:`\\|\\Delta u\\|^2`."""
    process_noise: np.ndarray
    """``q``, shape ``(n,)``: the white-jerk density of the acceleration's change where the input is constant."""


def fit_input_jumps(velocity: Sequence, inputs: Sequence, dt: float) -> InputJumps:
    r"""Least-squares estimates of the input jump model of :class:`KalmanCAInput` from recorded episodes.

    The acceleration change between consecutive sample intervals,
    :math:`\Delta a_k = (v_k - 2v_{k-1} + v_{k-2})/\tau`, is regressed on the change of input at the start of the
    later one, :math:`\Delta u_k = u_k - u_{k-1}`: :math:`\Delta a_k = G\Delta u_k + e_k`. The residual's variance is
    modelled as white jerk plus a share that grows with the change of input,
    :math:`\mathrm E\,e_k^2 = q\tau + s\|\Delta u_k\|^2`, fitted per channel by least squares on :math:`e_k^2`
    weighted by the inverse square of the modelled variance (iterated), both coefficients kept non-negative.

    Parameters
    ----------
    velocity : sequence of array_like, shape (T_i, n)
        True velocities at the samples of each episode.
    inputs : sequence of array_like, shape (T_i, m)
        Row ``k``: the input that acted over the interval ending at sample ``k``.
    dt : float
        The sampling step.

    Returns
    -------
    InputJumps

    Raises
    ------
    ValueError
        Episodes of unequal lengths or widths, non-finite entries, or fewer than two changes of input in all.
    """
    dt = float(dt)
    if not dt > 0:
        raise ValueError(f"expected dt > 0, actual value: {dt!r}")
    da, du = [], []
    for i, (v, u) in enumerate(zip(velocity, inputs, strict=True)):
        v, u = as_real_array("velocity", v), as_real_array("inputs", u)
        if v.ndim != 2 or u.ndim != 2 or len(v) != len(u) or not (np.isfinite(v).all() and np.isfinite(u).all()):
            raise ValueError(
                f"expected finite episodes (T, n) of velocities and (T, m) of inputs, actual value: shapes {v.shape} "
                f"and {u.shape} in episode {i}"
            )
        if len(v) >= 3:
            da.append(np.diff(v, n=2, axis=0) / dt)
            du.append(np.diff(u[1:], axis=0))
    changes = np.concatenate(du) if du else np.zeros((0, 0))
    if len(changes) == 0 or np.count_nonzero(np.any(changes != 0, axis=1)) < 2:
        raise ValueError("expected episodes in which the input changes at least twice, actual value: fewer changes")
    jumps = np.concatenate(da)
    gain = np.linalg.lstsq(changes, jumps, rcond=None)[0].T  # (n, m)
    residual2 = (jumps - changes @ gain.T) ** 2
    size2 = np.sum(changes**2, axis=1)
    design = np.column_stack([np.ones_like(size2), size2])
    coef = np.column_stack([_variance_model(design, residual2[:, j]) for j in range(residual2.shape[1])])
    return InputJumps(gain, coef[1], np.maximum(coef[0] / dt, np.finfo(float).tiny))


def _variance_model(design: np.ndarray, residual2: np.ndarray, iterations: int = 4) -> np.ndarray:
    r"""Non-negative ``(a, s)`` of :math:`\mathrm E\,e^2 = a + s x` from squared residuals, by least squares weighted
    with the inverse square of the modelled variance (the variance of :math:`e^2` for Gaussian :math:`e`), iterated
    from equal weights: unweighted, the few large residuals of big input changes dominate the estimate of ``a``."""
    weights = np.ones(len(residual2))
    coef = np.zeros(2)
    for _ in range(iterations):
        w = np.sqrt(weights)
        coef = np.linalg.lstsq(design * w[:, None], residual2 * w, rcond=None)[0]
        if (coef < 0).any():  # the non-negative solution: the better fit with one coefficient at zero
            fits = []
            for k in (0, 1):
                x = design[:, k] * w
                c = max(x @ (residual2 * w), 0.0) / max(x @ x, np.finfo(float).tiny)
                fits.append((np.sum((residual2 * w - c * x) ** 2), k, c))
            _, k, c = min(fits)
            coef = np.zeros(2)
            coef[k] = c
        variance = np.maximum(design @ coef, np.finfo(float).tiny)
        weights = (variance.min() / variance) ** 2  # 1 / variance^2 scaled to at most 1, without overflowing it:
        # a channel that never moves (Reacher's target) has a zero model, and 1 / tiny^2 is inf
    return coef


@njit(cache=True, error_model="numpy")
def _apply_jumps(state, u, u_prev, gain, noise, blocks, channels, saved):
    """Add the predicted jump ``gain @ du`` to the acceleration and ``noise * |du|^2`` to its variance in every
    constant-acceleration filter of the rows of ``channels`` (``blocks``: where each filter's mean starts; its
    covariance factors follow, as in :func:`~smo_gym.observers._kernels.kalman_ca_rows`), ``du = u - u_prev`` per
    batch element (zero where the previous input is unknown, NaN). Batch element ``b`` holds the state rows
    ``b n .. b n + n`` (``n`` = rows / batch elements); row ``c`` of ``gain`` and ``noise`` moves its row
    ``b n + channels[c]``. The 7 columns each filter changes (its acceleration, its factors) go to row
    ``b len(channels) + c`` of ``saved`` first."""
    batch, m = u.shape[0], gain.shape[1]
    n, k_channels = state.shape[0] // batch, channels.shape[0]
    for b in range(batch):
        known = True
        for j in range(m):
            known = known and not math.isnan(u_prev[b, j])
        size2 = 0.0
        for j in range(m):
            size2 += (u[b, j] - u_prev[b, j]) ** 2 if known else 0.0
        for c in range(k_channels):
            jump = 0.0
            if known:
                for j in range(m):
                    jump += gain[c, j] * (u[b, j] - u_prev[b, j])
            row, kept = b * n + channels[c], b * k_channels + c
            for k in range(blocks.shape[0]):
                o = blocks[k]
                for i in range(7):
                    saved[kept, 7 * k + i] = state[row, o + 2 + i]
                state[row, o + 2] += jump
                U = _kernels.kalman_ca_add_acceleration_variance(
                    state[row, o + 3], state[row, o + 4], state[row, o + 5], state[row, o + 6], state[row, o + 7],
                    state[row, o + 8], size2 * noise[c],
                )  # fmt: skip
                for i in range(6):
                    state[row, o + 3 + i] = U[i]


drop_stale([_apply_jumps], [_kernels.__file__])  # it links _kernels' factor update; numba checks this file only


class JumpTarget(NamedTuple):
    """Constant-acceleration filters that one input model moves at each change of input (:class:`InputJumpUpdates`)."""

    input_gain: np.ndarray
    """``G`` of these channels, shape ``(k, m)``."""
    jump_noise: np.ndarray
    """``s`` of these channels, shape ``(k,)``."""
    blocks: np.ndarray
    """Where each constant-acceleration filter's mean starts in a channel's state row (int64)."""
    channels: np.ndarray
    """The ``k`` channels (int64 indices into the last axis of the measurement)."""


class InputJumpUpdates:
    """The update of an observer some of whose constant-acceleration filters jump at each change of input (module
    notes): :class:`InputJumpFilter`, and :class:`~smo_gym.observers.input_kalman.PerChannelInput` (its parts told the
    input). A subclass sets ``input_gain`` (``(n, m)``: ``G`` of every channel, zero where no filter jumps) and
    ``jump_noise`` (``(n,)``), and says which filters move (:meth:`jump_targets`)."""

    takes_input = True
    #: the last input ``(..., m)``, NaN where unknown; None until the first reset
    _u_prev: np.ndarray | None = None

    def jump_targets(self) -> tuple[JumpTarget, ...]:
        """The filters the input moves, with their input model."""
        raise NotImplementedError

    @check_keywords
    def reset(self, y0, mask=None, *, derivatives=None) -> np.ndarray:
        """As :meth:`Observer.reset <smo_gym.observers.Observer.reset>`; the restarted rows forget their last input."""
        out = super().reset(y0, mask, derivatives=derivatives)
        if mask is None or self._u_prev is None:
            self._u_prev = np.full(self._shape[:-1] + self.input_gain.shape[1:], np.nan)
        else:
            mask = np.asarray(mask, dtype=bool)
            self._u_prev[mask if mask.shape == self._shape[:-1] else mask.any(axis=-1)] = np.nan
        return out

    def update(self, y, u=None) -> np.ndarray:
        """Process one sample ``y`` ``(..., n)`` with the input ``u`` ``(..., m)`` that acted over the interval
        ending at it; returns the estimate ``(..., n, order + 1)``. The state is unchanged if either is rejected."""
        if self._state is None:
            raise RuntimeError("expected reset(y0) before update(y), actual value: the observer was never reset")
        u = checked_input(u)
        if u is None:  # no input this sample: the next one cannot tell a jump (forgotten once y is taken)
            out = super().update(y)
            self._u_prev[...] = np.nan
            return out
        if u.shape != self._u_prev.shape:
            raise ValueError(f"expected u with shape {self._u_prev.shape}, actual value: {u.shape}")
        state, m = self._state, u.shape[-1]
        u2, u_prev2 = u.reshape(-1, m), self._u_prev.reshape(-1, m)
        moved = []
        try:
            for target in self.jump_targets():
                saved = np.empty((u2.shape[0] * target.channels.size, 7 * target.blocks.size))
                _apply_jumps(state, u2, u_prev2, target.input_gain, target.jump_noise, target.blocks, target.channels,
                             saved)  # fmt: skip
                moved.append((target, saved))
            out = super().update(y)
        except BaseException:
            n = self._shape[-1]
            for target, saved in reversed(moved):
                rows = (np.arange(u2.shape[0])[:, None] * n + target.channels).reshape(-1)
                state[rows[:, None], (target.blocks[:, None] + np.arange(2, 9)).reshape(-1)] = saved
            raise
        self._u_prev[...] = u
        return out

    @check_keywords
    def run(self, Y, U=None, *, out: np.ndarray | None = None) -> np.ndarray:
        """Process a recorded block ``Y`` ``(T, ..., n)`` with inputs ``U`` ``(T, ..., m)`` sample by sample; all or
        nothing, as :meth:`Observer.run <smo_gym.observers.Observer.run>`."""
        return self._run_updates(Y, U, (self._u_prev,), out)

    def step(self, state, y):
        raise NotImplementedError(
            "expected update(y, u) for an observer that takes the control input, actual value: step(state, y)"
        )


class InputJumpFilter(InputJumpUpdates):
    """What the input-aware filters add to their Kalman filter: the jump of the acceleration estimate(s) at each
    change of input (module notes). A subclass names the state columns of each acceleration and its variance; the
    wrapper builds every registered subclass from its calibration episodes (:meth:`from_episodes`)."""

    #: where the mean of each constant-acceleration filter of the state row starts (int64: the compiled jump reads
    #: it)
    _jump_blocks = np.zeros(0, dtype=np.int64)
    #: the constructor's parameters that may hold one value per channel (:meth:`of_channels`)
    _channel_parameters = ("process_noise", "measurement_noise", "wrap")

    def _set_input_model(self, input_gain, jump_noise) -> None:
        gain = as_real_array("input_gain", input_gain)
        if gain.ndim != 2 or 0 in gain.shape or not np.isfinite(gain).all():
            raise ValueError(f"expected a finite input_gain of shape (n, m), actual value: shape {gain.shape}")
        noise = as_real_array("jump_noise", jump_noise)
        if noise.ndim > 1 or noise.size not in (1, gain.shape[0]) or not (np.isfinite(noise) & (noise >= 0)).all():
            raise ValueError(
                f"expected jump_noise >= 0, one or one per channel ({gain.shape[0]}), actual value: {jump_noise!r}"
            )
        gain = np.ascontiguousarray(gain, dtype=np.float64)
        noise = np.broadcast_to(noise, gain.shape[:1]).astype(np.float64)
        channels = np.arange(gain.shape[0], dtype=np.int64)
        self._targets = (JumpTarget(gain, noise, self._jump_blocks, channels),)  # built once: read at every update

    @property
    def input_gain(self) -> np.ndarray:
        """``G``, shape ``(n, m)``: the acceleration jump per unit change of each input. It may be replaced by one
        of the same shape (the compiled jump indexes the state with it)."""
        return self._targets[0].input_gain

    @input_gain.setter
    def input_gain(self, value) -> None:
        self._replace_input_model(value, self.jump_noise)

    @property
    def jump_noise(self) -> np.ndarray:
        """``s``, shape ``(n,)``: the variance of what ``G`` misses per unit of :math:`\\|\\Delta u\\|^2`. It may be
        replaced by one value or one per channel."""
        return self._targets[0].jump_noise

    @jump_noise.setter
    def jump_noise(self, value) -> None:
        self._replace_input_model(self.input_gain, value)

    def _replace_input_model(self, input_gain, jump_noise) -> None:
        shape = self.input_gain.shape
        gain = as_real_array("input_gain", input_gain)
        if gain.shape != shape:
            raise ValueError(
                f"expected input_gain of the filter's shape {shape} (build a new filter for other channels or "
                f"inputs), actual value: shape {gain.shape}"
            )
        self._set_input_model(gain, jump_noise)  # the last input stays known: the model changes, the signal not

    def jump_targets(self) -> tuple[JumpTarget, ...]:
        """Every channel's filters, with ``G`` and ``s`` as given."""
        return self._targets

    def _channel_params(self, shape):
        if shape[-1] != self.input_gain.shape[0]:
            raise ValueError(
                f"expected measurements with {self.input_gain.shape[0]} channels (input_gain's rows), actual value: "
                f"shape {shape}"
            )
        return super()._channel_params(shape)

    def of_channels(self, channels) -> InputJumpFilter:
        """The same filter on the channels ``channels`` only (indices into its ``n``): every per-channel parameter
        taken there. Its channels are independent given the input, so on those channels it estimates exactly what
        this filter does: ``"auto"`` takes it on the joints where it wins
        (:class:`~smo_gym.observers.input_kalman.PerChannelInput`)."""
        n = self.input_gain.shape[0]
        idx = np.asarray(channels)
        if idx.ndim != 1 or idx.size == 0 or idx.dtype.kind not in "iu" or not ((idx >= 0) & (idx < n)).all():
            raise ValueError(f"expected a non-empty 1-d array of channels in 0..{n - 1}, actual value: {channels!r}")
        # rebuilt from its constructor's arguments (each stored under its own name), as scikit-learn's clone does:
        # a new filter, never reset, whatever state this one is in
        kwargs = {name: getattr(self, name) for name in inspect.signature(type(self)).parameters if name != "dt"}

        def taken(value):
            if np.ndim(value) >= 1 and np.shape(value)[0] == n:  # one per channel (else shared by all)
                return np.asarray(value)[idx]
            return value

        for name in ("input_gain", "jump_noise", *self._channel_parameters):
            kwargs[name] = taken(kwargs[name])
        kwargs["initial_std"] = tuple(taken(std) for std in kwargs["initial_std"])  # a pair, each maybe per channel
        return type(self)(self.dt, **kwargs)

    @classmethod
    def from_episodes(cls, dt: float, velocity, inputs, measurement_variance, **kwargs):
        """The filter with ``G``, ``s`` and ``q`` from :func:`fit_input_jumps` of recorded episodes, the
        measurement variance ``r`` (noise variance plus :math:`\\Delta^2/12` for quantization) and, unless
        ``initial_std`` is given, the prior at reset where the episodes start, per channel
        (:func:`~smo_gym.observers.linear.calibrated_prior` of their
        :func:`~smo_gym.calibration.calibration_from_velocities`), as the wrapper gives its Kalman filters. With
        the constructor's wide default the first estimates of every episode were least-squares fits of a few
        noisy samples: ``scripts/bench_accuracy.py``, ``kalman-imm-input`` over the 18 real-sensor physics rows
        0.484 -> 0.462 of the backward difference's RMSE (0.632 -> 0.579 under uniform random actions)."""
        jumps = fit_input_jumps(velocity, inputs, dt)
        if "initial_std" not in kwargs:
            from ..calibration import calibration_from_velocities  # it imports the observers: here, not above

            kwargs.update(calibrated_prior(calibration_from_velocities(list(velocity), dt, (1,), noise=0.0)))
        return cls(dt, jumps.process_noise, measurement_variance, jumps.input_gain, jumps.jump_noise, **kwargs)


class PerChannelInput(InputJumpUpdates, PerChannel):
    r""":class:`~smo_gym.observers.composite.PerChannel` with some parts told the control input: filters of
    :class:`~smo_gym.observers.input_kalman.InputJumpFilter` (``"kalman-imm-input"``, ...) on some channels,
    observers of the measurements only on the others.

    A told filter's channels are independent given the input (each is a Kalman filter of its own whose
    acceleration moves by its row of :math:`G\Delta u`), so on its channels the composite estimates exactly what
    the whole filter does on them; ``"auto"`` takes it on the joints where it wins. At each sample the told parts'
    filters move first (:meth:`~smo_gym.observers.input_kalman.InputJumpUpdates.update`), then the composite's one
    compiled step advances every part; ``update(y, u)`` and ``run(Y, U)`` as for the told filters, all or nothing.

    Parameters
    ----------
    parts, mean_over :
        As :class:`~smo_gym.observers.composite.PerChannel`; one or more parts are told the input, all with the
        same number of inputs ``m``.

    Attributes
    ----------
    input_gain : ndarray, shape (n_channels, m)
        ``G`` of every channel: the told part's rows, zero on the other channels.
    jump_noise : ndarray, shape (n_channels,)
        ``s`` of every channel, zero on the channels of parts not told the input.
    """

    @check_keywords
    def __init__(self, parts: Sequence, *, mean_over: float | None = None):
        super().__init__(parts, mean_over=mean_over)
        for i, (observer, _) in enumerate(self.parts):
            if observer.takes_input and not isinstance(observer, InputJumpFilter):
                raise TypeError(
                    f"expected parts told the input to be filters of InputJumpFilter, actual value: parts[{i}] is a "
                    f"{type(observer).__name__}"
                )
        told = [(observer, idx) for observer, idx in self.parts if isinstance(observer, InputJumpFilter)]
        widths = sorted({observer.input_gain.shape[1] for observer, _ in told})
        if len(widths) != 1:
            raise ValueError(
                "expected one or more parts told the same number of inputs, actual value: "
                + (f"inputs {widths}" if told else "none told the input; use PerChannel")
            )
        self.input_gain = np.zeros((self.n_channels, widths[0]))
        self.jump_noise = np.zeros(self.n_channels)
        for observer, idx in told:
            self.input_gain[idx] = observer.input_gain
            self.jump_noise[idx] = observer.jump_noise
        #: the told parts' filters on the composite's channels
        self._targets = tuple(
            JumpTarget(t.input_gain, t.jump_noise, t.blocks, idx[t.channels].astype(np.int64))
            for observer, idx in told
            for t in observer.jump_targets()
        )

    def jump_targets(self) -> tuple[JumpTarget, ...]:
        """The told parts' filters, on the composite's channels."""
        return self._targets


@register_observer("kalman-ca-input", bound=3, model_based=True)
class KalmanCAInput(InputJumpFilter, KalmanCA):
    r"""Constant-acceleration Kalman filter with the predicted acceleration jump of each change of input.

    Per channel :class:`~smo_gym.observers.KalmanCA` (module notes), whose acceleration estimate moves by
    :math:`G\Delta u_k` and whose acceleration variance grows by :math:`s\|\Delta u_k\|^2` before each prediction
    (:math:`\Delta u_k = u_k - u_{k-1}`, the change of the input that acts over the interval ending at sample
    ``k``). Shapes: measurements ``(..., n)``, inputs ``(..., m)`` with the same leading (batch) shape, estimates
    ``(..., n, 3)``.

    Parameters
    ----------
    dt, process_noise, measurement_noise, initial_std, huber, wrap :
        As :class:`~smo_gym.observers.KalmanCA`.
    input_gain : array_like, shape (n, m)
        ``G``: acceleration jump per unit change of each input (:func:`fit_input_jumps`).
    jump_noise : float or array_like, shape (n,)
        ``s`` >= 0: variance of the jump's prediction error per unit of :math:`\|\Delta u\|^2`.

    Notes
    -----
    The input before the first update after a reset is unknown (a reset is given measurements only), so the first
    update predicts no jump; the prior covariance (``initial_std``) covers it. ``update(y)`` without an input, or
    ``run(Y)``, is :class:`~smo_gym.observers.KalmanCA` and forgets the last input.
    """

    _jump_blocks = np.array([0], dtype=np.int64)

    @check_keywords
    def __init__(
        self,
        dt: float,
        process_noise,
        measurement_noise,
        input_gain,
        jump_noise=0.0,
        *,
        initial_std: tuple[float, float] = (10.0, 100.0),
        huber: float | None = None,
        discretization: str | None = None,
        wrap=None,
    ):
        super().__init__(
            dt, process_noise, measurement_noise, initial_std=initial_std, huber=huber,
            discretization=discretization, wrap=wrap,
        )  # fmt: skip
        self._set_input_model(input_gain, jump_noise)


@register_observer("kalman-imm-input", bound=3, model_based=True)
class KalmanIMMInput(InputJumpFilter, KalmanIMM):
    r"""The IMM estimator of two constant-acceleration Kalman filters (:class:`~smo_gym.observers.KalmanIMM`), each
    with the predicted acceleration jump of each change of input (as :class:`KalmanCAInput`).

    Parameters
    ----------
    dt, process_noise, measurement_noise, smooth_ratio, stay, initial_std, huber, wrap :
        As :class:`~smo_gym.observers.KalmanIMM` (``process_noise``: the fast mode's density).
    input_gain, jump_noise :
        As :class:`KalmanCAInput`.
    """

    _jump_blocks = np.array([_MODES, _MODES + 9], dtype=np.int64)

    @check_keywords
    def __init__(
        self,
        dt: float,
        process_noise,
        measurement_noise,
        input_gain,
        jump_noise=0.0,
        *,
        smooth_ratio: float = 0.01,
        stay: float = 0.99,
        initial_std: tuple[float, float] = (10.0, 100.0),
        huber: float | None = None,
        discretization: str | None = None,
        wrap=None,
    ):
        super().__init__(
            dt, process_noise, measurement_noise, smooth_ratio=smooth_ratio, stay=stay, initial_std=initial_std,
            huber=huber, discretization=discretization, wrap=wrap,
        )  # fmt: skip
        self._set_input_model(input_gain, jump_noise)
