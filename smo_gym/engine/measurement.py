r"""Joint measurements on the configuration manifold, and the observer of the measured signal.

Nothing here knows Gymnasium or dm_control; it needs a ``mujoco.MjModel`` (joint types, for the manifold) and
works on arrays of ``qpos``.

Tangent coordinates
-------------------
A velocity observer differentiates a real-valued signal. Hinge and slide joints give one directly (``qpos``).
Free and ball joints store orientations as unit quaternions (``nq != nv``), whose derivative is not ``qvel``.
:class:`TangentCoordinates` turns a stream of configurations into a continuous signal ``z`` of size ``nv``:

.. math:: z_k = z_{k-1} + \ominus(q_{k-1}, q_k),

with :math:`\ominus` MuJoCo's ``mj_differentiatePos`` (for hinge/slide dofs a plain difference, for a free/ball
rotation the body-frame rotation vector :math:`\log(q_{k-1}^{-1} q_k)`). Then :math:`\dot z = ` ``qvel`` exactly
in the limit of small steps (MuJoCo's angular velocity of a free/ball joint is in the local frame, like the
increment), so any observer of :math:`\dot z` estimates ``qvel``. Hinge/slide coordinates are taken from ``qpos``
directly (no accumulated round-off); ``z`` of a rotation is unwrapped, so it never jumps.

Sensor on the manifold
----------------------
:class:`JointMeasurement` applies a :class:`smo_gym.sensors.Sensor` to the *true* tangent coordinates and maps the
result back: :math:`q^{meas} = q \oplus (z^{meas} - z)` (``mj_integratePos``), i.e. the orientation error is a
rotation vector, noise on the manifold, and a measured quaternion is always a unit quaternion.
"""

from __future__ import annotations

import functools

import mujoco
import numpy as np
from numba import njit

from .._validation import check_positive
from ..observers import Observer
from ..observers.base import reported_coefficients, reported_velocity, step_mean_coefficients
from ..sensors import Sensor, Wrap, make_sensor
from .tangent import integrate_pos, joint_table, tangent_advance

__all__ = [
    "JointMeasurement",
    "TangentCoordinates",
    "VelocityEstimator",
    "angular_dofs",
    "check_finite_observation",
    "check_sample_time",
    "first_nonfinite_entry",
    "mean_velocity_span",
    "resolve_rate",
    "step_mean_coefficients",
]


def resolve_rate(rate, frame_skip: int) -> int:
    """Physics steps per sample: ``"physics"`` -> 1, ``"env"`` -> ``frame_skip``, an int ``k`` dividing it -> k."""
    if isinstance(rate, str):
        if rate == "physics":
            return 1
        if rate == "env":
            return int(frame_skip)
        raise ValueError(f"expected rate 'physics', 'env' or an int dividing frame_skip, actual value: {rate!r}")
    if isinstance(rate, bool) or not isinstance(rate, (int, np.integer)):
        raise TypeError(f"expected rate 'physics', 'env' or an int dividing frame_skip, actual value: {rate!r}")
    k = int(rate)
    if k < 1 or frame_skip % k != 0:
        raise ValueError(
            f"expected rate to be a positive divisor of frame_skip={frame_skip} (physics steps per sample), "
            f"actual value: {rate!r}"
        )
    return k


def check_sample_time(elapsed: float, sample_dt: float) -> None:
    """Raise if ``elapsed`` seconds of simulated time passed between two samples taken ``sample_dt`` apart: the
    environment took other physics steps than the sampling assumes (``frame_skip`` edited after wrapping, an action
    repeated inside ``step``), and the observer would differentiate with the wrong step.

    Raises
    ------
    RuntimeError
        ``elapsed`` off ``sample_dt`` by more than 1e-6 of it (the rounding of ``data.time`` is far below).
    """
    if not abs(elapsed - sample_dt) <= 1e-6 * sample_dt:
        raise RuntimeError(
            f"expected {sample_dt:g} s of simulated time per sample (frame_skip physics steps at rate='env'), "
            f"actual value: {elapsed:g} s; wrap the environment after editing frame_skip or opt.timestep, or "
            "sample inside the step with rate='physics'"
        )


_FREE, _BALL, _SLIDE, _HINGE = (
    int(mujoco.mjtJoint.mjJNT_FREE),
    int(mujoco.mjtJoint.mjJNT_BALL),
    int(mujoco.mjtJoint.mjJNT_SLIDE),
    int(mujoco.mjtJoint.mjJNT_HINGE),
)


