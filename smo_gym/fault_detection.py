r"""Fault detection and isolation with a bank of super-twisting observers (multi-model approach).

A mechanical system with measured positions, known input ``u`` and one of ``q`` known faults,

.. math::
    \dot x_1 = x_2,\qquad \dot x_2 = f(x_1, x_2, u) + F_i(x_1, x_2, u),\qquad y = x_1,
    \qquad F_i \in \{F_0 \equiv 0, F_1, \dots, F_q\},

is watched by ``q + 1`` super-twisting observers (:class:`smo_gym.observers.MechanicalSuperTwisting`, Davila,
Fridman and Levant 2005), observer ``i`` using the model :math:`f + F_i` (model 0 the nominal one). Once an observer
is in its sliding mode (finite time) its equivalent output injection equals what its model misses,

.. math:: r_i = F_{true}(x, u) - F_i(x, u),

which is the idea of Rios, Davila, Fridman and Edwards (2014) as presented in Fridman's slides ("Fault detection
using multi-model approach"): the observers are *multi-models* and the equivalent injections (low-pass filtered,
:attr:`~smo_gym.observers.MechanicalSuperTwisting.disturbance`) are the residuals.

Decision (:func:`diagnose`), with the residuals normalized per joint by the threshold,
:math:`\rho_i = \max_j |r_{i,j}| / \theta_j` (the band is :math:`\rho \le 1`):

* nothing is decided before ``settle_time`` (the observers' convergence from their initial error);
* **detection**: the first sample at which the nominal residual leaves the band, :math:`\rho_0 > 1`;
* **isolation**: after detection, the first sample at which exactly one fault model ``i`` has stayed inside the
  band for the last ``dwell`` seconds: the fault is :math:`F_i`. The matching model's residual stays in the band
  (it vanishes once its observer slides), so if model ``i`` leaves the band later the verdict is revoked and the
  search starts again after the exit (a wrong model can fit for a while when the input excites little). If no
  verdict stands at the end of the record, the fault is *unknown* (outside the bank).

Where the threshold comes from
------------------------------
Noise-free and with an exact model the residual of the matching model is the discretization error of the sampled
observer, :math:`O(h)`; with measurement noise it is dominated by the filtered chattering of the injection (of
amplitude up to :math:`k_2`). No closed-form bound of the latter is sharp enough to be useful, so with noise the
threshold is *calibrated* (:func:`calibrate_threshold`): a margin times the largest nominal residual over fault-free
runs with other noise seeds. A fault is detectable (and isolable) when :math:`|F_{true} - F_i|` exceeds the
threshold, for the wrong models, persistently (the distinguishability condition of the multi-model approach).

References
----------
.. [RDFE14] H. Rios, J. Davila, L. Fridman and C. Edwards, "Fault detection and isolation for nonlinear systems via
   high-order-sliding-mode multiple-observer", International Journal of Robust and Nonlinear Control, published
   online 2014, doi:10.1002/rnc.3232; in Fridman's slides ("H. Rios et al. IJRNC 2014"), "Fault detection using
   multi-model approach".
.. [DFL05] J. Davila, L. Fridman and A. Levant, "Second-order sliding-mode observer for mechanical systems",
   IEEE TAC 50(11), 2005.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ._validation import (
    as_real_array,
    check_int_in_range,
    check_keywords,
    check_names,
    check_nonnegative,
    check_positive,
)
from .observers.mechanical import Dynamics, MechanicalSuperTwisting

__all__ = ["FaultDiagnosis", "FaultObserverBank", "calibrate_threshold", "diagnose"]

#: ``FaultDiagnosis.isolated`` for a detected fault that no model of the bank explains
UNKNOWN = -1


class _FaultyModel:
    """``f + F``: a model (Dynamics object or callable ``f(q, v, u)``) plus an additive fault callable."""

    def __init__(self, n: int, base, fault: Callable | None):
        self.n = n
        self._base = base
        self._fault = fault

    def _base_acceleration(self, q, v, u):
        if isinstance(self._base, Dynamics):
            return np.asarray(self._base.acceleration(q, v, u), dtype=np.float64)
        return np.asarray(self._base(q, v, u), dtype=np.float64)

    def acceleration(self, q, v, u=None) -> np.ndarray:
        a = self._base_acceleration(q, v, u)
        if self._fault is None:
            return a
        return a + np.asarray(self._fault(q, v, u), dtype=np.float64)

    def inertia(self, q) -> np.ndarray:
        if isinstance(self._base, Dynamics):
            return self._base.inertia(q)
        q = np.asarray(q)
        return np.broadcast_to(np.eye(self.n), q.shape[:-1] + (self.n, self.n)).copy()


def _check_model(name: str, model) -> None:
    if not (isinstance(model, Dynamics) or callable(model)):
        raise TypeError(
            f"expected {name} to be a dynamics object (n, acceleration, inertia) or a callable f(q, v, u), "
            f"actual value: {type(model).__name__}"
        )


@dataclass(frozen=True)
class FaultDiagnosis:
    r"""What a bank of observers concluded about one record (arrays over the batch shape ``B``).

    Attributes
    ----------
    detected : ndarray of bool, shape B
        The nominal residual left the band after ``settle_time``.
    detection_time : ndarray of float, shape B
        Time [s] (from the first sample, which is time 0) of detection; NaN where nothing was detected.
    isolated : ndarray of int, shape B
        Index of the model of the bank that explains the data: ``i >= 1`` the fault :math:`F_i` (model ``i`` of the
        bank, the ``i - 1``-th entry of ``faults``), ``0`` no fault detected, ``-1`` detected but *unknown* (no
        fault model stayed in the band for ``dwell`` seconds).
    isolation_time : ndarray of float, shape B
        Time [s] of the standing isolation (the end of its dwell window); NaN where nothing was isolated.
    residual_norms : ndarray, shape (T, *B, q + 1)
        Normalized residual :math:`\rho_i = \max_j |r_{i,j}|/\theta_j` of each model at each sample (band: ``<= 1``).
    names : tuple of str
        Names of the ``q + 1`` models (``"nominal"`` first).
    """

    detected: np.ndarray
    detection_time: np.ndarray
    isolated: np.ndarray
    isolation_time: np.ndarray
    residual_norms: np.ndarray
    names: tuple[str, ...]

    def label(self, index=()) -> str:
        """The verdict of batch element ``index`` in words: ``"no fault"``, a fault's name, or ``"unknown"``."""
        i = int(np.asarray(self.isolated)[index])
        return "no fault" if i == 0 else ("unknown" if i == UNKNOWN else self.names[i])

    def final_norms(self, window: int = 50) -> np.ndarray:
        """Mean normalized residual of each model over the last ``window`` samples, shape ``(*B, q + 1)``."""
        window = check_int_in_range("window", window, 1, self.residual_norms.shape[0])
        return self.residual_norms[-window:].mean(axis=0)


