"""The stateful shell every observer shares: validation, batching, masked resets, bookkeeping.

The maths lives in the compiled channel steps of :mod:`smo_gym.observers._kernels`; a subclass only says which
kernel it uses, how wide its state is, and how its parameters are packed per channel.
"""

from __future__ import annotations

from typing import Any, ClassVar, NamedTuple

import numpy as np

from .._validation import (
    DivergenceError,
    as_real_array,
    check_choice,
    check_keywords,
    check_mask,
    check_positive,
    check_positive_array,
)
from . import _kernels

__all__ = ["Observer", "reported_coefficients", "reported_velocity", "step_mean_coefficients", "taylor_matrix"]

_FLOAT64 = np.dtype(np.float64)
_NDARRAY = np.ndarray
_empty = np.empty


_ENTRY_POINTS: dict = {}


def _compiled_entry(kernel, args):
    """The compiled entry point of a numba ``kernel`` for the types of ``args``, or ``kernel`` itself.

    Calling the entry point skips numba's per-call type dispatch (about 0.05 us per array argument). It performs
    no type checks, so the caller must pass arrays of exactly these types (dtype, ndim, layout, flags);
    :meth:`Observer.update` guarantees that. Anything that is not a numba dispatcher is returned unchanged.
    Resolved entry points are cached per kernel and argument types (``numba.typeof`` costs ~20 us per array).
    """
    key = (
        kernel,
        tuple(
            (a.dtype.str, a.ndim, a.flags.c_contiguous, a.flags.f_contiguous, a.flags.writeable, a.flags.aligned)
            for a in args
        ),
    )
    try:
        return _ENTRY_POINTS[key]
    except KeyError:
        pass
    except TypeError:  # unhashable kernel
        return kernel
    try:
        import numba

        sig = tuple(numba.typeof(a) for a in args)
        if sig not in kernel.overloads:
            kernel.compile(sig)
        entry = kernel.overloads[sig].entry_point
    except Exception:  # not a numba dispatcher, or numba internals changed: the dispatcher is always correct
        entry = kernel
    _ENTRY_POINTS[key] = entry
    return entry


def as_measurement(y, name: str) -> np.ndarray:
    """``y`` as a float64 array of shape ``(..., n_channels)`` with at least one channel, or a typed error.

    Every observer rejects an empty measurement (zero channels or a zero batch dimension) the same way: there is
    nothing to estimate, and an observer sized by it could never take a sample.
    """
    arr = as_real_array(name, y)
    if arr.ndim == 0:
        raise ValueError(f"expected {name} with shape (..., n_channels), actual value: a scalar {float(arr)!r}")
    if arr.size == 0:
        raise ValueError(
            f"expected {name} with at least one channel and no empty batch dimension, actual value: shape {arr.shape}"
        )
    return arr


def checked_input(u):
    """The input ``u`` of a model-term ``update(y, u)`` (any shape: the model's own convention) after checking it is
    real and finite, so that a NaN control is reported here rather than silently zeroed by the simulator (MuJoCo
    does); ``None`` passes."""
    if u is None:
        return None
    if type(u) is not np.ndarray or u.dtype is not _FLOAT64:
        u = as_real_array("u", u)
    # the compiled scan costs ~0.2 us; a NumPy reduction (np.isfinite(u).all()) ~2 us, on the physics-rate path
    if _kernels._first_nonfinite(u if u.ndim == 1 else u.reshape(-1)) >= 0:
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(u))[0])
        raise ValueError(f"expected finite inputs u, actual value: {u[bad]!r} at index {bad}")
    return u


def taylor_matrix(m: int, dt: float) -> np.ndarray:
    r"""The ``(m, m)`` matrix :math:`e^{\tau N}` with entries :math:`\tau^{j-i}/(j-i)!` (Wetzlinger et al., eq. (31)).

    It moves the estimate ``(f, f', ..., f^(m-1))`` of a polynomial of degree ``m - 1`` forward by one step
    ``tau`` exactly.
    """
    A = np.zeros((m, m))
    for i in range(m):
        fac = 1.0
        for j in range(i, m):
            A[i, j] = fac
            fac *= dt / (j - i + 1)
    return A


def check_wrap(wrap):
    """``wrap`` as given after checking it is None, a bool, or an array of bools (one per channel)."""
    if wrap is None or isinstance(wrap, (bool, np.bool_)):
        return None if wrap is None else bool(wrap)
    arr = np.asarray(wrap)
    if arr.dtype != np.bool_ or arr.ndim == 0:
        raise TypeError(f"expected wrap to be a bool or an array of bools (one per channel), actual value: {wrap!r}")
    return arr.copy()


def expand_mask(mask, shape: tuple[int, ...]) -> np.ndarray:
    """A reset mask of shape ``shape[:-1]`` (whole batch elements) or ``shape``, as a boolean array of ``shape``."""
    mask = check_mask("mask", mask)
    if mask.shape == shape[:-1]:
        return np.broadcast_to(mask[..., None], shape)
    if mask.shape != shape:
        raise ValueError(f"expected mask with shape {shape[:-1]} or {shape}, actual value: {mask.shape}")
    return mask


