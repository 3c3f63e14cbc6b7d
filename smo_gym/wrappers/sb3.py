r"""``VecEstimatedVelocity``: the Stable-Baselines3 vector-env form of the sensing wrapper (see :mod:`.vec`).

Its own module so that ``import smo_gym.wrappers`` does not import Stable-Baselines3 (and torch); the name is
exported lazily by :mod:`smo_gym.wrappers`.
"""

from __future__ import annotations

import inspect
import pickle

import gymnasium as gym
import numpy as np

from .._extras import require
from .._validation import check_equal
from .sensing import SensingInfo, check_seed
from .vec import _Sensing, attach_sensors, check_vector_rate, sensing_config

__all__ = ["VecEstimatedVelocity"]

_vec_env = require("stable_baselines3.common.vec_env", "rl")
DummyVecEnv, VecEnv, VecEnvWrapper = _vec_env.DummyVecEnv, _vec_env.VecEnv, _vec_env.VecEnvWrapper


class VecEstimatedVelocity(_Sensing, VecEnvWrapper):
    r"""SB3 vector-env wrapper: measured positions and batched velocity estimates for every environment.

    One observer of batch shape ``(n_envs, nv)`` is updated once per vector step (``rate="env"``: one sample per
    environment step). The observation space is the wrapped one, unchanged.

    Parameters
    ----------
    venv : stable_baselines3.common.vec_env.VecEnv
        Vector env of Gymnasium MuJoCo environments. With a ``DummyVecEnv`` its environments are wrapped in
        :class:`JointSensor` here if they are not already; any other vector env (``SubprocVecEnv``) must be
        built with ``JointSensor`` inside (``make_vec_env(..., wrapper_class=JointSensor,
        wrapper_kwargs=sensing_config(...))``).
    sensor, observer, observer_kwargs, **kwargs
        The sensing (:func:`sensing_config`, :class:`EstimatedVelocity`'s options); ``None`` (default when the
        sub-environments already have ``JointSensor``) takes theirs. Given and different: ``ValueError``.

    Notes
    -----
    ``infos[i]["smo"]`` is the per-environment wrapper's :class:`~smo_gym.wrappers.sensing.SensingInfo` (true
    ``qpos``/``qvel``, ``qvel_estimate``, ``qpos_measured`` and the clean ``observation``); for an environment whose
    episode ended in this step it describes that episode's last sample, like ``terminal_observation``. Sampling
    is once per environment step (``rate="env"``; see :func:`~smo_gym.wrappers.vec.check_vector_rate`).
    Pickles without ``venv`` (``__getstate__`` drops it; :meth:`set_venv` attaches one, as SB3's
    ``VecNormalize``); :meth:`save` / :meth:`load`. Stack ``VecNormalize`` *on top*: it then normalizes the
    sensed observations and the rewritten terminal observations.
    """

    def __init__(self, venv, sensor=None, observer=None, observer_kwargs=None, *, rate="env", **kwargs):
        check_vector_rate(rate)
        VecEnvWrapper.__init__(self, venv)
        self._requested = (
            None
            if sensor is None and observer is None and not kwargs and observer_kwargs is None
            else sensing_config(sensor or "encoder-12bit-noisy", observer or "auto", observer_kwargs, **kwargs)
        )
        self._attach(venv)

    def _attach(self, venv) -> None:
        if not isinstance(venv.observation_space, gym.spaces.Box):
            raise TypeError(f"expected a Box observation space, actual value: {venv.observation_space}")
        base = venv.unwrapped
        sensors = attach_sensors(base.envs, self._requested) if isinstance(base, DummyVecEnv) else None
        self._setup_sensing(self._requested, venv.num_envs, sensors)
        self._estimate = None

    def _call_envs(self, name: str, *args) -> list:
        return self.venv.env_method(name, *args)

    def _all_have(self, name: str) -> bool:
        return bool(self.venv.has_attr(name))

    # ---- VecEnv API -----------------------------------------------------------------------------------------
    def _reset_infos(self):
        return self.venv.unwrapped.reset_infos

    def reset(self):
        self._require_venv()
        self.venv.reset()
        positions = None
        if self._local is not None:
            Z = np.array([s.z_reset for s in self._local], dtype=np.float64)
            positions = self._local_positions()
            self._local_batch()  # the sensors have their streams now
        else:
            Z = np.array([info["smo_z"] for info in self._reset_infos()], dtype=np.float64)
        est = self._full_reset(Z)
        obs, _ = self._observe_all(est, positions)
        return obs

    def _require_venv(self):
        if self.venv is None:
            raise RuntimeError("expected a venv, actual value: none (unpickled or loaded: attach one with set_venv)")

    def step_async(self, actions: np.ndarray) -> None:
        self._require_venv()
        self._check_batch(actions, self.venv.action_space.shape)
        self.venv.step_async(actions)

    def seed(self, seed: int | None = None):
        """The environments' seeds at the next reset, ``seed + i`` (SB3's convention), checked now: a bad one would
        make every later reset fail."""
        self._require_venv()
        return self.venv.seed(check_seed(seed))

    def step_wait(self):
        if self.observer.shape is None:
            raise RuntimeError("expected reset() before step(), actual value: the wrapper was never reset")
        local = self._local
        if local is not None:
            batch = self._local_batch()
        _, rewards, dones, infos = self.venv.step_wait()
        done = np.asarray(dones, dtype=bool)
        ended = done if done.any() else None
        together = self._step_together() if ended is None else None
        terminal = None
        if together is not None:  # every environment goes on: one compiled call
            block, clean, est, obs = together
        else:
            if local is not None:
                # the environments that go on, measured together; the finished episodes' last samples, measured by
                # their JointSensor before the autoreset
                block, clean = self._local_block(ended, terminal=ended)
                Z = np.ascontiguousarray(block[:, batch.slices[5]])
            else:
                Z = np.array([info["smo_z"] for info in infos], dtype=np.float64)
            est = self._update(Z)  # one batched call for every environment (the last sample of finished episodes)
            if ended is not None:
                terminal = est  # the masked reset below returns a new estimate, and leaves this one as it is
                reset_infos = self._reset_infos()
                Z0 = Z.copy()
                for i in np.flatnonzero(done):
                    Z0[i] = local[i].z_reset if local is not None else reset_infos[i]["smo_z"]
                est = self.observer.reset(Z0, mask=done)  # their observers restart at their new first sample
            positions = None if local is None else self._local_positions(block, ended)
            obs, terms = self._observe_all(est, positions, terminal, ended)
        vel = self.estimator.velocity_of(terminal if terminal is not None else est)
        # the step's sample of every environment (a finished episode's last one, as terminal_observation)
        if local is not None:
            block[:, batch.slices[2]] = vel
            for info, sample in zip(infos, SensingInfo.rows(block, batch.slices[:4], clean), strict=True):
                info["smo"] = sample
        else:
            for info, v in zip(infos, vel, strict=True):
                s = info["smo"]
                info["smo"] = SensingInfo.of(s["qpos"], s["qvel"], v, s["qpos_measured"], s["observation"])
        if ended is not None:
            for i in np.flatnonzero(ended):
                infos[i]["terminal_observation"] = terms[i]
        return obs, rewards, dones, infos

    # ---- pickling without the venv (SB3 VecNormalize style) -------------------------------------------------
    def __getstate__(self):
        state = self.__dict__.copy()
        for key in ("venv", "class_attributes", "_local", "_index", "_plan_cache", "_batch", "_together"):
            state.pop(key, None)
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self.venv = None

    def set_venv(self, venv) -> None:
        """Attach a venv after unpickling/loading (with the saved observation and action spaces); then ``reset()``."""
        if self.venv is not None:
            raise ValueError("expected a wrapper without a venv (unpickled or loaded), actual value: it has one")
        if not isinstance(venv, VecEnv):
            raise TypeError(f"expected a stable_baselines3 VecEnv, actual value: {venv!r:.80}")
        check_equal("a venv with observation space", self.observation_space, venv.observation_space)
        check_equal("a venv with action space", self.action_space, venv.action_space)
        try:
            self.venv, self.num_envs, self.render_mode = venv, venv.num_envs, venv.render_mode
            self.class_attributes = dict(inspect.getmembers(self.__class__))
            self._requested = self.config
            self._attach(venv)
        except BaseException:  # refused (another sensing, say): without a venv, as before
            self.venv = None
            raise

    def save(self, path) -> None:
        """Pickle the wrapper (sensing options and observer, no venv) to ``path``."""
        with open(path, "wb") as fh:
            pickle.dump(self, fh)

    @staticmethod
    def load(path, venv) -> VecEstimatedVelocity:
        """Load a wrapper saved by :meth:`save` onto ``venv``."""
        with open(path, "rb") as fh:
            wrapper = pickle.load(fh)
        if not isinstance(wrapper, VecEstimatedVelocity):
            raise TypeError(f"expected a saved VecEstimatedVelocity, actual value: {type(wrapper).__name__}")
        wrapper.set_venv(venv)
        return wrapper
