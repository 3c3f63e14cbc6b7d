r"""Observation of the continuous and discrete state of linear switched systems (Fridman's slides, section 10).

A linear switched system has ``q`` modes sharing one state,

.. math::
    \dot x = A_\sigma x + B_\sigma u + D_\sigma w,\qquad y = C_\sigma x,\qquad \sigma(t) \in \{0, \dots, q-1\},

(the slides' (29), modes numbered from 0 here). Two problems:

*continuous state, known* :math:`\sigma` (:class:`SwitchedHOSMObserver`)
    one cascaded HOSM observer per mode (:class:`~smo_gym.control.CascadedHOSMObserver`: Luenberger stage, Levant
    differentiator of the output error, Molinari's relation); at a switch the new mode's observer is restarted
    from the estimate carried across the switch (the slides' reset equations: :math:`z_{\hat\sigma(t_i^+)} =
    \tilde x_{\hat\sigma^*}(t_i)`, :math:`\nu = 0`), or from the output alone (``on_switch="restart"``), after which
    it is exact again in finite time, shorter than the dwell time.
*continuous and discrete state, unknown* :math:`\sigma` (:class:`SwitchedObserverBank`)
    the bank of the slides: all ``q`` observers run on the same data, and the *equivalent injection* of observer
    ``j``, the part of its output-error dynamics its model does not explain,

    .. math:: r_j = \hat{\dot e}_j - A_j \hat e_j ,

    vanishes for the mode that is active (with :math:`w = 0`, the slides' assumption for the discrete state)
    and equals the model mismatch :math:`(A_\sigma - A_j)x + (B_\sigma - B_j)u` for the others. The mode estimate
    follows the decision rule of :mod:`smo_gym.fault_detection` (band and dwell) rather than the slides' bare
    :math:`\arg\min_j r_j` (which flips on every noise sample where two residuals are close): a switch is
    *detected* when the current mode's residual has left the band and exactly one other mode's residual has
    stayed in it for ``dwell`` seconds; the switching instant is estimated as the time the old mode's residual left
    the band. At each detection every observer of the bank restarts from the new mode's estimate (the slides'
    reset equations), so that the wrong models' errors start again from zero.

Conditions (:meth:`SwitchedLinearSystem.conditions`)
----------------------------------------------------
The slides' assumptions, each checked and named when it fails:

1. every pair :math:`(A_\sigma, C_\sigma)` is detectable (assumption 1);
2. every mode is *strongly observable* with respect to its unknown input (the slides' "best case": the relative
   degree vector sums to :math:`n` and there are no invariant zeros), the condition under which the cascaded HOSM
   observer is exact in finite time (:func:`~smo_gym.control.strong_observability`, which says why it fails);
3. the modes are pairwise *distinguishable*: :math:`(A_i, B_i, C_i) \neq (A_j, B_j, C_j)` for :math:`i \neq j`
   (assumption 6 of the slides, :math:`A_{1i} \neq A_{1j} \vee B_{1i} \neq B_{1j}`, on the strongly observable
   part, which is the whole state under condition 2);
4. a positive dwell time longer than the observers' convergence time (assumption 4): a property of the signal
   :math:`\sigma`, not of the matrices; the tests and the demonstration measure it.

Notes
-----
Where the slides' print and the derivation differ:

* The slides call the switching driven by the state (:math:`\sigma = i` when :math:`Hx \in \mathcal H_i`)
  *autonomous* and decide it from :math:`H\hat x` (condition :math:`\mathcal V^*_\sigma \subset \ker Q_\sigma`):
  :class:`AutonomousSwitchedObserver` with a :class:`SwitchingSurface`; the exogenous (*non-autonomous*) switching
  is decided from the equivalent injection with :math:`w = 0` by :class:`SwitchedObserverBank`, which needs no
  knowledge of a switching surface (and also serves autonomous switching whose surface is unknown).
* The slides' residual :math:`r_j = \sum \nu_{k,i,j}^2` is the squared equivalent injection in the coordinates of
  the differentiator; here it is the injection mapped to the state, :math:`\hat{\dot e}_j - A_j\hat e_j`, whose
  norm is comparable across modes whose output matrices differ (it is zero exactly when theirs is).
* Condition 3 (the printed assumption 6) is structural: a mismatch :math:`(A_i - A_j)x + (B_i - B_j)u` that the
  trajectory does not excite (e.g. a gear change while :math:`u = 0`) leaves the modes indistinguishable *for
  that trajectory*; the detection delay then grows until the input excites it.
* The sampled-data form is the one of :class:`~smo_gym.control.CascadedHOSMObserver` (module
  :mod:`smo_gym.control.estimators`); a switch between samples is seen at the next sample.

References
----------
.. [Fri] L. Fridman, "Sliding Mode Observers: Theory and Practice", lecture slides, section "Switched systems".
.. [DRF12] J. Davila, H. Rios and L. Fridman, "State observation for nonlinear switched systems using nonhomogeneous
   high-order sliding mode observers", Asian Journal of Control 14(4), 2012.
.. [RDF12] H. Rios, J. Davila and L. Fridman, "High-order sliding mode observers for nonlinear autonomous switched
   systems with unknown inputs", Journal of the Franklin Institute 349(10), 2012.
.. [RDF14] H. Rios, J. Davila and L. Fridman, "State estimation of linear switched systems with unknown inputs",
   Int. J. Adaptive Control and Signal Processing, 2014.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .._validation import (
    DivergenceError,
    as_real_array,
    check_bool,
    check_choice,
    check_int_at_least,
    check_int_in_range,
    check_keywords,
    check_nonnegative,
    check_positive,
)
from .estimators import CascadedHOSMObserver, _output_sample
from .plants import RANK_TOL, LinearPlant, NotStronglyObservableError, StrongObservabilityReport, _unit

__all__ = [
    "AutonomousSwitchedObserver",
    "ModeMetrics",
    "NonlinearSwitchedObserverBank",
    "NotDistinguishableError",
    "SwitchedConditions",
    "SwitchedEstimate",
    "SwitchedHOSMObserver",
    "SwitchedLinearSystem",
    "SwitchedObserverBank",
    "SwitchingSurface",
    "mode_metrics",
]


class NotDistinguishableError(ValueError):
    """Two modes of a switched system cannot be told apart from the output; the message names them."""


def is_detectable(A, C) -> bool:
    r"""Hautus test: :math:`\operatorname{rank}[A - \lambda I; C] = n` for every eigenvalue with
    :math:`\operatorname{Re}\lambda \ge 0`."""
    A, C = np.asarray(A, float), np.atleast_2d(np.asarray(C, float))
    A, C = _unit(A), _unit(C)  # unit scale, so that the tolerances below are relative to ||A|| and ||C||
    n = A.shape[0]
    for lam in np.linalg.eigvals(A):
        if lam.real < -RANK_TOL * max(1.0, abs(lam)):
            continue
        M = np.vstack([A - lam * np.eye(n), C])
        s = np.linalg.svd(M, compute_uv=False)
        if np.sum(s > RANK_TOL * max(s[0], 1.0)) < n:
            return False
    return True


def mode_mismatch(a: LinearPlant, b: LinearPlant) -> float:
    r"""Relative size of the difference of two modes, :math:`\|[\Delta A, \Delta B; \Delta C, 0]\|_F /
    \|[A_a, B_a; C_a, 0]\|_F` (0: the same mode for the output; the unknown-input matrix does not count)."""

    def block(p):
        return np.block([[p.A, p.B], [p.C, np.zeros((p.n_outputs, p.n_inputs))]])

    ref = max(np.linalg.norm(block(a)), np.linalg.norm(block(b)), 1e-300)
    return float(np.linalg.norm(block(a) - block(b)) / ref)


@dataclass(frozen=True)
class SwitchedConditions:
    """What :meth:`SwitchedLinearSystem.conditions` found; ``ok`` is the verdict, ``reason`` names a failure.

    Attributes
    ----------
    detectable : tuple of bool
        Per mode, :math:`(A_\\sigma, C_\\sigma)` detectable.
    mode_reports : tuple of StrongObservabilityReport
        Per mode, :func:`~smo_gym.control.strong_observability` of :math:`(A_\\sigma, C_\\sigma, D_\\sigma)`.
    mismatch : ndarray, shape (q, q)
        :func:`mode_mismatch` of each pair (symmetric, zero diagonal).
    distinguishable : ndarray of bool, shape (q, q)
        ``mismatch > tol`` off the diagonal (the diagonal is True).
    """

    ok: bool
    reason: str
    names: tuple[str, ...]
    detectable: tuple[bool, ...]
    mode_reports: tuple[StrongObservabilityReport, ...]
    mismatch: np.ndarray
    distinguishable: np.ndarray

    @property
    def strongly_observable(self) -> tuple[bool, ...]:
        return tuple(r.ok for r in self.mode_reports)

    @property
    def relative_degrees(self) -> tuple[np.ndarray, ...]:
        """Per mode, the relative degree of each output with respect to the unknown input."""
        return tuple(r.relative_degrees for r in self.mode_reports)


class SwitchedLinearSystem:
    r"""The ``q`` modes :math:`(A_\sigma, B_\sigma, C_\sigma, D_\sigma)` of a linear switched system.

    Parameters
    ----------
    modes : sequence of LinearPlant
        At least one; all with the same state, control, output and unknown-input dimensions.
    names : sequence of str, optional
        Labels of the modes (default ``"mode 0"``, ...).
    tol : float
        Relative mismatch below which two modes count as the same (:func:`mode_mismatch`).
    """

    @check_keywords
    def __init__(self, modes: Sequence[LinearPlant], *, names: Sequence[str] | None = None, tol: float = 1e-9):
        if isinstance(modes, (str, bytes, LinearPlant)) or not isinstance(modes, Sequence):
            raise TypeError(f"expected modes as a sequence of LinearPlant, actual value: {type(modes).__name__}")
        if len(modes) == 0:
            raise ValueError("expected at least one mode in modes, actual value: an empty sequence")
        for i, m in enumerate(modes):
            if not isinstance(m, LinearPlant):
                raise TypeError(f"expected modes[{i}] to be a LinearPlant, actual value: {type(m).__name__}")
        dims = [(m.n, m.n_inputs, m.n_outputs, m.n_unknown) for m in modes]
        for i, d in enumerate(dims):
            if d != dims[0]:
                raise ValueError(
                    f"expected every mode with the dimensions of modes[0] (n, inputs, outputs, unknown inputs) = "
                    f"{dims[0]}, actual value: modes[{i}] has {d}"
                )
        self.modes = tuple(modes)
        names = [f"mode {i}" for i in range(len(modes))] if names is None else [str(s) for s in names]
        if len(names) != len(modes):
            raise ValueError(f"expected {len(modes)} mode names, actual value: {len(names)}")
        self.names = tuple(names)
        self.tol = check_positive("tol", tol)
        self._zoh: dict[tuple[int, float], tuple[np.ndarray, np.ndarray]] = {}

    @property
    def q(self) -> int:
        """Number of modes."""
        return len(self.modes)

    @property
    def n(self) -> int:
        return self.modes[0].n

    @property
    def n_inputs(self) -> int:
        return self.modes[0].n_inputs

    @property
    def n_outputs(self) -> int:
        return self.modes[0].n_outputs

    @property
    def n_unknown(self) -> int:
        return self.modes[0].n_unknown

    def conditions(self) -> SwitchedConditions:
        """Check conditions 1-3 of the module docstring; ``reason`` names the first that fails."""
        det = tuple(is_detectable(m.A, m.C) for m in self.modes)
        reps = tuple(m.strong_observability() for m in self.modes)
        q = self.q
        mis = np.zeros((q, q))
        for i in range(q):
            for j in range(i + 1, q):
                mis[i, j] = mis[j, i] = mode_mismatch(self.modes[i], self.modes[j])
        dist = mis > self.tol
        np.fill_diagonal(dist, True)
        reason = ""
        for i in range(q):
            if not det[i]:
                reason = f"detectability: (A, C) of {self.names[i]!r} is not detectable"
                break
            if not reps[i].ok:
                reason = f"strong observability: {self.names[i]!r} is not strongly observable: {reps[i].reason}"
                break
        if not reason:
            bad = [(i, j) for i in range(q) for j in range(i + 1, q) if not dist[i, j]]
            if bad:
                i, j = bad[0]
                reason = (
                    f"distinguishability: {self.names[i]!r} and {self.names[j]!r} have the same (A, B, C) "
                    f"(relative mismatch {mis[i, j]:.3g} <= tol {self.tol:g}); they differ at most in the "
                    "unknown-input matrix D, which no output with w = 0 reveals"
                )
        return SwitchedConditions(
            ok=not reason,
            reason=reason,
            names=self.names,
            detectable=det,
            mode_reports=reps,
            mismatch=mis,
            distinguishable=dist,
        )

    def require_observable(self) -> SwitchedConditions:
        """Conditions 1-2 (every mode detectable and strongly observable), or the typed error naming the mode."""
        c = self.conditions()
        if not all(c.detectable) or not all(c.strongly_observable):
            # conditions() checks mode by mode, detectability first: its reason names the first failing mode
            raise NotStronglyObservableError(
                "expected every mode detectable and strongly observable (continuous-state estimation in finite "
                f"time), actual value: {c.reason}"
            )
        return c

    def require_distinguishable(self) -> SwitchedConditions:
        """Conditions 1-3, or the typed error naming the failing condition and the modes."""
        c = self.require_observable()
        if not c.ok:
            raise NotDistinguishableError(f"expected pairwise distinguishable modes, actual value: {c.reason}")
        return c

    def discretize(self, mode: int, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Exact zero-order-hold ``(Phi, Gamma)`` of mode ``mode`` over ``dt``, ``Gamma`` acting on ``[u; w]``."""
        mode = check_int_in_range("mode", mode, 0, self.q - 1)
        key = (mode, float(dt))
        if key not in self._zoh:
            m = self.modes[mode]
            aug = LinearPlant(m.A, np.hstack([m.B, m.D]), m.C, m.D)
            self._zoh[key] = aug.discretize(check_positive("dt", dt))
        return self._zoh[key]

    def simulate(self, x0, sigma, dt: float, u=None, w=None, *, steps: int | None = None) -> tuple:
        r"""Exact sampled trajectory with ``sigma[k]``, ``u[k]`` and ``w[k]`` held over :math:`[t_k, t_{k+1})`.

        Parameters
        ----------
        x0 : array_like, shape (n,)
        sigma : array_like of int, shape (T,), or SwitchingSurface
            The modes (exogenous switching), or the rule that decides them from the state (autonomous switching:
            :math:`\sigma_k = \sigma(x_k)`, sampled; give ``steps``; the modes are returned as a third array).
        dt : float
        u : array_like, shape (T, inputs), optional (zero)
        w : array_like, shape (T, unknown inputs), optional (zero)

        Returns
        -------
        X : ndarray, shape (T + 1, n)
            ``X[k] = x(k dt)``.
        Y : ndarray, shape (T + 1, outputs)
            ``Y[k] = C_{sigma[k]} X[k]`` (the last sample uses ``sigma[T - 1]``).
        sigma : ndarray of int, shape (T,)
            With a switching surface only: the modes it decided.
        steps : int, optional
            ``T``, with a switching surface.

        Raises
        ------
        ValueError
            If ``x0``, ``u`` or ``w`` is not finite or of the wrong shape, or ``sigma`` is not a 1-D sequence of mode
            indices.
        DivergenceError
            If the trajectory leaves the floating-point range (e.g. an unstable mode over a huge ``dt``).
        """
        dt = check_positive("dt", dt)
        surface = sigma if isinstance(sigma, SwitchingSurface) else None
        if surface is not None:  # autonomous: the mode over [t_k, t_k+1) is decided by the state at t_k
            if steps is None:
                raise ValueError("expected steps (the number of samples) with a switching surface, actual value: None")
            T = check_int_in_range("steps", steps, 1, 2**31)
            sigma = np.zeros(T, dtype=int)
        else:
            sigma = self._check_sigma(sigma)
            T = sigma.shape[0]
        x = as_real_array("x0", x0).reshape(-1)
        if x.shape != (self.n,):
            raise ValueError(f"expected x0 with shape ({self.n},), actual value: shape {x.shape}")
        if not np.isfinite(x).all():
            raise ValueError(f"expected x0 finite, actual value: {x!r}")
        U = self._signal("u", u, T, self.n_inputs)
        W = self._signal("w", w, T, self.n_unknown)
        X = np.zeros((T + 1, self.n))
        Y = np.zeros((T + 1, self.n_outputs))
        X[0] = x
        for k in range(T):
            if surface is not None:
                if not np.isfinite(X[k]).all():  # the surface cannot place it: the escape is the error
                    raise _escaped(k, dt)
                sigma[k] = surface.mode(X[k])
            Phi, Gam = self.discretize(int(sigma[k]), dt)
            Y[k] = self.modes[sigma[k]].C @ X[k]
            X[k + 1] = Phi @ X[k] + Gam @ np.concatenate([U[k], W[k]])
        Y[T] = self.modes[sigma[T - 1]].C @ X[T]
        if not (np.isfinite(X).all() and np.isfinite(Y).all()):
            raise _escaped(int(np.argmin(np.isfinite(X).all(axis=1))), dt)
        return (X, Y, sigma) if surface is not None else (X, Y)

    def _check_sigma(self, sigma) -> np.ndarray:
        s = as_real_array("sigma", sigma)
        if s.ndim != 1:  # a 2-D array would be read row after row as one long schedule
            raise ValueError(f"expected sigma as a 1-D sequence of mode indices, actual value: shape {s.shape}")
        if s.size == 0 or np.any(s != np.round(s)) or np.any(s < 0) or np.any(s >= self.q):
            raise ValueError(
                f"expected sigma as a non-empty sequence of mode indices in 0..{self.q - 1}, actual value: "
                f"{np.unique(s)[:10]!r}"
            )
        return s.astype(int)

    @staticmethod
    def _signal(name: str, value, T: int, width: int, *, extra: int = 0) -> np.ndarray:
        """``value`` as shape ``(T, width)`` (zero if None); ``extra`` more rows are accepted and dropped."""
        if value is None:
            return np.zeros((T, width))
        arr = as_real_array(name, value)
        if arr.ndim == 1 and width == 1:
            arr = arr[:, None]
        if arr.ndim == 2 and T <= arr.shape[0] <= T + extra:
            arr = arr[:T]
        if arr.shape != (T, width):
            raise ValueError(f"expected {name} with shape ({T}, {width}), actual value: shape {arr.shape}")
        if not np.isfinite(arr).all():
            raise ValueError(f"expected {name} finite, actual value: {arr!r:.80}")
        return arr

    def __repr__(self) -> str:
        return f"SwitchedLinearSystem(q={self.q}, n={self.n}, names={list(self.names)})"


