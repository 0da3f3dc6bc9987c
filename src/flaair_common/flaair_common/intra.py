"""In-process delivery of block streams between nodes composed into one process.

ROS 2 composition runs several nodes in one container; rclpy has no intra-process transport,
so a block published by one composed node would still be serialized, handed to Fast DDS and
deserialized by its neighbour (about 0.2 ms of CPU a message on this machine, most of the
loop's cost). Here a node publishes a block stream through `BlockPublisher`: the block's fields
go straight to the composed subscribers (a dict of numpy arrays, no serialization), and to DDS
only when someone outside listens (the recorder, an echo, the collision monitor process).

Delivery is a FIFO drained by whichever thread delivers first (the executor's, or a UDP reader
thread), one drainer at a time and in order, at most `budget_s` seconds (or, beside a reader
thread, `budget` callbacks) per call so the executor's timers still run; the container's loop
drains the rest. Subscribers off the hot path (the collision monitor, a recorder: `background`)
have their own FIFO, drained only by the main thread when the hot one is empty and
`background_batch` blocks wait: a per-wingbeat decision never delays a drive packet, and a
background core runs on longer blocks. Outside a container (`current()` is None) both helpers
fall back to plain rclpy publishers and raw subscriptions.
"""

from __future__ import annotations

import collections
import importlib
import math
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from flaair_common import cdr, topics

_current: Bus | None = None


