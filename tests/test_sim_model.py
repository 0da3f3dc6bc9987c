"""flaair_model.model and flaair_model.model_io: validation, effects, gains, YAML round trip."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from flaair_model.effects import EFFECT_NAMES, Collision, SensorDelay, StrainTransferLoss
from flaair_model.model import Model, with_effects, without_effects
from flaair_model.model_io import (
    default_model_path,
    load_model,
    model_from_dict,
    model_to_dict,
    save_model,
)
from flaair_model.validation import ModelError

REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / "config" / "model.yaml"


@pytest.fixture(scope="module")
def model() -> Model:
    return load_model()


def test_default_path_is_repo_config(monkeypatch):
    monkeypatch.delenv("FLAAIR_CONFIG_DIR", raising=False)
    assert default_model_path().resolve() == CONFIG.resolve()


def test_config_dir_env(monkeypatch, tmp_path, model):
    save_model(
        with_effects(model, {"feedthrough": {"gain_v_per_v": 0.01}}), tmp_path / "model.yaml"
    )
    monkeypatch.setenv("FLAAIR_CONFIG_DIR", str(tmp_path))
    assert load_model().effect("feedthrough").gain_v_per_v == 0.01


def test_sensor_gains_closed_form(model):
    # model-spec: 25.39 deg/V stroke, 24.87 deg/V pitch, both polarity -1
    assert model.stroke_gain_deg_per_v == pytest.approx(25.39, abs=0.005)
    assert model.pitch_gain_deg_per_v == pytest.approx(24.87, abs=0.005)
    assert model.stroke_polarity == -1 and model.pitch_polarity == -1
    assert model.sensors.pitch_volts_per_rad() == model.pitch_volts_per_rad
    assert (
        model.sensors.stroke_volts_per_rad(model.plant.transmission_ratio_rad_per_m)
        == model.stroke_volts_per_rad
    )


def test_stiffness_properties(model):
    pl = model.plant
    assert pl.stroke_stiffness_nm_per_rad == pytest.approx(5.0295e-5, rel=1e-4)
    assert pl.hinge_stiffness_nm_per_rad == pytest.approx(2.8502e-6, rel=1e-4)


def test_round_trip_file_layout(model, tmp_path):
    raw = yaml.safe_load(CONFIG.read_text())
    d = model_to_dict(model)
    assert list(d) == list(raw)
    for section in ("plant", "noise"):
        assert d[section] == raw[section]
    # YAML 1.1 reads "50.0e9" as a string; the numbers must still agree
    for key, value in raw["sensors"]["stroke"].items():
        assert d["sensors"]["stroke"][key] == float(value)
    assert d["effects"] == {}
    assert model_from_dict(d) == model

    rich = with_effects(
        model,
        {
            "sensor_delay": {"delay_s": 1.5e-4, "channel": "pitch"},
            "collision": {"stroke_limit_deg": 30.0},
            "strain_transfer_loss": {"efficiency": 0.23},
            "wing_damage": {"inertia_factor": 0.8},
        },
    )
    save_model(rich, tmp_path / "rich.yaml")
    back = load_model(tmp_path / "rich.yaml")
    assert back == rich
    assert model_to_dict(back) == model_to_dict(rich)
    assert model_to_dict(back)["effects"]["collision"] == {
        "stroke_limit_deg": 30.0,
        "contact_stiffness_ratio": 50.0,
        "contact_damping_ratio": 0.2,
    }


@pytest.mark.parametrize(
    "path, value, fragment",
    [
        (("plant", "stroke_inertia_kg_m2"), -1.0, "plant.stroke_inertia_kg_m2 must be > 0, got -1"),
        (("plant", "pitch_inertia_kg_m2"), 0.0, "plant.pitch_inertia_kg_m2 must be > 0"),
        (("plant", "aero_damping_nm_s2"), float("nan"), "plant.aero_damping_nm_s2 must be finite"),
        (
            ("plant", "transmission_ratio_rad_per_m"),
            "fast",
            "plant.transmission_ratio_rad_per_m must be a number",
        ),
        (("sensors", "pvdf", "thickness_m"), 0.0, "sensors.pvdf.thickness_m must be > 0"),
        (("sensors", "pitch", "length_m"), float("inf"), "sensors.pitch.length_m must be finite"),
        (("noise", "sensor_noise_v_rms"), -0.1, "noise.sensor_noise_v_rms must be >= 0"),
        (("plant", "bogus_key"), 1.0, "plant: unknown key(s) bogus_key"),
        (("sensors", "stroke", "width_m"), 1.0, "sensors.stroke: unknown key(s) width_m"),
        (("extras",), {}, "unknown section(s) extras"),
    ],
)
def test_model_error_names_parameter(model, path, value, fragment):
    d = model_to_dict(model)
    target = d
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = value
    with pytest.raises(ModelError, match=fragment.replace("(", r"\(").replace(")", r"\)")):
        model_from_dict(d)


def test_missing_key_named(model):
    d = model_to_dict(model)
    del d["plant"]["hinge_damping_nm_s_per_rad"]
    with pytest.raises(ModelError, match="hinge_damping_nm_s_per_rad"):
        model_from_dict(d)


def test_effect_validation(model):
    with pytest.raises(ModelError, match="unknown effect 'gremlins'"):
        with_effects(model, {"gremlins": {}})
    d = model_to_dict(model)
    d["effects"] = {"sensor_lag": {"delay_s": 0.001}}
    with pytest.raises(ModelError, match="sensor_lag"):
        model_from_dict(d)
    with pytest.raises(
        ModelError, match=r"effects.strain_transfer_loss.efficiency must be in \(0, 1\]"
    ):
        with_effects(model, {"strain_transfer_loss": {"efficiency": 1.5}})
    with pytest.raises(ModelError, match=re.escape("effects.wing_damage.inertia_factor")):
        with_effects(model, {"wing_damage": {"inertia_factor": 0.0}})
    with pytest.raises(ModelError, match=re.escape("effects.sensor_delay.channel")):
        with_effects(model, {"sensor_delay": {"delay_s": 0.001, "channel": "left"}})
    with pytest.raises(ModelError, match=re.escape("effects.sensor_delay.delay_s must be >= 0")):
        with_effects(model, {"sensor_delay": {"delay_s": -1e-3}})
    with pytest.raises(ModelError, match=re.escape("effects.collision: unknown parameter")):
        with_effects(model, {"collision": {"stroke_limit_deg": 10, "hardness": 3}})
    with pytest.raises(ModelError, match=r"effects.collision: missing parameter.*stroke_limit_deg"):
        with_effects(model, {"collision": {}})
    with pytest.raises(ModelError, match=re.escape("effects.collision must be a Collision")):
        with_effects(model, {"collision": SensorDelay(1e-3)})
    with pytest.raises(ModelError, match="unknown effect"):
        model.effect("gremlins")


def test_with_and_without_effects(model):
    assert len(EFFECT_NAMES) == 10 and len(set(EFFECT_NAMES)) == 10
    m = with_effects(
        model,
        {
            "collision": Collision(stroke_limit_deg=25.0),
            "strain_transfer_loss": {"efficiency": 0.5},
        },
    )
    assert m.effect("collision") == Collision(25.0, 50.0, 0.2)
    assert m.effect("strain_transfer_loss") == StrainTransferLoss(0.5, "pitch")
    assert m.effect("sensor_delay") is None
    assert m.effect_names == ("strain_transfer_loss", "collision")
    # replacing keeps the others; order of insertion does not matter for equality
    m2 = with_effects(
        with_effects(model, {"strain_transfer_loss": {"efficiency": 0.5}}),
        {"collision": {"stroke_limit_deg": 25.0}},
    )
    assert m2 == m and hash(m2) == hash(m)
    m3 = with_effects(m, {"collision": {"stroke_limit_deg": 40.0}})
    assert (
        m3.effect("collision").stroke_limit_deg == 40.0
        and m3.effect("strain_transfer_loss") is not None
    )
    assert without_effects(m) == model
    assert model.effects == ()


def test_model_is_immutable(model):
    with pytest.raises(dataclasses.FrozenInstanceError):
        model.plant.stroke_inertia_kg_m2 = 1.0  # type: ignore[misc]
    # numpy scalars are accepted and stored as float
    pl = dataclasses.replace(model.plant, stroke_inertia_kg_m2=np.float32(6.5e-11))
    assert type(pl.stroke_inertia_kg_m2) is float
