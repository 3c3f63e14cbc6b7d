r"""Output-feedback controllers built on the observers of :mod:`smo_gym.control.estimators`.

Every controller owns its observer and is stepped once per sample::

    u_k = controller.step(y_k, t_k)      # observer update, control law, observer prediction with u_k

:class:`StateFeedback`
    nominal :math:`u = -K\hat x` (with :func:`lqr` for ``K``); with a :class:`LuenbergerObserver` it is the
    baseline "LQR with a Luenberger observer".
:class:`CompensationController`
    HOSM identification and compensation, continuous: :math:`u = -K\hat x - \hat w` (Fridman's slides, section 6).
:class:`IntegralSlidingModeController`
    output-based integral sliding mode, discontinuous (Fridman's slides, section 6).
:class:`UnmatchedCompensationController`
    unmatched disturbances compensated through the sliding surface (Ferreira et al. 2013, and its extension to
    disturbances that need derivatives of ``w_hat``, the linear form of Ferreira et al. 2015).

Discontinuous terms: ``"unit"`` (unit vector :math:`-\rho s/\|s\|`, the slides' law) or ``"super-twisting"``
(:math:`-k_1\lceil s\rfloor^{1/2} + v,\ \dot v = -k_2\,\mathrm{sign}(s)`, componentwise, explicit Euler), which
is continuous and needs a bound on the *derivative* of what it rejects.

References
----------
.. [Fri] L. Fridman, "Sliding Mode Observers: Theory and Practice", lecture slides, section 6.
.. [FBF11] A. Ferreira de Loza, F. J. Bejarano and L. Fridman, "Unmatched uncertainties compensation based on
   high-order sliding mode observation", Int. J. Robust Nonlinear Control, 2013 (and Ferreira et al., 2011,
   on compensation vs integral sliding mode).
.. [FPU15] A. Ferreira de Loza, J. Punta, L. Fridman, G. Bartolini and S. Delprat, "Output tracking of systems
   subjected to perturbations and a class of actuator faults based on HOSM observation and identification",
   Automatica 59, 2015.
.. [Utk96] V. Utkin and J. Shi, "Integral sliding mode in systems operating under uncertainty conditions",
   CDC 1996.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla

from .._validation import check_bool, check_choice, check_nonnegative, check_positive, check_real
from .plants import LinearPlant, _check_definite, _matrix, _pow2, _square_matrix, _unit, left_annihilator

__all__ = [
    "CompensationController",
    "IntegralSlidingModeController",
    "StateFeedback",
    "UnmatchedCompensationController",
    "lqr",
    "regular_form",
    "sampled_lqr",
]


def lqr(A, B, Q=None, R=None) -> np.ndarray:
    r"""Continuous-time LQR gain :math:`K = R^{-1}B^T P` from ``scipy.linalg.solve_continuous_are``.

    Minimizes :math:`\int x^TQx + u^TRu`; defaults ``Q = I``, ``R = I``. Returns ``K`` of shape ``(q, n)`` with
    ``A - B K`` Hurwitz (checked).

    Raises
    ------
    TypeError, ValueError
        Matrices that are not real, finite or of fitting shapes; no stabilizing solution (an uncontrollable
        unstable mode, ``Q`` or ``R`` not definite as the Riccati equation needs).
    """
    A = _square_matrix("A", A)
    n = A.shape[0]
    B = _matrix("B", B, (n, None))
    Q = np.eye(n) if Q is None else _matrix("Q", np.atleast_2d(Q), (n, n))
    R = np.eye(B.shape[1]) if R is None else _matrix("R", np.atleast_2d(R), (B.shape[1], B.shape[1]))
    _check_definite("Q", Q)
    _check_definite("R", R, definite=True)
    try:
        P = sla.solve_continuous_are(A, B, Q, R)
        K = np.linalg.solve(R, B.T @ P)
    except (np.linalg.LinAlgError, ValueError) as exc:  # scipy's words name neither the cause nor the remedy
        raise ValueError(
            f"expected (A, B) stabilizable with Q >= 0 and R > 0, actual value: no stabilizing Riccati solution ({exc})"
        ) from None
    ev = np.linalg.eigvals(A - B @ K)
    if np.any(ev.real >= 0):
        raise ValueError(f"expected a stabilizing LQR gain, actual value: eigenvalues of A - BK {ev}")
    return K


def sampled_lqr(plant: LinearPlant, dt: float, Q=None, R=None) -> np.ndarray:
    r"""LQR gain for the plant sampled with a zero-order hold: the gain a digital controller should use.

    The continuous cost :math:`\int x^TQx + u^TRu` is approximated on the samples by
    :math:`\sum_k \tau(x_k^TQx_k + u_k^TRu_k)` for the exact ZOH model :math:`x_{k+1} = \Phi x_k + \Gamma u_k`:

    .. math:: K = (\tau R + \Gamma^TP\Gamma)^{-1}\Gamma^TP\Phi,

    with ``P`` from ``scipy.linalg.solve_discrete_are``. As :math:`\tau \to 0` it tends to :func:`lqr`; at a
    sampling step comparable to the continuous design's fastest pole (the inverted double pendulum at 10 ms: a pole
    near -100 rad/s) the two differ, and this one is the optimum for the plant the controller actually drives
    (checked: the eigenvalues of :math:`\Phi - \Gamma K` inside the unit circle).

    Returns
    -------
    ndarray, shape (q, n)
    """
    dt = check_positive("dt", dt)
    n, q = plant.n, plant.n_inputs
    Q = np.eye(n) if Q is None else np.asarray(Q, float)
    R = np.eye(q) if R is None else np.atleast_2d(np.asarray(R, float))
    Phi, Gamma = plant.discretize(dt)
    P = sla.solve_discrete_are(Phi, Gamma, Q * dt, R * dt)
    K = np.linalg.solve(R * dt + Gamma.T @ P @ Gamma, Gamma.T @ P @ Phi)
    rho = np.abs(np.linalg.eigvals(Phi - Gamma @ K)).max()
    if rho >= 1.0:
        raise ValueError(f"expected a stabilizing sampled LQR gain, actual value: spectral radius {rho:.6g}")
    return K


def regular_form(B) -> tuple[np.ndarray, np.ndarray]:
    r"""The transform :math:`T_r = [B^\perp; B^+]` of Ferreira et al. (2013) and its inverse.

    :math:`B^\perp B = 0` (orthonormal rows), :math:`B^+ = (B^TB)^{-1}B^T`, so :math:`\bar x = T_r x` splits into
    the unactuated :math:`x_1 = B^\perp x` (``n - q``) and :math:`x_2 = B^+ x` with :math:`\dot x_2 = \ldots + u`.
    """
    B = _matrix("B", B, (None, None))
    if B.shape[1] == 0 or B.shape[0] < B.shape[1]:
        raise ValueError(f"expected B of shape (n, q) with 1 <= q <= n, actual value: shape {B.shape}")
    if np.linalg.matrix_rank(B) < B.shape[1]:
        raise ValueError(
            f"expected B with full column rank, actual value: rank {np.linalg.matrix_rank(B)} < {B.shape[1]}"
        )
    Tr = np.vstack([left_annihilator(_unit(B)), np.linalg.pinv(B)])  # B^perp of any units (its floor is absolute)
    return Tr, np.linalg.inv(Tr)


class _Discontinuous:
    """The discontinuous term: unit vector or super-twisting, with its own integrator state."""

    def __init__(self, kind: str, rho, k1, k2, dt: float, q: int):
        self.kind = check_choice("discontinuity", kind, ("unit", "super-twisting"))
        if self.kind == "unit":
            self.rho = check_positive("rho", rho)
        else:
            if k1 is None or k2 is None:
                raise ValueError(
                    f"expected k1 and k2 for the super-twisting discontinuity, actual value: k1={k1!r}, k2={k2!r}"
                )
            self.k1, self.k2 = check_positive("k1", k1), check_positive("k2", k2)
        self.dt = dt
        self.v = np.zeros(q)

    def reset(self):
        self.v[:] = 0.0

    def __call__(self, s: np.ndarray) -> np.ndarray:
        if self.kind == "unit":
            ns = np.linalg.norm(s)
            return -self.rho * s / ns if ns > 0 else np.zeros_like(s)
        out = -self.k1 * np.sqrt(np.abs(s)) * np.sign(s) + self.v
        self.v = self.v - self.dt * self.k2 * np.sign(s)
        return out


class StateFeedback:
    r"""Observer-based state feedback :math:`u_k = -K\hat x_k` (``K`` from :func:`lqr` by default).

    Parameters
    ----------
    observer : LuenbergerObserver or CascadedHOSMObserver
    K : array_like, shape (q, n), optional
        Default ``lqr(A, B, Q, R)``.
    Q, R : array_like, optional
        LQR weights when ``K`` is not given.
    """

    def __init__(self, observer, K=None, *, Q=None, R=None):
        plant = getattr(observer, "plant", None)
        if not isinstance(plant, LinearPlant):
            raise TypeError(
                f"expected an observer of a LinearPlant (LuenbergerObserver, CascadedHOSMObserver, ...), actual value: "
                f"{type(observer).__name__}"
            )
        self.observer = observer
        self.plant: LinearPlant = plant
        if K is None:
            self.K = lqr(plant.A, plant.B, Q, R)
        else:  # checked now: a K that does not fit would fail in step, after the observer took the sample
            self.K = _matrix("K", np.atleast_2d(K), (plant.n_inputs, self._feedback_width()))
        self.u = np.zeros(plant.n_inputs)

    def _feedback_width(self) -> int:
        """The size of the state the law feeds back (the columns of ``K``): the plant's."""
        return self.plant.n

    @property
    def dt(self) -> float:
        return self.observer.dt

    def reset(self, y0, x_hat0=None) -> None:
        self.observer.reset(y0, x_hat0)
        self.u = np.zeros(self.plant.n_inputs)
        self._reset_law()

    def _reset_law(self) -> None:
        pass

    def nominal(self) -> np.ndarray:
        return -self.K @ self.observer.x_hat

    def law(self, t: float) -> np.ndarray:
        return self.nominal()

    def step(self, y, t: float, limits=None) -> np.ndarray:
        """Update the observer with ``y_k``, compute ``u_k``, predict the observer with it; return ``u_k``.

        ``limits = (low, high)`` (arrays of shape ``(q,)``, infinite entries allowed) clips ``u_k`` to a saturating
        actuator's range first: the observer predicts with, and the laws' memories (:attr:`u`) hold, the command
        actually applied.
        """
        t = check_real("t", t)  # checked before the observer takes the sample, as the limits are
        if limits is not None:
            q = self.plant.n_inputs
            try:
                low, high = (np.broadcast_to(np.asarray(v, dtype=float), (q,)) for v in limits)
            except (TypeError, ValueError, OverflowError):
                raise ValueError(f"expected limits (low, high) of shape ({q},), actual value: {limits!r:.80}") from None
            if np.isnan(low).any() or np.isnan(high).any() or (low > high).any():
                raise ValueError(f"expected limits with low <= high and no NaN, actual value: {limits!r:.80}")
        self.observer.update(y)
        u = np.atleast_1d(self.law(t))
        self.u = u if limits is None else np.clip(u, low, high)
        self.observer.advance(self.u)
        return self.u


