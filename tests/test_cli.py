"""``smo-gym compare``: the CLI runs, and its numbers are the wrapper's numbers on the same measurements."""

from __future__ import annotations

import dataclasses
import re

import gymnasium as gym
import numpy as np
import pytest

from smo_gym import cli
from smo_gym.experiments import compare as lib
from smo_gym.wrappers import EstimatedVelocity


@pytest.fixture(autouse=True)
def _private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SMO_GYM_CACHE_DIR", str(tmp_path / "cache"))


def _row(text: str, name: str) -> list[str]:
    """The RMSE and max-error cells of the table row of observer ``name`` (the timing column left out)."""
    return next(line.split()[1:3] for line in text.splitlines() if line.split()[:1] == [name])


def test_compare_prints_table_and_writes_png(tmp_path, capsys):
    out = tmp_path / "cmp.png"
    code = cli.main(
        [
            "compare",
            "--env",
            "InvertedPendulum-v5",
            "--steps",
            "60",
            "--seed",
            "1",
            "--out",
            str(out),
            "--observers",
            "auto,super-twisting,finite-difference,levant:order=1:discretization=matching",
            "--per-joint",
            "--joints",
            "hinge,0",
            "--sensor",
            "low-cost",
            "--rate",
            "1",
        ]
    )
    text = capsys.readouterr().out
    assert code == 0
    for word in (
        "observer",
        "RMSE",
        "max err",
        "us/step",
        "super-twisting",
        "levant:order=1:discretization=matching",
        "RMSE per dof",
        "slider [m/s]",
        "hinge [rad/s]",
    ):
        assert word in text
    assert re.search(r"^auto: .* on (slider|hinge)", text, re.MULTILINE)  # what auto chose, by joint name
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the run the options ask for: the library's recording with them gives the header and the rows printed
    rec = lib.record_rollout("InvertedPendulum-v5", sensor="low-cost", rate=1, steps=60, seed=1)
    (fd,) = lib.compare_observers(rec, ["finite-difference"])
    table = lib.format_table(rec, [fd])
    assert table.splitlines()[0] in text
    assert _row(text, "finite-difference") == _row(table, "finite-difference")  # RMSE and max error


def test_finite_difference_row_is_the_backward_difference_of_the_measurements():
    rec = lib.record_rollout("Hopper-v5", sensor="encoder-12bit-noisy", steps=40, seed=2)
    (fd,) = lib.compare_observers(rec, ["finite-difference"])
    starts = set(rec.episode_starts.tolist())
    for i in range(1, len(rec.z_measured)):
        if i not in starts and i - 1 not in starts:
            np.testing.assert_allclose(
                fd.velocity[i], (rec.z_measured[i] - rec.z_measured[i - 1]) / rec.dt, rtol=1e-12, atol=1e-9
            )
    # the metrics are over every estimate: all samples but the first of each episode (the observer's start)
    err = np.delete(fd.velocity - rec.qvel, rec.episode_starts, axis=0)
    assert len(err) == len(rec.qvel) - len(rec.episode_starts)
    assert fd.max_error == np.max(np.abs(err))
    np.testing.assert_allclose(fd.rmse, np.sqrt(np.mean(err**2)), rtol=1e-12)


@pytest.mark.parametrize("env_id", ["Hopper-v5", "Ant-v5"])
def test_compare_uses_the_wrappers_code_path(env_id):
    """Same seed, policy and sensor: the comparison's estimates equal the wrapper's at every control period."""
    seed, steps = 3, 30
    rec = lib.record_rollout(env_id, sensor="encoder-12bit-noisy", steps=steps, seed=seed)
    (auto,) = lib.compare_observers(rec, ["auto"])
    env = EstimatedVelocity(gym.make(env_id), sensor="encoder-12bit-noisy")  # the default observer: "auto"
    policy = lib.smooth_random_policy(env.action_space, seed)
    obs, info = env.reset(seed=seed)
    fs = env.adapter.frame_skip
    for k in range(steps):
        obs, _, term, trunc, info = env.step(policy(obs))
        if term or trunc:
            break
        np.testing.assert_array_equal(info["smo"]["qvel_estimate"], auto.velocity[(k + 1) * fs])
        np.testing.assert_array_equal(info["smo"]["qvel"], rec.qvel[(k + 1) * fs])


