r"""The Gymnasium side of sensing: ``info["smo"]``, and the checks of actions and seeds."""

from __future__ import annotations

import numpy as np

from ..engine.measurement import first_nonfinite_entry

__all__ = ["SensingInfo", "check_action", "check_seed"]

_FAST_DTYPES = (np.dtype(np.float32), np.dtype(np.float64))


def check_action(action, shape: tuple[int, ...]) -> None:
    """Raise a typed error for an action that is not of ``shape`` or has an entry that is not a finite real number.

    MuJoCo would otherwise zero a NaN or infinite control with a warning printed to stdout, and cast a complex
    one to its real part, silently. One compiled call for the float32 and float64 actions of RL libraries.
    """
    if type(action) is np.ndarray and action.shape == shape and action.dtype in _FAST_DTYPES:
        if action.ndim == 1:
            if first_nonfinite_entry(action.dtype)(action) == -1:
                return
        elif action.flags.c_contiguous and first_nonfinite_entry(action.dtype)(action.reshape(-1)) == -1:
            return  # a vector env's batch; a refused one is reported below, with its (environment, entry)
    try:
        arr = np.asarray(action)
    except (TypeError, ValueError):
        arr = np.asarray(None)
    if arr.dtype.kind not in "biuf":
        raise TypeError(f"expected an action of real numbers with shape {shape}, actual value: {action!r:.120}")
    if arr.shape != shape:
        raise ValueError(f"expected an action with shape {shape}, actual value: shape {arr.shape}")
    flat = arr.reshape(-1)
    bad = np.flatnonzero(~np.isfinite(flat.astype(np.float64)))
    if bad.size:  # a vector env's batch: (environment, entry)
        at = tuple(int(i) for i in np.unravel_index(bad[0], shape)) if len(shape) > 1 else int(bad[0])
        raise ValueError(f"expected a finite action, actual value: {flat[bad[0]]!r} at entry {at}")


def check_seed(seed) -> int | None:
    """``reset(seed=...)``'s None or integer >= 0, as a Python int (Gymnasium refuses NumPy ones), or a typed error."""
    if seed is None:
        return None
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise TypeError(f"expected seed to be None or an integer >= 0, actual value: {seed!r:.80}")
    if seed < 0:
        raise ValueError(f"expected seed to be None or an integer >= 0, actual value: {seed!r}")
    return int(seed)


class SensingInfo(dict):
    """``info["smo"]``: the true and the sensed state at the last sample, read-only.

    The same keys from :class:`~smo_gym.wrappers.EstimatedVelocity` and, per environment, from both vector
    wrappers:

    ==================  ===============  ==========================================================================
    key                 shape            what
    ==================  ===============  ==========================================================================
    ``qpos``            ``(nq,)``        true joint configuration
    ``qvel``            ``(nv,)``        true joint velocities
    ``qvel_estimate``   ``(nv,)``        the observer's velocity estimate (what the observation holds)
    ``qpos_measured``   ``(nq,)``        the sensor's measured configuration
    ``observation``     the env's        the *clean* observation: what the wrapped stack returns at the true state
                                         (for privileged critics, and to measure the estimation error in
                                         observation space)
    ==================  ===============  ==========================================================================

    New arrays at every step, safe to keep. Neither the dictionary nor its arrays can be changed
    (``dict(info["smo"])`` and ``np.array(info["smo"]["qvel"])`` give mutable copies), so
    ``copy.copy``/``copy.deepcopy`` return the object itself: SB3's ``DummyVecEnv`` deep-copies every step's
    infos, and a generic deep copy of five small arrays costs more than a physics step of a small model.
    """

    __slots__ = ()

    @classmethod
    def of(cls, qpos, qvel, qvel_estimate, qpos_measured, observation) -> SensingInfo:
        """From the four state arrays (copied) and the clean observation (copied)."""
        return cls.from_block(
            np.concatenate((qpos, qvel, qvel_estimate, qpos_measured)), cls.slices(len(qpos), len(qvel)), observation
        )

    @classmethod
    def rows(cls, block: np.ndarray, slices: tuple, observations: np.ndarray) -> list[SensingInfo]:
        """One per row of ``block`` ``(n, ...)``, rows ``[qpos, qvel, qvel_estimate, qpos_measured, ...]``
        (``slices`` from :meth:`slices`), and of the clean observations ``observations`` ``(n, ...)``: a vector
        env's samples, each of views of one row. Both arrays are owned from now on (made read-only)."""
        block.setflags(write=False)
        observations.setflags(write=False)
        s0, s1, s2, s3 = slices
        return [
            cls(qpos=row[s0], qvel=row[s1], qvel_estimate=row[s2], qpos_measured=row[s3], observation=observation)
            for row, observation in zip(block, observations, strict=True)
        ]

    @staticmethod
    def slices(nq: int, nv: int) -> tuple[slice, slice, slice, slice]:
        """Where ``qpos``, ``qvel``, ``qvel_estimate`` and ``qpos_measured`` lie in a block (computed once per
        wrapper: the per-step path only slices)."""
        return (slice(0, nq), slice(nq, nq + nv), slice(nq + nv, nq + 2 * nv), slice(nq + 2 * nv, 2 * nq + 2 * nv))

    @classmethod
    def from_block(cls, block: np.ndarray, slices: tuple, observation) -> SensingInfo:
        """From one block ``[qpos, qvel, qvel_estimate, qpos_measured, ...]`` (anything after these four is
        ignored; ``slices`` from :meth:`slices`), which it owns from now on (made read-only, as are its views),
        and the clean observation (an array or a dict of arrays, copied)."""
        block.setflags(write=False)
        s0, s1, s2, s3 = slices
        return cls(  # from a literal: every step pays this, and keyword arguments cost more
            {
                "qpos": block[s0],
                "qvel": block[s1],
                "qvel_estimate": block[s2],
                "qpos_measured": block[s3],
                "observation": _read_only_copy(observation),
            }
        )

    def _readonly(self, *args, **kwargs):
        raise TypeError(
            "expected no change to info['smo'] (read-only), actual value: an attempt to modify it; "
            "dict(info['smo']) is a mutable copy"
        )

    __setitem__ = __delitem__ = update = pop = popitem = clear = setdefault = __ior__ = _readonly

    def __copy__(self):
        return self

    def __deepcopy__(self, memo):
        return self

    def __reduce__(self):
        return _sensing_info, (dict(self),)


def _sensing_info(items: dict) -> SensingInfo:
    """Unpickle a :class:`SensingInfo` (its ``__setitem__`` refuses the default per-item restore)."""
    return SensingInfo({key: _read_only_copy(value) for key, value in items.items()})


def _read_only_copy(value):
    """A read-only copy of an array, or of every array of a dict (a dict observation)."""
    if type(value) is np.ndarray:  # every step's case, first: a copy and no conversion
        value = value.copy()
    elif isinstance(value, dict):
        return {key: _read_only_copy(item) for key, item in value.items()}
    else:
        value = np.array(value)
    value.setflags(write=False)
    return value
