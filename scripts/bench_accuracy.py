#!/usr/bin/env python
r"""Accuracy of the wrapper's velocity estimates: every observer on the same measurements, per environment,
sensor preset and sampling rate.

For each environment x sensor preset (:data:`smo_gym.sensors.PRESETS`: ``ideal``, ``encoder-12bit``,
``encoder-12bit-noisy``, ``low-cost``) x rate (``"physics"``: every MuJoCo step inside ``frame_skip``; ``"env"``:
once per environment step), one rollout under a seeded smooth random policy is recorded with
:func:`smo_gym.experiments.compare.record_rollout` (the wrapper's own substep hook and
:class:`~smo_gym.engine.measurement.JointMeasurement`), and every observer of :data:`smo_gym.observers.OBSERVERS`
(all of them differentiate the measured joint coordinates), and the two of :data:`TOLD_THE_ACTIONS` (the IMM
estimator told the recorded control input, :class:`~smo_gym.observers.KalmanIMMInput`, and ``auto`` with it as a
candidate), run on those same measurements through :func:`smo_gym.experiments.compare.compare_observers`, with the
wrapper's default gains (:func:`~smo_gym.calibration.default_observer` from the wrapper's calibration).
``FiniteDifference`` (the backward difference) and ``KalmanCA`` (constant-acceleration Kalman filter,
``from_levels``) are in the registry and so appear in every row as the references.

The number is ``compare_observers``' ``rmse``: the velocity RMSE over all dofs and estimates, i.e. every sample
but the first of each episode, where observers restart from the first measurement with zero velocity, as in the
wrapper (transients after it are included). A diverged
observer (non-finite state) is shown as ``div``. The smallest RMSE of a row is in bold; observers within 1 % of
it (or within ``1e-9`` times the velocity RMS: round-off on the Euler-integrated environments, where the backward
difference is exact with an ideal sensor) share the win. The second table counts wins per observer.

Run: ``MUJOCO_GL=disable .venv/bin/python scripts/bench_accuracy.py`` (a few minutes; ``--quick``: two
environments, two sensors, shorter rollouts). ``--markdown FILE`` also writes the tables to ``FILE``.
"""

from __future__ import annotations

import argparse
import inspect
import math
import os
import sys
import time
import warnings

import numpy as np

os.environ.setdefault("MUJOCO_GL", "disable")

from smo_gym.experiments.compare import compare_observers, estimate_errors, record_rollout
from smo_gym.observers import OBSERVERS
from smo_gym.specs import parse_observer_spec
from smo_gym.wrappers import EstimatedVelocity

ENVS = ("InvertedPendulum-v5", "InvertedDoublePendulum-v5", "Hopper-v5", "HalfCheetah-v5", "Walker2d-v5", "Ant-v5")
SENSORS = ("ideal", "encoder-12bit", "encoder-12bit-noisy", "low-cost")
RATES = ("physics", "env")
REFERENCES = ("finite-difference", "kalman-ca")
#: relative and velocity-scale tolerances of a shared win
TIE_RELATIVE, TIE_SCALE = 0.01, 1e-9
#: floor of the best RMSE in the regret, relative to the row's velocity RMS
REGRET_FLOOR = 1e-3


def default_observer_name() -> str:
    """The observer ``EstimatedVelocity`` uses when none is given (read from its signature)."""
    return inspect.signature(EstimatedVelocity.__init__).parameters["observer"].default


#: the columns told the control input (the recordings keep it): the IMM estimator with the input's jumps, and
#: ``auto`` with it as its candidate for all joints
TOLD_THE_ACTIONS = ("auto:model=kalman-imm-input", "kalman-imm-input")


def observer_names() -> list[str]:
    """Every registered observer, the wrapper's default first, then those told the control input, and the two
    references last."""
    default = default_observer_name()
    middle = [n for n in OBSERVERS if n != default and n not in REFERENCES]
    return [default, *TOLD_THE_ACTIONS, *middle, *REFERENCES]


def winners(rmse: dict[str, float], scale: float) -> list[str]:
    """Observers whose RMSE is within the tie tolerance of the smallest finite one."""
    finite = {k: v for k, v in rmse.items() if math.isfinite(v)}
    if not finite:
        return []
    best = min(finite.values())
    return [k for k, v in finite.items() if v <= best * (1.0 + TIE_RELATIVE) + TIE_SCALE * scale]


