r"""Different observers on different channels of one measurement, reported as one velocity observer.

The joints of a robot differ: a heavy, slow base joint is best differentiated by a filter that trusts its
measurements little, a light joint hit by impacts by one that trusts them a lot, and an ideal encoder on an
Euler-integrated joint by a plain backward difference. :class:`PerChannel` runs one observer per group of
channels and reports what a consumer of velocities reads, the value and the first derivative of every channel
(``order = 1``), each part's velocity taken as that part reports it (optionally converted to the mean over the last
step, as :class:`smo_gym.engine.measurement.VelocityEstimator` does). :func:`smo_gym.selection.auto_observer` builds
one from a calibration.

One compiled step
-----------------
The composite is an ordinary compiled observer: its step (:func:`composite_step`, generated and cached on disk per
tuple of part steps, registered with :func:`smo_gym.observers._kernels.register_step`) calls each part's own
compiled step on that part's channels, so ``update``, ``run``, the wrapper's one-call path and a masked reset are
the engine's, and a rejected sample leaves every part where it was. Its state has a row per channel, the part's
own state row padded with zeros to the widest part; its parameter row per channel is

.. code-block:: text

    [part, S, P, m, innovation column, K, start, c_0 .. c_{K-1}, the part's P parameters, zeros]

(:data:`PART` ... :data:`COEFFICIENTS`): the call its part runs in, the part's state, parameter and estimate
widths, where its innovation is, the ``K`` coefficients of the reported velocity :math:`\sum_j c_j \hat z_{j+1}`
(``[1]``: the first derivative as it is; :func:`smo_gym.observers.base.reported_coefficients` otherwise) and the
column where its parameters start. Per sample and call, the step gathers the call's rows into contiguous views of
one buffer, calls the part's step and scatters the result back: about 0.3 us per sample on six channels of two
parts (measured against the parts alone), more than a cheap step itself costs but a few percent of a wrapped
environment step. Parts that run the same step with the same state width and order share one call (their
parameters are per channel), and the calls are ordered by the steps' names, so that every composite of the same
steps runs one compiled step. The gathering, the part's step and the scattering are compiled once per part step
(``_advance``) and called by every composite step that holds it: a composite step of steps compiled before costs
~1.5 s to compile on a cold cache, where inlining them cost ~2 s more per part.
"""

from __future__ import annotations

import copy
import hashlib
import inspect
import math
from collections.abc import Sequence

import numpy as np

from .._numba_cache import cached_instance
from .._validation import check_keywords, check_positive
from . import _kernels
from .base import Observer, reported_coefficients
from .registry import family_of

__all__ = [
    "COEFFICIENTS",
    "ESTIMATES",
    "INNOVATION",
    "MAX_PARTS",
    "N_COEFFICIENTS",
    "PARAMS_AT",
    "PARAM_WIDTH",
    "PART",
    "STATE_WIDTH",
    "PerChannel",
    "compiled_step",
    "composite_step",
]

#: columns of a channel's parameter row (module notes): the call its part runs in, the part's state, parameter and
#: estimate widths, the part's innovation column, the number of velocity coefficients, the column where the part's
#: parameters start
PART, STATE_WIDTH, PARAM_WIDTH, ESTIMATES, INNOVATION, N_COEFFICIENTS, PARAMS_AT = range(7)
#: the first column of the velocity coefficients
COEFFICIENTS = 7
#: the most parts one composite step holds
MAX_PARTS = 8


def compiled_step(observer) -> _kernels.Step | None:
    """The compiled step an observer's ``update`` runs, or None: a registered family with compiled steps only, or a
    :class:`PerChannel` (a subclass of either is a family of its own whose Python may differ from the kernel)."""
    family = family_of(observer)
    if type(observer) is PerChannel or (family is not None and family.compiled):
        return _kernels.STEPS.get(observer._kernel)
    return None


def _part_step(observer) -> _kernels.Step | None:
    """The compiled step of a part of a composite: :func:`compiled_step`, or for an observer that takes the input
    the registered step of its kernel, if any: a filter told the input
    (:class:`~smo_gym.observers.input_kalman.InputJumpFilter`) runs its Kalman filter's step after moving it at
    each change of input, which :class:`~smo_gym.observers.input_kalman.PerChannelInput` does."""
    if observer.takes_input:
        return _kernels.STEPS.get(observer._kernel)
    return compiled_step(observer)


