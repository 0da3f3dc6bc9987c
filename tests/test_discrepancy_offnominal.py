"""The discrepancy workflow on off-nominal robots: fit the robot, then name what is missing.

Fixed draws of the project's randomized generator (`random_robot`): every plant parameter off
nominal (frequencies +-3 %, damping, gain, couplings +-15 %), noise 1-2x, truth at 20 kHz or a
2 kHz video rate. The workflow never sees the draw; the tests compare names, status, effect
parameters (10 %) and natural frequencies (0.5 %) with the hidden truth. Without the plant
identification every one of these robots ends `unexplained` (asserted for the no-effect robot).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import replace
from pathlib import Path

import pytest

from flaair_analysis.discrepancy import analyse
from flaair_analysis.discrepancy.datasets import make_runs
from flaair_analysis.discrepancy.offnominal import effective_plant, random_robot, true_plant
from flaair_model.model_io import load_model
from flaair_model.settings import discrepancy as discrepancy_settings
from flaair_tools import discrepancy
from test_discrepancy import write_case_csvs  # the case's runs as measured-run CSV files

FREQUENCIES = ("stroke_natural_frequency_hz", "pitch_natural_frequency_hz")
# (family, draw): what the draw holds
DRAWS = [
    ("offnominal_null", 1),  # no effect, 20 kHz truth
    ("offnominal_single", 0),  # sensor_delay on the pitch chain only, video-rate truth
    # hinge_stiffening (jointly with the four pitch parameters), video-rate truth
    ("offnominal_single", 5),
    # collision: stop, contact stiffness and contact damping, video-rate truth
    ("offnominal_single", 7),
    ("offnominal_single", 8),  # wing_damage: a plant change reproduces it, so nothing is named
    # strain_transfer_loss (stroke) + sensor_delay (pitch), video-rate
    # truth: the runs' initial states must be fitted on the sensors
    # too, or a wrong start transient is left as a pitch-sensor gap
    ("offnominal_pair", 2),
]


@pytest.fixture(scope="module")
def model():
    return load_model()


@pytest.mark.slow  # the whole search on an off-nominal robot with effects
@pytest.mark.parametrize("family,draw", DRAWS, ids=[f"{f}_{d}" for f, d in DRAWS])
def test_off_nominal_robot_names_its_effects_on_top_of_its_own_plant(
    family: str, draw: int, model
) -> None:
    case = random_robot(family, draw)
    result = analyse(make_runs(case, model), model, discrepancy_settings())
    assert result.status == case.expected_status, result.summary
    assert tuple(sorted(e.name for e in result.effects)) == case.effect_names, result.summary
    assert not result.discovered and not case.terms, [d.term for d in result.discovered]
    found = {e.name: e for e in result.effects}
    for name, params in case.effects:
        for key, value in params.items():
            if isinstance(value, str):
                assert found[name].parameters[key] == value, (name, key)
            else:
                assert found[name].parameters[key] == pytest.approx(value, rel=0.10), (name, key)
    effective = effective_plant(case, model)  # a lighter wing resonates higher
    for key in FREQUENCIES:
        assert result.plant_parameters[key]["value"] == pytest.approx(effective[key], rel=0.005), (
            key
        )
        assert result.plant_parameters[key]["nominal"] == getattr(model.plant, key)
        assert result.plant_parameters[key]["stderr"] > 0
    assert (
        result.model_out.plant.stroke_natural_frequency_hz
        == result.plant_parameters[FREQUENCIES[0]]["value"]
    )
    assert "wing_damage" in {d["effect"] for d in result.not_separable}


@pytest.mark.slow  # the whole search on a robot whose actuator is hysteretic
def test_a_hysteretic_actuator_is_named_with_its_loop_and_standard_errors(model) -> None:
    """The Bouc-Wen operator on the drive, drawn in its own family (loop fraction 0.40, saturation
    7.3 V: a loop of about 15 % of the stroke at 100 V): named, each parameter within 10 % and
    several standard errors from the null, the robot explained.
    """
    case = random_robot("offnominal_own", 0)
    result = analyse(make_runs(case, model), model, discrepancy_settings())
    assert result.status == "explained", result.summary
    assert [e.name for e in result.effects] == ["actuator_hysteresis"], result.summary
    found = result.effects[0]
    hidden = dict(case.effects)["actuator_hysteresis"]
    for key in ("loop_fraction", "saturation_v"):
        assert found.parameters[key] == pytest.approx(hidden[key], rel=0.10), key
    # the effect's two parameters first, then the plant parameters fitted with it
    se, values = found.evidence["standard_errors"][:2], found.evidence["values"][:2]
    assert all(0.0 < s < 0.05 * v for s, v in zip(se, values, strict=True)), (se, values)


@pytest.mark.slow  # the search on a robot with a delay on each film
def test_stroke_and_pitch_chains_keep_their_own_delay(model) -> None:
    """A robot whose two sensor chains lag differently (0.15 ms and 0.40
    ms): both delays are fitted, each on its own chain, and written
    as one value per chain (one shared value cannot explain both).
    """
    case = dataclasses.replace(
        random_robot("offnominal_null", 2),
        group="single",
        effects=(("sensor_delay", {"stroke": {"delay_s": 1.5e-4}, "pitch": {"delay_s": 4.0e-4}}),),
    )
    result = analyse(make_runs(case, model), model, discrepancy_settings())
    assert result.status == "explained", result.summary
    assert [e.name for e in result.effects] == ["sensor_delay"], result.summary
    fitted = result.effects[0].parameters
    assert fitted["stroke"]["delay_s"] == pytest.approx(1.5e-4, rel=0.10)
    assert fitted["pitch"]["delay_s"] == pytest.approx(4.0e-4, rel=0.10)
    assert (
        result.model_out.effect_on("sensor_delay", "stroke").delay_s == fitted["stroke"]["delay_s"]
    )
    assert result.model_out.effect_on("sensor_delay", "pitch").delay_s == fitted["pitch"]["delay_s"]


# slow: the whole workflow twice (with and without identification) on an off-nominal robot's runs
@pytest.mark.slow
def test_without_identification_parameter_drift_looks_like_missing_physics(model) -> None:
    """The fault the identification fixes: the same
    no-effect robot, searched against the nominal plant.
    """
    case = random_robot("offnominal_null", 1)
    old = analyse(make_runs(case, model), model, replace(discrepancy_settings(), identify=False))
    assert old.status == "unexplained"


# slow: the whole search (every vocabulary effect, then the terms) on an off-nominal robot
@pytest.mark.slow
def test_outside_the_vocabulary_stays_unexplained_on_a_fitted_plant(model) -> None:
    case = random_robot("offnominal_outside", 1)  # a second stroke resonance
    assert case.outside == "second_resonance"
    result = analyse(make_runs(case, model), model, discrepancy_settings())
    assert result.status == "unexplained"
    assert "stroke_deg" in {r["channel"] for r in result.remaining}


@pytest.mark.slow  # the discrepancy command end to end on an off-nominal robot
def test_cli_writes_plant_parameters_and_the_fitted_model(tmp_path: Path, model) -> None:
    case = random_robot("offnominal_null", 1)
    paths = [str(p) for p in write_case_csvs(case, model, tmp_path)]
    out = tmp_path / "out"
    assert discrepancy.main([*paths, "--out", str(out)]) == 0
    doc = json.loads(
        (out / "discrepancy.json").read_text(),
        parse_constant=lambda c: pytest.fail(f"non-strict {c}"),
    )
    assert doc["status"] == "no_discrepancy" and doc["effects"] == []
    fitted = load_model(out / "model.yaml")
    truth = true_plant(case, model)
    for key, p in doc["plant_parameters"].items():
        assert set(p) == {"value", "nominal", "stderr"}
        assert getattr(fitted.plant, key) == pytest.approx(p["value"], rel=1e-12)
        assert p["value"] == pytest.approx(truth[key], rel=0.03), key
    assert "wing_damage" in {d["effect"] for d in doc["not_separable"]}
    assert "This robot's plant" in (out / "report.html").read_text()
