r"""Different observers on different channels of one measurement, reported as one velocity observer.

The joints of a robot differ: a heavy, slow base joint is best differentiated by a filter that trusts its
measurements little, a light joint hit by impacts by one that trusts them a lot, and an ideal encoder on an
Euler-integrated joint by a plain backward difference. :class:`PerChannel` runs one observer per group of
channels and reports what a consumer of velocities reads, the value and the first derivative of every channel
(``order = 1``), each part's velocity taken as that part reports it (optionally converted to the mean over the last
step, as :class:`smo_gym.engine.measurement.VelocityEstimator` does). :func:`smo_gym.selection.auto_observer` builds
one from a calibration.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence

import numpy as np

from .._validation import DivergenceError, as_real_array, check_keywords, check_mask, check_positive
from .base import Observer, as_measurement, reported_coefficients, reported_velocity

__all__ = ["PerChannel"]


class PerChannel(Observer):
    r"""One observer per group of channels, reported as value and velocity (``order = 1``).

    Parameters
    ----------
    parts : sequence of (Observer, sequence of int)
        Each observer with the channels (indices into the last axis of the measurement) it observes. Every
        channel belongs to exactly one part; the observers must share ``dt``.
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
    velocity. ``update`` and ``run`` are all or nothing across the parts: if one part rejects a sample (a
    non-finite measurement, a diverging state), every part keeps the state it had before the call.
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
            owned.append(copy.deepcopy(observer))
            channels.append(idx.astype(np.intp))
            dts.append(observer.dt)
        flat = np.concatenate(channels)
        n = flat.size
        if flat.min() < 0 or not np.array_equal(np.sort(flat), np.arange(n)):
            raise ValueError(
                f"expected every channel 0..{n - 1} in exactly one part, actual value: channels "
                f"{[c.tolist() for c in channels]}"
            )
        if not np.allclose(dts, dts[0], rtol=1e-12, atol=0.0):
            raise ValueError(f"expected parts sharing one dt, actual value: dt {dts}")
        self.dt = float(dts[0])
        self.order = 1
        self.discretization = "per-channel"
        self.mean_over = None if mean_over is None else check_positive("mean_over", mean_over)
        self.parts = tuple(zip(owned, channels, strict=True))
        self._coefficients = tuple(reported_coefficients(observer, self.mean_over) for observer in owned)
        self.n_channels = n
        names = np.empty(n, dtype=object)
        for observer, idx in self.parts:
            names[idx] = observer.name or type(observer).__name__
        self.names = tuple(names)
        wrap = np.zeros(n, dtype=bool)
        for observer, idx in self.parts:  # a part's wrap: None, a bool, or one per channel of the part
            wrap[idx] = np.broadcast_to(np.asarray(False if observer.wrap is None else observer.wrap), idx.shape)
        self.wrap = wrap if wrap.any() else None
        self._shape = None
        self._estimate = None
        self.n_updates = 0

    # ---- assembling the parts' estimates --------------------------------------------------------------------
    def _assemble(self, estimates: Sequence[np.ndarray], lead: tuple[int, ...]) -> np.ndarray:
        out = np.empty(lead + (self.n_channels, 2))
        for i, ((_, idx), est) in enumerate(zip(self.parts, estimates, strict=True)):
            out[..., idx, 0] = est[..., 0]
            out[..., idx, 1] = reported_velocity(est, self._coefficients[i])
        return out

    def _checked(self, y, name: str) -> np.ndarray:
        y = as_measurement(y, name)
        if y.shape[-1] != self.n_channels:
            raise ValueError(f"expected {name} with {self.n_channels} channels (last axis), actual value: {y.shape}")
        if not np.isfinite(y).all():
            self._raise_nonfinite(y, name)
        return y

    # ---- public API -----------------------------------------------------------------------------------------
    @check_keywords
    def reset(self, y0, mask=None, *, derivatives=None) -> np.ndarray:
        """Start (or restart) every part at ``y0``; arguments as :meth:`Observer.reset` (``derivatives``: at most
        the velocity, shape ``(..., n_channels, 1)``)."""
        y0 = self._checked(y0, "y0")
        if mask is not None:
            if self._shape is None:
                raise RuntimeError("expected a full reset(y0) before a masked reset, actual value: never reset")
            if y0.shape != self._shape:
                raise ValueError(f"expected y0 with shape {self._shape} for a masked reset, actual value: {y0.shape}")
            mask = check_mask("mask", mask)
            if mask.shape not in (y0.shape[:-1], y0.shape):
                raise ValueError(f"expected mask with shape {y0.shape[:-1]} or {y0.shape}, actual value: {mask.shape}")
        if derivatives is not None:
            d = as_real_array("derivatives", derivatives)
            if d.shape not in (y0.shape + (0,), y0.shape + (1,)):
                raise ValueError(
                    f"expected derivatives with shape {y0.shape + (1,)} (the velocity of every channel), actual "
                    f"value: shape {d.shape}"
                )
        estimates = []
        for observer, idx in self.parts:
            kw = {}
            if mask is not None:
                kw["mask"] = mask if mask.shape == y0.shape[:-1] else mask[..., idx]
            if derivatives is not None:
                kw["derivatives"] = d[..., idx, :]
            estimates.append(observer.reset(y0[..., idx], **kw))
        self._shape = y0.shape
        self._estimate_parts = [observer.estimate for observer, _ in self.parts]
        self._estimate = self._assemble(estimates, y0.shape[:-1])
        if mask is None:
            self.n_updates = 0
        return self._estimate.copy()

    def restart(self, y0, *, derivatives=None) -> np.ndarray:
        """A full :meth:`reset` of every part (each keeps its parameters where it can: :meth:`Observer.restart`)."""
        if self._shape is None:
            raise RuntimeError("expected a full reset(y0) before restart(y0), actual value: never reset")
        y0 = self._checked(y0, "y0")
        if y0.shape != self._shape:
            raise ValueError(f"expected y0 with shape {self._shape} for a restart, actual value: {y0.shape}")
        if derivatives is not None:
            return self.reset(y0, derivatives=derivatives)
        self._estimate = self._assemble([o.restart(y0[..., idx]) for o, idx in self.parts], y0.shape[:-1])
        self._estimate_parts = [observer.estimate for observer, _ in self.parts]
        self.n_updates = 0
        return self._estimate.copy()

    def update(self, y) -> np.ndarray:
        """One sample through every part; returns the estimate ``(..., n_channels, 2)``; see :meth:`Observer.update`."""
        if self._shape is None:
            raise RuntimeError("expected reset(y0) before update(y), actual value: the observer was never reset")
        y = self._checked(y, "y")
        if y.shape != self._shape:
            raise ValueError(f"expected y with shape {self._shape}, actual value: {y.shape}")
        estimates = []
        for k, (observer, idx) in enumerate(self.parts):
            try:
                estimates.append(observer.update(np.ascontiguousarray(y[..., idx])))
            except DivergenceError:
                for (earlier, _), previous in zip(self.parts[:k], self._estimate_parts, strict=False):
                    earlier._undo_update(previous)  # all or nothing: the parts already advanced step back
                raise
        self._estimate_parts = estimates
        self._estimate = out = self._assemble(estimates, y.shape[:-1])
        self.n_updates += 1
        return out

    @check_keywords
    def run(self, Y, *, out: np.ndarray | None = None) -> np.ndarray:
        """A recorded block ``Y`` ``(T, ..., n_channels)`` through every part (each in one compiled call); returns
        ``(T, ..., n_channels, 2)``; see :meth:`Observer.run`."""
        if self._shape is None:
            raise RuntimeError("expected reset(y0) before run(Y), actual value: the observer was never reset")
        Y = as_real_array("Y", Y)
        if Y.ndim == 0 or Y.shape[1:] != self._shape:
            raise ValueError(f"expected Y with shape (T, *{self._shape}), actual value: {Y.shape}")
        if not np.isfinite(Y).all():
            self._raise_nonfinite(Y, "Y")
        T = Y.shape[0]
        out = self._output_array(out, (T,) + self._shape + (2,))
        if T == 0:
            return out
        checkpoints = [observer._checkpoint() for observer, _ in self.parts]
        estimates = []
        try:
            for observer, idx in self.parts:
                estimates.append(observer.run(np.ascontiguousarray(Y[..., idx])))
        except DivergenceError:  # all or nothing: the parts already advanced go back
            for (observer, _), checkpoint in zip(self.parts, checkpoints, strict=True):
                observer._rollback(checkpoint)
            raise
        out[...] = self._assemble(estimates, Y.shape[:-1])
        self._estimate_parts = [observer.estimate for observer, _ in self.parts]
        self._estimate = out[-1].copy()
        self.n_updates += T
        return out

    def step(self, state, y):
        raise TypeError(
            "expected an observer with one flat state for step(), actual value: a PerChannel observer, whose state "
            "is its parts' (step each part's observer instead)"
        )

    @property
    def output_error(self) -> np.ndarray:
        self._require_reset()
        out = np.empty(self._shape)
        for observer, idx in self.parts:
            out[..., idx] = observer.output_error
        return out

    @property
    def state(self):
        raise TypeError("expected an observer with one flat state, actual value: PerChannel (see each part's state)")

    @property
    def arrays(self):
        raise TypeError("expected an observer with one flat state, actual value: PerChannel (see each part's arrays)")

    def __repr__(self) -> str:
        groups = ", ".join(f"{self.names[idx[0]]}: {idx.tolist()}" for _, idx in self.parts)
        mean = "" if self.mean_over is None else f", mean_over={self.mean_over}"
        return f"PerChannel({{{groups}}}, dt={self.dt}{mean})"
