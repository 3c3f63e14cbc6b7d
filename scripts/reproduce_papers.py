#!/usr/bin/env python
r"""Rerun the numerical examples of the source papers and of Fridman's slides; print each claim next to what was
measured, with a verdict.

Usage::

    python scripts/reproduce_papers.py [--out outputs/papers] [--fast] [--papers KEY ...]

``PAPERS`` maps each key to its citation and runner. Lopez-Ramirez et al. 2016 (ILF finite-time / fixed-time
observers, section V) and Wetzlinger et al. (discrete-time HOSM observer, section 6) are reproduced here with
:class:`smo_gym.observers.ILFObserver`, :func:`smo_gym.design.ilf_gains` and
:class:`smo_gym.observers.DiscreteTimeHOSM`; the others live in scripts of their own, loaded when run:
``reproduce_efimov2017.py`` (switched-gain differentiator) and ``reproduce_slides_*.py`` (the slides' sections:
conventional observers, LTV systems, unknown inputs, finite-time stabilization). The experiment functions
(``lopez_ramirez_example``, ``run_ilf_errors``, ``simulate_wetzlinger_third_order``, ...) are also what
``tests/test_ilf.py`` and ``tests/test_discrete_hosm.py`` run, with coarser settings.

Lopez-Ramirez et al. 2016, how the errors are simulated
---------------------------------------
The plant of section V is unstable (eigenvalues up to 10.1), so from :math:`x(0) = 10^4x^*` its state reaches
~1e12 by t = 1.75 s, and the claim :math:`\|e(1.75)\| \le 2\cdot10^{-4}` would sit below float64 resolution of
``x - xhat``. The sampled ILF observer predicts the plant exactly (zero-order hold), so its error sequence is
autonomous — the same for every plant trajectory and input (``test_ilf`` checks this against a real plant run).
The large-error runs therefore use the plant :math:`x \equiv 0,\ u \equiv 0` with
:math:`\hat x(0) = -x(0)`, which has exactly the error sequence of the paper's set-up; Fig. 1 (small initial
error, :math:`u = \sin t`) is run with the real plant. The fixed-time claim is judged in continuous time: the error
equation (18) integrated with adaptive steps at two tolerances (:func:`smo_gym.observers.ilf.continuous_settling`),
since the implicit step of the sampled observer damps the error and a coarse step meets the bound by itself.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from smo_gym.design import ackermann_observer_gain, block_decomposition, ilf_gains
from smo_gym.design.lmi import LMIInfeasibleError
from smo_gym.observers import DiscreteTimeHOSM, ILFObserver
from smo_gym.observers.discrete_hosm import (
    canonical_error_step,
    max_eigenvalue,
    proven_eigenvalue_bound,
    rate_for_max_eigenvalue,
    stability_threshold,
)
from smo_gym.observers.ilf import continuous_settling, error_rhs  # noqa: F401 (the tests use error_rhs)

# ----------------------------------------------------------------------------------------------------------------
# Lopez-Ramirez et al. 2016, section V
# ----------------------------------------------------------------------------------------------------------------


def lopez_ramirez_example() -> dict:
    """The system, transformation and gains printed in section V of Lopez-Ramirez et al. 2016."""
    A = np.array([[1, 1, 2, 4, 5], [1, 3, 2, -1, -3], [2, 1, -3, 7, 3], [4, -2, 9, 1, -1], [1, -1, 0, 2, 1]], float)
    B = np.array([[0.0], [0.0], [0.0], [0.0], [1.0]])
    C = np.array([[1, 0, 0, 0, 0], [0, 0, 0, 0, 1]], float)
    Phi = np.array(
        [
            [1.0, 0, 0, 0, 0],
            [0, 0, 0, 0, 1.0],
            [-1.2333, -0.0793, 0.2673, 0.9604, 2.6729],
            [0.8995, -0.8414, -0.5345, 0.0793, 0.3865],
            [-0.2083, -0.9068, 0.8159, 0.5198, -3.1524],
        ]
    )
    L_finite = np.array(
        [[-5.2009, -0.9657], [-0.8583, -4.6400], [-7.6469, -6.6227], [-0.4210, -7.7855], [-2.0775, -1.4736]]
    )
    L_fixed = np.array(
        [
            [-22.9151, -4.7168],
            [-4.8386, -19.1328],
            [-170.0681, -138.8725],
            [-17.5165, -152.9384],
            [-234.9672, -159.6799],
        ]
    )
    return dict(
        A=A,
        B=B,
        C=C,
        Phi=Phi,
        L_finite=L_finite,
        L_fixed=L_fixed,
        mu_finite=1.0,
        mu_fixed=0.5,
        alpha=32.0 / 7.0,
        T_max=1.75,
        x_star=np.array([1.0, -1.0, 1.0, -1.0, 1.0]),
    )


def run_ilf_errors(observer: ILFObserver, x0: np.ndarray, T: float) -> tuple[np.ndarray, np.ndarray]:
    r"""Error norms :math:`\|x - \hat x\|` of ``observer`` from initial errors ``x0`` (batch ``(B, n)``).

    Plant :math:`x\equiv0` with :math:`\hat x(0) = -x_0` (same error sequence as any plant, see the module
    docstring). Returns ``(t, norms)`` with ``t`` of shape ``(K + 1,)`` and ``norms`` ``(K + 1, B)``.
    """
    x0 = np.atleast_2d(np.asarray(x0, dtype=float))
    K = int(round(T / observer.dt))
    norms = np.empty((K + 1, x0.shape[0]))
    norms[0] = np.linalg.norm(x0, axis=1)
    observer.reset(-x0)
    y = np.zeros((x0.shape[0], observer.C.shape[0]))
    for k in range(K):
        norms[k + 1] = np.linalg.norm(observer.update(y), axis=1)
    return np.arange(K + 1) * observer.dt, norms


def convergence_time(t: np.ndarray, norms: np.ndarray, tol: float) -> np.ndarray:
    """First time after which ``norms <= tol`` for good (``inf`` if never); ``norms`` ``(K + 1, B)``."""
    out = np.full(norms.shape[1], np.inf)
    for j in range(norms.shape[1]):
        above = np.flatnonzero(norms[:, j] > tol)
        if above.size == 0:
            out[j] = t[0]
        elif above[-1] < t.size - 1:
            out[j] = t[above[-1] + 1]
    return out


def run_real_plant(observer: ILFObserver, x0, T: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r"""Plant (1) with :math:`u = \sin t` held over each step (exact ZOH), observer from :math:`\hat x = 0`.

    Returns ``(t, x, xhat)`` with shapes ``(K + 1,)``, ``(K + 1, n)``, ``(K + 1, n)``.
    """
    from smo_gym.observers.ilf import _zoh

    h = observer.dt
    Ad, Bd = _zoh(observer.A, observer.B, h)
    K = int(round(T / h))
    x = np.empty((K + 1, observer.n))
    xh = np.empty_like(x)
    x[0] = x0
    xh[0] = observer.reset(np.zeros((1, observer.n)))[0]
    for k in range(K):
        u = np.array([np.sin(k * h)])
        x[k + 1] = Ad @ x[k] + Bd @ u
        xh[k + 1] = observer.update((observer.C @ x[k + 1])[None], u[None])[0]
    return np.arange(K + 1) * h, x, xh


def reproduce_lopez_ramirez2016(out_dir: Path | None, h: float = 1e-3, fast: bool = False) -> list[dict]:
    """Section V of Lopez-Ramirez et al. 2016: both observers, the paper's gains and ours; claims against
    measurements."""
    ex = lopez_ramirez_example()
    A, B, C = ex["A"], ex["B"], ex["C"]
    xs = ex["x_star"]
    claims: list[dict] = []
    dec_paper = block_decomposition(A, C, Phi=ex["Phi"])
    dec = block_decomposition(A, C)
    claims.append(
        dict(
            claim="Appendix decomposition gives the printed Phi (4 decimals)",
            paper="Phi printed in V.A",
            ours=f"max |Phi_computed - Phi_printed| = {np.abs(dec.Phi - ex['Phi']).max():.1e}",
            measured=f"max |Phi_computed - Phi_printed| = {np.abs(dec.Phi - ex['Phi']).max():.2e}, "
            f"blocks {dec.block_sizes}",
            ok=bool(np.abs(dec.Phi - ex["Phi"]).max() < 1e-4),
        )
    )

    # LMI designs (Algorithms 9 and 12)
    t0 = time.perf_counter()
    try:
        ilf_gains(A, C, 1.0, "finite")
        prop8 = "feasible"
    except LMIInfeasibleError:
        prop8 = "infeasible (r_m = 1 zeroes a diagonal block of (16))"
    des_f = ilf_gains(A, C, ex["mu_finite"], "finite", condition="points")
    des_x = ilf_gains(A, C, ex["mu_fixed"], "fixed", alpha=ex["alpha"])  # Algorithm 12 with Proposition 11
    claims.append(
        dict(
            claim="Algorithm 9 finds L for mu = 1, delta = (1+sqrt5)/(3+sqrt5) (paper: L printed in V.A)",
            measured=f"Prop. 8 grid: {prop8}; (14) on grid points: feasible, certified on "
            f"{des_f.certificate.dense_points} points (margin {des_f.certificate.parametric_margin:.1e}); "
            f"L^T = {np.array2string(des_f.L.T, precision=2)}",
            ok=des_f.certificate.ok,
        )
    )
    claims.append(
        dict(
            claim="Algorithm 12 finds L for mu = 0.5, alpha = 32/7 (T_max <= 1.75) (paper: L printed in V.B)",
            paper=f"max |L| = {np.abs(ex['L_fixed']).max():.1f}",
            ours=f"max |L| = {np.abs(des_x.L).max():.1f}, certified T_max bound {des_x.settling_time_bound:.3f}",
            measured=f"Prop. 11 grid (beta = r_1 = {des_x.variables.get('beta', 0.25)}), "
            f"{des_x.refinements} refinements, "
            f"certified (margin {des_x.certificate.parametric_margin:.1e}, T_max bound "
            f"{des_x.settling_time_bound:.3f}); L^T = {np.array2string(des_x.L.T, precision=1)}; paper "
            f"L^T = {np.array2string(ex['L_fixed'].T, precision=1)}",
            ok=des_x.certificate.ok and abs(des_x.settling_time_bound - 1.75) < 1e-9,
        )
    )
    lmi_time = time.perf_counter() - t0

    # fixed-time observer in continuous time: the error equation (18) integrated to convergence (adaptive steps at
    # two tolerances: the results are step-converged when they agree), paper gains and ours
    scales = np.array([1e2, 1e3, 1e4, 1e6, 1e8, 1e10])
    cont = {}
    for label, L, d in (("paper L", ex["L_fixed"], dec_paper), ("our L", des_x.L, des_x.decomposition)):
        for rtol in (1e-8, 1e-10):
            cont[label, rtol] = [
                continuous_settling(d.Phi @ (s * xs), d, L, ex["mu_fixed"], "fixed", rtol=rtol) for s in scales
            ]
        fine, coarse = cont[label, 1e-10], cont[label, 1e-8]
        dT = max(abs(a["T"] - b["T"]) for a, b in zip(fine, coarse, strict=True))
        de = max(
            (abs(a["at_query"] - b["at_query"]) / a["at_query"] for a, b in zip(fine, coarse, strict=True)),
            key=lambda v: v if np.isfinite(v) else 0.0,
        )
        Tc = np.array([c["T"] for c in fine])
        e175 = np.array([c["at_query"] for c in fine])
        claims.append(
            dict(
                claim=f"fixed-time ({label}), continuous time: ||e(1.75)|| <= 2e-4 and settling within "
                f"T_max = 1.75 for x(0) = 1e2..1e10 x* (the paper: 1e2, 1e3, 1e4)",
                paper="||e(1.75)|| <= 2e-4 for 1e2, 1e3, 1e4 x*; T_max <= 1.75 for every x(0)",
                ours="time to ||x - xhat|| <= 2e-4 for good: "
                + ", ".join(f"{s:.0e}: {v:.3f}" for s, v in zip(scales, Tc, strict=True))
                + " s; ||e(1.75)|| = "
                + ", ".join("<2e-6" if not np.isfinite(v) else f"{v:.1e}" for v in e175),
                measured="continuous error (18), Dormand-Prince 5(4) with rtol 1e-10 (rtol 1e-8: times differ by at "
                f"most {dT:.4f} s, ||e(1.75)|| by at most {de:.0e} relative). "
                "The settling time is bounded uniformly (fixed time) but by ~2.3 s, not by 1.75",
                ok=bool(np.all(Tc <= 1.75)),
            )
        )
    # the sampled observer (implicit injection) at the step the test used before: its numerical damping makes the
    # claim pass at a coarse step; at fine steps it misses the bound like the continuous error
    sampled = {}
    for hh in (5e-3, 1e-3) if fast else (5e-3, 1e-3, 5e-4, 2.5e-4, 1.25e-4):
        obs = ILFObserver(A, C, ex["L_fixed"], ex["mu_fixed"], "fixed", dt=hh, B=B, decomposition=dec_paper)
        t, norms = run_ilf_errors(obs, 1e4 * xs[None], 1.75)
        sampled[hh] = norms[-1, 0]
    e_cont = cont["paper L", 1e-10][2]["at_query"]
    claims.append(
        dict(
            claim="fixed-time (paper L), x(0) = 1e4 x*: ||e(1.75)|| <= 2e-4 judged at a sampled step",
            paper="||e(1.75)|| <= 2e-4",
            ours=", ".join(f"h = {k:g}: {v:.1e}" for k, v in sampled.items()) + f"; continuous {e_cont:.3e}",
            measured="sampled observer (exact prediction + implicit-Euler injection): at h >= 1 ms its numerical "
            "damping meets the bound by 13 orders of magnitude; at finer steps its error is of the continuous "
            "value's order and misses the bound too, without converging to it yet (from this error the injection "
            "gain times h stays far above 1 for most of the interval; from x* the sampled error converges at first "
            "order, tests/test_ilf.py)",
            ok=bool(e_cont <= 2e-4),
        )
    )
    runs = {label: cont[label, 1e-10] for label in ("paper L", "our L")}

    # finite-time observer: from 1e3 x* (and the growth of its convergence time)
    obs_f = ILFObserver(A, C, ex["L_finite"], ex["mu_finite"], "finite", dt=h, B=B, decomposition=dec_paper)
    t, norms_big = run_ilf_errors(obs_f, 1e3 * xs, 2.0)
    e175 = norms_big[int(round(1.75 / h)), 0]
    claims.append(
        dict(
            claim="finite-time: ||e(1.75)|| >= 100 for x(0) = 1e3 x*",
            paper=">= 100",
            ours=f"{e175:.3g} (h = {h})",
            measured=f"||e(1.75)|| = {e175:.3g}",
            ok=bool(e175 >= 100),
        )
    )
    h_long = 2e-3
    grow_scales = np.array([1e-1, 1.0, 3.0]) if fast else np.array([1e-1, 1.0, 3.0, 1e1])
    obs_long = ILFObserver(A, C, ex["L_finite"], ex["mu_finite"], "finite", dt=h_long, B=B, decomposition=dec_paper)
    t_long, norms_long = run_ilf_errors(obs_long, grow_scales[:, None] * xs, 8.0 if fast else 25.0)
    Tc_f = convergence_time(t_long, norms_long, 1e-3)
    claims.append(
        dict(
            claim="finite-time: settling time grows with the initial error (Theorem 6: T <= 3 V(e0)^(1/3))",
            measured="time to ||e|| <= 1e-3 from "
            + ", ".join(f"{s:g}" for s in grow_scales)
            + " x*: "
            + ", ".join(f"{v:.2f}" for v in Tc_f)
            + f" s (h = {h_long}); from 1e2 x* it has not converged "
            "after 20 s (||e|| ~ 1e6 and growing: the injection weakens as rho^-r_i at large errors)",
            ok=bool(np.all(np.isfinite(Tc_f)) and np.all(np.diff(Tc_f) > 0)),
        )
    )

    # Fig. 1: real plant, u = sin t, x(0) = 0.1 (1, -1, 1, -1, 1), xhat(0) = 0
    obs_fig1 = ILFObserver(A, C, ex["L_finite"], ex["mu_finite"], "finite", dt=h, B=B, decomposition=dec_paper)
    t1, x, xh = run_real_plant(obs_fig1, 0.1 * xs, 1.5)
    e1 = np.linalg.norm(x - xh, axis=1)
    x_at_1 = np.linalg.norm(x[int(round(1.0 / h))])
    claims.append(
        dict(
            claim="Fig. 1: ||x(1)|| ~ 1e7 for x(0) = 0.1 (1,-1,1,-1,1), u = sin t",
            paper="~1e7",
            ours=f"{x_at_1:.3g}",
            measured=f"||x(1)|| = {x_at_1:.3g} (largest eigenvalue of A is "
            f"{np.max(np.linalg.eigvals(A).real):.2f}, so ||x(1)|| ~ 1e7 does not follow from the printed A)",
            ok=bool(1e6 <= x_at_1 <= 1e8),
        )
    )
    Tc1 = convergence_time(t1, e1[:, None], 1e-5)[0]
    claims.append(
        dict(
            claim="Fig. 1: the finite-time observer converges (real plant, x(0) = 0.1 x*-like)",
            measured=f"||e|| <= 1e-5 from t = {Tc1:.3f} s; ||e(1.5)|| = {e1[-1]:.1e} (float resolution "
            f"of x - xhat with ||x(1.5)|| = {np.linalg.norm(x[-1]):.1e})",
            ok=bool(np.isfinite(Tc1)),
        )
    )

    if out_dir is not None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(1, 3, figsize=(15, 4))
        axes[0].semilogy(t1, np.maximum(e1, 1e-300))
        axes[0].set(title="001 Fig. 1: finite-time observer, real plant", xlabel="t [s]", ylabel="||x - xhat||")
        for label, runs_l in runs.items():
            axes[1].semilogx(scales, [c["T"] for c in runs_l], "o-", label=f"{label} (continuous time)")
        axes[1].axhline(1.75, color="k", lw=0.5, label="T_max = 1.75")
        axes[1].set(title="001: fixed-time observer, time to ||x - xhat|| <= 2e-4", xlabel="x(0) / x*", ylabel="s")
        axes[1].legend(fontsize=7)
        for j, s in enumerate(grow_scales):
            axes[2].semilogy(t_long, np.maximum(norms_long[:, j], 1e-300), label=f"x(0) = {s:g} x*")
        axes[2].semilogy(t[: norms_big.shape[0]], norms_big[:, 0], label="x(0) = 1e3 x* (h = 1e-3)")
        axes[2].set(title="001: finite-time observer, growing settling time", xlabel="t [s]", ylim=(1e-20, 1e10))
        axes[2].legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(out_dir / "lopez_ramirez2016.png", dpi=120)
        plt.close(fig)
    claims.append(dict(claim="(timing) LMI designs", measured=f"{lmi_time:.1f} s", ok=True))
    return claims


# ----------------------------------------------------------------------------------------------------------------
# Wetzlinger et al., section 6
# ----------------------------------------------------------------------------------------------------------------


def rk4(f, x: np.ndarray, u: float, h: float, substeps: int = 20) -> np.ndarray:
    """``substeps`` classical Runge-Kutta steps of ``x' = f(x, u)`` over ``h`` (the 'continuous' plant)."""
    dt = h / substeps
    for _ in range(substeps):
        k1 = f(x, u)
        k2 = f(x + 0.5 * dt * k1, u)
        k3 = f(x + 0.5 * dt * k2, u)
        k4 = f(x + dt * k3, u)
        x = x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


