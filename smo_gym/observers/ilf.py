r"""Finite-time and fixed-time observers of MIMO LTI systems designed by implicit Lyapunov functions ([LPEP16]).

For :math:`\dot x = Ax + Bu,\ y = Cx` in the block coordinates of :func:`smo_gym.design.block_decomposition`
(:math:`\Phi A\Phi^{-1} = F\tilde C + \tilde A`, :math:`C\Phi^{-1} = [C_0\ 0]`), the observers (6) and (17) are

.. math::
    \dot{\hat x} = A\hat x + Bu - \Phi^{-1}\big[\mathcal D(\|s\|)L - F\big]s,\qquad s = C_0^{-1}(y - C\hat x),

with :math:`\mathcal D(\rho) = D_{\tilde r}(\rho^{-1})` (finite time, (7)) or
:math:`\mathcal D(\rho) = \tfrac12\{D_{\tilde r}(\rho^{-1}) + D_{\tilde r}(\rho)\}` (fixed time, (17)), and the
error :math:`e = \Phi(x - \hat x)` obeys the autonomous equations (9) / (18),
:math:`\dot e = (\tilde A + \mathcal D(\|\tilde Ce\|)L\tilde C)e`.

Discretization (how a sampled implementation stays stable)
----------------------------------------------------------
The injection gains :math:`\rho^{\mp\tilde r_i}` are unbounded as :math:`\rho\to0` (finite time) and as
:math:`\rho\to\infty` (fixed time): explicit Euler is unstable for large errors at any fixed step. The step used
here is an *exact plant prediction followed by an implicit-Euler injection*:

.. math::
    \hat x^- = A_d\hat x_k + B_du_k,\qquad
    \hat x_{k+1} = \hat x^- + h\,(I - hA)^{-1}\,G(y_{k+1} - C\hat x_{k+1}),

with :math:`A_d = e^{Ah}`, :math:`B_d = \int_0^h e^{As}B\,ds` (zero-order-hold input). Because the prediction is
exact, the error of the sampled observer is autonomous (independent of the plant trajectory and of ``u``):

.. math:: (I - h\tilde A - h\mathcal D(\rho_{k+1})L\tilde C)\,e_{k+1} = (I - hA_w)e^{hA_w}\,e_k,
          \qquad A_w = \Phi A\Phi^{-1},

i.e. the implicit Euler step of (9) / (18) up to the factor :math:`(I - hA_w)e^{hA_w} = I + O(h^2)` that does not
grow with the gains. The implicit equation reduces to one scalar unknown, :math:`\rho = \|s_{k+1}\|` — the
level of the implicit Lyapunov function's argument — since for a frozen :math:`\rho` it is linear:

.. math:: \big(I_k - h\,\tilde C R_w(\mathcal D(\rho)L - F)\big)\,s_{k+1} = s^-,\qquad
          R_w = (I - hA_w)^{-1},\quad s^- = C_0^{-1}(y_{k+1} - C\hat x^-).

It is solved on :math:`\log\rho` by the Illinois method (regula falsi kept bracketing) after an expanding bracket,
compiled and row by row (:func:`solve_implicit_output_error`); the integrator-chain differentiators
(``"ilf-finite"``, ``"ilf-fixed"``) run that solver inside their compiled step. With :math:`\tilde r_m = 1` (finite
time, :math:`\mu = 1`) the last injection is discontinuous and the exact solution can be :math:`s_{k+1} = 0`; the
scheme then returns the solution with :math:`\rho = \rho_{\min}` (a regularisation at ``rho_min``, the set-valued
limit to that precision).

References
----------
.. [LPEP16] F. Lopez-Ramirez, A. Polyakov, D. Efimov and W. Perruquetti, "Finite-time and fixed-time observers
   design via implicit Lyapunov function", European Control Conference (ECC), 2016.
.. [PEB19] A. Polyakov, D. Efimov and B. Brogliato, "Consistent discretization of finite-time and fixed-time
   stable systems", SIAM J. Control Optim. 57(1), 2019.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from numba import njit

from .._validation import (
    DivergenceError,
    as_real_array,
    check_choice,
    check_int_in_range,
    check_keywords,
    check_positive,
    check_positive_array,
)
from ..design.ilf import BlockDecomposition, block_decomposition, ilf_degrees, ilf_gains
from . import _kernels
from .base import Observer
from .registry import lipschitz_unit_rule, register_observer

__all__ = [
    "ILFDifferentiator",
    "ILFObserver",
    "continuous_settling",
    "error_rhs",
    "injection_weights",
    "solve_implicit_output_error",
]


# ----------------------------------------------------------------------------------------------------------------
# pure maths
# ----------------------------------------------------------------------------------------------------------------
def injection_weights(rho, r_full: np.ndarray, kind: str) -> np.ndarray:
    r"""Diagonal of :math:`\mathcal D(\rho)`, shape ``rho.shape + (n,)``.

    ``"finite"``: :math:`\rho^{-\tilde r_i}` (7); ``"fixed"``: :math:`\tfrac12(\rho^{-\tilde r_i}+\rho^{\tilde r_i})`
    (17). ``r_full`` holds one weight per coordinate.
    """
    logr = np.log(np.asarray(rho, dtype=float))
    r_full = np.ascontiguousarray(r_full, dtype=float)
    weights = np.empty(logr.shape + r_full.shape)
    _weights_rows(logr.reshape(-1), r_full, kind == "fixed", weights.reshape(-1, r_full.size))
    return weights


@njit(cache=True, error_model="numpy")
def _weights_at(log_rho, r, fixed, d):
    """:func:`injection_weights` at one level, from its logarithm, into ``d`` (n,): the one place of the formula,
    for the compiled steps and (:func:`_weights_rows`) for NumPy callers."""
    for i in range(r.shape[0]):
        w = math.exp(-r[i] * log_rho)
        d[i] = 0.5 * (w + math.exp(r[i] * log_rho)) if fixed else w


@njit(cache=True, error_model="numpy")
def _weights_rows(log_rho, r, fixed, out):
    """:func:`_weights_at` at every level of ``log_rho`` (B,), into ``out`` (B, n)."""
    for b in range(log_rho.shape[0]):
        _weights_at(log_rho[b], r, fixed, out[b])


@njit(cache=True, error_model="numpy")
def _output_error_row(t, s_pred, Q, QF, L, h, r, fixed, d, s):
    r"""``s(rho)``, :math:`\rho = e^t`, solving :math:`(I - hQ(\mathcal D(\rho)L - F))s = s^-` for one row, into
    ``s`` (k,) (``d`` (n,) receives the weights); returns :math:`\log\|s\| - t`, decreasing through its root."""
    k, n = Q.shape
    _weights_at(t, r, fixed, d)
    if k == 1:  # scalar output: closed form
        qdl = 0.0
        for j in range(n):
            qdl += Q[0, j] * d[j] * L[j, 0]
        s[0] = s_pred[0] / (1.0 - h * (qdl - QF[0, 0]))
        norm = abs(s[0])
    else:
        N = np.empty((k, k))
        for a in range(k):
            for b in range(k):
                qdl = 0.0
                for j in range(n):
                    qdl += Q[a, j] * d[j] * L[j, b]
                N[a, b] = (1.0 if a == b else 0.0) - h * (qdl - QF[a, b])
        s[:] = np.linalg.solve(N, s_pred)
        norm = math.sqrt(np.sum(s * s))
    return math.log(max(norm, 1e-300)) - t


@njit(cache=True, error_model="numpy")
def _solve_row(s_pred, Q, QF, L, h, r, fixed, rho_min, iterations, d, s):
    """:func:`solve_implicit_output_error` for one row: ``s`` (k,) receives :math:`s_{k+1}`; returns
    :math:`\rho`."""
    norm0 = math.sqrt(np.sum(s_pred * s_pred))
    if not norm0 > 0.0:  # s_pred = 0: nothing to correct
        s[:] = 0.0
        return 0.0
    lo = math.log(rho_min)
    f_lo = _output_error_row(lo, s_pred, Q, QF, L, h, r, fixed, d, s)
    hi = math.log(max(norm0, rho_min)) + 1.0
    f_hi = _output_error_row(hi, s_pred, Q, QF, L, h, r, fixed, d, s)
    for _ in range(80):  # expand the bracket upwards until phi <= 0
        if not f_hi > 0:
            break
        hi += 5.0
        f_hi = _output_error_row(hi, s_pred, Q, QF, L, h, r, fixed, d, s)
    set_valued = f_lo <= 0  # no root above rho_min: the discontinuous injection zeroes s
    # Illinois (modified regula falsi) on the bracket [a, b], phi(a) > 0 >= phi(b)
    a, b, fa, fb = lo, hi, f_lo, f_hi
    todo = not set_valued
    side = 0
    for _ in range(iterations):
        if not todo:
            break
        denom = fb - fa
        t_new = b - fb * (b - a) / denom if denom != 0 else 0.5 * (a + b)
        t_new = min(max(t_new, min(a, b)), max(a, b))
        f_new = _output_error_row(t_new, s_pred, Q, QF, L, h, r, fixed, d, s)
        pos = f_new > 0
        # keep the bracket: replace the end with the same sign; halve the other's value if it stayed twice
        if pos:
            if side == -1:
                fb = 0.5 * fb
            a, fa, side = t_new, f_new, -1
        else:
            if side == 1:
                fa = 0.5 * fa
            b, fb, side = t_new, f_new, 1
        todo = abs(f_new) > 1e-14 and abs(b - a) > 1e-14 * (1.0 + abs(b))
    t = lo if set_valued else (a if abs(fa) < abs(fb) else b)  # the better end
    _output_error_row(t, s_pred, Q, QF, L, h, r, fixed, d, s)
    return math.exp(t)


@njit(cache=True, error_model="numpy")
def _solve_rows(s_pred, Q, QF, L, h, r, fixed, rho_min, iterations, s_new, rho):
    """:func:`_solve_row` for every row (``Q``, ``QF``, ``L``: one row for all or one per row)."""
    d = np.empty(r.shape[0])
    for i in range(s_pred.shape[0]):
        j = 0 if Q.shape[0] == 1 else i
        jf = 0 if QF.shape[0] == 1 else i
        jl = 0 if L.shape[0] == 1 else i
        rho[i] = _solve_row(s_pred[i], Q[j], QF[jf], L[jl], h[i], r, fixed, rho_min, iterations, d, s_new[i])


def solve_implicit_output_error(
    s_pred, Q, QF, L, h, r_full, kind: str, *, rho_min: float = 1e-14, iterations: int = 60
) -> tuple[np.ndarray, np.ndarray]:
    r"""Solve the implicit injection of the ILF observers for :math:`s_{k+1}` and :math:`\rho = \|s_{k+1}\|`.

    .. math:: \big(I_k - hQ(\mathcal D(\rho)L - F)\big)s = s^-,\qquad \rho = \|s\|,\qquad Q = \tilde CR_w.

    Parameters
    ----------
    s_pred : ndarray, shape (B, k)
        Predicted output error :math:`s^-`.
    Q : ndarray, shape (B or 1, k, n)
    QF : ndarray, shape (B or 1, k, k)
        :math:`QF`.
    L : ndarray, shape (B or 1, n, k)
    h : ndarray, shape (B,)
        Step (per batch row).
    r_full : ndarray, shape (n,)
        Homogeneity weights per coordinate.
    kind : {"finite", "fixed"}
    rho_min : float
        Lower end of the bracket; below it the discontinuous case is regularised.
    iterations : int
        Largest number of Illinois (safeguarded regula falsi) iterations on :math:`\log\rho`; it stops earlier
        once :math:`|\log\|s(\rho)\| - \log\rho| < 10^{-14}`.

    Returns
    -------
    s_new : ndarray, shape (B, k)
    rho : ndarray, shape (B,)

    Notes
    -----
    Compiled, row by row: the integrator-chain differentiators (``"ilf-finite"``, ``"ilf-fixed"``) call the same
    row solver from their compiled step.
    """
    s_pred = np.ascontiguousarray(s_pred, dtype=float)
    s_new = np.zeros_like(s_pred)
    rho = np.zeros(s_pred.shape[0])
    Q, QF, L, h, r_full = (np.ascontiguousarray(a, dtype=float) for a in (Q, QF, L, h, r_full))
    _solve_rows(s_pred, Q, QF, L, h, r_full, kind == "fixed", float(rho_min), int(iterations), s_new, rho)
    return s_new, rho


def _zoh(A: np.ndarray, B: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation ``(A_d, B_d)`` (block matrix exponential)."""
    n, s = B.shape
    M = np.zeros((n + s, n + s))
    M[:n, :n], M[:n, n:] = A, B
    from scipy.linalg import expm  # lazy: importing scipy.linalg costs ~0.4 s of `import smo_gym`

    E = expm(M * h)
    return E[:n, :n], E[:n, n:]


