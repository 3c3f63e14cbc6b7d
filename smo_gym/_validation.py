"""Typed input checks shared by every layer.

Every message follows one pattern, ``expected <what>, actual value: <what was received>``, so that a user who
passes a wrong step, gain or array sees at once what the library wanted. Numbers and arrays of numbers are
*real*: ``bool``, complex, date/time, string and other object values are rejected with ``TypeError`` rather than
converted (NumPy would turn ``True`` into 1.0, ``"2"`` into 2.0, drop an imaginary part or count nanoseconds).
"""

from __future__ import annotations

import difflib
import functools
import inspect
import math
import numbers
from collections.abc import Callable, Iterable

import numpy as np

__all__ = [
    "DivergenceError",
    "as_real_array",
    "check_bool",
    "check_choice",
    "check_equal",
    "check_int_at_least",
    "check_int_in_range",
    "check_keywords",
    "check_mask",
    "check_nonnegative",
    "check_nonnegative_array",
    "check_positive",
    "check_positive_array",
    "check_positive_parameter",
    "check_real",
    "check_real_in_range",
    "check_scale_range",
    "did_you_mean",
]


class DivergenceError(RuntimeError):
    """An observer's state became non-finite; the step was rejected and the previous state kept."""


def _short(value, limit: int = 200) -> str:
    """``repr(value)`` cut to ``limit`` characters (an error message must stay readable for a huge array)."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def did_you_mean(value, choices: Iterable[str]) -> str:
    """`` (did you mean 'x'?)`` for the choice closest to ``value``: the first that begins with it, else difflib's
    closest (ratio >= 0.5); ``""`` when none is close or ``value`` is not a string."""
    if not isinstance(value, str):
        return ""
    choices = [c for c in choices if isinstance(c, str)]
    close = [c for c in choices if value and c.startswith(value)][:1] or difflib.get_close_matches(
        value, choices, n=1, cutoff=0.5
    )
    return f" (did you mean {close[0]!r}?)" if close else ""


#: NumPy types that pass for numbers but are not (``timedelta64`` is a NumPy integer subclass)
_NOT_NUMBERS = (bool, np.bool_, np.timedelta64, np.datetime64)


def _is_real_scalar(value) -> bool:
    """A real number: Python or NumPy int/float (or another ``numbers.Real``), not a bool or a duration."""
    return isinstance(value, numbers.Real) and not isinstance(value, _NOT_NUMBERS)


def _holds_bool(sequence) -> bool:
    """Whether a (nested) list or tuple holds a bool or a bool array, which NumPy converts to numbers when other
    entries are numbers."""
    return any(
        isinstance(v, (bool, np.bool_))
        or (isinstance(v, np.ndarray) and v.dtype.kind == "b")
        or (isinstance(v, (list, tuple)) and _holds_bool(v))
        for v in sequence
    )


def _as_float(name: str, value, expected: str) -> float:
    """``value`` as a float if it is a real number; a TypeError if not, a ValueError saying ``expected`` if it is an
    integer beyond the range of a float (``float(10**400)`` raises OverflowError)."""
    if not _is_real_scalar(value):
        raise TypeError(f"expected {name} to be a real number, actual value: {_short(value)}")
    try:
        return float(value)
    except OverflowError:
        raise ValueError(
            f"expected {name} {expected}, actual value: {_short(value, 40)} (beyond a float's range)"
        ) from None


def check_names(name: str, value, kind: str = "names") -> list[str]:
    """``value`` as a list of strings; a single string is refused (iterating it would read it letter by letter), as is
    anything that is not a sequence."""
    if isinstance(value, str) or not isinstance(value, Iterable) or not all(isinstance(item, str) for item in value):
        raise TypeError(f"expected {name} as a sequence of {kind}, e.g. [{value!r:.40}], actual value: {value!r:.80}")
    return list(value)


def check_real(name: str, value) -> float:
    """Return ``value`` as a float after checking that it is a finite real number (not a bool or a string)."""
    value = _as_float(name, value, "to be finite")
    if not math.isfinite(value):
        raise ValueError(f"expected {name} to be finite, actual value: {value!r}")
    return value


def check_positive(name: str, value) -> float:
    """Return ``value`` as a float after checking that it is a finite number ``> 0``."""
    value = _as_float(name, value, "> 0 and finite")
    if not math.isfinite(value) or value <= 0.0:
        raise ValueError(f"expected {name} > 0, actual value: {value!r}")
    return value


def check_nonnegative(name: str, value) -> float:
    """Return ``value`` as a float after checking that it is a finite number ``>= 0``."""
    value = _as_float(name, value, ">= 0 and finite")
    if not math.isfinite(value) or value < 0.0:
        raise ValueError(f"expected {name} >= 0, actual value: {value!r}")
    return value


def as_real_array(name: str, value, *, copy: bool = False) -> np.ndarray:
    """``value`` as a float64 array, or ``TypeError`` if it is not an array of real numbers.

    Accepted: numbers, (nested) sequences of numbers and arrays of integer or floating dtype, and object arrays
    whose entries are all real numbers. Rejected: bools (also beside numbers in a list), complex numbers, dates and
    durations, strings, ``None`` and other objects, and ragged nested sequences (which NumPy cannot make an array
    of). Values are not checked for finiteness.
    """
    try:
        arr = np.array(value, copy=copy or None)
    except (TypeError, ValueError, OverflowError):  # ragged sequences, unconvertible objects
        raise TypeError(
            f"expected {name} to be an array of real numbers (a rectangular nesting of numbers), actual value: "
            f"{_short(value)}"
        ) from None
    kind = arr.dtype.kind
    if kind == "O" and all(_is_real_scalar(v) for v in arr.flat):
        kind = "f"  # e.g. Fractions, or Python ints too large for int64
    elif kind in "iuf" and isinstance(value, (list, tuple)) and _holds_bool(value):
        kind = "b"  # NumPy reads [True, -2.0] as [1.0, -2.0]
    if kind not in "iuf":
        what = {"b": "bool", "c": "complex", "M": "datetime", "m": "timedelta", "U": "str", "S": "bytes"}.get(
            kind, str(arr.dtype)
        )
        raise TypeError(f"expected {name} to be an array of real numbers, actual value: {what} values {_short(value)}")
    try:
        return np.asarray(arr, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise TypeError(f"expected {name} to be an array of real numbers, actual value: {_short(value)}") from None


def check_positive_array(name: str, value) -> np.ndarray:
    """Return ``value`` as a float64 array after checking that every entry is finite and ``> 0``."""
    arr = as_real_array(name, value)
    if arr.size == 0:
        raise ValueError(f"expected {name} with at least one entry, actual value: shape {arr.shape}")
    bad = ~np.isfinite(arr) | (arr <= 0.0)
    if np.any(bad):
        raise ValueError(f"expected {name} > 0 everywhere, actual value: {_short(value)}")
    return arr


def check_positive_parameter(name: str, value) -> float | np.ndarray:
    """A positive observer parameter given as one number (kept a ``float``) or one per channel (an array), checked
    as :func:`check_positive_array`."""
    arr = check_positive_array(name, value)
    return float(arr) if arr.ndim == 0 else arr


def check_nonnegative_array(name: str, value) -> np.ndarray:
    """Return ``value`` as a float64 array after checking that every entry is finite and ``>= 0``."""
    arr = as_real_array(name, value)
    if arr.size == 0:
        raise ValueError(f"expected {name} with at least one entry, actual value: shape {arr.shape}")
    bad = ~np.isfinite(arr) | (arr < 0.0)
    if np.any(bad):
        raise ValueError(f"expected {name} >= 0 everywhere, actual value: {_short(value)}")
    return arr


def check_scale_range(name: str, value, bounds: tuple[float, float]) -> tuple[float, float]:
    """A number ``s`` in ``bounds`` as ``(s, s)``, or a pair ``(low, high)`` in ``bounds`` with ``low <= high`` (a
    range to draw from); both ends of ``bounds`` included."""
    pair = tuple(value) if isinstance(value, (tuple, list)) else (value, value)
    if len(pair) != 2:
        raise ValueError(f"expected {name} a number or a pair (low, high), actual value: {_short(value)}")
    low, high = (check_real_in_range(name, v, *bounds) for v in pair)
    if low > high:
        raise ValueError(f"expected {name} (low, high) with low <= high, actual value: {value!r}")
    return low, high


def check_real_in_range(
    name: str, value, low: float, high: float, *, low_open: bool = False, high_open: bool = False
) -> float:
    """Return ``value`` as a float after checking it is a real number (not a bool) in the interval from ``low`` to
    ``high``, each end closed unless ``low_open``/``high_open``."""
    interval = f"{'(' if low_open else '['}{low}, {high}{')' if high_open else ']'}"
    value = _as_float(name, value, f"in {interval}")
    inside = (low < value if low_open else low <= value) and (value < high if high_open else value <= high)
    if not inside:
        raise ValueError(f"expected {name} in {interval}, actual value: {value!r}")
    return value


def check_equal(what: str, expected, actual) -> None:
    """Raise ``ValueError`` unless ``actual == expected`` (``what`` names the expectation: ``"a venv with action
    space"``); for values whose ``==`` is a plain bool, such as Gymnasium spaces (bounds, dtype and shape)."""
    if actual != expected:
        raise ValueError(f"expected {what} {expected}, actual value: {actual}")


def check_int_in_range(name: str, value, low: int, high: int) -> int:
    """Return ``value`` as an int after checking ``low <= value <= high``."""
    if isinstance(value, _NOT_NUMBERS) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"expected {name} to be an integer in [{low}, {high}], actual value: {_short(value)}")
    if not low <= int(value) <= high:
        raise ValueError(f"expected {name} in [{low}, {high}], actual value: {_short(value, 40)}")
    return int(value)


