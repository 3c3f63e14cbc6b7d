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
import importlib.util
import json
import math
import os
import re
import shutil
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

from ._extras import require
from ._validation import _short, check_bool, check_int_at_least, check_int_in_range, check_real
from .envs import check_env_id
from .envs import make as make_by_id
from .specs import make_sensor, needs_model, parse_observer_spec

__all__ = [
    "ALGOS",
    "SENSINGS",
    "VECTORIZE_FROM",
    "MaskEntries",
    "SelectEntries",
    "algo_kwargs",
    "check_run_folder",
    "default_run_folder",
    "evaluate",
    "load_hyperparams",
    "load_run",
    "make_env",
    "make_vec",
    "parse_policy_kwargs",
    "run_files",
    "sensing_settings",
    "train",
    "velocity_entries",
]

#: what the policy observes (see the module docstring)
SENSINGS = ("true", "estimated", "finite-difference", "no-velocity", "stacked-positions")
#: the largest seed :func:`train` takes: its evaluation environments are seeded ``10_000 + 100 seed + k``, and
#: SB3 seeds NumPy's legacy generator, which takes seeds below 2**32
MAX_TRAIN_SEED = (2**32 - 10_100) // 100
#: the most episodes an evaluation takes (SB3 counts them in a NumPy int64 array)
MAX_EPISODES = 2**63 - 1
#: the Stable-Baselines3 algorithms :func:`train` runs
ALGOS = ("PPO", "SAC")


# ----------------------------------------------------------------------------------------------------------------
# observation surgery
# ----------------------------------------------------------------------------------------------------------------
def velocity_entries(env: gym.Env, trials: int = 3, seed: int = 0) -> np.ndarray:
    r"""Indices of the observation entries that depend on the joint velocities.

    The environment's own observation function is evaluated on scratch data
    (:class:`~smo_gym.wrappers.GymnasiumMujocoAdapter`) at its current configuration with random velocities;
    an entry is velocity-dependent if it changes (``qvel`` itself, clipped velocities, ``cvel``, constraint
    forces that depend on velocity, ...). No per-environment table. Requires a reset environment. A ``Dict``
    observation (dm_control) is indexed as flattened (:func:`gymnasium.spaces.flatten`, keys in order).

    Returns
    -------
    ndarray of int, shape (n_velocity_entries,)
    """
    from .wrappers.adapters import make_adapter

    trials = check_int_at_least("trials", trials, 1)  # none would find no velocity entry: nothing masked
    seed = check_int_in_range("seed", seed, 0, 2**63 - 1)
    adapter = make_adapter(env)
    rng = np.random.default_rng(seed)
    qpos = np.array(adapter.data.qpos)
    nv = adapter.model.nv
    base = adapter.observation(qpos, np.zeros(nv))
    changed = np.zeros(base.shape, dtype=bool)
    for _ in range(trials):
        changed |= adapter.observation(qpos, rng.standard_normal(nv)) != base
    return np.flatnonzero(changed.reshape(-1))


def _entry_indices(env: gym.Env, indices) -> np.ndarray:
    """``indices`` of a flat ``Box`` observation of ``env``, checked: integers (a bool or a float would be read as
    another entry) within its size."""
    space = env.observation_space
    if not isinstance(space, gym.spaces.Box) or len(space.shape) != 1:
        raise ValueError(f"expected an environment with a flat Box observation, actual value: {space}")
    index = np.asarray(indices)
    if index.ndim != 1 or (index.size and index.dtype.kind not in "iu"):
        raise TypeError(f"expected indices to be a sequence of integers, actual value: {indices!r:.80}")
    size = space.shape[0]
    if index.size and not (index.min() >= -size and index.max() < size):
        raise ValueError(f"expected indices of entries in [0, {size}), actual value: {index.tolist()!r:.80}")
    return index.astype(np.intp) % max(size, 1)


class MaskEntries(gym.ObservationWrapper, gym.utils.RecordConstructorArgs):
    """Set the observation entries ``indices`` (integers) to zero (the observation space is unchanged)."""

    def __init__(self, env: gym.Env, indices):
        gym.utils.RecordConstructorArgs.__init__(self, indices=indices)
        gym.ObservationWrapper.__init__(self, env)
        self.indices = _entry_indices(env, indices)

    def observation(self, observation):
        observation = np.array(observation, copy=True)
        observation[self.indices] = 0.0
        return observation


class SelectEntries(gym.ObservationWrapper, gym.utils.RecordConstructorArgs):
    """Keep only the observation entries ``indices`` (integers; a Box of the selected bounds)."""

    def __init__(self, env: gym.Env, indices):
        gym.utils.RecordConstructorArgs.__init__(self, indices=indices)
        gym.ObservationWrapper.__init__(self, env)
        self.indices = _entry_indices(env, indices)
        space = env.observation_space
        self.observation_space = gym.spaces.Box(space.low[self.indices], space.high[self.indices], dtype=space.dtype)

    def observation(self, observation):
        return np.asarray(observation)[self.indices]


# ----------------------------------------------------------------------------------------------------------------
# environments
# ----------------------------------------------------------------------------------------------------------------
def _check_sensing(sensing: str) -> None:
    if sensing not in SENSINGS:
        raise ValueError(f"expected sensing in {', '.join(SENSINGS)}, actual value: {sensing!r}")


def _check_interchangeable(trained: str, other: str) -> None:
    """A policy trained under ``trained`` can be played under ``other``: stacked positions (two frames of the
    positions) are another observation than the state the other sensings give, even where the shapes agree."""
    _check_sensing(other)
    if (trained == "stacked-positions") != (other == "stacked-positions"):
        raise ValueError(
            f"expected a sensing interchangeable with {trained!r} (true, estimated, finite-difference and "
            f"no-velocity are; stacked-positions only with itself), actual value: {other!r}"
        )