def _advance_template(part, state, y, params, new_state, out, shared, index, work):
    """One sample of the part ``part`` (the step ``_ROWS``) on its channels: gathered into contiguous arrays (views
    of ``work``; ``index`` receives the channels), advanced, scattered back into ``new_state`` (padding columns
    copied) and ``out`` (value, reported velocity). Returns the step's status with the part's channel translated to
    the composite's. Compiled once per part step (:func:`_advance`) and called by every composite step that holds
    it."""
    n, width = state.shape
    count = 0
    for c in range(n):
        if params[0 if shared else c, PART] == part:
            index[count] = c
            count += 1
    if count == 0:
        return -1
    row = params[0 if shared else index[0]]
    S, P, m, at = int(row[STATE_WIDTH]), int(row[PARAM_WIDTH]), int(row[ESTIMATES]), int(row[PARAMS_AT])
    # work holds n (3 width + P_max + 1) numbers: enough for every part (S, m <= width, P <= P_max)
    part_state = work[: count * S].reshape((count, S))
    part_new = work[count * S : 2 * count * S].reshape((count, S))
    part_out = work[2 * count * S : count * (2 * S + m)].reshape((count, m))
    part_params = work[count * (2 * S + m) : count * (2 * S + m + P)].reshape((count, P))
    part_y = work[count * (2 * S + m + P) : count * (2 * S + m + P + 1)]
    for r in range(count):
        c = index[r]
        pc = 0 if shared else c
        part_y[r] = y[c]
        for j in range(S):
            part_state[r, j] = state[c, j]
        for j in range(P):
            part_params[r, j] = params[pc, at + j]
    status = _ROWS(part_state, part_y, part_params, part_new, part_out, False)
    if status != -1:
        return index[status] if status >= 0 else -2 - index[-2 - status]
    for r in range(count):
        c = index[r]
        pc = 0 if shared else c
        for j in range(S):
            new_state[c, j] = part_new[r, j]
        for j in range(S, width):
            new_state[c, j] = state[c, j]
        out[c, 0] = part_out[r, 0]
        out[c, 1] = _kernels.reported_sum(
            params[pc, COEFFICIENTS : COEFFICIENTS + int(params[pc, N_COEFFICIENTS])], part_out[r]
        )
    return -1


_ROWS = None  # the global of the template above, bound per part step by cached_instance
_ADVANCES: dict = {}


def _advance(rows):
    """The compiled :func:`_advance_template` of the part step ``rows`` (a cached dispatcher, made once per step).

    Why a function of its own, called rather than inlined into each composite step: the gathering and scattering
    around the part's step is most of a composite's code, and typed again in every composite that inlines it, ~2 s
    of compilation per part on a cold cache; ``"auto"`` builds a composite of other steps for nearly every
    environment and sensor, while the steps themselves are a handful. A call per part and sample costs nothing
    measurable next to the gathering itself (module notes).
    """
    advance = _ADVANCES.get(rows)
    if advance is None:
        label = f"{rows.py_func.__module__}.{rows.py_func.__qualname__}"
        deps = sorted({inspect.getfile(rows.py_func), _kernels.__file__})
        options = dict(cache=_kernels.CACHE, error_model="numpy")
        advance = _ADVANCES[rows] = cached_instance(_advance_template, label, options, deps, _ROWS=rows)
    return advance


# the globals of the template below, bound per tuple of part steps by cached_instance: each part's compiled
# _advance (unused slots: None, in branches numba prunes because _N_PARTS is a constant). The slots are written
# out: a loop over different functions needs numba's first-class function types, still experimental.
_N_PARTS = 0
_A0 = _A1 = _A2 = _A3 = _A4 = _A5 = _A6 = _A7 = None


