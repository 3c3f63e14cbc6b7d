r"""Output-feedback controllers that act as policies on a sensed MuJoCo environment.

A policy maps the *measured* joint configuration of one control period to an actuator command::

    policy.reset(qpos_measured)          # at the episode's first sample
    ctrl = policy.act(qpos_measured)     # once per environment step, shape (nu,)
    policy.diagnostics                   # estimated state, identified disturbance, sliding variable

``qpos_measured`` is the environment's full ``qpos`` as the sensor reports it (``info["smo"]["qpos_measured"]`` of
:class:`smo_gym.wrappers.EstimatedVelocity`); the policy reads the joints it measures from it. The command is
clipped to the actuators' ``ctrlrange``, and every observer inside is told the command that was actually applied.
"""

from __future__ import annotations

from typing import NamedTuple, Protocol, runtime_checkable

import numpy as np

from .._validation import (
    as_real_array,
    check_choice,
    check_int_in_range,
    check_nonnegative,
    check_nonnegative_array,
    check_positive,
)

__all__ = [
    "ControlDiagnostics",
    "LinearDesign",
    "LinearizedPolicy",
    "OperatingPoint",
    "OutputFeedbackPolicy",
    "actuator_map",
    "default_weights",
    "design",
    "differentiator_bound",
    "equilibrium",
    "sensor_noise",
]


class ControlDiagnostics(NamedTuple):
    """What an output-feedback policy knows after its last :meth:`~OutputFeedbackPolicy.act`.

    Attributes
    ----------
    t : float
        Time of the last sample since :meth:`~OutputFeedbackPolicy.reset` [s].
    qpos : ndarray, shape (n,)
        Estimated positions of the measured joints.
    qvel : ndarray, shape (n,)
        Estimated velocities of the measured joints.
    disturbance : ndarray, shape (m,)
        Identified unknown input: generalized forces on the policy's disturbance channels (N m or N); zeros for a
        policy that does not identify it.
    sliding : ndarray, shape (nu,)
        Sliding variable of the discontinuous term; zeros for a policy without one.
    """

    t: float
    qpos: np.ndarray
    qvel: np.ndarray
    disturbance: np.ndarray
    sliding: np.ndarray


@runtime_checkable
class OutputFeedbackPolicy(Protocol):
    """An output-feedback controller on a MuJoCo environment (see the module docstring).

    Attributes
    ----------
    dt : float
        The control period the policy was designed for (the environment step ``env.unwrapped.dt``).
    name : str
        Short label for tables and plots.
    """

    dt: float
    name: str

    def reset(self, qpos_measured) -> None: ...

    def act(self, qpos_measured) -> np.ndarray: ...

    @property
    def diagnostics(self) -> ControlDiagnostics: ...


# ----------------------------------------------------------------------------------------------------------------
# the linearized design: one call from an environment to a controller
# ----------------------------------------------------------------------------------------------------------------
#: controllers of :func:`design` built on the linearization (the cascaded HOSM observer or a baseline observer)
LINEAR_CONTROLLERS = ("compensation", "ism", "unmatched", "lqr", "lqr-luenberger", "lqr-kalman", "pid")
#: controllers that need the triple (A, C, D) strongly observable (they run the cascaded HOSM observer)
HOSM_CONTROLLERS = ("compensation", "ism", "unmatched", "lqr")
#: position scale [rad or m] of the default LQR weights (Bryson's rule): an error of this size costs as much as
#: the full actuator range
POSITION_SCALE = 0.05
#: time scale [s] of the default velocity weight: a velocity of ``POSITION_SCALE / VELOCITY_TIME`` costs as much
VELOCITY_TIME = 0.1
#: time scale [s] of the PID baseline's integral weight: an integrated error of ``POSITION_SCALE * INTEGRAL_TIME``
#: costs as much as a position error of ``POSITION_SCALE``
INTEGRAL_TIME = 0.5
#: time constant [s] of the PID baseline's derivative filter (a raw backward difference of a noisy encoder at a
#: few milliseconds is too noisy to feed back). Tuned, not calibrated: on the two-link arm of
#: ``scripts/bench_control.py`` (2 ms, 12-bit noisy encoder, 3 seeds) the steady band is 1.7 / 0.77 / 0.24 / 0.028 /
#: 0.0063 / 0.0096 rad for 0 / 4 / 10 / 20 / 40 / 80 ms, so the baseline gets its best value
DERIVATIVE_FILTER = 0.04
#: safety factor on the differentiator's bound (:func:`smo_gym.control.output_error_lipschitz`)
SAFETY = 2.5
#: default disturbance amplitude, as a fraction of the actuators' force range on the disturbance channels
DISTURBANCE_FRACTION = 0.2
#: default disturbance bandwidth [rad/s]: the bound on its derivatives is amplitude * bandwidth**i
DISTURBANCE_BANDWIDTH = 2 * np.pi * 0.5