def sensing_settings(sensing: str) -> tuple[str, ...]:
    """The settings that act under ``sensing``: ``sensor``, ``observer`` (only ``"estimated"``) and ``rate``
    (every measured sensing: it sets the sampling of the sensor's delay, drift and dropouts); none for ``"true"``."""
    _check_sensing(sensing)
    if sensing == "true":
        return ()
    return ("sensor", "observer", "rate") if sensing == "estimated" else ("sensor", "rate")


def _observer(sensing: str, observer: str, observer_kwargs: dict | None) -> tuple[str, dict | None]:
    """Observer name and options of a sensing: the spec ``observer`` (with ``observer_kwargs`` on top) when
    estimating, finite differences otherwise (their velocities are the estimate, or masked, or dropped)."""
    if sensing != "estimated":
        return "finite-difference", None
    name, kwargs = parse_observer_spec(observer)
    kwargs.update(observer_kwargs or {})
    return name, kwargs or None


def make_env(
    env_id: str,
    sensing: str = "estimated",
    *,
    sensor: str = "encoder-12bit-noisy",
    observer: str = "auto",
    rate="physics",
    observer_kwargs: dict | None = None,
    env_kwargs: dict | None = None,
) -> gym.Env:
    """One environment under a sensing (see the module docstring).

    ``sensor`` and ``observer`` are specs (:mod:`smo_gym.specs`, e.g. ``"encoder:counts_per_revolution=1024"``,
    ``"levant:order=1"``) or, for ``sensor``, a :class:`~smo_gym.sensors.Sensor`. A ``Dict`` observation (the
    dm_control suite) is flattened (:class:`gymnasium.wrappers.FlattenObservation`), so that an MLP policy takes it.
    """
    _check_sensing(sensing)
    env = make_by_id(env_id, **(env_kwargs or {}))
    if sensing != "true":
        from .wrappers import EstimatedVelocity

        name, kwargs = _observer(sensing, observer, observer_kwargs)
        env = EstimatedVelocity(env, sensor=make_sensor(sensor), observer=name, rate=rate, observer_kwargs=kwargs)
    if isinstance(env.observation_space, gym.spaces.Dict):
        env = gym.wrappers.FlattenObservation(env)
    if sensing in ("true", "estimated", "finite-difference"):
        return env
    env.reset(seed=0)
    vel = velocity_entries(env)
    if sensing == "no-velocity":
        return MaskEntries(env, vel)
    keep = np.setdiff1d(np.arange(int(np.prod(env.observation_space.shape))), vel)
    env = SelectEntries(env, keep)
    env = gym.wrappers.FrameStackObservation(env, 2)
    return gym.wrappers.FlattenObservation(env)


#: from how many environments :func:`make_vec` batches the observers by default: with fewer, per-environment
#: wrappers cost less per step (the batched wrapper's fixed cost per vector step; with 8 Hopper environments it
#: costs less, with 8 InvertedDoublePendulum environments about the same: ``scripts/bench_rl_throughput.py
#: --tables in-process``)
VECTORIZE_FROM = 8


def make_vec(
    env_id: str,
    sensing: str = "estimated",
    *,
    n_envs: int = 1,
    seed: int | None = 0,
    sensor: str = "encoder-12bit-noisy",
    observer: str = "auto",
    rate="physics",
    observer_kwargs: dict | None = None,
    env_kwargs: dict | None = None,
    vectorized: bool | None = None,
):
    """A ``DummyVecEnv`` (with ``Monitor``) of :func:`make_env` environments.

    With ``rate="env"``, an estimating sensing (``"estimated"``, ``"finite-difference"``) and a ``Box`` observation
    the observers run batched in :class:`~smo_gym.wrappers.VecEstimatedVelocity` (``vectorized=True``, or None
    with at least :data:`VECTORIZE_FROM` environments); otherwise one :class:`~smo_gym.wrappers.EstimatedVelocity`
    per environment. Both give the same observations. Model-based observers (and ``"auto"`` with a model) run per
    environment.

    Raises
    ------
    ValueError
        ``vectorized=True`` with a ``rate`` other than ``"env"`` (the batched wrapper samples once per environment
        step), with a sensing that does not estimate, or with a ``Dict`` observation; an unknown ``env_id``.
    """
    make_vec_env = require("stable_baselines3.common.env_util", "rl").make_vec_env

    _check_sensing(sensing)
    n_envs = check_int_at_least("n_envs", n_envs, 1)
    seed = None if seed is None else check_int_in_range("seed", seed, 0, 2**32 - n_envs)  # SB3 seeds seed + i
    explicit = vectorized = None if vectorized is None else check_bool("vectorized", vectorized)
    if vectorized is None:  # a model-based observer needs its environment's control input: per environment
        model_based = needs_model(*_observer(sensing, observer, observer_kwargs))
        vectorized = (
            rate == "env"
            and sensing in ("estimated", "finite-difference")
            and not model_based
            and n_envs >= VECTORIZE_FROM
        )
    if vectorized:
        if sensing not in ("estimated", "finite-difference"):
            raise ValueError(
                f"expected sensing 'estimated' or 'finite-difference' for vectorized sensing, actual value: {sensing!r}"
            )
        from .wrappers import VecEstimatedVelocity, sensing_config
        from .wrappers.vec import check_vector_rate

        check_vector_rate(rate)  # the batched wrapper samples once per environment step
        name, kwargs = _observer(sensing, observer, observer_kwargs)
        venv = make_vec_env(lambda: make_by_id(env_id, **(env_kwargs or {})), n_envs=n_envs, seed=seed)
        if isinstance(venv.observation_space, gym.spaces.Box):
            return VecEstimatedVelocity(venv, **sensing_config(make_sensor(sensor), name, kwargs))
        venv.close()
        if explicit:
            raise ValueError(
                f"expected a Box observation for vectorized sensing, actual value: "
                f"{venv.observation_space} (use vectorized=False: per-environment wrappers flatten it)"
            )
    return make_vec_env(
        lambda: make_env(
            env_id,
            sensing,
            sensor=sensor,
            observer=observer,
            rate=rate,
            observer_kwargs=observer_kwargs,
            env_kwargs=env_kwargs,
        ),
        n_envs=n_envs,
        seed=seed,
    )


