r"""Gain helpers for the model-free differentiators.

Pure functions of the Lipschitz bound ``L`` (the bound on the first derivative the observer does *not*
estimate, e.g. ``|f''| <= L`` for a velocity observer), plus Ackermann's formula for observer gains.

References
----------
.. [1] A. Levant, "Higher-order sliding modes, differentiation and output-feedback control",
   Int. J. Control 76(9-10), 2003.
.. [2] M. Livne and A. Levant, "Proper discretization of homogeneous differentiators", Automatica 50, 2014.
.. [3] M. Wetzlinger, M. Reichhartinger and M. Horn, "Higher order sliding mode inspired nonlinear discrete-time
   observer", eq. (35).
"""

from __future__ import annotations

import warnings
from math import comb

import numpy as np

from .._scaling import unit
from .._validation import as_real_array, check_int_in_range, check_positive, check_positive_array

__all__ = [
    "LEVANT_LAMBDAS",
    "MAX_LEVANT_ORDER",
    "ackermann_observer_gain",
    "binomial_coefficients",
    "levant_gains",
    "levant_lambdas",
    "levant_nonrecursive",
    "super_twisting_gains",
]

#: Levant's recursive-form parameters ``lambda_0 .. lambda_5`` (Fridman's lecture slides, below eq. (7); [1]).
LEVANT_LAMBDAS = (1.1, 1.5, 2.0, 3.0, 5.0, 8.0)
#: The table above covers differentiators of order 1 to 5.
MAX_LEVANT_ORDER = 5


def levant_lambdas(order: int, form: str = "recursive") -> np.ndarray:
    r"""Levant's differentiator parameters for a differentiator of ``order`` k.

    Parameters
    ----------
    order : int
        Differentiation order ``k`` in ``[1, 5]``.
    form : {"recursive", "nonrecursive"}
        ``"recursive"`` returns ``(lambda_k, ..., lambda_0)`` of eq. (7) of Fridman's slides, in state order (the entry
        ``i`` multiplies the correction of ``z_i``). ``"nonrecursive"`` returns the equivalent
        ``(Lambda_1, ..., Lambda_k, lambda_0)`` of the non-recursive form

        .. math:: \dot z_i = -\Lambda_{i+1} L^{(i+1)/(k+1)} \lceil z_0 - f\rfloor^{(k-i)/(k+1)} + z_{i+1},
                  \quad \dot z_k = -\lambda_0 L\, \mathrm{sign}(z_0 - f),

        obtained from :math:`\Lambda_0 = 1,\ \Lambda_{i+1} = \lambda_{k-i}\Lambda_i^{(k-i)/(k-i+1)}`.

    Returns
    -------
    ndarray, shape (k + 1,)

    Notes
    -----
    In (7) the quantity :math:`s_{i+1} = z_{i+1} - \nu_i` depends on :math:`z_0 - f` only, so the recursive and
    non-recursive forms are the *same map*, in continuous time and sample by sample. For ``k = 2`` this gives
    ``(2, 2.12, 1.1)`` and for ``k = 3`` ``(3, 4.16, 3.06, 1.1)``, the values of Livne and Levant [2].
    """
    k = check_int_in_range("order", order, 1, MAX_LEVANT_ORDER)
    if not isinstance(form, str):  # an array would be compared element by element
        raise TypeError(f"expected form to be 'recursive' or 'nonrecursive', actual value: {form!r:.80}")
    recursive = np.array([LEVANT_LAMBDAS[k - i] for i in range(k + 1)])
    if form == "recursive":
        return recursive
    if form != "nonrecursive":
        raise ValueError(f"expected form to be 'recursive' or 'nonrecursive', actual value: {form!r}")
    return levant_nonrecursive(LEVANT_LAMBDAS[: k + 1])


def levant_nonrecursive(lambdas) -> np.ndarray:
    r"""The non-recursive gains ``(Lambda_1, ..., Lambda_k, lambda_0)`` of any recursive parameters.

    Parameters
    ----------
    lambdas : array_like, shape (k + 1,)
        :math:`(\lambda_0, \lambda_1, \ldots, \lambda_k)` of eq. (7) of Fridman's slides (after [1]), indexed as there
        (:math:`\lambda_k` multiplies the first correction), each ``> 0``.

    Returns
    -------
    ndarray, shape (k + 1,)
        :math:`\Lambda_0 = 1,\ \Lambda_{i+1} = \lambda_{k-i}\Lambda_i^{(k-i)/(k-i+1)}` for ``i < k``, then
        :math:`\lambda_0` (see :func:`levant_lambdas` for the form they enter).

    Raises
    ------
    TypeError
        ``lambdas`` not real numbers.
    ValueError
        ``lambdas`` of another shape, not finite and ``> 0``, or gains beyond a float's range.
    """
    lam = check_positive_array("lambdas", lambdas)
    if lam.ndim != 1 or lam.size < 2:
        raise ValueError(f"expected lambdas with shape (k + 1,), k >= 1, actual value: shape {lam.shape}")
    k = lam.size - 1
    out = np.empty(k + 1)
    big_lambda = 1.0
    with np.errstate(over="ignore"):  # an overflow is refused below
        for i in range(k):
            big_lambda = lam[k - i] * big_lambda ** ((k - i) / (k - i + 1))
            out[i] = big_lambda
    out[k] = lam[0]
    if not np.isfinite(out).all():
        raise ValueError(f"expected lambdas whose non-recursive gains are finite, actual value: {lambdas!r:.80}")
    return out


