"""Pure cores of the sensor front end: no rclpy, no files, no plots.

Each takes frozen parameters and explicit state; the node (`flaair_sensors.frontend_node`) and the
offline tools call the same functions.

- ``frontend``: inverse sensor model, charge-amplifier volts -> wing angles (`step`, `estimate`)
- ``frontend_params``: its frozen parameters, from a model or a calibration
- ``calibration``: gain, polarity, offset and lag of each sensor against ground truth
- ``characterization``: transfer functions, error statistics and Bode data of the sensors
- ``bode``: the stepped-sine and chirp frequency-response estimates it uses
"""

__all__ = ["bode", "calibration", "characterization", "frontend", "frontend_params"]
