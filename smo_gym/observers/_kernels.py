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
Explicit schemes in the literature (Livne & Levant 2014; Wetzlinger et al., paper 003) are written as one-step
predictors, :math:`\hat x_{k+1} = F(\hat x_k, y_k)`: the state after seeing :math:`y_k` estimates the signal at
:math:`t_{k+1}`. The state stored here is exactly that predictor, so the recursion is the published one. The
*reported* estimate at :math:`t_k` is that prediction moved back by one step along the Taylor polynomial,
:math:`e^{-\tau N}\hat x_{k+1}` (``N`` the shift matrix), which is unbiased to the same order as the predictor and
uses the newest sample. Implicit schemes are already written at :math:`t_k` and report their state directly.

Performance
-----------
A call costs the compiled entry point (about 0.13 us for five array arguments, measured with an empty kernel
compiled as the batch kernels are, by ``scripts/bench_observers.py``) plus a few ns per channel. What keeps both
small:

* Fixed shapes at compile time. The kernels of the common sizes (order 1 and 2, i.e. ``m = 2, 3`` estimates)
  check the widths of their arrays once per call and then index them with constant strides, so LLVM vectorizes
  the loop over channels (AVX2: four channels per instruction) and unrolls the loops over the state.
* No early exit inside the channel loop: the finiteness of the new state is collected in a flag and located by
  a second pass only when something is not finite (then the status is the same ``-2 - i`` as before).
* Known exponents. The HOSM kernel recognises the exponent tables of Levant's, URED's and the uniform
  differentiator (``m = 2, 3``) from the first parameter row and runs a step in which every
  :math:`|e|^{q/m}` is a product of the root :math:`r = |e|^{1/m}` with ``q`` a compile-time constant; other
  tables run the generic step (:func:`hosm_channel_step`, one ``r`` and :func:`_abs_power` per term).
