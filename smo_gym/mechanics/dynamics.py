r"""MuJoCo-backed model terms of a mechanical system, for the model-based observers.

:class:`MujocoDynamics` implements the :class:`smo_gym.observers.mechanical.Dynamics` protocol on a *private
copy* of an ``MjModel`` with its own scratch ``MjData``: evaluating the model never touches the environment's
``MjData``, and the copy can carry a deliberate model mismatch (scaled masses, inertias, damping) for honest
experiments.

For the measured coordinates :math:`q \in \mathbb R^n` (hinge and slide joints) it provides

.. math::
    M(q)\,\ddot q + b(q, \dot q) = \tau_{act}(u) + \tau_{pas}(q, \dot q) \;(+\ \tau_{c}),\qquad
    f(q, \dot q, u) = M(q)^{-1}\bigl(\tau_{act}(u) + \tau_{pas}(q, \dot q) - b(q, \dot q)\bigr),

with :math:`M` from ``mj_fullM``, :math:`b` = ``qfrc_bias`` (Coriolis, centrifugal, gravity), :math:`\tau_{pas}` =
``qfrc_passive`` (springs, damping) and :math:`\tau_{act}` = ``qfrc_actuator`` (``ctrl`` through the actuator
moment arms, ``mj_fwdActuation``). ``qfrc_applied`` is always zero in the scratch data: external forces are what
the observer has to estimate.

Constraints
-----------
``contact="unknown"`` (default) disables the constraint solver on the copy (``mjDSBL_CONSTRAINT``,
``mjDSBL_CONTACT``): contacts, joint limits and dry friction (``frictionloss``, which MuJoCo implements as a
constraint) are *not* in ``f``; the observer sees them as an unknown input that its gain must dominate.
``contact="measured"`` keeps the solver and returns MuJoCo's constrained ``qacc``: the contact model is evaluated
at the measured configuration and the *estimated* velocity (soft contacts depend on both), i.e. the contact
forces are predicted rather than treated as a disturbance.

Joint equality constraints (``<equality><joint joint1=.. joint2=.. polycoef=..>``), which couple a dependent joint
to a measured one by :math:`y - y_0 = \sum_{i=0}^4 a_i (x - x_0)^i`, are eliminated exactly in the ``"unknown"``
mode: with :math:`q_{full} = \phi(q)`, :math:`J = \partial\phi/\partial q` and :math:`\dot J\dot q` from the second
derivative of the polynomial,

.. math::
    M_r = J^\top M J,\qquad f = M_r^{-1} J^\top\bigl(\tau_{act} + \tau_{pas} - b - M \dot J \dot q\bigr),

the rigid-constraint (Lagrangian) reduction. MuJoCo simulates the same constraint softly, so the plant deviates
from it by the constraint's softness (``solref``); that deviation is part of what the observer treats as unknown.

Only hinge and slide joints are supported (``nq == nv`` coordinate by coordinate); free and ball joints raise
``ValueError`` (their positions live on a manifold and would need ``mj_integratePos`` in the observer).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence

import mujoco
import numpy as np

from .._validation import as_real_array, check_int_at_least, check_real_in_range

__all__ = ["MASS_SCALE_RANGE", "MujocoDynamics", "calibrate_model_miss"]

#: the accepted ``mass_scale`` and ``inertia_scale``. They are a deliberate error of the observer's model: a few tens
#: of percent in the studies here, and a thousandfold one is another machine. Far beyond it MuJoCo's own limits break
#: the model (measured on the two-link arm, the Furuta pendulum and Hopper-v5: from 1e-15 down or 1e10 up, a
#: "too close to singular" inertia matrix and accelerations of 1e14 or more, inf or NaN, which the model-based
#: observers' calibration turned into a NaN ``lipschitz``).
MASS_SCALE_RANGE = (1e-3, 1e3)

#: MuJoCo's mjMAXVAL: ``mj_forward`` replaces a larger or non-finite control by 0 (with a warning only)
_MAX_U = 1e10
_F64 = np.dtype(np.float64)
_HINGE_SLIDE = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))


def _scale(name: str, value, size: int, *, positive: bool = False) -> np.ndarray:
    """A scale factor, one number or one per entry: finite and ``>= 0`` (``> 0`` if ``positive``: a zero mass
    leaves a singular inertia)."""
    arr = as_real_array(name, value)
    try:
        arr = np.broadcast_to(arr, (size,))
    except ValueError:
        raise ValueError(f"expected {name} scalar or of shape ({size},), actual value: shape {arr.shape}") from None
    if not np.all(np.isfinite(arr)) or np.any(arr <= 0 if positive else arr < 0):
        raise ValueError(f"expected {name} {'>' if positive else '>='} 0 and finite, actual value: {value!r}")
    return arr


def _mismatch_scale(name: str, value, size: int) -> np.ndarray:
    """A mass or inertia scale (:func:`_scale`, ``> 0``) within :data:`MASS_SCALE_RANGE`."""
    arr = _scale(name, value, size, positive=True)
    low, high = MASS_SCALE_RANGE
    if np.any((arr < low) | (arr > high)):
        raise ValueError(f"expected {name} in [{low:g}, {high:g}] (a model mismatch), actual value: {value!r:.80}")
    return arr


class MujocoDynamics:
    r"""Joint-space model terms of a MuJoCo model, evaluated on a private copy.

    Parameters
    ----------
    model : mujoco.MjModel
        The model; it is deep-copied, never modified.
    joints : sequence of str, optional
        Names of the measured joints (hinge or slide), in the order of the observer's channels. Default: every
        joint that is not the dependent side of an active joint equality constraint.
    mass_scale : float or array_like, shape (nbody,)
        Multiplies ``body_mass`` of the copy (model mismatch; in :data:`MASS_SCALE_RANGE`, ``[1e-3, 1e3]``).
        ``inertia_scale`` defaults to the same value, so the bodies keep their radii of gyration.
    inertia_scale : float or array_like, optional
        Multiplies ``body_inertia`` of the copy (also in :data:`MASS_SCALE_RANGE`).
    damping_scale : float
        Multiplies ``dof_damping`` (viscous joint friction).
    frictionloss_scale : float
        Multiplies ``dof_frictionloss`` (dry joint friction; a constraint in MuJoCo, so it only enters ``f`` with
        ``contact="measured"``).
    contact : {"unknown", "measured"}
        How constraints (contacts, limits, dry friction) enter ``f``; see the module notes.
    input : {"ctrl", "qfrc"}
        What ``u`` is in :meth:`acceleration`: actuator controls ``(nu,)``, or generalized forces on the measured
        coordinates ``(n,)``.

    Attributes
    ----------
    n : int
        Number of measured coordinates (the observer's channels).
    model, data : the private ``MjModel`` copy and scratch ``MjData``.
    dof : ndarray of int, shape (n,)
        ``qvel`` address of each measured coordinate (equal to its ``qpos`` address for hinge/slide joints).
    timestep : float
        ``model.opt.timestep``.
    mass_scale, inertia_scale : float or ndarray, shape (nbody,)
        The model mismatch in force (:meth:`set_mass_scale` changes it).
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        *,
        joints: Sequence[str] | None = None,
        mass_scale=1.0,
        inertia_scale=None,
        damping_scale=1.0,
        frictionloss_scale=1.0,
        contact: str = "unknown",
        input: str = "ctrl",
    ):
        if not isinstance(model, mujoco.MjModel):
            raise TypeError(f"expected a mujoco.MjModel, actual value: {type(model).__name__}")
        if contact not in ("unknown", "measured"):
            raise ValueError(f"expected contact to be 'unknown' or 'measured', actual value: {contact!r}")
        if input not in ("ctrl", "qfrc"):
            raise ValueError(f"expected input to be 'ctrl' or 'qfrc', actual value: {input!r}")
        m = copy.deepcopy(model)
        for j in range(m.njnt):
            if int(m.jnt_type[j]) not in _HINGE_SLIDE:
                name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j)
                raise ValueError(
                    "expected a model with hinge and slide joints only, actual value: joint "
                    f"{name or j!r} of type {mujoco.mjtJoint(int(m.jnt_type[j])).name}; free and ball joints are "
                    "not supported by the model-based observers"
                )
        self.model = m
        #: the nominal masses and inertias (of ``model``), which :meth:`set_mass_scale` scales
        self._nominal_mass = m.body_mass.copy()
        self._nominal_inertia = m.body_inertia.copy()
        self.set_mass_scale(mass_scale, inertia_scale)
        m.dof_damping[:] = m.dof_damping * float(_scale("damping_scale", damping_scale, 1)[0])
        m.dof_frictionloss[:] = m.dof_frictionloss * float(_scale("frictionloss_scale", frictionloss_scale, 1)[0])
        self.contact = contact
        self.input = input
        # joint equality couplings: dependent joint -> (independent joint, polycoef)
        self._couplings: dict[int, tuple[int, np.ndarray]] = {}
        for e in range(m.neq):
            if int(m.eq_type[e]) == int(mujoco.mjtEq.mjEQ_JOINT) and m.eq_active0[e] and m.eq_obj2id[e] >= 0:
                self._couplings[int(m.eq_obj1id[e])] = (int(m.eq_obj2id[e]), np.array(m.eq_data[e, :5]))
        if contact == "unknown":
            m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT) | int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
        self.data = mujoco.MjData(m)
        if joints is None:
            jids = [j for j in range(m.njnt) if j not in self._couplings]
        else:
            jids = []
            if isinstance(joints, str) or not all(isinstance(name, str) for name in joints):
                raise TypeError(f"expected joints to be a sequence of joint names, actual value: {joints!r:.80}")
            for name in joints:
                j = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)
                if j < 0:
                    raise ValueError(f"expected a joint name of the model, actual value: {name!r}")
                if j in jids:
                    raise ValueError(f"expected each joint once, actual value: {name!r} twice in {list(joints)}")
                jids.append(j)
        covered = set(jids) | set(self._couplings)
        missing = [j for j in range(m.njnt) if j not in covered]
        if missing:
            names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) for j in missing]
            raise ValueError(
                f"expected every joint measured or coupled by a joint equality, actual value: "
                f"joints {names} are neither"
            )
        for dep, (ind, _) in self._couplings.items():
            if ind not in jids:
                raise ValueError(
                    f"expected the independent joint of equality on joint {dep} among the measured "
                    f"joints, actual value: joint {ind} is not measured"
                )
        self.dof = np.array([m.jnt_dofadr[j] for j in jids], dtype=int)
        self._qadr = np.array([m.jnt_qposadr[j] for j in jids], dtype=int)
        self.n = len(jids)
        self.timestep = float(m.opt.timestep)
        self._reduce = bool(self._couplings) and contact == "unknown"
        self._fullM = np.zeros((m.nv, m.nv))
        self._chan_of_joint = {int(j): i for i, j in enumerate(jids)}
        self._u_width = m.nu if input == "ctrl" else self.n
        self._fast = (
            not self._couplings
            and m.nq == m.nv == self.n
            and np.array_equal(self.dof, np.arange(self.n))
            and np.array_equal(self._qadr, np.arange(self.n))
        )
        self._bind_views()

    def set_mass_scale(self, mass_scale, inertia_scale=None) -> None:
        """Scale the nominal masses (and inertias) of the private copy anew: the model mismatch of the constructor's
        ``mass_scale`` and ``inertia_scale`` (same meaning; ``inertia_scale`` defaults to ``mass_scale``), e.g. a
        new one per episode. Sets :attr:`mass_scale` and :attr:`inertia_scale`."""
        m = self.model
        ms = _mismatch_scale("mass_scale", mass_scale, m.nbody)
        isc = ms if inertia_scale is None else _mismatch_scale("inertia_scale", inertia_scale, m.nbody)
        m.body_mass[:] = self._nominal_mass * ms
        m.body_inertia[:] = self._nominal_inertia * isc[:, None]
        self.mass_scale = float(ms[0]) if np.ndim(mass_scale) == 0 else ms.copy()
        self.inertia_scale = self.mass_scale if inertia_scale is None else isc.copy()

    def _bind_views(self) -> None:
        """Cached views into the scratch data (hot path); rebuilt after copy/unpickling."""
        d = self.data
        self._qpos, self._qvel, self._qacc = d.qpos, d.qvel, d.qacc
        self._uview = d.ctrl if self.input == "ctrl" else d.qfrc_applied

    def __getstate__(self):
        state = dict(self.__dict__)
        for key in ("_qpos", "_qvel", "_qacc", "_uview"):
            state.pop(key, None)
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._bind_views()

    # ---- coordinates --------------------------------------------------------------------------------------
    def _set_state(self, q: np.ndarray, v: np.ndarray | None, u: np.ndarray | None) -> np.ndarray | None:
        """Write ``(q, v, u)`` into the scratch data; return ``Jdot v`` (nv,) when couplings are eliminated."""
        m, d = self.model, self.data
        d.qpos[self._qadr] = q
        if v is not None:
            d.qvel[self.dof] = v
        jdv = None
        if self._couplings:
            jdv = np.zeros(m.nv)
            for dep, (ind, c) in self._couplings.items():
                x = q[self._chan_of_joint[ind]] - m.qpos0[m.jnt_qposadr[ind]]
                d.qpos[m.jnt_qposadr[dep]] = (
                    m.qpos0[m.jnt_qposadr[dep]] + c[0] + x * (c[1] + x * (c[2] + x * (c[3] + x * c[4])))
                )
                if v is not None:
                    xd = min(max(float(v[self._chan_of_joint[ind]]), -1e150), 1e150)
                    d1 = c[1] + x * (2 * c[2] + x * (3 * c[3] + x * 4 * c[4]))
                    d2 = 2 * c[2] + x * (6 * c[3] + x * 12 * c[4])
                    d.qvel[m.jnt_dofadr[dep]] = d1 * xd
                    jdv[m.jnt_dofadr[dep]] = d2 * xd * xd
        if u is not None:
            if self.input == "ctrl":
                d.ctrl[:] = u
            else:
                d.qfrc_applied[:] = 0.0
                d.qfrc_applied[self.dof] = u
        return jdv

    def jacobian(self, q) -> np.ndarray:
        r"""``J = d q_full / d q``, shape ``(nv, n)``: identity rows for measured joints, polynomial slopes for
        coupled ones."""
        q = np.asarray(q, dtype=np.float64)
        m = self.model
        J = np.zeros((m.nv, self.n))
        J[self.dof, np.arange(self.n)] = 1.0
        for dep, (ind, c) in self._couplings.items():
            i = self._chan_of_joint[ind]
            x = q[i] - m.qpos0[m.jnt_qposadr[ind]]
            J[m.jnt_dofadr[dep], i] = c[1] + x * (2 * c[2] + x * (3 * c[3] + x * 4 * c[4]))
        return J

    # ---- protocol -------------------------------------------------------------------------------------------
    def _check(self, name, arr, width, *, finite=True):
        arr = as_real_array(name, arr)
        if arr.ndim == 0 or arr.shape[-1] != width:
            raise ValueError(f"expected {name} with shape (..., {width}), actual value: {arr.shape}")
        if finite and not np.isfinite(arr).all():  # MuJoCo would answer NaN without an error
            raise ValueError(f"expected {name} finite, actual value: {arr!r:.80}")
        return arr

    def _accel_one(self, q, v, u) -> np.ndarray:
        m, d = self.model, self.data
        jdv = self._set_state(q, v, u)
        mujoco.mj_forward(m, d)
        if not self._reduce:
            return d.qacc[self.dof].copy()
        J = self.jacobian(q)
        mujoco.mj_fullM(m, d, self._fullM)
        with np.errstate(over="ignore", invalid="ignore"):  # a diverging estimate is reported by the observer
            rhs = J.T @ (d.qfrc_smooth - self._fullM @ jdv)
        return np.linalg.solve(J.T @ self._fullM @ J, rhs)

    def acceleration(self, q, v, u=None) -> np.ndarray:
        r"""Model acceleration :math:`f(q, \dot q, u)` of the measured coordinates.

        Parameters
        ----------
        q, v : array_like, shape (..., n)
            Positions and velocities of the measured coordinates (any leading batch shape).
        u : array_like, shape (..., nu) or (..., n), optional
            Controls (``input="ctrl"``) or generalized forces (``input="qfrc"``); zero if omitted.

        Returns
        -------
        ndarray, shape (..., n)

        Raises
        ------
        ValueError
            If ``q``, ``v`` or ``u`` is not finite (or ``u`` beyond MuJoCo's bound), or of the wrong shape.
        """
        if (
            self._fast
            and type(q) is np.ndarray
            and type(v) is np.ndarray
            and q.dtype is _F64
            and v.dtype is _F64
            and q.shape == v.shape == (self.n,)
            # one sum of Python floats is non-finite if any entry is (without NumPy's overflow warnings); an
            # overflowing sum of finite entries only sends the call to the general path, which checks each entry
            and math.isfinite(sum(q.tolist() + v.tolist()))
            # |u|_2 <= 1e10 in one dot product (NaN and inf fail it); the general path checks entry by entry
            and (u is None or (type(u) is np.ndarray and u.shape == (self._u_width,) and u @ u <= _MAX_U * _MAX_U))
        ):
            # hot path (one environment, all joints measured in model order): no index arithmetic
            self._qpos[:] = q
            self._qvel[:] = v
            self._uview[:] = 0.0 if u is None else u  # "zero if omitted", not the previous call's input
            mujoco.mj_forward(self.model, self.data)
            return self._qacc.copy()
        q = self._check("q", q, self.n)
        v = self._check("v", v, self.n)
        width = self._u_width
        if u is None:
            u = np.zeros(q.shape[:-1] + (width,))
        else:
            u = self._check("u", u, width, finite=False)
            if not (np.abs(u) <= _MAX_U).all():  # MuJoCo would replace it by 0 without an error
                raise ValueError(f"expected u finite and within +-{_MAX_U:g} (MuJoCo's bound), actual value: {u!r:.80}")
        if q.ndim == 1 and v.ndim == 1 and u.ndim == 1:
            return self._accel_one(q, v, u)
        shape = np.broadcast_shapes(q.shape[:-1], v.shape[:-1], u.shape[:-1])
        qb = np.broadcast_to(q, shape + (self.n,)).reshape(-1, self.n)
        vb = np.broadcast_to(v, shape + (self.n,)).reshape(-1, self.n)
        ub = np.broadcast_to(u, shape + (width,)).reshape(-1, width)
        out = np.empty_like(qb)
        for b in range(qb.shape[0]):
            out[b] = self._accel_one(qb[b], vb[b], ub[b])
        return out.reshape(shape + (self.n,))

    def _inertia_one(self, q) -> np.ndarray:
        m, d = self.model, self.data
        self._set_state(q, None, None)
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_makeM(m, d)
        mujoco.mj_fullM(m, d, self._fullM)
        if not self._couplings:
            return self._fullM[np.ix_(self.dof, self.dof)].copy()
        J = self.jacobian(q)
        return J.T @ self._fullM @ J

    def inertia(self, q) -> np.ndarray:
        r"""Joint-space inertia :math:`M(q)` of the measured coordinates (reduced by couplings), shape
        ``(..., n, n)``."""
        q = self._check("q", q, self.n)
        if q.ndim == 1:
            return self._inertia_one(q)
        flat = q.reshape(-1, self.n)
        return np.stack([self._inertia_one(r) for r in flat]).reshape(q.shape[:-1] + (self.n, self.n))

    def terms(self, q, v, u=None) -> dict[str, np.ndarray]:
        r"""The individual terms at one state (unbatched): ``inertia`` (n, n), ``bias``, ``passive``,
        ``actuator`` (n,), projected on the measured coordinates by :math:`J^\top`, and ``acceleration``."""
        q = self._check("q", q, self.n)
        v = self._check("v", v, self.n)
        if q.shape != (self.n,) or v.shape != (self.n,):  # the data read below hold the last row of a batch only
            raise ValueError(f"expected q and v of shape ({self.n},), actual value: {q.shape} and {v.shape}")
        acc = self.acceleration(q, v, u)
        d = self.data
        J = self.jacobian(q)
        return {
            "inertia": self.inertia(q),
            "bias": J.T @ d.qfrc_bias,
            "passive": J.T @ d.qfrc_passive,
            "actuator": J.T @ d.qfrc_actuator,
            "acceleration": acc,
        }

    def self_quadratic_coefficient(self, q, step: float = 1e-5) -> np.ndarray:
        r"""Coefficient :math:`\alpha_i(q)` of the self-quadratic velocity term :math:`\alpha_i\dot q_i^2` in
        :math:`\ddot q_i`, shape ``(..., n)``.

        From :math:`\ddot q = M^{-1}(\ldots - C(q,\dot q)\dot q)` with Christoffel symbols
        :math:`c_{jii} = \partial_i M_{ji} - \tfrac12 \partial_j M_{ii}`,

        .. math:: \alpha_i(q) = -\sum_j (M^{-1})_{ij}\, c_{jii}(q),

        with :math:`\partial M` by central differences of :meth:`inertia` (step ``step``). For one coordinate
        this is :math:`\alpha = -M'(q)/(2M(q))`, the term Apaza et al.'s transform removes.
        """
        q = self._check("q", q, self.n)
        step = check_real_in_range("step", step, 1e-12, 1.0)
        flat = q.reshape(-1, self.n)
        out = np.empty_like(flat)
        for b, qb in enumerate(flat):
            Minv = np.linalg.inv(self._inertia_one(qb))
            dM = np.empty((self.n, self.n, self.n))  # dM[k] = dM/dq_k
            for k in range(self.n):
                dq = np.zeros(self.n)
                dq[k] = step
                dM[k] = (self._inertia_one(qb + dq) - self._inertia_one(qb - dq)) / (2 * step)
            for i in range(self.n):
                c = np.array([dM[i][j, i] - 0.5 * dM[j][i, i] for j in range(self.n)])
                out[b, i] = -Minv[i] @ c
        return out.reshape(q.shape)

    def alpha_function(self, reference=None, step: float = 1e-5):
        r"""Per-channel self-quadratic coefficient as a function of the channel's own coordinate.

        Returns a callable ``alpha(Y) -> A`` (``Y, A`` of shape ``(G, n)``) for
        :class:`smo_gym.observers.CoordinateTransform`: ``A[g, i]`` is :meth:`self_quadratic_coefficient`'s entry
        ``i`` at the configuration ``reference`` with coordinate ``i`` replaced by ``Y[g, i]``. For one DOF this
        is exactly :math:`-M'(q)/(2M(q))`; for several DOF the other joints are frozen at ``reference`` (default
        the model's ``qpos0``), see :class:`smo_gym.observers.DissipativeSuperTwisting` for what that leaves in
        the model term.
        """
        ref = self.model.qpos0[self._qadr].copy() if reference is None else as_real_array("reference", reference)
        step = check_real_in_range("step", step, 1e-12, 1.0)
        if ref.shape != (self.n,) or not np.isfinite(ref).all():
            raise ValueError(f"expected reference finite with shape ({self.n},), actual value: {ref!r:.80}")

        def alpha(Y):
            Y = as_real_array("Y", Y)
            if Y.ndim != 2 or Y.shape[1] != self.n:
                raise ValueError(f"expected Y with shape (G, {self.n}), actual value: {Y.shape}")
            if not np.isfinite(Y).all():
                raise ValueError(f"expected Y finite, actual value: {Y!r:.80}")
            out = np.empty_like(Y)
            for g in range(Y.shape[0]):
                for i in range(self.n):
                    q = ref.copy()
                    q[i] = Y[g, i]
                    out[g, i] = self.self_quadratic_coefficient(q, step)[i]
            return out

        return alpha

    def __repr__(self) -> str:
        return f"MujocoDynamics(n={self.n}, contact={self.contact!r}, input={self.input!r})"


