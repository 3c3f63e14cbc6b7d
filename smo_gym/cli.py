"""Command line: ``smo-gym compare`` (observers side by side on the same measurements of a MuJoCo rollout).

``smo-gym control``: the output-feedback control experiments of :mod:`smo_gym.control.experiments`.

Thin by design: parsing and printing only; the work is :mod:`smo_gym.wrappers.compare`.
"""

from __future__ import annotations

import argparse
import sys

__all__ = ["build_parser", "main"]

DEFAULT_OBSERVERS = "super-twisting,levant,levant:discretization=matching,high-gain,kalman-ca,finite-difference"


def _rate(text: str):
    return int(text) if text.lstrip("-").isdigit() else text


def build_parser() -> argparse.ArgumentParser:
    from .observers import OBSERVERS
    from .sensors import PRESETS

    parser = argparse.ArgumentParser(prog="smo-gym", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    cmp_ = sub.add_parser(
        "compare", help="compare velocity observers on one MuJoCo rollout",
        description="Run one Gymnasium MuJoCo environment under a seeded smooth random policy, measure its joint "
                    "positions with a sensor preset, and run several velocity observers on the same measurements.",
    )
    cmp_.add_argument("--env", default="Hopper-v5", help="Gymnasium MuJoCo environment id (default %(default)s)")
    cmp_.add_argument("--sensor", default="encoder-12bit-noisy",
                      help=f"sensor preset: {', '.join(PRESETS)} (default %(default)s)")
    cmp_.add_argument("--observers", default=DEFAULT_OBSERVERS,
                      help=f"comma-separated observers, each a name from {', '.join(OBSERVERS)}, optionally with "
                           "options name:key=value:... (default %(default)s)")
    cmp_.add_argument("--rate", type=_rate, default="physics",
                      help="'physics', 'env' or k physics steps per sample (default %(default)s)")
    cmp_.add_argument("--steps", type=int, default=1000, help="environment steps (default %(default)s)")
    cmp_.add_argument("--seed", type=int, default=0, help="seed of policy, environment and sensor (default 0)")
    cmp_.add_argument("--joints", default="",
                      help="comma-separated dof names or indices to plot (default: the two most active)")
    cmp_.add_argument("--out", default="outputs/smo_gym_compare.png", help="PNG file (default %(default)s)")
    cmp_.add_argument("--plot-seconds", type=float, default=1.0, help="time window of the plot (default 1 s)")
    cmp_.add_argument("--per-joint", action="store_true", help="also print the RMSE of every dof")
    cmp_.add_argument("--no-progress", action="store_true", help="no progress bar")
    from .control.experiments import add_subcommand as add_control

    add_control(sub)
    from .cli_rl import add_subcommands as add_rl

    add_rl(sub)
    return parser


def compare(args: argparse.Namespace) -> int:
    from .wrappers import compare as lib

    if args.steps < 1:
        raise ValueError(f"expected --steps >= 1, actual value: {args.steps}")
    observers = [name.strip() for name in args.observers.split(",") if name.strip()]
    for spec in observers:
        lib.parse_observer_spec(spec)  # fail before the rollout on a wrong name
    progress = not args.no_progress and args.steps >= 200
    rec = lib.record_rollout(args.env, sensor=args.sensor, rate=args.rate, steps=args.steps, seed=args.seed,
                             progress=progress)
    results = lib.compare_observers(rec, observers, progress=progress)
    print(lib.format_table(rec, results, per_joint=args.per_joint))
    joints = [j.strip() for j in args.joints.split(",") if j.strip()]
    path = lib.plot_velocities(rec, results, joints, args.out, seconds=args.plot_seconds)
    print(f"plot: {path}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``smo-gym`` console script."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        if args.command == "compare":
            return compare(args)
        if args.command in ("train", "evaluate"):
            from .cli_rl import run as rl

            return rl(args)
        if args.command == "control":
            from .control.experiments import cli as control

            return control(args)
    except (ValueError, TypeError) as exc:
        print(f"smo-gym {args.command}: error: {exc}", file=sys.stderr)
        return 2
    return 1  # pragma: no cover - argparse enforces the subcommand


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
