"""FLAAIR control: collision monitor, dSA controller, stroke-amplitude control.

``core/`` holds the pure decisions (no rclpy); beside it the ROS shells and their adapters:

- ``dsa_controller_node``, ``collision_monitor_node``, ``stroke_controller_node``,
  ``health_node``: the nodes (rclpy)
- ``dsa_io`` (the dSA controller), ``monitor_io`` (the collision monitor), ``stroke_io``,
  ``transition_io``, ``health_io`` (the health monitor): their parameters and message <-> core
  mappings (no rclpy)
"""

__all__ = [
    "collision_monitor_node",
    "core",
    "dsa_controller_node",
    "dsa_io",
    "health_io",
    "health_node",
    "monitor_io",
    "stroke_controller_node",
    "stroke_io",
    "transition_io",
]
