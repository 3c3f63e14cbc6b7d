r"""Low-power, peaking-free high-gain observer (Astolfi, Marconi, Praly and Teel 2018).

The standard high-gain observer (2) of an ``n``-dimensional integrator chain uses the gains
:math:`\ell, \ell^2, \ldots, \ell^n` and its estimate :math:`\hat x_i` peaks like :math:`\ell^{i-1}` after a
reset. The *low-power* observer of Astolfi and Marconi (2015) replaces it by a chain of ``n - 1`` second-order
high-gain observers that only use :math:`\ell` and :math:`\ell^2`; the *peaking-free* version of Astolfi, Marconi,
Praly and Teel (2018) saturates the interconnection terms and adds one first-order filter, for a state of
dimension ``2n - 1``:

.. math::
    \dot\xi_i &= A\xi_i + N\,\sigma(\xi_{i+1}) + D(\ell) K_i\,\bigl(\sigma_i(\xi_{i-1,2}) - \xi_{i,1}\bigr),
        \qquad i = 1, \ldots, n-1,\quad \sigma_1(\xi_{0,2}) := y,\\
    \dot\xi_{n-1} &= A\xi_{n-1} + B\varphi_s(\hat x) + D(\ell)K_{n-1}\bigl(\sigma_{n-1}(\xi_{n-2,2})
        - \xi_{n-1,1}\bigr),\\
    \dot\eta &= \varphi_s(\hat x) + \ell k_n\bigl(\sigma_n(\xi_{n-1,2}) - \eta\bigr),

with :math:`A = \begin{bmatrix}0&1\\0&0\end{bmatrix}`, :math:`N = \begin{bmatrix}0&0\\0&1\end{bmatrix}`,
:math:`B = (0, 1)^T`, :math:`D(\ell) = \mathrm{diag}(\ell, \ell^2)`, :math:`K_i = (k_{i,1}, k_{i,2})^T`, and
:math:`N\sigma(\xi_{i+1}) = (0, \sigma_{i+2}(\xi_{i+1,2}))^T`. :math:`\xi_{i,1}` and :math:`\xi_{i,2}` estimate
:math:`x_i` and :math:`x_{i+1}`; :math:`\sigma_j` saturates an estimate of :math:`x_j` at the known bound
:math:`r_j \ge \sup_t|x_j(t)|` (``bounds``). Here :math:`\varphi_s = 0` (model-free: a differentiator of
``y = f + noise``, :math:`x_j = f^{(j-1)}`).

Estimates (``readout``):

``"peaking-free"`` (default)
    :math:`\hat x_1 = \xi_{1,1}`, :math:`\hat x_i = \xi_{i,1}` (``2 <= i <= n-1``), :math:`\hat x_n = \eta`
    [AMPT18]. Each is the output of a second-order (or first-order) filter with :math:`\ell`-scaled dynamics driven
    by a *saturated* signal, so its transient is bounded independently of :math:`\ell`; only the ``n - 1``
    auxiliary states :math:`\xi_{i,2}` may reach values of order :math:`\ell` (not :math:`\ell^{n-1}`).
``"low-power"``
    :math:`\hat x_1 = \xi_{1,1}`, :math:`\hat x_{i+1} = \xi_{i,2}`: the estimates of Astolfi and Marconi (2015).

Gains
-----
The default :math:`k_{i,1} = 2`, :math:`k_{i,2} = (n-i)/i`, :math:`k_n = 1` places *all* ``2n - 1`` eigenvalues
of the (unsaturated) error dynamics at :math:`-\ell` (found by pole placement on the characteristic polynomial and
verified to :math:`10^{-14}` for ``n <= 10``; :func:`low_power_matrices` lets a test check it). So with the same
:math:`\ell` this observer and :class:`~smo_gym.observers.HighGain` with its default binomial coefficients (all
``n`` poles at :math:`-\ell`) have the same convergence rate. Any other ``K`` is accepted if the unsaturated
error matrix is Hurwitz.

Discretization
--------------
``"implicit"`` (only choice): implicit Euler of the saturated system,
:math:`s_k = s_{k-1} + h\,F(s_k, y_k)`. :math:`F` is piecewise linear; the step first solves the unsaturated
linear system (a precomputed inverse), and if a saturated argument leaves its linear zone it solves the
piecewise-linear equation by an active-set iteration (each pass fixes the clamped terms, solves the linear
system, and recomputes which terms are clamped). The linear part is therefore stable at every :math:`\ell h`
(the implicit Euler map of a Hurwitz matrix), which the explicit Euler step is not for :math:`\ell h \gtrsim 1`.
The saturation is the hard clip :math:`\sigma_r(s) = \max(-r, \min(r, s))`; the papers ask for a strictly
increasing :math:`C^1` function with :math:`|\sigma_r| \le r + 1` for the proofs, which changes nothing once the
estimates are inside their bounds.

Notes
-----
The copy of [AMPT18] used here stops after Section 2, and the published equations of Section 3 could not be
retrieved; the construction above is completed from what both papers state:
[AM15]'s chain of ``n - 1`` two-dimensional observers with gains :math:`\ell, \ell^2`, [AMPT18]'s dimension
``2n - 1``, its saturated interconnections, and its claim that the ``n`` estimates are peaking-free while the
``n - 1`` auxiliary variables reach values of order :math:`\ell`. Both claims are measured in
``tests/test_low_power.py`` (peak exponents about 0 for the estimates, about 1 for :math:`\xi_{i,2}`, against
``i - 1`` for the standard observer), as are the gain powers and the noise sensitivity
(``scripts/compare_low_power.py``).

References
----------
.. [AM15] D. Astolfi and L. Marconi, "A high-gain nonlinear observer with limited gain power", IEEE Transactions
   on Automatic Control 60(11), 3059-3064, 2015.
.. [AMPT18] D. Astolfi, L. Marconi, L. Praly and A. R. Teel, "Low-power peaking-free high-gain observers",
   Automatica 98, 169-179, 2018 (the copy used here stops after Section 2).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .._validation import (
    as_real_array,
    check_choice,
    check_int_in_range,
    check_keywords,
    check_positive,
    check_positive_parameter,
)
from . import _kernels
from .base import Observer
from .registry import register_observer


def _balanced_gain_rule(cls, calibration, order, kwargs):
    r"""The high gain balancing the bound and the noise of each channel, :math:`\ell = (L/\epsilon)^{1/n}`.

    Per channel, so that a channel's estimate does not depend on which channels share the observer: what
    ``observer="auto"`` measures on its trials is what it deploys on any subset of the channels."""
    n = int(kwargs.get("order", 1)) + 1
    return cls(dt=calibration.dt, **kwargs, gain=(calibration.bound(order) / calibration.noise_levels) ** (1.0 / n))


__all__ = ["LowPowerHighGain", "low_power_default_coefficients", "low_power_matrices", "polynomial_powers"]

CACHE = True


# ----------------------------------------------------------------------------------------------------------------
# pure maths
# ----------------------------------------------------------------------------------------------------------------
def low_power_default_coefficients(n: int) -> tuple[np.ndarray, float]:
    r"""``(K, k_n)`` with :math:`K_i = (2, (n-i)/i)`, ``k_n = 1``: every error eigenvalue at :math:`-\ell`.

    Returns ``K`` of shape ``(n - 1, 2)`` and the scalar ``k_n``.
    """
    n = check_int_in_range("n", n, 2, 10)
    i = np.arange(1, n)
    return np.column_stack([np.full(n - 1, 2.0), (n - i) / i]), 1.0


def low_power_matrices(n: int, ell: float, K, k_n: float) -> dict[str, np.ndarray]:
    r"""Matrices of the low-power observer, state :math:`s = (\xi_{1,1}, \xi_{1,2}, \ldots, \xi_{n-1,2}, \eta)`.

    .. math:: \dot s = F_0 s + F_c\,\sigma(P s) + G y,

    where :math:`Ps = (\xi_{1,2}, \ldots, \xi_{n-1,2})` are the interconnection signals (:math:`\xi_{j,2}` estimates
    :math:`x_{j+1}` and is saturated at :math:`r_{j+1}`), :math:`F_c` holds the columns through which they enter, and
    :math:`F_0` the rest. Without saturation the observer is :math:`\dot s = (F_0 + F_c P)s + Gy`.

    Returns
    -------
    dict with ``F0`` (N, N), ``Fc`` (N, n-1), ``P`` (n-1, N) selection, ``G`` (N,), ``F = F0 + Fc P`` and the
    read-out matrices ``R_peaking_free`` and ``R_low_power`` (n, N); ``N = 2n - 1``.
    """
    K = np.asarray(K, dtype=float)
    N = 2 * n - 1
    F0 = np.zeros((N, N))
    Fc = np.zeros((N, n - 1))
    P = np.zeros((n - 1, N))
    G = np.zeros(N)
    for j in range(n - 1):
        P[j, 2 * j + 1] = 1.0
    for i in range(n - 1):  # block i (0-based) = xi_{i+1}
        a, b = 2 * i, 2 * i + 1
        k1, k2 = K[i]
        F0[a, b] += 1.0  # A xi_i: d xi_{i,1} = xi_{i,2}
        F0[a, a] -= ell * k1  # D K_i (- xi_{i,1})
        F0[b, a] -= ell**2 * k2
        if i == 0:  # D K_1 y
            G[a] += ell * k1
            G[b] += ell**2 * k2
        else:  # D K_i sigma(xi_{i-1,2})
            Fc[a, i - 1] += ell * k1
            Fc[b, i - 1] += ell**2 * k2
        if i < n - 2:  # N sigma(xi_{i+1}): d xi_{i,2} += sigma(xi_{i+1,2})
            Fc[b, i + 1] += 1.0
    F0[N - 1, N - 1] -= ell * k_n  # eta
    Fc[N - 1, n - 2] += ell * k_n
    R_pf = np.zeros((n, N))
    R_lp = np.zeros((n, N))
    R_pf[0, 0] = R_lp[0, 0] = 1.0
    for i in range(1, n - 1):
        R_pf[i, 2 * i] = 1.0
    R_pf[n - 1, N - 1] = 1.0
    for i in range(1, n):
        R_lp[i, 2 * (i - 1) + 1] = 1.0
    return {"F0": F0, "Fc": Fc, "P": P, "G": G, "F": F0 + Fc @ P, "R_peaking_free": R_pf, "R_low_power": R_lp}


# ----------------------------------------------------------------------------------------------------------------
# compiled recursion
# params row: [dt, Minv (N*N), b (N), Aimp (N*N), hFc (N*(n-1)), r (n-1), R (n*N)]
# state row:  [s (N), innovation]
# ----------------------------------------------------------------------------------------------------------------
@njit(cache=CACHE, inline="always")
def solve_in_place(M, rhs):
    """Solve ``M s = rhs`` by Gaussian elimination with partial pivoting, overwriting both; ``rhs`` becomes ``s``.

    For the few-by-few systems of the active-set iteration this is as accurate as LAPACK's ``gesv`` (the same
    algorithm) and keeps numba's LAPACK bindings, which cost most of this kernel's cold compilation, out of it. A
    singular ``M`` gives non-finite entries, which the caller's state check rejects."""
    N = rhs.shape[0]
    for k in range(N):
        pivot = k
        for i in range(k + 1, N):
            if abs(M[i, k]) > abs(M[pivot, k]):
                pivot = i
        if pivot != k:
            for j in range(N):
                M[k, j], M[pivot, j] = M[pivot, j], M[k, j]
            rhs[k], rhs[pivot] = rhs[pivot], rhs[k]
        for i in range(k + 1, N):
            factor = M[i, k] / M[k, k]
            for j in range(k, N):
                M[i, j] -= factor * M[k, j]
            rhs[i] -= factor * rhs[k]
    for k in range(N - 1, -1, -1):
        acc = rhs[k]
        for j in range(k + 1, N):
            acc -= M[k, j] * rhs[j]
        rhs[k] = acc / M[k, k]