class Bus:
    """The composed nodes' in-process block streams (only `local_topics` travel here)."""

    def __init__(
        self,
        local_topics: set[str],
        budget: int = 64,
        profile: bool = False,
        background_batch: int = 100,
        dds_batch: int = 1,
        budget_s: float = 0.01,
    ) -> None:
        self.local_topics = set(local_topics)
        # A drain gives the executor its turn (timers, services) after `budget_s` seconds where
        # this process's own callbacks drive the loop (lockstep): a turn of the EventsExecutor
        # costs more than a block, and taken every few blocks it slowed the whole loop
        # (docs/results/NOTES-2026-11.md). Where a reader thread delivers (a UDP bridge), the
        # main thread takes what is left at most `budget` callbacks at a time and gives the lock
        # back to the thread that has the priority.
        self.budget, self.budget_s = budget, budget_s
        # DDS copies of the local block streams go out joined, this many blocks to a message:
        # one rclpy publish costs tens of us, 2000 blocks/s per stream are most of a core
        self.dds_batch = dds_batch
        self.publishers: list[BlockPublisher] = []
        # (queued at, task)
        self.deferred: collections.deque[tuple[float, Callable[[], None]]] = collections.deque()
        # one thread at a time runs them: each stream stays in order
        self._deferring = threading.Lock()
        # background blocks wait until this many queue: ~10 ms at
        # 20 kHz of a recorder's 6 streams and the monitor's 1
        self.background_batch = background_batch
        # FLAAIR_PROFILE: time every composed callback
        self.profile = CallbackProfile() if profile else None
        self.subscribers: dict[str, list[tuple[Callable[[dict], None], bool]]] = (
            collections.defaultdict(list)
        )
        self.queue: collections.deque[tuple[Callable[[dict], None], dict]] = collections.deque()
        self.background_queue: collections.deque[tuple[Callable[[dict], None], dict]] = (
            collections.deque()
        )
        self._draining = threading.Lock()
        self._draining_background = threading.Lock()
        self.building_background = False  # set by the container while it builds a background node
        # background callbacks that take every block whole
        self.unjoined: set[Callable[[dict], None]] = set()
        self.delivered = 0
        self.threaded = False  # some thread other than the main one has delivered blocks

    def subscribe(
        self,
        topic: str,
        callback: Callable[[dict], None],
        background: bool = False,
        join: bool = True,
    ) -> None:
        """`callback(fields)` for every block of `topic`; `background`: off the hot
        path (see the module), its queued contiguous blocks joined into one call
        unless `join` is False (a recorder keeps every message as it was published).
        """
        wrapped = callback if self.profile is None else self.profile.wrap(callback)
        self.subscribers[topic].append((wrapped, background or self.building_background))
        if not join:
            self.unjoined.add(wrapped)

    def defer(self, task: Callable[[], None]) -> None:
        """Run `task` later, in order, off the block path: DDS copies (encoding and publishing one
        holds the interpreter lock for 0.1-0.3 ms, rclpy does not let it go while publishing).

        Where a reader thread drives the loop, it runs them one at a time in the gap after it
        has answered a block (`use_gap`); the main thread takes only those left waiting longer
        than `older_than_s` (run_deferred). Elsewhere the main thread runs them all.
        """
        self.deferred.append((time.monotonic(), task))

    def run_deferred(
        self, older_than_s: float = 0.0, limit: int = 1 << 30, wait: bool = True
    ) -> int:
        """Run up to `limit` deferred tasks queued at
        least `older_than_s` ago; returns how many ran.
        """
        if not self._deferring.acquire(blocking=wait):
            return 0
        try:
            done, newest = 0, time.monotonic() - older_than_s
            while done < limit and self.deferred and self.deferred[0][0] <= newest:
                self.deferred.popleft()[1]()
                done += 1
            return done
        finally:
            self._deferring.release()

    def has_background(self) -> bool:
        """Some subscriber is off the hot path (its blocks wait for the main thread)."""
        return any(
            background for subscribers in self.subscribers.values() for _, background in subscribers
        )

    def subscriber_count(self, topic: str) -> int:
        return len(self.subscribers.get(topic, ()))

    def deliver(self, topic: str, fields: dict) -> None:
        """Queue the block for every composed subscriber of `topic`, and drain if no one else is."""
        for callback, background in self.subscribers.get(topic, ()):
            (self.background_queue if background else self.queue).append((callback, fields))
        if self._draining.locked() and (
            self.threaded or threading.current_thread() is threading.main_thread()
        ):
            # a delivery from a callback the drain runs (every block of a composed loop): the
            # draining thread takes it, as `drain` would leave it to that thread
            return
        self.drain()

    def drain(self, budget: int | None = None) -> int:
        """Run queued callbacks in order (one thread at a time); returns how many ran.

        The hot FIFO first; the background FIFO only
        from the main thread, once the hot one is empty.
        """
        if not self.threaded and threading.current_thread() is not threading.main_thread():
            # a reader thread delivers: the main thread leaves its blocks to it
            self.threaded = True
        until_s = math.inf
        if budget is None:
            budget = self.budget
            if not self.threaded:
                budget, until_s = 1 << 30, time.monotonic() + self.budget_s
        done = _drain(self.queue, self._draining, budget, until_s)
        if (
            not self.queue
            and done < budget
            and len(self.background_queue) >= self.background_batch
            and threading.current_thread() is threading.main_thread()
        ):
            done += self._drain_background(budget - done)
        self.delivered += done
        return done

    def flush(self) -> int:
        """Everything queued, background included, and the held DDS batches (a node closes: its
        last blocks reach their consumers).
        """
        done = _drain(self.queue, self._draining, 1 << 30)
        while self.background_queue or self.queue:
            done += self._drain_background(1 << 30) + _drain(self.queue, self._draining, 1 << 30)
        self.delivered += done
        for publisher in self.publishers:
            publisher.flush_dds()
        self.run_deferred()
        return done

    def _drain_background(self, budget: int) -> int:
        """Up to `budget` queued background blocks, each subscriber's contiguous ones joined into
        one call (a background core runs per call, not per sample: fewer, longer blocks cost less).
        """
        if not self._draining_background.acquire(blocking=False):
            return 0
        try:
            taken: dict[Callable[[dict], None], list[dict]] = {}
            while self.background_queue and sum(map(len, taken.values())) < budget:
                callback, fields = self.background_queue.popleft()
                taken.setdefault(callback, []).append(fields)
            for callback, blocks in taken.items():
                for fields in blocks if callback in self.unjoined else join_contiguous(blocks):
                    callback(fields)
            return sum(map(len, taken.values()))
        finally:
            self._draining_background.release()

    def pending(self) -> bool:
        return bool(self.queue) or len(self.background_queue) >= self.background_batch


