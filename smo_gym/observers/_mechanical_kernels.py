r"""Compiled per-sample recursion of the model-based (mechanical) super-twisting observers.

Same calling convention as :mod:`smo_gym.observers._kernels`: ``status = kernel(state, y, params, new_state, out)``.
The model term is *not* evaluated here (it needs the dynamics object): the observer class computes it before the
call and writes it into the column ``MODEL`` (and ``MODEL_POS``) of ``new_state``, the row the step then writes.
An input in the output row keeps ``state`` read-only: a step rejected for a non-finite measurement or a diverging
state leaves the observer's state exactly as it was.

State row (per channel): ``[x1, x2, innovation, model, injection, injection_filtered, e, model_pos]`` (columns
named below)
Params row: ``[dt, c, g11, g12, g20, g21, g22, implicit, filter_coefficient, pos_from_state, model_bound]``
(``model_bound``: the model term is clipped to ``[-model_bound, model_bound]``, Wetzlinger et al. eq. (33); ``inf`` for
none; not applied to a prediction integrated outside, which saturates its own substeps)

The recursion, for a sample interval ``h`` with the model term ``m`` (explicit, evaluated at the previous sample)::

    prediction      p1 = x1 + h x2 + c h^2 m,   p2 = x2 + h m,   w = X - p1
                    (with pos_from_state: p1 = x1 + h x2 + h^2 model_pos, a prediction integrated outside)
    x1 injection    g11 |e|^(1/2) sign(e) + g12 e
    x2 injection    g20 s + g21 |e|^(1/2) sign(e) + g22 e,   s in Sign(e)
    update          x1+ = p1 + h (x1 injection),  x2+ = p2 + h (x2 injection),  e = X - x1+   ("implicit")
                    e = w (explicit, "euler")

``implicit`` solves ``w = e + h (x1 injection) + h^2 (x2 injection)`` for ``e`` and ``s`` in closed form: with
``e = s r^2`` it is the quadratic ``a r^2 + b r - (|w| - thr) = 0``, ``a = 1 + h g12 + h^2 g22``,
``b = h g11 + h^2 g21``, ``thr = h^2 g20``, which :func:`_kernels.sta_implicit_channel_step` solves after dividing
by ``a`` (it is the ``a = 1`` case).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .. import _numba_cache
from . import _kernels
from ._kernels import CACHE, _check_state, _first_nonfinite, sta_implicit_channel_step

__all__ = [
    "ERROR",
    "FILTERED",
    "INJECTION",
    "MODEL",
    "MODEL_POS",
    "STATE_WIDTH",
    "mechanical_channel_step",
    "mechanical_kernel",
]

#: the columns of a channel's state row
STATE_WIDTH = 8
X1 = 0
X2 = 1
INNOVATION = 2
MODEL = 3
INJECTION = 4
FILTERED = 5
ERROR = 6
MODEL_POS = 7


@njit(cache=CACHE)
def mechanical_channel_step(x, X, params, x_new):
    r"""One step of the model-based super-twisting recursion for one channel (see the module docstring).

    ``x`` is the state row, ``X`` the new (transformed) measurement, ``x_new[MODEL]`` (and ``x_new[MODEL_POS]``)
    the model term on entry. Writes ``x_new`` and returns the predicted error ``w``.
    """
    h = params[0]
    c = params[1]
    g11 = params[2]
    g12 = params[3]
    g20 = params[4]
    g21 = params[5]
    g22 = params[6]
    implicit = params[7] != 0.0
    beta = params[8]
    m = x_new[MODEL]
    bound = params[10]
    if m > bound:
        m = bound
    elif m < -bound:
        m = -bound
    if params[9] != 0.0:
        p1 = x[X1] + h * x[X2] + h * h * x_new[MODEL_POS]
    else:
        p1 = x[X1] + h * x[X2] + c * h * h * m
        x_new[MODEL_POS] = 0.0  # no prediction integrated outside (the scratch row may hold anything)
    p2 = x[X2] + h * m
    w = X - p1
    if implicit:
        a = 1.0 + h * g12 + h * h * g22
        b = h * g11 + h * h * g21
        thr = h * h * g20
        if thr > 0.0:
            # closed-form implicit step of the plain STA (a = 1) on the problem divided by a
            tmp_in = np.empty(2)
            tmp_out = np.empty(2)
            tmp_in[0] = p1 / a
            tmp_in[1] = 0.0
            prm = np.empty(3)
            prm[0] = h
            prm[1] = b / (a * h)
            prm[2] = thr / (a * h * h)
            sta_implicit_channel_step(tmp_in, X / a, prm, tmp_out)
            e = X / a - tmp_out[0]
            s = tmp_out[1] / (h * prm[2])
        else:  # no discontinuous term: linear-plus-root injection, solve a r^2 + b r - |w| = 0
            r = 2.0 * abs(w) / (b + math.sqrt(b * b + 4.0 * a * abs(w))) if w != 0.0 else 0.0
            e = math.copysign(r * r, w)
            s = 0.0
    else:
        e = w
        s = 1.0 if e > 0.0 else (-1.0 if e < 0.0 else 0.0)
    root = math.copysign(math.sqrt(abs(e)), e)
    inj2 = g20 * s + g21 * root + g22 * e
    if implicit:
        x_new[X1] = X - e
    else:
        x_new[X1] = p1 + h * (g11 * root + g12 * e)
    x_new[X2] = p2 + h * inj2
    x_new[INNOVATION] = w
    x_new[MODEL] = m
    x_new[INJECTION] = inj2
    x_new[FILTERED] = x[FILTERED] + beta * (inj2 - x[FILTERED])
    x_new[ERROR] = e if implicit else X - x_new[X1]
    return w


@njit(cache=CACHE)
def mechanical_kernel(state, y, params, new_state, out):
    yf = y.reshape(y.size)
    o = out.reshape((yf.shape[0], out.shape[-1]))
    bad = _first_nonfinite(yf)
    if bad >= 0:
        return bad
    for ch in range(yf.shape[0]):
        mechanical_channel_step(state[ch], yf[ch], params[ch], new_state[ch])
        o[ch, 0] = new_state[ch, X1]
        o[ch, 1] = new_state[ch, X2]
    return _check_state(new_state, o)


# these inline helpers of _kernels.py: drop their cached code when it changes (see smo_gym._numba_cache)
_numba_cache.drop_stale((mechanical_channel_step, mechanical_kernel), [_kernels.__file__])
