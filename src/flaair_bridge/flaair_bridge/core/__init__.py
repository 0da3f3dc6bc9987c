"""Pure cores of the real-time target bridge: no rclpy, no sockets.

- ``protocol``: pack and unpack the target's sensor and drive packets (docs/REALTIME_PROTOCOL.md)
- ``bridge``: target sensor packets in, FLAAIR blocks out; FLAAIR drive in, drive packets out
"""

__all__ = ["protocol", "bridge"]