# ----------------------------------------------------------------------------------------------------------------
# continuous-time reference: the error equations (9) / (18) integrated with adaptive steps
# ----------------------------------------------------------------------------------------------------------------
# Dormand-Prince 5(4) tableau (the method of scipy's RK45)
_DP_A = np.array(
    [
        [0, 0, 0, 0, 0, 0],
        [1 / 5, 0, 0, 0, 0, 0],
        [3 / 40, 9 / 40, 0, 0, 0, 0],
        [44 / 45, -56 / 15, 32 / 9, 0, 0, 0],
        [19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729, 0, 0],
        [9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656, 0],
        [35 / 384, 0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84],
    ]
)
_DP_B = np.append(_DP_A[6], 0.0)  # 5th-order weights (the last stage is only for the error)
_DP_E = np.array([71 / 57600, 0, -71 / 16695, 71 / 1920, -17253 / 339200, 22 / 525, -1 / 40])


def error_rhs(e: np.ndarray, A_tilde, C_tilde, L, r_full, kind: str) -> np.ndarray:
    r"""Right-hand side of the error equations (9) (``"finite"``) and (18) (``"fixed"``) of Lopez-Ramirez et al.
    2016: :math:`\dot e = (\tilde A + \mathcal D(\|\tilde Ce\|)L\tilde C)e`, NumPy reference of :func:`_rhs`."""
    s = C_tilde @ e
    rho = np.linalg.norm(s)
    if rho == 0.0:
        return A_tilde @ e
    d = rho ** (-r_full) if kind == "finite" else 0.5 * (rho ** (-r_full) + rho**r_full)
    return A_tilde @ e + d * (L @ s)


