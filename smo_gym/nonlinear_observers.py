r"""HOSM observers for locally weakly observable BIBS nonlinear systems (Fridman, Shtessel, Edwards and Yan 2008).

The system, with ``n`` states, ``p`` outputs, a known input ``u`` and an unknown bounded input ``w``,

.. math::
    \dot x = f(x) + g(x)\,u(t) + d(x)\,w(t),\qquad y = h(x) \in \mathbb R^p,

is watched through its *observability map*: for observability indices :math:`r_1 + \dots + r_p = n`,

.. math::
    \xi = \Phi(x) = \big(h_1, L_f h_1, \ldots, L_f^{r_1-1}h_1,\ \ldots,\ h_p, \ldots, L_f^{r_p-1}h_p\big),
    \qquad L_f\varphi = \frac{\partial\varphi}{\partial x} f,

the coordinates of Fridman's slides ("Coordinate transformation", section 5). Two assumptions make it an observer:

* **local weak observability**: :math:`\partial\Phi/\partial x` has rank ``n`` on the region the state visits,
  so that :math:`\Phi` is a local diffeomorphism (:func:`check_observability` tests it on points);
* **relative degree**: the inputs reach the outputs only through their :math:`r_i`-th derivative,
  :math:`L_g L_f^j h_i = L_d L_f^j h_i = 0` for :math:`j < r_i - 1` (the slides' transformed system has the input
  term :math:`\lambda^i` in its last row only; the same condition as Davila, Fridman, Pisano and Usai 2009,
  :math:`dL_f^i h\,D = 0`, :math:`i \le n-2`). Then :math:`y_i^{(j)} = L_f^j h_i(x)` for :math:`j < r_i`, and

  .. math:: y_i^{(r_i)} = L_f^{r_i}h_i(x) + L_g L_f^{r_i-1}h_i(x)\,u + L_d L_f^{r_i-1}h_i(x)\,w

  is bounded when the state stays bounded (the system is BIBS) and the inputs are bounded: a Lipschitz constant
  :math:`L_i \ge |y_i^{(r_i)}|` exists, which is all Levant's differentiator needs.

The observer (:class:`NonlinearHOSMObserver`) differentiates each output with Levant's differentiator of order
:math:`r_i - 1` (eq. (16) of the slides, :class:`smo_gym.observers.Levant`), which gives :math:`\hat\xi = \Phi(x)`
after a finite time, and recovers the state by solving :math:`\Phi(\hat x) = \hat\xi` with Newton's method,
warm-started at the previous estimate. Neither ``u`` nor ``w`` is needed by the observer: by the relative-degree
condition they act on :math:`y^{(r_i)}` only, which the differentiator treats as an unknown bounded signal.

Accuracy (sampled with step :math:`\tau`, the order-``k`` differentiator's :math:`|z_j - y^{(j)}| =
O(L\tau^{k+1-j})` noise-free and :math:`O(L^{j/(k+1)}\varepsilon^{(k+1-j)/(k+1)})` under noise of amplitude
:math:`\varepsilon`, Levant 2003, Livne and Levant 2014): :math:`\hat x - x = (\partial\Phi/\partial x)^{-1}
(\hat\xi - \xi) + O(|\hat\xi - \xi|^2)`, so the state error is of the order of the *worst* derivative, the
:math:`(r_i - 1)`-th, with :math:`k = r_i - 1`: :math:`O(\tau)` noise-free and :math:`O(\varepsilon^{1/r})`
under noise (``r = max r_i``), with a constant that grows with the condition number of :math:`\partial\Phi/\partial x`.

Lie derivatives
---------------
:math:`\Phi` and its Jacobian are either supplied (``phi`` and ``phi_jacobian``, exact: the Lie derivatives worked
out by hand or by a computer algebra system) or computed by nested central differences (:func:`lie_derivatives`,
:func:`observability_jacobian`): :math:`L_v\varphi(x) \approx \|v\|\,(\varphi(x + s\hat v) - \varphi(x - s\hat v))
/ (2s)`, :math:`\hat v = v/\|v\|`, with :math:`s = \delta\,(1 + \|x\|_\infty)`. Nesting ``q`` of them has
truncation error :math:`O(\delta^2)` and rounding error :math:`O(\epsilon/\delta^q)` (:math:`\epsilon` the
machine epsilon); the default :math:`\delta = \epsilon^{1/(q_{max}+2)}` with :math:`q_{max} = r` (the Jacobian of
the highest Lie derivative) balances them to a relative accuracy of about :math:`\epsilon^{2/(r+2)}` at worst:
``1.5e-8`` for ``r = 2``, ``5e-7`` for ``r = 3``, ``6e-6`` for ``r = 4``. Measured: on the pendulum of the tests
(``r = 2``) ``3e-9`` in :math:`\Phi` and ``9e-9`` in its Jacobian; on linear systems (no truncation error, rounding
only) at most ``5e-8`` in the Jacobian up to ``r = 4`` (checked in
``tests/test_nonlinear_observers.py``). Each nesting doubles the evaluations (:math:`2^q` per Lie derivative).

Unknown inputs and the observer without transformation
------------------------------------------------------
With ``unknown_input`` (``D``), :class:`NonlinearHOSMObserver` also returns
:math:`\hat w = (y^{(n)} - L_f^nh(\hat x))/(L_DL_f^{n-1}h(\hat x))` (one output; ``p`` outputs by least squares),
from one more differentiator order. :class:`HOSMInjectionObserver` is Davila, Fridman, Pisano and Usai's (2009)
observer for one output: a copy of the system, :math:`\dot{\hat x} = f(\hat x) + M^{-1}(\hat x)\chi(y -
h(\hat x))`, with no inversion of :math:`\Phi`; its error in :math:`\Phi`-coordinates is Levant's differentiator's.

Without the BIBS property
-------------------------
:class:`GlobalHOSMObserver` is Apaza-Perez, Fridman and Moreno's (2018) global observer for the triangular form
:math:`\dot x = Ax + B(\psi(x) + w) + \varphi(u, y)`, :math:`y = x_1`, whose state may grow without bound: it
differentiates the output error of a high-gain copy, whose error stays bounded, instead of the output itself
(:func:`design_global_observer`: the design algorithm of the slides with its matrix inequality checked;
:func:`check_dissipativity`: its assumption on :math:`\psi`, tested on sample points).

Notes
-----
Where the slides' print and the derivation differ (the scan garbles formulas):

* the transformed system is printed with :math:`\eta = q(\xi, \eta)`; the internal dynamics are
  :math:`\dot\eta = q(\xi, \eta)`. They have :math:`n - r` states, which the outputs' derivatives do not
  determine: only ``r = n`` (no internal dynamics, :math:`x = \Phi^{-1}(\xi)`) is implemented;
* the last-row vector printed :math:`\Phi_i` is :math:`\psi^i = (0, \ldots, 0, L_f^{r_i}h_i)` (the name
  :math:`\Phi` is the coordinate change's), and the input term printed :math:`\sum_j a_{ij}\varphi^{-1}(x_j)` is,
  by the chain rule, :math:`(0, \ldots, 0, L_g L_f^{r_i-1}h_i(x)\,\varphi)`: the relative-degree condition above;
* the differentiator (16) has :math:`r_i + 1` states (order :math:`r_i`, the last one for the input
  reconstruction); the state needs order :math:`r_i - 1` only (:class:`NonlinearHOSMObserver`, Notes), the
  order used without ``unknown_input``;
* in the slide on Davila et al. (2009), :math:`g(\hat x) = M^{-1}(\hat x)(0, \ldots, 0, 1)^T` is the direction
  of their observer's correction, not the system's input field, and the law of the correction is not printed:
  :class:`HOSMInjectionObserver` (Notes) injects the whole correction of Levant's differentiator through
  :math:`M^{-1}(\hat x)`, whose last column is that :math:`g`;
* (17) prints :math:`\hat\xi^m_{r_1} = v^m_{r_1-1}` and :math:`\dot{\hat\xi}^m_{r_1} = v^m_{r_1}` for the
  ``m``-th output: the index is :math:`r_m`. The input is then read from :math:`v^i_{r_i} \approx y_i^{(r_i)}`
  through :math:`B = [L_{d_j}L_f^{r_i-1}h_i]` (:class:`NonlinearHOSMObserver`, Notes).

References
----------
.. [FSEY08] L. Fridman, Y. Shtessel, C. Edwards and X.-G. Yan, "Higher-order sliding-mode observer for state
   estimation and input reconstruction in nonlinear systems", Int. J. Robust Nonlinear Control 18(4-5), 2008;
   in Fridman's slides, "HOSM based Observers for Nonlinear Systems".
.. [DFPU09] J. Davila, L. Fridman, A. Pisano and E. Usai, "Finite-time state observation for non-linear uncertain
   systems via higher-order sliding modes", Int. J. Control 82(8), 2009.
.. [Lev03] A. Levant, "Higher-order sliding modes, differentiation and output-feedback control",
   Int. J. Control 76(9-10), 2003.
.. [AFM18] J. C. Apaza-Perez, L. Fridman and J. A. Moreno, Int. J. Control, 2018, as presented in Fridman's
   slides, section 5, "Global observers for nonlinear systems with unknown inputs without BIBS property".
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ._validation import (
    DivergenceError,
    _short,
    as_real_array,
    check_int_at_least,
    check_int_in_range,
    check_keywords,
    check_positive,
    check_real,
)
from .design.gains import _placed_gain, levant_nonrecursive
from .observers.differentiators import Levant, _levant_sequence

__all__ = [
    "GlobalHOSMObserver",
    "GlobalObserverDesign",
    "HOSMInjectionObserver",
    "InputReconstructionError",
    "NonlinearHOSMObserver",
    "ObservabilityError",
    "ObservabilityReport",
    "check_dissipativity",
    "check_observability",
    "default_fd_step",
    "design_global_observer",
    "dissipativity_constant",
    "lie_derivatives",
    "observability_jacobian",
    "observability_map",
]

_EPS = np.finfo(np.float64).eps


class ObservabilityError(ValueError):
    """The observability condition fails: :math:`\\partial\\Phi/\\partial x` is rank deficient at a point, or an input
    reaches an output below its relative degree. ``point`` and ``index`` name where, ``report`` holds the rest."""

    def __init__(self, message: str, *, index: int, point: np.ndarray, report: ObservabilityReport):
        super().__init__(message)
        self.index = index
        self.point = point
        self.report = report


class InputReconstructionError(ValueError):
    r"""The unknown input cannot be read from the outputs: the matrix :math:`B(x) = [L_{d_j}L_f^{r_i-1}h_i(x)]`
    (``p x m``) has rank below ``m`` at ``point`` (for one input and one output: :math:`L_D L_f^{n-1}h(x) = 0`)."""

    def __init__(self, message: str, *, point: np.ndarray, matrix: np.ndarray):
        super().__init__(message)
        self.point = point
        self.matrix = matrix


def default_fd_step(max_nesting: int) -> float:
    r"""The relative finite-difference step :math:`\delta = \epsilon^{1/(q+2)}` for ``q`` nested central
    differences: truncation :math:`O(\delta^2)` and rounding :math:`O(\epsilon/\delta^q)` balance there."""
    return float(_EPS ** (1.0 / (check_int_at_least("max_nesting", max_nesting, 1) + 2)))


#: the most nested central differences (a Lie derivative of order ``q`` costs ``2**q`` evaluations, and its error
#: :math:`O(\delta^2)` with :math:`\delta = \epsilon^{1/(q+2)}` is already ~3e-3 relative at ``q = 10``)
MAX_NESTING = 10


def _sample(name: str, y) -> float:
    """One finite measurement (a scalar or a one-entry array)."""
    value = as_real_array(name, y)
    if value.size != 1 or not np.isfinite(value).all():
        raise ValueError(f"expected {name} to be one finite measurement, actual value: {_short(value)}")
    return float(value.reshape(-1)[0])


def _point(name: str, x) -> np.ndarray:
    """``x`` as a finite, non-empty state ``(n,)`` (a worded ``ValueError`` otherwise)."""
    x = as_real_array(name, x)
    if x.ndim != 1 or x.size == 0 or not np.isfinite(x).all():
        raise ValueError(f"expected {name} to be a finite state with shape (n,), n >= 1, actual value: {_short(x)}")
    return x


def _finite(name: str, value: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``value`` if finite; else a ``ValueError`` naming what was evaluated (``f``, ``h``, ...) and the point."""
    if not np.isfinite(value).all():
        raise ValueError(f"expected {name} finite at x = {x.tolist()}, actual value: {_short(value)}")
    return value


