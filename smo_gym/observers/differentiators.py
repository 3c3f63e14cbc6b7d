r"""Model-free sliding-mode differentiators: super-twisting, Levant, URED, uniform Levant.

All estimate a signal ``f`` and its derivatives from samples ``y_k = f(t_k) + noise``, assuming only a bound
``L`` on the first derivative they do not estimate (``|f''| <= L`` for a velocity observer).

Discretizations (see ``DESIGN.md``)
-----------------------------------
``"euler"``
    explicit Euler of the continuous differentiator; chatters at the level ``L * tau`` in the last derivative.
``"taylor"``
    explicit, with the Taylor terms of Livne & Levant (2014): accuracy ``|z_i - f^(i)| = O(L tau^(k+1-i))``.
``"implicit"``
    set-valued implicit Euler (closed form for super-twisting; one monotone scalar equation for Levant, URED and
    uniform Levant, whose estimates are then Seeber's (2024) combinations of the states): chattering-free.
``"semi-implicit"``, ``"matching"``
    state-dependent eigenvalue mappings (15) and (16) of Wetzlinger, Reichhartinger and Horn:
    no discretization chattering and stable at any step for any initial error.

References
----------
.. [Lev03] A. Levant, "Higher-order sliding modes, differentiation and output-feedback control",
   Int. J. Control 76(9-10), 2003.
.. [LL14] M. Livne and A. Levant, "Proper discretization of homogeneous differentiators", Automatica 50, 2014.
.. [CMF11] E. Cruz-Zavala, J. A. Moreno and L. Fridman, "Uniform robust exact differentiator",
   IEEE TAC 56(11), 2011.
.. [AMF13] M. T. Angulo, J. A. Moreno and L. Fridman, "Robust exact uniformly convergent arbitrary order
   differentiator", Automatica 49(8), 2013.
.. [WRH] M. Wetzlinger, M. Reichhartinger and M. Horn, "Higher order sliding mode inspired nonlinear
   discrete-time observer".
.. [BPE] B. Brogliato, A. Polyakov and D. Efimov, "The implicit discretization of the super-twisting sliding-mode
   control algorithm", IEEE TAC 65(8), 2020.
"""

from __future__ import annotations

from math import comb

import numpy as np

from .._validation import (
    as_real_array,
    check_int_in_range,
    check_keywords,
    check_nonnegative,
    check_positive,
    check_positive_array,
)
from ..design.gains import (
    LEVANT_LAMBDAS,
    MAX_LEVANT_ORDER,
    binomial_coefficients,
    levant_nonrecursive,
    super_twisting_gains,
)
from . import _kernels
from .base import Observer, taylor_matrix
from .registry import lipschitz_rule, lipschitz_unit_rule, register_observer

__all__ = [
    "URED",
    "Levant",
    "SuperTwisting",
    "UniformLevant",
    "backward_difference_outputs",
    "eigenvalue_map_rate",
    "eigenvalue_mapping_vectors",
    "filtering_chain_matrix",
    "taylor_matrix",
]


def _check_optional_positive(**values) -> None:
    """Validate positive scalar-or-array parameters at construction (``None`` means "use the default")."""
    for name, value in values.items():
        if value is not None:
            check_positive_array(name, value)


def _pack_hosm(dt: float, taylor: bool, gains: np.ndarray, powers: np.ndarray) -> np.ndarray:
    """Parameter rows of the HOSM kernel: ``[dt, taylor, gains (m*J), powers (m*J)]`` per channel.

    ``gains`` has shape ``(N, m, J)``, ``powers`` ``(m, J)`` with ``J <= N_TERMS`` (padded with zero gains).
    """
    N, m, J = gains.shape
    g = np.zeros((N, m, _kernels.N_TERMS))
    p = np.zeros((m, _kernels.N_TERMS))
    g[:, :, :J] = gains
    p[:, :J] = powers
    head = np.tile([dt, 1.0 if taylor else 0.0], (N, 1))
    return np.hstack([head, g.reshape(N, -1), np.broadcast_to(p.reshape(1, -1), (N, m * _kernels.N_TERMS))])


