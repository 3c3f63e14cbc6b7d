r"""Compiled per-sample recursions (numba).

Every observer family has one *channel step* (the maths for one signal, one sample) and one *batch kernel* that
applies it to ``N`` independent channels. The batch kernels share one calling convention::

    status = kernel(state, y, params, new_state, out)

    state      (N, S)  float64   observer state before the sample (read only)
    y          (N,)    float64   the new measurement of each channel
    params     (N, P)  float64   per-channel parameters (gains, step, flags), packed by the observer class,
               (1, P)            or one row shared by every channel (the ``*_shared_kernel`` variants)
    new_state  (N, S)  float64   written: the state after the sample
    out        (N, m)  float64   written: the estimate at the sample time, ``(f, f', ..., f^(m-1))``

    status = -1             success
    status = i >= 0          y[i] is not finite (nothing written)
    status = -2 - i          new_state[i] or out[i] is not finite (the caller keeps ``state``)

The last column of every state is the *innovation* ``y - yhat^-`` (measurement minus predicted output), the
diagnostic the observer classes expose as ``output_error``.

One generic time loop, :func:`run_offline`, drives any batch kernel over a recorded ``(T, N)`` array, so the
offline :func:`smo_gym.differentiate` and the online ``update`` execute literally the same recursion.

Angles (``wrap``)
-----------------
A channel measured modulo :math:`P` (a single-turn absolute encoder reports angles in :math:`[-\pi, \pi)`,
:math:`P = 2\pi`) jumps by :math:`P` where the angle crosses the cut; a differentiator fed those samples sees a
velocity spike (:math:`P/\tau` for a finite difference). :func:`unwrap_measurement` is the one operation every
family shares: before the step, each wrapped measurement is moved to the branch nearest the observer's value
estimate (column 0 of every state in this package),

.. math:: \tilde y_k = y_k - P\,\bigl\lfloor (y_k - \hat x_0)/P + \tfrac12 \bigr\rfloor,

so that :math:`\tilde y_k - \hat x_0 \in [-P/2, P/2)`: the innovation the step then forms is the shortest
angular difference (up to the family's prediction :math:`\hat x_0^- - \hat x_0`, one step of motion), and the
state stays continuous (unwrapped). The kernels themselves are unchanged: ``Observer.update`` calls this function
first for an observer with wrapped channels, and :func:`run_offline` drives a kernel with it per sample
(:func:`_drive_wrapped`). Channels with :math:`P = 0` pass through bit for bit.

Prior and posterior
-------------------
Explicit schemes in the literature (Livne & Levant 2014; Wetzlinger et al.) are written as one-step
predictors, :math:`\hat x_{k+1} = F(\hat x_k, y_k)`: the state after seeing :math:`y_k` estimates the signal at
:math:`t_{k+1}`. The state stored here is exactly that predictor, so the recursion is the published one. The
*reported* estimate at :math:`t_k` is that prediction moved back by one step along the Taylor polynomial,
:math:`e^{-\tau N}\hat x_{k+1}` (``N`` the shift matrix), which is unbiased to the same order as the predictor and
uses the newest sample. Implicit schemes are already written at :math:`t_k` and report their state directly.
The eigenvalue-map step reports either: how far back it moves its prediction is one of its parameters (0 for
:class:`~smo_gym.observers.DiscreteTimeHOSM`, which reports the predictor itself, as Wetzlinger et al. do).

Performance
-----------
A call costs the compiled entry point (about 0.13 us for five array arguments, measured with an empty kernel
compiled as the batch kernels are, by ``scripts/bench_observers.py``) plus a few ns per channel. What keeps both
small:

* Fixed shapes at compile time where a step has them (the linear observer and finite differences for ``m = 2,
  3``, the Kalman filter): the widths are checked once per call and the rows indexed with constant strides.
* One step per algorithm. The signed-power step (:func:`hosm_channel_step`) and the eigenvalue map
  (:func:`eigmap_channel_step`) are the only implementations of their recursions; for ``m = 2, 3`` the same step
  runs with ``m`` a compile-time constant (its loops unrolled). Specialised vectorized variants for known exponent
  tables were removed: per ``update`` they were faster at 8-32 channels (Levant ``k = 2``, 32 channels: 1.6 us
  against 4.0 us now, 2 channels: equal), but inside the wrapper (up to 23 channels, an environment step of
  30-700 us) the difference did not show in ``scripts/bench_wrapper.py``.
* Vectorizable roots: ``sqrt`` for ``m = 2``; for ``m = 3`` the cube root of fdlibm (:func:`cbrt`: a bit-level
  first guess, a polynomial and one refinement step, error below 1 ulp) instead of ``exp(log(a) / 3)``, and
  fdlibm's ``exp`` (:func:`exp_nonpositive`) for the matching eigenvalue map, both written with plain arithmetic.
* Shared parameters. When every channel has the same parameter row (scalar gains: the usual case),
  ``Observer.update`` passes that one row ``(1, P)`` to the step's shared variant (:attr:`Step.shared_kernel`),
  whose loops are compiled with ``shared`` as a constant (they read parameter row ``pc = 0 if shared else c``):
  every parameter is then loop invariant instead of a load at a stride of ``P`` values per channel.
  ``Observer.run`` does the same through the offline driver of that variant (:attr:`Step.shared_run`); the
  wrapper's compiled drivers use the per-channel kernels.
* Generated, cached code. A family declares its step once, as a ``rows`` function; :func:`register_step`
  generates the batch kernels and the drivers from one template each (bound to the step as a global, see
  :func:`smo_gym._numba_cache.cached_instance`), so numba caches every one on disk.
* No reference counting at the entry. The batch kernels are compiled with numba's ``_nrt=False``: called from
  Python, their arrays are then unboxed without allocating a reference-counted ``MemInfo`` each, which halves
  the cost of the call (an empty five-array kernel: 0.27 against 0.13 us). The kernels allocate nothing.
* Compiled separately, joined by LLVM. Each numba function (helper, channel step, loop, batch kernel, driver) is
  compiled once and linked into its callers, where LLVM inlines it; numba compiles a call with a literal argument
  (``m = 2``, ``shared``) for that value, so the constants still unroll the loops. Inlining in numba's own IR
  (``inline="always"``) instead re-types the callee at every call site: with the ``m`` variants and the driver's
  two call sites that took 67 s for the eigenvalue-map driver from an empty cache (0.7 s now) and half of a cold
  test run, at no measured gain per ``update``, offline or in ``scripts/bench_wrapper.py``. Functions that take a
  function as an argument (the drivers' time loops, :func:`_chain_loop`, :func:`monotone_root`) are inlined in
  numba's IR: a compiled function with a function argument cannot be cached. Linking has its own cost: LLVM
  optimizes and emits a linked function again inside every caller, so each level of a call chain pays for all the
  code below it. A function with a single call site whose standalone compilation buys nothing is therefore
  inlined in numba's IR too: the composite step of :class:`~smo_gym.observers.PerChannel` (into its batch kernels
  and the wrapper's driver, which calls a step's ``rows`` directly rather than its batch kernel), the low-power
  observer's channel step and its solver, the sensor chain's per-sample kernel (a cold start of the default
  wrapper: 13.4 to about 10 s, ``scripts/bench_coldstart.py``).
* ``error_model="numpy"`` (no zero-division checks: every divisor is positive for valid parameters; a
  non-finite result still ends as status ``-2 - i``), and ``_flat`` reshapes only measurements with batch
  dimensions (a 1-D ``y`` passes through untouched).

These change results by rounding only (a few ulp per step, from the roots and ``exp``); through the
discontinuous sign of a sliding-mode step such a difference can grow along a chattering trajectory, like any
change of compiler or instruction order would.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core.dispatcher import Dispatcher
from numba.extending import intrinsic, overload

from .._numba_cache import cached_instance, drop_stale

#: Number of signed-power terms per state in the HOSM family (URED needs three in its second equation).
N_TERMS = 3
CACHE = True


def _without_nrt() -> dict:
    """``{"_nrt": False}`` if this numba accepts the option, else ``{}`` (see "Performance" above)."""
    try:
        from numba.core.options import DefaultOptions

        return {"_nrt": False} if hasattr(DefaultOptions, "_nrt") else {}
    except ImportError:  # pragma: no cover - numba reorganised: the kernels then run with NRT, a little slower
        return {}


#: options of the batch kernels: compiled without numba's reference counting when called from Python
KERNEL = dict(cache=CACHE, error_model="numpy", **_without_nrt())


# ----------------------------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------------------------
@njit(cache=CACHE, error_model="numpy")
def signed_power(e, p):
    r"""``|e|^p sign(e)`` with ``signed_power(0, p) = 0`` (so ``p = 0`` is the sign function)."""
    if e > 0.0:
        return e**p
    if e < 0.0:
        return -((-e) ** p)
    return 0.0


@njit(cache=CACHE, error_model="numpy")
def _taylor_back(x_new, m, dt, out_row):
    r"""``out = exp(-dt N) x_new``: move a prediction for ``t + dt`` back to ``t`` along the Taylor polynomial."""
    for i in range(m):
        acc = x_new[i]
        fac = 1.0
        for l in range(1, m - i):
            fac *= -dt / l
            acc += fac * x_new[i + l]
        out_row[i] = acc


def _flat(y, out):  # pragma: no cover - compiled only, see the overload below
    """Views ``(N,)`` and ``(N, m)`` of a C-contiguous measurement ``(..., n)`` and estimate ``(..., n, m)``."""
    raise NotImplementedError("_flat is only callable from compiled code")


@overload(_flat, inline="always")
def _flat_impl(y, out):
    # chosen at compile time from the number of dimensions: a 1-D measurement is already flat (a reshape is a
    # helper call of ~20 ns per array, a quarter of the kernel's budget at one channel)
    if y.ndim == 1:
        return lambda y, out: (y, out)
    return lambda y, out: (y.reshape(y.size), out.reshape((y.size, out.shape[-1])))


@njit(cache=CACHE, error_model="numpy")
def _check_rows(params, n, shared):
    """Require one parameter row per channel (``n``), or a single row if ``shared``."""
    if params.shape[0] != (1 if shared else n):
        raise ValueError("expected params with one row per channel, or one row for a *_shared_kernel")


@njit(cache=CACHE, error_model="numpy")
def _first_nonfinite(y):
    """Index of the first non-finite entry of ``y`` (N,), or -1: one branch-free pass, a second only on failure."""
    bad = False
    for i in range(y.shape[0]):
        bad |= not math.isfinite(y[i])
    if bad:
        for i in range(y.shape[0]):
            if not math.isfinite(y[i]):
                return i
    return -1


@njit(cache=CACHE, error_model="numpy")
def reported_sum(coefficients, estimate):
    r"""The reported velocity :math:`\sum_j c_j \hat z_{j+1}` of one channel's ``estimate`` (m,) with the
    ``coefficients`` (k,), summed term by term in the order of :func:`smo_gym.observers.base.reported_velocity`:
    the same numbers bit for bit (``[1.0]``: the first derivative as it is)."""
    v = coefficients[0] * estimate[1]
    for j in range(1, coefficients.shape[0]):
        v = v + coefficients[j] * estimate[1 + j]
    return v


@njit(cache=CACHE, error_model="numpy")
def _unwrap_rows(y, state, period, y_out):
    """The loop of :func:`unwrap_measurement` on flat ``y`` (N,), ``state`` (N, S), ``period``, ``y_out`` (N,)."""
    for c in range(y.shape[0]):
        p = period[c]
        q = (y[c] - state[c, 0]) / p if p > 0.0 else 0.0  # p = 0: not wrapped, y - 0 * 0 is y bit for bit
        # a non-finite y stays non-finite (NaN or inf - inf), so the kernel still reports its channel
        y_out[c] = y[c] - p * np.floor(q + 0.5)


@njit(cache=CACHE, error_model="numpy", **_without_nrt())
def unwrap_measurement(y, state, period, y_out):
    r"""Move each wrapped measurement to the branch nearest the observer's value estimate (module notes).

    .. math:: \tilde y_c = y_c - P_c\,\bigl\lfloor (y_c - s_{c,0})/P_c + \tfrac12 \bigr\rfloor,
        \qquad \tilde y_c - s_{c,0} \in [-P_c/2,\ P_c/2),

    Parameters
    ----------
    y : ndarray, shape (..., n)
        The measurement (C-contiguous float64), any batch shape of ``N`` values.
    state : ndarray, shape (N, S)
        The observer state before the sample; column 0 is the value estimate :math:`\hat x_0`.
    period : ndarray, shape (N,)
        :math:`P_c` per channel: ``2 pi`` for an angle, 0 for a channel that does not wrap (passed through).
    y_out : ndarray, shape (..., n)
        Written: :math:`\tilde y` (same shape as ``y``).
    """
    _unwrap_rows(y.reshape(y.size), state, period, y_out.reshape(y_out.size))


@njit(cache=CACHE, error_model="numpy")
def _check_state(new_state, out):
    """Status of a whole new state and its estimate: ``-2 - i`` for the first channel ``i`` with a non-finite entry
    in either (an estimate can overflow where the state does not: it is a sum of state entries), else ``-1``."""
    for i in range(new_state.shape[0]):
        for j in range(new_state.shape[1]):
            if not math.isfinite(new_state[i, j]):
                return -2 - i
        for j in range(out.shape[1]):
            if not math.isfinite(out[i, j]):
                return -2 - i
    return -1


@njit(cache=CACHE, error_model="numpy")
def _check_widths(state, new_state, params, out, S, P, m):
    """Fix the array widths for the compiler: after this check LLVM indexes rows with constant strides."""
    if state.shape[1] != S or new_state.shape[1] != S or params.shape[-1] != P or out.shape[1] != m:
        raise ValueError("expected state/new_state (N, S), params (N, P), out (N, m) of this kernel's widths")


@intrinsic
def _bits(typingctx, x):
    """The IEEE-754 bits of a float64 as an int64 (a register move; vectorizes)."""
    if x != types.float64:
        return None

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.IntType(64))

    return types.int64(types.float64), codegen


@intrinsic
def _from_bits(typingctx, i):
    """The float64 with the IEEE-754 bits ``i`` (int64)."""
    if i != types.int64:
        return None

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.DoubleType())

    return types.float64(types.int64), codegen


@njit(cache=CACHE, error_model="numpy")
def cbrt(a):
    r"""Cube root of ``a >= 0`` (finite), fdlibm's ``s_cbrt.c``: error below 0.667 ulp, no branches.

    First guess from the exponent bits (:math:`\lfloor hx/3\rfloor + B_1`, ``hx`` the high word), a polynomial
    to 23 bits, rounding to 22 bits, and one Newton step to 53 bits. Subnormal ``a`` are scaled by
    :math:`2^{54}` first; ``cbrt(0) = 0``. Written with arithmetic and bit moves only, so that a loop calling
    it vectorizes (``exp(log(a) / 3)`` costs two library calls per channel).
    """
    tiny = a < 2.2250738585072014e-308
    x = a * 18014398509481984.0 if tiny else a  # 2^54
    x = x if a > 0.0 else 1.0  # no division by zero below (any error model); cbrt(0) is set at the end
    hx = _bits(x) >> 32
    # floor(hx / 3) as a multiply-high (exact for 0 <= hx < 2^31); B1 = 715094163
    t = _from_bits((((hx * 0x55555556) >> 32) + 715094163) << 32)
    r = (t * t) * (t / x)
    t = t * (
        (1.87595182427177009643 + r * (-1.88497979543377169875 + r * 1.621429720105354466140))
        + ((r * r) * r) * (-0.758397934778766047437 + r * 0.145996192886612446982)
    )
    t = _from_bits((_bits(t) + 0x80000000) & -0x40000000)  # round away from zero to 22 bits
    s = t * t
    r = x / s
    w = t + t
    r = (r - t) / (w + r)
    t = t + t * r
    if tiny:
        t *= 3.814697265625e-06  # 2^-18
    return t if a > 0.0 else 0.0


@njit(cache=CACHE, error_model="numpy")
def _pow2(k):
    """``2.0 ** k`` for an integer-valued float ``-1022 <= k <= 1023`` (bits of the exponent field)."""
    # k + 1.5 * 2^52 has k in its low mantissa bits: an int conversion AVX2 can vectorize (cvtpd2qq cannot)
    ki = _bits(k + 6755399441055744.0) - 0x4338000000000000
    return _from_bits((ki + 1023) << 52)


@njit(cache=CACHE, error_model="numpy")
def exp_nonpositive(x):
    r"""``exp(x)`` for ``x <= 0`` (``-inf`` gives 0), fdlibm's ``e_exp.c``: error below 1 ulp, no branches.

    :math:`x = k\ln 2 + r` with ``|r| <= ln2 / 2`` (Cody-Waite, two-part ``ln 2``), a rational approximation of
    :math:`e^r`, and the scaling by :math:`2^k` in two halves so that subnormal results come out right.
    """
    x = -746.0 if x < -746.0 else x  # exp(-746) underflows to 0 like any smaller argument and -inf; NaN stays
    kf = np.floor(x * 1.44269504088896338700e00 + 0.5)  # np.floor stays float (math.floor is an int)
    hi = x - kf * 6.93147180369123816490e-01
    lo = kf * 1.90821492927058770002e-10
    r = hi - lo
    t = r * r
    c = r - t * (
        1.66666666666666019037e-01
        + t
        * (
            -2.77777777770155933842e-03
            + t * (6.61375632143793436117e-05 + t * (-1.65339022054652515390e-06 + t * 4.13813679705723846039e-08))
        )
    )
    y = 1.0 - ((lo - (r * c) / (2.0 - c)) - hi)
    k1 = np.floor(kf * 0.5)
    return y * _pow2(k1) * _pow2(kf - k1)


@njit(cache=CACHE, error_model="numpy")
def _row_finite(row):
    """Whether every entry of a state row is finite (checked per channel, right after the channel's step)."""
    for j in range(row.shape[0]):  # noqa: SIM110 - a loop numba compiles; all() of a generator it does not
        if not math.isfinite(row[j]):
            return False
    return True


@njit(cache=CACHE, error_model="numpy")
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
@njit(cache=CACHE, error_model="numpy")
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
        r = math.sqrt(a) if m == 2 else (cbrt(a) if m == 3 else math.exp(math.log(a) / m))
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


@njit(cache=CACHE, error_model="numpy")
def _hosm_loop(state, y, params, new_state, out, shared, m):
    """The channel loop of :func:`hosm_rows` for ``m`` estimates (a compile-time constant where the call passes
    a literal)."""
    _check_widths(state, new_state, params, out, m + 1, 2 + 2 * m * N_TERMS, m)
    failed = False
    for c in range(y.shape[0]):
        pc = 0 if shared else c  # the parameter row of channel c
        row = new_state[c]
        row[m] = hosm_channel_step(state[c], y[c], params[pc], m, row, out[c])
        failed |= not (_row_finite(row) and _row_finite(out[c]))
    return _check_state(new_state, out) if failed else -1


@njit(cache=CACHE, error_model="numpy")
def hosm_rows(state, y, params, new_state, out, shared):
    """:func:`hosm_channel_step` on every channel: one explicit step of a signed-power differentiator (Levant
    2003, any order; the explicit super-twisting step; Cruz-Zavala, Moreno and Fridman 2011; Angulo, Moreno and
    Fridman 2013), ``m = out.shape[1]`` estimates. ``shared``: one parameter row for every channel. The common
    orders run the same step with ``m`` a constant (the compiler unrolls its loops)."""
    m = out.shape[1]
    if m == 2:
        return _hosm_loop(state, y, params, new_state, out, shared, 2)
    if m == 3:
        return _hosm_loop(state, y, params, new_state, out, shared, 3)
    return _hosm_loop(state, y, params, new_state, out, shared, m)


# ----------------------------------------------------------------------------------------------------------------
# Super-twisting, set-valued implicit Euler (closed form)
# params row: [dt, k1, k2]
# ----------------------------------------------------------------------------------------------------------------
@njit(cache=CACHE, error_model="numpy")
def sta_implicit_channel_step(x, y, params, x_new):
    r"""Implicit Euler step of the super-twisting differentiator,
    :math:`\dot x_1 = x_2 + k_1\lceil y-x_1\rfloor^{1/2},\ \dot x_2 = k_2\,\mathrm{Sign}(y-x_1)`.

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
    # both cases evaluated, then selected (no branch: a loop over channels calling this vectorizes)
    stick = abs(w) <= thr
    sign = 1.0 if w > 0.0 else -1.0
    a = 0.0 if stick else abs(w) - thr
    b = dt * k1
    r = 2.0 * a / (b + math.sqrt(b * b + 4.0 * a))  # stable form of (-b + sqrt(b^2 + 4a)) / 2
    e = 0.0 if stick else sign * r * r
    s = w / thr if stick else sign
    x_new[1] = x[1] + dt * k2 * s
    x_new[0] = y - e
    return w


@njit(cache=CACHE, error_model="numpy")
def sta_implicit_rows(state, y, params, new_state, out, shared):
    """:func:`sta_implicit_channel_step` on every channel (``shared``: one parameter row for every channel)."""
    _check_widths(state, new_state, params, out, 3, 3, 2)
    failed = False
    for c in range(y.shape[0]):
        pc = 0 if shared else c  # the parameter row of channel c
        w = sta_implicit_channel_step(state[c], y[c], params[pc], new_state[c])
        new_state[c, 2] = w
        x0 = new_state[c, 0]
        x1 = new_state[c, 1]
        out[c, 0] = x0
        out[c, 1] = x1
        failed |= not (math.isfinite(x0) & math.isfinite(x1) & math.isfinite(w) & math.isfinite(state[c, 2]))
    return _check_state(new_state, out) if failed else -1


# ----------------------------------------------------------------------------------------------------------------
# Discrete-time eigenvalue-mapping observer of Wetzlinger et al. (differentiator part), with the filtering chain of
# Levant & Livne in front and a homogeneity degree d in [-1, 0] (Andritsch et al.)
# params row: [dt, p1, mu, mode, back, degree, V ((n + 1) * n)], mode 0 = semi-implicit (15), 1 = matching (16);
# back: the report is exp(-back N) z_{k+1}, back = dt (the estimate at t_k) or 0 (the predictor z_{k+1} itself);
# state row: [z_0, ..., z_{m-1}, w_1, ..., w_nf, innovation], n = m + nf states (nf = 0: no filter)
# ----------------------------------------------------------------------------------------------------------------
@njit(cache=CACHE, error_model="numpy")
def _eigenvalue_root(a, n):
    r"""The root :math:`|\sigma|^{1/n}` of the eigenvalue maps, for finite ``a >= 0``.

    ``sqrt`` for ``n = 2``, fdlibm's :func:`cbrt` for ``n = 3`` (below 1 ulp like the C library's ``pow``, but
    plain arithmetic, so the map vectorizes with it), ``a ** (1 / n)`` otherwise (no kernel of this module
    specialises ``n > 3``). The roots of ``cbrt`` and ``pow`` may differ by an ulp; through the matching map
    (16) :math:`z = e^u`, :math:`u = -\tau p_1 (1 + \mu|\sigma|)/|\sigma|^{1/n}`, that is a relative change of
    ``z`` of :math:`|u|` ulp (``|u| = 300`` at ``|sigma| = 1e-9`` for the parameters of the tests), which is why
    the test against NumPy's ``a ** (1 / n)`` (``test_mappings_match_the_compiled_kernel_and_the_closed_forms``)
    scales its tolerance with :math:`1 + |u|`.
    """
    return math.sqrt(a) if n == 2 else (cbrt(a) if n == 3 else a ** (1.0 / n))


@njit(cache=CACHE, error_model="numpy")
def _homogeneous_root(a, n, degree):
    r"""The root :math:`|\sigma|^{-q}`, :math:`q = d/(1 - d(n - 1))`, of the eigenvalue :math:`s = -p_1|\sigma|^q`
    of a differentiator of homogeneity degree ``d`` with ``n`` states (Andritsch et al.).

    ``d = -1`` gives :math:`|\sigma|^{1/n}` (:func:`_eigenvalue_root`, Levant's and Wetzlinger et al.'s case),
    ``d = 0`` gives 1 (a constant eigenvalue: a linear observer), also at :math:`\sigma = 0`.
    """
    if degree == -1.0:
        return _eigenvalue_root(a, n)
    return a ** (-degree / (1.0 - degree * (n - 1)))


@njit(cache=CACHE, error_model="numpy")
def _eigenvalue_from_root(a, root, dt, p1, mu, mode):
    r"""(15) or (16) given ``a = |sigma|`` and its root (see :func:`eigenvalue_map`); 0 where the root is 0 (the
    eigenvalue :math:`s \to -\infty` of a discontinuous differentiator at :math:`\sigma = 0`)."""
    semi = root / (dt * p1 * mu * a + root + dt * p1)
    matching = exp_nonpositive(-dt * p1 * (1.0 + mu * a) / root)  # -inf at root = 0 gives 0
    z = semi if mode == 0 else matching
    return z if root != 0.0 else 0.0


@njit(cache=CACHE, error_model="numpy")
def eigenvalue_map(sigma, dt, p1, mu, n, mode):
    r"""State-dependent eigenvalue :math:`z_n(\sigma)`: (15) semi-implicit or (16) matching of Wetzlinger et al.

    Both mappings are evaluated and one is selected (also ``z = 0`` at ``sigma = 0``, where both are 0 anyway):
    branches would keep LLVM from vectorizing a loop over channels that calls this.
    """
    a = abs(sigma)
    return _eigenvalue_from_root(a, _eigenvalue_root(a, n), dt, p1, mu, mode)


@njit(cache=CACHE, error_model="numpy")
def eigmap_channel_step(x, y, params, m, n, x_new, out_row):
    r"""One step of (33) with zero model terms, :math:`\hat\xi_{k+1} = \Phi\hat\xi_k + b(y_k)
    + \tilde l(z(\sigma_k))\sigma_k`, on a chain of ``n`` states whose last ``m`` estimate ``(f, ..., f^(m-1))``.

    Without filter (``n = m``), :math:`\Phi = A` is the Taylor matrix (31), :math:`b = 0` and
    :math:`\sigma_k = y_k - \hat\xi_{1,k}`: Wetzlinger et al.'s observer. With ``nf = n - m`` filter states
    :math:`w_1, \ldots, w_{nf}` in front (Levant & Livne's filtering differentiator, :math:`\dot w_{nf} = z_0 - f`),
    the chain is driven by :math:`u = z_0 - y` held over the step: :math:`w_i` moves by the Taylor terms of
    :math:`w_i, \ldots, w_{nf}` plus :math:`\tau^{nf-i+1}/(nf-i+1)!\,u_k`, the ``z`` block by the Taylor matrix,
    and :math:`\sigma_k = -w_{1,k}` (module :mod:`smo_gym.observers.filtering`). The Ackermann gain (35) is
    evaluated as :math:`\tilde l(z) = \sum_{j=0}^{n} (-z)^{n-j} v_j` with :math:`v_j = \binom{n}{j}\Phi^j
    \mathcal O^{-1} e_n` precomputed in the state's column order (the binomial expansion of
    :math:`(\Phi - zI)^n`), and the eigenvalue :math:`z` is (15) or (16) of :math:`s = -p_1|\sigma|^{q}`,
    :math:`q = d/(1 - d(n - 1))` for the degree ``d = params[5]`` (:func:`_homogeneous_root`; ``d = -1``:
    :math:`q = -1/n`, Wetzlinger et al.'s maps). ``x_new`` receives the predictor :math:`\hat\xi_{k+1}`;
    ``out_row`` the report :math:`e^{-bN}\hat z_{k+1}` of the ``z`` block with ``b = params[4]``: ``dt`` for the
    estimate at :math:`t_k` (``Levant``), 0 for the predictor itself (``DiscreteTimeHOSM``: zero times each higher
    entry is added, so the entries come out unchanged, up to the sign of a zero). Returns the innovation
    :math:`y_k - \hat z_{0,k}`.
    """
    dt = params[0]
    nf = n - m
    innovation = y - x[0]
    sigma = innovation if nf == 0 else -x[m]
    a = abs(sigma)
    z = _eigenvalue_from_root(a, _homogeneous_root(a, n, params[5]), dt, params[1], params[2], params[3])
    voff = 6
    for i in range(n):
        # the prediction: Taylor terms within the block of column i, and for a filter state the held input
        last = m if i < m else n  # one past the block of column i
        acc = x[i]
        fac = 1.0
        for l in range(1, last - i):
            fac *= dt / l
            acc += fac * x[i + l]
        if i >= m:
            acc -= fac * (dt / (n - i)) * innovation  # tau^(n-i)/(n-i)! (z_0 - y)
        # l_i(z) = sum_j (-z)^(n-j) v_j[i], Horner in (-z)
        gain = 0.0
        for j in range(n + 1):
            gain = gain * (-z) + params[voff + j * n + i]
        x_new[i] = acc + gain * sigma
    _taylor_back(x_new, m, params[4], out_row)
    return innovation


@njit(cache=CACHE, error_model="numpy", inline="always")
def _chain_loop(channel_step, state, y, params, new_state, out, shared, m, n):
    """``channel_step(x, y, params, m, n, x_new, out_row) -> innovation`` on every channel of a chain of ``n``
    states with ``m`` estimates, the innovation stored in column ``n`` (the eigenvalue-map and the filtering
    steps; ``shared``: one parameter row for every channel)."""
    failed = False
    for c in range(y.shape[0]):
        pc = 0 if shared else c  # the parameter row of channel c
        row = new_state[c]
        row[n] = channel_step(state[c], y[c], params[pc], m, n, row, out[c])
        failed |= not (_row_finite(row) and _row_finite(out[c]))
    return _check_state(new_state, out) if failed else -1


@njit(cache=CACHE, error_model="numpy")
def _eigmap_loop(state, y, params, new_state, out, shared, m, n):
    """The channel loop of :func:`eigmap_rows` for ``m`` estimates of ``n`` states (compile-time constants where
    the call passes literals)."""
    _check_widths(state, new_state, params, out, n + 1, 6 + (n + 1) * n, m)
    return _chain_loop(eigmap_channel_step, state, y, params, new_state, out, shared, m, n)


@njit(cache=CACHE, error_model="numpy")
def eigmap_rows(state, y, params, new_state, out, shared):
    """:func:`eigmap_channel_step` on every channel, ``m = out.shape[1]`` estimates of ``n = state.shape[1] - 1``
    states (``shared``: one parameter row for every channel); the common orders without filter with ``m`` a
    constant, as :func:`hosm_rows`."""
    m = out.shape[1]
    n = state.shape[1] - 1
    if m == 2 and n == 2:
        return _eigmap_loop(state, y, params, new_state, out, shared, 2, 2)
    if m == 3 and n == 3:
        return _eigmap_loop(state, y, params, new_state, out, shared, 3, 3)
    return _eigmap_loop(state, y, params, new_state, out, shared, m, n)


# ----------------------------------------------------------------------------------------------------------------
# Filtering differentiator of homogeneity degree d in [-1, 0], implicit (backward) Euler
# params row: [dt, degree, k (n)]; state row as the eigenvalue-map step's, [z_0, ..., z_{m-1}, w_1, ..., w_nf,
# innovation] with n = m + nf states
# ----------------------------------------------------------------------------------------------------------------
@njit(cache=CACHE, error_model="numpy")
def _chain_column(c, m, nf):
    """The state column of chain state ``c`` of ``w_1, ..., w_nf, z_0, ..., z_{m-1}``: the state stores the ``z``
    block first (column 0 is the value estimate, as in every family)."""
    return c - nf if c >= nf else m + c


@njit(cache=CACHE, error_model="numpy")
def _injection_sum(s, params, dt, q, n):
    r""":math:`g(s) = s + \sum_c \beta_c s^{p_c}` and :math:`g'(s)` at ``s > 0``, with :math:`\beta_c = \tau^{c+1}k_c`
    and :math:`p_c = 1 + q(c + 1)` (:func:`filtering_implicit_channel_step`)."""
    g = s
    dg = 1.0
    beta = 1.0
    for c in range(n):
        beta *= dt
        p = 1.0 + q * (c + 1)
        term = beta * params[2 + c] * s**p
        g += term
        dg += p * term / s
    return g, dg


@njit(cache=CACHE, error_model="numpy", inline="always")
def monotone_root(fun, target, params, dt, a, b):
    r"""The root ``s`` in :math:`(0, \mathrm{target}]` of :math:`g(s) = \mathrm{target}`, where
    ``fun(s, params, dt, a, b)`` returns :math:`g(s)` and :math:`g'(s)` and ``g`` increases, from below ``target``
    at :math:`0^+` to at least ``target`` at ``target``: Newton's method inside a shrinking bracket, bisecting
    where a Newton step would leave it, to a relative step of ``4e-16``. The scalar equation of every implicit
    (backward) Euler step of a signed-power differentiator has this form (:func:`_injection_sum`,
    :func:`_signed_power_sum`)."""
    lo = 0.0
    hi = target
    s = target
    for _ in range(200):
        g, dg = fun(s, params, dt, a, b)
        if g > target:
            hi = s
        else:
            lo = s
        new = s - (g - target) / dg
        if not (new > lo and new < hi):
            new = 0.5 * (lo + hi)
        if abs(new - s) <= 4e-16 * new:
            return new
        s = new
    return s


@njit(cache=CACHE, error_model="numpy")
def _newton_outputs(params, offset, x, m, out_row):
    """``out_row = M x[:m]`` for the upper-triangular output matrix ``M`` (m, m) stored row by row in ``params`` from
    ``offset`` (:func:`smo_gym.observers.differentiators.backward_difference_outputs`): the estimates of the implicit
    steps, the derivatives at the sample time from the backward-Euler states."""
    for i in range(m):
        z = 0.0
        for j in range(i, m):
            z += params[offset + i * m + j] * x[j]
        out_row[i] = z


@njit(cache=CACHE, error_model="numpy")
def filtering_implicit_channel_step(x, y, params, m, n, x_new, out_row):
    r"""One implicit (backward) Euler step of the filtering differentiator of degree ``d``
    (:class:`smo_gym.observers.FilteringDifferentiator`), in chain coordinates
    :math:`\xi = (w_1, \ldots, w_{nf}, z_0, \ldots, z_{m-1})`:

    .. math::
        \xi^+ = \xi + \tau\big(A\xi^+ + b\,y^+ + \psi(\sigma^+)\big),\qquad
        \psi_c(\sigma) = k_c\lceil\sigma\rfloor^{p_c},\quad p_c = 1 + q(c + 1),\quad q = \frac{d}{1 - d(n-1)},

    with ``A`` the shift, :math:`b = -e_{nf}` (:math:`\dot w_{nf} = z_0 - f`; ``b = 0`` without filter) and
    :math:`\sigma^+ = -w_1^+` (:math:`y^+ - z_0^+` without filter). With :math:`T = (I - \tau A)^{-1}`
    (:math:`T_{cd} = \tau^{d-c}`, ``d >= c``) it reads :math:`\xi^+ = T(\xi + \tau b y^+) + \tau T\psi(\sigma^+)`,
    whose first row is the scalar equation

    .. math:: \sigma^+ + \sum_c \beta_c\lceil\sigma^+\rfloor^{p_c} = \rho,\qquad \beta_c = \tau^{c+1}k_c,

    :math:`\rho` the error of :math:`T(\xi + \tau b y^+)`. Its left side increases strictly in :math:`\sigma^+`,
    so the solution is unique: for ``d = -1`` (:math:`p_{n-1} = 0`, a set-valued sign) it is :math:`\sigma^+ = 0`
    with :math:`\psi_{n-1} = k_{n-1}\rho/\beta_{n-1}` when :math:`|\rho| \le \beta_{n-1}`; otherwise
    :math:`\sigma^+ = \mathrm{sign}(\rho)s` with ``s`` the root of a monotone scalar equation
    (:func:`monotone_root`; for ``d = 0`` it is linear and the first Newton step solves it). Returns the
    innovation :math:`y^+ - \hat z_0`; ``out_row`` receives the estimates :math:`M z^+` of the ``z`` block, ``M``
    the output matrix of :func:`hosm_implicit_channel_step` (Newton's backward formula: on the true trajectory of a
    polynomial of degree ``< m`` the ``z`` block holds the backward differences of the samples, and ``M`` maps them
    to the derivatives at the sample time). Parameters ``[dt, d, k_0 .. k_{n-1}, M (m * m)]``.
    """
    dt = params[0]
    degree = params[1]
    nf = n - m
    moff = 2 + n
    q = degree / (1.0 - degree * (n - 1))
    # a_c = [T (xi + tau b y)]_c, by the recursion a_c = v_c + tau a_{c+1} from the last chain state up
    acc = 0.0
    for c in range(n - 1, -1, -1):
        v = x[_chain_column(c, m, nf)]
        if c == nf - 1:
            v -= dt * y
        acc = v + dt * acc
        x_new[_chain_column(c, m, nf)] = acc
    rho = (y if nf == 0 else 0.0) - x_new[_chain_column(0, m, nf)]
    # the injection psi(sigma+) solving the scalar equation, then xi+ = a + tau T psi (the same recursion)
    beta_last = dt**n * params[1 + n]
    sign = 1.0 if rho > 0.0 else -1.0
    stick = degree == -1.0 and abs(rho) <= beta_last
    s = 0.0 if (stick or rho == 0.0) else monotone_root(_injection_sum, abs(rho), params, dt, q, n)
    acc = 0.0
    for c in range(n - 1, -1, -1):
        if stick:
            psi = params[2 + c] * rho / beta_last if c == n - 1 else 0.0
        else:
            psi = sign * params[2 + c] * s ** (1.0 + q * (c + 1)) if s > 0.0 else 0.0
        acc = dt * (psi + acc)
        x_new[_chain_column(c, m, nf)] += acc
    _newton_outputs(params, moff, x_new, m, out_row)
    return y - x[0]


@njit(cache=CACHE, error_model="numpy")
def filtering_implicit_rows(state, y, params, new_state, out, shared):
    """:func:`filtering_implicit_channel_step` on every channel, ``m = out.shape[1]`` estimates of
    ``n = state.shape[1] - 1`` states (``shared``: one parameter row for every channel)."""
    m = out.shape[1]
    n = state.shape[1] - 1
    _check_widths(state, new_state, params, out, n + 1, 2 + n + m * m, m)
    return _chain_loop(filtering_implicit_channel_step, state, y, params, new_state, out, shared, m, n)


# ----------------------------------------------------------------------------------------------------------------
# Signed-power differentiators (Levant, URED, uniform Levant), implicit (backward) Euler with the outputs of Seeber
# params row: [dt, gains (m * N_TERMS), powers (m * N_TERMS), M (m * m)]; state row [xi_0, ..., xi_{m-1},
# innovation]
# ----------------------------------------------------------------------------------------------------------------
@njit(cache=CACHE, error_model="numpy")
def _signed_power_sum(s, params, dt, m, unused):
    r""":math:`g(s) = s + \sum_{c,j} \tau^{c+1} g_{cj} s^{p_{cj}}` and :math:`g'(s)` at ``s > 0``
    (:func:`hosm_implicit_channel_step`; ``unused`` keeps the signature of :func:`monotone_root`'s ``fun``)."""
    poff = 1 + m * N_TERMS
    g = s
    dg = 1.0
    beta = 1.0
    for c in range(m):
        beta *= dt
        for j in range(N_TERMS):
            gain = params[1 + c * N_TERMS + j]
            if gain != 0.0:
                p = params[poff + c * N_TERMS + j]
                term = beta * gain * s**p
                g += term
                dg += p * term / s
    return g, dg


@njit(cache=CACHE, error_model="numpy")
def hosm_implicit_channel_step(x, y, params, m, x_new, out_row):
    r"""One implicit (backward) Euler step of a signed-power differentiator (Levant 2003; Cruz-Zavala, Moreno and
    Fridman 2011; Angulo, Moreno and Fridman 2013), :math:`\dot\xi = A\xi + \psi(y - \xi_0)`:

    .. math::
        \xi^+ = \xi + \tau\big(A\xi^+ + \psi(\sigma^+)\big),\qquad \sigma^+ = y^+ - \xi_0^+,\qquad
        \psi_c(\sigma) = \sum_j g_{cj}\lceil\sigma\rfloor^{p_{cj}},

    ``A`` the shift and :math:`\lceil\sigma\rfloor^0 = \mathrm{Sign}(\sigma)` set-valued. With
    :math:`T = (I - \tau A)^{-1}` (:math:`T_{cd} = \tau^{d-c}`, ``d >= c``), :math:`\xi^+ = T\xi + \tau T\psi`,
    whose first row is the scalar equation in :math:`\sigma^+` alone

    .. math:: \sigma^+ + \sum_{c,j} \tau^{c+1} g_{cj}\lceil\sigma^+\rfloor^{p_{cj}} = \rho = y^+ - (T\xi)_0.

    Its left side increases strictly, so the solution is unique. With :math:`\theta` the sum of the
    :math:`\tau^{c+1}g_{cj}` of the sign terms (:math:`p_{cj} = 0`), :math:`|\rho| \le \theta` gives
    :math:`\sigma^+ = 0` (the estimate sticks to the measurement) with each sign term at :math:`\rho/\theta`;
    otherwise :math:`\sigma^+ = \mathrm{sign}(\rho)s`, ``s`` the root of :func:`_signed_power_sum` at
    :math:`|\rho|` (:func:`monotone_root`). Every other state is then explicit. ``out_row`` receives the
    estimates :math:`M\xi^+` (:func:`smo_gym.observers.differentiators.backward_difference_outputs`). Returns
    the innovation :math:`\rho`.
    """
    dt = params[0]
    poff = 1 + m * N_TERMS
    moff = 1 + 2 * m * N_TERMS
    # a = T xi by the recursion a_c = xi_c + tau a_{c+1} from the last state up
    acc = 0.0
    for c in range(m - 1, -1, -1):
        acc = x[c] + dt * acc
        x_new[c] = acc
    rho = y - x_new[0]
    theta = 0.0
    beta = 1.0
    for c in range(m):
        beta *= dt
        for j in range(N_TERMS):
            if params[poff + c * N_TERMS + j] == 0.0:
                theta += beta * params[1 + c * N_TERMS + j]
    stick = abs(rho) <= theta
    ratio = rho / theta if (stick and theta > 0.0) else 0.0  # the value of every sign term in the dead zone
    sign = 1.0 if rho > 0.0 else -1.0
    s = 0.0 if (stick or rho == 0.0) else monotone_root(_signed_power_sum, abs(rho), params, dt, m, 0)
    # xi+ = a + tau T psi (the same recursion)
    acc = 0.0
    for c in range(m - 1, -1, -1):
        psi = 0.0
        for j in range(N_TERMS):
            gain = params[1 + c * N_TERMS + j]
            p = params[poff + c * N_TERMS + j]
            if gain != 0.0:
                if stick:
                    psi += gain * ratio if p == 0.0 else 0.0
                elif s > 0.0:
                    psi += sign * gain * s**p
        acc = dt * (psi + acc)
        x_new[c] += acc
    if stick:
        x_new[0] = y  # what the recursion gives up to rounding: sigma+ = 0 exactly
    _newton_outputs(params, moff, x_new, m, out_row)
    return rho


@njit(cache=CACHE, error_model="numpy")
def hosm_implicit_rows(state, y, params, new_state, out, shared):
    """:func:`hosm_implicit_channel_step` on every channel, ``m = out.shape[1]`` estimates (``shared``: one
    parameter row for every channel)."""
    m = out.shape[1]
    _check_widths(state, new_state, params, out, m + 1, 1 + 2 * m * N_TERMS + m * m, m)
    failed = False
    for c in range(y.shape[0]):
        pc = 0 if shared else c  # the parameter row of channel c
        row = new_state[c]
        row[m] = hosm_implicit_channel_step(state[c], y[c], params[pc], m, row, out[c])
        failed |= not (_row_finite(row) and _row_finite(out[c]))
    return _check_state(new_state, out) if failed else -1


# ----------------------------------------------------------------------------------------------------------------
# Linear time-invariant observers (high-gain): s_new = F s + g y, out = R s_new
# params row: [F (m * m), g (m), R (m * m)]
# ----------------------------------------------------------------------------------------------------------------
@njit(cache=CACHE, error_model="numpy")
def _linear_loops(state, y, params, new_state, out, shared, m):
    """The loops of :func:`linear_rows` for ``m`` estimates (a compile-time constant where the call passes a literal).

    Two passes (``s_new = F s + g y``, then ``out = R s_new``) so that each loop has few enough strided accesses
    for LLVM's vectorizer.
    """
    goff = m * m
    roff = goff + m
    for c in range(y.shape[0]):
        pc = 0 if shared else c  # the parameter row of channel c
        for i in range(m):
            acc = params[pc, goff + i] * y[c]
            for j in range(m):
                acc += params[pc, i * m + j] * state[c, j]
            new_state[c, i] = acc
        new_state[c, m] = y[c] - state[c, 0]
    failed = False
    for c in range(y.shape[0]):
        pc = 0 if shared else c  # the parameter row of channel c
        for i in range(m):
            acc = 0.0
            for j in range(m):
                acc += params[pc, roff + i * m + j] * new_state[c, j]
            out[c, i] = acc
            failed |= not (math.isfinite(acc) & math.isfinite(new_state[c, i]))
        failed |= not math.isfinite(new_state[c, m])
    return _check_state(new_state, out) if failed else -1


@njit(cache=CACHE, error_model="numpy")
def linear_rows(state, y, params, new_state, out, shared):
    r"""The linear step :math:`s^+ = F s + g y`, :math:`\hat x = R s^+` on every channel (``shared``: one parameter
    row for every channel)."""
    m = out.shape[1]
    # fixed widths for the common orders (constant strides and unrolled loops, see module notes)
    if m == 2:
        _check_widths(state, new_state, params, out, 3, 10, 2)
        return _linear_loops(state, y, params, new_state, out, shared, 2)
    if m == 3:
        _check_widths(state, new_state, params, out, 4, 21, 3)
        return _linear_loops(state, y, params, new_state, out, shared, 3)
    return _linear_loops(state, y, params, new_state, out, shared, m)


# ----------------------------------------------------------------------------------------------------------------
# Constant-acceleration Kalman filter (3 states, scalar measurement), its covariance in U-D factors (G. J. Bierman,
# *Factorization Methods for Discrete Sequential Estimation*, Academic Press 1977)
# state row: [x0, x1, x2, U01, U02, U12, D0, D1, D2, innovation, rate]; params row: [dt, q, r, huber]
# ----------------------------------------------------------------------------------------------------------------
# The covariance is carried as :math:`P = U D U^T` (``U`` unit upper triangular, ``D`` diagonal): the
# recursion :math:`P^+ = P^- - K c^T P^-` subtracts nearly equal numbers when the measurement variance is small
# against the predicted one, and in double precision loses the covariance's positivity once their ratio is below
# about 1e-15 (a measurement variance of 1e-20 against a prior velocity spread of 10 at 1 ms), where the IMM
# estimator would take the logarithm of a negative innovation variance. The factored updates only add positive
# terms to ``D``: measured against the recursion in 60-digit arithmetic, within 1e-8 of the covariance's size at
# such ratios (1e-15 at moderate ones).
@njit(cache=CACHE, error_model="numpy")
def ud_of_sum(a01, a02, a12, p0, p1, p2, b01, b02, b12, q0, q1, q2, d0, d1, d2, s):
    r"""U-D factors of :math:`A\operatorname{diag}(p)A^T + B\operatorname{diag}(q)B^T + s\,dd^T` for unit upper
    triangular ``A`` and ``B`` (entries ``a01, a02, a12`` and ``b01, b02, b12``), weights ``p, q, s >= 0`` and a
    column ``d``: modified weighted Gram-Schmidt (Thornton 1976, in Bierman 1977).

    With :math:`W = [A \mid B \mid d]` (3 x 7) and its weights :math:`w`, the rows of ``W`` are taken last first:
    :math:`D_j = \sum_k w_k W_{jk}^2` and :math:`U_{ij} = \sum_k w_k W_{ik} W_{jk} / D_j` for :math:`i < j`,
    after which row ``i`` loses its part along row ``j``. Only sums of non-negative terms make ``D``, so the sum's
    factors stay positive where forming it and factoring it again would lose its small directions to rounding.
    Returns ``(U01, U02, U12, D0, D1, D2)``.
    """
    # j = 2: row 2 of W is (0, 0, 1 | 0, 0, 1 | d2)
    D2 = p2 + q2 + s * d2 * d2
    U12 = (p2 * a12 + q2 * b12 + s * d1 * d2) / D2
    U02 = (p2 * a02 + q2 * b02 + s * d0 * d2) / D2
    # rows 1 and 0 lose their part along row 2
    g12, h12, e1 = a12 - U12, b12 - U12, d1 - U12 * d2  # row 1: (0, 1, g12 | 0, 1, h12 | e1)
    g02, h02, e0 = a02 - U02, b02 - U02, d0 - U02 * d2  # row 0: (1, a01, g02 | 1, b01, h02 | e0)
    # j = 1
    D1 = p1 + p2 * g12 * g12 + q1 + q2 * h12 * h12 + s * e1 * e1
    U01 = (p1 * a01 + p2 * g02 * g12 + q1 * b01 + q2 * h02 * h12 + s * e0 * e1) / D1
    # j = 0, after row 0 lost its part along row 1
    r1, r2, t1, t2, e = a01 - U01, g02 - U01 * g12, b01 - U01, h02 - U01 * h12, e0 - U01 * e1
    D0 = p0 + p1 * r1 * r1 + p2 * r2 * r2 + q0 + q1 * t1 * t1 + q2 * t2 * t2 + s * e * e
    return U01, U02, U12, D0, D1, D2


@njit(cache=CACHE, error_model="numpy")
def kalman_ca_prior_factors(u01, u02, u12, d0, d1, d2, dt, q):
    r"""Factors of the prior covariance :math:`P^- = F P F^T + Q` from those of ``P`` (Thornton's time update):
    :func:`ud_of_sum` of :math:`FU\operatorname{diag}(D)(FU)^T + U_Q D_Q U_Q^T`, ``FU`` being unit upper
    triangular as ``U`` is, with the white-jerk ``Q`` factored in closed form,

    .. math::
        U_Q = \begin{bmatrix} 1 & \tau/2 & \tau^2/6\\ 0 & 1 & \tau/2\\ 0 & 0 & 1\end{bmatrix},\qquad
        D_Q = q\tau\,\operatorname{diag}(\tau^4/720,\ \tau^2/12,\ 1).

    Returns ``(U01, U02, U12, D0, D1, D2)``.
    """
    e2 = q * dt
    return ud_of_sum(
        u01 + dt,  # F U = (I + tau N + tau^2 N^2 / 2) U
        u02 + dt * u12 + 0.5 * dt * dt,
        u12 + dt,
        d0,
        d1,
        d2,
        0.5 * dt,  # U_Q
        dt * dt / 6.0,
        0.5 * dt,
        e2 * dt**4 / 720.0,  # D_Q
        e2 * dt * dt / 12.0,
        e2,
        0.0,
        0.0,
        0.0,
        0.0,
    )


@njit(cache=CACHE, error_model="numpy")
def kalman_ca_posterior_factors(u01, u02, u12, d0, d1, d2, r):
    r"""Gain :math:`K = P^- c / S`, :math:`S = c^T P^- c + r`, and the factors of :math:`P^+ = P^- - K c^T P^-`,
    ``c = (1, 0, 0)``, from those of :math:`P^-`: Bierman's measurement update (Bierman 1977).

    With :math:`f = U^T c = (1, U_{01}, U_{02})` and :math:`v = D f`, the partial sums
    :math:`\alpha_j = r + \sum_{k \le j} f_k v_k` (:math:`\alpha_2 = S`) give :math:`D^+_j = D_j
    \alpha_{j-1}/\alpha_j` (:math:`\alpha_{-1} = r`), products of positive numbers. Returns
    ``(U01, U02, U12, D0, D1, D2, k0, k1, k2, S)``.
    """
    v1, v2 = d1 * u01, d2 * u02
    a0 = r + d0
    a1 = a0 + u01 * v1
    a2 = a1 + u02 * v2
    i0, i1, i2 = 1.0 / a0, 1.0 / a1, 1.0 / a2
    # ratios first: a product of two variances overflows where both are above 1e154 (a record in large units)
    f0, f1, f2 = r * i0, a0 * i1, a1 * i2
    # U01 + b0 (-U01 / a0) with b0 = D0, and U02 + b0 (-U02 / a1) with b0 = D0 + U01 v1: both are U r / a
    n01, n02 = u01 * f0, u02 * (r * i1)
    n12 = u12 - u02 * (v1 * i1)
    b0 = d0 + u01 * v1 + u02 * v2  # P^- c
    b1 = v1 + u12 * v2
    return n01, n02, n12, d0 * f0, d1 * f1, d2 * f2, b0 * i2, b1 * i2, v2 * i2, a2


@njit(cache=CACHE, error_model="numpy")
def kalman_ca_add_acceleration_variance(u01, u02, u12, d0, d1, d2, delta):
    r"""Factors of :math:`P + \delta e_2 e_2^T` (the acceleration's variance grown by ``delta`` >= 0) from those
    of ``P``: the Agee-Turner rank-one update (Agee and Turner 1972, in Bierman 1977), which only adds to ``D``.

    Returns ``(U01, U02, U12, D0, D1, D2)``.
    """
    n2 = d2 + delta  # j = 2, a = e2
    beta = delta / n2
    delta *= d2 / n2
    a0, a1 = -u02, -u12  # a - a_2 U[:, 2]
    n02, n12 = u02 + beta * a0, u12 + beta * a1
    n1 = d1 + delta * a1 * a1  # j = 1
    beta = delta * a1 / n1
    delta *= d1 / n1
    a0 -= a1 * u01
    n01 = u01 + beta * a0
    return n01, n02, n12, d0 + delta * a0 * a0, n1, n2


#: Huber's update of the constant-acceleration filters (``huber``) is suspended while the share of the recent
#: innovations beyond its bound exceeds what Gaussian innovations give by more than this: a sensor's rare gross
#: errors add about their own rate (one sample in a thousand, say), and an excess this large says the model does
#: not fit the motion (a jerk far above the calibrated one), which clipping would only make the filter lose
HUBER_SUSPEND_EXCESS = 0.05
#: weight of the newest sample in that share (an exponential average over about 100 samples)
HUBER_RATE_WEIGHT = 0.01


@njit(cache=CACHE, error_model="numpy")
def huber_limit(huber, variance, previous, rate):
    r"""The bound :math:`c\sqrt S` to which Huber's function clips this sample's innovation (``inf``: the Kalman
    update), for the threshold ``huber`` ``c`` (``inf``: off) and the innovation variance ``variance`` ``S``.

    A gross error is a single sample: if the ``previous`` innovation was beyond the bound too, two in a row are a
    change of motion the model did not expect, taken whole; and while the exponential average ``rate`` of samples
    beyond it exceeds the share of Gaussian innovations beyond ``c`` standard deviations,
    :math:`\operatorname{erfc}(c/\sqrt 2)` (0.27 % at ``c = 3``), by more than :data:`HUBER_SUSPEND_EXCESS`, the
    model does not fit the motion and clipping is suspended.
    """
    if huber == math.inf:  # the Kalman filter
        return math.inf
    bound = huber * math.sqrt(variance)
    if abs(previous) > bound or rate > math.erfc(huber / math.sqrt(2.0)) + HUBER_SUSPEND_EXCESS:
        return math.inf
    return bound


@njit(cache=CACHE, error_model="numpy")
def huber_rate(rate, nu, huber, variance):
    """The exponential average of samples whose innovation ``nu`` is beyond ``huber`` standard deviations, updated
    (:data:`HUBER_RATE_WEIGHT`); zero while ``huber`` is ``inf``."""
    beyond = 1.0 if abs(nu) > huber * math.sqrt(variance) else 0.0
    return rate + HUBER_RATE_WEIGHT * (beyond - rate)


@njit(cache=CACHE, error_model="numpy")
def kalman_ca_mean(x0, x1, x2, y, dt, k0, k1, k2, limit):
    r"""Mean half of :func:`kalman_ca_rows`: :math:`x^- = F x`, :math:`x^+ = x^- + K\psi(y - c^T x^-)`.

    :math:`\psi(\nu) = \max(-\ell, \min(\nu, \ell))` is Huber's function with the bound ``limit`` ``l``
    (:func:`huber_limit`; Masreliez and Martin 1977), the identity for ``inf`` (the Kalman filter). Returns
    ``(x0, x1, x2, nu)`` with the innovation :math:`\nu = y - c^T x^-` (not clipped).
    """
    h = 0.5 * dt * dt
    # x^- = F x                                                   (prior mean)
    m0 = x0 + dt * x1 + h * x2
    m1 = x1 + dt * x2
    m2 = x2
    nu = y - m0
    used = max(-limit, min(nu, limit))  # Huber's psi: beyond the bound an innovation counts as the bound
    # x^+ = x^- + K psi(nu)                                        (posterior mean)
    return m0 + k0 * used, m1 + k1 * used, m2 + k2 * used, nu


@njit(cache=CACHE, error_model="numpy")
def kalman_ca_rows(state, y, params, new_state, out, shared):
    r"""The constant-acceleration Kalman filter on every channel (``shared``: one parameter row for every channel):
    predict with :math:`F = e^{\tau N}` and the white-jerk process noise, then update with ``y``,

    .. math::
        Q = q\begin{bmatrix} \tau^5/20 & \tau^4/8 & \tau^3/6\\ \tau^4/8 & \tau^3/3 & \tau^2/2\\
            \tau^3/6 & \tau^2/2 & \tau\end{bmatrix},\qquad
        K = P^- c / (c^T P^- c + r),\quad c = (1, 0, 0),

    the covariance half in U-D factors by :func:`kalman_ca_prior_factors` and :func:`kalman_ca_posterior_factors`
    (independent of the measurements), the mean half by :func:`kalman_ca_mean` with Huber's bound
    :func:`huber_limit`. State row: ``[x0, x1, x2, U01, U02, U12, D0, D1, D2, nu, rate]`` (the covariance
    :math:`P = UDU^T`, the last innovation and the share of innovations beyond Huber's bound, :func:`huber_rate`);
    params ``[dt, q, r, huber]``.
    """
    _check_widths(state, new_state, params, out, 11, 4, 3)
    # three passes (prior factors, posterior factors and gain, mean) so that each loop has few enough strided
    # accesses for LLVM's vectorizer; the prior waits in ``new_state``, the gain in ``out`` and the innovation
    # variance in the innovation's column
    for c in range(y.shape[0]):
        pc = 0 if shared else c  # the parameter row of channel c
        M = kalman_ca_prior_factors(
            state[c, 3], state[c, 4], state[c, 5], state[c, 6], state[c, 7], state[c, 8], params[pc, 0], params[pc, 1]
        )
        for i in range(6):
            new_state[c, 3 + i] = M[i]
    failed = False
    for c in range(y.shape[0]):
        pc = 0 if shared else c  # the parameter row of channel c
        P = kalman_ca_posterior_factors(
            new_state[c, 3],
            new_state[c, 4],
            new_state[c, 5],
            new_state[c, 6],
            new_state[c, 7],
            new_state[c, 8],
            params[pc, 2],
        )
        for i in range(6):
            new_state[c, 3 + i] = P[i]
            failed |= not math.isfinite(P[i])
        out[c, 0] = P[6]
        out[c, 1] = P[7]
        out[c, 2] = P[8]
        new_state[c, 9] = P[9]
    for c in range(y.shape[0]):
        pc = 0 if shared else c  # the parameter row of channel c
        huber, variance = params[pc, 3], new_state[c, 9]
        limit = huber_limit(huber, variance, state[c, 9], state[c, 10])
        x0, x1, x2, nu = kalman_ca_mean(
            state[c, 0], state[c, 1], state[c, 2], y[c], params[pc, 0], out[c, 0], out[c, 1], out[c, 2], limit
        )
        new_state[c, 0] = x0
        new_state[c, 1] = x1
        new_state[c, 2] = x2
        new_state[c, 9] = nu
        new_state[c, 10] = huber_rate(state[c, 10], nu, huber, variance)
        out[c, 0] = x0
        out[c, 1] = x1
        out[c, 2] = x2
        failed |= not (math.isfinite(x0) & math.isfinite(x1) & math.isfinite(x2) & math.isfinite(nu))
    return _check_state(new_state, out) if failed else -1


# ----------------------------------------------------------------------------------------------------------------
# Backward finite differences (order 1 or 2)
# state row: [y, v, (a), innovation, samples since reset]; params row: [dt]
# ----------------------------------------------------------------------------------------------------------------
@njit(cache=CACHE, error_model="numpy")
def _finite_difference_loop(state, y, params, new_state, out, shared, m):
    """The loop of :func:`finite_difference_rows` for ``m`` = 2 or 3 estimates (a compile-time constant where the
    call passes a literal)."""
    _check_widths(state, new_state, params, out, m + 2, 1, m)
    failed = False
    for c in range(y.shape[0]):
        pc = 0 if shared else c  # the parameter row of channel c
        dt = params[pc, 0]
        count = state[c, m + 1]
        yc = y[c]
        y0 = state[c, 0]
        v = (yc - y0) / dt
        new_state[c, 0] = yc
        new_state[c, 1] = v
        out[c, 0] = yc
        out[c, 1] = v
        if m > 2:
            # the first difference after a reset has no previous velocity: keep acceleration at zero
            a = (v - state[c, 1]) / dt if count >= 1.0 else 0.0
            new_state[c, 2] = a
            out[c, 2] = a
            failed |= not math.isfinite(a)
        new_state[c, m] = yc - y0
        new_state[c, m + 1] = count + 1.0
        failed |= not (math.isfinite(v) & math.isfinite(yc - y0) & math.isfinite(count + 1.0))
    return _check_state(new_state, out) if failed else -1


@njit(cache=CACHE, error_model="numpy")
def finite_difference_rows(state, y, params, new_state, out, shared):
    """Backward differences of order 1 or 2 on every channel (``shared``: one row for every channel)."""
    if out.shape[1] == 2:
        return _finite_difference_loop(state, y, params, new_state, out, shared, 2)
    return _finite_difference_loop(state, y, params, new_state, out, shared, 3)


# ----------------------------------------------------------------------------------------------------------------
# offline driver
# ----------------------------------------------------------------------------------------------------------------
@njit(error_model="numpy")
def _copy_rows(src, dst):
    """``dst[:, :] = src`` for two ``(N, S)`` arrays, as a loop.

    A slice assignment between arrays makes numba compile its shape-mismatch error message (string formatting:
    about 10 s of a cold compile, once per driver); this loop compiles in milliseconds.
    """
    for i in range(src.shape[0]):
        for j in range(src.shape[1]):
            dst[i, j] = src[i, j]


@njit(error_model="numpy", inline="always")
def _drive(kernel, state, Y, params, out):
    """The time loop of :func:`run_offline`, inlined into each kernel's compiled driver (it takes the kernel
    as an argument, which only an inlined function can do and still be cached).

    Ping-pong between ``state`` and one scratch buffer (no copy per sample), unrolled by two samples: the first
    call of a pair reads ``state`` and writes the scratch buffer, the second the reverse. Swapping two array
    variables instead (one call site) leaves LLVM with loop-carried array descriptors and halves the throughput of
    the vectorized kernel loop (measured for the implicit super-twisting kernel: 85 against 160 M channel-samples/s
    at 32768 channels). ``state`` receives the last accepted state at the end, also when a sample fails.
    """
    scratch = np.empty_like(state)
    T = Y.shape[0]
    for t in range(0, T, 2):
        status = kernel(state, Y[t], params, scratch, out[t])
        if status != -1:
            return status, t
        if t + 1 < T:
            status = kernel(scratch, Y[t + 1], params, state, out[t + 1])
            if status != -1:
                _copy_rows(scratch, state)
                return status, t + 1
    if T % 2 == 1:
        _copy_rows(scratch, state)
    return -1, T


@njit(error_model="numpy", inline="always")
def _drive_wrapped(kernel, state, Y, params, out, period):
    """The time loop with :func:`unwrap_measurement` before every sample (channels with ``period > 0`` wrap),
    swapping its two state arrays after each sample (one call site: the wrapped path is not the fast one).

    A failed sample reports the channel of ``Y[t]``: a non-finite measurement stays non-finite when unwrapped.
    """
    cur = state
    nxt = np.empty_like(state)
    y = np.empty(Y.shape[1])
    T = Y.shape[0]
    for t in range(T):
        _unwrap_rows(Y[t], cur, period, y)
        status = kernel(cur, y, params, nxt, out[t])
        if status != -1:
            if t % 2 == 1:
                _copy_rows(cur, state)
            return status, t
        cur, nxt = nxt, cur
    if T % 2 == 1:
        _copy_rows(cur, state)
    return -1, T


# ----------------------------------------------------------------------------------------------------------------
# registered steps: each gets its batch kernels and offline drivers, generated and cached
# ----------------------------------------------------------------------------------------------------------------
_ROWS = _SHARED = _KERNEL = None  # the globals of the templates below, bound per step by cached_instance


def _batch_template(state, y, params, new_state, out):
    """A batch kernel (module notes): the measurement checked, then ``_ROWS`` with ``shared = _SHARED``."""
    y, out = _flat(y, out)
    bad = _first_nonfinite(y)
    if bad >= 0:
        return bad
    _check_rows(params, y.shape[0], _SHARED)
    return _ROWS(state, y, params, new_state, out, _SHARED)


def _run_template(state, Y, params, out):
    """The offline driver of ``_KERNEL``: :func:`_drive` calling it."""
    return _drive(_KERNEL, state, Y, params, out)


def _run_wrapped_template(state, Y, params, out, period):
    """The offline driver of ``_KERNEL`` for wrapped channels: :func:`_drive_wrapped` calling it."""
    return _drive_wrapped(_KERNEL, state, Y, params, out, period)


@dataclass(frozen=True)
class Step:
    """The compiled functions of one registered step (:func:`register_step`).

    Attributes
    ----------
    rows : numba dispatcher
        ``rows(state, y, params, new_state, out, shared) -> status``: the step on ``N`` channels whose
        measurements are known to be finite (``params`` one row per channel, or one row if ``shared``).
    kernel : numba dispatcher
        The batch kernel ``kernel(state, y, params, new_state, out) -> status`` (module notes), per-channel rows.
    shared_kernel : numba dispatcher
        The same for one parameter row ``(1, P)`` shared by every channel (the loops see ``shared`` as a constant).
    run : numba dispatcher
        ``run(state, Y, params, out) -> (status, t)``: the offline time loop calling :attr:`kernel`.
    run_wrapped : numba dispatcher
        ``run_wrapped(state, Y, params, out, period)``: the same with :func:`unwrap_measurement` per sample.
    shared_run, shared_run_wrapped : numba dispatcher
        :attr:`run` and :attr:`run_wrapped` calling :attr:`shared_kernel` (one parameter row ``(1, P)``).
    sources : tuple of str
        The files whose code a compiled caller of :attr:`rows` contains (``rows``'s module, and those of the
        functions it calls from other modules): a caller's cached code is dropped when one of them changes.
    """

    rows: Any
    kernel: Any
    shared_kernel: Any
    run: Any
    run_wrapped: Any
    shared_run: Any
    shared_run_wrapped: Any
    sources: tuple = ()

    @property
    def label(self) -> str:
        """The qualified name of :attr:`rows`, which names the generated functions in numba's cache."""
        return f"{self.rows.py_func.__module__}.{self.rows.py_func.__qualname__}"


#: batch kernel -> its :class:`Step`, for every registered step
STEPS: dict = {}
#: batch kernel (per-channel or shared) -> its offline drivers ``(run, run_wrapped)``, for :func:`run_offline`
_DRIVERS: dict = {}


def register_step(rows, *, allocates: bool = False, sources: Sequence[str] = (), helpers: Sequence = ()) -> Step:
    """Generate and register the batch kernels and the offline drivers of a step (idempotent).

    ``rows`` is a module-level ``@njit(cache=True)`` function
    ``rows(state, y, params, new_state, out, shared) -> status`` (the calling convention of the module notes, after
    the measurements were found finite). Every generated function is cached on disk by numba and reused by a new
    process (:func:`smo_gym._numba_cache.cached_instance`), and its cache is dropped when ``rows``'s module
    changes. Observer families name the returned :attr:`Step.kernel` as their ``_kernel``;
    :func:`smo_gym.observers.registry.register_observer` registers the steps a family declares. ``allocates``:
    ``rows`` creates arrays, so its batch kernels keep numba's reference counting (module notes). ``sources``: the
    files of other modules whose functions ``rows`` calls (:attr:`Step.sources`). ``helpers``: the other cached
    functions of ``rows``'s module that it calls and that call this module's functions (a channel step): numba checks
    their own file only, so their cache is dropped with ``rows``'s when this module changed. A :class:`Step` is
    returned as it is.
    """
    if isinstance(rows, Step):
        return rows
    for step in STEPS.values():
        if step.rows is rows:
            return step
    label = f"{rows.py_func.__module__}.{rows.py_func.__qualname__}"
    deps = sorted({inspect.getfile(rows.py_func), __file__, *sources})
    drop_stale([rows, *helpers], [__file__])  # cached in their own module, they link this module's functions
    options = dict(KERNEL, _nrt=True) if allocates and "_nrt" in KERNEL else KERNEL
    kernel = cached_instance(_batch_template, label, options, deps, _ROWS=rows, _SHARED=False)
    shared = cached_instance(_batch_template, label + ".shared", options, deps, _ROWS=rows, _SHARED=True)
    driver = dict(cache=CACHE, error_model="numpy")  # numba compiles each on its first call only
    step = Step(
        rows=rows,
        kernel=kernel,
        shared_kernel=shared,
        run=cached_instance(_run_template, label, driver, deps, _KERNEL=kernel),
        run_wrapped=cached_instance(_run_wrapped_template, label, driver, deps, _KERNEL=kernel),
        shared_run=cached_instance(_run_template, label + ".shared", driver, deps, _KERNEL=shared),
        shared_run_wrapped=cached_instance(_run_wrapped_template, label + ".shared", driver, deps, _KERNEL=shared),
        sources=tuple(deps),
    )
    STEPS[kernel] = step
    _DRIVERS[kernel] = (step.run, step.run_wrapped)
    _DRIVERS[shared] = (step.shared_run, step.shared_run_wrapped)
    return step


hosm = register_step(hosm_rows)
sta_implicit = register_step(sta_implicit_rows)
eigmap = register_step(eigmap_rows)
filtering_implicit = register_step(filtering_implicit_rows)
hosm_implicit = register_step(hosm_implicit_rows)
linear = register_step(linear_rows)
kalman_ca = register_step(kalman_ca_rows)
finite_difference = register_step(finite_difference_rows)
#: the batch kernels of this module's steps, by the names the observer classes use
hosm_kernel, hosm_shared_kernel = hosm.kernel, hosm.shared_kernel
sta_implicit_kernel, sta_implicit_shared_kernel = sta_implicit.kernel, sta_implicit.shared_kernel
eigmap_kernel, eigmap_shared_kernel = eigmap.kernel, eigmap.shared_kernel
filtering_implicit_kernel = filtering_implicit.kernel
hosm_implicit_kernel, hosm_implicit_shared_kernel = hosm_implicit.kernel, hosm_implicit.shared_kernel
linear_kernel, linear_shared_kernel = linear.kernel, linear.shared_kernel
kalman_ca_kernel, kalman_ca_shared_kernel = kalman_ca.kernel, kalman_ca.shared_kernel
finite_difference_kernel, finite_difference_shared_kernel = finite_difference.kernel, finite_difference.shared_kernel


def _run_python(kernel, state, Y, params, out, period=None):
    """The time loop of :func:`_drive` in Python, for a kernel written in NumPy (not compiled)."""
    cur, nxt = state.copy(), np.empty_like(state)
    y = np.empty(Y.shape[1])
    for t in range(Y.shape[0]):
        if period is None:
            y = Y[t]
        else:
            _unwrap_rows(Y[t], cur, period, y)
        status = kernel(cur, y, params, nxt, out[t])
        if status != -1:
            state[:, :] = cur
            return status, t
        cur, nxt = nxt, cur
    state[:, :] = cur
    return -1, Y.shape[0]


def run_offline(kernel, state, Y, params, out, period=None):
    """Apply ``kernel`` to every row of ``Y`` (T, N); write estimates into ``out`` (T, N, m).

    Returns ``(status, t)``: ``status`` as the kernel's, ``t`` the sample at which it failed (or ``T``).
    ``state`` holds the last accepted state on return (the final state on success). A registered kernel
    (:attr:`Step.kernel` with a row of ``params`` per channel, or :attr:`Step.shared_kernel` with one row) runs
    through its cached compiled driver; a kernel written in NumPy through a Python loop. ``period`` (N,), optional:
    wrap the channels with ``period > 0`` (:func:`unwrap_measurement` before every sample).
    """
    drivers = _DRIVERS.get(kernel)
    if drivers is None:
        if isinstance(kernel, Dispatcher):
            raise TypeError(
                f"expected a kernel registered with register_step (a compiled driver for it), actual value: {kernel!r}"
            )
        return _run_python(kernel, state, Y, params, out, period)
    run, run_wrapped = drivers
    if period is not None:
        return run_wrapped(state, Y, params, out, period)
    return run(state, Y, params, out)
