"""LMI design of Efimov et al. 2017 (Assumption 1 / Remark 2): solution, NumPy re-verification, infeasibility."""

from __future__ import annotations

import re

import numpy as np
import pytest

from smo_gym.design import (
    LMIInfeasibleError,
    SwitchedGainCertificate,
    certify_switched_gain,
    switched_gain_lmi,
    switched_gain_lmi_matrix,
)


def _assumption1(P, l, kappa, rho_d, rho_v, gamma):
    """The block matrix of Assumption 1 written out here, independently of ``smo_gym.design.lmi``."""
    n = P.shape[0]
    A = np.diag(np.ones(n - 1), 1)
    b = np.eye(n)[:, [-1]]
    c = np.eye(n)[:, [0]]
    w = (P @ l).reshape(n, 1)
    S = A.T @ P + P @ A - c @ w.T - w @ c.T + kappa * P + (np.eye(n) if gamma > 0 else 0.0)
    z = np.zeros((1, 1))
    rows = [[S, P @ b, -w], [b.T @ P, -(rho_d**2) + z, z], [-w.T, z, -(rho_v**2) + z]]
    if gamma > 0:
        rows = [r + [extra] for r, extra in zip(rows, [-P @ b, z, z], strict=False)]
        rows.append([-b.T @ P, z, z, -(gamma**-2) + z])
    return np.block(rows)


def test_reproduces_the_printed_gain_of_section_6():
    """Efimov et al. 2017, Section 6: kappa = rho_d = rho_v = 1 gives l = [2.6 2.1], P = [[0.76 -0.48] [-0.48 0.6]]."""
    l, P, cert = switched_gain_lmi(2, kappa=1.0, rho_d=1.0, rho_v=1.0)
    assert np.allclose(l, [2.6, 2.1], atol=0.05)
    assert np.allclose(P, [[0.76, -0.48], [-0.48, 0.6]], atol=0.02)
    assert isinstance(cert, SwitchedGainCertificate) and cert.status == "optimal"


@pytest.mark.parametrize(
    "n, kappa, rho_d, rho_v, gamma",
    [
        (2, 1.0, 1.0, 1.0, 0.0),
        (3, 1.0, 1.0, 1.0, 0.0),
        (4, 2.0, 1.0, 0.5, 0.0),
        (2, 0.1, 2.0, 2.0, 0.2),
        (3, 0.2, 5.0, 5.0, 0.1),
    ],
)
def test_solution_is_reverified_in_numpy(n, kappa, rho_d, rho_v, gamma):
    l, P, cert = switched_gain_lmi(n, kappa, rho_d, rho_v, gamma)
    assert np.allclose(P, P.T)
    eig_P = np.linalg.eigvalsh(P)
    M = _assumption1(P, l, kappa, rho_d, rho_v, gamma)
    assert np.allclose(M, M.T)
    assert eig_P[0] > 0 and np.linalg.eigvalsh(M).max() <= 1e-7
    assert cert.min_eig_P == pytest.approx(eig_P[0]) and cert.max_eig_lmi <= 1e-7
    # the leading block implies (A - l c^T)^T P + P (A - l c^T) <= -kappa P: spectral abscissa <= -kappa / 2
    A = np.diag(np.ones(n - 1), 1)
    assert np.linalg.eigvals(A - np.outer(l, np.eye(n)[0])).real.max() <= -kappa / 2 + 1e-6


@pytest.mark.parametrize("spec", [(2, 100.0, 0.01, 0.01, 0.0), (2, 1.0, 1.0, 1.0, 10.0), (3, 1.0, 1.0, 1.0, 0.5)])
def test_infeasible_specification_raises(spec):
    with pytest.raises(LMIInfeasibleError, match="expected a feasible specification"):
        switched_gain_lmi(*spec)
    assert issubclass(LMIInfeasibleError, ValueError)


def test_printed_rounded_values_fail_the_strict_check():
    """Measured: the two-digit values printed in Section 6 violate the LMI by about 3e-3 (rounding)."""
    l, P = np.array([2.6, 2.1]), np.array([[0.76, -0.48], [-0.48, 0.6]])
    top = np.linalg.eigvalsh(_assumption1(P, l, 1.0, 1.0, 1.0, 0.0)).max()
    assert 1e-3 < top < 1e-2
    with pytest.raises(LMIInfeasibleError):
        certify_switched_gain(l, P, 1.0, 1.0, 1.0)


def test_certificate_scales_with_p_and_checks_lemma_3():
    """A gain that is not even stable (eigenvalues 1.618 and -0.618) was certified with ``P = 1e-9 I``: every
    block that carries the decay condition is linear in ``P``, so an absolute tolerance passed it. And
    a negative ``kappa`` or a NaN tolerance passed anything."""
    l, P = np.array([-1.0, -1.0]), 1e-9 * np.eye(2)
    assert np.linalg.eigvals(np.eye(2, k=1) - np.outer(l, [1.0, 0.0])).real.max() > 1.6
    with pytest.raises(LMIInfeasibleError, match="max eig"):
        certify_switched_gain(l, P, 1.0, 1.0, 1.0)
    l, P, cert = switched_gain_lmi(2, 1.0, 1.0, 1.0)  # the solver's design still passes, Lemma 3 included
    assert cert.observer_eigenvalues.real.max() < -0.5
    with pytest.raises(ValueError, match="kappa"):
        certify_switched_gain(l, P, -10.0, 1.0, 1.0)
    with pytest.raises(ValueError, match="tol"):
        certify_switched_gain([-5.0, -5.0], np.eye(2), 1.0, 1.0, 1.0, tol=np.nan)
    with pytest.raises(TypeError, match="expected P"):
        certify_switched_gain(l, P * (1 + 1j), 1.0, 1.0, 1.0)
    with pytest.raises(ValueError, match="expected l with 2 entries"):
        certify_switched_gain([1.0, 2.0, 3.0], P, 1.0, 1.0, 1.0)
    # an asymmetric P (the solver's plus a skew part) was certified as its symmetric part; rounding-level
    # asymmetry still passes
    skew = np.array([[0.0, 1.0], [-1.0, 0.0]]) * 1e-3 * np.abs(P).max()
    with pytest.raises(ValueError, match=re.escape(f"max |P - P^T| = {2e-3 * np.abs(P).max():.3e}")):
        certify_switched_gain(l, P + skew, 1.0, 1.0, 1.0)
    certify_switched_gain(l, P + 1e-12 * skew, 1.0, 1.0, 1.0)
    with pytest.raises(ValueError, match=r"rho_d in \[1e-150"):
        switched_gain_lmi(2, 1.0, 1e300, 1.0)


