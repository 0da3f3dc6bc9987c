"""Figure of the sync -> async transition (paper Fig. asynch b): K_r, stroke, Hilbert frequency, amplitude.

Library: ``transition_record`` joins the echoed wing-state and controller-state messages,
``plot_transition`` draws the PNG (a matplotlib Figure, no pyplot).

Command line (inside the environment, e.g. ``scripts/in_env.sh python -m flaair_tools.transition_figure``):

  --run             run the closed loop over DDS first (plant lockstep, front end, dSA controller
                    on a private ROS domain, localhost discovery), record /flaair/wing_state and
                    /flaair/controller/state with ``flaair topic echo``, then plot
  --wing-state F    JSON-lines echo of /flaair/wing_state (instead of --run)
  --controller-state F  JSON-lines echo of /flaair/controller/state
  -o PNG            output figure (default out/transition/transition.png; the records and a
                    JSON summary are written beside it)

Example: scripts/in_env.sh python -m flaair_tools.transition_figure --run --duration 2.0 \\
           --ramp-start 0.5 --ramp-duration 0.5
"""
from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable, NamedTuple, Sequence

import numpy as np

from flaair_common.graph import Graph, flaair_argv
from flaair_control.core import transition as tr
from flaair_control.transition_io import hilbert_params_from_config


class TransitionRecord(NamedTuple):
    """One closed-loop run: stroke (sensor estimate), K_r, and their times (signal time, s)."""

    time_s: np.ndarray
    stroke_deg: np.ndarray          # NaN where invalid or missing
    kr_time_s: np.ndarray
    kr: np.ndarray
    controller_frequency_hz: np.ndarray   # ControllerState.stroke_frequency_hz (crossing estimate)
    drive_v: np.ndarray                   # ControllerState.drive_v (last sample of each block)
    missing_blocks: int


def transition_record(wing_state: Sequence[dict], controller_state: Sequence[dict], sample_rate_hz: float) -> TransitionRecord:
    """Join echoed message dicts into a ``TransitionRecord``."""
    rec = tr.join_blocks(wing_state, ["stroke_deg"], sample_rate_hz, valid_field="stroke_valid")
    states = sorted(controller_state, key=tr.stamp_s)
    if not states:
        raise tr.TransitionError("no controller state messages")
    kr_t = np.array([tr.stamp_s(s) for s in states])
    return TransitionRecord(rec.time_s, rec.values["stroke_deg"], kr_t, np.array([s["k_r"] for s in states]),
                            np.array([s["stroke_frequency_hz"] for s in states]),
                            np.array([s["drive_v"] for s in states]), rec.missing_blocks)


def plot_transition(record: TransitionRecord, result: tr.HilbertResult, path: Path | str,
                    resonance_hz: float | None = None, predicted: tuple[float, float] | None = None,
                    title: str = "Synchronous to asynchronous transition (closed loop over DDS)") -> Path:
    """Four stacked panels like the paper's figure; returns the PNG path.

    ``predicted`` = (frequency_hz, amplitude_deg) of the describing-function limit cycle, drawn dashed.
    """
    from matplotlib.figure import Figure   # no pyplot: a notebook user's backend is left alone

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
    ax_f.plot(result.time_s, result.frequency_hz, color="C1", label="Hilbert (band-pass + Savitzky-Golay)")
    ax_f.set_ylabel("frequency (Hz)")
    ax_a.plot(result.time_s, result.amplitude, color="C2")
    ax_a.set_ylabel("amplitude (deg)")
    ax_a.set_xlabel("time (s)")
    if resonance_hz is not None:
        ax_f.axhline(resonance_hz, color="0.5", ls=":", label=f"stroke resonance {resonance_hz:g} Hz")
    if predicted is not None:
        ax_f.axhline(predicted[0], color="C3", ls="--", lw=0.8, label=f"limit cycle (theory) {predicted[0]:.1f} Hz")
        ax_a.axhline(predicted[1], color="C3", ls="--", lw=0.8, label=f"limit cycle (theory) {predicted[1]:.1f} deg")
        ax_a.legend(loc="lower right", fontsize=8)
    ax_f.legend(loc="lower right", fontsize=8)
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.suptitle(title, fontsize=10)
    fig.savefig(path, dpi=120)
    return path