def _escaped(k: int, dt: float) -> DivergenceError:
    return DivergenceError(
        f"expected a finite trajectory, actual value: the state left the floating-point range by sample {k} (dt={dt!r})"
    )


def _per_mode_lipschitz(system: SwitchedLinearSystem, lipschitz) -> np.ndarray:
    """``lipschitz`` as shape ``(q, p)``: a scalar, one value per output, or one row per mode."""
    L = as_real_array("lipschitz", lipschitz)
    q, p = system.q, system.n_outputs
    if L.shape in ((), (1,), (p,)):
        L = np.broadcast_to(L.reshape(-1) if L.ndim else L, (q, p))
    elif L.shape != (q, p):
        raise ValueError(
            f"expected lipschitz as a scalar, shape ({p},) or shape ({q}, {p}), actual value: shape {L.shape}"
        )
    if not np.all(np.isfinite(L)) or np.any(L <= 0):
        raise ValueError(f"expected lipschitz > 0 and finite, actual value: {lipschitz!r}")
    return np.array(L, dtype=float)


def _bank(system, dt, lipschitz, alpha, poles) -> list[CascadedHOSMObserver]:
    L = _per_mode_lipschitz(system, lipschitz)
    return [CascadedHOSMObserver(m, dt, L[i], alpha=alpha, poles=poles) for i, m in enumerate(system.modes)]


