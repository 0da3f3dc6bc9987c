"""What the world does to the simulated robot and how it is seen (pure).

- The obstacle schedule: a block runs on the model with the obstacle inside its sim-time
  windows (`model_at`).
- The ground truth as a camera sees it (`tracked_angles`): one valid frame every
  `frame_every` samples, with the model's tracking noise when noise is on (`tracking_generator`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from flaair_model.model import Model
from flaair_sim.core.damage import DamagedModels

__all__ = ["CameraParams", "model_at", "tracked_angles", "tracking_generator"]


@dataclass(frozen=True)
class CameraParams:
    """How the ground truth is seen.

    Attributes
    ----------
    frame_every : one valid frame every this many samples (sample index a multiple of it);
        1: every sample valid.
    tracking_noise_deg_rms : tracking noise added to both angles (with a generator only).
    """

    frame_every: int
    tracking_noise_deg_rms: float


def model_at(
    start_s: float,
    model: Model,
    obstacle_model: Model,
    windows_s: Sequence[tuple[float, float]],
    damage: DamagedModels | None = None,
) -> Model:
    """The model a block starting at `start_s` runs on: the obstacle's inside its windows,
    the damaged ones from the damage time on.
    """
    if damage is not None and damage.params.active and start_s >= damage.params.time_s:
        model, obstacle_model = damage.model, damage.obstacle_model
    return obstacle_model if windows_s and any(a <= start_s < b for a, b in windows_s) else model


def tracking_generator(noise: bool, seed: int, frame_every: int) -> np.random.Generator | None:
    """The tracking-noise generator: only a camera (frame_every > 1) with noise on has one.

    Seeded apart from the sensor noise (`[seed, 1]`), so the two draws are independent.
    """
    return np.random.default_rng([seed, 1]) if noise and frame_every > 1 else None


def tracked_angles(
    first_index: int,
    stroke_rad: np.ndarray,
    pitch_rad: np.ndarray,
    params: CameraParams,
    rng: np.random.Generator | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(stroke_deg, pitch_deg, valid) of a block from sample `first_index` as the camera sees it.

    The noise is drawn as rng.standard_normal((n, 2)), so the draw does not depend on the block
    split; `valid` is None when every sample is valid.
    """
    n = stroke_rad.size
    stroke, pitch = np.degrees(stroke_rad), np.degrees(pitch_rad)
    if rng is not None:
        noise = rng.standard_normal((n, 2)) * params.tracking_noise_deg_rms
        stroke, pitch = stroke + noise[:, 0], pitch + noise[:, 1]
    if params.frame_every > 1:
        return stroke, pitch, (first_index + np.arange(n)) % params.frame_every == 0
    return stroke, pitch, None