def step_mean_coefficients(order: int, span: float) -> np.ndarray:
    r"""Coefficients :math:`c_j = (-h)^{j-1}/j!`, ``j = 1..order``, of the mean velocity over the last ``h``:

    .. math:: \frac{f(t) - f(t - h)}{h} = \sum_{j \ge 1} \frac{(-h)^{j-1}}{j!} f^{(j)}(t),

    exact for polynomials of degree ``<= order`` (Taylor's formula), so :math:`\sum_j c_j \hat z_j` turns the
    derivatives estimated at the sample time into the velocity an Euler-integrating simulator reports.
    """
    j = np.arange(1, int(order) + 1)
    factorial = np.cumprod(j).astype(float)
    return (-float(span)) ** (j - 1) / factorial


def reported_coefficients(observer, span: float | None) -> np.ndarray | None:
    """The coefficients (:func:`step_mean_coefficients`) that turn ``observer``'s derivatives at the sample time into
    the mean velocity over the last ``span``: where a span is asked for, the observer estimates at least the
    acceleration and reports at the sample time (:attr:`Observer.reports_instant`); otherwise None, its first
    derivative is the velocity as it is."""
    if span is None or observer.order < 2 or not observer.reports_instant:
        return None
    return step_mean_coefficients(observer.order, span)


def reported_velocity(estimate: np.ndarray, coefficients: np.ndarray | None) -> np.ndarray:
    r"""The velocity reported from an estimate ``(..., n, order + 1)``: :math:`\sum_j c_j \hat z_j` with the
    ``coefficients`` :math:`c` (:func:`step_mean_coefficients`), or the first derivative where they are None.
    Summed term by term, in the order of the wrapper's compiled driver (:mod:`smo_gym.engine.fused`): the same
    numbers bit for bit."""
    if coefficients is None:
        return estimate[..., 1]
    v = coefficients[0] * estimate[..., 1]
    for j in range(1, len(coefficients)):
        v = v + coefficients[j] * estimate[..., 1 + j]
    return v


class ObserverArrays(NamedTuple):
    """The arrays of an observer's state, as its kernel reads them (``N`` channels, flat)."""

    state: np.ndarray
    """The recursion's state, shape ``(N, S)``."""
    params: np.ndarray
    """Per-channel parameter rows, shape ``(N, P)``."""


class ObserverCheckpoint(NamedTuple):
    """What :meth:`Observer.update` changes, copied (:meth:`Observer.checkpoint`)."""

    state: np.ndarray
    """The recursion's state, shape ``(N, S)``."""
    estimate: np.ndarray
    """The estimate, shape ``(..., n_channels, order + 1)``."""
    n_updates: int


