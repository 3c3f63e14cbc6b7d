r"""Sampled-data state observers for linear plants with unknown inputs.

:class:`LuenbergerObserver`
    the classical observer (the baseline, and the first stage of the cascade).
:class:`CascadedHOSMObserver`
    Fridman, Levant and Davila's cascade (Fridman's slides, section 3, eq. (10)-(11); the "HOSM algebraic observer" of
    section 6): a Luenberger observer bounds the estimation error, a HOSM differentiator
    (:class:`smo_gym.observers.Levant`, the same one the rest of smo_gym uses) differentiates the output error,
    Molinari's algebraic relation turns those derivatives into the state error, and the unknown input is
    identified from the error's derivative.

Sampled-data form of the cascade
--------------------------------
In continuous time the Luenberger copy :math:`\dot{\tilde x} = A\tilde x + Bu + L(y - C\tilde x)` gives
:math:`\dot e = (A - LC)e + Dw` for :math:`e = x - \tilde x`, and the slides identify
:math:`\hat w = D^+(\dot e - (A - LC)e)`. A sampled controller only has :math:`y_k = y(t_k)`: holding
:math:`y_k` inside the injection adds :math:`LC(x(t) - x(t_k))`, an ``O(tau)`` sawtooth in :math:`\dot e`
that caps the accuracy whatever the differentiator's order (measured on the slides' Furuta model with
``injection="held"``: velocity error order ~1 instead of ``alpha + 1``, identification order 1.1-1.5 instead of
``alpha``; ``scripts/control_experiments.py``, ablation table). Here the
injection is applied at the sampling instants instead (the "current" observer
:math:`\tilde x_k^+ = \tilde x_k^- + L_d(y_k - C\tilde x_k^-)`, exact ZOH prediction between samples), so that
*between samples* the error obeys exactly

.. math:: \dot e = A e + D w,

and it jumps by the known :math:`\Delta e_k = -L_d (y_k - C\tilde x_k^-)` at the samples. The differentiator's
predictor (its state estimates the output error and its derivatives at the next sample, see
:mod:`smo_gym.observers._kernels`) is shifted by the exactly known effect of that jump,
:math:`C A^j e^{A\tau}\Delta e_k` on the ``j``-th derivative, so the differentiator sees a smooth signal and keeps
its accuracy ``O(L tau^(k+1-j))``. The identification then uses ``A`` (not ``A - LC``):
:math:`\hat w = D^+(\hat{\dot e} - A\hat e)`; as ``tau -> 0`` with :math:`L_d = \tau L` this is the slides'
formula. ``L_d`` puts the eigenvalues of :math:`e^{A\tau}(I - L_d C)` at :math:`e^{\lambda_i\tau}` for the
continuous-time poles :math:`\lambda_i` requested.

Accuracy (Fridman's slides, section 6, after Angulo et al. 2011)
---------------------------------------------------------
With Molinari's relation needing output derivatives up to ``N`` and the differentiator of order
``k = N + alpha`` (``alpha >= 1``: the number of bounded derivatives of ``w`` the estimate exploits), the state
error is ``O(tau^(alpha + 1))`` and the identification error ``O(tau^alpha)`` for noise-free samples;
with noise of amplitude ``eta`` they are ``O(eta^((alpha+1)/(k+1)))`` and ``O(eta^(alpha/(k+1)))``.

References
----------
.. [FLD07] L. Fridman, A. Levant and J. Davila, "Observation of linear systems with unknown inputs via high-order
   sliding-modes", Int. J. Systems Science 38(10), 2007.
.. [Fri] L. Fridman, "Sliding Mode Observers: Theory and Practice", lecture slides, sections 3 and 6.
.. [AMF11] M. T. Angulo, L. Fridman and A. Levant, "Robust exact finite-time output based control using high-order
   sliding modes", Int. J. Systems Science 42(11), 2011.
.. [Mol76] B. P. Molinari, "A strong controllability and observability in linear multivariable control",
   IEEE TAC 21(5), 1976.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla

from .._validation import (
    DivergenceError,
    as_real_array,
    check_choice,
    check_int_in_range,
    check_nonnegative,
    check_nonnegative_array,
    check_positive,
)
from ..design.gains import MAX_LEVANT_ORDER, _placed_gain
from ..observers import Levant
from .plants import LinearPlant, _matrix, _square_matrix, molinari_decoupling

__all__ = ["CascadedHOSMObserver", "LuenbergerObserver", "output_error_lipschitz", "sampled_observer_gain"]


def _output_sample(name: str, y, p: int, what: str = "output") -> np.ndarray:
    """``y`` as a finite float vector of the ``p`` outputs (inputs, states: ``what``), or a typed error: a wrong
    length would broadcast silently against ``C x``, a NaN would stay in the estimate."""
    arr = as_real_array(name, y)
    arr = arr.reshape(-1) if arr.ndim <= 1 else arr
    if arr.shape != (p,):
        raise ValueError(f"expected {name} with shape ({p},) (one value per {what}), actual value: shape {np.shape(y)}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"expected a finite {name}, actual value: {arr!r}")
    return arr


def _observer_poles(poles, A: np.ndarray) -> np.ndarray:
    """Continuous-time observer poles (default :func:`_default_poles`), checked: ``n`` finite numbers with negative
    real parts (a bool or a string is not a pole)."""
    if poles is None:
        return _default_poles(A)
    raw = np.asarray(poles)
    if raw.dtype.kind not in "iufc":
        raise TypeError(f"expected observer poles to be numbers, actual value: {poles!r:.80}")
    out = raw.astype(complex)
    n = A.shape[0]
    if out.shape != (n,) or not np.all(np.isfinite(out)) or np.any(out.real >= 0):
        raise ValueError(
            f"expected {n} continuous-time observer poles with negative real parts, actual value: {poles!r}"
        )
    return out


def _finite_estimate(x: np.ndarray, what: str) -> np.ndarray:
    """``x``, or a DivergenceError if an entry is not finite (the caller has not stored it yet)."""
    if not np.all(np.isfinite(x)):
        raise DivergenceError(f"expected a finite estimate after {what}, actual value: {x!r:.120}; the state was kept")
    return x


def _highest_block(M: np.ndarray, p: int, a: float = 1.0) -> int:
    """Index of the last block of ``p`` columns of ``M`` with a non-negligible entry, block ``k`` weighted by ``a^k``.

    The estimators' maps weigh ``y, y', y'', ...`` block by block: with ``a = ||A||`` each block is compared at the
    size of what it multiplies (``||y^(k)|| ~ ||C|| ||A||^k``), since raw weights scale as ``a^-k`` and the answer
    would depend on the time unit. Compared in logarithms, where ``a^k`` cannot overflow.
    """
    k = np.arange(M.shape[1]) // p
    with np.errstate(divide="ignore"):  # a zero column: log 0 = -inf, never above the threshold
        size = np.log(np.abs(M).max(axis=0, initial=0.0)) + k * np.log(a or 1.0)
    big = k[size > size.max(initial=-np.inf) + np.log(1e-9)]
    return int(big.max()) if big.size else 0


def _default_poles(A: np.ndarray) -> np.ndarray:
    n = A.shape[0]
    speed = max(10.0, 2.0 * np.abs(np.linalg.eigvals(A).real).max())
    return -speed * (1.0 + 0.15 * np.arange(n))


def sampled_observer_gain(A, C, dt: float, poles=None) -> np.ndarray:
    r"""Gain ``L_d`` of the current observer :math:`\tilde x^+ = \tilde x^- + L_d(y - C\tilde x^-)`.

    Places the eigenvalues of :math:`\Phi(I - L_d C)`, :math:`\Phi = e^{A\tau}` (the error map from one sample's
    prior to the next), at :math:`e^{\lambda_i \tau}` for the continuous-time ``poles`` :math:`\lambda_i` (default
    distinct reals at least twice as fast as the plant). With :math:`L' = \Phi L_d` this is the standard
    placement for :math:`\Phi - L'C` (``scipy.signal.place_poles`` on the dual pair).

    Returns
    -------
    ndarray, shape (n, p)
    """
    A = _square_matrix("A", A)
    C = _matrix("C", np.atleast_2d(C), (None, A.shape[0]))
    dt = check_positive("dt", dt)
    poles = _observer_poles(poles, A)
    with np.errstate(over="ignore", invalid="ignore"):
        Phi = sla.expm(A * dt)
    if not np.isfinite(Phi).all():
        raise ValueError(f"expected a sampling step over which the plant's transition stays finite, actual value: {dt}")
    Lp = _placed_gain(Phi, C, np.exp(poles * dt))  # Phi - Lp C has the requested eigenvalues
    return np.linalg.solve(Phi, Lp)


def output_error_lipschitz(plant: LinearPlant, order: int, *, e_bound: float = 0.0, w_bounds=(1.0,)) -> np.ndarray:
    r"""Per-output bound ``L`` on the ``(order + 1)``-th derivative of the output error, for the differentiator.

    Between samples :math:`\dot e = Ae + Dw`, hence

    .. math:: y_e^{(k+1)} = C A^{k+1} e + \sum_{i=0}^{k} C A^{k-i} D\, w^{(i)},\qquad
              |y_{e,j}^{(k+1)}| \le \|c_j A^{k+1}\|\, e^+ + \sum_i \|c_j A^{k-i} D\|\, w_i^+ ,

    with ``e_bound`` :math:`=e^+ \ge \|e\|` (the Luenberger error after its transient) and ``w_bounds[i]``
    :math:`=w_i^+ \ge \|w^{(i)}\|` (the last entry is reused for higher derivatives).

    Returns
    -------
    ndarray, shape (p,)
    """
    if not isinstance(plant, LinearPlant):
        raise TypeError(f"expected a LinearPlant, actual value: {type(plant).__name__}")
    A, C, D = plant.A, plant.C, plant.D
    order = check_int_in_range("order", order, 0, 64)
    wb = list(check_nonnegative_array("w_bounds", w_bounds).reshape(-1))
    L = np.linalg.norm(C @ np.linalg.matrix_power(A, order + 1), axis=1) * check_nonnegative("e_bound", e_bound)
    for i in range(order + 1):
        wi = wb[min(i, len(wb) - 1)]
        L = L + np.linalg.norm(C @ np.linalg.matrix_power(A, order - i) @ D, axis=1) * wi
    return L


class LuenbergerObserver:
    r"""Sampled-data Luenberger observer (the "current" form), the baseline of the experiments.

    .. math::
        \tilde x_k^+ = \tilde x_k^- + L_d\,(y_k - C\tilde x_k^-),\qquad
        \tilde x_{k+1}^- = \Phi\,\tilde x_k^+ + \Gamma u_k,

    with the exact ZOH pair :math:`(\Phi, \Gamma)`. ``update(y)`` returns :math:`\hat x_k = \tilde x_k^+`;
    ``advance(u)`` applies the prediction with the control actually commanded over the next interval. Unknown
    inputs are ignored (so the estimate is biased under a persistent ``w``): ``w_hat`` is always zero.

    Parameters
    ----------
    plant : LinearPlant
    dt : float
        Sampling step ``tau``.
    poles : array_like, shape (n,), optional
        Continuous-time poles of the error dynamics (see :func:`sampled_observer_gain`).
    """

    n_w_derivatives = 0

    def __init__(self, plant: LinearPlant, dt: float, *, poles=None):
        self.plant = plant
        self.dt = check_positive("dt", dt)
        self.Phi, self.Gamma = plant.discretize(self.dt)
        self.L = sampled_observer_gain(plant.A, plant.C, self.dt, poles)
        self._prior = None
        self.x_hat = None
        self.w_hat = np.zeros(plant.n_unknown)
        self.w_hat_derivatives = np.zeros((1, plant.n_unknown))

    def reset(self, y0, x_hat0=None) -> np.ndarray:
        """Start from ``x_hat0`` (default: the least-squares state matching ``y0``, zero elsewhere)."""
        y0 = _output_sample("y0", y0, self.plant.n_outputs)
        n = self.plant.n
        self._prior = (
            np.linalg.pinv(self.plant.C) @ y0 if x_hat0 is None else _output_sample("x_hat0", x_hat0, n, "state")
        )
        self.x_hat = self._prior.copy()
        return self.x_hat

    def _require(self):
        if self._prior is None:
            raise RuntimeError("expected reset(y0) before update(y), actual value: the observer was never reset")

    def update(self, y) -> np.ndarray:
        """Correct with the sample ``y_k`` and return :math:`\\hat x_k`; a :class:`~smo_gym.DivergenceError` (the
        state kept) if the estimate would leave the range of a float."""
        self._require()
        y = _output_sample("y", y, self.plant.n_outputs)
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow is refused just below
            x_hat = self._prior + self.L @ (y - self.plant.C @ self._prior)
        self.x_hat = _finite_estimate(x_hat, "update(y)")
        return self.x_hat

    def advance(self, u) -> None:
        """Predict to the next sample with the control ``u`` held over the interval (a
        :class:`~smo_gym.DivergenceError`, the state kept, if the prediction would not be finite)."""
        self._require()
        u = _output_sample("u", u, self.plant.n_inputs, "input")
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow is refused just below
            prior = self.Phi @ self.x_hat + self.Gamma @ u
        self._prior = _finite_estimate(prior, "advance(u)")


class CascadedHOSMObserver:
    r"""Cascaded HOSM observer with unknown-input identification ([FLD07]; Fridman's slides, sections 3 and 6).

    .. math::
        \hat x_k = \tilde x_k^- + \hat e_k,\qquad \hat e_k = M^+ Q\,\hat Y_k,\qquad
        \hat w_k = D^+\big(\hat{\dot e}_k - A\hat e_k\big),

    where :math:`\tilde x` is the sampled Luenberger observer (module docstring), :math:`\hat Y_k` stacks the
    HOSM differentiator's estimates of the output error :math:`y_e = y - C\tilde x^-` and its derivatives, and
    :math:`M x = Q Y` is Molinari's decoupling relation (:func:`smo_gym.control.molinari_decoupling`). When every
    output has relative degree ``>= 2`` and ``C`` has full rank ``n/2`` (mechanical systems, positions measured)
    Molinari's relation is simply :math:`e = [C; CA]^{-1}[y_e; \dot y_e]`, the slides' :math:`K^{-1}` of (10);
    otherwise (``CD != 0``, ``sum r_i < n``) it is the decoupled relation. :math:`\hat{\dot e}` uses the same
    relation on the derivative-shifted stack, and derivatives of :math:`\hat w` (for
    :class:`UnmatchedCompensationController`) the stack shifted further.

    Parameters
    ----------
    plant : LinearPlant
        Must be strongly observable (raises :class:`~smo_gym.control.NotStronglyObservableError` saying why not).
    dt : float
        Sampling step ``tau``.
    lipschitz : float or array_like, shape (p,)
        Bound on the ``(k+1)``-th derivative of each output error, ``k`` the differentiator order (see
        :func:`output_error_lipschitz`).
    alpha : int
        Smoothness exploited: differentiator order ``k = N + n_w_derivatives + alpha``, ``N`` the highest output
        derivative Molinari's relation needs. State error ``O(tau^(alpha+1))``, identification ``O(tau^alpha)``
        when the outputs have relative degree 2 (see :attr:`theoretical_orders`).
    n_w_derivatives : int
        Also estimate :math:`\dot{\hat w}, \ldots` up to this order.
    poles : array_like, optional
        Continuous-time poles of the Luenberger stage.
    discretization : {"taylor", "euler"}
        Of the Levant differentiator (``"taylor"``: Livne & Levant 2014, needed for the orders above).
    injection : {"sampled", "held"}
        ``"sampled"`` (default): the Luenberger correction applied at the samples with its effect on the
        differentiator compensated exactly (module docstring). ``"held"``: the slides' continuous observer
        :math:`\dot{\tilde x} = A\tilde x + Bu + L(y_k - C\tilde x)` with the sample held (exact ZOH), the
        relation and :math:`\hat w = D^+(\hat{\dot e} - (A - LC)\hat e)` of the slides; kept as the ablation
        that shows the ``O(tau)`` floor of the held injection (``scripts/control_experiments.py``).

    Attributes
    ----------
    x_hat : ndarray, shape (n,)
    w_hat : ndarray, shape (m,)
    w_hat_derivatives : ndarray, shape (n_w_derivatives + 1, m)
        ``w_hat`` and its estimated derivatives.
    e_hat : ndarray, shape (n,)
        Estimated error of the Luenberger stage.
    e_hat_derivatives : ndarray, shape (n_w_derivatives + 2, n)
        ``e_hat`` and its estimated derivatives (Molinari's relation on the shifted derivative stacks).
    order : int
        Differentiator order ``k``.
    """

    def __init__(
        self,
        plant: LinearPlant,
        dt: float,
        lipschitz,
        *,
        alpha: int = 1,
        n_w_derivatives: int = 0,
        poles=None,
        discretization: str = "taylor",
        injection: str = "sampled",
    ):
        self.plant = plant
        self.injection = check_choice("injection", injection, ("sampled", "held"))
        self.report = self._check_plant(plant)
        self.dt = check_positive("dt", dt)
        alpha = check_int_in_range("alpha", alpha, 1, MAX_LEVANT_ORDER)
        n_w_derivatives = check_int_in_range("n_w_derivatives", n_w_derivatives, 0, MAX_LEVANT_ORDER)
        if discretization not in ("taylor", "euler"):
            raise ValueError(
                f"expected discretization to be one of 'taylor', 'euler', actual value: {discretization!r}"
            )
        if self.injection == "held":
            # the slides' continuous observer with y held between samples: e' = (A - L C) e + D w + L C (x - x_k)
            self.L = _placed_gain(plant.A, plant.C, _observer_poles(poles, plant.A))
            self._Adyn = plant.A - self.L @ plant.C
            mol = molinari_decoupling(self._Adyn, plant.C, plant.D)
        else:
            self._Adyn = plant.A
            mol = self.report.molinari
        self.molinari = mol
        N = mol.n_derivatives
        self.order = N + n_w_derivatives + alpha
        if self.order > MAX_LEVANT_ORDER:
            raise ValueError(
                f"expected a differentiator order N + n_w_derivatives + alpha <= {MAX_LEVANT_ORDER} "
                f"(N={N} from Molinari's relation), actual value: {self.order}"
            )
        self.alpha, self.n_w_derivatives = alpha, n_w_derivatives
        p = plant.n_outputs
        lipschitz = as_real_array("lipschitz", lipschitz)  # True or "100" are not bounds
        if lipschitz.shape not in ((), (1,), (p,)):
            raise ValueError(
                f"expected lipschitz a number or one per output ({p}), actual value: shape {lipschitz.shape}"
            )
        self.lipschitz = np.broadcast_to(lipschitz, (p,)).copy()
        self.differentiator = Levant(self.order, self.dt, self.lipschitz, discretization=discretization)
        self.Phi, self.Gamma = plant.discretize(self.dt)
        if self.injection == "sampled":
            self.L = self._sampled_gain(poles)
        else:  # exact ZOH of x~' = (A - LC) x~ + B u_k + L y_k
            held = LinearPlant(self._Adyn, np.hstack([plant.B, self.L]), plant.C, plant.D)
            Phi_h, Gam_h = held.discretize(self.dt)
            self._held = (Phi_h, Gam_h[:, : plant.n_inputs], Gam_h[:, plant.n_inputs :])
        # state map e = S Y, Y = [y_e; y_e'; ...; y_e^(N)]
        self._S = mol.state_map()
        self._N = N
        self._Dpinv = np.linalg.pinv(plant.D)
        # w = D^+ (e' - A e) as a map of the stack [y_e; ...; y_e^(N+1)] (for the accuracy orders)
        S_ext = np.hstack([self._S, np.zeros((plant.n, p))])
        S_shift = np.hstack([np.zeros((plant.n, p)), self._S])
        self._W_map = self._Dpinv @ (S_shift - self._Adyn @ S_ext)
        # effect of a unit jump of e on the j-th derivative of y_e at the next sample: C A^j Phi
        self._jump = np.vstack(
            [plant.C @ np.linalg.matrix_power(plant.A, j) @ self.Phi for j in range(self.order + 1)]
        )  # ((k+1) p, n), derivative-major
        self._prior = self._posterior = self._y_last = None
        self._dstate = None
        self.x_hat = self.e_hat = self.e_hat_derivatives = None
        self.w_hat = np.zeros(plant.n_unknown)
        self.w_hat_derivatives = np.zeros((n_w_derivatives + 1, plant.n_unknown))
        self.output_error = None

    def _check_plant(self, plant: LinearPlant):
        """The plant's report, or the typed error saying why this observer cannot run on it."""
        return plant.require_strongly_observable()

    def _sampled_gain(self, poles) -> np.ndarray:
        """Gain ``L_d`` of the sampled Luenberger stage (see :func:`sampled_observer_gain`)."""
        return sampled_observer_gain(self.plant.A, self.plant.C, self.dt, poles)

    @property
    def theoretical_orders(self) -> dict[str, int]:
        r"""Orders in ``tau`` of the state and identification errors for noise-free samples.

        The differentiator's ``j``-th derivative has error ``O(L tau^(k+1-j))`` (Livne & Levant 2014), so an
        estimate that is a linear map of the derivative stack has the order of the highest derivative it weights.
        For outputs of relative degree 2 (positions of a mechanical system, the slides' examples) the state uses
        ``y_e'`` and the identification ``y_e''``: orders ``alpha + 1`` and ``alpha``, the table of Fridman's slides,
        section 6. With an output of relative degree 1, ``w`` may be read from ``y_e'`` alone and the
        identification gains one order; the maps below say which.
        """
        p, a = self.plant.n_outputs, np.linalg.norm(self.plant.A)  # the weights of y^(k) compared at its size
        return {
            "state": self.order + 1 - _highest_block(self._S, p, a),
            "identification": self.order + 1 - _highest_block(self._W_map, p, a),
        }

    def reset(self, y0, x_hat0=None) -> np.ndarray:
        """Start the Luenberger stage at ``x_hat0`` (default ``C^+ y0``) and the differentiator at its output error."""
        y0 = _output_sample("y0", y0, self.plant.n_outputs)
        n = self.plant.n
        self._prior = (
            np.linalg.pinv(self.plant.C) @ y0 if x_hat0 is None else _output_sample("x_hat0", x_hat0, n, "state")
        )
        self._y_last = None
        ye0 = y0 - self.plant.C @ self._prior
        self.differentiator.reset(ye0)
        self._dstate = self.differentiator.state
        self._posterior = self._prior.copy()
        self.x_hat = self._prior.copy()
        self.e_hat = np.zeros(self.plant.n)
        return self.x_hat

    def update(self, y) -> np.ndarray:
        """Process the sample ``y_k``: return :math:`\\hat x_k` and set ``w_hat`` (and its derivatives)."""
        if self._prior is None:
            raise RuntimeError("expected reset(y0) before update(y), actual value: the observer was never reset")
        ye = _output_sample("y", y, self.plant.n_outputs) - self.plant.C @ self._prior
        self.output_error = ye
        new_state, Z = self.differentiator.step(self._dstate, ye)  # Z: (p, k+1), estimates at t_k (pre-jump)
        # e, e', e'', ...: Molinari's relation on the derivative stack shifted by j
        E = [self._S @ Z[:, j : j + self._N + 1].T.reshape(-1) for j in range(self.n_w_derivatives + 2)]
        self.e_hat, self.e_hat_derivatives = E[0], np.array(E)
        self.x_hat = self._prior + E[0]
        for j in range(self.n_w_derivatives + 1):
            self.w_hat_derivatives[j] = self._Dpinv @ (E[j + 1] - self._Adyn @ E[j])
        self.w_hat = self.w_hat_derivatives[0].copy()
        if self.injection == "held":
            self._y_last = np.asarray(y, dtype=float).copy()
            self._dstate = new_state
            return self.x_hat
        # Luenberger correction at the sample, and its exactly known effect on the differentiated signal
        correction = self.L @ ye
        self._posterior = self._prior + correction
        new_state[:, : self.order + 1] -= (self._jump @ correction).reshape(self.order + 1, -1).T
        self._dstate = new_state
        return self.x_hat

    def advance(self, u) -> None:
        """Predict the Luenberger stage to the next sample with the control ``u`` held over the interval."""
        if self._prior is None:
            raise RuntimeError("expected reset(y0) before advance(u), actual value: the observer was never reset")
        u = _output_sample("u", u, self.plant.n_inputs, "input")
        if self.injection == "held":
            if self._y_last is None:
                raise RuntimeError("expected update(y) before advance(u), actual value: no sample since the reset")
            Phi_h, Gam_u, Gam_y = self._held
            self._prior = Phi_h @ self._prior + Gam_u @ u + Gam_y @ self._y_last
            return
        self._prior = self.Phi @ self._posterior + self.Gamma @ u
