r"""Regressors of MuJoCo model parameters, for identification by the equivalent output injection.

For parameters :math:`\theta` that enter the equations of motion linearly (a body's mass with its centre of mass
and rotational inertia fixed, a joint's viscous damping), the inverse dynamics

.. math:: \tau(q, \dot q, \ddot q; \theta) = M(q;\theta)\ddot q + b(q, \dot q;\theta) - \tau_{pas}(q, \dot q;\theta)

is affine in :math:`\theta`, so its derivative :math:`Y = \partial\tau/\partial\theta` (MuJoCo's ``mj_inverse``,
differenced in :math:`\theta`) is exact up to rounding. With the nominal model :math:`\bar\theta` (acceleration
:math:`\bar f`) and the true one, :math:`\tau(\ddot q;\theta) = \tau(\bar f;\bar\theta)` gives
:math:`\bar M(\ddot q - \bar f) = -Y(q, \dot q, \ddot q)(\theta - \bar\theta)`: the acceleration-level regression
of :mod:`smo_gym.identification` with

.. math:: \Phi = -\bar M(q)^{-1}\,Y(q, \dot q, \ddot q),

which depends on the true acceleration :math:`\ddot q` when a parameter enters the inertia (a mass); the
identifier evaluates it at its estimate of :math:`\ddot q` (``uses_acceleration=True``).
"""

from __future__ import annotations

import copy
from collections.abc import Sequence

import mujoco
import numpy as np

from .._validation import check_positive

__all__ = ["MujocoParameterRegressor"]

_KINDS = {"body_mass": mujoco.mjtObj.mjOBJ_BODY, "dof_damping": mujoco.mjtObj.mjOBJ_JOINT}


class MujocoParameterRegressor:
    r"""Joint-space regressor :math:`\Phi = -\bar M^{-1}\partial\tau/\partial\theta` of MuJoCo model parameters,
    evaluated on a private copy of the model (never the simulation's).

    Parameters
    ----------
    model : mujoco.MjModel
        The nominal model; deep-copied. Every joint must be a hinge or a slide (``nq == nv``), all measured.
    parameters : sequence of (str, str)
        ``("body_mass", body_name)`` or ``("dof_damping", joint_name)`` pairs: the entries of :math:`\theta`.
    step : float
        Relative finite-difference step in :math:`\theta` (central differences; the inverse dynamics is affine in
        these parameters, so the step only sets the rounding error).

    Attributes
    ----------
    n, p : int
        Number of joints and of parameters.
    theta_bar : ndarray, shape (p,)
        The nominal values, read from the model.
    model, data : the private copy (constraints disabled: contacts are not part of the regression) and its data.

    Notes
    -----
    A call ``regressor(t, q, v, u, a)`` matches the regressor callable of
    :class:`smo_gym.identification.EquivalentInjectionIdentifier` with ``uses_acceleration=True`` (``t`` and
    ``u`` are not used: the parameters here do not enter the actuation).
    """

    def __init__(self, model: mujoco.MjModel, parameters: Sequence[tuple[str, str]], *, step: float = 1e-4):
        if not isinstance(model, mujoco.MjModel):
            raise TypeError(f"expected a mujoco.MjModel, actual value: {type(model).__name__}")
        m = copy.deepcopy(model)
        if m.nq != m.nv or any(
            int(t) not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)) for t in m.jnt_type
        ):
            raise ValueError("expected a model with hinge and slide joints only, actual value: other joint types")
        m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT) | int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
        step = check_positive("step", step)
        self.model, self.data = m, mujoco.MjData(m)
        self.n = m.nv
        self.step = step
        if isinstance(parameters, (str, bytes)) or len(parameters) == 0:
            raise ValueError(f"expected a non-empty sequence of (kind, name) pairs, actual value: {parameters!r}")
        self._fields = []
        for item in parameters:
            if not (isinstance(item, (tuple, list)) and len(item) == 2):
                raise ValueError(f"expected a (kind, name) pair, actual value: {item!r}")
            kind, name = item
            if kind not in _KINDS:
                raise ValueError(f"expected a parameter kind in {sorted(_KINDS)}, actual value: {kind!r}")
            i = mujoco.mj_name2id(m, _KINDS[kind], name)
            if i < 0:
                raise ValueError(f"expected the name of a {kind.split('_')[0]} of the model, actual value: {name!r}")
            if kind == "dof_damping":
                i = int(m.jnt_dofadr[i])
            self._fields.append((kind, i))
        self.p = len(self._fields)
        self.names = tuple(tuple(item) for item in parameters)
        self.theta_bar = np.array([getattr(m, kind)[i] for kind, i in self._fields], dtype=np.float64)
        self._M = np.zeros((self.n, self.n))

    def _inverse(self, q, v, a) -> np.ndarray:
        d = self.data
        d.qpos[:] = q
        d.qvel[:] = v
        d.qacc[:] = a
        mujoco.mj_inverse(self.model, d)
        return d.qfrc_inverse.copy()

    def _torque_one(self, q, v, a) -> np.ndarray:
        Y = np.empty((self.n, self.p))
        for j, (kind, i) in enumerate(self._fields):
            arr = getattr(self.model, kind)
            nominal = arr[i]
            h = self.step * max(abs(nominal), 1.0)
            try:
                arr[i] = nominal + h
                plus = self._inverse(q, v, a)
                arr[i] = nominal - h
                minus = self._inverse(q, v, a)
            finally:
                arr[i] = nominal
            Y[:, j] = (plus - minus) / (2.0 * h)
        return Y

    def _batched(self, fn, *arrays):
        arrays = [np.asarray(x, dtype=np.float64) for x in arrays]
        for x in arrays:
            if x.ndim == 0 or x.shape[-1] != self.n:
                raise ValueError(f"expected arrays of shape (..., {self.n}), actual value: shape {x.shape}")
        shape = np.broadcast_shapes(*(x.shape[:-1] for x in arrays))
        flat = [np.broadcast_to(x, shape + (self.n,)).reshape(-1, self.n) for x in arrays]
        rows = [fn(*(f[b] for f in flat)) for b in range(flat[0].shape[0])]
        return np.stack(rows).reshape(shape + rows[0].shape)

    def torque_regressor(self, q, v, a) -> np.ndarray:
        r""":math:`Y = \partial\tau/\partial\theta` at :math:`(q, \dot q, \ddot q)`, shape ``(..., n, p)``."""
        return self._batched(self._torque_one, q, v, a)

    def _inertia_one(self, q) -> np.ndarray:
        d = self.data
        d.qpos[:] = q
        mujoco.mj_kinematics(self.model, d)
        mujoco.mj_comPos(self.model, d)
        mujoco.mj_makeM(self.model, d)
        mujoco.mj_fullM(self.model, d, self._M)
        return self._M.copy()

    def inertia(self, q) -> np.ndarray:
        r"""Nominal :math:`\bar M(q)`, shape ``(..., n, n)``."""
        return self._batched(self._inertia_one, q)

    def __call__(self, t, q, v, u, a) -> np.ndarray:
        r""":math:`\Phi = -\bar M(q)^{-1} Y(q, \dot q, a)`, shape ``(..., n, p)``."""

        def one(q, v, a):
            return -np.linalg.solve(self._inertia_one(q), self._torque_one(q, v, a))

        return self._batched(one, q, v, a)
