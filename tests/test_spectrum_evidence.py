"""A multisine run set as evidence (`SpectrumEvidence`): calibrated in units of its noise (the
robot's own model at noise on every channel, a model without the hinge film's square term above
noise on that film only), one fit over it recovering a plant parameter, a realization held out,
and `is_multisine` telling a multisine from other drives.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from flaair_analysis.discrepancy.diagnosis import noise_estimates
from flaair_analysis.discrepancy.runs import Run, check_runs, simulate_runs
from flaair_analysis.evidence import fit_evidence
from flaair_analysis.multisine.analysis import SENSORS, VIDEO, RunInput, find_design
from flaair_analysis.multisine.design import design_multisine, realization_drive
from flaair_analysis.multisine.spectra import is_multisine
from flaair_analysis.multisine.spectrum_evidence import SpectrumEvidence, spectrum_channels
from flaair_analysis.tables.datasets import simulated_table
from flaair_analysis.tables.joint import identify_joint
from flaair_model import settings
from flaair_model.model_io import load_model
from flaair_sim.core.drive import chirp
from flaair_sim.core.measured_run import synthesize_measured_run

pytestmark = pytest.mark.timeout(60)

ROOT = Path(__file__).resolve().parents[1]
FILM_TERM = "discovered:\n  - {kind: square_angle_sensor, acts_on: pitch_sensor_v, " + (
    "parameters: {coefficient: 0.05}}\n"
)
FS_HZ = 20000.0
RUN_COLUMNS = ("drive_v", "stroke_sensor_v", "pitch_sensor_v", "stroke_deg", "pitch_deg")


def _design():
    return design_multisine(
        band_hz=(100.0, 250.0), base_hz=4.0, lines_per_group=3, rms_v=25.0, periods=2,
        transient_periods=1, realizations=2, fs_hz=FS_HZ, max_v=100.0, seed=5,
    )  # fmt: skip


@pytest.fixture(scope="module")
def film(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """A robot whose hinge film reads 0.05 psi^2 more, measured on two realizations (video
    every 10th sample), as the evidence of all four channels.
    """
    path = tmp_path_factory.mktemp("film") / "film.yaml"
    path.write_text((ROOT / "config" / "model.yaml").read_text() + FILM_TERM)
    robot = load_model(path)
    design, rng = _design(), np.random.default_rng(0)
    runs = []
    for m in range(design.realizations):
        cols = synthesize_measured_run(realization_drive(design, m), FS_HZ, robot, rng)
        off_frame = np.arange(cols["time_s"].size) % 10 != 0
        for name in VIDEO:
            cols[name][off_frame] = np.nan
        runs.append(RunInput(f"realization_{m + 1}", FS_HZ, cols))
    found = find_design(runs, None)
    channels, skipped = spectrum_channels(runs, found, (*VIDEO, *SENSORS))
    assert not skipped
    return {"robot": robot, "evidence": SpectrumEvidence(runs, found, channels)}


def test_the_robots_own_model_is_at_noise_and_a_missing_film_term_shows_on_that_film(
    film: dict,
) -> None:
    ev = film["evidence"]
    ratio, _, n, chi2 = ev.scores(film["robot"])
    # 2 realizations x 37 lines of the band (25 to 61, 100 to 244 Hz) x (real, imaginary) x 4
    assert n == 2 * 37 * 2 * 4
    index = ev.site_index()  # each channel's 148 residuals in turn
    assert np.array_equal(np.concatenate([index[c] for c in ev.sites]), np.arange(n))
    assert all(i.size == 2 * 37 * 2 for i in index.values())
    assert all(0.85 < r < 1.2 for r in ratio.values()), ratio
    assert 0.85 < chi2 / n < 1.2
    nominal, _, _, _ = ev.scores(load_model())
    assert nominal["pitch_sensor_v"] > 2.0  # the film's even distortion and its gain change
    assert all(0.85 < nominal[c] < 1.2 for c in ("stroke_deg", "pitch_deg", "stroke_sensor_v"))


def test_one_fit_over_the_spectra_recovers_the_stroke_frequency(film: dict) -> None:
    robot = film["robot"]
    truth = robot.plant.stroke_natural_frequency_hz
    ev = film["evidence"].only(["stroke_deg"])

    def to_model(u: np.ndarray):
        return replace(
            robot, plant=replace(robot.plant, stroke_natural_frequency_hz=math.exp(u[0]))
        )

    fit = fit_evidence(
        [ev], to_model, [np.array([math.log(1.05 * truth)])],
        np.array([math.log(truth / 1.5)]), np.array([math.log(truth * 1.5)]), np.array([1e-4]),
        max_nfev=50, tol=1e-10,
    )  # fmt: skip
    fitted, se = math.exp(fit.x[0]), math.exp(fit.x[0]) * math.sqrt(fit.covariance[0, 0])
    assert abs(fitted - truth) < 3.0 * se
    assert se < 1e-3 * truth  # the band's 37 lines of two realizations pin it to 0.1 %


def test_each_realization_is_held_out_once(film: dict) -> None:
    splits = film["evidence"].heldout()
    assert [s.name for s in splits] == ["realization_1", "realization_2"]
    for s in splits:
        assert s.fit.keep == [1 - s.where] and s.judged.keep == [s.where]
        # the part judged keeps the whole set's noise
        assert np.array_equal(s.judged.sigma["pitch_deg"], film["evidence"].sigma["pitch_deg"])


def test_the_joint_fit_takes_spectra_alone(film: dict) -> None:
    robot = film["robot"]
    off = replace(robot, plant=replace(robot.plant, pitch_natural_frequency_hz=200.0))
    fit = identify_joint([], None, off, {}, settings.tables(), spectra=film["evidence"])
    assert list(fit.agreement) == ["spectra"]
    assert fit.values["pitch_natural_frequency_hz"] == pytest.approx(190.0, rel=3e-3)
    assert fit.agreement["spectra"].noise_ratio["pitch_deg"] < 1.2


def test_is_multisine_tells_a_multisine_from_other_drives() -> None:
    design = _design()
    t = np.arange(int(design.n_samples)) / FS_HZ
    assert is_multisine(realization_drive(design, 0))
    assert not is_multisine(40.0 * np.sin(2 * np.pi * 140.0 * t))  # one line
    chirp = 40.0 * np.sin(2 * np.pi * (50.0 * t + 20.0 * t**2))
    assert not is_multisine(chirp)  # never repeats
    period = design.period_samples
    even = np.sin(2 * np.pi * 2 * np.arange(period) / period) + np.sin(
        2 * np.pi * 3 * np.arange(period) / period
    )
    assert not is_multisine(np.tile(even, 3))  # an even line excited
    assert not is_multisine(np.full(1000, np.nan))


@pytest.mark.slow  # two joint fits with a multisine set's spectra
@pytest.mark.timeout(120)
def test_the_joint_fit_takes_spectra_beside_runs_and_beside_a_table(film: dict) -> None:
    """Each set is scored against the one plant fitted on all; from a plant 5 % off, both
    pairings come back to the robot's stroke and pitch frequencies, every set at noise on the
    video channels it is fitted on (the films' spectra, fifty times the video's signal to noise,
    see what is left of the plant's error: they check the findings, they do not fit the plant).
    """
    robot, s = film["robot"], settings.tables()
    off = replace(
        robot,
        plant=replace(
            robot.plant, stroke_natural_frequency_hz=147.0, pitch_natural_frequency_hz=180.0
        ),
    )
    t = np.arange(round(0.5 * FS_HZ)) / FS_HZ
    cols = synthesize_measured_run(
        chirp(t, 100.0, 20.0, 200.0, 0.5), FS_HZ, robot, np.random.default_rng(4)
    )
    runs = check_runs([Run("chirp", FS_HZ, *(cols[c] for c in RUN_COLUMNS))])
    noise = noise_estimates(runs, simulate_runs([off], runs)[0], off)
    freqs = np.linspace(90.0, 220.0, 12)
    table = simulated_table(robot, [25.0, 45.0], freqs, s, np.random.default_rng(2))
    for fit in (
        identify_joint(runs, None, off, noise, s, spectra=film["evidence"]),
        identify_joint([], table, off, {}, s, spectra=film["evidence"]),
    ):
        assert len(fit.agreement) == 2 and "spectra" in fit.agreement
        for name, agreement in fit.agreement.items():
            if name != "table":
                assert set(agreement.noise_ratio) == {"stroke_deg", "pitch_deg"}
            assert max(agreement.noise_ratio.values()) < 1.3, (name, agreement.noise_ratio)
        assert fit.values["stroke_natural_frequency_hz"] == pytest.approx(140.0, rel=2e-3)
        assert fit.values["pitch_natural_frequency_hz"] == pytest.approx(190.0, rel=3e-3)
        assert not fit.warnings