def angular_dofs(model: mujoco.MjModel) -> np.ndarray:
    """Boolean mask ``(nv,)``: True for rotational dofs (hinge, ball, free rotation), False for translations."""
    mask = np.ones(model.nv, dtype=bool)
    for j in range(model.njnt):
        adr = model.jnt_dofadr[j]
        if model.jnt_type[j] == _SLIDE:
            mask[adr] = False
        elif model.jnt_type[j] == _FREE:
            mask[adr : adr + 3] = False
    return mask


def joint_layout(model: mujoco.MjModel) -> str:
    """The sizes of ``qpos`` and ``qvel`` and the joints' types, as ``"nq=.., nv=.., joint types [..]"``."""
    return f"nq={model.nq}, nv={model.nv}, joint types {np.asarray(model.jnt_type).tolist()}"


class TangentCoordinates:
    r"""Continuous tangent coordinates ``z`` (size ``nv``) of a stream of configurations ``q`` (size ``nq``).

    See the module docstring: :math:`z_k = z_{k-1} + \ominus(q_{k-1}, q_k)`, hinge/slide dofs copied from
    ``qpos``; the arithmetic is the compiled :mod:`smo_gym.engine.tangent` (MuJoCo's, bit for bit), which the
    wrapper's fused hot path shares. Models without free or ball joints take a fast path (``z = qpos``).
    """

    def __init__(self, model: mujoco.MjModel):
        self.model = model
        self.nq, self.nv = model.nq, model.nv
        types = np.asarray(model.jnt_type)
        self.manifold = bool(np.any((types == _FREE) | (types == _BALL)))
        #: (type, qpos address, dof address) per joint; empty without free/ball joints (then z = qpos)
        self.joints = joint_table(model) if self.manifold else np.zeros((0, 3), dtype=np.int64)
        #: the last configuration ``(nq,)`` and its coordinates ``z`` ``(nv,)``, updated in place (the engine's
        #: compiled path advances them too)
        self.previous = np.zeros(self.nq)
        self.z = np.zeros(self.nv)

    def use_arrays(self, previous: np.ndarray, z: np.ndarray) -> None:
        """Keep :attr:`previous` and :attr:`z` in these arrays from now on (rows of a caller's stacked arrays,
        :class:`~smo_gym.engine.batch.MeasurementBatch`): writeable, C-contiguous float64 of shapes ``(nq,)`` and
        ``(nv,)``; the current values are copied in and later steps and resets write into them. Models with free or
        ball joints only (without them ``z`` is ``qpos`` and nothing is kept).

        Raises
        ------
        ValueError
            A model without free or ball joints, or arrays of other shapes.
        TypeError
            Arrays that are not writeable C-contiguous float64.
        """
        if not self.manifold:
            raise ValueError(
                "expected a model with free or ball joints (whose tangent coordinates are kept), actual value: a "
                "model without them, where z is qpos"
            )
        for name, new, old in (("previous", previous, self.previous), ("z", z, self.z)):
            if not (
                type(new) is np.ndarray and new.dtype == np.float64 and new.flags.c_contiguous and new.flags.writeable
            ):
                raise TypeError(f"expected {name} as a writeable C-contiguous float64 array, actual value: {new!r:.80}")
            if new.shape != old.shape:
                raise ValueError(f"expected {name} with shape {old.shape}, actual value: {new.shape}")
            new[...] = old
        self.previous, self.z = previous, z

    def reset(self, q0: np.ndarray) -> np.ndarray:
        """Start at ``q0``: ``z0`` has the hinge/slide values and free-joint translations of ``q0``, and zero
        for free/ball rotations."""
        q0 = np.asarray(q0, dtype=np.float64)
        if not self.manifold:
            self.z = q0.copy()
            return self.z.copy()
        self.previous[:] = q0
        self.z[:] = 0.0
        entries, dofs = self._copied_at_reset
        self.z[dofs] = q0[entries]
        return self.z.copy()

    @functools.cached_property
    def _copied_at_reset(self) -> tuple[np.ndarray, np.ndarray]:
        """``(qpos entries, dofs)`` that :meth:`reset` copies from ``q0`` into ``z``: the hinge and slide values and
        the free joints' translations. Index arrays for one assignment per episode (a loop over Humanoid's 17 joints
        cost 22 us)."""
        entries, dofs = [], []
        for kind, a, d in self.joints:
            width = 3 if kind == _FREE else 0 if kind == _BALL else 1
            entries += range(a, a + width)
            dofs += range(d, d + width)
        return np.array(entries, dtype=np.intp), np.array(dofs, dtype=np.intp)

    def __call__(self, q: np.ndarray) -> np.ndarray:
        """Advance to the configuration ``q`` and return ``z`` (a new array)."""
        if not self.manifold:
            self.z = np.array(q, dtype=np.float64)
            return self.z  # a fresh copy already: callers may keep it
        tangent_advance(self.joints, self.previous, np.ascontiguousarray(q, dtype=np.float64), self.z)
        return self.z.copy()

    def to_qpos(self, q_ref: np.ndarray, z_ref: np.ndarray, z: np.ndarray) -> np.ndarray:
        r"""Configuration at tangent coordinates ``z``: :math:`q_{ref} \oplus (z - z_{ref})` (``mj_integratePos``)."""
        if not self.manifold:
            return np.array(z, dtype=np.float64)
        q = np.array(q_ref, dtype=np.float64)
        integrate_pos(self.joints, q, np.asarray(z, dtype=np.float64) - z_ref)
        return q


