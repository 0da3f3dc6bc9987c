"""Pure cores of the real-time target bridge: no rclpy, no sockets.

- ``protocol``: pack and unpack the target's sensor and drive packets (docs/REALTIME_PROTOCOL.md)
- ``bridge_params``: the bridge core's frozen parameters
- ``bridge``: target sensor packets in, FLAAIR blocks out; FLAAIR drive in, drive packets out
- ``bridge_report``: the run's one-line summary and raw event times for benchmarks
"""

__all__ = ["bridge", "bridge_params", "bridge_report", "protocol"]