@njit(cache=CACHE, inline="always")
def low_power_channel_step(x, y, p, n, x_new, out_row):
    r"""Implicit Euler step :math:`(I - hF)s_k = s_{k-1} + hGy_k` with the saturations handled by active sets."""
    N = 2 * n - 1
    o_minv = 1
    o_b = o_minv + N * N
    o_aimp = o_b + N
    o_fc = o_aimp + N * N
    o_r = o_fc + N * (n - 1)
    o_R = o_r + (n - 1)
    # unsaturated solution s = Minv s_prev + b y
    for i in range(N):
        acc = p[o_b + i] * y
        for j in range(N):
            acc += p[o_minv + i * N + j] * x[j]
        x_new[i] = acc
    # active set: clamp[j] = 0 (linear), +1 / -1 (clamped at +-r_j); xi_{j,2} sits at index 2j+1
    clamp = np.zeros(n - 1)
    violated = False
    for j in range(n - 1):
        v = x_new[2 * j + 1]
        r = p[o_r + j]
        if v > r:
            clamp[j] = 1.0
            violated = True
        elif v < -r:
            clamp[j] = -1.0
            violated = True
    if violated:
        M = np.empty((N, N))
        rhs = np.empty(N)
        # h G y = (I - hF) b y, since b = (I - hF)^{-1} h G
        hgy = np.empty(N)
        for i in range(N):
            acc = 0.0
            for j in range(N):
                acc += p[o_aimp + i * N + j] * p[o_b + j]
            hgy[i] = acc * y
        for _ in range(2 * n + 2):
            for i in range(N):
                for j in range(N):
                    M[i, j] = p[o_aimp + i * N + j]
                rhs[i] = x[i] + hgy[i]
            for j in range(n - 1):
                if clamp[j] != 0.0:
                    col = 2 * j + 1
                    r = p[o_r + j]
                    for i in range(N):
                        hfc = p[o_fc + i * (n - 1) + j]
                        M[i, col] += hfc  # remove -h Fc_j xi_{j,2} from (I - hF)
                        rhs[i] += hfc * clamp[j] * r  # add h Fc_j sigma = h Fc_j (+-r)
            solve_in_place(M, rhs)
            sol = rhs
            changed = False
            for j in range(n - 1):
                v = sol[2 * j + 1]
                r = p[o_r + j]
                new = 1.0 if v > r else (-1.0 if v < -r else 0.0)
                if new != clamp[j]:
                    clamp[j] = new
                    changed = True
            for i in range(N):
                x_new[i] = sol[i]
            if not changed:
                break
    for i in range(n):
        acc = 0.0
        for j in range(N):
            acc += p[o_R + i * N + j] * x_new[j]
        out_row[i] = acc
    return y - x[0]


