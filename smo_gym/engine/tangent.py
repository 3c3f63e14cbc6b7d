r"""Compiled configuration-space arithmetic for free and ball joints (MuJoCo's ``mj_differentiatePos`` and
``mj_integratePos`` with a unit step), shared by :class:`~smo_gym.engine.measurement.TangentCoordinates` and the
wrapper's fused hot path (:mod:`smo_gym.engine.fused`), so both compute the same numbers.

Joints are described by a table ``joints`` (njnt, 3) of ``(type, qpos address, dof address)`` rows
(:func:`joint_table`). A free joint is a translation (3 ``qpos``, 3 dofs, plain differences) followed by a unit
quaternion; a ball joint is a unit quaternion (4 ``qpos``, 3 dofs); hinge and slide joints are scalars. For a
rotation, the difference of two configurations is the body-frame rotation vector

.. math:: q_1 \ominus q_2 = \log(q_1^{-1} q_2) \in \mathbb R^3,

and the sum :math:`q \oplus v = q \exp(v/2)` (quaternion product on the right: MuJoCo's angular velocities of
free and ball joints are in the local frame). The formulas follow MuJoCo's ``mju_subQuat``/``mju_quat2Vel`` and
``mju_quatIntegrate`` (engine_util_spatial.c); tested against ``mj_differentiatePos``/``mj_integratePos`` to
round-off.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
from numba import njit

__all__ = ["differentiate_pos", "integrate_pos", "joint_table", "tangent_advance"]

#: MuJoCo's joint type codes of the joints with a quaternion (hinge and slide joints are copied as they are)
FREE, BALL = int(mujoco.mjtJoint.mjJNT_FREE), int(mujoco.mjtJoint.mjJNT_BALL)
#: MuJoCo's mjMINVAL: below this a norm counts as zero
_MINVAL = 1e-15


def joint_table(model: mujoco.MjModel) -> np.ndarray:
    """``(type, qpos address, dof address)`` of every joint, shape ``(njnt, 3)``, int64."""
    return np.ascontiguousarray(
        np.stack([np.asarray(model.jnt_type), np.asarray(model.jnt_qposadr), np.asarray(model.jnt_dofadr)], axis=1)
        .astype(np.int64)
        .reshape(-1, 3)
    )


@njit(cache=True)
def _normalize3(x, y, z):
    """``(x, y, z) / norm`` and ``norm``, MuJoCo's ``mju_normalize3``: ``(1, 0, 0)`` below ``mjMINVAL``."""
    norm = math.sqrt(x * x + y * y + z * z)
    if norm < _MINVAL:
        return 1.0, 0.0, 0.0, norm
    inv = 1.0 / norm
    return x * inv, y * inv, z * inv, norm


@njit(cache=True)
def _sub_quat(qa, a, qb, b, out, o, accumulate):
    r"""``out[o:o+3] = log(qb^{-1} qa)`` (rotation vector; ``+=`` with ``accumulate``), MuJoCo's
    ``mju_subQuat(res, qa, qb)``."""
    # qdif = conj(qb) * qa
    w0, x0, y0, z0 = qb[b], -qb[b + 1], -qb[b + 2], -qb[b + 3]
    w1, x1, y1, z1 = qa[a], qa[a + 1], qa[a + 2], qa[a + 3]
    w = w0 * w1 - x0 * x1 - y0 * y1 - z0 * z1
    x = w0 * x1 + x0 * w1 + y0 * z1 - z0 * y1
    y = w0 * y1 - x0 * z1 + y0 * w1 + z0 * x1
    z = w0 * z1 + x0 * y1 - y0 * x1 + z0 * w1
    # quat2Vel: axis-angle of qdif, the angle wrapped to (-pi, pi]
    x, y, z, norm = _normalize3(x, y, z)
    speed = 2.0 * math.atan2(norm, w)
    if speed > math.pi:
        speed -= 2.0 * math.pi
    if accumulate:
        out[o] += x * speed
        out[o + 1] += y * speed
        out[o + 2] += z * speed
    else:
        out[o] = x * speed
        out[o + 1] = y * speed
        out[o + 2] = z * speed


@njit(cache=True)
def _quat_integrate(q, a, v, d):
    r"""``q[a:a+4] <- normalize(q) * exp(v[d:d+3] / 2)``, MuJoCo's ``mju_quatIntegrate(quat, vel, 1)``."""
    vx, vy, vz, angle = _normalize3(v[d], v[d + 1], v[d + 2])
    if angle == 0.0:
        rw, rx, ry, rz = 1.0, 0.0, 0.0, 0.0
    else:
        s = math.sin(angle * 0.5)
        rw, rx, ry, rz = math.cos(angle * 0.5), vx * s, vy * s, vz * s
    w, x, y, z = q[a], q[a + 1], q[a + 2], q[a + 3]
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    if norm < _MINVAL:
        w, x, y, z = 1.0, 0.0, 0.0, 0.0
    elif abs(norm - 1.0) > _MINVAL:
        inv = 1.0 / norm
        w, x, y, z = w * inv, x * inv, y * inv, z * inv
    q[a] = w * rw - x * rx - y * ry - z * rz
    q[a + 1] = w * rx + x * rw + y * rz - z * ry
    q[a + 2] = w * ry - x * rz + y * rw + z * rx
    q[a + 3] = w * rz + x * ry - y * rx + z * rw


@njit(cache=True)
def differentiate_pos(joints, qpos1, qpos2, out):
    r"""``out = qpos2 \ominus qpos1`` (nv,): MuJoCo's ``mj_differentiatePos`` with ``dt = 1``."""
    for j in range(joints.shape[0]):
        kind, a, d = joints[j, 0], joints[j, 1], joints[j, 2]
        if kind == FREE:
            for i in range(3):
                out[d + i] = qpos2[a + i] - qpos1[a + i]
            _sub_quat(qpos2, a + 3, qpos1, a + 3, out, d + 3, False)
        elif kind == BALL:
            _sub_quat(qpos2, a, qpos1, a, out, d, False)
        else:
            out[d] = qpos2[a] - qpos1[a]


@njit(cache=True)
def integrate_pos(joints, qpos, v):
    r"""``qpos <- qpos \oplus v`` in place: MuJoCo's ``mj_integratePos`` with ``dt = 1``."""
    for j in range(joints.shape[0]):
        kind, a, d = joints[j, 0], joints[j, 1], joints[j, 2]
        if kind == FREE:
            for i in range(3):
                qpos[a + i] += v[d + i]
            _quat_integrate(qpos, a + 3, v, d + 3)
        elif kind == BALL:
            _quat_integrate(qpos, a, v, d)
        else:
            qpos[a] += v[d]


@njit(cache=True)
def tangent_advance(joints, prev, q, z):
    r"""Continuous tangent coordinates: ``z += q \ominus prev`` for free joints and ball joints, ``z = q`` for hinge
    and slide dofs, then ``prev = q`` (see :class:`~smo_gym.engine.measurement.TangentCoordinates`)."""
    for j in range(joints.shape[0]):
        kind, a, d = joints[j, 0], joints[j, 1], joints[j, 2]
        if kind == FREE:
            for i in range(3):
                z[d + i] += q[a + i] - prev[a + i]
            _sub_quat(q, a + 3, prev, a + 3, z, d + 3, True)
        elif kind == BALL:
            _sub_quat(q, a, prev, a, z, d, True)
        else:
            z[d] = q[a]
    for i in range(q.shape[0]):
        prev[i] = q[i]
