r"""Composable measurement models for joint positions.

A sensor maps the true signal ``y`` (joint positions, shape ``(..., n_channels)``) to what a real controller
reads. Models are *stages* applied in order; ``stage_a | stage_b`` (or :class:`Chain`) composes them:

==================  =========================================================================================
:class:`GaussianNoise`   :math:`x \leftarrow x + \sigma\,n_k,\ n_k \sim \mathcal N(0, 1)`
:class:`UniformNoise`    :math:`x \leftarrow x + b\,u_k,\ u_k \sim \mathcal U(-1, 1)` (bounded noise, the SMO setting)
:class:`Quantization`    :math:`x \leftarrow \Delta\,\lfloor x/\Delta + 1/2\rfloor` (an encoder's counts)
:class:`Bias`            :math:`x \leftarrow x + b`, ``b`` fixed or drawn per episode from :math:`\mathcal N(0, s^2)`
:class:`Drift`           :math:`d_k = d_{k-1} + \sigma_d\sqrt{\tau}\,n_k,\ x \leftarrow x + d_k` (random walk)
:class:`Delay`           :math:`x_k \leftarrow x_{k-d}` (``d`` samples of transport delay)
:class:`Dropout`         with probability ``p`` the sample is lost and the last output is held
:class:`Outliers`        with probability ``p`` a channel gets a gross error :math:`s\,n_k`
:class:`Wrap`            angles to :math:`[-\pi, \pi)`: :math:`x \leftarrow x - 2\pi\lfloor (x + \pi)/2\pi\rfloor`
==================  =========================================================================================

Every chain runs as **one compiled call per sample** (:func:`_chain_kernel`): the stages are packed into integer
codes and per-channel parameter rows, and the random numbers come from blocks pre-drawn from the sensor's own
``numpy.random.Generator`` (one NumPy call per ``BLOCK`` samples). Each stage consumes exactly one standard normal
and one uniform per channel and sample whether it needs them or not, so the stream, and therefore the
measurements, depend only on the seed and the chain, not on how samples are batched (``measure`` sample by sample
and ``run`` on a block give the same numbers).

Channels may be angular (hinge joints, rotational tangent coordinates; radians) or linear (slide joints,
translations; metres): :meth:`Sensor.reset` takes an ``angular`` mask and :class:`Quantization` a resolution for
each kind. Encoder resolutions come from counts per revolution, ``2 pi / counts`` rad; a linear axis is modelled
as the same encoder on a drive of ``linear_travel`` metres per revolution (default 1 cm per radian, i.e.
``2 pi * 0.01`` m per revolution), so its resolution is ``linear_travel / counts`` m.

A non-finite output (from a non-finite true signal or a model) is never returned: :meth:`Sensor.measure` raises
``ValueError`` naming the channel.

Named presets (:data:`PRESETS`, :func:`make_sensor`): ``"ideal"``, ``"encoder-12bit"``, ``"encoder-12bit-noisy"``,
``"encoder-16bit"``, ``"low-cost"`` (noise, 10-bit, 2-sample delay, 2 % dropouts), ``"drifting"`` (bias and random
walk), ``"outliers"`` (noisy 12-bit encoder with rare gross errors).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np
from numba import njit

from ._validation import (
    as_real_array,
    check_bool,
    check_int_in_range,
    check_keywords,
    check_mask,
    check_nonnegative,
    check_positive,
    did_you_mean,
)

__all__ = [
    "BLOCK",
    "PRESETS",
    "Bias",
    "Chain",
    "Delay",
    "Drift",
    "Dropout",
    "Encoder",
    "GaussianNoise",
    "Outliers",
    "Quantization",
    "Sensor",
    "Stage",
    "UniformNoise",
    "Wrap",
    "make_sensor",
    "resolution_from_counts",
]

#: samples of random numbers drawn per refill
BLOCK = 256
#: metres per revolution of the drive a linear axis' encoder is assumed to sit on (1 cm per radian)
LINEAR_TRAVEL = 2.0 * np.pi * 0.01

_GAUSS, _UNIFORM, _QUANT, _BIAS, _DRIFT, _DELAY, _DROPOUT, _OUTLIER, _WRAP = range(9)


# ----------------------------------------------------------------------------------------------------------------
# compiled chain
# ----------------------------------------------------------------------------------------------------------------
@njit(cache=True, inline="always")
def _chain_kernel(y, kinds, params, state, ring, ring_pos, rand, prime, out):
    """Apply the stages ``kinds`` to one sample ``y`` (N,), writing ``out`` (N,).

    ``params`` (S, 2, N) per-stage, per-channel parameters; ``state`` (S, N) bias / drift value / last output;
    ``ring`` (S, K, N) delay lines with write positions ``ring_pos`` (S,); ``rand`` (2, S, N) this sample's
    standard normals (``rand[0]``) and uniforms on [0, 1) (``rand[1]``). ``prime`` (reset): delay lines are filled
    with the current value and nothing is dropped or corrupted. Returns -1, or the first channel whose input (then
    nothing is changed) or output is not finite.
    """
    n = y.shape[0]
    normals = rand[0]
    uniforms = rand[1]
    for j in range(n):  # a non-finite true signal is reported before any stage state (delay line, held value) moves
        if not np.isfinite(y[j]):
            return j
    for j in range(n):
        out[j] = y[j]
    for s in range(kinds.shape[0]):
        k = kinds[s]
        if k == _GAUSS:
            for j in range(n):
                out[j] += params[s, 0, j] * normals[s, j]
        elif k == _UNIFORM:
            for j in range(n):
                out[j] += params[s, 0, j] * (2.0 * uniforms[s, j] - 1.0)
        elif k == _QUANT:
            for j in range(n):
                r = params[s, 0, j]
                if r > 0.0:
                    out[j] = r * np.floor(out[j] / r + 0.5)
        elif k == _BIAS:
            for j in range(n):
                out[j] += state[s, j]
        elif k == _DRIFT:
            for j in range(n):
                if not prime:
                    state[s, j] += params[s, 0, j] * normals[s, j]
                out[j] += state[s, j]
        elif k == _DELAY:
            K = ring.shape[1]
            d = int(params[s, 0, 0])
            pos = ring_pos[s]
            for j in range(n):
                if prime:
                    for i in range(K):
                        ring[s, i, j] = out[j]
                else:
                    ring[s, pos, j] = out[j]
                    out[j] = ring[s, (pos - d + K) % K, j]
            ring_pos[s] = (pos + 1) % K
        elif k == _DROPOUT:
            p = params[s, 0, 0]
            per_channel = params[s, 1, 0] > 0.0
            lost_all = (not prime) and uniforms[s, 0] < p
            for j in range(n):
                lost = (uniforms[s, j] < p) if per_channel else lost_all
                if lost and not prime:
                    out[j] = state[s, j]
                else:
                    state[s, j] = out[j]
        elif k == _OUTLIER:
            if not prime:
                for j in range(n):
                    if uniforms[s, j] < params[s, 0, j]:
                        out[j] += params[s, 1, j] * normals[s, j]
        elif k == _WRAP:
            for j in range(n):
                p = params[s, 0, j]  # the period: 2 pi on angular channels, 0 (unchanged) on linear ones
                if p > 0.0:
                    out[j] -= p * np.floor((out[j] + 0.5 * p) / p)
    for j in range(n):
        if not np.isfinite(out[j]):
            return j
    return -1


@njit(cache=True)
def _chain_block(Y, kinds, params, state, ring, ring_pos, rand, t0, out, prime=False):
    """:func:`_chain_kernel` over the rows of ``Y`` (T, N), random numbers from ``rand[t0 + t]``.

    Returns -1, or ``t * N + j`` for the first non-finite input or output (row ``t``, channel ``j``): one integer,
    so the call returns without boxing a tuple. Every input is checked before the first row runs, so a non-finite
    true signal anywhere in the block leaves the state as it was.
    """
    n = Y.shape[1]
    for t in range(Y.shape[0]):
        for j in range(n):
            if not np.isfinite(Y[t, j]):
                return t * n + j
    for t in range(Y.shape[0]):
        status = _chain_kernel(Y[t], kinds, params, state, ring, ring_pos, rand[t0 + t], prime, out[t])
        if status != -1:
            return t * n + status
    return -1


# ----------------------------------------------------------------------------------------------------------------
# checks
# ----------------------------------------------------------------------------------------------------------------
_FLOAT64 = np.dtype(np.float64)


def _as_block_input(y, name: str = "y") -> np.ndarray:
    """``y`` as a writeable, aligned, C-contiguous float64 array (the layout the bound entry point takes)."""
    if type(y) is np.ndarray and y.dtype is _FLOAT64 and (f := y.flags).c_contiguous and f.writeable and f.aligned:
        return y
    return np.array(as_real_array(name, y), dtype=np.float64, order="C")


def _nonneg(name: str, value) -> np.ndarray:
    arr = as_real_array(name, value)
    if arr.size == 0 or arr.ndim > 1:
        raise ValueError(
            f"expected {name} to be a number or one per channel (shape (n_channels,)), actual value: shape {arr.shape}"
        )
    if np.any(~np.isfinite(arr) | (arr < 0.0)):
        raise ValueError(f"expected {name} >= 0 and finite everywhere, actual value: {value!r}")
    return arr


def _probability(name: str, value) -> float:
    arr = _nonneg(name, value)
    if arr.ndim != 0 or float(arr) > 1.0:
        raise ValueError(f"expected {name} to be a probability in [0, 1], actual value: {value!r}")
    return float(arr)


def _per_channel(name: str, value: np.ndarray, n: int) -> np.ndarray:
    try:
        return np.broadcast_to(value, (n,)).astype(np.float64)
    except ValueError:
        raise ValueError(
            f"expected {name} to be a scalar or to have one entry per channel ({n}), actual value: shape "
            f"{np.shape(value)}"
        ) from None


def resolution_from_counts(counts_per_revolution: int) -> float:
    """Angular resolution ``2 pi / counts`` [rad] of an encoder with ``counts_per_revolution`` counts."""
    counts = check_int_in_range("counts_per_revolution", counts_per_revolution, 2, 2**40)
    return 2.0 * np.pi / counts


# ----------------------------------------------------------------------------------------------------------------
# the sensor: a chain of stages, run by the compiled kernel
# ----------------------------------------------------------------------------------------------------------------
class SensorArrays(NamedTuple):
    """The arrays of a sensor's stream, as the compiled chain (:func:`_chain_kernel`) reads and writes them.

    ``S`` stages, ``n`` channels, ``K`` the longest delay plus one, :data:`BLOCK` pre-drawn samples.
    """

    kinds: np.ndarray
    """Stage kind codes, shape ``(S,)``, int64."""
    params: np.ndarray
    """Packed stage parameters, shape ``(S, 2, n)``."""
    state: np.ndarray
    """Per-stage state (bias, drift, held value, ...), shape ``(S, n)``."""
    ring: np.ndarray
    """Delay lines, shape ``(S, K, n)``."""
    ring_pos: np.ndarray
    """Write position of each delay line, shape ``(S,)``, int64."""
    rand: np.ndarray
    """Pre-drawn random numbers (normal, uniform), shape ``(BLOCK, 2, S, n)``."""


class Sensor:
    """Base of every sensor model: a sequence of :class:`Stage` objects run by one compiled call per sample.

    Life cycle: ``reset(y0, seed=...)`` returns the first measurement and must come first; ``measure(y)``
    (or calling the sensor) processes one sample; ``run(Y)`` a block of samples ``(T, ...)``.

    A sensor is its stages: the compiled chain runs them from :attr:`arrays`, and so does the wrapper's fused path
    (:mod:`smo_gym.engine.fused`). A subclass therefore defines stages (a :class:`Stage` with a kind the chain
    knows, or a :class:`Chain`), never its own ``measure``/``run``/``reset``: that is refused when the class is
    defined, so that no path can run a sensor differently from another.

    Attributes
    ----------
    stages : tuple of Stage
        The models, applied in order.
    """

    #: the methods that run the stream: one implementation, the compiled chain
    _STREAM_METHODS = ("measure", "run", "reset", "__call__", "_run_flat")

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        overridden = [name for name in Sensor._STREAM_METHODS if name in vars(cls)]
        if overridden:
            raise TypeError(
                f"expected a sensor defined by its stages (smo_gym.sensors.Stage, Chain), actual value: "
                f"{cls.__name__} overrides {', '.join(overridden)}"
            )

    # state of the stream, set by reset (class defaults: a sensor that was never reset)
    _rng = None
    _config = None
    _kinds = None
    _block_call = None
    _arrays = None
    _storage = None

    @property
    def stages(self) -> tuple[Stage, ...]:
        raise NotImplementedError(
            f"expected a sensor model (a Stage, a Chain or a preset of make_sensor), actual "
            f"value: the base class {type(self).__name__}, which has no stages"
        )

    def __or__(self, other: Sensor) -> Chain:
        if not isinstance(other, Sensor):
            return NotImplemented
        return Chain(*self.stages, *other.stages)

    # ---- derived numbers ------------------------------------------------------------------------------------
    def error_std(self, n_channels: int, angular=None) -> np.ndarray:
        r"""Standard deviation of the zero-mean random error per channel, shape ``(n_channels,)``.

        :math:`\sqrt{\sum \sigma^2 + \sum b^2/3 + \sum \Delta^2/12}` over the Gaussian, uniform and quantization
        stages (bias, drift, delay, dropouts and outliers excluded). Used to tune the observers' gains.
        """
        n_channels = check_int_in_range("n_channels", n_channels, 1, 2**31)
        angular = self._angular(n_channels, angular)
        var = np.zeros(n_channels)
        with np.errstate(over="ignore"):  # an absurd model gives inf here, and is caught at the first sample
            for stage in self.stages:
                var += stage._variance(n_channels, angular)
        return np.sqrt(var)

    def quantization_step(self, n_channels: int, angular=None) -> np.ndarray:
        """The coarsest quantization step of the sensor per channel, shape ``(n_channels,)`` (0: no quantization)."""
        n_channels = check_int_in_range("n_channels", n_channels, 1, 2**31)
        angular = self._angular(n_channels, angular)
        step = np.zeros(n_channels)
        for stage in self.stages:
            step = np.maximum(step, stage._step(n_channels, angular))
        return step

    @staticmethod
    def _angular(n: int, angular) -> np.ndarray:
        if angular is None:
            return np.ones(n, dtype=bool)
        a = check_mask("angular", angular).reshape(-1)
        if a.shape != (n,):
            raise ValueError(f"expected angular with one entry per channel ({n}), actual value: shape {a.shape}")
        return a

    # ---- life cycle -----------------------------------------------------------------------------------------
    @check_keywords
    def reset(
        self, y0, *, seed=None, rng: np.random.Generator | None = None, dt: float = 1.0, angular=None
    ) -> np.ndarray:
        """Start the sensor at the true signal ``y0`` and return the first measurement.

        Parameters
        ----------
        y0 : array_like, shape (..., n_channels)
            True signal at the first sample.
        seed : int or SeedSequence, optional
            Seed of the sensor's own random stream (``numpy.random.default_rng(seed)``); ignored if ``rng`` is
            given. A vector env gives each environment its own seed, hence its own stream.
        rng : numpy.random.Generator, optional
            Use this generator (kept and advanced by the sensor). Passing the generator of the previous reset
            (same shape, ``dt`` and ``angular``) *continues* the stream: a new episode restarts the stages' state
            (delays, held values, drawn biases) but keeps the packed parameters and the random numbers already
            drawn, so a restart costs no refill. A new generator or seed packs the stages again.
        dt : float
            Sampling step [s] (scales the random walk of :class:`Drift`).
        angular : array_like of bool, shape (..., n_channels), optional
            Which channels are angles (radians); the others are lengths (metres). Default: all angular.

        Returns
        -------
        ndarray, shape (..., n_channels)
            The first measurement: quantized, biased and noisy, but never delayed, dropped or an outlier.
        """
        # everything is checked before any state changes: a rejected reset leaves the sensor as it was
        y0 = np.array(as_real_array("y0", y0), dtype=np.float64, order="C")
        if y0.ndim == 0:
            raise ValueError(f"expected y0 with shape (..., n_channels), actual value: a scalar {float(y0)!r}")
        if y0.size == 0:
            raise ValueError(
                f"expected y0 with at least one channel and no empty batch dimension, actual value: shape {y0.shape}"
            )
        self._check_finite_start(y0)
        dt = check_positive("dt", dt)
        if rng is not None and not isinstance(rng, np.random.Generator):
            raise TypeError(f"expected rng to be a numpy.random.Generator (or None), actual value: {rng!r}")
        if rng is None:
            try:
                fresh = np.random.default_rng(seed)
            except (TypeError, ValueError):
                raise TypeError(
                    "expected seed to be None, a non-negative int, a SeedSequence or a Generator, actual "
                    f"value: {seed!r}"
                ) from None
        n = y0.size
        if not (type(angular) is np.ndarray and angular.dtype == bool and angular.shape == (n,)):
            if angular is not None:
                angular = check_mask("angular", angular)
                try:
                    angular = np.broadcast_to(angular, y0.shape)
                except ValueError:
                    raise ValueError(
                        f"expected angular broadcastable to the shape of y0 {y0.shape}, actual value: "
                        f"shape {angular.shape}"
                    ) from None
            angular = self._angular(n, angular)
        config = (y0.shape, float(dt), angular.tobytes())
        if rng is not None and rng is self._rng and config == self._config:
            # the same stream continues (an episode restart without a new seed): the packed parameters and the
            # pre-drawn random block stay valid, so a restart costs no refill
            return self._start(y0.reshape(1, n))
        else:
            stages = self.stages
            S = len(stages)
            params = np.zeros((S, 2, n))
            for s, st in enumerate(stages):  # may reject per-channel values of another size: before any change
                params[s] = st._pack(n, angular, dt)
            K = 1 + max([st.samples for st in stages if isinstance(st, Delay)], default=0)
            arrays = SensorArrays(
                np.array([st._kind for st in stages], dtype=np.int64),
                params,
                np.zeros((S, n)),
                np.zeros((S, K, n)),
                np.zeros(S, dtype=np.int64),
                np.zeros((BLOCK, 2, S, n)),
            )
            storage = self._storage
            if storage is not None and all(a.shape == b.shape for a, b in zip(storage, arrays, strict=True)):
                for to, value in zip(storage, arrays, strict=True):  # the caller's arrays (use_arrays) keep the stream
                    to[...] = value
                arrays = storage
            else:
                self._storage = None  # another number of channels or stages: the caller's arrays do not fit
            self._kinds, self._params, self._state, self._ring, self._ring_pos, self._rand = arrays
            self._rng = rng if rng is not None else fresh
            self._shape, self._config, self._size = y0.shape, config, n
            # stages whose state is drawn per episode (Bias); the others start at zero
            self._drawn = [
                (s, st) for s, st in enumerate(stages) if type(st)._initial_state is not Stage._initial_state
            ]
            self._t = BLOCK  # drawn at the first sample
            self._block_call = None
        return self._start(y0.reshape(1, n))

    def restart(self, y0) -> np.ndarray:
        """Start a new episode at the true signal ``y0`` on the stream of the last reset, which goes on: the
        reset with that reset's generator, ``dt`` and ``angular``, for a ``y0`` of its shape.

        The stages' state starts again (delays, held values; biases drawn anew) and the packed parameters and the
        random numbers already drawn are kept, as in that reset; the arguments that did not change are not checked
        again (a wrapper restarts its sensor at every episode end, and the checks cost as much as the restart).

        Returns
        -------
        ndarray, shape (..., n_channels)
            The first measurement, as :meth:`reset`'s.

        Raises
        ------
        RuntimeError
            Before any reset.
        ValueError
            ``y0`` of another shape than the last reset's, or not finite (the sensor's state is kept).
        """
        y0 = self._check_ready(y0, "y0")
        if y0.shape != self._shape:
            raise ValueError(f"expected y0 with the last reset's shape {self._shape}, actual value: {y0.shape}")
        self._check_finite_start(y0)
        return self._start(y0.reshape(1, self._size))

    def _check_finite_start(self, y0: np.ndarray) -> None:
        """Refuse a true signal ``y0`` to start from with a non-finite entry, naming it, before any state changes."""
        if not np.isfinite(y0).all():
            channel = int(np.flatnonzero(~np.isfinite(y0))[0])
            raise ValueError(
                f"expected a finite measurement, actual value: {y0.reshape(-1)[channel]!r} at "
                f"{self._where(channel, y0.shape)} in the true signal y0; the sensor's state was kept"
            )

    def _start(self, y0f: np.ndarray) -> np.ndarray:
        """A new episode at the checked true signal ``y0f`` ``(1, n)``: the stages' state from zero and the drawn ones
        (:class:`Bias`) drawn, then the first measurement (one compiled call)."""
        self._state[:] = 0.0
        self._ring[:] = 0.0
        self._ring_pos[:] = 0
        for s, st in self._drawn:
            self._state[s] = st._initial_state(self._size, self._rng)
        if self._t >= BLOCK:
            self._refill()
        if self._block_call is None:
            self._bind()
        out = np.empty_like(y0f)
        status = self._block_call(
            y0f, self._kinds, self._params, self._state, self._ring, self._ring_pos, self._rand, self._t, out, True
        )
        self._t += 1
        if status != -1:
            self._raise(status, y0f[0], out[0])
        return out.reshape(self._shape)

    def _refill(self) -> None:
        S, n = self._state.shape
        if S:
            self._rand[:, 0] = self._rng.standard_normal((BLOCK, S, n))
            self._rand[:, 1] = self._rng.random((BLOCK, S, n))
        self._t = 0

    # ---- the stream's arrays, for a compiled caller --------------------------------------------------------------
    @property
    def arrays(self) -> SensorArrays:
        """The stream's arrays (not copies), for a compiled caller that runs the chain in place.

        A reset may replace them with new arrays: read them again after each. The caller reserves the random
        rows it uses with :meth:`reserve_random_rows`. The compiled chain trusts these arrays as the sensor wrote
        them: a caller writes only what a measurement writes (a delay ring's position out of range, say, would make
        it read outside the ring).
        """
        arrays = self._arrays
        if arrays is None or arrays.state is not self._state or arrays.rand is not self._rand:
            if self._kinds is None:
                raise RuntimeError("expected reset(y0) first, actual value: the sensor was never reset")
            arrays = self._arrays = SensorArrays(
                self._kinds, self._params, self._state, self._ring, self._ring_pos, self._rand
            )
        return arrays

    def use_arrays(self, arrays: SensorArrays) -> None:
        """Keep the stream in ``arrays`` from now on: a caller's arrays, e.g. rows of stacked arrays with one row per
        sensor, so that one compiled call advances several sensors (:class:`smo_gym.engine.batch.MeasurementBatch`).

        Each array must have the dtype and shape of the current one in :attr:`arrays` and be writeable, aligned and
        C-contiguous. The current stream is copied into them, and later resets write into them, also a reset with a
        new seed (a reset to another number of channels or stages cannot, and leaves them). The sensor stays usable
        on its own (``measure``, ``run``, ``reset``): it reads and writes the same arrays. Pickled or copied, a
        sensor has arrays of its own.

        Raises
        ------
        RuntimeError
            The sensor was never reset (it has no stream yet).
        TypeError, ValueError
            An array of another type, layout, dtype or shape.
        """
        current = self.arrays
        if not isinstance(arrays, tuple) or len(arrays) != len(SensorArrays._fields):
            raise TypeError(
                f"expected SensorArrays (a tuple of the {len(SensorArrays._fields)} arrays "
                f"{', '.join(SensorArrays._fields)}), actual value: {arrays!r:.80}"
            )
        arrays = SensorArrays(*arrays)
        for name, new, old in zip(SensorArrays._fields, arrays, current, strict=True):
            if not (
                type(new) is np.ndarray
                and new.dtype == old.dtype
                and (f := new.flags).c_contiguous
                and f.writeable
                and f.aligned
            ):
                raise TypeError(
                    f"expected {name} as a writeable, aligned, C-contiguous {old.dtype} array, actual value: "
                    f"{new!r:.80}"
                )
            if new.shape != old.shape:
                raise ValueError(f"expected {name} with shape {old.shape}, actual value: {new.shape}")
        for new, old in zip(arrays, current, strict=True):
            new[...] = old
        self._kinds, self._params, self._state, self._ring, self._ring_pos, self._rand = arrays
        self._storage = arrays

    def reserve_random_rows(self, n_samples: int) -> int | None:
        """Reserve the next ``n_samples`` rows of the random block for a compiled caller and return the first.

        Returns None, reserving nothing, when the rows would straddle the end of the block: the caller then
        measures through :meth:`run`, which splits the samples at the refill (so the random stream does not
        depend on how samples are batched). A block used up is refilled in place (the :attr:`arrays` stay valid).

        Raises
        ------
        TypeError, ValueError
            ``n_samples`` is not an integer in ``[1, BLOCK]`` (the compiled caller would read past the block).
        RuntimeError
            The sensor was never reset.
        """
        if type(n_samples) is not int or not 0 < n_samples <= BLOCK:  # the hot path is one comparison
            n_samples = check_int_in_range("n_samples", n_samples, 1, BLOCK)
        if self._kinds is None:
            raise RuntimeError("expected reset(y0) before reserving random rows, actual value: never reset")
        t0 = self._t
        if t0 + n_samples > BLOCK:
            if t0 < BLOCK:
                return None
            self._refill()
            t0 = 0
        self._t = t0 + n_samples
        return t0

    @staticmethod
    def _where(channel: int, shape: tuple[int, ...]) -> str:
        index = np.unravel_index(channel, shape)
        return f"channel {index[-1]}" + (
            f" of batch element {tuple(int(i) for i in index[:-1])}" if len(index) > 1 else ""
        )

    def _raise(self, channel: int, y: np.ndarray, out: np.ndarray):
        where = self._where(channel, self._shape)
        if not np.isfinite(y[channel]):  # rejected before any stage ran: the sensor's state is unchanged
            raise ValueError(
                f"expected a finite measurement, actual value: {y[channel]!r} at {where} in the true "
                "signal; the sample was rejected before any stage ran and the sensor's state kept"
            )
        raise ValueError(
            f"expected a finite measurement, actual value: {out[channel]!r} at {where}, produced by the sensor model "
            f"{self!r}; a non-finite measurement is never passed on (the sensor's stream has moved past the sample: "
            "its random numbers and stage states, as for a sample taken)"
        )

    def _check_ready(self, y, name: str = "y") -> np.ndarray:
        if getattr(self, "_kinds", None) is None:
            raise RuntimeError("expected reset(y0) before measure(y), actual value: the sensor was never reset")
        return _as_block_input(y, name)

    def _bind(self) -> None:
        """Resolve the compiled entry point of :func:`_chain_block` for this sensor's arrays (once per reset).

        ``run`` passes only writeable, aligned, C-contiguous float64 blocks, so one entry point serves every call
        and numba's per-call type dispatch (about 0.1 us per argument, nine arguments) is skipped.
        """
        from .observers.base import _compiled_entry

        Y = np.empty((1, self._size))
        self._block_call = _compiled_entry(
            _chain_block,
            (
                Y,
                self._kinds,
                self._params,
                self._state,
                self._ring,
                self._ring_pos,
                self._rand,
                np.int64(0),
                Y,
                np.bool_(False),
            ),
        )

    def measure(self, y) -> np.ndarray:
        """Measure one sample of the true signal ``y`` (shape as at ``reset``); returns a new array."""
        y = self._check_ready(y)
        if y.shape != self._shape:
            raise ValueError(f"expected y with shape {self._shape}, actual value: {y.shape}")
        return self._run_flat(y.reshape(1, self._size))[0].reshape(self._shape)

    __call__ = measure

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state.pop("_block_call", None)  # a compiled entry point does not pickle; bound again on first use
        state.pop("_storage", None)  # a copy has arrays of its own
        return state

    def run(self, Y) -> np.ndarray:
        """Measure a block ``Y`` of shape ``(T, ...)``, continuing the stream; equal to ``measure`` row by row."""
        Y = self._check_ready(Y, "Y")
        if Y.ndim == 0 or Y.shape[1:] != self._shape:
            raise ValueError(f"expected Y with shape (T, *{self._shape}), actual value: {Y.shape}")
        if Y.ndim == 2:  # already flat: skip two reshapes (this is the wrapper's per-step path)
            return self._run_flat(Y)
        return self._run_flat(Y.reshape(Y.shape[0], self._size)).reshape(Y.shape)

    def _run_flat(self, Y: np.ndarray) -> np.ndarray:
        """``run`` on a validated block ``Y`` (T, N): writeable, aligned, C-contiguous float64 (see ``_bind``)."""
        T = Y.shape[0]
        out = np.empty((T, self._size))
        call = self._block_call
        if call is None:
            self._bind()
            call = self._block_call
        if BLOCK - self._t < T and not np.isfinite(Y).all():
            # a block over several refills runs in several calls: check it all first, so that a non-finite true
            # signal anywhere leaves the state (and the random stream) as it was, as within one call
            t, channel = divmod(int(np.flatnonzero(~np.isfinite(Y))[0]), self._size)
            self._raise(channel, Y[t], Y[t])
        done = 0
        while done < T:
            if self._t >= BLOCK:
                self._refill()
            m = min(T - done, BLOCK - self._t)
            Yb, outb = (Y, out) if m == T else (Y[done : done + m], out[done : done + m])
            status = call(
                Yb, self._kinds, self._params, self._state, self._ring, self._ring_pos, self._rand, self._t, outb, False
            )
            if status != -1:
                t, channel = divmod(status, self._size)
                if np.isfinite(Yb[t, channel]):  # produced by the model: these random numbers are used
                    self._t += m
                self._raise(channel, Yb[t], outb[t])
            self._t += m
            done += m
        return out

    def __repr__(self) -> str:
        return f"{type(self).__name__}({', '.join(map(repr, self.stages))})"


class Stage(Sensor):
    """One measurement model; also a complete :class:`Sensor` on its own."""

    _kind: int = -1

    @property
    def stages(self) -> tuple[Stage, ...]:
        return (self,)

    def _pack(self, n: int, angular: np.ndarray, dt: float) -> np.ndarray:
        """Parameter rows ``(2, n)`` for ``n`` channels."""
        return np.zeros((2, n))

    def _initial_state(self, n: int, rng: np.random.Generator) -> np.ndarray:
        return np.zeros(n)

    def _variance(self, n: int, angular: np.ndarray) -> np.ndarray:
        return np.zeros(n)

    def _step(self, n: int, angular: np.ndarray) -> np.ndarray:
        """The quantization step per channel (0: this stage does not quantize)."""
        return np.zeros(n)

    def _fields(self) -> dict:
        return {}

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self._fields().items())
        return f"{type(self).__name__}({args})"

    def __eq__(self, other) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        a, b = self._fields(), other._fields()
        return a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)

    __hash__ = None  # mutable (the stream lives in the object)


class GaussianNoise(Stage):
    r"""Additive white Gaussian noise, :math:`x \leftarrow x + \sigma n_k`.

    Parameters
    ----------
    std : float or array_like, shape (n_channels,)
        :math:`\sigma \ge 0` in the channel's unit (rad or m).
    """

    _kind = _GAUSS

    @check_keywords
    def __init__(self, std):
        self.std = _nonneg("std", std)

    def _pack(self, n, angular, dt):
        p = np.zeros((2, n))
        p[0] = _per_channel("std", self.std, n)
        return p

    def _variance(self, n, angular):
        return _per_channel("std", self.std, n) ** 2

    def _fields(self):
        return {"std": self.std}


class UniformNoise(Stage):
    r"""Bounded additive noise, :math:`x \leftarrow x + b u_k,\ u_k \sim \mathcal U(-1, 1)`.

    The noise model of the sliding-mode literature (``|noise| <= b``): accuracy bounds there are stated for it.
    """

    _kind = _UNIFORM

    @check_keywords
    def __init__(self, bound):
        self.bound = _nonneg("bound", bound)

    def _pack(self, n, angular, dt):
        p = np.zeros((2, n))
        p[0] = _per_channel("bound", self.bound, n)
        return p

    def _variance(self, n, angular):
        return _per_channel("bound", self.bound, n) ** 2 / 3.0

    def _fields(self):
        return {"bound": self.bound}


class Quantization(Stage):
    r"""Round to the nearest multiple of the resolution, :math:`x \leftarrow \Delta\lfloor x/\Delta + 1/2\rfloor`.

    The error is in :math:`[-\Delta/2, \Delta/2]`, uniform for a moving signal (variance :math:`\Delta^2/12`).

    Parameters
    ----------
    resolution : float or array_like
        :math:`\Delta` [rad] of angular channels (hinges); 0 disables.
    linear_resolution : float or array_like, optional
        :math:`\Delta` [m] of linear channels (slides, translations); default
        ``resolution * LINEAR_TRAVEL / (2 pi)``, the same encoder on a drive of 1 cm per radian.
    """

    _kind = _QUANT

    @check_keywords
    def __init__(self, resolution, linear_resolution=None):
        self.resolution = _nonneg("resolution", resolution)
        self.linear_resolution = None if linear_resolution is None else _nonneg("linear_resolution", linear_resolution)

    @classmethod
    @check_keywords
    def from_counts(cls, counts_per_revolution: int, linear_travel: float = LINEAR_TRAVEL) -> Quantization:
        """An encoder of ``counts_per_revolution``: ``2 pi / counts`` rad, ``linear_travel / counts`` m."""
        res = resolution_from_counts(counts_per_revolution)
        return cls(res, linear_resolution=check_nonnegative("linear_travel", linear_travel) / counts_per_revolution)

    def _resolutions(self, n, angular):
        ang = _per_channel("resolution", self.resolution, n)
        lin = (
            ang * LINEAR_TRAVEL / (2.0 * np.pi)
            if self.linear_resolution is None
            else _per_channel("linear_resolution", self.linear_resolution, n)
        )
        return np.where(angular, ang, lin)

    def _pack(self, n, angular, dt):
        p = np.zeros((2, n))
        p[0] = self._resolutions(n, angular)
        return p

    def _variance(self, n, angular):
        return self._resolutions(n, angular) ** 2 / 12.0

    def _step(self, n, angular):
        return self._resolutions(n, angular)

    def _fields(self):
        return {"resolution": self.resolution, "linear_resolution": self.linear_resolution}


class Bias(Stage):
    r"""Constant offset :math:`x \leftarrow x + b`.

    Parameters
    ----------
    value : float or array_like
        Fixed offset (default 0).
    std : float or array_like
        If positive, a random offset :math:`\mathcal N(0, \mathrm{std}^2)` is added, drawn once at every
        ``reset`` (a calibration error that changes between episodes).
    """

    _kind = _BIAS

    @check_keywords
    def __init__(self, value=0.0, std=0.0):
        self.value = as_real_array("value", value)
        if self.value.size == 0 or self.value.ndim > 1 or not np.all(np.isfinite(self.value)):
            raise ValueError(f"expected a finite bias value, actual value: {value!r}")
        self.std = _nonneg("std", std)

    def _pack(self, n, angular, dt):
        _per_channel("value", self.value, n)  # checked with the other stages', before reset changes anything
        _per_channel("std", self.std, n)
        return np.zeros((2, n))

    def _initial_state(self, n, rng):
        b = _per_channel("value", self.value, n).copy()
        std = _per_channel("std", self.std, n)
        if np.any(std > 0):
            b += std * rng.standard_normal(n)
        return b

    def _fields(self):
        return {"value": self.value, "std": self.std}


class Drift(Stage):
    r"""Random-walk drift :math:`d_k = d_{k-1} + \sigma_d\sqrt{\tau}\,n_k`, :math:`x \leftarrow x + d_k`.

    Parameters
    ----------
    rate_std : float or array_like
        :math:`\sigma_d` [unit / sqrt(s)]: after ``t`` seconds the drift has standard deviation
        :math:`\sigma_d\sqrt t` whatever the sampling step ``tau`` (given to ``reset`` as ``dt``).
    """

    _kind = _DRIFT

    @check_keywords
    def __init__(self, rate_std):
        self.rate_std = _nonneg("rate_std", rate_std)

    def _pack(self, n, angular, dt):
        p = np.zeros((2, n))
        p[0] = _per_channel("rate_std", self.rate_std, n) * np.sqrt(dt)
        return p

    def _fields(self):
        return {"rate_std": self.rate_std}


class Delay(Stage):
    """Transport delay of ``samples`` samples: :math:`x_k \\leftarrow x_{k-d}`; before that, the first value."""

    _kind = _DELAY

    @check_keywords
    def __init__(self, samples: int):
        self.samples = check_int_in_range("samples", samples, 0, 10_000)

    def _pack(self, n, angular, dt):
        p = np.zeros((2, n))
        p[0] = self.samples
        return p

    def _fields(self):
        return {"samples": self.samples}


class Dropout(Stage):
    """Lost samples: with probability ``probability`` the output holds its last value.

    Parameters
    ----------
    probability : float
        Per sample (``per_channel=False``: the whole packet is lost, as on a field bus) or per channel.
    per_channel : bool
    """

    _kind = _DROPOUT

    @check_keywords
    def __init__(self, probability: float, per_channel: bool = False):
        self.probability = _probability("probability", probability)
        self.per_channel = check_bool("per_channel", per_channel)

    def _pack(self, n, angular, dt):
        p = np.zeros((2, n))
        p[0] = self.probability
        p[1] = 1.0 if self.per_channel else 0.0
        return p

    def _fields(self):
        return {"probability": self.probability, "per_channel": self.per_channel}


class Outliers(Stage):
    r"""Rare gross errors: with probability ``p`` per channel and sample, :math:`x \leftarrow x + s\,n_k`."""

    _kind = _OUTLIER

    @check_keywords
    def __init__(self, probability: float, scale):
        self.probability = _probability("probability", probability)
        self.scale = _nonneg("scale", scale)

    def _pack(self, n, angular, dt):
        p = np.zeros((2, n))
        p[0] = self.probability
        p[1] = _per_channel("scale", self.scale, n)
        return p

    def _fields(self):
        return {"probability": self.probability, "scale": self.scale}


class Wrap(Stage):
    r"""A single-turn angle: angular channels reduced to :math:`[-\pi, \pi)`, linear channels unchanged.

    .. math:: x \leftarrow x - 2\pi\,\bigl\lfloor (x + \pi) / 2\pi \bigr\rfloor

    What an absolute encoder without a turn counter reports. Differentiate its output with an observer built with
    ``wrap`` on the same channels (:class:`smo_gym.observers.Observer`), otherwise every crossing of
    :math:`\pm\pi` looks like a jump of :math:`2\pi` (a velocity spike of :math:`2\pi/\tau` for a finite
    difference).
    """

    _kind = _WRAP

    def _pack(self, n, angular, dt):
        p = np.zeros((2, n))
        p[0] = np.where(angular, 2.0 * np.pi, 0.0)
        return p


class Chain(Sensor):
    """Stages applied in order (``Chain(a, b)`` is ``a | b``); ``Chain()`` is the ideal sensor."""

    @check_keywords
    def __init__(self, *stages: Sensor):
        flat: list[Stage] = []
        for st in stages:
            if not isinstance(st, Sensor):
                raise TypeError(f"expected sensor stages (smo_gym.sensors.Stage), actual value: {st!r}")
            flat.extend(st.stages)
        self._stages = tuple(flat)

    @property
    def stages(self) -> tuple[Stage, ...]:
        return self._stages

    def __eq__(self, other) -> bool:
        if not isinstance(other, Chain):
            return NotImplemented
        return self.stages == other.stages

    __hash__ = None


class Encoder(Chain):
    r"""An encoder: optional electrical/interpolation noise, then quantization to counts, then (``wrap``) the
    reduction of a single-turn absolute encoder to one revolution.

    .. math:: y_k = \Delta\,\lfloor (x_k + \sigma n_k)/\Delta + 1/2 \rfloor

    The noise acts *before* the counter, so the output always lies on the encoder's grid, as real counts do.

    Parameters
    ----------
    resolution : float, optional
        :math:`\Delta` [rad]; give this or ``counts_per_revolution``.
    noise_std : float
        :math:`\sigma` [rad] (scaled by the linear/angular resolution ratio on linear channels).
    counts_per_revolution : int, optional
        Sets ``resolution = 2 pi / counts``.
    linear_resolution : float, optional
        Resolution of linear channels [m]; default the same encoder on a drive of 1 cm per radian.
    wrap : bool
        A single-turn absolute encoder: angular channels are reported in :math:`[-\pi, \pi)` (:class:`Wrap`,
        after noise and quantization, as the counter of a real one wraps); linear channels are not wrapped.
        Default False: the angle accumulates over turns (an incremental encoder with a counter).
    """

    @check_keywords
    def __init__(
        self,
        resolution=None,
        noise_std=0.0,
        *,
        counts_per_revolution: int | None = None,
        linear_resolution=None,
        wrap: bool = False,
    ):
        if (resolution is None) == (counts_per_revolution is None):
            raise ValueError(
                "expected exactly one of resolution and counts_per_revolution, actual value: "
                f"resolution={resolution!r}, counts_per_revolution={counts_per_revolution!r}"
            )
        if resolution is None:
            resolution = resolution_from_counts(counts_per_revolution)
        self.resolution, self.noise_std = resolution, noise_std
        self.counts_per_revolution, self.linear_resolution = counts_per_revolution, linear_resolution
        if not isinstance(wrap, (bool, np.bool_)):
            raise TypeError(f"expected wrap to be a bool, actual value: {wrap!r}")
        self.wrap = bool(wrap)
        stages: list[Stage] = []
        if np.any(_nonneg("noise_std", noise_std) > 0):
            stages.append(GaussianNoise(noise_std))
        stages.append(Quantization(resolution, linear_resolution))
        if self.wrap:
            stages.append(Wrap())
        super().__init__(*stages)

    def __repr__(self) -> str:
        wrap = ", wrap=True" if self.wrap else ""
        return f"Encoder(resolution={self.resolution!r}, noise_std={self.noise_std!r}{wrap})"


# ----------------------------------------------------------------------------------------------------------------
# presets
# ----------------------------------------------------------------------------------------------------------------
#: name -> factory of a fresh sensor (each call gives an independent object with its own stream)
PRESETS: dict[str, Callable[[], Sensor]] = {
    "ideal": lambda: Chain(),
    "encoder-12bit": lambda: Encoder(counts_per_revolution=4096),
    "encoder-12bit-noisy": lambda: Encoder(counts_per_revolution=4096, noise_std=1e-3),
    "encoder-16bit": lambda: Encoder(counts_per_revolution=65536),
    "low-cost": lambda: Chain(GaussianNoise(3e-3), Quantization.from_counts(1024), Delay(2), Dropout(0.02)),
    "drifting": lambda: Chain(Bias(std=5e-3), Drift(2e-3), Encoder(counts_per_revolution=4096, noise_std=1e-3)),
    "outliers": lambda: Chain(Encoder(counts_per_revolution=4096, noise_std=1e-3), Outliers(1e-3, 0.1)),
}


@check_keywords
def make_sensor(sensor: str | Sensor) -> Sensor:
    """A sensor from a preset name of :data:`PRESETS` or a spec of :mod:`smo_gym.specs`
    (``"encoder:counts_per_revolution=1024+delay:samples=2"``), or ``sensor`` itself if it already is one."""
    if isinstance(sensor, Sensor):
        return sensor
    if isinstance(sensor, str) and (":" in sensor or "+" in sensor):
        from .specs import make_sensor as from_spec  # specs builds on this module

        return from_spec(sensor)
    if not isinstance(sensor, str) or sensor not in PRESETS:
        raise ValueError(
            f"expected a sensor preset in {', '.join(sorted(PRESETS))} or a smo_gym.sensors.Sensor, "
            f"actual value: {sensor!r}{did_you_mean(sensor, PRESETS)}"
        )
    return PRESETS[sensor]()
