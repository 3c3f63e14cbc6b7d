r"""Finite-time output-feedback stabilization of disturbed LTI systems with arbitrary-order sliding modes.

Fridman's slides, section 6, after Angulo, Fridman and Levant (2011, 2012): for

.. math:: \dot x = Ax + B\,[u + w],\qquad y = Cx,\qquad \|w(t)\| \le W_1\|x(t)\| + W_2,

1. a HOSM observer (:class:`~smo_gym.control.CascadedHOSMObserver`) reconstructs ``x`` in finite time when
   ``(A, C, B)`` is strongly observable;
2. by controllability there is an output :math:`\zeta = Kx \in \mathbb R^m` (not the measured one) with vector
   relative degree ``(r_1, ..., r_m)``, :math:`\sum r_i = n` (:func:`sliding_output`), so the system is ``m``
   chains of integrators :math:`\zeta_i^{(r_i)} = F_i x + G_i(u + w)`;
3. non-homogeneous HOSM controllers
   :math:`v_i = -\alpha_i(k_{i,1}\|x\| + k_{i,2})\,H_{r_i}(\zeta_i, \dot\zeta_i, \ldots, \zeta_i^{(r_i-1)})`
   (:func:`quasi_continuous_hosm`, :func:`nested_hosm`, :func:`hosm_control`) force every chain to zero in
   finite time, and with it the whole state (:class:`FiniteTimeStabilizer`).

The state-proportional part :math:`k_{i,1}\|x\|` of the gain is what dominates a disturbance growing with the
state (and the drift :math:`F_i x` when it is not cancelled); with :math:`k_{i,1} = 0` the controllers are
Levant's homogeneous ones, exact only for bounded perturbations.

Sampled at step :math:`\tau`, an ``r``-sliding homogeneous controller keeps
:math:`|\sigma^{(i)}| \le \mu_i\tau^{r-i}` (Levant 2003, 2005): on the chains of the stabilizer the state residual
is :math:`O(\tau)` (it contains :math:`\zeta^{(r-1)}`).

References
----------
.. [Lev01] A. Levant, "Universal single-input-single-output (SISO) sliding-mode controllers with finite-time
   convergence", IEEE Trans. Automatic Control 46(9), 2001.
.. [Lev03] A. Levant, "Higher-order sliding modes, differentiation and output-feedback control", Int. J. Control
   76(9/10), 2003.
.. [Lev05] A. Levant, "Quasi-continuous high-order sliding-mode controllers", IEEE Trans. Automatic Control
   50(11), 2005.
.. [AFL11] M. T. Angulo, L. Fridman and A. Levant, "Robust exact finite-time output based control using high-order
   sliding modes", Int. J. Systems Science 42(11), 2011.
.. [AFL12] M. T. Angulo, L. Fridman and A. Levant, "Output-feedback finite-time stabilization of disturbed LTI
   systems", Automatica 48(4), 2012.
.. [Fri] L. Fridman, "Sliding Mode Observers: Theory and Practice", lecture slides, section 6.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._validation import (
    DivergenceError,
    as_real_array,
    check_bool,
    check_choice,
    check_int_in_range,
    check_nonnegative,
    check_nonnegative_array,
    check_positive,
    check_positive_array,
)
from .controllers import StateFeedback
from .plants import RANK_TOL, _unit, relative_degrees

__all__ = [
    "DEFAULT_BETAS",
    "FiniteTimeStabilizer",
    "RelativeDegreeError",
    "SlidingOutput",
    "hosm_control",
    "nested_hosm",
    "quasi_continuous_hosm",
    "settling_time",
    "simulate_chain",
    "sliding_output",
]

#: Levant's coefficients ``(beta_1, ..., beta_{r-1})`` for ``r <= 4``, the same for the nested (Levant 2001, 2003)
#: and the quasi-continuous (Levant 2005) controllers; higher orders need them passed explicitly.
DEFAULT_BETAS = {1: (), 2: (1.0,), 3: (1.0, 2.0), 4: (0.5, 1.0, 3.0)}

KINDS = ("quasi-continuous", "nested")


class RelativeDegreeError(ValueError):
    """No output with the vector relative degree the construction needs; the message names the failed condition."""


def _derivatives(value) -> np.ndarray:
    arr = as_real_array("derivatives", value)
    if arr.ndim == 0 or arr.shape[-1] < 1:
        raise ValueError(
            f"expected derivatives with shape (..., r), r >= 1 (sigma, sigma', ..., sigma^(r-1) on the last axis), "
            f"actual value: shape {arr.shape}"
        )
    if not np.all(np.isfinite(arr)):  # the 0/0 = 0 convention would turn a NaN measurement into zero control
        raise ValueError(f"expected finite derivatives, actual value: {arr!r:.120}")
    return arr


def _betas(betas, r: int) -> np.ndarray:
    if betas is None:
        if r not in DEFAULT_BETAS:
            raise ValueError(
                f"expected betas (r - 1 = {r - 1} positive numbers) for relative degree r = {r} (defaults exist for "
                f"r <= {max(DEFAULT_BETAS)}), actual value: None"
            )
        return np.asarray(DEFAULT_BETAS[r], dtype=float)
    b = np.atleast_1d(check_positive_array("betas", betas)) if r > 1 else as_real_array("betas", betas).reshape(-1)
    if b.shape != (r - 1,):
        raise ValueError(f"expected {r - 1} betas for relative degree r = {r}, actual value: shape {b.shape}")
    return b


def _ratio(phi, N):
    """``phi / N`` with ``0 / 0 = 0`` (the controllers' value at the origin)."""
    if np.ndim(N) == 0:
        return float(phi / N) if N > 0 else 0.0
    out = np.zeros(np.broadcast_shapes(np.shape(phi), np.shape(N)))
    np.divide(phi, N, out=out, where=N > 0)
    return out


def quasi_continuous_hosm(derivatives, betas=None) -> np.ndarray:
    r"""Levant's (2005) quasi-continuous ``r``-sliding controller :math:`\Psi_{r-1,r} \in [-1, 1]`.

    The control is :math:`u = -\alpha\Psi_{r-1,r}`:

    .. math::
        \varphi_{0,r} = \sigma,\quad N_{0,r} = |\sigma|,\quad
        \Psi_{0,r} = \varphi_{0,r}/N_{0,r} = \mathrm{sign}\,\sigma,

        \varphi_{i,r} = \sigma^{(i)} + \beta_i N_{i-1,r}^{(r-i)/(r-i+1)}\Psi_{i-1,r},\quad
        N_{i,r} = |\sigma^{(i)}| + \beta_i N_{i-1,r}^{(r-i)/(r-i+1)},\quad \Psi_{i,r} = \varphi_{i,r}/N_{i,r}.

    For ``r = 2``: :math:`(\dot\sigma + |\sigma|^{1/2}\mathrm{sign}\,\sigma)/(|\dot\sigma| + |\sigma|^{1/2})`;
    ``r = 3``: :math:`[\ddot\sigma + 2(|\dot\sigma| + |\sigma|^{2/3})^{-1/2}(\dot\sigma + |\sigma|^{2/3}
    \mathrm{sign}\,\sigma)]/[|\ddot\sigma| + 2(|\dot\sigma| + |\sigma|^{2/3})^{1/2}]`. Continuous everywhere
    except at :math:`\sigma = \ldots = \sigma^{(r-1)} = 0`, where it is set to 0. Homogeneous of degree 0 under
    :math:`\sigma^{(i)} \mapsto \kappa^{r-i}\sigma^{(i)}`.

    Parameters
    ----------
    derivatives : array_like, shape (..., r)
        :math:`(\sigma, \dot\sigma, \ldots, \sigma^{(r-1)})` on the last axis (leading axes: a batch).
    betas : array_like, shape (r - 1,), optional
        :math:`\beta_1, \ldots, \beta_{r-1} > 0`; default :data:`DEFAULT_BETAS` (``r <= 4``).

    Returns
    -------
    ndarray, shape (...)
    """
    s = _derivatives(derivatives)
    return np.asarray(_quasi_continuous(s, _betas(betas, s.shape[-1])), dtype=float)


def _quasi_continuous(s: np.ndarray, b: np.ndarray) -> np.ndarray:
    r = s.shape[-1]
    phi, N = s[..., 0], np.abs(s[..., 0])
    for i in range(1, r):
        Psi = _ratio(phi, N)
        term = b[i - 1] * N ** ((r - i) / (r - i + 1))
        phi = s[..., i] + term * Psi
        N = np.abs(s[..., i]) + term
    return _ratio(phi, N)


def nested_hosm(derivatives, betas=None, q: float | None = None) -> np.ndarray:
    r"""Levant's (2001, 2003) nested ``r``-sliding controller :math:`\Psi_{r-1,r} \in \{-1, 0, 1\}`.

    .. math::
        \Psi_{0,r} = \mathrm{sign}\,\sigma,\qquad
        \Psi_{i,r} = \mathrm{sign}\big(\sigma^{(i)} + \beta_i N_{i,r}\Psi_{i-1,r}\big),\qquad
        N_{i,r} = \Big(\sum_{j=0}^{i-1}|\sigma^{(j)}|^{q/(r-j)}\Big)^{(r-i)/q}.

    With ``q = 12`` (``r = 4``): :math:`\mathrm{sign}\{\dddot\sigma + 3(\ddot\sigma^6 + \dot\sigma^4 +
    |\sigma|^3)^{1/12}\mathrm{sign}[\ddot\sigma + (\dot\sigma^4 + |\sigma|^3)^{1/6}\mathrm{sign}(\dot\sigma +
    0.5|\sigma|^{3/4}\mathrm{sign}\,\sigma)]\}`, the formula printed by Levant (2001).

    Parameters
    ----------
    derivatives : array_like, shape (..., r)
    betas : array_like, shape (r - 1,), optional
        Default :data:`DEFAULT_BETAS`.
    q : float, optional
        Any ``q > 0``; default the least common multiple of ``1..r`` (Levant's choice: 2, 6, 12).

    Returns
    -------
    ndarray, shape (...)
    """
    s = _derivatives(derivatives)
    r = s.shape[-1]
    q = float(math.lcm(*range(1, r + 1))) if q is None else check_positive("q", q)
    return _nested(s, _betas(betas, r), q)


def _nested(s: np.ndarray, b: np.ndarray, q: float) -> np.ndarray:
    r = s.shape[-1]
    a = np.abs(s)
    Psi = np.sign(s[..., 0])
    acc = np.zeros(s.shape[:-1])
    for i in range(1, r):
        acc = acc + a[..., i - 1] ** (q / (r - i + 1))
        Psi = np.sign(s[..., i] + b[i - 1] * acc ** ((r - i) / q) * Psi)
    return Psi


def hosm_control(
    derivatives,
    alpha,
    *,
    kind: str = "quasi-continuous",
    betas=None,
    state_norm=0.0,
    k1=0.0,
    k2=1.0,
) -> np.ndarray:
    r"""Non-homogeneous HOSM control :math:`u = -\alpha\,(k_1\|x\| + k_2)\,H_r(\sigma, \ldots, \sigma^{(r-1)})`.

    The gain of Angulo, Fridman and Levant (2011, 2012) (Fridman's slides, section 6): ``H_r`` is
    :func:`quasi_continuous_hosm` or :func:`nested_hosm`. With ``k1 = 0, k2 = 1`` it is Levant's homogeneous
    controller, which makes :math:`\sigma^{(r)} = u + h`, :math:`|h| \le C`, reach :math:`\sigma = \ldots =
    \sigma^{(r-1)} = 0` in finite time for ``alpha`` large enough; with :math:`|h| \le C_1\|x\| + C_2` the gain
    must grow with the state: :math:`\alpha k_1 > C_1`, :math:`\alpha k_2 > C_2` (with margins; Levant gives no
    closed form for the margin).

    Parameters
    ----------
    derivatives : array_like, shape (..., r)
    alpha : float
        ``> 0``.
    kind : {"quasi-continuous", "nested"}
    betas : array_like, optional
    state_norm : float or array_like, shape (...)
        :math:`\|x\|` (or its estimate): finite, ``>= 0``, of a shape that broadcasts to the batch.
    k1, k2 : float
        ``k1 >= 0``, ``k2 > 0``.

    Returns
    -------
    ndarray, shape (...)

    Raises
    ------
    TypeError, ValueError
        When ``derivatives`` or ``state_norm`` is not finite, ``state_norm`` is negative or of a shape that does
        not broadcast to the batch (a negative norm would flip the control's sign).
    """
    alpha = check_positive("alpha", alpha)
    k1 = check_nonnegative("k1", k1)
    k2 = check_positive("k2", k2)
    kind = check_choice("kind", kind, KINDS)
    norm = as_real_array("state_norm", state_norm)
    if not np.all(np.isfinite(norm) & (norm >= 0.0)):
        raise ValueError(f"expected state_norm >= 0 and finite, actual value: {state_norm!r:.120}")
    H = quasi_continuous_hosm(derivatives, betas) if kind == "quasi-continuous" else nested_hosm(derivatives, betas)
    try:
        fits = np.broadcast_shapes(norm.shape, np.shape(H)) == np.shape(H)
    except ValueError:
        fits = False
    if not fits:
        raise ValueError(
            f"expected state_norm of a shape that broadcasts to {np.shape(H)} (the batch of derivatives), actual "
            f"value: shape {norm.shape}"
        )
    return -alpha * (k1 * norm + k2) * H


def simulate_chain(control, z0, dt: float, t_final: float, *, disturbance=None, substeps: int = 8):
    r"""Sampled-data run of the chain of integrators :math:`\sigma^{(r)} = u + h(t)` under a sampled controller.

    ``u_k = control(z_k, t_k)`` is held over :math:`[t_k, t_k + \tau)`; ``h`` is held on ``substeps`` equal
    sub-intervals (its value at their midpoints), so the integration is exact for the piecewise-constant
    disturbance it applies (itself an admissible bounded disturbance).

    Parameters
    ----------
    control : callable
        ``control(z, t) -> u``, ``z`` of shape ``(..., r)``, ``u`` of shape ``(...)``.
    z0 : array_like, shape (..., r)
        :math:`(\sigma, \ldots, \sigma^{(r-1)})` at ``t = 0`` (leading axes: a batch of runs).
    dt, t_final : float
    disturbance : callable, optional
        ``h(t)`` for an array ``t``, same shape out (applied to every run of the batch).
    substeps : int

    Returns
    -------
    t : ndarray, shape (T,)
    z : ndarray, shape (T, ..., r)
    u : ndarray, shape (T, ...)
    """
    dt = check_positive("dt", dt)
    t_final = check_positive("t_final", t_final)
    z = np.array(as_real_array("z0", z0), dtype=float)
    if z.ndim == 0 or z.shape[-1] == 0 or not np.isfinite(z).all():
        raise ValueError(f"expected a finite z0 of shape (..., r) with r >= 1, actual value: {z!r:.80}")
    r = z.shape[-1]
    n_sub = check_int_in_range("substeps", substeps, 1, 10_000)
    h = dt / n_sub

    def chain_maps(step):
        Phi = np.zeros((r, r))
        for i in range(r):
            for j in range(i, r):
                Phi[i, j] = step ** (j - i) / math.factorial(j - i)
        Gam = np.array([step ** (r - i) / math.factorial(r - i) for i in range(r)])
        return Phi, Gam

    Phi, Gam = chain_maps(dt)
    Phi_h, Gam_h = chain_maps(h)
    # effect of the disturbance held on sub-interval j: Phi_h^(n_sub-1-j) Gam_h
    Ew = np.stack([np.linalg.matrix_power(Phi_h, n_sub - 1 - j) @ Gam_h for j in range(n_sub)], axis=-1)  # (r, n_sub)
    T = int(round(t_final / dt)) + 1
    t = np.arange(T) * dt
    if disturbance is None:
        Hw = np.zeros((T, n_sub))
    else:
        mids = t[:, None] + h * (np.arange(n_sub) + 0.5)
        Hw = np.asarray(disturbance(mids.reshape(-1)), dtype=float).reshape(T, n_sub)
    Z = np.zeros((T,) + z.shape)
    U = np.zeros((T,) + z.shape[:-1])
    for k in range(T):
        u = np.asarray(control(z, t[k]), dtype=float)
        Z[k], U[k] = z, u
        z = z @ Phi.T + u[..., None] * Gam + Ew @ Hw[k]
    return t, Z, U


def settling_time(t, err, tol) -> np.ndarray:
    r"""First time after which ``err`` stays ``<= tol`` (``inf`` if it does not at the last sample).

    Parameters
    ----------
    t : array_like, shape (T,)
    err : array_like, shape (T, ...)
    tol : float or array_like broadcasting with ``err[0]``

    Returns
    -------
    ndarray, shape (...)
    """
    t, err = as_real_array("t", t), as_real_array("err", err)
    if t.ndim != 1 or t.size == 0 or err.shape[:1] != t.shape:
        raise ValueError(f"expected t (T,) with T >= 1 and err (T, ...), actual value: shapes {t.shape}, {err.shape}")
    tol = as_real_array("tol", tol)
    if np.isnan(tol).any():
        raise ValueError(f"expected tol without NaN, actual value: {tol!r}")
    bad = ~(err <= tol)  # a NaN error is not settled
    out = np.full(bad.shape[1:], np.inf)
    ever = ~bad[-1]
    last_bad = bad.shape[0] - 1 - np.argmax(bad[::-1], axis=0)  # index of the last violation
    never_bad = ~bad.any(axis=0)
    idx = np.where(never_bad, 0, np.minimum(last_bad + 1, bad.shape[0] - 1))
    out[ever] = t[idx[ever]]
    return out


@dataclass(frozen=True)
class SlidingOutput:
    r"""A virtual output :math:`\zeta = Kx` with vector relative degree ``r`` w.r.t. ``u`` and :math:`\sum r_i = n`.

    .. math:: \zeta_i^{(j)} = k_iA^jx\ (j < r_i),\qquad \zeta^{(r)} = Fx + G(u + w),

    with :math:`F_i = k_iA^{r_i}`, :math:`G_i = k_iA^{r_i-1}B` (``G`` invertible) and the stack
    ``Z = T x`` of :math:`(\zeta_1, \ldots, \zeta_1^{(r_1-1)}, \zeta_2, \ldots)` (``T`` invertible).

    Attributes
    ----------
    K : ndarray, shape (m, n)
    degrees : ndarray of int, shape (m,)
    T : ndarray, shape (n, n)
    G : ndarray, shape (m, m)
    F : ndarray, shape (m, n)
    """

    K: np.ndarray
    degrees: np.ndarray
    T: np.ndarray
    G: np.ndarray
    F: np.ndarray

    def chains(self, x) -> list[np.ndarray]:
        """``[(zeta_i, ..., zeta_i^(r_i - 1)) for each i]`` from the state ``x`` of shape ``(..., n)``."""
        Z = np.asarray(x, dtype=float) @ self.T.T
        ends = np.cumsum(self.degrees)
        return [Z[..., e - r : e] for e, r in zip(ends, self.degrees, strict=True)]


def _controllability_output(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Rows ``k_i`` of Luenberger's controllable canonical form (one per input), or RelativeDegreeError."""
    n, m = B.shape
    if np.linalg.matrix_rank(B, tol=RANK_TOL * max(np.abs(B).max(), 1e-300)) < m:
        raise RelativeDegreeError(
            f"expected B with full column rank {m} (independent inputs) for a vector relative degree, actual value: "
            f"rank {np.linalg.matrix_rank(B)}"
        )
    cols, cols_unit, owner = [], [], []  # A^j b_i, and the same on its factors' scale for the rank decisions
    mu = np.zeros(m, dtype=int)
    for j in range(n):
        AjB, AjB_unit = np.linalg.matrix_power(A, j) @ B, np.linalg.matrix_power(_unit(A), j) @ _unit(B)
        for i in range(m):
            if j > 0 and mu[i] < j:  # A^j b_i depends on the earlier columns once A^(j-1) b_i did
                continue
            s = np.linalg.svd(np.column_stack(cols_unit + [AjB_unit[:, i]]), compute_uv=False)
            if s[-1] > RANK_TOL * max(s[0], 1.0) * 1e2 and len(cols) < n:
                cols.append(AjB[:, i])
                cols_unit.append(AjB_unit[:, i])
                owner.append(i)
                mu[i] += 1
    if len(cols) < n:
        raise RelativeDegreeError(
            f"expected a controllable pair (A, B) (controllability matrix of rank n = {n}) for an output with vector "
            f"relative degree summing to n, actual value: rank {len(cols)}"
        )
    order = np.argsort(np.array(owner), kind="stable")  # [b1, A b1, ..., b2, A b2, ...]
    Q = np.column_stack([cols[k] for k in order])
    Qinv = np.linalg.inv(Q)
    return Qinv[np.cumsum(mu) - 1]


def sliding_output(A, B, K=None) -> SlidingOutput:
    r"""The virtual output :math:`\zeta = Kx` of the stabilizer, built or checked (Angulo et al. 2012).

    Without ``K``: the last row of each block of :math:`Q^{-1}`,
    :math:`Q = [b_1, Ab_1, \ldots, A^{\mu_1-1}b_1, b_2, \ldots]` (Luenberger's controllable canonical form,
    controllability indices :math:`\mu_i`), which gives relative degrees :math:`r_i = \mu_i`,
    :math:`\sum r_i = n`. With ``K``: its vector relative degree is checked.

    Raises
    ------
    RelativeDegreeError
        ``(A, B)`` not controllable, ``B`` rank deficient, an output never reached by ``u``, a singular decoupling
        matrix ``G`` (no vector relative degree), or :math:`\sum r_i \ne n` (the zero dynamics of ``zeta`` would
        not be stabilized in finite time).
    """
    A = as_real_array("A", A)
    if A.ndim != 2 or A.shape[0] != A.shape[1]:
        raise ValueError(f"expected a square A, actual value: shape {A.shape}")
    n = A.shape[0]
    B = as_real_array("B", B)
    B = B[:, None] if B.ndim == 1 else B
    if B.ndim != 2 or B.shape[0] != n:
        raise ValueError(f"expected B with shape ({n}, q), actual value: shape {B.shape}")
    m = B.shape[1]
    if m == 0 or not (np.isfinite(A).all() and np.isfinite(B).all()):  # the SVDs below would fail unexplained
        raise ValueError(f"expected finite A and B with at least one input, actual value: A={A!r:.80}, B={B!r:.80}")
    if K is None:
        K = _controllability_output(A, B)
    else:
        K = np.atleast_2d(as_real_array("K", K))
        if K.shape != (m, n):
            raise ValueError(f"expected K with shape ({m}, {n}) (one output per input), actual value: shape {K.shape}")
    r = relative_degrees(A, K, B)
    if np.any(r == 0):
        raise RelativeDegreeError(
            f"expected every sliding output reached by the control (k_i A^j B != 0 for some j), actual value: "
            f"relative degrees {r.tolist()}"
        )
    G = np.vstack([K[i] @ np.linalg.matrix_power(A, r[i] - 1) @ B for i in range(m)])
    # rows k_i A^(r_i - 1) B on their factors' scale: rows with different r_i scale differently with A
    G_unit = np.vstack([_unit(K[i]) @ np.linalg.matrix_power(_unit(A), r[i] - 1) @ _unit(B) for i in range(m)])
    sG = np.linalg.svd(G_unit, compute_uv=False)
    if sG[-1] <= RANK_TOL * 1e2 * max(sG[0], 1e-300):
        raise RelativeDegreeError(
            f"expected a vector relative degree (decoupling matrix G = [k_i A^(r_i-1) B] invertible), actual value: "
            f"G singular (singular values {sG.tolist()}, relative degrees {r.tolist()})"
        )
    if int(r.sum()) != n:
        raise RelativeDegreeError(
            f"expected relative degrees summing to n = {n} (no zero dynamics, so that zeta = 0 means x = 0), "
            f"actual value: {r.tolist()} (sum {int(r.sum())})"
        )
    T = np.vstack([K[i] @ np.linalg.matrix_power(A, j) for i in range(m) for j in range(r[i])])
    F = np.vstack([K[i] @ np.linalg.matrix_power(A, r[i]) for i in range(m)])
    return SlidingOutput(K=K, degrees=r, T=T, G=G, F=F)


class FiniteTimeStabilizer(StateFeedback):
    r"""Output-feedback finite-time stabilization of :math:`\dot x = Ax + B(u + w)` (Angulo et al. 2011, 2012).

    .. math::
        Z = T\hat x,\qquad v_i = -\alpha_i\,(k_{i,1}\|\hat x\| + k_{i,2})\,
        H_{r_i}(\zeta_i, \ldots, \zeta_i^{(r_i-1)}),\qquad u = G^{-1}(v - F\hat x),

    with :math:`\hat x` from the HOSM ``observer`` and the virtual output of :func:`sliding_output`. Once the
    observer has converged, :math:`\zeta_i^{(r_i)} = (Gw)_i + v_i`: ``m`` chains of integrators with a
    perturbation bounded by :math:`\|G\|(W_1\|x\| + W_2)`, which the non-homogeneous gain dominates
    (:math:`\alpha_i k_{i,1} > \|G_i\|W_1`, :math:`\alpha_i k_{i,2} > \|G_i\|W_2`, with Levant's margins); every
    chain then reaches zero in finite time, and :math:`x = T^{-1}Z = 0`. With ``cancel_drift=False`` the law is
    :math:`u = G^{-1}v` and :math:`F x` joins the perturbation (covered by :math:`k_{i,1}` too).

    Sampled at :math:`\tau`: :math:`|\zeta_i^{(j)}| = O(\tau^{r_i - j})`, so :math:`\|x\| = O(\tau)`.

    Parameters
    ----------
    observer : CascadedHOSMObserver (or any observer with ``plant``, ``dt``, ``x_hat``, ``update``, ``advance``)
        Its plant's unknown input must be matched (``span D`` in ``span B``).
    alpha : float or array_like, shape (m,)
        ``> 0``, in the order of :attr:`sliding` ``.degrees``.
    k1 : float or array_like, shape (m,)
        ``>= 0``: the state-proportional part of the gain.
    k2 : float or array_like, shape (m,)
        ``> 0``.
    output : array_like, shape (m, n), optional
        The virtual output ``K`` (checked); default :func:`sliding_output`'s canonical one (``G`` unit
        upper-triangular).
    output_scale : float or array_like, shape (m,)
        ``c > 0``: the chains are :math:`c_i\zeta_i` (rows of ``K``, ``G``, ``F`` multiplied by ``c_i``).
        Levant's controllers need ``alpha`` above a threshold even without perturbation (a property of
        :math:`H_r` and the betas, not of the size of ``zeta``), while the physical control amplitude is
        :math:`\alpha_i(k_{i,1}\|x\| + k_{i,2})/c_i` and the perturbation condition
        :math:`\alpha_i k_{i,2} > c_i\|G_i\|W_2`: ``c`` lets a control just above the disturbance meet that
        threshold, and the sampled ripple (:math:`O(\tau)` times the physical amplitude) stay small.
    kind : {"quasi-continuous", "nested"}
    betas : array_like, optional
        For every chain (default :data:`DEFAULT_BETAS` of each ``r_i``).
    cancel_drift : bool
    t_start : float
        Before it ``u = 0`` (the observer converging; the slides' separation by waiting).

    Attributes
    ----------
    sliding : SlidingOutput
    sigma : list of ndarray
        The chains' estimated :math:`(\zeta_i, \ldots, \zeta_i^{(r_i-1)})` at the last step.

    Notes
    -----
    The slides print the example :math:`H_2` as ":math:`\zeta_i \leftarrow \dot\zeta_i + \beta|\zeta_i|^{1/2}
    \mathrm{sign}\,\zeta_i`" (text scan); read as Levant's nested 2-sliding controller
    :math:`H_2 = \mathrm{sign}(\dot\zeta + \beta|\zeta|^{1/2}\mathrm{sign}\,\zeta)`, which :func:`nested_hosm`
    gives for ``r = 2``. Two conditions the slides leave implicit, both measured on the slides' Furuta model
    (``tests/test_finite_time_control.py``, ``scripts/reproduce_slides_finite_time.py``):

    - the differentiator of the observer must be sized for the disturbance the state-dependent part produces
      (:math:`\|w\| \le W_1\|x\| + W_2` with the largest :math:`\|x\|` of the transient); with the bound sized for
      ``W2`` alone the loop is lost from 0.2 rad with ``W1 = 10`` whatever ``k1`` (the slides: "adapt the gain of
      the differentiator");
    - sampled, the ripple :math:`O(\tau)` grows with the gain and the gain with :math:`\|\hat x\|`: with
      :math:`\tau\,\alpha k_1/c` too large the two feed each other and the loop diverges (``alpha = 25``,
      ``c = 10``, ``tau = 1 ms``, no ``W1``, from 0.05 rad: ``k1 = 10`` converges, ``k1 = 40`` diverges); ``k1``
      must dominate ``W1`` with a moderate margin.
    """

    def __init__(
        self,
        observer,
        *,
        alpha,
        k1=0.0,
        k2=1.0,
        output=None,
        output_scale: float = 1.0,
        kind: str = "quasi-continuous",
        betas=None,
        cancel_drift: bool = True,
        t_start: float = 0.0,
    ):
        missing = [a for a in ("plant", "dt", "x_hat", "update", "advance") if not hasattr(observer, a)]
        if missing:
            raise TypeError(
                "expected an observer with plant, dt, x_hat, update and advance (e.g. CascadedHOSMObserver), actual "
                f"value: {type(observer).__name__} without {', '.join(missing)}"
            )
        self.observer = observer
        P = self.plant = observer.plant
        m = P.n_inputs
        Bw = np.linalg.pinv(P.B) @ P.D
        miss = np.linalg.norm(P.B @ Bw - P.D)
        if miss > 1e-9 * np.linalg.norm(P.D):  # relative to ||D||: a floor of 1 passed any unmatched D below 1e-9
            raise ValueError(
                "expected a matched unknown input (span D inside span B) for finite-time stabilization through u, "
                f"actual value: ||B B^+ D - D|| = {miss:.3g}"
            )
        base = sliding_output(P.A, P.B, output)

        def per_output(name, value, check):
            arr = np.broadcast_to(check(name, value), (m,)) if np.ndim(value) == 0 else check(name, value)
            if arr.shape != (m,):
                raise ValueError(f"expected {name} scalar or of shape ({m},), actual value: shape {arr.shape}")
            return np.array(arr, dtype=float)

        c = per_output("output_scale", output_scale, check_positive_array)
        self.sliding = SlidingOutput(
            K=c[:, None] * base.K,
            degrees=base.degrees,
            T=np.repeat(c, base.degrees)[:, None] * base.T,
            G=c[:, None] * base.G,
            F=c[:, None] * base.F,
        )

        self.alpha = per_output("alpha", alpha, check_positive_array)
        self.k1 = per_output("k1", k1, check_nonnegative_array)
        self.k2 = per_output("k2", k2, check_positive_array)
        self.kind = check_choice("kind", kind, KINDS)
        self.betas = [_betas(betas, int(r)) for r in self.sliding.degrees]
        self.cancel_drift = check_bool("cancel_drift", cancel_drift)
        self.t_start = check_nonnegative("t_start", t_start)
        self._Ginv = np.linalg.inv(self.sliding.G)
        self.K = None
        self.u = np.zeros(m)
        self.sigma = [np.zeros(int(r)) for r in self.sliding.degrees]

    def law(self, t: float) -> np.ndarray:
        """The control :math:`u_k` from the observer's current estimate.

        Raises
        ------
        DivergenceError
            When the control is not finite (an estimate so large that the gain overflows). Within :meth:`step` the
            observer has then taken the sample: :meth:`reset` before the next step.
        """
        x = self.observer.x_hat
        sigma = self.sliding.chains(x)
        if t < self.t_start:
            self.sigma = sigma
            return np.zeros(self.plant.n_inputs)
        nrm = math.hypot(*x)  # sqrt(x . x) overflows from ||x|| ~ 1.3e154, and 0 * inf = NaN with k1 = 0
        v = np.zeros(self.plant.n_inputs)
        with np.errstate(over="ignore", invalid="ignore"):  # a non-finite control is reported just below
            for i, (s, b) in enumerate(zip(sigma, self.betas, strict=True)):
                if self.kind == "quasi-continuous":
                    H = _quasi_continuous(s, b)
                else:
                    H = _nested(s, b, float(math.lcm(*range(1, s.shape[-1] + 1))))
                v[i] = -self.alpha[i] * (self.k1[i] * nrm + self.k2[i]) * H
            if self.cancel_drift:
                v = v - self.sliding.F @ x
            u = self._Ginv @ v
        if not np.all(np.isfinite(u)):
            raise DivergenceError(
                f"expected a finite control, actual value: {u!r:.120} at t={t} from an estimate of norm {nrm:.3g} "
                "(the gain alpha (k1 ||x_hat|| + k2) overflows); the observer has taken this sample: reset before the "
                "next step"
            )
        self.sigma = sigma
        return u
