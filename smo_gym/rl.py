r"""Reinforcement learning with realistic sensing: environments, training and evaluation with Stable-Baselines3.

A *sensing* says what the policy observes of a MuJoCo environment:

``"true"``
    the environment's own observation (true positions and velocities);
``"estimated"``
    :class:`~smo_gym.wrappers.EstimatedVelocity`: measured positions, velocities from an observer (default the
    wrapper's, super-twisting, at ``rate="physics"``);
``"finite-difference"``
    the same measurements, velocities by backward differences of consecutive samples;
``"no-velocity"``
    the same measured positions, every velocity-dependent entry set to zero (rl_zoo3's ``MaskVelocityWrapper``,
    with the entries found generically by :func:`velocity_entries`);
``"stacked-positions"``
    the same measured positions without the velocity entries, the last two frames stacked (the policy may
    difference them itself).

Training (:func:`train`) writes a run folder: ``model.zip``, ``vecnormalize.pkl`` (PPO), ``run.json`` (the
sensing, the hyperparameters and, under ``evaluations``, the returns at the requested budgets), ``progress.csv``
(SB3 logger; TensorBoard event files too when ``tensorboard`` is installed) and ``checkpoints/``. Evaluation
(:func:`evaluate`) loads a run and plays it under *any* sensing with the same observation shape (a policy
trained on true velocities, deployed on estimates), with the training normalization statistics frozen.
"""

from __future__ import annotations

import copy
import json
import os
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

from .envs import make as make_by_id

__all__ = [
    "SENSINGS",
    "MaskEntries",
    "SelectEntries",
    "evaluate",
    "make_env",
    "make_vec",
    "train",
    "velocity_entries",
]

SENSINGS = ("true", "estimated", "finite-difference", "no-velocity", "stacked-positions")
ALGOS = ("PPO", "SAC")


# ----------------------------------------------------------------------------------------------------------------
# observation surgery
# ----------------------------------------------------------------------------------------------------------------
def velocity_entries(env: gym.Env, trials: int = 3, seed: int = 0) -> np.ndarray:
    r"""Indices of the observation entries that depend on the joint velocities.

    The environment's own observation function is evaluated on scratch data
    (:class:`~smo_gym.wrappers.GymnasiumMujocoAdapter`) at its current configuration with random velocities;
    an entry is velocity-dependent if it changes (``qvel`` itself, clipped velocities, ``cvel``, constraint
    forces that depend on velocity, ...). No per-environment table. Requires a reset environment.

    Returns
    -------
    ndarray of int, shape (n_velocity_entries,)
    """
    from .wrappers.adapters import GymnasiumMujocoAdapter

    adapter = GymnasiumMujocoAdapter(env.unwrapped)
    rng = np.random.default_rng(seed)
    qpos = np.array(adapter.data.qpos)
    nv = adapter.model.nv
    base = adapter.observation(qpos, np.zeros(nv))
    changed = np.zeros(base.shape, dtype=bool)
    for _ in range(trials):
        changed |= adapter.observation(qpos, rng.standard_normal(nv)) != base
    return np.flatnonzero(changed.reshape(-1))


class MaskEntries(gym.ObservationWrapper, gym.utils.RecordConstructorArgs):
    """Set the observation entries ``indices`` to zero (the observation space is unchanged)."""

    def __init__(self, env: gym.Env, indices):
        gym.utils.RecordConstructorArgs.__init__(self, indices=indices)
        gym.ObservationWrapper.__init__(self, env)
        self.indices = np.asarray(indices, dtype=int)

    def observation(self, observation):
        observation = np.array(observation, copy=True)
        observation[self.indices] = 0.0
        return observation


class SelectEntries(gym.ObservationWrapper, gym.utils.RecordConstructorArgs):
    """Keep only the observation entries ``indices`` (a Box of the selected bounds)."""

    def __init__(self, env: gym.Env, indices):
        gym.utils.RecordConstructorArgs.__init__(self, indices=indices)
        gym.ObservationWrapper.__init__(self, env)
        self.indices = np.asarray(indices, dtype=int)
        space = env.observation_space
        self.observation_space = gym.spaces.Box(space.low[self.indices], space.high[self.indices],
                                                dtype=space.dtype)

    def observation(self, observation):
        return np.asarray(observation)[self.indices]


# ----------------------------------------------------------------------------------------------------------------
# environments
# ----------------------------------------------------------------------------------------------------------------
def _check_sensing(sensing: str) -> None:
    if sensing not in SENSINGS:
        raise ValueError(f"expected sensing in {', '.join(SENSINGS)}, actual value: {sensing!r}")


