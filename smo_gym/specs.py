r"""Observers and sensors written as text: ``name:key=value:key=value`` (the command line's syntax).

One syntax for both, shared by ``smo-gym compare``, ``train`` and ``evaluate`` and by
:mod:`smo_gym.experiments.compare`:

``levant:order=1:discretization=matching``
    an observer of :data:`smo_gym.observers.OBSERVERS` with constructor options (gains not given are calibrated
    by the wrapper, :func:`smo_gym.calibration.default_observer`);
``mechanical-super-twisting:mass_scale=1.1``
    a model-based observer of :data:`smo_gym.observers.MODEL_BASED_OBSERVERS` with constructor options and the
    settings of its private model (:data:`MODEL_OPTIONS`), for :class:`smo_gym.wrappers.EstimatedVelocity`;
``auto:model=true:mass_scale=1.1``
    the automatic choice, with a model-based observer as one more candidate (``model``: ``true`` or a model-based
    name) and the settings of its model;
``encoder-12bit-noisy``
    a sensor preset of :data:`smo_gym.sensors.PRESETS` (presets take no options);
``encoder:counts_per_revolution=4096:noise_std=1e-3``
    a sensor model of :mod:`smo_gym.sensors` by its name in :data:`SENSOR_MODELS` with constructor options;
``encoder:counts_per_revolution=1024+delay:samples=2+dropout:probability=0.02``
    models chained with ``+`` (applied left to right, :class:`smo_gym.sensors.Chain`).

Values are read by :func:`parse_value` (``true``/``false``, ``none``, integers, floats, else strings). An unknown
name or option raises ``ValueError`` that lists the valid ones and suggests the closest.

Only :mod:`smo_gym.observers` and :mod:`smo_gym.sensors` are imported: every layer above may use this module.
"""

from __future__ import annotations

import inspect
import re

from . import sensors
from ._validation import did_you_mean
from .observers import FAMILIES, MODEL_BASED_OBSERVERS, OBSERVERS, Observer
from .observers.input_kalman import InputJumpFilter

__all__ = [
    "MODEL_OPTIONS",
    "SENSOR_MODELS",
    "make_sensor",
    "needs_model",
    "parse_observer_spec",
    "parse_spec",
    "parse_value",
    "sensor_names",
]

#: spec name -> sensor model class (the stages of :mod:`smo_gym.sensors` and the encoder)
SENSOR_MODELS: dict[str, type[sensors.Sensor]] = {
    "encoder": sensors.Encoder,
    "gaussian-noise": sensors.GaussianNoise,
    "uniform-noise": sensors.UniformNoise,
    "quantization": sensors.Quantization,
    "bias": sensors.Bias,
    "drift": sensors.Drift,
    "delay": sensors.Delay,
    "dropout": sensors.Dropout,
    "outliers": sensors.Outliers,
}

# "+" joins chained sensor models; not the sign of an exponent such as 1e+3 (a digit follows it there)
_CHAIN_SPLIT = re.compile(r"\+(?=[A-Za-z])")


def parse_value(text: str) -> bool | int | float | str | None:
    """A spec value: ``true``/``false`` -> bool, ``none`` -> None, then int, then float, else the string itself."""
    if not isinstance(text, str):
        raise TypeError(f"expected a spec value as a string, actual value: {type(text).__name__} {text!r:.80}")
    lowered = text.strip().lower()
    if lowered in ("true", "false"):
        return lowered == "true"
    if lowered == "none":
        return None
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            continue
    return text


def _check_name(kind: str, name: str, choices) -> None:
    if name not in choices:
        raise ValueError(
            f"expected {kind} in {', '.join(choices)}, actual value: {name!r}{did_you_mean(name, choices)}"
        )


def parse_spec(spec: str, kind: str = "spec") -> tuple[str, dict]:
    """Split ``"name:key=value:..."`` into ``(name, {key: parse_value(value)})`` (syntax only; ``kind`` names the
    thing in error messages)."""
    if not isinstance(spec, str):
        raise TypeError(f"expected a {kind} as text name:key=value:..., actual value: {spec!r}")
    name, *items = spec.strip().split(":")
    if not name:
        raise ValueError(f"expected a {kind} as name:key=value:..., actual value: {spec!r}")
    kwargs: dict = {}
    for item in items:
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or not key or not value.strip():
            raise ValueError(f"expected {kind} options as key=value, actual value: {item!r} in {spec!r}")
        if key in kwargs:
            raise ValueError(f"expected each {kind} option once, actual value: {key!r} twice in {spec!r}")
        kwargs[key] = parse_value(value.strip())
    return name, kwargs


def _options(callables, skip=("self", "dt")) -> list[str]:
    """Named parameters of ``callables`` (keyword-only ones of every callable after the first)."""
    names: list[str] = []
    for k, fn in enumerate(callables):
        for p in inspect.signature(fn).parameters.values():
            if p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD) or p.name in skip:
                continue
            if k > 0 and p.kind is not p.KEYWORD_ONLY:
                continue
            if p.name not in names:
                names.append(p.name)
    return names


def _check_keys(kind: str, name: str, kwargs: dict, valid: list[str], spec: str) -> None:
    for key in kwargs:
        if key not in valid:
            raise ValueError(
                f"expected options of {kind} {name!r} in {', '.join(valid) or '(none)'}, actual value: {key!r} in "
                f"{spec!r}{did_you_mean(key, valid)}"
            )