class SwitchedHOSMObserver:
    r"""Continuous-state observer of a switched system whose mode :math:`\sigma` is known (exogenous, measured).

    One :class:`~smo_gym.control.CascadedHOSMObserver` per mode; only the active mode's observer runs. When the
    mode changes at sample ``k`` the new mode's observer restarts

    * ``on_switch="continue"`` (default; the slides' reset equations): at the prior carried across the switch,
      :math:`\tilde x_k^- = \Phi_{old}\hat x_{k-1} + \Gamma_{old}u_{k-1}`, with the differentiator at zero output
      error (:math:`\nu = 0`). When the estimate before the switch was exact it stays exact;
    * ``on_switch="restart"``: from the output alone (:math:`\tilde x = C^+ y_k`), as if nothing were known;
      exact again after the differentiator's finite convergence time, which must be shorter than the dwell time.

    Parameters
    ----------
    system : SwitchedLinearSystem
        Every mode must be strongly observable (raises :class:`~smo_gym.control.NotStronglyObservableError`).
    dt : float
        Sampling step.
    lipschitz : float or array_like, shape (p,) or (q, p)
        Per mode, the bound on the ``(k+1)``-th derivative of the output error
        (:func:`~smo_gym.control.output_error_lipschitz`).
    alpha : int
        Smoothness exploited by each cascade (see :class:`~smo_gym.control.CascadedHOSMObserver`).
    poles : array_like, optional
        Continuous-time poles of the Luenberger stages.
    on_switch : {"continue", "restart"}

    Attributes
    ----------
    observers : list of CascadedHOSMObserver
    mode : int
        The mode of the last sample.
    x_hat : ndarray, shape (n,)
    switch_samples : list of int
        Samples (counted from the reset, which is sample 0) at which the mode changed.
    """

    @check_keywords
    def __init__(
        self, system: SwitchedLinearSystem, dt: float, lipschitz, *, alpha: int = 1, poles=None, on_switch="continue"
    ):
        if not isinstance(system, SwitchedLinearSystem):
            raise TypeError(f"expected a SwitchedLinearSystem, actual value: {type(system).__name__}")
        system.require_observable()
        self.system = system
        self.dt = check_positive("dt", dt)
        self.on_switch = check_choice("on_switch", on_switch, ("continue", "restart"))
        self.observers = _bank(system, self.dt, lipschitz, alpha, poles)
        self.mode: int | None = None
        self.x_hat = None
        self.switch_samples: list[int] = []
        self._carry = None
        self._k = 0

    def reset(self, y0, mode: int, x_hat0=None) -> np.ndarray:
        """Start in ``mode`` at the sample ``y0`` (estimate ``x_hat0``, default ``C^+ y0``); return the estimate."""
        mode = check_int_in_range("mode", mode, 0, self.system.q - 1)
        self.observers[mode].reset(y0, x_hat0)
        self.x_hat = self.observers[mode].update(y0)
        self.mode, self.switch_samples, self._k, self._carry = mode, [], 0, None  # once the sample was taken
        return self.x_hat

    def update(self, y, mode: int) -> np.ndarray:
        r"""Process the sample ``y_k`` taken in ``mode`` (the mode over :math:`[t_k, t_{k+1})`); return
        :math:`\hat x_k`."""
        if self.mode is None:
            raise RuntimeError("expected reset(y0, mode) before update(y, mode), actual value: never reset")
        if self._carry is None:
            raise RuntimeError("expected advance(u) after each update, actual value: update called twice in a row")
        mode = check_int_in_range("mode", mode, 0, self.system.q - 1)
        if mode != self.mode:  # the new mode's observer starts here; it is the active one once it took the sample
            y = _output_sample("y", y, self.system.n_outputs)  # named y here, not as the restart's y0
            self.observers[mode].reset(y, self._carry if self.on_switch == "continue" else None)
        self.x_hat = self.observers[mode].update(y)
        self._k += 1
        if mode != self.mode:
            self.switch_samples.append(self._k)
            self.mode = mode
        self._carry = None
        return self.x_hat

    def switch(self, mode: int, y, x_hat) -> np.ndarray:
        """Make ``mode`` the active mode at the sample ``y`` just processed, its observer started at the estimate
        ``x_hat`` (the slides' reset); for a mode decided after the sample, as in autonomous switching."""
        if self.mode is None:
            raise RuntimeError("expected reset(y0, mode) before switch(...), actual value: never reset")
        mode = check_int_in_range("mode", mode, 0, self.system.q - 1)
        y = _output_sample("y", y, self.system.n_outputs)  # named y and x_hat here, not as the restart's y0, x_hat0
        x_hat = _output_sample("x_hat", x_hat, self.system.n, "state")
        self.observers[mode].reset(y, x_hat)
        self.x_hat = self.observers[mode].update(y)  # the sample is consumed: predict from it at the next advance
        self.mode = mode
        self.switch_samples.append(self._k)
        return self.x_hat

    def advance(self, u=None) -> None:
        """Predict to the next sample with the control ``u`` (default zero) held over the interval."""
        if self.mode is None:
            raise RuntimeError("expected reset(y0, mode) before advance(u), actual value: never reset")
        # a string or a bool is refused, not converted to a number
        u = np.zeros(self.system.n_inputs) if u is None else _output_sample("u", u, self.system.n_inputs, "input")
        self.observers[self.mode].advance(u)
        Phi, Gam = self.system.discretize(self.mode, self.dt)
        self._carry = Phi @ self.x_hat + Gam[:, : self.system.n_inputs] @ u

    def run(self, Y, sigma, U=None, x_hat0=None) -> np.ndarray:
        """Reset at ``Y[0]`` in ``sigma[0]`` and process ``Y[1:]``; ``U[k]``, ``sigma[k]`` act over
        ``[t_k, t_{k+1})`` (``Y``: shape ``(T, p)``; ``sigma``, ``U``: ``T`` or ``T - 1`` rows). Returns ``X_hat``,
        shape ``(T, n)``."""
        Y = as_real_array("Y", Y)
        sigma = self.system._check_sigma(sigma)
        if Y.ndim != 2 or Y.shape[0] < 1 or Y.shape[1] != self.system.n_outputs or sigma.shape[0] < Y.shape[0] - 1:
            raise ValueError(
                f"expected Y with shape (T >= 1, {self.system.n_outputs}) and sigma with at least T - 1 entries, "
                f"actual value: Y shape {Y.shape}, sigma length {sigma.shape[0]}"
            )
        T = Y.shape[0]
        U = SwitchedLinearSystem._signal("U", U, T - 1, self.system.n_inputs, extra=1)
        X = np.zeros((T, self.system.n))
        X[0] = self.reset(Y[0], int(sigma[0]), x_hat0)
        for k in range(1, T):
            self.advance(U[k - 1])
            X[k] = self.update(Y[k], int(sigma[k] if k < sigma.shape[0] else sigma[-1]))
        return X


