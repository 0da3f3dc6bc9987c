"""`flaair identify`: fit this robot's plant parameters to its runs, its tables, or both (grey-box).

Inputs are measured-run CSV files, bags and frequency-response tables (docs/TABLES.md), in any
mix, told apart by their content (a CSV whose header names frequency_hz and no time_s is a
table; runs whose drive is a periodic odd multisine are a multisine set, fitted as line spectra:
docs/MULTISINE.md); --table TABLE.csv names a table explicitly. Every input is evidence for one
fit: each residual in units of its own noise, the sum of their chi-squares minimised. The stroke
natural frequency, aerodynamic damping and actuator gain are fitted to the ground-truth stroke,
then the pitch natural frequency, hinge damping and the stroke-to-pitch couplings to the
ground-truth pitch (scipy least_squares on the simulated runs, each from its measured initial
state, started from a frequency-domain estimate of the sweeps' transfer functions). The
inertias, sensor constants (Table 1, charge amplifiers) and transmission ratio are
fabrication-known and stay.

Writes into --out DIR:
  model.yaml           the input model with the fitted plant parameters (as config/model.yaml)
  identification.json  the inputs; per parameter: value, nominal, start, stderr; correlations;
                       the combinations the data cannot separate; per data set its agreement;
                       warnings and notes

Exit status: 0 when fitted, 2 on bad input, 130 when interrupted (Ctrl-C / SIGTERM).

Runs alone start from the better of the model and their frequency-domain estimate; a table alone
from its own peaks; any other mix from the table fitted alone (or the runs' estimate), every set
fitted at once, each weighed by its chi-square. identification.json is one document whatever the
mix: per data set its residual over its noise, and whether the sets agree (docs/TABLES.md).

Examples
--------
  bin/flaair identify lab/robot3_sweep.csv --out out/robot3
  bin/flaair identify lab/chirp_full.csv lab/robot3_sweep.csv --out out/robot3-joint
  bin/flaair identify lab/chirp_full.csv lab/chirp_half.csv lab/stepped.csv --out out/robot7
  bin/flaair identify bags/robot7 --model config/model.yaml --out out/robot7

Terms (identification, held-out): docs/GLOSSARY.md.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path

from flaair_analysis.tables.joint import JointFit, identify_evidence
from flaair_common.cli_help import HelpFormatter
from flaair_common.outputs import write_outputs
from flaair_common.strictjson import json_safe
from flaair_model.model_io import save_model
from flaair_tools.tables.report import table_doc

from .evidence_inputs import CommandInputs, evidence_arguments, run_command
from .run_inputs import sort_inputs

PROG = "flaair identify"
USAGE = (
    "flaair identify INPUT ... --out DIR [--model FILE] [--force]\n"
    "       (INPUT: a measured-run CSV, a bag, a frequency-response table or a multisine\n"
    "       set's runs; any mix)"
)
OUT_FILES = ("model.yaml", "identification.json")


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG, usage=USAGE, description=__doc__, formatter_class=HelpFormatter
    )
    evidence_arguments(parser)
    return parser


def compute(inputs: CommandInputs, progress: Callable[[str], None]) -> JointFit:
    """The one identification on the command's evidence."""
    progress("fit")
    return identify_evidence(
        inputs.runs,
        inputs.table,
        inputs.model,
        inputs.noise,
        inputs.s,
        spectra=inputs.spectra,
        extra=inputs.extra,
    )


def identification_doc(
    inputs: CommandInputs, fit: JointFit, args: argparse.Namespace, seconds: float
) -> dict:
    """identification.json: the inputs, the fit (`JointFit.as_dict`), where it came from."""
    table = inputs.table
    return json_safe(
        {
            "runs": [r.name for r in inputs.runs],
            "multisine_runs": [r.name for r in inputs.multisine],
            "table": table.name if table is not None else None,
            "table_points": table.n_points if table is not None else 0,
            "table_summary": table_doc(table) if table is not None else None,
            "model_in": str(args.model or "config/model.yaml"),
            "model_out": str(args.out / "model.yaml"),
            "seconds": seconds,
            **fit.as_dict(),
        }
    )


def main(argv: list[str] | None = None) -> int:
    """`flaair identify INPUT... [--model FILE] --out DIR`; returns the exit status."""
    parser = _parser()
    args = parser.parse_args(argv)
    inputs = sort_inputs(args.inputs, args.table)
    args.inputs, args.table, args.others = inputs.runs, inputs.tables, inputs.others
    if not (args.inputs or args.table or args.others):
        parser.error("give measured-run CSV files, bags or a frequency-response table")
    done = run_command(PROG, args, OUT_FILES, compute)
    if isinstance(done, int):
        return done
    written, inputs, fit, elapsed = done
    doc = identification_doc(inputs, fit, args, elapsed)

    def write_files(stage: Path) -> None:
        save_model(fit.model, stage / "model.yaml")
        text = json.dumps(doc, indent=2, allow_nan=False)
        (stage / "identification.json").write_text(text, encoding="utf-8")

    if (failed := write_outputs(PROG, args.out, written, write_files)) is not None:
        return failed
    print_fit(PROG, inputs, fit, elapsed)
    print(f"  -> {args.out / 'model.yaml'}, {args.out / 'identification.json'}")
    return 0


def _agreement(fit: JointFit) -> str:
    parts = []
    for name, a in fit.agreement.items():
        worst = max(a.noise_ratio.values(), default=float("nan"))
        parts.append(f"{name} {worst:.2f}x noise")
    return ", ".join(parts)


def print_fit(prog: str, inputs: CommandInputs, fit: JointFit, elapsed: float | None) -> None:
    """The fit in a few lines: the summary (with `elapsed`), each parameter, each set's
    agreement, what the data cannot separate, notes; warnings on stderr.
    """
    if elapsed is not None:
        only = f"the {next(iter(fit.agreement))}" if len(fit.agreement) == 1 else ""
        sets = only or {2: "both"}.get(len(fit.agreement), "every set")
        verdict = "the sets agree" if not fit.warnings else "the sets DISAGREE (see warning)"
        if len(fit.agreement) == 1:
            verdict = "at its noise" if not fit.warnings else "a gap above noise (see warning)"
        print(
            f"{prog}: {inputs.what}, plant fitted on {sets} in {elapsed:.1f} s: "
            f"{_agreement(fit)}; {verdict}"
        )
    print(f"  {'parameter':30s} {'fitted':>11s} {'model':>11s} {'change':>8s} {'rel. SE':>8s}")
    for k in fit.keys:
        v, nom, se = fit.values[k], fit.nominal[k], fit.stderr[k]
        print(f"  {k:30s} {v:11.5g} {nom:11.5g} {v / nom - 1.0:+8.2%} {se / v:8.2%}")
    for name, a in fit.agreement.items():
        cols = ", ".join(
            f"{c} {v:.2f}x noise (NRMSE {a.nrmse[c]:.4f})" for c, v in a.noise_ratio.items()
        )
        print(f"  {name}: {cols}")
    for note in fit.inseparable:
        print(f"  cannot separate: {note}")
    for note in fit.notes:
        print(f"  note: {note}")
    for w in fit.warnings:
        print(f"{prog}: warning: {w}", file=sys.stderr)


if __name__ == "__main__":
    sys.exit(main())