def check_int_at_least(name: str, value, low: int) -> int:
    """Return ``value`` as an int after checking ``value >= low``."""
    if isinstance(value, _NOT_NUMBERS) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"expected {name} to be an integer >= {low}, actual value: {_short(value)}")
    if int(value) < low:
        raise ValueError(f"expected {name} >= {low}, actual value: {_short(value, 40)}")
    return int(value)


def check_bool(name: str, value) -> bool:
    """Return ``value`` as a bool after checking it is one (``True``/``False`` or a NumPy bool, not ``"yes"``)."""
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"expected {name} to be True or False, actual value: {_short(value)}")
    return bool(value)


def check_mask(name: str, value) -> np.ndarray:
    """``value`` as a boolean array, after checking that it holds bools only (not ``"yes"``, not 0/1 numbers)."""
    arr = np.asarray(value) if not isinstance(value, np.ndarray) else value
    if arr.dtype != np.bool_:
        raise TypeError(f"expected {name} to be a bool or an array of bools, actual value: {_short(value)}")
    return arr


def check_choice(name: str, value, choices: Iterable[str]) -> str:
    """Return ``value`` after checking it is one of ``choices`` (the message lists them and the closest one)."""
    choices = tuple(choices)
    try:
        known = value in choices
    except (TypeError, ValueError):  # an object whose == does not give one bool (an array, say)
        known = False
    if not known or not isinstance(value, str):
        raise ValueError(
            f"expected {name} to be one of {', '.join(map(repr, choices))}, actual value: "
            f"{_short(value)}{did_you_mean(value, choices)}"
        )
    return value


