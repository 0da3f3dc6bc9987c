"""The recorder and the player: record FLAAIR topics to a bag, play a bag back onto its topics.

Modules (import them by name; this package imports none of them eagerly):
- `recording`: the recorder's pure decisions (what, which QoS, which log time)
- `recorder_io`: its parameters and `bin/flaair record` options
- `recorder_node`: the recorder node
- `player`: the player node (`bin/flaair play`)
"""

__all__ = ["player", "recorder_io", "recorder_node", "recording"]