def test_bad_input_exit_codes(capsys):
    assert cli.main(["compare", "--observers", "magic", "--steps", "5"]) == 2
    assert "super-twisting" in capsys.readouterr().err
    assert cli.main(["compare", "--env", "Hopper-v5", "--rate", "3", "--steps", "5"]) == 2
    assert "divisor of frame_skip=4" in capsys.readouterr().err
    assert cli.main(["compare", "--sensor", "nope", "--steps", "5"]) == 2
    assert "low-cost" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli.main([])


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["compare", "--env", "Hoper-v5"], "did you mean 'Hopper-v5'?"),
        (["compare", "--joints", "thigh"], "did you mean 'thigh_joint'?"),
        (["compare", "--joints", "7"], "expected a dof index in [0, 5]"),
        (["compare", "--plot-seconds", "-1"], "expected a finite --plot-seconds > 0, actual value: -1.0"),
        (["compare", "--plot-seconds", "inf"], "expected a finite --plot-seconds > 0, actual value: inf"),
        (["compare", "--out", "{file}/plot.png"], "is a file"),
        (["compare", "--out", "{tmp}"], "expected a plot file ending in"),
        (["compare", "--observers", "levant:ordr=1"], "did you mean 'order'?"),
        (["compare", "--sensor", "encoder:counts=1024"], "did you mean 'counts_per_revolution'?"),
        (["train", "--env", "Hopper-v55"], "did you mean 'Hopper-v5'?"),
        (["train", "--env", "Hopper-v5", "--out", "{file}/run"], "is a file"),
        (["train", "--env", "Hopper-v5", "--out", ""], "expected out to be a folder path"),
        (["train", "--env", "Hopper-v5", "--observer", "levnat"], "did you mean 'levant'?"),
        (["evaluate", "{tmp}/missing"], "expected a run folder, model.zip or checkpoint"),
        (["compare", "--seed", "-1"], "expected --seed >= 0, actual value: -1"),
        (["train", "--env", "Hopper-v5", "--seed", "-1"], "expected --seed >= 0"),
        (["evaluate", "{tmp}/missing", "--seed", "-1"], "expected --seed >= 0"),
        (["control", "--env", "NoSuch-v0"], "expected a registered Gymnasium environment id"),
        (["control", "--frame-skip", "0"], "expected --frame-skip >= 1"),
        (["control", "--seeds", "0"], "expected --seeds >= 1"),
        (["control", "--seconds", "0"], "expected --seconds > 0"),
        (["control", "--controller", ",,"], "expected at least one controller"),
        (["control", "--out", "{file}"], "is a file"),
    ],
)
def test_bad_arguments_are_refused_before_any_work_with_one_line(argv, message, tmp_path, capsys, monkeypatch):
    """Unknown env ids, joints, observers and sensor options, a negative plot window and unusable output paths end
    the command with one line on stderr, before a rollout or a training starts."""
    from smo_gym import rl

    def no_work(*args, **kwargs):
        raise AssertionError("work started before the arguments were checked")

    from smo_gym.experiments import closed_loop

    monkeypatch.setattr(lib, "record_rollout", no_work)
    monkeypatch.setattr(rl, "make_vec", no_work)
    monkeypatch.setattr(closed_loop, "compare_controllers", no_work)
    (tmp_path / "file").write_text("not a folder")
    argv = [a.format(file=tmp_path / "file", tmp=tmp_path) for a in argv]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert message in err


def test_help_shows_every_default_and_explains_every_column(capsys):
    parser = cli.build_parser()
    subparsers = next(a for a in parser._actions if a.dest == "command").choices
    for name in ("compare", "train", "evaluate"):
        for action in subparsers[name]._actions:
            if action.dest in ("help", "model"):
                continue
            assert "default" in (action.help or ""), f"{name} {action.option_strings} shows no default"
        with pytest.raises(SystemExit):
            cli.main([name, "--help"])
        text = " ".join(capsys.readouterr().out.split())
        assert "%(default)" not in text
    with pytest.raises(SystemExit):
        cli.main(["compare", "--help"])
    text = capsys.readouterr().out
    for column, meaning in lib.TABLE_COLUMNS.items():
        assert f"{column} " in text and " ".join(meaning.split()[:4]) in " ".join(text.split())
    assert "rad/s" in text and "m/s" in text


