"""Typed input checks shared by every layer.

Every message follows one pattern, ``expected <what>, actual value: <what was received>``, so that a user who
passes a wrong step, gain or array sees at once what the library wanted.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

__all__ = [
    "DivergenceError",
    "check_choice",
    "check_finite_array",
    "check_int_in_range",
    "check_positive",
    "check_positive_array",
    "check_real_in_range",
]


class DivergenceError(RuntimeError):
    """An observer's state became non-finite; the step was rejected and the previous state kept."""


def check_positive(name: str, value) -> float:
    """Return ``value`` as a float after checking that it is a finite number ``> 0``."""
    if isinstance(value, bool) or not np.isscalar(value) or not isinstance(value, (int, float, np.number)):
        raise TypeError(f"expected {name} to be a real number, actual value: {value!r}")
    value = float(value)
    if not np.isfinite(value) or value <= 0.0:
        raise ValueError(f"expected {name} > 0, actual value: {value!r}")
    return value


def check_positive_array(name: str, value) -> np.ndarray:
    """Return ``value`` as a float64 array after checking that every entry is finite and ``> 0``."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise TypeError(f"expected {name} to be a number or an array of numbers, actual value: {value!r}") from None
    bad = ~np.isfinite(arr) | (arr <= 0.0)
    if np.any(bad):
        raise ValueError(f"expected {name} > 0 everywhere, actual value: {value!r}")
    return arr


def check_real_in_range(name: str, value, low: float, high: float, *, low_open: bool = False,
                        high_open: bool = False) -> float:
    """Return ``value`` as a float after checking it is a real number (not a bool) in the interval from ``low`` to
    ``high``, each end closed unless ``low_open``/``high_open``."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"expected {name} to be a real number, actual value: {value!r}")
    value = float(value)
    interval = f"{'(' if low_open else '['}{low}, {high}{')' if high_open else ']'}"
    inside = (low < value if low_open else low <= value) and (value < high if high_open else value <= high)
    if not inside:
        raise ValueError(f"expected {name} in {interval}, actual value: {value!r}")
    return value


def check_int_in_range(name: str, value, low: int, high: int) -> int:
    """Return ``value`` as an int after checking ``low <= value <= high``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"expected {name} to be an integer in [{low}, {high}], actual value: {value!r}")
    if not low <= int(value) <= high:
        raise ValueError(f"expected {name} in [{low}, {high}], actual value: {value!r}")
    return int(value)


def check_choice(name: str, value, choices: Iterable[str]) -> str:
    """Return ``value`` after checking it is one of ``choices`` (the message lists them)."""
    choices = tuple(choices)
    if value not in choices:
        raise ValueError(f"expected {name} to be one of {', '.join(map(repr, choices))}, actual value: {value!r}")
    return value


def check_finite_array(name: str, arr: np.ndarray) -> None:
    """Raise ``ValueError`` naming the first non-finite entry of ``arr``."""
    bad = ~np.isfinite(arr)
    if np.any(bad):
        index = tuple(int(i) for i in np.argwhere(bad)[0])
        raise ValueError(
            f"expected finite values in {name}, actual value: {arr[index]!r} at index {index} "
            f"(channel {index[-1] if index else 0})"
        )
