"""Front-end tuning the unit tests spell for themselves (the core has no defaults).

The values the tests were written against: drift tracking at 0.5 Hz, lag compensation with a
1 kHz lead roll-off, no rails, 1.5 ms hold-off, 1 kHz velocity cutoff.
"""

import math

FRONTEND_TUNING = {
    "drift_corner_hz": 0.5,
    "compensate_lag": True,
    "lead_rolloff_hz": 1000.0,
    "rail_low_v": -math.inf,
    "rail_high_v": math.inf,
    "rail_margin_v": 0.0,
    "holdoff_s": 1.5e-3,
    "velocity_cutoff_hz": 1000.0,
}