class OperatingPoint(NamedTuple):
    """Where :func:`design` linearizes: an equilibrium of the environment's model.

    Attributes
    ----------
    qpos : ndarray, shape (nq,)
    ctrl : ndarray, shape (nu,)
        The control that holds ``qpos`` at rest (from MuJoCo's inverse dynamics, least squares over the actuators).
    """

    qpos: np.ndarray
    ctrl: np.ndarray


class LinearDesign(NamedTuple):
    """Everything :func:`design` computed, for inspection and for reports.

    Attributes
    ----------
    plant : LinearPlant
        The linearization: state ``[qpos - qpos0 (nv), qvel (nv)]``, input ``ctrl - ctrl0``, outputs the measured
        positions, unknown input the generalized forces on the disturbance channels.
    operating_point : OperatingPoint
    joints : tuple of str
        The measured joints, in the order of the outputs.
    disturbance_dofs : ndarray of int, shape (m,)
        ``qvel`` addresses the unknown input acts on.
    K : ndarray, shape (nu, 2 nv)
        The state feedback.
    Q, R : ndarray
        The LQR weights it was computed from.
    lipschitz : ndarray, shape (p,) or None
        The differentiator's bound per output (HOSM controllers).
    w_bounds : tuple of float
        Bounds on the disturbance and its derivatives the gains assume.
    noise_std : ndarray, shape (p,)
        The sensor's error standard deviation per output (noise and quantization).
    """

    plant: object
    operating_point: OperatingPoint
    joints: tuple
    disturbance_dofs: np.ndarray
    K: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    lipschitz: np.ndarray | None
    w_bounds: tuple
    noise_std: np.ndarray


def _mujoco():
    import mujoco  # lazy: the rest of smo_gym.control does not need MuJoCo

    return mujoco


def _joint_dofs(model, joints) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """Names, ``qpos`` and ``qvel`` addresses of ``joints`` (``None``: every joint); hinge and slide joints only."""
    mujoco = _mujoco()
    names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) or f"joint{j}" for j in range(model.njnt)]
    bad = [
        n
        for j, n in enumerate(names)
        if int(model.jnt_type[j]) not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
    ]
    if bad:
        raise ValueError(
            f"expected a model with hinge and slide joints only (positions in a vector space), actual value: joints "
            f"{bad} are free or ball joints"
        )
    if joints is None:
        ids = list(range(model.njnt))
    else:
        if isinstance(joints, str):
            joints = [joints]
        ids = []
        for name in joints:
            if name not in names:
                raise ValueError(f"expected a joint of the model ({names}), actual value: {name!r}")
            ids.append(names.index(name))
    return (
        tuple(names[j] for j in ids),
        np.array([model.jnt_qposadr[j] for j in ids], dtype=int),
        np.array([model.jnt_dofadr[j] for j in ids], dtype=int),
    )


def actuator_map(model, data) -> tuple[np.ndarray, np.ndarray]:
    r"""The generalized force of the actuators as an affine map of the controls at ``data``'s state.

    .. math:: \tau_{act}(u) = G u + g_0,\qquad G = \partial\,\mathtt{qfrc\_actuator} / \partial u,

    exact for MuJoCo's affine actuators (motors, position and velocity servos) without activation dynamics; ``G``
    by one evaluation per control with ``mj_fwdActuation`` (``data`` is used as scratch and left at ``u = 0``).

    Returns
    -------
    G : ndarray, shape (nv, nu)
    g0 : ndarray, shape (nv,)
    """
    mujoco = _mujoco()
    data.ctrl[:] = 0.0
    mujoco.mj_forward(model, data)
    g0 = data.qfrc_actuator.copy()
    G = np.zeros((model.nv, model.nu))
    for j in range(model.nu):
        data.ctrl[:] = 0.0
        data.ctrl[j] = 1.0
        mujoco.mj_fwdActuation(model, data)
        G[:, j] = data.qfrc_actuator - g0
    data.ctrl[:] = 0.0
    mujoco.mj_fwdActuation(model, data)
    return G, g0