@njit(cache=CACHE)
def low_power_rows(state, y, params, new_state, out, shared):
    """:func:`low_power_channel_step` on every channel (``shared``: one parameter row for every channel)."""
    n = out.shape[1]
    N = 2 * n - 1
    for c in range(y.shape[0]):
        pc = 0 if shared else c  # the parameter row of channel c
        new_state[c, N] = low_power_channel_step(state[c], y[c], params[pc], n, new_state[c], out[c])
    return _kernels._check_state(new_state, out)


#: the compiled step (its channel step solves linear systems: it allocates, and it links _kernels' functions)
low_power = _kernels.register_step(low_power_rows, allocates=True, helpers=(low_power_channel_step,))
low_power_kernel = low_power.kernel


# ----------------------------------------------------------------------------------------------------------------
# class
# ----------------------------------------------------------------------------------------------------------------
@register_observer(
    "low-power-high-gain",
    steps=(low_power,),
    calibrate=_balanced_gain_rule,
    given=(("gain",),),
    examples=(dict(gain=50.0, order=2), dict(gain=20.0, order=1, readout="low-power")),
)
class LowPowerHighGain(Observer):
    r"""Low-power (gains :math:`\ell, \ell^2` only), peaking-free high-gain differentiator [AMPT18], [AM15].

    Parameters
    ----------
    dt : float
        Sampling step.
    gain : float or array_like
        The high gain :math:`\ell > 0` (1/s); with the default coefficients every error eigenvalue is at
        :math:`-\ell`. An array is one gain per channel (broadcast to the measurement's shape).
    order : int
        Derivatives estimated, ``n = order + 1`` (``1 <= order <= 9``). Observer dimension ``2n - 1``.
    bounds : float or array_like, shape (order,), optional
        Saturation levels :math:`r_2, \ldots, r_n`: known bounds of :math:`|f^{(1)}|, \ldots, |f^{(n-1)}|`.
        ``None``: no saturation (the low-power observer of [AM15] plus the output filter).
    coefficients : array_like, shape (order, 2), optional
        :math:`K_i = (k_{i,1}, k_{i,2})`; default :func:`low_power_default_coefficients`.
    filter_coefficient : float, optional
        :math:`k_n` of the last estimate's filter (default 1).
    readout : {"peaking-free", "low-power"}
        Which states are reported as estimates (see the module docstring).
    discretization : {"implicit"}
    wrap : bool or array_like of bool, optional
        Channels measured as angles modulo ``2 pi`` (see :class:`~smo_gym.observers.Observer`).

    Examples
    --------
    >>> import numpy as np
    >>> from smo_gym.observers import LowPowerHighGain
    >>> obs = LowPowerHighGain(dt=1e-3, gain=50.0, order=2, bounds=[2.0, 2.0])
    >>> obs.powers_of_gain()
    [0, 1, 2]
    """

    discretizations = ("implicit",)

    @check_keywords
    def __init__(
        self,
        dt: float,
        gain,
        order: int = 1,
        *,
        bounds=None,
        coefficients=None,
        filter_coefficient: float | None = None,
        readout: str = "peaking-free",
        discretization: str | None = None,
        wrap=None,
    ):
        order = check_int_in_range("order", order, 1, 9)
        super().__init__(dt, order, discretization, wrap)
        n = order + 1
        self.gain = check_positive_parameter("gain", gain)
        self.readout = check_choice("readout", readout, ("peaking-free", "low-power"))
        K, k_n = low_power_default_coefficients(n)
        if coefficients is not None:
            K = as_real_array("coefficients", coefficients)
            if K.shape != (n - 1, 2) or not np.all(np.isfinite(K)):
                raise ValueError(f"expected coefficients with shape ({n - 1}, 2), actual value: {coefficients!r}")
        if filter_coefficient is not None:
            k_n = check_positive("filter_coefficient", filter_coefficient)
        self.coefficients, self.filter_coefficient = K, float(k_n)
        unit = low_power_matrices(n, 1.0, K, k_n)["F"]
        if np.max(np.linalg.eigvals(unit).real) >= 0:
            raise ValueError(
                f"expected coefficients making the error dynamics Hurwitz, actual value: {K.tolist()} "
                f"(eigenvalues {np.round(np.linalg.eigvals(unit), 4).tolist()})"
            )
        if bounds is None:
            self.bounds = np.full(order, np.inf)
        else:
            b = as_real_array("bounds", bounds)
            try:
                b = np.broadcast_to(b, (order,)).astype(float)
            except ValueError:
                raise ValueError(
                    f"expected bounds with shape ({order},) or a scalar, actual value: {bounds!r}"
                ) from None
            if np.any(~(b > 0)) or np.any(np.isnan(b)):
                raise ValueError(f"expected bounds > 0, actual value: {bounds!r}")
            self.bounds = b
        self._channel_params(np.shape(self.gain) or (1,))  # fail at construction, not at reset, if a step overflows

    def system_matrices(self, gain: float | None = None) -> dict[str, np.ndarray]:
        """The continuous-time matrices at ``gain`` (default: this observer's, if it is one number), see
        :func:`low_power_matrices`."""
        if gain is None:
            if np.ndim(self.gain):
                raise ValueError(f"expected a gain for an observer with one per channel, actual value: {gain!r}")
            gain = self.gain
        return low_power_matrices(
            self.order + 1, check_positive("gain", gain), self.coefficients, self.filter_coefficient
        )

    def powers_of_gain(self) -> list[int]:
        r"""Powers of :math:`\ell` that appear in the observer's matrices, found numerically.

        Fits every entry of :math:`(F_0, F_c, G)` evaluated at several :math:`\ell` with a polynomial in
        :math:`\ell` of degree ``n`` and returns the degrees with a nonzero coefficient. For this observer the
        answer is ``[0, 1, 2]`` whatever ``order``; for the standard high-gain observer it is ``[0, 1, ..., n]``.
        """
        n = self.order + 1
        probes = 1.0 + 0.5 * np.cos(np.pi * (np.arange(n + 3) + 0.5) / (n + 3))  # Chebyshev points in [0.5, 1.5]
        rows = []
        for ell in probes:
            M = low_power_matrices(n, ell, self.coefficients, self.filter_coefficient)
            rows.append(np.concatenate([M["F0"].ravel(), M["Fc"].ravel(), M["G"]]))
        return polynomial_powers(np.asarray(probes), np.asarray(rows), n)

    # ---- Observer plumbing ------------------------------------------------------------------------------------
    @property
    def internal_state(self) -> np.ndarray:
        r"""The observer state :math:`s = (\xi_{1,1}, \xi_{1,2}, \ldots, \xi_{n-1,2}, \eta)` of every channel in
        the papers' coordinates, shape ``(..., n_channels, 2n - 1)``."""
        self._require_reset()
        n = self.order + 1
        return (self._state[:, : 2 * n - 1] * self._channel_scale()).reshape(self._shape + (2 * n - 1,))

    @property
    def _kernel(self):
        return low_power_kernel

    def _state_width(self) -> int:
        return 2 * (self.order + 1)

    def _innovation_column(self) -> int:
        return 2 * (self.order + 1) - 1

    def _load_estimate(self, state, x0, params):
        r"""The state of an observer whose every estimate is exact: :math:`\xi_{i,1} = x_i`,
        :math:`\xi_{i,2} = x_{i+1}`, :math:`\eta = x_n` (both read-outs then return ``x0``), in the kernel's
        coordinates :math:`\zeta = T^{-1}s` (:meth:`state_scale`)."""
        n = self.order + 1
        s = np.empty((x0.shape[0], 2 * n - 1))
        s[:, 0 : 2 * n - 2 : 2] = x0[:, : n - 1]  # xi_{i,1} = x_i
        s[:, 1 : 2 * n - 2 : 2] = x0[:, 1:]  # xi_{i,2} = x_{i+1}
        s[:, 2 * n - 2] = x0[:, n - 1]  # eta = x_n
        state[:, : 2 * n - 1] = s / self._channel_scale()

    def state_scale(self, gain=None) -> np.ndarray:
        r"""Diagonal ``T`` of the internal coordinates: the kernel's state is :math:`\zeta = T^{-1}s` with
        :math:`\zeta_{i,1} = \xi_{i,1}/\ell^{i-1}`, :math:`\zeta_{i,2} = \xi_{i,2}/\ell^{i}`,
        :math:`\zeta_\eta = \eta/\ell^{n-1}`, in which the observer matrix is :math:`\ell F|_{\ell=1}`; the implicit
        step is solved there (condition number of order :math:`(\ell h)^{2}` instead of :math:`\ell^{2n}`).
        Shape ``np.shape(gain) + (2n - 1,)``, at ``gain`` (default: this observer's)."""
        n = self.order + 1
        powers = np.concatenate([[i, i + 1] for i in range(n - 1)] + [[n - 1]])
        gain = self.gain if gain is None else gain
        return np.asarray(gain, dtype=float)[..., None] ** powers.astype(float)

    def _channel_scale(self) -> np.ndarray:
        """:meth:`state_scale` of every channel of the last reset, shape ``(N, 2n - 1)``."""
        return self.state_scale(self._per_channel("gain", self.gain, self._shape))

    def _channel_params(self, shape):
        return self._rows_per_value("gain", self.gain, shape, self._gain_params)

    def _gain_params(self, gain: float) -> np.ndarray:
        """The parameter row of a channel with high gain ``gain`` (the kernel's discrete step)."""
        n = self.order + 1
        N = 2 * n - 1
        h = self.dt
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # overflow is reported below
            try:
                M = self.system_matrices(gain)
            except OverflowError:  # ell**2 of a Python float
                M = {
                    k: np.full_like(v, np.nan)
                    for k, v in low_power_matrices(n, 1.0, self.coefficients, self.filter_coefficient).items()
                }
            T = self.state_scale(gain)
            cols = 2 * np.arange(n - 1) + 1  # xi_{j,2}, the saturated interconnection signals
            F = M["F"] * T[None, :] / T[:, None]  # T^-1 F T
            Aimp = np.eye(N) - h * F
            try:
                Minv = np.linalg.inv(Aimp)
            except (np.linalg.LinAlgError, ValueError):
                Minv = np.full((N, N), np.nan)
            b = Minv @ (h * M["G"] / T)
            fc = h * M["Fc"] / T[:, None] * T[cols][None, :]  # column j acts on zeta_{j,2} = xi_{j,2} / T
            levels = self.bounds / T[cols]  # r_j in zeta units (inf: no saturation)
            R = (M["R_peaking_free"] if self.readout == "peaking-free" else M["R_low_power"]) * T[None, :]
        if not all(np.isfinite(a).all() for a in (Minv, b, Aimp, fc, R)) or np.isnan(levels).any():
            raise ValueError(
                f"expected gain and dt giving a finite implicit step (gain^(2n-2) and gain * dt "
                f"representable), actual value: gain={gain!r}, dt={self.dt!r}, order={self.order}"
            )
        return np.concatenate([[h], Minv.ravel(), b, Aimp.ravel(), fc.ravel(), levels, R.ravel()])

    def __repr__(self) -> str:
        return (
            f"LowPowerHighGain(dt={self.dt}, gain={np.asarray(self.gain).tolist()}, order={self.order}, "
            f"bounds={self.bounds.tolist()}, readout={self.readout!r})"
        )


def polynomial_powers(ells: np.ndarray, values: np.ndarray, max_degree: int, rtol: float = 1e-6) -> list[int]:
    """Degrees ``d`` such that some column of ``values`` (rows indexed by ``ells``) has a nonzero ``ell**d`` term.

    Exact polynomial fit (Vandermonde least squares) of each column up to ``max_degree``; coefficients below
    ``rtol`` times the column's scale count as zero.
    """
    V = np.vander(ells, max_degree + 1, increasing=True)
    coef, *_ = np.linalg.lstsq(V, values, rcond=None)
    scale = np.maximum(np.abs(values).max(axis=0), 1.0)
    present = np.abs(coef) > rtol * scale  # (deg, cols)
    return [int(d) for d in range(max_degree + 1) if np.any(present[d])]
