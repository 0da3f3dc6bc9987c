"""The discovery's ranking reads a truth channel's residual change per composed form from
`ResidualProblem.angle_columns`: a compiled pass must give the bits (and the memory layout) of
the numpy expression it replaced, since the ranking meets ties within 2e-16.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from flaair_analysis.discrepancy.fitting import Fold, ResidualProblem

pytestmark = pytest.mark.timeout(120)


def _numpy_columns(problem: ResidualProblem, changes: dict[int, np.ndarray]) -> np.ndarray:
    """The array expression the ranking used before (the truth here)."""
    cols = []
    for f, idx in zip(problem.folds, problem.idx, strict=True):
        x = np.degrees(changes[f.run][idx].T)
        cols.append(-(x - x.mean(axis=1, keepdims=True)) / problem.weight)
    return np.concatenate(cols, axis=1)


@settings(max_examples=60, deadline=None)
@given(
    m=st.integers(1, 7),
    n=st.integers(8, 400),
    runs=st.integers(1, 3),
    decimate=st.integers(1, 3),
    seed=st.integers(0, 2**32 - 1),
)
@example(m=2, n=8, runs=1, decimate=2, seed=6)  # folds of one sample: numpy's other layout
def test_the_compiled_columns_are_numpys_to_the_bit(
    m: int, n: int, runs: int, decimate: int, seed: int
) -> None:
    rng = np.random.default_rng(seed)
    measured = {}
    for r in range(runs):
        angle = rng.standard_normal(n)
        angle[rng.random(n) < 0.05] = np.nan  # samples the folds leave out
        measured[r] = SimpleNamespace(channel=lambda _, a=angle: a)
    folds = [Fold(r, a, b, f"{r}{a}") for r in range(runs) for a, b in ((0, n // 2), (n // 2, n))]
    sigma = float(rng.uniform(0.01, 5))
    problem = ResidualProblem(measured, folds, "stroke_deg", sigma, False, decimate)
    # columns of very different sizes: a sum's rounding depends on its order
    changes = {
        r: rng.standard_normal((n, m)) * 10.0 ** rng.uniform(-9, 3, size=m) for r in range(runs)
    }
    got, want = problem.angle_columns(changes), _numpy_columns(problem, changes)
    assert got.shape == want.shape and got.strides == want.strides
    assert np.array_equal(got, want)