def _samples(name: str, duration: float, dt: float) -> int:
    """``ceil(duration / dt)`` samples (less a rounding allowance), or a ValueError where the ratio overflows."""
    ratio = duration / dt - 1e-9
    if not math.isfinite(ratio):  # math.ceil(inf) raises OverflowError
        raise ValueError(f"expected {name} / dt within a float's range, actual value: {duration!r} / {dt!r}")
    return math.ceil(ratio)


def _first_window(inside: np.ndarray, m: int) -> np.ndarray:
    """Per column of ``inside`` (T, k): does the window of the last ``m`` samples ending at each sample lie inside."""
    c = np.cumsum(np.vstack([np.zeros((1, inside.shape[1]), dtype=int), inside.astype(int)]), axis=0)
    full = np.zeros(inside.shape, dtype=bool)
    if inside.shape[0] >= m:
        full[m - 1 :] = (c[m:] - c[:-m]) == m
    return full


@check_keywords
def diagnose(
    residual_norms, dt: float, *, dwell: float, settle_time: float = 0.0, names: Sequence[str] | None = None
) -> FaultDiagnosis:
    r"""Detection and isolation from the normalized residuals of a bank (the decision rule of the module).

    Parameters
    ----------
    residual_norms : array_like, shape (T, *B, q + 1)
        :math:`\rho_i` per sample, model 0 the nominal one; the band is :math:`\rho \le 1`.
    dt : float
        Sampling step [s].
    dwell : float
        How long [s] a fault model's residual must stay in the band to be isolated (``>= dt``: at least one
        sample).
    settle_time : float
        Samples before this time [s] are ignored (the observers' convergence from their initial error).
    names : sequence of str, optional
        Names of the ``q + 1`` models.

    Returns
    -------
    FaultDiagnosis

    Raises
    ------
    TypeError
        Non-numbers where numbers are expected, ``names`` not a sequence of strings.
    ValueError
        A shape, a NaN residual, a non-positive ``dt`` or ``dwell``, ``dwell / dt`` or ``settle_time / dt`` beyond a
        float's range, or a wrong number of names.
    """
    rho = as_real_array("residual_norms", residual_norms)
    if rho.ndim < 2 or rho.shape[-1] < 2 or rho.shape[0] < 1:
        raise ValueError(
            f"expected residual_norms with shape (T, ..., q + 1), T >= 1 and q >= 1 fault models, actual value: "
            f"shape {rho.shape}"
        )
    if np.isnan(rho).any():  # a NaN compares as in the band: it would read as "no fault"
        t = int(np.flatnonzero(np.isnan(rho).reshape(rho.shape[0], -1).any(axis=1))[0])
        raise ValueError(f"expected residual norms without NaN, actual value: NaN at sample {t}")
    dt = check_positive("dt", dt)
    dwell = check_positive("dwell", dwell)
    settle_time = check_nonnegative("settle_time", settle_time)
    T, k = rho.shape[0], rho.shape[-1]
    batch = rho.shape[1:-1]
    if names is None:
        names = ("nominal",) + tuple(f"F{i}" for i in range(1, k))
    names = tuple(check_names("names", names))
    if len(names) != k:
        raise ValueError(f"expected {k} model names, actual value: {len(names)}")
    m = max(1, _samples("dwell", dwell, dt))
    k0 = min(T, _samples("settle_time", settle_time, dt))
    flat = rho.reshape(T, -1, k)
    nb = flat.shape[1]
    detected = np.zeros(nb, dtype=bool)
    t_det = np.full(nb, np.nan)
    isolated = np.zeros(nb, dtype=int)
    t_iso = np.full(nb, np.nan)
    for b in range(nb):
        out = np.flatnonzero(flat[k0:, b, 0] > 1.0)
        if out.size == 0:
            continue
        kd = k0 + int(out[0])
        detected[b], t_det[b] = True, kd * dt
        isolated[b] = UNKNOWN
        start = kd  # windows counted from detection on: residuals before it describe the healthy system
        while start < T:
            inside = flat[start:, b, 1:] <= 1.0
            full = _first_window(inside, m)
            single = np.flatnonzero(full.sum(axis=1) == 1)
            if single.size == 0:
                isolated[b], t_iso[b] = UNKNOWN, np.nan
                break
            ki = int(single[0])
            i = int(np.flatnonzero(full[ki])[0])
            isolated[b], t_iso[b] = 1 + i, (start + ki) * dt
            # the matching model's residual stays in the band: a later exit revokes the verdict, search again
            exits = np.flatnonzero(~inside[ki + 1 :, i])
            if exits.size == 0:
                break
            start += ki + 1 + int(exits[0])
    return FaultDiagnosis(
        detected=detected.reshape(batch),
        detection_time=t_det.reshape(batch),
        isolated=isolated.reshape(batch),
        isolation_time=t_iso.reshape(batch),
        residual_norms=rho,
        names=names,
    )