class JointMeasurement:
    r"""A sensor on the joint positions of a MuJoCo model, with noise on the manifold for free/ball joints.

    Parameters
    ----------
    model : mujoco.MjModel
    sensor : str or smo_gym.sensors.Sensor
        A preset name of :data:`smo_gym.sensors.PRESETS` or a sensor object (used as is).
    dt : float
        Sampling step [s].

    Attributes
    ----------
    z_true, z_measured : ndarray, shape (nv,)
        Tangent coordinates of the true and of the measured configuration at the last sample.
    qpos_measured : ndarray, shape (nq,)
        The measured configuration :math:`q \oplus (z^{meas} - z)`.
    timestep : float
        The model's ``opt.timestep`` at construction, which :meth:`reset` requires.
    """

    #: the generator of the sensor's last reset: a reset on the same one restarts the sensor on its stream (the
    #: sensor is this measurement's, and its channels, ``dt`` and ``angular`` are fixed at construction)
    _stream: np.random.Generator | None = None

    def __init__(self, model: mujoco.MjModel, sensor: str | Sensor, dt: float):
        self.model = model
        self.sensor = make_sensor(sensor)
        self.dt = float(dt)
        #: the physics step ``dt`` is a multiple of (checked at every reset: the observer's gains were made for it)
        self.timestep = float(model.opt.timestep)
        self.tangent = TangentCoordinates(model)
        self.angular = angular_dofs(model)
        #: the sensor reports single-turn angles (a :class:`~smo_gym.sensors.Wrap` stage): observers of its
        #: measurements need ``wrap`` on the angular channels
        self.wraps = any(isinstance(stage, Wrap) for stage in self.sensor.stages)
        if self.wraps and self.tangent.manifold:
            raise ValueError(
                "expected a model without free or ball joints for a single-turn (wrapping) encoder, which measures "
                "hinge angles, actual value: a model with free or ball joints"
            )
        self._z_true = self._z_measured = self._qpos_measured = self._last_qpos = None
        self._fused_block = None

    def load_block(self, block: np.ndarray) -> None:
        """Take the last sample from a compiled caller's block ``[qpos, qvel, qvel_estimate, qpos_measured, z_true,
        z_measured]`` (``2 nq + 4 nv``; :meth:`FusedSensing.sample <smo_gym.engine.fused.FusedSensing.sample>`),
        unpacked only when read."""
        self._fused_block = block

    # the last sample, as kept by measure_block or (lazily unpacked) from load_block
    def _unpack_fused(self) -> None:
        block, nq, nv = self._fused_block, self.model.nq, self.model.nv
        self._fused_block = None  # [qpos, qvel, qvel_estimate, qpos_measured, z_true, z_measured]
        self._last_qpos = block[:nq]
        self._qpos_measured = block[nq + 2 * nv : 2 * nq + 2 * nv]
        self._z_true = block[2 * nq + 2 * nv : 2 * nq + 3 * nv]
        self._z_measured = block[2 * nq + 3 * nv :]

    @property
    def z_true(self) -> np.ndarray | None:
        if self._fused_block is not None:
            self._unpack_fused()
        return self._z_true

    @property
    def z_measured(self) -> np.ndarray | None:
        if self._fused_block is not None:
            self._unpack_fused()
        return self._z_measured

    @property
    def qpos_measured(self) -> np.ndarray | None:
        return None if self._z_measured is None and self._fused_block is None else self.measured_qpos()

    def noise_std(self) -> np.ndarray:
        """Per-dof standard deviation of the sensor's random error, shape ``(nv,)``."""
        return self.sensor.error_std(self.model.nv, self.angular)

    def quantization_step(self) -> np.ndarray:
        """Per-dof quantization step of the sensor (0 where it does not quantize), shape ``(nv,)``."""
        return self.sensor.quantization_step(self.model.nv, self.angular)

    def follow(self, model: mujoco.MjModel) -> None:
        """Measure on ``model`` from now on: a model the environment rebuilt, or a copy's own (its timestep is checked
        by :meth:`reset`).

        Raises
        ------
        ValueError
            ``model`` has other joints than :attr:`model` (they make the sensor's and the observer's channels).
        """
        if model is self.model:
            return
        have, got = joint_layout(self.model), joint_layout(model)
        if have != got:
            raise ValueError(
                f"expected a model with the joints of the one the sensor and the observer were made for ({have}), "
                f"actual value: {got}"
            )
        self.model = self.tangent.model = model

    def reset(self, qpos: np.ndarray, rng: np.random.Generator, model: mujoco.MjModel | None = None) -> np.ndarray:
        """First measurement of the configuration ``qpos`` (the sensor's stream comes from ``rng``); ``model``: the
        environment's model now, followed first (:meth:`follow`).

        Raises
        ------
        ValueError
            The model's ``opt.timestep`` is no longer :attr:`timestep` (edited after construction: the samples would
            be ``dt`` apart no more, and the observer would differentiate with the wrong step); a model with other
            joints.
        """
        if model is not None:
            self.follow(model)
        if self.model.opt.timestep != self.timestep:
            raise ValueError(
                f"expected the model's opt.timestep {self.timestep} that the sampling step {self.dt} and the "
                f"observer's gains were made for, actual value: {self.model.opt.timestep}; edit the timestep before "
                "wrapping the environment (the calibration reads the live model), and again in a copy of the wrapper "
                "(Gymnasium rebuilds a copied environment from its constructor); a model rebuilt at reset keeps it"
            )
        qpos = np.asarray(qpos, dtype=np.float64)
        self._fused_block = None
        self._z_true = self.tangent.reset(qpos)
        if rng is not None and rng is self._stream:  # an episode on the same stream (an autoreset): nothing changed
            self._z_measured = self.sensor.restart(self._z_true)
        else:
            self._z_measured = self.sensor.reset(self._z_true, rng=rng, dt=self.dt, angular=self.angular)
            self._stream = rng
        self._last_qpos = qpos.copy()
        self._qpos_measured = self.tangent.to_qpos(qpos, self._z_true, self._z_measured)
        return self._qpos_measured

    def measure(self, qpos: np.ndarray) -> np.ndarray:
        """Measure the next sample; returns (and stores) the measured tangent coordinates ``z_measured``."""
        return self.measure_block(np.asarray(qpos, dtype=np.float64)[None])[0]

    def measure_block(self, Q: np.ndarray) -> np.ndarray:
        """Measure consecutive samples ``Q`` (T, nq) with one compiled sensor call; returns ``Z_meas`` (T, nv).

        Same numbers as ``measure`` row by row (the sensor's stream does not depend on batching). ``Q`` may be a
        view of live simulation data (``data.qpos[None]``): what is kept of it is copied.
        """
        self._fused_block = None
        if self.tangent.manifold:
            Z = np.array([self.tangent(q) for q in Q])
            self._last_qpos = np.array(Q[-1])
            self._z_true = Z[-1]
            self._qpos_measured = None  # mapped back lazily: only the last sample of a control period is needed
            Zm = self.sensor.run(Z)
        else:  # z = qpos: no copy of the block, and the measured configuration is the measurement itself
            Zm = self.sensor.run(Q)
            self._z_true = self._last_qpos = Q[-1].copy()
            self._qpos_measured = Zm[-1]
        self._z_measured = Zm[-1]
        return Zm

    def measured_qpos(self) -> np.ndarray:
        """The measured configuration at the last sample, shape ``(nq,)``."""
        if self._fused_block is not None:
            self._unpack_fused()
        if self._qpos_measured is None:
            self._qpos_measured = self.tangent.to_qpos(self._last_qpos, self._z_true, self._z_measured)
        return self._qpos_measured


