r"""Estimation beyond strong observability: strongly detectable systems, functional observers, left inverses.

For :math:`\dot x = Ax + Bu + Dw,\ y = Cx` with an unknown input ``w`` (Fridman's slides, section 3), the cascaded
HOSM observer (:class:`~smo_gym.control.CascadedHOSMObserver`) needs *strong observability*: the state follows
from ``y`` and its derivatives. Three weaker settings of the slides (sections 3 and 7) are covered here.

:class:`StronglyDetectableObserver`
    Fridman, Davila and Levant (2011); Moreno (2001). All invariant zeros in the open left half-plane: the
    strongly observable coordinates are recovered exactly in finite time, the rest asymptotically, at the rate
    of the zeros.
:class:`FunctionalUnknownInputObserver`
    Angulo, Fridman and Moreno (2014). A combination :math:`Ex` when no observer of the whole state exists; it
    exists iff ``E`` does not see the unstable zero dynamics (the slides' ``E4 = 0``).
:class:`LeftInverseIdentifier`
    Bejarano, Fridman and Poznyak (2009). The unknown input from a static left inverse
    :math:`w = G\,[y; \dot y; \ldots; y^{(k)}]` with HOSM differentiators; the system may be neither strongly
    observable nor strongly detectable.

Decomposition used throughout (coordinate-free, so no canonical form is computed)
------------------------------------------------------------------------------------
Molinari's algorithm (:func:`~smo_gym.control.molinari_decoupling`) gives :math:`Mx = QY`, ``Y`` the stacked output
derivatives, and :math:`\ker M = \mathcal V^*`, the weakly unobservable subspace (the states that an input can
hide from ``y``). With orthonormal bases, rows :math:`T_o` of the row space of ``M`` and :math:`T_w` of
:math:`\mathcal V^*`,

.. math:: x = T_o^T z + T_w^T \xi,\qquad z = T_o x = T_o M^+ Q Y \ \text{(known from } y\text{)} .

For a left-invertible triple (Rosenbrock normal rank ``n + m``) :math:`T_o D` has full column rank, so
:math:`\dot z = T_o A x + T_o D w` gives :math:`w = (T_oD)^+(\dot z - T_oAx)` and

.. math::
    \dot\xi = A_\xi \xi + K_0 z + H\dot z,\qquad
    A_\xi = T_w \Pi A T_w^T,\ K_0 = T_w \Pi A T_o^T,\ H = T_w D (T_oD)^+,\
    \Pi = I - D(T_oD)^+T_o .

:math:`\Pi A` is :math:`A + DF` with the (unique on :math:`\mathcal V^*`) friend :math:`F = -(T_oD)^+T_oA`, which
leaves :math:`\mathcal V^*` invariant, so the eigenvalues of :math:`A_\xi` are the invariant zeros
(the zero dynamics). The derivative :math:`\dot z` is removed by :math:`\zeta = \xi - Hz`:

.. math:: \dot\zeta = A_\xi\zeta + (A_\xi H + K_0)\,z ,

a system driven by the known ``z`` alone: the slides' "copy of the system without injection" for their block
:math:`x_3` (:math:`\dot{\hat x}_3 = A_{31}y_1 + A_{32}y_2 + A_{33}\hat x_3`). A real Schur form
:math:`A_\xi = U\,\mathrm{diag\text{-}blocks}\,U^T` with the unstable eigenvalues first splits ``zeta`` into the
unstable part :math:`U_+^T\zeta` (the slides' ``x4``, cannot be estimated) and the stable part
:math:`s = U_-^T\zeta` with :math:`\dot s = T_{22}s + U_-^T(A_\xi H + K_0)z` (the slides' ``x3``).

References
----------
.. [Fri] L. Fridman, "Sliding Mode Observers: Theory and Practice", lecture slides, sections 3 and 7.
.. [FDL11] L. Fridman, J. Davila and A. Levant, "High-order sliding-mode observation for linear systems with
   unknown inputs", Nonlinear Analysis: Hybrid Systems 5(2), 2011.
.. [Mor01] J. A. Moreno, "Quasi-unknown input observers for linear systems", Proc. IEEE Conference on Control
   Applications, 2001.
.. [Hau83] M. L. J. Hautus, "Strong detectability and observers", Linear Algebra Appl. 50, 1983.
.. [AFM14] M. T. Angulo, L. Fridman and J. A. Moreno, functional unknown-input observers for linear systems with
   HOSM differentiators, J. Franklin Institute, 2014 (the slides' "[Angulo et al.: JFI14]"; the title could not be
   checked here).
.. [SS87] P. Sannuti and A. Saberi, "Special coordinate basis for multivariable linear systems: finite and
   infinite zero structure, squaring down and decoupling", Int. J. Control 45(5), 1987.
.. [BFP09] F. J. Bejarano, L. Fridman and A. Poznyak, "Unknown input and state estimation for unobservable
   systems", SIAM J. Control Optim. 48(2), 1155-1178, 2009.
.. [Mol76] B. P. Molinari, "A strong controllability and observability in linear multivariable control",
   IEEE TAC 21(5), 1976.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla

from .._validation import as_real_array, check_int_in_range, check_positive
from ..design.gains import MAX_LEVANT_ORDER
from ..observers import Levant
from .estimators import CascadedHOSMObserver, _highest_block, sampled_observer_gain
from .plants import (
    RANK_TOL,
    LinearPlant,
    MolinariDecoupling,
    NotStronglyObservableError,
    _matrix,
    _rank,
    _triple,
    _unit,
    strong_observability,
)

__all__ = [
    "FunctionalObservabilityReport",
    "FunctionalUnknownInputObserver",
    "LeftInverseIdentifier",
    "LeftInverseReport",
    "NoFunctionalObserverError",
    "NoStaticLeftInverseError",
    "NotStronglyDetectableError",
    "StrongDetectabilityReport",
    "StronglyDetectableObserver",
    "ZeroDynamics",
    "detectable_observer_gain",
    "functional_observability",
    "left_inverse",
    "strong_detectability",
    "zero_dynamics",
]

#: an eigenvalue counts as unstable when its real part is at or above ``-STABILITY_TOL * ||A||`` (relative: the
#: zeros scale with ``A``; ``||A||`` read as 1 when ``A = 0``)
STABILITY_TOL = 1e-9


class NotStronglyDetectableError(NotStronglyObservableError):
    """``(A, C, D)`` is not strongly detectable (an invariant zero with ``Re s >= 0``, or not left-invertible)."""


class NoFunctionalObserverError(ValueError):
    """No functional unknown-input observer of ``E x`` exists (``E4 != 0``: ``E`` sees an unstable zero)."""


class NoStaticLeftInverseError(ValueError):
    """The unknown input is not a static function ``G(y, y', ..., y^(k))`` of the output."""


def _fmt(z: np.ndarray) -> str:
    return ", ".join(f"{complex(v):.4g}" for v in np.sort_complex(np.asarray(z, dtype=complex)))


def _orthonormal_rows(M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal rows spanning the row space of ``M`` and its null space (``ker M``), by one SVD."""
    n = M.shape[1]
    if M.size == 0:
        return np.zeros((0, n)), np.eye(n)
    _, s, Vh = np.linalg.svd(M)
    r = int(np.sum(s > RANK_TOL * max(s[0], 1.0)))
    return Vh[:r].copy(), Vh[r:].copy()


def _stability_bound(A: np.ndarray) -> float:
    """How far left of the imaginary axis a stable eigenvalue of a system with matrix ``A`` must be
    (:data:`STABILITY_TOL`)."""
    return STABILITY_TOL * (np.linalg.norm(A, 2) or 1.0)


def _unstable(ev: np.ndarray, A: np.ndarray) -> np.ndarray:
    return np.asarray(ev).real >= -_stability_bound(A)


@dataclass(frozen=True)
class ZeroDynamics:
    r"""The split of the state into its strongly observable part and the zero dynamics (module docstring).

    .. math::
        x = T_o^T z + T_w^T(\zeta + H z),\qquad \dot\zeta = A_\xi \zeta + K z,\qquad z = T_o M^+ Q\,Y,

    and the real Schur form :math:`A_\xi = U T U^T` with the ``n_unstable`` unstable eigenvalues first.

    Attributes
    ----------
    T_o : ndarray, shape (r, n)
        Orthonormal rows: the strongly observable coordinates ``z = T_o x`` (``r = rank M``).
    T_w : ndarray, shape (d, n)
        Orthonormal rows spanning the weakly unobservable subspace :math:`\mathcal V^*` (``d = n - r``).
    A_zero : ndarray, shape (d, d)
        :math:`A_\xi`: its eigenvalues are the invariant zeros.
    H : ndarray, shape (d, r)
    K : ndarray, shape (d, r)
        :math:`A_\xi H + K_0`, the input of the ``zeta`` dynamics.
    U : ndarray, shape (d, d)
        Schur vectors of ``A_zero``, the unstable ones first.
    T_schur : ndarray, shape (d, d)
        Quasi-triangular Schur factor.
    n_unstable : int
    molinari : MolinariDecoupling
    """

    T_o: np.ndarray
    T_w: np.ndarray
    A_zero: np.ndarray
    H: np.ndarray
    K: np.ndarray
    U: np.ndarray
    T_schur: np.ndarray
    n_unstable: int
    molinari: MolinariDecoupling = field(repr=False)

    @property
    def zeros(self) -> np.ndarray:
        """Eigenvalues of ``A_zero`` (the invariant zeros), sorted."""
        return np.sort_complex(np.linalg.eigvals(self.A_zero).astype(complex))

    @property
    def unstable_subspace(self) -> np.ndarray:
        r"""Orthonormal columns, shape ``(n, n_unstable)``, spanning :math:`\mathcal V^*_+`, the unstable zero
        directions in the state space (the slides' ``x4`` block)."""
        return self.T_w.T @ self.U[:, : self.n_unstable]


def zero_dynamics(A, C=None, D=None) -> ZeroDynamics:
    r"""The strongly observable coordinates and the zero dynamics of a left-invertible triple (module docstring).

    Parameters
    ----------
    A : array_like, shape (n, n), or LinearPlant
        ``zero_dynamics(plant)`` or ``zero_dynamics(A, C, D)``.
    C : array_like, shape (p, n)
    D : array_like, shape (n, m)

    Raises
    ------
    NotStronglyDetectableError
        The triple is not left-invertible (``rank D < m`` or Rosenbrock normal rank ``< n + m``): then an input
        moves the state inside :math:`\mathcal V^*` without trace in ``y`` and no zero dynamics exist.
    """
    A, C, D = _triple(A, C, D, "zero_dynamics")
    rep = strong_observability(A, C, D)
    n, m = A.shape[0], D.shape[1]
    if _rank(_unit(D)) < m or rep.normal_rank < n + m:
        raise NotStronglyDetectableError(
            f"expected a left-invertible triple (rank D = m = {m} and Rosenbrock normal rank n + m = {n + m}), "
            f"actual value: rank D = {_rank(_unit(D))}, normal rank {rep.normal_rank}: an unknown input can move the "
            "state without any trace in y"
        )
    mol = rep.molinari
    T_o, T_w = _orthonormal_rows(mol.M)
    TD = T_o @ D
    if _rank(T_o @ _unit(D)) < m:  # cannot happen for a left-invertible triple; guards the rank decisions
        raise RuntimeError(f"expected T_o D of full column rank {m}, actual value: rank {_rank(T_o @ _unit(D))}")
    TDp = np.linalg.pinv(TD)
    Pi = np.eye(n) - D @ TDp @ T_o
    A_xi = T_w @ Pi @ A @ T_w.T
    K0 = T_w @ Pi @ A @ T_o.T
    H = T_w @ D @ TDp
    d = T_w.shape[0]
    if d:
        T_s, U, n_uns = _unstable_first_schur(A_xi, _stability_bound(A))
    else:
        T_s, U, n_uns = np.zeros((0, 0)), np.zeros((0, 0)), 0
    return ZeroDynamics(
        T_o=T_o,
        T_w=T_w,
        A_zero=A_xi,
        H=H,
        K=A_xi @ H + K0,
        U=U,
        T_schur=T_s,
        n_unstable=int(n_uns),
        molinari=mol,
    )


def _unstable_first_schur(M: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray, int]:
    """Real Schur form ``M = U T U^T`` with the eigenvalues of real part ``>= -tol`` first, and their number.

    A defective eigenvalue near the boundary (a double zero at 0 computed as ``+-1e-8``) can cross it while the form
    is reordered, which scipy refuses (``LinAlgError``); the boundary is then moved ten times further into the
    stable half-plane, counting such an eigenvalue as unstable: the conservative side for detectability.
    """
    for widen in (1.0, 10.0, 100.0):
        try:
            return sla.schur(M, output="real", sort=lambda re, im, bound=-widen * tol: re >= bound)
        except np.linalg.LinAlgError:
            continue
    raise ValueError(
        "expected zero dynamics whose eigenvalues can be split at the stability boundary, actual value: "
        f"eigenvalues {np.linalg.eigvals(M)!r:.200} cross it within rounding"
    )


@dataclass(frozen=True)
class StrongDetectabilityReport:
    """What :func:`strong_detectability` found; ``ok`` is the verdict and ``reason`` explains a failure.

    Attributes
    ----------
    ok : bool
        Strongly detectable.
    strongly_observable : bool
    reason : str
    invariant_zeros : ndarray of complex
    unstable_zeros : ndarray of complex
        The zeros with ``Re s >= 0`` (up to :data:`STABILITY_TOL`).
    normal_rank : int
    weakly_unobservable_dim : int
    molinari : MolinariDecoupling
    zero_dynamics : ZeroDynamics or None
        ``None`` when the triple is not left-invertible.
    """

    ok: bool
    strongly_observable: bool
    reason: str
    invariant_zeros: np.ndarray
    unstable_zeros: np.ndarray
    normal_rank: int
    weakly_unobservable_dim: int
    molinari: MolinariDecoupling = field(repr=False)
    zero_dynamics: ZeroDynamics | None = field(default=None, repr=False)


def strong_detectability(A, C=None, D=None) -> StrongDetectabilityReport:
    r"""Check that ``(A, C, D)`` is strongly detectable (Hautus 1983; Fridman's slides, section 3).

    Strongly detectable: :math:`y \equiv 0` implies :math:`x(t) \to 0` whatever ``w`` is; equivalently the
    Rosenbrock matrix :math:`\begin{bmatrix} sI - A & -D \\ C & 0\end{bmatrix}` has full column rank ``n + m``
    for every ``s`` with :math:`\operatorname{Re} s \ge 0`: left-invertible, and every invariant zero in the open
    left half-plane (the slides' "minimum phase"; trajectories in :math:`\mathcal V^*` converge to zero).

    The zeros come from :func:`~smo_gym.control.invariant_zeros` (staircase reduction) and, independently, as
    the eigenvalues of the zero dynamics :math:`A_\xi` (:func:`zero_dynamics`); the verdict uses the staircase
    zeros, and a disagreement in their number raises ``RuntimeError`` (a rank decision went wrong).

    Parameters
    ----------
    A : array_like, shape (n, n), or LinearPlant
        ``strong_detectability(plant)`` or ``strong_detectability(A, C, D)``.
    C : array_like, shape (p, n)
    D : array_like, shape (n, m)
    """
    A, C, D = _triple(A, C, D, "strong_detectability")
    so = strong_observability(A, C, D)
    n, m = A.shape[0], D.shape[1]
    empty = np.zeros(0, dtype=complex)
    if _rank(_unit(D)) < m or so.normal_rank < n + m:
        return StrongDetectabilityReport(
            ok=False,
            strongly_observable=False,
            reason=f"not left-invertible: {so.reason}",
            invariant_zeros=empty,
            unstable_zeros=empty,
            normal_rank=so.normal_rank,
            weakly_unobservable_dim=so.weakly_unobservable_dim,
            molinari=so.molinari,
        )
    zd = zero_dynamics(A, C, D)
    zeros = so.invariant_zeros
    if zeros.size != zd.A_zero.shape[0]:
        raise RuntimeError(
            f"expected as many invariant zeros as the dimension of the weakly unobservable subspace, actual value: "
            f"{zeros.size} zeros ({_fmt(zeros)}) and dim V* = {zd.A_zero.shape[0]}"
        )
    unstable = zeros[_unstable(zeros, A)]
    reason = ""
    if unstable.size:
        reason = (
            f"unstable invariant zeros at s = {_fmt(unstable)} (Re s >= 0): an input w(t) = w0 exp(s t) keeps y = 0 "
            "while the state does not converge to zero"
        )
    return StrongDetectabilityReport(
        ok=not reason,
        strongly_observable=so.ok,
        reason=reason,
        invariant_zeros=zeros,
        unstable_zeros=unstable,
        normal_rank=so.normal_rank,
        weakly_unobservable_dim=so.weakly_unobservable_dim,
        molinari=so.molinari,
        zero_dynamics=zd,
    )


def _unobservable_basis(A: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Orthonormal rows spanning the unobservable subspace of ``(A, C)`` (null space of the observability matrix)."""
    n = A.shape[0]
    O = np.vstack([_unit(C) @ np.linalg.matrix_power(_unit(A), j) for j in range(n)])  # C A^j on its factors' scale
    return _orthonormal_rows(O)[1]


def detectable_observer_gain(A, C, dt: float, poles=None) -> np.ndarray:
    r"""Gain ``L_d`` of the sampled current observer for a *detectable* pair ``(A, C)``.

    The same observer as :func:`~smo_gym.control.sampled_observer_gain`; when ``(A, C)`` is not observable the
    eigenvalues are placed on the observable part only (orthogonal Kalman decomposition: rows :math:`T_n` spanning
    the unobservable subspace, :math:`T_{ob}` the rest; :math:`L_d = T_{ob}^T L_{ob}`), and the unobservable
    modes keep their eigenvalues :math:`e^{\lambda\tau}`, which must be stable.

    Parameters
    ----------
    A : array_like, shape (n, n)
    C : array_like, shape (p, n)
    dt : float
    poles : array_like, optional
        Continuous-time poles, one per *observable* mode (default as in ``sampled_observer_gain``).

    Raises
    ------
    ValueError
        ``(A, C)`` has an unobservable eigenvalue with ``Re >= 0`` (not detectable), or a matrix is not finite or
        of the wrong shape.
    """
    A = _matrix("A", A, (None, None))  # bool and string entries refused, not read as numbers
    n = A.shape[0]
    if A.shape != (n, n):
        raise ValueError(f"expected a square A, actual value: shape {A.shape}")
    C = _matrix("C", np.atleast_2d(C), (None, n))
    dt = check_positive("dt", dt)
    Tn = _unobservable_basis(A, C)
    if Tn.shape[0] == 0:
        return sampled_observer_gain(A, C, dt, poles)
    An = Tn @ A @ Tn.T
    ev = np.linalg.eigvals(An)
    if np.any(_unstable(ev, A)):
        raise ValueError(
            f"expected a detectable pair (A, C) (stable unobservable modes) for the Luenberger stage, actual value: "
            f"unobservable eigenvalues {_fmt(ev)}"
        )
    Tob = _orthonormal_rows(Tn)[1]
    Lob = sampled_observer_gain(Tob @ A @ Tob.T, C @ Tob.T, dt, poles)
    return Tob.T @ Lob


def _foh(A: np.ndarray, B: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r"""``(Phi, G0, G1)``: exact solution of :math:`\dot s = As + Bz` with ``z`` linear between two samples,
    :math:`s_{k+1} = \Phi s_k + G_0 z_k + G_1 z_{k+1}` (first-order hold)."""
    d, r = B.shape
    M = np.zeros((d + 2 * r, d + 2 * r))
    M[:d, :d], M[:d, d : d + r], M[d : d + r, d + r :] = A * dt, B * dt, np.eye(r)
    E = sla.expm(M)
    Phi, Ga, Gb = E[:d, :d], E[:d, d : d + r], E[:d, d + r :]
    return Phi, Ga - Gb, Gb


@dataclass(frozen=True)
class FunctionalObservabilityReport:
    """What :func:`functional_observability` found; ``ok`` says whether a functional UIO of ``E x`` exists.

    Attributes
    ----------
    ok : bool
    reason : str
    E4 : ndarray, shape (l, n_unstable)
        ``E`` on an orthonormal basis of the unstable zero directions (the slides' ``E4``).
    unstable_zeros : ndarray of complex
    functional : ndarray, shape (l, n)
    zero_dynamics : ZeroDynamics
    """

    ok: bool
    reason: str
    E4: np.ndarray
    unstable_zeros: np.ndarray
    functional: np.ndarray
    zero_dynamics: ZeroDynamics = field(repr=False)

    @property
    def molinari(self) -> MolinariDecoupling:
        """Molinari's relation of the triple."""
        return self.zero_dynamics.molinari


def functional_observability(A, C=None, D=None, *, functional) -> FunctionalObservabilityReport:
    r"""Whether :math:`Ex` can be estimated from ``y`` whatever ``w`` is: the slides' condition ``E4 = 0``.

    In Sannuti and Saberi's (1987) special coordinate basis (Fridman's slides, "Functional Unknown Input
    Observers"), ``x4`` carries the unstable invariant zeros; a functional unknown-input observer of
    :math:`z = Ex` exists iff :math:`E_4 = 0` (Angulo, Fridman and Moreno 2014). Coordinate-free: ``E`` vanishes on
    :math:`\mathcal V^*_+`, the invariant subspace of the zero dynamics for the zeros with ``Re s >= 0``.
    Necessity: two states differing by :math:`v \in \mathcal V^*_+` give the same ``y`` for suitable inputs
    while :math:`E v(t)` does not decay. ``E4`` is tested against ``1e-8 * ||E||``.

    Parameters
    ----------
    A : array_like, shape (n, n), or LinearPlant
    C : array_like, shape (p, n)
    D : array_like, shape (n, m)
    functional : array_like, shape (l, n)
        ``E`` (a vector is one row).

    Raises
    ------
    NotStronglyDetectableError
        The triple is not left-invertible (see :func:`zero_dynamics`).
    """
    A, C, D = _triple(A, C, D, "functional_observability")
    E = _matrix("functional", np.atleast_2d(functional), (None, A.shape[0]))
    zd = zero_dynamics(A, C, D)
    E4 = E @ zd.unstable_subspace
    zeros = np.linalg.eigvals(zd.A_zero).astype(complex)
    unstable = zeros[_unstable(zeros, A)]
    size = float(np.abs(E4).max()) if E4.size else 0.0
    reason = ""
    if size > 1e-8 * max(np.linalg.norm(E), 1e-300):
        reason = (
            f"E4 != 0: the functional sees the unstable zero dynamics (max |E4| = {size:.3g}, unstable invariant "
            f"zeros at s = {_fmt(unstable)}); two states differing along them give the same output"
        )
    return FunctionalObservabilityReport(
        ok=not reason, reason=reason, E4=E4, unstable_zeros=unstable, functional=E, zero_dynamics=zd
    )


class FunctionalUnknownInputObserver(CascadedHOSMObserver):
    r"""Functional unknown-input observer of :math:`Ex` (Angulo, Fridman and Moreno 2014; Fridman's slides, sec. 3).

    The cascade of :class:`~smo_gym.control.CascadedHOSMObserver` (sampled Luenberger stage, HOSM differentiator of
    the output error, Molinari's relation) recovers the strongly observable coordinates :math:`z = T_o x` exactly
    after a finite time; the stable part ``s`` of the zero dynamics is estimated by its copy driven by
    :math:`\hat z` (module docstring), exact solution with :math:`\hat z` linear between samples:

    .. math::
        \hat z_k = T_o\big(\tilde x_k^- + \hat e_k\big),\qquad
        \hat s_{k} = \Phi_s \hat s_{k-1} + G_0 \hat z_{k-1} + G_1 \hat z_k,\\
        \hat x_k = T_o^T\hat z_k + T_w^T\big(H\hat z_k + U_-\hat s_k + U_+U_+^T \tilde\zeta_k\big),\qquad
        \widehat{Ex}_k = E\hat x_k .

    The unstable part :math:`U_+^T\zeta` cannot be estimated; ``x_hat`` takes it from the Luenberger stage
    (:math:`\tilde\zeta = (T_w - HT_o)\tilde x^-`), which ``E`` does not see when ``E4 = 0``. Errors: ``z``
    exact in finite time (``O(tau^(alpha+1))`` sampled, as the cascade); ``s`` converges as
    :math:`e^{T_{22}t}`, the stable invariant zeros.

    Parameters
    ----------
    plant : LinearPlant
    functional : array_like, shape (l, n)
        ``E``. Raises :class:`NoFunctionalObserverError` when ``E4 != 0`` (:func:`functional_observability`).
    dt, lipschitz, alpha, poles, discretization
        As for :class:`~smo_gym.control.CascadedHOSMObserver` (``poles``: one per observable mode of ``(A, C)``,
        see :func:`detectable_observer_gain`).

    Attributes
    ----------
    z_hat : ndarray, shape (l,)
        Estimate of ``E x``.
    x_hat : ndarray, shape (n,)
        State estimate whose error converges into :math:`\mathcal V^*_+` (to zero when there is no unstable zero).
    w_hat : ndarray, shape (m,)
        Zeros: ``w`` is not identified by a functional observer (it depends on the unstable zero dynamics).
    zero_dynamics : ZeroDynamics

    Notes
    -----
    The slides estimate their block ``x2`` (observable, not reached by ``w``) with a Luenberger observer instead of
    differentiating; here every strongly observable coordinate comes from the differentiator (finite time).
    Needs ``(A, C)`` detectable for the Luenberger stage (an unstable unobservable mode is refused).
    """

    def __init__(
        self,
        plant: LinearPlant,
        functional,
        dt: float,
        lipschitz,
        *,
        alpha: int = 1,
        poles=None,
        discretization: str = "taylor",
    ):
        if not isinstance(plant, LinearPlant):
            raise TypeError(f"expected plant to be a LinearPlant, actual value: {type(plant).__name__}")
        self.functional = _matrix("functional", np.atleast_2d(functional), (None, plant.n))
        super().__init__(plant, dt, lipschitz, alpha=alpha, poles=poles, discretization=discretization)
        zd = self.zero_dynamics
        nu = zd.n_unstable
        self._U_minus, self._U_plus = zd.U[:, nu:], zd.U[:, :nu]
        As = zd.T_schur[nu:, nu:]
        self._s_maps = _foh(As, self._U_minus.T @ zd.K, self.dt)
        self._zeta_of_x = zd.T_w - zd.H @ zd.T_o  # zeta = (T_w - H T_o) x
        self.s_hat = self._z_prev = None
        self.z_hat = None

    def _check_plant(self, plant: LinearPlant):
        rep = functional_observability(plant, functional=self.functional)
        if not rep.ok:
            raise NoFunctionalObserverError(
                f"expected a functional E x with E4 = 0 (E blind to the unstable zero dynamics), actual value: "
                f"{rep.reason}"
            )
        self.zero_dynamics = rep.zero_dynamics
        return rep

    def _sampled_gain(self, poles) -> np.ndarray:
        return detectable_observer_gain(self.plant.A, self.plant.C, self.dt, poles)

    @property
    def theoretical_orders(self) -> dict[str, int]:
        """Order in ``tau`` of the error of the strongly observable coordinates ``z`` (noise-free samples)."""
        k = _highest_block(self._S, self.plant.n_outputs, np.linalg.norm(self.plant.A))  # y^(k) at its size
        return {"strongly observable state": self.order + 1 - k}

    def reset(self, y0, x_hat0=None) -> np.ndarray:
        """Start the cascade (see :meth:`CascadedHOSMObserver.reset`) and the copy of the stable zero dynamics."""
        super().reset(y0, x_hat0)
        self.s_hat = self._U_minus.T @ self._zeta_of_x @ self._prior
        self._z_prev = None
        self._compose()
        return self.x_hat

    def _compose(self) -> None:
        zd = self.zero_dynamics
        z = zd.T_o @ self.x_hat if self._z_prev is None else self._z_prev
        zeta = self._U_minus @ self.s_hat + self._U_plus @ (self._U_plus.T @ self._zeta_of_x @ self._prior)
        self.x_hat = zd.T_o.T @ z + zd.T_w.T @ (zd.H @ z + zeta)
        self.z_hat = self.functional @ self.x_hat

    def update(self, y) -> np.ndarray:
        """Process ``y_k``: return the state estimate ``x_hat`` (see the class docstring) and set ``z_hat``."""
        super().update(y)  # x_hat = x~^- + P_o e_hat: exact in the strongly observable coordinates
        z = self.zero_dynamics.T_o @ self.x_hat
        if self._z_prev is not None:
            Phi, G0, G1 = self._s_maps
            self.s_hat = Phi @ self.s_hat + G0 @ self._z_prev + G1 @ z
        self._z_prev = z
        self._compose()
        self.w_hat = np.zeros(self.plant.n_unknown)
        self.w_hat_derivatives[:] = 0.0
        return self.x_hat


class StronglyDetectableObserver(FunctionalUnknownInputObserver):
    r"""Observer of the whole state of a strongly detectable triple (Fridman, Davila and Levant 2011; Moreno 2001).

    Fridman's slides, "Cascaded Observers for strongly detectable LTI systems": in the canonical form the
    strongly observable block is recovered with output derivatives (here exactly in finite time by the cascaded
    HOSM observer) and the block of the invariant zeros by a copy of its dynamics without injection, which
    converges at the rate of the zeros. It is :class:`FunctionalUnknownInputObserver` with ``E = I`` (every zero
    stable, so ``E4`` is empty), plus the asymptotic identification of the unknown input

    .. math:: \hat w_k = (T_oD)^+\,T_o\big(\hat{\dot e}_k - A\,(\hat x_k - \tilde x_k^-)\big),

    (:math:`\dot e = Ae + Dw` between samples, ``e = x - x~``), which converges as the zero dynamics do: by
    Bejarano et al. (2009) ``w`` depends on the zero dynamics unless they are unobservable modes.

    Parameters
    ----------
    plant : LinearPlant
        Strongly detectable; otherwise :class:`NotStronglyDetectableError` names the unstable zeros.
    dt, lipschitz, alpha, poles, discretization
        As for :class:`FunctionalUnknownInputObserver`.
    """

    def __init__(
        self, plant: LinearPlant, dt: float, lipschitz, *, alpha: int = 1, poles=None, discretization: str = "taylor"
    ):
        if not isinstance(plant, LinearPlant):
            raise TypeError(f"expected plant to be a LinearPlant, actual value: {type(plant).__name__}")
        super().__init__(plant, np.eye(plant.n), dt, lipschitz, alpha=alpha, poles=poles, discretization=discretization)
        zd = self.zero_dynamics
        self._w_map = np.linalg.pinv(zd.T_o @ plant.D) @ zd.T_o

    def _check_plant(self, plant: LinearPlant):
        rep = strong_detectability(plant)
        if not rep.ok:
            raise NotStronglyDetectableError(
                "expected a strongly detectable triple (A, C, D) (left-invertible, every invariant zero with "
                f"Re s < 0), actual value: {rep.reason}"
            )
        self.zero_dynamics = rep.zero_dynamics
        return rep

    def update(self, y) -> np.ndarray:
        """Process ``y_k``: return ``x_hat`` and set ``w_hat`` (asymptotic identification)."""
        prior = self._prior  # x~^- of this sample (the cascade's update leaves it in place)
        super().update(y)
        e_dot = self.e_hat_derivatives[1]
        self.w_hat = self._w_map @ (e_dot - self.plant.A @ (self.x_hat - prior))
        self.w_hat_derivatives[0] = self.w_hat
        return self.x_hat


# ---------------------------------------------------------------------------------------------------------------
# static left inverse
# ---------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class LeftInverseReport:
    r"""What :func:`left_inverse` found.

    Attributes
    ----------
    static : bool
        A static left inverse :math:`w = G\,[y; \dot y; \ldots; y^{(k)}]` exists.
    asymptotic : bool
        Bejarano et al.'s (2009) condition for estimating ``w`` (asymptotically): every invariant zero that is not
        an unobservable mode is in the open left half-plane.
    reason : str
        Why ``static`` is false (empty otherwise).
    G : ndarray, shape (m, p (k + 1)) or None
        Weights of the stacked derivatives ``[y; y'; ...; y^(k)]``.
    n_derivatives : int
        ``k``.
    invariant_zeros : ndarray of complex
    unobservable_eigenvalues : ndarray of complex
    visible_zeros : ndarray of complex
        Invariant zeros that are not unobservable modes (eigenvalues of the zero dynamics on
        :math:`\mathcal V^*/\mathcal N`).
    strongly_observable, strongly_detectable : bool
    """

    static: bool
    asymptotic: bool
    reason: str
    G: np.ndarray | None
    n_derivatives: int
    invariant_zeros: np.ndarray
    unobservable_eigenvalues: np.ndarray
    visible_zeros: np.ndarray
    strongly_observable: bool
    strongly_detectable: bool


def left_inverse(A, C=None, D=None) -> LeftInverseReport:
    r"""The static left inverse :math:`w = G\,[y; \dot y; \ldots; y^{(k)}]` of ``(A, C, D)``, when it exists.

    Fridman's slides, section 7 ("static left-inverse", after Bejarano, Fridman and Poznyak 2009). With the
    decomposition of the module docstring, :math:`w = (T_oD)^+(\dot z - T_oAT_o^Tz - T_oAT_w^T\xi)`, and ``w``
    is a static function of the output iff the last term vanishes for every :math:`\xi`, i.e. iff
    :math:`\mathcal V^*` is ``A``-invariant: :math:`\mathcal V^* = \mathcal N`, the unobservable subspace
    (for :math:`y \equiv 0` the state moves in :math:`\mathcal V^*` with :math:`w = Fx`, and :math:`F` vanishes
    exactly on :math:`\mathcal N`). Then, with :math:`z = T_o S Y`, :math:`S = M^+Q` (Molinari):

    .. math:: G = (T_oD)^+\,T_o\,\big(S^{\uparrow} - A S\big),

    :math:`S^\uparrow` the relation on the stack shifted by one derivative. Unobservable modes may be unstable:
    neither strong observability nor strong detectability is needed.

    Notes
    -----
    The slides state Bejarano et al.'s theorem as "a static left-inverse exists iff the invariant zeros that are
    not unobservable eigenvalues are stable". Bejarano et al.'s abstract states it as the condition for
    *estimating* ``w``, which is asymptotic when such zeros exist (``w`` then depends on their decaying
    modes); an exact *static* inverse needs that there be none. ``asymptotic`` reports the slides' condition,
    ``static`` the exact one.

    Parameters
    ----------
    A : array_like, shape (n, n), or LinearPlant
    C : array_like, shape (p, n)
    D : array_like, shape (n, m)
    """
    A, C, D = _triple(A, C, D, "left_inverse")
    det = strong_detectability(A, C, D)
    Tn = _unobservable_basis(A, C)
    unobs = np.sort_complex(np.linalg.eigvals(Tn @ A @ Tn.T).astype(complex))
    empty = np.zeros(0, dtype=complex)
    common = dict(
        invariant_zeros=det.invariant_zeros,
        unobservable_eigenvalues=unobs,
        strongly_observable=det.strongly_observable,
        strongly_detectable=det.ok,
    )
    if det.zero_dynamics is None:
        return LeftInverseReport(
            static=False, asymptotic=False, reason=det.reason, G=None, n_derivatives=0, visible_zeros=empty, **common
        )
    zd = det.zero_dynamics
    # N inside V* in the coordinates xi = T_w x; the zero dynamics leave it invariant; quotient V*/N
    Nw = zd.T_w @ Tn.T
    Qc = _orthonormal_rows(Nw.T)[1].T  # complement of N in V* coordinates
    visible = np.sort_complex(np.linalg.eigvals(Qc.T @ zd.A_zero @ Qc).astype(complex)) if Qc.size else empty
    asymptotic = not np.any(_unstable(visible, A))
    if visible.size:
        return LeftInverseReport(
            static=False,
            asymptotic=asymptotic,
            reason=(
                f"invariant zeros at s = {_fmt(visible)} are not unobservable modes: w depends on their modes, "
                "which y cannot reveal at once (no static left inverse"
                + ("; w can still be estimated asymptotically)" if asymptotic else ")")
            ),
            G=None,
            n_derivatives=0,
            visible_zeros=visible,
            **common,
        )
    mol = zd.molinari
    p, n = C.shape[0], A.shape[0]
    S = mol.state_map()
    S_ext = np.hstack([S, np.zeros((n, p))])
    S_up = np.hstack([np.zeros((n, p)), S])
    TD = zd.T_o @ D
    G = np.linalg.pinv(TD) @ zd.T_o @ (S_up - A @ S_ext)
    k = _highest_block(G, p, np.linalg.norm(A))  # the weights of y^(k) compared at the size of y^(k)
    return LeftInverseReport(
        static=True,
        asymptotic=True,
        reason="",
        G=G[:, : p * (k + 1)],
        n_derivatives=k,
        visible_zeros=empty,
        **common,
    )


class LeftInverseIdentifier:
    r"""Unknown-input identification by a static left inverse and HOSM differentiators (Fridman's slides, sec. 7).

    .. math:: \hat w_k = G\,\big[\hat y_k; \hat{\dot y}_k; \ldots; \hat y^{(k)}_k\big],

    ``G`` from :func:`left_inverse`, the derivatives from Levant's differentiator of order ``K = k + alpha - 1``
    on each output. Exact after the differentiator's finite-time transient for noise-free continuous
    measurements; sampled at step ``tau`` the error is ``O(L tau^(K+1-k)) = O(tau^alpha)``, and with noise of
    amplitude ``eta`` it is ``O(eta^(alpha/(K+1)))`` (Levant 2003), ``k`` the highest derivative ``G`` weights.

    The output is differentiated directly (no Luenberger stage): ``lipschitz`` must bound
    :math:`|y^{(K+1)}|` along the trajectory, which may contain unstable *unobservable* modes (they never reach
    ``y``) but not unstable observable ones (use :class:`~smo_gym.control.CascadedHOSMObserver` there when the
    triple is strongly observable).

    Parameters
    ----------
    plant : LinearPlant
        Must have a static left inverse (:class:`NoStaticLeftInverseError` says why not).
    dt : float
    lipschitz : float or array_like, shape (p,)
        Bound on :math:`|y_i^{(K+1)}|`.
    alpha : int
        ``K = k + alpha - 1``, ``alpha >= 1``.
    discretization : {"taylor", "euler"}

    Attributes
    ----------
    w_hat : ndarray, shape (m,)
    derivatives : ndarray, shape (p, K + 1)
        The differentiator's estimates of ``y`` and its derivatives.
    report : LeftInverseReport
    """

    def __init__(self, plant: LinearPlant, dt: float, lipschitz, *, alpha: int = 1, discretization: str = "taylor"):
        if not isinstance(plant, LinearPlant):
            raise TypeError(f"expected plant to be a LinearPlant, actual value: {type(plant).__name__}")
        self.plant = plant
        self.report = left_inverse(plant)
        if not self.report.static:
            raise NoStaticLeftInverseError(
                f"expected a triple with a static left inverse w = G(y, y', ..., y^(k)), actual value: "
                f"{self.report.reason}"
            )
        self.dt = check_positive("dt", dt)
        alpha = check_int_in_range("alpha", alpha, 1, MAX_LEVANT_ORDER)
        if discretization not in ("taylor", "euler"):
            raise ValueError(
                f"expected discretization to be one of 'taylor', 'euler', actual value: {discretization!r}"
            )
        self.G, self.n_derivatives = self.report.G, self.report.n_derivatives
        self.order = self.n_derivatives + alpha - 1
        if self.order > MAX_LEVANT_ORDER or self.order < 1:
            raise ValueError(
                f"expected a differentiator order k + alpha - 1 in [1, {MAX_LEVANT_ORDER}] (k={self.n_derivatives} "
                f"from the left inverse), actual value: {self.order}"
            )
        self.alpha = alpha
        p = plant.n_outputs
        # True, "2" or 10**400 are refused rather than converted
        if np.ndim(lipschitz) == 0:
            lip = np.full(p, check_positive("lipschitz", lipschitz))
        else:
            lip = as_real_array("lipschitz", lipschitz)
            if lip.shape not in ((1,), (p,)):
                raise ValueError(f"expected lipschitz a number or shape ({p},), actual value: shape {lip.shape}")
            lip = np.broadcast_to(lip, (p,)).copy()
        if not np.all(np.isfinite(lip) & (lip > 0)):
            raise ValueError(f"expected lipschitz > 0 for every output, actual value: {lip!r}")
        self.lipschitz = lip
        self.differentiator = Levant(self.order, self.dt, self.lipschitz, discretization=discretization)
        self._dstate = None
        self.w_hat = np.zeros(plant.n_unknown)
        self.derivatives = None

    @property
    def theoretical_orders(self) -> dict[str, float]:
        """Orders of the identification error: in ``tau`` (noise-free) and in the noise amplitude ``eta``."""
        return {"sampling": self.order + 1 - self.n_derivatives, "noise": self.alpha / (self.order + 1)}

    def reset(self, y0) -> np.ndarray:
        """Start the differentiator at ``y0`` (derivatives zero)."""
        y0 = as_real_array("y0", y0)
        self.differentiator.reset(y0)
        self._dstate = self.differentiator.state
        self.w_hat = np.zeros(self.plant.n_unknown)
        return self.w_hat

    def update(self, y) -> np.ndarray:
        """Process the sample ``y_k`` and return :math:`\\hat w_k`."""
        if self._dstate is None:
            raise RuntimeError("expected reset(y0) before update(y), actual value: the identifier was never reset")
        self._dstate, Z = self.differentiator.step(self._dstate, as_real_array("y", y))
        self.derivatives = Z
        k = self.n_derivatives
        self.w_hat = self.G @ Z[:, : k + 1].T.reshape(-1)
        return self.w_hat