#: the settings of a model-based observer's private model of the environment (``mass_scale``: every mass and
#: inertia scaled, a model mismatch; ``contact``: ``"unknown"`` or ``"measured"``), as
#: :func:`smo_gym.wrappers.model_based.model_based_observer` reads them
MODEL_OPTIONS = ("mass_scale", "contact")


def needs_model(observer, options: dict | None = None) -> bool:
    """Whether the observer ``observer`` (a name, a spec or an observer) with ``options`` runs a model of the
    environment: a model-based name, ``"auto"`` with ``model`` set (it may choose one), or an observer that takes the
    input. Such an observer takes the environment's control input at every sample, so it runs in
    :class:`~smo_gym.wrappers.EstimatedVelocity` only."""
    if isinstance(observer, Observer):
        return observer.takes_input
    if not isinstance(observer, str):
        return False
    if ":" in observer:  # a spec: its name, and its options under the given ones
        observer, spec_options = parse_observer_spec(observer)
        options = {**spec_options, **(options or {})}
    return observer in MODEL_BASED_OBSERVERS or (
        observer == "auto" and isinstance(options, dict) and bool(options.get("model"))
    )


def observer_options(name: str) -> list[str]:
    """The options an observer spec may set: the parameters its family registers
    (:attr:`Family.parameters <smo_gym.observers.Family.parameters>`: the constructor's, ``dt`` excepted since the
    rate sets it); for a model-based observer ``lipschitz`` (the bound of its model miss, which the dissipative
    observer's gains are designed from), its constructor's other scalar options and :data:`MODEL_OPTIONS` (the
    dynamics are built from the environment), or for one without a model (``"kalman-ca-input"``) the options of its
    constructor that are not fitted; for ``"auto"`` (:mod:`smo_gym.selection`) ``model`` (a model-based
    candidate: ``true`` or its name) and :data:`MODEL_OPTIONS`."""
    _check_name("an observer name", name, ["auto", *OBSERVERS, *MODEL_BASED_OBSERVERS])
    if name == "auto":
        return ["model", *MODEL_OPTIONS]
    if name in MODEL_BASED_OBSERVERS:
        cls = MODEL_BASED_OBSERVERS[name]
        if issubclass(cls, InputJumpFilter):  # fitted from the environment's runs, no model
            fitted = ("self", "dt", "process_noise", "measurement_noise", "input_gain", "jump_noise")
            return _options([cls], skip=fitted)
        built = ("self", "dt", "dynamics", "transform", "gains")  # from the environment's model
        options = _options([cls], skip=built)
        return [*dict.fromkeys(["lipschitz", *options]), *MODEL_OPTIONS]
    return list(FAMILIES[name].parameters)


def parse_observer_spec(spec: str) -> tuple[str, dict]:
    """``"levant:order=1:discretization=matching"`` -> ``("levant", {"order": 1, "discretization": "matching"})``.

    Raises
    ------
    ValueError
        Unknown observer name or option (the message lists the valid ones and suggests the closest).
    """
    name, kwargs = parse_spec(spec, "observer")
    _check_keys("observer", name, kwargs, observer_options(name), spec)
    return name, kwargs


def sensor_names() -> list[str]:
    """Every sensor name a spec may start with: the presets, then the models."""
    return list(sensors.PRESETS) + list(SENSOR_MODELS)


def _sensor_part(spec: str, whole: str) -> sensors.Sensor:
    name, kwargs = parse_spec(spec, "sensor")
    _check_name("a sensor preset or model", name, sensor_names())
    if name in sensors.PRESETS:
        if kwargs:
            raise ValueError(
                f"expected no options for the sensor preset {name!r} (a fixed model; build one from models "
                f"instead, e.g. 'encoder:counts_per_revolution=4096:noise_std=1e-3'), actual value: {whole!r}"
            )
        return sensors.make_sensor(name)
    cls = SENSOR_MODELS[name]
    _check_keys("sensor model", name, kwargs, _options([cls]), whole)
    try:  # only a missing option is this message's case: a refused value keeps its own error
        inspect.signature(cls).bind(**kwargs)
    except TypeError as exc:
        required = [
            p.name
            for p in inspect.signature(cls).parameters.values()
            if p.default is p.empty and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)
        ]
        raise ValueError(
            f"expected the options {', '.join(required)} of sensor model {name!r}, actual value: {whole!r} ({exc})"
        ) from None
    return cls(**kwargs)


def make_sensor(spec: str | sensors.Sensor) -> sensors.Sensor:
    """A fresh sensor from a spec (see the module docstring), or ``spec`` itself if it already is a sensor.

    Raises
    ------
    ValueError
        Unknown name or option, a preset given options, or values the model rejects.
    """
    if isinstance(spec, sensors.Sensor):
        return spec
    if not isinstance(spec, str):
        raise TypeError(f"expected a sensor spec (text) or a smo_gym.sensors.Sensor, actual value: {spec!r}")
    parts = [_sensor_part(part, spec) for part in _CHAIN_SPLIT.split(spec.strip())]
    return parts[0] if len(parts) == 1 else sensors.Chain(*parts)
