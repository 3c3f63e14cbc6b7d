"""smo_gym.specs: one ``name:key=value`` syntax for observers and sensors."""

from __future__ import annotations

import numpy as np
import pytest

from smo_gym import sensors, specs


@pytest.mark.parametrize(
    ("text", "value"),
    [
        ("true", True),
        ("False", False),
        ("none", None),
        ("3", 3),
        ("-2", -2),
        ("1e-3", 1e-3),
        ("2.5", 2.5),
        ("1e+3", 1000.0),
        ("matching", "matching"),
    ],
)
def test_parse_value(text, value):
    parsed = specs.parse_value(text)
    assert parsed == value and type(parsed) is type(value)


def test_observer_spec_parses_options_and_checks_them():
    assert specs.parse_observer_spec("levant:order=1:discretization=matching") == (
        "levant",
        {"order": 1, "discretization": "matching"},
    )
    with pytest.raises(ValueError, match=r"actual value: 'levnat' \(did you mean 'levant'\?\)"):
        specs.parse_observer_spec("levnat")
    with pytest.raises(ValueError, match=r"'ordr' in 'levant:ordr=1' \(did you mean 'order'\?\)"):
        specs.parse_observer_spec("levant:ordr=1")
    with pytest.raises(ValueError, match="key=value"):
        specs.parse_observer_spec("levant:order")
    with pytest.raises(ValueError, match="options of observer 'super-twisting'"):
        specs.parse_observer_spec("super-twisting:dt=0.1")  # dt is the sampling step, not an option


def test_sensor_specs_build_the_same_models_as_the_classes():
    assert (
        specs.make_sensor("encoder:counts_per_revolution=4096:noise_std=1e-3").stages
        == sensors.Encoder(counts_per_revolution=4096, noise_std=1e-3).stages
    )
    chain = specs.make_sensor(
        "gaussian-noise:std=3e-3+quantization:resolution=1e-2+delay:samples=2+dropout:probability=0.02:per_channel=true"
    )
    assert (
        chain.stages
        == sensors.Chain(
            sensors.GaussianNoise(3e-3),
            sensors.Quantization(1e-2),
            sensors.Delay(2),
            sensors.Dropout(0.02, per_channel=True),
        ).stages
    )
    for name in sensors.PRESETS:  # presets by name, the same models as make_sensor's
        assert specs.make_sensor(name).stages == sensors.make_sensor(name).stages
    # the same measurements from the spec and from the class with the same seed
    y = np.linspace(0.0, 1.0, 50)[:, None] * np.ones((1, 2))
    a, b = (
        specs.make_sensor("encoder:counts_per_revolution=1024:noise_std=2e-3"),
        sensors.Encoder(counts_per_revolution=1024, noise_std=2e-3),
    )
    np.testing.assert_array_equal(a.reset(y[0], seed=3, dt=0.01), b.reset(y[0], seed=3, dt=0.01))
    np.testing.assert_array_equal(a.run(y[1:]), b.run(y[1:]))


def test_sensor_spec_errors_name_what_was_expected():
    with pytest.raises(ValueError, match=r"\(did you mean 'encoder'\?\)"):
        specs.make_sensor("encodr:counts_per_revolution=10")
    with pytest.raises(ValueError, match=r"'counts' in .* \(did you mean 'counts_per_revolution'\?\)"):
        specs.make_sensor("encoder:counts=4096")
    with pytest.raises(ValueError, match="no options for the sensor preset 'low-cost'"):
        specs.make_sensor("low-cost:noise_std=1")
    with pytest.raises(ValueError, match="samples"):
        specs.make_sensor("delay")
    with pytest.raises(ValueError, match="probability"):  # the model's own check of the value
        specs.make_sensor("dropout:probability=2")


def test_model_based_observer_specs_and_autos_model_options():
    assert specs.parse_observer_spec("mechanical-super-twisting:mass_scale=1.1:contact=measured") == (
        "mechanical-super-twisting",
        {"mass_scale": 1.1, "contact": "measured"},
    )
    assert specs.parse_observer_spec("dissipative-super-twisting:lipschitz=50") == (
        "dissipative-super-twisting",
        {"lipschitz": 50},
    )
    assert specs.parse_observer_spec("auto:model=true:mass_scale=0.9") == ("auto", {"model": True, "mass_scale": 0.9})
    with pytest.raises(ValueError, match="options of observer 'auto' in model, mass_scale, contact"):
        specs.parse_observer_spec("auto:order=2")  # auto calibrates each candidate's gains itself
    with pytest.raises(ValueError, match="options of observer 'dissipative-super-twisting'"):
        specs.parse_observer_spec("dissipative-super-twisting:k1=2")  # its gains come from the design lemma


def test_compare_takes_model_free_observers_only():
    from smo_gym.experiments.compare import parse_observer_specs

    assert parse_observer_specs(["auto", "levant:order=1"])["levant:order=1"] == ("levant", {"order": 1})
    for spec in ("mechanical-super-twisting", "auto:model=true"):
        with pytest.raises(ValueError, match=f"expected model-free observers.*'{spec}'"):
            parse_observer_specs([spec])


def test_needs_model_reads_specs():
    """A spec runs a model where its name, or auto's model option, says so; the options given win over the spec's."""
    assert specs.needs_model("kalman-ca-input:huber=3") and specs.needs_model("auto:model=true")
    assert not specs.needs_model("kalman-ca:huber=3") and not specs.needs_model("auto:model=false")
    assert not specs.needs_model("auto:model=true", {"model": False})
    with pytest.raises(ValueError, match="options of observer 'kalman-ca'"):
        specs.needs_model("kalman-ca:bogus=1")
