r"""Wrapper integration of the model-based observers: the dynamics are built from the environment's own model.

:class:`ModelBasedEstimatedVelocity` is :class:`smo_gym.wrappers.EstimatedVelocity` with a
:class:`smo_gym.observers.MechanicalSuperTwisting` (``observer="mechanical-super-twisting"``) or
:class:`smo_gym.observers.DissipativeSuperTwisting` (``observer="dissipative-super-twisting"``) whose dynamics
object is a :class:`smo_gym.mechanics.MujocoDynamics` on a private copy of ``env.unwrapped.model`` (optionally with
a deliberate mass mismatch), and whose input at each sample is the ``ctrl`` that acted over the sample interval
(read from the simulation, i.e. the action). External forces (``qfrc_applied``, ``xfrc_applied``) are not given
to the observer: they are what its disturbance estimate (``wrapper.observer.external_torque``) recovers.

Default gains: the disturbance bound ``L`` of each joint is ``safety * quantile(|dv/dt - f(q, v, u)|)`` over a
calibration rollout of the model itself with random actions (what the model misses, contacts included when
``contact="unknown"``), and the model term is saturated at ``safety * quantile(|dv/dt|)`` (Wetzlinger et al., eq. (33)).
With ``rate="env"`` the model is integrated over the ``frame_skip`` physics steps of a sample
(``model_substeps``), so the cost per physics step is that of the physics-rate observer.

Limitations: hinge and slide joints only (free/ball joints raise ``ValueError`` from ``MujocoDynamics``), and no
joint-equality couplings (the wrapper measures every joint; use the observers directly on such models, as
``scripts/plot_coriolis_transform.py`` does on ``VariableInertia-v0``).
"""

from __future__ import annotations

import numpy as np

from .. import design
from ..engine.measurement import VelocityEstimator
from ..mechanics import MujocoDynamics
from ..observers import CoordinateTransform, DissipativeSuperTwisting, MechanicalSuperTwisting
from .estimated_velocity import EstimatedVelocity, resolve_rate

__all__ = ["InputAwareEstimator", "ModelBasedEstimatedVelocity", "calibrate_model_miss"]

NAMES = ("mechanical-super-twisting", "dissipative-super-twisting")


class InputAwareEstimator(VelocityEstimator):
    """A :class:`VelocityEstimator` that passes the simulation's current ``ctrl`` to ``observer.update(z, u)``."""

    def __init__(self, observer, adapter):
        super().__init__(observer)
        self.adapter = adapter

    def update(self, z: np.ndarray) -> np.ndarray:
        return self.observer.update(z, self.adapter.data.ctrl.copy())[..., 1]


def calibrate_model_miss(
    model, dynamics: MujocoDynamics, frame_skip: int, *, steps: int = 2000, quantile: float = 0.99, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    r"""Quantiles of the model miss :math:`|\Delta v/h - f(q, v, u)|` and of :math:`|\Delta v/h|` per dof.

    Rollout of ``steps`` physics steps of ``model`` (its own ``MjData``, from ``qpos0`` plus small noise) with
    uniform random controls held for ``frame_skip`` steps; restarts when the state becomes non-finite.
    """
    import mujoco

    data = mujoco.MjData(model)
    rng = np.random.default_rng(seed)
    lo, hi = model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1]
    limited = model.actuator_ctrllimited.astype(bool)
    lo = np.where(limited, lo, -1.0)
    hi = np.where(limited, hi, 1.0)
    h = model.opt.timestep
    miss, acc = [], []
    data.qpos[:] = model.qpos0 + rng.uniform(-0.01, 0.01, model.nq)
    u = np.zeros(model.nu)
    for k in range(steps):
        if k % frame_skip == 0:
            u = rng.uniform(lo, hi)
        q, v = data.qpos.copy(), data.qvel.copy()
        f = dynamics.acceleration(q[dynamics.dof], v[dynamics.dof], u)
        data.ctrl[:] = u
        mujoco.mj_step(model, data)
        if not (np.all(np.isfinite(data.qpos)) and np.all(np.isfinite(data.qvel))):
            mujoco.mj_resetData(model, data)
            continue
        a = (data.qvel[dynamics.dof] - v[dynamics.dof]) / h
        miss.append(np.abs(a - f))
        acc.append(np.abs(a))
    return np.quantile(np.array(miss), quantile, axis=0), np.quantile(np.array(acc), quantile, axis=0)