def _drain(
    queue: collections.deque, lock: threading.Lock, budget: int, until_s: float = math.inf
) -> int:
    """Run up to `budget` callbacks of `queue` in order under `lock`, none started after the
    monotonic time `until_s` but the first (skip if another thread holds the lock: that thread
    takes what was queued).
    """
    done = 0
    while queue and done < budget:
        if not lock.acquire(blocking=False):
            return done
        try:
            while queue and done < budget:
                callback, fields = queue.popleft()
                callback(fields)
                done += 1
                if time.monotonic() > until_s:
                    return done
        finally:
            lock.release()
    return done


def join_contiguous(blocks: list[dict]) -> list[dict]:
    """Blocks of one stream with each run of contiguous ones joined into one block.

    Contiguous: a block's first_sample_index is the previous one's plus its length. A joined
    block keeps the first block's stamp and scalars; its sample arrays are concatenated.
    """
    out: list[dict] = []
    run: list[dict] = []

    def flush() -> None:
        if len(run) == 1:
            out.append(run[0])
        elif run:
            first = run[0]
            out.append(
                {
                    key: np.concatenate([b[key] for b in run])
                    if isinstance(value, np.ndarray)
                    else value
                    for key, value in first.items()
                }
            )
        run.clear()

    for fields in blocks:
        if run and fields["first_sample_index"] != run[-1]["first_sample_index"] + _length(run[-1]):
            flush()
        if run and any(
            isinstance(v, np.ndarray) and not isinstance(fields.get(k), np.ndarray)
            for k, v in run[0].items()
        ):
            flush()
        run.append(fields)
    flush()
    return out


def _length(fields: dict) -> int:
    return next((len(v) for v in fields.values() if isinstance(v, np.ndarray)), 0)


class CallbackProfile:
    """CPU (thread time) and wall time spent in each composed subscriber's callback.

    Callbacks on the bus never nest (one drainer at a time), so a callback's time is its node's
    own work on one block: the core, the shell around it and its publishes (not the neighbour
    that a publish feeds). The container prints `report()` at exit when FLAAIR_PROFILE is set.
    """

    def __init__(self) -> None:
        self.entries: dict[str, list[float]] = {}  # name -> [calls, cpu_s, wall_s]

    def wrap(self, callback: Callable[[dict], None]) -> Callable[[dict], None]:
        owner = getattr(callback, "__self__", None)
        node = (
            owner.get_name()
            if hasattr(owner, "get_name")
            else type(owner).__name__
            if owner
            else ""
        )
        entry = self.entries.setdefault(
            f"{node}.{callback.__name__}" if node else callback.__qualname__, [0, 0.0, 0.0]
        )
        cpu, wall = time.thread_time, time.perf_counter

        def timed(fields: dict) -> None:
            c0, w0 = cpu(), wall()
            try:
                callback(fields)
            finally:
                entry[0] += 1
                entry[1] += cpu() - c0
                entry[2] += wall() - w0

        return timed

    def report(self) -> list[str]:
        """One line per callback: `profile: NAME: N calls, X us CPU, Y us wall per call`."""
        return [
            f"profile: {name}: {int(n)} calls, {1e6 * cpu / max(n, 1):.1f} us CPU, "
            f"{1e6 * wall / max(n, 1):.1f} us wall per call"
            for name, (n, cpu, wall) in self.entries.items()
        ]


def current() -> Bus | None:
    """The bus of the container this process runs, if any."""
    return _current


def use_gap() -> None:
    """The hot path has just answered a block and has a gap until the next one: one deferred DDS
    copy goes out now, on this thread, instead of competing with the next block for the
    interpreter lock (a main-thread flush every 20 blocks made the blocks it met 0.3 ms later).
    """
    if _current is not None and _current.deferred:
        _current.run_deferred(limit=1, wait=False)


def install(bus: Bus | None) -> None:
    """Make `bus` the current one (the container does, before it builds its nodes)."""
    global _current
    _current = bus


# Per-block decisions (publish to DDS or not) re-read a publisher's DDS subscription count every
# this many blocks: rclpy's query costs 3-5 us, and the loop made five of them a block. A listener
# that matches meanwhile gets the stream up to this many blocks (4 ms at 20 kHz in 10-sample
# blocks) later, well inside DDS discovery's own delay; one that leaves costs a few unread writes.
LISTENER_REFRESH_BLOCKS = 8