def system_73(x, u):
    """System (73): ``x1' = x2, x2' = x3 + sin(x1) u, x3' = -sin(x2) u``."""
    return np.array([x[1], x[2] + np.sin(x[0]) * u, -np.sin(x[1]) * u])


def system_4th(x, u):
    """The fourth-order example: ``x2' = x3 - sin(x1) u, x3' = x4 - sin(x2) u, x4' = -sin(x3) u`` (unknown)."""
    return np.array([x[1], x[2] - np.sin(x[0]) * u, x[3] - np.sin(x[1]) * u, -np.sin(x[2]) * u])


def simulate_plant(f, x0, h: float, T: float, u: float = 1.0) -> np.ndarray:
    """Samples ``x(t_k)``, ``k = 0..K``, of the continuous plant (RK4 with 20 substeps per sample)."""
    K = int(round(T / h))
    X = np.empty((K + 1, len(x0)))
    X[0] = x0
    for k in range(K):
        X[k + 1] = rk4(f, X[k], u, h)
    return X


def sigma3_observers(h: float = 0.01, p1: float = 30.0, mu: float = 1.0):
    """The three observers of section 6 as step functions ``xhat_{k+1} = step(xhat_k, y_k)`` plus Sigma2 itself.

    Sigma1: dead-beat (all eigenvalues at 0), Ackermann gain, no model terms (74). Sigma2: observer (75), mapping
    (15), saturated model terms (77)-(78) with level 1, Ackermann gain (35) (not the printed (79)-(82)). Sigma3:
    Luenberger observer of the ZOH linearisation (84)-(85) with the triple eigenvalue 0.1.
    """
    sig2 = DiscreteTimeHOSM(
        3,
        h,
        p1,
        mu,
        "semi-implicit",
        gamma=[None, lambda xi, u: np.sin(xi[..., 0]) * u, lambda xi, u: -np.sin(xi[..., 1]) * u],
        L_gamma=[np.inf, 1.0, 1.0],
    )
    A = sig2.A
    l0 = sig2.gain(0.0)
    Abar = np.array([[1 + h * h / 2, h, h * h / 2], [h, 1.0, h], [-h * h / 2, -h, 1 - h * h / 2]])  # (85)
    l3 = ackermann_observer_gain(Abar, [1.0, 0.0, 0.0], [0.1, 0.1, 0.1])
    return {
        "Sigma1": lambda x, y: A @ x + l0 * (y - x[0]),
        "Sigma3": lambda x, y: Abar @ x + l3 * (y - x[0]),
    }, sig2