def _per_channel_rows_template(state, y, params, new_state, out, shared):
    """The composite's step (module notes): every part's step (``_A0`` ...: :func:`_advance` of each) on its
    channels, stopping at the first that fails."""
    n, width = state.shape
    index = np.empty(n, np.int64)
    work = np.empty(n * (3 * width + params.shape[1] + 1))  # one allocation per sample, shared by the parts
    # the part's index typed int64, not as the literal 0, 1, ...: numba compiles a callee once per literal
    # argument, so a step's _advance would be compiled again for each slot it takes in some composite
    status = _A0(np.int64(0), state, y, params, new_state, out, shared, index, work)
    if _N_PARTS > 1 and status == -1:
        status = _A1(np.int64(1), state, y, params, new_state, out, shared, index, work)
    if _N_PARTS > 2 and status == -1:
        status = _A2(np.int64(2), state, y, params, new_state, out, shared, index, work)
    if _N_PARTS > 3 and status == -1:
        status = _A3(np.int64(3), state, y, params, new_state, out, shared, index, work)
    if _N_PARTS > 4 and status == -1:
        status = _A4(np.int64(4), state, y, params, new_state, out, shared, index, work)
    if _N_PARTS > 5 and status == -1:
        status = _A5(np.int64(5), state, y, params, new_state, out, shared, index, work)
    if _N_PARTS > 6 and status == -1:
        status = _A6(np.int64(6), state, y, params, new_state, out, shared, index, work)
    if _N_PARTS > 7 and status == -1:
        status = _A7(np.int64(7), state, y, params, new_state, out, shared, index, work)
    return status


_COMPOSITE_STEPS: dict = {}


def composite_step(steps: Sequence[_kernels.Step]) -> _kernels.Step:
    """The registered step (:func:`smo_gym.observers._kernels.register_step`) of a composite of ``steps``, one per
    part in order: generated once per tuple, cached on disk like every step (its code contains the parts' code, so
    its cache is dropped when their modules change)."""
    rows = tuple(step.rows for step in steps)
    step = _COMPOSITE_STEPS.get(rows)
    if step is None:
        if not 1 <= len(rows) <= MAX_PARTS:
            raise ValueError(f"expected 1 to {MAX_PARTS} parts, actual value: {len(rows)}")
        labels = [f"{r.py_func.__module__}.{r.py_func.__qualname__}" for r in rows]
        # the name numba caches it under: short (it is part of a file name), unique (the digest of the full names)
        digest = hashlib.sha1("+".join(labels).encode()).hexdigest()[:10]
        label = "+".join(r.py_func.__qualname__ for r in rows)[:60] + "." + digest
        slots = {f"_A{i}": _advance(rows[i]) if i < len(rows) else None for i in range(MAX_PARTS)}
        deps = sorted({inspect.getfile(r.py_func) for r in rows} | {_kernels.__file__})
        # compiled once and called by its drivers (the batch kernels, the offline loop, the wrapper's one-call
        # drivers), not inlined into each: numba's inlining types the parts' code again in every driver, 6-8 s
        # each (FD, KalmanCA and the IMM estimator: the batch kernel 8.4 s inlined, 2.1 s calling it, after 6 s
        # for the composite alone), and a process often builds two or three drivers; the step costs the same
        options = dict(cache=_kernels.CACHE, error_model="numpy", inline="never")
        compiled = cached_instance(_per_channel_rows_template, label, options, deps, _N_PARTS=len(rows), **slots)
        step = _COMPOSITE_STEPS[rows] = _kernels.register_step(compiled, allocates=True, sources=deps)
    return step


