"""Regenerate the format examples (docs/formats/): a measured-run CSV and a sweep table.

Both come from the paper's bench robot (the project's simulated plant with 23 % strain
transfer on the hinge film, the robot of examples/lab_session):

- ``examples/runs/run01.csv``, ``run02.csv``: a 0.3 s 20-200 Hz chirp at 100 V and at 50 V
  logged at 10 kHz, the sensor voltages with the model's noise, the angles from a 2,000 fps
  video (every 5th sample, with tracking noise; empty cells between frames):
  docs/formats/MEASURED_RUN_CSV.md;
- ``examples/sweep_table/robot_sweep.csv``: steady sines at 3 drive levels x 12 frequencies,
  the stroke and pitch peak-to-peak amplitudes read as from video (reading noise, a third of the
  pitch cells not measured): docs/formats/SWEEP_TABLE.md.

Deterministic (seeded): running it again writes the same bytes
(tests/test_format_examples.py checks the shipped files against a fresh run).

Run: scripts/in_env.sh python scripts/make_format_examples.py [--out DIR]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

REPO_ROOT = Path(__file__).resolve().parents[1]

RUN_HZ, RUN_S, VIDEO_EVERY = 10000.0, 0.3, 5
RUNS = {"run01": (100.0, 1), "run02": (50.0, 2)}  # name: (drive amplitude [V], noise seed)
LEVELS_V = (30.0, 60.0, 90.0)
FREQUENCIES_HZ = tuple(float(f) for f in np.linspace(100.0, 210.0, 12))


def bench_model():
    """The paper's bench robot: nominal plant, 23 % strain transfer on the hinge film."""
    from flaair_model.model import with_effects
    from flaair_model.model_io import load_model

    return with_effects(
        load_model(), {"strain_transfer_loss": {"efficiency": 0.23, "channel": "pitch"}}
    )


def _cell(value: float, fmt: str) -> str:
    return format(value, fmt) if np.isfinite(value) else ""


def write_run_csv(path: Path, amplitude_v: float, seed: int) -> None:
    """A chirp run, as a lab's export: truth only on the video's frames."""
    from flaair_sim.core.drive import DriveParams, drive_record
    from flaair_sim.core.measured_run import synthesize_measured_run

    n = int(RUN_S * RUN_HZ)
    params = DriveParams(
        kind="chirp", amplitude_v=amplitude_v, start_hz=20.0, stop_hz=200.0, duration_s=RUN_S
    )
    drive = drive_record(params, RUN_HZ, n)
    run = synthesize_measured_run(drive, RUN_HZ, bench_model(), np.random.default_rng(seed))
    between = np.arange(n) % VIDEO_EVERY != 0
    for name in ("stroke_deg", "pitch_deg"):
        run[name] = np.where(between, np.nan, run[name])
    names = ("time_s", "drive_v", "stroke_sensor_v", "pitch_sensor_v", "stroke_deg", "pitch_deg")
    formats = (".6g", ".6g", ".7g", ".7g", ".5g", ".5g")
    lines = [",".join(names)]
    for i in range(n):
        lines.append(",".join(_cell(run[c][i], f) for c, f in zip(names, formats, strict=True)))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def write_sweep_table(path: Path) -> None:
    """Steady sines at 3 levels x 12 frequencies, read as from video."""
    from flaair_analysis.tables.datasets import simulated_table
    from flaair_model.settings import tables
    from flaair_tools.tables.table_io import write_table

    table = simulated_table(
        bench_model(),
        LEVELS_V,
        FREQUENCIES_HZ,
        tables(),
        np.random.default_rng(2),
        missing_pitch=0.33,
        name="robot_sweep",
    )
    write_table(
        table,
        path,
        "robot: bench robot (simulated), steady sines, peak to peak read from 2,000 fps video",
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--out", type=Path, default=REPO_ROOT / "examples", help="examples directory to write"
    )
    args = parser.parse_args(argv)
    (args.out / "runs").mkdir(parents=True, exist_ok=True)
    (args.out / "sweep_table").mkdir(parents=True, exist_ok=True)
    for name, (amplitude_v, seed) in RUNS.items():
        write_run_csv(args.out / "runs" / f"{name}.csv", amplitude_v, seed)
    write_sweep_table(args.out / "sweep_table" / "robot_sweep.csv")
    print(f"wrote {args.out / 'runs'}/run01.csv, run02.csv and {args.out / 'sweep_table'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
