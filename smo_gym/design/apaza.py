r"""Gain design for the dissipative super-twisting observer (Apaza-Perez, Moreno and Fridman 2018).

The observer error in the coordinates :math:`\zeta = (\phi_1(e_1), e_2)` obeys
:math:`\dot\zeta = \phi_1'(e_1)\bigl(A\zeta + B(\rho_1 + \rho_2)\bigr)` with

.. math::
    A = \begin{bmatrix} -k_1 & 1\\ -k_2 & 0\end{bmatrix},\quad B = \begin{bmatrix}0\\1\end{bmatrix},\quad
    C = [1\ 0],\quad E = [k_3\ 1],

:math:`\rho_1` the model nonlinearity (bounded through its :math:`\{q, s, r\}`-dissipativity, assumption A-3) and
:math:`\rho_2` the unknown input (:math:`|w| \le L_w`, assumption A-1). The gain lemma of Fridman's slides asks for
:math:`P \succ 0`, :math:`\theta_1, \theta_2, \epsilon > 0` with

.. math::
    \begin{bmatrix}
      A^\top P + PA + \theta_1 H_E + \theta_2 H_C + \epsilon I & PB & PB\\
      B^\top P & \theta_1 q & 0\\
      B^\top P & 0 & -\theta_2 c_2
    \end{bmatrix} \preceq 0,\qquad
    H_E = E^\top\Bigl(\frac{|s| + \sqrt{s^2 - qr}}{\sqrt{-q}\,\mu_2}\Bigr)^2 E,\quad H_C = L_w^2 C^\top C.

Notes
-----
Two deviations from the printed slide, both from re-deriving the S-procedure:

* The slide prints the last diagonal block as :math:`+\theta_2(\mu_1/(2d_2))^2`. A positive diagonal entry makes
  the matrix impossible to be negative semidefinite for :math:`\theta_2 > 0`, so the sign is a garbled minus.
* The bound on :math:`\rho_2 = -\Upsilon w/\phi_1'` uses :math:`1/\phi_1' \le 2|e_1|^{1/2}/\mu_1` and
  :math:`|e_1|^{1/2} \le |\phi_1|/\mu_1`, which gives :math:`|\rho_2| \le 2 d_2 L_w |\zeta_1|/\mu_1^2` with
  :math:`d_2 = \max\Upsilon` (``upsilon_max``, :math:`e^{L_\alpha}` under assumption A-2). Hence
  :math:`c_2 = (\mu_1^2/(2 d_2))^2`; the slide's :math:`(\mu_1/(2 d_2))^2` corresponds to a different
  normalisation of :math:`d_2` that the slides do not define. We implement the derived constant.

The lemma's matrix is linear in :math:`(P, \theta_1, \theta_2, \epsilon)` for fixed gains; it is homogeneous, so
:math:`P \succeq I` and a fixed :math:`\epsilon` fix the scale. :func:`apaza_gains` keeps ``k1, k2, k3`` and the
ratio ``mu2 / mu1`` and bisects on the scale of ``(mu1, mu2)`` (larger injections shrink both perturbation
bounds), returning the smallest feasible scale found, with the certificate re-verified in NumPy.

References
----------
.. [AMF18] J. C. Apaza-Perez, J. A. Moreno and L. Fridman, "Dissipative approach to sliding mode observers
   design for uncertain mechanical systems", Automatica 87, 2018 (Fridman's lecture slides, "Dissipative approach",
   Lemma "gain design").
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._extras import require
from .._validation import as_real_array, check_int_in_range, check_real_in_range

#: solver-side margin so that the NumPy re-check sees a strictly negative matrix despite solver tolerances
_MARGIN = 1e-6

__all__ = ["ApazaGains", "InfeasibleGainsError", "apaza_gains", "apaza_lmi_matrix"]

#: the range of the magnitudes the design takes (their squares and products stay finite)
_SMALL, _BIG = 1e-50, 1e50


class InfeasibleGainsError(ValueError):
    """The gain lemma's matrix inequality has no solution for the given data."""