def calibrate_model_miss(
    model, dynamics: MujocoDynamics, frame_skip: int, *, steps: int = 2000, quantile: float = 0.99, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    r"""Quantiles of the model miss :math:`|\Delta v/h - f(q, v, u)|` and of :math:`|\Delta v/h|` per dof.

    Rollout of ``steps`` physics steps of ``model`` (its own ``MjData``, from ``qpos0`` plus small noise) with
    uniform random controls held for ``frame_skip`` steps; restarts when the state becomes non-finite. The default
    gains of the wrapper's model-based observers come from them (:mod:`smo_gym.wrappers.model_based`).

    Raises
    ------
    ValueError
        If ``dynamics`` was built on a model of other dimensions than ``model``.
    """
    if not isinstance(model, mujoco.MjModel) or not isinstance(dynamics, MujocoDynamics):
        raise TypeError(
            "expected a mujoco.MjModel and a MujocoDynamics, actual value: "
            f"{type(model).__name__} and {type(dynamics).__name__}"
        )
    # the dynamics' joint addresses index the rollout's state: another model's would read the wrong coordinates
    dims = ("nq", "nv", "nu", "njnt", "nbody")
    have, want = (tuple(int(getattr(x, k)) for k in dims) for x in (dynamics.model, model))
    if have != want:
        raise ValueError(
            f"expected dynamics of model ({', '.join(f'{k}={v}' for k, v in zip(dims, want, strict=True))}), "
            f"actual value: dynamics of a model with {', '.join(f'{k}={v}' for k, v in zip(dims, have, strict=True))}"
        )
    frame_skip = check_int_at_least("frame_skip", frame_skip, 1)
    steps = check_int_at_least("steps", steps, 1)
    quantile = check_real_in_range("quantile", quantile, 0.0, 1.0)
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