def backward_difference_outputs(m: int, dt: float) -> np.ndarray:
    r"""The output matrix ``M``, shape ``(m, m)``, of the implicit (backward) Euler step of a signed-power
    differentiator: estimates :math:`\hat z = M\xi` from its states :math:`\xi` (Seeber 2024).

    In the dead zone of the implicit step (:func:`smo_gym.observers._kernels.hosm_implicit_channel_step`) the
    states are the backward differences of the samples, :math:`\xi_{j,k} = \nabla^j y_k / \tau^j` (the
    recursion :math:`\xi_j^+ = \xi_j + \tau\xi_{j+1}^+` with :math:`\xi_0 = y`), which are biased estimates
    of the derivatives (:math:`\xi_1 = f' - \tau f''/2 + \ldots`). Newton's backward formula
    :math:`\tau D = -\ln(1 - \nabla)` maps them to the derivatives, exactly for polynomials of degree ``m - 1``:

    .. math:: M_{ij} = \tau^{j-i}\,[x^j]\big(-\ln(1 - x)\big)^i,\qquad i \le j < m,

    unit upper triangular (:math:`M = I` for ``m = 2``; for ``m = 3`` :math:`\hat z_1 = \xi_1 + \tau\xi_2/2`).
    """
    series = np.r_[0.0, 1.0 / np.arange(1, m)]  # -ln(1 - x) up to x^(m-1)
    power = np.zeros(m)
    power[0] = 1.0
    M = np.zeros((m, m))
    j = np.arange(m)
    with np.errstate(over="ignore", invalid="ignore"):  # an overflow (inf, or 0 * inf) is reported below
        for i in range(m):
            M[i] = power * dt ** (j - i).clip(min=0)
            power = np.convolve(power, series)[:m]
    if not np.isfinite(M).all():
        raise ValueError(f"expected dt giving finite outputs (dt^{m - 1} representable), actual value: {dt!r}")
    return M


def _pack_hosm_implicit(dt: float, gains: np.ndarray, powers: np.ndarray) -> np.ndarray:
    """Parameter rows of the implicit HOSM kernel: ``[dt, gains (m*J), powers (m*J), M (m*m)]`` per channel, the
    injections as for :func:`_pack_hosm` and ``M`` of :func:`backward_difference_outputs`."""
    rows = _pack_hosm(dt, False, gains, powers)
    m = powers.shape[0]
    M = np.broadcast_to(backward_difference_outputs(m, dt).reshape(1, -1), (rows.shape[0], m * m))
    return np.hstack([rows[:, :1], rows[:, 2:], M])


class _ImplicitOutputs:
    r"""Mixin of the signed-power differentiators with an ``"implicit"`` discretization: their state then holds
    the backward-Euler coordinates :math:`\xi = M^{-1}\hat z` (:func:`backward_difference_outputs`)."""

    def _load_estimate(self, state, x0, params):
        if self.discretization != "implicit":
            return super()._load_estimate(state, x0, params)
        m = x0.shape[1]
        state[:, :m] = np.linalg.solve(backward_difference_outputs(m, self.dt), x0.T).T
        return None

    @property
    def reports_instant(self) -> bool:
        # Newton's backward formula: the outputs are the derivatives at the sample time, exact on polynomials
        return self.discretization == "implicit" or super().reports_instant


def _levant_sequence(gains, order: int) -> np.ndarray:
    """Levant's recursive parameters ``(lambda_0, ..., lambda_k)``: ``gains`` validated, or the paper's choice."""
    if gains is None:
        return np.array(LEVANT_LAMBDAS[: order + 1])
    lam = check_positive_array("gains", gains)
    if lam.shape != (order + 1,):
        raise ValueError(
            f"expected gains with shape ({order + 1},), Levant's (lambda_0, ..., lambda_{order}), actual value: "
            f"shape {lam.shape}"
        )
    return lam.copy()


def filtering_chain_matrix(m: int, dt: float, filtering_order: int = 0) -> np.ndarray:
    r"""The transition matrix :math:`\Phi` of the eigenvalue-map step over one step ``dt``, shape ``(n, n)`` with
    ``n = m + filtering_order``, in the state's column order :math:`(z_0, \ldots, z_{m-1}, w_1, \ldots, w_{nf})`.

    The ``z`` block is the Taylor matrix (31) (:func:`taylor_matrix`); each filter state :math:`w_i` moves by the
    Taylor terms of :math:`w_i, \ldots, w_{nf}` and by :math:`\tau^{nf-i+1}/(nf-i+1)!\,z_0`, the zero-order
    hold of the input :math:`u = z_0 - f` of the filter chain (the measurement's part,
    :math:`-\tau^{nf-i+1}/(nf-i+1)!\,y`, enters the step as an input; module :mod:`smo_gym.observers.filtering`).
    Without filter it is the Taylor matrix itself.
    """
    nf = filtering_order
    n = m + nf
    Phi = np.zeros((n, n))
    Phi[:m, :m] = taylor_matrix(m, dt)
    if nf:
        chain = taylor_matrix(nf + 1, dt)  # w_1, ..., w_nf and the held input in the last column
        Phi[m:, m:] = chain[:nf, :nf]
        Phi[m:, 0] = chain[:nf, nf]
    return Phi


