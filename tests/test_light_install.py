"""A light install: the core runs without any extra, and a feature of a missing extra names the extra to install.

The optional modules are hidden from a subprocess by a meta-path finder that refuses to import them, as if they
were not installed (``pip install smo_gym`` without extras).
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from smo_gym._extras import EXTRAS, MissingExtraError, require

ROOT = Path(__file__).resolve().parents[1]

#: every module of every extra, and tqdm (a progress bar, optional)
OPTIONAL = sorted({m for modules in EXTRAS.values() for m in modules})

BLOCKER = textwrap.dedent(
    f"""
    import importlib.abc
    import sys

    BLOCKED = {set(OPTIONAL)!r}

    class Blocker(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in BLOCKED:
                raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
            return None

    sys.meta_path.insert(0, Blocker())
    for name in [m for m in sys.modules if m.split(".")[0] in BLOCKED]:
        del sys.modules[name]
    """
)


def run_light(code: str, timeout: float = 240) -> subprocess.CompletedProcess:
    """Run ``code`` in a fresh interpreter (this checkout first on the path) with the optional modules hidden."""
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
        "MUJOCO_GL": "disable",
    }
    return subprocess.run(
        [sys.executable, "-c", BLOCKER + textwrap.dedent(code)],
        capture_output=True,
        text=True,
        env=env,
        cwd=ROOT,
        timeout=timeout,
        check=False,
    )


def test_the_blocker_hides_the_optional_modules():
    """The check below would pass vacuously if the finder let an optional module through."""
    res = run_light(
        """
        import importlib
        for name in BLOCKED:
            try:
                importlib.import_module(name)
            except ImportError:
                continue
            raise SystemExit(f"{name} imported")
        print("all hidden")
        """
    )
    assert res.returncode == 0, res.stderr
    assert "all hidden" in res.stdout


def test_the_core_runs_without_extras(tmp_path):
    res = run_light(
        f"""
        import os, sys
        os.environ["SMO_GYM_CACHE_DIR"] = {str(tmp_path)!r}
        import gymnasium as gym
        import numpy as np
        import smo_gym, smo_gym.observers, smo_gym.sensors, smo_gym.wrappers
        from smo_gym.wrappers import EstimatedVelocity

        env = EstimatedVelocity(gym.make("InvertedPendulum-v5"))
        obs, info = env.reset(seed=0)
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        assert obs.shape == env.observation_space.shape and np.all(np.isfinite(obs))
        assert info["smo"]["qvel_estimate"].shape == (2,)
        y = np.sin(np.linspace(0.0, 1.0, 101))[:, None]
        assert smo_gym.differentiate(y, 0.01, "super-twisting", lipschitz=2.0).shape == (101, 1, 2)
        loaded = sorted(m for m in sys.modules if m.split(".")[0] in BLOCKED)
        print("loaded optional:", loaded)
        """
    )
    assert res.returncode == 0, res.stderr
    assert "loaded optional: []" in res.stdout


@pytest.mark.parametrize(
    "extra, code",
    [
        ("rl", "from smo_gym.wrappers import VecEstimatedVelocity"),
        ("rl", "import smo_gym.rl; smo_gym.rl.train('InvertedPendulum-v5', steps=10)"),
        ("design", "from smo_gym import design; design.switched_gain_lmi(n=2, kappa=1.0, rho_d=1.0, rho_v=1.0)"),
        ("dm_control", "from smo_gym.wrappers import make_dm_control; make_dm_control('cartpole', 'swingup')"),
        ("dm_control", "import smo_gym.envs; smo_gym.envs.make('dm_control/cartpole-swingup-v0')"),
        ("plots", "from smo_gym.experiments.control import _plt; _plt()"),
    ],
)
def test_a_missing_extra_is_named(extra, code):
    res = run_light(
        f"""
        try:
            {code}
        except ImportError as exc:
            print("ImportError:", exc)
        else:
            print("no error")
        """
    )
    assert res.returncode == 0, res.stderr
    assert "ImportError:" in res.stdout, res.stdout
    assert f'pip install "smo_gym[{extra}]"' in res.stdout, res.stdout


def test_the_cli_names_a_missing_extra():
    """``smo-gym compare`` checks that it can write its plot before any work: a one-line error naming the extra."""
    res = run_light(
        """
        from smo_gym.cli import main
        raise SystemExit(main(["compare", "--steps", "5"]))
        """
    )
    assert res.returncode == 2, res.stderr
    assert 'pip install "smo_gym[plots]"' in res.stderr


def test_require_returns_the_module_and_checks_the_extra():
    import numpy

    assert require("numpy", "plots") is numpy
    with pytest.raises(ValueError, match="expected an extra in"):
        require("numpy", "nonsense")
    with pytest.raises(MissingExtraError, match=r'pip install "smo_gym\[design\]"') as info:
        require("smo_gym_no_such_module", "design")
    assert isinstance(info.value, ModuleNotFoundError)


def test_require_leaves_other_import_errors_alone(tmp_path, monkeypatch):
    """A module of the extra that is installed but fails to import something else is a broken installation, not a
    missing extra: its own error comes through unchanged."""
    (tmp_path / "smo_gym_broken_module.py").write_text("import smo_gym_some_other_missing_module\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(ModuleNotFoundError) as info:
        require("smo_gym_broken_module", "plots")
    assert not isinstance(info.value, MissingExtraError)
    assert info.value.name == "smo_gym_some_other_missing_module"


def test_plain_progress_yields_everything(capsys):
    from smo_gym._extras import _plain_progress

    assert list(_plain_progress(range(25), desc="work", total=None, unit="step")) == list(range(25))
    err = capsys.readouterr().err
    assert "work: 0/25 step" in err and "work: 20/25 step" in err
