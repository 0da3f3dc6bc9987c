"""`flaair multisine analyze RUN... --out DIR`: the best linear approximation, its noise, and the
odd and even nonlinear distortion of each channel, from one run per realization of an odd
random-phase multisine; with --model, the distortion the model does not predict.

RUN is a measured-run CSV (../shared/measured-run-format.md; drive_v the multisine as logged,
from the first sample of its realization) or a bag directory (each marked run one realization,
as `flaair experiment multisine` records it). Without --design the period, the excited lines and
the transient periods are found from the drive and the sensors.

Writes DIR/nonlinearity.json (strict JSON: the design, per channel the BLA with std_noise and
std_nl, levels_db, class, and with --model the model's figures and `disagrees`), one figure per
channel (figure_<channel>.png) and DIR/report.html. ../shared/multisine.md defines every field;
docs/MULTISINE.md shows how to read them.

Exit status: 0 written; 2 on bad input: one line naming the file and what is wrong, nothing
written (DIR not made).

Examples
--------
  bin/flaair multisine analyze examples/multisine/runs/realization_*.csv --out out/ms
  bin/flaair multisine analyze bags/multisine --model config/model.yaml --out out/ms_bag
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from flaair_analysis.multisine.analysis import (
    CHANNEL_UNITS,
    MultisineInputError,
    RunInput,
    analyse,
    model_columns,
)
from flaair_analysis.multisine.design import DesignError
from flaair_common.cli_help import HelpFormatter
from flaair_common.outputs import OutputError, check_output, write_outputs
from flaair_common.runcsv import RunFileError, read_run
from flaair_common.strictjson import json_safe
from flaair_model.config import ConfigError
from flaair_model.model_io import load_model
from flaair_model.schema import ParameterError
from flaair_model.settings import node_section
from flaair_model.validation import ModelError
from flaair_sim.plant_io import PLANT_PARAMS
from flaair_tools import bagio
from flaair_tools.bagio.runs import load_runs

from .design_file import read_design
from .report import figure_file, write_report

PROG = "flaair multisine analyze"
REQUIRED = ("time_s", "drive_v", "stroke_sensor_v", "pitch_sensor_v")
OUTPUT_FILES = ("nonlinearity.json", "report.html", *(figure_file(c) for c in CHANNEL_UNITS))


def read_runs(paths: Sequence[Path]) -> list[RunInput]:
    """Each CSV a run; each bag directory its marked runs (or one run)."""
    runs: list[RunInput] = []
    for path in paths:
        if path.is_dir():
            for run in load_runs([path], need_truth=False):
                runs.append(RunInput(f"{path}:{run.name}", run.sample_rate_hz, run.columns))
        else:
            got = read_run(path, required=REQUIRED)
            runs.append(RunInput(str(path), got.sample_rate_hz, got.columns))
    return runs


def parser() -> argparse.ArgumentParser:
    """The command's options."""
    p = argparse.ArgumentParser(prog=PROG, description=__doc__, formatter_class=HelpFormatter)
    p.add_argument("runs", nargs="+", type=Path, help="one CSV (or bag) per realization")
    p.add_argument("--design", type=Path, default=None, help="multisine.yaml of the runs")
    p.add_argument("--model", type=Path, default=None, help="model YAML to compare against")
    p.add_argument("--out", type=Path, required=True, help="directory to create")
    p.add_argument("--force", action="store_true", help="write into an existing non-empty DIR")
    return p


def main(argv: list[str] | None = None) -> int:
    """`flaair multisine analyze`; returns the exit status."""
    args = parser().parse_args(argv)
    try:
        if args.out.is_dir() and any(args.out.iterdir()) and not args.force:
            raise OutputError(f"--out {args.out}: exists and is not empty (--force writes in it)")
        written = check_output(
            args.out, [*args.runs, args.design, args.model], args.force, OUTPUT_FILES
        )
        design = read_design(args.design) if args.design is not None else None
        model = None
        if args.model is not None:
            try:
                model = load_model(args.model)
            except (ModelError, ConfigError, OSError) as exc:
                raise ModelError(f"--model {args.model}: cannot be read: {exc}") from None
        runs = read_runs(args.runs)
        result = analyse(runs, design)  # refusals before the model is simulated
        if model is not None:
            limit = float(node_section(PLANT_PARAMS, "plant_node", "flaair.yaml")["drive_limit_v"])
            result = analyse(runs, design, model_columns(runs, model, limit))
    except (
        MultisineInputError,
        DesignError,
        RunFileError,
        OutputError,
        ModelError,
        ConfigError,
        ParameterError,
        bagio.BagError,
    ) as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return 2
    doc = {
        "design": result.doc["design"],
        "runs": [r.name for r in runs],
        "model": None if args.model is None else str(args.model),
        **{k: v for k, v in result.doc.items() if k != "design"},
    }
    doc = json_safe(doc)

    def write_files(stage: Path) -> None:
        (stage / "nonlinearity.json").write_text(
            json.dumps(doc, indent=1, allow_nan=False), encoding="utf-8"
        )
        write_report(doc, result.spectra, stage)

    if (failed := write_outputs(PROG, args.out, written, write_files)) is not None:
        return failed
    classes = ", ".join(f"{c} {e['class']}" for c, e in doc["channels"].items())
    print(f"{PROG}: {len(runs)} run(s), {classes} -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