def equilibrium(model, qpos=None) -> OperatingPoint:
    r"""The equilibrium nearest to ``qpos`` (default ``model.qpos0``) and the control that holds it.

    At rest (:math:`\dot q = \ddot q = 0`) MuJoCo's inverse dynamics give the generalized force a configuration
    needs, :math:`\tau^*(q) = \mathtt{qfrc\_inverse}` (gravity, springs); the control solves
    :math:`G u_0 = \tau^* - g_0` (:func:`actuator_map`) by least squares. The joints the actuators do not reach
    (zero rows of ``G``) must be at rest by themselves: their positions are corrected by Newton's method on
    :math:`\tau^*` of those joints (finite-difference Jacobian), which finds e.g. the exactly balanced pose of a
    model whose upright ``qpos0`` is slightly off. A configuration with no equilibrium within 0.2 rad (or m) of
    ``qpos`` on the unactuated joints, or one the actuators cannot hold within their range, is refused.
    """
    mujoco = _mujoco()
    if not isinstance(model, mujoco.MjModel):
        raise TypeError(f"expected model to be a mujoco.MjModel, actual value: {type(model).__name__}")
    if model.na:
        raise ValueError(
            f"expected actuators without activation dynamics (na = 0), actual value: na = {model.na}; the "
            "linearized designs act on forces directly"
        )
    names, qadr, dofs = _joint_dofs(model, None)
    d = mujoco.MjData(model)
    q0 = model.qpos0.copy() if qpos is None else as_real_array("qpos", qpos, copy=True).reshape(-1)
    if q0.shape != (model.nq,) or not np.all(np.isfinite(q0)):
        raise ValueError(f"expected a finite operating point of shape ({model.nq},), actual value: {qpos!r}")
    d.qpos[:] = q0
    G, _ = actuator_map(model, d)
    free = np.abs(G).max(axis=1, initial=0.0) == 0.0  # dofs no actuator reaches

    def need(q):
        d.qpos[:] = q
        d.qvel[:] = 0.0
        d.ctrl[:] = 0.0
        mujoco.mj_forward(model, d)
        g0 = d.qfrc_actuator.copy()
        d.qacc[:] = 0.0  # after the forward pass, which overwrites it
        mujoco.mj_inverse(model, d)
        return d.qfrc_inverse - g0

    tau0 = need(q0)
    q = q0.copy()
    fq = qadr[free[dofs]]  # qpos addresses of the unactuated joints (hinge/slide: one per dof)
    fd = dofs[free[dofs]]
    tol = 1e-9 * max(1.0, float(np.abs(G).max(initial=0.0)))
    for _ in range(20):
        r = need(q)[fd]
        if fd.size == 0 or np.abs(r).max() <= tol:
            break
        J = np.empty((fd.size, fd.size))
        for i, a in enumerate(fq):
            dq = np.zeros_like(q)
            dq[a] = 1e-6
            J[:, i] = (need(q + dq)[fd] - need(q - dq)[fd]) / 2e-6
        q[fq] -= np.linalg.lstsq(J, r, rcond=None)[0]
    tau = need(q)
    ctrl0 = np.linalg.lstsq(G, tau, rcond=None)[0] if model.nu else np.zeros(0)
    miss = tau - G @ ctrl0
    shift = np.abs(q - q0).max(initial=0.0)
    if np.abs(miss).max(initial=0.0) > tol + 1e-6 * np.abs(tau).max(initial=0.0) or shift > 0.2:
        unheld = [n for n, v in zip(names, dofs, strict=True) if free[v] and abs(tau0[v]) > tol]
        raise ValueError(
            f"expected an operating point the actuators can hold at rest, actual value: qpos {q0.tolist()} needs "
            f"generalized forces {np.round(tau0[free], 6).tolist()} on the unactuated joints {unheld}, which the "
            f"actuators cannot produce, and the nearest equilibrium of those joints is {shift:.3g} away; pick an "
            "equilibrium (upright or hanging)"
        )
    lo, hi = model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1]
    limited = model.actuator_ctrllimited.astype(bool)
    if np.any(limited & ((ctrl0 < lo - 1e-9) | (ctrl0 > hi + 1e-9))):
        raise ValueError(
            f"expected an operating point within the actuator range, actual value: holding it needs ctrl "
            f"{ctrl0.tolist()} outside {model.actuator_ctrlrange.tolist()}"
        )
    return OperatingPoint(q, ctrl0)


