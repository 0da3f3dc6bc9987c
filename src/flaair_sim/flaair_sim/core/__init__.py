"""Pure cores of the simulation package: no rclpy, no files, no plots.

- ``plant``: plant dynamics and sensor chain (numba kernels, `step`, `simulate`, batches)
- ``plant_kernel``: its numba kernels (RK4 with the collision stop, one model or a batch)
- ``describing``: the plant's torques at a motion's fundamental (stroke stiffness, pitch response)
- ``plant_params``: a model and its effects as the kernels' parameter vector (`prepare`)
- ``plant_terms``: a model's discovered terms at the drive and the sensor outputs (with state)
- ``term_kernel``: its discovered dynamics terms inside the RK4 kernel
- ``torque_response``: the plant's response to small added torques, linearised about its motion
- ``sensor_kernel``: the sensor chain's kernel (high-pass, delay)
- ``hysteresis_kernel``: the actuator's hysteresis (a Bouc-Wen operator on the drive)
- ``measured_run``: a simulated run in the measured-run CSV's columns
- ``damage``: the robot damaged mid-run (inertia, stiffness, a film's gain from a time on)
- ``actuator``: which drive block the plant steps next, and when (drive watchdog, ring-down)
- ``drive``: drive-voltage generators, whole-record and sample-exact blocks
- ``drive_pacing``: when the open-loop drive generator sends which block
- ``scene``: the obstacle schedule and the ground truth as a camera sees it
"""

__all__ = [
    "actuator",
    "damage",
    "describing",
    "drive",
    "drive_pacing",
    "hysteresis_kernel",
    "measured_run",
    "plant",
    "plant_kernel",
    "plant_params",
    "plant_terms",
    "scene",
    "sensor_kernel",
    "term_kernel",
    "torque_response",
]
