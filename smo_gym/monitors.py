r"""Online monitors of a sensed system: identified parameters and fault flags from measured positions and inputs.

A *monitor* is a stateful object with

* ``reset(q_measured) -> record`` at the first sample of an episode, and
* ``update(q_measured, ctrl) -> record`` at every following sample, ``ctrl`` the input that acted over the sample
  interval ending at ``q_measured``,

whose record is a flat ``dict`` of NumPy arrays, numbers and strings (what Gymnasium's vector environments
aggregate per key). It sees what a controller sees, never a simulator's true state, so the same object serves a
simulation (:class:`smo_gym.wrappers.Monitored` writes its record into ``info``), a logged record and a real plant.

* :class:`ParameterMonitor`: online parameter identification by the equivalent output injection of a super-twisting
  observer (:class:`smo_gym.identification.EquivalentInjectionIdentifier`, Davila, Fridman and Levant 2005);
  :meth:`ParameterMonitor.from_mujoco` builds it for MuJoCo model parameters (a payload mass, a joint's damping;
  :class:`smo_gym.mechanics.MujocoParameterRegressor`).
* :class:`ModeMonitor`: the discrete mode of a switched system and its switching instants, by the bank of cascaded
  HOSM observers of :class:`smo_gym.control.SwitchedObserverBank` (Davila, Rios and Fridman 2012; Rios et al.
  2012, 2014), run online.
* :class:`FaultMonitor`: fault detection and isolation by a bank of observers
  (:class:`smo_gym.fault_detection.FaultObserverBank`, Rios, Davila, Fridman and Edwards 2014), with the decision
  rule of :func:`smo_gym.fault_detection.diagnose` applied online: the flags at a sample are those that
  ``diagnose`` gives on the record up to that sample.

A monitor may also state what it was built for, as optional attributes (absent or None: unknown), which
:class:`smo_gym.wrappers.Monitored` checks against the environment before anything runs (:func:`check_monitor`):

* ``dt``: the interval between its samples [s], one environment step (``frame_skip`` physics steps);
* ``nq``: the length of ``q_measured`` (the model's ``nq``);
* ``n_ctrl``: the length of ``ctrl`` (the model's ``nu``).

The library's monitors define those they know: ``dt`` all three, ``nq`` :class:`ParameterMonitor` and
:class:`FaultMonitor`, ``n_ctrl`` :class:`ModeMonitor` and a :class:`ParameterMonitor` given one.

Why a wrapper of its own (:class:`smo_gym.wrappers.Monitored`) rather than an option of the model-based velocity
observer: a monitor needs only the sensor's reading and the input, not the velocity observer, so it serves every
observer family and sensor; one wrapper per monitor composes (a parameter monitor and a fault monitor stacked, each
under its own ``info`` key); and the maths stays here, free of Gymnasium, testable on arrays and usable on logged
data. The wrapper reads ``info["smo"]["qpos_measured"]`` of the :class:`~smo_gym.wrappers.EstimatedVelocity` below
it and, at each step, the ``ctrl`` of the simulation through that wrapper's adapter (its ``adapter`` attribute):
the input after any action transformation of the stack.

References
----------
.. [DFL05] J. Davila, L. Fridman and A. Levant, "Second-order sliding-mode observer for mechanical systems",
   IEEE TAC 50(11), 2005.
.. [RDFE14] H. Rios, J. Davila, L. Fridman and C. Edwards, "Fault detection and isolation for nonlinear systems via
   high-order-sliding-mode multiple-observer", International Journal of Robust and Nonlinear Control, 2014.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ._validation import DivergenceError, _short, as_real_array, check_int_at_least
from .fault_detection import UNKNOWN, FaultObserverBank, diagnose
from .identification import EquivalentInjectionIdentifier

__all__ = ["FaultMonitor", "ModeMonitor", "ParameterMonitor", "check_monitor", "measured"]


def measured(info, key: str | None = None) -> np.ndarray:
    """``info["smo"]["qpos_measured"]`` (the sensor's reading, :class:`smo_gym.wrappers.sensing.SensingInfo`),
    with a typed error naming what is missing. Given ``key`` (where a monitor's record is to go), an ``info`` that
    already has that entry is refused: the record would overwrite the environment's own, without a word."""
    if isinstance(info, dict) and key is not None and key in info:
        raise ValueError(
            f"expected an info without the monitor's key {key!r} (the record would replace the environment's "
            f"entry: choose another key), actual value: info keys {sorted(info)}"
        )
    sensing = info.get("smo") if isinstance(info, dict) else None
    if not isinstance(sensing, dict) or "qpos_measured" not in sensing:
        raise ValueError(
            "expected info['smo']['qpos_measured'] (an EstimatedVelocity wrapper below this one), actual value: "
            f"info keys {sorted(info) if isinstance(info, dict) else type(info).__name__}"
        )
    return sensing["qpos_measured"]


def check_monitor(monitor, key: str, adapter=None):
    """Check that ``monitor`` has ``reset`` and ``update`` and that ``key`` is a non-empty string; return it.

    With ``adapter`` (a :class:`~smo_gym.wrappers.adapters.MujocoAdapter`: ``model`` and ``frame_skip``), the
    monitor's ``dt``, ``nq`` and ``n_ctrl`` (those of the protocol it has, module docstring) must be the
    environment step ``frame_skip * model.opt.timestep``, ``model.nq`` and ``model.nu``: a monitor built for
    another step or model is refused before a reset or a step moves the simulation.
    """
    if not (callable(getattr(monitor, "reset", None)) and callable(getattr(monitor, "update", None))):
        raise TypeError(
            f"expected a monitor with reset(q_measured) and update(q_measured, ctrl), actual value: "
            f"{type(monitor).__name__}"
        )
    if not isinstance(key, str):
        raise TypeError(f"expected key as a string, actual value: {type(key).__name__}")
    if not key or key == "smo":
        raise ValueError(f"expected key as a non-empty string other than 'smo', actual value: {key!r}")
    if adapter is None:
        return monitor
    model = adapter.model
    step = adapter.frame_skip * float(model.opt.timestep)
    # optional attributes of the protocol: a duck-typed monitor (reset and update only) is not checked
    dt, nq, n_ctrl = (getattr(monitor, name, None) for name in ("dt", "nq", "n_ctrl"))
    if dt is not None and not np.isclose(dt, step, rtol=1e-9, atol=0.0):
        raise ValueError(
            f"expected a monitor with dt equal to the environment step {step} (frame_skip {adapter.frame_skip} x "
            f"timestep {model.opt.timestep}), actual value: {dt}"
        )
    for name, own, env_size in (("nq", nq, model.nq), ("n_ctrl", n_ctrl, model.nu)):
        if own is not None and own != env_size:
            raise ValueError(f"expected a monitor with {name} = {env_size} (the model's), actual value: {own}")
    return monitor


def _vector(name: str, value, n: int) -> np.ndarray:
    """A finite float array of shape ``(n,)`` (a copy)."""
    arr = as_real_array(name, value, copy=True)
    if arr.shape != (n,) or not np.isfinite(arr).all():
        raise ValueError(f"expected a finite {name} of shape ({n},), actual value: {arr!r}")
    return arr


def _broadcast(name: str, value, n: int) -> np.ndarray:
    """A real scalar or array broadcast to ``(n,)`` (a worded error otherwise)."""
    arr = as_real_array(name, value)
    try:
        return np.broadcast_to(arr, (n,))
    except ValueError:
        raise ValueError(f"expected {name} of shape () or ({n},), actual value: shape {arr.shape}") from None


def _indices(name: str, value, n: int) -> np.ndarray:
    """``n`` non-negative integer indices (not bools, not floats)."""
    arr = np.asarray(value)
    if arr.dtype.kind not in "iu" or arr.ndim != 1 or arr.shape != (n,) or np.any(arr < 0):
        raise ValueError(f"expected {n} non-negative integer indices as {name}, actual value: {_short(value)}")
    return arr.astype(np.intp)


class _TimeInvariant:
    """``nominal(t, q, v, u)`` of a dynamics object's ``acceleration(q, v, u)`` (a class, not a lambda: picklable)."""

    def __init__(self, dynamics):
        self.dynamics = dynamics

    def __call__(self, t, q, v, u):
        return self.dynamics.acceleration(q, v, u)


class ParameterMonitor:
    r"""Identified parameters :math:`\hat\theta` and the least-squares gain :math:`\Gamma`, sample by sample.

    Parameters
    ----------
    identifier : smo_gym.identification.EquivalentInjectionIdentifier
        Unbatched (its state is reset by this monitor at :meth:`reset`).
    names : sequence of str, optional
        Names of the ``p`` parameters (default ``theta0``, ``theta1``, ...).
    n_ctrl : int, optional
        Expected length of ``ctrl`` (checked when given).

    Notes
    -----
    The record of :meth:`reset` and :meth:`update`:

    ================  =========  ==================================================================================
    key               shape      what
    ================  =========  ==================================================================================
    ``theta``         ``(p,)``   :math:`\hat\theta = \bar\theta + \hat\vartheta` (at reset: :math:`\bar\theta`)
    ``gamma_diag``    ``(p,)``   diagonal of :math:`\Gamma` (for dynamic least squares :math:`\sigma^2\Gamma` is
                                 the covariance of the estimate under white injection noise of variance
                                 :math:`\sigma^2`; it stays at :math:`\gamma_0` in unexcited directions)
    ``time``          ``()``     time since the reset [s]
    ================  =========  ==================================================================================
    """

    def __init__(self, identifier: EquivalentInjectionIdentifier, *, names: Sequence[str] | None = None, n_ctrl=None):
        if not isinstance(identifier, EquivalentInjectionIdentifier):
            raise TypeError(f"expected an EquivalentInjectionIdentifier, actual value: {type(identifier).__name__}")
        self.identifier = identifier
        self.names = tuple(f"theta{i}" for i in range(identifier.p)) if names is None else tuple(map(str, names))
        if len(self.names) != identifier.p:
            raise ValueError(f"expected {identifier.p} parameter names, actual value: {len(self.names)}")
        self.n_ctrl = None if n_ctrl is None else check_int_at_least("n_ctrl", n_ctrl, 0)
        self._started = False

    @classmethod
    def from_mujoco(
        cls,
        model,
        parameters: Sequence[tuple[str, str]],
        dt: float,
        *,
        lipschitz,
        gamma0: float = 1e3,
        forgetting=None,
        filter_time_constant: float = 0.02,
        observer_options: dict | None = None,
    ) -> ParameterMonitor:
        r"""Identify MuJoCo model parameters (``("body_mass", body)``, ``("dof_damping", joint)``) of ``model``.

        ``model`` is the *nominal* model (copied: :class:`smo_gym.mechanics.MujocoDynamics` gives :math:`\bar f`,
        :class:`smo_gym.mechanics.MujocoParameterRegressor` gives :math:`\Phi` and :math:`\bar\theta`); ``dt`` the
        sampling step (an environment's ``dt``); the other arguments are those of
        :class:`~smo_gym.identification.EquivalentInjectionIdentifier` (``uses_acceleration=True``: a mass enters
        the inertia).
        """
        from .mechanics import MujocoDynamics, MujocoParameterRegressor  # mujoco only when asked for

        regressor = MujocoParameterRegressor(model, parameters)
        identifier = EquivalentInjectionIdentifier(
            dt,
            _TimeInvariant(MujocoDynamics(model)),
            regressor,
            regressor.theta_bar,
            n=regressor.n,
            lipschitz=lipschitz,
            gamma0=gamma0,
            forgetting=forgetting,
            filter_time_constant=filter_time_constant,
            uses_acceleration=True,
            observer_options=observer_options,
        )
        return cls(identifier, names=[f"{kind}:{name}" for kind, name in regressor.names], n_ctrl=model.nu)

    @property
    def dt(self) -> float:
        """The identifier's sampling step [s]."""
        return self.identifier.dt

    @property
    def nq(self) -> int:
        """The length of ``q_measured``: the identifier's ``n``."""
        return self.identifier.n

    def _record(self) -> dict:
        ident = self.identifier
        gain = ident.gain
        return {"theta": ident.theta, "gamma_diag": np.diagonal(gain).copy(), "time": float(ident.time)}

    def reset(self, q_measured) -> dict:
        """Restart at the measurement ``q_measured`` (shape ``(n,)``): estimate :math:`\\bar\\theta`,
        :math:`\\Gamma = \\gamma_0 I`, velocity estimate zero, time 0."""
        self.identifier.reset(_vector("q_measured", q_measured, self.identifier.n))
        self._started = True
        return self._record()

    def update(self, q_measured, ctrl) -> dict:
        """One sample: the measurement ``q_measured`` ``(n,)`` and the ``ctrl`` that acted over the interval."""
        if not self._started:
            raise RuntimeError("expected reset(q_measured) before update(...), actual value: never reset")
        q = _vector("q_measured", q_measured, self.identifier.n)
        u = as_real_array("ctrl", ctrl, copy=True)
        if u.ndim != 1 or (self.n_ctrl is not None and u.shape != (self.n_ctrl,)) or not np.isfinite(u).all():
            raise ValueError(f"expected a finite ctrl of shape ({self.n_ctrl or 'nu'},), actual value: {u!r}")
        self.identifier.update(q, u)
        return self._record()


class FaultMonitor:
    r"""Fault detection and isolation flags, sample by sample, from a bank of observers.

    Parameters
    ----------
    bank : smo_gym.fault_detection.FaultObserverBank
        Unbatched; its ``dwell`` and ``settle_time`` set the decision (:func:`smo_gym.fault_detection.diagnose`).

    Notes
    -----
    The record of :meth:`reset` and :meth:`update` (times from the reset sample, which is time 0):

    ====================  ==========  ==============================================================================
    key                   shape       what
    ====================  ==========  ==============================================================================
    ``detected``          ``()``      bool: the nominal residual left the band after ``settle_time``
    ``detection_time``    ``()``      time of detection [s], NaN before
    ``isolated``          ``()``      int: ``i >= 1`` fault ``i`` of the bank, ``0`` none detected, ``-1`` unknown
    ``isolated_name``     str         ``"no fault"``, the fault's name or ``"unknown"``
    ``isolation_time``    ``()``      time of the standing isolation [s], NaN without one
    ``residual_norms``    ``(q+1,)``  :math:`\rho_i = \max_j |r_{i,j}|/\theta_j` of each model (band: ``<= 1``)
    ``time``              ``()``      time since the reset [s]
    ====================  ==========  ==============================================================================

    The flags at sample ``k`` equal those of ``diagnose`` on the residuals up to ``k`` (an isolation can be
    revoked when the matching model's residual leaves the band). Cost: constant per sample until detection and while
    an isolation stands; otherwise ``diagnose`` on the samples since detection (linear in their number).
    """

    def __init__(self, bank: FaultObserverBank):
        if not isinstance(bank, FaultObserverBank):
            raise TypeError(f"expected a FaultObserverBank, actual value: {type(bank).__name__}")
        self.bank = bank
        self._rho: list[np.ndarray] | None = None

    @property
    def names(self) -> tuple[str, ...]:
        """``("nominal", *fault names)``."""
        return self.bank.names

    @property
    def dt(self) -> float:
        """The bank's sampling step [s]."""
        return self.bank.dt

    @property
    def nq(self) -> int:
        """The length of ``q_measured``: the bank's ``n``."""
        return self.bank.n

    def reset(self, q_measured) -> dict:
        """Restart every observer at ``q_measured`` (shape ``(n,)``) and clear the flags."""
        self.bank.reset(_vector("q_measured", q_measured, self.bank.n))
        self._rho = [np.zeros(self.bank.q + 1)]  # the reset sample: in the band by construction (as bank.diagnose)
        self._k_detect = None
        self._standing = None  # (model, isolation time) of a standing isolation
        return self._record()

    def update(self, q_measured, ctrl) -> dict:
        """One sample: the measurement ``q_measured`` ``(n,)`` and the ``ctrl`` that acted over the interval."""
        if self._rho is None:
            raise RuntimeError("expected reset(q_measured) before update(...), actual value: never reset")
        q = _vector("q_measured", q_measured, self.bank.n)
        u = as_real_array("ctrl", ctrl, copy=True)
        if u.ndim != 1 or not np.isfinite(u).all():
            raise ValueError(f"expected a finite ctrl of shape (nu,), actual value: {u!r}")
        rho = np.asarray(self.bank.update(q, u), dtype=np.float64)
        self._rho.append(rho)
        k = len(self._rho) - 1
        bank = self.bank
        if self._k_detect is None and rho[0] > 1.0 and k >= math.ceil(bank.settle_time / bank.dt - 1e-9):
            self._k_detect = k
        return self._record()

    def _record(self) -> dict:
        bank, k = self.bank, len(self._rho) - 1
        record = {
            "detected": False,
            "detection_time": math.nan,
            "isolated": 0,
            "isolated_name": "no fault",
            "isolation_time": math.nan,
            "residual_norms": self._rho[-1].copy(),
            "time": k * bank.dt,
        }
        kd = self._k_detect
        if kd is None:
            return record
        standing = self._standing
        # a standing isolation of model i stays while i's residual stays in the band (diagnose's rule): no new call
        if standing is None or self._rho[-1][standing[0]] > 1.0:
            # windows are counted from detection on: the rule of diagnose on the samples since then
            d = diagnose(np.stack(self._rho[kd:]), bank.dt, dwell=bank.dwell, names=bank.names)
            i, t_iso = int(d.isolated), kd * bank.dt + float(d.isolation_time)
            standing = self._standing = (i, t_iso) if i >= 1 else None
        i, t_iso = standing if standing is not None else (UNKNOWN, math.nan)
        record.update(
            detected=True,
            detection_time=kd * bank.dt,
            isolated=i,
            isolated_name="unknown" if i == UNKNOWN else bank.names[i],
            isolation_time=t_iso,
        )
        return record


class ModeMonitor:
    r"""The estimated mode of a switched system and its switching instants, sample by sample.

    The online form of :meth:`smo_gym.control.SwitchedObserverBank.run`: the bank's observers are predicted with the
    input that acted over the interval, then updated with the sample. The bank works in the deviation coordinates
    of its linearizations, :math:`y = q_{meas} - q_0` (of the ``outputs`` entries of the measured ``qpos``) and
    :math:`u = \mathtt{ctrl} - u_0`.

    Parameters
    ----------
    bank : smo_gym.control.SwitchedObserverBank
    qpos_offset : float or array_like, shape (p,)
        :math:`q_0`, the configuration the modes were linearized at.
    ctrl_offset : float or array_like, shape (inputs,)
        :math:`u_0`, the control they were linearized at.
    outputs : array_like of int, shape (p,), optional
        Which entries of the measured ``qpos`` are the bank's outputs (default the first ``p``).

    Notes
    -----
    The record of :meth:`reset` and :meth:`update` (times from the reset sample):

    ====================  ==========  ==============================================================================
    key                   shape       what
    ====================  ==========  ==============================================================================
    ``mode``              ``()``      int: the estimated mode :math:`\hat\sigma`
    ``mode_name``         str         its name in the :class:`~smo_gym.control.SwitchedLinearSystem`
    ``switched``          ``()``      bool: a switch was decided at this sample
    ``switch_time``       ``()``      estimated instant of the last switch [s], NaN before the first
    ``switches``          ``()``      int: switches decided since the reset
    ``residual_norms``    ``(q,)``    :math:`\rho_j` of each mode's observer (band: ``<= 1``)
    ``time``              ``()``      time since the reset [s]
    ====================  ==========  ==============================================================================
    """

    def __init__(self, bank, *, qpos_offset=0.0, ctrl_offset=0.0, outputs=None):
        from .control import SwitchedObserverBank

        if not isinstance(bank, SwitchedObserverBank):
            raise TypeError(f"expected a SwitchedObserverBank, actual value: {type(bank).__name__}")
        self.bank = bank
        p, m = bank.system.n_outputs, bank.system.n_inputs
        self.outputs = np.arange(p) if outputs is None else _indices("outputs", outputs, p)
        self.qpos_offset = _vector("qpos_offset", _broadcast("qpos_offset", qpos_offset, p), p)
        self.ctrl_offset = _vector("ctrl_offset", _broadcast("ctrl_offset", ctrl_offset, m), m)
        self._k = None

    @property
    def dt(self) -> float:
        """The bank's sampling step [s]."""
        return self.bank.dt

    @property
    def n_ctrl(self) -> int:
        """The length of ``ctrl``: the system's inputs."""
        return self.ctrl_offset.size

    def _outputs(self, q_measured) -> np.ndarray:
        q = as_real_array("q_measured", q_measured)
        if q.ndim != 1 or q.size <= self.outputs.max() or not np.isfinite(q).all():
            raise ValueError(
                f"expected a finite q_measured of shape (nq,) with nq > {self.outputs.max()}, actual value: {q!r}"
            )
        return q[self.outputs] - self.qpos_offset

    def reset(self, q_measured) -> dict:
        """Restart every observer at ``q_measured`` in the bank's initial mode."""
        self.bank.reset(self._outputs(q_measured))
        self._k, self._n_switches = 0, 0
        return self._record()

    def update(self, q_measured, ctrl) -> dict:
        """One sample: the measurement and the ``ctrl`` (shape ``(inputs,)``) that acted over the interval."""
        if self._k is None:
            raise RuntimeError("expected reset(q_measured) before update(...), actual value: never reset")
        y = self._outputs(q_measured)
        u = _vector("ctrl", ctrl, self.ctrl_offset.size)
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow is reported below, as an error
            self.bank.advance(u - self.ctrl_offset)
            x = self.bank.update(y)
        if not (np.isfinite(x).all() and np.isfinite(self.bank.residual_norms).all()):
            self._k = None  # the observers took the sample: there is no state to go back to
            raise DivergenceError(
                f"expected finite estimates and residuals, actual value: non-finite after q_measured = "
                f"{_short(np.asarray(q_measured))}, ctrl = {_short(np.asarray(ctrl))}; reset(q_measured) before the "
                "next update"
            )
        self._k += 1
        return self._record()

    def _record(self) -> dict:
        bank = self.bank
        switches = bank.switches
        switched = len(switches) > self._n_switches
        self._n_switches = len(switches)
        return {
            "mode": int(bank.mode),
            "mode_name": bank.system.names[bank.mode],
            "switched": switched,
            "switch_time": switches[-1][0] if switches else math.nan,
            "switches": len(switches),
            "residual_norms": np.array(bank.residual_norms, dtype=float),
            "time": self._k * bank.dt,
        }