@njit(cache=True)
def _rhs(e, At, Ct, L, r, fixed, out):  # pragma: no cover - compiled
    s = Ct @ e
    rho = np.sqrt(np.sum(s * s))
    Ls = L @ s
    for i in range(e.size):
        acc = 0.0
        for j in range(e.size):
            acc += At[i, j] * e[j]
        if rho > 0.0:
            d = 0.5 * (rho ** (-r[i]) + rho ** r[i]) if fixed else rho ** (-r[i])
            acc += d * Ls[i]
        out[i] = acc


@njit(cache=True)
def _dopri(e0, At, Ct, L, r, fixed, Tinv, t_end, t_query, tol, floor, rtol, atol):  # pragma: no cover - compiled
    n = e0.size
    K = np.zeros((7, n))
    e = e0.copy()
    t, h, steps = 0.0, 1e-7, 0
    last_above = 0.0 if np.sqrt(np.sum((Tinv @ e) ** 2)) > tol else -1.0
    at_query = np.nan
    _rhs(e, At, Ct, L, r, fixed, K[0])
    while t < t_end:
        if t < t_query < t + h:
            h = t_query - t  # land on t_query
        h = min(h, t_end - t)
        for i in range(1, 7):
            y = e.copy()
            for j in range(i):
                y += h * _DP_A[i, j] * K[j]
            _rhs(y, At, Ct, L, r, fixed, K[i])
        y = e.copy()
        err = np.zeros(n)
        for j in range(7):
            y += h * _DP_B[j] * K[j]
            err += h * _DP_E[j] * K[j]
        scale = atol + rtol * np.maximum(np.abs(e), np.abs(y))
        en = np.sqrt(np.mean((err / scale) ** 2))
        if en <= 1.0 and np.all(np.isfinite(y)):
            t += h
            e = y
            K[0] = K[6]  # first same as last
            steps += 1
            nx = np.sqrt(np.sum((Tinv @ e) ** 2))
            if nx > tol:
                last_above = t
            if abs(t - t_query) <= 1e-12 * max(1.0, t_query):
                at_query = nx
            if nx <= floor:
                break
            h *= min(5.0, max(0.2, 0.9 * en ** (-0.2))) if en > 0 else 5.0
        else:
            h *= max(0.1, 0.9 * en ** (-0.2)) if np.isfinite(en) else 0.1
    return t, last_above, at_query, steps


