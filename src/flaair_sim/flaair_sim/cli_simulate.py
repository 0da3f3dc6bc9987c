"""`flaair simulate`: replay a measured run's drive through the model.

Reads time_s and drive_v from a CSV in the measured-run format (docs/LAB_CSV_FORMAT.md;
other columns are ignored), simulates the model (config/model.yaml or --model, effects
included) and writes the same format with simulated sensor voltages and angles.
With --noise the output carries the model's sensor and video-tracking noise, like a bench run.

Example:
  bin/flaair simulate bench/run01.csv --model out/discrepancy/model.yaml --out sim/run01.csv
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from flaair_common.runcsv import RunFileError, read_run, write_run
from flaair_model.model import ModelError
from flaair_model.model_io import load_model
from flaair_sim.plant import simulate, synthesize_measured_run


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="flaair simulate", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("input", type=Path, help="measured-run CSV with time_s and drive_v")
    parser.add_argument("--model", type=Path, default=None, help="model YAML (default: config/model.yaml)")
    parser.add_argument("--noise", action="store_true", help="add sensor and tracking noise (model's noise section)")
    parser.add_argument("--seed", type=int, default=0, help="noise seed")
    parser.add_argument("--out", type=Path, required=True, help="output CSV")
    args = parser.parse_args(argv)
    try:
        run = read_run(args.input, required=("time_s", "drive_v"))
        model = load_model(args.model)
    except (RunFileError, ModelError, OSError) as exc:
        print(f"flaair simulate: {exc}", file=sys.stderr)
        return 2
    drive_v, fs_hz = run["drive_v"], run.sample_rate_hz
    if args.noise:
        columns = synthesize_measured_run(drive_v, fs_hz, model, np.random.default_rng(args.seed))
    else:
        out = simulate(drive_v, fs_hz, model)
        columns = {
            "drive_v": drive_v, "stroke_sensor_v": out.stroke_sensor_v, "pitch_sensor_v": out.pitch_sensor_v,
            "stroke_deg": np.degrees(out.stroke_rad), "pitch_deg": np.degrees(out.pitch_rad),
        }
    columns["time_s"] = run["time_s"]
    write_run(args.out, columns)
    print(f"flaair simulate: {len(drive_v)} samples at {fs_hz:g} Hz -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