class CompensationController(StateFeedback):
    r"""HOSM identification and compensation control (continuous; Fridman's slides, section 6).

    .. math:: u = -K\hat x - B^+ D\,\hat w,

    i.e. :math:`u = -K\hat x - \hat w` for the slides' matched case ``D = B``. Closed-loop accuracy
    :math:`O(\Delta^{\alpha+1}) + O(\Delta^\alpha) + O(\mu)` (observation, identification, actuator).

    Parameters
    ----------
    observer : CascadedHOSMObserver
    K, Q, R : see :class:`StateFeedback`.
    t_start : float
        Time ``T`` after which the observer has converged; before it ``w_hat`` is not used.
    """

    def __init__(self, observer, K=None, *, Q=None, R=None, t_start: float = 0.0):
        super().__init__(observer, K, Q=Q, R=R)
        P = self.plant
        self.Bw = np.linalg.pinv(P.B) @ P.D
        # relative to ||D||, whatever its units (B B^+ does not depend on B's): a floor of 1 passed any unmatched D
        # below 1e-9
        if np.linalg.norm(P.B @ self.Bw - P.D) > 1e-9 * np.linalg.norm(P.D):
            raise ValueError(
                "expected a matched unknown input (span D inside span B) for compensation through u, "
                f"actual value: ||B B^+ D - D|| = {np.linalg.norm(P.B @ self.Bw - P.D):.3g}; use "
                "UnmatchedCompensationController"
            )
        self.t_start = check_nonnegative("t_start", t_start)

    def law(self, t: float) -> np.ndarray:
        u = self.nominal()
        if t >= self.t_start:
            u = u - self.Bw @ self.observer.w_hat
        return u