def continuous_settling(
    e0,
    dec,
    L,
    mu: float,
    kind: str,
    *,
    tol: float = 2e-4,
    t_query: float = 1.75,
    rtol: float = 1e-10,
    t_end: float = 10.0,
) -> dict:
    r"""Settling of the continuous-time error equation (9) (``"finite"``) or (18) (``"fixed"``) of [LPEP16].

    :math:`\dot e = (\tilde A + \mathcal D(\|\tilde Ce\|)L\tilde C)e` from :math:`e(0) = \Phi(x(0) - \hat x(0))`,
    integrated by an adaptive Dormand-Prince 5(4) method (compiled; relative tolerance ``rtol``, absolute 1e-14)
    until :math:`\|x - \hat x\| = \|\Phi^{-1}e\| \le tol/100`. The reference against which the sampled observer
    (whose implicit step damps the error) is judged: halve ``rtol`` by decades until the results agree.

    Parameters
    ----------
    e0 : array_like, shape (n,)
        Initial error in block coordinates.
    dec : BlockDecomposition
        The coordinates ``L`` is expressed in (:math:`\Phi`, :math:`\tilde A`, :math:`\tilde C`).
    L : array_like, shape (n, k)
    mu : float
    kind : {"finite", "fixed"}
    tol : float
        Convergence threshold on :math:`\|x - \hat x\|` (2e-4: Section V.B).
    t_query : float
        A time at which :math:`\|x - \hat x\|` is reported (the step lands on it).
    rtol, t_end : float

    Returns
    -------
    dict
        ``T``: the last time :math:`\|x - \hat x\| > tol` (resolution one accepted step), ``at_query``: the norm at
        ``t_query`` (``nan`` if it stopped earlier: the norm was below ``tol / 100`` then), ``t_stop``, ``steps``.

    Raises
    ------
    RuntimeError
        If the error is not below ``tol / 100`` by ``t_end``.
    """
    kind = check_choice("kind", kind, ("finite", "fixed"))
    for name, value in (("tol", tol), ("t_query", t_query), ("rtol", rtol), ("t_end", t_end), ("mu", mu)):
        check_positive(name, value)
    e0 = as_real_array("e0", e0)
    if e0.shape != (dec.n,) or not np.isfinite(e0).all():
        raise ValueError(f"expected a finite e0 with shape ({dec.n},), actual value: {e0!r}")
    r = np.repeat(ilf_degrees(dec.m, mu), dec.block_sizes).astype(float)
    t, T, at_q, steps = _dopri(
        e0,
        dec.A_tilde,
        dec.C_tilde,
        np.asarray(L, dtype=float),
        r,
        kind == "fixed",
        np.linalg.inv(dec.Phi),
        t_end,
        t_query,
        tol,
        tol / 100.0,
        rtol,
        1e-14,
    )
    if not t < t_end:
        raise RuntimeError(f"expected the error below {tol / 100} before t = {t_end}, actual value: not reached")
    return dict(T=T, at_query=at_q, t_stop=t, steps=steps)