class PerChannel(Observer):
    r"""One observer per group of channels, reported as value and velocity (``order = 1``).

    Parameters
    ----------
    parts : sequence of (Observer, sequence of int)
        Each observer with the channels (indices into the last axis of the measurement) it observes. Every
        channel belongs to exactly one part; the observers must share ``dt`` and run compiled steps (registered
        families that are not model-based; at most :data:`MAX_PARTS` parts). They configure
        the parts: their gains and per-channel parameters are read at each full reset, their state is the
        composite's own.
    mean_over : float, optional
        Report each part's velocity as the mean over the last ``mean_over`` seconds where the part reports
        derivatives at the sample time (:attr:`~smo_gym.observers.Observer.reports_instant`; the velocity of an
        Euler-integrating simulator, :func:`smo_gym.engine.measurement.mean_velocity_span`). The composite itself
        then reports means: its ``reports_instant`` is False.

    Attributes
    ----------
    parts : tuple of (Observer, ndarray of int)
        The observers (owned: copies of those given) and their channels.
    names : tuple of str
        The observer name of every channel (``"kalman-ca"``, ...): what :func:`repr` and the wrapper report.

    Notes
    -----
    Estimates have shape ``(..., n_channels, 2)``: the value estimate of each channel's observer, and its
    velocity. One compiled step advances every part (module notes), so ``update`` and ``run`` are all or nothing
    across the parts as for any observer: if one part rejects a sample (a non-finite measurement, a diverging
    state), every part keeps the state it had before the call.
    """

    discretizations = ("per-channel",)

    @check_keywords
    def __init__(self, parts: Sequence, *, mean_over: float | None = None):
        if isinstance(parts, (str, bytes)) or not isinstance(parts, Sequence) or len(parts) == 0:
            raise TypeError(f"expected a non-empty sequence of (observer, channels) pairs, actual value: {parts!r:.80}")
        owned, channels, dts = [], [], []
        for i, part in enumerate(parts):
            if not (isinstance(part, Sequence) and len(part) == 2 and isinstance(part[0], Observer)):
                raise TypeError(f"expected parts[{i}] to be a pair (Observer, channels), actual value: {part!r:.80}")
            observer, idx = part
            try:
                idx = np.asarray(idx)
                if idx.ndim != 1 or idx.size == 0 or idx.dtype.kind not in "iu":
                    raise TypeError
            except TypeError:
                raise TypeError(
                    f"expected the channels of parts[{i}] as a non-empty 1-d sequence of ints, actual value: "
                    f"{part[1]!r}"
                ) from None
            if isinstance(observer, PerChannel) or _part_step(observer) is None or observer.lead != 0:
                raise TypeError(
                    f"expected parts[{i}] to be an observer that runs a compiled step and reports at its sample "
                    "(a registered family that is not model-based, or a filter told the input), actual value: "
                    f"{type(observer).__name__}"
                )
            if observer.takes_input and not self.takes_input:
                raise TypeError(
                    f"expected parts that do not take the control input in a PerChannel, actual value: parts[{i}] "
                    f"is a {type(observer).__name__}; use smo_gym.observers.PerChannelInput"
                )
            owned.append(copy.deepcopy(observer))
            channels.append(idx.astype(np.intp))
            dts.append(observer.dt)
        if len(owned) > MAX_PARTS:
            raise ValueError(f"expected at most {MAX_PARTS} parts, actual value: {len(owned)}")
        flat = np.concatenate(channels)
        n = flat.size
        if flat.min() < 0 or not np.array_equal(np.sort(flat), np.arange(n)):
            raise ValueError(
                f"expected every channel 0..{n - 1} in exactly one part, actual value: channels "
                f"{[c.tolist() for c in channels]}"
            )
        if not np.allclose(dts, dts[0], rtol=1e-12, atol=0.0):
            raise ValueError(f"expected parts sharing one dt, actual value: dt {dts}")
        mean_over = None if mean_over is None else check_positive("mean_over", mean_over)
        wrap = np.zeros(n, dtype=bool)
        for observer, idx in zip(owned, channels, strict=True):  # a part's wrap: None, a bool, or one per channel
            wrap[idx] = np.broadcast_to(np.asarray(False if observer.wrap is None else observer.wrap), idx.shape)
        super().__init__(dts[0], 1, "per-channel", wrap=wrap if wrap.any() else None)
        self.mean_over = mean_over
        self.parts = tuple(zip(owned, channels, strict=True))
        self.n_channels = n
        self._coefficients = tuple(reported_coefficients(observer, mean_over) for observer in owned)
        names = np.empty(n, dtype=object)
        for observer, idx in self.parts:
            names[idx] = observer.name or type(observer).__name__
        self.names = tuple(names)

    @property
    def self_starting(self) -> bool:
        """Whether every part is (:attr:`Observer.self_starting <smo_gym.observers.Observer.self_starting>`)."""
        return all(observer.self_starting for observer, _ in self.parts)

    @property
    def _kernel(self):
        return composite_step(self._slots()[0]).kernel

    def _step_kernel(self) -> tuple:
        """The per-channel kernel and rows, always: a composite's rows are equal only with one part, and its shared
        variant would compile the composite step and its part's advance a second time to save one index per channel
        and sample (the IMM estimator on Hopper's six joints, a wrapper step, ``update`` and ``run`` on a cold cache:
        19.2 s of compilation with it, 14.6 s without). The wrappers' drivers call the per-channel kernel too."""
        return self._kernel, self._params

    def _slots(self) -> tuple[tuple[_kernels.Step, ...], list[int]]:
        """The distinct steps the composite step calls, in the order of their names, and each part's index among
        them.

        Parts that run the same step with the same state width and order (the IMM estimator twice, with Huber's
        update and without) are one call per sample, and composites of the same steps share one compiled step
        whatever the order of their parts: each further step in a composite costs 1-2.5 s of compilation on a cold
        cache, and ``"auto"`` builds a new grouping for nearly every environment and sensor.
        """
        steps = [_part_step(observer) for observer, _ in self.parts]
        observers = [observer for observer, _ in self.parts]
        keys = [(step.label, o._state_width(), o.order) for step, o in zip(steps, observers, strict=True)]
        distinct = sorted(set(keys))
        step_of = dict(zip(keys, steps, strict=True))
        return tuple(step_of[key] for key in distinct), [distinct.index(key) for key in keys]

    # ---- the state and parameters of the composite step (module notes) ---------------------------------------
    def _part_rows(self, shape: tuple[int, ...]) -> list[np.ndarray]:
        """For each part, the flat rows of its channels in every batch element (in the part's own flat order), for
        measurements of ``shape``; kept for the last shape (every restart of an episode needs them)."""
        cached = self.__dict__.get("_rows_of_shape")
        if cached is None or cached[0] != shape:
            batch = math.prod(shape[:-1])
            rows = [(np.arange(batch)[:, None] * self.n_channels + idx[None, :]).reshape(-1) for _, idx in self.parts]
            cached = self._rows_of_shape = (shape, rows)
        return cached[1]

    def _state_width(self) -> int:
        return max(observer._state_width() for observer, _ in self.parts)

    def _channel_params(self, shape: tuple[int, ...]) -> np.ndarray:
        if shape[-1] != self.n_channels:
            raise ValueError(
                f"expected a measurement with {self.n_channels} channels (last axis), actual value: shape {shape}"
            )
        packed = []
        for observer, idx in self.parts:
            observer.reset(np.zeros(shape[:-1] + idx.shape))  # sizes the part's per-channel parameters
            packed.append(observer.arrays.params)
        slot = self._slots()[1]
        widths = {}
        for k, part_params in zip(slot, packed, strict=True):  # one call per slot reads one parameter width
            if widths.setdefault(k, part_params.shape[1]) != part_params.shape[1]:
                raise RuntimeError(f"expected parts of one step with one parameter width, actual value: {widths[k]} "
                                   f"and {part_params.shape[1]}")  # fmt: skip
        K = max(len(c) if c is not None else 1 for c in self._coefficients)
        at = COEFFICIENTS + K
        params = np.zeros((int(np.prod(shape, dtype=np.int64)), at + max(p.shape[1] for p in packed)))
        parts = zip(self.parts, packed, self._coefficients, self._part_rows(shape), strict=True)
        for k, ((observer, _), part_params, c, rows) in enumerate(parts):
            c = np.ones(1) if c is None else c
            params[rows, :COEFFICIENTS] = [
                slot[k],
                observer._state_width(),
                part_params.shape[1],
                observer.order + 1,
                observer._innovation_column(),
                len(c),
                at,
            ]
            params[rows, COEFFICIENTS : COEFFICIENTS + len(c)] = c
            params[rows, at : at + part_params.shape[1]] = part_params
        return params

    def _fresh_state(self, y0: np.ndarray, x0: np.ndarray | None) -> np.ndarray:
        """Every part's state after a reset at ``y0`` (with the derivatives of ``x0``), row by row: each part's own
        fresh state from its parameters (the parts' own states are not used; restarting each part instead cost
        ~10 us more per episode)."""
        state = np.zeros((y0.size, self._state_width()))
        for (observer, idx), rows in zip(self.parts, self._part_rows(y0.shape), strict=True):
            y0_part = y0[..., idx]
            x0_part = None if x0 is None else observer._initial_estimate(y0_part, x0[..., idx, 1:])
            part_state = observer._fresh_state(y0_part, x0_part)
            state[rows, : part_state.shape[1]] = part_state
        return state

    @property
    def output_error(self) -> np.ndarray:
        self._require_reset()
        columns = self._params[:, INNOVATION].astype(np.intp)
        return self._state[np.arange(self._state.shape[0]), columns].reshape(self._shape)

    def __repr__(self) -> str:
        groups = ", ".join(f"{self.names[idx[0]]}: {idx.tolist()}" for _, idx in self.parts)
        mean = "" if self.mean_over is None else f", mean_over={self.mean_over}"
        return f"{type(self).__name__}({{{groups}}}, dt={self.dt}{mean})"
