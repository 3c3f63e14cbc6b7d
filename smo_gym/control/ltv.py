r"""Linear time-varying plants with unknown inputs: strong observability and the cascaded HOSM observer.

The plant of Fridman's slides, section 3, eq. (13):

.. math::
    \dot x = A(t) x + B(t) u + D(t) w,\qquad y = C(t) x,

``x`` in :math:`\mathbb R^n`, ``u`` in :math:`\mathbb R^q` (known), ``w`` in :math:`\mathbb R^m` (unknown),
``y`` in :math:`\mathbb R^p`. :class:`LTVPlant` holds the matrix functions and their derivatives;
:func:`ltv_strong_observability` is the test of Kratz and Liebscher (1998) at given times; :func:`ltv_state_map`
is the state reconstruction of their corollary; :class:`CascadedLTVObserver` is the observer of Galvan-Guerra,
Fridman and Davila (2017): an auxiliary observer keeps the estimation error bounded, a HOSM differentiator
differentiates the output error, and the corollary turns the derivatives into the state error.

Derivative bookkeeping
----------------------
Every construction needs derivatives of products of ``A``, ``C``, ``D``. They are carried as truncated Taylor
series at the time of interest: ``f[k] = f^(k)(t) / k!``, with the product
:math:`(fg)_k = \sum_j f_j g_{k-j}` and the derivative :math:`(\dot f)_k = (k+1) f_{k+1}` (each derivative costs one
coefficient). The series of ``A``, ``C``, ``D`` come from user-supplied derivatives or numerically
(:meth:`LTVPlant.taylor`), and everything else is exact arithmetic on them.

References
----------
.. [KL98] W. Kratz and D. Liebscher, "A local characterization of observability", Linear Algebra and its
   Applications 269, 1998.
.. [GFD17] R. Galvan-Guerra, L. Fridman and J. Davila, "High-order sliding-mode observer for linear time-varying
   systems with unknown inputs", Int. J. Robust and Nonlinear Control 27, 2338-2356, 2017.
.. [Rug96] W. J. Rugh, "Linear System Theory", 2nd ed., Prentice Hall, 1996.
.. [LM67] J. N. Lyness and C. B. Moler, "Numerical differentiation of analytic functions", SIAM J. Numerical
   Analysis 4(2), 1967.
.. [Fri] L. Fridman, "Sliding Mode Observers: Theory and Practice", lecture slides, section 3.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from .._validation import (
    DivergenceError,
    as_real_array,
    check_bool,
    check_choice,
    check_int_at_least,
    check_int_in_range,
    check_nonnegative,
    check_positive,
    check_real,
)
from ..design.gains import MAX_LEVANT_ORDER
from ..observers import Levant
from .estimators import _highest_block
from .plants import RANK_TOL, NotStronglyObservableError, _rank, left_annihilator

__all__ = [
    "CascadedLTVObserver",
    "LTVPlant",
    "LTVStrongObservabilityReport",
    "ltv_example",
    "ltv_state_map",
    "ltv_strong_observability",
    "simulate_ltv",
]

_NAMES = ("A", "B", "C", "D")


# ---- truncated Taylor series: f[k] = f^(k)(t) / k!, shape (K + 1, rows, cols) -------------------------------------
def _smul(f: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Product of two matrix series, as long as the shorter one."""
    K = min(len(f), len(g))
    out = np.zeros((K, f.shape[1], g.shape[2]))
    for k in range(K):
        for j in range(k + 1):
            out[k] += f[j] @ g[k - j]
    return out


def _sdiff(f: np.ndarray) -> np.ndarray:
    """Series of the time derivative (one coefficient shorter)."""
    return f[1:] * np.arange(1, len(f))[:, None, None]


def _sadd(f: np.ndarray, g: np.ndarray) -> np.ndarray:
    K = min(len(f), len(g))
    return f[:K] + g[:K]


def _observability_series(A: np.ndarray, C: np.ndarray, count: int) -> list[np.ndarray]:
    r"""Series of Rugh's :math:`N_0 = C,\ N_i = N_{i-1} A + \dot N_{i-1}`, ``i < count``."""
    N = [C]
    for _ in range(1, count):
        N.append(_sadd(_smul(N[-1], A), _sdiff(N[-1])))
    return N


def kratz_liebscher_matrices(A: np.ndarray, C: np.ndarray, D: np.ndarray, blocks: int, *, _N=None):
    r"""Observability matrix :math:`\mathcal O_l` and input matrix :math:`\mathcal J_l` of [KL98] at one time.

    .. math::
        \begin{bmatrix} y \\ \dot y \\ \vdots \\ y^{(l-1)} \end{bmatrix}
        = \mathcal O_l(t)\,x + \mathcal J_l(t)\begin{bmatrix} w \\ \vdots \\ w^{(l-2)} \end{bmatrix},
        \qquad y^{(i)} = N_i x + \sum_{\nu=1}^{i} \mathcal D_{i+1,\nu}\, w^{(\nu-1)},

    with :math:`\mathcal D_{\mu,\mu-1} = CD`, :math:`\mathcal D_{\mu,1} = N_{\mu-2}D + \dot{\mathcal D}_{\mu-1,1}`
    and :math:`\mathcal D_{\mu,\nu} = \mathcal D_{\mu-1,\nu-1} + \dot{\mathcal D}_{\mu-1,\nu}` for
    :math:`2 \le \nu < \mu` (differentiate :math:`y^{(i)}` once and collect the terms).

    Parameters
    ----------
    A, C, D : ndarray, shapes (K + 1, n, n), (K + 1, p, n), (K + 1, n, m)
        Taylor series at ``t`` (``f[k] = f^(k)(t)/k!``) with ``K >= blocks - 1``.
    blocks : int
        ``l``, the number of output derivatives ``y, ..., y^(l-1)``.

    Returns
    -------
    O : ndarray, shape (p l, n)
    J : ndarray, shape (p l, m (l - 1))
        Block ``(i, j)`` (derivative-major rows) is :math:`\mathcal D_{i+1,j+1}`; zero for ``j >= i``.
    """
    blocks = check_int_at_least("blocks", blocks, 1)
    p, m = C.shape[1], D.shape[2]
    if min(len(A), len(C), len(D)) < blocks:
        raise ValueError(
            f"expected Taylor series with at least {blocks} coefficients for {blocks} derivative blocks, actual "
            f"value: {len(A)}, {len(C)}, {len(D)} coefficients of A, C, D"
        )
    N = _observability_series(A, C, blocks) if _N is None else _N
    O = np.vstack([Ni[0] for Ni in N[:blocks]])
    J = np.zeros((p * blocks, m * max(blocks - 1, 0)))
    G = [_smul(C, D)]  # G[j]: series of the coefficient of w^(j) in the current y^(i); i = 1 here
    for i in range(1, blocks):
        for j, Gj in enumerate(G):
            J[i * p : (i + 1) * p, j * m : (j + 1) * m] = Gj[0]
        if i + 1 < blocks:  # y^(i+1): differentiate y^(i) = N_i x + sum_j G[j] w^(j), with x' = A x + D w
            new = [_sadd(_smul(N[i], D), _sdiff(G[0]))]
            new += [_sadd(_sdiff(G[j]), G[j - 1]) for j in range(1, i)]
            new.append(G[i - 1][:-1])
            G = new
    return O, J


