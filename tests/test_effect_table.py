"""The effect table (flaair_model.effects) is the one declaration of each effect.

Every entry reaches the plant (its kernel terms, and only those, change the kernels' vector),
changes exactly the measured channels it names, and is known to the discrepancy vocabulary and
to the hidden-effect generator with ranges inside its fit bounds. An entry whose term the plant
does not know is refused by name: adding an effect is one entry plus its kernel term.
"""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np
import pytest

from flaair_analysis.discrepancy import offnominal, vocabulary
from flaair_model.effects import (
    EFFECT_NAMES,
    EFFECTS,
    ENTRIES,
    PLANT_TERMS,
    SCALE_TERMS,
    SENSOR_TERMS,
    TermContext,
)
from flaair_model.model import with_effects
from flaair_model.model_io import load_model
from flaair_model.validation import ModelError
from flaair_sim.core import plant, plant_params

FS_HZ = 20000.0
NAMES = [e.name for e in EFFECTS]


def _middle(entry) -> dict:
    """The effect at the middle of its draw ranges (both sensor chains for a sensor effect)."""
    params = {
        r.key: math.sqrt(r.low * r.high) if r.log else 0.5 * (r.low + r.high) for r in entry.draw
    }
    return params | ({"channel": "both"} if entry.per_sensor else {})


@pytest.fixture(scope="module")
def nominal():
    return load_model()


def test_the_model_vocabulary_and_generator_list_the_table_in_its_order() -> None:
    assert tuple(NAMES) == EFFECT_NAMES
    assert tuple(e.name for e in vocabulary.VOCABULARY) == tuple(NAMES)
    own = tuple(n for n in NAMES if ENTRIES[n].own_family)
    assert (
        tuple(n for n in NAMES if ENTRIES[n].separable and n not in own)
        + tuple(n for n in NAMES if not ENTRIES[n].separable)
        == offnominal.EFFECT_NAMES_ORDER
    )
    assert offnominal.OWN_FAMILY_EFFECTS == own == ("actuator_hysteresis",)


@pytest.mark.parametrize("name", NAMES)
def test_each_parameter_has_a_fit_and_a_draw_range_inside_the_fit_bounds(name: str) -> None:
    entry = ENTRIES[name]
    keys = [f.name for f in dataclasses.fields(entry.kind) if f.name != "channel"]
    assert [p.key for p in entry.fit] == keys and [r.key for r in entry.draw] == keys
    for p, r in zip(entry.fit, entry.draw, strict=True):
        assert p.lower <= r.low < r.high <= p.upper, (p, r)
    assert set(entry.searched_on) <= set(entry.acts_on)
    assert set(entry.kernel_terms) <= set(PLANT_TERMS + SCALE_TERMS + SENSOR_TERMS)


@pytest.mark.parametrize("name", NAMES)
def test_the_generator_draws_each_effect_inside_its_ranges(name: str) -> None:
    entry = ENTRIES[name]
    for seed in range(20):
        params = offnominal.random_effect(name, np.random.default_rng(seed))
        with_effects(load_model(), {name: params})  # a valid effect
        for r in entry.draw:
            assert r.low <= abs(params[r.key]) <= r.high, (r, params)
        assert ("channel" in params) == entry.per_sensor