# ----------------------------------------------------------------------------------------------------------------
# MIMO observer
# ----------------------------------------------------------------------------------------------------------------
class ILFObserver:
    r"""Finite-time (6)-(9) or fixed-time (17)-(18) observer of [LPEP16] for :math:`\dot x = Ax + Bu,\ y = Cx`.

    See the module docstring for the equations and the discretization (exact ZOH prediction + implicit-Euler
    injection solved for the scalar :math:`\rho = \|s_{k+1}\|` by a bracketing root finder): stable at any step
    ``dt`` and for any initial error, and its error sequence is independent of the plant trajectory.

    Parameters
    ----------
    A : array_like, shape (n, n)
    C : array_like, shape (k, n)
        Full row rank, ``(A, C)`` observable.
    L : array_like, shape (n, k)
        Gain in the block coordinates (from :func:`smo_gym.design.ilf_gains`, or printed in the paper), with
        :math:`\tilde A + L\tilde C` Hurwitz.
    mu : float
        Homogeneity parameter of the design (``0 < mu <= 1`` finite, ``0 < mu < 1`` fixed).
    kind : {"finite", "fixed"}
    dt : float
        Sampling step ``h``.
    B : array_like, shape (n, s), optional
        Input matrix (default: no input).
    decomposition : BlockDecomposition, optional
        Default :func:`smo_gym.design.block_decomposition` of ``(A, C)``; pass the paper's (or the design's) to
        match the coordinates ``L`` was computed in.
    rho_min : float
        Regularisation of the discontinuous case (see Notes of the module).
    iterations : int
        Largest number of root-finder iterations per step.

    Attributes
    ----------
    n_updates : int
    rho : ndarray, shape (...)
        :math:`\|s_{k+1}\|` of the last step (the injection's level).

    Notes
    -----
    Shapes: ``reset(x0_hat)`` with ``x0_hat`` of shape ``(..., n)`` fixes the batch shape ``(...)``; then
    ``update(y, u)`` takes ``y`` of shape ``(..., k)`` (and ``u`` ``(..., s)``) measured at the *end* of the step
    (``u`` held over it) and returns :math:`\hat x_{k+1}`, shape ``(..., n)``.
    """

    @check_keywords
    def __init__(
        self,
        A,
        C,
        L,
        mu: float,
        kind: str = "finite",
        *,
        dt: float,
        B=None,
        decomposition: BlockDecomposition | None = None,
        rho_min: float = 1e-14,
        iterations: int = 60,
    ):
        self.kind = check_choice("kind", kind, ("finite", "fixed"))
        self.mu = check_positive("mu", mu)
        if self.kind == "finite" and self.mu > 1:
            raise ValueError(f"expected 0 < mu <= 1 for the finite-time observer, actual value: {mu!r}")
        if self.kind == "fixed" and self.mu >= 1:
            raise ValueError(f"expected 0 < mu < 1 for the fixed-time observer, actual value: {mu!r}")
        self.dt = check_positive("dt", dt)
        self.rho_min = check_positive("rho_min", rho_min)
        self.iterations = check_int_in_range("iterations", iterations, 1, 200)
        A = as_real_array("A", A)
        if A.ndim != 2 or A.shape[0] != A.shape[1] or A.size == 0 or not np.isfinite(A).all():
            raise ValueError(f"expected a finite square matrix A (n, n), actual value: {A!r}")
        C = as_real_array("C", C)
        if C.ndim not in (1, 2) or C.shape[-1] != A.shape[0] or C.size == 0 or not np.isfinite(C).all():
            raise ValueError(f"expected a finite C with shape (k, {A.shape[0]}), actual value: {C!r}")
        C = C.reshape(-1, A.shape[0])
        if decomposition is None:
            try:
                decomposition = block_decomposition(A, C)
            except np.linalg.LinAlgError as exc:
                raise ValueError(
                    f"expected A and C with a computable block decomposition, actual value: {exc}"
                ) from None
        elif not isinstance(decomposition, BlockDecomposition):
            raise TypeError(f"expected a BlockDecomposition, actual value: {type(decomposition).__name__}")
        dec = decomposition
        self.decomposition = dec
        n, k = dec.n, dec.C0.shape[0]
        if A.shape != (n, n) or C.shape != (k, n):
            raise ValueError(
                f"expected A ({n}, {n}) and C ({k}, {n}) matching the decomposition, actual value: "
                f"A {A.shape}, C {C.shape}"
            )
        L = as_real_array("L", L)
        if L.shape != (n, k) or not np.all(np.isfinite(L)):
            raise ValueError(f"expected a finite L with shape ({n}, {k}), actual value: shape {L.shape}")
        abscissa = float(np.max(np.linalg.eigvals(dec.A_tilde + L @ dec.C_tilde).real))
        if abscissa >= 0:
            raise ValueError(
                f"expected L with A_tilde + L C_tilde Hurwitz, actual value: spectral abscissa {abscissa:.3g}"
            )
        if B is None:
            B = np.zeros((n, 0))
        else:
            B = as_real_array("B", B)
            if B.ndim not in (1, 2) or B.shape[0] != n or not np.isfinite(B).all():
                raise ValueError(f"expected a finite B with shape ({n}, s), actual value: {B!r}")
            B = B.reshape(n, -1)
        self.A, self.C, self.B, self.L = A, C, B, L
        h = self.dt
        self._Ad, self._Bd = _zoh(A, B, h)
        Aw = dec.Phi @ A @ np.linalg.inv(dec.Phi)
        Rw = np.linalg.inv(np.eye(n) - h * Aw)
        self._Q = (dec.C_tilde @ Rw)[None]  # (1, k, n)
        self._QF = (self._Q[0] @ dec.F)[None]
        self._L = L[None]
        self._Psi = np.linalg.inv(np.eye(n) - h * A) @ np.linalg.inv(dec.Phi)  # (I - hA)^-1 Phi^-1
        self._C0inv = np.linalg.inv(dec.C0)
        self._r = np.repeat(ilf_degrees(dec.m, self.mu), dec.block_sizes)
        if not all(np.isfinite(M).all() for M in (self._Ad, self._Bd, self._Q, self._Psi)):
            raise ValueError(
                f"expected A and dt with a finite discretization e^(A dt), actual value: dt={self.dt!r}, "
                f"spectral radius of A {float(np.max(np.abs(np.linalg.eigvals(A)))):.3g}"
            )
        self._x: np.ndarray | None = None
        self.rho: np.ndarray | None = None
        self.n_updates = 0

    @property
    def n(self) -> int:
        return self.A.shape[0]

    @classmethod
    def from_design(cls, A, C, design, *, dt: float, B=None, **kwargs) -> ILFObserver:
        """Build from an :class:`smo_gym.design.ILFDesign` (its gain, ``mu``, kind and decomposition)."""
        return cls(A, C, design.L, design.mu, design.kind, dt=dt, B=B, decomposition=design.decomposition, **kwargs)

    @check_keywords
    def reset(self, x0_hat) -> np.ndarray:
        """Start at the estimate ``x0_hat`` (shape ``(..., n)``); returns a copy of it."""
        x0 = self._array(x0_hat, "x0_hat", self.n)
        self._x = x0.copy()
        self.rho = np.zeros(x0.shape[:-1])
        self.n_updates = 0
        return x0.copy()

    def _array(self, value, name: str, width: int) -> np.ndarray:
        arr = as_real_array(name, value, copy=True)
        if arr.ndim == 0 or arr.shape[-1] != width or arr.size == 0:
            raise ValueError(
                f"expected {name} with shape (..., {width}) and no empty batch dimension, actual value: "
                f"shape {arr.shape}"
            )
        if not np.all(np.isfinite(arr)):
            bad = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
            raise ValueError(
                f"expected finite values in {name}, actual value: {arr[bad]!r} at channel {bad[-1]}"
                + (f" of batch element {bad[:-1]}" if len(bad) > 1 else "")
            )
        return arr

    def update(self, y, u=None) -> np.ndarray:
        r"""One step: ``y`` measured at :math:`t_{k+1}`, ``u`` held on :math:`[t_k, t_{k+1})`.

        Returns :math:`\hat x_{k+1}`, shape ``(..., n)``.
        """
        if self._x is None:
            raise RuntimeError("expected reset(x0_hat) before update(y), actual value: the observer was never reset")
        batch = self._x.shape[:-1]
        y = self._array(y, "y", self.C.shape[0])
        if y.shape[:-1] != batch:
            raise ValueError(f"expected y with shape {batch + (self.C.shape[0],)}, actual value: {y.shape}")
        s_dim = self.B.shape[1]
        x = self._x.reshape(-1, self.n)
        if u is not None:
            if s_dim == 0:
                raise ValueError("expected u=None for an observer built without B, actual value: an input")
            u = self._array(u, "u", s_dim)
            try:
                u = np.broadcast_to(u, batch + (s_dim,)).reshape(-1, s_dim)
            except ValueError:
                raise ValueError(f"expected u with shape {batch + (s_dim,)}, actual value: {u.shape}") from None
        with np.errstate(all="ignore"):  # an overflow is reported below as a divergence, the state kept
            x_pred = x @ self._Ad.T
            if u is not None:
                x_pred = x_pred + u @ self._Bd.T
            s_pred = (y.reshape(-1, y.shape[-1]) - x_pred @ self.C.T) @ self._C0inv.T
            h = np.full(x.shape[0], self.dt)
            s_new, rho = solve_implicit_output_error(
                s_pred,
                self._Q,
                self._QF,
                self._L,
                h,
                self._r,
                self.kind,
                rho_min=self.rho_min,
                iterations=self.iterations,
            )
            d = injection_weights(np.where(rho > 0, rho, 1.0), self._r, self.kind)
            inj = d * (s_new @ self.L.T) - s_new @ self.decomposition.F.T  # (D L - F) s, in block coordinates
            x_new = x_pred - self.dt * inj @ self._Psi.T
        if not np.all(np.isfinite(x_new)):
            raise DivergenceError(
                "expected a finite observer state, actual value: non-finite after update "
                f"(dt={self.dt}); the previous state was kept"
            )
        self._x = x_new.reshape(batch + (self.n,))
        self.rho = rho.reshape(batch)
        self.n_updates += 1
        return self._x.copy()

    @property
    def estimate(self) -> np.ndarray:
        """Last estimate :math:`\\hat x`, shape ``(..., n)``."""
        if self._x is None:
            raise RuntimeError("expected reset(x0_hat) first, actual value: the observer was never reset")
        return self._x.copy()

    def error_coordinates(self, x) -> np.ndarray:
        r""":math:`e = \Phi(x - \hat x)` for a true state ``x`` of shape ``(..., n)``."""
        x = self._array(x, "x", self.n)
        try:
            with np.errstate(over="ignore", invalid="ignore"):
                e = (x - self.estimate) @ self.decomposition.Phi.T
        except ValueError:
            raise ValueError(f"expected x with shape {self.estimate.shape}, actual value: {x.shape}") from None
        if not np.isfinite(e).all():
            raise ValueError(
                f"expected x close enough to the estimate for finite error coordinates, actual value: {x!r}"
            )
        return e

    def __repr__(self) -> str:
        return f"ILFObserver(kind={self.kind!r}, mu={self.mu}, dt={self.dt}, n={self.n}, k={self.C.shape[0]})"