def _unit_scales(A: np.ndarray, C: np.ndarray, D: np.ndarray, blocks: int) -> tuple[np.ndarray, np.ndarray, float]:
    r"""``(rows, cols, a)``: the scalings that bring :math:`\mathcal O_l` and :math:`\mathcal J_l` to unit size.

    With the rate ``a`` of ``A`` (time unit ``1/a``) and the sizes ``c`` of ``C`` and ``d`` of ``D``, ``y^(i)`` has
    the size ``c a^i`` and ``w^(j)`` the size ``d a^j``: block row ``i`` is divided by ``c a^i`` (``rows``) and the
    block column of ``w^(j)`` in ``J`` multiplied by ``a^(j+1) / d`` (``cols``), so that :math:`N_i` and
    :math:`\mathcal D_{i+1,j+1}` (``~ C A^i`` and ``C A^(i-1-j) D`` for constant matrices) are judged against the
    size of their rounding errors, as the LTI rank decisions are (:func:`~smo_gym.control.plants._unit`): no
    verdict depends on the units of time, ``y`` or ``w``, and a block that vanishes in exact arithmetic stays at
    rank 0. ``a = max_k ||A_k||^(1/(k+1))`` over the Taylor coefficients used (``||A||`` for a constant ``A``),
    ``c = max_k ||C_k|| / a^k`` (the series, not ``C(t)`` alone, which may vanish at ``t``) and ``d`` likewise,
    each read as 1 where it is 0. Not rounded to powers of two: scaled exactly with the units, they leave the
    report's margin unchanged too.
    """
    k = np.arange(blocks)

    def size(M):  # the norms of the Taylor coefficients used by O_l and J_l
        return np.linalg.norm(M[:blocks], axis=(1, 2))

    a = float(max(size(A) ** (1.0 / (k + 1)))) or 1.0
    c, d = (float(max(size(M) / a**k)) or 1.0 for M in (C, D))
    p, m = C.shape[1], D.shape[2]
    return np.repeat(1.0 / (c * a**k), p), np.repeat(a ** k[1:] / d, m), a