def _inertia(model, qpos) -> np.ndarray:
    mujoco = _mujoco()
    d = mujoco.MjData(model)
    d.qpos[:] = qpos
    mujoco.mj_forward(model, d)
    M = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, d, M)
    return M


def _disturbance_dofs(model, disturbance, G) -> np.ndarray:
    if isinstance(disturbance, str) and disturbance == "actuated":
        dofs = np.nonzero(np.abs(G).max(axis=1) > 0)[0]
    elif isinstance(disturbance, str) and disturbance == "joints":
        dofs = np.arange(model.nv)
    else:
        try:
            dofs = _joint_dofs(model, disturbance)[2]
        except TypeError:
            raise TypeError(
                f"expected disturbance 'actuated', 'joints' or a sequence of joint names, actual value: {disturbance!r}"
            ) from None
    if dofs.size == 0:
        raise ValueError(f"expected at least one disturbance channel, actual value: {disturbance!r} selects none")
    return dofs


def default_weights(model, qpos, G) -> tuple[np.ndarray, np.ndarray]:
    r"""Default LQR weights (Bryson's rule, with the velocity weighted by the inertia).

    .. math::
        Q = \begin{bmatrix} I/\theta^2 & 0 \\ 0 & \dfrac{T^2}{\theta^2}\,\dfrac{M(q_0)}{\bar m}\end{bmatrix},
        \qquad R = \mathrm{diag}(1/u_{max,j}^2),

    with :math:`\theta` = :data:`POSITION_SCALE`, :math:`T` = :data:`VELOCITY_TIME`, :math:`\bar m` the mean of the
    diagonal of the joint-space inertia :math:`M(q_0)` and :math:`u_{max}` the actuator's largest control
    magnitude (its ``ctrlrange``; 1 for an unlimited actuator): a position error of :math:`\theta`, a velocity of
    :math:`\theta/T` on a joint of average inertia (kinetic energy weighted by the inertia, so heavy joints count
    more) and a full actuator command cost the same.

    Raises
    ------
    ValueError
        If ``qpos`` is not finite or not of shape ``(nq,)`` (the inertia, and so ``Q``, would be NaN).
    """
    nv = model.nv
    q = as_real_array("qpos", qpos)
    if q.shape != (model.nq,) or not np.isfinite(q).all():
        raise ValueError(f"expected qpos finite with shape ({model.nq},), actual value: {qpos!r:.80}")
    M = _inertia(model, q)
    mbar = float(np.mean(np.diag(M)))
    Q = np.zeros((2 * nv, 2 * nv))
    Q[:nv, :nv] = np.eye(nv) / POSITION_SCALE**2
    Q[nv:, nv:] = (VELOCITY_TIME / POSITION_SCALE) ** 2 * M / mbar
    umax = np.where(model.actuator_ctrllimited.astype(bool), np.abs(model.actuator_ctrlrange).max(axis=1), 1.0).astype(
        float
    )
    R = np.diag(1.0 / np.maximum(umax, 1e-12) ** 2)
    return Q, R


