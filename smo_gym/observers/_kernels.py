r"""Compiled per-sample recursions (numba).

Every observer family has one *channel step* (the maths for one signal, one sample) and one *batch kernel* that
applies it to ``N`` independent channels. The batch kernels share one calling convention::

    status = kernel(state, y, params, new_state, out)

    state      (N, S)  float64   observer state before the sample (read only)
    y          (N,)    float64   the new measurement of each channel
    params     (N, P)  float64   per-channel parameters (gains, step, flags), packed by the observer class
    new_state  (N, S)  float64   written: the state after the sample
    out        (N, m)  float64   written: the estimate at the sample time, ``(f, f', ..., f^(m-1))``

    status = -1             success
    status = i >= 0          y[i] is not finite (nothing written)
    status = -2 - i          new_state[i] is not finite (the caller keeps ``state``)

The last column of every state is the *innovation* ``y - yhat^-`` (measurement minus predicted output), the
diagnostic the observer classes expose as ``output_error``.

One generic time loop, :func:`run_offline`, drives any batch kernel over a recorded ``(T, N)`` array, so the
offline :func:`smo_gym.differentiate` and the online ``update`` execute literally the same recursion.

Prior and posterior
-------------------
Explicit schemes in the literature (Livne & Levant 2014; Wetzlinger et al., paper 003) are written as one-step
predictors, :math:`\hat x_{k+1} = F(\hat x_k, y_k)`: the state after seeing :math:`y_k` estimates the signal at
:math:`t_{k+1}`. The state stored here is exactly that predictor, so the recursion is the published one. The
*reported* estimate at :math:`t_k` is that prediction moved back by one step along the Taylor polynomial,
:math:`e^{-\tau N}\hat x_{k+1}` (``N`` the shift matrix), which is unbiased to the same order as the predictor and
uses the newest sample. Implicit schemes are already written at :math:`t_k` and report their state directly.

Performance
-----------
A call costs the numba dispatch (about 0.3-0.5 us for five array arguments, measured with an empty kernel by
``scripts/bench_observers.py``) plus a few ns to a few tens of ns per channel. What keeps the per-channel part
small: the HOSM step computes one root :math:`r = |e|^{1/m}` per channel and builds every
:math:`|e|^{q/m}` by multiplication (one ``sqrt`` for super-twisting and URED instead of two or five ``pow``);
the finiteness of each channel's new state is checked right after its step (no second pass); the channel steps
are inlined into the batch loops (no array views passed through calls); and ``error_model="numpy"`` drops the
zero-division checks (every divisor here is positive for valid parameters; a non-finite result still ends as
status ``-2 - i``). These change results by rounding only (a few ulp per step); through the discontinuous sign of
a sliding-mode step such a difference can grow along a chattering trajectory, like any change of compiler or
instruction order would. The eigenvalue-mapping kernel keeps ``pow`` for its root because its high-order
Ackermann gains (of order ``tau^-k``) amplify rounding differences.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

#: Number of signed-power terms per state in the HOSM family (URED needs three in its second equation).
N_TERMS = 3
CACHE = True


# ----------------------------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------------------------
@njit(cache=CACHE, error_model="numpy", inline="always")
def signed_power(e, p):
    r"""``|e|^p sign(e)`` with ``signed_power(0, p) = 0`` (so ``p = 0`` is the sign function)."""
    if e > 0.0:
        return e**p
    if e < 0.0:
        return -((-e) ** p)
    return 0.0


@njit(cache=CACHE, error_model="numpy", inline="always")
def _taylor_back(x_new, m, dt, out_row):
    r"""``out = exp(-dt N) x_new``: move a prediction for ``t + dt`` back to ``t`` along the Taylor polynomial."""
    for i in range(m):
        acc = x_new[i]
        fac = 1.0
        for l in range(1, m - i):
            fac *= -dt / l
            acc += fac * x_new[i + l]
        out_row[i] = acc


@njit(cache=CACHE, error_model="numpy", inline="always")
def _flat(y, out):
    """Views ``(N,)`` and ``(N, m)`` of a C-contiguous measurement ``(..., n)`` and estimate ``(..., n, m)``."""
    yf = y.reshape(y.size)
    return yf, out.reshape((yf.shape[0], out.shape[-1]))


@njit(cache=CACHE, error_model="numpy", inline="always")
def _first_nonfinite(y):
    for i in range(y.shape[0]):
        if not math.isfinite(y[i]):
            return i
    return -1


@njit(cache=CACHE, error_model="numpy")
def _check_state(new_state):
    """Status of a whole new state: ``-2 - i`` for the first channel ``i`` with a non-finite entry, else ``-1``."""
    for i in range(new_state.shape[0]):
        for j in range(new_state.shape[1]):
            if not math.isfinite(new_state[i, j]):
                return -2 - i
    return -1


@njit(cache=CACHE, error_model="numpy", inline="always")
def _row_finite(row):
    """Whether every entry of a state row is finite (checked per channel, right after the channel's step)."""
    for j in range(row.shape[0]):
        if not math.isfinite(row[j]):
            return False
    return True


@njit(cache=CACHE, error_model="numpy", inline="always")
def _abs_power(a, r, p, m):
    r"""``a**p`` given ``r = a**(1/m)``: ``r**q`` by multiplication when ``p = q/m`` with an integer ``0 <= q <= 16``.

    Levant's exponents ``(k - i)/(k + 1)``, super-twisting's and URED's halves and the uniform differentiator's
    ``(n + i)/n`` are all such multiples, so one root per channel replaces one ``pow`` per term (the results agree
    with ``a**p`` to a few ulp). Any other exponent falls back to ``a**p``.
    """
    q = p * m
    qi = int(q + 0.5)
    if qi >= 0 and qi <= 16 and abs(q - qi) <= 1e-12:
        acc = 1.0
        for _ in range(qi):
            acc *= r
        return acc
    return a**p


# ----------------------------------------------------------------------------------------------------------------
# HOSM family: Levant (any order), super-twisting (explicit), URED, uniform Levant
# params row: [dt, taylor, gains (m * N_TERMS), powers (m * N_TERMS)]
# ----------------------------------------------------------------------------------------------------------------
@njit(cache=CACHE, error_model="numpy", inline="always")
def hosm_channel_step(x, y, params, m, x_new, out_row):
    r"""One explicit step of a differentiator with signed-power injections.

    .. math::
        e_k = \hat x_{0,k} - y_k,\qquad
        \hat x_{i,k+1} = \sum_{l=0}^{L_i} \frac{\tau^l}{l!}\hat x_{i+l,k}
                         - \tau \sum_{j} g_{ij} \lceil e_k \rfloor^{p_{ij}},

    with ``L_i = 1`` for ``"euler"`` and ``L_i = m - 1 - i`` for ``"taylor"`` (Livne & Levant 2014).
    Returns the innovation ``y - xhat_0``.
    """
    dt = params[0]
    taylor = params[1] != 0.0
    goff = 2
    poff = 2 + m * N_TERMS
    e = x[0] - y
    # sign(e) |e|^p for every term from one root r = |e|^(1/m) (see _abs_power); e == 0 gives no correction
    a = abs(e)
    s = 1.0 if e > 0.0 else -1.0
    r = 0.0
    if e != 0.0:
        r = math.sqrt(a) if m == 2 else math.exp(math.log(a) / m)
    for i in range(m):
        corr = 0.0
        if e != 0.0:
            for j in range(N_TERMS):
                g = params[goff + i * N_TERMS + j]
                if g != 0.0:
                    corr += g * _abs_power(a, r, params[poff + i * N_TERMS + j], m)
            corr *= s
        acc = x[i]
        if i + 1 < m:
            acc += dt * x[i + 1]
            if taylor:
                fac = dt
                for l in range(2, m - i):
                    fac *= dt / l
                    acc += fac * x[i + l]
        x_new[i] = acc - dt * corr
    _taylor_back(x_new, m, dt, out_row)
    return -e


@njit(cache=CACHE, error_model="numpy", inline="always")
def hosm_kernel(state, y, params, new_state, out):
    y, out = _flat(y, out)
    bad = _first_nonfinite(y)
    if bad >= 0:
        return bad
    m = out.shape[1]
    for c in range(y.shape[0]):
        row = new_state[c]
        row[m] = hosm_channel_step(state[c], y[c], params[c], m, row, out[c])
        if not _row_finite(row):
            return -2 - c
    return -1


# ----------------------------------------------------------------------------------------------------------------
# Super-twisting, set-valued implicit Euler (closed form)
# params row: [dt, k1, k2]
# ----------------------------------------------------------------------------------------------------------------
@njit(cache=CACHE, error_model="numpy", inline="always")
def sta_implicit_channel_step(x, y, params, x_new):
    r"""Implicit Euler step of :math:`\dot x_1 = x_2 + k_1\lceil y-x_1\rfloor^{1/2},\ \dot x_2 = k_2\,\mathrm{Sign}(y-x_1)`.

    With ``e = y_{k+1} - x_{1,k+1}`` and the predicted error :math:`w = y_{k+1} - x_{1,k} - \tau x_{2,k}`, the
    implicit step requires :math:`w = e + \tau k_1\lceil e\rfloor^{1/2} + \tau^2 k_2 s`,
    :math:`s \in \mathrm{Sign}(e)`. If :math:`|w| \le \tau^2 k_2` the solution is :math:`e = 0,\ s = w/(\tau^2 k_2)`
    (the estimate sticks to the measurement); otherwise :math:`s = \mathrm{sign}(w)` and
    :math:`r = |e|^{1/2}` is the positive root of :math:`r^2 + \tau k_1 r - (|w| - \tau^2 k_2) = 0`.
    Returns the innovation ``w``.
    """
    dt = params[0]
    k1 = params[1]
    k2 = params[2]
    w = y - x[0] - dt * x[1]
    thr = dt * dt * k2
    if abs(w) <= thr:
        e = 0.0
        s = w / thr
    else:
        s = 1.0 if w > 0.0 else -1.0
        a = abs(w) - thr
        b = dt * k1
        r = 2.0 * a / (b + math.sqrt(b * b + 4.0 * a))  # stable form of (-b + sqrt(b^2 + 4a)) / 2
        e = s * r * r
    x_new[1] = x[1] + dt * k2 * s
    x_new[0] = y - e
    return w


@njit(cache=CACHE, error_model="numpy", inline="always")
def sta_implicit_kernel(state, y, params, new_state, out):
    y, out = _flat(y, out)
    bad = _first_nonfinite(y)
    if bad >= 0:
        return bad
    for c in range(y.shape[0]):
        row = new_state[c]
        row[2] = sta_implicit_channel_step(state[c], y[c], params[c], row)
        if not _row_finite(row):
            return -2 - c
        out[c, 0] = row[0]
        out[c, 1] = row[1]
    return -1


# ----------------------------------------------------------------------------------------------------------------
# Discrete-time eigenvalue-mapping observer of paper 003 (differentiator part)
# params row: [dt, p1, mu, mode, V ((m + 1) * m)], mode 0 = semi-implicit (15), 1 = matching (16)
# ----------------------------------------------------------------------------------------------------------------
@njit(cache=CACHE, error_model="numpy", inline="always")
def eigenvalue_map(sigma, dt, p1, mu, n, mode):
    r"""State-dependent discrete eigenvalue :math:`z_n(\sigma)`: (15) semi-implicit or (16) matching of paper 003."""
    a = abs(sigma)
    if a == 0.0:
        return 0.0
    # pow kept for n > 2: the high-order gains amplify any rounding change of the root (see module notes)
    root = math.sqrt(a) if n == 2 else a ** (1.0 / n)
    if mode == 0:
        return root / (dt * p1 * mu * a + root + dt * p1)
    return math.exp(-dt * p1 * (1.0 + mu * a) / root)


@njit(cache=CACHE, error_model="numpy", inline="always")
def eigmap_channel_step(x, y, params, m, x_new, out_row):
    r"""One step of (33) with zero model terms: :math:`\hat\xi_{k+1} = A\hat\xi_k + \tilde l(z_n(\sigma_k))\sigma_k`.

    ``A`` is the Taylor matrix (31), :math:`\sigma_k = y_k - \hat\xi_{1,k}`, and the Ackermann gain (35) is evaluated
    as :math:`\tilde l(z) = \sum_{j=0}^{m} (-z)^{m-j} v_j` with :math:`v_j = \binom{m}{j} A^j \mathcal O^{-1} e_m`
    precomputed (the binomial expansion of :math:`(A - zI)^m`).
    """
    dt = params[0]
    sigma = y - x[0]
    z = eigenvalue_map(sigma, dt, params[1], params[2], m, params[3])
    voff = 4
    for i in range(m):
        acc = x[i]
        fac = 1.0
        for l in range(1, m - i):
            fac *= dt / l
            acc += fac * x[i + l]
        # l_i(z) = sum_j (-z)^(m-j) v_j[i], Horner in (-z)
        gain = 0.0
        for j in range(m + 1):
            gain = gain * (-z) + params[voff + j * m + i]
        x_new[i] = acc + gain * sigma
    _taylor_back(x_new, m, dt, out_row)
    return sigma


@njit(cache=CACHE, error_model="numpy", inline="always")
def eigmap_kernel(state, y, params, new_state, out):
    y, out = _flat(y, out)
    bad = _first_nonfinite(y)
    if bad >= 0:
        return bad
    m = out.shape[1]
    for c in range(y.shape[0]):
        row = new_state[c]
        row[m] = eigmap_channel_step(state[c], y[c], params[c], m, row, out[c])
        if not _row_finite(row):
            return -2 - c
    return -1


# ----------------------------------------------------------------------------------------------------------------
# Linear time-invariant observers (high-gain): s_new = F s + g y, out = R s_new
# params row: [F (m * m), g (m), R (m * m)]
# ----------------------------------------------------------------------------------------------------------------
@njit(cache=CACHE, error_model="numpy", inline="always")
def linear_kernel(state, y, params, new_state, out):
    y, out = _flat(y, out)
    bad = _first_nonfinite(y)
    if bad >= 0:
        return bad
    m = out.shape[1]
    goff = m * m
    roff = goff + m
    for c in range(y.shape[0]):
        p = params[c]
        for i in range(m):
            acc = p[goff + i] * y[c]
            for j in range(m):
                acc += p[i * m + j] * state[c, j]
            new_state[c, i] = acc
        for i in range(m):
            acc = 0.0
            for j in range(m):
                acc += p[roff + i * m + j] * new_state[c, j]
            out[c, i] = acc
        new_state[c, m] = y[c] - state[c, 0]
        if not _row_finite(new_state[c]):
            return -2 - c
    return -1


# ----------------------------------------------------------------------------------------------------------------
# Constant-acceleration Kalman filter (3 states, scalar measurement)
# state row: [x0, x1, x2, P00, P01, P02, P11, P12, P22, innovation]; params row: [dt, q, r]
# ----------------------------------------------------------------------------------------------------------------
@njit(cache=CACHE, error_model="numpy", inline="always")
def kalman_ca_channel_step(s, y, params, s_new):
    r"""Predict with :math:`F = e^{\tau N}` and the white-jerk process noise, then update with ``y``.

    .. math::
        Q = q\begin{bmatrix} \tau^5/20 & \tau^4/8 & \tau^3/6\\ \tau^4/8 & \tau^3/3 & \tau^2/2\\
            \tau^3/6 & \tau^2/2 & \tau\end{bmatrix},\qquad
        K = P^- c / (c^T P^- c + r),\quad c = (1, 0, 0).
    """
    dt = params[0]
    q = params[1]
    r = params[2]
    h = 0.5 * dt * dt
    # x^- = F x                                                   (prior mean)
    x0 = s[0] + dt * s[1] + h * s[2]
    x1 = s[1] + dt * s[2]
    x2 = s[2]
    p00, p01, p02, p11, p12, p22 = s[3], s[4], s[5], s[6], s[7], s[8]
    # P^- = F P F^T + Q                                           (prior covariance)
    a00 = p00 + dt * p01 + h * p02  # rows of F P
    a01 = p01 + dt * p11 + h * p12
    a02 = p02 + dt * p12 + h * p22
    a11 = p11 + dt * p12
    a12 = p12 + dt * p22
    m00 = a00 + dt * a01 + h * a02  # (F P) F^T, upper triangle
    m01 = a01 + dt * a02
    m02 = a02
    m11 = a11 + dt * a12
    m12 = a12
    m22 = p22
    dt2 = dt * dt
    dt3 = dt2 * dt
    m00 += q * dt3 * dt2 / 20.0
    m01 += q * dt2 * dt2 / 8.0
    m02 += q * dt3 / 6.0
    m11 += q * dt3 / 3.0
    m12 += q * dt2 / 2.0
    m22 += q * dt
    # innovation and gain                                          nu = y - c x^-,  S = c P^- c^T + r
    nu = y - x0
    S_inv = 1.0 / (m00 + r)
    k0 = m00 * S_inv
    k1 = m01 * S_inv
    k2 = m02 * S_inv
    # x^+ = x^- + K nu,  P^+ = (I - K c) P^-                       (posterior)
    s_new[0] = x0 + k0 * nu
    s_new[1] = x1 + k1 * nu
    s_new[2] = x2 + k2 * nu
    s_new[3] = m00 - k0 * m00
    s_new[4] = m01 - k0 * m01
    s_new[5] = m02 - k0 * m02
    s_new[6] = m11 - k1 * m01
    s_new[7] = m12 - k1 * m02
    s_new[8] = m22 - k2 * m02
    return nu


@njit(cache=CACHE, error_model="numpy", inline="always")
def kalman_ca_kernel(state, y, params, new_state, out):
    y, out = _flat(y, out)
    bad = _first_nonfinite(y)
    if bad >= 0:
        return bad
    m = out.shape[1]
    for c in range(y.shape[0]):
        row = new_state[c]
        row[9] = kalman_ca_channel_step(state[c], y[c], params[c], row)
        if not _row_finite(row):
            return -2 - c
        for i in range(m):
            out[c, i] = row[i]
    return -1


# ----------------------------------------------------------------------------------------------------------------
# Backward finite differences (order 1 or 2)
# state row: [y, v, (a), innovation, samples since reset]; params row: [dt]
# ----------------------------------------------------------------------------------------------------------------
@njit(cache=CACHE, error_model="numpy", inline="always")
def finite_difference_kernel(state, y, params, new_state, out):
    y, out = _flat(y, out)
    bad = _first_nonfinite(y)
    if bad >= 0:
        return bad
    m = out.shape[1]
    for c in range(y.shape[0]):
        dt = params[c, 0]
        count = state[c, m + 1]
        v = (y[c] - state[c, 0]) / dt
        new_state[c, 0] = y[c]
        new_state[c, 1] = v
        if m > 2:
            # the first difference after a reset has no previous velocity: keep acceleration at zero
            new_state[c, 2] = (v - state[c, 1]) / dt if count >= 1.0 else 0.0
        new_state[c, m] = y[c] - state[c, 0]
        new_state[c, m + 1] = count + 1.0
        if not _row_finite(new_state[c]):
            return -2 - c
        for i in range(m):
            out[c, i] = new_state[c, i]
    return -1


# ----------------------------------------------------------------------------------------------------------------
# offline driver
# ----------------------------------------------------------------------------------------------------------------
@njit(error_model="numpy", inline="always")
def _drive(kernel, state, Y, params, out):
    """The time loop of :func:`run_offline`, inlined into each kernel's compiled driver.

    Ping-pong between ``state`` and one scratch buffer (no copy per sample); ``state`` receives the last accepted
    state at the end, also when a sample fails.
    """
    cur = state
    nxt = np.empty_like(state)
    done = Y.shape[0]
    status = -1
    for t in range(Y.shape[0]):
        status = kernel(cur, Y[t], params, nxt, out[t])
        if status != -1:
            done = t
            break
        cur, nxt = nxt, cur
    if done % 2 == 1:
        state[:, :] = cur
    return status, done


# One cached driver per kernel. A compiled function that takes a kernel as an argument is specialised on the
# dispatcher's type, which numba's on-disk cache cannot reuse across processes (it recompiled for seconds in every
# new process and could fail while re-saving its index); drivers that name their kernel cache normally.
@njit(cache=CACHE, error_model="numpy")
def _run_hosm(state, Y, params, out):
    return _drive(hosm_kernel, state, Y, params, out)


@njit(cache=CACHE, error_model="numpy")
def _run_sta_implicit(state, Y, params, out):
    return _drive(sta_implicit_kernel, state, Y, params, out)


@njit(cache=CACHE, error_model="numpy")
def _run_eigmap(state, Y, params, out):
    return _drive(eigmap_kernel, state, Y, params, out)


@njit(cache=CACHE, error_model="numpy")
def _run_linear(state, Y, params, out):
    return _drive(linear_kernel, state, Y, params, out)


@njit(cache=CACHE, error_model="numpy")
def _run_kalman_ca(state, Y, params, out):
    return _drive(kalman_ca_kernel, state, Y, params, out)


@njit(cache=CACHE, error_model="numpy")
def _run_finite_difference(state, Y, params, out):
    return _drive(finite_difference_kernel, state, Y, params, out)


@njit(error_model="numpy")  # not cached: specialised per kernel type (see above)
def _run_any(kernel, state, Y, params, out):
    return _drive(kernel, state, Y, params, out)


_DRIVERS = {
    hosm_kernel: _run_hosm,
    sta_implicit_kernel: _run_sta_implicit,
    eigmap_kernel: _run_eigmap,
    linear_kernel: _run_linear,
    kalman_ca_kernel: _run_kalman_ca,
    finite_difference_kernel: _run_finite_difference,
}


def register_driver(kernel, driver) -> None:
    """Register the cached compiled driver of a kernel defined in another module.

    ``driver(state, Y, params, out) -> (status, t)`` must be ``return _drive(kernel, state, Y, params, out)``
    compiled with ``@njit(cache=True)`` at module level, so that :meth:`Observer.run` (through
    :func:`run_offline`) reuses numba's on-disk cache for it.
    """
    _DRIVERS[kernel] = driver


def run_offline(kernel, state, Y, params, out):
    """Apply ``kernel`` to every row of ``Y`` (T, N); write estimates into ``out`` (T, N, m).

    Returns ``(status, t)``: ``status`` as the kernel's, ``t`` the sample at which it failed (or ``T``).
    ``state`` holds the last accepted state on return (the final state on success). Kernels of this module run
    through their own cached compiled driver; any other kernel through a generic compiled loop (compiled once per
    process and kernel).
    """
    driver = _DRIVERS.get(kernel)
    if driver is not None:
        return driver(state, Y, params, out)
    return _run_any(kernel, state, Y, params, out)
