r"""Default design of the dissipative super-twisting observer for a MuJoCo model (Apaza-Perez, Moreno and Fridman).

The observer of :class:`smo_gym.observers.DissipativeSuperTwisting` needs a coordinate transform that removes the
Coriolis terms and gains from the dissipativity of the unknown input; both are computed here from the model
alone, per joint.
"""

from __future__ import annotations

import numpy as np

from .._validation import check_nonnegative_array
from ..design import apaza_gains
from ..observers import CoordinateTransform
from .dynamics import MujocoDynamics

__all__ = ["default_transform", "dissipative_gains"]


def default_transform(dyn: MujocoDynamics, grid: int = 201) -> CoordinateTransform:
    """The transform of every joint's self-quadratic term (:meth:`MujocoDynamics.alpha_function` at ``qpos0``)
    over the joint's range (``jnt_range`` if limited, else :math:`\\pm\\pi`), referenced at ``qpos0`` (clipped)."""
    model = dyn.model
    jid = [model.dof_jntid[d] for d in dyn.dof]
    lower = np.array([model.jnt_range[j, 0] if model.jnt_limited[j] else -np.pi for j in jid])
    upper = np.array([model.jnt_range[j, 1] if model.jnt_limited[j] else np.pi for j in jid])
    ref = np.clip(model.qpos0[dyn.dof], lower, upper)
    return CoordinateTransform(dyn.alpha_function(), lower, upper, reference=ref, grid=grid)


def dissipative_gains(dyn: MujocoDynamics, transform: CoordinateTransform, lipschitz) -> dict:
    r"""Gains ``k1, k2, k3, mu1, mu2`` per joint (arrays of shape ``(n,)``) from :func:`smo_gym.design.apaza_gains`.

    Joint ``i`` gets the bound :math:`L_w` = ``lipschitz[i]`` of its unknown input and the dissipativity of its
    damping, :math:`(q, s, r) = (-1, -c/2, 0)` with :math:`c = d_i / \min M_{ii}` (the largest damping rate over
    the joint's range, the other joints at ``qpos0``), and :math:`\Upsilon_{max}` the largest of the transform's
    grid (at least 1).
    """
    if not isinstance(dyn, MujocoDynamics) or not isinstance(transform, CoordinateTransform):
        raise TypeError(
            "expected a MujocoDynamics and a CoordinateTransform, actual value: "
            f"{type(dyn).__name__} and {type(transform).__name__}"
        )
    if transform.grid_y.shape[1] != dyn.n:
        raise ValueError(
            f"expected a transform of the {dyn.n} joints of the dynamics, actual value: {transform.grid_y.shape[1]}"
        )
    lipschitz = check_nonnegative_array("lipschitz", lipschitz)
    if lipschitz.shape not in ((), (1,), (dyn.n,)):
        raise ValueError(f"expected lipschitz scalar or of shape ({dyn.n},), actual value: shape {lipschitz.shape}")
    lipschitz = np.broadcast_to(lipschitz, (dyn.n,))
    ref = dyn.model.qpos0[dyn.dof].copy()
    rows = []
    for i in range(dyn.n):
        ys = transform.grid_y[:, i]
        inertia = []
        for y in ys[:: max(1, len(ys) // 20)]:
            q = ref.copy()
            q[i] = y
            inertia.append(dyn.inertia(q)[i, i])
        c = float(dyn.model.dof_damping[dyn.dof[i]]) / min(inertia)
        upsilon = max(1.0, float(transform.grid_upsilon[:, i].max()))
        rows.append(apaza_gains(float(lipschitz[i]), q=-1.0, s=-c / 2.0, r=0.0, upsilon_max=upsilon).as_dict())
    return {key: np.array([r[key] for r in rows]) for key in ("k1", "k2", "k3", "mu1", "mu2")}