# ----------------------------------------------------------------------------------------------------------------
# hyperparameters in rl-zoo3's format
# ----------------------------------------------------------------------------------------------------------------
#: rl-zoo3 keys :func:`train` reads itself (the others go to the SB3 algorithm)
RUN_KEYS = ("n_timesteps", "policy", "n_envs", "normalize", "env_kwargs")
#: rl-zoo3 keys with no meaning here, and why
UNSUPPORTED_KEYS = {
    "env_wrapper": "the sensing is smo-gym's own (--sensing, --sensor, --observer, --rate); the env_wrapper recipe "
    "is for rl-zoo3 itself (see the README)",
    "vec_env_wrapper": "not supported by smo-gym train",
    "frame_stack": "not supported by smo-gym train (sensing 'stacked-positions' stacks measured positions)",
    "callback": "not supported by smo-gym train",
    "monitor_kwargs": "not supported by smo-gym train",
    "noise_type": "action noise is not supported by smo-gym train",
    "noise_std": "action noise is not supported by smo-gym train",
}
#: hyperparameters that rl-zoo3 reads as schedules when written ``lin_<initial value>``
SCHEDULE_KEYS = ("learning_rate", "clip_range", "clip_range_vf")
#: what ``policy_kwargs`` may name besides literals and ``dict(...)`` (torch.nn activations and optimizers)
_ACTIVATIONS = ("ReLU", "Tanh", "ELU", "LeakyReLU", "SiLU", "GELU", "Sigmoid", "Softplus", "Identity")
_OPTIMIZERS = ("Adam", "AdamW", "RMSprop", "SGD")
#: SB3 arguments that count (samples per rollout, minibatch size, epochs, replay buffer size): SB3 takes zero or a
#: negative count and fails inside ``learn`` (``n_epochs=0``: an ``UnboundLocalError`` after the first rollout)
_COUNT_KEYS = ("n_steps", "batch_size", "n_epochs", "buffer_size")
#: SB3 constructor arguments :func:`train` sets itself
_OWN_ARGS = ("self", "policy", "env", "seed", "device", "verbose", "tensorboard_log", "_init_setup_model")


def linear_schedule(initial_value: float):
    r"""rl-zoo3's ``lin_<value>`` schedule: :math:`v(p) = p\,v_0` with ``p`` the progress remaining (1 -> 0)."""
    initial_value = check_real("the initial value of a linear schedule", initial_value)

    def schedule(progress_remaining: float) -> float:
        return progress_remaining * initial_value

    return schedule


def _policy_kwargs_node(node, text: str):
    import ast

    def bad(what: str):
        return ValueError(
            f"expected policy_kwargs made of dict(...), literals, nn.<activation> ({', '.join(_ACTIVATIONS)}) and "
            f"optim.<optimizer> ({', '.join(_OPTIMIZERS)}), actual value: {what} in {text!r}"
        )

    if isinstance(node, ast.Constant) and isinstance(node.value, (int, float, str, bool, type(None))):
        return node.value
    if (
        isinstance(node, ast.UnaryOp)
        and isinstance(node.op, (ast.USub, ast.UAdd))
        and isinstance(node.operand, ast.Constant)
        and isinstance(node.operand.value, (int, float))
    ):
        return -node.operand.value if isinstance(node.op, ast.USub) else node.operand.value
    if isinstance(node, (ast.List, ast.Tuple)):
        items = [_policy_kwargs_node(e, text) for e in node.elts]
        return items if isinstance(node, ast.List) else tuple(items)
    if isinstance(node, ast.Dict):
        if any(k is None for k in node.keys):
            raise bad("'**' unpacking")
        if not all(isinstance(k, ast.Constant) and isinstance(k.value, str) for k in node.keys):
            raise bad("a key that is not a string")
        return {
            _policy_kwargs_node(k, text): _policy_kwargs_node(v, text)
            for k, v in zip(node.keys, node.values, strict=True)
        }
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "dict":
        if node.args or any(kw.arg is None for kw in node.keywords):
            raise bad(repr(ast.unparse(node)))
        return {kw.arg: _policy_kwargs_node(kw.value, text) for kw in node.keywords}
    if isinstance(node, ast.Attribute):
        dotted = ast.unparse(node)
        module, _, attr = dotted.rpartition(".")
        torch = require("torch", "rl")

        if module in ("nn", "th.nn", "torch.nn") and attr in _ACTIVATIONS:
            return getattr(torch.nn, attr)
        if module in ("optim", "th.optim", "torch.optim") and attr in _OPTIMIZERS:
            return getattr(torch.optim, attr)
        raise bad(repr(dotted))
    raise bad(repr(ast.unparse(node)))


def parse_policy_kwargs(text: str) -> dict:
    """rl-zoo3's ``policy_kwargs`` string, e.g. ``"dict(net_arch=[64, 64], activation_fn=nn.Tanh)"``, evaluated
    safely: the expression is parsed and only ``dict(...)``, ``{...}``, lists, tuples, numbers, strings, booleans,
    ``None`` and the torch names ``nn.<activation>`` / ``optim.<optimizer>`` are accepted (nothing is executed)."""
    import ast

    try:
        tree = ast.parse(str(text).strip(), mode="eval")
    except SyntaxError as exc:
        raise ValueError(f"expected policy_kwargs as a Python expression, actual value: {text!r} ({exc.msg})") from None
    value = _policy_kwargs_node(tree.body, text)
    if not isinstance(value, dict):
        raise ValueError(f"expected policy_kwargs to be a dict, actual value: {text!r}")
    return value


def _algo_class(algo: str):
    if algo not in ALGOS:
        raise ValueError(f"expected algo in {', '.join(ALGOS)}, actual value: {algo!r}")
    return getattr(require("stable_baselines3", "rl"), algo)