def levant_gains(order: int, lipschitz) -> tuple[np.ndarray, np.ndarray]:
    r"""Gains and exponents of the non-recursive Levant differentiator of ``order`` k with bound ``L``.

    Returns ``(gains, powers)`` such that the correction of state ``i`` is
    ``-gains[..., i] * |e|**powers[i] * sign(e)``, ``e = z_0 - f``, with
    ``gains[..., i] = Lambda_{i+1} L^{(i+1)/(k+1)}`` and ``powers[i] = (k - i)/(k + 1)``.

    Parameters
    ----------
    order : int
        ``k`` in ``[1, 5]``.
    lipschitz : float or array_like
        ``L > 0``, a bound on ``|f^{(k+1)}|``; an array gives per-channel gains (shape ``(..., k + 1)`` returned).
    """
    k = check_int_in_range("order", order, 1, MAX_LEVANT_ORDER)
    L = check_positive_array("lipschitz", lipschitz)[..., None]
    lam = levant_lambdas(k, "nonrecursive")
    exponents = np.arange(1, k + 2) / (k + 1)
    gains = lam * L**exponents
    powers = (k - np.arange(k + 1)) / (k + 1)
    return gains, powers


def super_twisting_gains(lipschitz) -> tuple[np.ndarray | float, np.ndarray | float]:
    r"""Default super-twisting differentiator gains ``k1 = 1.5 sqrt(L)``, ``k2 = 1.1 L`` (Levant 1998, 2003).

    With :math:`|\ddot f| \le L` the differentiator
    :math:`\dot x_1 = x_2 - k_1 \lceil x_1 - f\rfloor^{1/2},\ \dot x_2 = -k_2\, \mathrm{sign}(x_1 - f)`
    converges to :math:`x_1 = f,\ x_2 = \dot f` in finite time.
    """
    L = check_positive_array("lipschitz", lipschitz)
    k1, k2 = 1.5 * np.sqrt(L), 1.1 * L
    if k1.ndim == 0:
        return float(k1), float(k2)
    return k1, k2


def binomial_coefficients(n: int, rate: float = 1.0) -> np.ndarray:
    """Coefficients ``(k_1, ..., k_n)`` of ``(s + rate)^n = s^n + k_1 s^{n-1} + ... + k_n``.

    Raises ``TypeError`` for a non-integer ``n`` or a non-number ``rate``, ``ValueError`` for ``n`` outside
    ``[1, 64]``, ``rate <= 0`` or coefficients beyond a float's range."""
    n = check_int_in_range("n", n, 1, 64)
    rate = check_positive("rate", rate)
    try:
        coeffs = np.array([comb(n, i) * rate**i for i in range(1, n + 1)], dtype=np.float64)
    except OverflowError:  # float ** int raises where float * float gives inf
        coeffs = np.array([np.inf])
    if not np.isfinite(coeffs).all():
        raise ValueError(
            f"expected n and rate with finite coefficients rate^i C(n, i), actual value: n={n}, rate={rate!r}"
        )
    return coeffs


def _observability_rank(A: np.ndarray, C: np.ndarray) -> int:
    """Rank of the observability matrix ``[C; C A; ...; C A^(n-1)]``, built from ``A`` and ``C`` at unit norm.

    Observability does not change under ``A -> a A``, ``C -> c C``, but the blocks ``C A^i`` scale as ``c a^i``:
    NumPy's tolerance on the raw stack, relative to its largest singular value, judged the blocks of a small ``A``
    (all but the first of a large one) as zero. The factors are scaled by powers of two (exact), never the stack,
    as in the control library's rank decisions (:mod:`smo_gym._scaling`).
    """
    A, C = unit(A), unit(C)
    return int(np.linalg.matrix_rank(np.vstack([C @ np.linalg.matrix_power(A, i) for i in range(A.shape[0])])))