class ModelBasedEstimatedVelocity(EstimatedVelocity):
    r"""``EstimatedVelocity`` with a model-based observer built from the environment's own MuJoCo model.

    Parameters
    ----------
    env, sensor, rate :
        As :class:`smo_gym.wrappers.EstimatedVelocity`.
    observer : {"mechanical-super-twisting", "dissipative-super-twisting"}
    observer_kwargs : dict, optional
        Constructor arguments of the observer overriding the calibrated defaults (``lipschitz``,
        ``accel_bound``, ``model_substeps``, ``disturbance_time_constant``, ...; for the dissipative observer
        ``transform`` and ``gains`` may be given).
    mass_scale : float
        Model mismatch of the observer's private model (all masses and inertias scaled).
    contact : {"unknown", "measured"}
        How the observer's model treats contacts (see :mod:`smo_gym.mechanics.dynamics`).
    calibration_steps, calibration_quantile, calibration_safety :
        Default gains (module docstring).
    **wrapper_kwargs :
        Passed to :class:`EstimatedVelocity` (``positions``, ``contact_forces``, ``disk_cache``).

    Notes
    -----
    For ``"dissipative-super-twisting"`` each joint gets the transform of its self-quadratic term
    (:meth:`MujocoDynamics.alpha_function` at ``qpos0``) over its range (``jnt_range`` if limited, else
    ``+-pi``), and gains from :func:`smo_gym.design.apaza_gains` with :math:`L_w` the calibrated bound and the
    dissipativity of the joint damping, :math:`(q, s, r) = (-1, -c/2, 0)`, :math:`c = \max d_i / M_{ii}`.
    """

    def __init__(
        self,
        env,
        sensor="encoder-12bit-noisy",
        observer: str = "mechanical-super-twisting",
        rate="physics",
        observer_kwargs: dict | None = None,
        *,
        mass_scale=1.0,
        contact: str = "unknown",
        calibration_steps: int = 2000,
        calibration_quantile: float = 0.99,
        calibration_safety: float = 2.0,
        **wrapper_kwargs,
    ):
        if observer not in NAMES:
            raise ValueError(f"expected observer in {', '.join(NAMES)}, actual value: {observer!r}")
        unwrapped = env.unwrapped
        model = unwrapped.model
        frame_skip = int(unwrapped.frame_skip)
        sample_every = resolve_rate(rate, frame_skip)
        dt = float(model.opt.timestep) * sample_every
        dyn = MujocoDynamics(model, mass_scale=mass_scale, contact=contact)
        if dyn.n != model.nv:
            raise ValueError(
                f"expected a model without joint-equality couplings (every dof measured), actual value: {dyn.n} "
                f"independent coordinates for nv={model.nv}; use the observers directly on such models"
            )
        kwargs = dict(observer_kwargs or {})
        needs_bounds = "lipschitz" not in kwargs and not ("k1" in kwargs and "k2" in kwargs)
        if needs_bounds or "accel_bound" not in kwargs:
            miss, acc = calibrate_model_miss(
                model, dyn, frame_skip, steps=calibration_steps, quantile=calibration_quantile
            )
            floor = 1e-3 * max(float(acc.max()), 1.0)
            self.model_miss_bound = calibration_safety * np.maximum(miss, floor)
            kwargs.setdefault("accel_bound", calibration_safety * np.maximum(acc, floor))
        else:
            self.model_miss_bound = None
        if observer == "mechanical-super-twisting":
            if needs_bounds:
                kwargs["lipschitz"] = self.model_miss_bound
            kwargs.setdefault("model_substeps", sample_every)
            obs = MechanicalSuperTwisting(dt, dyn, **kwargs)
        else:
            transform = kwargs.pop("transform", None) or self._default_transform(model, dyn)
            gains = kwargs.pop("gains", None)
            if gains is None:
                L = self.model_miss_bound if needs_bounds else np.broadcast_to(kwargs.pop("lipschitz"), (dyn.n,))
                gains = self._default_gains(model, dyn, transform, L)
            kwargs.pop("lipschitz", None)
            obs = DissipativeSuperTwisting(dt, dyn, transform, gains, **kwargs)
        super().__init__(env, sensor, obs, rate, None, **wrapper_kwargs)
        self.estimator = InputAwareEstimator(self.observer, self.adapter)

    @staticmethod
    def _default_transform(model, dyn: MujocoDynamics) -> CoordinateTransform:
        jid = [model.dof_jntid[d] for d in dyn.dof]
        lower = np.array([model.jnt_range[j, 0] if model.jnt_limited[j] else -np.pi for j in jid])
        upper = np.array([model.jnt_range[j, 1] if model.jnt_limited[j] else np.pi for j in jid])
        ref = np.clip(model.qpos0[dyn.dof], lower, upper)
        return CoordinateTransform(dyn.alpha_function(), lower, upper, reference=ref, grid=201)

    @staticmethod
    def _default_gains(model, dyn: MujocoDynamics, transform: CoordinateTransform, L: np.ndarray) -> dict:
        ref = model.qpos0[dyn.dof].copy()
        rows = []
        for i in range(dyn.n):
            ys = transform.grid_y[:, i]
            Mii = []
            for y in ys[:: max(1, len(ys) // 20)]:
                q = ref.copy()
                q[i] = y
                Mii.append(dyn.inertia(q)[i, i])
            c = float(dyn.model.dof_damping[dyn.dof[i]]) / min(Mii)
            g = design.apaza_gains(
                float(L[i]), q=-1.0, s=-c / 2.0, r=0.0, upsilon_max=max(1.0, float(transform.grid_upsilon[:, i].max()))
            )
            rows.append(g.as_dict())
        return {key: np.array([r[key] for r in rows]) for key in ("k1", "k2", "k3", "mu1", "mu2")}