def simulate_wetzlinger_third_order(h: float = 0.01, T: float = 10.0) -> dict:
    r"""Section 6, system (73): errors :math:`\sigma_k = \xi_k - \hat\xi_k` of Sigma1, Sigma2, Sigma3, ``(K, 3)``."""
    X = simulate_plant(system_73, [np.pi / 8, 0.0, 0.0], h, T)
    K = X.shape[0] - 1
    linear, sig2 = sigma3_observers(h)
    errors = {}
    for name, step in linear.items():
        xh = np.zeros(3)
        E = np.empty((K, 3))
        for k in range(K):
            E[k] = X[k] - xh
            xh = step(xh, X[k, 0])
        errors[name] = E
    sig2.reset(np.zeros(1))  # the paper starts every observer at xi_0 = 0
    E = np.empty((K, 3))
    for k in range(K):
        E[k] = X[k] - sig2.estimate[0]
        sig2.update(X[k, :1], 1.0)
    errors["Sigma2"] = E
    errors["t"] = np.arange(K) * h
    errors["x"] = X[:K]
    errors["stability_margin"] = sig2.stability_margin()
    return errors


def simulate_wetzlinger_fourth_order(h: float = 0.01, T: float = 10.0, x0=(0.0, 0.0, 0.0, np.pi / 8)) -> dict:
    """The fourth-order example (p1 = 40, mu = 10): errors ``(K, 4)``; channel 4's ``-sin(x3) u`` unknown."""
    X = simulate_plant(system_4th, list(x0), h, T)
    K = X.shape[0] - 1
    obs = DiscreteTimeHOSM(
        4,
        h,
        40.0,
        10.0,
        "semi-implicit",
        gamma=[None, lambda xi, u: -np.sin(xi[..., 0]) * u, lambda xi, u: -np.sin(xi[..., 1]) * u, None],
        L_gamma=[np.inf, 1.0, 1.0, 0.0],
    )
    obs.reset(np.zeros(1))  # xi_0 = 0
    E = np.empty((K, 4))
    for k in range(K):
        E[k] = X[k] - obs.estimate[0]
        obs.update(X[k, :1], 1.0)
    return {"t": np.arange(K) * h, "x": X[:K], "errors": E}