def differentiator_bound(plant, dt: float, L_d: np.ndarray, order: int, w_bounds, noise_bound) -> np.ndarray:
    r"""Per-output bound on the ``(order + 1)``-th derivative of the cascade's output error, calibrated.

    Between samples the error of the sampled Luenberger stage obeys :math:`\dot e = Ae + Dw`, so
    (as in :func:`smo_gym.control.output_error_lipschitz`)

    .. math:: y_e^{(k+1)} = C A^{k+1} e + \sum_{i=0}^{k} C A^{k-i} D\, w^{(i)} .

    Instead of a guessed bound on :math:`\|e\|`, the first term is bounded by the exact peak-to-peak gain of the
    error recursion :math:`e_{j+1} = \Phi(I - L_d C)e_j + \Gamma_D w_j - \Phi L_d\eta_j` seen through
    :math:`c_i A^{k+1}`:

    .. math::
        |c_i A^{k+1} e| \le \sum_{j \ge 0} \big|c_i A^{k+1} M^j \Gamma_D\big|\,w^+ +
        \big|c_i A^{k+1} M^j \Phi L_d\big|\,\eta^+,\qquad M = \Phi(I - L_d C),

    (absolute values and sums entrywise: the :math:`\ell_1` norm of the impulse response, which is attained by the
    worst bounded input), with :math:`w^+` the disturbance bound and :math:`\eta^+` the sensor's error bound per
    output. It is tight where a norm bound of :math:`\|e\|` is not (non-normal error dynamics).

    Parameters
    ----------
    plant : LinearPlant
    dt : float
    L_d : ndarray, shape (n, p)
        Gain of the sampled Luenberger stage (:func:`smo_gym.control.sampled_observer_gain`).
    order : int
        The differentiator's order ``k``.
    w_bounds : sequence of float
        Bounds of :math:`|w^{(i)}|` (each channel), ``i = 0, 1, ...`` (the last is reused; one number: the same
        bound for every ``i``, as :func:`smo_gym.control.output_error_lipschitz` reads it).
    noise_bound : array_like, shape (p,)
        Bound of the measurement error per output.

    Returns
    -------
    ndarray, shape (p,)

    Raises
    ------
    ValueError
        If a bound is negative or not finite, ``L_d`` is not a finite ``(n, p)`` array, or the error map
        :math:`M` is not stable (spectral radius >= 1: the sum diverges).
    """
    from .estimators import output_error_lipschitz
    from .plants import LinearPlant

    A, C = plant.A, plant.C
    p = C.shape[0]
    order = check_int_in_range("order", order, 0, 64)
    w0 = float(check_nonnegative_array("w_bounds", w_bounds).reshape(-1)[0])
    noise = as_real_array("noise_bound", noise_bound)
    if noise.shape not in ((), (p,)) or not np.all(np.isfinite(noise) & (noise >= 0)):
        raise ValueError(f"expected noise_bound >= 0 and finite, a number or shape ({p},), actual value: {noise!r}")
    noise = np.broadcast_to(noise, (p,))
    L_d = as_real_array("L_d", L_d)
    if L_d.shape != (plant.n, p) or not np.isfinite(L_d).all():
        raise ValueError(f"expected L_d with shape ({plant.n}, {p}), finite, actual value: {L_d!r:.120}")
    Phi, Gamma_D = LinearPlant(A, plant.D, C, plant.D).discretize(dt)
    M = Phi @ (np.eye(plant.n) - L_d @ C)
    rho = float(np.abs(np.linalg.eigvals(M)).max(initial=0.0))
    if not rho < 1.0:  # the impulse response's l1 norm is infinite: the iteration would overflow into NaN
        raise ValueError(
            f"expected L_d making the error map Phi (I - L_d C) stable, actual value: spectral radius {rho:.6g}"
        )
    row = C @ np.linalg.matrix_power(A, order + 1)
    inputs = np.hstack([Gamma_D * w0, (Phi @ L_d) * noise[None, :]])
    total = np.zeros(p)
    for _ in range(200_000):
        term = np.abs(row @ inputs).sum(axis=1)
        total += term
        if term.max() <= 1e-12 * max(total.max(), 1e-300):
            break
        row = row @ M
    else:  # a spectral radius this close to 1 leaves the sum unconverged: no bound to trust
        raise ValueError(
            f"expected an error map Phi (I - L_d C) that decays, actual value: spectral radius {rho:.12g}, the sum "
            "did not converge in 200000 samples"
        )
    return total + output_error_lipschitz(plant, order, e_bound=0.0, w_bounds=w_bounds)