# --------------------------------------------------------------------------- closed-loop experiment


def run_closed_loop(start: Callable[..., subprocess.Popen], duration_s: float, controller_args: Sequence[str] = (),
                    sample_rate_hz: float = 20000.0, block_size: int = 10, timeout_s: float = 600.0,
                    ) -> tuple[list[dict], list[dict]]:
    """Run plant (lockstep) + front end + dSA controller for ``duration_s`` of signal time.

    ``start(*flaair_args, stdout=...)`` starts ``bin/flaair <args>`` (tests pass
    ``rosproc.Processes.flaair``); the caller owns and stops the processes. Returns the echoed
    wing-state and controller-state dicts.
    """
    n_blocks = int(round(duration_s * sample_rate_hz / block_size))
    with tempfile.TemporaryDirectory() as tmp:
        ws_path, cs_path = Path(tmp) / "ws.jsonl", Path(tmp) / "cs.jsonl"
        with open(ws_path, "w") as ws_file, open(cs_path, "w") as cs_file:
            echo_ws = start("topic", "echo", "/flaair/wing_state", "flaair_msgs/msg/WingStateBlock",
                            "--count", str(n_blocks), "--timeout", str(timeout_s), stdout=ws_file)
            echo_cs = start("topic", "echo", "/flaair/controller/state", "flaair_msgs/msg/ControllerState",
                            "--count", str(n_blocks), "--timeout", str(timeout_s), stdout=cs_file)
            start("run", "flaair_sim", "plant_node", "--ros-args", "-p", "mode:=lockstep")
            start("run", "flaair_sensors", "frontend_node")
            start("run", "flaair_control", "dsa_controller_node", "--ros-args",
                  "-p", f"run_time_s:={duration_s + 4 * block_size / sample_rate_hz}", *controller_args)
            echo_ws.wait(timeout=timeout_s + 30)
            try:   # the states come with the blocks; under load a few may still be in flight
                echo_cs.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(echo_cs.pid, signal.SIGINT)
                echo_cs.wait(timeout=10)
        wing_state = [json.loads(line) for line in ws_path.read_text().splitlines() if line]
        controller_state = [json.loads(line) for line in cs_path.read_text().splitlines() if line]
    return wing_state, controller_state