def make_env(env_id: str, sensing: str = "estimated", *, sensor: str = "encoder-12bit-noisy",
             observer: str = "super-twisting", rate="physics", observer_kwargs: dict | None = None,
             env_kwargs: dict | None = None) -> gym.Env:
    """One environment under a sensing (see the module docstring)."""
    _check_sensing(sensing)
    env = make_by_id(env_id, **(env_kwargs or {}))
    if sensing == "true":
        return env
    from .wrappers import EstimatedVelocity

    if sensing in ("no-velocity", "stacked-positions"):
        observer, observer_kwargs = "finite-difference", None  # its velocities are masked or dropped anyway
    elif sensing == "finite-difference":
        observer, observer_kwargs = "finite-difference", None
    env = EstimatedVelocity(env, sensor=sensor, observer=observer, rate=rate, observer_kwargs=observer_kwargs)
    if sensing in ("estimated", "finite-difference"):
        return env
    env.reset(seed=0)
    vel = velocity_entries(env)
    if sensing == "no-velocity":
        return MaskEntries(env, vel)
    keep = np.setdiff1d(np.arange(int(np.prod(env.observation_space.shape))), vel)
    env = SelectEntries(env, keep)
    env = gym.wrappers.FrameStackObservation(env, 2)
    return gym.wrappers.FlattenObservation(env)


def make_vec(env_id: str, sensing: str = "estimated", *, n_envs: int = 1, seed: int | None = 0,
             sensor: str = "encoder-12bit-noisy", observer: str = "super-twisting", rate="physics",
             observer_kwargs: dict | None = None, env_kwargs: dict | None = None, vectorized: bool | None = None):
    """A ``DummyVecEnv`` (with ``Monitor``) of :func:`make_env` environments.

    With ``rate="env"`` and an estimating sensing (``"estimated"``, ``"finite-difference"``) the observers run
    batched in :class:`~smo_gym.wrappers.VecEstimatedVelocity` (``vectorized=None`` or ``True``); otherwise one
    :class:`~smo_gym.wrappers.EstimatedVelocity` per environment. Both give the same observations.
    """
    from stable_baselines3.common.env_util import make_vec_env

    _check_sensing(sensing)
    if vectorized is None:
        vectorized = rate == "env" and sensing in ("estimated", "finite-difference")
    if vectorized:
        if sensing not in ("estimated", "finite-difference"):
            raise ValueError(f"expected sensing 'estimated' or 'finite-difference' for vectorized sensing, "
                             f"actual value: {sensing!r}")
        from .wrappers import VecEstimatedVelocity, sensing_config

        obs_name = observer if sensing == "estimated" else "finite-difference"
        venv = make_vec_env(lambda: make_by_id(env_id, **(env_kwargs or {})), n_envs=n_envs, seed=seed)
        return VecEstimatedVelocity(venv, **sensing_config(sensor, obs_name,
                                                           observer_kwargs if sensing == "estimated" else None))
    return make_vec_env(lambda: make_env(env_id, sensing, sensor=sensor, observer=observer, rate=rate,
                                         observer_kwargs=observer_kwargs, env_kwargs=env_kwargs),
                        n_envs=n_envs, seed=seed)


# ----------------------------------------------------------------------------------------------------------------
# training
# ----------------------------------------------------------------------------------------------------------------
def _progress_callback():
    """SB3's rich progress bar when ``rich`` is installed, else a plain tqdm bar with the same role."""
    from stable_baselines3.common.callbacks import BaseCallback, ProgressBarCallback

    try:
        import rich  # noqa: F401

        return ProgressBarCallback()
    except ImportError:
        from tqdm.auto import tqdm

        class TqdmProgress(BaseCallback):
            def _on_training_start(self):
                self.pbar = tqdm(total=self.locals["total_timesteps"] - self.model.num_timesteps, unit="step")

            def _on_step(self):
                self.pbar.update(self.training_env.num_envs)
                return True

            def _on_training_end(self):
                self.pbar.close()

        return TqdmProgress()


def _logger(folder: Path, verbose: int):
    from stable_baselines3.common.logger import configure

    formats = ["csv"] + (["stdout"] if verbose else [])
    try:
        import tensorboard  # noqa: F401

        formats.append("tensorboard")
    except ImportError:
        pass
    return configure(str(folder), formats)


