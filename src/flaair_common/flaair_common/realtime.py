"""Real-time scheduling for the threads that keep a 20 kHz loop (no ROS)."""

from __future__ import annotations

import os


def take_realtime_priority(priority: int) -> str:
    """Run the calling thread (and the threads it starts afterwards) SCHED_FIFO at `priority`.

    0 leaves the scheduling as it is. Returns "" on success, else why not (not root, no
    CAP_SYS_NICE, not Linux): the caller warns and runs on at normal priority.
    """
    if priority <= 0:
        return ""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (OSError, AttributeError) as exc:
        return str(exc)
    return ""
