"""A synthetic measured run: the simulated robot's signals in the measured-run CSV's columns."""

from __future__ import annotations

import numpy as np

from flaair_model.model import Model
from flaair_sim.core.plant import simulate

__all__ = ["synthesize_measured_run"]


def synthesize_measured_run(
    drive_v: np.ndarray, fs_hz: float, model: Model, rng: np.random.Generator
) -> dict[str, np.ndarray]:
    """Synthetic measured run in the measured-run CSV columns and units.

    Sensor voltages carry sensor noise; angles are the truth plus video-tracking noise
    (model.noise.tracking_noise_deg_rms).

    Returns
    -------
    dict
        time_s, drive_v, stroke_sensor_v, pitch_sensor_v, stroke_deg, pitch_deg.
    """
    out = simulate(drive_v, fs_hz, model, noise=True, rng=rng)  # checks the drive
    drive = np.asarray(drive_v, dtype=np.float64)
    tracking = rng.standard_normal((drive.shape[0], 2)) * model.noise.tracking_noise_deg_rms
    return {
        "time_s": np.arange(drive.shape[0]) / float(fs_hz),
        "drive_v": drive.copy(),
        "stroke_sensor_v": out.stroke_sensor_v,
        "pitch_sensor_v": out.pitch_sensor_v,
        "stroke_deg": np.degrees(out.stroke_rad) + tracking[:, 0],
        "pitch_deg": np.degrees(out.pitch_rad) + tracking[:, 1],
    }
