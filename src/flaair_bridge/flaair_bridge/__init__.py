"""FLAAIR real-time target bridge: UDP to the lab's target, blocks to and from ROS.

``core/`` holds the pure protocol and bridge logic (no rclpy, no sockets); beside it:

- ``bridge_node``: the bridge node (rclpy), a thin shell over ``core.bridge``
- ``bridge_io``: its parameters and message <-> core mapping (no rclpy)
- ``udp``: the socket and its reader thread
- ``emulated_target``: a stand-in for the lab's target, for tests and `live`
"""

__all__ = ["bridge_io", "bridge_node", "core", "emulated_target", "udp"]