def worst_case_lower_bound(rec) -> float:
    r"""The largest over dofs of :math:`2\sqrt{\epsilon L}`: no differentiator of samples with errors up to
    :math:`\epsilon` of a signal with :math:`|f''| \le L` can guarantee a smaller worst-case error (the
    Kolmogorov-Landau inequality of the continuous-time limit; sampling only removes information; Levant 2003,
    Haimovich et al. 2021). :math:`\epsilon` per dof: half the quantization step plus three standard deviations
    of the remaining random error (Gaussian noise has no bound: a 99.7 % one); ``L``: the largest acceleration of
    the dof in the rollout. Zero for an ideal sensor."""
    resolution = np.asarray(rec.resolution, dtype=float)
    rest = np.sqrt(np.maximum(np.asarray(rec.noise_std, dtype=float) ** 2 - resolution**2 / 12.0, 0.0))
    eps = resolution / 2.0 + 3.0 * rest
    starts = set(int(i) for i in rec.episode_starts)
    keep = np.array([i not in starts for i in range(1, len(rec.qvel))])
    accel = np.abs(np.diff(rec.qvel, axis=0) / rec.dt)[keep]
    L = accel.max(axis=0) if len(accel) else np.zeros(rec.qvel.shape[1])
    return float(np.max(2.0 * np.sqrt(eps * L)))


def joint_oracles(errors: list[np.ndarray]) -> tuple[float, float]:
    """Two hindsight oracles over the observers' velocity errors (each ``(T, nv)``, same samples): the RMSE of the
    best observer of each joint, and of the best convex blend ``w e_a + (1 - w) e_b`` of the two best of each
    joint (``w`` in [0, 1] minimizing that joint's squared error). No rule that chooses or mixes these observers
    per joint from other data can do better on this rollout."""
    E = np.stack(errors)  # (observers, T, nv)
    mse = np.mean(E**2, axis=1)
    best = np.argsort(mse, axis=0)
    chosen, blended = [], []
    for j in range(E.shape[2]):
        a, b = E[best[0, j], :, j], E[best[1, j], :, j]
        chosen.append(mse[best[0, j], j])
        d = a - b
        w = float(np.clip(-np.dot(b, d) / np.dot(d, d), 0.0, 1.0)) if np.dot(d, d) > 0 else 1.0
        blended.append(np.mean((w * a + (1 - w) * b) ** 2))
    return float(np.sqrt(np.mean(chosen))), float(np.sqrt(np.mean(blended)))


def run(envs, sensors, rates, steps: int, seed: int, names: list[str], smoothing: float = 0.9) -> list[dict]:
    rows = []
    for env_id in envs:
        for rate in rates:
            for sensor in sensors:
                t0 = time.perf_counter()
                if any(r["env"] == env_id and r["sensor"] == sensor and r["frame_skip"] == 1 for r in rows):
                    continue  # one physics step per env step (dm_control cartpole, acrobot, cheetah): same row
                rec = record_rollout(env_id, sensor=sensor, rate=rate, steps=steps, seed=seed, smoothing=smoothing)
                results = compare_observers(rec, names)
                rmse = {r.name: (r.rmse if r.diverged_at is None else float("nan")) for r in results}
                free = [r for r in results if r.diverged_at is None and r.name not in TOLD_THE_ACTIONS]
                per_joint, blend = joint_oracles([estimate_errors(rec, r.velocity) for r in free])
                scale = float(np.sqrt(np.mean(rec.qvel**2)))
                rows.append(
                    dict(
                        env=env_id,
                        sensor=sensor,
                        rate=rate,
                        dt=rec.dt,
                        samples=len(rec.qvel),
                        frame_skip=rec.context["adapter"].frame_skip,
                        episodes=len(rec.episode_starts),
                        scale=scale,
                        rmse=rmse,
                        max_error={r.name: (r.max_error if r.diverged_at is None else float("inf")) for r in results},
                        observed={r.name: r.rmse_observed for r in results},
                        bound=worst_case_lower_bound(rec),
                        joint_oracle=per_joint,
                        blend_oracle=blend,
                        diverged={r.name for r in results if r.diverged_at is not None},
                        winners=winners({k: v for k, v in rmse.items() if k not in TOLD_THE_ACTIONS}, scale),
                    )
                )
                print(
                    f"  {env_id} {sensor} {rate}: {len(rec.qvel)} samples, {time.perf_counter() - t0:.1f} s, "
                    f"best {', '.join(rows[-1]['winners'])}",
                    file=sys.stderr,
                    flush=True,
                )
    return rows


