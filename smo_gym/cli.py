"""Command line: ``smo-gym compare`` (observers side by side on the same measurements of a MuJoCo rollout).

``smo-gym train`` / ``evaluate``: reinforcement learning under realistic sensing (:mod:`smo_gym.cli_rl`);
``smo-gym control``: the output-feedback control experiments of :mod:`smo_gym.experiments.control`.

Thin by design: parsing, checking and printing only; the work is :mod:`smo_gym.experiments.compare` and
:mod:`smo_gym.rl`. Every argument is checked before any work starts, and a wrong one ends the command with one line
on stderr (exit status 2), not a traceback. Observers and sensors are written ``name:key=value:...``
(:mod:`smo_gym.specs`).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from gymnasium.error import Error as GymnasiumError

from ._extras import MissingExtraError, require
from .envs import check_env_id

__all__ = [
    "DEFAULT_OBSERVERS",
    "HelpFormatter",
    "build_parser",
    "check_env_id",
    "check_output_file",
    "check_seed_argument",
    "main",
]

DEFAULT_OBSERVERS = (
    "auto,super-twisting,levant:discretization=implicit,low-power-high-gain,alpha-beta,kalman-ca,finite-difference"
)


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Keeps the line breaks of descriptions and epilogs (the column and syntax explanations)."""


def parse_rate(text: str):
    """``--rate``: ``physics``, ``env`` or a positive number of physics steps per sample."""
    if text in ("physics", "env"):
        return text
    try:
        k = int(text)
    except ValueError:
        k = 0
    if k < 1:
        raise argparse.ArgumentTypeError(f"expected 'physics', 'env' or an integer >= 1, actual value: {text!r}")
    return k


def spec_help(kind: str) -> str:
    """The syntax of observer and sensor specs, for the epilogs (wrapped to 100 columns)."""
    import textwrap

    from .observers import OBSERVERS
    from .sensors import PRESETS
    from .specs import SENSOR_MODELS

    def item(head: str, text: str) -> str:
        return textwrap.fill(text, 100, initial_indent=f"  {head:<11}", subsequent_indent=" " * 13)

    return "\n".join(
        [
            f"{kind} are written name:key=value:key=value (values: numbers, true/false, none or text).",
            item(
                "observers:",
                f"{', '.join(OBSERVERS)}; options are constructor arguments, e.g. "
                "levant:order=1:lipschitz=50 (gains not given are calibrated from a rollout, as the "
                "wrapper does)",
            ),
            item(
                "sensors:",
                f"a preset ({', '.join(PRESETS)}) or a model ({', '.join(SENSOR_MODELS)}) with its "
                "constructor arguments, e.g. encoder:counts_per_revolution=4096:noise_std=1e-3; models "
                "chain with +, e.g. encoder:counts_per_revolution=1024+delay:samples=2",
            ),
        ]
    )


def build_parser() -> argparse.ArgumentParser:
    from . import __version__
    from .experiments.compare import TABLE_COLUMNS

    parser = argparse.ArgumentParser(prog="smo-gym", description=__doc__.splitlines()[0], formatter_class=HelpFormatter)
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    columns = "\n".join(f"  {name:<9} {text}" for name, text in TABLE_COLUMNS.items())
    cmp_ = sub.add_parser(
        "compare",
        help="compare velocity observers on one MuJoCo rollout",
        formatter_class=HelpFormatter,
        description="Run one Gymnasium MuJoCo environment under a seeded smooth random policy, measure its joint "
        "positions with\na sensor, and run several velocity observers on the same measurements. Prints "
        "a table and writes a plot\nof true and estimated velocities.",
        epilog=f"table columns (metrics over every estimate: each sample but the first of each episode, where the\n"
        f"observer starts at the first measurement with zero velocity; transients after it are included):\n"
        f"{columns}\n"
        f"  a diverged observer (non-finite state) shows the time it diverged instead of its errors.\n\n"
        f"plot: the y-axis of each dof is set by its true velocity; estimates beyond it are clipped at the\n"
        f"edge, marked with triangles, and their legend entry gives the fraction off scale and the peak.\n"
        f"Units: rad/s for hinge (and rotational) dofs, m/s for slide (and translational) dofs.\n\n"
        + spec_help("observers and the sensor"),
    )
    cmp_.add_argument(
        "--env",
        default="Hopper-v5",
        help="Gymnasium MuJoCo environment id, also smo_gym/... and dm_control/... (default %(default)s)",
    )
    cmp_.add_argument("--sensor", default="encoder-12bit-noisy", help="sensor spec (default %(default)s)")
    cmp_.add_argument(
        "--observers", default=DEFAULT_OBSERVERS, help="comma-separated observer specs (default %(default)s)"
    )
    cmp_.add_argument(
        "--rate",
        type=parse_rate,
        default="physics",
        help="'physics', 'env' or k physics steps per sample (default %(default)s)",
    )
    cmp_.add_argument("--steps", type=int, default=1000, help="environment steps (default %(default)s)")
    cmp_.add_argument(
        "--seed", type=int, default=0, help="seed of policy, environment and sensor (default %(default)s)"
    )
    cmp_.add_argument(
        "--joints", default="", help="comma-separated dof names or indices to plot (default: the two most active)"
    )
    cmp_.add_argument("--out", default="outputs/smo_gym_compare.png", help="plot file (default %(default)s)")
    cmp_.add_argument(
        "--plot-seconds", type=float, default=1.0, help="time window of the plot in seconds (default %(default)s)"
    )
    cmp_.add_argument("--per-joint", action="store_true", help="also print the RMSE of every dof (default: off)")
    cmp_.add_argument("--no-progress", action="store_true", help="no progress bar (default: a bar from 200 steps)")
    from .experiments.control import add_subcommand as add_control

    add_control(sub)
    from .cli_rl import add_subcommands as add_rl

    add_rl(sub)
    return parser


