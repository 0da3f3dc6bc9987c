"""Pure cores of the control package: no rclpy, no files, no plots.

Each decision the nodes make is a function of explicit state, inputs and frozen parameters here.

- ``spectral``: the paper's FFT/RMSE collision metric
- ``collision``: the per-wingbeat collision monitor (windows, distortion, decision)
- ``monitor``: the collision monitor node's decisions as a step function
- ``dsa``: delayed-stretch-activation controller (filter, sync/async blend, delay compensation)
- ``health``: proprioceptive health (wing inertia, film gains per wingbeat; change events)
- ``change_test``: the health monitor's change test (CUSUMs, their thresholds, the cause named)
- ``hopf``: linear theory of the dSA loop (characteristic polynomial, Hopf onset, limit cycle)
- ``safety``: drive clamp, slew limit and sensor watchdog
- ``stroke``: the per-wingbeat stroke-amplitude controller
- ``stroke_loop``: the stroke controller's start, start retry and watchdog timing
- ``supervisor``: the dSA controller's start / loop / trip / keepalive state machine
- ``loop_state``: its parameters, state, events and outputs (``supervisor`` steps over them)
- ``transition``: sync -> async transition analysis
"""

__all__ = [
    "change_test",
    "collision",
    "dsa",
    "health",
    "hopf",
    "loop_state",
    "monitor",
    "safety",
    "spectral",
    "stroke",
    "stroke_loop",
    "supervisor",
    "transition",
]