def algo_kwargs(algo: str, hyperparams: dict | None) -> dict:
    """SB3 constructor arguments from hyperparameters written as in rl-zoo3: ``lin_<v>`` schedules
    (:data:`SCHEDULE_KEYS`), a ``policy_kwargs`` string (:func:`parse_policy_kwargs`), everything else as is.

    Values are copied (SB3 writes into a ``policy_kwargs`` dict it is given).

    Raises
    ------
    TypeError
        A key that is not a string.
    ValueError
        A key that is not an argument of the algorithm (the closest is suggested), or a malformed value: a
        non-finite number (a NaN ``clip_range`` trains on NaN losses to the end), a count (``n_steps``,
        ``batch_size``, ``n_epochs``, ``buffer_size``) below 1.
    """
    import difflib
    import inspect

    cls = _algo_class(algo)
    if hyperparams is not None and not isinstance(hyperparams, dict):
        raise TypeError(f"expected hyperparams to be a dict (or None), actual value: {hyperparams!r:.80}")
    valid = [p for p in inspect.signature(cls.__init__).parameters if p not in _OWN_ARGS]
    out = {}
    for key, value in (hyperparams or {}).items():
        if not isinstance(key, str):
            raise TypeError(f"expected hyperparameter names (str), actual value: {key!r:.80}")
        if key in RUN_KEYS:
            own = "steps" if key == "n_timesteps" else key
            raise ValueError(
                f"expected hyperparameters of {algo}, actual value: {key!r} (an rl-zoo3 key that is train's own "
                f"argument {own}=; load_hyperparams separates them)"
            )
        if key in UNSUPPORTED_KEYS:
            raise ValueError(
                f"expected hyperparameters smo-gym train supports, actual value: {key!r} ({UNSUPPORTED_KEYS[key]})"
            )
        if key not in valid:
            match = difflib.get_close_matches(key, valid + list(RUN_KEYS), n=1)
            hint = f" (did you mean {match[0]!r}?)" if match else ""
            raise ValueError(
                f"expected a hyperparameter of {algo} or one of {', '.join(RUN_KEYS)}, actual value: {key!r}{hint}"
            )
        if key in SCHEDULE_KEYS and isinstance(value, str):
            if not value.startswith("lin_"):
                raise ValueError(f"expected {key} as a number or lin_<number>, actual value: {value!r}")
            try:
                value = linear_schedule(float(value[4:]))
            except ValueError:
                raise ValueError(f"expected {key} as a number or lin_<number>, actual value: {value!r}") from None
        elif key == "policy_kwargs" and isinstance(value, str):
            value = parse_policy_kwargs(value)
        elif isinstance(value, float) and not math.isfinite(value):
            raise ValueError(f"expected {key} to be finite, actual value: {value!r}")
        if key in _COUNT_KEYS:  # an integral float, as yaml reads 1e6, is the count SB3 needs
            value = check_int_at_least(key, int(value) if isinstance(value, float) and value.is_integer() else value, 1)
        out[key] = copy.deepcopy(value)
    return out


def _normalize_option(value) -> bool | dict:
    """rl-zoo3's ``normalize``: a bool, a dict of ``VecNormalize`` arguments, or that dict written as a string."""
    import ast

    if isinstance(value, str):
        try:
            value = ast.literal_eval(value)
        except (ValueError, SyntaxError):
            raise ValueError(
                f"expected normalize as true/false or a dict string such as "
                f"\"{{'norm_obs': True, 'norm_reward': False}}\", actual value: {value!r}"
            ) from None
    if isinstance(value, bool):
        return value
    if isinstance(value, dict):
        import inspect

        VecNormalize = require("stable_baselines3.common.vec_env", "rl").VecNormalize

        valid = [p for p in inspect.signature(VecNormalize.__init__).parameters if p not in ("self", "venv")]
        bad = [k for k in value if k not in valid]
        if bad:
            raise ValueError(f"expected normalize options in {', '.join(valid)}, actual value: {bad[0]!r}")
        return value
    raise ValueError(f"expected normalize as a bool or a dict, actual value: {value!r}")