class LinearizedPolicy:
    r"""A controller of :mod:`smo_gym.control` on the linearization of a MuJoCo environment, as a policy.

    In deviation coordinates :math:`y = q_{meas} - q_0`, :math:`u = \mathtt{ctrl} - u_0` (the operating point), every
    sample runs the controller's observer update, its law, the clip to the actuators' range and the observer's
    prediction with the command actually applied. Built by :func:`design`.

    Attributes
    ----------
    controller
        The :mod:`smo_gym.control` controller (its ``observer``, gains, sliding variable).
    design : LinearDesign
        The numbers it was built from.
    """

    def __init__(self, controller, design: LinearDesign, dt: float, name: str, model, qpos_adr):
        self.controller = controller
        self.design = design
        self.dt = float(dt)
        self.name = name
        self._q0 = design.operating_point.qpos
        self._u0 = design.operating_point.ctrl
        limited = model.actuator_ctrllimited.astype(bool)  # an unlimited actuator's ctrlrange is (0, 0)
        self._lo = np.where(limited, model.actuator_ctrlrange[:, 0], -np.inf)
        self._hi = np.where(limited, model.actuator_ctrlrange[:, 1], np.inf)
        self._out_adr = np.asarray(qpos_adr, dtype=int)
        self._nv = design.plant.n // 2
        self._t = None  # time of the next sample; None before reset
        self._last_t = 0.0  # time of the last command

    def _outputs(self, qpos_measured) -> np.ndarray:
        q = as_real_array("qpos_measured", qpos_measured)  # not True as 1.0, "0.1" as 0.1, or 0.1+1j as 0.1
        if q.shape != self._q0.shape:
            raise ValueError(f"expected qpos_measured of shape {self._q0.shape}, actual value: shape {q.shape}")
        if not np.all(np.isfinite(q)):
            raise ValueError(f"expected finite measured positions, actual value: {q!r}")
        return q[self._out_adr] - self._q0[self._out_adr]

    def reset(self, qpos_measured) -> None:
        """Start the observer from the first measurement (velocities zero, unmeasured positions at the operating
        point)."""
        self.controller.reset(self._outputs(qpos_measured))
        self._t = 0.0
        self._last_t = 0.0

    def act(self, qpos_measured) -> np.ndarray:
        """The actuator command for this sample, shape ``(nu,)``, within ``ctrlrange``."""
        if self._t is None:
            raise RuntimeError("expected reset(qpos_measured) before act(), actual value: the policy was never reset")
        du = self.controller.step(
            self._outputs(qpos_measured), self._t, limits=(self._lo - self._u0, self._hi - self._u0)
        )
        self._last_t = self._t
        self._t += self.dt
        return self._u0 + du

    @property
    def diagnostics(self) -> ControlDiagnostics:
        """Estimated positions and velocities of every joint, identified disturbance, sliding variable (before the
        first :meth:`act`: the operating point at rest)."""
        if self._t is None:  # nothing estimated yet: the operating point, at rest, no disturbance
            m, nu = self.design.plant.n_unknown, len(self._u0)
            return ControlDiagnostics(0.0, self._q0.copy(), np.zeros(self._nv), np.zeros(m), np.zeros(nu))
        obs, nv = self.controller.observer, self._nv
        x = obs.x_hat
        q = self._q0.copy()
        q[:nv] += x[:nv]  # hinge/slide joints: qpos and qvel share addresses
        s = getattr(self.controller, "s", None)
        return ControlDiagnostics(
            t=self._last_t,
            qpos=q,
            qvel=x[nv : 2 * nv].copy(),
            disturbance=np.array(obs.w_hat, dtype=float),
            sliding=np.zeros(len(self._u0)) if s is None else np.array(s, dtype=float),
        )

    def __repr__(self) -> str:
        return f"LinearizedPolicy({self.name!r}, dt={self.dt}, joints={list(self.design.joints)})"


def sensor_noise(sensor, model, dofs) -> np.ndarray:
    """The sensor's error standard deviation per joint of ``dofs`` (``qvel`` addresses, hinge and slide joints:
    hinges read as angles, slides as lengths), shape ``(len(dofs),)`` (:meth:`smo_gym.sensors.Sensor.error_std`)."""
    from ..sensors import make_sensor

    mujoco = _mujoco()
    s = make_sensor(sensor)
    jnt = model.dof_jntid[dofs]
    angular = np.array([int(model.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_HINGE) for j in jnt])
    return s.error_std(len(dofs), angular)


