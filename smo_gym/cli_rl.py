"""``smo-gym train`` and ``smo-gym evaluate``: argument parsing and printing only; the work is :mod:`smo_gym.rl`."""

from __future__ import annotations

import argparse
import json

__all__ = ["add_subcommands", "run"]


def _rate(text: str):
    return int(text) if text.lstrip("-").isdigit() else text


def add_subcommands(sub) -> None:
    """Register ``train`` and ``evaluate`` on the ``smo-gym`` subparsers ``sub``."""
    from .observers import OBSERVERS
    from .rl import ALGOS, SENSINGS
    from .sensors import PRESETS

    def sensing_args(p, defaults: bool):
        d = (lambda v: v) if defaults else (lambda v: None)
        p.add_argument("--sensing", choices=SENSINGS, default=d("estimated"),
                       help="what the policy observes" + (" (default %(default)s)" if defaults else
                                                          " (default: as trained)"))
        p.add_argument("--sensor", default=d("encoder-12bit-noisy"), help=f"sensor preset: {', '.join(PRESETS)}")
        p.add_argument("--observer", default=d("super-twisting"), help=f"observer: {', '.join(OBSERVERS)}")
        p.add_argument("--rate", type=_rate, default=d("physics"), help="'physics', 'env' or k physics steps")

    tr = sub.add_parser("train", help="train a Stable-Baselines3 agent under realistic sensing",
                        description="Train PPO or SAC on a Gymnasium MuJoCo environment whose policy sees measured "
                                    "positions and estimated velocities (or the true state, finite differences, ...). "
                                    "Writes model.zip, vecnormalize.pkl, run.json, progress.csv and checkpoints.")
    tr.add_argument("--env", default="InvertedDoublePendulum-v5", help="environment id (default %(default)s)")
    sensing_args(tr, True)
    tr.add_argument("--algo", choices=ALGOS, default="PPO")
    tr.add_argument("--steps", type=int, default=100_000, help="environment steps (default %(default)s)")
    tr.add_argument("--seed", type=int, default=0)
    tr.add_argument("--n-envs", type=int, default=1)
    tr.add_argument("--out", default=None, help="run folder (default outputs/runs/ENV-SENSING-ALGO-sSEED)")
    tr.add_argument("--checkpoint-every", type=int, default=50_000, help="steps between checkpoints (0: none)")
    tr.add_argument("--eval-episodes", type=int, default=10, help="episodes of the final evaluation")
    tr.add_argument("--no-progress", action="store_true", help="no progress bar")
    tr.add_argument("--verbose", type=int, default=0, help="SB3 verbosity (1: training table on stdout)")

    ev = sub.add_parser("evaluate", help="evaluate a trained agent under any sensing",
                        description="Play a run of `smo-gym train` (folder or model.zip) under a sensing, which "
                                    "need not be the one it was trained with; prints the true returns.")
    ev.add_argument("model", help="run folder or model.zip")
    ev.add_argument("--env", default=None, help="environment id (default: as trained)")
    sensing_args(ev, False)
    ev.add_argument("--episodes", type=int, default=10)
    ev.add_argument("--seed", type=int, default=10_000)
    ev.add_argument("--json", action="store_true", help="print the result as JSON")


def run(args: argparse.Namespace) -> int:
    from . import rl

    if args.command == "train":
        out = args.out or f"outputs/runs/{args.env}-{args.sensing}-{args.algo}-s{args.seed}"
        summary = rl.train(args.env, sensing=args.sensing, sensor=args.sensor, observer=args.observer,
                           rate=args.rate, algo=args.algo, steps=args.steps, seed=args.seed, n_envs=args.n_envs,
                           out=out, checkpoint_every=args.checkpoint_every, evaluate_at=[args.steps],
                           eval_episodes=args.eval_episodes, progress_bar=not args.no_progress,
                           verbose=args.verbose)
        ev = summary["evaluations"][-1] if summary["evaluations"] else None
        print(f"trained {summary['trained_steps']} steps in {summary['seconds']:.0f} s "
              f"({summary['steps_per_second']:.0f} steps/s); run folder: {out}")
        if ev:
            print(f"return under {ev['sensing']}: {ev['mean']:.1f} +- {ev['std']:.1f} ({len(ev['returns'])} episodes)")
        return 0
    res = rl.evaluate(args.model, env_id=args.env, sensing=args.sensing, sensor=args.sensor,
                      observer=args.observer, rate=args.rate, episodes=args.episodes, seed=args.seed)
    if args.json:
        print(json.dumps(res))
    else:
        print(f"{res['env']} under {res['sensing']} (sensor {res['sensor']}, observer {res['observer']}, rate "
              f"{res['rate']}): return {res['mean']:.1f} +- {res['std']:.1f} over {len(res['returns'])} episodes")
    return 0
