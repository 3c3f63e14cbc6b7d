"""``smo-gym train`` and ``smo-gym evaluate``: argument parsing, checks and printing only; the work is
:mod:`smo_gym.rl`."""

from __future__ import annotations

import argparse
import json

__all__ = ["add_subcommands", "run"]

DEFAULT_STEPS = 100_000
DEFAULT_N_ENVS = 1

_SENSINGS_HELP = (
    "sensings: true (the environment's own state), estimated (measured positions, velocities from "
    "--observer),\n  finite-difference (measured positions, backward differences), no-velocity "
    "(measured positions,\n  velocity entries zeroed), stacked-positions (measured positions of the "
    "last two steps, no velocities).\n  --sensor and --rate act under every sensing but true; "
    "--observer only under estimated.\n  Model-based observers take their model's settings, e.g. "
    "mechanical-super-twisting:mass_scale=1.1,\n  and auto:model=true:mass_scale=1.1 adds one as a candidate."
)

_ZOO_HELP = """--hyperparams FILE reads rl-zoo3's yaml format: the entry of --env, e.g.
  InvertedPendulum-v5:
    n_timesteps: !!float 1e5           # --steps (a flag given on the command line wins)
    n_envs: 4                          # --n-envs (likewise)
    policy: 'MlpPolicy'
    normalize: true                    # or "{'norm_obs': True, 'norm_reward': False}"
    learning_rate: lin_3e-4            # lin_<v>: linear schedule (also clip_range, clip_range_vf)
    policy_kwargs: "dict(net_arch=[64, 64], activation_fn=nn.Tanh)"
    n_steps: 256                       # any other argument of the SB3 algorithm
Unknown keys are refused; env_wrapper is rl-zoo3's own hook (see the README for that recipe)."""


def add_subcommands(sub) -> None:
    """Register ``train`` and ``evaluate`` on the ``smo-gym`` subparsers ``sub``."""
    from .cli import HelpFormatter, parse_rate, spec_help
    from .rl import ALGOS, SENSINGS

    def sensing_args(p, defaults: bool):
        def d(value):
            return value if defaults else None

        def shown(value):
            return f"(default {value})" if defaults else "(default: as trained)"

        p.add_argument(
            "--sensing", choices=SENSINGS, default=d("estimated"), help=f"what the policy observes {shown('estimated')}"
        )
        p.add_argument("--sensor", default=d("encoder-12bit-noisy"), help=f"sensor spec {shown('encoder-12bit-noisy')}")
        p.add_argument("--observer", default=d("auto"), help=f"observer spec {shown('auto')}")
        p.add_argument(
            "--rate",
            type=parse_rate,
            default=d("physics"),
            help=f"'physics', 'env' or k physics steps per sample {shown('physics')}",
        )

    tr = sub.add_parser(
        "train",
        help="train a Stable-Baselines3 agent under realistic sensing",
        formatter_class=HelpFormatter,
        description="Train PPO or SAC on a Gymnasium MuJoCo environment (or dm_control/..., observation "
        "flattened) whose policy\nsees measured positions and estimated velocities (or the true state, "
        "finite differences, ...). Writes\nmodel.zip, vecnormalize.pkl, run.json, progress.csv and "
        "checkpoints into the run folder.",
        epilog=f"{_SENSINGS_HELP}\n\n{_ZOO_HELP}\n\n{spec_help('the observer and the sensor')}",
    )
    tr.add_argument("--env", default="InvertedDoublePendulum-v5", help="environment id (default %(default)s)")
    sensing_args(tr, True)
    tr.add_argument("--algo", choices=ALGOS, default="PPO", help="algorithm (default %(default)s)")
    tr.add_argument(
        "--steps",
        type=int,
        default=None,
        help=f"environment steps (default: n_timesteps of --hyperparams, else {DEFAULT_STEPS})",
    )
    tr.add_argument("--seed", type=int, default=0, help="seed of the agent and the environments (default %(default)s)")
    tr.add_argument(
        "--n-envs",
        type=int,
        default=None,
        help=f"parallel environments (default: n_envs of --hyperparams, else {DEFAULT_N_ENVS})",
    )
    tr.add_argument(
        "--hyperparams",
        default=None,
        metavar="FILE",
        help="rl-zoo3 yaml file of hyperparameters; its entry for --env is used (default: SB3's defaults)",
    )
    tr.add_argument(
        "--out",
        default=None,
        help="run folder (default outputs/runs/ENV-SENSING[-OBSERVER][-SENSOR][-rate-RATE]-ALGO-sSEED, "
        "naming the settings that act under the sensing)",
    )
    tr.add_argument(
        "--force",
        action="store_true",
        help="replace the run in --out if there is one (default: refuse to overwrite a run)",
    )
    tr.add_argument(
        "--checkpoint-every", type=int, default=50_000, help="steps between checkpoints, 0: none (default %(default)s)"
    )
    tr.add_argument(
        "--eval-episodes", type=int, default=10, help="episodes of the final evaluation (default %(default)s)"
    )
    tr.add_argument("--no-progress", action="store_true", help="no progress bar (default: a progress bar)")
    tr.add_argument(
        "--verbose", type=int, default=0, help="SB3 verbosity, 1: training table on stdout (default %(default)s)"
    )

    ev = sub.add_parser(
        "evaluate",
        help="evaluate a trained agent under any sensing",
        formatter_class=HelpFormatter,
        description="Play a run of `smo-gym train` (its folder, model.zip or a checkpoint "
        "checkpoints/model_N_steps.zip)\nunder a sensing, which need not be the one it was trained with; "
        "prints the true returns. The run's\nrun.json gives the environment and the sensing, and the "
        "normalization statistics saved with the model are\nused, frozen.",
        epilog=f"{_SENSINGS_HELP}\n\n{spec_help('the observer and the sensor')}",
    )
    ev.add_argument("model", help="run folder, model.zip or checkpoint .zip")
    ev.add_argument("--env", default=None, help="environment id (default: as trained)")
    sensing_args(ev, False)
    ev.add_argument("--episodes", type=int, default=10, help="episodes (default %(default)s)")
    ev.add_argument("--seed", type=int, default=10_000, help="seed of the first episode (default %(default)s)")
    ev.add_argument("--json", action="store_true", help="print the result as JSON (default: one line of text)")