def test_table_has_exactly_the_explained_columns():
    """No column without an explanation (the former convergence column measured nothing: environments start at
    rest, so every observer read 0)."""
    rec = lib.record_rollout("InvertedPendulum-v5", steps=20, seed=0)
    results = lib.compare_observers(rec, ["finite-difference", "super-twisting"])
    header = lib.format_table(rec, results).splitlines()[1].split("  ")
    assert [h.strip() for h in header if h.strip()] == list(lib.TABLE_COLUMNS)


def test_sensor_spec_in_compare(tmp_path, capsys):
    out = tmp_path / "cmp.png"
    spec = "encoder:counts_per_revolution=1024:noise_std=2e-3+delay:samples=1"
    assert (
        cli.main(
            [
                "compare",
                "--env",
                "InvertedPendulum-v5",
                "--steps",
                "30",
                "--sensor",
                spec,
                "--observers",
                "finite-difference",
                "--out",
                str(out),
                "--no-progress",
            ]
        )
        == 0
    )
    assert f"sensor {spec}" in capsys.readouterr().out
    rec = lib.record_rollout("InvertedPendulum-v5", sensor=spec, steps=30)
    # one-sample delay: the first two measurements are the first sample, and the grid is 2 pi / 1024 (hinge)
    np.testing.assert_array_equal(rec.z_measured[0], rec.z_measured[1])
    hinge = rec.names.index("hinge")
    k = rec.z_measured[:, hinge] / (2 * np.pi / 1024)
    np.testing.assert_allclose(k, np.round(k), atol=1e-9)