def band(errors: np.ndarray, t: np.ndarray, after: float) -> np.ndarray:
    """``max |sigma_i|`` over ``t >= after`` (the band the paper reads off its figures)."""
    return np.abs(errors[t >= after]).max(axis=0)


def wetzlinger_fig2(alphas, mapping: str, eps: float = 1e-6, K: int = 600) -> tuple[float, np.ndarray]:
    r"""Fig. 2: practical convergence steps :math:`k_\varepsilon` (:math:`\|e_k\| \le \varepsilon` for all
    :math:`k \ge k_\varepsilon`) of the unperturbed error (22)-(23), ``n = 2``, ``h = 1``, ``mu = 1``, from
    :math:`e_0 = (\alpha, \alpha)`, with ``p1`` chosen per mapping so that :math:`\max z_n = 2/3`.

    The paper prints neither :math:`\varepsilon` nor the range of :math:`\alpha`; ``eps`` and ``alphas`` are ours.
    Returns ``(h p1, k_eps)``, ``k_eps`` of shape ``alphas.shape``.
    """
    n, h, mu = 2, 1.0, 1.0
    hp = rate_for_max_eigenvalue(2.0 / 3.0, n, mu, mapping)
    alphas = np.asarray(alphas, dtype=float)
    E = np.repeat(alphas[:, None], n, axis=1)
    above = np.empty((K + 1, alphas.size), dtype=bool)
    above[0] = np.linalg.norm(E, axis=1) > eps
    for k in range(K):
        E = canonical_error_step(E, h, hp / h, mu, mapping)
        above[k + 1] = np.linalg.norm(E, axis=1) > eps
    if np.any(above[-1]):
        raise RuntimeError(f"expected convergence within {K} steps, actual value: not reached for some alpha")
    last = np.array([np.flatnonzero(col)[-1] + 1 if col.any() else 0 for col in above.T])
    return hp, last