def eigenvalue_mapping_vectors(m: int, dt: float, filtering_order: int = 0) -> np.ndarray:
    r"""Vectors :math:`v_j = \binom{n}{j} \Phi^j \mathcal{O}^{-1} e_n`, ``j = 0..n``, shape ``(n + 1, n)``,
    ``n = m + filtering_order``, in the state's column order.

    With :math:`\Phi` the transition matrix (:func:`filtering_chain_matrix`: the Taylor matrix (31) without filter)
    and ``c`` the error's row (``e_1``; the first filter state :math:`w_1` with a filter), Ackermann's formula (35)
    of [WRH] for the observer gain that puts all eigenvalues of :math:`\Phi - l c^T` at ``z`` expands to
    :math:`l(z) = \sum_j (-z)^{n-j} v_j`, a polynomial in ``z`` the kernel evaluates per sample by Horner's rule.

    Notes
    -----
    The closed-form gains (79)-(82) printed by Wetzlinger et al. are not stable (their eigenvalues are not the
    placed ones); these vectors come from Ackermann's formula itself, and the tests check the placed eigenvalues.
    """
    nf = filtering_order
    n = m + nf
    Phi = filtering_chain_matrix(m, dt, nf)
    if nf:  # Ackermann's formula in chain order (w_1 first: the measured error), then back to the columns
        order = np.r_[m:n, 0:m]
        Phi = Phi[np.ix_(order, order)]
    obs = np.vstack([np.linalg.matrix_power(Phi, i)[0] for i in range(n)])
    e_n = np.zeros(n)
    e_n[-1] = 1.0
    w = np.linalg.solve(obs, e_n)
    V = np.array([comb(n, j) * np.linalg.matrix_power(Phi, j) @ w for j in range(n + 1)])
    if nf:
        V = V[:, np.argsort(order)]
    return V


def eigenvalue_map_rate(lipschitz, m: int) -> np.ndarray:
    r"""The default rate :math:`p_1 = (1.1 L)^{1/m}` of the eigenvalue maps of Wetzlinger, Reichhartinger and Horn.

    Their continuous-time counterpart (11) has the gains of :math:`(s + p_1)^m`, whose last, :math:`p_1^m`, then
    equals Levant's :math:`\lambda_0 L` with :math:`\lambda_0 = 1.1` for a bound :math:`L \ge |f^{(m)}|`.
    ``lipschitz`` any shape; returns that shape.
    """
    return (1.1 * np.asarray(lipschitz, dtype=float)) ** (1.0 / m)


def _pack_eigmap(
    dt: float,
    p1: np.ndarray,
    mu: float,
    mode: str,
    m: int,
    *,
    predictor: bool = False,
    filtering_order: int = 0,
    degree: float = -1.0,
) -> np.ndarray:
    r"""Parameter rows of the eigenvalue-mapping kernel: ``[dt, p1, mu, mode, back, degree, V]`` per channel.

    ``back`` is how far the step moves its prediction back for the report: ``dt`` (the estimate at the sample
    time), or 0 with ``predictor`` (the predictor :math:`\hat\xi_{k+1}` itself). ``m`` estimates, after
    ``filtering_order`` filter states; ``degree`` the homogeneity degree of the eigenvalue (-1: Wetzlinger et al.'s
    maps). The one parameter construction of :class:`Levant`'s eigenvalue maps, :class:`DiscreteTimeHOSM` and
    :class:`~smo_gym.observers.FilteringDifferentiator`.
    """
    V = eigenvalue_mapping_vectors(m, dt, filtering_order).reshape(-1)
    N = p1.shape[0]
    head = np.column_stack(
        [
            np.full(N, dt),
            p1,
            np.full(N, mu),
            np.full(N, 0.0 if mode == "semi-implicit" else 1.0),
            np.full(N, 0.0 if predictor else dt),
            np.full(N, float(degree)),
        ]
    )
    return np.hstack([head, np.broadcast_to(V, (N, V.size))])