# ----------------------------------------------------------------------------------------------------------------
# integrator-chain adapter (the differentiator registered as "ilf-finite" / "ilf-fixed")
# ----------------------------------------------------------------------------------------------------------------
_DEFAULT_MU = {"finite": 1.0, "fixed": 0.5}


@lru_cache(maxsize=32)
def chain_gain(n: int, mu: float, kind: str, alpha: float | None) -> tuple[float, ...]:
    r"""ILF gain of the ``n``-integrator chain (``C = e_1``), from :func:`smo_gym.design.ilf_gains` (cached).

    For the chain :math:`\Phi = I`, ``F = 0``, every block is scalar and :math:`\tilde r_i = i\mu/(1+(n-1)\mu)`; with
    ``mu = 1`` the finite-time observer is Levant's differentiator in the non-recursive form (exponents
    :math:`1 - i/n`), with gains from the LMIs.
    """
    A = np.diag(np.ones(n - 1), 1)
    C = np.eye(1, n)
    dec = block_decomposition(A, C, Phi=np.eye(n))  # the chain is its own block form: Phi = I, F = 0
    design = ilf_gains(A, C, mu, kind, alpha=alpha, condition="points", decomposition=dec)
    return tuple(design.L[:, 0])


@njit(cache=True, error_model="numpy")
def ilf_chain_rows(state, y, params, new_state, out, shared):
    r"""One step of the chain observer on every channel, in the time scale :math:`\tau = \omega t` (the calling
    convention of :mod:`smo_gym.observers._kernels`; ``shared``: one parameter row for every channel).

    ``state`` rows ``[x~_1..x~_m, innovation]`` with :math:`\tilde x_i = \hat x_i/\omega^{i-1}`; ``params`` rows
    ``[h, omega, kind(0 finite/1 fixed), rho_min, u, L_1..L_m, r_1..r_m]``, ``u`` the channel's unit, ``r`` the
    weights :func:`~smo_gym.design.ilf_degrees` of ``mu``: the step runs on
    :math:`y/u` and :math:`\tilde x/u`. It is the step of :class:`ILFObserver` with :math:`A` the shift matrix,
    :math:`\Phi = I`, ``F = 0`` and step :math:`\omega h`: the exact prediction :math:`e^{hN}\tilde x` (Taylor),
    the implicit output error of :func:`solve_implicit_output_error` (its row solver, :math:`Q` the first row
    ``[1, h, h^2, ...]`` of :math:`(I - hN)^{-1}`), and the injection :math:`h(I - hN)^{-1}\mathcal D(\rho)Ls`.
    """
    m = out.shape[1]
    Q = np.empty((1, m))  # the first row of R = (I - hN)^-1: [1, h, h^2, ...]
    QF = np.zeros((1, 1))
    L = np.empty((m, 1))
    r = np.empty(m)
    d = np.empty(m)
    s_pred = np.empty(1)
    s = np.empty(1)
    x = np.empty(m)
    failed = False
    for c in range(y.shape[0]):
        p = params[0 if shared else c]
        omega, fixed, rho_min, unit = p[1], p[2] != 0.0, p[3], p[4]
        h = p[0] * omega  # the step in tau
        power = 1.0
        for i in range(m):
            L[i, 0] = p[5 + i]
            r[i] = p[5 + m + i]
            Q[0, i] = power
            power *= h
        for i in range(m):  # the exact prediction, in units of u (the fixed-time weights take |s| in them)
            acc = 0.0
            term = 1.0  # h^(j - i) / (j - i)!
            for j in range(i, m):
                acc += state[c, j] / unit * term
                term *= h / (j - i + 1)
            x[i] = acc
        s_pred[0] = y[c] / unit - x[0]
        rho = _solve_row(s_pred, Q, QF, L, h, r, fixed, rho_min, 60, d, s)
        _weights_at(math.log(rho) if rho > 0 else 0.0, r, fixed, d)  # weights 1 where rho is 0
        for i in range(m):  # the injection D(rho) L s
            d[i] = d[i] * L[i, 0] * s[0]
        scale = 1.0
        for i in range(m):  # x_new = x_pred - h R inj, R_ij = h^(j-i) for j >= i
            acc = 0.0
            for j in range(i, m):
                acc += d[j] * Q[0, j - i]
            new_state[c, i] = (x[i] - h * acc) * unit
            out[c, i] = new_state[c, i] * scale
            scale *= omega
        new_state[c, m] = y[c] - unit * x[0]
        for i in range(m + 1):
            failed |= not math.isfinite(new_state[c, i])
        for i in range(m):
            failed |= not math.isfinite(out[c, i])
    return _kernels._check_state(new_state, out) if failed else -1