@njit(cache=True)
def _first_nonfinite(x) -> int:
    """Index of the first non-finite entry of the 1-D array ``x``, or -1."""
    for i in range(x.shape[0]):
        if not np.isfinite(x[i]):
            return i
    return -1


_FLOAT64 = np.dtype(np.float64)
#: dtype -> entry point of :func:`_first_nonfinite` for 1-D arrays of that dtype, any layout
_NONFINITE_ENTRIES: dict = {}


def first_nonfinite_entry(dtype: np.dtype):
    """Entry point of :func:`_first_nonfinite` for 1-D float32 or float64 arrays of any layout (strided views
    too), so that a caller only has to check the dtype and the number of dimensions."""
    entry = _NONFINITE_ENTRIES.get(dtype)
    if entry is None:
        import numba

        sig = (numba.types.Array(numba.from_dtype(dtype), 1, "A"),)
        if sig not in _first_nonfinite.overloads:
            _first_nonfinite.compile(sig)
        entry = _NONFINITE_ENTRIES[dtype] = _first_nonfinite.overloads[sig].entry_point
    return entry


def check_finite_observation(obs: np.ndarray) -> None:
    """Raise ``ValueError`` naming the first non-finite entry of a sensed observation (1-D array).

    A sensed observation is a function of finite measurements and finite estimates (the sensor and the
    observer reject anything else), but the environment's observation function could still produce inf (a
    constraint force at an impossible measured configuration, say); it never reaches the agent silently. The
    check is one compiled call (a NumPy reduction costs about 1 us, comparable to the rest of the step on a
    small model).
    """
    if type(obs) is np.ndarray and obs.dtype is _FLOAT64 and obs.ndim == 1:
        bad = first_nonfinite_entry(_FLOAT64)(obs)
        if bad == -1:
            return
    else:
        flat = np.asarray(obs, dtype=np.float64).reshape(-1)
        if np.all(np.isfinite(flat)):
            return
        bad = int(np.flatnonzero(~np.isfinite(flat))[0])
        obs = flat
    raise ValueError(f"expected a finite sensed observation, actual value: {obs[bad]!r} at entry {bad}")


