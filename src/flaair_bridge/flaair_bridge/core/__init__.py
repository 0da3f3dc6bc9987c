"""Pure cores of the real-time target bridge: no rclpy, no sockets.

- ``protocol``: pack and unpack the target's sensor and drive packets (docs/REALTIME_PROTOCOL.md)
- ``bridge_params``: the bridge core's frozen parameters
- ``bridge``: target sensor packets in, FLAAIR blocks out; FLAAIR drive in, drive packets out
- ``bridge_state``: the core's counters, state, inputs and outputs (``bridge`` steps over them)
- ``bridge_drive``: the bridge core's drive side (anchoring, release, stop packets)
- ``bridge_report``: the run's one-line summary and raw event times for benchmarks
- ``target``: where drive and stop packets go (configured, or learnt from the target's packets)
"""

__all__ = [
    "bridge",
    "bridge_drive",
    "bridge_params",
    "bridge_report",
    "bridge_state",
    "protocol",
    "target",
]
