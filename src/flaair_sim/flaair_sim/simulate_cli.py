"""`flaair simulate`: replay a measured run's drive through the model.

Reads time_s and drive_v from a CSV in the measured-run format (docs/LAB_CSV_FORMAT.md;
other columns are ignored), simulates the model (config/model.yaml or --model, effects
included) and writes the same format with simulated sensor voltages and angles.
With --noise the output carries the model's sensor and video-tracking noise, like a bench run.
A drive beyond the actuator's safe range (drive_limit_v, config/flaair.yaml) is clamped to it,
as the plant node does, with a warning. Bad input gets a one-line error and exit 2.

Example:
  bin/flaair simulate bench/run01.csv --model out/discrepancy/model.yaml --out sim/run01.csv
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from flaair_common.cli_help import HelpFormatter
from flaair_common.outputs import OutputError, check_output, writing_outputs
from flaair_common.runcsv import RunFileError, read_run, write_run
from flaair_model.config import ConfigError
from flaair_model.model_io import load_model
from flaair_model.schema import ParameterError
from flaair_model.settings import node_section
from flaair_model.validation import ModelError
from flaair_sim.core.measured_run import synthesize_measured_run
from flaair_sim.core.plant import simulate
from flaair_sim.plant_io import PLANT_PARAMS

CONFIG_FILE = "flaair.yaml"
LIMIT_SECTION = "plant_node"  # the plant clamps its drive to this section's drive_limit_v


def clamp_drive(drive_v: np.ndarray, limit_v: float) -> tuple[np.ndarray, int]:
    """The drive clamped to +-limit_v and how many samples were beyond it."""
    over = int(np.count_nonzero(np.abs(drive_v) > limit_v))
    return np.clip(drive_v, -limit_v, limit_v), over


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="flaair simulate",
        description=__doc__,
        formatter_class=HelpFormatter,
    )
    parser.add_argument("input", type=Path, help="measured-run CSV with time_s and drive_v")
    parser.add_argument(
        "--model", type=Path, default=None, help="model YAML (default: config/model.yaml)"
    )
    parser.add_argument(
        "--noise", action="store_true", help="add sensor and tracking noise (model's noise section)"
    )
    parser.add_argument("--seed", type=int, default=0, help="noise seed")
    parser.add_argument("--out", type=Path, required=True, help="output CSV (never an input)")
    parser.add_argument("--force", action="store_true", help="replace an existing --out")
    parser.add_argument(
        "--drive-limit-v",
        type=float,
        default=None,
        help="actuator safe range: drive clamped to +-this [V] (default: "
        f"{LIMIT_SECTION}.drive_limit_v "
        f"in config/{CONFIG_FILE})",
    )
    args = parser.parse_args(argv)
    try:
        written = check_output(args.out, [args.input, args.model], args.force)
        limit_v = args.drive_limit_v
        if limit_v is None:
            limit_v = float(node_section(PLANT_PARAMS, LIMIT_SECTION, CONFIG_FILE)["drive_limit_v"])
        if not (np.isfinite(limit_v) and limit_v > 0):
            raise ModelError(f"drive_limit_v must be a finite voltage > 0, got {limit_v}")
        run = read_run(args.input, required=("time_s", "drive_v"))
        model = load_model(args.model)
    except (
        RunFileError,
        ModelError,
        ConfigError,
        ParameterError,
        OutputError,
        OSError,
        KeyError,
    ) as exc:
        print(f"flaair simulate: {exc}", file=sys.stderr)
        return 2
    drive_v, over = clamp_drive(run["drive_v"], limit_v)
    fs_hz = run.sample_rate_hz
    if over:
        print(
            f"flaair simulate: warning: {args.input}: {over} drive_v sample(s) beyond the "
            f"actuator's safe range, up to {np.abs(run['drive_v']).max():.4g} V; clamped to "
            f"+-{limit_v:g} V (drive_limit_v)",
            file=sys.stderr,
        )
    try:
        if args.noise:
            columns = synthesize_measured_run(
                drive_v, fs_hz, model, np.random.default_rng(args.seed)
            )
        else:
            out = simulate(drive_v, fs_hz, model)
            columns = {
                "drive_v": drive_v,
                "stroke_sensor_v": out.stroke_sensor_v,
                "pitch_sensor_v": out.pitch_sensor_v,
                "stroke_deg": np.degrees(out.stroke_rad),
                "pitch_deg": np.degrees(out.pitch_rad),
            }
    except (ModelError, ValueError) as exc:
        where = args.model or "config/model.yaml"
        # the plant's own text blames the drive
        detail = f": {exc}" if isinstance(exc, ModelError) else ""
        print(
            f"flaair simulate: {where}: the model makes the plant diverge with a drive within "
            f"+-{limit_v:g} V (the model's parameters are at fault, not the drive){detail}",
            file=sys.stderr,
        )
        return 2
    if not all(np.isfinite(values).all() for values in columns.values()):
        print(
            f"flaair simulate: {args.model or 'config/model.yaml'}: the simulation produced "
            f"non-finite values with a drive within +-{limit_v:g} V: the model is at fault",
            file=sys.stderr,
        )
        return 2
    columns["time_s"] = run["time_s"]
    try:
        with writing_outputs(args.out, written) as stage:
            write_run(stage, columns)
    except OutputError as exc:
        print(f"flaair simulate: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("flaair simulate: interrupted; nothing written", file=sys.stderr)
        return 130
    print(f"flaair simulate: {len(drive_v)} samples at {fs_hz:g} Hz -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
