"""What a pure core has to say: one `Note` type for every core's log lines.

A core never logs; its `step` returns notes in its outputs, and the ROS shell logs them
(`flaair_common.runtime.log_notes`), the same way in every node. Offline (replay, tests) the notes
are plain data to read or ignore.
"""

from __future__ import annotations

from typing import NamedTuple

__all__ = ["ERROR", "INFO", "LEVELS", "WARNING", "Note"]

INFO, WARNING, ERROR = "info", "warning", "error"
LEVELS = (INFO, WARNING, ERROR)


class Note(NamedTuple):
    """One log line of a core.

    Attributes
    ----------
    level : str
        One of `LEVELS`.
    text : str
        The whole line, counts included (the shell adds nothing).
    counter : str
        The name of the count a repeated warning belongs to ("" for none): the shell logs such a
        warning every time for its first ten occurrences, then at most once a second.
    """

    level: str
    text: str
    counter: str = ""
