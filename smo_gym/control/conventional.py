r"""Conventional (first-order) sliding-mode observers and the unknown-input observer without differentiation.

Fridman's slides, section 1, for the linear plant

.. math:: \dot x = A x + B u + D w,\qquad y = C x,

``x`` in :math:`\mathbb R^n`, ``u`` in :math:`\mathbb R^q` (known), ``w`` in :math:`\mathbb R^m` (unknown, possibly
absent), ``y`` in :math:`\mathbb R^p`, ``C`` of full row rank.

:class:`UtkinObserver`
    the simple sliding-mode observer (Utkin 1992; the slides' "Drakunov-Utkin observer") in the coordinates where
    :math:`C = [0\ I_p]`, with the equivalent output injection recovered by a first-order low-pass filter.
:class:`StepByStepObserver`
    Drakunov's (1992) step-by-step observer on the observable block (Hessenberg) form: the equivalent injection of
    each step is the "measurement" of the next, finite-time exact.
:class:`WalcottZakObserver` and :func:`walcott_zak_design`
    Walcott and Zak's (1987) observer for matched bounded unknown inputs, gains from the Lyapunov/LMI conditions in
    the form of Edwards and Spurgeon (1994), solved with cvxpy and re-verified in NumPy.
:class:`UnknownInputObserver`
    the full-order linear unknown-input observer of Darouach, Zasadzinski and Xu (1994): state reconstruction
    without differentiation whatever ``w`` is, under Hautus's (1983) strong* detectability.
:func:`unknown_input_conditions`
    the existence conditions of the last two (the observer-matching condition ``rank(CD) = rank(D)`` and minimum
    phase), as a report; the observers raise :class:`UnknownInputConditionError` naming the failing condition.

Sampled-data form
-----------------
Every observer here is a sampled-data object with the interface of :class:`~smo_gym.control.LuenbergerObserver`:
``reset(y0)``, ``update(y_k)`` (correct with the sample, return :math:`\hat x_k`) and ``advance(u_k)`` (predict to
the next sample with the control held), plus ``run(y, u)`` for a recorded sequence. Estimates carry any leading
batch dimensions of ``y``: ``y`` of shape ``(..., p)`` gives :math:`\hat x` of shape ``(..., n)``. The discontinuous
injections act at the samples, with weight ``dt``, either

``"implicit"`` (default)
    the set-valued implicit Euler step: the sign is replaced by the value in :math:`[-\rho, \rho]` that puts the
    corrected output estimate on the measurement when that is reachable in one step (a clip; Acary and Brogliato
    2010). In sliding mode the injection *is* its equivalent value, without chattering or filter lag;
``"euler"``
    the explicit step :math:`\rho\,\mathrm{sign}(\cdot)`: chattering of amplitude :math:`\rho\,dt`, and the
    equivalent injection has to be recovered by the low-pass filter.

References
----------
.. [Utk92] V. I. Utkin, *Sliding Modes in Control and Optimization*, Springer, 1992.
.. [Dra92] S. V. Drakunov, "Sliding-mode observers based on equivalent control method", Proc. 31st IEEE CDC, 1992.
.. [DU95] S. Drakunov and V. Utkin, "Sliding mode observers. Tutorial", Proc. 34th IEEE CDC, 1995.
.. [WZ87] B. L. Walcott and S. H. Zak, "State observation of nonlinear uncertain dynamical systems", IEEE TAC
   32(2), 1987.
.. [ES94] C. Edwards and S. K. Spurgeon, "On the development of discontinuous observers", Int. J. Control 59(5),
   1994.
.. [Hau83] M. L. J. Hautus, "Strong detectability and observers", Linear Algebra Appl. 50, 1983.
.. [DZX94] M. Darouach, M. Zasadzinski and S. J. Xu, "Full-order observers for linear systems with unknown
   inputs", IEEE TAC 39(3), 1994.
.. [AB10] V. Acary and B. Brogliato, "Implicit Euler numerical scheme and chattering-free implementation of
   sliding mode systems", Systems & Control Letters 59, 2010.
.. [Fri] L. Fridman, "Sliding Mode Observers: Theory and Practice", lecture slides, section 1.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla

from .._extras import require
from .._validation import (
    DivergenceError,
    as_real_array,
    check_choice,
    check_nonnegative,
    check_positive,
    check_positive_array,
)
from ..design.gains import _placed_gain, ackermann_observer_gain
from ..design.lmi import LMIInfeasibleError
from .plants import RANK_TOL, _matrix, _rank, _unit
from .unknown_inputs import StrongDetectabilityReport, strong_detectability

__all__ = [
    "ObservableBlockForm",
    "StepByStepObserver",
    "UnknownInputConditionError",
    "UnknownInputConditions",
    "UnknownInputObserver",
    "UtkinObserver",
    "WalcottZakDesign",
    "WalcottZakObserver",
    "certify_walcott_zak",
    "observable_block_form",
    "output_coordinate_change",
    "unknown_input_conditions",
    "walcott_zak_design",
]

_DISCRETIZATIONS = ("implicit", "euler")


class UnknownInputConditionError(ValueError):
    """An existence condition of an unknown-input observer fails; :attr:`condition` names it.

    Attributes
    ----------
    condition : str
        ``"rank(D) = m"``, ``"rank(CD) = rank(D)"``, ``"minimum phase"`` or ``"observability"``.
    """

    def __init__(self, condition: str, message: str):
        super().__init__(message)
        self.condition = condition


# ----------------------------------------------------------------------------------------------------------------
# shared checks and coordinate changes
# ----------------------------------------------------------------------------------------------------------------


def _check_system(A, B, C, D=None):
    """Checked float ``(A, B, C, D)``; ``B = None`` gives no control input (``q = 0``), ``D`` may be None."""
    A = _matrix("A", A, (None, None))
    n = A.shape[0]
    if A.shape != (n, n):
        raise ValueError(f"expected a square A, actual value: shape {A.shape}")
    B = np.zeros((n, 0)) if B is None else _matrix("B", B, (n, None))
    C = _matrix("C", np.atleast_2d(C), (None, n))
    if _rank(_unit(C)) < C.shape[0]:
        raise ValueError(
            f"expected C of full row rank {C.shape[0]} (independent outputs), actual value: rank {_rank(_unit(C))}"
        )
    if D is not None:
        D = _matrix("D", D, (n, None))
    return A, B, C, D


def output_coordinate_change(C) -> np.ndarray:
    r"""The slides' eq. (3): :math:`T_c = \begin{bmatrix} N_c^T \\ C \end{bmatrix}` with :math:`C T_c^{-1} = [0\ I_p]`.

    ``N_c`` (orthonormal columns) spans the null space of ``C``, so that :math:`z = T_c x` has the outputs as its
    last ``p`` entries, and :math:`T_c^{-1} = [N_c\ \ C^T (C C^T)^{-1}]`.

    Parameters
    ----------
    C : array_like, shape (p, n)
        Full row rank.

    Returns
    -------
    ndarray, shape (n, n)
    """
    C = _matrix("C", np.atleast_2d(C), (None, None))
    p, n = C.shape
    if p > n or _rank(_unit(C)) < p:
        raise ValueError(f"expected C of full row rank p <= n, actual value: shape {C.shape}, rank {_rank(_unit(C))}")
    _, _, Vh = np.linalg.svd(C)
    return np.vstack([Vh[p:], C])


def _place(A, C, poles) -> np.ndarray:
    """``L`` with eigenvalues of ``A + L C`` at ``poles``: Ackermann's formula for one output, else
    ``scipy.signal.place_poles`` on the dual pair, re-verified (``smo_gym.design.gains._placed_gain``)."""
    if C.shape[0] == 1:
        return -ackermann_observer_gain(A, C[0], poles)[:, None]
    return -_placed_gain(A, C, poles)


def _default_poles(A: np.ndarray, k: int) -> np.ndarray:
    speed = max(2.0, 2.0 * (np.abs(np.linalg.eigvals(A).real).max() if A.size else 0.0))
    return -speed * (1.0 + 0.5 * np.arange(k))


def _gain_vector(name: str, value, p: int) -> np.ndarray:
    arr = check_positive_array(name, value)
    if arr.ndim > 1 or arr.size not in (1, p):
        raise ValueError(f"expected {name} a number or {p} numbers, actual value: shape {arr.shape}")
    return np.broadcast_to(arr, (p,)).copy()


def _lowpass_weight(dt: float, tau: float) -> float:
    """Exact discretization of :math:`\\tau \\dot\\nu_f = \\nu - \\nu_f` with ``nu`` held over ``dt``."""
    return float(-np.expm1(-dt / tau))


def _zoh(A: np.ndarray, B: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    n, q = A.shape[0], B.shape[1]
    M = np.zeros((n + q, n + q))
    M[:n, :n], M[:n, n:] = A * dt, B * dt
    E = sla.expm(M)
    return E[:n, :n], E[:n, n:]


class _SampledObserver:
    """Bookkeeping shared by the observers: shapes, ``reset``/``update``/``advance``/``run``."""

    #: the attributes ``update`` and ``advance`` change: restored when a step is refused
    _STATE: tuple[str, ...] = ("x_hat",)

    def __init__(self, A, B, C, dt):
        self.A, self.B, self.C, _ = _check_system(A, B, C)
        self.dt = check_positive("dt", dt)
        self.n, self.q, self.p = self.A.shape[0], self.B.shape[1], self.C.shape[0]
        self.x_hat = None
        self._batch = None

    def _require(self):
        if self._batch is None:
            raise RuntimeError("expected reset(y0) before update(y), actual value: the observer was never reset")

    def _y(self, y, batch=None) -> np.ndarray:
        y = as_real_array("y", y)
        batch = self._batch if batch is None else batch
        if y.ndim == 0 or y.shape[-1] != self.p:
            raise ValueError(f"expected y of shape (..., {self.p}), actual value: shape {y.shape}")
        if batch is not None and y.shape[:-1] != batch:
            raise ValueError(f"expected y of shape {batch + (self.p,)}, actual value: shape {y.shape}")
        if not np.isfinite(y).all():
            raise ValueError(f"expected finite measurements y, actual value: {y!r:.80}; the state was kept")
        return y

    def _u(self, u) -> np.ndarray:
        if u is None:
            return np.zeros(self._batch + (self.q,))
        u = as_real_array("u", u)
        if u.ndim == 0 or u.shape[-1] != self.q:
            raise ValueError(f"expected u of shape (..., {self.q}), actual value: shape {u.shape}")
        if not np.isfinite(u).all():
            raise ValueError(f"expected finite inputs u, actual value: {u!r:.80}; the state was kept")
        try:
            return np.broadcast_to(u, self._batch + (self.q,))
        except ValueError:
            raise ValueError(f"expected u of shape {self._batch + (self.q,)}, actual value: {u.shape}") from None

    def reset(self, y0, x_hat0=None) -> np.ndarray:
        """Start from ``x_hat0`` (default: the least-squares state matching ``y0``); returns the estimate.

        Parameters
        ----------
        y0 : array_like, shape (..., p)
        x_hat0 : array_like, shape (..., n), optional
        """
        y0 = as_real_array("y0", y0)
        y0 = self._y(y0, y0.shape[:-1])  # any batch shape; checked before the previous reset is given up
        batch = y0.shape[:-1]
        if x_hat0 is None:
            x0 = y0 @ np.linalg.pinv(self.C).T
        else:
            x0 = as_real_array("x_hat0", x_hat0)
            if x0.shape[-1:] != (self.n,) or not np.isfinite(x0).all():
                raise ValueError(f"expected a finite x_hat0 of shape (..., {self.n}), actual value: {x0!r:.80}")
            try:
                x0 = np.broadcast_to(x0, batch + (self.n,)).copy()
            except ValueError:
                raise ValueError(f"expected x_hat0 of shape {batch + (self.n,)}, actual value: {x0.shape}") from None
        self._batch = batch
        self._reset(x0, y0)
        return self.x_hat

    def update(self, y) -> np.ndarray:
        """Correct with the sample ``y_k`` (shape ``(..., p)``) and return :math:`\\hat x_k`, shape ``(..., n)``.

        Raises
        ------
        DivergenceError
            When the corrected state is not finite; the state before the call is kept.
        """
        self._require()
        self._finite_step(self._correct, self._y(y), "update(y)")
        return self.x_hat

    def advance(self, u=None) -> None:
        """Predict to the next sample with the control ``u`` (shape ``(..., q)``, default 0) held over ``dt``.

        Raises
        ------
        DivergenceError
            When the predicted state is not finite (an unstable plant over a long step); the state before the call
            is kept.
        """
        self._require()
        self._finite_step(self._predict, self._u(u), "advance(u)")

    def _finite_step(self, step, arg, what: str) -> None:
        """``step(arg)``, undone with a DivergenceError if it leaves a non-finite entry in the :attr:`_STATE`."""
        # arrays copied: some observers write their state in place
        saved = {k: getattr(self, k) for k in self._STATE}
        saved = {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in saved.items()}
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow is reported just below
            step(arg)
        bad = [
            k
            for k in self._STATE
            if isinstance(v := getattr(self, k), np.ndarray) and v.dtype.kind == "f" and not np.isfinite(v).all()
        ]
        if bad:
            for k, v in saved.items():
                setattr(self, k, v)
            raise DivergenceError(
                f"expected a finite state after {what}, actual value: non-finite {', '.join(bad)}; the state was kept"
            )

    def run(self, y, u=None, x_hat0=None) -> np.ndarray:
        """Filter a recorded sequence: ``y`` of shape ``(T, ..., p)``, ``u`` of shape ``(T, ..., q)``.

        Returns :math:`\\hat x` of shape ``(T, ..., n)``; the per-sample diagnostics are in :attr:`history`
        (a dict of arrays with the leading ``T``).
        """
        y = as_real_array("y", y)
        if y.ndim < 2:
            raise ValueError(f"expected y of shape (T, ..., {self.p}), actual value: shape {y.shape}")
        if y.shape[0] == 0:  # the first sample starts the observer
            raise ValueError(f"expected y with at least one sample, actual value: shape {y.shape}")
        if u is not None:
            u = as_real_array("u", u)
            if u.ndim == 0 or len(u) < len(y) - 1:
                raise ValueError(f"expected u with a row per sample of y ({len(y)}), actual value: shape {u.shape}")
        out = np.empty(y.shape[:-1] + (self.n,))
        rec: dict[str, list] = {}
        self.reset(y[0], x_hat0)
        for k in range(y.shape[0]):
            if k:
                self.advance(None if u is None else u[k - 1])
                self.update(y[k])
            out[k] = self.x_hat
            for key, val in self._diagnostics().items():
                rec.setdefault(key, []).append(np.array(val))
        self.history = {key: np.array(v) for key, v in rec.items()}
        return out

    def _diagnostics(self) -> dict:
        return {}


# ----------------------------------------------------------------------------------------------------------------
# Utkin's simple sliding-mode observer
# ----------------------------------------------------------------------------------------------------------------


def _injection(s: np.ndarray, gain: np.ndarray, dt: float, discretization: str) -> np.ndarray:
    """Componentwise :math:`\\rho\\,\\mathrm{sign}(s)`: explicit, or the implicit-Euler value ``clip(s/dt, +-rho)``."""
    if discretization == "euler":
        return gain * np.sign(s)
    return np.clip(s / dt, -gain, gain)


class UtkinObserver(_SampledObserver):
    r"""Utkin's simple sliding-mode observer with the equivalent output injection (the slides' eq. (3)-(5)).

    In the coordinates :math:`z = T_c x = (z_1, z_2)`, :math:`z_2 = y` (:func:`output_coordinate_change`),

    .. math::
        \dot{\hat z}_1 = A_{11}\hat z_1 + A_{12}\hat z_2 + B_1 u + L\nu,\qquad
        \dot{\hat z}_2 = A_{21}\hat z_1 + A_{22}\hat z_2 + B_2 u - \nu,\qquad
        \nu_i = \rho_i\,\mathrm{sign}(\hat y_i - y_i).

    The error :math:`e = \hat z - z`, :math:`e_y = \hat y - y` obeys
    :math:`\dot e_y = A_{21}e_1 + A_{22}e_y - \nu`: it reaches :math:`e_y = 0` in finite time, in at most
    :math:`|e_{y,i}(0)| / (\rho_i - \delta_i)` for a single output, :math:`\delta_i \ge |A_{21,i}e_1 + A_{22,i}e_y|`.
    There the equivalent injection is :math:`\nu_{eq} = A_{21}e_1` and the rest of the error obeys the reduced
    Luenberger dynamics :math:`\dot e_1 = (A_{11} + L A_{21})e_1`, at the rate of the designed matrix.

    The equivalent injection is recovered by the low-pass filter :math:`\tau\dot\nu_f = \nu - \nu_f`. When
    :math:`A_{21}` has full column rank (``n - p <= p`` and no unobservable direction in one step) it reconstructs
    the unmeasured states at once, without waiting for the reduced dynamics:
    :math:`z_1 = \hat z_1 - A_{21}^+ \nu_{eq}` (:attr:`x_reconstructed`, up to the filter's lag).

    Parameters
    ----------
    A : array_like, shape (n, n)
    B : array_like, shape (n, q), or None
    C : array_like, shape (p, n)
        Full row rank.
    dt : float
        Sampling step; the prediction between samples is the exact zero-order hold of ``(A, B)``, the injection
        acts at the samples with weight ``dt``.
    gain : float or array_like, shape (p,)
        :math:`\rho > 0` (per output). Must exceed the bound on :math:`|A_{21}e_1 + A_{22}e_y|` for sliding.
    L : array_like, shape (n - p, p), optional
        Design matrix; :math:`A_{11} + L A_{21}` must be Hurwitz.
    poles : array_like, shape (n - p,), optional
        Eigenvalues of :math:`A_{11} + L A_{21}` (pole placement on the pair :math:`(A_{11}, A_{21})`, observable
        when ``(A, C)`` is). Default: distinct reals at least twice as fast as ``A``.
    tau : float
        Time constant of the low-pass filter of the injection.
    discretization : {"implicit", "euler"}
        See the module docstring.

    Attributes
    ----------
    T : ndarray, shape (n, n)
        :math:`T_c`; ``A_z = T A T^{-1}`` and its blocks ``A11, A12, A21, A22``.
    nu, nu_filtered : ndarray, shape (..., p)
        The injection at the last sample and its low-pass filtered value.
    sliding : ndarray of bool, shape (..., p)
        Implicit discretization: the output error was brought to zero at the last sample (the injection was not
        saturated). Explicit: the output error changed sign.
    x_reconstructed : ndarray, shape (..., n), or None
        The estimate with :math:`z_1` corrected by the filtered equivalent injection (None when :math:`A_{21}` has
        not full column rank).

    References
    ----------
    V. I. Utkin, *Sliding Modes in Control and Optimization*, 1992; S. Drakunov and V. Utkin, "Sliding mode
    observers. Tutorial", CDC 1995; Fridman's slides, section 1 ("Drakunov-Utkin observer").

    Notes
    -----
    The slides print :math:`\dot e_{y,i} = \ldots - \rho\nu_i` with :math:`\nu_i = \rho\,\mathrm{sign}(e_{y,i})`
    (the gain twice); the observer they state above it has :math:`-\nu`, which is what is implemented.
    """

    _STATE = ("z_hat", "nu", "nu_filtered", "sliding", "x_hat", "x_reconstructed")

    def __init__(self, A, B, C, dt, gain, *, L=None, poles=None, tau=0.01, discretization="implicit"):
        super().__init__(A, B, C, dt)
        n, p = self.n, self.p
        self.gain = _gain_vector("gain", gain, p)
        self.tau = check_positive("tau", tau)
        self.discretization = check_choice("discretization", discretization, _DISCRETIZATIONS)
        self.T = output_coordinate_change(self.C)
        self.T_inv = np.linalg.inv(self.T)
        Az = self.T @ self.A @ self.T_inv
        k = n - p
        self.A11, self.A12, self.A21, self.A22 = Az[:k, :k], Az[:k, k:], Az[k:, :k], Az[k:, k:]
        if L is not None and poles is not None:
            raise TypeError("expected L or poles, not both, actual value: both given")
        if k == 0:
            self.L = np.zeros((0, p))
        elif L is not None:
            self.L = _matrix("L", L, (k, p))
        else:
            poles = _default_poles(self.A, k) if poles is None else np.asarray(poles, dtype=complex)
            if poles.shape != (k,):
                raise ValueError(f"expected {k} poles, actual value: shape {poles.shape}")
            self.L = np.real(_place(self.A11, self.A21, poles))
        self.reduced_matrix = self.A11 + self.L @ self.A21
        ev = np.linalg.eigvals(self.reduced_matrix) if k else np.zeros(0)
        if np.any(ev.real >= 0):
            raise ValueError(f"expected A11 + L A21 Hurwitz, actual value: eigenvalues {ev}")
        self.reduced_eigenvalues = ev
        Bz = self.T @ self.B
        self._Phi, self._Gam = _zoh(Az, Bz, self.dt)
        self._a = _lowpass_weight(self.dt, self.tau)
        A21_unit = _unit(self.C) @ _unit(self.A) @ self.T_inv[:, :k]  # A21 = C A N_c on its factors' scale
        self._A21_pinv = np.linalg.pinv(self.A21) if k and _rank(A21_unit) == k else None
        self.z_hat = None
        self.nu = self.nu_filtered = self.sliding = self.x_reconstructed = None

    def _reset(self, x0, y0):
        self.z_hat = x0 @ self.T.T
        self.nu = np.zeros(self._batch + (self.p,))
        self.nu_filtered = self.nu.copy()
        self.sliding = np.zeros(self._batch + (self.p,), dtype=bool)
        self._set_outputs(y0)

    def _set_outputs(self, y):
        self.x_hat = self.z_hat @ self.T_inv.T
        if self._A21_pinv is None:
            self.x_reconstructed = None
            return
        k = self.n - self.p
        z1 = self.z_hat[..., :k] - self.nu_filtered @ self._A21_pinv.T
        self.x_reconstructed = np.concatenate([z1, y], axis=-1) @ self.T_inv.T

    def _correct(self, y):
        k = self.n - self.p
        s = self.z_hat[..., k:] - y  # e_y = y_hat - y (the slides' sign)
        nu = _injection(s, self.gain, self.dt, self.discretization)
        self.sliding = np.abs(nu) < self.gain if self.discretization == "implicit" else np.sign(s) != np.sign(self.nu)
        self.nu = nu
        self.z_hat = np.concatenate(
            [self.z_hat[..., :k] + self.dt * nu @ self.L.T, self.z_hat[..., k:] - self.dt * nu], -1
        )
        self.nu_filtered = self.nu_filtered + self._a * (nu - self.nu_filtered)
        self._set_outputs(y)

    def _predict(self, u):
        self.z_hat = self.z_hat @ self._Phi.T + u @ self._Gam.T
        self.x_hat = self.z_hat @ self.T_inv.T

    def _diagnostics(self):
        d = {"nu": self.nu, "nu_filtered": self.nu_filtered, "sliding": self.sliding}
        if self.x_reconstructed is not None:
            d["x_reconstructed"] = self.x_reconstructed
        return d


# ----------------------------------------------------------------------------------------------------------------
# Drakunov's step-by-step observer
# ----------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ObservableBlockForm:
    r"""The observable block (Hessenberg) form of ``(A, B, C)``: :math:`\xi = T x` (``T`` orthogonal) with

    .. math::
        \dot\xi_i = \sum_{j \le i+1} A_{ij}\xi_j + B_i u,\qquad y = C_1 \xi_1,

    :math:`A_{ij} = 0` for :math:`j > i + 1`, every :math:`A_{i,i+1}` (``p_i x p_{i+1}``) of full column rank and
    :math:`C_1` (``p x p``) invertible.

    Attributes
    ----------
    T : ndarray, shape (n, n)
        Orthogonal; ``A_xi = T A T^T``.
    A : ndarray, shape (n, n)
    B : ndarray, shape (n, q)
    C1 : ndarray, shape (p, p)
    sizes : tuple of int
        Block sizes ``p_1 = p >= p_2 >= ... >= p_r``, summing to ``n``.
    """

    T: np.ndarray
    A: np.ndarray
    B: np.ndarray
    C1: np.ndarray
    sizes: tuple

    def blocks(self) -> list[slice]:
        """The index ranges of the blocks."""
        edges = np.concatenate([[0], np.cumsum(self.sizes)])
        return [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True)]


def observable_block_form(A, B, C) -> ObservableBlockForm:
    r"""Orthogonal reduction of an observable ``(A, C)`` to the observable block (Hessenberg) form.

    The dual of the controllability staircase (Van Dooren 1981): the row space of ``C`` is the first block; at
    each step the coupling of the blocks found so far to the rest is compressed by an SVD, which gives the next
    block and a full-column-rank :math:`A_{i,i+1}`. Raises :class:`UnknownInputConditionError` (condition
    ``"observability"``) when the coupling vanishes before all ``n`` states are reached.

    Parameters
    ----------
    A : array_like, shape (n, n)
    B : array_like, shape (n, q), or None
    C : array_like, shape (p, n)
        Full row rank.
    """
    A, B, C, _ = _check_system(A, B, C)
    n, p = A.shape[0], C.shape[0]
    Vh = np.linalg.svd(C)[2]
    Q = Vh.T  # columns: row space of C (first p), then the rest
    sizes = [p]
    done = p
    scale = np.linalg.norm(A)  # the couplings are blocks of Q^T A Q: judged against ||A||, whatever its units
    while done < n:
        At = Q.T @ A @ Q
        last = slice(done - sizes[-1], done)
        coupling = At[last, done:]  # A_{i, rest}: rows of the last block, columns not yet reached
        _, sv, Wh = np.linalg.svd(coupling)
        k = int(np.sum(sv > RANK_TOL * scale))
        if k == 0:
            raise UnknownInputConditionError(
                "observability",
                f"expected (A, C) observable, actual value: only {done} of n={n} states are reached from y "
                f"(observable block sizes {sizes})",
            )
        Q[:, done:] = Q[:, done:] @ Wh.T  # first k new columns: the part the last block sees
        sizes.append(k)
        done += k
    T = Q.T
    At = T @ A @ T.T
    return ObservableBlockForm(T=T, A=At, B=T @ B, C1=(C @ T.T)[:, :p], sizes=tuple(sizes))


class StepByStepObserver(_SampledObserver):
    r"""Drakunov's step-by-step sliding-mode observer on the observable block form (Drakunov 1992; the slides'
    "Drakunov-Utkin observer" applied block by block).

    In the coordinates of :func:`observable_block_form`, with :math:`z_1 = C_1^{-1}y`, step ``i = 1..r-1`` is

    .. math::
        \dot{\hat x}_i = \sum_{j \le i} A_{ij} z_j + B_i u + \nu_i,\qquad \nu_i = M_i\,\mathrm{sign}(z_i - \hat x_i),
        \qquad z_{i+1} = A_{i,i+1}^+\,\{\nu_i\}_{eq}.

    Once :math:`z_j = \xi_j` for :math:`j \le i`, the error :math:`s_i = z_i - \hat x_i` obeys
    :math:`\dot s_i = A_{i,i+1}\xi_{i+1} - \nu_i`, reaches zero in finite time when
    :math:`M_i > |A_{i,i+1}\xi_{i+1}|`, and the equivalent injection is :math:`A_{i,i+1}\xi_{i+1}`: the next
    block. After ``r - 1`` finite reaching phases the whole state is exact (noise free).

    Sampled form (``dt``), predictions by Euler with the reconstructions held (they exist at the samples only):
    ``"implicit"`` (default, the exact equivalent-value approach) takes :math:`\nu_i = \mathrm{clip}(s_i^-/dt,
    \pm M_i)`, which *is* the equivalent value once step ``i`` slides; noise free the state error is then
    ``O(dt)``. In sliding mode this value equals the backward difference of :math:`z_i` minus the model terms, so
    a noise of amplitude :math:`\eta` is amplified like :math:`\eta/dt^{i}` in block ``i + 1``: a conventional
    step-by-step observer is a cascade of first differences. ``"euler"`` takes :math:`M_i\,\mathrm{sign}(s_i^-)`
    and the next step's measurement is its low-pass filtered value (time constant ``tau``), the textbook
    implementation; it is ``O(dt / tau + tau)`` accurate at best and degrades with the number of steps.

    Parameters
    ----------
    A, B, C : array_like
        ``(A, C)`` observable, ``C`` full row rank (``B`` may be None).
    dt : float
    gain : float or sequence of float
        :math:`M_i > 0`, one value for all steps or one per step (``r - 1`` values).
    tau : float, optional
        Low-pass time constant for ``"euler"`` (default ``20 dt``); ignored by ``"implicit"``.
    discretization : {"implicit", "euler"}

    Attributes
    ----------
    form : ObservableBlockForm
    n_steps : int
        ``r - 1``.
    sliding : ndarray of bool, shape (..., n_steps)
        Step ``i`` was on its sliding manifold at the last sample (implicit: no component saturated).
    xi_hat : ndarray, shape (..., n)
        The reconstructions :math:`(z_1, \ldots, z_r)`; ``x_hat = xi_hat @ T``.
    s, nu : ndarray, shape (..., n)
        Per block ``i < r``: the sliding variable :math:`s_i = z_i - \hat x_i^-` before the correction and the
        injection :math:`\nu_i` at the last sample.
    """

    _STATE = ("xi_hat", "_x_steps", "s", "_nu_f", "nu", "sliding", "x_hat")

    def __init__(self, A, B, C, dt, gain, *, tau=None, discretization="implicit"):
        super().__init__(A, B, C, dt)
        self.form = observable_block_form(self.A, self.B, self.C)
        self.discretization = check_choice("discretization", discretization, _DISCRETIZATIONS)
        self.tau = 20.0 * self.dt if tau is None else check_positive("tau", tau)
        self.n_steps = len(self.form.sizes) - 1
        g = check_positive_array("gain", gain)
        if g.ndim > 1 or g.size not in (1, max(self.n_steps, 1)):
            raise ValueError(f"expected gain a number or {self.n_steps} numbers (one per step), actual value: {g!r}")
        self.gain = np.broadcast_to(g, (self.n_steps,)).copy()
        self._blocks = self.form.blocks()
        Af = self.form.A
        self._sup_pinv = [np.linalg.pinv(Af[self._blocks[i], self._blocks[i + 1]]) for i in range(self.n_steps)]
        self._C1_inv = np.linalg.inv(self.form.C1)
        self._a = _lowpass_weight(self.dt, self.tau)

    def _reset(self, x0, y0):
        xi0 = x0 @ self.form.T.T
        self._x_steps = xi0.copy()  # step observers x_hat_i (blocks 1..r-1 used), from the initial guess
        xi0[..., self._blocks[0]] = y0 @ self._C1_inv.T
        self.xi_hat = xi0  # reconstructions z_1..z_r
        self.s = np.zeros(self._batch + (self.n,))
        self._nu_f = np.zeros(self._batch + (self.n,))
        self.nu = np.zeros(self._batch + (self.n,))
        self.sliding = np.zeros(self._batch + (self.n_steps,), dtype=bool)
        self.x_hat = self.xi_hat @ self.form.T

    def _correct(self, y):
        b, dt = self._blocks, self.dt
        self.xi_hat = self.xi_hat.copy()
        self.xi_hat[..., b[0]] = y @ self._C1_inv.T
        sliding = []
        for i in range(self.n_steps):
            s = self.xi_hat[..., b[i]] - self._x_steps[..., b[i]]
            self.s[..., b[i]] = s
            nu = _injection(s, self.gain[i], dt, self.discretization)
            self._x_steps[..., b[i]] += dt * nu
            self.nu[..., b[i]] = nu
            if self.discretization == "implicit":
                sliding.append(np.all(np.abs(nu) < self.gain[i], axis=-1))
                eq = nu
            else:
                sliding.append(np.all(np.abs(s) <= self.gain[i] * dt, axis=-1))
                self._nu_f[..., b[i]] += self._a * (nu - self._nu_f[..., b[i]])
                eq = self._nu_f[..., b[i]]
            self.xi_hat[..., b[i + 1]] = eq @ self._sup_pinv[i].T
        self.sliding = np.stack(sliding, axis=-1) if sliding else np.zeros(self._batch + (0,), dtype=bool)
        self.x_hat = self.xi_hat @ self.form.T

    def _predict(self, u):
        Af, Bf, b = self.form.A, self.form.B, self._blocks
        for i in range(self.n_steps):
            rows = b[i]
            known = slice(0, rows.stop)  # blocks j <= i: the reconstructions
            drift = self.xi_hat[..., known] @ Af[rows, known].T + u @ Bf[rows].T
            self._x_steps[..., rows] += self.dt * drift

    def _diagnostics(self):
        return {"sliding": self.sliding, "nu": self.nu, "s": self.s, "xi_hat": self.xi_hat}


# ----------------------------------------------------------------------------------------------------------------
# existence conditions of unknown-input observers
# ----------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class UnknownInputConditions:
    r"""Report of :func:`unknown_input_conditions`.

    Attributes
    ----------
    ok : bool
        All conditions hold: an observer without differentiation exists (strong* detectability, Hautus 1983).
    failing : tuple of str
        The names of the failing conditions: ``"rank(D) = m"``, ``"rank(CD) = rank(D)"``, ``"minimum phase"``.
    reason : str
        Why, in words ("" when ``ok``).
    rank_D, rank_CD : int
    invariant_zeros : ndarray of complex
        Of ``(A, D, C)`` (empty when a rank condition fails, as the zeros are then not those of a square-able
        pencil).
    strongly_observable : bool
        No invariant zeros at all (then the observer's error rate can be chosen freely).
    detectability : StrongDetectabilityReport or None
        The :func:`~smo_gym.control.strong_detectability` report behind the minimum-phase verdict (None when a
        rank condition fails first).
    """

    ok: bool
    failing: tuple
    reason: str
    rank_D: int
    rank_CD: int
    invariant_zeros: np.ndarray
    strongly_observable: bool
    detectability: StrongDetectabilityReport | None = field(default=None, repr=False)

    def require(self) -> UnknownInputConditions:
        """Return the report, or raise :class:`UnknownInputConditionError` naming the first failing condition."""
        if not self.ok:
            raise UnknownInputConditionError(
                self.failing[0], f"expected the condition {self.failing[0]} to hold, actual value: {self.reason}"
            )
        return self


def unknown_input_conditions(A, C, D) -> UnknownInputConditions:
    r"""Existence conditions of an observer for :math:`\dot x = Ax + Bu + Dw,\ y = Cx` that needs no derivative of
    ``y`` and converges whatever the unknown input ``w`` is (Hautus 1983; Darouach et al. 1994; for the
    Walcott-Zak observer, Edwards and Spurgeon 1994).

    1. ``rank(D) = m``: the unknown inputs act independently (a rank-deficient ``D`` can be reduced first).
    2. The observer-matching condition ``rank(CD) = rank(D)``: every unknown input reaches the output with
       relative degree one (the slides: "relative degree 1 condition").
    3. Minimum phase (:func:`~smo_gym.control.strong_detectability`): the invariant zeros of ``(A, D, C)``, the
       ``s`` where :math:`\begin{bmatrix} sI - A & -D \\ C & 0\end{bmatrix}` loses rank, lie in the open left
       half-plane (with 2., the strong detectability of Hautus). They are the eigenvalues that no observer gain can
       move.

    Parameters
    ----------
    A : array_like, shape (n, n)
    C : array_like, shape (p, n)
    D : array_like, shape (n, m)

    Notes
    -----
    The slide "State reconstruction without differentiation [Hautus 1983]" lists "the system does not have
    invariant zeroes" (strong observability) among the assumptions; Hautus's theorem needs only that they are
    stable (strong* detectability), which is what is checked. Without zeros (``strongly_observable``) every
    eigenvalue of the observer's error can be placed.
    """
    A, _, C, D = _check_system(A, None, C, D)
    m = D.shape[1]
    rD, rCD = _rank(_unit(D)), _rank(_unit(C) @ _unit(D))  # CD judged against ||C|| ||D||
    failing, reasons = [], []
    zeros = np.zeros(0, dtype=complex)
    if rD < m:
        failing.append("rank(D) = m")
        reasons.append(f"D has rank {rD} < m={m} columns")
    if rCD != rD:
        failing.append("rank(CD) = rank(D)")
        reasons.append(
            f"rank(CD) = {rCD} != rank(D) = {rD}: some unknown input reaches y only through derivatives "
            "(relative degree > 1), so it cannot be rejected without differentiating y"
        )
    detect = None
    if not failing:  # left-invertible now (rank CD = m): the zeros are those of a square-able pencil
        detect = strong_detectability(A, C, D)
        zeros = detect.invariant_zeros
        if not detect.ok:
            failing.append("minimum phase")
            z = ", ".join(f"{complex(v):.4g}" for v in detect.unstable_zeros)
            reasons.append(
                f"(A, D, C) has invariant zeros at s = {z}, not in the open left half-plane: the error mode there "
                "is invisible in y and cannot be stabilized (not strongly detectable)"
            )
    return UnknownInputConditions(
        ok=not failing,
        failing=tuple(failing),
        reason="; ".join(reasons),
        rank_D=rD,
        rank_CD=rCD,
        invariant_zeros=zeros,
        strongly_observable=not failing and zeros.size == 0,
        detectability=detect,
    )


# ----------------------------------------------------------------------------------------------------------------
# Walcott-Zak observer
# ----------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class WalcottZakDesign:
    r"""Gains of the Walcott-Zak observer and their NumPy certificate.

    Attributes
    ----------
    P : ndarray, shape (n, n)
        Lyapunov matrix, :math:`P > 0`.
    G : ndarray, shape (n, p)
        Linear gain.
    F : ndarray, shape (m, p)
        :math:`F C = D^T P`, computed as :math:`D^T P C^+` from the returned ``P``.
    min_eig_P : float
    max_eig_lyapunov : float
        Largest eigenvalue of :math:`(A - GC)^T P + P(A - GC) + 2\,\mathrm{decay}\,P` (must be ``< 0``).
    equality_residual : float
        :math:`\|D^T P - F C\|_F / \|D^T P\|_F`.
    observer_eigenvalues : ndarray of complex, shape (n,)
        Of :math:`A - GC`.
    status : str
        The solver's status.
    """

    P: np.ndarray
    G: np.ndarray
    F: np.ndarray
    min_eig_P: float
    max_eig_lyapunov: float
    equality_residual: float
    observer_eigenvalues: np.ndarray
    status: str


def walcott_zak_design(A, C, D, *, decay: float = 0.0, eps: float = 1e-6, tol: float = 1e-6) -> WalcottZakDesign:
    r"""Solve the Walcott-Zak conditions by an LMI (Edwards and Spurgeon 1994 form) and re-verify them in NumPy.

    Find :math:`P = P^T \succeq I`, :math:`Y = PG` and ``F`` with

    .. math::
        A^T P + P A - C^T Y^T - Y C + 2\,\mathrm{decay}\,P \preceq -\epsilon I,\qquad D^T P = F C,

    minimizing :math:`\mathrm{tr}\,P` (the conditions are homogeneous, so ``P >= I`` only fixes the scale), with
    cvxpy and Clarabel. The existence conditions (:func:`unknown_input_conditions`: ``rank(CD) = rank(D) = m``
    and minimum phase; for ``decay > 0`` the zeros must lie left of ``-decay``) are checked first and a failure
    raises :class:`UnknownInputConditionError` naming the condition; an infeasible or unverified solution raises
    :class:`~smo_gym.design.LMIInfeasibleError`.

    Parameters
    ----------
    A : array_like, shape (n, n)
    C : array_like, shape (p, n)
    D : array_like, shape (n, m)
    decay : float
        Guaranteed decay rate of :math:`e^T P e` is ``2 decay`` (``>= 0``).
    eps : float
        Margin of the strict inequality.
    tol : float
        Largest accepted ``equality_residual`` and smallest accepted margin in the NumPy re-verification.
    """
    A, _, C, D = _check_system(A, None, C, D)
    decay = check_nonnegative("decay", decay)
    eps = check_positive("eps", eps)
    tol = check_positive("tol", tol)
    report = unknown_input_conditions(A, C, D).require()
    if decay > 0 and np.any(report.invariant_zeros.real >= -decay):
        raise UnknownInputConditionError(
            "minimum phase",
            f"expected the invariant zeros left of -decay = {-decay}, actual value: {report.invariant_zeros}",
        )
    cp = require("cvxpy", "design")
    n, p, m = A.shape[0], C.shape[0], D.shape[1]
    P = cp.Variable((n, n), symmetric=True)
    Y = cp.Variable((n, p))
    F = cp.Variable((m, p))
    S = A.T @ P + P @ A - C.T @ Y.T - Y @ C + 2.0 * decay * P
    S = 0.5 * (S + S.T)
    problem = cp.Problem(cp.Minimize(cp.trace(P)), [P >> np.eye(n), S << -eps * np.eye(n), D.T @ P == F @ C])
    try:
        problem.solve(solver=cp.CLARABEL)
    except cp.error.SolverError as exc:  # pragma: no cover - reported as infeasibility
        raise LMIInfeasibleError(f"expected a solution of the Walcott-Zak LMI, actual value: {exc}") from None
    if problem.status != "optimal":
        raise LMIInfeasibleError(f"expected status 'optimal' for the Walcott-Zak LMI, actual value: {problem.status}")
    Pv = 0.5 * (P.value + P.value.T)
    G = np.linalg.solve(Pv, Y.value)
    return certify_walcott_zak(A, C, D, Pv, G, decay=decay, tol=tol, status=problem.status)


def certify_walcott_zak(A, C, D, P, G, *, decay: float = 0.0, tol: float = 1e-6, status: str = "given"):
    r"""NumPy certificate of the Walcott-Zak conditions for given ``(P, G)``; ``F = D^T P C^+``.

    Raises :class:`~smo_gym.design.LMIInfeasibleError` when ``P`` is not positive definite, the Lyapunov matrix
    (with ``2 decay P``, ``decay >= 0`` as in :func:`walcott_zak_design`) is not negative definite, or
    :math:`\|D^T P - FC\|_F > tol\,\|D^T P\|_F` (``tol >= 0``); ``ValueError`` for a negative or non-finite
    ``decay`` or ``tol`` (a NaN would make every comparison false and certify anything).
    """
    decay = check_nonnegative("decay", decay)
    tol = check_nonnegative("tol", tol)
    A, _, C, D = _check_system(A, None, C, D)
    P = _matrix("P", P, A.shape)
    G = _matrix("G", G, (A.shape[0], C.shape[0]))
    P = 0.5 * (P + P.T)
    F = D.T @ P @ np.linalg.pinv(C)
    Acl = A - G @ C
    lyap = Acl.T @ P + P @ Acl + 2.0 * decay * P
    eig_P = np.linalg.eigvalsh(P)
    eig_L = np.linalg.eigvalsh(0.5 * (lyap + lyap.T))
    resid = float(np.linalg.norm(D.T @ P - F @ C) / max(np.linalg.norm(D.T @ P), 1e-300))
    if eig_P[0] <= 0.0 or eig_L[-1] >= 0.0 or resid > tol:
        raise LMIInfeasibleError(
            "expected P > 0, (A - GC)^T P + P (A - GC) < 0 and D^T P = F C in the NumPy re-verification, actual "
            f"value: min eig(P) = {eig_P[0]:.3e}, max eig(Lyapunov) = {eig_L[-1]:.3e}, residual = {resid:.3e}"
        )
    return WalcottZakDesign(
        P=P,
        G=G,
        F=F,
        min_eig_P=float(eig_P[0]),
        max_eig_lyapunov=float(eig_L[-1]),
        equality_residual=resid,
        observer_eigenvalues=np.linalg.eigvals(Acl),
        status=status,
    )


class WalcottZakObserver(_SampledObserver):
    r"""Walcott and Zak's (1987) observer for matched, bounded unknown inputs (the slides' "Walcott-Zak observers").

    For :math:`\dot x = Ax + Bu + Dw`, :math:`\|w\| \le \rho`, :math:`y = Cx`, with :math:`e_y = y - C\hat x`:

    .. math::
        \dot{\hat x} = A\hat x + Bu + G e_y + D v,\qquad
        v = \rho\,\frac{F e_y}{\|F e_y\|},

    where ``(P, G, F)`` satisfy :math:`(A - GC)^T P + P(A - GC) < 0`, :math:`D^T P = FC`
    (:func:`walcott_zak_design`). With :math:`\varepsilon = x - \hat x`,
    :math:`\dot\varepsilon = (A - GC)\varepsilon + D(w - v)` and :math:`V = \varepsilon^T P\varepsilon` gives
    :math:`\dot V \le \varepsilon^T((A - GC)^T P + P(A - GC))\varepsilon + 2\|F e_y\|(\|w\| - \rho) < 0`, since
    :math:`\varepsilon^T P D = (F C\varepsilon)^T = (F e_y)^T`: the error converges asymptotically (exponentially)
    whatever the bounded ``w``. As :math:`\varepsilon \to 0`, :math:`D(v_{eq} - w) \to 0`: the low-pass filtered
    injection :math:`v_f` (:math:`\tau\dot v_f = v - v_f`) estimates ``w``.

    Sampled form: exact zero-order-hold prediction of ``(A, B)``; at the samples
    :math:`\hat x^+ = \hat x^- + dt\,(G e_y^- + D v)`, :math:`e_y^- = y_k - C\hat x^-`, with ``"euler"``
    :math:`v = \rho\,F e_y^-/\|F e_y^-\|` (chattering of amplitude ``O(rho dt)``, hence an ``O(dt)`` error), or
    ``"implicit"``: the ``v`` with :math:`\|v\| \le \rho` and :math:`v \in \rho\,\partial\|\cdot\|(s - dt\,Mv)`,
    :math:`s = F(I - dt\,CG)e_y^-` (the switching function after the linear correction, so that
    :math:`F e_y^+ = s - dt\,Mv`), :math:`M = FCD = D^TPD` (symmetric positive definite):
    :math:`v = M^{-1}s/dt` when that has norm at most :math:`\rho` (the sliding sample, :math:`F e_y^+ = 0`), else
    the unique root of a scalar equation in the eigenbasis of ``M`` (Acary and Brogliato 2010).

    The observer corrects at the samples only and its prediction ignores ``w``, so between samples the error grows
    by about :math:`dt\,Dw`: the sampled error is ``O(dt ||D w||)`` (measured order 1 in ``dt``), which is large when
    ``D`` is (the MuJoCo Furuta pendulum: ``||D|| ~ 700``). The unknown-input observer
    :class:`UnknownInputObserver` annihilates ``w`` instead and has no such term.

    Parameters
    ----------
    A, B, C, D : array_like
        ``B`` may be None. The conditions of :func:`unknown_input_conditions` must hold.
    dt : float
    rho : float
        Bound on :math:`\|w\|`, ``> 0``.
    design : WalcottZakDesign, optional
        Default :func:`walcott_zak_design` ``(A, C, D, decay=decay)``. A given design is re-verified on these
        ``A``, ``C``, ``D`` (:func:`certify_walcott_zak`: ``A - G C`` Hurwitz and the shapes fit), ``ValueError``
        otherwise; its ``observer_eigenvalues`` are then those of this ``A - G C``.
    decay : float
        Passed to :func:`walcott_zak_design`.
    tau : float
        Low-pass time constant of :attr:`v_filtered`.
    discretization : {"implicit", "euler"}

    Attributes
    ----------
    v, v_filtered : ndarray, shape (..., m)

    Notes
    -----
    The slides write the injection in a canonical form, :math:`\nu = \rho\,e_2/\|e_2\|` on the output errors
    :math:`e_2` that ``w`` contaminates; :math:`F e_y` with :math:`FC = D^TP` is the coordinate-free form of the
    same switching function (Edwards and Spurgeon 1994), used here so that no canonical form is needed.
    """

    _STATE = ("x_hat", "v", "v_filtered")

    def __init__(self, A, B, C, D, dt, rho, *, design=None, decay=0.0, tau=0.02, discretization="implicit"):
        super().__init__(A, B, C, dt)
        _, _, _, self.D = _check_system(self.A, None, self.C, D)
        self.rho = check_positive("rho", rho)
        self.tau = check_positive("tau", tau)
        self.discretization = check_choice("discretization", discretization, _DISCRETIZATIONS)
        if design is None:
            design = walcott_zak_design(self.A, self.C, self.D, decay=decay)
        elif not isinstance(design, WalcottZakDesign):
            raise TypeError(f"expected design to be a WalcottZakDesign, actual value: {type(design).__name__}")
        else:
            design = self._fitting_design(design)
        self.design = design
        self.m = self.D.shape[1]
        self._Phi, self._Gam = _zoh(self.A, self.B, self.dt)
        M = design.F @ self.C @ self.D
        lam, Q = np.linalg.eigh(0.5 * (M + M.T))
        if lam[0] <= 0:
            raise ValueError(f"expected F C D = D^T P D positive definite, actual value: eigenvalues {lam}")
        self._lam, self._Q = lam, Q
        self._a = _lowpass_weight(self.dt, self.tau)

    def _fitting_design(self, design: WalcottZakDesign) -> WalcottZakDesign:
        """``design`` re-verified on this observer's ``A``, ``C``, ``D`` (it may have been made for another system),
        with the error eigenvalues of this ``A - G C``."""
        n, p, m = self.n, self.p, self.D.shape[1]
        shapes = {"P": (n, n), "G": (n, p), "F": (m, p)}
        wrong = {k: np.shape(getattr(design, k)) for k, v in shapes.items() if np.shape(getattr(design, k)) != v}
        if wrong:
            raise ValueError(
                f"expected a design for this system (P, G, F of shapes {shapes}), actual value: shapes {wrong}"
            )
        eig = np.linalg.eigvals(self.A - design.G @ self.C)
        try:
            checked = certify_walcott_zak(self.A, self.C, self.D, design.P, design.G, status=design.status)
        except LMIInfeasibleError as exc:
            raise ValueError(
                f"expected a design for this system (A - G C Hurwitz with the certificate of P), actual value: "
                f"eigenvalues of A - G C {eig}; {exc}"
            ) from None
        if not np.allclose(checked.F, design.F, rtol=1e-6, atol=1e-12 * max(np.abs(checked.F).max(), 1.0)):
            raise ValueError(
                f"expected a design for this system (F = D^T P C^+), actual value: F {design.F!r:.80}, this system "
                f"gives {checked.F!r:.80}"
            )
        return dataclasses.replace(design, observer_eigenvalues=eig)

    def _reset(self, x0, y0):
        self.x_hat = x0
        self.v = np.zeros(self._batch + (self.m,))
        self.v_filtered = self.v.copy()

    def _unit_injection(self, s: np.ndarray) -> np.ndarray:
        if self.discretization == "euler":
            norm = np.linalg.norm(s, axis=-1, keepdims=True)
            return np.where(norm > 0, self.rho * s / np.where(norm > 0, norm, 1.0), 0.0)
        if self.m == 1:  # the implicit step of a scalar sign is a clip
            return np.clip(s / (self.dt * self._lam[0]), -self.rho, self.rho)
        # implicit: v = rho z/|z|, z = s - dt M v  <=>  z_i = s_i r / (r + dt rho lam_i) in M's eigenbasis, r = |z|
        st = s @ self._Q
        hl = self.dt * self._lam
        v_slide = st / hl
        slide = np.linalg.norm(v_slide, axis=-1, keepdims=True) <= self.rho
        # phi(r) = sum st_i^2 / (r + dt rho lam_i)^2 - 1 is decreasing and convex in r > 0: Newton from below
        c = self.rho * hl
        r = np.maximum(np.linalg.norm(st, axis=-1, keepdims=True) - c.max(), 0.0)
        for _ in range(60):
            d = r + c
            phi = np.where(slide, 0.0, np.sum(st**2 / d**2, axis=-1, keepdims=True) - 1.0)
            if np.all(np.abs(phi) < 1e-13):
                break
            dphi = -2.0 * np.sum(st**2 / d**3, axis=-1, keepdims=True)
            r = np.maximum(r - phi / np.where(dphi < 0, dphi, -1.0), 0.0)
        zt = st * r / (r + c)
        nz = np.linalg.norm(zt, axis=-1, keepdims=True)
        v_sat = self.rho * zt / np.where(nz > 0, nz, 1.0)
        return np.where(slide, v_slide, v_sat) @ self._Q.T

    def _correct(self, y):
        e_y = y - self.x_hat @ self.C.T
        x_lin = self.x_hat + self.dt * e_y @ self.design.G.T
        # F e_y after the linear correction, so that the implicit step solves F e_y^+ = s - dt F C D v exactly
        s = (y - x_lin @ self.C.T) @ self.design.F.T if self.discretization == "implicit" else e_y @ self.design.F.T
        self.v = self._unit_injection(s)
        self.x_hat = x_lin + self.dt * self.v @ self.D.T
        self.v_filtered = self.v_filtered + self._a * (self.v - self.v_filtered)

    def _predict(self, u):
        self.x_hat = self.x_hat @ self._Phi.T + u @ self._Gam.T

    def _diagnostics(self):
        return {"v": self.v, "v_filtered": self.v_filtered}


# ----------------------------------------------------------------------------------------------------------------
# Unknown-input observer without differentiation (Darouach, Zasadzinski and Xu 1994)
# ----------------------------------------------------------------------------------------------------------------


class UnknownInputObserver(_SampledObserver):
    r"""Full-order unknown-input observer (Darouach, Zasadzinski and Xu 1994): no derivative of ``y``, exact
    whatever ``w`` is (the slides' "state reconstruction without differentiation", after Hautus 1983).

    .. math::
        \dot z = N z + L y + G u,\qquad \hat x = z - E y,

    with :math:`E = -D(CD)^+`, :math:`T = I + EC` (so :math:`TD = 0`), :math:`N = TA - KC`,
    :math:`L = K(I + CE) - TAE`, :math:`G = TB`. Then :math:`e = \hat x - x = z - Tx` obeys
    :math:`\dot e = Ne + (NT + LC - TA)x + (G - TB)u - TDw = Ne`: the unknown input is annihilated, not
    estimated. ``K`` makes :math:`N` Hurwitz; that is possible exactly when :math:`(TA, C)` is detectable, i.e.
    under the conditions of :func:`unknown_input_conditions` (``rank(CD) = rank(D) = m`` and minimum phase). The
    unobservable modes of :math:`(TA, C)` are the invariant zeros of ``(A, D, C)``: they stay eigenvalues of
    ``N`` whatever ``K`` is, so they bound the convergence rate. ``K`` here is the dual LQR gain of
    :math:`(TA + \mathrm{decay}\,I, C)` with identity weights, which only needs detectability.

    Sampled form: exact zero-order hold of the ``z`` dynamics with ``y`` and ``u`` held over ``dt``; holding ``y``
    adds :math:`L(y_k - y(t))` to the error dynamics, an ``O(dt)`` error.

    Parameters
    ----------
    A, B, C, D : array_like
        ``B`` may be None.
    dt : float
    decay : float
        ``>= 0``; the eigenvalues of ``N`` that ``K`` can move go left of ``-decay``. The invariant zeros cannot
        be moved: they must lie left of ``-decay`` (else :class:`UnknownInputConditionError`).
    K : array_like, shape (n, p), optional
        A given gain instead (``N`` must be Hurwitz).

    Attributes
    ----------
    conditions : UnknownInputConditions
    E, T, N, L, G, K : ndarray
    error_eigenvalues : ndarray of complex
        Of ``N``.

    References
    ----------
    M. Darouach, M. Zasadzinski and S. J. Xu, "Full-order observers for linear systems with unknown inputs",
    IEEE TAC 39(3), 606-609, 1994; M. L. J. Hautus, "Strong detectability and observers", 1983.
    """

    _STATE = ("z", "_y_last", "x_hat")

    def __init__(self, A, B, C, D, dt, *, decay=0.0, K=None):
        super().__init__(A, B, C, dt)
        _, _, _, self.D = _check_system(self.A, None, self.C, D)
        self.conditions = unknown_input_conditions(self.A, self.C, self.D).require()
        decay = check_nonnegative("decay", decay)
        zeros = self.conditions.invariant_zeros
        if K is None and np.any(zeros.real >= -decay):
            raise UnknownInputConditionError(
                "minimum phase",
                f"expected the invariant zeros (fixed eigenvalues of N) left of -decay = {-decay}, actual value: "
                f"{zeros}",
            )
        A, B, C, D = self.A, self.B, self.C, self.D
        n, p = self.n, self.p
        self.E = -D @ np.linalg.pinv(C @ D)
        self.T = np.eye(n) + self.E @ C
        TA = self.T @ A
        if K is None:
            try:
                X = sla.solve_continuous_are((TA + decay * np.eye(n)).T, C.T, np.eye(n), np.eye(p))
            except (np.linalg.LinAlgError, ValueError):
                X = np.full((n, n), np.nan)  # refused just below, with the decay asked for
            self.K = X @ C.T
        else:
            self.K = _matrix("K", K, (n, p))
        self.N = TA - self.K @ C
        self.error_eigenvalues = np.linalg.eigvals(self.N) if np.isfinite(self.N).all() else np.full(n, np.nan)
        if K is None and not np.all(self.error_eigenvalues.real < -decay * (1.0 - 1e-9)):
            # the shifted Riccati equation places them left of -decay in exact arithmetic; far beyond the system's
            # own time scales its numerical solution does not (decay = 1e8 gave a real part of -5e4)
            raise ValueError(
                f"expected a decay the Riccati design achieves (eigenvalues of N left of -decay = {-decay:g}), "
                f"actual value: eigenvalues {self.error_eigenvalues}; choose a smaller decay or give K"
            )
        if np.any(self.error_eigenvalues.real >= 0):
            raise ValueError(f"expected N = TA - KC Hurwitz, actual value: eigenvalues {self.error_eigenvalues}")
        self.L = self.K @ (np.eye(p) + C @ self.E) - TA @ self.E
        self.G = self.T @ B
        self._Phi, Gam = _zoh(self.N, np.hstack([self.L, self.G]), self.dt)
        self._Gy, self._Gu = Gam[:, :p], Gam[:, p:]
        self._y_last = None

    def _reset(self, x0, y0):
        self.z = x0 + y0 @ self.E.T
        self._y_last = y0
        self.x_hat = x0

    def _correct(self, y):
        self._y_last = y
        self.x_hat = self.z - y @ self.E.T

    def _predict(self, u):
        self.z = self.z @ self._Phi.T + self._y_last @ self._Gy.T + u @ self._Gu.T
