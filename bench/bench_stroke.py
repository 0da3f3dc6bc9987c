"""Stroke-amplitude controller on the simulated robot:
settling (wingbeats) and steady error (deg), from the bags.

Run: python bench/bench_stroke.py [--json out.json]

Each of config/sweeps.yaml's stroke experiments (setpoint step 15 -> 20 deg, 30 % inertia loss,
obstacle at 13 deg) in both modes (dsa: gain mu; sync: drive amplitude at 140 Hz) runs as the
lockstep loop of the cores, is recorded as a bag and analysed from it. Targets: settle within
20 wingbeats (every later wingbeat within settle_band_deg of the setpoint), steady error
<= 0.5 deg. Baseline, same run: the same experiment with the feed-forward alone (the loop's
integral gain 1e-9: the designed command, never corrected).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from benchlib import REPO_ROOT, compare, print_table, write_json
from flaair_analysis import wingbeat
from flaair_model.config import config_dir, load_yaml, node_parameters
from flaair_model.model_io import load_model
from flaair_tools.sweeps import stroke_experiments as se


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--json", type=Path, default=REPO_ROOT / "out" / "bench" / "bench_stroke.json"
    )
    args = parser.parse_args()
    section = load_yaml(config_dir() / "sweeps.yaml")["stroke_experiments"]
    values = node_parameters("flaair.yaml", "stroke_controller_node")
    frontend = node_parameters("flaair.yaml", "frontend_node")
    model = load_model()
    beats = wingbeat.WingbeatParams(
        float(values["sample_rate_hz"]),
        values["crossing_hysteresis_deg"],
        values["min_wingbeat_hz"],
        values["max_wingbeat_hz"],
    )
    band, steady = float(section["settle_band_deg"]), int(section["steady_wingbeats"])
    figures = []
    with tempfile.TemporaryDirectory() as tmp:
        for exp in se.experiments_from_config(section):
            result = {}
            for label, v in (
                ("loop", values),
                ("feed-forward", {**values, "error_fraction_per_wingbeat": 1e-9}),
            ):
                bag = Path(tmp) / f"{exp.name}_{label}"
                se.write_bag(bag, exp, se.run_closed_loop(exp, model, v, frontend))
                result[label] = se.analyse_bag(bag, band, steady, beats)["estimate"]
            loop, ff = result["loop"], result["feed-forward"]
            settle = loop["settling_wingbeats"]
            ff_text = (
                f"feed-forward only: error {ff['steady_error_deg']:+.2f} deg, "
                f"settles {ff['settling_wingbeats']}"
            )
            figures.append(
                compare(
                    f"{exp.name}: settling",
                    float("nan") if settle is None else settle,
                    "wingbeats",
                    "<=",
                    20,
                    ff_text,
                )
            )
            figures.append(
                compare(
                    f"{exp.name}: steady error",
                    abs(loop["steady_error_deg"]),
                    "deg",
                    "<=",
                    0.5,
                    f"error {loop['steady_error_deg']:+.3g} deg at "
                    f"{loop['steady_frequency_hz']:.1f} Hz",
                )
            )
    print_table(figures)
    write_json(figures, args.json)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
