r"""Wrapper integration of the observers that take the control input, built from the environment's model or runs.

With ``observer="mechanical-super-twisting"`` (:class:`~smo_gym.observers.MechanicalSuperTwisting`),
``"dissipative-super-twisting"`` (:class:`~smo_gym.observers.DissipativeSuperTwisting`) or ``"kalman-ca-input"``
(:class:`~smo_gym.observers.KalmanCAInput`), :class:`smo_gym.wrappers.EstimatedVelocity` builds the observer here
(:func:`model_based_observer`); its input at each sample is the ``ctrl`` that acted over the sample interval (the
action). The first two run a :class:`smo_gym.mechanics.MujocoDynamics` on a private copy of the environment's model
(optionally with a deliberate mass mismatch, fixed or drawn per episode); external forces (``qfrc_applied``,
``xfrc_applied``) are what their disturbance estimate (``observer.external_torque``) recovers. The Kalman filter's
input gain is fitted (:func:`~smo_gym.observers.fit_input_jumps`) on episodes of a copy of the environment under the
uniform and the low-passed random actions of ``"auto"``'s trials.

Default gains: the disturbance bound ``L`` of each joint is ``safety * quantile(|dv/dt - f(q, v, u)|)`` per physics
step over random-action episodes of a copy of the environment, with its resets and terminations (what the model
misses where the environment goes; contacts too with ``contact="unknown"``; for a range of mass scales, the larger
miss of its two ends; else on :func:`~smo_gym.mechanics.calibrate_model_miss`), and the model term is saturated at
``safety * quantile(|dv/dt|)`` (Wetzlinger et al., eq. (33)). With ``rate="env"`` the model is integrated over
the ``frame_skip`` physics steps of a sample (``model_substeps``): the cost per physics step of ``rate="physics"``.

Limitations: hinge and slide joints only (``MujocoDynamics`` refuses free and ball joints), no joint-equality
couplings (use the observers directly on such models, as ``scripts/plot_coriolis_transform.py`` does), no vector
wrappers (they refuse these names, ``"auto"`` with a model, observers taking the input), no single-turn angle sensors.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._validation import check_scale_range
from ..calibration import NOISE_FLOOR
from ..engine.measurement import VelocityEstimator, mean_velocity_span
from ..mechanics import MASS_SCALE_RANGE, MujocoDynamics, calibrate_model_miss, default_transform, dissipative_gains
from ..observers import MODEL_BASED_OBSERVERS, DissipativeSuperTwisting, MechanicalSuperTwisting, Observer
from ..observers.input_kalman import InputJumpFilter
from ..specs import MODEL_OPTIONS
from .estimated_velocity import TRIAL_SMOOTHING, JointCandidate, random_episodes

__all__ = ["InputAwareEstimator", "ModelBasedObserver", "joint_candidate", "model_based_observer"]

INPUT_FILTERS = {n: cls for n, cls in MODEL_BASED_OBSERVERS.items() if issubclass(cls, InputJumpFilter)}
NAMES = ("mechanical-super-twisting", "dissipative-super-twisting", *INPUT_FILTERS)


class InputAwareEstimator(VelocityEstimator):
    """A :class:`VelocityEstimator` that passes the simulation's current ``ctrl`` to ``observer.update(z, u)``."""

    def __init__(self, observer, adapter):
        super().__init__(observer, mean_over=mean_velocity_span(adapter.model))
        self.adapter = adapter

    def update(self, z: np.ndarray) -> np.ndarray:
        return self.velocity_of(self.observer.update(z, self.adapter.data.ctrl.copy()))


class ModelBasedObserver(NamedTuple):
    """What :func:`model_based_observer` builds: the observer, the calibrated bound of its model miss per dof (None
    for given gains) and the range each reset draws its mass scale from (None for a fixed one)."""

    observer: Observer
    model_miss_bound: np.ndarray | None
    mass_scale_range: tuple[float, float] | None


