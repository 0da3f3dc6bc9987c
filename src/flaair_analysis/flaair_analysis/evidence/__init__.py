"""Evidence for one fit (pure): the protocol every measured data set meets and the one
least-squares fit over any list of them.

Modules: `protocol` (`Evidence`: residuals in units of the data's own noise, its nuisance
parameters, the sites it sees, its held-out `Split`s; `EvidenceSet`: a measured set beside the
runs in the joint identification, its stage pieces and its agreement) and `fit`
(`fit_evidence`: shared parameters and each piece's nuisance fitted over every piece at once,
the Birge reweighting, the covariance) and `judging` (the rules every candidate is judged by on
any evidence: the held-out error above noise and its drop, the distance from doing nothing,
what noise allows another set's chi-square to rise by).
The kinds of evidence live with their data:
`flaair_analysis.discrepancy.RunEvidence` (measured runs),
`flaair_analysis.tables.TableEvidence` (frequency-response tables) and
`flaair_analysis.multisine.spectrum_evidence.SpectrumEvidence` (a multisine set's line spectra).
"""

from __future__ import annotations

from .fit import RANK_TOL, EvidenceFit, covariance, fit_evidence
from .judging import (
    chi2_allowance,
    distance_from_null,
    drop_failure,
    excess_above_noise,
    excess_of_rss,
    gap_drop,
    passes_drop,
    passes_z,
    z_failure,
)
from .protocol import Evidence, EvidenceSet, Split

__all__ = [
    "RANK_TOL",
    "Evidence",
    "EvidenceFit",
    "EvidenceSet",
    "Split",
    "chi2_allowance",
    "covariance",
    "distance_from_null",
    "drop_failure",
    "excess_above_noise",
    "excess_of_rss",
    "fit_evidence",
    "gap_drop",
    "passes_drop",
    "passes_z",
    "z_failure",
]