def _check_callable(name: str, func) -> None:
    if not callable(func):
        raise TypeError(f"expected {name} to be a callable, actual value: {type(func).__name__}")


def _check_indices(indices, n: int) -> tuple[int, ...]:
    if isinstance(indices, (int, np.integer)) and not isinstance(indices, bool):
        indices = (indices,)
    try:
        r = tuple(check_int_at_least("indices", int(i) if isinstance(i, np.integer) else i, 1) for i in indices)
    except TypeError:
        raise TypeError(f"expected indices to be a sequence of integers >= 1, actual value: {indices!r}") from None
    if not r or sum(r) != n:
        raise ValueError(
            f"expected observability indices r_1 + ... + r_p = n = {n}, actual value: {r!r} (sum {sum(r)})"
        )
    return r


def _input_field(d, n: int) -> Callable[[np.ndarray], np.ndarray]:
    """An unknown-input field, callable ``d(x)`` or constant array, as a function ``x -> (n, m)`` (shape checked)."""
    if d is None:
        raise TypeError(
            "expected unknown_input to be a callable d(x) or an array of shape (n,) or (n, m), actual value: None"
        )
    if not callable(d):
        D = as_real_array("unknown_input", d)
        if D.shape[:1] != (n,) or D.ndim > 2 or not np.isfinite(D).all():
            raise ValueError(f"expected unknown_input with shape ({n},) or ({n}, m), actual value: shape {D.shape}")
        D = D.reshape(n, -1).copy()
        return lambda x: D

    def field(x):
        D = as_real_array("unknown_input(x)", d(x))
        if D.shape[:1] != (n,) or D.ndim > 2:
            raise ValueError(f"expected unknown_input(x) with shape ({n},) or ({n}, m), actual value: shape {D.shape}")
        return D.reshape(n, -1)

    return field


def _input_matrix(jacobian_rows: np.ndarray, D: np.ndarray, rtol: float, x: np.ndarray) -> np.ndarray:
    r""":math:`B = [dL_f^{r_i-1}h_i\,d_j]`, shape ``(p, m)``, checked for rank ``m`` relative to the norms of its
    factors (:class:`InputReconstructionError` otherwise)."""
    B = jacobian_rows @ D
    scale = np.linalg.norm(jacobian_rows, axis=1)[:, None] * np.linalg.norm(D, axis=0)[None, :]
    Bn = B / np.maximum(scale, np.finfo(float).tiny)
    sv = np.linalg.svd(Bn, compute_uv=False)
    if B.shape[0] < B.shape[1] or sv[-1] <= rtol:
        raise InputReconstructionError(
            "expected L_D L_f^(r_i - 1) h_i (the unknown input's gain on the outputs' r_i-th derivatives, p x m) of "
            f"rank m = {D.shape[1]}, nonzero for one input, actual value: {B.tolist()} (relative singular values "
            f"{sv.tolist()}, rtol {rtol}) at x = {x.tolist()}",
            point=x.copy(),
            matrix=B,
        )
    return B