def design(
    env,
    controller: str = "compensation",
    *,
    measured="positions",
    disturbance="actuated",
    disturbance_bound=None,
    disturbance_bandwidth: float = DISTURBANCE_BANDWIDTH,
    operating_point=None,
    sensor="encoder-12bit-noisy",
    Q=None,
    R=None,
    alpha: int = 2,
    regulated=None,
    t_start: float | None = None,
):
    r"""Design an output-feedback controller for a MuJoCo environment; return it as a policy.

    The recipe (each step a documented function of this module or of :mod:`smo_gym.control`):

    1. the operating point: ``operating_point`` (a ``qpos``; default the model's ``qpos0``) and the control that
       holds it at rest (:func:`equilibrium`);
    2. :func:`smo_gym.control.linearize` there, with the measured joints as outputs and the unknown input
       :math:`w` as generalized forces on the disturbance channels (``qfrc_applied``;
       :math:`D \approx [0;\ M(q_0)^{-1}E]`);
    3. for the sliding-mode controllers, the strong-observability check of :math:`(A, C, D)`: a system whose state
       cannot be recovered from the outputs whatever :math:`w` is, is refused with the failing condition
       (:class:`smo_gym.control.NotStronglyObservableError`);
    4. the state feedback: LQR for the sampled plant (:func:`smo_gym.control.sampled_lqr`) with
       :func:`default_weights` (or ``Q``, ``R``);
    5. the cascaded HOSM observer's differentiator bound from the disturbance bounds
       :math:`|w^{(i)}| \le W\omega^i` and the Luenberger stage's error, bounded by its exact peak-to-peak gain
       from the disturbance and the sensor's noise and quantization (:func:`differentiator_bound`), times
       :data:`SAFETY`.

    Parameters
    ----------
    env : gymnasium.Env
        A MuJoCo environment (any wrapper stack; its ``unwrapped`` has ``model`` and ``dt``) with hinge and slide
        joints only. The policy runs at ``env.unwrapped.dt``.
    controller : str
        ``"compensation"`` (:class:`CompensationController`: :math:`u = -K\hat x - B^+D\hat w`), ``"ism"``
        (:class:`IntegralSlidingModeController`, unit vector), ``"unmatched"``
        (:class:`UnmatchedCompensationController`), ``"lqr"`` (LQR on the cascaded observer's estimate), or the
        baselines ``"lqr-luenberger"``, ``"lqr-kalman"`` (:class:`KalmanObserver` with the same noise and disturbance
        bounds) and ``"pid"`` (:class:`PIDController`, on filtered finite-difference velocities).
        ``"computed-torque"`` returns :meth:`ComputedTorquePolicy.from_env` (no linearization; fully actuated
        models only) with ``operating_point`` as its target and ``disturbance_bound``; the other options are
        those of the linear designs.
    measured : "positions" or sequence of str
        The measured joints (default all).
    disturbance : "actuated", "joints" or sequence of str
        The joints the unknown input acts on: the actuated ones (a matched disturbance, default), all, or named.
    disturbance_bound : float, optional
        :math:`W`, bound on each disturbance force [N m or N]; default :data:`DISTURBANCE_FRACTION` of the
        actuators' largest force on those channels.
    disturbance_bandwidth : float
        :math:`\omega` [rad/s] in :math:`|w^{(i)}| \le W\omega^i`.
    operating_point : array_like, shape (nq,), optional
        The configuration to regulate to (default ``model.qpos0``).
    sensor : str or Sensor
        The sensor the measurements come from (its noise and quantization enter the gains).
    Q, R : array_like, optional
        LQR weights (default :func:`default_weights`).
    alpha : int
        Derivatives of ``w`` the cascaded observer exploits (identification error :math:`O(\tau^\alpha)`). The
        default 2 beats 1 with and without noise on the examples of ``scripts/bench_control.py``: the
        identification reads the differentiator's second-highest derivative instead of its highest, whose
        discretization and noise errors are the largest (:math:`O(L\tau)` and
        :math:`O(L^{2/3}\eta^{1/3})` for ``alpha = 1`` against :math:`O(L\tau^2)` and
        :math:`O(L^{1/2}\eta^{1/2})`).
    regulated : array_like, optional
        ``E`` of the unmatched controller (regulated output :math:`z = Ex`, ``EB = 0``).
    t_start : float, optional
        Time after which the identified disturbance and the sliding term are used (default ``max(0.05, 5 dt)``).

    Returns
    -------
    LinearizedPolicy or ComputedTorquePolicy
    """
    from .controllers import (
        CompensationController,
        IntegralSlidingModeController,
        StateFeedback,
        UnmatchedCompensationController,
        sampled_lqr,
    )
    from .estimators import CascadedHOSMObserver, LuenbergerObserver, sampled_observer_gain
    from .plants import linearize

    unwrapped = getattr(env, "unwrapped", env)
    model = getattr(unwrapped, "model", None)
    mujoco = _mujoco()
    if not isinstance(model, mujoco.MjModel):
        raise TypeError(
            f"expected a MuJoCo environment (env.unwrapped.model a mujoco.MjModel), actual value: "
            f"{type(unwrapped).__name__}"
        )
    choices = (*LINEAR_CONTROLLERS, "computed-torque")
    controller = check_choice("controller", controller, choices)
    dt = check_positive("env.unwrapped.dt", float(unwrapped.dt))
    if controller == "computed-torque":
        from .computed_torque import ComputedTorquePolicy

        # None: the policy's own default, qpos0 of the joints it measures (a joint coupled by an equality has none)
        target = None if operating_point is None else as_real_array("operating_point", operating_point)
        options = (
            {}
            if disturbance_bound is None
            else {"disturbance_bound": check_positive("disturbance_bound", disturbance_bound)}
        )
        return ComputedTorquePolicy.from_env(env, sensor=sensor, target=target, **options)
    alpha = check_int_in_range("alpha", alpha, 1, 4)
    op = equilibrium(model, operating_point)
    joints, out_adr, out_dofs = _joint_dofs(model, None if measured == "positions" else measured)
    d = mujoco.MjData(model)
    d.qpos[:] = op.qpos
    G, _ = actuator_map(model, d)
    dist_dofs = _disturbance_dofs(model, disturbance, G)
    nv = model.nv
    C = np.zeros((out_dofs.size, 2 * nv))
    C[np.arange(out_dofs.size), out_dofs] = 1.0
    plant = linearize(model, op.qpos, op.ctrl, C=C, force_dofs=dist_dofs)
    if controller in HOSM_CONTROLLERS:
        plant.require_strongly_observable()
    if disturbance_bound is None:
        umax = np.where(model.actuator_ctrllimited.astype(bool), np.abs(model.actuator_ctrlrange).max(axis=1), 1.0)
        force = np.abs(G[dist_dofs]) @ umax
        W = DISTURBANCE_FRACTION * float(force.max(initial=0.0) or 1.0)
    else:
        W = check_positive("disturbance_bound", disturbance_bound)
    omega = check_positive("disturbance_bandwidth", disturbance_bandwidth)
    w_bounds = tuple(W * omega**i for i in range(8))
    Qd, Rd = default_weights(model, op.qpos, G)
    Q = Qd if Q is None else np.asarray(Q, dtype=float)
    R = Rd if R is None else np.atleast_2d(np.asarray(R, dtype=float))
    K = sampled_lqr(plant, dt, Q, R)
    noise = sensor_noise(sensor, model, out_dofs)
    if controller == "lqr-kalman" and not np.all(noise > 0):
        # checked here, before any gain: KalmanObserver's own refusal names an argument design's caller never gave
        exact = [name for name, level in zip(joints, noise, strict=True) if not level > 0]
        raise ValueError(
            "expected a sensor with a random error on every measured joint for controller='lqr-kalman' (the "
            "Kalman gain weighs the samples by that error's variance, and an exact sample has none), actual "
            f"value: sensor {sensor!r} measures {exact} exactly; use a noisy sensor or 'lqr-luenberger'"
        )
    t_start = max(0.05, 5 * dt) if t_start is None else check_nonnegative("t_start", t_start)
    lipschitz = None
    if controller in HOSM_CONTROLLERS:
        n_w = 0
        if controller == "unmatched":
            n_w = 1
        order = plant.strong_observability().molinari.n_derivatives + n_w + alpha
        L_d = sampled_observer_gain(plant.A, plant.C, dt)
        lipschitz = SAFETY * differentiator_bound(plant, dt, L_d, order, w_bounds, 3.0 * noise)

        def cascade(n_w_derivatives=0):
            return CascadedHOSMObserver(plant, dt, lipschitz, alpha=alpha, n_w_derivatives=n_w_derivatives)

    rho_u = 1.5 * float(np.abs(np.linalg.pinv(plant.B) @ plant.D).sum(axis=1).max() * W)
    if controller == "compensation":
        ctl = CompensationController(cascade(), K, t_start=t_start)
    elif controller == "ism":
        ctl = IntegralSlidingModeController(cascade(), K, rho=rho_u, t_start=t_start)
    elif controller == "unmatched":
        ctl = UnmatchedCompensationController(cascade(1), rho=rho_u, regulated=regulated, t_start=t_start)
    elif controller == "lqr":
        ctl = StateFeedback(cascade(), K)
    elif controller == "lqr-luenberger":
        ctl = StateFeedback(LuenbergerObserver(plant, dt), K)
    elif controller == "lqr-kalman":
        from .baselines import KalmanObserver

        # w as white noise of the same power: an RMS W/sqrt(2) correlated over 1/omega has the density W^2/omega
        ctl = StateFeedback(KalmanObserver(plant, dt, noise_std=noise, disturbance_std=W / np.sqrt(omega)), K)
    else:  # "pid"
        from .baselines import PIDController, default_integral_outputs

        Qi = np.eye(len(default_integral_outputs(plant))) / (POSITION_SCALE * INTEGRAL_TIME) ** 2
        ctl = PIDController(plant, dt, Q=Q, R=R, Qi=Qi, derivative_filter=DERIVATIVE_FILTER)
    record = LinearDesign(plant, op, joints, dist_dofs, K, Q, R, lipschitz, w_bounds, noise)
    return LinearizedPolicy(ctl, record, dt, controller, model, out_adr)
