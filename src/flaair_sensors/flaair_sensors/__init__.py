"""FLAAIR sensor front end: charge-amplifier volts ->
wing stroke and pitch, calibration, characterization.

``core/`` holds the pure functions (no rclpy); beside it the ROS shell and its adapters:

- ``frontend_node``: the front-end node (rclpy), a thin shell over ``core.frontend``
- ``frontend_io``: its parameters and the message <-> core mapping (no rclpy)
- ``analysis_io``: the analysis bands every tool reads from config/flaair.yaml
- ``figures``: the Bode figure (matplotlib)
"""

__all__ = ["analysis_io", "core", "figures", "frontend_io", "frontend_node"]