@dataclass(frozen=True)
class ApazaGains:
    """Gains of :class:`smo_gym.observers.DissipativeSuperTwisting` with their verified certificate.

    Attributes
    ----------
    k1, k2, k3, mu1, mu2 : float
        Observer gains.
    P : ndarray, shape (2, 2)
        Lyapunov matrix of the certificate.
    theta1, theta2, epsilon : float
        S-procedure multipliers and the decay margin.
    lmi_max_eigenvalue : float
        Largest eigenvalue of the lemma's matrix at the certificate, recomputed in NumPy (``<= 0``).
    p_min_eigenvalue : float
        Smallest eigenvalue of ``P`` recomputed in NumPy (``> 0``).
    data : dict
        The problem data ``lipschitz, q, s, r, upsilon_max``.
    """

    k1: float
    k2: float
    k3: float
    mu1: float
    mu2: float
    P: np.ndarray
    theta1: float
    theta2: float
    epsilon: float
    lmi_max_eigenvalue: float
    p_min_eigenvalue: float
    data: dict = field(default_factory=dict)

    def as_dict(self) -> dict[str, float]:
        """``{"k1", "k2", "k3", "mu1", "mu2"}``, the observer's ``gains=`` argument."""
        return {"k1": self.k1, "k2": self.k2, "k3": self.k3, "mu1": self.mu1, "mu2": self.mu2}


def _constants(k1, k2, k3, mu1, mu2, lipschitz, q, s, r, upsilon_max):
    A = np.array([[-k1, 1.0], [-k2, 0.0]])
    B = np.array([[0.0], [1.0]])
    C = np.array([[1.0, 0.0]])
    E = np.array([[k3, 1.0]])
    gamma = (abs(s) + np.sqrt(s * s - q * r)) / (np.sqrt(-q) * mu2)
    H_E = gamma**2 * E.T @ E
    H_C = lipschitz**2 * C.T @ C
    c2 = (mu1**2 / (2.0 * upsilon_max)) ** 2
    return A, B, H_E, H_C, c2


def _check_lemma_data(lipschitz, q, s, r, upsilon_max, k1, k2, k3, epsilon) -> tuple[float, ...]:
    """The lemma's numbers as floats, checked: magnitudes within 1e-50 .. 1e50 (the matrix holds their squares
    and products, which must stay finite), ``q < 0`` and ``s^2 - q r >= 0`` (assumption A-3)."""
    lipschitz = check_real_in_range("lipschitz", lipschitz, 0.0, _BIG)
    q = check_real_in_range("q (assumption A-3: q < 0)", q, -_BIG, 0.0, high_open=True)
    s, r = check_real_in_range("s", s, -_BIG, _BIG), check_real_in_range("r", r, -_BIG, _BIG)
    if s * s - q * r < 0:
        raise ValueError(f"expected s, r with s^2 - q r >= 0, actual value: s={s!r}, r={r!r}")
    upsilon_max, k1, k2, epsilon = (
        check_real_in_range(name, value, _SMALL, _BIG)
        for name, value in (("upsilon_max", upsilon_max), ("k1", k1), ("k2", k2), ("epsilon", epsilon))
    )
    return lipschitz, q, s, r, upsilon_max, k1, k2, check_real_in_range("k3", k3, -_BIG, _BIG), epsilon


