"""The search over any list of evidence (`discrepancy.evidence_search`) on a test-only kind of
evidence: readings of an effect's parameter, each held out in turn. Only its own class is
written; the search, its fits and its rules are the tables' own.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pytest

from flaair_analysis.discrepancy.evidence_search import (
    Candidate,
    FreeParam,
    Side,
    heldout,
    search_sides,
)
from flaair_analysis.discrepancy.vocabulary import param_spec
from flaair_analysis.evidence import Split
from flaair_model import settings
from flaair_model.effects import EFFECTS
from flaair_model.model import Model
from flaair_model.model_io import load_model

EFFECT, KEY = "hinge_stiffening", "cubic_per_rad2"


class Readings:
    """The hinge's cubic stiffening read off directly, `sigma` each (a bench test of the hinge)."""

    name = "readings"
    n_nuisance = 0
    sites = ("pitch_deg",)

    def __init__(self, values: Sequence[float], sigma: float) -> None:
        self.values, self.sigma = np.asarray(values, float), sigma

    def nuisance_start(self) -> np.ndarray:
        return np.zeros(0)

    def nuisance_steps(self) -> np.ndarray:
        return np.zeros(0)

    def residuals(self, models: Sequence[Model], nuisance: np.ndarray) -> np.ndarray:
        effects = [m.effect(EFFECT) for m in models]
        value = np.array([0.0 if e is None else getattr(e, KEY) for e in effects])
        return (value[:, None] - self.values[None, :]) / self.sigma

    def linearised(self, models, nuisance, h):
        rows = self.residuals(models, nuisance)
        return rows, np.zeros((rows.shape[1], 0))

    def heldout(self) -> tuple[Split, ...]:
        keep = np.arange(self.values.size)
        return tuple(
            Split(
                f"reading {i}",
                Readings(self.values[keep != i], self.sigma),
                Readings(self.values[[i]], self.sigma),
                i,
            )
            for i in keep
        )

    def site_index(self) -> dict[str, np.ndarray]:
        return {"pitch_deg": np.arange(self.values.size)}


def _candidate(name: str) -> Candidate:
    """Effect `name` as a candidate on the pitch side, its first parameter free."""
    p = next(e for e in EFFECTS if e.name == name).fit[0]
    start = p.grid[0] if p.grid else p.null
    free = FreeParam(param_spec(name, p, "pitch_deg"), start)
    return Candidate(name, False, "pitch", (free,), (p.null,), tuple(p.grid), ())


def _search(readings: Readings):
    s = settings.tables()
    model = load_model()
    pieces = (readings,)
    start = heldout(pieces, model, [], s.heldout_max_nfev)
    pool = [_candidate(EFFECT), _candidate("structural_damping")]
    return start, search_sides(
        [Side("pitch", pieces, ())], pieces, model, [], start, lambda m, side: pool, s
    )


@pytest.mark.timeout(60)
def test_the_search_names_the_effect_a_new_kind_of_evidence_shows() -> None:
    rng = np.random.default_rng(3)
    values = 2.5 + 0.1 * rng.standard_normal(6)
    start, found = _search(Readings(values, 0.1))
    # without the effect every reading is 25 noise units off; held out, the effect fitted on
    # the other five predicts each within noise
    assert start.ratio["pitch_deg"] == pytest.approx(np.sqrt(np.mean((values / 0.1) ** 2)))
    assert [j.candidate.name for j in found.accepted] == [EFFECT]
    best = found.accepted[0]
    assert best.fit.values[f"effect.{EFFECT}.{KEY}"] == pytest.approx(values.mean(), abs=1e-6)
    # sigma / sqrt(n), scaled by the chi-square per degree of freedom where it is above 1
    birge = max(1.0, float(np.sum((values - values.mean()) ** 2)) / 0.1**2 / 5)
    se = 0.1 / np.sqrt(6) * np.sqrt(birge)
    assert best.fit.stderr[f"effect.{EFFECT}.{KEY}"] == pytest.approx(se, rel=1e-3)
    # held out, each reading is predicted by the mean of the other five
    loo = [(np.delete(values, i).mean() - values[i]) / 0.1 for i in range(6)]
    assert found.final.ratio["pitch_deg"] == pytest.approx(np.sqrt(np.mean(np.square(loo))))
    assert best.drop > 0.9 and best.z > 20
    assert found.model.effect(EFFECT) is not None
    decoy = [j for j in found.tried if j.candidate.name == "structural_damping"]
    assert decoy and decoy[0].failed  # it cannot move the readings: no drop, no distance


@pytest.mark.timeout(60)
def test_evidence_at_noise_is_not_searched() -> None:
    rng = np.random.default_rng(4)
    start, found = _search(Readings(0.1 * rng.standard_normal(6), 0.1))
    assert start.ratio["pitch_deg"] < settings.tables().gap_ratio
    assert found.accepted == () and found.tried == ()
