"""The live view over the Foxglove WebSocket protocol.

Modules (import them by name; this package imports none of them eagerly):
- `live_view`: what is published (per-sample messages, wingbeat summary, layout)
- `foxglove_io`: its parameters and the argv that starts it
- `foxglove_node`: the node serving it
- `foxglove_cli`: `bin/flaair foxglove`
- `foxglove_client`: a minimal protocol client for tests and benchmarks
"""

__all__ = ["foxglove_cli", "foxglove_client", "foxglove_io", "foxglove_node", "live_view"]