def predicted_limit_cycle(controller: dict, sample_rate_hz: float = 20000.0, block_size: int = 10) -> tuple[float, float]:
    """Describing-function limit cycle (Hz, deg) of the configured loop (flaair_control.core.hopf)."""
    from flaair_control.core import dsa, hopf
    from flaair_model.model_io import load_model

    from flaair_sensors.frontend_io import velocity_delay_s

    model = load_model(controller.get("model_file") or None)
    lin = hopf.LinearStrokePlant(model.plant.stroke_inertia_kg_m2, model.plant.stroke_stiffness_nm_per_rad)
    fc = controller["compensation_frequency_hz"]
    vdel = controller["velocity_delay_s"] if controller["velocity_delay_s"] >= 0 else velocity_delay_s(fc)
    delay = dsa.loop_delay_s(block_size * controller["blocks_in_flight"], sample_rate_hz, vdel * sample_rate_hz)
    lc = hopf.limit_cycle(lin, model.plant.aero_damping_nm_s2, controller["r3_rad_s"], controller["kappa"],
                          controller["mu_nm_s_per_rad"], delay, delay if controller["compensate_delay"] else 0.0,
                          2 * math.pi * fc)
    return lc.frequency_hz, math.degrees(lc.amplitude_rad)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="transition_figure", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", action="store_true", help="run the closed loop over DDS first")
    parser.add_argument("--duration", type=float, default=2.0, help="--run: signal time [s]")
    parser.add_argument("--ramp-start", type=float, default=0.5, help="--run: K_r ramp start [s]")
    parser.add_argument("--ramp-duration", type=float, default=0.5, help="--run: K_r ramp duration [s]")
    parser.add_argument("--wing-state", type=Path, help="echo of /flaair/wing_state (JSON lines)")
    parser.add_argument("--controller-state", type=Path, help="echo of /flaair/controller/state (JSON lines)")
    parser.add_argument("-o", "--output", type=Path, default=Path("out/transition/transition.png"))
    args = parser.parse_args(argv)
    from flaair_model.config import node_parameters
    from flaair_model.model_io import load_model

    shared = node_parameters("flaair.yaml", "dsa_controller_node")
    fs, block = float(shared["sample_rate_hz"]), int(shared["block_size"])
    if args.run:
        t0 = time.monotonic()
        # node logs beside the figure; the graph on a private domain, stopped on any exit
        with Graph(log_dir=args.output.parent) as graph:
            count = iter(range(1000))

            def start(*flaair_args: str, stdout=None) -> subprocess.Popen:
                name = flaair_args[2] if flaair_args[0] == "run" else f"echo{next(count)}"
                return graph.start(name, flaair_argv(*flaair_args), stdout=stdout)

            # watchdog 10 s: a shared, loaded machine can stall the lockstep loop for over a second
            # of wall-clock time, and a trip would end the experiment with a ramp-down
            ws, cs = run_closed_loop(start, args.duration, ["-p", f"kr_ramp_start_s:={args.ramp_start}",
                                                            "-p", f"kr_ramp_duration_s:={args.ramp_duration}",
                                                            "-p", "watchdog_timeout_s:=10.0"], fs, block)
        print(f"closed loop: {args.duration:g} s of signal in {time.monotonic() - t0:.1f} s wall")
        args.output.parent.mkdir(parents=True, exist_ok=True)
        (args.output.parent / "wing_state.jsonl").write_text("".join(json.dumps(m) + "\n" for m in ws))
        (args.output.parent / "controller_state.jsonl").write_text("".join(json.dumps(m) + "\n" for m in cs))
        controller = dict(shared, kr_ramp_start_s=args.ramp_start, kr_ramp_duration_s=args.ramp_duration)
    else:
        if not (args.wing_state and args.controller_state):
            parser.error("give --run or both --wing-state and --controller-state")
        ws = [json.loads(line) for line in args.wing_state.read_text().splitlines() if line]
        cs = [json.loads(line) for line in args.controller_state.read_text().splitlines() if line]
        controller = shared
    record = transition_record(ws, cs, fs)
    result = tr.hilbert_analysis(record.stroke_deg, fs, hilbert_params_from_config(), start_time_s=float(record.time_s[0]))
    f_n = load_model(controller.get("model_file") or None).plant.stroke_natural_frequency_hz
    predicted = predicted_limit_cycle(controller, fs, block)
    path = plot_transition(record, result, args.output, resonance_hz=f_n, predicted=predicted)
    end = float(record.time_s[-1])
    window = (end - 0.35, end - 0.05)   # settled part, clear of the filters' end transient
    f_end = tr.window_stats(result.time_s, result.frequency_hz, *window)
    a_end = tr.window_stats(result.time_s, result.amplitude, *window)
    summary = {"figure": str(path), "final_frequency_hz": f_end.mean, "final_frequency_std_hz": f_end.std,
               "final_amplitude_deg": a_end.mean, "final_amplitude_std_deg": a_end.std,
               "stroke_resonance_hz": f_n, "limit_cycle_theory_hz": predicted[0],
               "limit_cycle_theory_deg": predicted[1], "missing_blocks": record.missing_blocks}
    (path.parent / (path.stem + "_summary.json")).write_text(json.dumps(summary, indent=2))
    print(json.dumps(summary, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