@check_keywords
def calibrate_threshold(residuals, dt: float, *, settle_time: float = 0.0, margin: float = 1.5) -> np.ndarray:
    r"""Per-joint threshold from the nominal residuals of fault-free runs: ``margin`` times their largest magnitude.

    Parameters
    ----------
    residuals : array_like, shape (T, ..., n)
        Nominal residuals (filtered equivalent injections) of fault-free runs, e.g. several noise seeds stacked on
        the batch axes. Use other seeds than those evaluated, or the false-alarm rate is flattered.
    dt : float
    settle_time : float
        Samples before this time [s] are left out (observer convergence).
    margin : float
        ``> 0``; the threshold is ``margin * max |r|`` per joint.

    Returns
    -------
    ndarray, shape (n,)

    Raises
    ------
    TypeError
        Non-numbers where numbers are expected.
    ValueError
        An empty or 1-D ``residuals``, non-positive ``dt`` or ``margin``, a ``settle_time`` not shorter than the
        record, non-finite or all-zero residuals of a joint, or a threshold beyond a float's range.
    """
    r = as_real_array("residuals", residuals)
    if r.ndim < 2 or r.size == 0:
        raise ValueError(f"expected residuals with shape (T, ..., n), none empty, actual value: shape {r.shape}")
    dt = check_positive("dt", dt)
    margin = check_positive("margin", margin)
    k0 = _samples("settle_time", check_nonnegative("settle_time", settle_time), dt)
    if k0 >= r.shape[0]:
        raise ValueError(f"expected settle_time shorter than the record ({r.shape[0] * dt} s), actual value: {k0 * dt}")
    peak = np.abs(r[k0:]).reshape(-1, r.shape[-1]).max(axis=0)
    if not np.all(np.isfinite(peak)) or np.any(peak <= 0):
        raise ValueError(f"expected finite residuals, not all zero per joint, actual value: peaks {peak!r}")
    with np.errstate(over="ignore"):  # an overflow is refused below
        threshold = margin * peak
    if not np.all(np.isfinite(threshold)):
        raise ValueError(f"expected a finite threshold margin * peak, actual value: {margin!r} * {peak!r}")
    return threshold