def _eval(name: str, func, x: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """``func(x)`` as a float array of ``shape`` (a worded ``ValueError`` if it has another)."""
    value = as_real_array(f"{name}(x)", func(x))
    if value.shape != shape:
        if value.size == 1 and shape in ((), (1,)):
            return value.reshape(shape)
        raise ValueError(f"expected {name}(x) with shape {shape}, actual value: shape {value.shape}")
    return value


def _directional(phi: Callable, x: np.ndarray, v: np.ndarray, step: float) -> np.ndarray:
    r"""Central difference of ``phi`` along ``v``: :math:`\|v\|(\varphi(x+s\hat v) - \varphi(x-s\hat v))/(2s)`."""
    norm = float(np.max(np.abs(v)))
    if norm == 0.0:
        return np.zeros_like(np.asarray(phi(x), dtype=float))
    s = step * (1.0 + float(np.max(np.abs(x))))
    u = v / norm
    return norm * (np.asarray(phi(x + s * u), dtype=float) - np.asarray(phi(x - s * u), dtype=float)) / (2.0 * s)


def lie_derivatives(f: Callable, h: Callable, x, order: int, *, step: float | None = None) -> np.ndarray:
    r"""Lie derivatives :math:`L_f^j h(x)`, ``j = 0..order``, by nested central differences along ``f``.

    Parameters
    ----------
    f : callable
        ``f(x) -> (n,)``, the drift vector field.
    h : callable
        ``h(x) -> (p,)`` (or a scalar for ``p = 1``), the output map.
    x : array_like, shape (n,)
    order : int
        Highest derivative, ``>= 0``.
    step : float, optional
        Relative step :math:`\delta`; default :func:`default_fd_step` of ``order`` (module docstring: accuracy).

    Returns
    -------
    ndarray, shape (order + 1, p)
        Row ``j`` is :math:`L_f^j h(x)`.
    """
    _check_callable("f", f)
    _check_callable("h", h)
    x = _point("x", x)
    n = x.size
    order = check_int_in_range("order", order, 0, MAX_NESTING)
    step = default_fd_step(max(order, 1)) if step is None else check_positive("step", step)
    p = np.atleast_1d(_finite("h(x)", as_real_array("h(x)", h(x)), x)).size
    _finite("f(x)", _eval("f", f, x, (n,)), x)
    funcs = [lambda z: np.atleast_1d(_eval("h", h, z, (p,)))]
    for _ in range(order):
        funcs.append(lambda z, prev=funcs[-1]: _directional(prev, z, _eval("f", f, z, (n,)), step))
    return _finite("the Lie derivatives of h along f", np.array([fn(x) for fn in funcs]).reshape(order + 1, p), x)


def _fd_map(f: Callable, h: Callable, n: int, indices: tuple[int, ...], step: float) -> Callable:
    """:math:`\\Phi` by nested central differences (one call of :func:`lie_derivatives` per point)."""
    r_max = max(indices)
    if r_max - 1 > MAX_NESTING:
        raise ValueError(
            f"expected observability indices of at most {MAX_NESTING + 1} for finite differences (nested central "
            f"differences of order r - 1 lose all accuracy beyond that), actual value: {indices!r}; pass the exact "
            "phi_jacobian or phi"
        )

    def phi(x):
        L = lie_derivatives(f, h, x, r_max - 1, step=step)
        return np.concatenate([L[:r, i] for i, r in enumerate(indices)])

    return phi


def observability_map(f: Callable, h: Callable, x, indices=None, *, step: float | None = None) -> np.ndarray:
    r"""The observability map :math:`\Phi(x)`, shape ``(n,)``, by finite differences (module docstring).

    ``indices``: the observability indices :math:`(r_1, \ldots, r_p)`, summing to ``n``; default ``(n,)`` for a
    single output. The entries are :math:`h_1, \ldots, L_f^{r_1-1}h_1, h_2, \ldots`.
    """
    x = _point("x", x)
    r = _check_indices(x.size if indices is None else indices, x.size)
    step = default_fd_step(max(r)) if step is None else check_positive("step", step)
    return _fd_map(f, h, x.size, r, step)(x)


def _jacobian(phi: Callable, x: np.ndarray, step: float) -> np.ndarray:
    """Central-difference Jacobian of ``phi`` at ``x``, one column per coordinate."""
    n = x.size
    s = step * (1.0 + float(np.max(np.abs(x))))
    cols = []
    for j in range(n):
        e = np.zeros(n)
        e[j] = s
        cols.append((np.asarray(phi(x + e), dtype=float) - np.asarray(phi(x - e), dtype=float)) / (2.0 * s))
    return np.column_stack(cols)


def observability_jacobian(f: Callable, h: Callable, x, indices=None, *, step: float | None = None) -> np.ndarray:
    r""":math:`\partial\Phi/\partial x`, shape ``(n, n)``, by finite differences of :func:`observability_map`
    (row ``j`` is :math:`dL_f^{j}h`, the matrix ``M(z)`` of Davila et al. 2009 for one output)."""
    x = _point("x", x)
    r = _check_indices(x.size if indices is None else indices, x.size)
    step = default_fd_step(max(r)) if step is None else check_positive("step", step)
    return _jacobian(_fd_map(f, h, x.size, r, step), x, step)


@dataclass(frozen=True)
class ObservabilityReport:
    r"""Local weak observability of :math:`\Phi` on a set of points (:func:`check_observability`).

    Attributes
    ----------
    points : ndarray, shape (N, n)
    singular_values : ndarray, shape (N, n)
        Of :math:`\partial\Phi/\partial x` at each point, largest first.
    rank : ndarray of int, shape (N,)
        Numerical rank: singular values above ``rtol`` times the largest.
    condition : ndarray, shape (N,)
        :math:`\sigma_{max}/\sigma_{min}` (inf where singular): how much the observer amplifies derivative errors.
    input_coupling : ndarray, shape (N,)
        Largest :math:`|L_g L_f^j h_i| / (\|dL_f^j h_i\|\,\|g\|)` over ``j < r_i - 1`` (0 without ``g`` or when all
        :math:`r_i = 1`): a known or unknown input reaching an output below its relative degree.
    indices : tuple of int
    rtol : float
    """

    points: np.ndarray
    singular_values: np.ndarray
    rank: np.ndarray
    condition: np.ndarray
    input_coupling: np.ndarray
    indices: tuple[int, ...]
    rtol: float

    @property
    def observable(self) -> np.ndarray:
        """Per point: full rank and no input below the relative degree."""
        return (self.rank == self.points.shape[1]) & (self.input_coupling <= self.rtol)


@check_keywords
def check_observability(
    f: Callable,
    h: Callable,
    points,
    indices=None,
    *,
    g: Callable | None = None,
    phi_jacobian: Callable | None = None,
    rtol: float = 1e-6,
    step: float | None = None,
    raise_error: bool = True,
) -> ObservabilityReport:
    r"""Test local weak observability (rank of :math:`\partial\Phi/\partial x`) and the relative-degree condition on
    a set of points.

    Parameters
    ----------
    f, h : callable
        Drift ``f(x) -> (n,)`` and output ``h(x) -> (p,)``.
    points : array_like, shape (N, n) or (n,)
    indices : sequence of int, optional
        Observability indices, default ``(n,)``.
    g : callable, optional
        Input field(s), ``g(x) -> (n,)`` or ``(n, m)`` (known and unknown inputs alike): checks
        :math:`L_g L_f^j h_i = dL_f^j h_i\,g = 0` for :math:`j < r_i - 1` (relative to the norms, within ``rtol``).
    phi_jacobian : callable, optional
        Exact :math:`\partial\Phi/\partial x`, ``(n,) -> (n, n)``; default finite differences (module docstring).
    rtol : float
        Relative rank tolerance; keep it above the finite-difference accuracy (default ``1e-6``).
    raise_error : bool
        Raise :class:`ObservabilityError` at the first failing point (default), or only return the report.

    Raises
    ------
    ObservabilityError
        Naming the first failing point (index and coordinates) and the failing condition.
    """
    _check_callable("f", f)
    _check_callable("h", h)
    P = as_real_array("points", points)
    if P.ndim == 1:
        P = P[None, :]
    if P.ndim != 2 or P.shape[0] == 0 or not np.isfinite(P).all():
        raise ValueError(f"expected finite points with shape (N, n), N >= 1, actual value: shape {P.shape}")
    n = P.shape[1]
    r = _check_indices(n if indices is None else indices, n)
    rtol = check_positive("rtol", rtol)
    step = default_fd_step(max(r)) if step is None else check_positive("step", step)
    fd_phi = _fd_map(f, h, n, r, step) if phi_jacobian is None else None
    rows_below = [sum(r[:i]) + j for i, ri in enumerate(r) for j in range(ri - 1)]
    sv, coupling = [], []
    for x in P:
        J = _jacobian(fd_phi, x, step) if phi_jacobian is None else _eval("phi_jacobian", phi_jacobian, x, (n, n))
        _finite("dPhi/dx" if phi_jacobian is None else "phi_jacobian(x)", J, x)
        sv.append(np.linalg.svd(J, compute_uv=False))
        c = 0.0
        if g is not None and rows_below:
            G = _finite("g(x)", np.asarray(as_real_array("g(x)", g(x))), x)
            G = G.reshape(n, -1) if G.shape[:1] == (n,) else None
            if G is None:
                raise ValueError(f"expected g(x) with shape (n,) or (n, m), n = {n}, actual value: {g(x)!r}")
            for row in rows_below:
                scale = np.linalg.norm(J[row]) * np.linalg.norm(G, axis=0)
                c = max(c, float(np.max(np.abs(J[row] @ G) / np.maximum(scale, np.finfo(float).tiny))))
        coupling.append(c)
    sv = np.array(sv)
    rank = (sv > rtol * sv[:, :1]).sum(axis=1)
    with np.errstate(divide="ignore"):
        cond = np.where(sv[:, -1] > 0, sv[:, 0] / sv[:, -1], np.inf)
    report = ObservabilityReport(P, sv, rank, cond, np.array(coupling), r, rtol)
    if raise_error:
        for k in range(P.shape[0]):
            if rank[k] < n:
                raise ObservabilityError(
                    f"expected dPhi/dx of rank n = {n} (local weak observability), actual value: rank {rank[k]} at "
                    f"point {k}, x = {P[k].tolist()} (singular values {sv[k].tolist()}, rtol {rtol})",
                    index=k,
                    point=P[k],
                    report=report,
                )
            if coupling[k] > rtol:
                raise ObservabilityError(
                    "expected L_g L_f^j h_i = 0 for j < r_i - 1 (the inputs reach each output at its relative degree "
                    f"only), actual value: relative coupling {coupling[k]:.3g} at point {k}, x = {P[k].tolist()}",
                    index=k,
                    point=P[k],
                    report=report,
                )
    return report


class NonlinearHOSMObserver:
    r"""HOSM observer of Fridman, Shtessel, Edwards and Yan (2008): Levant's differentiators on the outputs, then
    the state from :math:`\Phi(\hat x) = \hat\xi` by Newton's method (module docstring).

    Parameters
    ----------
    f, h : callable
        Drift ``f(x) -> (n,)`` and output map ``h(x) -> (p,)`` (a scalar for one output). NumPy functions of one
        state ``(n,)``.
    n : int
        State dimension.
    dt : float
        Sampling step ``tau > 0`` [s].
    lipschitz : float or array_like, shape (p,)
        :math:`L_i \ge |y_i^{(r_i)}|` along the trajectories (inputs included): exists for a BIBS system with
        bounded inputs. With ``unknown_input``, :math:`L_i \ge |y_i^{(r_i+1)}|` (one more differentiator order).
    indices : sequence of int, optional
        Observability indices :math:`(r_1, \ldots, r_p)` with sum ``n``; default ``(n,)`` (one output).
    phi, phi_jacobian : callable, optional
        Exact :math:`\Phi(x) -> (n,)` and :math:`\partial\Phi/\partial x -> (n, n)`; each defaults to finite
        differences (module docstring: accuracy).
    discretization : str
        Of :class:`smo_gym.observers.Levant`; default ``"implicit"`` (set-valued backward Euler with Seeber's
        outputs): it does not chatter, so the noise-free floor is its :math:`O(L\tau^{k+1-j})` error alone
        (measured: about 19 times smaller than with ``"taylor"`` on the pendulum of the tests).
    gains : array_like, optional
        Levant's :math:`(\lambda_0, \ldots, \lambda_k)`, used for every output (so all :math:`r_i > 1` must then be
        equal); default Levant's sequence for each order.
    tol : float, optional
        Newton stops when :math:`\|\Phi(x) - \hat\xi\|_\infty \le \mathrm{tol}\,(1 + \|\hat\xi\|_\infty)` or
        :math:`\|\Delta x\|_\infty \le \mathrm{tol}\,(1 + \|x\|_\infty)`; default ``1e-10`` with
        an exact ``phi``, else 10 times the finite-difference accuracy :math:`\epsilon^{2/(r+2)}`.
    max_iter : int
        Newton iterations per sample (default 20); the estimate after them is kept, with ``converged = False``.
    unknown_input : array_like, shape (n,) or (n, m), or callable, optional
        The unknown input's field ``D`` (or ``d(x)``) of :math:`\dot x = f(x) + D\,w`. Given, the observer also
        reconstructs ``w`` (Notes): each differentiator gets one more order, ``r_i``, and ``lipschitz`` must then
        bound :math:`|y_i^{(r_i+1)}|` (``w`` Lipschitz in time; at a jump of ``w`` the estimate is lost for a
        finite time). The observer assumes no known input then (:math:`y^{(r_i)} - L_f^{r_i}h_i` is read as
        ``B w``).
    lie_top : callable, optional
        Exact :math:`x \mapsto (L_f^{r_1}h_1(x), \ldots, L_f^{r_p}h_p(x))`, shape ``(p,)``, for the reconstruction;
        default nested central differences.
    rtol : float
        Relative tolerance on the rank of :math:`B(\hat x)` (:class:`InputReconstructionError` below it).

    Attributes
    ----------
    state : ndarray, shape (n,)
        The estimate :math:`\hat x`.
    derivatives : ndarray, shape (n,)
        :math:`\hat\xi`, the differentiators' outputs in the order of :math:`\Phi`.
    converged : bool
        Whether the last Newton solve met ``tol``.
    iterations : int
        Newton iterations of the last sample.
    residual : float
        :math:`\|\Phi(\hat x) - \hat\xi\|_\infty` after the last solve (nonzero while :math:`\hat\xi` is outside the
        range of :math:`\Phi`, during the differentiators' transient).
    input_estimate : ndarray, shape (m,) or None
        :math:`\hat w` of the last sample (with ``unknown_input``).

    Notes
    -----
    The slides print the differentiator (16) with :math:`r_i + 1` states :math:`v_0, \ldots, v_{r_i}` (order
    :math:`r_i`, the last one for the input reconstruction, which needs :math:`y^{(r_i+1)}` bounded); the state
    alone needs :math:`y, \ldots, y^{(r_i-1)}`, so the order :math:`r_i - 1` is used, which needs only
    :math:`|y^{(r_i)}| \le L` and holds with discontinuous unknown inputs. The Newton step solves
    :math:`J\Delta x = \Phi(x) - \hat\xi` by least squares (a rank-deficient :math:`J` during a transient gives
    the minimum-norm step), halving it at most 8 times while the residual does not decrease. The observer of Davila,
    Fridman, Pisano and Usai (2009), which injects the differentiator into a copy of the system through
    :math:`M^{-1}(\hat x)` instead of inverting :math:`\Phi`, is :class:`HOSMInjectionObserver`.

    Unknown-input reconstruction (the slides' (17): :math:`\dot{\hat\xi}_{r_i} = v_{r_i}`). With
    :math:`\dot x = f(x) + D(x)w` and the relative-degree condition,
    :math:`y_i^{(r_i)} = L_f^{r_i}h_i(x) + \sum_j L_{d_j}L_f^{r_i-1}h_i(x)\,w_j`, so

    .. math:: \hat w = B(\hat x)^{+}\big(z_{r_i}^i - L_f^{r_i}h_i(\hat x)\big)_i,\qquad
        B = [L_{d_j}L_f^{r_i-1}h_i] = [dL_f^{r_i-1}h_i\,d_j] \in \mathbb R^{p\times m},

    for one input and one output :math:`\hat w = (z_n - L_f^nh(\hat x))/(L_DL_f^{n-1}h(\hat x))`, with the
    differentiator's last state :math:`z_{r_i} \approx y_i^{(r_i)}`. It needs :math:`B` of rank ``m`` (checked at
    every sample: :class:`InputReconstructionError`). Accuracy, sampled and noise-free (Levant 2003, order
    :math:`k = r_i`): :math:`|z_{r_i} - y_i^{(r_i)}| = O(L\tau)`, so :math:`\hat w - w = O(\tau)`, and the state,
    now from :math:`z_0..z_{r_i-1}`, gains an order: :math:`O(L\tau^2)` (measured in the tests: slopes 1.00 and 2.00).
    """

    @check_keywords
    def __init__(
        self,
        f: Callable,
        h: Callable,
        n: int,
        dt: float,
        lipschitz,
        *,
        indices: Sequence[int] | None = None,
        phi: Callable | None = None,
        phi_jacobian: Callable | None = None,
        discretization: str = "implicit",
        gains=None,
        tol: float | None = None,
        max_iter: int = 20,
        unknown_input=None,
        lie_top: Callable | None = None,
        rtol: float = 1e-6,
    ):
        _check_callable("f", f)
        _check_callable("h", h)
        for name, func in (("phi", phi), ("phi_jacobian", phi_jacobian), ("lie_top", lie_top)):
            if func is not None:
                _check_callable(name, func)
        self.n = check_int_at_least("n", n, 1)
        self.dt = check_positive("dt", dt)
        self.indices = _check_indices(self.n if indices is None else indices, self.n)
        p = len(self.indices)
        L = as_real_array("lipschitz", lipschitz)
        if L.shape not in ((), (1,), (p,)) or not np.isfinite(L).all() or np.any(L <= 0):
            raise ValueError(f"expected lipschitz > 0, a number or shape ({p},), actual value: {lipschitz!r}")
        self.lipschitz = np.broadcast_to(L.reshape(-1), (p,)).copy()
        self.f, self.h = f, h
        self.step = default_fd_step(max(self.indices))
        self._phi = _fd_map(f, h, self.n, self.indices, self.step) if phi is None else phi
        self._phi_jacobian = phi_jacobian
        exact = phi is not None
        self.tol = (1e-10 if exact else 10.0 * self.step**2) if tol is None else check_positive("tol", tol)
        self.max_iter = check_int_at_least("max_iter", max_iter, 1)
        self.rtol = check_positive("rtol", rtol)
        self._d = None if unknown_input is None else _input_field(unknown_input, self.n)
        self._lie_top = lie_top
        # one Levant differentiator per output, of order r_i - 1 for the state (none for r_i = 1: the output is the
        # coordinate), one more (order r_i) for the unknown input, which needs y_i^(r_i)
        extra = 0 if self._d is None else 1
        self._diffs = [
            None
            if r - 1 + extra == 0
            else Levant(r - 1 + extra, self.dt, float(self.lipschitz[i]), discretization=discretization, gains=gains)
            for i, r in enumerate(self.indices)
        ]
        self._top_rows = np.cumsum(self.indices) - 1  # the rows dL_f^(r_i - 1) h_i of dPhi/dx
        self._offsets = np.cumsum((0,) + self.indices)
        self.state: np.ndarray | None = None
        self.derivatives: np.ndarray | None = None
        self.converged, self.iterations, self.residual = False, 0, np.nan
        self.input_estimate: np.ndarray | None = None

    @property
    def reconstructs_input(self) -> bool:
        """Whether the observer was built with ``unknown_input`` (and sets :attr:`input_estimate`)."""
        return self._d is not None

    def _y(self, y) -> np.ndarray:
        y = as_real_array("y", y).reshape(-1) if np.ndim(y) <= 1 else as_real_array("y", y)
        if y.shape != (len(self.indices),):
            raise ValueError(f"expected y with shape ({len(self.indices)},), actual value: shape {np.shape(y)}")
        if not np.isfinite(y).all():
            raise ValueError(f"expected a finite measurement y, actual value: {y!r}")
        return y

    def phi(self, x) -> np.ndarray:
        """:math:`\\Phi(x)`, shape ``(n,)`` (the supplied map or finite differences)."""
        return _eval("phi", self._phi, np.asarray(x, dtype=float), (self.n,))

    def jacobian(self, x) -> np.ndarray:
        """:math:`\\partial\\Phi/\\partial x`, shape ``(n, n)`` (the supplied one or central differences)."""
        x = np.asarray(x, dtype=float)
        if self._phi_jacobian is not None:
            return _eval("phi_jacobian", self._phi_jacobian, x, (self.n, self.n))
        return _jacobian(self.phi, x, self.step)

    def invert(self, xi, x_guess) -> np.ndarray:
        """Solve :math:`\\Phi(x) = \\xi` by damped Newton from ``x_guess`` (sets ``converged``, ``iterations``,
        ``residual``)."""
        x = np.array(x_guess, dtype=float)
        res = self.phi(x) - xi
        err = np.abs(res).max()
        scale = 1.0 + np.abs(xi).max()
        self.converged = bool(err <= self.tol * scale)  # already solved (the warm start after convergence, often)
        k = 0
        while not self.converged and k < self.max_iter:
            k += 1
            J = self.jacobian(x)
            try:
                dx = np.linalg.solve(J, res)
            except np.linalg.LinAlgError:  # singular during a transient: the minimum-norm step
                dx = np.linalg.lstsq(J, res, rcond=None)[0]
            for _ in range(9):  # backtracking: accept the first step that does not increase the residual
                x_new = x - dx
                res_new = self.phi(x_new) - xi
                err_new = np.abs(res_new).max()
                if err_new <= err:
                    break
                dx = 0.5 * dx
            else:
                break  # no descent along the Newton direction: keep x
            decrease = err - err_new
            x, res, err = x_new, res_new, err_new
            # a vanishing step converges only where it still lowers the residual: a singular Jacobian's
            # minimum-norm step can be zero with the residual where it was (that is a stall, not a solution)
            small_step = np.abs(dx).max() <= self.tol * (1.0 + np.abs(x).max())
            self.converged = bool(err <= self.tol * scale or (small_step and decrease > 0))
            if small_step and not self.converged:
                break
        self.iterations, self.residual = k, float(err)
        return x

    def _xi(self, estimates, y) -> np.ndarray:
        xi = np.empty(self.n)
        for i, (d, est) in enumerate(zip(self._diffs, estimates, strict=True)):
            a, b = self._offsets[i], self._offsets[i + 1]
            xi[a:b] = y[i] if d is None else est[: b - a]
        return xi

    def lie_top(self, x) -> np.ndarray:
        """:math:`(L_f^{r_1}h_1(x), \\ldots, L_f^{r_p}h_p(x))`, shape ``(p,)`` (the supplied ``lie_top`` or nested
        central differences)."""
        x = np.asarray(x, dtype=float)
        p = len(self.indices)
        if self._lie_top is not None:
            return _eval("lie_top", self._lie_top, x, (p,))
        r_max = max(self.indices)
        L = lie_derivatives(self.f, self.h, x, r_max, step=default_fd_step(r_max))
        return np.array([L[r, i] for i, r in enumerate(self.indices)])

    def _input(self, estimates, x) -> np.ndarray:
        r"""The unknown input from :math:`y_i^{(r_i)} = L_f^{r_i}h_i(x) + B(x)\,w` (least squares for ``p > m``)."""
        top = np.array([est[-1] for est in estimates])
        B = _input_matrix(self.jacobian(x)[self._top_rows], self._d(x), self.rtol, x)
        return np.linalg.lstsq(B, top - self.lie_top(x), rcond=None)[0]

    def reset(self, y0, x0) -> np.ndarray:
        """Start at the first measurement ``y0`` (shape ``(p,)``) with the state guess ``x0`` (shape ``(n,)``).

        The differentiators start at ``y0`` with the guess's derivatives :math:`\\Phi(x_0)`; the estimate is then
        the Newton solution from ``x0``. Returns :math:`\\hat x`, shape ``(n,)``.
        """
        y = self._y(y0)
        x0 = as_real_array("x0", x0)
        if x0.shape != (self.n,) or not np.isfinite(x0).all():
            raise ValueError(f"expected a finite x0 with shape ({self.n},), actual value: {x0!r}")
        guess = self.phi(x0)
        top = None if self._d is None else self.lie_top(x0)
        estimates = []
        for i, d in enumerate(self._diffs):
            if d is None:
                estimates.append(None)
                continue
            a, b = self._offsets[i], self._offsets[i + 1]
            start = guess[a + 1 : b] if top is None else np.append(guess[a + 1 : b], top[i])
            estimates.append(d.reset(y[i : i + 1], derivatives=start[None, :])[0])
        self.derivatives = self._xi(estimates, y)
        self.state = self.invert(self.derivatives, x0)
        if self._d is not None:
            self.input_estimate = self._input(estimates, self.state)
        return self.state.copy()

    def update(self, y) -> np.ndarray:
        """Process one measurement ``y`` (shape ``(p,)``); returns :math:`\\hat x`, shape ``(n,)``."""
        if self.state is None:
            raise RuntimeError("expected reset(y0, x0) before update(y), actual value: the observer was never reset")
        y = self._y(y)
        saved = [None if d is None else d.checkpoint() for d in self._diffs]
        try:
            estimates = [None if d is None else d.update(y[i : i + 1])[0] for i, d in enumerate(self._diffs)]
            derivatives = self._xi(estimates, y)
            state = self.invert(derivatives, self.state)
            input_estimate = None if self._d is None else self._input(estimates, state)
        except BaseException:  # the inversion or the input's reconstruction failed: the sample was not taken
            for d, checkpoint in zip(self._diffs, saved, strict=True):
                if d is not None:
                    d.restore(checkpoint)
            raise
        self.derivatives, self.state = derivatives, state
        if self._d is not None:
            self.input_estimate = input_estimate
        return self.state.copy()

    def run(self, Y, x0, *, inputs: bool = False):
        """Reset at ``Y[0]`` with the guess ``x0`` and process the record ``Y`` (shape ``(T, p)`` or ``(T,)``);
        returns the estimates, shape ``(T, n)``, and with ``inputs=True`` (needs ``unknown_input``) also the
        unknown-input estimates, shape ``(T, m)``."""
        Y = as_real_array("Y", Y)
        Y = Y.reshape(Y.shape[0], -1) if Y.ndim >= 1 and Y.shape[0] > 0 else Y
        if Y.ndim != 2 or Y.shape[0] == 0:
            raise ValueError(f"expected Y with shape (T, p), T >= 1, actual value: shape {Y.shape}")
        if inputs and self._d is None:
            raise ValueError("expected unknown_input at construction for run(..., inputs=True), actual value: None")
        out = np.empty((Y.shape[0], self.n))
        out[0] = self.reset(Y[0], x0)
        W = [self.input_estimate] if inputs else None
        for k in range(1, Y.shape[0]):
            out[k] = self.update(Y[k])
            if inputs:
                W.append(self.input_estimate)
        return (out, np.array(W)) if inputs else out


class HOSMInjectionObserver:
    r"""Observer without system transformation of Davila, Fridman, Pisano and Usai (2009): a copy of the system
    corrected by a HOSM injection through :math:`M^{-1}(\hat x)`, for one output.

    The system :math:`\dot x = f(x) + D\,w(x, t)`, :math:`y = h(x) \in \mathbb R`, with a known distribution
    ``D`` and a bounded unknown input ``w``, under the two assumptions of the slides:

    * :math:`dL_f^i h\,D = 0` for ``i = 0..n-2`` (the input reaches :math:`y^{(n)}` only);
    * :math:`M(z) = \partial\Phi/\partial z`, rows :math:`dh, dL_fh, \ldots, dL_f^{n-1}h`, nonsingular.

    The observer integrates

    .. math::
        \dot{\hat x} = f(\hat x) + M^{-1}(\hat x)\,\chi(y - h(\hat x)),\qquad
        \chi_j(e) = \Lambda_{j+1} L^{\frac{j+1}{n}} \lceil e\rfloor^{\frac{n-1-j}{n}}\ (j < n-1),\quad
        \chi_{n-1}(e) = \lambda_0 L\,\mathrm{sign}(e),

    the corrections of Levant's order-``(n-1)`` differentiator in non-recursive form
    (:func:`smo_gym.design.levant_gains`). Since :math:`\frac{d}{dt}\Phi(\hat x) = M(\hat x)\dot{\hat x}`, the
    estimate's coordinates :math:`\hat\xi = \Phi(\hat x)` obey :math:`\dot{\hat\xi}_j = \hat\xi_{j+1} + \chi_j`,
    :math:`\dot{\hat\xi}_{n-1} = L_f^n h(\hat x) + \chi_{n-1}`, and the error :math:`e = \Phi(x) - \Phi(\hat x)`

    .. math::
        \dot e_j = e_{j+1} - \chi_j(e_0),\qquad \dot e_{n-1} = \underbrace{L_f^nh(x) - L_f^nh(\hat x)
        + L_DL_f^{n-1}h(x)\,w}_{|\cdot|\ \le\ L} - \chi_{n-1}(e_0)

    is exactly the error of Levant's differentiator driven by a bounded perturbation: :math:`e = 0` after a finite
    time (Levant 2003), so :math:`\Phi(\hat x) = \Phi(x)` and :math:`\hat x = x` where :math:`\Phi` is injective.
    ``L`` must bound the perturbation along both trajectories (the system BIBS, the estimate bounded).

    Parameters
    ----------
    f, h : callable
        Drift ``f(x) -> (n,)`` and output ``h(x)`` (a scalar or shape ``(1,)``).
    n : int
    dt : float
        Sampling step ``tau > 0`` [s]; the observer is integrated by explicit Euler at this step with the
        measurement held (Levant 2003: the sampled differentiator keeps :math:`|e_j| = O(L\tau^{n-j})`, so the
        state error is :math:`O(L\tau)`, from :math:`e_{n-1}`).
    lipschitz : float
        ``L`` above.
    unknown_input : array_like, shape (n,) or (n, m), or callable, optional
        ``D``; with ``check_points`` it is checked against :math:`dL_f^ih\,D = 0`.
    check_points : array_like, shape (N, n), optional
        Points (the region the state and the estimate visit) on which both assumptions are checked at
        construction by :func:`check_observability` (raises :class:`ObservabilityError` naming the point and
        the condition).
    phi_jacobian : callable, optional
        Exact :math:`M(x)`, ``(n,) -> (n, n)``; default central differences of :func:`observability_map`.
    gains : array_like, shape (n,), optional
        Levant's recursive :math:`(\lambda_0, \ldots, \lambda_{n-1})`; default Levant's sequence.
    rtol : float
        A step raises :class:`ObservabilityError` when :math:`M(\hat x)` has a singular value below ``rtol``
        times its largest (the estimate left the region where the assumption holds).

    Attributes
    ----------
    state : ndarray, shape (n,)
        :math:`\hat x` at the time of the last measurement.
    output_error : float
        :math:`y - h(\hat x)` at the last measurement.
    injection : ndarray, shape (n,)
        :math:`\chi` of the last step (its last entry, averaged once :math:`e = 0`, is the equivalent injection
        :math:`L_DL_f^{n-1}h(x)\,w`, Notes).

    Notes
    -----
    The slides print the observer as :math:`\dot{\hat x} = f(\hat x) + g(\hat x)u`, :math:`g = M^{-1}(\hat x)
    (0, \ldots, 0, 1)^T`, without the law of ``u``. A scalar ``u`` through that one direction acts on the output
    error only through its ``n``-th derivative, so ``u`` would have to be an ``n``-sliding controller with its own
    differentiator; the derivation above injects the differentiator's whole correction vector through
    :math:`M^{-1}(\hat x)`, whose last column is the slides' :math:`g`, and carries the unknown input
    :math:`L_DL_f^{n-1}h(x)\,w` in the last component. That component switches at the sampling rate (explicit
    Euler, ``sign``), so the unknown input is not read from it here: :class:`NonlinearHOSMObserver` with
    ``unknown_input`` reconstructs it.

    References
    ----------
    J. Davila, L. Fridman, A. Pisano and E. Usai, "Finite-time state observation for non-linear uncertain systems
    via higher-order sliding modes", Int. J. Control 82(8), 2009; Fridman's slides, section 5, "Observers for BIBS
    systems with unknown inputs without system transformation". A. Levant, "Higher-order sliding modes,
    differentiation and output-feedback control", Int. J. Control 76(9-10), 2003.
    """

    @check_keywords
    def __init__(
        self,
        f: Callable,
        h: Callable,
        n: int,
        dt: float,
        lipschitz: float,
        *,
        unknown_input=None,
        check_points=None,
        phi_jacobian: Callable | None = None,
        gains=None,
        rtol: float = 1e-9,
    ):
        _check_callable("f", f)
        _check_callable("h", h)
        if phi_jacobian is not None:
            _check_callable("phi_jacobian", phi_jacobian)
        self.f, self.h = f, h
        self.n = check_int_at_least("n", n, 2)
        self.dt = check_positive("dt", dt)
        self.lipschitz = check_positive("lipschitz", lipschitz)
        self.rtol = check_positive("rtol", rtol)
        self._d = None if unknown_input is None else _input_field(unknown_input, self.n)
        self._phi_jacobian = phi_jacobian
        self.step = default_fd_step(self.n)
        self._phi = _fd_map(f, h, self.n, (self.n,), self.step)
        # Levant's non-recursive gains Lambda_{j+1} L^((j+1)/n) and powers (n-1-j)/n of the order n-1 differentiator
        nonrecursive = levant_nonrecursive(_levant_sequence(gains, self.n - 1))
        self._gains = nonrecursive * self.lipschitz ** (np.arange(1, self.n + 1) / self.n)
        self._powers = (self.n - 1 - np.arange(self.n)) / self.n
        if check_points is not None:
            check_observability(f, h, check_points, g=self._d, phi_jacobian=phi_jacobian)
        self.state: np.ndarray | None = None
        self.output_error = np.nan
        self.injection = np.zeros(self.n)

    def jacobian(self, x) -> np.ndarray:
        """:math:`M(x) = \\partial\\Phi/\\partial x`, shape ``(n, n)``."""
        x = np.asarray(x, dtype=float)
        if self._phi_jacobian is not None:
            return _eval("phi_jacobian", self._phi_jacobian, x, (self.n, self.n))
        return _jacobian(self._phi, x, self.step)

    def _y(self, y) -> float:
        return _sample("y", y)

    def _error(self, y: float, x: np.ndarray) -> float:
        return y - float(_eval("h", self.h, x, (1,))[0])

    def reset(self, y0, x0) -> np.ndarray:
        """Start at the measurement ``y0`` with the guess ``x0`` (shape ``(n,)``); returns :math:`\\hat x = x_0`."""
        x0 = as_real_array("x0", x0)
        if x0.shape != (self.n,) or not np.isfinite(x0).all():
            raise ValueError(f"expected a finite x0 with shape ({self.n},), actual value: {x0!r}")
        error = _finite("the output error y0 - h(x0)", np.float64(self._error(self._y(y0), x0)), x0)
        self.state, self.output_error = x0.copy(), float(error)  # only once both are known: a refusal changes nothing
        return self.state.copy()

    def update(self, y) -> np.ndarray:
        r"""Euler step from the previous measurement's time to this one's, with the previous output error held;
        returns :math:`\hat x` at this measurement, shape ``(n,)``."""
        if self.state is None:
            raise RuntimeError("expected reset(y0, x0) before update(y), actual value: the observer was never reset")
        y = self._y(y)
        x = self.state
        M = self.jacobian(x)
        if not np.isfinite(M).all():
            raise DivergenceError(f"expected a finite dPhi/dx at the estimate {x.tolist()}, actual value: {_short(M)}")
        sv = np.linalg.svd(M, compute_uv=False)
        if not sv[-1] > self.rtol * sv[0]:
            check_observability(self.f, self.h, x, g=self._d, phi_jacobian=lambda z: M, rtol=self.rtol)
        e = self.output_error
        injection = self._gains * np.abs(e) ** self._powers * np.sign(e)
        with np.errstate(over="ignore", invalid="ignore"):
            state = x + self.dt * (_eval("f", self.f, x, (self.n,)) + np.linalg.solve(M, injection))
            error = self._error(y, state) if np.isfinite(state).all() else np.nan
        if not (np.isfinite(state).all() and np.isfinite(error)):
            raise DivergenceError(
                f"expected a finite estimate and output error after the step, actual value: {_short(state)} and "
                f"{error!r} (from {x.tolist()}); the previous state was kept (a smaller dt or smaller gains)"
            )
        self.state, self.injection, self.output_error = state, injection, error
        return self.state.copy()

    def run(self, Y, x0) -> np.ndarray:
        """Reset at ``Y[0]`` with the guess ``x0`` and process the record ``Y`` (shape ``(T,)``); returns the
        estimates, shape ``(T, n)``."""
        Y = as_real_array("Y", Y).reshape(-1)
        if Y.size == 0:
            raise ValueError("expected Y with shape (T,), T >= 1, actual value: shape (0,)")
        out = np.empty((Y.size, self.n))
        out[0] = self.reset(Y[0], x0)
        for k in range(1, Y.size):
            out[k] = self.update(Y[k])
        return out


def _chain(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(A, B, C)`` of the chain of ``n`` integrators of the triangular form (21)."""
    A = np.eye(n, k=1)
    B = np.zeros(n)
    B[-1] = 1.0
    C = np.zeros(n)
    C[0] = 1.0
    return A, B, C


def dissipativity_constant(q: float, S, R) -> float:
    r""":math:`\varrho_\psi` of a :math:`\{q, S, R\}`-dissipative nonlinearity (Apaza-Perez, Fridman and Moreno 2018):
    the gain :math:`|\Psi(x, h)| \le \varrho_\psi\|h\|` that the dissipation inequality implies for :math:`q < 0`,

    .. math:: \varrho_\psi = \frac{1}{-q}\Big(\sqrt{-\lambda_{max}(R)\,q + \lambda_{max}(S^TS)}
              + \lambda_{max}(S^TS)^{1/2}\Big).

    Notes
    -----
    :math:`q\Psi^2 + 2\Psi Sh + h^TRh \ge 0` is a quadratic in :math:`\Psi` opening downwards, so :math:`|\Psi|` is at
    most its larger root, :math:`(|Sh| + \sqrt{(Sh)^2 - q\,h^TRh})/(-q)`, and :math:`|Sh| \le
    \lambda_{max}(S^TS)^{1/2}\|h\|`, :math:`h^TRh \le \lambda_{max}(R)\|h\|^2` give the formula. Fridman's slides
    print the factor :math:`1/\sqrt{-q}`, which agrees with it only at :math:`q = -1` and is too small for
    :math:`|q| < 1`: :math:`\psi = 2x_2` is :math:`\{-1/4, 0, 1\}`-dissipative (the form is :math:`-\Psi^2/4 + h^2 =
    0`) and its gain is 2, where the slides' factor gives 1.
    """
    q, S, R = _supply_rate(q, S, R)
    if not q < 0:
        raise ValueError(f"expected q < 0 (the dissipativity of the assumption), actual value: {q!r}")
    sts = float(np.linalg.eigvalsh(S.T @ S).max())
    radicand = -float(np.linalg.eigvalsh(R).max()) * q + sts
    if radicand < 0:  # then q Psi^2 + 2 Psi S h + h'Rh < 0 for every Psi and h != 0: no nonlinearity satisfies it
        raise ValueError(
            "expected a supply rate some nonlinearity satisfies, -lambda_max(R) q + lambda_max(S'S) >= 0, actual "
            f"value: {radicand!r} (q = {q!r}, lambda_max(R) = {float(np.linalg.eigvalsh(R).max())!r})"
        )
    value = (np.sqrt(radicand) + np.sqrt(sts)) / -q
    if not np.isfinite(value):
        raise ValueError(f"expected q, S and R of moderate magnitude, actual value: rho_psi = {value!r}")
    return float(value)


def _supply_rate(q, S, R, m: int | None = None) -> tuple[float, np.ndarray, np.ndarray]:
    """``q`` (a finite real), ``S`` ``(1, m)`` and ``R`` ``(m, m)`` (finite, ``m`` from ``R`` unless given), checked."""
    q = check_real("q", q)
    R = np.atleast_2d(as_real_array("R", R))
    m = R.shape[0] if m is None else m
    S = np.atleast_2d(as_real_array("S", S))
    if R.shape != (m, m) or S.size != m or m == 0:
        raise ValueError(
            f"expected S of {m} entries and R of shape ({m}, {m}), m >= 1, actual value: shapes {S.shape} and {R.shape}"
        )
    if not (np.isfinite(S).all() and np.isfinite(R).all()):
        raise ValueError(f"expected finite S and R, actual value: S = {_short(S)}, R = {_short(R)}")
    return q, S.reshape(1, m), R


def check_dissipativity(psi: Callable, q: float, S, R, points, *, h_scale: float = 1.0, samples: int = 64,
                        seed: int = 0) -> tuple[bool, float, np.ndarray, np.ndarray]:  # fmt: skip
    r"""Test the assumption of :class:`GlobalHOSMObserver` on sample points: :math:`\psi` is
    :math:`\{q, S, R\}`-dissipative in the coordinates ``2..n``,

    .. math:: \begin{bmatrix}\Psi \\ h\end{bmatrix}^T\begin{bmatrix} q & S \\ S^T & R\end{bmatrix}
              \begin{bmatrix}\Psi \\ h\end{bmatrix} \ge 0,\qquad
              \Psi(x, h) = \psi(x_1, x_2 + h_1, \ldots, x_n + h_{n-1}) - \psi(x),

    at every point of ``points`` (shape ``(P, n)``) for ``samples`` random increments ``h`` per point (normal, scale
    ``h_scale``, seeded) and the unit increments :math:`\pm e_i`. A sample test, not a proof: it finds violations,
    it cannot certify their absence.

    Returns
    -------
    ok : bool
    worst : float
        The smallest value of the quadratic form found (relative to :math:`\|h\|^2`).
    x, h : ndarray
        Where it was found.
    """
    _check_callable("psi", psi)
    points = as_real_array("points", points)
    if points.ndim != 2 or points.shape[0] == 0 or points.shape[1] < 2 or not np.isfinite(points).all():
        raise ValueError(f"expected finite points of shape (P >= 1, n >= 2), actual value: {_short(points)}")
    n = points.shape[1]
    q, S, R = _supply_rate(q, S, R, n - 1)
    h_scale = check_positive("h_scale", h_scale)
    samples = check_int_at_least("samples", samples, 0)
    rng = np.random.default_rng(seed)
    unit = np.vstack([np.eye(n - 1), -np.eye(n - 1)]) * h_scale
    worst, where = np.inf, (points[0], unit[0])
    for x in points:
        base = _psi_value(psi, x)
        for h in np.vstack([unit, h_scale * rng.standard_normal((samples, n - 1))]):
            Psi = _psi_value(psi, x + np.r_[0.0, h]) - base
            value = (q * Psi * Psi + 2.0 * Psi * (S @ h).item() + h @ R @ h) / max(h @ h, 1e-300)
            if not np.isfinite(value):  # a comparison with NaN is False: the test would pass unseen
                raise ValueError(
                    f"expected a finite dissipation form, actual value: {value!r} at x = {x.tolist()}, "
                    f"h = {h.tolist()} (Psi = {Psi!r})"
                )
            if value < worst:
                worst, where = value, (x, h)
    return bool(worst >= -1e-12), float(worst), np.array(where[0]), np.array(where[1])


def _psi_value(psi: Callable, x: np.ndarray) -> float:
    """``psi(x)`` as a finite float (a scalar or a one-entry array)."""
    value = as_real_array("psi(x)", psi(x))
    if value.size != 1 or not np.isfinite(value).all():
        raise ValueError(
            f"expected psi(x) to return a finite scalar at x = {x.tolist()}, actual value: {_short(value)}"
        )
    return float(value.reshape(-1)[0])


@dataclass(frozen=True)
class GlobalObserverDesign:
    r"""The design of :class:`GlobalHOSMObserver` by the algorithm of Apaza-Perez, Fridman and Moreno (2018).

    Attributes
    ----------
    K : ndarray, shape (n,)
        :math:`A_K = A + KC` Hurwitz.
    P : ndarray, shape (n, n)
        Solution of :math:`PA_K + A_K^TP + \epsilon Q + \Lambda_{\varrho_\psi} = -I` (step c, with margin).
    l : float
        The smallest scale of the search for which the theorem's matrix inequality holds (step d).
    margin : float
        Largest eigenvalue of that matrix at ``l`` (negative: the inequality holds).
    rho_psi : float
    """

    K: np.ndarray
    P: np.ndarray
    l: float
    margin: float
    rho_psi: float


def design_global_observer(n: int, q: float, S, R, *, poles=None, N=None, epsilon: float = 1.0,
                           l_max: float = 1e4) -> GlobalObserverDesign:  # fmt: skip
    r"""Steps a)-d) of the design algorithm of Apaza-Perez, Fridman and Moreno (2018), checked in NumPy.

    a) ``K`` places the eigenvalues of :math:`A_K = A + KC` at ``poles`` (default ``-1, -1.5, ..., ``);
    b) :math:`Q = I`, :math:`\tilde N` (``N[1:]``, default zero) and :math:`\epsilon`;
    c) ``P`` from the Lyapunov equation :math:`PA_K + A_K^TP = -(\epsilon Q + \Lambda_{\varrho_\psi} + I)`,
       :math:`\Lambda_{\varrho_\psi} = \mathrm{diag}(\varrho_\psi/(n - i + 1)^2)`;
    d) ``l`` doubled from 1 until the theorem's inequality holds,

    .. math::
        \begin{bmatrix} PA_K + A_K^TP + \epsilon Q + l^{-2n}T_l^TRT_l & * \\
        B^TP + l^{-(2n-1)}ST_l & lq \end{bmatrix} \preceq 0,\qquad T_l = \tilde I_n\Delta_l + l\tilde NC,

    (:math:`\tilde I_n` the rows 2..n of the identity, :math:`\Delta_l = \mathrm{diag}(l, \ldots, l^n)`) as
    printed in Fridman's slides; raises ``ValueError`` when no ``l <= l_max`` satisfies it.
    """
    from scipy.linalg import solve_continuous_lyapunov

    n = check_int_at_least("n", n, 2)
    A, B, C = _chain(n)
    poles = -(1.0 + 0.5 * np.arange(n)) if poles is None else as_real_array("poles", poles)
    if poles.shape != (n,) or not np.all(poles < 0):  # NaN is not negative either
        raise ValueError(f"expected {n} negative poles, actual value: {_short(poles)}")
    q, S, R = _supply_rate(q, S, R, n - 1)
    rho = dissipativity_constant(q, S, R)
    Nt = np.zeros(n) if N is None else as_real_array("N", N).reshape(-1)
    if Nt.shape != (n,) or not np.isfinite(Nt).all():
        raise ValueError(f"expected a finite N with shape ({n},), actual value: {_short(Nt)}")
    Nt = Nt[1:]
    epsilon = check_positive("epsilon", epsilon)
    l_max = check_positive("l_max", l_max)
    if l_max < 1.0 or 2 * n * math.log2(l_max) >= 1000:  # l runs 1, 2, 4, ... and enters as l^(2n)
        raise ValueError(
            f"expected 1 <= l_max with l_max^(2n) within a float's range (n = {n}), actual value: l_max = {l_max!r}"
        )
    K = -_placed_gain(A, C[None, :], poles)[:, 0]  # A + K C has the poles (checked there)
    AK = A + np.outer(K, C)
    Lam = np.diag(rho / (n - np.arange(n)) ** 2)
    P = solve_continuous_lyapunov(AK.T, -(epsilon * np.eye(n) + Lam + np.eye(n)))
    It = np.eye(n)[1:]
    l = 1.0
    while l <= l_max:
        T = It @ np.diag(l ** np.arange(1, n + 1)) + l * np.outer(Nt, C)
        top = P @ AK + AK.T @ P + epsilon * np.eye(n) + T.T @ R @ T / l ** (2 * n)
        off = B @ P + (S @ T).reshape(-1) / l ** (2 * n - 1)
        M = np.block([[top, off[:, None]], [off[None, :], np.array([[l * float(q)]])]])
        margin = float(np.linalg.eigvalsh(0.5 * (M + M.T)).max())
        if margin <= 0.0:
            return GlobalObserverDesign(K=K, P=P, l=l, margin=margin, rho_psi=rho)
        l *= 2.0
    raise ValueError(
        f"expected a scale l <= {l_max} satisfying the theorem's matrix inequality, actual value: none (last "
        f"largest eigenvalue {margin:.3g}); the nonlinearity's dissipativity {q, S.tolist(), R.tolist()} is too weak "
        "for these poles"
    )


class GlobalHOSMObserver:
    r"""Global finite-time observer for nonlinear systems with unknown inputs without the BIBS property
    (Apaza-Perez, Fridman and Moreno, IJC 2018; Fridman's slides, section 5, (21)-(22)).

    The system is in the triangular form

    .. math:: \dot x = Ax + B(\psi(x) + w) + \varphi(u, y),\qquad y = Cx = x_1,

    (``A`` the chain of integrators, :math:`B = e_n`), forward complete but possibly *unbounded*: no Lipschitz bound
    on :math:`y^{(n)}` exists, so the observer of Fridman et al. (2008) (:class:`NonlinearHOSMObserver`) cannot be
    used globally. The observer (22) bounds the error of a high-gain copy first and differentiates *its* output:

    .. math::
        \dot v = Av + B\psi\big(v + N(Cv - y)\big) + \varphi(u, y) + \Delta_lK(Cv - y),\qquad
        \hat x = v - \mathcal O^{-1}z,

    with :math:`\Delta_l = \mathrm{diag}(l, \ldots, l^n)`, :math:`N = (-1, \tilde N)` (so the nonlinearity reads
    the *measured* first coordinate: the unbounded part cancels in the error), ``z`` Levant's differentiator of
    :math:`e_{vy} = Cv - y` (order ``n - 1``, bound :math:`L_f` on :math:`e_{vy}^{(n)}`, which exists because the
    copy's error :math:`e_v = v - x` stays bounded) and
    :math:`\mathcal O = [C; CA_{K,l}; \ldots; CA_{K,l}^{n-1}]`, :math:`A_{K,l} = A + \Delta_lKC`: since
    :math:`e_{vy}^{(j)} = CA_{K,l}^je_v` for :math:`j < n`, :math:`z = \mathcal O e_v` after the differentiator's
    finite convergence time and :math:`\hat x = x` exactly.

    Parameters
    ----------
    psi : callable
        :math:`\psi(x) \to` scalar, for one state ``(n,)``; :math:`\{q, S, R\}`-dissipative in the coordinates
        ``2..n`` (:func:`design_global_observer` checks the theorem's inequality for given ``q, S, R``).
    n : int
    dt : float
        Sampling step.
    K : array_like, shape (n,)
        :math:`A + KC` Hurwitz (:func:`design_global_observer`).
    l : float
        Scale :math:`l \ge l_0` of the theorem.
    lipschitz : float
        :math:`L_f \ge |e_{vy}^{(n)}|`.
    N : array_like, shape (n,), optional
        Default ``(-1, 0, ..., 0)``; its first entry must be ``-1``.
    phi : callable, optional
        :math:`\varphi(u, y) \to (n,)` (default zero).
    substeps : int
        RK4 steps of the copy ``v`` per sample. Between samples the copy reads ``y`` as its Taylor polynomial at
        the last estimate, :math:`y(t_k + s) \approx \sum_{j<n} \hat x_{j+1}s^j/j!` (:math:`y^{(j)} = x_{j+1}` in
        the chain), whose error :math:`O(\tau^n)` does not grow with :math:`\Delta_l` the way a held sample's
        :math:`O(\tau)` does.

    Attributes
    ----------
    state : ndarray, shape (n,)
        :math:`\hat x`.
    copy : ndarray, shape (n,)
        ``v``.
    """

    @check_keywords
    def __init__(self, psi: Callable, n: int, dt: float, *, K, l: float, lipschitz: float, N=None,
                 phi: Callable | None = None, substeps: int = 4, discretization: str = "implicit"):  # fmt: skip
        _check_callable("psi", psi)
        if phi is not None:
            _check_callable("phi", phi)
        self.n = check_int_at_least("n", n, 2)
        self.dt = check_positive("dt", dt)
        self.l = check_positive("l", l)
        self.lipschitz = check_positive("lipschitz", lipschitz)
        self.substeps = check_int_at_least("substeps", substeps, 1)
        self.psi, self.phi = psi, phi
        self.K = as_real_array("K", K, copy=True).reshape(-1)
        self.N = np.r_[-1.0, np.zeros(self.n - 1)] if N is None else as_real_array("N", N, copy=True).reshape(-1)
        if self.K.shape != (self.n,) or self.N.shape != (self.n,) or self.N[0] != -1.0:
            raise ValueError(
                f"expected K and N of shape ({self.n},) with N[0] = -1 (psi reads the measured x1), actual value: "
                f"K={self.K!r}, N={self.N!r}"
            )
        A, self._B, self._C = _chain(self.n)
        self._A = A
        if np.any(np.linalg.eigvals(A + np.outer(self.K, self._C)).real >= 0):
            raise ValueError(f"expected A + K C Hurwitz, actual value: K={self.K!r}")
        self._DK = (self.l ** np.arange(1, self.n + 1)) * self.K  # Delta_l K
        AKl = A + np.outer(self._DK, self._C)
        O = np.vstack([self._C @ np.linalg.matrix_power(AKl, j) for j in range(self.n)])
        self._O_inv = np.linalg.inv(O)
        self._diff = Levant(self.n - 1, self.dt, self.lipschitz, discretization=discretization)
        self._fact = np.array([1.0 / np.prod(np.arange(1, j + 1)) for j in range(self.n)])
        self.state: np.ndarray | None = None
        self.copy: np.ndarray | None = None

    def _psi(self, x) -> float:
        return _psi_value(self.psi, x)

    def _rhs(self, v, y: float, u) -> np.ndarray:
        e = self._C @ v - y
        dv = self._A @ v + self._B * self._psi(v + self.N * e) + self._DK * e
        if self.phi is not None:
            dv = dv + np.asarray(self.phi(u, y), dtype=float).reshape(self.n)
        return dv

    def reset(self, y0, x0) -> np.ndarray:
        """Start the copy at the guess ``x0`` (its first entry replaced by ``y0``); the first :meth:`update`, with
        the sample ``y0``, starts the differentiator. Returns :math:`\\hat x`."""
        y = _sample("y0", y0)
        x0 = as_real_array("x0", x0, copy=True).reshape(-1)
        if x0.shape != (self.n,) or not np.isfinite(x0).all():
            raise ValueError(f"expected a finite x0 with shape ({self.n},), actual value: {x0!r}")
        x0[0] = y
        self.copy = x0
        self.state = x0.copy()
        self._fresh = True  # the first update starts the differentiator at its sample
        return self.state.copy()

    def update(self, y, u=None) -> np.ndarray:
        """Process the sample ``y_k``; return :math:`\\hat x_k`, then move the copy to the next sample with the input
        ``u`` held over :math:`[t_k, t_{k+1})`."""
        if self.state is None:
            raise RuntimeError("expected reset(y0, x0) before update(y), actual value: the observer was never reset")
        y = _sample("y", y)
        e = np.array([self._C @ self.copy - y])
        saved = None if self._fresh else self._diff.checkpoint()
        try:
            z = (self._diff.reset(e) if self._fresh else self._diff.update(e))[0]
            state = self.copy - self._O_inv @ z
            v = self._next_copy(state, u)
        except BaseException:  # psi, phi or the step failed: the sample was not taken
            if saved is not None:
                self._diff.restore(saved)
            raise
        self._fresh = False
        self.state, self.copy = state, v
        return self.state.copy()

    def _next_copy(self, state: np.ndarray, u) -> np.ndarray:
        """The copy over the next interval (Runge-Kutta 4, :attr:`substeps` steps), ``y`` read as the Taylor polynomial
        of the estimate ``state``."""
        h = self.dt / self.substeps
        v, s = self.copy.copy(), 0.0
        taylor = state * self._fact

        def y_at(t):
            return float(np.polyval(taylor[::-1], t))

        with np.errstate(over="ignore", invalid="ignore"):
            for _ in range(self.substeps):
                k1 = self._rhs(v, y_at(s), u)
                k2 = self._rhs(v + h / 2 * k1, y_at(s + h / 2), u)
                k3 = self._rhs(v + h / 2 * k2, y_at(s + h / 2), u)
                k4 = self._rhs(v + h * k3, y_at(s + h), u)
                v = v + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
                s += h
        if not (np.all(np.isfinite(v)) and np.all(np.isfinite(state))):
            raise DivergenceError(
                "expected a finite estimate and copy after the step, actual value: non-finite; the previous state "
                "was kept (a smaller dt or l)"
            )
        return v

    def run(self, Y, x0, U=None) -> np.ndarray:
        """Reset at ``Y[0]`` with the guess ``x0`` and process ``Y`` (shape ``(T,)``), ``U[k]`` held over
        ``[t_k, t_{k+1})``; returns the estimates, shape ``(T, n)``."""
        Y = as_real_array("Y", Y).reshape(-1)
        if Y.size == 0 or (U is not None and len(U) < Y.size):
            raise ValueError(
                f"expected Y with shape (T,), T >= 1, and U with T rows, actual value: T = {Y.size}, "
                f"{'no U' if U is None else f'{len(U)} rows of U'}"
            )
        out = np.empty((Y.size, self.n))
        self.reset(Y[0], x0)
        for k in range(Y.size):
            out[k] = self.update(Y[k], None if U is None else U[k])
        return out