class ListenerCount:
    """A publisher's DDS subscription count for per-block decisions (`LISTENER_REFRESH_BLOCKS`)."""

    def __init__(self, publisher: Any) -> None:
        self.publisher, self.count, self.left = publisher, 0, 0

    def __call__(self) -> int:
        if self.left <= 0:
            self.count = self.publisher.get_subscription_count()
            self.left = LISTENER_REFRESH_BLOCKS
        self.left -= 1
        return self.count


class BlockPublisher:
    """A block stream publisher: composed subscribers in-process, DDS for everyone else.

    With the bus's ``dds_batch`` > 1, a sample-block stream (one with ``first_sample_index``)
    reaches DDS in joined blocks of that many (contiguous) blocks; in-process subscribers still
    get every block at once. Messages without samples (ControllerState) go out one by one.
    """

    def __init__(
        self, node: Any, msg_type: type, topic: str, codec: cdr.FixedCodec, qos: Any
    ) -> None:
        self.topic, self.codec = topic, codec
        self.publisher = node.create_publisher(msg_type, topic, qos)
        self.dds_listeners = ListenerCount(self.publisher)
        bus = current()
        self.bus = bus if bus is not None and topic in bus.local_topics else None
        fields = dict(codec.layout.fields)
        sampled = "first_sample_index" in fields and any(
            kind.endswith("[]") for kind in fields.values()
        )
        self.batch = self.bus.dds_batch if self.bus is not None and sampled else 1
        self.held: list[tuple[int, dict]] = []  # blocks not yet on DDS (batching)
        self.held_end = 0  # sample index after the last held block
        # per-sample fields
        self.arrays = [name for name, kind in codec.layout.fields if kind.endswith("[]")]
        self.sized: dict[int, cdr.FixedCodec] = {}
        if self.bus is not None:
            self.bus.publishers.append(self)

    def subscription_count(self) -> int:
        """Subscribers of this stream: on DDS and, when composed, in-process."""
        local = self.bus.subscriber_count(self.topic) if self.bus is not None else 0
        return self.publisher.get_subscription_count() + local

    def has_listeners(self) -> bool:
        """Someone listens (`subscription_count` > 0) for a per-block decision: the DDS part
        re-read every `LISTENER_REFRESH_BLOCKS` calls.
        """
        if self.bus is not None and self.bus.subscriber_count(self.topic):
            return True
        return self.dds_listeners() > 0

    def publish(self, stamp_ns: int, fields: dict) -> None:
        """Publish one block: its header stamp (ns) and its fields as `cdr` names them."""
        # DDS first: the in-process delivery may run the whole loop before it returns, and an
        # outside listener must still see this stream in order.
        if self.batch > 1:
            self._hold(stamp_ns, fields)
        elif self.bus is not None and self.bus.dds_batch > 1:  # off the hot path, as the batches
            self.bus.defer(lambda: self._publish_now(stamp_ns, fields))
        elif self.bus is None or self.dds_listeners() > 0:
            self.publisher.publish(self.codec.encode(stamp_ns, fields))
        if self.bus is not None:
            sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
            self.bus.deliver(
                self.topic,
                {**fields, "sec": sec, "nanosec": nanosec, "frame_id": self.codec.frame_id},
            )

    def _hold(self, stamp_ns: int, fields: dict) -> None:
        first = fields["first_sample_index"]
        if self.held and first != self.held_end:
            self.flush_dds()
        self.held.append((stamp_ns, fields))
        self.held_end = first + len(fields[self.arrays[0]])
        if len(self.held) >= self.batch:
            self.flush_dds()

    def _publish_now(self, stamp_ns: int, fields: dict) -> None:
        if self.publisher.get_subscription_count() > 0:
            self.publisher.publish(self.codec.encode(stamp_ns, fields))

    def flush_dds(self) -> None:
        """Hand the held blocks to the main thread, which publishes them joined into one message."""
        if self.held:
            held, self.held = self.held, []
            self.bus.defer(lambda: self._publish_joined(held))

    def _publish_joined(self, held: list[tuple[int, dict]]) -> None:
        """Publish held (contiguous: `_hold` sees to it) blocks joined into one message, the first
        block's stamp and scalars, every sample in order (if anyone listens on DDS).
        """
        if self.publisher.get_subscription_count() == 0:  # volatile: no listener, nothing lost
            return
        joined = {
            **held[0][1],
            **{name: np.concatenate([fields[name] for _, fields in held]) for name in self.arrays},
        }
        n = len(joined[self.arrays[0]])
        codec = (
            self.codec
            if n == self.codec.block_size
            else self.sized.get(n)
            or self.sized.setdefault(n, cdr.FixedCodec(self.codec.layout, n, self.codec.frame_id))
        )
        self.publisher.publish(codec.encode(held[0][0], joined))