def _settings(res: dict, sensing: str) -> str:
    """``" (sensor X, observer Y, rate Z)"`` with only the settings that act under ``sensing``."""
    from .rl import sensing_settings

    acting = [f"{k} {res[k]}" for k in sensing_settings(sensing)]
    return f" ({', '.join(acting)})" if acting else ""


def _check_specs(sensor, observer) -> None:
    from .specs import make_sensor, parse_observer_spec

    if sensor is not None:
        make_sensor(sensor)
    if observer is not None:
        parse_observer_spec(observer)


def train(args: argparse.Namespace) -> int:
    from . import rl
    from .cli import check_env_id, check_seed_argument

    # every argument is checked before anything is made
    check_env_id(args.env)
    check_seed_argument(args.seed)
    _check_specs(args.sensor, args.observer)
    zoo = rl.load_hyperparams(args.hyperparams, args.env, args.algo) if args.hyperparams else {}
    steps = args.steps if args.steps is not None else zoo.get("n_timesteps", DEFAULT_STEPS)
    n_envs = args.n_envs if args.n_envs is not None else zoo.get("n_envs", DEFAULT_N_ENVS)
    if steps < 1 or n_envs < 1:
        raise ValueError(f"expected --steps >= 1 and --n-envs >= 1, actual value: {steps}, {n_envs}")
    if args.checkpoint_every < 0 or args.eval_episodes < 0:
        raise ValueError(
            f"expected --checkpoint-every >= 0 and --eval-episodes >= 0, actual value: "
            f"{args.checkpoint_every}, {args.eval_episodes}"
        )
    out = (
        args.out
        if args.out is not None
        else rl.default_run_folder(
            args.env, args.sensing, args.algo, args.seed, sensor=args.sensor, observer=args.observer, rate=args.rate
        )
    )
    rl.check_run_folder(out, overwrite=args.force)
    summary = rl.train(
        args.env,
        sensing=args.sensing,
        sensor=args.sensor,
        observer=args.observer,
        rate=args.rate,
        algo=args.algo,
        steps=steps,
        seed=args.seed,
        n_envs=n_envs,
        out=out,
        normalize=zoo.get("normalize"),
        hyperparams=zoo.get("hyperparams"),
        policy=zoo.get("policy", "MlpPolicy"),
        env_kwargs=zoo.get("env_kwargs"),
        checkpoint_every=args.checkpoint_every,
        evaluate_at=[steps] if args.eval_episodes else [],
        eval_episodes=args.eval_episodes,
        progress_bar=not args.no_progress,
        verbose=args.verbose,
        overwrite=args.force,
    )
    print(
        f"trained {summary['trained_steps']} steps in {summary['seconds']:.0f} s "
        f"({summary['steps_per_second']:.0f} steps/s); run folder: {out}"
    )
    for ev in summary["evaluations"]:
        print(
            f"return under {ev['sensing']}{_settings(summary, ev['sensing'])}: {ev['mean']:.1f} +- {ev['std']:.1f} "
            f"({len(ev['returns'])} episodes)"
        )
    return 0


def evaluate(args: argparse.Namespace) -> int:
    from . import rl
    from .cli import check_env_id, check_seed_argument

    if args.episodes < 1:
        raise ValueError(f"expected --episodes >= 1, actual value: {args.episodes}")
    check_seed_argument(args.seed)
    rl.run_files(args.model)
    if args.env is not None:
        check_env_id(args.env)
    _check_specs(args.sensor, args.observer)
    res = rl.evaluate(
        args.model,
        env_id=args.env,
        sensing=args.sensing,
        sensor=args.sensor,
        observer=args.observer,
        rate=args.rate,
        episodes=args.episodes,
        seed=args.seed,
    )
    if args.json:
        print(json.dumps(res))
    else:
        print(
            f"{res['env']} under {res['sensing']}{_settings(res, res['sensing'])}: return {res['mean']:.1f} +- "
            f"{res['std']:.1f} over {len(res['returns'])} episodes"
        )
    return 0


def run(args: argparse.Namespace) -> int:
    """Run ``train`` or ``evaluate`` for parsed ``args``."""
    return train(args) if args.command == "train" else evaluate(args)
