"""`flaair discrepancy`: find where the model and the measurement disagree, and fix the model.

Inputs are measured-run CSV files (docs/formats/MEASURED_RUN_CSV.md), bags (runs marked on
/flaair/run_marker; topics /flaair/sensor_v, /flaair/drive, /flaair/wing_state/truth) and
frequency-response tables (docs/TABLES.md), in any mix, told apart by their content (a CSV whose
header names frequency_hz and no time_s is a table; --table TABLE.csv names one; runs whose drive
is a periodic odd multisine are a multisine set, read as line spectra: docs/MULTISINE.md). First
this robot's own plant parameters are fitted (as `flaair identify` does: natural frequencies,
damping, actuator gain, couplings); then every run is simulated with its recorded drive from
its measured initial state and compared on stroke_deg, pitch_deg, stroke_sensor_v and
pitch_sensor_v; the missing effects are named from the model's vocabulary, fitted jointly with
the plant parameters they trade off against, checked on held-out runs and added to the model.
Parameter drift alone is not missing physics: it ends `no_discrepancy`, with the refitted
parameters in model.yaml and under `plant_parameters` in discrepancy.json.

Writes into --out DIR:
  model.yaml         the input model with this robot's plant parameters and the found effects
                     (bin/flaair simulate --model accepts it)
  discrepancy.json   status, effects (name, channel, parameters, evidence), gap_before/gap_after
  report.html        gap per channel, where the model disagrees, search log, decision rules, figures

--validate runs the workflow on the project's hidden-effect datasets (a few minutes) and writes
validation.json/validation.html with the confusion table (true vs found); with inputs as well,
the table is embedded in report.html (--validation FILE embeds a saved one).

Exit status: 0 when the analysis ran (whatever the status), 2 on bad input.

Examples
--------
  bin/flaair discrepancy lab/chirp_full.csv lab/chirp_half.csv lab/stepped.csv --out out/discrepancy
  bin/flaair discrepancy bags/robot1 --model config/model.yaml --out out/discrepancy
  bin/flaair discrepancy --validate --out out/discrepancy-validation
  bin/flaair discrepancy lab/robot3_sweep.csv --out out/robot3  (a lab's table,
                     docs/TABLES.md)
  bin/flaair discrepancy lab/chirp_full.csv lab/robot3_sweep.csv --out out/joint
                     (runs and a table of the same robot together, docs/TABLES.md)

Terms (gap, held-out, vocabulary, discovered): docs/GLOSSARY.md.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from tqdm import tqdm

from flaair_analysis.discrepancy.datasets import dataset_cases, make_runs
from flaair_analysis.discrepancy.runs import Run
from flaair_analysis.discrepancy.scoring import confusion_table, score_case
from flaair_analysis.discrepancy.workflow import analyse, format_parameters
from flaair_analysis.tables.joint_workflow import JointDiscrepancy, analyse_evidence
from flaair_analysis.tables.workflow import TableDiscrepancy
from flaair_common.cli_help import HelpFormatter
from flaair_common.outputs import check_output, write_outputs
from flaair_common.strictjson import json_safe
from flaair_model import settings as config
from flaair_model.model import Model
from flaair_model.model_io import load_model, save_model
from flaair_model.settings import DiscrepancySettings, node_section
from flaair_sim.plant_io import PLANT_PARAMS
from flaair_tools.tables.report import write_report as write_table_report

from .evidence_inputs import CommandInputs, evidence_arguments, run_command
from .identify import print_fit
from .report import write_report, write_validation
from .run_inputs import InputError, bad_input_errors, sort_inputs
from .validation_file import read_validation

PROG = "flaair discrepancy"
USAGE = (
    "flaair discrepancy [INPUT ...] --out DIR [--model FILE] [--force]\n"
    "       [--validate [--cases NAME ...]] [--validation FILE]\n"
    "       (INPUT: a measured-run CSV, a bag, a frequency-response table or a multisine\n"
    "       set's runs, any mix; or --validate alone)"
)
VALIDATION_FILES = ("validation.json", "validation.html")
REPORT_FILES = ("model.yaml", "discrepancy.json", "report.html")
TABLE_FIGURES = ("table_response.png",)


def run_validation(
    model: Model, names: Sequence[str] | None, settings: DiscrepancySettings
) -> dict:
    """Run the workflow on the hidden-effect dataset cases; returns the validation document."""
    cases = [c for c in dataset_cases() if not names or c.name in names]
    unknown = sorted(set(names or ()) - {c.name for c in dataset_cases()})
    if unknown:
        raise InputError(f"unknown dataset case(s) {', '.join(unknown)}")
    outcomes = []
    start = time.perf_counter()
    for case in tqdm(cases, desc="validation cases", unit="case", file=sys.stderr):
        runs = make_runs(case, model)
        t0 = time.perf_counter()
        result = analyse(runs, model, settings)
        outcomes.append(score_case(case, result, time.perf_counter() - t0))
    table = confusion_table(outcomes)
    return {
        "confusion": table,
        "cases": [o.as_dict() for o in outcomes],
        "total_s": time.perf_counter() - start,
    }


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG, usage=USAGE, description=__doc__, formatter_class=HelpFormatter
    )
    evidence_arguments(parser, " (optional with --validate)")
    parser.add_argument(
        "--validate", action="store_true", help="also run the hidden-effect dataset cases"
    )
    parser.add_argument(
        "--cases", nargs="+", default=None, help="with --validate: only these case names"
    )
    parser.add_argument(
        "--validation", type=Path, default=None, help="embed a saved validation.json in report.html"
    )
    return parser


def main(argv: list[str] | None = None) -> int:
    """`flaair discrepancy INPUT... [--model FILE] --out DIR`; returns the exit status."""
    args = _parser().parse_args(argv)
    inputs = sort_inputs(args.inputs, args.table)
    args.inputs, args.table, args.others = inputs.runs, inputs.tables, inputs.others
    if args.table and args.validate:
        print(f"{PROG}: {_VALIDATE_ON_RUNS}, not with a table", file=sys.stderr)
        return 2
    if args.inputs or args.table or args.others:
        return _discrepancy(args)
    if not args.validate:
        print(f"{PROG}: give measured-run CSV files or bags (or --validate)", file=sys.stderr)
        return 2
    return _validation_only(args)


_VALIDATE_ON_RUNS = "--validate runs the hidden-effect cases on runs"


def _discrepancy(args: argparse.Namespace) -> int:
    """The workflow on the inputs, whatever their mix (`analyse_evidence`), and with --validate
    the hidden-effect cases; the exit status.
    """
    table_alone = bool(args.table) and not args.inputs
    files = REPORT_FILES + (TABLE_FIGURES if table_alone else ())
    files += VALIDATION_FILES if args.validate else ()
    try:  # everything checked before anything is computed
        settings = config.discrepancy()
        drive_limit_v = float(
            node_section(PLANT_PARAMS, "plant_node", "flaair.yaml")["drive_limit_v"]
        )
        saved = read_validation(args.validation) if args.validation else None
    except bad_input_errors() as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return 2

    def compute(i: CommandInputs, progress: Callable[[str], None]) -> tuple[Any, dict | None]:
        if args.validate and i.spectra is not None:
            raise InputError(f"{_VALIDATE_ON_RUNS}, not with a multisine set")
        validation = saved
        if args.validate:
            progress("validation cases")
            validation = run_validation(i.model, args.cases, settings)
        result = analyse_evidence(
            i.runs,
            i.table,
            i.model,
            i.s,
            settings,
            progress,
            spectra=i.spectra,
            search_runs=i.searched,
            drive_limit_v=drive_limit_v,
            extra=i.extra,
        )
        return result, validation

    done = run_command(PROG, args, files, compute, protected=[args.validation])
    if isinstance(done, int):
        return done
    written, inputs, (result, validation), elapsed = done
    model_path = args.out / "model.yaml"
    docs: list[dict] = []

    def write_files(stage: Path) -> None:
        if args.validate and validation is not None:
            _write_validation(stage, validation)
        save_model(result.model_out, stage / "model.yaml")
        if isinstance(result, TableDiscrepancy):
            assert inputs.table is not None
            docs.append(write_table_report(result, inputs.table, inputs.s, stage))
        elif isinstance(result, JointDiscrepancy):
            report_runs = list(result.joint.runs) or inputs.searched
            joint = json_safe(result.as_dict())
            doc = write_report(
                stage, report_runs, result.runs_result, str(model_path), settings, joint=joint
            )
            doc["status"] = result.status
            doc["joint"] = joint
            text = json.dumps(json_safe(doc), indent=2, allow_nan=False)
            (stage / "discrepancy.json").write_text(text, encoding="utf-8")
        else:
            write_report(stage, inputs.runs, result, str(model_path), settings, validation)

    if (failed := write_outputs(PROG, args.out, written, write_files)) is not None:
        return failed
    if isinstance(result, TableDiscrepancy):
        _print_table(inputs, docs[0], elapsed)
    elif isinstance(result, JointDiscrepancy):
        _print_sets(inputs, result, elapsed)
    else:
        _print_result(inputs.runs, result, elapsed)
    print(f"  -> {model_path}, {args.out / 'discrepancy.json'}, {args.out / 'report.html'}")
    return 0


def _validation_only(args: argparse.Namespace) -> int:
    """--validate alone: the hidden-effect cases; the exit status."""
    try:
        settings = config.discrepancy()
        written = check_output(
            args.out, [args.model, args.validation], args.force, VALIDATION_FILES
        )
        validation = run_validation(load_model(args.model), args.cases, settings)
    except bad_input_errors() as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted; nothing written", file=sys.stderr)
        return 130

    def write_files(stage: Path) -> None:
        _write_validation(stage, validation)

    return write_outputs(PROG, args.out, written, write_files) or 0


def _print_sets(inputs: CommandInputs, result: JointDiscrepancy, elapsed: float) -> None:
    print(f"{PROG}: {inputs.what} in {elapsed:.1f} s: status {result.status}")
    print_fit(PROG, inputs, result.final or result.joint, None)
    for c, g in result.runs_result.gap_before.items():
        print(f"  {c:16s} NRMSE {g:.4f} -> {result.runs_result.gap_after[c]:.4f} (held-out runs)")
    for before, after in (
        (result.table_before, result.table_after),
        (result.spectra_before, result.spectra_after),
    ):
        if before is None or after is None:
            continue
        print(
            f"  {before.kind}: chi2 per residual {before.chi2 / max(before.n, 1):.2f} -> "
            f"{after.chi2 / max(after.n, 1):.2f}"
        )
        for c, v in before.nrmse.items():
            print(f"  {c:16s} NRMSE {v:.4f} -> {after.nrmse[c]:.4f} ({before.kind})")
    for note in result.notes:
        print(f"  note: {note}")


def _print_table(inputs: CommandInputs, doc: dict, elapsed: float) -> None:
    table = inputs.table
    assert table is not None
    print(f"{PROG}: table {table.name}, {table.n_points} points, {elapsed:.1f} s")
    print(f"  {doc['summary']}")
    for c, v in doc["gap_before"].items():
        gi, ga = doc["gap_identified"][c], doc["gap_after"][c]
        fmt = lambda x: "-" if x is None else f"{x:.3f}"
        print(f"  {c:22s} gap before {fmt(v)}, plant fitted {fmt(gi)}, after {fmt(ga)}")
    for note in doc["notes"]:
        print(f"  note: {note}")
        if note.startswith("warning: "):
            print(f"{PROG}: {note}", file=sys.stderr)


def _write_validation(out: Path, validation: dict) -> None:
    doc = write_validation(out, validation["cases"], validation["confusion"], validation["total_s"])
    table = doc["confusion"]
    print(
        f"{PROG}: validation {table['correct']}/{table['total']} cases right in "
        f"{doc['total_s']:.0f} s -> {out / 'validation.html'}"
    )


def _print_result(runs: list[Run], result: Any, elapsed: float) -> None:
    print(f"{PROG}: {len(runs)} run(s) analysed in {elapsed:.1f} s: status {result.status}")
    for k, p in result.plant_parameters.items():
        print(
            f"  plant {k:28s} {p['value']:.5g} (model {p['nominal']:.5g}, "
            f"{p['value'] / p['nominal'] - 1.0:+.2%}, SE {p['stderr']:.2g})"
        )
    for e in result.effects:
        print(f"  + {e.name} on {e.channel}: {format_parameters(e.parameters)}")
    for e in result.approximate:
        print(
            f"  ~ {e.name} on {e.channel}: {format_parameters(e.parameters)} "
            "(fitted, not named: the channel keeps a gap)"
        )
    for d in result.discovered:
        print(f"  + discovered (a hypothesis to test): {d.term.acts_on} += {d.term.expression}")
    for c in result.gap_before:
        print(f"  {c:16s} NRMSE {result.gap_before[c]:.4f} -> {result.gap_after[c]:.4f} (held-out)")
    for r in result.remaining:
        print(
            f"  gap left on {r['channel']}: band {r['band_hz']} Hz, full/low drive ratio "
            f"{r['drive_level_ratio']:.3g}"
        )


if __name__ == "__main__":
    sys.exit(main())