@dataclass(frozen=True)
class SwitchedEstimate:
    r"""What :class:`SwitchedObserverBank` concluded about a record.

    Attributes
    ----------
    modes : ndarray of int, shape (T,)
        Estimated mode :math:`\hat\sigma` at each sample (sample 0 is the reset).
    switch_times : ndarray, shape (s,)
        Estimated switching instants [s]: when the old mode's residual left the band.
    detection_times : ndarray, shape (s,)
        When each switch was decided [s] (the end of the new mode's dwell window).
    new_modes : ndarray of int, shape (s,)
        The mode switched to.
    residual_norms : ndarray, shape (T, q)
        Normalized residual :math:`\sqrt{\overline{\|r_j\|^2}}/\theta` of every mode (band: ``<= 1``).
    x_hat : ndarray, shape (T, n)
        The estimated mode's continuous-state estimate.
    dt : float
    """

    modes: np.ndarray
    switch_times: np.ndarray
    detection_times: np.ndarray
    new_modes: np.ndarray
    residual_norms: np.ndarray
    x_hat: np.ndarray
    dt: float


class _ModeDecision:
    """The band-and-dwell rule of the banks (module docstring), on the squared residual norms of each mode.

    Filters the squared norms (first order, ``residual_time_constant``), normalizes their root by the band, and
    switches to the unique other mode whose residual stayed in the band for ``dwell`` once the current mode's has
    left it (not before ``settle_time``). Keeps the history the banks report.
    """

    def __init__(self, q: int, dt: float, threshold: float, dwell: float, settle_time: float, time_constant: float):
        self.q, self.dt, self.threshold = q, dt, threshold
        self.dwell_samples = max(1, math.ceil(dwell / dt - 1e-9))
        self.settle_samples = math.ceil(settle_time / dt - 1e-9)
        self.gain = dt / (time_constant + dt)  # implicit Euler of the low-pass filter
        self.mode: int | None = None

    def reset(self, mode: int) -> None:
        self.mode, self.k, self.exit = mode, 0, None
        self.mean_square = np.zeros(self.q)
        self.runs = np.zeros(self.q, dtype=int)
        self.rho = np.zeros(self.q)
        self.switches: list[tuple[float, float, int]] = []
        self.modes, self.rhos = [mode], [np.zeros(self.q)]

    def step(self, squared_norms: np.ndarray) -> bool:
        """One sample; returns whether the mode switched (then :attr:`mode` is the new one)."""
        self.k += 1
        # mean square over the filter's memory (the slides' squared injection): a wrong model's mismatch changes
        # sign along the trajectory, and its instantaneous value passing through zero must not look like a fit
        self.mean_square += self.gain * (squared_norms - self.mean_square)
        self.rho = np.sqrt(self.mean_square) / self.threshold
        switched = self.k >= self.settle_samples and self._decide()
        self.modes.append(self.mode)
        self.rhos.append(self.rho)
        return switched

    def _decide(self) -> bool:
        inside = self.rho <= 1.0
        self.runs = np.where(inside, self.runs + 1, 0)
        if inside[self.mode]:
            self.exit = None
            return False
        if self.exit is None:
            self.exit = self.k
        cand = [j for j in range(self.q) if j != self.mode and self.runs[j] >= self.dwell_samples]
        if len(cand) != 1:
            return False
        self.switches.append((self.exit * self.dt, self.k * self.dt, cand[0]))
        self.mode, self.exit = cand[0], None
        return True

    def restart(self) -> None:
        """Forget the filtered residuals and the runs (after the observers were restarted at a switch)."""
        self.mean_square[:] = 0.0
        self.runs[:] = 0

    def estimate(self, x_hat: list) -> SwitchedEstimate:
        sw = np.array(self.switches, dtype=float).reshape(-1, 3)
        return SwitchedEstimate(
            modes=np.array(self.modes, dtype=int),
            switch_times=sw[:, 0],
            detection_times=sw[:, 1],
            new_modes=sw[:, 2].astype(int),
            residual_norms=np.array(self.rhos),
            x_hat=np.array(x_hat),
            dt=self.dt,
        )


