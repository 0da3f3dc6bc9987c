"""Run markers: which sample range of a bag's block streams is which run (std_msgs/String JSON).

Part of `flaair_tools.bagio` (its `__init__` lists the public names).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass

from flaair_tools.bagio.messages import BagError

__all__ = ["RUN_KINDS", "RunMarker"]

# The drive kinds a run marker's "kind" may name (flaair_tools.analysis.runkind recognises them).
RUN_KINDS = ("chirp", "stepped_sine", "sine", "transition", "free", "unrecognised")


@dataclass(frozen=True)
class RunMarker:
    """One run in a bag: its name, sample range in the block streams, source file and start time."""

    run: str
    first_sample_index: int
    n_samples: int
    source_file: str
    sample_rate_hz: float
    start_ns: int

    def to_json(self) -> str:
        """The marker as the JSON text carried by a std_msgs/String."""
        return json.dumps(dataclasses.asdict(self))

    @classmethod
    def from_json(cls, text: str) -> RunMarker:
        """Parse a marker's JSON text; the message names a missing or bad key."""
        try:
            values = json.loads(text)
            return cls(
                run=str(values["run"]),
                first_sample_index=int(values["first_sample_index"]),
                n_samples=int(values["n_samples"]),
                source_file=str(values.get("source_file", "")),
                sample_rate_hz=float(values.get("sample_rate_hz", "nan")),
                start_ns=int(values.get("start_ns", 0)),
            )
        except (ValueError, KeyError, TypeError) as exc:
            raise BagError(f"bad run marker {text!r}: {exc!r}") from None