# ----------------------------------------------------------------------------------------------------------------
# checks shared by the subcommands (before any work)
# ----------------------------------------------------------------------------------------------------------------
def check_seed_argument(seed: int) -> int:
    """``--seed`` after checking it is >= 0 (Gymnasium refuses a negative one only once the work has started)."""
    if seed < 0:
        raise ValueError(f"expected --seed >= 0, actual value: {seed}")
    return seed


def check_output_file(path: str) -> Path:
    """``path`` after checking that a plot can be written there: a format matplotlib writes, not a folder, and
    the nearest existing folder above it writable (folders in between are created)."""
    Figure = require("matplotlib.figure", "plots").Figure

    out = Path(path)
    formats = Figure().canvas.get_supported_filetypes()
    if out.suffix.lstrip(".").lower() not in formats:
        raise ValueError(f"expected a plot file ending in .{', .'.join(sorted(formats))}, actual value: {path!r}")
    if out.is_dir():
        raise ValueError(f"expected a plot file, actual value: {path!r} is a folder")
    parent = out.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise ValueError(f"expected the plot under a folder, actual value: {str(parent)!r} is a file")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ValueError(f"expected a writable folder for the plot, actual value: {str(parent)!r} is not writable")
    return out


def compare(args: argparse.Namespace) -> int:
    from .experiments import compare as lib
    from .specs import make_sensor

    # every argument is checked before the rollout
    check_seed_argument(args.seed)
    if args.steps < 1:
        raise ValueError(f"expected --steps >= 1, actual value: {args.steps}")
    if not 0 < args.plot_seconds < float("inf"):
        raise ValueError(f"expected a finite --plot-seconds > 0, actual value: {args.plot_seconds}")
    check_env_id(args.env)
    make_sensor(args.sensor)
    observers = [name.strip() for name in args.observers.split(",") if name.strip()]
    if not observers:
        raise ValueError(f"expected at least one observer in --observers, actual value: {args.observers!r}")
    lib.parse_observer_specs(observers, inputs=True)  # the rollout records its ctrl
    check_output_file(args.out)
    joints = [j.strip() for j in args.joints.split(",") if j.strip()]
    if joints:
        lib.resolve_joints(lib.env_dof_names(args.env), joints)
    progress = not args.no_progress and args.steps >= 200
    rec = lib.record_rollout(
        args.env, sensor=args.sensor, rate=args.rate, steps=args.steps, seed=args.seed, progress=progress
    )
    results = lib.compare_observers(rec, observers, progress=progress)
    print(lib.format_table(rec, results, per_joint=args.per_joint))
    for result in results:  # what "auto" chose, per joint
        found = getattr(result.observer, "selection", None)
        if found is not None:
            names = lib.dof_names(rec.context["adapter"].model)
            groups = {}
            for joint, spec in zip(names, found.names, strict=True):
                groups.setdefault(spec, []).append(joint)
            print(f"{result.name}: " + "; ".join(f"{spec} on {', '.join(j)}" for spec, j in groups.items()))
    path = lib.plot_velocities(rec, results, joints, args.out, seconds=args.plot_seconds)
    print(f"plot: {path}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``smo-gym`` console script (and of ``python -m smo_gym``)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        if args.command == "compare":
            return compare(args)
        if args.command in ("train", "evaluate"):
            from .cli_rl import run as rl

            return rl(args)
        if args.command == "control":
            from .experiments.control import cli as control

            return control(args)
    except (ValueError, TypeError, MissingExtraError, OSError, ArithmeticError, GymnasiumError) as exc:
        # bad arguments, files that cannot be written or read, an expression that divides by zero, an id or seed
        # Gymnasium refuses: one error line and exit status 2, as argparse's own errors, never a traceback
        message = " ".join(str(exc).split()) or type(exc).__name__  # one line
        print(f"smo-gym {args.command}: error: {message}", file=sys.stderr)
        return 2
    return 1  # pragma: no cover - argparse enforces the subcommand


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