def apaza_lmi_matrix(
    P, theta1, theta2, epsilon, *, k1, k2, k3, mu1, mu2, lipschitz, q, s, r, upsilon_max
) -> np.ndarray:
    r"""The lemma's ``(4, 4)`` matrix (module docstring) at given multipliers, in NumPy (symmetrised)."""
    lipschitz, q, s, r, upsilon_max, k1, k2, k3, epsilon = _check_lemma_data(
        lipschitz, q, s, r, upsilon_max, k1, k2, k3, epsilon
    )
    mu1, mu2 = check_real_in_range("mu1", mu1, _SMALL, _BIG), check_real_in_range("mu2", mu2, _SMALL, _BIG)
    theta1, theta2 = check_real_in_range("theta1", theta1, 0.0, _BIG), check_real_in_range("theta2", theta2, 0.0, _BIG)
    P = as_real_array("P", P)
    if P.shape != (2, 2) or not np.isfinite(P).all():
        raise ValueError(f"expected a finite P of shape (2, 2), actual value: {P!r:.80}")
    A, B, H_E, H_C, c2 = _constants(k1, k2, k3, mu1, mu2, lipschitz, q, s, r, upsilon_max)
    top = A.T @ P + P @ A + theta1 * H_E + theta2 * H_C + epsilon * np.eye(2)
    PB = P @ B
    Mx = np.block(
        [
            [top, PB, PB],
            [PB.T, np.array([[theta1 * q]]), np.zeros((1, 1))],
            [PB.T, np.zeros((1, 1)), np.array([[-theta2 * c2]])],
        ]
    )
    return (Mx + Mx.T) / 2


def _solve(k1, k2, k3, mu1, mu2, lipschitz, q, s, r, upsilon_max, epsilon):
    cp = require("cvxpy", "design")

    A, B, H_E, H_C, c2 = _constants(k1, k2, k3, mu1, mu2, lipschitz, q, s, r, upsilon_max)
    P = cp.Variable((2, 2), symmetric=True)
    t1 = cp.Variable(nonneg=True)
    t2 = cp.Variable(nonneg=True)
    top = A.T @ P + P @ A + t1 * H_E + t2 * H_C + epsilon * np.eye(2)
    PB = P @ B
    Mx = cp.bmat(
        [
            [top, PB, PB],
            [PB.T, cp.reshape(t1 * q, (1, 1), order="C"), np.zeros((1, 1))],
            [PB.T, np.zeros((1, 1)), cp.reshape(-t2 * c2, (1, 1), order="C")],
        ]
    )
    Ms = (Mx + Mx.T) / 2
    cons = [Ms << -_MARGIN * np.eye(4), P >> np.eye(2), t1 >= epsilon, t2 >= epsilon]
    prob = cp.Problem(cp.Minimize(cp.trace(P)), cons)
    try:
        prob.solve(solver=cp.CLARABEL)
    except cp.error.SolverError:
        return None
    if prob.status != "optimal":
        return None
    Pv = (P.value + P.value.T) / 2
    th1, th2 = float(t1.value), float(t2.value)
    lm = apaza_lmi_matrix(
        Pv,
        th1,
        th2,
        epsilon,
        k1=k1,
        k2=k2,
        k3=k3,
        mu1=mu1,
        mu2=mu2,
        lipschitz=lipschitz,
        q=q,
        s=s,
        r=r,
        upsilon_max=upsilon_max,
    )
    lmax = float(np.linalg.eigvalsh(lm).max())
    pmin = float(np.linalg.eigvalsh(Pv).min())
    if lmax >= 0.0 or pmin <= 0 or th1 <= 0 or th2 <= 0:
        return None  # solver tolerance: the certificate does not verify; treat as infeasible at this point
    return Pv, th1, th2, lmax, pmin