def mean_velocity_span(model: mujoco.MjModel) -> float | None:
    r"""The span over which MuJoCo's ``qvel`` is a mean velocity, or None where it is the instantaneous one.

    Every integrator but RK4 (semi-implicit Euler, implicit, implicitfast) advances the positions with the new
    velocity, :math:`q_k = q_{k-1} + h\,v_k`, so :math:`v_k = (q_k - q_{k-1})/h` exactly: the mean velocity over
    the last physics step ``h = opt.timestep``, whatever the sampling step. RK4's is the velocity at the time.
    """
    return None if model.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4 else float(model.opt.timestep)


class VelocityEstimator:
    r"""An observer on the measured tangent coordinates; its velocity estimates ``qvel``.

    Parameters
    ----------
    observer : smo_gym.observers.Observer
        Any observer; its ``dt`` must be the sampling step.
    mean_over : float, optional
        Report the mean velocity over the last ``mean_over`` seconds (:func:`mean_velocity_span`: what MuJoCo's
        ``qvel`` is unless it integrates with RK4): an observer of order >= 2 whose derivatives are those at the
        sample time (:attr:`~smo_gym.observers.Observer.reports_instant`) reports
        :math:`\sum_j c_j \hat z_j` (:func:`step_mean_coefficients`) instead of :math:`\hat z_1`. Without it, or
        for other observers, the velocity is :math:`\hat z_1`.
    """

    def __init__(self, observer: Observer, *, mean_over: float | None = None):
        if not isinstance(observer, Observer):
            raise TypeError(f"expected a smo_gym.observers.Observer, actual value: {observer!r}")
        self.observer = observer
        self.mean_over = None if mean_over is None else check_positive("mean_over", mean_over)
        #: the coefficients of the step-mean velocity, or None: the reported velocity is the estimate's column 1
        self.coefficients = reported_coefficients(observer, self.mean_over)

    def velocity_of(self, estimate: np.ndarray) -> np.ndarray:
        """The reported velocity of an estimate ``(..., n, order + 1)`` of this observer: shape ``(..., n)``."""
        return reported_velocity(estimate, self.coefficients)

    def reset(self, z0: np.ndarray) -> np.ndarray:
        """Start at the first measurement (velocity zero); returns the velocity estimate ``(nv,)``.

        A reset with the shape of the previous one is an :meth:`Observer.restart`: the per-channel parameters,
        derived from the gains at the first reset, are kept instead of derived again (~40 us, paid at every
        episode of a short-episode environment).
        """
        observer = self.observer
        z0 = np.asarray(z0, dtype=np.float64)
        if observer.shape == z0.shape:
            return self.velocity_of(observer.restart(z0))
        return self.velocity_of(observer.reset(z0))

    def update(self, z: np.ndarray) -> np.ndarray:
        """One sample; returns the velocity estimate ``(nv,)``."""
        return self.velocity_of(self.observer.update(z))

    @property
    def velocity(self) -> np.ndarray:
        return self.velocity_of(self.observer.estimate)

    @property
    def filtered(self) -> np.ndarray:
        """Filtered tangent coordinates (the observer's value estimate), shape ``(nv,)``."""
        return self.observer.estimate[..., 0]
