r"""Computed torque with the model-based super-twisting observer: nonlinear identification and compensation control.

For a fully actuated MuJoCo mechanism with measured joint positions :math:`y = q`,

.. math::
    M(q)\,\ddot q + b(q, \dot q) = \tau_{act}(u) + \tau_{pas}(q, \dot q) + \tau_{ext},\qquad
    \ddot q = f(q, \dot q, u) + w,\quad w = M(q)^{-1}\tau_{ext},

the model-based super-twisting observer (Davila, Fridman and Levant 2005; :class:`smo_gym.observers.
MechanicalSuperTwisting`) estimates :math:`\hat q, \hat v` and identifies the unknown acceleration :math:`w` by its
equivalent output injection :math:`\hat w`. The controller needs no linearization: per sample

.. math::
    a^* &= \ddot q^*(t) - K_p\,(y - q^*(t)) - K_d\,(\hat v - \dot q^*(t)),\\
    \tau &= M(y)\,(a^* - \hat w + a_{sm}) + b(y, \hat v) - \tau_{pas}(y, \hat v),\qquad
    u = B^+\bigl(\tau - \tau_{act}(0)\bigr),

so the model's acceleration :math:`f(y, \hat v, u)` is :math:`a^* - \hat w + a_{sm}` and the plant's
:math:`a^* + (w - \hat w) + a_{sm}` up to the velocity and model errors: the matched disturbance is removed by
identification (the compensation control of Fridman's slides, section 6, in its nonlinear computed-torque form),
and the closed loop is the critically damped linear error system :math:`\ddot e + K_d\dot e + K_p e = w - \hat w`.
``B`` is the actuator map :math:`\partial\tau_{act}/\partial u` (:func:`joint_actuator_map`), exact for MuJoCo actuators
without activation dynamics (their force is affine in ``ctrl``).

The optional output integral sliding mode (Utkin and Shi 1996; the slides' output-based ISM) adds

.. math::
    s(t) = \hat v(t) - \hat v(T) - \int_T^t a^*(\tau)\,d\tau,\qquad a_{sm} = -\rho\,\frac{s}{\|s\|}
    \ \text{(or a super-twisting term in } s\text{)},

whose sliding mode :math:`\dot s = a_{sm} + (w - \hat w) = 0` rejects what the identification misses (the lag of the
filter on the equivalent injection, the observer's error while it converges, model mismatch the observer has not
yet seen); :math:`\rho` bounds that residual, not :math:`w` itself. Which is better depends on the accuracies
(Ferreira et al. 2011, in the slides): identification error :math:`\ll` execution error favours plain compensation,
the opposite favours ISM. Without ISM the reported sliding variable is zero.

Gains
-----
* PD: critically damped, :math:`K_p = \omega_c^2,\ K_d = 2\omega_c` with the closed-loop bandwidth
  :math:`\omega_c` (default :func:`default_bandwidth`: :math:`0.1/h`, a tenth of the sampling rate in rad/s, so
  the sampled loop behaves as the continuous one; lower it on noisier sensors).
* Observer: ``L`` bounds :math:`|w|` per joint; from a torque bound :math:`\bar\tau` on the external torques,
  :math:`L_i = \sigma\,\max_q \sum_j |M^{-1}(q)_{ij}|\,\bar\tau_j` (:func:`acceleration_bound`, maximised over
  sampled configurations) with the safety factor :math:`\sigma` (default 2: the sampled observer keeps sliding
  only with margin). A noisy sensor caps it (:func:`noise_limited_lipschitz`): above
  :math:`L_\eta = 2\eta/h^2` (:math:`\eta = 3\sigma_\eta`, three standard deviations of the position error) the
  sampled super-twisting step is a backward difference (worst case: nothing beats finite differences there), and a
  larger ``L`` only lets more noise into :math:`\hat w`, whose equivalent injection is bounded by
  :math:`k_2 = 1.1L`.
* ``accel_bound`` (Wetzlinger et al., eq. (33)): the model term is clipped to
  :math:`\sigma\max_q\sum_j|M^{-1}_{ij}|(\bar\tau_{act,j} + |g_j(q)| + \bar\tau_j)`, the largest acceleration the
  actuators, gravity and the disturbance can produce at rest, so a large velocity error cannot make the Coriolis
  terms escape.
* ``disturbance_time_constant``: the filter on the equivalent injection, default :math:`5h`: it averages the
  sampled injection's noise over about five samples and lags a disturbance of frequency :math:`\omega` by
  :math:`\omega\tau` (0.05 N m for the arm's 0.5 N m at 2 rad/s).
* ``t_start``: :math:`\hat w` (and ISM) act only after the observer has converged; default 0.2 s (on the two-link
  arm the identified torque reaches its steady accuracy 0.1-0.2 s after a reset with velocity errors of 0.1 rad/s).

References
----------
.. [DFL05] J. Davila, L. Fridman and A. Levant, "Second-order sliding-mode observer for mechanical systems",
   IEEE TAC 50(11), 2005.
.. [Fri] L. Fridman, "Sliding Mode Observers: Theory and Practice", lecture slides, section 6 (identification and
   compensation control; output integral sliding mode; Ferreira et al. 2011 on choosing between them).
.. [US96] V. Utkin and J. Shi, "Integral sliding mode in systems operating under uncertainty conditions", CDC 1996.
.. [WRH] M. Wetzlinger, M. Reichhartinger and M. Horn, "Higher order sliding mode inspired nonlinear
   discrete-time observer", eq. (33).
.. [Lev03] A. Levant, "Higher-order sliding modes, differentiation and output-feedback control", IJC 76, 2003
   (accuracy of the sampled differentiators).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from .._validation import as_real_array, check_bool, check_keywords, check_nonnegative, check_positive
from ..observers import MechanicalSuperTwisting
from .controllers import _Discontinuous
from .policies import ControlDiagnostics

if TYPE_CHECKING:  # MuJoCo is imported when a policy is built: ``import smo_gym.control`` stays light
    import mujoco

    from ..mechanics import MujocoDynamics

__all__ = [
    "ComputedTorquePolicy",
    "UnderactuatedError",
    "acceleration_bound",
    "computed_torque",
    "default_bandwidth",
    "joint_actuator_map",
    "noise_limited_lipschitz",
    "pd_gains",
]


class UnderactuatedError(ValueError):
    """The model's actuators do not span every measured joint: computed torque cannot assign all accelerations.

    Attributes
    ----------
    joints : list of str
        The joints without an independent actuator.
    """

    def __init__(self, message: str, joints: list[str]):
        super().__init__(message)
        self.joints = joints


# ---- the maths, as pure functions --------------------------------------------------------------------------------
def pd_gains(bandwidth: float) -> tuple[float, float]:
    r"""Critically damped PD gains for the closed-loop bandwidth :math:`\omega_c` [rad/s].

    The error system :math:`\ddot e + K_d\dot e + K_p e = 0` has the double pole :math:`-\omega_c` for

    .. math:: K_p = \omega_c^2,\qquad K_d = 2\omega_c .

    Returns
    -------
    (kp, kd) : tuple of float
    """
    w = check_positive("bandwidth", bandwidth)
    if not math.isfinite(w * w):  # an infinite kp makes every later control NaN
        raise ValueError(f"expected a bandwidth whose square is finite, actual value: {w!r}")
    return w * w, 2.0 * w


def default_bandwidth(dt: float) -> float:
    r"""Default closed-loop bandwidth :math:`\omega_c = 0.1/h` [rad/s] for the control period ``h``.

    A tenth of the sampling rate (in rad/s): the double pole at :math:`-\omega_c` maps to
    :math:`e^{-0.1} \approx 0.905`, so the sampled loop keeps the continuous one's behaviour, and the derivative
    gain :math:`K_d = 0.2/h` multiplies the velocity estimate's noise by a moderate factor. On the 100 Hz
    :class:`smo_gym.envs.TwoLinkArmEnv` with a 12-bit encoder this is 10 rad/s.
    """
    w = 0.1 / check_positive("dt", dt)
    if not math.isfinite(w):
        raise ValueError(f"expected a control period dt whose inverse is finite, actual value: {dt!r}")
    return w


def acceleration_bound(inverse_inertias, torque_bound) -> np.ndarray:
    r"""Largest joint acceleration a bounded joint torque can cause, per joint.

    .. math:: \bar a_i = \max_k \sum_j \bigl|\bigl(M(q_k)^{-1}\bigr)_{ij}\bigr|\,\bar\tau_j

    Parameters
    ----------
    inverse_inertias : array_like, shape (K, n, n)
        :math:`M(q_k)^{-1}` at ``K`` configurations.
    torque_bound : array_like, shape (n,) or (K, n)
        :math:`\bar\tau_j \ge 0` (per configuration if 2-D).

    Returns
    -------
    ndarray, shape (n,)
    """
    Minv = as_real_array("inverse_inertias", inverse_inertias)
    if Minv.ndim != 3 or Minv.shape[1] != Minv.shape[2] or Minv.shape[0] == 0:
        raise ValueError(f"expected inverse_inertias of shape (K, n, n) with K >= 1, actual value: {Minv.shape}")
    tau = as_real_array("torque_bound", torque_bound)
    try:
        tau = np.broadcast_to(tau, Minv.shape[:2])
    except ValueError:
        raise ValueError(
            f"expected torque_bound of shape ({Minv.shape[1]},) or {Minv.shape[:2]}, actual value: {tau.shape}"
        ) from None
    if not (np.all(np.isfinite(tau)) and np.all(tau >= 0)):
        raise ValueError(f"expected torque_bound finite and >= 0, actual value: {torque_bound!r}")
    return np.max(np.einsum("kij,kj->ki", np.abs(Minv), tau), axis=0)


def noise_limited_lipschitz(dt: float, noise_std) -> np.ndarray | float:
    r"""The largest useful Lipschitz constant of the sampled super-twisting observer under position noise.

    .. math:: L_\eta = \frac{2\eta}{h^2},\qquad \eta = 3\sigma_\eta .

    With noise bound :math:`\eta` and :math:`|\ddot q| \le L`, a backward difference is worst-case optimal once
    :math:`h \ge \sqrt{2\eta/L}`, i.e. :math:`L \ge L_\eta`: there the observer filters nothing and its
    equivalent injection (:math:`\hat w`, bounded by :math:`k_2 = 1.1L`) is a second difference of the noise.
    Returns ``inf`` where ``noise_std`` is zero.
    """
    h = check_positive("dt", dt)
    s = as_real_array("noise_std", noise_std)
    if not (np.all(np.isfinite(s)) and np.all(s >= 0)):
        raise ValueError(f"expected noise_std finite and >= 0, actual value: {noise_std!r}")
    with np.errstate(divide="ignore"):
        out = np.where(s > 0, 2.0 * 3.0 * s / (h * h), np.inf)
    return float(out) if out.ndim == 0 else out


def computed_torque(inertia, acceleration, bias, passive) -> np.ndarray:
    r"""Generalized force giving the model the acceleration ``acceleration``.

    .. math:: \tau = M(q)\,a + b(q, \dot q) - \tau_{pas}(q, \dot q)

    Parameters
    ----------
    inertia : array_like, shape (n, n)
    acceleration, bias, passive : array_like, shape (n,)

    Returns
    -------
    ndarray, shape (n,)

    Raises
    ------
    TypeError, ValueError
        When an argument is not real or its shape does not fit (NumPy would broadcast a scalar or a length-1
        vector into every joint).
    """
    M = as_real_array("inertia", inertia)
    if M.ndim != 2 or M.shape[0] != M.shape[1]:
        raise ValueError(f"expected inertia of shape (n, n), actual value: shape {M.shape}")
    vectors = []
    for name, value in (("acceleration", acceleration), ("bias", bias), ("passive", passive)):
        arr = as_real_array(name, value)
        if arr.shape != (M.shape[0],):
            raise ValueError(f"expected {name} of shape ({M.shape[0]},), actual value: shape {arr.shape}")
        vectors.append(arr)
    a, b, p = vectors
    return M @ a + b - p


def joint_actuator_map(dynamics: MujocoDynamics, q, v) -> tuple[np.ndarray, np.ndarray]:
    r"""Actuator map :math:`B = \partial\tau_{act}/\partial u` and the offset :math:`\tau_{act}(0)` at ``(q, v)``,
    on the measured coordinates.

    :func:`smo_gym.control.actuator_map` (exact for MuJoCo's affine actuators) on the dynamics' scratch data at
    ``(q, v)``, projected on the measured coordinates (:math:`J^\top`, for joint couplings).

    Parameters
    ----------
    dynamics : MujocoDynamics
    q, v : array_like, shape (n,)
        Measured coordinates and their velocities.

    Returns
    -------
    B : ndarray, shape (n, nu)
    offset : ndarray, shape (n,)
    """
    from .policies import actuator_map

    m, d = dynamics.model, dynamics.data
    J = dynamics.jacobian(q)
    dynamics.acceleration(np.asarray(q, dtype=np.float64), np.asarray(v, dtype=np.float64), np.zeros(m.nu))
    G, g0 = actuator_map(m, d)
    return J.T @ G, J.T @ g0


def _joint_names(dynamics: MujocoDynamics) -> list[str]:
    import mujoco

    m = dynamics.model
    names = []
    for dof in dynamics.dof:
        j = int(m.dof_jntid[dof])
        names.append(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) or f"joint {j}")
    return names


def _check_actuated(dynamics: MujocoDynamics, B: np.ndarray) -> None:
    """``UnderactuatedError`` naming the joints the actuators do not span (``rank B < n``)."""
    n = dynamics.n
    rank = int(np.linalg.matrix_rank(B)) if B.size else 0
    if rank == n:
        return
    names = _joint_names(dynamics)
    scale = max(float(np.abs(B).max()) if B.size else 0.0, 1.0)
    zero = [names[i] for i in range(n) if not np.any(np.abs(B[i]) > 1e-12 * scale)]
    joints = zero or names
    what = "no actuator" if zero else f"only {rank} independent actuator directions"
    raise UnderactuatedError(
        f"expected a fully actuated model (actuator map of rank n = {n}), actual value: rank {rank}; joints "
        f"{joints} have {what}; computed torque needs every joint actuated (use the linearized designs of "
        "smo_gym.control for underactuated systems)",
        joints,
    )


def _configurations(dynamics: MujocoDynamics, count: int, extra) -> np.ndarray:
    """``count`` configurations of the measured joints drawn (fixed seed) over their ranges (hinges without
    limits: a full turn; slides without limits: +-1 m around qpos0), plus the rows of ``extra``."""
    import mujoco

    m = dynamics.model
    rng = np.random.default_rng(0)
    lo, hi = np.empty(dynamics.n), np.empty(dynamics.n)
    for i, dof in enumerate(dynamics.dof):
        j = int(m.dof_jntid[dof])
        q0 = float(m.qpos0[m.jnt_qposadr[j]])
        if m.jnt_limited[j]:
            lo[i], hi[i] = m.jnt_range[j]
        elif int(m.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_HINGE):
            lo[i], hi[i] = -np.pi, np.pi
        else:
            lo[i], hi[i] = q0 - 1.0, q0 + 1.0
    return np.vstack([rng.uniform(lo, hi, size=(count, dynamics.n))] + [np.atleast_2d(e) for e in extra])


def _as_joint_vector(name: str, value, n: int) -> np.ndarray:
    arr = as_real_array(name, value)
    try:
        arr = np.broadcast_to(arr, (n,)).copy()
    except ValueError:
        raise ValueError(f"expected {name} a number or of shape ({n},), actual value: shape {arr.shape}") from None
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"expected a finite {name}, actual value: {value!r}")
    return arr


class ComputedTorquePolicy:
    r"""Computed-torque control with identification and compensation of the external joint torques.

    See the module docstring for the law and the gain recipes. Implements
    :class:`smo_gym.control.policies.OutputFeedbackPolicy`: ``reset(qpos_measured)`` at the first sample, then
    ``act(qpos_measured)`` once per control period; the observer is updated with the command that was applied
    (clipped to ``ctrlrange``).

    Parameters
    ----------
    model : mujoco.MjModel
        The plant's model; the policy works on a private copy (:class:`smo_gym.mechanics.MujocoDynamics`). Every
        joint must be a hinge or a slide, and the actuators must span all of them (else
        :class:`UnderactuatedError`); actuators with activation dynamics are refused (``ValueError``).
    dt : float
        Control period [s] (``env.unwrapped.dt``); the observer samples at it.
    target : array_like, shape (n,), or callable, optional
        Constant set point :math:`q^*` (zero target velocity), or ``target(t) -> (q, v, a)`` a reference with its
        first two derivatives, each of shape ``(n,)``. Default ``model.qpos0``.
    bandwidth : float, optional
        Closed-loop bandwidth :math:`\omega_c` [rad/s]; default :func:`default_bandwidth`.
    disturbance_bound : float or array_like, shape (n,), optional
        Bound :math:`\bar\tau` on the external generalized forces per joint [N m or N]; sets the observer's
        Lipschitz constant (module notes). Default: a tenth of the largest force the actuators can exert on each
        joint (a disturbance beyond their authority cannot be compensated anyway); required for actuators without
        a ``ctrlrange``, as is ``accel_bound``.
    noise_std : float or array_like, shape (n,)
        Standard deviation of the position measurement error (the sensor's ``error_std``); caps the Lipschitz
        constant at :func:`noise_limited_lipschitz`.
    safety : float
        Safety factor :math:`\sigma` on the Lipschitz constant and the acceleration bound.
    lipschitz, accel_bound : float or array_like, optional
        Override the recipes.
    compensation : bool
        Use :math:`\hat w` (default). ``False`` gives the same computed-torque PD without disturbance
        compensation (the baseline).
    ism : bool
        Add the output integral sliding mode (module notes).
    ism_gain : float, optional
        :math:`\rho` of the unit-vector term, an acceleration bound on :math:`|w - \hat w|` [rad/s^2]; default
        ``0.1 * min(L)`` (the residual is about an order below the disturbance; measured on the two-link arm).
        With ``discontinuity="super-twisting"`` the gains are :math:`k_1 = 1.5\sqrt{\rho},\ k_2 = 1.1\rho` (then
        :math:`\rho` bounds the residual's derivative).
    discontinuity : {"unit", "super-twisting"}
    t_start : float
        Time [s] after :meth:`reset` from which :math:`\hat w` and the ISM act (observer convergence).
    mass_scale : float
        Scales every mass and inertia of the policy's model (a deliberate mismatch, in
        :data:`~smo_gym.mechanics.MASS_SCALE_RANGE`; the observer sees it as disturbance).
    disturbance_time_constant : float, optional
        Time constant [s] of the filter on the equivalent injection (:class:`~smo_gym.observers.
        MechanicalSuperTwisting`); default ``5 * dt``.

    Attributes
    ----------
    dynamics : MujocoDynamics
    observer : MechanicalSuperTwisting
    kp, kd : float
    lipschitz, accel_bound : ndarray, shape (n,)
    name : str
    """

    @check_keywords
    def __init__(
        self,
        model: mujoco.MjModel,
        dt: float,
        *,
        target=None,
        bandwidth: float | None = None,
        disturbance_bound=None,
        noise_std=0.0,
        safety: float = 2.0,
        lipschitz=None,
        accel_bound=None,
        compensation: bool = True,
        ism: bool = False,
        ism_gain: float | None = None,
        discontinuity: str = "unit",
        t_start: float = 0.2,
        mass_scale: float = 1.0,
        disturbance_time_constant: float | None = None,
    ):
        import mujoco

        from ..mechanics import MujocoDynamics

        self.dt = check_positive("dt", dt)
        self.dynamics = dyn = MujocoDynamics(model, mass_scale=check_positive("mass_scale", mass_scale))
        m, n = dyn.model, dyn.n
        self.n, self.nu = n, m.nu
        if m.nu and np.any(m.actuator_dyntype != int(mujoco.mjtDyn.mjDYN_NONE)):
            bad = [
                mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, a) or f"actuator {a}"
                for a in np.flatnonzero(m.actuator_dyntype != int(mujoco.mjtDyn.mjDYN_NONE))
            ]
            raise ValueError(
                f"expected actuators without activation dynamics (force affine in ctrl), actual value: {bad}"
            )
        self._qadr = dyn.dof  # hinge/slide joints only: qpos address == dof address
        if target is None:
            target = m.qpos0[self._qadr].copy()
        if callable(target):
            self._target_fn: Callable | None = target
            self.target = None
        else:
            self._target_fn = None
            self.target = _as_joint_vector("target", target, n)
        self.bandwidth = default_bandwidth(self.dt) if bandwidth is None else check_positive("bandwidth", bandwidth)
        self.kp, self.kd = pd_gains(self.bandwidth)
        self.safety = check_positive("safety", safety)
        self.noise_std = _as_joint_vector("noise_std", noise_std, n)
        if np.any(self.noise_std < 0):
            raise ValueError(f"expected noise_std >= 0, actual value: {noise_std!r}")
        self.compensation = check_bool("compensation", compensation)
        self.ism = check_bool("ism", ism)
        self.t_start = check_nonnegative("t_start", t_start)

        # actuator map at rest over sampled configurations: full rank required
        lo = np.where(m.actuator_ctrllimited.astype(bool), m.actuator_ctrlrange[:, 0], -np.inf)
        hi = np.where(m.actuator_ctrllimited.astype(bool), m.actuator_ctrlrange[:, 1], np.inf)
        self._ctrl_low, self._ctrl_high = lo, hi
        extra = [] if self.target is None else [self.target]
        Q = _configurations(dyn, 64, extra + [m.qpos0[self._qadr]])
        zero_v = np.zeros(n)
        B0, _ = joint_actuator_map(dyn, Q[-1], zero_v)
        _check_actuated(dyn, B0)
        limited = np.isfinite(lo) & np.isfinite(hi)
        if not np.all(limited) and (disturbance_bound is None or accel_bound is None):
            raise ValueError(
                "expected disturbance_bound and accel_bound for actuators without a ctrlrange (their defaults "
                "scale with the actuators' force range), actual value: unlimited actuators "
                f"{[mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, a) or a for a in np.flatnonzero(~limited)]}"
            )
        u_span = np.where(limited, np.maximum(np.abs(lo), np.abs(hi)), 0.0)
        if disturbance_bound is None:  # a tenth of the actuators' authority on each joint (module notes)
            self.disturbance_bound = 0.1 * (np.abs(B0) @ u_span)
        else:
            self.disturbance_bound = _as_joint_vector("disturbance_bound", disturbance_bound, n)
            if np.any(self.disturbance_bound < 0):
                raise ValueError(f"expected disturbance_bound >= 0, actual value: {disturbance_bound!r}")

        # gain recipes (module notes)
        Minv = np.empty((len(Q), n, n))
        static = np.empty((len(Q), n))  # |actuator force range| + |gravity| + disturbance bound, at rest
        for k, q in enumerate(Q):
            t = dyn.terms(q, zero_v, np.zeros(m.nu))
            Minv[k] = np.linalg.inv(t["inertia"])
            B, _ = joint_actuator_map(dyn, q, zero_v)
            static[k] = np.abs(B) @ u_span + np.abs(t["bias"]) + self.disturbance_bound
        if lipschitz is None:
            L = self.safety * acceleration_bound(Minv, self.disturbance_bound)
            L = np.minimum(L, noise_limited_lipschitz(self.dt, self.noise_std))
            L = np.maximum(L, 1e-6)  # a zero disturbance bound still needs a (tiny) sliding gain
        else:
            L = _as_joint_vector("lipschitz", lipschitz, n)
            if np.any(L <= 0):
                raise ValueError(f"expected lipschitz > 0, actual value: {lipschitz!r}")
        self.lipschitz = L
        if accel_bound is None:
            self.accel_bound = self.safety * acceleration_bound(Minv, static)
        else:
            self.accel_bound = _as_joint_vector("accel_bound", accel_bound, n)
            if np.any(self.accel_bound <= 0):
                raise ValueError(f"expected accel_bound > 0, actual value: {accel_bound!r}")
        ratio = self.dt / dyn.timestep
        substeps = int(round(ratio)) if abs(ratio - round(ratio)) < 1e-6 and ratio >= 1 else 1
        self.observer = MechanicalSuperTwisting(
            self.dt,
            dyn,
            L,
            accel_bound=self.accel_bound,
            model_substeps=substeps,
            disturbance_time_constant=5.0 * self.dt
            if disturbance_time_constant is None
            else check_positive("disturbance_time_constant", disturbance_time_constant),
        )
        rho = 0.1 * float(np.min(L)) if ism_gain is None else check_positive("ism_gain", ism_gain)
        self.ism_gain = rho
        self._switch = (
            _Discontinuous(discontinuity, rho, 1.5 * np.sqrt(rho), 1.1 * rho, self.dt, n) if self.ism else None
        )
        self.name = "computed-torque" + ("+ism" if self.ism else "") + ("" if self.compensation else " (no comp.)")
        self._k = -1  # samples since reset; -1: never reset
        self._u = np.zeros(m.nu)
        nan = np.full(n, np.nan)  # nothing is known before reset
        self._diag = ControlDiagnostics(np.nan, nan, nan, nan, nan)

    @classmethod
    def from_env(cls, env, sensor="encoder-12bit-noisy", **kwargs) -> ComputedTorquePolicy:
        """A policy for a Gymnasium MuJoCo environment: its model and ``dt``, the sensor's noise, and its ``TARGET``
        (if it has one) as the default set point.

        Parameters
        ----------
        env : gymnasium.Env
            A MuJoCo environment (possibly wrapped); ``env.unwrapped.model`` and ``env.unwrapped.dt`` are read.
        sensor : str or smo_gym.sensors.Sensor
            The sensor preset or model whose ``error_std`` is ``noise_std`` (unless given).
        **kwargs
            Further arguments of the constructor.
        """
        import mujoco

        base = getattr(env, "unwrapped", env)
        model = getattr(base, "model", None)
        if not isinstance(model, mujoco.MjModel):
            raise TypeError(f"expected a MuJoCo environment (env.unwrapped.model), actual value: {type(base).__name__}")
        if "target" not in kwargs and getattr(base, "TARGET", None) is not None:
            kwargs["target"] = np.asarray(base.TARGET, dtype=np.float64)
        if "noise_std" not in kwargs:  # the largest error over the joints
            from .policies import sensor_noise

            kwargs["noise_std"] = float(np.max(sensor_noise(sensor, model, np.arange(model.nv))))
        return cls(model, float(base.dt), **kwargs)

    # ---- policy protocol ---------------------------------------------------------------------------------------
    def _measured(self, qpos_measured) -> np.ndarray:
        q = as_real_array("qpos_measured", qpos_measured)
        nq = self.dynamics.model.nq
        if q.shape != (nq,):
            raise ValueError(f"expected qpos_measured of shape ({nq},) (the full qpos), actual value: {q.shape}")
        y = q[self._qadr]
        if not np.all(np.isfinite(y)):
            raise ValueError(f"expected finite measured positions, actual value: {y!r}")
        return np.ascontiguousarray(y)

    def _reference(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if self._target_fn is None:
            z = np.zeros(self.n)
            return self.target, z, z
        out = self._target_fn(t)
        if not (isinstance(out, tuple) and len(out) == 3):
            raise TypeError(f"expected target(t) to return a tuple (q, v, a), actual value: {type(out).__name__}")
        return tuple(_as_joint_vector(f"target(t)[{i}]", x, self.n) for i, x in enumerate(out))

    def reset(self, qpos_measured) -> None:
        """Start an episode at the measurement ``qpos_measured`` (shape ``(nq,)``); zero velocity estimate."""
        y = self._measured(qpos_measured)
        self.observer.reset(y)
        self._k = 0
        self._u = np.zeros(self.nu)
        self._s = np.zeros(self.n)
        self._v_start = None
        self._a_prev = None
        if self._switch is not None:
            self._switch.reset()
        z = np.zeros(self.n)
        self._diag = ControlDiagnostics(0.0, y.copy(), z, z.copy(), z.copy())

    def act(self, qpos_measured) -> np.ndarray:
        r"""The command for the current sample, shape ``(nu,)``, clipped to ``ctrlrange``.

        The first call after :meth:`reset` takes the reset's sample (no observer update); every later call first
        updates the observer with the new measurement and the command returned by the previous call.
        """
        if self._k < 0:
            raise RuntimeError("expected reset(qpos_measured) before act(qpos_measured), actual value: never reset")
        y = self._measured(qpos_measured)
        t = self._k * self.dt
        # the reference first: a target(t) that fails must leave the observer without this sample
        q_ref, v_ref, a_ref = self._reference(t)
        if self._k > 0:
            self.observer.update(y, self._u)
        est = self.observer.estimate
        q_hat, v_hat = est[:, 0].copy(), est[:, 1].copy()
        w_hat = self.observer.disturbance.copy()
        a_star = a_ref - self.kp * (y - q_ref) - self.kd * (v_hat - v_ref)
        a = a_star.copy()
        active = t >= self.t_start
        if self.compensation and active:
            a -= w_hat
        if self.ism and active:
            a += self._sliding(v_hat, a_star)
        terms = self.dynamics.terms(y, v_hat, np.zeros(self.nu))
        tau = computed_torque(terms["inertia"], a, terms["bias"], terms["passive"])
        B, offset = joint_actuator_map(self.dynamics, y, v_hat)
        u = np.linalg.lstsq(B, tau - offset, rcond=None)[0]
        self._u = np.clip(u, self._ctrl_low, self._ctrl_high)
        self._diag = ControlDiagnostics(t, q_hat, v_hat, terms["inertia"] @ w_hat, self._s.copy())
        self._k += 1
        return self._u.copy()

    def _sliding(self, v_hat: np.ndarray, a_star: np.ndarray) -> np.ndarray:
        r"""Update :math:`s_k = s_{k-1} + \hat v_k - \hat v_{k-1} - h\,a^*_{k-1}` (``s(T) = 0``); return the
        discontinuous acceleration."""
        if self._v_start is None:
            self._v_start = v_hat.copy()
        else:
            self._s = self._s + v_hat - self._v_start - self.dt * self._a_prev
            self._v_start = v_hat.copy()
        self._a_prev = a_star.copy()
        return self._switch(self._s)

    @property
    def diagnostics(self) -> ControlDiagnostics:
        """Estimates after the last :meth:`act`: ``qpos``, ``qvel`` (observer), ``disturbance`` the identified
        external torque :math:`M(y)\\hat w` (N m), ``sliding`` the ISM variable in joint coordinates, shape ``(n,)``
        (``n = nu`` for the usual one motor per joint; zeros without ISM). All NaN before :meth:`reset`."""
        return self._diag