def reproduce_wetzlinger(out_dir: Path | None, T: float = 10.0) -> list[dict]:
    res = simulate_wetzlinger_third_order(T=T)
    t = res["t"]
    b = {name: band(res[name], t, 1.0) for name in ("Sigma1", "Sigma2", "Sigma3")}
    r1, r3 = b["Sigma1"][2] / b["Sigma2"][2], b["Sigma3"][2] / b["Sigma2"][2]
    claims = [
        dict(
            claim="Sigma2 drives sigma_3 to a band |sigma_3| < 2e-3",
            paper="< 2e-3",
            ours=f"{b['Sigma2'][2]:.2e}",
            measured=f"max |sigma_3| for t >= 1 s: {b['Sigma2'][2]:.2e}",
            ok=bool(b["Sigma2"][2] < 2e-3),
        ),
        dict(
            claim="with Sigma1 and Sigma3 the band of sigma_3 is ~500 times larger",
            paper="~500",
            ours=f"{r1:.0f} (Sigma1), {r3:.0f} (Sigma3)",
            measured=f"ratios {r1:.0f} (Sigma1) and {r3:.0f} "
            f"(Sigma3); bands {b['Sigma1'][2]:.2f}, {b['Sigma3'][2]:.2f}",
            ok=bool(200 <= r1 <= 1000 and 200 <= r3 <= 1000),
        ),
        dict(
            claim="p1 = 30, mu = 1, h = 0.01 fulfil the stability condition (71)",
            paper=f"h p1 = 0.3 > (2 - 0.9972)/(3 cbrt(2)) = {(2 - 0.9972) / (3 * 2 ** (1 / 3)):.4f} ((71) as printed)",
            ours=f"h p1 = 0.3 < {stability_threshold(3, 1.0):.4f} (derived); z_max = "
            f"{max_eigenvalue(3, 0.01, 30.0, 1.0):.4f} > z* = {proven_eigenvalue_bound(3):.7f}",
            measured=f"z* - z_max = {res['stability_margin']:.3f}: outside the proven region ((71) reads 2 - 2 z* "
            "where inverting (51) gives 2/z* - 2); the observer converges nonetheless (the condition is sufficient)",
            ok=bool(res["stability_margin"] >= 0),
        ),
    ]
    # Section 5: the thresholds derived from the Lyapunov analysis (z* = first root of det M(z), then (51)/(52))
    printed = {
        (2, "semi-implicit"): ("(63)", (np.sqrt(2.0) - 1.0) / 2.0),
        (2, "matching"): ("(64)", np.log(2.0) / 4.0),
        (3, "semi-implicit"): ("(71)", (2.0 - 0.9972) / (3.0 * 2.0 ** (1 / 3))),
        (3, "matching"): ("(72)", -2.0 / (3.0 * 2.0 ** (1 / 3)) * np.log(0.498582)),
    }
    z_star = {n: proven_eigenvalue_bound(n) for n in (2, 3)}
    claims.append(
        dict(
            claim="Section 5: the proven eigenvalue bound z* ((61)-(62), (69)-(70)), from det M(z) = 0",
            paper="n = 2: 1/sqrt2 = 0.7071068; n = 3: 0.498582",
            ours=f"n = 2: {z_star[2]:.7f}; n = 3: {z_star[3]:.7f}",
            measured="first positive root of det(P - A_o(z)^T P A_o(z)), P from (46) with the paper's Q (59), (67)",
            ok=bool(abs(z_star[2] - 2**-0.5) < 1e-9 and abs(z_star[3] - 0.498582) < 1e-6),
        )
    )
    derived = {key: stability_threshold(key[0], 1.0, key[1]) for key in printed}
    claims.append(
        dict(
            claim="Section 5: smallest h p1 proven stable, mu = 1 ((63), (64), (71), (72))",
            paper=", ".join(f"{eq} {v:.4f}" for eq, v in printed.values()),
            ours=", ".join(f"{printed[k][0]} {v:.4f}" for k, v in derived.items()),
            measured="z_max of (51) / corrected (52) = z*; (71) as printed differs (2 - 2z* for 2/z* - 2); (72) "
            "agrees with (52) only when (52) carries the factor n/(n-1)",
            ok=bool(all(abs(derived[k] - printed[k][1]) < 1e-5 for k in printed)),
        )
    )
    alphas = np.logspace(-6, 14, 21)
    fig2 = {m: wetzlinger_fig2(alphas, m) for m in ("semi-implicit", "matching")}
    big = {m: wetzlinger_fig2(np.array([1e30, 1e60, 1e100]), m)[1] for m in fig2}
    claims.append(
        dict(
            claim="Fig. 2 (n = 2, h = 1, mu = 1, max z = 2/3, e0 = (alpha, alpha)): the practical convergence time "
            "of both mappings has an upper bound independent of alpha",
            paper="bounded (figure only; epsilon and the alpha range are not printed)",
            ours="; ".join(
                f"{m} (h p1 = {hp:.4f}): at most {k.max()} steps for alpha in [1e-6, 1e14], {big[m].tolist()} "
                "at 1e30, 1e60, 1e100"
                for m, (hp, k) in fig2.items()
            ),
            measured="steps to ||e_k|| <= 1e-6 for good, per decade of alpha: "
            + "; ".join(f"{m}: {k.tolist()}" for m, (hp, k) in fig2.items())
            + ". The matching mapping is dead-beat (2 steps) for large errors; the semi-implicit one still grows, by "
            "3 steps from 1e14 to 1e100: bounded over any practical range, not strictly",
            ok=bool(all(k.max() <= 40 for _, k in fig2.values()) and max(big["semi-implicit"]) <= 40),
        )
    )
    four = simulate_wetzlinger_fourth_order(T=T)
    b4 = band(four["errors"], four["t"], 1.0)
    claims.append(
        dict(
            claim="4th-order example: precision from ~1e-7 (first state) to ~0.4 (last state)",
            paper="~1e-7 ... ~0.4",
            ours=f"{b4[0]:.1e} ... {b4[-1]:.1e}",
            measured="max |sigma_i| for t >= 1 s: "
            + ", ".join(f"{v:.1e}" for v in b4)
            + " (x0 = (0, 0, 0, pi/8): the printed x0 lost one entry)",
            ok=bool(b4[0] <= 1e-7 and b4[-1] <= 0.4 and np.all(np.diff(b4) > 0)),
        )
    )
    if out_dir is not None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(2, 4, figsize=(16, 7))
        axes[0, 0].plot(t, res["x"])
        axes[0, 0].set(title="003 (73): states", xlabel="t [s]")
        for i in range(3):
            for name in ("Sigma1", "Sigma2", "Sigma3"):
                axes[0, i + 1].semilogy(t, np.abs(res[name][:, i]) + 1e-16, label=name, lw=0.8)
            axes[0, i + 1].set(title=f"|sigma_{i + 1}|", xlabel="t [s]")
            axes[0, i + 1].legend(fontsize=7)
        for i in range(4):
            axes[1, i].semilogy(four["t"], np.abs(four["errors"][:, i]) + 1e-16, lw=0.8)
            axes[1, i].set(title=f"4th order: |sigma_{i + 1}|", xlabel="t [s]")
        fig.tight_layout()
        fig.savefig(out_dir / "wetzlinger.png", dpi=120)
        plt.close(fig)
        fig, ax = plt.subplots(figsize=(6, 4))
        for m, (_hp, k) in fig2.items():
            ax.semilogx(alphas, k, "o-", label=f"({'15' if m == 'semi-implicit' else '16'}) {m}")
        ax.set(title="003 Fig. 2: steps to ||e|| <= 1e-6", xlabel="alpha (e0 = (alpha, alpha))", ylabel="k_eps")
        ax.legend()
        fig.tight_layout()
        fig.savefig(out_dir / "wetzlinger_fig2.png", dpi=120)
        plt.close(fig)
    return claims