@pytest.mark.parametrize(
    "kwargs, exc",
    [
        (dict(n=1, kappa=1.0, rho_d=1.0, rho_v=1.0), ValueError),
        (dict(n=2.0, kappa=1.0, rho_d=1.0, rho_v=1.0), TypeError),
        (dict(n=2, kappa=-1.0, rho_d=1.0, rho_v=1.0), ValueError),
        (dict(n=2, kappa=1.0, rho_d="a", rho_v=1.0), TypeError),
        (dict(n=2, kappa=1.0, rho_d=1.0, rho_v=1.0, gamma=-0.1), ValueError),
    ],
)
def test_bad_input_raises_typed_errors(kwargs, exc):
    with pytest.raises(exc, match="expected"):
        switched_gain_lmi(**kwargs)


def test_lemma_3_check_has_no_fixed_slack():
    """With a tiny kappa a fixed slack of 1e-6 certified the unstable observer eigenvalues (1e-7, 0)."""
    with pytest.raises(LMIInfeasibleError, match="Lemma 3"):
        certify_switched_gain([-1e-7, 0.0], np.diag([1e-8, 1.0]), 1e-9, 1e4, 1.0)
    l, P, _ = switched_gain_lmi(3, 1.0, 1.0, 1.0)
    cert = certify_switched_gain(l, P, 1.0, 1.0, 1.0)
    assert cert.observer_eigenvalues.real.max() < -0.5


def test_block_matrix_refuses_non_finite_input_and_overflow():
    from smo_gym.design import switched_gain_lmi_matrix

    with pytest.raises(ValueError, match="finite P and w"):
        switched_gain_lmi_matrix(np.full((2, 2), np.nan), [1.0, 1.0], 1.0, 1.0, 1.0)
    with pytest.raises(ValueError, match="overflow"):
        switched_gain_lmi_matrix(1e200 * np.eye(2), [1e200, 1e200], 1e150, 1.0, 1.0)
    assert np.isfinite(switched_gain_lmi_matrix(np.eye(2), [1.0, 1.0], 1.0, 1.0, 1.0)).all()


@pytest.mark.parametrize("gamma", [0.0, 0.1])
def test_block_matrix_is_assumption_1(gamma):
    """The NumPy block matrix is the one written out above, with the ``I_n`` term and the last row and column
    exactly when ``gamma > 0`` (Efimov et al. 2017, Assumption 1; Remark 2 for ``gamma = 0``)."""
    rng = np.random.default_rng(0)
    X = rng.normal(size=(3, 3))
    P, l = X @ X.T + np.eye(3), rng.normal(size=3)
    expected = _assumption1(P, l, 0.2, 5.0, 5.0, gamma)
    np.testing.assert_allclose(switched_gain_lmi_matrix(P, P @ l, 0.2, 5.0, 5.0, gamma), expected, atol=1e-13)


def test_a_returned_design_is_the_callers_own():
    """The designs are cached: what a caller does to the arrays it got must not change the next caller's design."""
    l, P, _ = switched_gain_lmi(2, 1.0, 1.0, 1.0)
    kept = l.copy(), P.copy()
    l[:] = 0.0
    P[:] = 0.0
    again, P_again, _ = switched_gain_lmi(2, 1.0, 1.0, 1.0)
    np.testing.assert_array_equal(again, kept[0])
    np.testing.assert_array_equal(P_again, kept[1])


def test_the_design_keeps_its_margin():
    """``eps`` is the margin the solver is asked for: the certified largest eigenvalue of the block matrix is at
    most ``-eps`` (relative to the solver's tolerance)."""
    _, _, cert = switched_gain_lmi(2, 1.0, 1.0, 1.0, eps=1e-3)
    assert cert.max_eig_lmi <= -1e-3 * (1 - 1e-4), cert.max_eig_lmi


def test_lemma_3_and_a_positive_p_are_checked_whatever_the_tolerance():
    """The block matrix's tolerance does not excuse the rest of the certificate: observer eigenvalues at -0.6
    (``s^2 + 1.2 s + 0.36``) are above ``-kappa/2 = -1`` (Lemma 3), and an indefinite ``P`` is no Lyapunov
    matrix, both refused with the loosest tolerance."""
    with pytest.raises(LMIInfeasibleError):
        certify_switched_gain([1.2, 0.36], np.eye(2), 2.0, 1.0, 1.0, tol=1e12)
    l, P, _ = switched_gain_lmi(2, 1.0, 1.0, 1.0)
    values, vectors = np.linalg.eigh(P)
    indefinite = vectors @ np.diag([-values[0], values[1]]) @ vectors.T
    with pytest.raises(LMIInfeasibleError):
        certify_switched_gain(l, indefinite, 1.0, 1.0, 1.0, tol=1e12)