_STEP = _kernels.register_step(ilf_chain_rows, allocates=True)


@register_observer(
    "ilf-finite",
    steps=(_STEP,),
    calibrate=lipschitz_unit_rule,
    given=(("lipschitz",), ("rate",)),
    examples=(dict(order=1, lipschitz=20.0),),
)
class ILFDifferentiator(Observer):
    r"""Lopez-Ramirez et al.'s finite-time / fixed-time observer applied to each channel as an integrator chain.

    Each channel's signal ``f`` is the output of the chain :math:`x_1 = f,\ \dot x_i = x_{i+1}` of ``order + 1``
    states. The observer of :class:`ILFObserver` for that chain (:math:`\Phi = I`, ``F = 0``, gains ``L`` from
    :func:`smo_gym.design.ilf_gains`) runs in the time scale :math:`\tau = \omega t` (so one LMI design serves every
    channel): in the original time the correction of :math:`\hat x_i` is
    :math:`-\omega^i L_i\,\mathcal D_i(|s|)\,s`. For ``kind="finite"`` with ``mu = 1`` this is Levant's
    differentiator in non-recursive form; the default rate
    :math:`\omega = (1.1\,L_f/(u|L_n|))^{1/n}` (``u`` the ``unit``) makes its discontinuous last gain
    :math:`u\,\omega^n|L_n|` equal to Levant's :math:`\lambda_0 L_f = 1.1 L_f` for :math:`|f^{(n)}| \le L_f`
    (``lipschitz``). For ``mu < 1`` (and the
    fixed-time kind) the injections are continuous: exact for polynomial signals of degree ``< n`` only, with an
    error of order :math:`L_f` otherwise.

    Parameters
    ----------
    dt : float
    lipschitz : float or array_like, optional
        :math:`L_f`, per channel; sets the default ``rate``.
    order : int
        Derivatives estimated, ``1 <= order <= 4``.
    mu : float, optional
        Default 1 (finite) or 0.5 (fixed).
    alpha : float, optional
        Fixed-time rate of Theorem 10 in the :math:`\tau` scale (default 2).
    rate : float or array_like, optional
        :math:`\omega` (1/s), overrides the default from ``lipschitz``.
    gain : array_like, shape (order + 1,), optional
        ``L`` in the :math:`\tau` scale (default: :func:`chain_gain`).
    rho_min : float
        The smallest level :math:`\rho` the implicit step resolves (module notes), in units of ``unit``.
    unit : float or array_like
        The size of one unit of ``y`` (per channel if an array; default 1): the observer runs on ``y / unit``, where
        the fixed-time weights :math:`\rho^{\tilde r_i}` of positive degree take :math:`|s| = 1` as the level at
        which the fixed-time part takes over. Calibrated (the registry's gain rule) it is the calibration's
        :attr:`~smo_gym.calibration.Calibration.unit`: 1 for the wrapper's joints, so that a record in other units
        gives the same estimates in them. The finite-time kind is homogeneous and the same in any unit (but for
        ``rho_min``).
    discretization : {"implicit"}
        Exact chain prediction plus implicit-Euler injection (see :mod:`smo_gym.observers.ilf`); stable at any
        step and any error.
    wrap : bool or array_like of bool, optional
        Channels measured as angles modulo ``2 pi`` (see :class:`~smo_gym.observers.Observer`).

    Notes
    -----
    The first construction for a given ``(order, mu, kind, alpha)`` solves the LMIs (1-5 s, cvxpy); the gain is
    cached for the process. The default rate suits ``kind="finite", mu=1`` (Levant-like, exact under
    :math:`|f^{(n)}|\le L_f`); for ``kind="fixed"`` it is usually slow and the error under :math:`f^{(n)}\ne0`
    is of order :math:`L_f/\omega^n` — pass a larger ``rate`` for tracking.
    """

    discretizations = ("implicit",)
    kind = "finite"

    @check_keywords
    def __init__(
        self,
        dt: float,
        lipschitz=None,
        *,
        order: int = 1,
        mu: float | None = None,
        alpha: float | None = None,
        rate=None,
        gain=None,
        rho_min: float = 1e-14,
        unit=1.0,
        discretization: str | None = None,
        wrap=None,
    ):
        order = check_int_in_range("order", order, 1, 4)
        super().__init__(dt, order, discretization, wrap)
        n = order + 1
        self.mu = _DEFAULT_MU[self.kind] if mu is None else check_positive("mu", mu)
        if (self.kind == "finite" and self.mu > 1) or (self.kind == "fixed" and self.mu >= 1):
            raise ValueError(
                f"expected 0 < mu {'<=' if self.kind == 'finite' else '<'} 1 for the {self.kind}-time "
                f"observer, actual value: {mu!r}"
            )
        alpha = None if alpha is None else check_positive("alpha", alpha)  # checked even where the kind ignores it
        self.alpha = None if self.kind == "finite" else (2.0 if alpha is None else alpha)
        if lipschitz is None and rate is None:
            raise ValueError("expected lipschitz > 0 or rate > 0, actual value: both None")
        for name, value in (("lipschitz", lipschitz), ("rate", rate), ("unit", unit)):
            if value is not None:
                check_positive_array(name, value)  # fail at construction, not at reset
        self.lipschitz, self.rate, self.unit = lipschitz, rate, unit
        if gain is None:
            gain = chain_gain(n, self.mu, self.kind, self.alpha)
        gain = as_real_array("gain", gain)
        if gain.shape != (n,) or not np.isfinite(gain).all():
            raise ValueError(f"expected a finite gain with shape ({n},), actual value: {gain!r}")
        # the error dynamics of the chain (Phi = I, F = 0) are those of A_tilde + L C_tilde = N + L e_1^T: the
        # design needs that matrix Hurwitz (a zero last gain, say, would leave the last derivative uncorrected)
        abscissa = float(np.max(np.linalg.eigvals(np.eye(n, k=1) + np.outer(gain, np.eye(n)[0])).real))
        if not abscissa < 0:
            raise ValueError(
                f"expected a gain L with N + L e_1^T Hurwitz (L from smo_gym.design.ilf_gains), actual "
                f"value: {gain.tolist()}, spectral abscissa {abscissa:.3g}"
            )
        self.gain = gain
        self.rho_min = check_positive("rho_min", rho_min)

    @property
    def _kernel(self):
        return _STEP.kernel

    def _load_estimate(self, state, x0, params):
        r"""The state in the time scale :math:`\tau = \omega t`: :math:`\tilde x_i = \hat x_i/\omega^{i-1}`."""
        m = self.order + 1
        state[:, :m] = x0 / params[:, 1:2] ** np.arange(m)[None, :]

    def _channel_params(self, shape):
        n = self.order + 1
        unit = self._per_channel("unit", self.unit, shape)
        if self.rate is not None:
            omega = self._per_channel("rate", self.rate, shape)
        else:  # from the bound of y / unit: the same rate in any units (the finite kind is homogeneous)
            omega = (1.1 * self._per_channel("lipschitz", self.lipschitz, shape) / unit / abs(self.gain[-1])) ** (
                1.0 / n
            )
        N = omega.size
        head = np.column_stack(
            [
                np.full(N, self.dt),
                omega,
                np.full(N, 0.0 if self.kind == "finite" else 1.0),
                np.full(N, self.rho_min),
                unit,
            ]
        )
        weights = ilf_degrees(n, self.mu)
        return np.hstack([head, np.broadcast_to(self.gain, (N, n)), np.broadcast_to(weights, (N, n))])


@register_observer(
    "ilf-fixed",
    steps=(_STEP,),
    calibrate=lipschitz_unit_rule,
    given=(("lipschitz",), ("rate",)),
    examples=(dict(order=1, rate=30.0),),
)
class ILFFixedDifferentiator(ILFDifferentiator):
    __doc__ = ILFDifferentiator.__doc__
    kind = "fixed"
