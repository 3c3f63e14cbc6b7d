r"""Parameter identification by the equivalent output injection of a super-twisting observer.

A mechanical system in regressor form (Fridman's lecture slides, "Parameter identification"),

.. math::
    \dot x_1 = x_2,\qquad \dot x_2 = F(t, x_1, x_2, u) + \Phi(t, x_1, x_2, u)\,\theta(t),\qquad y = x_1,

with :math:`x_1, x_2 \in \mathbb R^n`, a known part :math:`F`, a known regressor matrix
:math:`\Phi \in \mathbb R^{n\times p}` and unknown parameters :math:`\theta \in \mathbb R^p`. A super-twisting
observer (Davila, Fridman and Levant 2005) run with the *nominal* parameters :math:`\bar\theta`,

.. math::
    \dot{\hat x}_1 = \hat x_2 + k_1|e|^{1/2}\mathrm{sign}(e),\qquad
    \dot{\hat x}_2 = F(t, x_1, \hat x_2, u) + \Phi(t, x_1, \hat x_2, u)\,\bar\theta + k_2\,\mathrm{sign}(e),
    \qquad e = y - \hat x_1,

reaches the second-order sliding set :math:`e = \dot e = 0` in finite time, after which :math:`\hat x_2 = x_2`
and the equivalent value of the discontinuous injection is the model mismatch,

.. math:: z_{eq} = \bigl[k_2\,\mathrm{sign}(e)\bigr]_{eq} = \Phi\,(\theta - \bar\theta) =: \Phi\,\vartheta,

a *linear regression* for :math:`\vartheta`, solved online by

dynamic least squares (constant :math:`\theta`)
    :math:`\dot{\hat\vartheta} = \Gamma\Phi^\top(z_{eq} - \Phi\hat\vartheta)`,
    :math:`\dot\Gamma = -\Gamma\Phi^\top\Phi\,\Gamma`;
the matrix forgetting factor (time-varying :math:`\theta`)
    :math:`\dot{\hat\vartheta} = \Gamma^\top\Phi^\top(z_{eq} - \Phi\hat\vartheta)`,
    :math:`\dot\Gamma = -(\Gamma\Phi^\top\Phi + \ln R)\,\Gamma` with :math:`R = R^\top`,
    :math:`0 < \lambda_{\min}(R)`, :math:`\|R\| < 1`.

The slides write the parameters as a matrix :math:`\theta \in \mathbb R^{n\times l}` times a regressor *vector*
:math:`\varphi \in \mathbb R^l`; that is the special case :math:`\Phi = I_n \otimes \varphi^\top`,
:math:`\vartheta = \mathrm{vec}_{row}(\theta - \bar\theta)` (:func:`regressor_matrix`), for which the laws above
are the slides' row by row (the gain of the vector law is :math:`I_n \otimes \Gamma`). The general form is needed
for physical parameters that act on several joints at once, such as a payload mass.

Sampled implementation
----------------------
With :math:`Q = \Gamma^{-\top}` (:math:`= \Gamma^{-1}` unless a non-scalar :math:`R` makes :math:`\Gamma`
asymmetric) and :math:`b = Q\hat\vartheta`, both laws are *linear* ODEs,

.. math:: \dot Q = \Phi^\top\Phi + \ln R\;Q,\qquad \dot b = \Phi^\top z_{eq} + \ln R\; b,
   \qquad \hat\vartheta = Q^{-1} b,

(:math:`\ln R = 0` for dynamic least squares). With :math:`\Phi` and :math:`z_{eq}` held over a sample (zero-order
hold) they are integrated *exactly*: :math:`Q_{k+1} = E Q_k + S\Phi_k^\top\Phi_k`,
:math:`b_{k+1} = E b_k + S\Phi_k^\top z_k`, :math:`E = R^{h}`, :math:`S = \int_0^h R^s ds = (\ln R)^{-1}(R^h - I)`
(:math:`E = I, S = hI` without forgetting), :func:`forgetting_transition`. Without forgetting and for
:math:`R = \rho I`, :math:`Q` stays symmetric positive definite for every step ``h`` (a sum of positive semidefinite
terms and a positive definite start): the discretization is unconditionally stable, and :math:`\Gamma` is never
propagated (it is :math:`Q^{-\top}` on demand). For a general :math:`R` it is the exact sampled solution of the
printed law, whose :math:`\Gamma` need not stay symmetric (Notes).

Notes
-----
Where the print of the slides and the derivation differ:

* the forgetting factor is printed :math:`R \in \mathbb R^{n\times n}`; :math:`\Gamma\varphi\varphi^\top + \ln R`
  only makes sense for :math:`R` of the size of :math:`\Gamma` (:math:`l\times l`; here :math:`p\times p`);
* the condition printed :math:`|\lambda_{\min}(R)| > 0` admits negative eigenvalues, for which :math:`\ln R` is not
  real: the derivation needs :math:`\lambda_{\min}(R) > 0`, which is what :func:`check_forgetting_factor` checks;
  with :math:`\|R\| < 1` it makes :math:`-\ln R` positive definite (the forgetting rates);
* :math:`\dot\Gamma = -(\Gamma\varphi\varphi^\top + \ln R)\Gamma` keeps :math:`\Gamma` symmetric only when
  :math:`\ln R` commutes with :math:`\Gamma` (e.g. :math:`R = \rho I`); in general :math:`\Gamma` is not symmetric
  and the consistent update of the row form :math:`\dot{\hat\Delta} = (z - \hat\Delta\varphi)\varphi^\top\Gamma`
  is, for the column :math:`\hat\vartheta`, the one with :math:`\Gamma^\top` written above (identical for
  :math:`R = \rho I` and without forgetting).

Filtering. The per-sample injection chatters (with noise) around its equivalent value; it is low-pass filtered by
the observer (:attr:`smo_gym.observers.MechanicalSuperTwisting.disturbance`, a first-order filter of time
constant :math:`\tau`). The regressor is filtered by the *same* filter, so that :math:`z_f = \Phi_f\vartheta` holds
exactly for constant :math:`\vartheta` (a linear filter commutes with a constant factor) instead of lagging by
:math:`\tau`.

References
----------
.. [DFL05] J. Davila, L. Fridman and A. Levant, "Second-order sliding-mode observer for mechanical systems",
   IEEE TAC 50(11), 2005.
.. [F] L. Fridman, "Sliding Mode Observers: Theory and Practice", lecture slides, section "Parameter
   identification" (regressor form, equivalent output injection, dynamic least squares, matrix forgetting factor).
.. [LS] L. Ljung and T. Söderström, "Theory and practice of recursive identification", MIT Press, 1983
   (least squares with exponential forgetting, the scalar case :math:`R = \rho I`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ._validation import (
    as_real_array,
    check_bool,
    check_int_at_least,
    check_int_in_range,
    check_keywords,
    check_positive,
    check_real,
)
from .observers.mechanical import MechanicalSuperTwisting

__all__ = [
    "EquivalentInjectionIdentifier",
    "ForgettingFactorError",
    "LeastSquaresIdentifier",
    "check_forgetting_factor",
    "forgetting_transition",
    "least_squares_step",
    "regressor_matrix",
]


class ForgettingFactorError(ValueError):
    """A matrix forgetting factor ``R`` that violates a condition of the forgetting law.

    Attributes
    ----------
    condition : str
        The failed condition: ``"shape"``, ``"finite"``, ``"symmetric"``, ``"lambda_min(R) > 0"`` or
        ``"||R|| < 1"``.
    """

    def __init__(self, condition: str, message: str):
        super().__init__(message)
        self.condition = condition


def check_forgetting_factor(R, p: int) -> np.ndarray:
    r"""Validate a matrix forgetting factor and return it as a symmetric ``(p, p)`` array.

    Parameters
    ----------
    R : float or array_like, shape (p, p)
        The forgetting factor per unit time; a scalar :math:`\rho` means :math:`\rho I`.
    p : int
        Number of parameters.

    Returns
    -------
    ndarray, shape (p, p)

    Raises
    ------
    ForgettingFactorError
        Naming the failed condition (``R = R^T``, :math:`\lambda_{\min}(R) > 0`, :math:`\|R\| < 1`, finite, shape).
    """
    p = check_int_in_range("p", p, 1, 100_000)
    arr = as_real_array("R", R)
    if arr.ndim == 0:
        arr = float(arr) * np.eye(p)
    if arr.shape != (p, p):
        raise ForgettingFactorError("shape", f"expected R scalar or of shape ({p}, {p}), actual value: {arr.shape}")
    if not np.isfinite(arr).all():
        raise ForgettingFactorError("finite", f"expected a finite R, actual value: {arr!r}")
    if not np.allclose(arr, arr.T, rtol=1e-12, atol=1e-12):
        raise ForgettingFactorError(
            "symmetric", f"expected R = R^T, actual value: max |R - R^T| = {np.max(np.abs(arr - arr.T)):.3g}"
        )
    arr = 0.5 * (arr + arr.T)
    eig = np.linalg.eigvalsh(arr)
    if eig[0] <= 0.0:
        raise ForgettingFactorError(
            "lambda_min(R) > 0", f"expected lambda_min(R) > 0 (a real ln R), actual value: {eig[0]!r}"
        )
    if eig[-1] >= 1.0:
        raise ForgettingFactorError(
            "||R|| < 1", f"expected ||R|| = lambda_max(R) < 1 (a forgetting ln R < 0), actual value: {eig[-1]!r}"
        )
    return arr


def forgetting_transition(R, dt: float, p: int) -> tuple[np.ndarray, np.ndarray]:
    r"""The exact zero-order-hold transition of :math:`\dot X = \ln R\,X + G` over one sample.

    Parameters
    ----------
    R : None, float or array_like, shape (p, p)
        Forgetting factor (validated by :func:`check_forgetting_factor`); ``None`` for no forgetting.
    dt : float
        Sampling step ``h > 0``.
    p : int
        Number of parameters.

    Returns
    -------
    E, S : ndarray, shape (p, p)
        :math:`E = R^h = e^{h\ln R}` and :math:`S = \int_0^h e^{s\ln R} ds = (\ln R)^{-1}(R^h - I)`, so that
        :math:`X_{k+1} = E X_k + S G_k`. Without forgetting :math:`E = I`, :math:`S = hI`.
    """
    h = check_positive("dt", dt)
    p = check_int_in_range("p", p, 1, 100_000)
    if R is None:
        return np.eye(p), h * np.eye(p)
    R = check_forgetting_factor(R, p)
    lam, V = np.linalg.eigh(R)
    log = np.log(lam)  # < 0
    e = np.exp(h * log)
    s = np.expm1(h * log) / log  # accurate for slow forgetting (log -> 0-)
    return (V * e) @ V.T, (V * s) @ V.T


def regressor_matrix(phi, n: int) -> np.ndarray:
    r"""The regressor matrix :math:`\Phi = I_n \otimes \varphi^\top` of the slides' form
    :math:`\theta\varphi` (:math:`\theta \in \mathbb R^{n\times l}`, :math:`\varphi \in \mathbb R^l`).

    Parameters
    ----------
    phi : array_like, shape (..., l)
    n : int
        Number of coordinates.

    Returns
    -------
    ndarray, shape (..., n, n * l)
        With :math:`\vartheta = \theta.\mathrm{reshape}(n l)` (row-major), :math:`\Phi\vartheta = \theta\varphi`.
    """
    phi = as_real_array("phi", phi)
    n = check_int_in_range("n", n, 1, 100_000)
    if phi.ndim == 0:
        raise ValueError(f"expected phi with shape (..., l), actual value: shape {phi.shape}")
    if not np.isfinite(phi).all():
        raise ValueError(f"expected a finite phi, actual value: {phi!r:.120}")
    l = phi.shape[-1]
    out = np.zeros(phi.shape[:-1] + (n, n * l))
    for i in range(n):
        out[..., i, i * l : (i + 1) * l] = phi
    return out


def least_squares_step(Q, b, Phi, z, E, S) -> tuple[np.ndarray, np.ndarray]:
    r"""One exact zero-order-hold step of the dynamic least squares / matrix forgetting law (module docstring).

    .. math:: Q_{k+1} = E Q_k + S\,\Phi^\top\Phi,\qquad b_{k+1} = E b_k + S\,\Phi^\top z,
       \qquad \hat\vartheta_{k+1} = Q_{k+1}^{-1} b_{k+1},\quad \Gamma_{k+1} = Q_{k+1}^{-\top}.

    Parameters
    ----------
    Q : ndarray, shape (..., p, p)
        Information matrix (:math:`\Gamma^{-\top}`).
    b : ndarray, shape (..., p)
        :math:`Q\hat\vartheta`.
    Phi : ndarray, shape (..., n, p)
        Regressor held over the sample.
    z : ndarray, shape (..., n)
        Equivalent output injection held over the sample.
    E, S : ndarray, shape (p, p)
        From :func:`forgetting_transition`.

    Returns
    -------
    Q, b : the new arrays (the inputs are not modified).

    Raises
    ------
    ValueError
        Shapes that do not fit together (NumPy would broadcast a ``z`` of the wrong length into the result).
    """
    Q, b, Phi, z = as_real_array("Q", Q), as_real_array("b", b), as_real_array("Phi", Phi), as_real_array("z", z)
    E, S = as_real_array("E", E), as_real_array("S", S)
    p = b.shape[-1] if b.ndim else 0
    if (
        b.ndim < 1
        or Q.shape != b.shape + (p,)
        or Phi.ndim < 2
        or Phi.shape[-1] != p
        or z.shape != Phi.shape[:-1]
        or E.shape != (p, p)
        or S.shape != (p, p)
    ):
        raise ValueError(
            "expected Q (..., p, p), b (..., p), Phi (..., n, p), z (..., n) and E, S (p, p), actual value: shapes "
            f"{Q.shape}, {b.shape}, {Phi.shape}, {z.shape}, {E.shape}, {S.shape}"
        )
    info = np.einsum("...ki,...kj->...ij", Phi, Phi)
    corr = np.einsum("...ki,...k->...i", Phi, z)
    Q_new = E @ Q + S @ info
    b_new = np.einsum("ij,...j->...i", E, b) + np.einsum("ij,...j->...i", S, corr)
    return Q_new, b_new


class LeastSquaresIdentifier:
    r"""Online identification of :math:`\vartheta` in :math:`z = \Phi\vartheta` by dynamic least squares, or by the
    matrix forgetting factor for time-varying parameters (sampled exactly, see the module docstring).

    Parameters
    ----------
    n_params : int
        ``p``, the number of parameters.
    dt : float
        Sampling step [s].
    gamma0 : float
        Initial gain :math:`\Gamma(0) = \gamma_0 I` (large: little trust in the initial estimate).
    forgetting : None, float or array_like, shape (p, p)
        The matrix forgetting factor ``R`` per unit time (a scalar :math:`\rho` means :math:`\rho I`, forgetting
        rate :math:`-\ln\rho` per second); ``None``: dynamic least squares (constant parameters).

    Attributes
    ----------
    estimate : ndarray, shape (..., p)
        :math:`\hat\vartheta`.
    gain : ndarray, shape (..., p, p)
        :math:`\Gamma`; without persistent excitation its eigenvalue in the unexcited direction stays
        :math:`\gamma_0` (no information is gained there).
    information : ndarray, shape (..., p, p)
        :math:`Q = \Gamma^{-\top}`.

    Notes
    -----
    For a scalar regressor held constant, :math:`\Phi = \varphi_0`, and :math:`R = \rho I`, the estimate obeys
    :math:`\dot{\hat\vartheta} = \lambda(\vartheta - \hat\vartheta)` asymptotically, :math:`\lambda = -\ln\rho`:
    a ramp of slope ``s`` is tracked with the lag error :math:`s/\lambda` (in general with
    :math:`\overline{\Phi^\top\Phi}` constant on average, the same to first order).
    """

    @check_keywords
    def __init__(self, n_params: int, dt: float, *, gamma0: float = 1e3, forgetting=None):
        self.n_params = check_int_in_range("n_params", n_params, 1, 100_000)
        self.dt = check_positive("dt", dt)
        self.gamma0 = check_positive("gamma0", gamma0)
        if not np.isfinite(1.0 / self.gamma0):  # the initial information I / gamma0 would be inf
            raise ValueError(f"expected gamma0 whose inverse is finite, actual value: {self.gamma0!r}")
        self.forgetting = None if forgetting is None else check_forgetting_factor(forgetting, self.n_params)
        self._E, self._S = forgetting_transition(self.forgetting, self.dt, self.n_params)
        self._Q = None
        self._b = None
        self._estimate = None

    def reset(self, batch_shape=(), theta0=None) -> np.ndarray:
        """Start from ``theta0`` (shape ``(..., p)``, default zero) with :math:`\\Gamma = \\gamma_0 I` for a batch
        of shape ``batch_shape``; returns the estimate."""
        sizes = tuple(batch_shape) if isinstance(batch_shape, (tuple, list, np.ndarray)) else (batch_shape,)
        batch_shape = tuple(check_int_at_least("a batch_shape entry", s, 0) for s in sizes)
        p = self.n_params
        th = np.zeros(batch_shape + (p,))
        if theta0 is not None:
            t0 = as_real_array("theta0", theta0)
            try:
                th[...] = t0
            except ValueError:
                raise ValueError(
                    f"expected theta0 broadcastable to shape {batch_shape + (p,)}, actual value: shape {t0.shape}"
                ) from None
            if not np.isfinite(th).all():
                raise ValueError(f"expected a finite theta0, actual value: {t0!r}")
        self._Q = np.broadcast_to(np.eye(p) / self.gamma0, batch_shape + (p, p)).copy()
        self._b = th / self.gamma0
        self._estimate = th
        return th.copy()

    def _require_reset(self):
        if self._Q is None:
            raise RuntimeError("expected reset() before update(Phi, z), actual value: the identifier was never reset")

    def update(self, Phi, z) -> np.ndarray:
        """One sample: the regressor ``Phi`` (shape ``(..., n, p)``) and injection ``z`` (``(..., n)``) held over
        the sample ending now. Returns the new estimate ``(..., p)``."""
        self._require_reset()
        Phi = as_real_array("Phi", Phi)
        z = as_real_array("z", z)
        batch = self._b.shape[:-1]
        if Phi.ndim != len(batch) + 2 or Phi.shape[:-2] != batch or Phi.shape[-1] != self.n_params:
            raise ValueError(f"expected Phi with shape {batch} + (n, {self.n_params}), actual value: {Phi.shape}")
        if z.shape != Phi.shape[:-1]:
            raise ValueError(f"expected z with shape {Phi.shape[:-1]} (Phi's rows), actual value: {z.shape}")
        if not (np.isfinite(Phi).all() and np.isfinite(z).all()):
            raise ValueError("expected finite Phi and z, actual value: non-finite entries")
        with np.errstate(all="ignore"):  # an overflow is refused below, with the state as it was
            Q, b = least_squares_step(self._Q, self._b, Phi, z, self._E, self._S)
            try:
                estimate = np.linalg.solve(Q, b[..., None])[..., 0] if np.isfinite(Q).all() else Q[..., 0]
            except np.linalg.LinAlgError:  # the prior gamma0 I is lost next to the information of the samples
                raise ValueError(
                    f"expected an information matrix that stays invertible, actual value: singular after this sample "
                    f"(gamma0 = {self.gamma0:g} is too large a prior next to |Phi| {np.abs(Phi).max():.3g}); the "
                    "state was kept"
                ) from None
        if not (np.isfinite(Q).all() and np.isfinite(b).all() and np.isfinite(estimate).all()):
            raise ValueError(
                "expected a regressor and injection whose information stays finite, actual value: the update "
                f"overflows (largest |Phi| {np.abs(Phi).max():.3g}, |z| {np.abs(z).max():.3g}); the state was kept"
            )
        self._Q, self._b, self._estimate = Q, b, estimate
        return self._estimate.copy()

    @property
    def estimate(self) -> np.ndarray:
        self._require_reset()
        return self._estimate.copy()

    @property
    def information(self) -> np.ndarray:
        self._require_reset()
        return self._Q.copy()

    @property
    def gain(self) -> np.ndarray:
        self._require_reset()
        return np.swapaxes(np.linalg.inv(self._Q), -1, -2)


class _NominalModel:
    """The observer's dynamics object: the nominal acceleration at the identifier's current time."""

    def __init__(self, nominal: Callable, n: int):
        self._nominal = nominal
        self.n = n
        self.t = 0.0

    def acceleration(self, q, v, u=None) -> np.ndarray:
        return np.asarray(self._nominal(self.t, q, v, u), dtype=np.float64)

    def inertia(self, q) -> np.ndarray:
        """Identity: the disturbance is an acceleration (the regression is written for accelerations)."""
        return np.broadcast_to(np.eye(self.n), np.shape(q)[:-1] + (self.n, self.n))


class EquivalentInjectionIdentifier:
    r"""Online parameter identification from measured positions: a super-twisting observer with the nominal
    parameters (:class:`smo_gym.observers.MechanicalSuperTwisting`), its filtered equivalent output injection,
    and dynamic least squares or the matrix forgetting factor (:class:`LeastSquaresIdentifier`).

    Parameters
    ----------
    dt : float
        Sampling step [s].
    nominal : callable
        ``nominal(t, x1, x2, u) -> (..., n)``: the nominal acceleration :math:`F + \Phi\bar\theta`.
    regressor : callable
        ``regressor(t, x1, x2, u) -> (..., n, p)``: :math:`\Phi` (for the slides' vector :math:`\varphi`, wrap it
        with :func:`regressor_matrix`). With ``uses_acceleration=True`` it is called
        ``regressor(t, x1, x2, u, a)`` with ``a`` the current estimate of :math:`\dot x_2` (see Notes).
    theta_bar : array_like, shape (p,)
        Nominal parameters (the estimate starts there).
    lipschitz : float or array_like, shape (n,)
        Bound on :math:`|\Phi\vartheta|` plus the model's sensitivity to the velocity error; sets the
        observer's gains (:class:`~smo_gym.observers.MechanicalSuperTwisting`). Required unless
        ``observer_options`` gives both ``k1`` and ``k2``.
    gamma0, forgetting :
        See :class:`LeastSquaresIdentifier`.
    filter_time_constant : float
        Time constant [s] of the first-order filter applied to the injection and to the regressor.
    uses_acceleration : bool
        Parameters entering the inertia (a payload mass) make the acceleration-level regressor depend on the true
        acceleration, :math:`\Phi = -\bar M^{-1}\,\partial(M\ddot q + c)/\partial\theta` at :math:`\ddot q`; it is
        evaluated at :math:`a = F + \Phi\bar\theta + z_f` of the previous sample.
    observer_options : dict, optional
        More keywords for :class:`~smo_gym.observers.MechanicalSuperTwisting` (``discretization``,
        ``accel_bound``, ``euler_substeps``, ``k1``/``k2``).

    Attributes
    ----------
    observer : MechanicalSuperTwisting
    least_squares : LeastSquaresIdentifier
    theta : ndarray, shape (..., p)
        :math:`\hat\theta = \bar\theta + \hat\vartheta`.
    z_eq, regressor_filtered : the filtered injection ``(..., n)`` and regressor ``(..., n, p)`` of the last step.

    Notes
    -----
    The regressor is evaluated where the observer evaluates its model term: at the previous sample
    :math:`(t_{k-1}, y_{k-1}, \hat x_{2,k-1})` with the input that acts over the sample, so that the injection of
    step ``k`` and the regressor describe the same interval.

    Accuracy (noise free): the sampled observer's injection matches the model mismatch up to the explicit model
    term's error over one sample, :math:`O(h)`, so :math:`\hat\theta - \theta = O(h)` once excited. With position
    noise of amplitude :math:`\varepsilon > k_2 h^2` the injection saturates (the set-valued sign is bounded by
    :math:`k_2`), the observer filters, and the velocity in the regressor is accurate to the worst-case
    :math:`O(\varepsilon^{1/2})`, which the estimate inherits. For :math:`\varepsilon < k_2 h^2` the injection is a
    second difference of the noise that shares it with the regressor's velocity: besides the zero-mean part
    (:math:`O(\varepsilon)`, averaged by least squares) an errors-in-variables bias of order :math:`\varepsilon^2`.
    """

    @check_keywords
    def __init__(
        self,
        dt: float,
        nominal: Callable,
        regressor: Callable,
        theta_bar,
        *,
        n: int,
        lipschitz=None,
        gamma0: float = 1e3,
        forgetting=None,
        filter_time_constant: float = 0.02,
        uses_acceleration: bool = False,
        observer_options: dict | None = None,
    ):
        if not callable(nominal) or not callable(regressor):
            raise TypeError(
                "expected callables nominal(t, x1, x2, u) and regressor(t, x1, x2, u), actual value: "
                f"{type(nominal).__name__}, {type(regressor).__name__}"
            )
        self.n = check_int_in_range("n", n, 1, 10_000)
        tb = as_real_array("theta_bar", theta_bar)
        if tb.ndim != 1 or tb.size == 0 or not np.isfinite(tb).all():
            raise ValueError(f"expected a finite theta_bar of shape (p,), actual value: {tb!r}")
        self.theta_bar = tb
        self.p = tb.size
        self.dt = check_positive("dt", dt)
        self.filter_time_constant = check_positive("filter_time_constant", filter_time_constant)
        self._regressor = regressor
        self._nominal = nominal
        self.uses_acceleration = check_bool("uses_acceleration", uses_acceleration)
        self._model = _NominalModel(nominal, self.n)
        self.observer = MechanicalSuperTwisting(
            dt,
            self._model,
            lipschitz,
            disturbance_time_constant=self.filter_time_constant,
            **(observer_options or {}),
        )
        self.least_squares = LeastSquaresIdentifier(self.p, dt, gamma0=gamma0, forgetting=forgetting)
        self._beta = self.dt / (self.filter_time_constant + self.dt)  # the observer's filter coefficient
        self._state = None

    def reset(self, y0, v0=None, t0: float = 0.0) -> np.ndarray:
        """Start at the measurement ``y0`` (shape ``(..., n)``), velocity estimate ``v0`` (default zero) and time
        ``t0``, the estimate at ``theta_bar``; returns :attr:`theta`."""
        t0 = check_real("t0", t0)
        self._model.t = t0
        xhat = self.observer.reset(y0, v0=v0)
        batch = xhat.shape[:-2]
        self.least_squares.reset(batch)
        self._t = t0
        self._y_prev = xhat[..., 0].copy()
        self._v_prev = xhat[..., 1].copy()
        self.regressor_filtered = np.zeros(batch + (self.n, self.p))
        self.z_eq = np.zeros(batch + (self.n,))
        self._state = True
        return self.theta

    def _call_regressor(self, u) -> np.ndarray:
        args = (self._t, self._y_prev, self._v_prev, u)
        if self.uses_acceleration:
            a = np.asarray(self._nominal(*args), dtype=np.float64) + self.z_eq
            Phi = self._regressor(*args, a)
        else:
            Phi = self._regressor(*args)
        Phi = as_real_array("regressor(...)", Phi)
        shape = self.z_eq.shape + (self.p,)
        if Phi.shape != shape:
            raise ValueError(f"expected the regressor to return shape {shape}, actual value: {Phi.shape}")
        return Phi

    def update(self, y, u=None) -> np.ndarray:
        """One sample: the measurement ``y`` (shape ``(..., n)``) and the input ``u`` that acted over the sample
        ending at ``y``. Returns :attr:`theta`."""
        if self._state is None:
            raise RuntimeError(
                "expected reset(y0) before update(y), actual value: the identifier was never reset, or its least "
                "squares refused a sample its observer had taken"
            )
        Phi = self._call_regressor(u)  # at the previous sample, where the observer evaluates its model term
        if not np.isfinite(Phi).all():  # before anything steps: a refused sample changes nothing
            raise ValueError(f"expected a finite regressor at t = {self._t!r}, actual value: {Phi!r:.120}")
        self._model.t = self._t
        xhat = self.observer.update(y, u)
        self.z_eq = self.observer.disturbance
        self.regressor_filtered = self.regressor_filtered + self._beta * (Phi - self.regressor_filtered)
        try:
            self.least_squares.update(self.regressor_filtered, self.z_eq)
        except ValueError as exc:  # the observer took the sample the least squares refused: no longer one instant
            self._state = None
            message = str(exc).removesuffix("; the state was kept")  # the least squares' state, not this one's
            raise ValueError(
                f"{message}; the observer had already taken the sample: reset(y0) before the next update"
            ) from None
        self._t += self.dt
        self._y_prev = np.array(y, dtype=np.float64)
        self._v_prev = xhat[..., 1].copy()
        return self.theta

    @property
    def theta(self) -> np.ndarray:
        if self._state is None:
            raise RuntimeError("expected reset(y0) before reading theta, actual value: the identifier was never reset")
        return self.theta_bar + self.least_squares.estimate

    @property
    def gain(self) -> np.ndarray:
        """:math:`\\Gamma` of the least-squares law, shape ``(..., p, p)``."""
        return self.least_squares.gain

    @property
    def time(self) -> float:
        """Time of the last sample [s]."""
        if self._state is None:
            raise RuntimeError("expected reset(y0) before reading time, actual value: the identifier was never reset")
        return self._t