@pytest.mark.parametrize("name", NAMES)
def test_an_effect_changes_its_kernel_terms_and_nothing_else(name: str, nominal) -> None:
    entry = ENTRIES[name]
    model = with_effects(nominal, {name: _middle(entry)})
    terms = entry.terms(
        model.effect_on(name, "stroke") if entry.per_sensor else model.effect(name),
        TermContext(
            nominal.plant.stroke_inertia_kg_m2, nominal.plant.stroke_stiffness_nm_per_rad, FS_HZ
        ),
    )
    assert tuple(terms) == entry.kernel_terms
    before, after = plant_params.prepare(nominal, FS_HZ), plant_params.prepare(model, FS_HZ)
    changed = set(np.flatnonzero(before.params != after.params))
    delays = (after.delay_stroke_samples, after.delay_pitch_samples) != (
        before.delay_stroke_samples,
        before.delay_pitch_samples,
    )
    assert changed or delays, f"{name} does not reach the plant"
    if "delay_samples" in terms:
        assert delays
    expected = {
        "structural_damping_nm_s_per_rad": {plant_params.P_CSTRUCT},
        "hinge_cubic_per_rad2": {plant_params.P_HCUBIC},
        "contact_on": {plant_params.CONTACT_ON_INDEX},
        "stroke_limit_rad": {plant_params.P_PHI_LIM},
        "contact_stiffness_nm_per_rad": {plant_params.P_KC},
        "contact_damping_nm_s_per_rad": {plant_params.P_CC},
        "transmission_cubic_per_rad2": {plant_params.P_TCUBIC},
        "feedthrough_v_per_v": {plant_params.P_FT},
        "hysteresis_fraction": {plant_params.P_HYST_FRAC},
        "hysteresis_saturation_v": {plant_params.P_HYST_SAT},
        "inertia_factor": {plant_params.P_I, plant_params.P_IP},
        "highpass_b0": {
            plant_params.P_HPS_B0,
            plant_params.P_HPP_B0,
            plant_params.P_HPS_ON,
            plant_params.P_HPP_ON,
        },
        "highpass_b1": {plant_params.P_HPS_B1, plant_params.P_HPP_B1},
        "highpass_a1": {plant_params.P_HPS_A1, plant_params.P_HPP_A1},
        "gain_factor": {plant_params.P_GS, plant_params.P_GP},
        "delay_samples": {plant_params.P_DS_FRAC, plant_params.P_DP_FRAC},
    }
    allowed = set().union(*(expected[t] for t in entry.kernel_terms))
    assert changed <= allowed, (name, sorted(changed - allowed))


@pytest.mark.parametrize("name", NAMES)
def test_an_effect_changes_the_channels_it_acts_on_and_no_other(name: str, nominal) -> None:
    entry = ENTRIES[name]
    t = np.arange(int(0.2 * FS_HZ)) / FS_HZ
    # ~47 deg: reaches a stop
    drive_v = 100.0 * np.sin(2 * np.pi * 120.0 * t) * np.minimum(1.0, t / 0.02)
    base = plant.simulate(drive_v, FS_HZ, nominal)
    out = plant.simulate(drive_v, FS_HZ, with_effects(nominal, {name: _middle(entry)}))
    signals = {
        "stroke_deg": "stroke_rad",
        "pitch_deg": "pitch_rad",
        "stroke_sensor_v": "stroke_sensor_v",
        "pitch_sensor_v": "pitch_sensor_v",
    }
    changed = {
        channel
        for channel, field in signals.items()
        if np.max(np.abs(getattr(out, field) - getattr(base, field)))
        > 1e-3 * np.ptp(getattr(base, field))
    }
    assert changed == set(entry.acts_on), (name, sorted(changed))


def test_an_entry_with_a_term_the_plant_does_not_know_is_refused_by_name(
    monkeypatch, nominal
) -> None:
    bad = dataclasses.replace(
        ENTRIES["feedthrough"],
        kernel_terms=("feedthrough_gain",),
        terms=lambda e, c: {"feedthrough_gain": e.gain_v_per_v},
    )
    monkeypatch.setattr(
        plant_params, "EFFECTS", tuple(bad if e.name == "feedthrough" else e for e in EFFECTS)
    )
    plant_params.prepare.cache_clear()
    try:
        with pytest.raises(
            ModelError,
            match=re.escape(
                "effects.feedthrough: kernel term 'feedthrough_gain' is not one the plant"
            ),
        ):
            plant_params.prepare(
                with_effects(nominal, {"feedthrough": {"gain_v_per_v": 0.01}}), FS_HZ
            )
    finally:
        plant_params.prepare.cache_clear()
