r"""One compiled call per control period: sensor chain, observer recursion and the wrapper's outputs.

A wrapped environment step on a small model (InvertedPendulum-v5: ~30 us of physics and Python) has room for
only a few microseconds of sensing, and each Python-level operation costs two to three times more right after
``mj_step`` (the simulator has evicted the interpreter's caches) than in a micro-benchmark. So the wrapper's hot
path is one compiled function per observer kernel that, for the ``T`` samples of a control period,

1. runs the sensor chain (:func:`smo_gym.sensors._chain_kernel`, same random numbers as ``Sensor.run``),
2. advances the observer (its own compiled kernel, the same one ``Observer.update`` calls), all or nothing:
   the state is committed only if every sample passed,
3. writes the sensed state into the scratch ``MjData`` (measured or filtered ``qpos``, estimated ``qvel``) and
   the ``info["smo"]`` block (true ``qpos``, true ``qvel``, estimated ``qvel``, measured ``qpos``),
4. and, where the observation is a clipped selection of ``qpos``/``qvel`` (probed by the adapter: Hopper,
   HalfCheetah, Walker2d, Swimmer, InvertedPendulum), the observation itself.

Free and ball joints go through the same compiled tangent coordinates as the general path
(:mod:`smo_gym.wrappers._tangent`).

The numbers are those of the general path (``Sensor.run`` then ``Observer.run``), bit for bit (tested). The
function is generic in the kernel and inlined into one cached driver per kernel (a compiled function taking the
kernel as an argument would be recompiled in every new process, see :mod:`smo_gym.observers._kernels`); kernels
without a driver here use the general path.

Status codes of a driver: ``-1`` success; ``t * nv + j >= 0`` the sensor produced a non-finite value at sample
``t``, channel ``j``; ``-2 - (t * nv + j)`` the observer's state became non-finite there.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .._numba_cache import drop_stale
from ..observers import _kernels as K
from ..sensors import _chain_kernel
from ._tangent import integrate_pos, tangent_advance

__all__ = ["FUSED_DRIVERS", "register_fused_driver"]


@njit(error_model="numpy", inline="always")
def _sense(kernel, Q, qvel_true, t0, est, info, Zm, obs, kinds, sparams, sstate, ring, ring_pos, rand, state, params,
           work, scratch_qpos, scratch_qvel, filtered, joints, prev, z, obs_index, obs_bounds):
    """Sensor, observer and outputs for the samples ``Q`` (T, nq) of one control period (see module docstring).

    The arguments that change every call come first (the caller appends the others as one prepared tuple):
    ``qvel_true`` (nv,) the live velocity, ``t0`` the sensor's position in its random block ``rand``, ``est``
    (nv, m) receives the estimate at the last sample, ``info`` (2 nq + 4 nv,) the block
    ``[qpos, qvel, qvel_estimate, qpos_measured, z_true, z_measured]``, ``Zm`` (>= T, nv) the measurements (work
    space), ``obs`` (n_obs,) receives the observation if it is a selection of the sensed state (empty otherwise,
    see the end). Then the sensor's arrays (``kinds`` ... ``rand``, see :class:`smo_gym.sensors.Sensor`), the
    observer's state (nv, S) and parameters, ``work`` (2, nv, S) ping-pong buffers of the state, the scratch
    ``qpos``/``qvel`` of the observation, ``filtered`` (put the observer's filtered value instead of the
    measurement into ``scratch_qpos``), and the tangent coordinates of free/ball joints
    (:mod:`smo_gym.wrappers._tangent`): ``joints`` (njnt, 3), empty for a model without them (then ``z = qpos``),
    ``prev`` (nq,) the last configuration and ``z`` (nv,) its tangent coordinates, both advanced in place. Last,
    for an observation that is a selection of the sensed state (:attr:`GymnasiumMujocoAdapter.observation_map
    <smo_gym.wrappers.adapters.GymnasiumMujocoAdapter.observation_map>`): ``obs[i] = min(max(x[obs_index[i]],
    obs_bounds[0, i]), obs_bounds[1, i])`` with ``x = [scratch_qpos, scratch_qvel]``.
    """
    T, nq = Q.shape
    n, S = state.shape
    manifold = joints.shape[0] > 0
    for c in range(n):
        for j in range(S):
            work[0, c, j] = state[c, j]
    cur = 0
    for t in range(T):
        if manifold:
            tangent_advance(joints, prev, Q[t], z)
            y = z
        else:
            y = Q[t]
        status = _chain_kernel(y, kinds, sparams, sstate, ring, ring_pos, rand[t0 + t], False, Zm[t])
        if status != -1:
            return t * n + status
        status = kernel(work[cur], Zm[t], params, work[1 - cur], est)
        if status != -1:
            return -2 - (t * n + (-2 - status if status <= -2 else status))
        cur = 1 - cur
    for c in range(n):
        for j in range(S):
            state[c, j] = work[cur, c, j]
    last = Q[T - 1]
    zm = Zm[T - 1]
    o_qvel, o_vhat, o_qmeas, o_z, o_zm = nq, nq + n, nq + 2 * n, 2 * nq + 2 * n, 2 * nq + 3 * n
    for i in range(nq):
        info[i] = last[i]
    for c in range(n):
        info[o_qvel + c] = qvel_true[c]
        info[o_vhat + c] = est[c, 1]
        info[o_zm + c] = zm[c]
        info[o_z + c] = z[c] if manifold else last[c]
        scratch_qvel[c] = est[c, 1]
    if manifold:  # measured configuration q (+) (z_meas - z), filtered one q_meas (+) (z_filtered - z_meas)
        dz = np.empty(n)
        for c in range(n):
            dz[c] = zm[c] - z[c]
        for i in range(nq):
            info[o_qmeas + i] = last[i]
        integrate_pos(joints, info[o_qmeas:o_qmeas + nq], dz)
        for i in range(nq):
            scratch_qpos[i] = info[o_qmeas + i]
        if filtered:
            for c in range(n):
                dz[c] = est[c, 0] - zm[c]
            integrate_pos(joints, scratch_qpos, dz)
    else:
        for c in range(n):
            info[o_qmeas + c] = zm[c]
            scratch_qpos[c] = est[c, 0] if filtered else zm[c]
    for i in range(obs.shape[0]):  # np.clip's order: the lower bound first
        k = obs_index[i]
        v = scratch_qpos[k] if k < nq else scratch_qvel[k - nq]
        v = max(v, obs_bounds[0, i])
        obs[i] = min(v, obs_bounds[1, i])
    return -1


# One cached driver per kernel, each naming its kernel: written out rather than generated, because numba caches a
# compiled function only if it is a module-level function whose body names its callees (see _kernels.py).
@njit(cache=True, error_model="numpy")
def _sense_sta_implicit(Q, qvel_true, t0, est, info, Zm, obs, kinds, sparams, sstate, ring, ring_pos, rand,
                        state, params, work, sq, sv, filtered, joints, prev, z, oi, ob):
    return _sense(K.sta_implicit_kernel, Q, qvel_true, t0, est, info, Zm, obs, kinds, sparams, sstate, ring, ring_pos,
                  rand, state, params, work, sq, sv, filtered, joints, prev, z, oi, ob)


@njit(cache=True, error_model="numpy")
def _sense_hosm(Q, qvel_true, t0, est, info, Zm, obs, kinds, sparams, sstate, ring, ring_pos, rand,
                state, params, work, sq, sv, filtered, joints, prev, z, oi, ob):
    return _sense(K.hosm_kernel, Q, qvel_true, t0, est, info, Zm, obs, kinds, sparams, sstate, ring, ring_pos,
                  rand, state, params, work, sq, sv, filtered, joints, prev, z, oi, ob)


@njit(cache=True, error_model="numpy")
def _sense_eigmap(Q, qvel_true, t0, est, info, Zm, obs, kinds, sparams, sstate, ring, ring_pos, rand,
                  state, params, work, sq, sv, filtered, joints, prev, z, oi, ob):
    return _sense(K.eigmap_kernel, Q, qvel_true, t0, est, info, Zm, obs, kinds, sparams, sstate, ring, ring_pos,
                  rand, state, params, work, sq, sv, filtered, joints, prev, z, oi, ob)


@njit(cache=True, error_model="numpy")
def _sense_linear(Q, qvel_true, t0, est, info, Zm, obs, kinds, sparams, sstate, ring, ring_pos, rand,
                  state, params, work, sq, sv, filtered, joints, prev, z, oi, ob):
    return _sense(K.linear_kernel, Q, qvel_true, t0, est, info, Zm, obs, kinds, sparams, sstate, ring, ring_pos,
                  rand, state, params, work, sq, sv, filtered, joints, prev, z, oi, ob)


@njit(cache=True, error_model="numpy")
def _sense_kalman_ca(Q, qvel_true, t0, est, info, Zm, obs, kinds, sparams, sstate, ring, ring_pos, rand,
                     state, params, work, sq, sv, filtered, joints, prev, z, oi, ob):
    return _sense(K.kalman_ca_kernel, Q, qvel_true, t0, est, info, Zm, obs, kinds, sparams, sstate, ring, ring_pos,
                  rand, state, params, work, sq, sv, filtered, joints, prev, z, oi, ob)


@njit(cache=True, error_model="numpy")
def _sense_finite_difference(Q, qvel_true, t0, est, info, Zm, obs, kinds, sparams, sstate, ring, ring_pos, rand,
                             state, params, work, sq, sv, filtered, joints, prev, z, oi, ob):
    return _sense(K.finite_difference_kernel, Q, qvel_true, t0, est, info, Zm, obs, kinds, sparams, sstate, ring,
                  ring_pos, rand, state, params, work, sq, sv, filtered, joints, prev, z, oi, ob)


#: observer kernel -> its fused driver
FUSED_DRIVERS = {
    K.sta_implicit_kernel: _sense_sta_implicit,
    K.hosm_kernel: _sense_hosm,
    K.eigmap_kernel: _sense_eigmap,
    K.linear_kernel: _sense_linear,
    K.kalman_ca_kernel: _sense_kalman_ca,
    K.finite_difference_kernel: _sense_finite_difference,
}


def register_fused_driver(kernel, driver) -> None:
    """Register the fused driver of another observer kernel.

    ``driver`` must be ``return _sense(kernel, ...)`` with the signature above, compiled with
    ``@njit(cache=True)`` at module level.
    """
    FUSED_DRIVERS[kernel] = driver


# the drivers inline the observer kernels, the sensor chain and the tangent arithmetic of other modules: drop
# their cached machine code when one of those is newer (numba keys the cache on this file only)
def _dependencies() -> list[str]:
    from .. import sensors
    from . import _tangent

    return [K.__file__, sensors.__file__, _tangent.__file__]


drop_stale(FUSED_DRIVERS.values(), _dependencies())
