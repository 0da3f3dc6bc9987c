"""The simulated robot damaged mid-run (flaair_sim.core.damage, plant_io's schedule)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from flaair_model.model_io import load_model
from flaair_model.schema import ParameterError
from flaair_model.settings import node_section
from flaair_sim import plant_io
from flaair_sim.core import plant, scene
from flaair_sim.core.damage import DamageParams, damaged


def _values(**kw):
    values = dict(node_section(plant_io.PLANT_PARAMS, "plant_node", "flaair.yaml"))
    values.update(kw)
    return values


def test_damaged_model_changes_exactly_what_it_names():
    model = load_model()
    d = damaged(model, DamageParams(1.0, 0.8, 1.21, 0.85, 0.9, 0.7))
    assert d.effect("wing_damage").inertia_factor == 0.8
    assert d.effect_on("strain_transfer_loss", "stroke").efficiency == 0.85
    assert d.effect_on("strain_transfer_loss", "pitch").efficiency == 0.9
    assert d.plant.stroke_stiffness_nm_per_rad == pytest.approx(
        1.21 * model.plant.stroke_stiffness_nm_per_rad, rel=1e-12
    )
    assert d.plant.actuator_gain_nm_per_v == pytest.approx(0.7 * model.plant.actuator_gain_nm_per_v)
    assert damaged(model, DamageParams(-1.0, 0.8, 1.0, 1.0, 1.0, 1.0)) is model
    # the stroke film reads 0.85 of the angle the undamaged one reads, same motion
    drive = 40.0 * np.sin(2 * math.pi * 140.0 * np.arange(4000) / 20000.0)
    film = damaged(model, DamageParams(0.0, 1.0, 1.0, 0.85, 1.0, 1.0))
    a, b = plant.simulate(drive, 20000.0, model), plant.simulate(drive, 20000.0, film)
    vref = model.sensors.reference_voltage_v
    np.testing.assert_allclose(a.stroke_rad, b.stroke_rad)
    np.testing.assert_allclose(b.stroke_sensor_v - vref, 0.85 * (a.stroke_sensor_v - vref))


def test_plant_schedule_switches_between_blocks_from_the_damage_time():
    values = _values(damage_time_s=0.5, damage_inertia_factor=0.8)
    model, obstacle, windows = plant_io.plant_models(values)
    damage = plant_io.plant_damage(values, model, obstacle)
    assert scene.model_at(0.49995, model, obstacle, windows, damage) is model
    after = scene.model_at(0.5, model, obstacle, windows, damage)
    assert after.effect("wing_damage").inertia_factor == 0.8
    on = scene.model_at(0.7, model, obstacle, [(0.6, 0.8)], damage)
    assert on.effect("wing_damage") is not None and on.effect("collision") is not None
    default = plant_io.plant_damage(_values(), model, obstacle)
    assert scene.model_at(10.0, model, obstacle, windows, default) is model


def test_bad_damage_is_named():
    values = _values(damage_time_s=0.5, damage_pitch_film_gain=1.5)
    model, obstacle, _ = plant_io.plant_models(values)
    with pytest.raises(ParameterError, match="'damage_pitch_film_gain'"):
        plant_io.plant_damage(values, model, obstacle)