def apaza_gains(
    lipschitz: float,
    q: float,
    s: float,
    r: float,
    *,
    upsilon_max: float = 1.0,
    k1: float = 2.0,
    k2: float = 1.0,
    k3: float = 0.0,
    mu1: float | None = None,
    mu2: float | None = None,
    mu_ratio: float = 1.0,
    epsilon: float = 1e-3,
    max_scale: float = 1e6,
    iterations: int = 40,
) -> ApazaGains:
    r"""Gains of the dissipative super-twisting observer from the gain lemma, with a NumPy-verified certificate.

    Parameters
    ----------
    lipschitz : float
        :math:`L_w \ge 0`, bound of the unknown input (A-1), in the original (acceleration) units.
    q, s, r : float
        Dissipativity of the model nonlinearity (A-3), :math:`q < 0`, :math:`s^2 - qr \ge 0`.
    upsilon_max : float
        :math:`d_2 = \max\Upsilon \ge 1` over the operating range (``CoordinateTransform.grid_upsilon.max()``).
    k1, k2 : float
        Gains of ``A`` (must make it Hurwitz: ``k1, k2 > 0``).
    k3 : float
        The gain of the model argument (``E = [k3, 1]``).
    mu1, mu2 : float, optional
        If both are given, only check feasibility at these values (raise if infeasible). Otherwise search the
        smallest scale ``lam`` with ``(mu1, mu2) = lam * (1, mu_ratio)`` by bisection.
    epsilon : float
        Decay margin :math:`\epsilon` (and the lower bound of the multipliers); ``P >= I`` fixes the scale.

    Returns
    -------
    ApazaGains

    Raises
    ------
    TypeError
        On a non-number (a string, a bool) where a number is expected.
    ValueError
        On invalid data (``q >= 0``, ``s^2 - q r < 0``, non-positive gains, a non-finite or out-of-range ``mu1`` or
        ``mu2``, or only one of them given).
    InfeasibleGainsError
        (a ``ValueError``) if the inequality has no verified solution at the given ``mu1, mu2``, or up to
        ``max_scale``.
    """
    lipschitz, q, s, r, upsilon_max, k1, k2, k3, epsilon = _check_lemma_data(
        lipschitz, q, s, r, upsilon_max, k1, k2, k3, epsilon
    )
    max_scale = check_real_in_range("max_scale", max_scale, 1.0, _BIG)
    iterations = check_int_in_range("iterations", iterations, 0, 1000)
    data = {"lipschitz": lipschitz, "q": q, "s": s, "r": r, "upsilon_max": upsilon_max}

    def attempt(m1, m2):
        return _solve(k1, k2, k3, m1, m2, lipschitz, q, s, r, upsilon_max, epsilon)

    def result(m1, m2, sol):
        Pv, th1, th2, lmax, pmin = sol
        return ApazaGains(k1, k2, k3, float(m1), float(m2), Pv, th1, th2, epsilon, lmax, pmin, data)

    m1 = None if mu1 is None else check_real_in_range("mu1", mu1, _SMALL, _BIG)
    m2 = None if mu2 is None else check_real_in_range("mu2", mu2, _SMALL, _BIG)
    if (m1 is None) != (m2 is None):  # a lone multiplier would be silently replaced by the search
        raise ValueError(
            f"expected mu1 and mu2 given together (to check them) or both omitted (to search), actual value: "
            f"mu1={mu1!r}, mu2={mu2!r}"
        )
    if m1 is not None:
        sol = attempt(m1, m2)
        if sol is None:
            raise InfeasibleGainsError(
                f"expected a feasible gain lemma, actual value: no verified solution for k1={k1}, k2={k2}, "
                f"k3={k3}, mu1={m1}, mu2={m2} with L_w={lipschitz}, (q, s, r)=({q}, {s}, {r}), "
                f"upsilon_max={upsilon_max}; increase mu1 and mu2 or omit them to search"
            )
        return result(m1, m2, sol)
    ratio = check_real_in_range("mu_ratio", mu_ratio, _SMALL, _BIG)
    hi = 1.0
    sol_hi = attempt(hi, ratio * hi)
    while sol_hi is None:
        hi *= 10.0
        if hi > max_scale:
            raise InfeasibleGainsError(
                f"expected a feasible gain lemma, actual value: infeasible up to mu1={max_scale} for "
                f"L_w={lipschitz}, (q, s, r)=({q}, {s}, {r}), upsilon_max={upsilon_max}, k1={k1}, k2={k2}, k3={k3}"
            )
        sol_hi = attempt(hi, ratio * hi)
    lo = hi / 10.0 if hi > 1.0 else 0.0
    for _ in range(iterations):
        if hi - lo <= 1e-3 * hi:
            break
        mid = 0.5 * (lo + hi) if lo > 0 else hi / 2.0
        sol = attempt(mid, ratio * mid)
        if sol is None:
            lo = mid
        else:
            hi, sol_hi = mid, sol
        if lo == 0.0 and hi < 1e-6:
            break
    return result(hi, ratio * hi, sol_hi)