class Observer:
    r"""Base class of the signal observers (differentiators).

    Shapes: measurements are ``(..., n_channels)``; any leading dimensions (environments of a vector env, say)
    are batch dimensions, and every channel is an independent signal. Estimates are
    ``(..., n_channels, order + 1)``: ``xhat[..., 0]`` the filtered value, ``xhat[..., 1]`` the first derivative,
    and so on.

    Life cycle (scipy ``OdeSolver`` style): ``reset(y0)`` sizes the state from the first measurement and must come
    first; ``update(y)`` validates and keeps the bookkeeping; the recursion itself is the compiled kernel.

    Angles: with ``wrap`` (a constructor argument of every registered family) the measured channels it selects are
    angles modulo :math:`2\pi` (a single-turn absolute encoder, :class:`smo_gym.sensors.Encoder` with
    ``wrap=True``). Each such measurement is first moved to the branch nearest the value estimate, so the
    innovation is the shortest angular difference (in :math:`[-\pi, \pi)`) and crossing the cut at
    :math:`\pm\pi` produces no velocity spike (:func:`smo_gym.observers._kernels.unwrap_measurement`). The value
    estimate ``xhat[..., 0]`` is reported **unwrapped** (continuous: it counts turns, which is what a controller
    needs); ``np.mod(xhat[..., 0] + np.pi, 2 * np.pi) - np.pi`` is the wrapped angle. The derivatives do not
    depend on the branch.

    Attributes
    ----------
    dt : float
        Sampling step ``tau`` in seconds.
    order : int
        Number of derivatives estimated.
    discretization : str
        One of the class's ``discretizations``.
    n_updates : int
        Samples processed since the last full reset.
    wrap : bool, ndarray of bool or None
        Which measured channels are angles modulo :math:`2\pi` (True: all; an array broadcast to the measurement
        shape at the full reset; None or False: none).
    """

    #: discretizations the class implements; the first is its default
    discretizations: ClassVar[tuple[str, ...]] = ("euler",)
    #: short name used by :func:`smo_gym.observers.make_observer`, the wrapper and the CLI
    name: ClassVar[str] = ""
    #: samples ahead of the last measurement at which ``update`` and ``run`` report: 0, the estimate at the sample
    #: time (every family but one), or 1, the one-step prediction :math:`\hat x_{k+1}` that
    #: :class:`~smo_gym.observers.DiscreteTimeHOSM` reports as its paper does (``reset`` reports at its sample)
    lead: ClassVar[int] = 0
    #: whether ``update(y, u)`` and ``run(Y, U)`` take the control input (a model-based observer)
    takes_input: ClassVar[bool] = False
    #: whether the first estimates after ``reset`` do not hinge on the initial derivatives: a finite window of
    #: samples (the backward difference) or a prior covariance that makes them least-squares fits (the Kalman
    #: filters); :func:`smo_gym.differentiate` starts the other families from a Kalman filter's estimate
    self_starting: ClassVar[bool] = False
    # compiled call of update(), bound lazily (class-level defaults keep subclasses and old pickles working):
    # ``(entry point, params, measurement shape, estimate shape)``, one attribute for the hot path
    _bound = None
    wrap = None
    _period = None
    _arrays = None

    @check_keywords
    def __init__(self, dt: float, order: int, discretization: str | None, wrap=None):
        if type(self)._channel_params is Observer._channel_params:
            raise TypeError(
                f"expected a concrete observer class (SuperTwisting, Levant, ...; see "
                f"smo_gym.observers.OBSERVERS), actual value: {type(self).__name__}, which has no "
                "recursion of its own"
            )
        self.dt = check_positive("dt", dt)
        self.wrap = check_wrap(wrap)
        self.order = order
        self.discretization = check_choice(
            "discretization",
            self.discretizations[0] if discretization is None else discretization,
            self.discretizations,
        )
        self._shape: tuple[int, ...] | None = None
        self._state: np.ndarray | None = None
        self._scratch: np.ndarray | None = None
        self._params: np.ndarray | None = None
        self._estimate: np.ndarray | None = None
        self._period: np.ndarray | None = None  # (N,) 2 pi for wrapped channels, 0 for the others; None: none wrap
        self.n_updates = 0
        self._unbind()

    # ---- what a subclass provides ---------------------------------------------------------------------------
    @property
    def _kernel(self):  # pragma: no cover - abstract
        raise NotImplementedError

    def _state_width(self) -> int:
        """Columns of the state: the ``order + 1`` estimates plus the innovation, by default."""
        return self.order + 2

    def _innovation_column(self) -> int:
        """Column of the state that holds the innovation."""
        return self.order + 1

    def _channel_params(self, shape: tuple[int, ...]) -> np.ndarray:  # pragma: no cover - abstract
        """Per-channel parameter rows, shape ``(prod(shape), P)``, for measurements of ``shape``."""
        raise NotImplementedError

    def _initial_state(self, y0: np.ndarray, params: np.ndarray) -> np.ndarray:
        """State after ``reset``: value ``y0``, zero derivatives, zero innovation. ``y0`` is flat ``(N,)``."""
        state = np.zeros((y0.shape[0], self._state_width()))
        state[:, 0] = y0
        return state

    @property
    def reports_instant(self) -> bool:
        """Whether the reported derivatives are those at the sample time (exact, Taylor and eigenvalue-mapping
        discretizations), rather than what a backward-Euler step or a difference reports, a mean over the last
        step. A consumer that wants the mean velocity over a step (the velocity of a simulator that integrates with
        Euler, :class:`smo_gym.engine.measurement.VelocityEstimator`) converts only instant reports."""
        return False

    def _predicts(self) -> bool:
        """Whether the state is the one-step prediction for the next sample (the explicit schemes; see "Prior and
        posterior" in :mod:`smo_gym.observers._kernels`) rather than the estimate at the last sample."""
        return False

    def _load_estimate(self, state: np.ndarray, x0: np.ndarray, params: np.ndarray) -> None:
        r"""Write the estimate ``x0`` (N, order + 1) at the reset sample into a fresh ``state`` (N, S) of
        :meth:`_initial_state`: the estimate itself, or its exact polynomial prediction :math:`e^{\tau N} x_0` when
        the state is a prediction (:meth:`_predicts`). Subclasses whose state has other coordinates override it."""
        m = x0.shape[1]
        state[:, :m] = x0 @ taylor_matrix(m, self.dt).T if self._predicts() else x0

    # ---- helpers for subclasses -----------------------------------------------------------------------------
    @classmethod
    def _rows_per_value(cls, name: str, value, shape: tuple[int, ...], row) -> np.ndarray:
        """Parameter rows ``row(v)`` of every channel, ``v`` the positive parameter ``value`` (one number or one per
        channel) of that channel: shape ``(prod(shape), P)``, ``row`` evaluated once per distinct value."""
        values = cls._per_channel(name, value, shape)
        unique, which = np.unique(values, return_inverse=True)
        return np.stack([row(float(v)) for v in unique])[which.reshape(-1)]

    @staticmethod
    def _per_channel(name: str, value, shape: tuple[int, ...]) -> np.ndarray:
        """Broadcast a positive scalar or array parameter to the channel shape and flatten it to ``(N,)``."""
        arr = check_positive_array(name, value)
        try:
            return np.broadcast_to(arr, shape).reshape(-1)
        except ValueError:
            raise ValueError(
                f"expected {name} broadcastable to the measurement shape {shape}, actual value: shape {arr.shape}"
            ) from None

    # ---- compiled call used by update() ----------------------------------------------------------------------
    def _step_kernel(self) -> tuple:
        """``(kernel, params)`` for one sample: :attr:`_kernel` and the per-channel rows, or, when every channel
        has the same row and the kernel is a registered step (:data:`~smo_gym.observers._kernels.STEPS`), its
        shared-parameter variant and the row ``(1, P)``."""
        kernel, params = self._kernel, self._params
        step = _kernels.STEPS.get(kernel)
        if params.shape[0] > 1 and step is not None and (params == params[0]).all():
            return step.shared_kernel, params[:1].copy()
        return kernel, params

    def _unbind(self) -> None:
        self._bound = None  # bound again on the first update after a full reset

    @property
    def _call(self):
        """The compiled entry point ``update()`` calls (``None`` before the first update after a full reset)."""
        return None if self._bound is None else self._bound[0]

    def _bind(self) -> tuple:
        """Resolve the kernel and its entry point once per full reset (``update`` then calls it directly)."""
        out = np.empty(self._estimate.shape)
        y = np.empty(self._shape)
        kernel, params = self._step_kernel()
        call = _compiled_entry(kernel, (self._state, y, params, self._scratch, out))
        if self._period is not None:
            call = self._unwrapping(call, y)
        self._bound = (call, params, self._shape, out.shape)
        return self._bound

    def _unwrapping(self, call, y: np.ndarray):
        """``call`` preceded by :func:`~smo_gym.observers._kernels.unwrap_measurement` (the wrapped channels moved to
        the branch nearest the value estimate); a non-finite measurement stays non-finite, so the kernel's status
        still names its channel."""
        period, buffer = self._period, np.empty(self._shape)
        unwrap = _compiled_entry(_kernels.unwrap_measurement, (y, self._state, period, buffer))

        def unwrapped_call(state, y, params, new_state, out):
            unwrap(y, state, period, buffer)
            return call(state, buffer, params, new_state, out)

        return unwrapped_call

    # ---- public API -----------------------------------------------------------------------------------------
    def _as_measurement(self, y, name: str) -> np.ndarray:
        return as_measurement(y, name)

    def _raise_nonfinite(self, arr: np.ndarray, name: str) -> None:
        bad = np.argwhere(~np.isfinite(arr))[0]
        index = tuple(int(i) for i in bad)
        raise ValueError(
            f"expected finite measurements in {name}, actual value: {arr[index]!r} at channel {index[-1]}"
            + (f" of batch element {index[:-1]}" if len(index) > 1 else "")
        )

    def _initial_estimate(self, y0: np.ndarray, derivatives) -> np.ndarray | None:
        """The estimate at a reset, shape ``y0.shape + (order + 1,)``: ``y0``, the given derivatives, then zeros.

        ``None`` when no derivatives are given. ``derivatives`` must have shape ``y0.shape + (k,)`` with
        ``0 <= k <= order`` and finite entries.
        """
        if derivatives is None:
            return None
        try:
            d = np.asarray(derivatives)
            if d.dtype.kind not in "iuf":  # bools, complex, strings, objects
                raise TypeError
            d = d.astype(np.float64, copy=False)
        except (TypeError, ValueError):
            raise TypeError(
                f"expected derivatives to be an array of real numbers, actual value: {derivatives!r}"
            ) from None
        if d.ndim != y0.ndim + 1 or d.shape[:-1] != y0.shape or d.shape[-1] > self.order:
            raise ValueError(
                f"expected derivatives with shape {y0.shape + ('k',)}, k <= order = {self.order} (the derivatives "
                f"1..k of each channel), actual value: shape {d.shape}"
            )
        if not np.isfinite(d).all():
            index = tuple(int(i) for i in np.argwhere(~np.isfinite(d))[0])
            raise ValueError(f"expected finite derivatives, actual value: {d[index]!r} at index {index}")
        if d.shape[-1] == 0:
            return None
        x0 = np.zeros(y0.shape + (self.order + 1,))
        x0[..., 0] = y0
        x0[..., 1 : d.shape[-1] + 1] = d
        return x0

    def _fresh_state(self, y0: np.ndarray, x0: np.ndarray | None) -> np.ndarray:
        """:meth:`_initial_state` at ``y0`` (flat), with the estimate ``x0`` loaded if derivatives were given."""
        state = self._initial_state(y0.reshape(-1), self._params)
        if x0 is not None:
            self._load_estimate(state, x0.reshape(-1, self.order + 1), self._params)
        return state

    def _wrap_periods(self, shape: tuple[int, ...]) -> np.ndarray | None:
        """``wrap`` as flat periods ``(N,)``: ``2 pi`` for wrapped channels, 0 for the others; None if none wraps."""
        if self.wrap is None or self.wrap is False:
            return None
        try:
            wrapped = np.broadcast_to(self.wrap, shape).reshape(-1)
        except ValueError:
            raise ValueError(
                f"expected wrap broadcastable to the measurement shape {shape}, actual value: shape "
                f"{np.shape(self.wrap)}"
            ) from None
        if not wrapped.any():
            return None
        return np.where(wrapped, 2.0 * np.pi, 0.0)

    @check_keywords
    def reset(self, y0, mask=None, *, derivatives=None) -> np.ndarray:
        """Start (or restart) the observer at the measurement ``y0``.

        Parameters
        ----------
        y0 : array_like, shape (..., n_channels)
            First measurement; the value estimate starts there.
        mask : array_like of bool, optional
            Restart only some rows: shape ``(...)`` (whole batch elements, e.g. one environment of a vector
            env) or ``(..., n_channels)``. Requires a previous full reset with the same shape.
        derivatives : array_like, shape (..., n_channels, k), optional
            Initial estimates of the derivatives ``1..k`` of every channel, ``k <= order`` (a known initial
            velocity, say); the higher ones start at zero. Default: every derivative starts at zero. With
            ``mask``, only the masked rows are read.

        Returns
        -------
        ndarray, shape (..., n_channels, order + 1)
            The initial estimate: ``y0``, then ``derivatives`` (or zeros), then zeros.

        Raises
        ------
        TypeError
            ``y0`` or ``derivatives`` is not an array of real numbers.
        ValueError
            Non-finite ``y0`` or ``derivatives``, or a shape that does not fit (``mask``, ``derivatives``,
            ``wrap``, a per-channel gain).
        RuntimeError
            A masked reset before any full reset.
        """
        y0 = self._as_measurement(y0, "y0")
        if not np.isfinite(y0).all():
            self._raise_nonfinite(y0, "y0")
        x0 = self._initial_estimate(y0, derivatives)
        if mask is None:
            # all or nothing: a rejected reset (parameters that do not fit this shape) keeps the previous shape,
            # whose arrays the compiled step would otherwise index out of bounds
            previous = (self._shape, self._params, self._period)
            self._shape = y0.shape  # a subclass's _initial_state may read the new shape
            try:
                self._params = np.ascontiguousarray(self._channel_params(y0.shape), dtype=np.float64)
                self._period = self._wrap_periods(y0.shape)
                state = np.ascontiguousarray(self._fresh_state(y0, x0), dtype=np.float64)
            except BaseException:
                self._shape, self._params, self._period = previous
                raise
            self._state = state
            self._scratch = np.empty_like(self._state)
            if x0 is None:
                self._estimate = np.zeros(y0.shape + (self.order + 1,))
                self._estimate[..., 0] = y0
            else:
                self._estimate = x0
            self.n_updates = 0
            self._unbind()  # new arrays and shape: the next update binds the entry point again
            return self._estimate.copy()
        if self._state is None:
            raise RuntimeError("expected a full reset(y0) before a masked reset, actual value: never reset")
        if y0.shape != self._shape:
            raise ValueError(f"expected y0 with shape {self._shape} for a masked reset, actual value: {y0.shape}")
        mask = check_mask("mask", mask)
        shape = self._shape
        if mask.shape == shape[:-1]:
            block = shape[-1]  # whole batch elements: blocks of n_channels rows
        elif mask.shape == shape:
            block = 1
        else:
            raise ValueError(f"expected mask with shape {shape[:-1]} or {shape}, actual value: {mask.shape}")
        # a loop over the selected blocks of the flat rows: a masked restart runs at every episode end of a vector
        # env (usually one environment), where boolean-mask assignments over a mask broadcast to every channel
        # cost three times as much
        fresh = self._fresh_state(y0, x0)
        width = self._state.shape[-1]
        state, fresh = self._state.reshape(-1, block, width), fresh.reshape(-1, block, width)  # views: C-contiguous
        # a new estimate array: the last one was returned by update (or run) as the caller's to keep
        self._estimate = self._estimate.copy()
        estimate, y0 = self._estimate.reshape(-1, block, self.order + 1), y0.reshape(-1, block)
        x0 = None if x0 is None else x0.reshape(-1, block, self.order + 1)
        for i in np.flatnonzero(mask):
            state[i] = fresh[i]
            if x0 is None:
                estimate[i] = 0.0
                estimate[i, :, 0] = y0[i]
            else:
                estimate[i] = x0[i]
        return self._estimate.copy()

    def restart(self, y0, *, derivatives=None) -> np.ndarray:
        """``reset(y0)`` for a measurement of the shape of the last full reset, keeping the per-channel parameters.

        A new episode of the same environment: the state is rewritten in place (arrays keep their identity, so
        a compiled caller holding them stays valid), the estimate starts at ``y0`` with the given
        ``derivatives`` (as :meth:`reset`; default zero) and ``n_updates`` at 0, and the parameters are not derived
        again (a full reset re-validates and re-packs them, ~40 us). Subclasses that override ``reset`` get
        ``reset(y0)`` itself.
        """
        if type(self).reset is not Observer.reset:
            return self.reset(y0) if derivatives is None else self.reset(y0, derivatives=derivatives)
        if self._state is None:
            raise RuntimeError("expected a full reset(y0) before restart(y0), actual value: never reset")
        y0 = self._as_measurement(y0, "y0")
        if y0.shape != self._shape:
            raise ValueError(f"expected y0 with shape {self._shape} for a restart, actual value: {y0.shape}")
        if not np.isfinite(y0).all():  # the method: np.all's Python wrapper costs ~3 us, paid every episode
            self._raise_nonfinite(y0, "y0")
        x0 = self._initial_estimate(y0, derivatives)
        self._state[...] = self._fresh_state(y0, x0)
        if x0 is None:
            estimate = np.zeros(self._estimate.shape)
            estimate[..., 0] = y0
        else:
            estimate = x0
        self._estimate = estimate
        self.n_updates = 0
        return estimate.copy()

    def update(self, y) -> np.ndarray:
        """Process one sample and return the estimate at its time.

        Parameters
        ----------
        y : array_like, shape (..., n_channels)
            The measurement, same shape as at ``reset``.

        Returns
        -------
        ndarray, shape (..., n_channels, order + 1)
            A new array (safe to keep): value, first derivative, ...

        Raises
        ------
        RuntimeError
            If called before ``reset``.
        ValueError
            On a wrong shape, or a NaN/inf measurement (the channel is named; the state is unchanged).
        DivergenceError
            If the state would become non-finite (the previous state is kept).
        """
        bound = self._bound
        if bound is None:  # never reset, or the first update after a full reset
            if self._state is None:
                raise RuntimeError("expected reset(y0) before update(y), actual value: the observer was never reset")
            bound = self._bind()
        call, params, shape, out_shape = bound
        # the compiled entry point needs exactly: ndarray, native float64, C-contiguous, aligned, shape as at reset
        # (``carray``: C-contiguous, aligned and writeable, one flag for the common case)
        if (
            type(y) is not _NDARRAY
            or y.dtype is not _FLOAT64
            or not ((f := y.flags).carray or (f.c_contiguous and f.aligned))
        ):
            y = np.require(self._as_measurement(y, "y"), _FLOAT64, ("C", "A"))
        if y.shape != shape:
            raise ValueError(f"expected y with shape {shape}, actual value: {y.shape}")
        out = _empty(out_shape)
        state = self._state
        scratch = self._scratch
        status = call(state, y, params, scratch, out)
        if status != -1:
            self._raise_status(status, y)
        self._state = scratch
        self._scratch = state
        self._estimate = out
        self.n_updates += 1
        return out

    def _raise_status(self, status: int, y: np.ndarray, sample: int | None = None):
        """The error of a compiled step's ``status`` on the measurement ``y`` (sample ``sample`` of ``run``'s ``Y``)."""
        if status >= 0:
            self._raise_nonfinite(y, "y" if sample is None else f"Y at sample {sample}")
        channel = -2 - status
        index = np.unravel_index(channel, self._shape)
        after = "update" if sample is None else f"the update of sample {sample}"
        raise DivergenceError(
            f"expected a finite observer state, actual value: non-finite after {after} at channel {index[-1]}"
            + (f" of batch element {tuple(int(i) for i in index[:-1])}" if len(index) > 1 else "")
            + f" (dt={self.dt}); the step was rejected and the previous state kept. The step is too large for this "
            "observer and discretization at this error level: reduce dt or choose an implicit discretization."
        )

    def step(self, state: np.ndarray, y) -> tuple[np.ndarray, np.ndarray]:
        """Pure form of ``update``: return ``(new_state, estimate)`` for a flat state without touching ``self``.

        ``state`` has shape ``(N, S)`` as ``self.state``; ``y`` shape ``(N,)`` or the measurement shape of the
        last full reset. Requires a previous ``reset`` (for the per-channel parameters). Both are checked before
        the compiled step runs (it indexes them without bounds checks): a wrong shape, a non-real dtype or a
        non-finite state raises ``TypeError``/``ValueError``.
        """
        if self._params is None:
            raise RuntimeError("expected reset(y0) before step(), actual value: the observer was never reset")
        y, state = self._check_step_arguments(state, y)
        if self._period is not None:
            y_measured, y = y, np.empty_like(y)
            _kernels.unwrap_measurement(y_measured, state, self._period, y)
        new_state = np.empty_like(state)
        out = np.empty((state.shape[0], self.order + 1))
        kernel, params = self._step_kernel()
        status = kernel(state, y, params, new_state, out)
        if status != -1:
            self._raise_status(status, y if self._period is None else y_measured)
        return new_state, out

    def _check_step_arguments(self, state, y) -> tuple[np.ndarray, np.ndarray]:
        """``(y, state)`` of :meth:`step` as C-contiguous float64 arrays of the sizes the kernel indexes."""
        expected = self._state.shape
        state = np.ascontiguousarray(as_real_array("state", state))
        if state.shape != expected:
            raise ValueError(f"expected state with shape {expected} (as observer.state), actual value: {state.shape}")
        if not np.isfinite(state).all():
            bad = tuple(int(i) for i in np.argwhere(~np.isfinite(state))[0])
            raise ValueError(
                f"expected a finite state, actual value: {state[bad]!r} at row {bad[0]} (channel), column {bad[1]}"
            )
        y = np.ascontiguousarray(as_real_array("y", y))
        if y.shape not in ((expected[0],), self._shape):
            raise ValueError(f"expected y with shape ({expected[0]},) or {self._shape}, actual value: {y.shape}")
        return y.reshape(-1), state

    @check_keywords
    def run(self, Y, *, out: np.ndarray | None = None) -> np.ndarray:
        """Process a recorded block ``Y`` of shape ``(T, ...)`` (continuing from the current state) in one call.

        Returns the estimates, shape ``(T, ..., order + 1)``. Uses the same compiled kernel as ``update``.
        If a sample is not finite (``ValueError``) or the state diverges (``DivergenceError``), nothing is
        committed: the observer keeps the state it had before the call, as ``update`` does.

        ``out``, optional: a C-contiguous float64 array of that shape to write the estimates into (and return),
        e.g. a slice of a larger result, which saves allocating and copying one (:func:`smo_gym.differentiate`).
        """
        if self._state is None:
            raise RuntimeError("expected reset(y0) before run(Y), actual value: the observer was never reset")
        Y = np.ascontiguousarray(as_real_array("Y", Y))
        if Y.ndim == 0 or Y.shape[1:] != self._shape:
            raise ValueError(f"expected Y with shape (T, *{self._shape}), actual value: {Y.shape}")
        T = Y.shape[0]
        m = self.order + 1
        out = self._output_array(out, (T,) + self._estimate.shape, Y)
        if T == 0:
            return out
        # all or nothing, like update(): the kernel loop advances a copy, committed only if every sample passed
        state = self._state.copy()
        kernel, params = self._step_kernel()  # scalar gains: the driver of the shared-parameter kernel
        status, t = _kernels.run_offline(kernel, state, Y.reshape(T, -1), params, out.reshape(T, -1, m), self._period)
        if status != -1:
            self._raise_status(status, Y[t], t)
        self._state = state
        self._estimate = out[-1].copy()
        self.n_updates += T
        return out

    def _run_updates(self, Y, U, kept: tuple, out: np.ndarray | None = None) -> np.ndarray:
        """``update(Y[t], U[t])`` for every row of ``Y`` ``(T, ...)`` and ``U`` ``(T, ...)`` (or None), for the
        observers that take an input (no compiled driver): all or nothing, as :meth:`run`; a rejected sample restores
        the state, the estimate, ``n_updates`` and the arrays ``kept`` that ``update`` changes in place (the last
        measurement or input). ``out``: as :meth:`run`'s."""
        self._require_reset()
        Y = as_real_array("Y", Y)
        if Y.ndim == 0 or Y.shape[1:] != self._shape:
            raise ValueError(f"expected Y with shape (T, *{self._shape}), actual value: {Y.shape}")
        if U is not None:
            U = as_real_array("U", U)
            if U.ndim == 0 or U.shape[0] != Y.shape[0]:
                raise ValueError(
                    f"expected U with shape (T, ...), one row per sample of Y ({Y.shape[0]}), actual value: shape "
                    f"{U.shape}"
                )
        out = self._output_array(out, Y.shape + (self.order + 1,), Y)
        saved = (self._state.copy(), [a.copy() for a in kept], self._estimate, self.n_updates)
        try:
            for t in range(Y.shape[0]):
                out[t] = self.update(Y[t], None if U is None else U[t])
        except BaseException:
            state, arrays, self._estimate, self.n_updates = saved
            self._state[...] = state  # in place: a bound entry point keeps its arrays
            for array, old in zip(kept, arrays, strict=True):
                array[...] = old
            raise
        return out

    @staticmethod
    def _output_array(out, shape: tuple[int, ...], Y: np.ndarray) -> np.ndarray:
        """The ``out`` argument of :meth:`run` after checking it, or a new array of ``shape``. An ``out`` that shares
        memory with the samples ``Y`` is refused: the estimates would overwrite samples not yet read."""
        if out is None:
            return np.empty(shape)
        if isinstance(out, np.ndarray) and np.shares_memory(out, Y):
            raise ValueError(
                "expected out not to share memory with the samples Y (the estimates would overwrite samples not yet "
                "read), actual value: overlapping arrays"
            )
        if not (
            isinstance(out, np.ndarray)
            and out.shape == shape
            and out.dtype == np.float64
            and out.flags.c_contiguous
            and out.flags.writeable
        ):
            raise ValueError(
                f"expected out to be a writeable C-contiguous float64 array of shape {shape}, actual value: "
                + (f"{out.dtype} array of shape {out.shape}" if isinstance(out, np.ndarray) else repr(type(out)))
            )
        return out

    # ---- read-only views ------------------------------------------------------------------------------------
    def _require_reset(self) -> np.ndarray:
        if self._estimate is None:
            raise RuntimeError("expected reset(y0) first, actual value: the observer was never reset")
        return self._estimate

    @property
    def estimate(self) -> np.ndarray:
        """Last estimate, shape ``(..., n_channels, order + 1)``."""
        return self._require_reset()

    @property
    def velocity(self) -> np.ndarray:
        """Last first-derivative estimate, shape ``(..., n_channels)``."""
        return self._require_reset()[..., 1]

    @property
    def output_error(self) -> np.ndarray:
        r"""Last innovation, shape ``(..., n_channels)``: the measurement minus the observer's prediction of it,
        :math:`y_k - \hat y_k^-`, or, for the steps that form no prediction (the backward difference, the implicit
        steps of the linear and filtering differentiators, the low-power observer), minus the previous value
        estimate, :math:`y_k - \hat y_{k-1}`."""
        self._require_reset()
        return self._state[:, self._innovation_column()].reshape(self._shape)

    @property
    def state(self) -> np.ndarray:
        """Internal state, shape ``(N, S)`` with ``N`` the number of channels (a copy)."""
        self._require_reset()
        return self._state.copy()

    @property
    def shape(self) -> tuple[int, ...] | None:
        """Measurement shape ``(..., n_channels)`` fixed at the last full reset."""
        return self._shape

    # ---- the state's arrays, for a compiled caller --------------------------------------------------------------
    @property
    def arrays(self) -> ObserverArrays:
        """The state and parameter arrays (not copies) the kernel reads, for a compiled caller that advances the
        observer in place (the wrapper's one-call path); report what it did with :meth:`advanced`.

        ``update`` and ``run`` replace the state array: read the arrays again after either. The compiled kernels
        trust these arrays (layout, indices, gains) as the observer wrote them: a caller writes only what a step
        writes; anything else (a negative gain, an index out of range) can make them read outside the arrays.
        """
        arrays = self._arrays
        if arrays is None or arrays.state is not self._state or arrays.params is not self._params:
            self._require_reset()
            arrays = self._arrays = ObserverArrays(self._state, self._params)  # read once per step: kept
        return arrays

    def advanced(self, estimate: np.ndarray, n_samples: int) -> None:
        """Record that a compiled caller advanced :attr:`arrays` in place by ``n_samples`` samples, ending at
        ``estimate`` (shape as :attr:`estimate`; kept, not copied)."""
        current = self._estimate
        if current is None or estimate.shape != current.shape:
            raise ValueError(
                f"expected an estimate of shape {self._require_reset().shape}, actual value: {estimate.shape}"
            )
        self._estimate = estimate
        self.n_updates += n_samples

    def checkpoint(self) -> ObserverCheckpoint:
        """A copy of what :meth:`update` changes (the state, the estimate, ``n_updates``), for :meth:`restore`: a
        caller that must undo a step it cannot complete (a nonlinear observer whose inversion fails after its
        differentiators took the sample). Observers that take an input also keep the last one, which this does not
        cover: they refuse."""
        if self.takes_input:
            raise TypeError(f"expected an observer without an input, actual value: {type(self).__name__} takes one")
        self._require_reset()
        return ObserverCheckpoint(self._state.copy(), self._estimate.copy(), self.n_updates)

    def restore(self, checkpoint: ObserverCheckpoint) -> None:
        """Return to a :meth:`checkpoint` taken since the last full reset (the state is written in place, so a
        compiled caller holding :attr:`arrays` stays valid)."""
        if not isinstance(checkpoint, ObserverCheckpoint):
            raise TypeError(f"expected an ObserverCheckpoint, actual value: {type(checkpoint).__name__}")
        self._require_reset()
        if checkpoint.state.shape != self._state.shape or checkpoint.estimate.shape != self._estimate.shape:
            raise ValueError(
                f"expected a checkpoint of this observer since its last full reset (state {self._state.shape}), "
                f"actual value: state {checkpoint.state.shape}"
            )
        self._state[...] = checkpoint.state
        self._estimate = checkpoint.estimate.copy()
        self.n_updates = checkpoint.n_updates

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state.pop("_bound", None)  # compiled entry points do not pickle (bound again at the next update)
        return state

    def __repr__(self) -> str:
        wrap = "" if self.wrap is None else f", wrap={self.wrap!r}"
        return f"{type(self).__name__}(dt={self.dt}, order={self.order}, discretization={self.discretization!r}{wrap})"
