"""`flaair_analysis.evidence.fit_evidence` against closed forms: one fit over any mix of evidence.

A toy kind of evidence (measurements y_i of one plant number with noise sigma, residuals
(theta - y_i) / sigma, optionally each shifted by its own nuisance offset) makes the least
squares linear, so the fit's value, standard error and weighting have closed forms.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np
import pytest

from flaair_analysis.discrepancy import Run, RunEvidence
from flaair_analysis.evidence import Evidence, Split, fit_evidence
from flaair_analysis.tables import TableEvidence, TableLimits, read_table
from flaair_model import settings
from flaair_model.model import Model
from flaair_model.model_io import load_model

KEY = "stroke_natural_frequency_hz"


class Readings:
    """Readings y of the stroke natural frequency with noise sigma; with `offset`, one nuisance
    offset b shared by the readings (residual (theta + b - y) / sigma).
    """

    name = "readings"
    sites = ("stroke_deg",)

    def __init__(self, y: Sequence[float], sigma: float, offset: bool = False) -> None:
        self.y, self.sigma = np.asarray(y, float), sigma
        self.n_nuisance = 1 if offset else 0

    def nuisance_start(self) -> np.ndarray:
        return np.zeros(self.n_nuisance)

    def nuisance_steps(self) -> np.ndarray:
        return np.full(self.n_nuisance, 1e-3)

    def residuals(self, models: Sequence[Model], nuisance: np.ndarray) -> np.ndarray:
        b = float(nuisance[0]) if self.n_nuisance else 0.0
        theta = np.array([getattr(m.plant, KEY) for m in models])
        return (theta[:, None] + b - self.y[None, :]) / self.sigma

    def linearised(self, models, nuisance, h):
        rows = self.residuals(models, nuisance)
        jac = np.full((self.y.size, self.n_nuisance), 1.0 / self.sigma)
        return rows, jac

    def heldout(self) -> tuple[Split, ...]:
        return ()

    def site_index(self) -> dict[str, np.ndarray]:
        return {"stroke_deg": np.arange(self.y.size)}


def _fit(pieces, start=100.0, **kw):
    nominal = load_model()

    def to_model(x: np.ndarray) -> Model:
        return replace(nominal, plant=replace(nominal.plant, **{KEY: float(x[0])}))

    return fit_evidence(
        pieces, to_model, [np.array([start])], np.array([1.0]), np.array([1e4]),
        np.array([1e-3]), max_nfev=50, **kw,
    )  # fmt: skip


@pytest.mark.timeout(30)
def test_the_fit_is_the_inverse_variance_mean_with_its_standard_error() -> None:
    rng = np.random.default_rng(1)
    a = 140.0 + 2.0 * rng.standard_normal(40)
    b = 141.0 + 0.5 * rng.standard_normal(10)
    fit = _fit([Readings(a, 2.0), Readings(b, 0.5)])
    w = np.r_[np.full(a.size, 1 / 4.0), np.full(b.size, 1 / 0.25)]
    y = np.r_[a, b]
    mean = float(w @ y / w.sum())
    assert fit.x[0] == pytest.approx(mean, abs=1e-6)
    chi2 = float(w @ (y - mean) ** 2)
    scale = max(1.0, chi2 / (y.size - 1))  # never more precise than the noise model says
    assert np.sqrt(fit.covariance[0, 0]) == pytest.approx(np.sqrt(scale / w.sum()), rel=1e-4)
    assert fit.n == (40, 10) and sum(fit.chi2) == pytest.approx(chi2, rel=1e-6)
    assert fit.weights == (1.0, 1.0) and not fit.singular


@pytest.mark.timeout(30)
def test_a_piece_above_its_noise_is_weighted_down_by_its_birge_ratio() -> None:
    rng = np.random.default_rng(2)
    honest = 140.0 + 1.0 * rng.standard_normal(30)
    optimistic = 141.0 + 3.0 * rng.standard_normal(300)  # claims noise 1, scatters 3
    y = np.r_[honest, optimistic]
    plain = _fit([Readings(honest, 1.0), Readings(optimistic, 1.0)])
    weighted = _fit([Readings(honest, 1.0), Readings(optimistic, 1.0)], birge_refit=1.2)
    # unweighted, the big optimistic set outvotes the honest one by its size
    assert plain.x[0] == pytest.approx(y.mean(), abs=1e-6)
    # each set divided by its chi-square per reading at the plain fit (its Birge ratio)
    ratio = [float(np.mean((p - plain.x[0]) ** 2)) for p in (honest, optimistic)]
    assert weighted.weights == pytest.approx([1.0 / max(1.0, r) for r in ratio], rel=1e-6)
    assert weighted.weights[1] < 0.5 * weighted.weights[0]
    w = np.r_[np.full(30, weighted.weights[0]), np.full(300, weighted.weights[1])]
    assert weighted.x[0] == pytest.approx(w @ y / w.sum(), abs=1e-6)
    assert abs(weighted.x[0] - 140.0) < abs(plain.x[0] - 140.0)


@pytest.mark.timeout(30)
def test_a_nuisance_of_one_piece_is_fitted_with_the_shared_parameter() -> None:
    shared = Readings([140.0, 140.2, 139.8], 0.1)
    shifted = Readings([145.0, 145.1, 144.9], 0.1, offset=True)  # its own offset: +5
    fit = _fit([shared, shifted])
    assert fit.x[0] == pytest.approx(140.0, abs=1e-6)
    assert fit.nuisance[1][0] == pytest.approx(5.0, abs=1e-6)  # theta + b = 145
    assert fit.nuisance[0].size == 0


@pytest.mark.timeout(30)
def test_the_better_of_two_starts_starts_the_fit() -> None:
    pieces = [Readings([140.0, 141.0], 0.5)]
    nominal = load_model()

    def to_model(x: np.ndarray) -> Model:
        return replace(nominal, plant=replace(nominal.plant, **{KEY: float(x[0])}))

    fit = fit_evidence(
        pieces, to_model, [np.array([10.0]), np.array([139.0])], np.array([1.0]),
        np.array([1e4]), np.array([1e-3]), max_nfev=50,
    )  # fmt: skip
    assert fit.start_costs[0] > fit.start_costs[1] and fit.x[0] == pytest.approx(140.5)


def _run(name: str, n: int) -> Run:
    z = np.zeros(n)
    return Run(name, 20000.0, z, z, z, np.linspace(0.0, 1.0, n), z)


@pytest.mark.timeout(30)
def test_runs_split_one_run_out_and_a_lone_run_into_halves() -> None:
    noise = {"stroke_deg": 0.1}
    two = RunEvidence([_run("a", 400), _run("b", 600)], noise, 4, ("stroke_deg",), "stroke")
    assert isinstance(two, Evidence) and two.n_nuisance == 4
    splits = two.heldout()
    assert [s.name for s in splits] == ["a", "b"]
    assert [r.name for r in splits[0].fit.runs] == ["b"]  # type: ignore[attr-defined]
    assert [r.name for r in splits[0].judged.runs] == ["a"]  # type: ignore[attr-defined]
    lone = RunEvidence([_run("a", 400)], noise, 4, ("stroke_deg",)).heldout()
    assert [s.name for s in lone] == ["a[first half]", "a[second half]"]
    assert lone[0].judged.windows == [(0, 200)] and lone[0].fit.windows == [(200, 400)]  # type: ignore[attr-defined]
    # a window compares only its samples (every 4th: 50 of the first half's 200)
    assert lone[0].judged.idx[0]["stroke_deg"].max() < 200  # type: ignore[attr-defined]
    assert lone[0].judged.idx[0]["stroke_deg"].size == 50  # type: ignore[attr-defined]
    # each channel's residuals sit run by run: run a's 100 samples of each, then run b's 150
    both = RunEvidence(
        [_run("a", 400), _run("b", 600)],
        {**noise, "pitch_deg": 0.1},
        4,
        ("stroke_deg", "pitch_deg"),
    )
    index = both.site_index()
    assert np.array_equal(index["stroke_deg"], np.r_[0:100, 200:350])
    assert np.array_equal(index["pitch_deg"], np.r_[100:200, 350:500])
    assert both.residuals([load_model()], both.nuisance_start()).shape == (1, 500)


@pytest.mark.timeout(30)
def test_a_table_splits_one_drive_level_out() -> None:
    text = "drive_amplitude_v,frequency_hz,stroke_pp_deg\n" + "".join(
        f"{v},{f},{10 + f / 10}\n" for v in (30, 60) for f in (100, 120, 140)
    )
    (table,) = read_table(text, "t.csv", TableLimits(20.0, 1000.0, 300.0))
    evidence = TableEvidence(table, settings.tables(), ["stroke_pp_deg"])
    assert isinstance(evidence, Evidence) and evidence.n_nuisance == 0
    splits = evidence.heldout()
    assert [s.name for s in splits] == ["30 V", "60 V"]
    masks = np.array([s.where for s in splits])
    assert (masks.sum(axis=0) == 1).all()  # every point judged exactly once
    assert splits[0].judged.table.n_points == 3 and splits[0].fit.table.n_points == 3  # type: ignore[attr-defined]
    assert np.array_equal(evidence.site_index()["stroke_pp_deg"], np.arange(6))