def ackermann_observer_gain(A, c, poles) -> np.ndarray:
    r"""Observer gain ``l`` placing the eigenvalues of ``A - l c^T`` at ``poles`` (Ackermann's formula).

    .. math:: l = p(A)\, \mathcal{O}^{-1} e_n,\qquad
              \mathcal{O} = \begin{bmatrix} c^T \\ c^T A \\ \vdots \\ c^T A^{n-1}\end{bmatrix},\qquad
              p(s) = \prod_j (s - s_j).

    Parameters
    ----------
    A : array_like, shape (n, n)
    c : array_like, shape (n,)
        Output row, ``y = c^T x``.
    poles : array_like, shape (n,)
        Desired eigenvalues (complex ones in conjugate pairs).

    Returns
    -------
    ndarray, shape (n,)

    Raises
    ------
    TypeError
        ``A`` or ``c`` not real, or ``poles`` not numbers (bools included).
    ValueError
        If shapes disagree, an entry is not finite, the polynomial ``p`` or the gain overflows, ``(A, c)`` is not
        observable, or the computed gain does not place the eigenvalues (an observability matrix too
        ill-conditioned for the formula in floating point: the characteristic polynomial of ``A - l c^T`` is checked
        against ``p``).
    """
    A = as_real_array("A", A)
    c = as_real_array("c", c).reshape(-1)
    # NumPy reads True in [True, -2] as the pole 1: look at the entries as given
    has_bool = any(isinstance(p, (bool, np.bool_)) for p in np.asarray(poles, dtype=object).flat)
    poles = np.asarray(poles)
    if poles.dtype.kind not in "iufc" or has_bool:
        raise TypeError(f"expected poles to be real or complex numbers, actual value: {poles!r:.80}")
    poles = poles.reshape(-1)
    n = A.shape[0] if A.ndim == 2 else -1
    if A.shape != (n, n) or n < 1 or c.shape != (n,) or poles.shape != (n,):
        raise ValueError(
            f"expected A (n, n), c (n,) and poles (n,), actual value: A {A.shape}, c {c.shape}, poles {poles.shape}"
        )
    if not (np.isfinite(A).all() and np.isfinite(c).all() and np.isfinite(poles).all()):
        raise ValueError("expected finite A, c and poles, actual value: a NaN or infinite entry")
    obs = np.vstack([c @ np.linalg.matrix_power(A, i) for i in range(n)])
    rank = _observability_rank(A, c)
    if rank < n:
        raise ValueError(f"expected an observable pair (A, c), actual value: observability rank {rank} < {n}")
    coeffs = np.real_if_close(np.poly(poles))  # p(s) = s^n + a_1 s^{n-1} + ... + a_n
    if np.iscomplexobj(coeffs):
        raise ValueError(f"expected poles closed under conjugation, actual value: {poles!r}")
    if not np.isfinite(coeffs).all():
        raise ValueError(f"expected poles whose polynomial p has finite coefficients, actual value: {poles!r:.80}")
    p_of_A = sum(a * np.linalg.matrix_power(A, n - i) for i, a in enumerate(coeffs))
    e_n = np.zeros(n)
    e_n[-1] = 1.0
    l = p_of_A @ np.linalg.solve(obs, e_n)
    if not np.isfinite(l).all():
        raise ValueError(f"expected a finite gain, actual value: {l!r:.80} (poles or A too large for a float)")
    # the formula is exact in exact arithmetic only: compare the placed characteristic polynomial with p, each
    # coefficient a_i relative to rho^i (rho bounds the eigenvalues' scale), as a backward-error test; no floor at
    # 1, which made the test absolute for a slow system (A and the poles scaled by 1e-8 passed a misplaced gain)
    rho = max(float(np.abs(poles).max()), float(np.linalg.norm(A, 2))) or 1.0
    placed = np.real_if_close(np.poly(A - np.outer(l, c)))
    error = float(np.max(np.abs(placed - coeffs) / rho ** np.arange(n + 1)))
    if not np.isfinite(error) or error > 1e-6:
        raise ValueError(
            "expected a gain that places the eigenvalues of A - l c^T at the poles, actual value: a relative error "
            f"{error:.1e} of its characteristic polynomial (observability matrix condition number "
            f"{np.linalg.cond(obs):.1e}); use a better conditioned realization, or scipy.signal.place_poles"
        )
    return l


def _placed_gain(A: np.ndarray, C: np.ndarray, poles: np.ndarray) -> np.ndarray:
    """``L`` with the eigenvalues of ``A - L C`` at ``poles`` (``scipy.signal.place_poles`` on the dual pair, for
    any number of outputs), re-verified: its refusals (an unobservable pair, poles repeated beyond the number of
    outputs) and a gain that misplaces them (``place_poles`` returns one for an unobservable pair, with only a
    warning) are a ``ValueError`` that says why. ``A``, ``C`` and ``poles`` are checked by the caller."""
    from scipy.signal import place_poles  # lazy: scipy.signal is slow to import

    try:
        with warnings.catch_warnings():
            # the method of Tits and Yang (1996) iterates on the conditioning of the eigenvectors and warns when
            # that iteration stops short (the 12-state chain of six double integrators does); the gain is then
            # less robust, not wrong, and whether it places the poles is checked below
            warnings.filterwarnings("ignore", "Convergence was not reached", UserWarning)
            L = place_poles(A.T, C.T, poles).gain_matrix.T
    except ValueError as exc:
        raise ValueError(f"expected poles the output can place, actual value: {np.round(poles, 6)} ({exc})") from None
    placed = np.sort_complex(np.linalg.eigvals(A - L @ C))
    # relative to the poles' size, without a floor: an absolute tolerance passes anything for slow poles
    if not np.allclose(placed, np.sort_complex(poles), rtol=1e-6, atol=1e-9 * np.abs(poles).max()):
        raise ValueError(f"expected poles the gain places accurately, actual value: asked {poles}, placed {placed}")
    return L