class SwitchedObserverBank:
    r"""Bank of cascaded HOSM observers estimating the continuous state *and* the unknown mode (module docstring).

    Parameters
    ----------
    system : SwitchedLinearSystem
        Must satisfy conditions 1-3 (raises :class:`~smo_gym.control.NotStronglyObservableError` or
        :class:`NotDistinguishableError` naming the failing condition).
    dt : float
    lipschitz : float or array_like, shape (p,) or (q, p)
        Of each observer (must also cover what a wrong model misses, the mismatch, for the wrong observers to stay
        bounded).
    threshold : float
        :math:`\theta > 0`: the band :math:`\|r_j\|_2 \le \theta` of the residuals (units of :math:`\dot x`). Noise
        free, the active mode's residual is the sampling error; with noise, calibrate it on runs with a known mode.
    initial_mode : int
        :math:`\sigma(0)`, known (the slides' assumption 3).
    dwell : float
        How long [s] the new mode's residual must stay in the band before a switch is decided.
    settle_time : float
        No decision before this time [s] (the observers' convergence from the initial estimate).
    residual_time_constant : float
        Time constant [s] of the first-order filter of the squared residuals (0: none): the decision compares the
        root mean square :math:`\sqrt{\overline{\|r_j\|^2}}` over about this time with the band.
    alpha : int
    poles : array_like, optional
    reset_on_switch : bool
        Restart every observer from the new mode's estimate at each detection (the slides' reset equations).

    Attributes
    ----------
    observers : list of CascadedHOSMObserver
    mode : int
        Current mode estimate.
    residuals : ndarray, shape (q, n)
        The equivalent injections :math:`r_j` of the last sample (unfiltered).
    residual_norms : ndarray, shape (q,)
        The normalized filtered residuals :math:`\rho_j` of the last sample (band: ``<= 1``).
    """

    @check_keywords
    def __init__(
        self,
        system: SwitchedLinearSystem,
        dt: float,
        lipschitz,
        *,
        threshold: float,
        initial_mode: int = 0,
        dwell: float = 0.02,
        settle_time: float = 0.0,
        residual_time_constant: float = 0.0,
        alpha: int = 1,
        poles=None,
        reset_on_switch: bool = True,
    ):
        if not isinstance(system, SwitchedLinearSystem):
            raise TypeError(f"expected a SwitchedLinearSystem, actual value: {type(system).__name__}")
        if system.q < 2:
            raise ValueError(f"expected at least 2 modes for mode estimation, actual value: {system.q}")
        self.conditions = system.require_distinguishable()
        self.system = system
        self.dt = check_positive("dt", dt)
        self.threshold = check_positive("threshold", threshold)
        self.initial_mode = check_int_in_range("initial_mode", initial_mode, 0, system.q - 1)
        self.dwell = check_positive("dwell", dwell)
        self.settle_time = check_nonnegative("settle_time", settle_time)
        self.residual_time_constant = check_nonnegative("residual_time_constant", residual_time_constant)
        self.reset_on_switch = check_bool("reset_on_switch", reset_on_switch)
        self.observers = _bank(system, self.dt, lipschitz, alpha, poles)
        self._rule = _ModeDecision(
            system.q, self.dt, self.threshold, self.dwell, self.settle_time, self.residual_time_constant
        )
        self.mode: int | None = None
        self.residuals = None
        self.residual_norms = None
        self._x_history = None

    def reset(self, y0, x_hat0=None) -> np.ndarray:
        """Start every observer at the sample ``y0`` (estimate ``x_hat0``, default ``C^+ y0``) in the initial mode."""
        for obs in self.observers:
            obs.reset(y0, x_hat0)
            obs.update(y0)  # the differentiator consumes the sample it was reset at
        self._rule.reset(self.initial_mode)
        self.mode = self.initial_mode
        self.residuals = np.zeros((self.system.q, self.system.n))
        self.residual_norms = np.zeros(self.system.q)
        x = self.observers[self.mode].x_hat
        self._x_history = [x.copy()]
        return x

    def _residual(self, j: int) -> np.ndarray:
        obs = self.observers[j]
        return obs.e_hat_derivatives[1] - self.system.modes[j].A @ obs.e_hat_derivatives[0]

    def update(self, y) -> np.ndarray:
        """Process the sample ``y_k``; return the estimated mode's :math:`\\hat x_k` (the mode is :attr:`mode`)."""
        if self._x_history is None:
            raise RuntimeError("expected reset(y0) before update(y), actual value: the bank was never reset")
        for obs in self.observers:
            obs.update(y)
        self.residuals = np.stack([self._residual(j) for j in range(self.system.q)])
        if self._rule.step(np.sum(self.residuals**2, axis=1)):
            self.mode = self._rule.mode
            if self.reset_on_switch:
                x = self.observers[self.mode].x_hat.copy()
                for obs in self.observers:
                    obs.reset(y, x)
                    obs.update(y)  # the sample is consumed: predict from it at the next advance
                self._rule.restart()
        self.residual_norms = self._rule.rho
        x = self.observers[self.mode].x_hat
        self._x_history.append(x.copy())
        return x

    @property
    def switches(self) -> tuple[tuple[float, float, int], ...]:
        """``(switching instant [s], decision time [s], new mode)`` of every switch decided since :meth:`reset`."""
        if self._x_history is None:
            raise RuntimeError("expected reset(y0) before switches, actual value: the bank was never reset")
        return tuple(self._rule.switches)

    def advance(self, u=None) -> None:
        """Predict every observer to the next sample with the control ``u`` (default zero)."""
        if self._x_history is None:
            raise RuntimeError("expected reset(y0) before advance(u), actual value: the bank was never reset")
        u = np.zeros(self.system.n_inputs) if u is None else u
        for obs in self.observers:
            obs.advance(u)

    def result(self) -> SwitchedEstimate:
        """Everything processed since :meth:`reset` (time 0 is the reset sample)."""
        if self._x_history is None:
            raise RuntimeError("expected reset(y0) before result(), actual value: the bank was never reset")
        return self._rule.estimate(self._x_history)

    def run(self, Y, U=None, x_hat0=None) -> SwitchedEstimate:
        """Reset at ``Y[0]`` and process ``Y[1:]`` (shape ``(T, p)``) with ``U[k]`` held over ``[t_k, t_{k+1})``
        (``U``: ``T`` or ``T - 1`` rows)."""
        Y = as_real_array("Y", Y)
        if Y.ndim != 2 or Y.shape[1] != self.system.n_outputs or Y.shape[0] < 2:
            raise ValueError(f"expected Y with shape (T >= 2, {self.system.n_outputs}), actual value: shape {Y.shape}")
        T = Y.shape[0]
        U = None if U is None else SwitchedLinearSystem._signal("U", U, T - 1, self.system.n_inputs, extra=1)
        self.reset(Y[0], x_hat0)
        for k in range(1, T):
            self.advance(None if U is None else U[k - 1])
            self.update(Y[k])
        return self.result()


