r"""Figure of the sync -> async transition (paper Fig.
asynch b): K_r, stroke, Hilbert frequency, amplitude.

Runs the closed loop and draws the figure; the record, the predicted limit cycle and the plot
are ``flaair_tools.analysis.transition``.

Command line (inside the environment, e.g. ``scripts/in_env.sh
python -m flaair_tools.orchestration.transition_figure``):

  --run             run the closed loop over DDS first (plant lockstep, front end, dSA controller
                    on a private ROS domain, localhost discovery), record /flaair/wing_state and
                    /flaair/controller/state with ``flaair topic echo``, then plot
  --wing-state F    JSON-lines echo of /flaair/wing_state (instead of --run)
  --controller-state F  JSON-lines echo of /flaair/controller/state
  -o PNG            output figure (default out/transition/transition.png; the records and a
                    JSON summary are written beside it)

Example: scripts/in_env.sh python -m
flaair_tools.orchestration.transition_figure --run --duration 2.0 \
           --ramp-start 0.5 --ramp-duration 0.5
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from flaair_common.cli_help import HelpFormatter
from flaair_common.graph import Graph, flaair_argv
from flaair_control.core import transition as tr
from flaair_control.transition_io import hilbert_params_from_config
from flaair_model import settings
from flaair_model.model_io import load_model
from flaair_tools.analysis.transition import (
    plot_transition,
    predicted_limit_cycle,
    transition_record,
)
from flaair_tools.orchestration.graphs import GRAPHS

# --------------------------------------------------------------------------- closed-loop experiment


def run_closed_loop(
    start: Callable[..., subprocess.Popen],
    duration_s: float,
    controller_args: Sequence[str] = (),
    sample_rate_hz: float = 20000.0,
    block_size: int = 10,
    timeout_s: float = 600.0,
) -> tuple[list[dict], list[dict]]:
    """Run the declared lockstep loop (plant, front end,
    dSA controller) for ``duration_s`` of signal time.

    ``start(*flaair_args, stdout=...)`` starts ``bin/flaair <args>`` (tests pass
    ``rosproc.Processes.flaair``); the caller owns and stops the processes. Returns the echoed
    wing-state and controller-state dicts.
    """
    n_blocks = round(duration_s * sample_rate_hz / block_size)
    with tempfile.TemporaryDirectory() as tmp:
        ws_path, cs_path = Path(tmp) / "ws.jsonl", Path(tmp) / "cs.jsonl"
        with open(ws_path, "w") as ws_file, open(cs_path, "w") as cs_file:
            echo_ws = start(
                "topic",
                "echo",
                "--json",
                "/flaair/wing_state",
                "flaair_msgs/msg/WingStateBlock",
                "--count",
                str(n_blocks),
                "--silence",
                str(timeout_s),
                stdout=ws_file,
            )
            echo_cs = start(
                "topic",
                "echo",
                "--json",
                "/flaair/controller/state",
                "flaair_msgs/msg/ControllerState",
                "--count",
                str(n_blocks),
                "--silence",
                str(timeout_s),
                stdout=cs_file,
            )
            loop = GRAPHS["lockstep_loop"]
            extra = {
                "controller": [
                    "-p",
                    f"run_time_s:={duration_s + 4 * block_size / sample_rate_hz}",
                    *controller_args,
                ]
            }
            for node in loop.nodes():
                declared = [
                    arg
                    for key, value in loop.parameters.get(node.role, {}).items()
                    for arg in ("-p", f"{key}:={value}")
                ]
                ros_args = [*declared, *extra.get(node.role, [])]
                start(
                    "run",
                    node.package,
                    node.executable,
                    *(["--ros-args", *ros_args] if ros_args else []),
                )
            echo_ws.wait(timeout=timeout_s + 30)
            try:  # the states come with the blocks; under load a few may still be in flight
                echo_cs.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(echo_cs.pid, signal.SIGINT)
                echo_cs.wait(timeout=10)
        wing_state = [json.loads(line) for line in ws_path.read_text().splitlines() if line]
        controller_state = [json.loads(line) for line in cs_path.read_text().splitlines() if line]
    return wing_state, controller_state


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="transition_figure",
        description=__doc__,
        formatter_class=HelpFormatter,
    )
    parser.add_argument("--run", action="store_true", help="run the closed loop over DDS first")
    parser.add_argument("--duration", type=float, default=2.0, help="--run: signal time [s]")
    parser.add_argument("--ramp-start", type=float, default=0.5, help="--run: K_r ramp start [s]")
    parser.add_argument(
        "--ramp-duration", type=float, default=0.5, help="--run: K_r ramp duration [s]"
    )
    parser.add_argument("--wing-state", type=Path, help="echo of /flaair/wing_state (JSON lines)")
    parser.add_argument(
        "--controller-state", type=Path, help="echo of /flaair/controller/state (JSON lines)"
    )
    parser.add_argument("-o", "--output", type=Path, default=Path("out/transition/transition.png"))
    args = parser.parse_args(argv)
    shared = settings.controller()
    fs, block = shared.sample_rate_hz, shared.block_size
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
            ws, cs = run_closed_loop(
                start,
                args.duration,
                [
                    "-p",
                    f"kr_ramp_start_s:={args.ramp_start}",
                    "-p",
                    f"kr_ramp_duration_s:={args.ramp_duration}",
                    "-p",
                    "watchdog_timeout_s:=10.0",
                ],
                fs,
                block,
            )
        print(f"closed loop: {args.duration:g} s of signal in {time.monotonic() - t0:.1f} s wall")
        args.output.parent.mkdir(parents=True, exist_ok=True)
        (args.output.parent / "wing_state.jsonl").write_text(
            "".join(json.dumps(m) + "\n" for m in ws)
        )
        (args.output.parent / "controller_state.jsonl").write_text(
            "".join(json.dumps(m) + "\n" for m in cs)
        )
        controller = dict(
            shared, kr_ramp_start_s=args.ramp_start, kr_ramp_duration_s=args.ramp_duration
        )
    else:
        if not (args.wing_state and args.controller_state):
            parser.error("give --run or both --wing-state and --controller-state")
        ws = [json.loads(line) for line in args.wing_state.read_text().splitlines() if line]
        cs = [json.loads(line) for line in args.controller_state.read_text().splitlines() if line]
        controller = shared
    record = transition_record(ws, cs, fs)
    result = tr.hilbert_analysis(
        record.stroke_deg, fs, hilbert_params_from_config(), start_time_s=float(record.time_s[0])
    )
    f_n = load_model(controller.get("model_file") or None).plant.stroke_natural_frequency_hz
    predicted = predicted_limit_cycle(controller, fs, block)
    path = plot_transition(record, result, args.output, resonance_hz=f_n, predicted=predicted)
    end = float(record.time_s[-1])
    window = (end - 0.35, end - 0.05)  # settled part, clear of the filters' end transient
    f_end = tr.window_stats(result.time_s, result.frequency_hz, *window)
    a_end = tr.window_stats(result.time_s, result.amplitude, *window)
    summary = {
        "figure": str(path),
        "final_frequency_hz": f_end.mean,
        "final_frequency_std_hz": f_end.std,
        "final_amplitude_deg": a_end.mean,
        "final_amplitude_std_deg": a_end.std,
        "stroke_resonance_hz": f_n,
        "limit_cycle_theory_hz": predicted[0],
        "limit_cycle_theory_deg": predicted[1],
        "missing_blocks": record.missing_blocks,
    }
    (path.parent / (path.stem + "_summary.json")).write_text(json.dumps(summary, indent=2))
    print(json.dumps(summary, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