class IntegralSlidingModeController(StateFeedback):
    r"""Output-based integral sliding mode control (discontinuous; Fridman's slides, section 6).

    .. math::
        s(t) = B^+\Big[\hat x(t) - \hat x(T) - \int_T^t \big(A\hat x(\tau) + Bu_n(\tau)\big)\,d\tau\Big],\qquad
        u = u_n - \rho\,\frac{s}{\|s\|},\quad u_n = -K\hat x,\quad \rho > w^+ .

    In the sliding mode :math:`\dot s = u - u_n + B^+Dw = 0`: the equivalent control cancels the matched
    disturbance without identifying it. Closed-loop accuracy :math:`O(\Delta^{\alpha+1}) + O(\mu)`.

    Sampled form: over each sampling interval the integral is that of the nominal model started at
    :math:`\hat x_{k-1}` with :math:`u_{n,k-1}` held, i.e. the exact ZOH map,
    :math:`s_k = s_{k-1} + B^+(\hat x_k - \Phi\hat x_{k-1} - \Gamma u_{n,k-1})`, :math:`s(T) = 0`.
    Anti-windup: when the command applied (``self.u``, set by :meth:`step` or by a caller that clips it to the
    actuator's range) differs from the one computed, :math:`u_{n,k-1}` is shifted by that difference, so that
    :math:`s` integrates the disturbance and the discontinuous term only, not the saturation (otherwise the
    integral winds up during a saturated transient and the sliding term spends seconds unwinding it).

    Parameters
    ----------
    observer : CascadedHOSMObserver (or any observer with ``x_hat``)
    rho : float
        Gain of the unit-vector term (``discontinuity="unit"``).
    discontinuity : {"unit", "super-twisting"}
    k1, k2 : float
        Super-twisting gains (``k1 = 1.5 sqrt(L)``, ``k2 = 1.1 L`` for ``|d/dt w| <= L``).
    t_start : float
        ``T``: the surface is integrated from there; before it ``u = u_n``.
    """

    def __init__(
        self,
        observer,
        K=None,
        *,
        rho: float | None = None,
        discontinuity: str = "unit",
        k1=None,
        k2=None,
        Q=None,
        R=None,
        t_start: float = 0.0,
    ):
        super().__init__(observer, K, Q=Q, R=R)
        self.switch = _Discontinuous(discontinuity, rho, k1, k2, observer.dt, self.plant.n_inputs)
        self.Phi, self.Gamma = self.plant.discretize(observer.dt)
        self.Bpinv = np.linalg.pinv(self.plant.B)
        self.t_start = check_nonnegative("t_start", t_start)
        self._reset_law()

    def _reset_law(self) -> None:
        self.s = np.zeros(self.plant.n_inputs)
        self._last = None  # (x_hat_{k-1}, u_n,{k-1})
        self.switch.reset()

    def law(self, t: float) -> np.ndarray:
        x_hat = self.observer.x_hat
        u_n = self.nominal()
        if t < self.t_start:
            return u_n
        if self._last is not None:
            x_prev, un_prev, u_cmd_prev = self._last
            # anti-windup: what the actuator did not deliver of the last command (self.u is the command applied,
            # clipped by a saturating actuator) is not the disturbance's doing, so it is kept out of s
            un_prev = un_prev + (self.u - u_cmd_prev)
            self.s = self.s + self.Bpinv @ (x_hat - self.Phi @ x_prev - self.Gamma @ un_prev)
        u = u_n + self.switch(self.s)
        self._last = (x_hat.copy(), u_n.copy(), u.copy())
        return u