def model_based_observer(
    name: str,
    adapter,
    measurement,
    observer_kwargs: dict | None = None,
    calibration_steps: int = 2000,
    calibration_quantile: float = 0.99,
    calibration_safety: float = 2.0,
) -> ModelBasedObserver:
    r"""An observer that takes the input, with a private copy of the environment's model or a fitted input gain.

    Parameters
    ----------
    name : {"mechanical-super-twisting", "dissipative-super-twisting"} or a name of :data:`INPUT_FILTERS`
    adapter : smo_gym.wrappers.adapters.MujocoAdapter
        The environment's adapter (its model is copied, never modified).
    measurement : smo_gym.engine.measurement.JointMeasurement
        The wrapper's: its step (physics steps per sample) and, for ``"kalman-ca-input"``, its noise.
    observer_kwargs : dict, optional
        The observer's model settings, ``mass_scale`` (a number: every mass and inertia scaled; a pair
        ``(low, high)``: a scale drawn per episode by the wrapper, the model starting at the midpoint) and
        ``contact`` (``"unknown"`` or ``"measured"``, see :mod:`smo_gym.mechanics.dynamics`); and constructor
        arguments of the observer overriding the calibrated defaults (``lipschitz``, ``accel_bound``,
        ``model_substeps``, ``disturbance_time_constant``, ...; for the dissipative observer ``transform`` and
        ``gains``); for ``"kalman-ca-input"`` constructor arguments only (``huber``, ``initial_std``, ...).
    calibration_steps, calibration_quantile, calibration_safety :
        Default gains (module notes).

    Notes
    -----
    For ``"dissipative-super-twisting"`` the transform and gains are :func:`smo_gym.mechanics.default_transform`
    and :func:`smo_gym.mechanics.dissipative_gains` with :math:`L_w` the calibrated bound.
    """
    if name not in NAMES:
        raise ValueError(f"expected observer in {', '.join(NAMES)}, actual value: {name!r}")
    model, kwargs = adapter.model, dict(observer_kwargs or {})
    sample_every, dt = round(measurement.dt / model.opt.timestep), measurement.dt
    if name in INPUT_FILTERS:  # the input gain from the two scenarios of auto's trials
        found = [random_episodes(adapter, sample_every, calibration_steps, smoothing=s) or () for s in TRIAL_SMOOTHING]
        episodes = [e for scene in found for e in scene if len(e.qvel) > 2 and np.isfinite(e.qvel).all()]
        r = np.maximum(measurement.noise_std() ** 2 + measurement.quantization_step() ** 2 / 12, NOISE_FLOOR**2)
        velocity, inputs = [e.qvel for e in episodes], [e.ctrl for e in episodes]
        return ModelBasedObserver(INPUT_FILTERS[name].from_episodes(dt, velocity, inputs, r, **kwargs), None, None)
    low, high = check_scale_range("mass_scale", kwargs.pop("mass_scale", 1.0), MASS_SCALE_RANGE)
    dyn = MujocoDynamics(model, mass_scale=0.5 * (low + high), contact=kwargs.pop("contact", "unknown"))
    if dyn.n != model.nv:
        raise ValueError(
            f"expected a model without joint-equality couplings (every dof measured), actual value: {dyn.n} "
            f"independent coordinates for nv={model.nv}; use the observers directly on such models"
        )
    needs_bounds = "lipschitz" not in kwargs and not ("k1" in kwargs and "k2" in kwargs)
    miss_bound = None
    if needs_bounds or "accel_bound" not in kwargs:
        miss, acc = _model_miss(adapter, dyn, sorted({low, high}), calibration_steps, calibration_quantile)
        dyn.set_mass_scale(0.5 * (low + high))
        floor = 1e-3 * max(float(acc.max()), 1.0)
        miss_bound = calibration_safety * np.maximum(miss, floor)
        kwargs.setdefault("accel_bound", calibration_safety * np.maximum(acc, floor))
    if name == "mechanical-super-twisting":
        if needs_bounds:
            kwargs["lipschitz"] = miss_bound
        kwargs.setdefault("model_substeps", sample_every)
        obs = MechanicalSuperTwisting(dt, dyn, **kwargs)
    else:
        transform = kwargs.pop("transform", None) or default_transform(dyn)
        gains = kwargs.pop("gains", None)
        if gains is None:
            L = miss_bound if needs_bounds else np.broadcast_to(kwargs.pop("lipschitz"), (dyn.n,))
            gains = dissipative_gains(dyn, transform, L)
        kwargs.pop("lipschitz", None)
        obs = DissipativeSuperTwisting(dt, dyn, transform, gains, **kwargs)
    return ModelBasedObserver(obs, miss_bound, None if low == high else (low, high))


def joint_candidate(adapter, measurement, observer_kwargs: dict, *how) -> tuple:
    """``observer="auto"`` with ``observer_kwargs["model"]`` (True: ``"mechanical-super-twisting"``, or a name of
    :data:`NAMES`): ``(JointCandidate, ModelBasedObserver, the other kwargs)``, built by
    :func:`model_based_observer` (``how``: its calibration arguments) with the model settings among the kwargs."""
    kwargs = dict(observer_kwargs)
    name = kwargs.pop("model")
    name = "mechanical-super-twisting" if name is True else name
    settings = {k: kwargs.pop(k) for k in MODEL_OPTIONS if k in kwargs}
    built = model_based_observer(name, adapter, measurement, settings, *how)
    return JointCandidate(built.observer, (name, settings)), built, kwargs


def _model_miss(adapter, dyn: MujocoDynamics, scales, steps: int, quantile: float) -> tuple[np.ndarray, np.ndarray]:
    """``quantile`` of the model miss per dof, the largest over the mass ``scales``, and of the acceleration."""
    h, dof = adapter.model.opt.timestep, dyn.dof
    episodes = [e for e in random_episodes(adapter, 1, steps) or () if len(e.qvel) > 1 and np.isfinite(e.qvel).all()]
    misses = []
    for scale in scales:
        dyn.set_mass_scale(scale)
        if not episodes:
            miss, acc = calibrate_model_miss(adapter.model, dyn, adapter.frame_skip, steps=steps, quantile=quantile)
        else:  # the ctrl of each physics step is on the row of the sample it ends at
            A = np.concatenate([np.diff(e.qvel[:, dof], axis=0) / h for e in episodes])
            f = np.concatenate([dyn.acceleration(e.qpos[:-1, dof], e.qvel[:-1, dof], e.ctrl[1:]) for e in episodes])
            miss, acc = np.quantile(np.abs(A - f), quantile, axis=0), np.quantile(np.abs(A), quantile, axis=0)
        misses.append(miss)
    return np.max(misses, axis=0), acc
