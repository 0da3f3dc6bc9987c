"""The rules every candidate (an effect, a term) is judged by, whatever the evidence: one
convention for runs, tables and spectra. Pure.

Every piece of evidence gives residuals in units of its own noise (`Evidence`), so on each site
it sees (a run's channel, a table's column) a model whose error is all noise has a mean square of
1. The model error above noise is the mean over the sites of max(mean square - 1, 0): each site
counts once, however many residuals it has. A candidate's held-out drop is on the RMS scale,
1 - sqrt(excess after / excess before), the scale of the NRMSE the reports print. It must exceed
`JudgingRules.min_heldout_drop` (R1), and its parameter must lie more than `min_z` standard
errors from doing nothing (R3; a stop's limit that many below the largest stroke the model
reaches). A finding kept on one kind of evidence is checked on every other: their chi-squares
may rise by no more than noise moves them (`chi2_allowance`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable

from flaair_model.settings import JudgingRules

__all__ = [
    "chi2_allowance",
    "distance_from_null",
    "drop_failure",
    "excess_above_noise",
    "excess_of_rss",
    "gap_drop",
    "passes_drop",
    "passes_z",
    "z_failure",
]


def excess_above_noise(mean_squares: Iterable[float]) -> float:
    """The model error above noise: the mean over sites of max(ms - 1, 0), each site's `ms` the
    mean square of its noise-weighted residuals (0 with no site).
    """
    excess = [max(ms - 1.0, 0.0) for ms in mean_squares]
    return sum(excess) / len(excess) if excess else 0.0


def excess_of_rss(rss: float, n: int) -> float:
    """The excess above noise of one site whose `n` noise-weighted residuals sum to `rss`."""
    return excess_above_noise([rss / n]) if n > 0 else 0.0


def gap_drop(excess_before: float, excess_after: float) -> float:
    """Relative drop of the model error above noise, on the RMS scale (0 when there was none)."""
    if not excess_before > 0:
        return 0.0
    return 1.0 - math.sqrt(excess_after / excess_before)


def distance_from_null(value: float, se: float, null: float, reach: float = math.inf) -> float:
    """R3's distance of a fitted `value` (standard error `se`) from doing nothing, in standard
    errors: from its `null`, or for a stop (a null of inf: a limit never reached) how far below
    the largest value the model `reach`es it lies. 0 where `se` says nothing (0 or inf) and for a
    stop at or beyond its reach.
    """
    if not 0 < se < math.inf:
        return 0.0
    if math.isinf(null):
        return (reach - value) / se if value < reach else 0.0
    return abs(value - null) / se


def chi2_allowance(n: int) -> float:
    """How far noise alone moves a chi-square of `n` noise-weighted residuals (two standard
    deviations, 2 sqrt(2 n)): a finding kept on one set may raise another's by no more.
    """
    return 2.0 * math.sqrt(2.0 * n)


def passes_drop(drop: float, rules: JudgingRules) -> bool:
    """R1: the held-out error above noise drops by more than the rules ask."""
    return bool(drop > rules.min_heldout_drop)


def passes_z(z: float, rules: JudgingRules) -> bool:
    """R3: the parameter lies more than `min_z` standard errors from doing nothing."""
    return bool(z > rules.min_z)


def drop_failure(drop: float, rules: JudgingRules) -> str:
    """Why R1 refused a candidate, in a report's words."""
    return f"held-out error above noise dropped {drop:.0%} (needs > {rules.min_heldout_drop:.0%})"


def z_failure(z: float, rules: JudgingRules) -> str:
    """Why R3 refused a candidate, in a report's words."""
    return f"{z:.1f} standard errors from doing nothing (needs > {rules.min_z:g})"
