"""`flaair calibrate`: fit each sensor's gain (deg/V) and lag against ground truth in bags.

Reads every run of the given bags (sensor voltages, drive and ground-truth angles), fits per
sensor the gain, polarity, offset and lag (flaair_sensors.core.calibration), and writes:
  DIR/calibration.yaml  loadable by the front end
                        (-p gains_from:=calibration -p calibration_file:=...)
  DIR/calibration.json  {"stroke": {"gain_deg_per_v", "lag_s", "amplitude_rmse_deg",
                        "phase_rmse_deg", ...}, "pitch": {...}} plus band-limited figures.
With several runs, gains and lags are fitted per run and combined (median); the spread is reported.

Example:
  bin/flaair calibrate out/demo/bags/characterization_chirp --out out/cal

Terms (V_HREF): docs/GLOSSARY.md.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import yaml

from flaair_common.cli_help import HelpFormatter
from flaair_common.outputs import OutputError, check_output, writing_outputs
from flaair_common.strictjson import json_safe
from flaair_model.model_io import load_model
from flaair_sensors.analysis_io import analysis_bands_from_config
from flaair_sensors.core.calibration import CalibrationError, calibrate
from flaair_tools import bagio
from flaair_tools.bagio.runs import load_runs

OUT_FILES = ("calibration.json", "calibration.yaml")
COMBINED_KEYS = (
    "gain_deg_per_v",
    "offset_v",
    "lag_s",
    "amplitude_rmse_deg",
    "phase_rmse_deg",
    "amplitude_rmse_band_deg",
)


def combine(per_run: list[dict]) -> dict:
    """One calibration from per-run fits: medians, the run-to-run spread, the per-run fits."""
    out: dict = {
        "reference_voltage_v": per_run[0]["reference_voltage_v"],
        "sample_rate_hz": per_run[0]["sample_rate_hz"],
    }
    for channel in ("stroke", "pitch"):
        fits = [r[channel] for r in per_run]
        polarities = {f["polarity"] for f in fits}
        if len(polarities) > 1:
            raise CalibrationError(
                f"{channel}: polarity differs between runs ({sorted(polarities)}): check the wiring"
            )
        merged = dict(fits[0])
        for key in COMBINED_KEYS:
            values = np.array([f[key] for f in fits], float)
            # a run without a figure (no valid window) does not vote
            values = values[np.isfinite(values)]
            merged[key] = float(np.median(values)) if values.size else None
            merged[f"{key}_spread"] = float(np.ptp(values)) if values.size else None
        out[channel] = merged
    return out


def _figure(value: float | None, fmt: str) -> str:
    return "n/a" if value is None else format(value, fmt)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="flaair calibrate",
        description=__doc__,
        formatter_class=HelpFormatter,
    )
    parser.add_argument(
        "bags",
        nargs="+",
        type=Path,
        help="bags with /flaair/sensor_v, /flaair/drive, /flaair/wing_state/truth",
    )
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument("--force", action="store_true", help="replace existing outputs in --out")
    parser.add_argument(
        "--model",
        type=Path,
        default=None,
        help="model YAML for V_HREF (default: config/model.yaml)",
    )
    parser.add_argument(
        "--band-hz",
        type=float,
        nargs=2,
        default=None,
        metavar=("LOW", "HIGH"),
        help="band of the band-limited amplitude RMSE (default: config/flaair.yaml "
        "analyze.amplitude_band_hz, the stroke-to-pitch resonance band)",
    )
    args = parser.parse_args(argv)
    try:
        written = check_output(args.out, [*args.bags, args.model], args.force, OUT_FILES)
        band_hz = (
            tuple(args.band_hz) if args.band_hz else analysis_bands_from_config().amplitude_band_hz
        )
        reference_v = load_model(args.model).sensors.reference_voltage_v
        runs = load_runs(args.bags)
        per_run = []
        for run in runs:
            try:
                per_run.append(
                    calibrate(
                        run.columns,
                        reference_v,
                        sample_rate_hz=run.sample_rate_hz,
                        amplitude_band_hz=band_hz,
                    )
                )
            except CalibrationError as exc:
                raise CalibrationError(f"{run.bag}, run '{run.name}': {exc}") from None
        result = combine(per_run)
    except (bagio.BagError, CalibrationError, ValueError, OSError) as exc:
        print(f"flaair calibrate: {exc}", file=sys.stderr)
        return 2
    result["runs"] = [
        {"bag": r.bag, "run": r.name, **{c: fit[c] for c in ("stroke", "pitch")}}
        for r, fit in zip(runs, per_run, strict=True)
    ]
    loadable = {"reference_voltage_v": result["reference_voltage_v"]}
    for channel in ("stroke", "pitch"):
        loadable[channel] = {
            k: result[channel][k] for k in ("gain_deg_per_v", "polarity", "offset_v", "lag_s")
        }
    try:
        with writing_outputs(args.out, written) as stage:
            (stage / "calibration.json").write_text(
                json.dumps(json_safe(result), indent=2, allow_nan=False)
            )
            (stage / "calibration.yaml").write_text(
                "# FLAAIR sensor calibration (bin/flaair "
                "calibrate); load with the front end's\n# -p "
                "gains_from:=calibration -p calibration_file:=<this "
                "file>\n" + yaml.safe_dump(loadable, sort_keys=False)
            )
    except OutputError as exc:
        print(f"flaair calibrate: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("flaair calibrate: interrupted; nothing written", file=sys.stderr)
        return 130
    for channel in ("stroke", "pitch"):
        c = result[channel]
        print(
            f"{channel:6s} gain {c['gain_deg_per_v']:8.3f} deg/V  polarity {c['polarity']:+d}  "
            f"lag {c['lag_s'] * 1e3:7.4f} ms  amplitude RMSE "
            f"{_figure(c['amplitude_rmse_deg'], '.3f')} deg  phase RMSE "
            f"{_figure(c['phase_rmse_deg'], '.2f')} deg"
        )
        if c["amplitude_rmse_deg"] is None:
            print(
                f"flaair calibrate: warning: {channel}: no window had enough ground truth for "
                "the RMSE figures",
                file=sys.stderr,
            )
    print(
        f"wrote {args.out / 'calibration.yaml'} and {args.out / 'calibration.json'} ({len(runs)} "
        "run(s))"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
