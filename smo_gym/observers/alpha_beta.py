r"""The alpha-beta tracker with the gains of Kalata's tracking index (Kalata 1984).

The steady-state Kalman filter of the constant-velocity model with a white (piecewise constant) acceleration of
standard deviation :math:`\sigma_w`, measured with white noise of standard deviation :math:`\sigma_v` at the step
:math:`T`, is the fixed-gain filter

.. math::
    \hat x^- = \hat x_{k-1} + T\hat v_{k-1},\qquad r_k = y_k - \hat x^-,\qquad
    \hat x_k = \hat x^- + \alpha r_k,\qquad \hat v_k = \hat v_{k-1} + \frac{\beta}{T} r_k,

whose gains depend on the tracking index :math:`\Lambda = \sigma_w T^2/\sigma_v` alone:

.. math::
    \alpha = -\frac{\Lambda^2 + 8\Lambda - (\Lambda + 4)\sqrt{\Lambda^2 + 8\Lambda}}{8},\qquad
    \beta = \frac{\Lambda^2 + 4\Lambda - \Lambda\sqrt{\Lambda^2 + 8\Lambda}}{4}.

The tracking index is capped at :data:`MAX_TRACKING_INDEX` :math:`= 8`. There the two poles of the error dynamics,
the roots of :math:`z^2 - (2 - \alpha - \beta) z + 1 - \alpha`, meet in a double pole at :math:`-(\sqrt 2 - 1)^2
\approx -0.17`: the smallest spectral radius of the family, the fastest-settling tracker. Above it one pole moves
towards :math:`-1` (:math:`\alpha \to 1`, :math:`\beta \to 2` as :math:`\Lambda \to \infty`, the edge of the
stability region), an alternating mode that decays ever slower. Kalata's filter is optimal there only if the
acceleration is exactly constant between samples, which no simulator's is (semi-implicit Euler moves the position by
:math:`T^2 a`, not :math:`T^2 a / 2`; contacts change it within a step): with a nearly ideal sensor, every such
mismatch would ring on (measured on the wrapper's accuracy table: Ant at ``rate="env"`` with an ideal encoder, 7.6
rad/s RMS uncapped, 0.40 capped, against 0.44 for a backward difference).

References
----------
.. [Kal84] P. R. Kalata, "The tracking index: a generalized parameter for alpha-beta and alpha-beta-gamma target
   trackers", IEEE Transactions on Aerospace and Electronic Systems 20(2), 1984.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .._validation import check_keywords, check_positive_parameter
from . import _kernels
from .base import Observer
from .registry import register_observer

__all__ = ["MAX_TRACKING_INDEX", "AlphaBeta", "alpha_beta_step", "tracking_index_gains"]

#: the largest tracking index :class:`AlphaBeta` uses (module notes): the double pole at :math:`-(\sqrt 2 - 1)^2`
MAX_TRACKING_INDEX = 8.0


def tracking_index_gains(tracking_index):
    r"""The steady-state gains ``(alpha, beta)`` of Kalata's tracking index :math:`\Lambda > 0` (module notes); a
    float or an array of them (one per channel), and gains of the same shape."""
    lam = check_positive_parameter("tracking_index", tracking_index)
    # Kalata's alpha = -(L^2 + 8L - (L + 4) r) / 8 and beta = (L^2 + 4L - L r) / 4 with r = sqrt(L^2 + 8L), written
    # with u = r - L = 8L / (r + L): the same values without the cancellation of the printed form (which loses
    # all digits for large L) and without overflowing L^2
    root = lam * np.sqrt(1.0 + 8.0 / lam)
    u = 8.0 * lam / (root + lam)
    return root * u / (2.0 * (root + lam)), lam * u / (root + lam)


@njit(cache=True, error_model="numpy")
def alpha_beta_step(x, v, y, dt, alpha, beta):
    r"""One step of the alpha-beta tracker [Kal84]: predict with constant velocity, correct by the residual.

    .. math:: r = y - (x + Tv),\quad x^+ = x + Tv + \alpha r,\quad v^+ = v + (\beta/T)\,r.

    Returns ``(x+, v+, r)``.
    """
    x_prior = x + dt * v
    r = y - x_prior
    return x_prior + alpha * r, v + (beta / dt) * r, r


@njit(cache=True, error_model="numpy")
def alpha_beta_rows(state, y, params, new_state, out, shared):
    """:func:`alpha_beta_step` on every channel; state rows ``[x, v, r]``, parameter rows ``[T, alpha, beta]``."""
    for c in range(y.shape[0]):
        pc = 0 if shared else c  # the parameter row of channel c
        x, v, r = alpha_beta_step(state[c, 0], state[c, 1], y[c], params[pc, 0], params[pc, 1], params[pc, 2])
        new_state[c, 0] = x
        new_state[c, 1] = v
        new_state[c, 2] = r
        out[c, 0] = x
        out[c, 1] = v
    return _kernels._check_state(new_state, out)


def _tracking_index_rule(cls, calibration, order, kwargs):
    r"""Per channel, :math:`\sigma_w` = the typical (RMS) acceleration and :math:`\sigma_v` = the noise level (floored
    like every noise level a formula divides by): the model's white acceleration is a typical level, not a worst
    case (which would make the tracker trust the samples about as much as a backward difference does)."""
    levels = {"acceleration_std": calibration.rms(order), "noise_std": calibration.noise_levels}
    return cls(dt=calibration.dt, **{**levels, **kwargs})


_STEP = _kernels.register_step(alpha_beta_rows)


@register_observer(
    "alpha-beta",
    steps=(_STEP,),
    bound=2,
    calibrate=_tracking_index_rule,
    given=(("acceleration_std", "noise_std"), ("alpha", "beta")),
    examples=(dict(acceleration_std=50.0, noise_std=1e-4), dict(alpha=0.5, beta=0.2)),
)
class AlphaBeta(Observer):
    r"""The alpha-beta tracker (constant-velocity model) with Kalata's steady-state gains (module notes).

    Parameters
    ----------
    dt : float
        Sampling step ``T > 0``.
    acceleration_std, noise_std : float or array_like, optional
        :math:`\sigma_w` and :math:`\sigma_v`; the gains follow from :math:`\Lambda = \sigma_w T^2/\sigma_v`, taken
        at most :data:`MAX_TRACKING_INDEX` (module notes). Required unless ``alpha`` and ``beta`` are given. Arrays
        are per channel (broadcast to the measurement).
    alpha, beta : float or array_like, optional
        The gains themselves, inside the stability region :math:`0 < \alpha < 2`, :math:`0 < \beta < 4 - 2\alpha`.
    discretization : {"exact"}
        The tracker is a discrete-time filter.
    wrap : bool or array_like of bool, optional
        Channels measured as angles modulo ``2 pi`` (see :class:`~smo_gym.observers.Observer`).
    """

    discretizations = ("exact",)

    @check_keywords
    def __init__(
        self,
        dt: float,
        acceleration_std=None,
        noise_std=None,
        *,
        alpha=None,
        beta=None,
        discretization: str | None = None,
        wrap=None,
    ):
        super().__init__(dt, 1, discretization, wrap)
        if alpha is None and beta is None:
            if acceleration_std is None or noise_std is None:
                raise ValueError(
                    "expected acceleration_std and noise_std, or alpha and beta, actual value: "
                    f"acceleration_std={acceleration_std!r}, noise_std={noise_std!r}"
                )
            accel = check_positive_parameter("acceleration_std", acceleration_std)
            with np.errstate(over="ignore"):  # an index beyond the float range is capped like any large one
                index = accel * np.square(self.dt) / check_positive_parameter("noise_std", noise_std)
            alpha, beta = tracking_index_gains(np.minimum(index, MAX_TRACKING_INDEX))
        elif alpha is None or beta is None or acceleration_std is not None or noise_std is not None:
            raise ValueError(
                f"expected both alpha and beta without acceleration_std and noise_std, actual value: alpha={alpha!r}, "
                f"beta={beta!r}, acceleration_std={acceleration_std!r}, noise_std={noise_std!r}"
            )
        self.alpha, self.beta = check_positive_parameter("alpha", alpha), check_positive_parameter("beta", beta)
        if not (np.all(self.alpha < 2.0) and np.all(self.beta < 4.0 - 2.0 * np.asarray(self.alpha))):
            raise ValueError(
                f"expected 0 < alpha < 2 and 0 < beta < 4 - 2 alpha (a stable tracker), actual value: "
                f"alpha={self.alpha!r}, beta={self.beta!r}"
            )

    @property
    def _kernel(self):
        return _STEP.kernel

    def _channel_params(self, shape):
        alpha, beta = self._per_channel("alpha", self.alpha, shape), self._per_channel("beta", self.beta, shape)
        return np.column_stack([np.full(alpha.shape, self.dt), alpha, beta])