def dds_listeners() -> int:
    """The fewest DDS subscribers any of this container's batched block streams has (a recorder in
    another process listens to all of them); a large number outside such a container.
    """
    bus = current()
    counts = (
        [p.publisher.get_subscription_count() for p in bus.publishers if p.batch > 1]
        if bus is not None
        else []
    )
    return min(counts) if counts else 1 << 30


def subscribe_blocks(
    node: Any,
    msg_type: type,
    topic: str,
    codec: cdr.FixedCodec,
    callback: Callable[[Any], None],
    qos: Any,
    on_error: Callable[[Exception], None],
    background: bool = False,
) -> Any | None:
    """Call `callback(fields)` for every block of `topic`: in-process when composed, else from DDS.

    ``fields`` is indexable by the message's field names and ``sec``/``nanosec`` either way (a
    `cdr` record from DDS, a dict in-process); undecodable DDS bytes go to ``on_error``. Returns
    the DDS subscription (None in-process).
    """
    bus = current()
    if bus is not None and topic in bus.local_topics:
        bus.subscribe(topic, callback, background)
        return None

    def on_bytes(data: bytes) -> None:
        try:
            fields = codec.decode(data)
        except cdr.CdrError as exc:
            on_error(exc)
            return
        callback(fields)

    return node.create_subscription(msg_type, topic, on_bytes, qos, raw=True)


# The fixed-size sample-block streams: topic -> (CDR layout, header frame_id or None).
_SAMPLE_STREAMS = {
    topics.DRIVE: (cdr.DRIVE_COMMAND_BLOCK, None),
    topics.DRIVE_APPLIED: (cdr.DRIVE_COMMAND_BLOCK, None),
    topics.SENSOR_VOLTAGE: (cdr.SENSOR_VOLTAGE_BLOCK, topics.FRAME_ID),
    topics.WING_STATE: (cdr.WING_STATE_BLOCK, topics.FRAME_ID),
    topics.WING_STATE_TRUTH: (cdr.WING_STATE_BLOCK, topics.FRAME_ID),
}


def stream_codec(topic: str, block_size: int) -> cdr.FixedCodec:
    """The fixed-size CDR codec of the sample-block stream `topic` at `block_size` samples."""
    layout, frame_id = _SAMPLE_STREAMS[topic]
    return (
        cdr.FixedCodec(layout, block_size, frame_id)
        if frame_id
        else cdr.FixedCodec(layout, block_size)
    )


def _message_class(topic: str) -> type:
    return getattr(
        importlib.import_module("flaair_msgs.msg"),
        topics.BLOCK_STREAM_TYPES[topic].rsplit("/", 1)[1],
    )


def block_publisher(node: Any, topic: str, block_size: int, qos: Any) -> BlockPublisher:
    """The `BlockPublisher` of the sample-block stream
    `topic` (message type and codec from the topic).
    """
    return BlockPublisher(node, _message_class(topic), topic, stream_codec(topic, block_size), qos)


def subscribe_stream(
    node: Any,
    topic: str,
    block_size: int,
    callback: Callable[[Any], None],
    qos: Any,
    on_error: Callable[[Exception], None],
    background: bool = False,
) -> Any | None:
    """`subscribe_blocks` to the sample-block stream
    `topic` (message type and codec from the topic).
    """
    return subscribe_blocks(
        node,
        _message_class(topic),
        topic,
        stream_codec(topic, block_size),
        callback,
        qos,
        on_error,
        background,
    )
