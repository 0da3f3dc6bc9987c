"""The sync -> async transition (paper Fig. asynch b)
from a closed-loop run: record, limit cycle, figure.

``transition_record`` joins the echoed wing-state and controller-state messages,
``predicted_limit_cycle`` gives the describing-function limit cycle of the configured loop, and
``plot_transition`` draws the PNG (a matplotlib Figure, no pyplot). The run itself is
``flaair_tools.orchestration.transition_figure``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np

from flaair_control.core import dsa, hopf
from flaair_control.core import transition as tr
from flaair_model.model_io import load_model
from flaair_sensors.frontend_io import velocity_delay_s

__all__ = ["TransitionRecord", "plot_transition", "predicted_limit_cycle", "transition_record"]


class TransitionRecord(NamedTuple):
    """One closed-loop run: stroke (sensor estimate), K_r, and their times (signal time, s)."""

    time_s: np.ndarray
    stroke_deg: np.ndarray  # NaN where invalid or missing
    kr_time_s: np.ndarray
    kr: np.ndarray
    controller_frequency_hz: np.ndarray  # ControllerState.stroke_frequency_hz (crossing estimate)
    drive_v: np.ndarray  # ControllerState.drive_v (last sample of each block)
    missing_blocks: int


def transition_record(
    wing_state: Sequence[dict], controller_state: Sequence[dict], sample_rate_hz: float
) -> TransitionRecord:
    """Join echoed message dicts into a ``TransitionRecord``."""
    rec = tr.join_blocks(wing_state, ["stroke_deg"], sample_rate_hz, valid_field="stroke_valid")
    states = sorted(controller_state, key=tr.stamp_s)
    if not states:
        raise tr.TransitionError("no controller state messages")
    kr_t = np.array([tr.stamp_s(s) for s in states])
    return TransitionRecord(
        rec.time_s,
        rec.values["stroke_deg"],
        kr_t,
        np.array([s["k_r"] for s in states]),
        np.array([s["stroke_frequency_hz"] for s in states]),
        np.array([s["drive_v"] for s in states]),
        rec.missing_blocks,
    )


def plot_transition(
    record: TransitionRecord,
    result: tr.HilbertResult,
    path: Path | str,
    resonance_hz: float | None = None,
    predicted: tuple[float, float] | None = None,
    title: str = "Synchronous to asynchronous transition (closed loop over DDS)",
) -> Path:
    """Four stacked panels like the paper's figure; returns the PNG path.

    ``predicted`` = (frequency_hz, amplitude_deg) of
    the describing-function limit cycle, drawn dashed.
    """
    # deferred: matplotlib (0.7 s); `analyze` imports this module, and its --help draws nothing
    from matplotlib.figure import Figure  # no pyplot: a notebook user's backend is left alone

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig = Figure(figsize=(7.0, 8.0), constrained_layout=True)
    axes = fig.subplots(4, 1, sharex=True)
    ax_kr, ax_s, ax_f, ax_a = axes
    ax_kr.plot(record.kr_time_s, record.kr, color="k")
    ax_kr.set_ylabel("$K_r$")
    ax_kr.set_ylim(-0.05, 1.05)
    ax_s.plot(record.time_s, record.stroke_deg, lw=0.6, color="C0")
    ax_s.set_ylabel("stroke (deg)")
    ax_f.plot(
        result.time_s, result.frequency_hz, color="C1", label="Hilbert (band-pass + Savitzky-Golay)"
    )
    ax_f.set_ylabel("frequency (Hz)")
    ax_a.plot(result.time_s, result.amplitude, color="C2")
    ax_a.set_ylabel("amplitude (deg)")
    ax_a.set_xlabel("time (s)")
    if resonance_hz is not None:
        ax_f.axhline(
            resonance_hz, color="0.5", ls=":", label=f"stroke resonance {resonance_hz:g} Hz"
        )
    if predicted is not None:
        ax_f.axhline(
            predicted[0],
            color="C3",
            ls="--",
            lw=0.8,
            label=f"limit cycle (theory) {predicted[0]:.1f} Hz",
        )
        ax_a.axhline(
            predicted[1],
            color="C3",
            ls="--",
            lw=0.8,
            label=f"limit cycle (theory) {predicted[1]:.1f} deg",
        )
        ax_a.legend(loc="lower right", fontsize=8)
    ax_f.legend(loc="lower right", fontsize=8)
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.suptitle(title, fontsize=10)
    fig.savefig(path, dpi=120)
    return path


def predicted_limit_cycle(
    controller: dict, sample_rate_hz: float = 20000.0, block_size: int = 10
) -> tuple[float, float]:
    """Describing-function limit cycle (Hz, deg) of
    the configured loop (flaair_control.core.hopf).
    """
    model = load_model(controller.get("model_file") or None)
    lin = hopf.LinearStrokePlant(
        model.plant.stroke_inertia_kg_m2, model.plant.stroke_stiffness_nm_per_rad
    )
    fc = controller["compensation_frequency_hz"]
    vdel = (
        controller["velocity_delay_s"]
        if controller["velocity_delay_s"] >= 0
        else velocity_delay_s(fc)
    )
    delay = dsa.loop_delay_s(
        block_size * controller["blocks_in_flight"], sample_rate_hz, vdel * sample_rate_hz
    )
    lc = hopf.limit_cycle(
        lin,
        model.plant.aero_damping_nm_s2,
        controller["r3_rad_s"],
        controller["kappa"],
        controller["mu_nm_s_per_rad"],
        delay,
        delay if controller["compensate_delay"] else 0.0,
        2 * math.pi * fc,
    )
    return lc.frequency_hz, math.degrees(lc.amplitude_rad)