# ----------------------------------------------------------------------------------------------------------------
# The reproductions kept in scripts of their own
# ----------------------------------------------------------------------------------------------------------------


def _from_script(filename: str, function: str):
    """The runner ``function(out_dir, fast)`` of ``scripts/<filename>``, loaded when first called (None when the
    script is absent)."""

    def run(out_dir: Path | None, fast: bool) -> list[dict] | None:
        path = Path(__file__).with_name(filename)
        if not path.exists():
            return None
        name = path.stem
        if name not in sys.modules:
            spec = importlib.util.spec_from_file_location(name, path)
            sys.modules[name] = module = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(module)
        return getattr(sys.modules[name], function)(out_dir, fast)

    return run


#: ``--papers`` choice -> (citation, runner); a runner takes the figure directory (or None) and ``fast`` and
#: returns the claims as dicts with ``claim``, ``measured`` and ``ok`` (or None when its script is absent), and
#: optionally ``paper`` (the paper's number) and ``ours`` (the number measured here), printed when present.
PAPERS = {
    "efimov2017": (
        "Efimov, Polyakov, Levant and Perruquetti 2017",
        _from_script("reproduce_efimov2017.py", "reproduce_efimov2017"),
    ),
    "levant2005": (
        "Levant 2003, 2005 (r-sliding accuracy)",
        _from_script("reproduce_slides_finite_time.py", "reproduce_levant2005"),
    ),
    "angulo2012": (
        "Angulo, Fridman and Levant 2012 (slides' Furuta model)",
        _from_script("reproduce_slides_finite_time.py", "reproduce_angulo2012"),
    ),
    "angulo2012-mujoco": (
        "Angulo, Fridman and Levant 2012 (MuJoCo Furuta pendulum)",
        _from_script("reproduce_slides_finite_time.py", "reproduce_angulo2012_mujoco"),
    ),
    "lopez-ramirez2016": (
        "Lopez-Ramirez, Polyakov, Efimov and Perruquetti 2016",
        lambda out, fast: reproduce_lopez_ramirez2016(out, fast=fast),
    ),
    "wetzlinger": (
        "Wetzlinger, Reichhartinger and Horn",
        lambda out, fast: reproduce_wetzlinger(out),
    ),
    "strong-detectability": (
        "Fridman's slides: observer for strongly detectable systems (Fridman, Davila and Levant 2011; Moreno 2001)",
        _from_script("reproduce_slides_unknown_inputs.py", "reproduce_strong_detectability"),
    ),
    "functional-uio": (
        "Fridman's slides: functional unknown-input observers (Angulo, Fridman and Moreno 2014)",
        _from_script("reproduce_slides_unknown_inputs.py", "reproduce_functional_uio"),
    ),
    "left-inverse": (
        "Fridman's slides: static left inverse (Bejarano, Fridman and Poznyak 2009)",
        _from_script("reproduce_slides_unknown_inputs.py", "reproduce_left_inverse"),
    ),
    "galvan-guerra2017": (
        "Galvan-Guerra, Fridman and Davila 2017 (cascaded HOSM observer for LTV systems; our example)",
        _from_script("reproduce_slides_ltv.py", "reproduce_galvan_guerra2017"),
    ),
    "kratz-liebscher1998": (
        "Kratz and Liebscher 1998 (LTV strong observability; the slides' plants)",
        _from_script("reproduce_slides_ltv.py", "reproduce_kratz_liebscher1998"),
    ),
    "utkin": (
        "Utkin 1992 (Fridman's slides, section 1: simple sliding-mode observer)",
        _from_script("reproduce_slides_conventional.py", "reproduce_utkin"),
    ),
    "drakunov-utkin": (
        "Drakunov 1992; Drakunov and Utkin 1995 (step-by-step observer)",
        _from_script("reproduce_slides_conventional.py", "reproduce_drakunov_utkin"),
    ),
    "walcott-zak": (
        "Walcott and Zak 1987; Edwards and Spurgeon 1994",
        _from_script("reproduce_slides_conventional.py", "reproduce_walcott_zak"),
    ),
    "hautus-uio": (
        "Hautus 1983; Darouach, Zasadzinski and Xu 1994",
        _from_script("reproduce_slides_conventional.py", "reproduce_hautus_uio"),
    ),
    "furuta-unknown-input": (
        "Walcott-Zak observer and UIO on the MuJoCo Furuta pendulum",
        _from_script("reproduce_slides_conventional.py", "reproduce_furuta"),
    ),
}


def _print(paper: str, claims: list[dict] | None) -> None:
    print(f"\n=== {PAPERS[paper][0]} ===")
    if claims is None:
        print("pending (its script is not present yet)")
        return
    for c in claims:
        print(f"[{'reproduced' if c['ok'] else 'DIFFERS'}] {c['claim']}")
        for key in ("paper", "ours", "measured"):  # paper and ours are optional
            if c.get(key) is not None:
                print(f"        {key + ':':<9} {c[key]}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    parser.add_argument("--out", default="outputs/papers", help="directory for the figures")
    parser.add_argument("--papers", nargs="+", default=list(PAPERS), choices=list(PAPERS))
    parser.add_argument("--fast", action="store_true", help="shorter horizons")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for paper in args.papers:
        t0 = time.perf_counter()
        claims = PAPERS[paper][1](out, args.fast)
        _print(paper, claims)
        print(f"({time.perf_counter() - t0:.1f} s)")
    print(f"\nfigures in {out.resolve()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