def check_keywords(func: Callable) -> Callable:
    """Decorator: a call with an unknown keyword, a missing or a surplus argument raises a worded ``TypeError``.

    ``unknown parameter 'lipschits' of SuperTwisting (did you mean 'lipschitz'?)`` instead of Python's
    ``unexpected keyword argument``. The signature is only examined when the call itself fails to bind, so a
    correct call costs one extra function frame.
    """
    signature = inspect.signature(func)
    owner = func.__qualname__.removesuffix(".__init__")

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        try:
            return func(*args, **kwargs)
        except TypeError:
            try:
                signature.bind(*args, **kwargs)
            except TypeError:  # the call itself did not bind: say which argument, and what was meant
                raise _binding_error(owner, signature, args, kwargs) from None
            raise  # a TypeError of the body (a validated argument of the wrong type): unchanged

    return wrapper


def _binding_error(owner: str, signature: inspect.Signature, args: tuple, kwargs: dict) -> TypeError:
    params = signature.parameters
    names = [p for p, v in params.items() if v.kind not in (v.VAR_POSITIONAL, v.VAR_KEYWORD) and p != "self"]
    takes_kwargs = any(v.kind is v.VAR_KEYWORD for v in params.values())
    for key, value in kwargs.items():
        if key not in params and not takes_kwargs:
            return TypeError(
                f"unknown parameter {key!r} of {owner}: expected one of {', '.join(names)}, "
                f"actual value: {key}={_short(value, 80)}{did_you_mean(key, names)}"
            )
    positional = [p for p, v in params.items() if v.kind in (v.POSITIONAL_ONLY, v.POSITIONAL_OR_KEYWORD)]
    if len(args) > len(positional) and not any(v.kind is v.VAR_POSITIONAL for v in params.values()):
        return TypeError(
            f"expected at most {len(positional) - ('self' in params)} positional arguments to "
            f"{owner} ({', '.join(p for p in positional if p != 'self')}), actual value: "
            f"{len(args) - ('self' in params)}"
        )
    given = set(positional[: len(args)]) | set(kwargs)
    for p, v in params.items():
        if v.default is v.empty and v.kind not in (v.VAR_POSITIONAL, v.VAR_KEYWORD) and p not in given:
            return TypeError(f"expected argument {p!r} of {owner}, actual value: missing")
    duplicated = set(positional[: len(args)]) & set(kwargs)
    return TypeError(
        f"expected each argument of {owner} once, actual value: {', '.join(sorted(duplicated))} "
        "given by position and by keyword"
    )