def load_hyperparams(path: str | os.PathLike, env_id: str, algo: str = "PPO") -> dict:
    """The entry of ``env_id`` in a hyperparameter file in rl-zoo3's yaml format, checked.

    The file maps environment ids to hyperparameters, e.g.::

        InvertedPendulum-v5:
          n_timesteps: !!float 1e5
          policy: 'MlpPolicy'
          n_envs: 4
          normalize: true            # or "{'norm_obs': True, 'norm_reward': False}"
          learning_rate: lin_3e-4
          policy_kwargs: "dict(net_arch=[64, 64], activation_fn=nn.Tanh)"
          n_steps: 256

    Returns
    -------
    dict
        ``{"n_timesteps", "policy", "n_envs", "normalize", "env_kwargs"}`` where given (:data:`RUN_KEYS`) and
        ``"hyperparams"``: the rest, as written (checked with :func:`algo_kwargs`).

    Raises
    ------
    ValueError
        Missing or unreadable file, no entry for ``env_id`` (the closest is suggested), unknown keys or bad values.
    """
    import difflib

    yaml = require("yaml", "rl")
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"expected a path to a hyperparameter file, actual value: {path!r:.80}")
    if not isinstance(env_id, str):
        raise TypeError(f"expected env_id to be a Gymnasium environment id (a str), actual value: {env_id!r:.80}")
    path = Path(path)
    if not path.is_file():
        what = "is not a file" if path.exists() else "does not exist"
        raise ValueError(f"expected a hyperparameter file (rl-zoo3 yaml), actual value: {str(path)!r} {what}")
    try:
        content = yaml.safe_load(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise ValueError(f"expected a yaml text file (UTF-8), actual value: {str(path)!r} is not text") from None
    except yaml.YAMLError as exc:
        raise ValueError(f"expected a yaml file, actual value: {str(path)!r} ({str(exc).splitlines()[0]})") from None
    if not isinstance(content, dict):
        raise ValueError(
            f"expected a yaml mapping of env ids to hyperparameters, actual value: {type(content).__name__}"
            f" in {str(path)!r}"
        )
    if env_id not in content:
        match = difflib.get_close_matches(env_id, [str(k) for k in content], n=1)
        hint = f" (did you mean {match[0]!r}?)" if match else ""
        raise ValueError(
            f"expected an entry for {env_id!r} in {str(path)!r}, actual value: entries "
            f"{', '.join(map(str, content)) or '(none)'}{hint}"
        )
    entry = content[env_id] or {}
    if not isinstance(entry, dict) or not all(isinstance(key, str) for key in entry):
        raise ValueError(
            f"expected the entry of {env_id!r} to map hyperparameter names to values, actual value: "
            f"{_short(entry, 80)} in {str(path)!r}"
        )
    entry = dict(entry)
    out: dict = {}
    if "n_timesteps" in entry:
        n = entry.pop("n_timesteps")
        if isinstance(n, bool) or not isinstance(n, (int, float)) or not math.isfinite(n) or n < 1 or n != int(n):
            raise ValueError(f"expected n_timesteps to be a positive integer, actual value: {n!r}")
        out["n_timesteps"] = int(n)
    if "n_envs" in entry:
        n = entry.pop("n_envs")
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise ValueError(f"expected n_envs to be a positive integer, actual value: {n!r}")
        out["n_envs"] = n
    if "policy" in entry:
        policy = entry.pop("policy")
        if not isinstance(policy, str):  # yaml's null would be the policy "None"
            raise ValueError(f"expected policy to be an SB3 policy name, actual value: {policy!r}")
        out["policy"] = policy
    if "normalize" in entry:
        out["normalize"] = _normalize_option(entry.pop("normalize"))
    if "env_kwargs" in entry:
        kwargs = entry.pop("env_kwargs")
        if not isinstance(kwargs, dict):
            raise ValueError(f"expected env_kwargs to be a mapping, actual value: {kwargs!r}")
        out["env_kwargs"] = kwargs
    algo_kwargs(algo, entry)  # checks the rest
    out["hyperparams"] = entry
    return out


# ----------------------------------------------------------------------------------------------------------------
# run folders
# ----------------------------------------------------------------------------------------------------------------
#: what a run folder holds (written by :func:`train`, replaced with ``overwrite=True``)
RUN_FILES = ("run.json", "model.zip", "vecnormalize.pkl", "progress.csv", "checkpoints")


def _slug(text) -> str:
    return re.sub(r"[^A-Za-z0-9._=+-]+", "_", str(text)).strip("_")


def default_run_folder(
    env_id: str,
    sensing: str,
    algo: str,
    seed: int,
    *,
    sensor="encoder-12bit-noisy",
    observer="auto",
    rate="physics",
    root="outputs/runs",
) -> Path:
    """``root/ENV-SENSING[-OBSERVER][-SENSOR][-rate-RATE]-ALGO-sSEED``, naming only the settings that act under the
    sensing (:func:`sensing_settings`), so that runs differing in any of them get different folders."""
    values = {"sensor": sensor, "observer": observer, "rate": f"rate-{rate}"}
    parts = [env_id, sensing] + [values[k] for k in ("observer", "sensor", "rate") if k in sensing_settings(sensing)]
    return Path(root) / "-".join(_slug(p) for p in parts + [algo, f"s{seed}"])


def holds_run(folder: str | os.PathLike) -> bool:
    """Whether ``folder`` holds a run of :func:`train` (any of :data:`RUN_FILES`)."""
    folder = Path(folder)
    return folder.is_dir() and any((folder / name).exists() for name in RUN_FILES)


def check_run_folder(out: str | os.PathLike, overwrite: bool = False) -> Path:
    """``out`` as a path after checking that a run can be written there.

    Raises
    ------
    ValueError
        ``out`` or a folder above it is a file, the nearest existing folder is not writable, or ``out`` holds a
        run already and ``overwrite`` is false.
    """
    overwrite = check_bool("overwrite", overwrite)  # "False" would replace a run
    if not isinstance(out, (str, os.PathLike)) or not str(out):
        raise TypeError(f"expected out to be a folder path, actual value: {out!r}")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"expected a run folder, actual value: {str(out)!r} is a file")
    if holds_run(out) and not overwrite:
        raise ValueError(
            f"expected a new run folder, actual value: {str(out)!r} holds a run already "
            "(choose another folder, or overwrite it: --force / overwrite=True)"
        )
    parent = out
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise ValueError(f"expected a run folder under a folder, actual value: {str(parent)!r} is a file")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ValueError(f"expected a writable folder for the run, actual value: {str(parent)!r} is not writable")
    return out


def _remove_run(folder: Path) -> None:
    """Remove the files of :data:`RUN_FILES` (and TensorBoard event files) from ``folder``; nothing else."""
    for name in RUN_FILES:
        target = folder / name
        if target.is_dir():
            shutil.rmtree(target)
        elif target.exists():
            target.unlink()
    for event in folder.glob("events.out.tfevents.*"):
        event.unlink()


# ----------------------------------------------------------------------------------------------------------------
# training
# ----------------------------------------------------------------------------------------------------------------
def _progress_callback():
    """SB3's rich progress bar when ``rich`` is installed, else a plain tqdm bar with the same role."""
    callbacks = require("stable_baselines3.common.callbacks", "rl")
    BaseCallback, ProgressBarCallback = callbacks.BaseCallback, callbacks.ProgressBarCallback

    if importlib.util.find_spec("rich") is not None:  # SB3's progress bar needs rich
        return ProgressBarCallback()
    tqdm = require("tqdm.auto", "rl").tqdm

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
    configure = require("stable_baselines3.common.logger", "rl").configure

    formats = ["csv"] + (["stdout"] if verbose else [])
    if importlib.util.find_spec("tensorboard") is not None:
        formats.append("tensorboard")
    return configure(str(folder), formats)


def _frozen_normalization(train_venv, eval_venv):
    """Wrap ``eval_venv`` in a ``VecNormalize`` with ``train_venv``'s observation statistics, frozen."""
    VecNormalize = require("stable_baselines3.common.vec_env", "rl").VecNormalize

    if not isinstance(train_venv, VecNormalize):
        return eval_venv
    norm = VecNormalize(
        eval_venv,
        training=False,
        norm_obs=train_venv.norm_obs,
        norm_reward=False,
        clip_obs=train_venv.clip_obs,
        epsilon=train_venv.epsilon,
        norm_obs_keys=train_venv.norm_obs_keys,
    )
    norm.obs_rms = copy.deepcopy(train_venv.obs_rms)
    return norm


