"""`remember_last`: the last result again for the same first object and equal other arguments."""

from __future__ import annotations

import pytest

from flaair_model.last_call import remember_last


@pytest.mark.timeout(10)
def test_the_last_result_comes_back_only_for_the_same_object_and_equal_rest() -> None:
    calls: list[tuple] = []

    @remember_last
    def prepared(params: dict, rate: float) -> tuple:
        calls.append((id(params), rate))
        return (len(params), rate)

    a, b = {"k": 1}, {"k": 1}  # equal, not the same object
    assert prepared(a, 20000.0) == prepared(a, 20000.0) == (1, 20000.0)
    assert len(calls) == 1
    prepared(b, 20000.0)  # another object: computed again, even though equal
    prepared(b, 10000.0)  # another rate
    prepared(a, 10000.0)  # only the last call is kept
    assert len(calls) == 4
    assert prepared.__name__ == "prepared"
