"""FLAAIR control cores: collision metric/monitor, dSA controller, Hopf theory, drive safety.

Pure numpy/scipy/numba modules (no ROS, no file I/O):

- ``collision``: paper FFT/RMSE collision metric and a per-wingbeat collision monitor
- ``dsa``: delayed-stretch-activation controller (filter, sync/async blend, delay compensation)
- ``hopf``: linear theory of the dSA loop (characteristic polynomial, Hopf onset)
- ``safety``: drive clamp, slew limit and sensor watchdog
"""
