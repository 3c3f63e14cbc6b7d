r"""Discrete-time HOSM-inspired observer of Wetzlinger, Reichhartinger and Horn, arbitrary order.

For a system in the observability form (27)-(28) with sampled output :math:`y_k = \xi_{1,k}`,

.. math::
    \dot\xi_i = \xi_{i+1} + \gamma_i(\xi_1,\dots,\xi_i,u) + \delta_i,\quad i < n,\qquad
    \dot\xi_n = \gamma_n(\xi,u) + \delta_n,

the observer (33) is the one-step predictor

.. math::
    \hat\xi_{k+1} = \mathbf A\hat\xi_k + \mathbf B\begin{bmatrix}\gamma_1(y_k,u_k)\\
    \mathrm{sat}_{L_{\gamma_2}}\hat\gamma_2(y_k,\hat\xi_{2,k},u_k)\\ \vdots\\
    \mathrm{sat}_{L_{\gamma_n}}\hat\gamma_n(y_k,\hat\xi_{2,k},\dots,\hat\xi_{n,k},u_k)\end{bmatrix}
    + \tilde{\mathbf l}(z_n(\sigma_{1,k}))\,\sigma_{1,k},\qquad \sigma_{1,k} = y_k - \hat\xi_{1,k},

with the Taylor matrices :math:`\mathbf A_{ij} = h^{j-i}/(j-i)!` (31), :math:`\mathbf B_{ij} = h^{j-i+1}/(j-i+1)!`
(32), and the gain of Ackermann's formula (35),
:math:`\tilde{\mathbf l}(z) = (\mathbf A - z\mathbf I)^n\mathcal O^{-1}e_n`, which places all ``n`` eigenvalues of
the error matrix :math:`\mathbf A - \tilde{\mathbf l}\mathbf c^T` at the state-dependent
:math:`z_n(\sigma_{1,k})` of the semi-implicit mapping (15) or the matching mapping (16):

.. math::
    z_s(e) = \frac{|e|^{1/n}}{hp_1\mu|e| + |e|^{1/n} + hp_1},\qquad
    z_m(e) = \exp\Big(-hp_1\frac{1 + \mu|e|}{|e|^{1/n}}\Big).

Without model terms it is the differentiator of section 3.1 discretised by (15)/(16) — the same recursion as
:class:`smo_gym.observers.Levant` with ``discretization="semi-implicit"`` / ``"matching"`` (which reports the
prediction moved back to :math:`t_k`; this class reports the predictor :math:`\hat\xi_{k+1}` itself, as the paper).

References
----------
.. [WRH] M. Wetzlinger, M. Reichhartinger and M. Horn, "Higher order sliding mode inspired nonlinear
   discrete-time observer", eqs. (15), (16), (24), (31)-(41), (51)-(52), section 6.
.. [KR19] S. Koch and M. Reichhartinger, "Discrete-time equivalents of the super-twisting algorithm",
   Automatica 107, 2019 (the matching mapping).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import ClassVar

import numpy as np

from .._validation import (
    DivergenceError,
    as_real_array,
    check_choice,
    check_int_in_range,
    check_keywords,
    check_nonnegative,
    check_positive,
    check_positive_array,
)
from .base import as_measurement, expand_mask
from .differentiators import eigenvalue_mapping_vectors, taylor_matrix

__all__ = [
    "DiscreteTimeHOSM",
    "ackermann_gain",
    "eigenvalue_mapping",
    "input_matrix",
    "max_eigenvalue",
    "perturbation_bounds",
    "printed_third_order_gain",
]

MAPPINGS = ("semi-implicit", "matching")


def eigenvalue_mapping(sigma, dt: float, p1, mu: float, n: int, mapping: str = "semi-implicit") -> np.ndarray:
    r"""The state-dependent discrete eigenvalue :math:`z_n(\sigma)`, (15) or (16); :math:`z_n(0) = 0`.

    Parameters
    ----------
    sigma : array_like
        Output error :math:`\sigma_{1,k}` (any shape).
    dt, p1, mu : float (``p1`` may be an array broadcasting with ``sigma``)
    n : int
        System order (the root :math:`|\sigma|^{1/n}`).
    mapping : {"semi-implicit", "matching"}
    """
    a = np.abs(np.asarray(sigma, dtype=float))
    root = a ** (1.0 / n)
    hp = dt * np.asarray(p1, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        if mapping == "semi-implicit":
            z = root / (hp * mu * a + root + hp)
        else:
            z = np.exp(-hp * (1.0 + mu * a) / root)
    return np.where(a > 0.0, z, 0.0)


def max_eigenvalue(n: int, dt: float, p1: float, mu: float, mapping: str = "semi-implicit") -> float:
    r"""Largest value of the mapping over :math:`\sigma`, attained at :math:`|\sigma| = 1/(\mu(n-1))`.

    .. math:: z_{s,\max} = \frac{n-1}{n-1 + n(\mu(n-1))^{1/n}hp_1},\qquad
              z_{m,\max} = \exp\Big(-hp_1\frac{n}{n-1}(\mu(n-1))^{1/n}\Big).

    The stability proofs of section 5 need :math:`z_{\max} < 1/\sqrt2` (n = 2, (62)) and
    :math:`z_{\max} < 0.498582` (n = 3, (70)).

    Notes
    -----
    :math:`z_{s,\max}` is (51). The printed (52) reads :math:`\exp(-hp_1n(\mu(n-1))^{1/n})`; evaluating (16) at
    its maximiser gives the factor :math:`n/(n-1)` above (the two agree for ``n = 2`` only). And (71) prints the
    threshold :math:`hp_1 > (2 - 0.9972)/(3\sqrt[3]{2\mu})`, whereas (51) with (70) gives
    :math:`hp_1 > (2/0.498582 - 2)/(3\sqrt[3]{2\mu})` (0.532 for :math:`\mu = 1`): the example's
    :math:`p_1 = 30,\ h = 0.01` has :math:`z_{\max} = 0.638`, outside the proven region (it still converges in
    simulation; the condition is sufficient).
    """
    n = check_int_in_range("n", n, 2, 64)
    q = (mu * (n - 1)) ** (1.0 / n) * dt * p1
    if mapping == "semi-implicit":
        return (n - 1) / (n - 1 + n * q)
    return float(np.exp(-n / (n - 1) * q))


def input_matrix(n: int, dt: float) -> np.ndarray:
    r"""The matrix (32), :math:`\mathbf B_{ij} = h^{j-i+1}/(j-i+1)!` for ``j >= i``, shape ``(n, n)``."""
    B = np.zeros((n, n))
    for i in range(n):
        fac = dt
        for j in range(i, n):
            B[i, j] = fac
            fac *= dt / (j - i + 2)
    return B


def ackermann_gain(z, n: int, dt: float) -> np.ndarray:
    r"""Ackermann's formula (35) evaluated directly: :math:`(\mathbf A - z\mathbf I)^n\mathcal O^{-1}e_n`.

    Reference implementation (matrix powers) of what the observer evaluates as a polynomial in ``z``
    (:func:`smo_gym.observers.differentiators.eigenvalue_mapping_vectors`). ``z`` scalar; returns shape ``(n,)``.
    """
    A = taylor_matrix(n, dt)
    O = np.vstack([np.linalg.matrix_power(A, i)[0] for i in range(n)])
    e_n = np.zeros(n)
    e_n[-1] = 1.0
    return np.linalg.matrix_power(A - z * np.eye(n), n) @ np.linalg.solve(O, e_n)


def printed_third_order_gain(z, dt: float) -> np.ndarray:
    r"""The third-order gain as printed in (79)-(82) of Wetzlinger et al. (kept only to show that it is wrong).

    .. math:: \mathbf l = \big(\Phi_1 + 1,\ \Phi_2/h,\ \Phi_3/h^2\big),\quad \Phi_1 = 3z-2,\quad
              \Phi_2 = -\tfrac12z^3 - \tfrac32z^2 + \tfrac92z - \tfrac52,\quad \Phi_3 = z^3 - 3z^2 + 3z - 1.

    With it, :math:`\mathbf A - \mathbf l\mathbf c^T` does not have the triple eigenvalue ``z`` and is unstable
    (checked in the tests); use :func:`ackermann_gain`.
    """
    p1 = 3 * z - 2
    p2 = -0.5 * z**3 - 1.5 * z**2 + 4.5 * z - 2.5
    p3 = z**3 - 3 * z**2 + 3 * z - 1
    return np.array([p1 + 1, p2 / dt, p3 / dt**2])


def perturbation_bounds(L_gamma, L_delta, measured_only=None) -> np.ndarray:
    r"""Bounds on the disturbance :math:`\mathbf d_k` of the error dynamics (36), from (40)-(41).

    .. math:: |d_1| \le L_{\delta_1},\qquad |d_i| \le 2L_{\gamma_i} + L_{\delta_i},\quad i \ge 2,

    and :math:`|d_i| \le L_{\delta_i}` when :math:`\gamma_i` depends on the measured output and the input only
    (then the observer uses it exactly).

    Parameters
    ----------
    L_gamma, L_delta : array_like, shape (n,)
        Bounds of the model terms and of the perturbations (``L_gamma[0]`` is ignored: :math:`\gamma_1` is exact).
    measured_only : array_like of bool, shape (n,), optional
        Channels whose :math:`\gamma_i` depends only on ``(y, u)``.
    """
    Lg = np.asarray(L_gamma, dtype=float)
    Ld = np.asarray(L_delta, dtype=float)
    if Lg.shape != Ld.shape or Lg.ndim != 1:
        raise ValueError(f"expected L_gamma and L_delta of equal shape (n,), actual value: {Lg.shape}, {Ld.shape}")
    if np.any(Lg < 0) or np.any(Ld < 0):
        raise ValueError(f"expected non-negative bounds, actual value: L_gamma={Lg}, L_delta={Ld}")
    exact = np.zeros(Lg.shape, dtype=bool) if measured_only is None else np.asarray(measured_only, dtype=bool)
    exact = exact.copy()
    exact[0] = True
    return np.where(exact, Ld, 2.0 * Lg + Ld)


class DiscreteTimeHOSM:
    r"""Observer (33) of Wetzlinger et al. for ``n``-th order input-affine systems in observability form, batched.

    Every channel is an independent SISO system of order ``n`` with output :math:`y = \xi_1` (e.g. one joint:
    position, velocity, acceleration, ... for an integrator chain).

    Parameters
    ----------
    n : int
        System order (number of states, ``2 <= n <= 10``).
    dt : float
        Sampling step ``h``.
    p1 : float or array_like
        Rate parameter :math:`p_1 > 0` (per channel if an array broadcastable to ``(..., n_channels)``).
    mu : float
        :math:`\mu \ge 0` (0: no uniform part).
    mapping : {"semi-implicit", "matching"}
        Eigenvalue mapping (15) or (16).
    gamma : sequence of ``n`` callables or None, optional
        Model terms :math:`\gamma_i`. Each is called as ``gamma[i](xi, u)`` with ``xi`` of shape
        ``(..., n_channels, n)`` (column 0 the *measurement* :math:`y_k`, columns ``1..`` the estimates
        :math:`\hat\xi_{2..n,k}`) and ``u`` the input as passed to :meth:`update` (or ``None``), and returns
        ``(..., n_channels)``. ``gamma[0]`` must depend on ``y`` and ``u`` only; ``None`` entries are zero.
    L_gamma : array_like, shape (n,), optional
        Saturation levels :math:`L_{\gamma_i}` of :math:`\hat\gamma_i`, ``i >= 2`` (``inf``: no saturation);
        ``L_gamma[0]`` is unused (:math:`\gamma_1` is not saturated in (33)). Required with ``gamma``.

    Attributes
    ----------
    output_error : ndarray
        :math:`\sigma_{1,k} = y_k - \hat\xi_{1,k}` of the last update, shape ``(..., n_channels)``.
    eigenvalue : ndarray
        :math:`z_n(\sigma_{1,k})` of the last update.

    Notes
    -----
    Gains: Ackermann's formula (35) evaluated as :math:`\tilde{\mathbf l}(z) = \sum_{j=0}^n (-z)^{n-j}v_j` with
    :math:`v_j = \binom nj\mathbf A^j\mathcal O^{-1}e_n` (the binomial expansion of :math:`(\mathbf A - zI)^n`).
    The printed closed form (79)-(82) is not stable (see
    :func:`printed_third_order_gain`). The paper's section 5 proves global asymptotic stability of the unperturbed error
    for ``n = 2, 3`` when :func:`max_eigenvalue` is below :math:`1/\sqrt2` and 0.498582; a ``RuntimeWarning`` is
    not raised for other settings, but ``stability_margin`` reports :math:`z^* - z_{\max}` for ``n <= 3``.
    """

    #: :math:`z^*` of (62) and (70): the proven stability bounds on the discrete eigenvalue
    PROVEN_Z_BOUND: ClassVar[dict[int, float]] = {2: 1.0 / np.sqrt(2.0), 3: 0.498582}

    @check_keywords
    def __init__(
        self,
        n: int,
        dt: float,
        p1,
        mu: float = 1.0,
        mapping: str = "semi-implicit",
        *,
        gamma: Sequence[Callable | None] | None = None,
        L_gamma=None,
    ):
        self.n = check_int_in_range("n", n, 2, 10)
        self.dt = check_positive("dt", dt)
        self.p1 = p1
        self._check_p1(p1)
        self.mu = check_nonnegative("mu", mu)
        self.mapping = check_choice("mapping", mapping, MAPPINGS)
        if gamma is not None:
            if isinstance(gamma, (str, bytes)) or not hasattr(gamma, "__iter__"):
                raise TypeError(
                    f"expected gamma to be a sequence of {self.n} callables or None, actual value: {gamma!r}"
                )
            gamma = list(gamma)
            if len(gamma) != self.n:
                raise ValueError(
                    f"expected gamma with {self.n} entries (callables or None), actual value: {len(gamma)} entries"
                )
            for i, g in enumerate(gamma):
                if g is not None and not callable(g):
                    raise TypeError(f"expected gamma[{i}] callable or None, actual value: {g!r}")
            if L_gamma is None:
                raise ValueError("expected L_gamma (saturation levels) with gamma, actual value: None")
        if L_gamma is not None:
            L_gamma = as_real_array("L_gamma", L_gamma)
            if L_gamma.shape != (self.n,) or np.any(np.isnan(L_gamma)) or np.any(L_gamma[1:] < 0):
                raise ValueError(
                    f"expected L_gamma of shape ({self.n},) with entries >= 0 (inf allowed), actual value: {L_gamma!r}"
                )
        self.gamma, self.L_gamma = gamma, L_gamma
        with np.errstate(all="ignore"):  # an overflow is reported below
            self.A = taylor_matrix(self.n, self.dt)
            self.B = input_matrix(self.n, self.dt)
            try:
                self._V = eigenvalue_mapping_vectors(self.n, self.dt)  # (n + 1, n)
            except np.linalg.LinAlgError:  # dt^(n-1) underflows: a singular observability matrix
                self._V = np.full((self.n + 1, self.n), np.nan)
        if not (np.isfinite(self.A).all() and np.isfinite(self.B).all() and np.isfinite(self._V).all()):
            raise ValueError(
                f"expected dt giving finite matrices (31), (32) and (35) (dt^n representable), actual "
                f"value: {self.dt!r}"
            )
        self._shape: tuple[int, ...] | None = None
        self._x: np.ndarray | None = None
        self._p1: np.ndarray | None = None
        self.output_error: np.ndarray | None = None
        self.eigenvalue: np.ndarray | None = None
        self.n_updates = 0

    @staticmethod
    def _check_p1(p1) -> np.ndarray:
        return check_positive_array("p1", p1)

    # ---- pure maths -------------------------------------------------------------------------------------------
    def gain(self, z) -> np.ndarray:
        r""":math:`\tilde{\mathbf l}(z)` of (35) for an array ``z``; shape ``z.shape + (n,)`` (Horner in ``-z``)."""
        z = as_real_array("z", z)
        if not np.isfinite(z).all():
            raise ValueError(f"expected finite eigenvalues z, actual value: {z!r}")
        with np.errstate(over="ignore", invalid="ignore"):
            out = self._gain(z)
        if not np.isfinite(out).all():
            raise ValueError(f"expected eigenvalues z with a finite gain (|z| near 1 or below), actual value: {z!r}")
        return out

    def _gain(self, z: np.ndarray) -> np.ndarray:
        """:meth:`gain` without the checks (the update checks the new state as a whole)."""
        z = z[..., None]
        out = np.zeros(z.shape[:-1] + (self.n,))
        for j in range(self.n + 1):
            out = out * (-z) + self._V[j]
        return out

    @check_keywords
    def stability_margin(self, p1: float | None = None) -> float | None:
        """:math:`z^* - z_{\\max}` of section 5 (positive: inside the proven region), ``None`` for ``n > 3``."""
        if self.n not in self.PROVEN_Z_BOUND:
            return None
        p = float(np.min(self._check_p1(self.p1 if p1 is None else p1)))
        return self.PROVEN_Z_BOUND[self.n] - max_eigenvalue(self.n, self.dt, p, self.mu, self.mapping)

    def model_terms(self, xi: np.ndarray, u) -> np.ndarray:
        r"""The vector multiplying :math:`\mathbf B` in (33): :math:`\gamma_1`, then the saturated
        :math:`\hat\gamma_i`."""
        out = np.zeros(xi.shape)
        if self.gamma is None:
            return out
        for i, g in enumerate(self.gamma):
            if g is None:
                continue
            val = as_real_array(f"gamma[{i}](xi, u)", g(xi, u))
            try:
                val = np.broadcast_to(val, xi.shape[:-1])
            except ValueError:
                raise ValueError(
                    f"expected gamma[{i}] to return shape {xi.shape[:-1]}, actual value: {val.shape}"
                ) from None
            if not np.isfinite(val).all():
                bad = tuple(int(j) for j in np.argwhere(~np.isfinite(val))[0])
                raise ValueError(
                    f"expected gamma[{i}] to return finite values, actual value: {val[bad]!r} at channel {bad[-1]}"
                )
            if i > 0:
                val = np.clip(val, -self.L_gamma[i], self.L_gamma[i])
            out[..., i] = val
        return out

    # ---- state ------------------------------------------------------------------------------------------------
    def _measurement(self, y, name: str) -> np.ndarray:
        arr = as_measurement(y, name)
        if not np.all(np.isfinite(arr)):
            bad = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
            raise ValueError(f"expected finite measurements in {name}, actual value: {arr[bad]!r} at index {bad}")
        return arr

    @check_keywords
    def reset(self, y0, xi0=None, mask=None) -> np.ndarray:
        r"""Start at :math:`\hat\xi_0` = ``xi0`` (shape ``(..., n_channels, n)``), default ``(y0, 0, ..., 0)``.

        ``mask`` (shape ``(...)`` or ``(..., n_channels)``) restarts only those rows after a full reset.
        Returns the current estimate (the predictor state), shape ``(..., n_channels, n)``.
        """
        y0 = self._measurement(y0, "y0")
        if xi0 is None:
            fresh = np.zeros(y0.shape + (self.n,))
            fresh[..., 0] = y0
        else:
            fresh = as_real_array("xi0", xi0, copy=True)
            if fresh.shape != y0.shape + (self.n,) or not np.all(np.isfinite(fresh)):
                raise ValueError(
                    f"expected finite xi0 with shape {y0.shape + (self.n,)}, actual value: shape {fresh.shape}"
                )
        if mask is None:
            p1 = self._check_p1(self.p1)
            try:
                self._p1 = np.broadcast_to(p1, y0.shape).astype(float)
            except ValueError:
                raise ValueError(
                    f"expected p1 broadcastable to the measurement shape {y0.shape}, actual value: shape {p1.shape}"
                ) from None
            self._shape = y0.shape
            self._x = fresh
            self.output_error = np.zeros(y0.shape)
            self.eigenvalue = np.zeros(y0.shape)
            self.n_updates = 0
            return self._x.copy()
        if self._x is None:
            raise RuntimeError("expected a full reset(y0) before a masked reset, actual value: never reset")
        if y0.shape != self._shape:
            raise ValueError(f"expected y0 with shape {self._shape} for a masked reset, actual value: {y0.shape}")
        mask = expand_mask(mask, self._shape)
        self._x[mask] = fresh[mask]
        self.output_error[mask] = 0.0
        self.eigenvalue[mask] = 0.0
        return self._x.copy()

    def update(self, y, u=None) -> np.ndarray:
        r"""Process :math:`y_k` (and :math:`u_k`); returns the predictor :math:`\hat\xi_{k+1}`.

        Shape ``(..., n_channels, n)``.

        Raises ``RuntimeError`` before ``reset``, ``ValueError`` on a wrong shape or a non-finite sample (state
        unchanged), ``DivergenceError`` if the new state is not finite (state unchanged).
        """
        if self._x is None:
            raise RuntimeError("expected reset(y0) before update(y), actual value: the observer was never reset")
        y = self._measurement(y, "y")
        if y.shape != self._shape:
            raise ValueError(f"expected y with shape {self._shape}, actual value: {y.shape}")
        if u is not None:  # the model terms' input, in their own convention: only required real and finite
            u = as_real_array("u", u)
            if not np.isfinite(u).all():
                bad = tuple(int(i) for i in np.argwhere(~np.isfinite(u))[0])
                raise ValueError(f"expected finite inputs u, actual value: {u[bad]!r} at index {bad}")
        x = self._x
        xi = x.copy()
        xi[..., 0] = y  # gamma_i sees the measured xi_1 and the estimates of the others
        terms = self.model_terms(xi, u)
        with np.errstate(all="ignore"):  # an overflow is reported below as a divergence, the state kept
            sigma = y - x[..., 0]  # sigma_{1,k}
            z = eigenvalue_mapping(sigma, self.dt, self._p1, self.mu, self.n, self.mapping)
            x_new = x @ self.A.T + terms @ self.B.T + self._gain(z) * sigma[..., None]  # (33)
        if not np.all(np.isfinite(x_new)):
            raise DivergenceError(
                "expected a finite observer state, actual value: non-finite after update "
                f"(dt={self.dt}); the step was rejected and the previous state kept"
            )
        self._x = x_new
        self.output_error = sigma
        self.eigenvalue = z
        self.n_updates += 1
        return x_new.copy()

    @check_keywords
    def run(self, Y, U=None) -> np.ndarray:
        """Process ``Y`` of shape ``(T, ..., n_channels)`` (and ``U`` with leading ``T``); returns ``(T, ..., n)``.

        All or nothing: if a sample is rejected, the observer keeps the state it had before the call.
        """
        if self._x is None:
            raise RuntimeError("expected reset(y0) before run(Y), actual value: the observer was never reset")
        Y = as_real_array("Y", Y)
        if Y.ndim == 0 or Y.shape[1:] != self._shape:
            raise ValueError(f"expected Y with shape (T, *{self._shape}), actual value: {Y.shape}")
        if U is not None:
            U = as_real_array("U", U)
            if U.ndim == 0 or U.shape[0] != Y.shape[0]:
                raise ValueError(
                    f"expected U with one row per sample of Y ({Y.shape[0]}), actual value: shape {U.shape}"
                )
        saved = (self._x, self.output_error, self.eigenvalue, self.n_updates)
        out = np.empty(Y.shape + (self.n,))
        try:
            for t in range(Y.shape[0]):
                out[t] = self.update(Y[t], None if U is None else U[t])
        except BaseException:
            self._x, self.output_error, self.eigenvalue, self.n_updates = saved
            raise
        return out

    @property
    def estimate(self) -> np.ndarray:
        r"""Current predictor :math:`\hat\xi_{k+1}`, shape ``(..., n_channels, n)``."""
        if self._x is None:
            raise RuntimeError("expected reset(y0) first, actual value: the observer was never reset")
        return self._x.copy()

    @property
    def shape(self) -> tuple[int, ...] | None:
        return self._shape

    def __repr__(self) -> str:
        return (
            f"DiscreteTimeHOSM(n={self.n}, dt={self.dt}, p1={self.p1!r}, mu={self.mu}, "
            f"mapping={self.mapping!r}, model={'yes' if self.gamma else 'no'})"
        )
