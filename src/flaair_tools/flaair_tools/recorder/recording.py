"""The recorder's decisions, pure: what to record, with which QoS, at which log time.

Log time: every message is logged at its signal time, so a bag's timeline is the signal's
own (3 s of simulated signal span 3 s of log time). A message with a leading header (or a
/clock) carries that time; a header-less message (a run marker) takes the signal time of the
latest stamped message, and waits for the first one; at the end of a bag with no stamped
message at all the waiting ones keep their publish time (else the receive time). /diagnostics
is logged as a header-less message is: its stamp is the publishing node's wall clock, which in
simulation is not the signal's (the array keeps its stamp inside).
``step(state, inputs, params) -> (state, writes)`` applies that rule to one received message
(`Received`) or to the end of recording (`Finish`).

Drain: the executor hands a callback one message per wake-up, too few for 20 kHz streams in
10-sample blocks; `drain` takes the messages already queued behind it, at most
`RecordingParams.drain_limit` per callback so that other topics get their turn.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple, TypeVar

from rosbags.interfaces import QosDurability, QosReliability

from flaair_common.topics import CLOCK, TIME_ANCHOR
from flaair_model.schema import ParameterError

NAMESPACE = "/flaair/"
DIAGNOSTICS = "/diagnostics"  # every node's health (diagnostic_msgs/DiagnosticArray), 1 Hz
T = TypeVar("T")


@dataclass(frozen=True)
class RecordingParams:
    """How many messages one callback takes from its subscription at most."""

    drain_limit: int


class LogTimeState(NamedTuple):
    """Signal time of the latest stamped message, and the header-less messages before it."""

    signal_ns: int | None = None
    pending: tuple[Write, ...] = ()


class Received(NamedTuple):
    """One raw message; `stamp_ns` is its leading stamp (None: header-less)."""

    topic: str
    data: bytes | memoryview
    stamp_ns: int | None
    publish_ns: int | None  # the publisher's send time, if the middleware gave it


class Finish(NamedTuple):
    """End of recording at wall time `now_ns`."""

    now_ns: int


class Write(NamedTuple):
    """One message for the bag at log time `log_ns`."""

    topic: str
    log_ns: int
    data: bytes | memoryview
    publish_ns: int | None


def step(
    state: LogTimeState, inputs: Received | Finish, params: RecordingParams | None = None
) -> tuple[LogTimeState, tuple[Write, ...]]:
    """The writes one message (or the finish) releases, in order."""
    if isinstance(inputs, Finish):  # no stamped message ever came: publish (else receive) times
        return LogTimeState(state.signal_ns), tuple(
            w._replace(log_ns=w.publish_ns or inputs.now_ns) for w in state.pending
        )
    topic, data, stamp_ns, publish_ns = inputs
    if topic == DIAGNOSTICS:
        stamp_ns = None
    if stamp_ns is not None:
        write = (Write(topic, stamp_ns, data, publish_ns),)
        if state.pending:
            write = tuple(w._replace(log_ns=stamp_ns) for w in state.pending) + write
        return LogTimeState(stamp_ns), write
    if state.signal_ns is None:  # keep a copy: the middleware may reuse the buffer
        return LogTimeState(None, (*state.pending, Write(topic, 0, bytes(data), publish_ns))), ()
    return state, (Write(topic, state.signal_ns, data, publish_ns),)


def drain(take: Callable[[], T | None], params: RecordingParams, already: int = 1) -> list[T]:
    """Messages from `take()` until it returns None or `already` + taken reach the drain limit."""
    taken: list[T] = []
    while already + len(taken) < params.drain_limit:
        message = take()
        if message is None:
            break
        taken.append(message)
    return taken


def parse_topic_list(text: str) -> tuple[str, ...]:
    """Topics from a comma- or space-separated list; each must be an absolute name."""
    names = tuple(name for name in text.replace(",", " ").split() if name)
    bad = [name for name in names if not name.startswith("/")]
    if bad:
        raise ParameterError(
            f"parameter 'topics': topic names must start with '/': {', '.join(bad)}"
        )
    return names


def wanted(topic: str, chosen: tuple[str, ...], record_clock: bool, namespace: str = "/") -> bool:
    """Whether to record `topic`: the chosen ones, else every /flaair topic of the recorder's
    `namespace` (a recorder started in /bench2 records /bench2/flaair/...); /clock if asked;
    /diagnostics and the namespace's /flaair/time_anchor always (a bag keeps a run's health
    and how its sample clocks map to ROS time).
    """
    if topic == CLOCK:
        return record_clock or topic in chosen
    if topic == DIAGNOSTICS or topic == namespace.rstrip("/") + TIME_ANCHOR:
        return True
    if chosen:
        return topic in chosen
    return topic.startswith(namespace.rstrip("/") + NAMESPACE)


@dataclass(frozen=True)
class SubscriptionQos:
    """What the recorder subscribes with, decided from the publishers' offers."""

    reliable: bool
    transient_local: bool


def adapt_qos(offered: list[Any]) -> SubscriptionQos:
    """Reliable / transient-local only when every publisher offers it (else nothing would match)."""
    if not offered:
        return SubscriptionQos(True, False)
    reliable = all(q.reliability == QosReliability.RELIABLE for q in offered)
    transient = all(q.durability == QosDurability.TRANSIENT_LOCAL for q in offered)
    return SubscriptionQos(reliable, transient)


def default_output_path(now_s: float) -> Path:
    """out/bags/flaair_<YYYYmmdd_HHMMSS> under the working directory."""
    return Path("out") / "bags" / time.strftime("flaair_%Y%m%d_%H%M%S", time.localtime(now_s))
