"""FLAAIR plant simulation: the robot's dynamics and sensor chain, the drive generator.

``core/`` holds the pure functions (no rclpy); beside it the ROS shells and the CLI:

- ``plant_node``, ``drive_node``: the nodes (rclpy)
- ``plant_io``, ``drive_io``: their parameters and message <-> core mappings (no rclpy)
- ``simulate_cli``: `bin/flaair simulate`
"""

__all__ = ["core", "drive_io", "drive_node", "plant_io", "plant_node", "simulate_cli"]