def _diverging(rec, name="diverging", scale=1e189):
    """An ObserverResult whose estimate blows up to ``scale`` and then becomes non-finite."""
    v = rec.qvel.copy()
    n = len(v)
    v[2 : n // 2] = scale * np.where(np.arange(2, n // 2) % 2, 1.0, -1.0)[:, None]
    v[n // 2 :] = np.nan
    return lib.ObserverResult(
        name=name,
        velocity=v,
        rmse=float("nan"),
        max_error=float("inf"),
        cost_us=1.0,
        rmse_per_dof=np.full(v.shape[1], np.nan),
        diverged_at=n // 2 * rec.dt,
    )


def test_plot_axes_follow_the_true_velocity_not_a_diverging_observer():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rec = lib.record_rollout("InvertedPendulum-v5", steps=100, seed=4)
    results = lib.compare_observers(rec, ["finite-difference"]) + [_diverging(rec)]
    seconds = 0.3
    fig = lib.velocity_figure(rec, results, ["slider", "hinge"], seconds=seconds)
    n = round(seconds / rec.dt) + 1
    axes = fig.axes
    for ax, d, unit in zip(axes, [0, 1], ["m/s", "rad/s"], strict=True):
        true = rec.qvel[:n, d]
        lo, hi = ax.get_ylim()
        span = true.max() - true.min()
        assert lo <= true.min() and hi >= true.max()
        assert (hi - lo) <= 4 * span  # within a small factor of the true range, although one estimate is 1e189
        assert ax.get_ylabel().endswith(f"[{unit}]")
    fig.canvas.draw()
    legend = fig.legends[0]
    box = legend.get_window_extent()
    for ax in axes:
        assert not box.overlaps(ax.get_window_extent()), "the legend covers the data"
    labels = [t.get_text() for t in legend.get_texts()]
    assert any("diverging (diverged at" in lbl and "clipped" in lbl and "1e+189" in lbl for lbl in labels)
    plt.close(fig)


def test_environment_ids_of_dm_control_need_no_import_first():
    """``smo-gym compare/train/evaluate --env dm_control/...`` make their environments with ``smo_gym.envs.make``,
    which registers shimmy's ids itself: checked in a fresh interpreter (here shimmy may already be imported)."""
    import os
    import subprocess
    import sys

    code = (
        "import sys; from smo_gym.envs import make; assert 'shimmy' not in sys.modules; "
        "env = make('dm_control/cartpole-swingup-v0'); env.reset(seed=0); env.close()"
    )
    result = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
        env={**os.environ, "MUJOCO_GL": "disable"},
    )
    assert result.returncode == 0, result.stderr[-2000:]


def _run_module(*args):
    import os
    import subprocess
    import sys

    return subprocess.run(
        [sys.executable, "-m", "smo_gym", *args],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
        env={**os.environ, "MUJOCO_GL": "disable"},
    )


def test_python_dash_m_runs_the_command_line():
    result = _run_module("compare", "--env", "NoSuchEnv-v0")
    assert result.returncode == 2
    assert result.stderr.strip() == (
        "smo-gym compare: error: expected a registered Gymnasium environment id, actual value: 'NoSuchEnv-v0'"
    )


def test_version():
    import smo_gym

    result = _run_module("--version")
    assert result.returncode == 0 and result.stdout.strip() == f"smo-gym {smo_gym.__version__}"


def test_compare_runs_an_observer_told_the_actions(tmp_path, capsys):
    """The rollout records its ``ctrl``: ``--observers`` takes the names that need the input."""
    out = tmp_path / "cmp.png"
    argv = ["compare", "--env", "InvertedPendulum-v5", "--steps", "30", "--no-progress", "--out", str(out)]
    assert cli.main([*argv, "--observers", "kalman-ca-input,finite-difference"]) == 0
    text = capsys.readouterr().out
    rec = lib.record_rollout("InvertedPendulum-v5", steps=30)
    results = lib.compare_observers(rec, ["kalman-ca-input", "finite-difference"])
    assert _row(text, "kalman-ca-input") == _row(lib.format_table(rec, results), "kalman-ca-input")
    told = results[0]
    # and the input is the recorded one: without it (zeros) the filter's estimates are others
    blind = lib.compare_observers(dataclasses.replace(rec, inputs=np.zeros_like(rec.inputs)), ["kalman-ca-input"])[0]
    assert not np.allclose(blind.velocity, told.velocity)


def test_the_comparison_refuses_what_it_would_misread():
    """An unstable ``smoothing`` (2: the actions grow to inf) gave a recording with infinite inputs; a misspelled
    spec in ``observer_kwargs`` was dropped; a spec string was read letter by letter; an empty comparison crashed
    ``format_table``; ``plot_limits`` returned NaN or inverted limits; a bool was dof index 1."""
    with pytest.raises(ValueError, match="smoothing"):
        lib.record_rollout("InvertedPendulum-v5", steps=5, smoothing=2.0)
    rec = lib.record_rollout("InvertedPendulum-v5", steps=20)
    with pytest.raises(ValueError, match="keyed by specs"):
        lib.compare_observers(rec, ["alpha-beta"], observer_kwargs={"alpha-bta": {"alpha": 0.5}})
    with pytest.raises(TypeError, match="sequence of specs"):
        lib.compare_observers(rec, "kalman-ca")
    assert "observer" in lib.format_table(rec, lib.compare_observers(rec, []))
    for velocity, kwargs in (([np.nan, 1.0], {}), ([0.0, 1.0], {"margin": -5.0}), ([-1e308, 1e308], {})):
        with pytest.raises(ValueError, match="expected"):
            lib.plot_limits(velocity, **kwargs)
    assert lib.plot_limits([0.0, 1.0]) == (-1.0, 2.0)
    with pytest.raises(TypeError, match="integer index"):
        lib.resolve_joints(["a", "b", "c"], [True])
    with pytest.raises(ValueError, match=r"shape \(T, 3\)"):
        lib.resolve_joints(["a", "b", "c"], None, np.ones((5, 2)))


def test_estimate_errors_refuse_a_velocity_of_another_shape():
    """A column of one dof's estimates broadcast against every dof's true velocity: errors of samples it does not
    hold, with no error raised."""
    rec = lib.record_rollout("InvertedPendulum-v5", steps=10)
    assert rec.qvel.shape[1] == 2
    np.testing.assert_array_equal(lib.estimate_errors(rec, rec.qvel), 0.0)
    with pytest.raises(ValueError, match=r"recording's shape"):
        lib.estimate_errors(rec, rec.qvel[:, :1])
