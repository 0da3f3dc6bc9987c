"""flaair_analysis.evidence.judging: one convention for the held-out drop on any evidence."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from flaair_analysis import evidence
from flaair_analysis.discrepancy.effect_judging import rss_gap_drop
from flaair_model.settings import JudgingRules

RULES = JudgingRules(min_heldout_drop=0.2, min_z=5.0)


def test_the_error_above_noise_counts_each_site_once() -> None:
    # a column at twice the noise's mean square and one at the noise: (1 + 0) / 2
    assert evidence.excess_above_noise([2.0, 1.0]) == pytest.approx(0.5)
    # a site below its noise has no error above it; none at all is no error
    assert evidence.excess_above_noise([0.5, 3.0]) == pytest.approx(1.0)
    assert evidence.excess_above_noise([]) == 0.0
    # 1000 samples summing to 1500: a mean square of 1.5
    assert evidence.excess_of_rss(1500.0, 1000) == pytest.approx(0.5)
    assert evidence.excess_of_rss(0.0, 0) == 0.0


def test_the_drop_is_on_the_rms_scale() -> None:
    # the error above noise a quarter of its mean square: half its RMS
    assert evidence.gap_drop(4.0, 1.0) == pytest.approx(0.5)
    assert evidence.gap_drop(1.0, 0.0) == 1.0
    assert evidence.gap_drop(0.0, 2.0) == 0.0  # nothing above noise to drop
    assert evidence.gap_drop(1.0, 4.0) == pytest.approx(-1.0)  # worse: a negative drop


@settings(max_examples=200, deadline=None)
@given(
    n=st.integers(1, 10**6),
    before=st.floats(1e-4, 1e3),
    after=st.just(0.0) | st.floats(1e-4, 1e3),
)
def test_a_runs_channel_and_a_table_side_are_judged_alike(
    n: int, before: float, after: float
) -> None:
    # a run channel's R1 on its pooled residual sum of squares, as written for runs
    rss_before, rss_after = n * (1.0 + before), n * (1.0 + after)
    closed = (
        1.0 - math.sqrt(max(rss_after - n, 0.0)) / math.sqrt(max(rss_before - n, 0.0))
        if rss_before > n
        else 0.0
    )
    assert rss_gap_drop(rss_before, rss_after, n) == pytest.approx(closed, rel=1e-6, abs=1e-6)
    # the same error above noise on one table column (its mean square) drops the same
    side = evidence.gap_drop(
        evidence.excess_above_noise([1.0 + before]),
        evidence.excess_above_noise([1.0 + after]),
    )
    assert side == pytest.approx(closed, rel=1e-6, abs=1e-6)


def test_the_rules_and_their_words() -> None:
    assert evidence.passes_drop(0.21, RULES) and not evidence.passes_drop(0.2, RULES)
    assert evidence.passes_z(5.1, RULES) and not evidence.passes_z(5.0, RULES)
    assert (
        evidence.drop_failure(0.03, RULES) == "held-out error above noise dropped 3% (needs > 20%)"
    )
    assert evidence.z_failure(1.17, RULES) == "1.2 standard errors from doing nothing (needs > 5)"


def test_the_distance_from_doing_nothing() -> None:
    # a structural damping of 0.05 +- 0.01 from its null 0: five standard errors
    assert evidence.distance_from_null(0.05, 0.01, 0.0) == pytest.approx(5.0)
    assert evidence.distance_from_null(-0.05, 0.01, 0.0) == pytest.approx(5.0)
    # a stop at 22 +- 0.5 deg where the model reaches 25 deg: six below its reach
    assert evidence.distance_from_null(22.0, 0.5, math.inf, reach=25.0) == pytest.approx(6.0)
    # a stop beyond the reach does nothing, and a standard error of 0 or inf says nothing
    assert evidence.distance_from_null(26.0, 0.5, math.inf, reach=25.0) == 0.0
    assert evidence.distance_from_null(0.05, math.inf, 0.0) == 0.0
    assert evidence.distance_from_null(0.05, 0.0, 0.0) == 0.0


def test_another_set_may_rise_by_what_noise_moves_it() -> None:
    # a chi-square of n unit-variance residuals has variance 2 n: two standard deviations
    assert evidence.chi2_allowance(60) == pytest.approx(2 * math.sqrt(120))
    assert evidence.chi2_allowance(0) == 0.0