* Vectorizable roots: ``sqrt`` for ``m = 2``; for ``m = 3`` the cube root of fdlibm (:func:`cbrt`: a bit-level
  first guess, a polynomial and one refinement step, error below 1 ulp) instead of ``exp(log(a) / 3)``, and
  fdlibm's ``exp`` (:func:`exp_nonpositive`) for the matching eigenvalue map, both written with plain arithmetic
  so that they vectorize (numba has no vector math library without SVML). The eigenvalue maps use the same
  ``cbrt`` for ``m = 3`` (see :func:`_eigenvalue_root` for how far that moves them from NumPy's ``a ** (1/3)``)
  and compute root and map in one vectorized pass.
* Few strided accesses per loop. LLVM's vectorizer gives up on a loop with too many accesses at non-unit
  strides (``Too many SCEV assumptions``), so wide steps run in several passes over the channels, the
  intermediate values waiting in ``new_state`` or ``out``: two for the order-2 HOSM step (the root, then the
  rest), the order-2 eigenvalue-mapping step (the eigenvalue, then the rest) and the linear observer, three for
  the Kalman filter. Merging passes further was measured slower (the merged loop stays scalar); what remains
  per channel is mostly the strided loads and stores of the ``(N, S)``/``(N, P)`` rows themselves.
* Shared parameters. When every channel has the same parameter row (scalar gains: the usual case),
  ``Observer.update`` passes that one row ``(1, P)`` to the kernel's ``*_shared_kernel`` variant
  (:data:`SHARED_KERNELS`), whose loops are compiled with ``shared`` as a constant (they read parameter row
  ``pc = 0 if shared else c``): every parameter is then loop invariant instead of a load at a stride of ``P``
  values per channel (measured 10-15 % faster at 32 channels). The variants are separate functions (one factory
  per family, ``shared`` a closure constant) so that each compiles only when used; one function with both loops
  took seven times as long to compile. ``Observer.run`` and the wrapper's compiled drivers use the per-channel
  kernels.
* No reference counting at the entry. The batch kernels are compiled with numba's ``_nrt=False``: called from
  Python, their arrays are then unboxed without allocating a reference-counted ``MemInfo`` each, which halves
  the cost of the call (an empty five-array kernel: 0.27 against 0.13 us). The kernels allocate nothing, and
  inlined into a compiled driver they take the driver's options.
* ``error_model="numpy"`` (no zero-division checks: every divisor is positive for valid parameters; a
  non-finite result still ends as status ``-2 - i``), and ``_flat`` reshapes only measurements with batch
  dimensions (a 1-D ``y`` passes through untouched).

These change results by rounding only (a few ulp per step, from the roots and ``exp``); through the
discontinuous sign of a sliding-mode step such a difference can grow along a chattering trajectory, like any
change of compiler or instruction order would.

Contract of the specialised HOSM steps: the exponent columns, the unused-term gains and the scheme flag must be
the same in every parameter row (the observer classes pack them so); the kernel reads them from the first row to
choose the step. Step sizes and gains remain per channel.
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic, overload

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
KERNEL = dict(cache=CACHE, error_model="numpy", inline="always", **_without_nrt())


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
def _store_order2(state, new_state, out, c, dt, n0, n1, n2, innovation):
    r"""Write row ``c`` of an order-2 step: the new state ``(n0, n1, n2)`` and the estimate
    :math:`e^{-\tau N}\hat x^+` (the operations of :func:`_taylor_back` for ``m = 3``). Returns whether the row,
    its estimate, its innovation or the old row's last column is not finite.

    Reading the whole old row (its last column only for this flag) leaves no gap in the load group, so LLVM needs
    no scalar tail; a flag raised by that column alone ends in :func:`_check_state`, which returns -1.
    """
    new_state[c, 0] = n0
    new_state[c, 1] = n1
    new_state[c, 2] = n2
    o0 = n0 + (-dt) * n1 + ((-dt) * (-dt / 2.0)) * n2
    o1 = n1 + (-dt) * n2
    out[c, 0] = o0
    out[c, 1] = o1
    out[c, 2] = n2
    return not (
        math.isfinite(n0)
        & math.isfinite(n1)
        & math.isfinite(n2)
        & math.isfinite(innovation)
        & math.isfinite(state[c, 3])
        & math.isfinite(o0)
        & math.isfinite(o1)
    )


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


@njit(cache=CACHE, error_model="numpy", inline="always")
def _check_rows(params, n, shared):
    """Require one parameter row per channel (``n``), or a single row if ``shared``."""
    if params.shape[0] != (1 if shared else n):
        raise ValueError("expected params with one row per channel, or one row for a *_shared_kernel")


@njit(cache=CACHE, error_model="numpy", inline="always")
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


@njit(cache=CACHE, error_model="numpy", inline="always")
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


@njit(cache=CACHE, error_model="numpy", inline="always")
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


@njit(cache=CACHE, error_model="numpy", inline="always")
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


@njit(cache=CACHE, error_model="numpy", inline="always")
def _pow2(k):
    """``2.0 ** k`` for an integer-valued float ``-1022 <= k <= 1023`` (bits of the exponent field)."""
    # k + 1.5 * 2^52 has k in its low mantissa bits: an int conversion AVX2 can vectorize (cvtpd2qq cannot)
    ki = _bits(k + 6755399441055744.0) - 0x4338000000000000
    return _from_bits((ki + 1023) << 52)


@njit(cache=CACHE, error_model="numpy", inline="always")
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


@njit(cache=CACHE, error_model="numpy", inline="always")
def _row_finite(row):
    """Whether every entry of a state row is finite (checked per channel, right after the channel's step)."""
    for j in range(row.shape[0]):  # noqa: SIM110 - a loop numba compiles; all() of a generator it does not
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


@njit(cache=CACHE, error_model="numpy", inline="always")
def _rpow(r, q):
    """``r**q`` for an integer ``q >= 0`` by repeated multiplication (as :func:`_abs_power`)."""
    acc = 1.0
    for _ in range(q):
        acc *= r
    return acc


@njit(cache=CACHE, error_model="numpy", inline="always")
def _injection(prow, i, r, qi):
    r"""``sum_j g_ij r^q_ij`` over the terms of state ``i``; ``qi`` a compile-time tuple, ``q < 0`` = no term."""
    acc = 0.0
    for j in range(N_TERMS):
        if qi[j] >= 0:
            acc += prow[2 + i * N_TERMS + j] * _rpow(r, qi[j])
    return acc


#: exponent numerators ``q_ij`` (power ``q_ij / m``; -1 = unused term, zero gain) of the specialised HOSM steps
LEVANT_Q2 = ((1, -1, -1), (0, -1, -1))  # Levant k = 1 and explicit super-twisting: 1/2, 0
URED_Q = ((1, 3, -1), (0, 2, 4))  # URED: 1/2, 3/2 | 0, 1, 2
LEVANT_Q3 = ((2, -1, -1), (1, -1, -1), (0, -1, -1))  # Levant k = 2: 2/3, 1/3, 0
UNIFORM_Q3 = ((2, 4, -1), (1, 5, -1), (0, 6, -1))  # uniform Levant k = 2, alpha = 1: (3 -+ i) / 3


@njit(cache=CACHE, error_model="numpy", inline="always")
def _matches(params, m, q):
    """Whether the first parameter row has the exponent table ``q`` (the test of :func:`_abs_power`, 1e-12)."""
    goff = 2
    poff = 2 + m * N_TERMS
    ok = True
    for i in range(m):
        for j in range(N_TERMS):
            if q[i][j] >= 0:
                ok &= abs(params[0, poff + i * N_TERMS + j] * m - q[i][j]) <= 1e-12
            else:
                ok &= params[0, goff + i * N_TERMS + j] == 0.0
    return ok


@njit(cache=CACHE, error_model="numpy", inline="always")
def _hosm2(state, y, params, new_state, out, shared, q):
    r"""The step of :func:`hosm_channel_step` for ``m = 2`` and the exponent table ``q`` known at compile time.

    .. math::
        \hat x_0^+ = \hat x_0 + \tau\hat x_1 - \tau\,\mathrm{sign}(e)\sum_j g_{0j} r^{q_{0j}},\quad
        \hat x_1^+ = \hat x_1 - \tau\,\mathrm{sign}(e)\sum_j g_{1j} r^{q_{1j}},\quad r = |e|^{1/2},

    same operations in the same order as the generic step (the Taylor and Euler schemes coincide for ``m = 2``).
    """
    _check_widths(state, new_state, params, out, 3, 2 + 4 * N_TERMS, 2)
    bad = False
    for c in range(y.shape[0]):
        pc = 0 if shared else c  # the parameter row of channel c
        prow = params[pc]
        dt = prow[0]
        x0 = state[c, 0]
        x1 = state[c, 1]
        e = x0 - y[c]
        s = 1.0 if e > 0.0 else (-1.0 if e < 0.0 else 0.0)
        r = math.sqrt(abs(e))
        n0 = x0 + dt * x1 - dt * (_injection(prow, 0, r, q[0]) * s)
        n1 = x1 - dt * (_injection(prow, 1, r, q[1]) * s)
        new_state[c, 0] = n0
        new_state[c, 1] = n1
        new_state[c, 2] = -e
        o0 = n0 + (-dt) * n1  # exp(-tau N) x^+
        out[c, 0] = o0
        out[c, 1] = n1
        bad |= not (
            math.isfinite(n0) & math.isfinite(n1) & math.isfinite(e) & math.isfinite(state[c, 2]) & math.isfinite(o0)
        )
    return _check_state(new_state, out) if bad else -1


@njit(cache=CACHE, error_model="numpy", inline="always")
def _hosm3(state, y, params, new_state, out, shared, taylor, q):
    r"""The step of :func:`hosm_channel_step` for ``m = 3``, the scheme and the exponents known at compile time.

    ``r = cbrt(|e|)``; ``"taylor"`` adds :math:`\tfrac{\tau^2}{2}\hat x_2` to :math:`\hat x_0^+`. Same
    operations in the same order as the generic step. Two passes over the channels: the error and its root
    (kept in ``new_state``), then the injections :math:`\mathrm{sign}(e)\sum_j g_{ij} r^{q_{ij}}`, the Taylor
    update and the estimate. A single loop has more strided accesses than LLVM's vectorizer accepts with the six
    gains of the uniform differentiator (it then leaves the loop scalar, about three times slower). Splitting
    after the root rather than after the injections leaves the root pass with few memory accesses: for Levant
    k = 2 measured 0.38 instead of 0.43-0.47 us at 8 channels, 0.53 instead of 0.56 at 32 and 2.06 instead of
    2.25 at 256. The uniform differentiator's table runs :func:`_hosm3_injections_first` at 32 channels and more.
    """
    _check_widths(state, new_state, params, out, 4, 2 + 6 * N_TERMS, 3)
    for c in range(y.shape[0]):
        e = state[c, 0] - y[c]
        new_state[c, 3] = -e
        new_state[c, 0] = cbrt(abs(e))
    bad = False
    for c in range(y.shape[0]):
        pc = 0 if shared else c  # the parameter row of channel c
        prow = params[pc]
        dt = prow[0]
        x0 = state[c, 0]
        x1 = state[c, 1]
        x2 = state[c, 2]
        e = -new_state[c, 3]
        r = new_state[c, 0]
        s = 1.0 if e > 0.0 else (-1.0 if e < 0.0 else 0.0)
        a0 = x0 + dt * x1
        if taylor:
            a0 += (dt * (dt / 2.0)) * x2
        n0 = a0 - dt * (_injection(prow, 0, r, q[0]) * s)
        n1 = x1 + dt * x2 - dt * (_injection(prow, 1, r, q[1]) * s)
        n2 = x2 - dt * (_injection(prow, 2, r, q[2]) * s)
        bad |= _store_order2(state, new_state, out, c, dt, n0, n1, n2, e)
    return _check_state(new_state, out) if bad else -1


@njit(cache=CACHE, error_model="numpy", inline="always")
def _hosm3_injections_first(state, y, params, new_state, out, shared, taylor, q):
    r""":func:`_hosm3` split after the injections, for the exponent table of the uniform differentiator.

    Same operations in the same order as the generic step. Two passes over the channels: the injections
    :math:`\mathrm{sign}(e)\sum_j g_{ij} r^{q_{ij}}` (kept in ``new_state``), then the Taylor update and the
    estimate; with up to six gains per channel a single loop has more strided accesses than LLVM's vectorizer
    accepts (it then leaves the loop scalar, about three times slower). With six gains this split is faster than
    :func:`_hosm3`'s at 32 and 256 channels (measured 0.60 against 0.63 us, 2.65 against 2.83 us) and slower at
    8 (0.48 against 0.41 us); the issue's targets are per call up to 32 channels, where neither meets 0.5 us.
    """
    _check_widths(state, new_state, params, out, 4, 2 + 6 * N_TERMS, 3)
    for c in range(y.shape[0]):
        pc = 0 if shared else c  # the parameter row of channel c
        prow = params[pc]
        e = state[c, 0] - y[c]
        s = 1.0 if e > 0.0 else (-1.0 if e < 0.0 else 0.0)
        r = cbrt(abs(e))
        new_state[c, 0] = _injection(prow, 0, r, q[0]) * s
        new_state[c, 1] = _injection(prow, 1, r, q[1]) * s
        new_state[c, 2] = _injection(prow, 2, r, q[2]) * s
        new_state[c, 3] = -e
    bad = False
    for c in range(y.shape[0]):
        pc = 0 if shared else c  # the parameter row of channel c
        dt = params[pc, 0]
        x0 = state[c, 0]
        x1 = state[c, 1]
        x2 = state[c, 2]
        a0 = x0 + dt * x1
        if taylor:
            a0 += (dt * (dt / 2.0)) * x2
        n0 = a0 - dt * new_state[c, 0]
        n1 = x1 + dt * x2 - dt * new_state[c, 1]
        n2 = x2 - dt * new_state[c, 2]
        bad |= _store_order2(state, new_state, out, c, dt, n0, n1, n2, new_state[c, 3])
    return _check_state(new_state, out) if bad else -1


def _hosm_kernel(shared: bool):
    """The HOSM batch kernel for per-channel parameter rows, or for one row shared by every channel.

    ``shared`` is a closure constant, so each variant compiles (and is cached) as its own function. The body is
    written here rather than in one more inlined function: behind that layer the kernel took twice as long to
    compile (numba merges its many returns). Each family has its own factory, with its loops named as globals:
    one generic factory taking the loop function as a closure variable compiled afresh in every process (numba
    does not cache a closure over a dispatcher).
    """

    @njit(**KERNEL)
    def kernel(state, y, params, new_state, out):
        y, out = _flat(y, out)
        bad = _first_nonfinite(y)
        if bad >= 0:
            return bad
        _check_rows(params, y.shape[0], shared)
        m = out.shape[1]
        if y.shape[0] > 0:
            # a specialised step for the exponent tables of the observers of this package (see module notes)
            if m == 2:
                if _matches(params, 2, LEVANT_Q2):
                    return _hosm2(state, y, params, new_state, out, shared, LEVANT_Q2)
                if _matches(params, 2, URED_Q):
                    return _hosm2(state, y, params, new_state, out, shared, URED_Q)
            elif m == 3:
                taylor = params[0, 1] != 0.0
                if _matches(params, 3, LEVANT_Q3):
                    if taylor:
                        return _hosm3(state, y, params, new_state, out, shared, True, LEVANT_Q3)
                    return _hosm3(state, y, params, new_state, out, shared, False, LEVANT_Q3)
                if _matches(params, 3, UNIFORM_Q3):
                    # same operations either way; which split is faster depends on the number of channels (measured)
                    if y.shape[0] >= 32:
                        if taylor:
                            return _hosm3_injections_first(state, y, params, new_state, out, shared, True, UNIFORM_Q3)
                        return _hosm3_injections_first(state, y, params, new_state, out, shared, False, UNIFORM_Q3)
                    if taylor:
                        return _hosm3(state, y, params, new_state, out, shared, True, UNIFORM_Q3)
                    return _hosm3(state, y, params, new_state, out, shared, False, UNIFORM_Q3)
        failed = False
        for c in range(y.shape[0]):
            pc = 0 if shared else c  # the parameter row of channel c
            row = new_state[c]
            row[m] = hosm_channel_step(state[c], y[c], params[pc], m, row, out[c])
            failed |= not (_row_finite(row) and _row_finite(out[c]))
        return _check_state(new_state, out) if failed else -1

    return kernel


hosm_kernel = _hosm_kernel(False)
hosm_shared_kernel = _hosm_kernel(True)


# ----------------------------------------------------------------------------------------------------------------
# Super-twisting, set-valued implicit Euler (closed form)
# params row: [dt, k1, k2]
# ----------------------------------------------------------------------------------------------------------------
@njit(cache=CACHE, error_model="numpy", inline="always")
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


def _sta_implicit_kernel(shared: bool):
    """The implicit super-twisting batch kernel for per-channel parameter rows, or for one row shared by every channel
    (``shared``, a closure constant: see :func:`_hosm_kernel`)."""

    @njit(**KERNEL)
    def kernel(state, y, params, new_state, out):
        y, out = _flat(y, out)
        bad = _first_nonfinite(y)
        if bad >= 0:
            return bad
        _check_rows(params, y.shape[0], shared)
        return _sta_implicit_rows(state, y, params, new_state, out, shared)

    return kernel


sta_implicit_kernel = _sta_implicit_kernel(False)
sta_implicit_shared_kernel = _sta_implicit_kernel(True)


@njit(cache=CACHE, error_model="numpy", inline="always")
def _sta_implicit_rows(state, y, params, new_state, out, shared):
    """:func:`sta_implicit_kernel` after the measurement check (``shared``: one parameter row for every channel)."""
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
# Discrete-time eigenvalue-mapping observer of paper 003 (differentiator part)
# params row: [dt, p1, mu, mode, V ((m + 1) * m)], mode 0 = semi-implicit (15), 1 = matching (16)
# ----------------------------------------------------------------------------------------------------------------
@njit(cache=CACHE, error_model="numpy", inline="always")
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


@njit(cache=CACHE, error_model="numpy", inline="always")
def _eigenvalue_from_root(a, root, dt, p1, mu, mode):
    """(15) or (16) given ``a = |sigma|`` and its root (see :func:`eigenvalue_map`)."""
    semi = root / (dt * p1 * mu * a + root + dt * p1)
    matching = exp_nonpositive(-dt * p1 * (1.0 + mu * a) / root)  # -inf at a = 0 gives 0
    z = semi if mode == 0 else matching
    return z if a != 0.0 else 0.0


@njit(cache=CACHE, error_model="numpy", inline="always")
def eigenvalue_map(sigma, dt, p1, mu, n, mode):
    r"""State-dependent discrete eigenvalue :math:`z_n(\sigma)`: (15) semi-implicit or (16) matching of paper 003.

    Both mappings are evaluated and one is selected (also ``z = 0`` at ``sigma = 0``, where both are 0 anyway):
    branches would keep LLVM from vectorizing a loop over channels that calls this.
    """
    a = abs(sigma)
    return _eigenvalue_from_root(a, _eigenvalue_root(a, n), dt, p1, mu, mode)


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
def _eigmap3(state, y, params, new_state, out, shared, mode):
    r""":func:`eigmap_channel_step` for ``m = 3`` and the mapping ``mode`` of every row (same operations in the
    same order), in two passes for (15) and three for (16); ``-3`` if a row has another mode.

    The first pass computes :math:`\sigma`, the root :math:`|\sigma|^{1/3}` (:func:`cbrt`) and for (15) the map
    :math:`z(\sigma)`; for (16) a second pass computes the map (a division and :func:`exp_nonpositive`), all
    vectorized, with ``sigma`` and the root or ``z`` waiting in ``new_state``. The last pass computes
    :math:`\hat x^+ = A\hat x + \tilde l(z)\sigma` and the estimate. Merged into one loop, the root, the map and
    the twelve strided gain loads are more than LLVM's vectorizer accepts (measured 1.2 us instead of 0.7 at 32
    channels). Root and map in one pass form one long chain of dependent divisions per channel (three in the root,
    two in the matching map), and at 32 channels (eight vector iterations) the processor overlaps too little of
    it: apart they were measured 0.035-0.05 us faster for (16) at 32 channels, but 0.03 us slower for (15), whose
    map has one division; five passes (one per state component, then the estimate) cost 2-10 % more.
    """
    _check_widths(state, new_state, params, out, 4, 16, 3)
    n = y.shape[0]
    other_mode = False
    for c in range(n):
        pc = 0 if shared else c  # the parameter row of channel c
        # eigenvalue_map(sigma, ...); the mapping is a compile-time choice (the other one is not computed); rows of
        # another mode are redone by the generic step
        sigma = y[c] - state[c, 0]
        a = abs(sigma)
        new_state[c, 3] = sigma
        root = _eigenvalue_root(a, 3)
        if mode == 1.0:
            new_state[c, 0] = root  # the matching map in a pass of its own (see above)
        else:
            new_state[c, 0] = _eigenvalue_from_root(a, root, params[pc, 0], params[pc, 1], params[pc, 2], mode)
        other_mode |= params[pc, 3] != mode
    if other_mode:
        return -3  # not a status: the caller runs the generic step
    if mode == 1.0:
        for c in range(n):
            pc = 0 if shared else c  # the parameter row of channel c
            new_state[c, 0] = _eigenvalue_from_root(
                abs(new_state[c, 3]), new_state[c, 0], params[pc, 0], params[pc, 1], params[pc, 2], mode
            )
    failed = False
    for c in range(n):
        pc = 0 if shared else c  # the parameter row of channel c
        dt = params[pc, 0]
        x0 = state[c, 0]
        x1 = state[c, 1]
        x2 = state[c, 2]
        mz = -new_state[c, 0]
        sigma = new_state[c, 3]
        # l_i(z) = sum_j (-z)^(3-j) v_j[i] by Horner's rule (the generic step's first step 0 * (-z) + v_0 is exact)
        g0 = ((params[pc, 4] * mz + params[pc, 7]) * mz + params[pc, 10]) * mz + params[pc, 13]
        g1 = ((params[pc, 5] * mz + params[pc, 8]) * mz + params[pc, 11]) * mz + params[pc, 14]
        g2 = ((params[pc, 6] * mz + params[pc, 9]) * mz + params[pc, 12]) * mz + params[pc, 15]
        # x^+ = A x + l(z) sigma, A = exp(tau N) (the generic step's Taylor sums: its factors 1 * (dt / 1) = dt)
        n0 = x0 + dt * x1 + (dt * (dt / 2.0)) * x2 + g0 * sigma
        n1 = x1 + dt * x2 + g1 * sigma
        n2 = x2 + g2 * sigma
        failed |= _store_order2(state, new_state, out, c, dt, n0, n1, n2, sigma)
    return _check_state(new_state, out) if failed else -1


def _eigmap_kernel(shared: bool):
    """The eigenvalue-mapping batch kernel for per-channel parameter rows, or for one row shared by every channel
    (``shared``, a closure constant: see :func:`_hosm_kernel`)."""

    @njit(**KERNEL)
    def kernel(state, y, params, new_state, out):
        y, out = _flat(y, out)
        bad = _first_nonfinite(y)
        if bad >= 0:
            return bad
        _check_rows(params, y.shape[0], shared)
        m = out.shape[1]
        if m == 3 and y.shape[0] > 0:
            status = -3
            if params[0, 3] == 0.0:
                status = _eigmap3(state, y, params, new_state, out, shared, 0.0)
            elif params[0, 3] == 1.0:
                status = _eigmap3(state, y, params, new_state, out, shared, 1.0)
            if status != -3:
                return status
        failed = False
        for c in range(y.shape[0]):
            pc = 0 if shared else c  # the parameter row of channel c
            row = new_state[c]
            row[m] = eigmap_channel_step(state[c], y[c], params[pc], m, row, out[c])
            failed |= not (_row_finite(row) and _row_finite(out[c]))
        return _check_state(new_state, out) if failed else -1

    return kernel


eigmap_kernel = _eigmap_kernel(False)
eigmap_shared_kernel = _eigmap_kernel(True)


# ----------------------------------------------------------------------------------------------------------------
# Linear time-invariant observers (high-gain): s_new = F s + g y, out = R s_new
# params row: [F (m * m), g (m), R (m * m)]
# ----------------------------------------------------------------------------------------------------------------
@njit(cache=CACHE, error_model="numpy", inline="always")
def _linear_rows(state, y, params, new_state, out, shared, m):
    """The loops of :func:`linear_kernel` for ``m`` estimates (a compile-time constant when inlined).

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


def _linear_kernel(shared: bool):
    """The linear batch kernel for per-channel parameter rows, or for one row shared by every channel
    (``shared``, a closure constant: see :func:`_hosm_kernel`)."""

    @njit(**KERNEL)
    def kernel(state, y, params, new_state, out):
        y, out = _flat(y, out)
        bad = _first_nonfinite(y)
        if bad >= 0:
            return bad
        _check_rows(params, y.shape[0], shared)
        return _linear_steps(state, y, params, new_state, out, shared)

    return kernel


linear_kernel = _linear_kernel(False)
linear_shared_kernel = _linear_kernel(True)


@njit(cache=CACHE, error_model="numpy", inline="always")
def _linear_steps(state, y, params, new_state, out, shared):
    """:func:`linear_kernel` after the measurement check (``shared``: one parameter row for every channel)."""
    m = out.shape[1]
    # fixed widths for the common orders (constant strides and unrolled loops, see module notes)
    if m == 2:
        _check_widths(state, new_state, params, out, 3, 10, 2)
        return _linear_rows(state, y, params, new_state, out, shared, 2)
    if m == 3:
        _check_widths(state, new_state, params, out, 4, 21, 3)
        return _linear_rows(state, y, params, new_state, out, shared, 3)
    return _linear_rows(state, y, params, new_state, out, shared, m)


# ----------------------------------------------------------------------------------------------------------------
# Constant-acceleration Kalman filter (3 states, scalar measurement)
# state row: [x0, x1, x2, P00, P01, P02, P11, P12, P22, innovation]; params row: [dt, q, r]
# ----------------------------------------------------------------------------------------------------------------
@njit(cache=CACHE, error_model="numpy", inline="always")
def kalman_ca_prior_covariance(p00, p01, p02, p11, p12, p22, dt, q):
    r"""Prior covariance :math:`P^- = F P F^T + Q` (upper triangle ``(m00, m01, m02, m11, m12, m22)``)."""
    h = 0.5 * dt * dt
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
    return m00, m01, m02, m11, m12, m22


@njit(cache=CACHE, error_model="numpy", inline="always")
def kalman_ca_posterior_covariance(m00, m01, m02, m11, m12, m22, r):
    r"""Gain :math:`K = P^- c / (c^T P^- c + r)` and :math:`P^+ = (I - K c^T) P^-`, ``c = (1, 0, 0)``.

    Returns ``(P00, P01, P02, P11, P12, P22, k0, k1, k2)``.
    """
    S_inv = 1.0 / (m00 + r)
    k0 = m00 * S_inv
    k1 = m01 * S_inv
    k2 = m02 * S_inv
    return (m00 - k0 * m00, m01 - k0 * m01, m02 - k0 * m02, m11 - k1 * m01, m12 - k1 * m02, m22 - k2 * m02, k0, k1, k2)


@njit(cache=CACHE, error_model="numpy", inline="always")
def kalman_ca_covariance(p00, p01, p02, p11, p12, p22, dt, q, r):
    r"""Covariance half of :func:`kalman_ca_channel_step`: posterior :math:`P^+` (upper triangle) and gain ``K``.

    .. math::
        P^- = F P F^T + Q,\quad K = P^- c / (c^T P^- c + r),\quad P^+ = (I - K c^T) P^-,\quad c = (1, 0, 0).

    Returns ``(P00, P01, P02, P11, P12, P22, k0, k1, k2)``. It does not depend on the measurement.
    """
    m00, m01, m02, m11, m12, m22 = kalman_ca_prior_covariance(p00, p01, p02, p11, p12, p22, dt, q)
    return kalman_ca_posterior_covariance(m00, m01, m02, m11, m12, m22, r)


@njit(cache=CACHE, error_model="numpy", inline="always")
def kalman_ca_mean(x0, x1, x2, y, dt, k0, k1, k2):
    r"""Mean half of :func:`kalman_ca_channel_step`: :math:`x^- = F x`, :math:`x^+ = x^- + K(y - c^T x^-)`.

    Returns ``(x0, x1, x2, nu)`` with the innovation :math:`\nu = y - c^T x^-`.
    """
    h = 0.5 * dt * dt
    # x^- = F x                                                   (prior mean)
    m0 = x0 + dt * x1 + h * x2
    m1 = x1 + dt * x2
    m2 = x2
    nu = y - m0
    # x^+ = x^- + K nu                                             (posterior mean)
    return m0 + k0 * nu, m1 + k1 * nu, m2 + k2 * nu, nu


@njit(cache=CACHE, error_model="numpy", inline="always")
def kalman_ca_channel_step(s, y, params, s_new):
    r"""Predict with :math:`F = e^{\tau N}` and the white-jerk process noise, then update with ``y``.

    .. math::
        Q = q\begin{bmatrix} \tau^5/20 & \tau^4/8 & \tau^3/6\\ \tau^4/8 & \tau^3/3 & \tau^2/2\\
            \tau^3/6 & \tau^2/2 & \tau\end{bmatrix},\qquad
        K = P^- c / (c^T P^- c + r),\quad c = (1, 0, 0).

    State row ``s``: ``[x0, x1, x2, P00, P01, P02, P11, P12, P22, ...]``; params ``[dt, q, r]``. Returns the
    innovation.
    """
    P = kalman_ca_covariance(s[3], s[4], s[5], s[6], s[7], s[8], params[0], params[1], params[2])
    x0, x1, x2, nu = kalman_ca_mean(s[0], s[1], s[2], y, params[0], P[6], P[7], P[8])
    s_new[0] = x0
    s_new[1] = x1
    s_new[2] = x2
    for i in range(6):
        s_new[3 + i] = P[i]
    return nu


def _kalman_ca_kernel(shared: bool):
    """The Kalman batch kernel for per-channel parameter rows, or for one row shared by every channel
    (``shared``, a closure constant: see :func:`_hosm_kernel`)."""

    @njit(**KERNEL)
    def kernel(state, y, params, new_state, out):
        y, out = _flat(y, out)
        bad = _first_nonfinite(y)
        if bad >= 0:
            return bad
        _check_rows(params, y.shape[0], shared)
        return _kalman_ca_rows(state, y, params, new_state, out, shared)

    return kernel


kalman_ca_kernel = _kalman_ca_kernel(False)
kalman_ca_shared_kernel = _kalman_ca_kernel(True)


@njit(cache=CACHE, error_model="numpy", inline="always")
def _kalman_ca_rows(state, y, params, new_state, out, shared):
    """:func:`kalman_ca_kernel` after the measurement check (``shared``: one parameter row for every channel)."""
    _check_widths(state, new_state, params, out, 10, 3, 3)
    # three passes (prior covariance, posterior covariance and gain, mean) so that each loop has few enough
    # strided accesses for LLVM's vectorizer; the prior waits in ``new_state``, the gain in ``out``
    for c in range(y.shape[0]):
        pc = 0 if shared else c  # the parameter row of channel c
        M = kalman_ca_prior_covariance(
            state[c, 3], state[c, 4], state[c, 5], state[c, 6], state[c, 7], state[c, 8], params[pc, 0], params[pc, 1]
        )
        for i in range(6):
            new_state[c, 3 + i] = M[i]
    failed = False
    for c in range(y.shape[0]):
        pc = 0 if shared else c  # the parameter row of channel c
        P = kalman_ca_posterior_covariance(
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
    for c in range(y.shape[0]):
        pc = 0 if shared else c  # the parameter row of channel c
        x0, x1, x2, nu = kalman_ca_mean(
            state[c, 0], state[c, 1], state[c, 2], y[c], params[pc, 0], out[c, 0], out[c, 1], out[c, 2]
        )
        new_state[c, 0] = x0
        new_state[c, 1] = x1
        new_state[c, 2] = x2
        new_state[c, 9] = nu
        out[c, 0] = x0
        out[c, 1] = x1
        out[c, 2] = x2
        failed |= not (math.isfinite(x0) & math.isfinite(x1) & math.isfinite(x2) & math.isfinite(nu))
    return _check_state(new_state, out) if failed else -1


# ----------------------------------------------------------------------------------------------------------------
# Backward finite differences (order 1 or 2)
# state row: [y, v, (a), innovation, samples since reset]; params row: [dt]
# ----------------------------------------------------------------------------------------------------------------
@njit(cache=CACHE, error_model="numpy", inline="always")
def _finite_difference_rows(state, y, params, new_state, out, shared, m):
    """The loop of :func:`finite_difference_kernel` for ``m`` = 2 or 3 estimates (compile-time when inlined)."""
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


def _finite_difference_kernel(shared: bool):
    """The finite-difference batch kernel for per-channel parameter rows, or for one row shared by every channel
    (``shared``, a closure constant: see :func:`_hosm_kernel`)."""

    @njit(**KERNEL)
    def kernel(state, y, params, new_state, out):
        y, out = _flat(y, out)
        bad = _first_nonfinite(y)
        if bad >= 0:
            return bad
        _check_rows(params, y.shape[0], shared)
        return _finite_difference_steps(state, y, params, new_state, out, shared)

    return kernel


finite_difference_kernel = _finite_difference_kernel(False)
finite_difference_shared_kernel = _finite_difference_kernel(True)


@njit(cache=CACHE, error_model="numpy", inline="always")
def _finite_difference_steps(state, y, params, new_state, out, shared):
    """:func:`finite_difference_kernel` after the measurement check (``shared``: one row for every channel)."""
    if out.shape[1] == 2:
        return _finite_difference_rows(state, y, params, new_state, out, shared, 2)
    return _finite_difference_rows(state, y, params, new_state, out, shared, 3)


# ----------------------------------------------------------------------------------------------------------------
# offline driver
# ----------------------------------------------------------------------------------------------------------------
@njit(error_model="numpy", inline="always")
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
    """The time loop of :func:`run_offline`, inlined into each kernel's compiled driver.

    Ping-pong between ``state`` and one scratch buffer (no copy per sample), unrolled by two samples: the first
    call of a pair reads ``state`` and writes the scratch buffer, the second the reverse. Swapping two array
    variables instead (one call site) leaves LLVM with loop-carried array descriptors and halves the throughput of
    the vectorized kernel loop (measured for the implicit super-twisting kernel: 85 against 160 M channel-samples/s
    at 32768 channels); the price is a second inlined copy of the kernel, so a large kernel (the HOSM family) uses
    :func:`_drive_compact`. ``state`` receives the last accepted state at the end, also when a sample fails.
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
def _drive_compact(kernel, state, Y, params, out):
    """:func:`_drive` with one call site of the kernel (the two arrays swapped after each sample): half the
    compiled code, for kernels whose inlined body is large, at the cost of the throughput noted there."""
    cur = state
    nxt = np.empty_like(state)
    T = Y.shape[0]
    for t in range(T):
        status = kernel(cur, Y[t], params, nxt, out[t])
        if status != -1:
            if t % 2 == 1:
                _copy_rows(cur, state)
            return status, t
        cur, nxt = nxt, cur
    if T % 2 == 1:
        _copy_rows(cur, state)
    return -1, T


@njit(error_model="numpy", inline="always")
def _drive_wrapped(kernel, state, Y, params, out, period):
    """:func:`_drive_compact` with :func:`unwrap_measurement` before every sample (channels with ``period > 0``
    wrap).

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


# One cached driver per kernel. A compiled function that takes a kernel as an argument is specialised on the
# dispatcher's type, which numba's on-disk cache cannot reuse across processes (it recompiled for seconds in every
# new process and could fail while re-saving its index); drivers that name their kernel cache normally.
#: :data:`hosm_kernel` compiled as a function of its own, called rather than inlined by its offline driver: numba
#: inlines a function by copying its IR at every call site, recursively, and the HOSM kernel holds eight
#: specialised steps, so the inlined driver took about 75 s of CPU to compile (measured cold, on top of the
#: kernel's own 34 s), against nothing more than the kernel here. Same function, same cache entries as
#: :data:`hosm_kernel` (numba keys them on the code and its closure, not on the inline option).
_hosm_kernel_called = njit(**{**KERNEL, "inline": "never"})(hosm_kernel.py_func)


@njit(cache=CACHE, error_model="numpy")
def _run_hosm(state, Y, params, out):
    return _drive_compact(_hosm_kernel_called, state, Y, params, out)


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


# the same with wrapped channels: separate functions, so that observers without angles run the drivers above
# unchanged, and each of these compiles only when an observer with wrapped channels first runs offline
@njit(cache=CACHE, error_model="numpy")
def _run_hosm_wrapped(state, Y, params, out, period):
    return _drive_wrapped(_hosm_kernel_called, state, Y, params, out, period)


@njit(cache=CACHE, error_model="numpy")
def _run_sta_implicit_wrapped(state, Y, params, out, period):
    return _drive_wrapped(sta_implicit_kernel, state, Y, params, out, period)


@njit(cache=CACHE, error_model="numpy")
def _run_eigmap_wrapped(state, Y, params, out, period):
    return _drive_wrapped(eigmap_kernel, state, Y, params, out, period)


@njit(cache=CACHE, error_model="numpy")
def _run_linear_wrapped(state, Y, params, out, period):
    return _drive_wrapped(linear_kernel, state, Y, params, out, period)


@njit(cache=CACHE, error_model="numpy")
def _run_kalman_ca_wrapped(state, Y, params, out, period):
    return _drive_wrapped(kalman_ca_kernel, state, Y, params, out, period)


@njit(cache=CACHE, error_model="numpy")
def _run_finite_difference_wrapped(state, Y, params, out, period):
    return _drive_wrapped(finite_difference_kernel, state, Y, params, out, period)


@njit(error_model="numpy")  # not cached: specialised per kernel type (see above)
def _run_any_wrapped(kernel, state, Y, params, out, period):
    return _drive_wrapped(kernel, state, Y, params, out, period)


_DRIVERS = {
    hosm_kernel: _run_hosm,
    sta_implicit_kernel: _run_sta_implicit,
    eigmap_kernel: _run_eigmap,
    linear_kernel: _run_linear,
    kalman_ca_kernel: _run_kalman_ca,
    finite_difference_kernel: _run_finite_difference,
}


_WRAPPED_DRIVERS = {
    hosm_kernel: _run_hosm_wrapped,
    sta_implicit_kernel: _run_sta_implicit_wrapped,
    eigmap_kernel: _run_eigmap_wrapped,
    linear_kernel: _run_linear_wrapped,
    kalman_ca_kernel: _run_kalman_ca_wrapped,
    finite_difference_kernel: _run_finite_difference_wrapped,
}


#: the variant of each batch kernel for one parameter row ``(1, P)`` shared by every channel (module notes)
SHARED_KERNELS = {
    hosm_kernel: hosm_shared_kernel,
    sta_implicit_kernel: sta_implicit_shared_kernel,
    eigmap_kernel: eigmap_shared_kernel,
    linear_kernel: linear_shared_kernel,
    kalman_ca_kernel: kalman_ca_shared_kernel,
    finite_difference_kernel: finite_difference_shared_kernel,
}


def register_driver(kernel, driver) -> None:
    """Register the cached compiled driver of a kernel defined in another module.

    ``driver(state, Y, params, out) -> (status, t)`` must be ``return _drive(kernel, state, Y, params, out)``
    compiled with ``@njit(cache=True)`` at module level, so that :meth:`Observer.run` (through
    :func:`run_offline`) reuses numba's on-disk cache for it.
    """
    _DRIVERS[kernel] = driver


def run_offline(kernel, state, Y, params, out, period=None):
    """Apply ``kernel`` to every row of ``Y`` (T, N); write estimates into ``out`` (T, N, m).

    Returns ``(status, t)``: ``status`` as the kernel's, ``t`` the sample at which it failed (or ``T``).
    ``state`` holds the last accepted state on return (the final state on success). Kernels of this module run
    through their own cached compiled driver; any other kernel through a generic compiled loop (compiled once per
    process and kernel). ``period`` (N,), optional: wrap the channels with ``period > 0``
    (:func:`unwrap_measurement` before every sample).
    """
    if period is not None:
        driver = _WRAPPED_DRIVERS.get(kernel)
        if driver is not None:
            return driver(state, Y, params, out, period)
        return _run_any_wrapped(kernel, state, Y, params, out, period)
    driver = _DRIVERS.get(kernel)
    if driver is not None:
        return driver(state, Y, params, out)
    return _run_any(kernel, state, Y, params, out)