class NonlinearSwitchedObserverBank:
    r"""Continuous and discrete state of a *nonlinear* switched system, mode unknown (Davila, Rios and Fridman
    2012; Rios, Davila and Fridman 2012): a bank of HOSM observers, the mode from their input reconstructions.

    Mode ``j`` is :math:`\dot x = f_j(x) + d_j(x)w,\ y = h_j(x)`; its observer is a
    :class:`smo_gym.nonlinear_observers.NonlinearHOSMObserver` with ``unknown_input`` :math:`d_j`, which
    reconstructs the input that model ``j`` needs to explain the measured output,
    :math:`\hat w_j = B_j(\hat x_j)^+\big(\hat y^{(r)} - L_{f_j}^{r}h_j(\hat x_j)\big)`. With :math:`w = 0` (the
    slides' assumption for the discrete state) it vanishes for the active mode, up to the differentiator's
    accuracy, and equals the model mismatch for the others: the nonlinear counterpart of the equivalent injection
    of :class:`SwitchedObserverBank`, and the mode follows the same band-and-dwell rule on
    :math:`\|\hat w_j\|`.

    Parameters
    ----------
    observers : sequence of NonlinearHOSMObserver
        One per mode, each with ``unknown_input`` (the same output, sampling step and differentiator settings).
    threshold : float
        :math:`\theta > 0`: the band :math:`\|\hat w_j\| \le \theta` (units of ``w``).
    names : sequence of str, optional
    initial_mode, dwell, settle_time, residual_time_constant, reset_on_switch :
        As for :class:`SwitchedObserverBank`.

    Attributes
    ----------
    mode : int
    x_hat : ndarray, shape (n,)
        The estimated mode's estimate.
    residual_norms : ndarray, shape (q,)
    """

    @check_keywords
    def __init__(
        self,
        observers,
        *,
        threshold: float,
        names: Sequence[str] | None = None,
        initial_mode: int = 0,
        dwell: float = 0.02,
        settle_time: float = 0.0,
        residual_time_constant: float = 0.0,
        reset_on_switch: bool = True,
    ):
        from ..nonlinear_observers import NonlinearHOSMObserver

        observers = list(observers)
        if len(observers) < 2 or not all(isinstance(o, NonlinearHOSMObserver) for o in observers):
            raise TypeError(
                "expected at least two NonlinearHOSMObserver (one per mode), actual value: "
                f"{[type(o).__name__ for o in observers]}"
            )
        if not all(o.reconstructs_input for o in observers):
            raise ValueError(
                "expected observers built with unknown_input (their input reconstruction is the residual), actual "
                f"value: modes {[j for j, o in enumerate(observers) if not o.reconstructs_input]} have none"
            )
        first = observers[0]
        if any(o.n != first.n or o.dt != first.dt or o.indices != first.indices for o in observers):
            raise ValueError("expected observers with the same state size, sampling step and observability indices")
        self.observers = observers
        self.q = len(observers)
        self.names = tuple(f"mode{j}" for j in range(self.q)) if names is None else tuple(names)
        if len(self.names) != self.q:
            raise ValueError(f"expected {self.q} names, actual value: {len(self.names)}")
        self.dt = first.dt
        self.threshold = check_positive("threshold", threshold)
        self.initial_mode = check_int_in_range("initial_mode", initial_mode, 0, self.q - 1)
        self.reset_on_switch = check_bool("reset_on_switch", reset_on_switch)
        self._rule = _ModeDecision(
            self.q,
            self.dt,
            self.threshold,
            check_positive("dwell", dwell),
            check_nonnegative("settle_time", settle_time),
            check_nonnegative("residual_time_constant", residual_time_constant),
        )
        self.mode: int | None = None
        self.x_hat = None
        self.residual_norms = None
        self._x_history = None

    def reset(self, y0, x0) -> np.ndarray:
        """Start every observer at the sample ``y0`` with the state guess ``x0``, in the initial mode."""
        for obs in self.observers:
            obs.reset(y0, x0)
        self._rule.reset(self.initial_mode)
        self.mode = self.initial_mode
        self.residual_norms = np.zeros(self.q)
        self.x_hat = self.observers[self.mode].state.copy()
        self._x_history = [self.x_hat.copy()]
        return self.x_hat

    def update(self, y) -> np.ndarray:
        """Process the sample ``y_k``; return the estimated mode's :math:`\\hat x_k` (the mode is :attr:`mode`)."""
        if self._x_history is None:
            raise RuntimeError("expected reset(y0, x0) before update(y), actual value: the bank was never reset")
        for obs in self.observers:
            obs.update(y)
        squared = np.array([float(np.sum(obs.input_estimate**2)) for obs in self.observers])
        if self._rule.step(squared):
            self.mode = self._rule.mode
            if self.reset_on_switch:  # every model restarts from the new mode's estimate (the slides' reset)
                x = self.observers[self.mode].state.copy()
                for obs in self.observers:
                    obs.reset(y, x)
                self._rule.restart()
        self.residual_norms = self._rule.rho
        self.x_hat = self.observers[self.mode].state.copy()
        self._x_history.append(self.x_hat.copy())
        return self.x_hat

    @property
    def switches(self) -> tuple[tuple[float, float, int], ...]:
        """``(switching instant [s], decision time [s], new mode)`` of every switch decided since :meth:`reset`."""
        if self._x_history is None:
            raise RuntimeError("expected reset(y0, x0) before switches, actual value: the bank was never reset")
        return tuple(self._rule.switches)

    def run(self, Y, x0) -> SwitchedEstimate:
        """Reset at ``Y[0]`` with the guess ``x0`` and process ``Y[1:]`` (shape ``(T, p)`` or ``(T,)``)."""
        Y = as_real_array("Y", Y)
        Y = Y.reshape(Y.shape[0], -1) if Y.ndim >= 1 and Y.shape[0] > 0 else Y
        if Y.ndim != 2 or Y.shape[0] < 2:
            raise ValueError(f"expected Y with shape (T >= 2, p), actual value: shape {Y.shape}")
        self.reset(Y[0], x0)
        for k in range(1, Y.shape[0]):
            self.update(Y[k])
        return self._rule.estimate(self._x_history)


