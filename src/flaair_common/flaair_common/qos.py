"""QoS profiles for FLAAIR topics.

Block streams are reliable with a deep queue: a lost block is a hole in a 20 kHz record and, for
the lockstep plant, a stalled loop. Reliable KEEP_LAST still drops what a slow reader has not
taken once the writer's history is full, so the history holds 10 s of 0.5 ms blocks (a 1000-deep
one lost front-end blocks on a loaded machine). Status topics keep the latest few; events are
reliable and transient-local so a late subscriber still sees the last onset/clearance.
"""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

BLOCK_STREAM = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=20000,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
STATUS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=50,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
EVENTS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=100,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