@register_observer(
    "super-twisting",
    steps=(_kernels.sta_implicit_rows, _kernels.hosm_rows),
    bound=2,
    calibrate=lipschitz_rule,
    given=(("lipschitz",), ("k1", "k2")),
    examples=(dict(lipschitz=5.0, discretization="implicit"), dict(lipschitz=5.0, discretization="euler")),
)
class SuperTwisting(Observer):
    r"""Levant's first-order robust exact differentiator (super-twisting algorithm).

    .. math::
        \dot{\hat x}_1 = \hat x_2 - k_1 \lceil \hat x_1 - y\rfloor^{1/2},\qquad
        \dot{\hat x}_2 = -k_2\,\mathrm{sign}(\hat x_1 - y),

    with defaults :math:`k_1 = 1.5\sqrt L,\ k_2 = 1.1 L` for :math:`|\ddot f| \le L` (Fridman's slides, "STA observer").
    Converges in finite time to :math:`\hat x_1 = f,\ \hat x_2 = \dot f`.

    Parameters
    ----------
    dt : float
        Sampling step ``tau > 0`` [s].
    lipschitz : float or array_like, optional
        ``L``, bound on ``|f''|`` (per channel if an array broadcastable to ``(..., n_channels)``). Required unless
        both ``k1`` and ``k2`` are given.
    k1, k2 : float or array_like, optional
        Override the default gains.
    discretization : {"implicit", "euler"}
        ``"implicit"`` (default): the set-valued implicit Euler step [BPE] in closed form; on a constant signal the
        derivative becomes exactly zero, and it is stable at any step. ``"euler"``: explicit Euler, chattering of
        amplitude ``O(k2 tau)`` in the derivative.
    wrap : bool or array_like of bool, optional
        Channels measured as angles modulo ``2 pi`` (see :class:`~smo_gym.observers.Observer`).

    Notes
    -----
    The implicit step is an estimator at the current sample (it uses ``y_k`` to produce ``xhat_k``). When the
    predicted error is within ``tau^2 k2`` of the measurement it sets ``xhat_1 = y_k`` and
    ``xhat_2 = (y_k - xhat_{1,k-1}) / tau``: inside its sliding set it *is* a backward difference of its own
    estimate, which is why at coarse steps with large ``L`` it matches finite differences (DESIGN.md).
    """

    discretizations = ("implicit", "euler")

    @check_keywords
    def __init__(self, dt: float, lipschitz=None, *, k1=None, k2=None, discretization: str | None = None, wrap=None):
        super().__init__(dt, 1, discretization, wrap)
        if lipschitz is None and (k1 is None or k2 is None):
            raise ValueError("expected lipschitz > 0 or both k1 and k2, actual value: lipschitz=None")
        _check_optional_positive(lipschitz=lipschitz, k1=k1, k2=k2)  # fail at construction, not at reset
        self.lipschitz, self.k1, self.k2 = lipschitz, k1, k2

    def _gains(self, shape):
        L = None if self.lipschitz is None else self._per_channel("lipschitz", self.lipschitz, shape)
        k1 = super_twisting_gains(L)[0] if self.k1 is None else self._per_channel("k1", self.k1, shape)
        k2 = super_twisting_gains(L)[1] if self.k2 is None else self._per_channel("k2", self.k2, shape)
        return np.asarray(k1, dtype=float).reshape(-1), np.asarray(k2, dtype=float).reshape(-1)

    @property
    def _kernel(self):
        return _kernels.sta_implicit_kernel if self.discretization == "implicit" else _kernels.hosm_kernel

    def _predicts(self):
        return self.discretization == "euler"

    def _channel_params(self, shape):
        k1, k2 = self._gains(shape)
        if self.discretization == "implicit":
            return np.column_stack([np.full(k1.shape, self.dt), k1, k2])
        return _pack_hosm(self.dt, False, np.stack([k1, k2], axis=1)[:, :, None], np.array([[0.5], [0.0]]))