def _state_map_from(O: np.ndarray, J: np.ndarray, rows, cols) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(F, K, KO)`` on the matrices scaled to unit size by ``rows`` and ``cols`` (:func:`_unit_scales`): ``K``
    with ``ker K = Im J`` (orthonormal rows) and ``F = (KO)^+ K``, scaled back to the derivatives of ``y``."""
    O, J = rows[:, None] * O, rows[:, None] * J * cols
    K = left_annihilator(J) if J.size else np.eye(O.shape[0])
    KO = K @ O
    return (np.linalg.pinv(KO) @ K) * rows, K, KO


def input_map(O: np.ndarray, J: np.ndarray, m: int, rows=None, cols=None) -> np.ndarray | None:
    r"""``G`` with :math:`G\mathcal J = [I_m\ 0]`, so that :math:`w = G(\bar y - \mathcal O x)`; ``None`` if none.

    From :math:`\bar y - \mathcal O x = \mathcal J \bar w = J_1 w + J_2 [\dot w; \ldots]`: with :math:`\Pi`
    the left annihilator of :math:`J_2`, :math:`w = (\Pi J_1)^+\Pi(\bar y - \mathcal O x)` when
    :math:`\Pi J_1` has full column rank ``m`` (``w`` is then fixed by the output derivatives, whatever its own
    derivatives are). Computed on ``J`` scaled to unit size by ``rows`` and ``cols`` (:func:`_unit_scales`;
    default none): the rank decisions of ``left_annihilator`` and of :math:`\Pi J_1` have an absolute floor.
    """
    if not np.isfinite(J).all():  # the SVDs below would fail unexplained
        raise ValueError(f"expected a finite J, actual value: {J!r:.80}")
    rows = np.ones(J.shape[0]) if rows is None else rows
    cols = np.ones(J.shape[1]) if cols is None else cols
    J = rows[:, None] * J * cols
    J1, J2 = J[:, :m], J[:, m:]
    Pi = left_annihilator(J2) if J2.size else np.eye(J.shape[0])
    PJ1 = Pi @ J1
    if _rank(PJ1) < m:
        return None
    return cols[:m, None] * (np.linalg.pinv(PJ1) @ Pi) * rows  # G = S_1 G' R for J' = R J S


# ---- the plant -------------------------------------------------------------------------------------------------
class LTVPlant:
    r"""A linear time-varying plant with a known control and an unknown input (Fridman's slides, eq. (13)).

    .. math:: \dot x = A(t) x + B(t) u + D(t) w(t),\qquad y = C(t) x.

    Parameters
    ----------
    A : callable ``t -> (n, n)`` or array_like, shape (n, n)
        A constant array is a constant function (its derivatives are exactly zero).
    B : callable ``t -> (n, q)``, array_like or None
        Control matrix; ``None`` is no control (``q = 0``).
    C : callable ``t -> (p, n)`` or array_like
    D : callable ``t -> (n, m)`` or array_like
        A vector is one column, for arrays and for callables' values.
    derivatives : dict, optional
        Exact derivatives: ``{"A": f, ...}`` with ``f(t, k)`` returning the stack ``[M(t), M'(t), ..., M^(k)(t)]``,
        shape ``(k + 1, rows, cols)``. The matrices not listed are differentiated numerically by ``method``.
    method : {"complex", "central"}
        Numerical differentiation.

        ``"complex"`` (default): Cauchy's integral formula by the trapezoidal rule on a circle of radius ``radius``
        around ``t`` in the complex plane (Lyness and Moler 1967), i.e. a discrete Fourier transform of
        ``M(t + r e^{2 pi i j / N})``, ``N = n_points``. Needs callables that are real-analytic and accept a
        complex ``t`` (``np.sin``, ``np.exp``, polynomials do; ``abs``, ``float(t)``, piecewise definitions do
        not: :class:`LTVPlant` compares the first derivative with a real central difference at ``t0`` and
        raises ``ValueError`` on a mismatch). Error of the ``k``-th Taylor coefficient: aliasing
        :math:`\sum_{j \ge 1} |M_{k+jN}| r^{jN}` plus rounding :math:`\approx 10^{-16}\max|M| / r^k`; for entire
        functions varying on a time scale ``T >> r`` the derivatives are exact to ~``1e-13 k! / r^k``.

        ``"central"``: the Taylor polynomial of degree ``2s`` through ``2s + 1`` equally spaced real samples
        ``t + j h`` (``h = radius``, ``2s + 1 = n_points``), i.e. central differences of order ``2s + 1 - k``
        for the ``k``-th derivative: truncation :math:`O(|M^{(2s+1)}| h^{2s+1-k})`, rounding
        :math:`O(10^{-16}\max|M| / h^k)`; for real-only callables.
    radius : float
        ``r`` (or the step ``h``): must be well below the time scale on which ``A``, ``C``, ``D`` vary and
        below the distance to their complex singularities.
    n_points : int, optional
        Default ``max(8, 2 (K + 1))`` for ``K`` derivatives with ``"complex"`` (aliasing then adds a relative
        :math:`(r/T)^N K!/(K+N)!` for a time scale ``T``: below ``1e-10`` for ``r <= T/3``), 9 for ``"central"``.
    t0 : float
        A time at which the callables are evaluated to find the shapes (and the check above is done).

    Attributes
    ----------
    n, n_inputs, n_outputs, n_unknown : int
    """

    def __init__(self, A, B, C, D, *, derivatives=None, method="complex", radius=0.1, n_points=None, t0=0.0):
        self.method = check_choice("method", method, ("complex", "central"))
        self.radius = check_positive("radius", radius)
        self.t0 = check_real("t0", t0)
        low = 4 if method == "complex" else 3
        self.n_points = None if n_points is None else check_int_in_range("n_points", n_points, low, 64)
        if method == "central" and self.n_points is not None and self.n_points % 2 == 0:
            raise ValueError(f"expected an odd n_points for method='central', actual value: {n_points}")
        self._funcs, self._const = {}, {}
        for name, value in zip(_NAMES, (A, B, C, D), strict=True):
            if value is None and name != "B":
                raise TypeError(f"expected {name} a callable t -> matrix or a constant matrix, actual value: None")
            if callable(value):
                self._funcs[name] = value
            elif value is not None:
                arr = self._as_matrix(name, np.atleast_2d(value) if name == "C" else value, None)
                self._const[name] = arr
                self._funcs[name] = lambda t, arr=arr: arr
        A0 = self._as_matrix("A", self._funcs["A"](self.t0), None)
        n = A0.shape[0]
        if A0.shape != (n, n):
            raise ValueError(f"expected A(t) square, actual value: shape {A0.shape} at t={self.t0}")
        if n == 0:
            raise ValueError(f"expected A(t) with at least one state, actual value: shape {A0.shape} at t={self.t0}")
        C0 = self._as_matrix("C", np.atleast_2d(self._funcs["C"](self.t0)), None)
        D0 = self._as_matrix("D", self._funcs["D"](self.t0), None)
        if "B" not in self._funcs:
            self._const["B"] = np.zeros((n, 0))
            self._funcs["B"] = lambda t: self._const["B"]
        B0 = self._as_matrix("B", self._funcs["B"](self.t0), None)
        self._shapes = {"A": (n, n), "B": (n, B0.shape[1]), "C": (C0.shape[0], n), "D": (n, D0.shape[1])}
        for name, val in (("B", B0), ("C", C0), ("D", D0)):
            if val.shape != self._shapes[name]:
                raise ValueError(
                    f"expected {name}(t) with shape {self._shape_text(name)} (n={n} from A), actual value: shape "
                    f"{val.shape} at t={self.t0}"
                )
        if derivatives is not None and not isinstance(derivatives, dict):
            raise TypeError(
                f"expected derivatives a dict {{'A': f, ...}} of callables (t, k) -> stack, actual value: "
                f"{derivatives!r:.80}"
            )
        self._derivs = {}
        for name, f in (derivatives or {}).items():
            if name not in ("A", "C", "D", "B"):
                raise ValueError(f"expected derivatives keys among 'A', 'B', 'C', 'D', actual value: {name!r}")
            if not callable(f):
                raise TypeError(f"expected derivatives[{name!r}] callable (t, k) -> stack, actual value: {f!r}")
            self._derivs[name] = f
        if self.method == "complex":
            for name in ("A", "C", "D"):
                if name not in self._const and name not in self._derivs:
                    self._check_complex(name)

    # -- shapes and evaluation --------------------------------------------------------------------------------
    @property
    def n(self) -> int:
        return self._shapes["A"][0]

    @property
    def n_inputs(self) -> int:
        return self._shapes["B"][1]

    @property
    def n_outputs(self) -> int:
        return self._shapes["C"][0]

    @property
    def n_unknown(self) -> int:
        return self._shapes["D"][1]

    def _shape_text(self, name: str) -> str:
        return "({}, {})".format(*self._shapes[name])

    @staticmethod
    def _as_matrix(name: str, value, shape, *, t=None, dtype=np.float64) -> np.ndarray:
        where = "" if t is None else f" at t={t!r}"
        try:
            arr = np.array(value, dtype=dtype)
        except (TypeError, ValueError):
            raise TypeError(f"expected {name} to be a real matrix{where}, actual value: {value!r}") from None
        except OverflowError:  # an integer beyond a float's range
            raise ValueError(f"expected {name} within a float's range{where}, actual value: {value!r:.80}") from None
        if arr.ndim == 1:  # a vector is one column
            arr = arr[:, None]
        if arr.ndim != 2 or (shape is not None and arr.shape != shape):
            want = "a matrix" if shape is None else f"shape {shape}"
            raise ValueError(f"expected {name}(t) with {want}{where}, actual value: shape {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"expected finite entries in {name}(t){where}, actual value: {arr!r}")
        return arr

    def matrix(self, name: str, t, *, dtype=np.float64) -> np.ndarray:
        """``name(t)`` (``name`` one of ``"A"``, ``"B"``, ``"C"``, ``"D"``), checked for its shape."""
        name = check_choice("name", name, _NAMES)
        value = self._funcs[name](t)
        if name == "C":
            value = np.atleast_2d(value)
        return self._as_matrix(name, value, self._shapes[name], t=t, dtype=dtype)

    def A(self, t) -> np.ndarray:
        return self.matrix("A", t)

    def B(self, t) -> np.ndarray:
        return self.matrix("B", t)

    def C(self, t) -> np.ndarray:
        return self.matrix("C", t)

    def D(self, t) -> np.ndarray:
        return self.matrix("D", t)

    # -- derivatives ------------------------------------------------------------------------------------------
    def taylor(self, name: str, t: float, order: int) -> np.ndarray:
        r"""Taylor coefficients :math:`M^{(k)}(t)/k!`, ``k = 0..order``, of ``M = name``; shape (order + 1, r, c)."""
        name = check_choice("name", name, _NAMES)
        order = check_int_in_range("order", order, 0, 32)
        t = check_real("t", t)
        shape = self._shapes[name]
        if name in self._const:
            out = np.zeros((order + 1, *shape))
            out[0] = self._const[name]
            return out
        if name in self._derivs:
            stack = np.asarray(self._derivs[name](t, order), dtype=float)
            if name == "C" and stack.ndim == 2:
                stack = stack[:, None, :]
            if stack.ndim == 2 and shape[1] == 1:
                stack = stack[:, :, None]
            if stack.shape != (order + 1, *shape):
                raise ValueError(
                    f"expected derivatives[{name!r}](t, {order}) with shape {(order + 1, *shape)}, actual value: "
                    f"shape {stack.shape}"
                )
            if not np.all(np.isfinite(stack)):  # the SVDs of the rank test would fail on them, unexplained
                raise ValueError(
                    f"expected finite entries in derivatives[{name!r}](t, {order}) at t={t!r}, actual value: "
                    f"{stack!r:.120}"
                )
            return stack / np.array([math.factorial(k) for k in range(order + 1)])[:, None, None]
        if self.method == "complex":
            M = max(8, 2 * (order + 1)) if self.n_points is None else self.n_points
            if 2 * (order + 1) > M:
                raise ValueError(
                    f"expected n_points >= 2 (order + 1) = {2 * (order + 1)} for {order} derivatives by the "
                    f"complex method, actual value: {M}"
                )
            nodes = t + self.radius * np.exp(2j * np.pi * np.arange(M) / M)
            coef = np.fft.fft(self._samples(name, nodes, complex), axis=0)[: order + 1] / M
            return coef.real / self.radius ** np.arange(order + 1)[:, None, None]
        s = (9 if self.n_points is None else self.n_points) // 2
        if 2 * s < order:
            raise ValueError(
                f"expected n_points >= {order + 1} for {order} derivatives by central differences, actual value: "
                f"{self.n_points}"
            )
        j = np.arange(-s, s + 1, dtype=float)
        V = j[:, None] ** np.arange(2 * s + 1)[None, :]
        vals = self._samples(name, t + self.radius * j, float)
        coef = np.linalg.solve(V, vals.reshape(len(j), -1)).reshape(len(j), *shape)
        return coef[: order + 1] / self.radius ** np.arange(order + 1)[:, None, None]

    def _samples(self, name: str, times: np.ndarray, dtype) -> np.ndarray:
        """``name(t)`` at each of ``times``, stacked, checked once (the hot path of :meth:`taylor`)."""
        f, shape = self._funcs[name], self._shapes[name]
        allowed = [shape]
        if (name == "C" and shape[0] == 1) or (name in ("B", "D") and shape[1] == 1):
            allowed.append((shape[0] * shape[1],))  # a vector is one row of C, one column of B or D
        with warnings.catch_warnings():  # a callable that drops the imaginary part of t must fail here
            warnings.simplefilter("error", np.exceptions.ComplexWarning)
            try:
                vals = np.array([f(s) for s in times], dtype=dtype)
            except (TypeError, ValueError, np.exceptions.ComplexWarning):
                vals = None
            if vals is None or vals.shape[1:] not in allowed or not np.all(np.isfinite(vals)):
                for s in times:  # find the offending time and say what is wrong there
                    self.matrix(name, s, dtype=dtype)
                raise ValueError(f"expected {name}(t) with shape {shape}, actual value: shape {np.shape(vals)[1:]}")
        return vals.reshape(len(times), *shape)

    def _check_complex(self, name: str) -> None:
        """Refuse callables that drop the imaginary part of ``t`` (their Cauchy derivatives would be garbage)."""
        t = self.t0
        try:
            d_complex = self.taylor(name, t, 1)[1]
        except (TypeError, ValueError, np.exceptions.ComplexWarning) as exc:
            raise ValueError(
                f"expected {name}(t) to accept a complex t for method='complex' (Cauchy's formula), actual value: "
                f"{type(exc).__name__}: {exc}; use method='central' or supply derivatives"
            ) from None
        h = 1e-5 * max(1.0, abs(t))
        d_real = (self.matrix(name, t + h) - self.matrix(name, t - h)) / (2 * h)
        scale = max(np.abs(self.matrix(name, t)).max(), np.abs(d_real).max(), 1.0)
        if np.abs(d_complex - d_real).max() > 1e-5 * scale:
            raise ValueError(
                f"expected {name}(t) analytic and accepting a complex t for method='complex', actual value: its "
                f"Cauchy derivative at t={t} differs from a central difference by "
                f"{np.abs(d_complex - d_real).max():.3g}; use method='central' or supply derivatives"
            )

    def series(self, t: float, order: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Taylor series of ``(A, C, D)`` at ``t`` up to ``order`` (see :meth:`taylor`)."""
        return self.taylor("A", t, order), self.taylor("C", t, order), self.taylor("D", t, order)

    def __repr__(self) -> str:
        return (
            f"LTVPlant(n={self.n}, inputs={self.n_inputs}, outputs={self.n_outputs}, unknown inputs="
            f"{self.n_unknown}, method={self.method!r})"
        )


# ---- strong observability ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class LTVStrongObservabilityReport:
    r"""What :func:`ltv_strong_observability` found on a time grid.

    Attributes
    ----------
    ok : bool
        Strongly observable at every time of the grid, with ``blocks`` output derivative blocks.
    condition : str
        ``""`` if ``ok``; otherwise the condition that failed: ``"observability"`` (Rugh's rank condition:
        :math:`\operatorname{rank}\mathcal O_l(t) < n` for every ``l`` tried, so not even the known-input problem
        is solvable) or ``"strong observability"`` (Kratz and Liebscher's
        :math:`\operatorname{rank} S(t) < \operatorname{rank} S^*(t)`).
    reason : str
        Plain words, with the first failing time and the ranks.
    times : ndarray, shape (T,)
    blocks : int
        ``l``: output derivatives ``y .. y^(l-1)`` used (the smallest that works at every time of the grid, or
        the one requested).
    observability_index : int or None
        Rugh's observability index on the grid: the smallest ``l`` with ``rank O_l(t) = n`` at every time
        (``None``: not reached up to the largest ``l`` tried).
    rank_S, rank_S_star : ndarray of int, shape (T,)
        The ranks of :math:`S = [\mathcal O_l\ \mathcal J_l]` and :math:`S^* = [I\ 0;\ \mathcal O_l\ \mathcal J_l]`.
    margin : ndarray, shape (T,)
        Smallest over largest singular value of :math:`K\mathcal O_l` (zero where the condition fails), with each
        output derivative at unit size (:func:`_unit_scales`, so that no unit changes it): how far the
        reconstruction is from singular.
    """

    ok: bool
    condition: str
    reason: str
    times: np.ndarray
    blocks: int
    observability_index: int | None
    rank_S: np.ndarray
    rank_S_star: np.ndarray
    margin: np.ndarray


def _scaled_rank(M: np.ndarray, scale: float | None = None) -> int:
    """Rank of ``M`` counting singular values above ``RANK_TOL * scale`` (default: ``M``'s largest one).

    Relative to the matrix's own scale, so that multiplying ``C`` by a constant changes no rank decision (an
    absolute floor would call a tiny ``C`` blind and hide a unit identity block next to a huge ``C``).
    """
    if M.size == 0:
        return 0
    s = np.linalg.svd(M, compute_uv=False)
    return int(np.sum(s > RANK_TOL * (s[0] if scale is None else scale)))


def _ranks(O: np.ndarray, J: np.ndarray, rows, cols) -> tuple[int, int, float]:
    n = O.shape[1]
    KO = _state_map_from(O, J, rows, cols)[2]
    O, J = rows[:, None] * O, rows[:, None] * J * cols  # unit sizes (_unit_scales)
    S = np.hstack([O, J])
    # rank S* = n + rank J exactly; stacking I_n on S would judge the identity on the scale of O and J
    scale = np.linalg.svd(S, compute_uv=False)[0] if S.size else 0.0
    rank_S, rank_S_star = _scaled_rank(S, scale), n + _scaled_rank(J, scale)
    s = np.linalg.svd(KO, compute_uv=False) if KO.size else np.zeros(1)
    margin = float(s[-1] / s[0]) if s.size >= n and s[0] > 0 else 0.0
    return rank_S, rank_S_star, margin


def ltv_strong_observability(plant: LTVPlant, t, *, blocks=None, max_blocks=None) -> LTVStrongObservabilityReport:
    r"""Strong observability of ``(A(t), C(t), D(t))`` at the times ``t`` (Kratz and Liebscher 1998).

    The triple is strongly observable on an interval iff, at every time of it,

    .. math::
        \operatorname{rank} S(t) = \operatorname{rank} S^*(t),\qquad
        S = \begin{bmatrix}\mathcal O_l & \mathcal J_l\end{bmatrix},\quad
        S^* = \begin{bmatrix} I_n & 0 \\ \mathcal O_l & \mathcal J_l\end{bmatrix}

    (Fridman's slides, eq. (15); :func:`kratz_liebscher_matrices`). Since
    :math:`\operatorname{rank} S^* = n + \operatorname{rank}\mathcal J_l` and
    :math:`\operatorname{rank} S = \operatorname{rank}\mathcal J_l + \operatorname{rank} K\mathcal O_l` for
    :math:`\ker K = \operatorname{Im}\mathcal J_l`, the condition says that ``y .. y^(l-1)`` fix ``x`` whatever
    ``w .. w^(l-2)`` are: the state map of :func:`ltv_state_map` exists.

    Parameters
    ----------
    plant : LTVPlant
    t : float or array_like, shape (T,)
        The times checked (a grid stands for an interval: the test is pointwise).
    blocks : int, optional
        ``l``. Default: the smallest ``l <= max_blocks`` for which the condition holds at every time.
    max_blocks : int, optional
        Largest ``l`` tried; default ``n`` (enough for constant matrices: the weakly unobservable subspaces
        :math:`\mathcal V_l` of Molinari's algorithm, ``x`` with :math:`\mathcal O_l x \in \operatorname{Im}
        \mathcal J_l`, shrink at every step until they stop, so they settle by ``l = n``).

    Notes
    -----
    The slides print the recursion :math:`\mathcal D_{\mu,\nu} = \mathcal D_{\mu-1,\nu-1} +
    \dot{\mathcal D}_{\mu-1,\nu}` for :math:`3 \le \nu < \mu`; differentiating :math:`y^{(\mu-2)}` gives it for
    :math:`2 \le \nu < \mu` (``D_{4,2}`` needs it), which is what is implemented. The slides use ``l`` equal to
    Rugh's observability index; that can be too few derivatives for the unknown-input problem (with
    ``x1' = x3, x3' = x4, x2' = x4 + w, y = (x1, x2)`` the index is 2 but ``x4`` is read from ``y1''`` only),
    hence the search over ``l``.
    """
    if not isinstance(plant, LTVPlant):
        raise TypeError(f"expected an LTVPlant, actual value: {type(plant).__name__}")
    if isinstance(t, (bool, np.bool_)):
        raise TypeError(f"expected t a time or a grid of times, actual value: {t!r}")
    times = np.atleast_1d(as_real_array("t", t))
    if times.ndim != 1 or times.size == 0 or not np.all(np.isfinite(times)):
        raise ValueError(f"expected t a finite time or a 1-D grid of them, actual value: {t!r}")
    n = plant.n
    max_blocks = n if max_blocks is None else check_int_in_range("max_blocks", max_blocks, 1, 16)
    if blocks is not None:
        blocks = check_int_in_range("blocks", blocks, 1, 16)
    top = blocks if blocks is not None else max_blocks
    series = [plant.series(float(ti), top) for ti in times]

    def observability_rank(s, lo):  # of O_l with its block rows y^(i) at unit size (_unit_scales)
        return _scaled_rank(_unit_scales(*s, lo)[0][:, None] * kratz_liebscher_matrices(*s, lo)[0])

    # Rugh's observability index (the O_l part only)
    obs_index = None
    for lo in range(1, top + 1):
        if all(observability_rank(s, lo) == n for s in series):
            obs_index = lo
            break
    candidates = [blocks] if blocks is not None else list(range(1, max_blocks + 1))
    for lo in candidates:
        results = [_ranks(*kratz_liebscher_matrices(*s, lo), *_unit_scales(*s, lo)[:2]) for s in series]
        rS = np.array([r[0] for r in results])
        rSs = np.array([r[1] for r in results])
        if np.all(rS == rSs):
            break
    margin = np.array([r[2] if r[0] == r[1] else 0.0 for r in results])
    bad = np.nonzero(rS != rSs)[0]
    if bad.size == 0:
        return LTVStrongObservabilityReport(True, "", "", times, lo, obs_index, rS, rSs, margin)
    i = int(bad[0])
    rank_O = observability_rank(series[i], lo)
    if rank_O < n:
        condition = "observability"
        reason = (
            f"(A(t), C(t)) is not observable at t={times[i]:.6g}: rank O_{lo}(t) = {rank_O} < n = {n} "
            f"(Rugh's rank condition, l up to {lo})"
        )
    else:
        condition = "strong observability"
        reason = (
            f"rank S(t) = {rS[i]} < rank S*(t) = {rSs[i]} at t={times[i]:.6g} with l = {lo} derivative blocks "
            f"(Kratz and Liebscher 1998): an unknown input hides a {rSs[i] - rS[i]}-dimensional set of states "
            "from y and its derivatives"
        )
    if bad.size > 1:
        reason += f"; fails at {bad.size} of {times.size} times"
    return LTVStrongObservabilityReport(False, condition, reason, times, lo, obs_index, rS, rSs, margin)


def _raise_if_not(report: LTVStrongObservabilityReport) -> None:
    if not report.ok:
        raise NotStronglyObservableError(
            f"expected a strongly observable triple (A(t), C(t), D(t)), actual value: the {report.condition} "
            f"condition fails: {report.reason}"
        )


def ltv_state_map(plant: LTVPlant, t: float, blocks: int) -> np.ndarray:
    r"""The state from the output derivatives (Kratz and Liebscher's corollary; Fridman's slides).

    .. math::
        x(t) = \mathcal H^{-1}\mathcal O_l^T K^T K\,\bar y,\qquad
        \mathcal H = \mathcal O_l^T K^T K \mathcal O_l,\qquad \ker K = \operatorname{Im}\mathcal J_l,\qquad
        \bar y = [y; \dot y; \ldots; y^{(l-1)}],

    valid for every unknown input (``K`` kills the input terms of :math:`\bar y = \mathcal O_l x +
    \mathcal J_l \bar w`). Computed as :math:`(K\mathcal O_l)^+ K` with orthonormal rows of ``K`` on
    :math:`\bar y` with each derivative at unit size (:func:`_unit_scales`), then scaled back.

    Returns
    -------
    ndarray, shape (n, p l)
        Columns in derivative-major order (``y``, then ``y'``, ...).

    Raises
    ------
    NotStronglyObservableError
        When :math:`\mathcal H(t)` is singular (the condition of :func:`ltv_strong_observability` fails at ``t``).
    """
    report = ltv_strong_observability(plant, t, blocks=blocks)
    _raise_if_not(report)
    series = plant.series(float(t), blocks)
    return _state_map_from(*kratz_liebscher_matrices(*series, blocks), *_unit_scales(*series, blocks)[:2])[0]


# ---- simulation ------------------------------------------------------------------------------------------------
def _vector(name: str, value, size: int, t: float) -> np.ndarray:
    arr = np.atleast_1d(as_real_array(f"{name}(t)", value)).reshape(-1)
    if arr.shape != (size,):
        raise ValueError(f"expected {name}(t) with shape ({size},) at t={t}, actual value: shape {arr.shape}")
    if not np.all(np.isfinite(arr)):  # a NaN would spread silently through the estimate or the trajectory
        raise ValueError(f"expected finite {name}(t) at t={t}, actual value: {arr!r:.120}")
    return arr


def simulate_ltv(plant: LTVPlant, x0, t_final: float, dt: float, *, w=None, u=None, substeps: int = 8):
    r"""Simulate the plant with RK4 and sample its output every ``dt``.

    ``u`` is held between samples (zero-order hold, as a sampled controller applies it); ``w`` is evaluated
    continuously. RK4 on the step ``dt / substeps``: global error :math:`O((dt/\text{substeps})^4)`.

    Parameters
    ----------
    x0 : array_like, shape (n,)
    w : callable ``t -> (m,)``, optional
        The unknown input (default zero).
    u : callable ``t -> (q,)``, optional
        Evaluated at the samples (default zero).

    Returns
    -------
    t : ndarray, shape (T,)
    x : ndarray, shape (T, n)
    y : ndarray, shape (T, p)
    u : ndarray, shape (T, q)
        The held controls.

    Raises
    ------
    ValueError
        When ``x0``, ``w(t)`` or ``u(t)`` has a non-finite entry.
    DivergenceError
        When the state becomes non-finite (an unstable plant over a long horizon).
    """
    dt = check_positive("dt", dt)
    t_final = check_positive("t_final", t_final)
    substeps = check_int_in_range("substeps", substeps, 1, 10_000)
    n, m, q = plant.n, plant.n_unknown, plant.n_inputs
    x = _vector("x0", x0, n, 0.0)
    steps = int(round(t_final / dt))
    t = plant.t0 + dt * np.arange(steps + 1)
    X, Y, U = np.zeros((steps + 1, n)), np.zeros((steps + 1, plant.n_outputs)), np.zeros((steps + 1, q))

    def wv(s):
        return np.zeros(m) if w is None else _vector("w", w(s), m, s)

    h = dt / substeps
    for k, tk in enumerate(t):
        X[k], Y[k] = x, plant.C(tk) @ x
        U[k] = np.zeros(q) if u is None else _vector("u", u(tk), q, tk)
        if k == steps:
            break
        for i in range(substeps):
            s = tk + i * h

            def f(s, x, k=k):
                return plant.A(s) @ x + plant.B(s) @ U[k] + plant.D(s) @ wv(s)

            with np.errstate(over="ignore", invalid="ignore"):  # an overflow is reported just below
                k1 = f(s, x)
                k2 = f(s + h / 2, x + h / 2 * k1)
                k3 = f(s + h / 2, x + h / 2 * k2)
                k4 = f(s + h, x + h * k3)
                x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            if not np.all(np.isfinite(x)):
                raise DivergenceError(
                    f"expected a finite state, actual value: {x!r:.120} at t={s + h:.6g} (the plant's state left "
                    "the range of a float; shorten t_final)"
                )
    return t, X, Y, U


# ---- an example -------------------------------------------------------------------------------------------------
def ltv_example() -> tuple[LTVPlant, callable, np.ndarray]:
    r"""An unstable, strongly observable LTV plant with an unknown input (our example; the slides print none).

    .. math::
        A(t) = \begin{bmatrix} 0.5 & 1 + 0.3\sin t & 0 \\ 0 & 0 & 1 \\ 1 & 0.4\cos t & 0.5 \end{bmatrix},\quad
        C(t) = \begin{bmatrix} 1 & 0 & 0 \\ 0 & 0.3\sin t & 1 \end{bmatrix},\quad
        D(t) = \begin{bmatrix} 0 \\ 0 \\ 1 + 0.3\cos t \end{bmatrix},

    :math:`w(t) = 0.5\sin 2t + 0.3\cos 3t + 0.2`, :math:`x(0) = (1, -1, 0.5)`. The frozen ``A(t)`` has an
    eigenvalue near ``1.5`` and the state grows about 14-fold in 2.5 s. The input reaches :math:`\dot y_2` (``CD``
    is not zero), so the reconstruction must remove it (``K`` of the corollary): two derivative blocks, Rugh's
    observability index 2. Exact derivatives are supplied (:class:`LTVPlant` ``derivatives``).

    Returns
    -------
    plant : LTVPlant
    w : callable ``t -> (1,)``
    x0 : ndarray, shape (3,)
    """

    def A(t):
        return np.array([[0.5, 1 + 0.3 * np.sin(t), 0.0], [0.0, 0.0, 1.0], [1.0, 0.4 * np.cos(t), 0.5]])

    def C(t):
        return np.array([[1.0, 0.0, 0.0], [0.0, 0.3 * np.sin(t), 1.0]])

    def D(t):
        return np.array([[0.0], [0.0], [1 + 0.3 * np.cos(t)]])

    def shifted(f, t, k):  # f^(j)(t) = f(t + j pi / 2) for sin and cos
        return np.array([f(t + j * np.pi / 2) for j in range(k + 1)])

    def dA(t, k):
        out = np.zeros((k + 1, 3, 3))
        out[0] = A(t)
        out[1:, 0, 1] = 0.3 * shifted(np.sin, t, k)[1:]
        out[1:, 2, 1] = 0.4 * shifted(np.cos, t, k)[1:]
        return out

    def dC(t, k):
        out = np.zeros((k + 1, 2, 3))
        out[0] = C(t)
        out[1:, 1, 1] = 0.3 * shifted(np.sin, t, k)[1:]
        return out

    def dD(t, k):
        out = np.zeros((k + 1, 3, 1))
        out[0] = D(t)
        out[1:, 2, 0] = 0.3 * shifted(np.cos, t, k)[1:]
        return out

    def w(t):
        return np.array([0.5 * np.sin(2 * t) + 0.3 * np.cos(3 * t) + 0.2])

    plant = LTVPlant(A, None, C, D, derivatives={"A": dA, "C": dC, "D": dD})
    return plant, w, np.array([1.0, -1.0, 0.5])


# ---- the observer ------------------------------------------------------------------------------------------------
def _symmetric_positive_definite(name: str, value, n: int) -> np.ndarray:
    """``value`` as a finite symmetric positive definite ``(n, n)`` matrix (symmetrized)."""
    M = LTVPlant._as_matrix(name, value, (n, n))
    if not np.allclose(M, M.T) or np.linalg.eigvalsh((M + M.T) / 2).min() <= 0:
        raise ValueError(f"expected {name} symmetric positive definite, actual value: {M!r}")
    return (M + M.T) / 2


class CascadedLTVObserver:
    r"""Cascaded HOSM observer for strongly observable LTV systems (Galvan-Guerra, Fridman and Davila 2017).

    Fridman's slides, eq. (15)-(17):

    .. math::
        \dot z = A z + B u + L(t)(y - C z),\qquad \hat x = z + F(t)\,W(e_y),\qquad e_y = y - C z,

    :math:`L = P^{-1} C^T` with :math:`\dot P = -PA - A^T P + 2C^TC - Q(t)` (the error :math:`e = x - z` then has
    :math:`\frac{d}{dt}e^TPe = -e^TQe` without input, and stays bounded with a bounded ``w``), ``W`` stacks the
    HOSM differentiator's estimates of :math:`e_y, \dot e_y, \ldots, e_y^{(l-1)}`, and ``F`` is the state map of
    :func:`ltv_state_map`. Once the differentiator has converged, :math:`\hat x = x` exactly, whatever the
    instability of ``A`` and the bounded unknown input.

    Parameters
    ----------
    plant : LTVPlant
    dt : float
        Sampling step ``tau``; the samples are at ``t0 + k tau``.
    lipschitz : float or array_like, shape (p,)
        Bound ``L`` on the ``(k+1)``-th derivative of each output error, ``k`` the differentiator order.
    alpha : int
        Differentiator order ``k = l - 1 + alpha`` (``alpha = 0``: the slides' :math:`W_{l-1}`, the smallest
        order; each extra order uses one more bounded derivative of ``w`` and gains one order of accuracy).
    blocks : int, optional
        ``l`` (default: the smallest that works at the times ``check_times``).
    check_times : array_like, optional
        Where strong observability is checked before starting (default: ``t0`` only; the state map is also
        refused at every sample where it is singular).
    P0 : array_like, shape (n, n)
        Initial ``P`` (symmetric positive definite); default the identity.
    Q : array_like or callable, optional
        ``Q(t)`` of (17) (default zero).
    forgetting : float
        ``q >= 0``: adds ``q P`` to ``Q`` (a forgetting factor: :math:`\frac{d}{dt}e^TPe \le -q\,e^TPe`, and
        ``P`` stays bounded when ``q`` exceeds twice the decay rate of the plant's stable modes). ``Q + q P``
        must be positive definite: ``Q`` positive definite or ``q > 0``.
    t0 : float
        Time of the first sample (default the plant's ``t0``).
    discretization : {"taylor", "euler"}
        Of the Levant differentiator.
    identify : bool
        Also estimate the unknown input (needs ``alpha >= 1``): between samples :math:`\dot e = Ae + Dw`, so the
        stack of ``l + 1`` output-error derivatives obeys
        :math:`\bar e_y = \mathcal O_{l+1} e + \mathcal J_{l+1}\bar w` and
        :math:`\hat w = G(\hat{\bar e}_y - \mathcal O_{l+1}\hat e)` with :math:`G\mathcal J_{l+1} = [I\ 0]`
        (:func:`input_map`; the slides give no LTV identification, this is the LTI one of Fridman, Levant and
        Davila 2007 in the Kratz-Liebscher form). Error :math:`O(\tau^{\alpha})` at worst (when it weights the
        ``l``-th derivative; :attr:`theoretical_orders` says which). Raises
        :class:`~smo_gym.control.NotStronglyObservableError` where ``G`` does not exist.

    Notes
    -----
    **Sampled implementation.** The injection is applied at the samples,
    :math:`z_k^+ = z_k^- + \tau L(t_k)(y_k - C(t_k) z_k^-)` (the Euler form of the continuous injection), and
    between samples :math:`\dot z = A z + B u_k` and (17) are integrated by RK4 (one step of ``tau``). Between
    samples the error then obeys exactly :math:`\dot e = A e + D w`: the output error is smooth there, and its
    jump at the sample, :math:`\Delta e_k = -\tau L e_{y,k}`, has the exactly known effect
    :math:`N_j(t_{k+1})\Phi(t_{k+1}, t_k)\Delta e_k` on the ``j``-th derivative of :math:`e_y` at the next
    sample (``N_j`` of Rugh's recursion for ``(A, C)``, :math:`\Phi` the transition matrix), which is removed from
    the differentiator's prediction, as :class:`~smo_gym.control.CascadedHOSMObserver` does for constant
    matrices. Hence the state map is the one of ``(A, C, D)`` and not of ``(A - LC, C, D)`` as in the slides'
    continuous-time :math:`F(t)`: the continuous injection and its derivatives would be needed otherwise, and a
    held sample would cap the accuracy at ``O(tau)``.

    **Accuracy.** With noise-free samples the differentiator's ``i``-th derivative has error
    :math:`O(L\tau^{k+1-i})` (Livne and Levant 2014), and ``F`` weights derivatives up to ``i = l - 1``: the
    state error is :math:`O(\tau^{\alpha+1})`, and :math:`O(\varepsilon^{(\alpha+1)/(k+1)})` under noise of
    amplitude :math:`\varepsilon` (:attr:`theoretical_orders`). The slides' theorem also gives the gain condition
    :math:`\Gamma > 2\zeta_0^+\|N_{l-1}\|\|D\|\|P\|/\|Q\| + \sum_j\|\mathcal D_{l,j}\|\zeta_j^+` for the
    differentiator; here ``lipschitz`` is that bound for the order chosen, supplied by the caller.

    Attributes
    ----------
    x_hat : ndarray, shape (n,)
    w_hat : ndarray, shape (m,) or None
        The identified unknown input (``identify=True``), else ``None``.
    e_hat : ndarray, shape (n,)
        Estimated error of the auxiliary observer.
    z : ndarray, shape (n,)
        The auxiliary observer's state before the correction (``z_k^-``).
    P : ndarray, shape (n, n)
    t : float
        Time of the next sample.
    order : int
        Differentiator order ``k``.
    blocks : int
        ``l``.
    report : LTVStrongObservabilityReport
    """

    def __init__(
        self,
        plant: LTVPlant,
        dt: float,
        lipschitz,
        *,
        alpha: int = 1,
        blocks=None,
        check_times=None,
        P0=None,
        Q=None,
        forgetting: float = 1.0,
        t0=None,
        discretization: str = "taylor",
        identify: bool = False,
    ):
        if not isinstance(plant, LTVPlant):
            raise TypeError(f"expected an LTVPlant, actual value: {type(plant).__name__}")
        self.plant = plant
        self.dt = check_positive("dt", dt)
        self.t0 = plant.t0 if t0 is None else check_real("t0", t0)
        alpha = check_int_in_range("alpha", alpha, 0, MAX_LEVANT_ORDER)
        self.discretization = check_choice("discretization", discretization, ("taylor", "euler"))
        times = self.t0 if check_times is None else check_times
        self.report = ltv_strong_observability(plant, times, blocks=blocks)
        _raise_if_not(self.report)
        self.blocks = self.report.blocks
        self.alpha = alpha
        self.order = self.blocks - 1 + alpha
        if not 1 <= self.order <= MAX_LEVANT_ORDER:
            raise ValueError(
                f"expected a differentiator order l - 1 + alpha in [1, {MAX_LEVANT_ORDER}] (l={self.blocks}), "
                f"actual value: {self.order}"
            )
        n, p = plant.n, plant.n_outputs
        self.forgetting = check_nonnegative("forgetting", forgetting)
        if Q is None:
            self._Q = lambda t: np.zeros((n, n))
        elif callable(Q):
            self._Q = Q
        else:
            Qc = LTVPlant._as_matrix("Q", Q, (n, n))
            self._Q = lambda t: Qc
        Qt0 = LTVPlant._as_matrix("Q", self._Q(self.t0), (n, n), t=self.t0)
        if self.forgetting == 0.0 and np.linalg.eigvalsh((Qt0 + Qt0.T) / 2).min() <= 0:
            raise ValueError(
                "expected Q(t) positive definite or forgetting > 0 (slides eq. (17)), actual value: forgetting=0 "
                f"and eig(Q(t0)) min {np.linalg.eigvalsh((Qt0 + Qt0.T) / 2).min():.3g}"
            )
        self._P0 = np.eye(n) if P0 is None else _symmetric_positive_definite("P0", P0, n)
        self.identify = check_bool("identify", identify)
        if self.identify:
            if alpha < 1:
                raise ValueError(
                    "expected alpha >= 1 with identify=True (w needs the output derivative of order l), actual "
                    f"value: alpha={alpha}"
                )
            series, top = plant.series(self.t0, self.blocks), self.blocks + 1
            O1, J1 = kratz_liebscher_matrices(*series, top)
            if input_map(O1, J1, plant.n_unknown, *_unit_scales(*series, top)[:2]) is None:
                raise NotStronglyObservableError(
                    "expected the unknown input fixed by y .. y^(l) (G J = [I 0] solvable), actual value: not at "
                    f"t={self.t0} with l={self.blocks}"
                )
        self.w_hat = None
        lipschitz = as_real_array("lipschitz", lipschitz)
        if lipschitz.shape not in ((), (1,), (p,)):
            raise ValueError(
                f"expected lipschitz a number or one per output ({p}), actual value: shape {lipschitz.shape}"
            )
        self.lipschitz = np.broadcast_to(lipschitz, (p,)).copy()
        self.differentiator = Levant(self.order, self.dt, self.lipschitz, discretization=discretization)
        self._cache: dict[float, tuple[np.ndarray, np.ndarray]] = {}
        self.z = self.x_hat = self.e_hat = self.P = None
        self._dstate = None
        self.t = None
        self.output_error = None

    @property
    def theoretical_orders(self) -> dict[str, float]:
        r"""Orders of the errors in ``tau`` (noise-free) and in the noise amplitude, from the maps at ``t0``.

        The differentiator's ``i``-th derivative has error :math:`O(L\tau^{k+1-i})` and
        :math:`O(\varepsilon^{(k+1-i)/(k+1)})` (Levant 2003; Livne and Levant 2014), so an estimate that is a
        linear map of the derivative stack has the order of the highest derivative it weights: ``F`` weights
        ``i = l - 1`` (order ``alpha + 1``), ``G`` at most ``i = l`` (order ``alpha``, or ``alpha + 1`` when
        ``w`` reaches an output's derivative of order ``< l`` and the others are not needed).
        """
        k = self.order
        F, _, ident = self._geometry(self.t0)
        p = self.plant.n_outputs
        a = _unit_scales(*self.plant.series(self.t0, self.blocks), self.blocks)[2]
        i = _highest_block(F, p, a)  # the weights of y^(i) compared at its size
        out = {"state": float(k + 1 - i), "noise": (k + 1 - i) / (k + 1)}
        if ident is not None:
            j = _highest_block(ident[0], p, a)
            out["identification"] = float(k + 1 - j)
            out["identification_noise"] = (k + 1 - j) / (k + 1)
        return out

    def _geometry(self, t: float):
        """``(F(t), [N_0(t); ...; N_k(t)], (G, O_{l+1}) or None)``, cached for the sample times."""
        key = round(t, 12)
        hit = self._cache.get(key)
        if hit is not None:
            return hit
        A, C, D = self.plant.series(t, self.order)
        Ns = _observability_series(A, C, self.order + 1)
        O, J = kratz_liebscher_matrices(A, C, D, self.blocks, _N=Ns)
        rows, cols, _ = _unit_scales(A, C, D, self.blocks)
        O, J = rows[:, None] * O, rows[:, None] * J * cols  # unit sizes, as in ltv_strong_observability
        K = left_annihilator(J) if J.size else np.eye(O.shape[0])
        U, sv, Vt = np.linalg.svd(K @ O, full_matrices=False)
        if sv.size < self.plant.n or not sv[-1] > RANK_TOL * sv[0]:  # the rank decision of _scaled_rank
            report = ltv_strong_observability(self.plant, t, blocks=self.blocks)
            _raise_if_not(report)
            raise NotStronglyObservableError(
                f"expected a strongly observable triple (A(t), C(t), D(t)), actual value: K O_{self.blocks}(t) "
                f"singular at t={t:.6g} (singular values {sv})"
            )
        F = Vt.T @ (U.T / sv[:, None]) @ K * rows  # (K O)^+ K, back to the derivatives of y
        N = np.vstack([Ni[0] for Ni in Ns])
        ident = None
        if self.identify:  # w = G (Y_{l+1} - O_{l+1} e)
            O1, J1 = kratz_liebscher_matrices(A, C, D, self.blocks + 1, _N=Ns)
            G = input_map(O1, J1, self.plant.n_unknown, *_unit_scales(A, C, D, self.blocks + 1)[:2])
            if G is None:
                raise NotStronglyObservableError(
                    f"expected the unknown input fixed by y .. y^(l) at t={t:.6g}, actual value: G J = [I 0] has no "
                    "solution there"
                )
            ident = (G, O1)
        if len(self._cache) > 4:
            self._cache.clear()
        self._cache[key] = (F, N, ident)
        return F, N, ident

    def reset(self, y0, z0=None, *, P0=None) -> np.ndarray:
        """Start at ``t0`` with ``z = z0`` (default ``C(t0)^+ y0``) and the differentiator at the output error.

        Raises
        ------
        TypeError, ValueError
            When ``y0``, ``z0`` or ``P0`` is not finite, of the wrong shape, or ``P0`` is not symmetric positive
            definite; the observer is then left as it was.
        """
        t = self.t0
        y0 = _vector("y0", y0, self.plant.n_outputs, t)
        C0 = self.plant.C(t)
        z = np.linalg.pinv(C0) @ y0 if z0 is None else _vector("z0", z0, self.plant.n, t)
        P = self._P0.copy() if P0 is None else _symmetric_positive_definite("P0", P0, self.plant.n)
        # the differentiator is reset last: nothing above may fail once the observer's state starts changing
        self.differentiator.reset(y0 - C0 @ z)
        self.t, self.z, self.P = t, z, P
        self._dstate = self.differentiator.state
        self.x_hat, self.e_hat = self.z.copy(), np.zeros(self.plant.n)
        self._posterior = None
        self._step_mats = {}
        return self.x_hat

    def _require(self, what: str) -> None:
        if self.t is None:
            raise RuntimeError(f"expected reset(y0) before {what}, actual value: the observer was never reset")

    def update(self, y) -> np.ndarray:
        """Process the sample ``y_k = y(t_k)``; return :math:`\\hat x_k`.

        Raises
        ------
        TypeError, ValueError
            When ``y`` is not a finite vector of ``p`` outputs.
        NotStronglyObservableError
            When the state map does not exist at ``t_k`` or at the next sample ``t_k + dt`` (needed to carry the
            injection over). A refused update leaves the observer as it was.
        """
        self._require("update(y)")
        if self._posterior is not None:
            raise RuntimeError("expected advance(u) between two updates, actual value: update(y) called twice")
        p, t = self.plant.n_outputs, self.t
        C = self._mats(t)[2]
        ey = _vector("y", y, p, t) - C @ self.z
        # everything is computed into locals first: the map at t + dt can still be refused
        new_state, Zd = self.differentiator.step(self._dstate, ey)  # (p, k+1): e_y and derivatives at t_k
        F, _, ident = self._geometry(t)
        Y = Zd[:, : self.blocks].T.reshape(-1)  # derivative-major stack [e_y; e_y'; ...]
        e_hat = F @ Y
        w_hat = self.w_hat
        if ident is not None:
            G, O1 = ident
            w_hat = G @ (Zd[:, : self.blocks + 1].T.reshape(-1) - O1 @ e_hat)
        # injection at the sample, and its known effect on the output error's derivatives at the next sample
        L = np.linalg.solve(self.P, C.T)
        correction = self.dt * (L @ ey)
        Phi = self._transition(t)
        _, N_next, _ = self._geometry(t + self.dt)
        new_state[:, : self.order + 1] -= (N_next @ (Phi @ correction)).reshape(self.order + 1, p).T
        self.output_error, self.e_hat, self.w_hat = ey, e_hat, w_hat
        self.x_hat = self.z + e_hat
        self._posterior, self._Phi = self.z + correction, Phi
        self._dstate = new_state
        return self.x_hat

    def _mats(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(A(t), B(t), C(t))``, evaluated once per time of the current step."""
        hit = self._step_mats.get(t)
        if hit is None:
            hit = self._step_mats[t] = (self.plant.A(t), self.plant.B(t), self.plant.C(t))
        return hit

    def _transition(self, t: float) -> np.ndarray:
        """``Phi(t + dt, t)``: one RK4 step of ``Phi' = A Phi`` (the map RK4 applies to ``z``)."""
        h = self.dt
        A0, A1, A2 = (self._mats(s)[0] for s in (t, t + h / 2, t + h))
        eye = np.eye(len(A0))
        k1 = A0
        k2 = A1 @ (eye + h / 2 * k1)
        k3 = A1 @ (eye + h / 2 * k2)
        k4 = A2 @ (eye + h * k3)
        return eye + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)

    def _pdot(self, t: float, P: np.ndarray) -> np.ndarray:
        A, _, C = self._mats(t)
        return -P @ A - A.T @ P + 2.0 * C.T @ C - self._Q(t) - self.forgetting * P

    def advance(self, u=None) -> None:
        """Integrate ``z`` (with ``u`` held) and ``P`` (eq. (17)) to the next sample, one RK4 step each."""
        self._require("advance(u)")
        if self._posterior is None:
            raise RuntimeError("expected update(y) before advance(u), actual value: advance called twice")
        t, h = self.t, self.dt
        q = self.plant.n_inputs
        u = np.zeros(q) if u is None else _vector("u", u, q, t)
        (_, B0, _), (A1, B1, _), (A2, B2, _) = (self._mats(s) for s in (t, t + h / 2, t + h))
        # RK4 is linear in z: Phi z+ plus the RK4 of the forced part z' = A z + B u_k from zero
        k1 = B0 @ u
        k2 = A1 @ (h / 2 * k1) + B1 @ u
        k3 = A1 @ (h / 2 * k2) + B1 @ u
        k4 = A2 @ (h * k3) + B2 @ u
        z = self._Phi @ self._posterior + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        P = self.P
        p1 = self._pdot(t, P)
        p2 = self._pdot(t + h / 2, P + h / 2 * p1)
        p3 = self._pdot(t + h / 2, P + h / 2 * p2)
        p4 = self._pdot(t + h, P + h * p3)
        P = P + h / 6 * (p1 + 2 * p2 + 2 * p3 + p4)
        P = (P + P.T) / 2
        if not np.all(np.isfinite(P)) or np.linalg.eigvalsh(P).min() <= 0:  # refused before anything changes
            raise RuntimeError(
                f"expected P(t) positive definite (slides eq. (17)), actual value: eigenvalues "
                f"{np.linalg.eigvalsh(P) if np.isfinite(P).all() else P} at t={t + h:.6g}; choose P0, Q and "
                "forgetting so that P stays positive definite and bounded (the observer is still at t)"
            )
        self.z, self.P = z, P
        self._posterior = None
        self.t = t + h
        self._step_mats = {self.t: self._step_mats[t + h]}

    def run(self, y, u=None) -> np.ndarray:
        """Process a whole record: ``y`` shape (T, p) sampled from ``t0`` every ``dt``; returns ``x_hat`` (T, n)."""
        y = as_real_array("y", y)
        if y.ndim != 2 or y.shape[1] != self.plant.n_outputs:
            raise ValueError(f"expected y with shape (T, {self.plant.n_outputs}), actual value: shape {y.shape}")
        if len(y) == 0:  # the first sample starts the observer
            raise ValueError(f"expected y with at least one sample, actual value: shape {y.shape}")
        out = np.zeros((len(y), self.plant.n))
        self.reset(y[0])
        for k in range(len(y)):
            out[k] = self.update(y[k])
            self.advance(None if u is None else u[k])
        return out