def _returns(model, venv, episodes: int, deterministic: bool = True) -> np.ndarray:
    evaluate_policy = require("stable_baselines3.common.evaluation", "rl").evaluate_policy

    rewards, _ = evaluate_policy(
        model, venv, n_eval_episodes=episodes, deterministic=deterministic, return_episode_rewards=True, warn=False
    )
    return np.asarray(rewards, dtype=float)


def _describe(sensor) -> str:
    return sensor if isinstance(sensor, str) else repr(sensor)


def train(
    env_id: str,
    *,
    sensing: str = "estimated",
    sensor: str = "encoder-12bit-noisy",
    observer: str = "auto",
    rate="physics",
    algo: str = "PPO",
    steps: int = 100_000,
    seed: int = 0,
    n_envs: int = 1,
    out: str | os.PathLike = "outputs/runs/run",
    normalize: bool | dict | None = None,
    hyperparams: dict | None = None,
    policy: str = "MlpPolicy",
    env_kwargs: dict | None = None,
    checkpoint_every: int = 0,
    evaluate_at=(),
    eval_sensings=None,
    eval_episodes: int = 10,
    progress_bar: bool = False,
    verbose: int = 0,
    vectorized: bool | None = None,
    observer_kwargs: dict | None = None,
    overwrite: bool = False,
) -> dict:
    r"""Train an SB3 agent on ``env_id`` under a sensing; returns the run summary (also in ``out/run.json``).

    Parameters
    ----------
    sensing, sensor, observer, rate, observer_kwargs
        What the policy observes (:func:`make_env`; ``sensor`` and ``observer`` are specs of :mod:`smo_gym.specs`).
    algo : {"PPO", "SAC"}
    steps : int
        Environment steps (summed over the ``n_envs`` environments).
    seed : int
        Seed of the training environments (``seed + i``), of the algorithm and, through ``10_000 + 100 seed + k``,
        of the evaluations; in ``[0, MAX_TRAIN_SEED]``.
    out : path
        The run folder. One that holds a run already (:func:`holds_run`) is refused unless ``overwrite``, which
        replaces that run's files (:data:`RUN_FILES`) and nothing else. If training fails before its first
        checkpoint, what this call created is removed again.
    normalize : bool or dict, optional
        ``VecNormalize`` (observations and rewards; a dict gives its arguments); default on for PPO, off for SAC.
    hyperparams : dict, optional
        Arguments of the SB3 algorithm, as rl-zoo3 writes them (``lin_3e-4`` schedules, ``policy_kwargs`` as a
        string: :func:`algo_kwargs`); :func:`load_hyperparams` reads them from rl-zoo3's yaml files.
    policy : str
        SB3 policy name (``"MlpPolicy"``).
    env_kwargs : dict, optional
        Arguments of ``gymnasium.make``.
    checkpoint_every : int
        Save a checkpoint (model and normalization) every so many steps; 0: none.
    evaluate_at : sequence of int
        Budgets (steps, each in ``[1, steps]``) at which the current policy is evaluated on ``eval_episodes``
        episodes for each of ``eval_sensings`` (default: the training sensing; each interchangeable with it, see
        :func:`evaluate`), with the normalization statistics of that moment.
    progress_bar : bool
        SB3's progress bar (a tqdm bar when ``rich`` is missing).

    Returns
    -------
    dict
        ``run.json``'s content: the options, ``seconds``, ``steps_per_second`` and ``evaluations`` (a list of
        ``{"steps", "sensing", "returns", "mean", "std"}``). ``run.json`` is written when training starts (with
        ``"status": "training"``) and completed at the end (``"status": "done"``), so that checkpoints of an
        interrupted run can be evaluated under their sensing.
    """
    torch = require("torch", "rl")
    callbacks = require("stable_baselines3.common.callbacks", "rl")
    BaseCallback, CheckpointCallback = callbacks.BaseCallback, callbacks.CheckpointCallback
    VecNormalize = require("stable_baselines3.common.vec_env", "rl").VecNormalize

    # every argument is checked before anything is made: a bad one found later would cost the training done
    _check_sensing(sensing)
    cls = _algo_class(algo)
    steps, n_envs = check_int_at_least("steps", steps, 1), check_int_at_least("n_envs", n_envs, 1)
    seed = check_int_in_range("seed", seed, 0, MAX_TRAIN_SEED)
    checkpoint_every = check_int_at_least("checkpoint_every", checkpoint_every, 0)
    if isinstance(evaluate_at, (str, bytes)) or not hasattr(evaluate_at, "__iter__"):
        raise TypeError(f"expected evaluate_at to be a sequence of budgets (steps), actual value: {evaluate_at!r}")
    budgets = sorted({check_int_in_range("a budget of evaluate_at", b, 1, steps) for b in evaluate_at})
    # SB3 counts episodes in a NumPy int64 array, after the training it would otherwise throw away
    eval_episodes = check_int_in_range("eval_episodes", eval_episodes, 1 if budgets else 0, MAX_EPISODES)
    if isinstance(eval_sensings, str) or not (eval_sensings is None or hasattr(eval_sensings, "__iter__")):
        raise TypeError(f"expected eval_sensings to be a sequence of sensings, actual value: {eval_sensings!r}")
    for name, value in (("observer_kwargs", observer_kwargs), ("env_kwargs", env_kwargs)):
        if value is not None and not isinstance(value, dict):
            raise TypeError(f"expected {name} to be a dict (or None), actual value: {value!r:.80}")
    eval_sensings = list(eval_sensings or [sensing])
    for other in eval_sensings:
        _check_interchangeable(sensing, other)
    if not isinstance(policy, (str, type)):
        raise TypeError(f"expected policy to be an SB3 policy name or class, actual value: {policy!r:.80}")
    check_env_id(env_id)
    progress_bar = check_bool("progress_bar", progress_bar)
    verbose = check_int_in_range("verbose", verbose, 0, 2)
    make_sensor(sensor)  # check the specs before anything is made
    _observer(sensing, observer, observer_kwargs)
    normalize = (algo == "PPO") if normalize is None else _normalize_option(normalize)
    raw_params = dict(hyperparams or {})  # SB3's defaults for everything not given
    params = algo_kwargs(algo, raw_params)
    out = check_run_folder(out, overwrite)
    created = out
    while not created.parent.exists():  # the topmost folder this call creates (None: out exists)
        created = created.parent
    created = None if out.exists() else created
    torch.set_num_threads(1)
    sense = dict(sensor=sensor, observer=observer, rate=rate, observer_kwargs=observer_kwargs)
    summary = dict(
        env=env_id,
        sensing=sensing,
        algo=algo,
        steps=int(steps),
        seed=int(seed),
        n_envs=int(n_envs),
        normalize=normalize,
        policy=policy,
        hyperparams=raw_params,
        env_kwargs=env_kwargs,
        sensor=_describe(sensor),
        observer=observer,
        rate=rate,
        observer_kwargs=observer_kwargs,
        settings=list(sensing_settings(sensing)),
        status="training",
    )
    venv, writing = None, False
    try:
        venv = make_vec(
            env_id, sensing, n_envs=n_envs, seed=seed, vectorized=vectorized, env_kwargs=env_kwargs, **sense
        )
        if normalize:
            venv = VecNormalize(venv, **(normalize if isinstance(normalize, dict) else {}))
        try:
            model = cls(policy, venv, seed=seed, verbose=verbose, device="cpu", **params)
        # SB3's checks of its arguments, and torch's of the network they describe (a negative layer width)
        except (AssertionError, TypeError, ValueError, KeyError, RuntimeError) as exc:
            raise ValueError(
                f"expected {algo} arguments SB3 accepts, actual value: policy {policy!r} with {raw_params!r:.200} "
                f"({type(exc).__name__}: {exc})"
            ) from exc
        if overwrite:
            _remove_run(out)
        writing = True  # from here on the run's files are this call's
        out.mkdir(parents=True, exist_ok=True)
        (out / "run.json").write_text(json.dumps(summary, indent=1, default=str))
        model.set_logger(_logger(out, verbose))
        evaluations: list[dict] = []

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
                        ev = _frozen_normalization(
                            self_cb.training_env,
                            make_vec(env_id, s, n_envs=1, seed=10_000 + seed * 100 + k, env_kwargs=env_kwargs, **sense),
                        )
                        r = _returns(self_cb.model, ev, eval_episodes)
                        ev.close()
                        evaluations.append(
                            dict(
                                steps=at,
                                trained_steps=int(self_cb.num_timesteps),
                                sensing=s,
                                returns=r.tolist(),
                                mean=float(r.mean()),
                                std=float(r.std()),
                            )
                        )

        callbacks = [Budgets()]
        if checkpoint_every > 0:
            callbacks.append(
                CheckpointCallback(
                    max(checkpoint_every // n_envs, 1),
                    str(out / "checkpoints"),
                    name_prefix="model",
                    save_vecnormalize=bool(normalize),
                )
            )
        if progress_bar:
            callbacks.append(_progress_callback())
        t0 = time.perf_counter()
        model.learn(total_timesteps=int(steps), callback=callbacks)
        seconds = time.perf_counter() - t0
    except BaseException:
        if venv is not None:
            venv.close()
        if not any((out / "checkpoints").glob("*.zip")):  # nothing worth keeping: leave no half-made run behind
            if created is not None and created.exists():
                shutil.rmtree(created)
            elif writing:  # not an old run that overwrite=True was to replace: it is kept until then
                _remove_run(out)
        raise
    model.save(out / "model.zip")
    if normalize:
        venv.save(str(out / "vecnormalize.pkl"))
    summary.update(
        trained_steps=int(model.num_timesteps),
        seconds=seconds,
        steps_per_second=model.num_timesteps / seconds,
        evaluations=evaluations,
        status="done",
    )
    (out / "run.json").write_text(json.dumps(summary, indent=1, default=str))
    venv.close()
    return summary


# ----------------------------------------------------------------------------------------------------------------
# evaluation
# ----------------------------------------------------------------------------------------------------------------
_CHECKPOINT = re.compile(r"(?P<prefix>.+)_(?P<steps>\d+)_steps\.zip")


def run_files(path: str | os.PathLike) -> dict:
    """The files of a trained model: ``{"model", "run", "vecnormalize"}`` (paths; ``None`` where absent).

    ``path`` is a run folder (``model.zip``, ``run.json``, ``vecnormalize.pkl`` in it), a run's ``model.zip``, or
    a checkpoint ``.../checkpoints/model_<N>_steps.zip``, whose statistics are ``model_vecnormalize_<N>_steps.pkl``
    beside it (SB3's ``CheckpointCallback`` names) and whose ``run.json`` is in the run folder above.
    """
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"expected a run folder, model.zip or checkpoint path, actual value: {path!r:.80}")
    path = Path(path)
    if path.is_dir():
        folder, model = path, path / "model.zip"
    else:
        folder, model = path.parent, path
    if not model.is_file():
        raise ValueError(
            f"expected a run folder, model.zip or checkpoint, actual value: {str(path)!r} (no {str(model)!r})"
        )
    match = _CHECKPOINT.fullmatch(model.name)
    if match:
        norm = folder / f"{match['prefix']}_vecnormalize_{match['steps']}_steps.pkl"
    else:
        norm = folder / "vecnormalize.pkl"
    run = next((d / "run.json" for d in (folder, folder.parent) if (d / "run.json").is_file()), None)
    return {"model": model, "run": run, "vecnormalize": norm if norm.is_file() else None}