@register_observer(
    "levant",
    steps=(_kernels.hosm_rows, _kernels.eigmap_rows, _kernels.hosm_implicit_rows),
    calibrate=lipschitz_rule,
    given=(("lipschitz",),),
    examples=tuple(
        dict(order=k, lipschitz=5.0, discretization=d)
        for k, d in [
            (1, "taylor"),
            (2, "taylor"),
            (3, "euler"),
            (2, "semi-implicit"),
            (3, "matching"),
            (5, "taylor"),
            (2, "implicit"),
            (4, "implicit"),
        ]
    ),
)
class Levant(_ImplicitOutputs, Observer):
    r"""Levant's arbitrary-order robust exact differentiator (Fridman's slides, eq. (7); [Lev03]).

    For ``|f^(k+1)| <= L`` the order-``k`` differentiator, in the non-recursive form equivalent to (7)
    (see :func:`smo_gym.design.levant_lambdas`),

    .. math::
        \dot z_i = -\Lambda_{i+1} L^{\frac{i+1}{k+1}} \lceil z_0 - f\rfloor^{\frac{k-i}{k+1}} + z_{i+1},
        \quad i < k,\qquad \dot z_k = -\lambda_0 L\,\mathrm{sign}(z_0 - f),

    gives :math:`z_i = f^{(i)}` after a finite time.

    Parameters
    ----------
    order : int
        ``k`` in ``[1, 5]`` (Levant's table of lambdas).
    dt : float
        Sampling step.
    lipschitz : float or array_like
        ``L``, per channel if an array.
    discretization : {"implicit", "taylor", "euler", "semi-implicit", "matching"}
        ``"implicit"`` (default): set-valued implicit (backward) Euler ([MBA21], [CSLD]) with the outputs of
        [See24] (Notes); it neither chatters nor diverges with gains calibrated from data, where the explicit steps
        do (the wrapper's accuracy tables: geometric-mean regret 1.17 against 64 for ``"taylor"``); on the smooth
        signals of ``scripts/bench_signals.py`` it is within 6 % of ``"taylor"`` at 1 ms and up to 20x better at
        10 ms. ``"taylor"`` ([LL14]): accuracy ``O(L tau^(k+1-i))`` for ``z_i`` on noise-free signals, and
        ``O(L^(i/(k+1)) eps^((k+1-i)/(k+1)))`` under noise of amplitude ``eps``. ``"euler"``: the same without the
        Taylor terms, hence first order (``O(tau^2)`` in ``z_0``, ``O(tau)`` in every derivative; measured in
        ``tests/test_differentiators.py``). ``"semi-implicit"`` / ``"matching"``: the discrete-time observer of
        Wetzlinger et al. with eigenvalue mapping (15) / (16); its continuous-time counterpart (11) is a Levant-type
        differentiator with gains from ``(s + p1)^(k+1)``.
    p1 : float, optional
        Eigenvalue-mapping rate of Wetzlinger et al.; default ``(1.1 L)^(1/(k+1))`` so that the last gain
        ``p1^(k+1)`` equals Levant's ``lambda_0 L``.
    mu : float
        Wetzlinger et al.'s ``mu >= 0`` (0 gives finite-time, ``mu > 0`` adds the uniform, fixed-time part).
    gains : array_like, shape (order + 1,), optional
        Levant's parameters :math:`(\lambda_0, \ldots, \lambda_k)` of the recursive form (7), indexed as in the
        paper (:math:`\lambda_0` multiplies :math:`L\,\mathrm{sign}` in the last equation, :math:`\lambda_k` the
        first correction); the kernel runs the equivalent non-recursive gains
        (:func:`smo_gym.design.levant_nonrecursive`). Default: the sequence of [Lev03] printed below (7) in paper
        004, :math:`\lambda_0, \ldots, \lambda_5 = 1.1, 1.5, 2, 3, 5, 8`. [Lev03] shows convergence for
        parameters chosen large enough one after the other, starting from :math:`\lambda_0 > 1`; the printed
        sequence is one such choice for ``k <= 5``, not a law, so other sequences are accepted as given (only
        their shape and positivity are checked: convergence with them is the caller's choice). For ``"taylor"``,
        ``"euler"`` and ``"implicit"`` only: the eigenvalue mappings are tuned by ``p1``.
    wrap : bool or array_like of bool, optional
        Channels measured as angles modulo ``2 pi`` (see :class:`~smo_gym.observers.Observer`).

    Notes
    -----
    ``"implicit"`` (:func:`smo_gym.observers._kernels.hosm_implicit_channel_step`): the backward Euler step
    :math:`\xi^+ = \xi + \tau(A\xi^+ + \psi(y^+ - \xi_0^+))` of the differentiator, with
    :math:`\psi_i(\sigma) = \Lambda_{i+1}L^{(i+1)/(k+1)}\lceil\sigma\rfloor^{(k-i)/(k+1)}` and the
    set-valued sign in the last state. Solving the shift for :math:`\xi^+` leaves one scalar equation in the new
    output error :math:`\sigma^+`, :math:`\sigma^+ + \sum_i \tau^{i+1}\psi_i(\sigma^+) = \rho` with
    :math:`\rho` the error of the prediction :math:`(I - \tau A)^{-1}\xi`; its left side increases strictly, so
    it has one solution, :math:`\sigma^+ = 0` (the estimate sticks to the measurement) when
    :math:`|\rho| \le \tau^{k+1}\lambda_0 L`, and every other state is then explicit. In that dead zone the
    states are the backward differences :math:`\nabla^i y/\tau^i`, biased by :math:`O(\tau)`; the estimates
    are their combinations by Newton's backward formula (:func:`backward_difference_outputs`), which, as
    [See24] shows for his outputs, removes the bias: on a noise-free signal with :math:`|f^{(k+1)}| \le L`
    (:math:`\lambda_0 > 1`), the estimate sticks after convergence and :math:`|\hat z_i - f^{(i)}| =
    O(L\tau^{k+1-i})` (measured in ``tests/test_implicit_differentiators.py``), with no chattering.

    References
    ----------
    .. [MBA21] M. R. Mojallizadeh, B. Brogliato and V. Acary, "Time-discretizations of differentiators: design
       of implicit algorithms and comparative analysis", Int. J. Robust Nonlinear Control 31(16), 2021.
    .. [CSLD] J. E. Carvajal-Rubio, J. D. Sanchez-Torres, A. G. Loukianov and M. Defoort, implicit and exact
       discretizations of the arbitrary-order differentiator.
    .. [See24] R. Seeber, "Proper implicit discretization of arbitrary-order robust exact differentiators",
       arXiv:2404.02770, 2024.
    """

    discretizations = ("implicit", "taylor", "euler", "semi-implicit", "matching")

    @check_keywords
    def __init__(
        self,
        order: int = 2,
        dt: float = 1e-3,
        lipschitz=1.0,
        *,
        discretization: str | None = None,
        p1=None,
        mu: float = 0.0,
        gains=None,
        wrap=None,
    ):
        order = check_int_in_range("order", order, 1, MAX_LEVANT_ORDER)
        super().__init__(dt, order, discretization, wrap)
        self.lipschitz = lipschitz
        check_positive_array("lipschitz", lipschitz)  # validate now, not at reset
        eigmap = self.discretization in ("semi-implicit", "matching")
        if p1 is not None:
            if not eigmap:  # the Taylor and Euler steps have no eigenvalue map: a p1 would be silently ignored
                raise ValueError(
                    "expected p1 only with discretization 'semi-implicit' or 'matching', actual "
                    f"value: p1={p1!r} with discretization {self.discretization!r}"
                )
            check_positive_array("p1", p1)
        self.p1 = p1
        self.mu = check_nonnegative("mu", mu)
        if eigmap:
            try:
                with np.errstate(all="ignore"):
                    finite = np.isfinite(eigenvalue_mapping_vectors(order + 1, self.dt)).all()
            except np.linalg.LinAlgError:  # dt^order underflows: a singular observability matrix
                finite = False
            if not finite:
                raise ValueError(
                    f"expected dt giving a finite eigenvalue mapping (dt^{order} representable), actual "
                    f"value: {self.dt!r}"
                )
        if self.mu != 0.0 and not eigmap:
            raise ValueError(
                "expected mu only with discretization 'semi-implicit' or 'matching' (the uniform part "
                f"of Wetzlinger, Reichhartinger and Horn's observer), actual value: mu={mu!r} with "
                f"discretization {self.discretization!r}"
            )
        if gains is not None and self.discretization in ("semi-implicit", "matching"):
            raise ValueError(
                "expected gains only with discretization 'taylor', 'euler' or 'implicit' (the eigenvalue mappings "
                "are tuned by p1), "
                f"actual value: gains={gains!r} with discretization={self.discretization!r}"
            )
        self.gains = _levant_sequence(gains, order)

    @property
    def _kernel(self):
        if self.discretization in ("semi-implicit", "matching"):
            return _kernels.eigmap_kernel
        return _kernels.hosm_implicit_kernel if self.discretization == "implicit" else _kernels.hosm_kernel

    @property
    def reports_instant(self) -> bool:
        return self.discretization in ("taylor", "matching", "implicit")

    def _predicts(self):
        return self.discretization != "implicit"

    def _channel_params(self, shape):
        k, m = self.order, self.order + 1
        L = self._per_channel("lipschitz", self.lipschitz, shape)
        if self.discretization in ("semi-implicit", "matching"):
            p1 = eigenvalue_map_rate(L, m) if self.p1 is None else self._per_channel("p1", self.p1, shape)
            return _pack_eigmap(self.dt, p1, self.mu, self.discretization, m)
        lam = levant_nonrecursive(self.gains)
        gains = lam[None, :] * L[:, None] ** (np.arange(1, m + 1) / m)[None, :]
        powers = ((k - np.arange(m)) / m)[:, None]
        if self.discretization == "implicit":
            return _pack_hosm_implicit(self.dt, gains[:, :, None], powers)
        return _pack_hosm(self.dt, self.discretization == "taylor", gains[:, :, None], powers)


