"""A node's exit waits for its readers to acknowledge its last messages (flaair_common.runtime),
with a budget a loaded machine's recorder can meet, and names the topics still unacknowledged.
A soak run lost the last 0.6 s of a `live` run's drive when the wait was 2 s in all and the
first publisher's reader had used it up.
"""

from __future__ import annotations

import pytest

from flaair_common import runtime


class FakeClock:
    def __init__(self) -> None:
        self.now_s = 100.0

    def monotonic(self) -> float:
        return self.now_s


class FakePublisher:
    """Acknowledged after `ack_after_s` of waiting (never when None); records what it was given."""

    def __init__(self, topic: str, ack_after_s: float | None, clock: FakeClock) -> None:
        self.topic_name, self.ack_after_s, self.clock = topic, ack_after_s, clock
        self.offered_s: float | None = None

    def wait_for_all_acked(self, timeout) -> bool:
        self.offered_s = timeout.nanoseconds / 1e9
        if self.ack_after_s is not None and self.ack_after_s <= self.offered_s:
            self.clock.now_s += self.ack_after_s
            return True
        self.clock.now_s += self.offered_s
        return False


class FakeNode:
    def __init__(self, publishers: list[FakePublisher]) -> None:
        self.publishers, self.warnings = publishers, []

    def get_logger(self):
        return self

    def warning(self, text: str) -> None:
        self.warnings.append(text)


@pytest.fixture
def clock(monkeypatch) -> FakeClock:
    fake = FakeClock()
    monkeypatch.setattr(runtime.time, "monotonic", fake.monotonic)
    return fake


def test_a_slow_first_reader_leaves_the_other_topics_their_wait(clock) -> None:
    sensor = FakePublisher("/flaair/sensor_v", 3.0, clock)  # a recorder 3 s behind
    drive = FakePublisher("/flaair/drive", 1.5, clock)
    node = FakeNode([sensor, drive])
    runtime.wait_for_acks([node])
    assert drive.offered_s == pytest.approx(runtime.ACK_WAIT_S - 3.0)
    assert node.warnings == []


def test_topics_still_unacknowledged_are_named(clock) -> None:
    stuck = FakePublisher("/flaair/drive", None, clock)
    fine = FakePublisher("/flaair/controller/state", 0.0, clock)
    node = FakeNode([stuck, fine])
    runtime.wait_for_acks([node], timeout_s=4.0)
    assert clock.now_s == pytest.approx(104.0)
    assert node.warnings == [
        "not acknowledged by every reader within 4 s, may be lost: the last "
        "messages on /flaair/drive"
    ]