def load_run(path: str | os.PathLike):
    """``(model, run)``: the SB3 model and ``run.json`` (``{}`` if none) of a run folder, model or checkpoint
    (:func:`run_files`)."""
    files = run_files(path)
    try:
        run = json.loads(files["run"].read_text(encoding="utf-8")) if files["run"] else {}
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"expected run.json to be JSON, actual value: {str(files['run'])!r} is not ({exc})") from exc
    if (
        not isinstance(run, dict)
        or not all(isinstance(run.get(key, ""), str) for key in ("env", "algo", "sensing"))
        or not all(isinstance(run.get(key) or {}, dict) for key in ("env_kwargs", "observer_kwargs"))
    ):
        raise ValueError(
            f"expected run.json to hold an object with the run's env, algo and sensing names (and env_kwargs, "
            f"observer_kwargs as objects), actual value: {json.dumps(run)[:120]} in {str(files['run'])!r}"
        )
    algo = run.get("algo", "PPO")
    if algo not in ALGOS:
        raise ValueError(f"expected algo in {', '.join(ALGOS)} in {str(files['run'])!r}, actual value: {algo!r}")
    try:
        return _algo_class(algo).load(files["model"], device="cpu"), run
    except Exception as exc:  # a truncated, foreign or other-algorithm file: SB3's messages name none of these
        raise ValueError(
            f"expected a {algo} model SB3 saved (the algorithm run.json names), actual value: "
            f"{str(files['model'])!r} cannot be read as one ({type(exc).__name__}: {exc})"
        ) from exc