class SwitchingSurface:
    r"""Autonomous switching: the mode is decided by the state through intervals of :math:`Hx` (the slides' (29)).

    .. math:: \sigma = \mathrm{modes}[i]\quad\text{for}\quad Hx \in (e_{i-1}, e_i],\qquad
              e_0 = -\infty,\ e_q = +\infty .

    Parameters
    ----------
    H : array_like, shape (n,)
        The row :math:`H` (the slides' :math:`H \in \mathbb R^{1\times n}`, known).
    edges : array_like, shape (r,)
        Increasing interior edges :math:`e_1 < \dots < e_r` of the ``r + 1`` disjoint intervals
        :math:`\mathcal H_i`.
    modes : sequence of int, shape (r + 1,)
        The mode of each interval, from :math:`-\infty` up.
    """

    def __init__(self, H, edges, modes):
        self.H = as_real_array("H", H, copy=True).reshape(-1)
        self.edges = as_real_array("edges", edges, copy=True).reshape(-1)
        # each an integer: a float would be truncated, a bool read as 0 or 1
        self.modes = np.array([check_int_at_least("modes", m, 0) for m in np.asarray(modes, dtype=object).reshape(-1)])
        if not np.all(np.isfinite(self.H)) or not np.any(self.H):
            raise ValueError(f"expected a finite, nonzero H, actual value: {self.H!r}")
        if not np.all(np.isfinite(self.edges)) or np.any(np.diff(self.edges) <= 0):
            raise ValueError(f"expected finite, strictly increasing edges, actual value: {self.edges!r}")
        if self.modes.shape != (self.edges.size + 1,) or np.any(self.modes < 0):
            raise ValueError(
                f"expected {self.edges.size + 1} non-negative mode indices (one per interval), actual value: {modes!r}"
            )

    def mode(self, x) -> int:
        """The mode of the state ``x`` (shape ``(n,)``).

        Raises
        ------
        ValueError
            If ``x`` is not finite (it lies in no interval) or not of shape ``(n,)``.
        """
        x = as_real_array("x", x)
        if x.shape != self.H.shape:
            raise ValueError(f"expected x with shape {self.H.shape}, actual value: shape {x.shape}")
        hx = float(self.H @ x)
        if not math.isfinite(hx):
            raise ValueError(f"expected x finite, actual value: {x!r}")
        return int(self.modes[np.searchsorted(self.edges, hx, side="left")])

    def condition(self, system: SwitchedLinearSystem) -> tuple[bool, str]:
        r"""The slides' condition for exact, finite-time discrete-state estimation from :math:`H\hat x`:

        .. math:: \mathcal V^*_\sigma \subset \ker Q_\sigma,\qquad
                  Q_\sigma = [H;\ HA_\sigma;\ \dots;\ HA_\sigma^{n-1}],

        for every mode (:math:`\mathcal V^*_\sigma` the weakly unobservable subspace, the kernel of Molinari's
        ``M``): what the HOSM observer cannot recover never moves :math:`Hx` or its derivatives. It holds whenever
        every mode is strongly observable (:math:`\mathcal V^* = \{0\}`). Returns ``(ok, reason)``.
        """
        if self.H.shape != (system.n,):
            raise ValueError(f"expected H with {system.n} entries, actual value: {self.H.shape}")
        if self.modes.max() >= system.q:
            raise ValueError(f"expected modes in 0..{system.q - 1}, actual value: {self.modes.tolist()}")
        from .plants import molinari_decoupling

        for j, m in enumerate(system.modes):
            M = molinari_decoupling(m.A, m.C, m.D).M
            _, sv, Vh = np.linalg.svd(M) if M.size else (None, np.zeros(0), np.eye(system.n))
            rank = int(np.sum(sv > RANK_TOL * max(sv.max(initial=0.0), 1.0)))
            V = Vh[rank:].T  # basis of the weakly unobservable subspace
            if V.size == 0:
                continue
            Q = np.vstack([_unit(self.H) @ np.linalg.matrix_power(_unit(m.A), i) for i in range(system.n)])
            leak = np.abs(Q @ V).max()
            if leak > 1e-9 * max(np.abs(Q).max(), 1.0):
                return False, (
                    f"mode {system.names[j]!r}: its weakly unobservable subspace (dimension {V.shape[1]}) is not in "
                    f"ker Q (|Q V| = {leak:.3g}): H x depends on what the observer cannot recover"
                )
        return True, ""

    def __repr__(self) -> str:
        return f"SwitchingSurface(H={self.H.tolist()}, edges={self.edges.tolist()}, modes={self.modes.tolist()})"