def regret_table(rows: list[dict], names: list[str]) -> dict[str, tuple[float, float]]:
    """Per observer: geometric mean and maximum over rows of ``rmse / max(best, REGRET_FLOOR * vel. RMS)``, the best
    among the observers not told the actions."""
    ratios = {n: [] for n in names}
    for row in rows:
        finite = [v for k, v in row["rmse"].items() if math.isfinite(v) and k not in TOLD_THE_ACTIONS]
        best = max(min(finite), REGRET_FLOOR * row["scale"]) if finite else float("nan")
        for n in names:
            ratios[n].append(row["rmse"][n] / best)
    cap = max(v for vals in ratios.values() for v in vals if math.isfinite(v))
    out = {}
    for n, vals in ratios.items():
        v = np.array([x if math.isfinite(x) else cap for x in vals])
        out[n] = (float(np.exp(np.mean(np.log(np.maximum(v, 1.0))))), float(np.max(v)))
    return out


def format_tables(rows: list[dict], names: list[str]) -> str:
    short = {
        "super-twisting": "ST",
        "levant": "Levant",
        "ured": "URED",
        "uniform-levant": "uLevant",
        "high-gain": "HG",
        "finite-difference": "FD",
        "kalman-ca": "KalmanCA",
        "switched-gain": "SwitchedHG",
        "low-power-high-gain": "LowPowerHG",
        "ilf-finite": "ILF-fin",
        "ilf-fixed": "ILF-fix",
        "filtering": "Filtering",
        "alpha-beta": "AlphaBeta",
        "kalman-imm": "KalmanIMM",
        "discrete-hosm": "DT-HOSM",
        "auto": "auto",
    }
    cols = [short.get(n.split(":")[0], n.split(":")[0]) + n[len(n.split(":")[0]) :] for n in names]
    out = [
        "| environment | sensor | rate | vel. RMS | " + " | ".join(cols) + " |",
        "|---|---|---|---:|" + "---:|" * len(cols),
    ]
    for row in rows:
        cells = []
        for n in names:
            v = row["rmse"][n]
            text = "div" if n in row["diverged"] else f"{v:.3g}"
            cells.append(f"**{text}**" if n in row["winners"] else text)
        env = row["env"].replace("-v5", "").replace("dm_control/", "").replace("-v0", "")
        rate = "physics = env" if row["frame_skip"] == 1 else row["rate"]
        out.append(f"| {env} | {row['sensor']} | {rate} | {row['scale']:.3g} | " + " | ".join(cells) + " |")
    default = default_observer_name()
    out += [
        "",
        f"Wins per observer over {len(rows)} rows (shared wins count for each; the wrapper's default is "
        f"`{default}`). Regret: RMSE / best RMSE of the row, the best floored at {REGRET_FLOOR:g} x the velocity "
        "RMS (so round-off-exact rows do not dominate); geometric mean and worst over the rows (diverged or "
        "non-finite: counted as the worst finite regret of the table).",
        "",
        '| observer | wins | at rate="physics" | at rate="env" | wins, sensor not ideal | regret, geo. mean | '
        "regret, worst | diverged |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    regrets = regret_table(rows, names)
    free = [n for n in names if n not in TOLD_THE_ACTIONS]
    for n in sorted(free, key=lambda n: -sum(n in r["winners"] for r in rows)):
        wins = [r for r in rows if n in r["winners"]]
        g, worst = regrets[n]
        out.append(
            f"| {n} | {len(wins)} | {sum(r['rate'] == 'physics' for r in wins)} | "
            f"{sum(r['rate'] == 'env' for r in wins)} | {sum(r['sensor'] != 'ideal' for r in wins)} | "
            f"{g:.3g} | {worst:.3g} | {sum(n in r['diverged'] for r in rows)} |"
        )
    told = [n for n in names if n in TOLD_THE_ACTIONS]
    if told:
        out += ["", "Told the actions (not in the wins above: the best of a row is among the observers without them):"]
        for n in told:
            g, worst = regrets[n]
            below = sum(r["rmse"][n] <= min(r["rmse"][w] for w in r["winners"]) * (1.0 + TIE_RELATIVE) for r in rows)
            out.append(
                f"- `{n}`: at or below the row's best in {below} of {len(rows)} rows; regret against it {g:.3g} "
                f"(geometric mean), worst {worst:.3g}."
            )
    counts = {n: sum(n in r["winners"] for r in rows) for n in free}
    if default not in counts:  # a subset without the default (--observers): no verdict on it
        return "\n".join(out)
    top = max(counts.values())
    leaders = [n for n, c in counts.items() if c == top]
    verdict = (
        "wins most rows"
        if default in leaders and len(leaders) == 1
        else "shares the most wins"
        if default in leaders
        else f"does not win most rows ({counts[default]} wins against {top} for {', '.join(leaders)})"
    )
    out += ["", f"Default observer `{default}` {verdict}."]
    return "\n".join(out)


def auto_table(rows: list[dict]) -> str:
    """``auto`` against the better of the two references on every row: RMSE and max error, the ratio the target
    reads, and the row's worst-case lower bound; then the summary the targets are stated in."""
    out = [
        "| environment | sensor | rate | auto | FD | KalmanCA | auto / best ref. | auto max | FD max | KalmanCA max "
        "| lower bound |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    ratios, physics_fd, oracle, joint_oracle, blend_oracle = [], [], [], [], []
    told = [n for n in TOLD_THE_ACTIONS if all(n in row["rmse"] for row in rows)]
    told_fd, told_ratio = {n: [] for n in told}, {n: [] for n in told}
    seen_fd = {n: [] for n in ("auto", *told)}  # the same ratio at the samples a policy sees
    for row in rows:
        rm, mx = row["rmse"], row["max_error"]
        best = min(rm["finite-difference"], rm["kalman-ca"])
        floor = TIE_SCALE * row["scale"]  # round-off-exact rows: both at machine precision
        ratio = (rm["auto"] + floor) / (best + floor)
        ratios.append(ratio)
        for n in told:
            told_ratio[n].append((rm[n] + floor) / (best + floor))
        if row["sensor"] != "ideal" and row["rate"] == "physics" and not row["env"].startswith("dm_control/"):
            physics_fd.append(rm["auto"] / rm["finite-difference"])
            free = [v for k, v in rm.items() if k not in TOLD_THE_ACTIONS and math.isfinite(v)]
            oracle.append(min(free) / rm["finite-difference"])
            joint_oracle.append(row["joint_oracle"] / rm["finite-difference"])
            blend_oracle.append(row["blend_oracle"] / rm["finite-difference"])
            for n in told:
                told_fd[n].append(rm[n] / rm["finite-difference"])
            for n, found in seen_fd.items():
                found.append(row["observed"][n] / row["observed"]["finite-difference"])
        env = row["env"].replace("-v5", "").replace("dm_control/", "").replace("-v0", "")
        rate = "physics = env" if row["frame_skip"] == 1 else row["rate"]
        cells = [f"{rm[n]:.3g}" for n in ("auto", "finite-difference", "kalman-ca")]
        cells.append(f"**{ratio:.3g}**" if ratio > 1.02 else f"{ratio:.3g}")
        cells += [f"{mx[n]:.3g}" for n in ("auto", "finite-difference", "kalman-ca")]
        cells.append(f"{row['bound']:.3g}")
        out.append(f"| {env} | {row['sensor']} | {rate} | " + " | ".join(cells) + " |")
    worse = sum(r > 1.02 for r in ratios)
    out += [
        "",
        f"auto / better of FD and KalmanCA: worst {max(ratios):.3g}, geometric mean "
        f"{float(np.exp(np.mean(np.log(ratios)))):.3g}, {worse} of {len(rows)} rows above 1.02 (bold).",
    ]
    if physics_fd:
        out.append(
            f"auto / FD, geometric mean over the {len(physics_fd)} rows with a non-ideal sensor at "
            f'rate="physics": {float(np.exp(np.mean(np.log(physics_fd)))):.3f}; the best observer of each of those '
            f"rows, chosen with hindsight (an oracle over every column not told the actions): "
            f"{float(np.exp(np.mean(np.log(oracle)))):.3f}; the best of each joint: "
            f"{float(np.exp(np.mean(np.log(joint_oracle)))):.3f}; the best blend of the two best of each joint: "
            f"{float(np.exp(np.mean(np.log(blend_oracle)))):.3f}."
        )
    if physics_fd:
        out.append(
            "The same geometric mean over the samples the wrapper returns (the last of each environment step: what "
            "a policy sees): "
            + ", ".join(f"{n} {float(np.exp(np.mean(np.log(found)))):.3g}" for n, found in seen_fd.items())
            + "."
        )
    for n in told:  # the same summaries for the columns told the control input
        r = told_ratio[n]
        out.append(
            f"{n} / better of FD and KalmanCA: worst {max(r):.3g}, {sum(x > 1.02 for x in r)} of {len(r)} rows "
            "above 1.02"
            + (
                f"; / FD, geometric mean over the same rows: {float(np.exp(np.mean(np.log(told_fd[n])))):.3g}."
                if told_fd[n]
                else "."
            )
        )
    out.append(f"auto diverged on {sum('auto' in row['diverged'] for row in rows)} rows.")
    return "\n".join(out)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--envs", default=",".join(ENVS), help="Gymnasium ids; dm_control suite tasks as dm_control/<domain>-<task>-v0"
    )
    parser.add_argument("--sensors", default=",".join(SENSORS))
    parser.add_argument("--rates", default=",".join(RATES))
    parser.add_argument("--steps", type=int, default=400, help="environment steps per rollout")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--smoothing",
        type=float,
        default=0.9,
        help="the policy a_{k+1} = s a_k + (1 - s) u_k of the rollouts (default 0.9; 0: uniform random actions)",
    )
    parser.add_argument(
        "--observers",
        default="",
        help="comma-separated names or specs name:key=value (default: all of OBSERVERS)",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="InvertedDoublePendulum-v5 and HalfCheetah-v5, ideal and noisy encoder, 150 steps",
    )
    parser.add_argument("--markdown", metavar="FILE", help="also write the tables to FILE")
    args = parser.parse_args(argv)
    if args.quick:
        args.envs, args.sensors, args.steps = (
            "InvertedDoublePendulum-v5,HalfCheetah-v5",
            "ideal,encoder-12bit-noisy",
            150,
        )
    warnings.filterwarnings("ignore")
    names = [n.strip() for n in args.observers.split(",") if n.strip()] or observer_names()
    for spec in names:  # names, or specs "name:key=value:..." such as levant:discretization=implicit
        try:
            parse_observer_spec(spec)
        except ValueError as exc:
            parser.error(str(exc))
    if "dm_control/" in args.envs:
        import shimmy  # noqa: F401  (registers the dm_control/... ids)
    t0 = time.perf_counter()
    rows = run(
        [e for e in args.envs.split(",") if e],
        [s for s in args.sensors.split(",") if s],
        [r for r in args.rates.split(",") if r],
        args.steps,
        args.seed,
        names,
        args.smoothing,
    )
    text = format_tables(rows, names)
    if {"auto", *REFERENCES} <= set(names):
        text += "\n\n" + auto_table(rows)
    header = (
        f"Velocity RMSE (rad/s or m/s, all dofs, every sample but each episode's first), {args.steps} env steps "
        f"per rollout, seed {args.seed}, "
        + (f"smooth random policy (smoothing {args.smoothing:g})" if args.smoothing else "uniform random actions")
        + "; bold = best of the row (ties within 1 %) among the observers not told the actions\n"
    )
    print(header)
    print(text)
    print(f"\n({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    if args.markdown:
        with open(args.markdown, "w") as fh:
            fh.write(header + "\n" + text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