def evaluate(
    model: str | os.PathLike,
    *,
    env_id: str | None = None,
    sensing: str | None = None,
    sensor: str | None = None,
    observer: str | None = None,
    rate=None,
    episodes: int = 10,
    seed: int = 10_000,
    deterministic: bool = True,
) -> dict:
    """Play a trained run under a sensing (default: the one it was trained with); the true return per episode.

    ``model`` is a run folder, its ``model.zip`` or one of its checkpoints (:func:`run_files`): the run's
    ``run.json`` supplies the environment and sensing, and the normalization statistics saved with that model are
    loaded frozen. The sensing may differ from the training one if the observation shape is the same (true
    state, estimated, finite differences and masked velocities are interchangeable; stacked positions are not).

    Returns
    -------
    dict
        ``{"env", "sensing", "sensor", "observer", "rate", "returns", "mean", "std", "lengths", "model",
        "vecnormalize"}``; settings that do not act under the sensing (:func:`sensing_settings`) are None.

    Raises
    ------
    ValueError
        No ``run.json`` and no ``env_id``/``sensing`` given; statistics the run normalized with are missing; a
        sensing of another observation shape.
    """
    VecNormalize = require("stable_baselines3.common.vec_env", "rl").VecNormalize

    episodes = check_int_in_range("episodes", episodes, 1, MAX_EPISODES)
    seed = check_int_in_range("seed", seed, 0, 2**32 - 1)
    deterministic = check_bool("deterministic", deterministic)
    for name, value in (("env_id", env_id), ("sensing", sensing), ("sensor", sensor), ("observer", observer)):
        if isinstance(value, str) and not value:  # None is the run's own setting; "" is not a setting
            raise ValueError(f"expected {name} to be None (the run's) or a name, actual value: ''")
    if env_id is not None:
        check_env_id(env_id)
    files = run_files(model)
    agent, run = load_run(model)
    env_id = env_id or run.get("env")
    sensing = sensing or run.get("sensing")
    if env_id is None or sensing is None:
        raise ValueError(
            f"expected the run.json of {str(files['model'])!r} beside it or in the folder above, naming the "
            f"environment and the sensing, actual value: {'none' if not run else 'a run.json without them'}; "
            "give env_id and sensing"
        )
    _check_sensing(sensing)
    if run.get("sensing"):
        _check_interchangeable(run["sensing"], sensing)
    if run.get("normalize") and files["vecnormalize"] is None:
        raise ValueError(
            f"expected the normalization statistics saved with {str(files['model'])!r} (the run trained "
            "on normalized observations), actual value: none found beside it"
        )
    sense = dict(
        sensor=sensor or run.get("sensor") or "encoder-12bit-noisy",
        observer=observer or run.get("observer") or "auto",
        rate=rate if rate is not None else run.get("rate") or "physics",
    )
    venv = make_vec(
        env_id,
        sensing,
        n_envs=1,
        seed=seed,
        env_kwargs=run.get("env_kwargs") if env_id == run.get("env") else None,  # arguments of the run's env
        observer_kwargs=run.get("observer_kwargs") if sensing == "estimated" and observer is None else None,
        **sense,
    )
    if venv.observation_space.shape != agent.observation_space.shape:
        venv.close()
        raise ValueError(
            f"expected a sensing with the model's observation shape {agent.observation_space.shape}, actual value: "
            f"{venv.observation_space.shape} under sensing {sensing!r}"
        )
    if files["vecnormalize"] is not None:
        try:
            venv = VecNormalize.load(str(files["vecnormalize"]), venv)
        except Exception as exc:  # a truncated or foreign file: pickle's own messages name neither
            venv.close()
            raise ValueError(
                f"expected the normalization statistics SB3's VecNormalize.save wrote, actual value: "
                f"{str(files['vecnormalize'])!r} cannot be read ({type(exc).__name__}: {exc})"
            ) from exc
        venv.training = False
        venv.norm_reward = False
    evaluate_policy = require("stable_baselines3.common.evaluation", "rl").evaluate_policy

    rewards, lengths = evaluate_policy(
        agent, venv, n_eval_episodes=episodes, deterministic=deterministic, return_episode_rewards=True, warn=False
    )
    venv.close()
    r = np.asarray(rewards, dtype=float)
    acting = sensing_settings(sensing)
    return dict(
        env=env_id,
        sensing=sensing,
        **{k: (v if k in acting else None) for k, v in sense.items()},
        returns=r.tolist(),
        lengths=list(map(int, lengths)),
        mean=float(r.mean()),
        std=float(r.std()),
        model=str(files["model"]),
        vecnormalize=str(files["vecnormalize"]) if files["vecnormalize"] else None,
    )