class FaultObserverBank:
    r"""``q + 1`` super-twisting observers, one per model :math:`f + F_i` (:math:`F_0 = 0`), and their decision.

    Parameters
    ----------
    dt : float
        Sampling step [s].
    nominal : Dynamics or callable
        The nominal model: a dynamics object (e.g. :class:`smo_gym.mechanics.MujocoDynamics`) or a callable
        ``f(q, v, u) -> (..., n)`` (then ``n`` is required).
    faults : sequence
        The ``q >= 1`` known faults, each either a callable ``F_i(q, v, u) -> (..., n)`` added to the nominal model,
        or a dynamics object that *replaces* it (the faulty model, e.g. a ``MujocoDynamics`` of a modified copy of
        the model).
    threshold : float or array_like, shape (n,)
        :math:`\theta_j > 0`, the band of each joint's residual (see the module notes, :func:`calibrate_threshold`).
    lipschitz : float or array_like, shape (n,), optional
        ``L`` of the observers (bounds what a model misses, the faults included): gains
        :math:`k_1 = 1.5\sqrt L`, :math:`k_2 = 1.1 L`. Required unless ``k1`` and ``k2`` are given.
    k1, k2 : float or array_like, optional
    n : int, optional
        Number of joints; required when ``nominal`` is a callable, checked otherwise.
    dwell : float
        Isolation dwell time [s] (:func:`diagnose`).
    settle_time : float
        Decisions start after this time [s].
    disturbance_time_constant : float
        Time constant [s] of the filter on the equivalent injections (the residuals).
    names : sequence of str, optional
        Names of the ``q`` faults.
    **observer_options
        ``accel_bound``, ``discretization``, ``euler_substeps``, ``model_substeps`` of
        :class:`~smo_gym.observers.MechanicalSuperTwisting`.

    Attributes
    ----------
    observers : list of MechanicalSuperTwisting
        Model 0 nominal, model ``i`` fault ``i``.
    threshold : ndarray, shape (n,)
    names : tuple of str
        ``("nominal", *fault names)``.

    Notes
    -----
    Batched over leading dimensions as the observers are: ``reset(y0)`` with ``y0`` of shape ``(..., n)``; the
    models receive the batch (a ``MujocoDynamics`` evaluates it element by element).
    """

    @check_keywords
    def __init__(
        self,
        dt: float,
        nominal,
        faults: Sequence,
        threshold,
        *,
        lipschitz=None,
        k1=None,
        k2=None,
        n: int | None = None,
        dwell: float = 0.1,
        settle_time: float = 0.2,
        disturbance_time_constant: float = 0.02,
        names: Sequence[str] | None = None,
        **observer_options,
    ):
        self.dt = check_positive("dt", dt)
        _check_model("nominal", nominal)
        if isinstance(nominal, Dynamics):
            n_model = check_int_in_range("nominal.n", nominal.n, 1, 10_000)
            if n is not None and check_int_in_range("n", n, 1, 10_000) != n_model:
                raise ValueError(f"expected n equal to nominal.n ({n_model}), actual value: {n}")
            n = n_model
        elif n is None:
            raise ValueError("expected n (the number of joints) with a callable nominal model, actual value: None")
        self.n = n = check_int_in_range("n", n, 1, 10_000)
        if isinstance(faults, (str, bytes)) or not isinstance(faults, Sequence):
            raise TypeError(f"expected faults as a sequence of models, actual value: {type(faults).__name__}")
        if len(faults) == 0:
            raise ValueError("expected at least one fault model in faults, actual value: an empty sequence")
        models = [_FaultyModel(n, nominal, None)]
        for i, fault in enumerate(faults):
            _check_model(f"faults[{i}]", fault)
            if isinstance(fault, Dynamics):
                if fault.n != n:
                    raise ValueError(f"expected faults[{i}].n == {n}, actual value: {fault.n}")
                models.append(_FaultyModel(n, fault, None))
            else:
                models.append(_FaultyModel(n, nominal, fault))
        if names is None:
            names = [f"F{i}" for i in range(1, len(faults) + 1)]
        names = check_names("names", names)
        if len(names) != len(faults):
            raise ValueError(f"expected {len(faults)} fault names, actual value: {len(names)}")
        self.names = ("nominal", *names)
        th = as_real_array("threshold", threshold)
        th = np.broadcast_to(th, (n,)) if th.shape in ((), (1,), (n,)) else None
        if th is None or not np.all(np.isfinite(th)) or np.any(th <= 0):
            raise ValueError(f"expected threshold > 0, finite, scalar or of shape ({n},), actual value: {threshold!r}")
        self.threshold = np.array(th, dtype=np.float64)
        self.dwell = check_positive("dwell", dwell)
        self.settle_time = check_nonnegative("settle_time", settle_time)
        self.observers = [
            MechanicalSuperTwisting(
                self.dt,
                model,
                lipschitz,
                k1=k1,
                k2=k2,
                disturbance_time_constant=disturbance_time_constant,
                **observer_options,
            )
            for model in models
        ]
        self._history: list[np.ndarray] | None = None
        self._unreset = "the bank was never reset"

    @property
    def q(self) -> int:
        """Number of fault models."""
        return len(self.observers) - 1

    def reset(self, y0, v0=None) -> None:
        """Start every observer at the measurement ``y0`` (shape ``(..., n)``), velocity estimate ``v0`` (default 0),
        and clear the residual history."""
        for obs in self.observers:
            obs.reset(y0, v0=v0)
        self._history = []

    @property
    def residuals(self) -> np.ndarray:
        """Residual of each model (filtered equivalent injection, an acceleration), shape ``(..., q + 1, n)``."""
        if self._history is None:
            raise RuntimeError("expected reset(y0) before reading residuals, actual value: the bank was never reset")
        return np.stack([obs.disturbance for obs in self.observers], axis=-2)

    def update(self, y, u=None) -> np.ndarray:
        r"""Process one sample ``y`` (shape ``(..., n)``) with the input ``u`` that acted over the interval ending at
        it; return the normalized residuals :math:`\rho` of the ``q + 1`` models, shape ``(..., q + 1)``.

        The bank does not know the width of ``u`` (a model's own convention): an input one model refuses after the
        models before it took the sample leaves the bank to be reset."""
        if self._history is None:
            raise RuntimeError(f"expected reset(y0) before update(y), actual value: {self._unreset}")
        for i, obs in enumerate(self.observers):
            try:
                obs.update(y, u)
            except Exception:
                if i:  # the models before it took the sample: the bank no longer describes one instant
                    self._history = None
                    self._unreset = f"model {i} refused a sample the models before it had taken"
                raise
        rho = np.max(np.abs(self.residuals) / self.threshold, axis=-1)
        self._history.append(rho)
        return rho

    def velocity(self, model: int = 0) -> np.ndarray:
        """Velocity estimate of observer ``model`` (0: nominal), shape ``(..., n)``."""
        model = check_int_in_range("model", model, 0, self.q)
        return self.observers[model].velocity

    def diagnose(self) -> FaultDiagnosis:
        """The decision (:func:`diagnose`) on everything processed since :meth:`reset`; time 0 is the reset sample."""
        if not self._history:
            raise RuntimeError("expected at least one update after reset, actual value: none")
        # the reset sample has no residual yet (in the band by construction)
        rho = np.stack([np.zeros_like(self._history[0])] + self._history)
        return diagnose(rho, self.dt, dwell=self.dwell, settle_time=self.settle_time, names=self.names)

    def run(self, Y, U=None, v0=None) -> FaultDiagnosis:
        """Reset at ``Y[0]`` and process ``Y[1:]`` (shape ``(T, ..., n)``) with ``U[1:]`` (``U[k]`` the input over
        the interval ending at ``Y[k]``); return :meth:`diagnose`."""
        # the whole record is checked before the reset: a bad sample found midway would lose the history
        Y = as_real_array("Y", Y)
        if Y.ndim < 2 or Y.shape[-1] != self.n or Y.shape[0] < 2:
            raise ValueError(f"expected Y with shape (T >= 2, ..., {self.n}), actual value: shape {Y.shape}")
        if not np.isfinite(Y).all():
            t = int(np.flatnonzero(~np.isfinite(Y).reshape(Y.shape[0], -1).all(axis=1))[0])
            raise ValueError(f"expected finite measurements Y, actual value: NaN or inf at sample {t}")
        if U is not None:
            U = as_real_array("U", U)
            if U.ndim < 1 or U.shape[0] != Y.shape[0]:
                raise ValueError(f"expected U with one row per sample of Y ({Y.shape[0]}), actual value: {U.shape}")
            if not np.isfinite(U).all():
                t = int(np.flatnonzero(~np.isfinite(U).reshape(U.shape[0], -1).all(axis=1))[0])
                raise ValueError(f"expected finite inputs U, actual value: NaN or inf at sample {t}")
        self.reset(Y[0], v0=v0)
        for k in range(1, Y.shape[0]):
            self.update(Y[k], None if U is None else U[k])
        return self.diagnose()
