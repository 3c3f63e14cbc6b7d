r"""Observer gains from linear matrix inequalities (cvxpy + Clarabel), re-verified in NumPy.

Every design here follows one recipe (see ``DESIGN.md``): ``symmetric=True`` variables, symmetrised blocks, strict
inequalities replaced by margins ``>> eps * I``, ``solver=cp.CLARABEL`` passed explicitly, ``status == "optimal"``
checked, and the returned matrices re-checked with NumPy eigenvalues. The NumPy check is the certificate the
caller receives; an infeasible specification raises :class:`LMIInfeasibleError` instead of returning a gain.

References
----------
.. [EPLP17] D. Efimov, A. Polyakov, A. Levant and W. Perruquetti, "Switched gain differentiator with fixed-time
   convergence", Proc. 20th IFAC World Congress, 2017, Assumption 1, Remark 2, Lemma 3.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from .._extras import require
from .._validation import as_real_array, check_int_in_range, check_nonnegative, check_positive, check_real_in_range

__all__ = [
    "LMIInfeasibleError",
    "SwitchedGainCertificate",
    "certify_switched_gain",
    "switched_gain_lmi",
    "switched_gain_lmi_matrix",
]


class LMIInfeasibleError(ValueError):
    """A linear-matrix-inequality specification has no solution (or the solver's answer failed re-verification)."""


@dataclass(frozen=True)
class SwitchedGainCertificate:
    r"""NumPy re-verification of Assumption 1 of Efimov et al. 2017 for a returned ``(l, P)``.

    Attributes
    ----------
    min_eig_P : float
        :math:`\lambda_{\min}(P)` (must be ``> 0``).
    max_eig_P : float
        :math:`\lambda_{\max}(P)`.
    max_eig_lmi : float
        Largest eigenvalue of the block matrix of Assumption 1 (Remark 2 for ``gamma = 0``) evaluated at
        ``(P, w = P l)``; must be ``<= 0``.
    observer_eigenvalues : ndarray, shape (n,)
        Eigenvalues of :math:`A - l c^T` (all real parts ``< -kappa/2`` by Lemma 3).
    kappa, rho_d, rho_v, gamma : float
        The specification that was certified.
    status : str
        The solver status (``"optimal"``).
    """

    min_eig_P: float
    max_eig_P: float
    max_eig_lmi: float
    observer_eigenvalues: np.ndarray
    kappa: float
    rho_d: float
    rho_v: float
    gamma: float
    status: str


def _check_spec(kappa, rho_d, rho_v, gamma) -> tuple[float, float, float, float]:
    """``(kappa, rho_d, rho_v, gamma)`` as floats: positive (``gamma`` also 0) and within ``[1e-150, 1e150]``, so
    that the squares and the inverse square of the block matrix are finite."""
    kappa, rho_d, rho_v = (
        check_real_in_range(name, value, 1e-150, 1e150)
        for name, value in (("kappa", kappa), ("rho_d", rho_d), ("rho_v", rho_v))
    )
    gamma = check_nonnegative("gamma", gamma)
    if gamma != 0.0:
        gamma = check_real_in_range("gamma (when not 0)", gamma, 1e-150, 1e150)
    return kappa, rho_d, rho_v, gamma


def _canonical(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``A`` (shift), ``b = e_n`` and ``c = e_1`` of the canonical form (2), as ``(n, n), (n, 1), (n, 1)``."""
    A = np.eye(n, k=1)
    b = np.zeros((n, 1))
    b[-1, 0] = 1.0
    c = np.zeros((n, 1))
    c[0, 0] = 1.0
    return A, b, c


@np.errstate(over="ignore", invalid="ignore")  # an overflow is refused at the end
def switched_gain_lmi_matrix(P, w, kappa: float, rho_d: float, rho_v: float, gamma: float = 0.0) -> np.ndarray:
    r"""The block matrix of Assumption 1 of Efimov et al. 2017 (Remark 2 when ``gamma = 0``), evaluated in NumPy.

    .. math::
        \begin{bmatrix} \tilde S & Pb & -w & -Pb\\ b^T P & -\rho_d^2 & 0 & 0\\ -w^T & 0 & -\rho_v^2 & 0\\
        -b^T P & 0 & 0 & -\gamma^{-2}\end{bmatrix} \preceq 0,\qquad
        \tilde S = A^T P + PA - c w^T - w c^T + I_n + \kappa P,

    and for :math:`\gamma = 0` the last row and column and the :math:`I_n` term are dropped.

    Parameters
    ----------
    P : array_like, shape (n, n)
    w : array_like, shape (n,)

    Returns
    -------
    ndarray, shape (n + 2, n + 2) or (n + 3, n + 3), symmetric.

    Raises
    ------
    TypeError, ValueError
        Arguments of another type, shape or range, non-finite ``P`` or ``w``, or a block matrix that overflows.
    """
    P = as_real_array("P", P)
    n = P.shape[0] if P.ndim == 2 else -1
    w = as_real_array("w", w)
    if P.shape != (n, n) or n < 1 or w.size != n:
        raise ValueError(f"expected P (n, n) and w (n,), actual value: P {P.shape}, w {w.shape}")
    if not (np.isfinite(P).all() and np.isfinite(w).all()):
        raise ValueError("expected finite P and w, actual value: a NaN or infinite entry")
    kappa, rho_d, rho_v, gamma = _check_spec(kappa, rho_d, rho_v, gamma)
    w = w.reshape(n, 1)
    A, b, c = _canonical(n)
    S = A.T @ P + P @ A - c @ w.T - w @ c.T + kappa * P
    z = np.zeros((1, 1))
    if gamma > 0.0:
        S = S + np.eye(n)
        M = np.block(
            [
                [S, P @ b, -w, -P @ b],
                [b.T @ P, -(rho_d**2) * np.ones((1, 1)), z, z],
                [-w.T, z, -(rho_v**2) * np.ones((1, 1)), z],
                [-b.T @ P, z, z, -(gamma**-2) * np.ones((1, 1))],
            ]
        )
    else:
        M = np.block(
            [
                [S, P @ b, -w],
                [b.T @ P, -(rho_d**2) * np.ones((1, 1)), z],
                [-w.T, z, -(rho_v**2) * np.ones((1, 1))],
            ]
        )
    M = 0.5 * (M + M.T)
    if not np.isfinite(M).all():
        raise ValueError("expected P and w small enough for a finite block matrix, actual value: an overflow")
    return M


def switched_gain_lmi(
    n: int, kappa: float, rho_d: float, rho_v: float, gamma: float = 0.0, *, eps: float = 1e-6, tol: float = 1e-7
) -> tuple[np.ndarray, np.ndarray, SwitchedGainCertificate]:
    r"""Gain ``l`` and Lyapunov matrix ``P`` of Assumption 1 / Remark 2 of Efimov et al. 2017.

    Solves, over :math:`P = P^T` and :math:`w \in \mathbb R^n`,

    .. math::
        \max\ \nu \quad\text{s.t.}\quad P \succeq \nu I,\ \nu \ge \epsilon,\
        \text{(block matrix of Assumption 1)} \preceq -\epsilon I,

    and returns :math:`l = P^{-1} w`. Then the observer (3) satisfies Lemma 3:
    :math:`\|x - \hat x\| \le \sqrt{\lambda_{\max}/\lambda_{\min}}\,e^{-\kappa t/2}\|x(0)-\hat x(0)\|
    + (\rho_d D + \rho_v V)/\sqrt{\kappa\lambda_{\min}(P)}`.

    Parameters
    ----------
    n : int
        State dimension of the canonical form (2), ``2 <= n <= 10`` (``order + 1`` of a differentiator).
    kappa : float
        Decay rate ``> 0`` of the Lyapunov function (error decay :math:`e^{-\kappa t/2}`).
    rho_d, rho_v : float
        Gains ``> 0`` from the disturbance ``d`` and the noise ``v``.
    gamma : float, default 0
        Lipschitz constant of the uncertainty ``g`` (``0``: Remark 2, no uncertainty).
    eps : float
        Margin replacing the strict inequalities.
    tol : float
        Tolerance of the NumPy re-verification (eigenvalues of the block matrix must be ``<= tol`` times
        ``min(1, lambda_max(P))``: :func:`certify_switched_gain`).

    Returns
    -------
    l : ndarray, shape (n,)
    P : ndarray, shape (n, n)
    certificate : SwitchedGainCertificate

    Raises
    ------
    LMIInfeasibleError
        If the solver does not return ``"optimal"``, or if the returned matrices fail the NumPy check.

    Notes
    -----
    The paper only asks for *a* feasible point. The objective "maximise :math:`\lambda_{\min}(P)`" minimises the
    asymptotic bound of Lemma 3, and it reproduces the values printed in Section 6 for ``n = 2``,
    ``kappa = rho_d = rho_v = 1``: :math:`l \approx (2.60, 2.08)`, :math:`\lambda(P) \approx (0.197, 1.173)`
    (printed: :math:`l = (2.6, 2.1)`, :math:`P` with eigenvalues ``(0.193, 1.167)``; the printed, rounded
    matrices violate the LMI by about ``3e-3``).
    """
    n = check_int_in_range("n", n, 2, 10)
    kappa, rho_d, rho_v, gamma = _check_spec(kappa, rho_d, rho_v, gamma)
    eps = check_positive("eps", eps)
    l, P, status = _solve_cached(n, kappa, rho_d, rho_v, float(gamma), float(eps))
    if status != "optimal":
        raise LMIInfeasibleError(
            f"expected a feasible specification for Assumption 1 of Efimov et al. 2017 (n={n}, kappa={kappa}, "
            f"rho_d={rho_d}, rho_v={rho_v}, gamma={gamma}), actual value: solver status {status!r}; "
            "decrease kappa or gamma, or increase rho_d or rho_v"
        )
    l, P = l.copy(), P.copy()
    cert = certify_switched_gain(l, P, kappa, rho_d, rho_v, gamma, tol=tol)
    return l, P, cert


def certify_switched_gain(
    l, P, kappa: float, rho_d: float, rho_v: float, gamma: float = 0.0, *, tol: float = 1e-7, status: str = "optimal"
) -> SwitchedGainCertificate:
    r"""Re-verify Assumption 1 of Efimov et al. 2017 for given ``(l, P)`` with NumPy eigenvalues; raise if it fails.

    Checks :math:`P \succ 0`, the block matrix of :func:`switched_gain_lmi_matrix` at ``(P, P l)`` below ``tol``
    relative to the scale of ``P`` (the blocks that carry the decay condition are linear in ``P``: an absolute
    tolerance would pass any gain with a small enough ``P``), and what Lemma 3 derives from it, every eigenvalue
    of :math:`A - l c^T` with real part below :math:`-\kappa/2` (up to the rounding of the eigenvalue computation,
    and never a real part ``>= 0``).

    Raises
    ------
    TypeError, ValueError
        Arguments of another type, shape or range (``P`` symmetric up to rounding, of size 2 to 10, ``l`` of its
        size).
    LMIInfeasibleError
        The re-verification fails.
    """
    P = as_real_array("P", P)
    n = P.shape[0] if P.ndim == 2 else -1
    if P.shape != (n, n) or not 2 <= n <= 10:
        raise ValueError(f"expected P of shape (n, n) with 2 <= n <= 10, actual value: shape {P.shape}")
    l = as_real_array("l", l).ravel()
    if l.shape != (n,):
        raise ValueError(f"expected l with {n} entries (the size of P), actual value: shape {l.shape}")
    if not (np.isfinite(P).all() and np.isfinite(l).all()):
        raise ValueError("expected finite l and P, actual value: a NaN or infinite entry")
    kappa, rho_d, rho_v, gamma = _check_spec(kappa, rho_d, rho_v, gamma)
    tol = check_nonnegative("tol", tol)
    asymmetry = float(np.abs(P - P.T).max())
    if asymmetry > 1e-9 * float(np.abs(P).max()):  # Assumption 1 is for symmetric P; eigvalsh reads one triangle
        raise ValueError(
            f"expected a symmetric P (up to rounding, 1e-9 of its largest entry), actual value: max |P - P^T| = "
            f"{asymmetry:.3e}"
        )
    P = 0.5 * (P + P.T)
    eig_P = np.linalg.eigvalsh(P)
    M = switched_gain_lmi_matrix(P, P @ l, kappa, rho_d, rho_v, gamma)
    eig_M = np.linalg.eigvalsh(M)
    A, _, c = _canonical(n)
    A_l = A - np.outer(l, c.ravel())
    obs = np.linalg.eigvals(A_l)
    # Lemma 3 bounds the real parts strictly by -kappa/2: allow only the rounding of the eigenvalue computation,
    # relative to the scale of A - l c^T and kappa (a fixed slack passed unstable gains when kappa is tiny)
    slack = 64 * np.finfo(float).eps * max(np.linalg.norm(A_l, np.inf), kappa)
    if eig_P[0] <= 0.0 or eig_M[-1] > tol * min(1.0, eig_P[-1]):
        raise LMIInfeasibleError(
            "expected P > 0 and the Assumption 1 matrix <= 0 in the NumPy re-verification, actual value: "
            f"min eig(P) = {eig_P[0]:.3e}, max eig(LMI) = {eig_M[-1]:.3e} (tolerance {tol:.1e} x min(1, max eig(P)))"
        )
    if obs.real.max() >= 0.0 or obs.real.max() > -kappa / 2 + slack:
        raise LMIInfeasibleError(
            f"expected the eigenvalues of A - l c^T with real parts below -kappa/2 = {-kappa / 2:.6g} (Lemma 3), "
            f"actual value: {obs.real.max():.6g}"
        )
    return SwitchedGainCertificate(
        min_eig_P=float(eig_P[0]),
        max_eig_P=float(eig_P[-1]),
        max_eig_lmi=float(eig_M[-1]),
        observer_eigenvalues=obs,
        kappa=float(kappa),
        rho_d=float(rho_d),
        rho_v=float(rho_v),
        gamma=float(gamma),
        status=status,
    )


@lru_cache(maxsize=64)
def _solve_cached(n: int, kappa: float, rho_d: float, rho_v: float, gamma: float, eps: float):
    cp = require("cvxpy", "design")  # imported here: cvxpy takes about a second to import

    A, b, c = _canonical(n)
    P = cp.Variable((n, n), symmetric=True)
    w = cp.Variable((n, 1))
    nu = cp.Variable()
    S = A.T @ P + P @ A - c @ w.T - w @ c.T + kappa * P
    z = np.zeros((1, 1))
    if gamma > 0.0:
        S = S + np.eye(n)
        M = cp.bmat(
            [
                [S, P @ b, -w, -P @ b],
                [b.T @ P, -(rho_d**2) * np.ones((1, 1)), z, z],
                [-w.T, z, -(rho_v**2) * np.ones((1, 1)), z],
                [-b.T @ P, z, z, -(gamma**-2) * np.ones((1, 1))],
            ]
        )
    else:
        M = cp.bmat(
            [
                [S, P @ b, -w],
                [b.T @ P, -(rho_d**2) * np.ones((1, 1)), z],
                [-w.T, z, -(rho_v**2) * np.ones((1, 1))],
            ]
        )
    M = 0.5 * (M + M.T)
    k = M.shape[0]
    problem = cp.Problem(cp.Maximize(nu), [P >> nu * np.eye(n), nu >= eps, M << -eps * np.eye(k)])
    try:
        problem.solve(solver=cp.CLARABEL)
    except cp.error.SolverError as exc:  # pragma: no cover - solver failure is reported as infeasibility
        return None, None, f"solver error: {exc}"
    if problem.status != "optimal":
        return None, None, problem.status
    Pv = 0.5 * (P.value + P.value.T)
    l = np.linalg.solve(Pv, w.value).ravel()
    return l, Pv, problem.status