class AutonomousSwitchedObserver:
    r"""Continuous and discrete state of a switched system whose switching is autonomous (Fridman's slides,
    section 10, "autonomous switchings"; Rios, Davila and Fridman 2012).

    The discrete-state observer is the switching rule applied to the estimate,
    :math:`\hat\sigma = \sigma(H\hat x)` (:class:`SwitchingSurface`): under the condition of
    :meth:`SwitchingSurface.condition` it is exact once the continuous estimate is, i.e. in finite time. One
    cascaded HOSM observer per mode; the active one processes each sample with the mode that acted over the last
    interval, then the rule decides the mode of the next interval from its estimate, and at a change the new
    mode's observer starts from that estimate (the slides' reset, :math:`\nu = 0`).

    Parameters
    ----------
    system : SwitchedLinearSystem
        Every mode strongly observable (:class:`~smo_gym.control.NotStronglyObservableError` otherwise).
    surface : SwitchingSurface
    dt : float
    lipschitz : float or array_like, shape (p,) or (q, p)
        As for :class:`SwitchedHOSMObserver`.
    alpha : int
    poles : array_like, optional

    Attributes
    ----------
    mode : int
        :math:`\hat\sigma` for the next interval.
    x_hat : ndarray, shape (n,)
    switch_times : list of float
        Times [s] (from the reset) at which the estimated mode changed.

    Notes
    -----
    The continuous state is a :class:`SwitchedHOSMObserver` told the mode the rule decides, switched by
    :meth:`SwitchedHOSMObserver.switch` after the sample that decided it.
    """

    @check_keywords
    def __init__(
        self, system: SwitchedLinearSystem, surface: SwitchingSurface, dt: float, lipschitz, *, alpha: int = 1,
        poles=None,
    ):  # fmt: skip
        if not isinstance(system, SwitchedLinearSystem):
            raise TypeError(f"expected a SwitchedLinearSystem, actual value: {type(system).__name__}")
        if not isinstance(surface, SwitchingSurface):
            raise TypeError(f"expected a SwitchingSurface, actual value: {type(surface).__name__}")
        # the continuous state: the known-mode observer, told the mode the rule decides (and its checks)
        self._known = SwitchedHOSMObserver(system, dt, lipschitz, alpha=alpha, poles=poles)
        ok, reason = surface.condition(system)
        if not ok:  # unreachable under strong observability, kept for the statement's sake
            raise NotStronglyObservableError(f"expected V*_sigma inside ker Q_sigma, actual value: {reason}")
        self.system, self.surface, self.dt = system, surface, self._known.dt

    @property
    def mode(self) -> int | None:
        return self._known.mode

    @property
    def x_hat(self) -> np.ndarray | None:
        return self._known.x_hat

    @property
    def switch_times(self) -> list[float]:
        return [k * self.dt for k in self._known.switch_samples]

    def reset(self, y0, x_hat0=None, mode: int | None = None) -> np.ndarray:
        """Start at the sample ``y0`` (estimate ``x_hat0``, default ``C^+ y0``) in ``mode`` (default: the rule
        applied to the initial estimate)."""
        m0 = self.surface.mode(np.zeros(self.system.n) if x_hat0 is None else np.asarray(x_hat0, float))
        return self._known.reset(y0, m0 if mode is None else mode, x_hat0)

    def update(self, y) -> np.ndarray:
        """Process the sample ``y_k``; return :math:`\\hat x_k` and set :attr:`mode` for the next interval."""
        if self._known.mode is None:
            raise RuntimeError("expected reset(y0) before update(y), actual value: never reset")
        x_hat = self._known.update(y, self._known.mode)  # the mode that acted over the last interval
        new = self.surface.mode(x_hat)
        return x_hat if new == self._known.mode else self._known.switch(new, y, x_hat)

    def advance(self, u=None) -> None:
        """Predict to the next sample with the control ``u`` (default zero) in the estimated mode."""
        if self._known.mode is None:
            raise RuntimeError("expected reset(y0) before advance(u), actual value: never reset")
        self._known.advance(u)

    def run(self, Y, U=None, x_hat0=None) -> tuple[np.ndarray, np.ndarray]:
        """Reset at ``Y[0]`` and process ``Y[1:]`` with ``U[k]`` held over ``[t_k, t_{k+1})``. Returns ``(X_hat,
        modes)``: the estimates ``(T, n)`` and the estimated mode of each interval ``(T,)``."""
        Y = as_real_array("Y", Y)
        if Y.ndim != 2 or Y.shape[1] != self.system.n_outputs or Y.shape[0] < 2:
            raise ValueError(f"expected Y with shape (T >= 2, {self.system.n_outputs}), actual value: shape {Y.shape}")
        T = Y.shape[0]
        U = SwitchedLinearSystem._signal("U", U, T - 1, self.system.n_inputs, extra=1)
        X, modes = np.zeros((T, self.system.n)), np.zeros(T, dtype=int)
        X[0], modes[0] = self.reset(Y[0], x_hat0), self.mode
        for k in range(1, T):
            self.advance(U[k - 1])
            X[k], modes[k] = self.update(Y[k]), self.mode
        return X, modes


@dataclass(frozen=True)
class ModeMetrics:
    """Comparison of an estimated mode sequence with the true one (:func:`mode_metrics`)."""

    accuracy: float
    delays: np.ndarray
    missed: int
    false_switches: int
    #: ``(time [s], from mode, to mode)`` of each missed true switch
    missed_switches: tuple[tuple[float, int, int], ...] = ()


def mode_metrics(estimate: SwitchedEstimate, sigma, *, start: float = 0.0) -> ModeMetrics:
    r"""Score an estimated mode sequence against the true one.

    Parameters
    ----------
    estimate : SwitchedEstimate
    sigma : array_like of int, shape (T,)
        True mode at each sample of the record (``sigma[k]`` over :math:`[t_k, t_{k+1})`).
    start : float
        Score from this time [s] on (e.g. after the settle time).

    Returns
    -------
    ModeMetrics
        ``accuracy``: fraction of samples from ``start`` with the right mode; ``delays``: for each true switch
        after ``start``, the time from it to the first detection of the new mode before the next true switch
        (missed switches are left out and counted in ``missed``); ``false_switches``: detections that match no
        true switch.

    Raises
    ------
    ValueError
        If ``sigma`` is not a sequence of ``T`` mode indices (non-negative integers), or ``start`` is not before the
        record's end.
    """
    if not isinstance(estimate, SwitchedEstimate):
        raise TypeError(f"expected a SwitchedEstimate, actual value: {type(estimate).__name__}")
    s = as_real_array("sigma", sigma)
    T = estimate.modes.shape[0]
    if s.shape != (T,):
        raise ValueError(f"expected sigma with {T} samples (one per estimate), actual value: shape {s.shape}")
    if not (np.isfinite(s).all() and np.all(s == np.round(s)) and np.all(s >= 0)):  # int() would truncate them
        raise ValueError(f"expected sigma as mode indices (integers >= 0), actual value: {np.unique(s)[:10]!r}")
    s = s.astype(int)
    dt = estimate.dt
    start = check_nonnegative("start", start)
    k0 = math.ceil(start / dt - 1e-9)
    if k0 >= T:  # nothing left to score: the accuracy would be the mean of no samples
        raise ValueError(f"expected start < {T * dt:g} (the record's end), actual value: {start!r}")
    acc = float(np.mean(estimate.modes[k0:] == s[k0:]))
    true_k = [k for k in range(1, T) if s[k] != s[k - 1] and k >= k0]
    bounds = true_k + [T]
    used = np.zeros(estimate.detection_times.shape[0], dtype=bool)
    delays, missed = [], []
    for i, k in enumerate(true_k):
        t0, t1 = k * dt, bounds[i + 1] * dt
        hit = np.flatnonzero(
            (estimate.detection_times >= t0 - 1e-12)
            & (estimate.detection_times < t1)
            & (estimate.new_modes == s[k])
            & ~used
        )
        if hit.size:
            used[hit[0]] = True
            delays.append(float(estimate.detection_times[hit[0]] - t0))
        else:
            missed.append((k * dt, int(s[k - 1]), int(s[k])))
    false = int(np.sum(~used & (estimate.detection_times >= k0 * dt)))
    return ModeMetrics(
        accuracy=acc, delays=np.array(delays), missed=len(missed), false_switches=false, missed_switches=tuple(missed)
    )
