"""Optional dependencies: import them where a feature needs them, and name the extra that installs them.

The core of smo_gym (sensors, observers, ``differentiate``, the Gymnasium wrappers) needs NumPy, SciPy, numba,
MuJoCo and Gymnasium only. Everything else belongs to an extra of the package:

=================  ==========================================  =================================================
extra              installs                                    for
=================  ==========================================  =================================================
``rl``             torch, stable-baselines3, pyyaml, tqdm      :mod:`smo_gym.rl`, ``smo-gym train/evaluate``,
                                                               ``VecEstimatedVelocity``
``dm_control``     dm-control, shimmy                          dm_control suite tasks
``design``         cvxpy, clarabel                             the LMI gain designs of :mod:`smo_gym.design`
``plots``          matplotlib                                  plots (``smo-gym compare``, ``smo-gym control``)
``all``            all of the above
=================  ==========================================  =================================================
"""

from __future__ import annotations

import importlib
import sys
from types import ModuleType

__all__ = ["EXTRAS", "MissingExtraError", "progress", "require"]

#: extra -> the top-level modules it installs
EXTRAS: dict[str, tuple[str, ...]] = {
    "rl": ("torch", "stable_baselines3", "yaml", "tqdm"),
    "dm_control": ("dm_control", "shimmy"),
    "design": ("cvxpy", "clarabel"),
    "plots": ("matplotlib",),
}


class MissingExtraError(ModuleNotFoundError):
    """A module of an optional extra of smo_gym is not installed; the message names the extra to install."""


def require(module: str, extra: str) -> ModuleType:
    """Import ``module`` (dotted names allowed), which the extra ``extra`` of smo_gym installs.

    Parameters
    ----------
    module : str
        The module to import, e.g. ``"stable_baselines3.common.vec_env"``.
    extra : str
        The extra of smo_gym that installs it (a key of :data:`EXTRAS`).

    Returns
    -------
    types.ModuleType
        The imported module.

    Raises
    ------
    MissingExtraError
        A :class:`ModuleNotFoundError`: the module, or another module of the same extra that it imports, is
        missing; the message says ``pip install "smo_gym[extra]"``. Other import errors (a broken installation)
        propagate unchanged.
    ValueError
        ``extra`` is not an extra of smo_gym.
    """
    if extra not in EXTRAS:
        raise ValueError(f"expected an extra in {', '.join(sorted(EXTRAS))}, actual value: {extra!r}")
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        missing = (exc.name or module).split(".")[0]
        if missing not in EXTRAS[extra] and missing != module.split(".")[0]:
            raise
        raise MissingExtraError(
            f"this feature of smo_gym needs {missing!r}, which is not installed: "
            f'pip install "smo_gym[{extra}]" (or "smo_gym[all]")',
            name=missing,
        ) from exc


def progress(iterable, *, desc: str, total: int | None = None, unit: str = "it"):
    """``iterable`` with a progress bar on standard error: tqdm's when tqdm is installed, else a plain one.

    tqdm is optional (it comes with the ``rl`` extra); without it the bar is a line of text rewritten at every
    tenth of ``total`` (``len(iterable)`` when not given) and erased at the end, as ``tqdm(leave=False)`` does.
    """
    try:
        from tqdm.auto import tqdm
    except ImportError:
        return _plain_progress(iterable, desc=desc, total=total, unit=unit)
    return tqdm(iterable, desc=desc, total=total, unit=unit, leave=False)


def _plain_progress(iterable, *, desc: str, total: int | None, unit: str):
    if total is None:
        total = len(iterable)
    shown = -1
    line = ""
    for k, item in enumerate(iterable):
        tenth = 10 * k // max(total, 1)
        if tenth != shown:
            shown = tenth
            line = f"{desc}: {k}/{total} {unit}"
            sys.stderr.write("\r" + line)
            sys.stderr.flush()
        yield item
    if line:
        sys.stderr.write("\r" + " " * len(line) + "\r")
        sys.stderr.flush()