class UnmatchedCompensationController(StateFeedback):
    r"""Compensation of unmatched disturbances through the sliding surface ([FBF11]; Fridman's slides, section 6).

    In the regular form :math:`x_1 = B^\perp x,\ x_2 = B^+ x` (:func:`regular_form`),

    .. math::
        \dot x_1 = A_{11}x_1 + A_{12}x_2 + D_1 w,\qquad \dot x_2 = A_{21}x_1 + A_{22}x_2 + D_2 w + u,

    the surface :math:`s = K\hat x_1 + \hat x_2 + G\hat w`, :math:`G = A_{12}^+ D_1`, gives on :math:`s = 0`
    the disturbance-free reduced dynamics :math:`\dot x_1 = (A_{11} - A_{12}K)x_1` when
    :math:`\mathrm{span}\,D_1 \subset \mathrm{span}\,A_{12}` (assumption A4). The control is
    :math:`u = u_n - \rho s/\|s\|` (or super-twisting) with the nominal part cancelling the known terms of
    :math:`\dot s`.

    Extension (when A4 fails, e.g. the slides' helicopter): with a regulated output :math:`z = E x` (``E B = 0``),
    the surface becomes

    .. math::
        s = K(\hat x_1 - x_1^*) + \hat x_2 - x_2^*,\qquad
        x_1^* = \sum_{j=0}^{J}\Pi_j \hat w^{(j)},\quad x_2^* = \sum_{j=0}^{J}\Gamma_j \hat w^{(j)},

    where :math:`(x_1^*, x_2^*)` is a trajectory of the regular form driven by ``w`` along which ``z = 0``:
    :math:`\Pi_{j-1} = A_{11}\Pi_j + A_{12}\Gamma_j + D_1\delta_{j0}`, :math:`\Pi_J = 0`, :math:`E_1\Pi_j = 0`
    (coefficients of :math:`w^{(j)}`, solved by least squares for the smallest ``J``). On ``s = 0``,
    :math:`\frac{d}{dt}(x_1 - x_1^*) = (A_{11} - A_{12}K)(x_1 - x_1^*)`, so ``z -> 0`` exponentially whatever
    ``w`` is. With ``E = I`` (default) ``J = 0``, :math:`\Pi_0 = 0`, :math:`\Gamma_0 = -G`: the 2013 surface.
    This is the linear, single-surface form of the dynamic sliding surface of [FPU15] (which needs
    :math:`\hat w` derivatives up to the relative degree of the disturbance to the actuated block); the observer
    must provide ``n_w_derivatives >= J``.

    Parameters
    ----------
    observer : CascadedHOSMObserver
    K : array_like, shape (q, n - q), optional
        Reduced-order gain; default LQR on ``(A11, A12)``.
    rho : float
        Unit-vector gain (``discontinuity="unit"``).
    regulated : array_like, shape (r, n), optional
        ``E``; default all of ``x_1``.
    feedforward : bool
        Cancel the identified terms of :math:`\dot s` in the nominal control (:math:`-(KD_1 + D_2)\hat w` and the
        :math:`\hat w` derivatives the observer provides). ``False`` gives the slides' law
        :math:`u = -\Phi x - \rho s/\|s\|`, which needs :math:`\rho > (\|KD_1 + D_2\| + \|G\|)w^+`.
    discontinuity, k1, k2 : see :class:`IntegralSlidingModeController`.
    t_start : float
        Before ``T`` the disturbance terms are not used.

    Notes
    -----
    The slides print the reduced dynamics as :math:`(A_{11} - A_{22}K)x_1`; substituting
    :math:`x_2 = -Kx_1 - Gw` gives :math:`(A_{11} - A_{12}K)x_1`, which is what ``K`` is designed for here.
    """

    def __init__(
        self,
        observer,
        K=None,
        *,
        rho: float | None = None,
        regulated=None,
        feedforward: bool = True,
        discontinuity: str = "unit",
        k1=None,
        k2=None,
        Qr=None,
        Rr=None,
        t_start: float = 0.0,
    ):
        self.observer = observer
        P = self.plant = observer.plant
        q, n = P.n_inputs, P.n
        self.Tr, self.Tr_inv = regular_form(P.B)
        Ab = self.Tr @ P.A @ self.Tr_inv
        Db = self.Tr @ P.D
        r = n - q
        self.A11, self.A12, self.A21, self.A22 = Ab[:r, :r], Ab[:r, r:], Ab[r:, :r], Ab[r:, r:]
        self.D1, self.D2 = Db[:r], Db[r:]
        self.Kr = lqr(self.A11, self.A12, Qr, Rr) if K is None else np.atleast_2d(np.asarray(K, float))
        if regulated is None:
            E1 = np.eye(r)
        else:
            E = _matrix("regulated", np.atleast_2d(regulated), (None, self.plant.n))
            if np.linalg.norm(_unit(E) @ _unit(P.B)) > 1e-9:  # E B judged against ||E|| ||B||, whatever the units
                raise ValueError(
                    f"expected a regulated output z = E x not directly actuated (E B = 0), actual "
                    f"value: ||E B|| = {np.linalg.norm(E @ P.B):.3g}"
                )
            E1 = E @ self.Tr_inv[:, :r]
        self.Pi, self.Gam = self._solve_surface(E1)
        self.J = len(self.Pi) - 1
        if observer.n_w_derivatives < self.J:
            raise ValueError(
                f"expected an observer with n_w_derivatives >= {self.J} (the surface uses w_hat "
                f"derivatives up to order {self.J}), actual value: {observer.n_w_derivatives}"
            )
        self.G = -self.Gam[0] if self.J == 0 else None
        self.feedforward = check_bool("feedforward", feedforward)
        self.switch = _Discontinuous(discontinuity, rho, k1, k2, observer.dt, q)
        self.t_start = check_nonnegative("t_start", t_start)
        self.K = None
        self.u = np.zeros(q)
        self.s = np.zeros(q)

    def _solve_surface(self, E1):
        r"""Smallest ``J`` and ``(Pi_j, Gamma_j)`` with ``Pi_{j-1} = A11 Pi_j + A12 Gamma_j + D1 delta_j0``,
        ``Pi_J = 0``, ``E1 Pi_j = 0``.

        Solved for ``A``, ``B``, ``D`` and ``E1`` at unit norm (divided by powers of two ``a``, ``b``, ``d``, ``e``)
        and scaled back, ``Pi_j = d a^-(j+1) Pi_j'``, ``Gamma_j = d a^-(j+1) b^-1 Gamma_j'``: the raw equations mix
        blocks of sizes ``a``, ``a b`` and 1, so which ``J`` passed the residual test depended on the units."""
        P = self.plant
        a, b, d = (float(_pow2(np.linalg.norm(M))) for M in (P.A, P.B, P.D))
        A11, A12, D1, E1 = self.A11 / a, self.A12 / (a * b), self.D1 / d, _unit(E1)  # A12 = B^perp A B, D1 = B^perp D
        r, q = A12.shape
        m = D1.shape[1]
        for J in range(r + 1):
            nv = (J + 1) * (r + q)  # unknowns per column of w: Pi_0..Pi_J, Gamma_0..Gamma_J
            rows = []
            rhs = []
            for j in range(J + 2):  # coefficient of w^(j)
                row = np.zeros((r, nv))
                if j <= J:
                    row[:, j * r : (j + 1) * r] += A11
                    row[:, (J + 1) * r + j * q : (J + 1) * r + (j + 1) * q] += A12
                if j >= 1:
                    row[:, (j - 1) * r : j * r] -= np.eye(r)
                rows.append(row)
                rhs.append(-D1 if j == 0 else np.zeros((r, m)))
            for j in range(J + 1):
                row = np.zeros((E1.shape[0], nv))
                row[:, j * r : (j + 1) * r] = E1
                rows.append(row)
                rhs.append(np.zeros((E1.shape[0], m)))
            M, R = np.vstack(rows), np.vstack(rhs)
            X = np.linalg.lstsq(M, R, rcond=None)[0]
            if np.linalg.norm(M @ X - R) <= 1e-9 * max(np.linalg.norm(R), 1.0):  # a D1 of rounding errors is 0
                size = [d / a ** (j + 1) for j in range(J + 1)]  # of Pi_j; Gamma_j's is size[j] / b
                Pi = [X[j * r : (j + 1) * r] * size[j] for j in range(J + 1)]
                Gam = [X[(J + 1) * r + j * q : (J + 1) * r + (j + 1) * q] * (size[j] / b) for j in range(J + 1)]
                return Pi, Gam
        raise ValueError(
            "expected a disturbance that can be compensated on the regulated output through the "
            "sliding surface (span D1 inside span A12 for the full x1, or a regulated output E that "
            "the pseudo-control x2 can keep at zero), actual value: no solution for any J <= n - q; "
            "pass a smaller regulated output"
        )

    def _reset_law(self) -> None:
        self.s = np.zeros(self.plant.n_inputs)
        self.switch.reset()

    def reset(self, y0, x_hat0=None) -> None:
        self.observer.reset(y0, x_hat0)
        self.u = np.zeros(self.plant.n_inputs)
        self._reset_law()

    def targets(self, use_w: bool):
        """``(x1*, x2*)`` from the identified disturbance and its derivatives, and the derivative parts."""
        r, q = self.A12.shape
        x1s, x2s, dx1s, dx2s = np.zeros(r), np.zeros(q), np.zeros(r), np.zeros(q)
        if not use_w:
            return x1s, x2s, dx1s, dx2s
        W = self.observer.w_hat_derivatives
        for j in range(self.J + 1):
            x1s += self.Pi[j] @ W[j]
            x2s += self.Gam[j] @ W[j]
            if j + 1 < W.shape[0]:
                dx1s += self.Pi[j] @ W[j + 1]
                dx2s += self.Gam[j] @ W[j + 1]
        return x1s, x2s, dx1s, dx2s

    def law(self, t: float) -> np.ndarray:
        r = self.A11.shape[0]
        xb = self.Tr @ self.observer.x_hat
        x1, x2 = xb[:r], xb[r:]
        use_w = t >= self.t_start
        x1s, x2s, dx1s, dx2s = self.targets(use_w)
        Kr = self.Kr
        self.s = Kr @ (x1 - x1s) + x2 - x2s
        # s' = K(A11 x1 + A12 x2 + D1 w - x1*') + A21 x1 + A22 x2 + D2 w + u - x2*'
        u_n = -(Kr @ self.A11 + self.A21) @ x1 - (Kr @ self.A12 + self.A22) @ x2
        if self.feedforward and use_w:
            u_n = u_n - (Kr @ self.D1 + self.D2) @ self.observer.w_hat + Kr @ dx1s + dx2s
        return u_n + self.switch(self.s)