def _frozen_normalization(train_venv, eval_venv):
    """Wrap ``eval_venv`` in a ``VecNormalize`` with ``train_venv``'s observation statistics, frozen."""
    from stable_baselines3.common.vec_env import VecNormalize

    if not isinstance(train_venv, VecNormalize):
        return eval_venv
    norm = VecNormalize(eval_venv, training=False, norm_obs=train_venv.norm_obs, norm_reward=False,
                        clip_obs=train_venv.clip_obs)
    norm.obs_rms = copy.deepcopy(train_venv.obs_rms)
    return norm


def _returns(model, venv, episodes: int, deterministic: bool = True) -> np.ndarray:
    from stable_baselines3.common.evaluation import evaluate_policy

    rewards, _ = evaluate_policy(model, venv, n_eval_episodes=episodes, deterministic=deterministic,
                                 return_episode_rewards=True, warn=False)
    return np.asarray(rewards, dtype=float)


DEFAULT_HYPERPARAMS = {
    "PPO": {},  # SB3 defaults (n_steps=2048, batch_size=64, n_epochs=10, lr=3e-4), with VecNormalize
    "SAC": {},
}


def train(env_id: str, *, sensing: str = "estimated", sensor: str = "encoder-12bit-noisy",
          observer: str = "super-twisting", rate="physics", algo: str = "PPO", steps: int = 100_000, seed: int = 0,
          n_envs: int = 1, out: str | os.PathLike = "outputs/runs/run", normalize: bool | None = None,
          hyperparams: dict | None = None, checkpoint_every: int = 0, evaluate_at=(), eval_sensings=None,
          eval_episodes: int = 10, progress_bar: bool = False, verbose: int = 0, vectorized: bool | None = None,
          observer_kwargs: dict | None = None) -> dict:
    r"""Train an SB3 agent on ``env_id`` under a sensing; returns the run summary (also in ``out/run.json``).

    Parameters
    ----------
    sensing, sensor, observer, rate, observer_kwargs
        What the policy observes (:func:`make_env`).
    algo : {"PPO", "SAC"}
    steps : int
        Environment steps (summed over the ``n_envs`` environments).
    normalize : bool, optional
        ``VecNormalize`` (observations and rewards); default on for PPO, off for SAC.
    checkpoint_every : int
        Save a checkpoint (model and normalization) every so many steps; 0: none.
    evaluate_at : sequence of int
        Budgets (steps) at which the current policy is evaluated on ``eval_episodes`` episodes for each of
        ``eval_sensings`` (default: the training sensing), with the normalization statistics of that moment.
    progress_bar : bool
        SB3's progress bar (a tqdm bar when ``rich`` is missing).

    Returns
    -------
    dict
        ``run.json``'s content: the options, ``seconds``, ``steps_per_second`` and ``evaluations`` (a list of
        ``{"steps", "sensing", "returns", "mean", "std"}``).
    """
    import torch
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback
    from stable_baselines3.common.vec_env import VecNormalize

    _check_sensing(sensing)
    if algo not in ALGOS:
        raise ValueError(f"expected algo in {', '.join(ALGOS)}, actual value: {algo!r}")
    if steps < 1 or n_envs < 1:
        raise ValueError(f"expected steps >= 1 and n_envs >= 1, actual value: steps={steps}, n_envs={n_envs}")
    torch.set_num_threads(1)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    normalize = (algo == "PPO") if normalize is None else bool(normalize)
    sense = dict(sensor=sensor, observer=observer, rate=rate, observer_kwargs=observer_kwargs)
    venv = make_vec(env_id, sensing, n_envs=n_envs, seed=seed, vectorized=vectorized, **sense)
    if normalize:
        venv = VecNormalize(venv)
    params = dict(DEFAULT_HYPERPARAMS[algo])
    params.update(hyperparams or {})
    cls = PPO if algo == "PPO" else SAC
    model = cls("MlpPolicy", venv, seed=seed, verbose=verbose, device="cpu", **params)
    model.set_logger(_logger(out, verbose))
    evaluations: list[dict] = []
    budgets = sorted(int(b) for b in evaluate_at)
    eval_sensings = list(eval_sensings or [sensing])

    class Budgets(BaseCallback):
        # checked between rollouts (after the policy update) and at the end, so a budget's policy has been
        # trained on every sample collected up to it
        def _on_step(self_cb):
            return True

        def _on_rollout_start(self_cb):
            self_cb.evaluate()

        def _on_training_end(self_cb):
            self_cb.evaluate()

        def evaluate(self_cb):
            while budgets and self_cb.num_timesteps >= budgets[0]:
                at = budgets.pop(0)
                for k, s in enumerate(eval_sensings):
                    ev = _frozen_normalization(self_cb.training_env, make_vec(
                        env_id, s, n_envs=1, seed=10_000 + seed * 100 + k, **sense))
                    r = _returns(self_cb.model, ev, eval_episodes)
                    ev.close()
                    evaluations.append(dict(steps=at, trained_steps=int(self_cb.num_timesteps), sensing=s,
                                            returns=r.tolist(), mean=float(r.mean()), std=float(r.std())))

    callbacks = [Budgets()]
    if checkpoint_every > 0:
        callbacks.append(CheckpointCallback(max(checkpoint_every // n_envs, 1), str(out / "checkpoints"),
                                            name_prefix="model", save_vecnormalize=normalize))
    if progress_bar:
        callbacks.append(_progress_callback())
    t0 = time.perf_counter()
    model.learn(total_timesteps=int(steps), callback=callbacks)
    seconds = time.perf_counter() - t0
    model.save(out / "model.zip")
    if normalize:
        venv.save(str(out / "vecnormalize.pkl"))
    summary = dict(env=env_id, sensing=sensing, algo=algo, steps=int(steps), trained_steps=int(model.num_timesteps),
                   seed=int(seed), n_envs=int(n_envs), normalize=normalize, hyperparams=params,
                   seconds=seconds, steps_per_second=model.num_timesteps / seconds, evaluations=evaluations,
                   **{k: v for k, v in sense.items()})
    (out / "run.json").write_text(json.dumps(summary, indent=1, default=str))
    venv.close()
    return summary


def load_run(path: str | os.PathLike):
    """``(model, run)``: the SB3 model and ``run.json`` of a run folder (or of the folder of a ``model.zip``)."""
    from stable_baselines3 import PPO, SAC

    path = Path(path)
    folder = path if path.is_dir() else path.parent
    model_file = folder / "model.zip" if path.is_dir() else path
    if not model_file.exists():
        raise ValueError(f"expected a run folder or model.zip, actual value: {str(path)!r} (no {model_file})")
    run_file = folder / "run.json"
    run = json.loads(run_file.read_text()) if run_file.exists() else {}
    cls = SAC if run.get("algo") == "SAC" else PPO
    return cls.load(model_file, device="cpu"), run


def evaluate(model: str | os.PathLike, *, env_id: str | None = None, sensing: str | None = None,
             sensor: str | None = None, observer: str | None = None, rate=None, episodes: int = 10,
             seed: int = 10_000, deterministic: bool = True) -> dict:
    """Play a trained run under a sensing (default: the one it was trained with); the true return per episode.

    The training normalization statistics (``vecnormalize.pkl``) are loaded frozen. The sensing may differ from
    the training one if the observation shape is the same (true state, estimated, finite differences and
    masked velocities are interchangeable; stacked positions are not).

    Returns
    -------
    dict
        ``{"env", "sensing", "sensor", "observer", "rate", "returns", "mean", "std", "lengths"}``.
    """
    from stable_baselines3.common.vec_env import VecNormalize

    if episodes < 1:
        raise ValueError(f"expected episodes >= 1, actual value: {episodes}")
    agent, run = load_run(model)
    env_id = env_id or run.get("env")
    if env_id is None:
        raise ValueError("expected env_id (the run has no run.json), actual value: None")
    sensing = sensing or run.get("sensing", "true")
    _check_sensing(sensing)
    sense = dict(sensor=sensor or run.get("sensor", "encoder-12bit-noisy"),
                 observer=observer or run.get("observer", "super-twisting"),
                 rate=rate if rate is not None else run.get("rate", "physics"))
    venv = make_vec(env_id, sensing, n_envs=1, seed=seed, **sense)
    if venv.observation_space.shape != agent.observation_space.shape:
        raise ValueError(
            f"expected a sensing with the model's observation shape {agent.observation_space.shape}, actual value: "
            f"{venv.observation_space.shape} under sensing {sensing!r}")
    folder = Path(model) if Path(model).is_dir() else Path(model).parent
    norm_file = folder / "vecnormalize.pkl"
    if norm_file.exists():
        venv = VecNormalize.load(str(norm_file), venv)
        venv.training = False
        venv.norm_reward = False
    from stable_baselines3.common.evaluation import evaluate_policy

    rewards, lengths = evaluate_policy(agent, venv, n_eval_episodes=episodes, deterministic=deterministic,
                                       return_episode_rewards=True, warn=False)
    venv.close()
    r = np.asarray(rewards, dtype=float)
    return dict(env=env_id, sensing=sensing, **sense, returns=r.tolist(), lengths=list(map(int, lengths)),
                mean=float(r.mean()), std=float(r.std()))