def _ured_rule(cls, calibration, order, kwargs):
    """:func:`~smo_gym.observers.registry.lipschitz_rule` with ``beta`` one over the calibration's ``unit`` per
    channel (its dimension is 1/[y]), unless given."""
    return lipschitz_rule(cls, calibration, order, {"beta": 1.0 / calibration.unit, **kwargs})


@register_observer(
    "ured",
    steps=(_kernels.hosm_rows, _kernels.hosm_implicit_rows),
    bound=2,
    calibrate=_ured_rule,
    given=(("lipschitz",), ("k1", "k2")),
    examples=(dict(lipschitz=5.0), dict(lipschitz=5.0, discretization="euler")),
)
class URED(_ImplicitOutputs, Observer):
    r"""Uniform robust exact differentiator of Cruz-Zavala, Moreno and Fridman [CMF11] (in Fridman's slides).

    .. math::
        \dot z_0 = -k_1 \phi_1(z_0 - y) + z_1,\quad \dot z_1 = -k_2 \phi_2(z_0 - y),\\
        \phi_1(\sigma) = \lceil\sigma\rfloor^{1/2} + \beta\lceil\sigma\rfloor^{3/2},\quad
        \phi_2(\sigma) = \tfrac12\mathrm{sign}(\sigma) + 2\beta\sigma + \tfrac32\beta^2\lceil\sigma\rfloor^{2}.

    Convergence time is bounded uniformly in the initial error. The slides print ``beta = 1``.

    Parameters
    ----------
    dt : float
    lipschitz : float or array_like
        ``L >= |f''|``; defaults ``k1 = 1.5 sqrt(L)``, ``k2 = 2.2 L`` so that near the origin (where the
        ``beta`` terms vanish) it is the super-twisting differentiator with Levant's gains.
    k1, k2 : optional overrides.
    beta : float or array_like
        Weight of the high-degree terms (units 1/[y]; per channel if an array); larger means faster from large
        errors. Calibrated (the registry's gain rule) it is one over the calibration's
        :attr:`~smo_gym.calibration.Calibration.unit`: 1 for the wrapper's joints, so that a record in other
        units gives the same estimates in them.
    discretization : {"implicit", "euler"}
        Default ``"implicit"``. ``"euler"``: explicit Euler. The high-degree terms make it stiff: at error ``|e|``
        the step must satisfy roughly ``tau * k1 * beta * |e|^(1/2) < 1``, otherwise it diverges (raised as
        ``DivergenceError``).
        ``"implicit"``: set-valued implicit (backward) Euler, stable at any step and from any initial error, with
        the outputs of [See24] (as for :class:`Levant`, Notes there: the scalar equation in the new output error
        gains the high-degree terms and stays strictly increasing).
    wrap : bool or array_like of bool, optional
        Channels measured as angles modulo ``2 pi`` (see :class:`~smo_gym.observers.Observer`).
    """

    discretizations = ("implicit", "euler")

    @check_keywords
    def __init__(
        self,
        dt: float,
        lipschitz=1.0,
        *,
        k1=None,
        k2=None,
        beta: float = 1.0,
        discretization: str | None = None,
        wrap=None,
    ):
        super().__init__(dt, 1, discretization, wrap)
        _check_optional_positive(lipschitz=lipschitz, k1=k1, k2=k2, beta=beta)  # fail at construction, not at reset
        self.lipschitz, self.k1, self.k2, self.beta = lipschitz, k1, k2, beta

    @property
    def _kernel(self):
        return _kernels.hosm_implicit_kernel if self.discretization == "implicit" else _kernels.hosm_kernel

    def _predicts(self):
        return self.discretization != "implicit"

    def _channel_params(self, shape):
        L = self._per_channel("lipschitz", self.lipschitz, shape)
        k1 = 1.5 * np.sqrt(L) if self.k1 is None else self._per_channel("k1", self.k1, shape)
        k2 = 2.2 * L if self.k2 is None else self._per_channel("k2", self.k2, shape)
        b = self._per_channel("beta", self.beta, shape)
        gains = np.zeros((k1.size, 2, 3))
        with np.errstate(over="ignore"):
            gains[:, 0, 0], gains[:, 0, 1] = k1, k1 * b
            gains[:, 1, 0], gains[:, 1, 1], gains[:, 1, 2] = 0.5 * k2, 2.0 * b * k2, 1.5 * b * b * k2
        if not np.isfinite(gains).all():
            raise ValueError(
                f"expected beta and the gains small enough that beta^2 k2 is finite, actual value: beta={self.beta!r}, "
                f"k2 up to {float(np.max(k2)):.3g}"
            )
        powers = np.array([[0.5, 1.5, 0.0], [0.0, 1.0, 2.0]])
        if self.discretization == "implicit":
            return _pack_hosm_implicit(self.dt, gains, powers)
        return _pack_hosm(self.dt, False, gains, powers)


