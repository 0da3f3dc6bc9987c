"""A sensor effect with its own value per sensor chain: model, model file, plant."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from flaair_model.effects import SensorDelay
from flaair_model.model import (
    PerChannel,
    effect_params,
    with_effect_on,
    with_effects,
    without_effect_on,
)
from flaair_model.model_io import load_model, model_from_dict, model_to_dict, save_model
from flaair_model.validation import ModelError
from flaair_sim.core.plant import sensor_chain, simulate

FS_HZ = 20_000.0
SPLIT = {"stroke": {"delay_s": 1.5e-4}, "pitch": {"delay_s": 4.0e-4}}


@pytest.fixture(scope="module")
def model():
    return load_model()


def test_per_channel_values_round_trip_through_the_model_file(model, tmp_path: Path) -> None:
    m = with_effects(
        model,
        {
            "sensor_delay": SPLIT,
            "charge_amp_highpass": {"corner_hz": 5.0, "channel": "pitch"},
            "strain_transfer_loss": {"stroke": {"efficiency": 0.8}, "pitch": {"efficiency": 0.25}},
        },
    )
    assert m.effect("sensor_delay") == PerChannel(
        SensorDelay(1.5e-4, "stroke"), SensorDelay(4.0e-4, "pitch")
    )
    assert m.effect_on("sensor_delay", "pitch").delay_s == 4.0e-4
    assert m.effect_on("charge_amp_highpass", "stroke") is None
    assert m.effect_on("charge_amp_highpass", "pitch").corner_hz == 5.0
    save_model(m, tmp_path / "model.yaml")
    raw = yaml.safe_load((tmp_path / "model.yaml").read_text())
    # readable layout: one block per chain, the chain implied by its key
    assert raw["effects"]["sensor_delay"] == SPLIT
    assert raw["effects"]["charge_amp_highpass"] == {"corner_hz": 5.0, "channel": "pitch"}
    assert load_model(tmp_path / "model.yaml") == m
    assert model_from_dict(model_to_dict(m)) == m


def test_one_chain_given_is_that_chain_alone(model) -> None:
    m = with_effects(model, {"sensor_delay": {"pitch": {"delay_s": 2e-4}}})
    assert m.effect("sensor_delay") == SensorDelay(2e-4, "pitch")
    assert effect_params(m.effect("sensor_delay")) == {"delay_s": 2e-4, "channel": "pitch"}


@pytest.mark.parametrize(
    "bad,words",
    [
        (
            {"stroke": {"delay_s": 1e-4}, "pitch": {"delay_s": 1e-4, "channel": "stroke"}},
            "sensor_delay.pitch.channel",
        ),
        (
            {"stroke": {"delay_s": -1e-4}, "pitch": {"delay_s": 1e-4}},
            "effects.sensor_delay.delay_s must be >= 0",
        ),
        (
            {"stroke": 3.0, "pitch": {"delay_s": 1e-4}},
            "effects.sensor_delay.stroke must be a mapping",
        ),
        ({"stroke": {"delay_s": 1e-4}, "left": {"delay_s": 1e-4}}, "unknown parameter(s) left"),
    ],
)
def test_bad_per_channel_values_name_the_key(model, bad: dict, words: str) -> None:
    with pytest.raises(ModelError) as info:
        with_effects(model, {"sensor_delay": bad})
    assert words in str(info.value)


def test_feedthrough_has_no_per_channel_form(model) -> None:
    with pytest.raises(ModelError, match="unknown parameter"):
        with_effects(
            model,
            {"feedthrough": {"stroke": {"gain_v_per_v": 0.01}, "pitch": {"gain_v_per_v": 0.01}}},
        )
    with pytest.raises(ModelError, match="no per-channel value"):
        with_effect_on(model, "feedthrough", "stroke", {"gain_v_per_v": 0.01})


def test_setting_one_chain_keeps_the_other(model) -> None:
    both = with_effects(model, {"sensor_delay": {"delay_s": 1e-4, "channel": "both"}})
    split = with_effect_on(both, "sensor_delay", "pitch", {"delay_s": 3e-4})
    assert split.effect_on("sensor_delay", "stroke") == SensorDelay(1e-4, "stroke")
    assert split.effect_on("sensor_delay", "pitch") == SensorDelay(3e-4, "pitch")
    assert without_effect_on(split, "sensor_delay", "pitch").effect("sensor_delay") == SensorDelay(
        1e-4, "stroke"
    )
    assert without_effect_on(split, "sensor_delay", "stroke").effect("sensor_delay") == SensorDelay(
        3e-4, "pitch"
    )
    assert with_effect_on(model, "sensor_delay", "stroke", {"delay_s": 2e-4}).effect(
        "sensor_delay"
    ) == SensorDelay(2e-4, "stroke")


def test_plant_applies_each_chains_own_value(model) -> None:
    """Each sensor output of the split model equals the model with that
    chain's values alone (to the bit); an 8-sample delay on the pitch chain
    alone shifts the pitch output by 8 samples and leaves the stroke's.
    """
    t = np.arange(int(0.2 * FS_HZ)) / FS_HZ
    drive = 80.0 * np.sin(2 * np.pi * 120.0 * t) * np.minimum(t / 0.02, 1.0)
    effects = {
        "sensor_delay": {"stroke": {"delay_s": 3 / FS_HZ}, "pitch": {"delay_s": 8 / FS_HZ}},
        "charge_amp_highpass": {"stroke": {"corner_hz": 4.0}, "pitch": {"corner_hz": 12.0}},
        "strain_transfer_loss": {"stroke": {"efficiency": 0.8}, "pitch": {"efficiency": 0.3}},
    }
    split = simulate(drive, FS_HZ, with_effects(model, effects))
    for side in ("stroke", "pitch"):
        alone = with_effects(model, {n: {**v[side], "channel": side} for n, v in effects.items()})
        out = simulate(drive, FS_HZ, alone)
        key = f"{side}_sensor_v"
        np.testing.assert_array_equal(getattr(split, key), getattr(out, key))
    plain = simulate(
        drive,
        FS_HZ,
        with_effects(
            model, {"sensor_delay": {"stroke": {"delay_s": 0.0}, "pitch": {"delay_s": 8 / FS_HZ}}}
        ),
    )
    ref = simulate(drive, FS_HZ, model)
    vref = model.sensors.reference_voltage_v
    np.testing.assert_allclose(
        plain.pitch_sensor_v[8:], ref.pitch_sensor_v[:-8], rtol=0, atol=1e-12
    )
    np.testing.assert_array_equal(plain.pitch_sensor_v[:8], vref)
    np.testing.assert_array_equal(plain.stroke_sensor_v, ref.stroke_sensor_v)
    # the sensor chain alone (used by the discrepancy search) agrees with the simulation
    vs, vp = sensor_chain(
        with_effects(model, effects), FS_HZ, split.stroke_rad, split.pitch_rad, drive
    )
    np.testing.assert_allclose(vs, split.stroke_sensor_v, rtol=0, atol=1e-12)
    np.testing.assert_allclose(vp, split.pitch_sensor_v, rtol=0, atol=1e-12)
