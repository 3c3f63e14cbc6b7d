r"""Closed-loop sampled-data simulation of a :class:`LinearPlant` under an output-feedback controller, and the
numbers the experiments report (steady-state error, total variation, fitted accuracy orders).

Plant integration: the state is propagated exactly for the zero-order-held control and, on an internal step
``h <= w_step`` that divides the sampling step, the convolution with the unknown input
:math:`\int_0^h e^{A(h-s)}Dw(t+s)\,ds` is computed by 3-point Gauss-Legendre quadrature (error
``O(h^7)`` per step for smooth ``w``), so the simulation error is far below the effects being measured.

Sensing and actuation (Fridman's slides, section 6, "accuracy"):

- sampling step ``dt`` (:math:`\delta`);
- measurement noise: Gaussian ``noise_std`` and/or uniform quantization ``resolution`` (an encoder);
- actuator: first-order lag :math:`\mu\dot u_a = u - u_a` with ``actuator_tau = mu`` (execution error
  :math:`O(\mu)`); the observer only knows the commanded ``u``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from .._validation import DivergenceError, as_real_array, check_nonnegative, check_positive, check_real
from .plants import LinearPlant

__all__ = ["SimulationResult", "fit_order", "simulate", "steady_state_error", "total_variation_rate"]

#: the longest record :func:`simulate` allocates (samples)
MAX_SAMPLES = 10**8

_GAUSS_NODES = 0.5 * (1.0 + np.array([-np.sqrt(3.0 / 5.0), 0.0, np.sqrt(3.0 / 5.0)]))
_GAUSS_WEIGHTS = np.array([5.0, 8.0, 5.0]) / 18.0


@dataclass
class SimulationResult:
    """Sampled trajectories of a closed-loop run (one row per sampling instant ``t_k``).

    Attributes
    ----------
    t : ndarray, shape (T,)
    x : ndarray, shape (T, n)
        True state at ``t_k``.
    y : ndarray, shape (T, p)
        Measurements (with noise / quantization).
    u : ndarray, shape (T, q)
        Commanded control held over ``[t_k, t_k+1)``.
    u_applied : ndarray, shape (T, q)
        Actuator output at ``t_k`` (equals ``u`` without an actuator lag).
    x_hat : ndarray, shape (T, n)
    w : ndarray, shape (T, m)
        True unknown input at ``t_k``.
    w_hat : ndarray, shape (T, m)
        Identified unknown input (zeros for observers that do not identify).
    """

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    u: np.ndarray
    u_applied: np.ndarray
    x_hat: np.ndarray
    w: np.ndarray
    w_hat: np.ndarray
    dt: float

    def after(self, t0: float) -> np.ndarray:
        """Boolean mask of the samples with ``t >= t0``."""
        return self.t >= t0


def _w_values(w, t: np.ndarray, m: int) -> np.ndarray:
    if w is None:
        return np.zeros((t.size, m))
    vals = np.asarray(w(t), dtype=float)
    if vals.ndim == 1:
        vals = vals[:, None]
    if vals.shape != (t.size, m):
        raise ValueError(f"expected w(t) to return shape (len(t), {m}) or (len(t),), actual value: {vals.shape}")
    return vals


def simulate(
    plant: LinearPlant,
    controller,
    *,
    t_final: float,
    w=None,
    x0=None,
    noise_std: float = 0.0,
    noise_bound: float = 0.0,
    resolution: float = 0.0,
    actuator_tau: float = 0.0,
    w_step: float = 1e-3,
    x_hat0=None,
    seed: int | None = 0,
) -> SimulationResult:
    r"""Run ``controller`` on ``plant`` in closed loop, sampled at ``controller.dt``.

    Parameters
    ----------
    plant : LinearPlant
        The true plant (may differ from the controller's model).
    controller
        Object with ``dt``, ``reset(y0, x_hat0)``, ``step(y, t) -> u`` and ``observer`` (``x_hat``, ``w_hat``).
    t_final : float
        Duration [s].
    w : callable, optional
        ``w(t)`` for an array ``t`` returning ``(len(t), m)`` (or ``(len(t),)`` when ``m = 1``).
    x0 : array_like, shape (n,), optional
        Initial state (default zero).
    noise_std : float
        Standard deviation of Gaussian measurement noise.
    noise_bound : float
        Bound of uniform measurement noise in ``[-noise_bound, noise_bound]`` (the bounded noise the sliding-mode
        differentiators' accuracy is stated for: Levant 2003); 0 for none.
    resolution : float
        Quantization step of the measurement (an encoder's ``2 pi / counts``); 0 for none.
    actuator_tau : float
        Time constant ``mu`` of a first-order actuator; 0 for an ideal actuator.
    w_step : float
        Largest internal step for the quadrature of ``w``.
    x_hat0 : array_like, optional
        Observer initial state (default from the first measurement).
    seed : int, optional
        Noise seed.
    """
    if not isinstance(plant, LinearPlant):
        raise TypeError(f"expected a LinearPlant, actual value: {type(plant).__name__}")
    dt = check_positive("dt", controller.dt)
    t_final = check_positive("t_final", t_final)
    if t_final / dt > MAX_SAMPLES:  # the record is allocated up front
        raise ValueError(f"expected at most {MAX_SAMPLES} samples (t_final / dt), actual value: {t_final / dt:.3g}")
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0):
        raise TypeError(f"expected seed None or an integer >= 0, actual value: {seed!r}")
    noise_bound = check_nonnegative("noise_bound", noise_bound)
    noise_std, resolution = check_nonnegative("noise_std", noise_std), check_nonnegative("resolution", resolution)
    w_step = check_positive("w_step", w_step)
    n, q, m = plant.n, plant.n_inputs, plant.n_unknown
    A, B, D = plant.augmented(actuator_tau)
    na = A.shape[0]
    n_sub = max(1, int(np.ceil(dt / w_step - 1e-9)))
    h = dt / n_sub
    M = np.zeros((na + q, na + q))
    M[:na, :na], M[:na, na:] = A * h, B * h
    E = sla.expm(M)
    Phi_h, Gam_h = E[:na, :na], E[:na, na:]
    # quadrature weights of the three Gauss nodes side by side: (na, 3 m) acting on [w(s1); w(s2); w(s3)]
    nodes = zip(_GAUSS_NODES, _GAUSS_WEIGHTS, strict=True)
    Ew = np.hstack([c * sla.expm(A * h * (1.0 - s)) @ D * h for s, c in nodes])
    T = int(round(t_final / dt)) + 1
    t = np.arange(T) * dt
    node_t = t[:-1, None, None] + h * (np.arange(n_sub)[None, :, None] + _GAUSS_NODES[None, None, :])
    Wn = _w_values(w, node_t.reshape(-1), m).reshape(T - 1, n_sub, 3 * m) if T > 1 else None
    Wt = _w_values(w, t, m)
    rng = np.random.default_rng(seed)
    xa = np.zeros(na)
    if x0 is not None:  # one entry would be copied into every state
        x0 = as_real_array("x0", x0)
        if x0.shape != (n,) or not np.isfinite(x0).all():
            raise ValueError(f"expected a finite x0 of shape ({n},), actual value: {x0!r:.80}")
        xa[:n] = x0
    p = plant.n_outputs
    X, Y, U, UA, XH, WH = (np.zeros((T, k)) for k in (n, p, q, q, n, m))

    def measure(x):
        y = plant.C @ x
        if noise_std > 0:
            y = y + noise_std * rng.standard_normal(p)
        if noise_bound > 0:
            y = y + rng.uniform(-noise_bound, noise_bound, p)
        if resolution > 0:
            y = resolution * np.round(y / resolution)
        return y

    y = measure(xa[:n])
    controller.reset(y, x_hat0)
    for k in range(T):
        if k > 0:
            y = measure(xa[:n])
        u = controller.step(y, t[k])
        X[k], Y[k], U[k] = xa[:n], y, u
        UA[k] = xa[n:] if actuator_tau > 0 else u
        XH[k] = controller.observer.x_hat
        WH[k] = controller.observer.w_hat
        if k == T - 1:
            break
        for j in range(n_sub):
            xa = Phi_h @ xa + Gam_h @ u + Ew @ Wn[k, j]
        if not np.all(np.isfinite(xa)):
            raise DivergenceError(f"expected a bounded closed loop, actual value: non-finite state at t={t[k]}")
    return SimulationResult(t=t, x=X, y=Y, u=U, u_applied=UA, x_hat=XH, w=Wt, w_hat=WH, dt=dt)


def steady_state_error(result: SimulationResult, t0: float, indices=None) -> float:
    """``max_k |x_i(t_k)|`` over ``t_k >= t0`` and the state entries ``indices`` (default every entry)."""
    sel = result.after(check_real("t0", t0))
    if indices is not None:
        n = result.x.shape[1]
        index = np.asarray(indices)
        if (
            index.ndim != 1
            or index.size == 0
            or index.dtype.kind not in "iu"
            or not np.all((-n <= index) & (index < n))
        ):
            raise ValueError(
                f"expected indices a non-empty sequence of state indices in [0, {n}), actual value: {indices!r}"
            )
    x = result.x[sel] if indices is None else result.x[sel][:, indices]
    if x.size == 0:
        raise ValueError(f"expected samples at t >= t0, actual value: t0 = {t0!r} after the record's end")
    return float(np.abs(x).max())


def total_variation_rate(u: np.ndarray, t: np.ndarray) -> float:
    r"""Total variation of the control per second, :math:`\frac{1}{t_N - t_0}\sum_k \|u_{k+1} - u_k\|_1`.

    Chattering in numbers: a continuous control has a variation set by the signal it tracks; a switching control
    of amplitude ``rho`` at step ``tau`` reaches ``~ 2 rho / tau``.
    """
    u, t = as_real_array("u", u), as_real_array("t", t)
    if u.ndim == 1:
        u = u[:, None]
    if t.ndim != 1 or t.size < 2 or u.shape[0] != t.size:
        raise ValueError(f"expected u (T, ...) and increasing t (T,) with T >= 2, actual value: {u.shape}, {t.shape}")
    if not (np.isfinite(u).all() and np.isfinite(t).all() and np.all(np.diff(t) > 0)):
        raise ValueError(f"expected finite u and finite, increasing t, actual value: t={t!r:.80}, u={u!r:.80}")
    return float(np.abs(np.diff(u, axis=0)).sum() / (t[-1] - t[0]))


def fit_order(steps, errors) -> float:
    """Slope of ``log(error)`` against ``log(step)`` by least squares: the fitted accuracy order."""
    steps, errors = as_real_array("steps", steps).reshape(-1), as_real_array("errors", errors).reshape(-1)
    if steps.shape != errors.shape or steps.size < 2 or np.unique(steps).size < 2:
        raise ValueError(
            f"expected steps and errors of one length with two steps or more, actual value: {steps!r}, {errors!r}"
        )
    if not (np.all(steps > 0) and np.all(errors > 0) and np.isfinite(steps).all() and np.isfinite(errors).all()):
        raise ValueError(f"expected finite steps and errors > 0 (logarithms), actual value: {steps!r}, {errors!r}")
    return float(np.polyfit(np.log(steps), np.log(errors), 1)[0])