@register_observer(
    "uniform-levant",
    steps=(_kernels.hosm_rows, _kernels.hosm_implicit_rows),
    calibrate=lipschitz_unit_rule,
    given=(("lipschitz",),),
    examples=(
        dict(order=2, lipschitz=5.0),
        dict(order=3, lipschitz=5.0, discretization="taylor"),
        dict(order=2, lipschitz=5.0, discretization="euler"),
    ),
)
class UniformLevant(_ImplicitOutputs, Observer):
    r"""Arbitrary-order uniform robust exact differentiator of Angulo, Moreno and Fridman [AMF13].

    Eq. (8) of Fridman's lecture slides.

    With ``n = order + 1`` states and :math:`e = y - \hat x_1`,

    .. math::
        \dot{\hat x}_i = \lambda_i L^{i/n}\lceil e\rfloor^{\frac{n-i}{n}} + k_i\lceil e\rfloor^{\frac{n+\alpha i}{n}}
        + \hat x_{i+1},\quad
        \dot{\hat x}_n = \lambda_n L\,\mathrm{sign}(e) + k_n \lceil e\rfloor^{1+\alpha}.

    The low-degree terms are Levant's (non-recursive lambdas); the high-degree ones make the convergence time
    uniform in the initial error.

    Parameters
    ----------
    order : int
        ``1 <= order <= 5``.
    dt, lipschitz : as for :class:`Levant`.
    alpha : float
        ``alpha > 0``; default 1, which for ``order = 1`` gives URED's exponents 3/2 and 2.
    k : array_like, shape (order + 1,), optional
        Coefficients making ``s^n + k_1 s^(n-1) + ... + k_n`` Hurwitz; default those of
        ``(s + (L / unit^(1 + alpha))^(1/n))^n``, so that at an error of one ``unit`` the uniform part has the
        time scale of the Levant part.
    unit : float or array_like
        The size of one unit of ``y`` for the default ``k`` (per channel if an array; default 1). Calibrated (the
        registry's gain rule) it is the calibration's :attr:`~smo_gym.calibration.Calibration.unit`: 1 for the
        wrapper's joints, so that a record in other units gives the same estimates in them.
    gains : array_like, shape (order + 1,), optional
        Levant's parameters :math:`(\lambda_0, \ldots, \lambda_k)` of the low-degree terms, as for
        :class:`Levant` (default the sequence of [Lev03]).
    discretization : {"implicit", "euler", "taylor"}
        Default ``"implicit"``. ``"euler"``, ``"taylor"``: explicit; stiff for large errors like :class:`URED`
        (errors raise ``DivergenceError``). ``"implicit"``: set-valued implicit (backward) Euler with the outputs
        of [See24], as for :class:`Levant` (Notes there), stable at any step and from any initial error.
    wrap : bool or array_like of bool, optional
        Channels measured as angles modulo ``2 pi`` (see :class:`~smo_gym.observers.Observer`).

    Notes
    -----
    The slides print the injections as :math:`-\lambda_i\lceil y - \hat x_1\rfloor^{\cdot}`, which with
    :math:`\dot{\hat x}_1 = \ldots + \hat x_2` pushes the estimate *away* from ``y``; the derivation (and [AMF13])
    needs the error ``y - xhat_1`` with positive sign, as implemented. The printed stability condition on
    ``P(s) = k_n s^(n-1) + ... + k_1`` is garbled; we use the Hurwitz condition of the linear limit
    ``alpha -> 0``, ``s^n + k_1 s^(n-1) + ... + k_n``.
    """

    discretizations = ("implicit", "euler", "taylor")

    @check_keywords
    def __init__(
        self,
        order: int = 2,
        dt: float = 1e-3,
        lipschitz=1.0,
        *,
        alpha: float = 1.0,
        k=None,
        unit=1.0,
        gains=None,
        discretization: str | None = None,
        wrap=None,
    ):
        order = check_int_in_range("order", order, 1, MAX_LEVANT_ORDER)
        super().__init__(dt, order, discretization, wrap)
        _check_optional_positive(lipschitz=lipschitz, unit=unit)  # fail at construction, not at reset
        self.lipschitz, self.unit = lipschitz, unit
        self.alpha = check_positive("alpha", alpha)
        if k is not None:
            k = as_real_array("k", k)
            if k.shape != (order + 1,) or not np.isfinite(k).all():
                raise ValueError(f"expected finite k with shape ({order + 1},), actual value: {k!r}")
            roots = np.roots(np.concatenate([[1.0], k]))
            if np.any(roots.real >= 0):
                raise ValueError(
                    f"expected k making s^n + k_1 s^(n-1) + ... + k_n Hurwitz, actual value: roots {roots}"
                )
        self.k = k
        self.gains = _levant_sequence(gains, order)

    @property
    def _kernel(self):
        return _kernels.hosm_implicit_kernel if self.discretization == "implicit" else _kernels.hosm_kernel

    def _predicts(self):
        return self.discretization != "implicit"

    def _channel_params(self, shape):
        n = self.order + 1
        L = self._per_channel("lipschitz", self.lipschitz, shape)
        i = np.arange(1, n + 1)
        lam = levant_nonrecursive(self.gains)[None, :] * L[:, None] ** (i / n)[None, :]
        if self.k is None:
            unit = self._per_channel("unit", self.unit, shape)
            rates = (L / unit ** (1.0 + self.alpha)) ** (1.0 / n)
            kk = np.stack([binomial_coefficients(n, float(rate)) for rate in rates])
        else:
            kk = np.broadcast_to(self.k, (L.size, n))
        gains = np.stack([lam, kk], axis=2)
        powers = np.stack([(n - i) / n, (n + self.alpha * i) / n], axis=1)
        if self.discretization == "implicit":
            return _pack_hosm_implicit(self.dt, gains, powers)
        return _pack_hosm(self.dt, self.discretization == "taylor", gains, powers)
