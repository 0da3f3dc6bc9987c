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
  identification.json  per parameter: value, nominal, start, stderr; correlations; the
                       combinations the runs cannot separate

Exit status: 0 when fitted, 2 on bad input, 130 when interrupted (Ctrl-C / SIGTERM).

With a table alone the plant is fitted to the table's cells (started from its peaks); with runs
beside a table or a multisine set, or with a multisine set alone, to every set at once, and
identification.json says whether the sets agree (docs/TABLES.md).

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
import signal
import sys
import time
from pathlib import Path

from tqdm import tqdm

from flaair_analysis.discrepancy.diagnosis import noise_estimates
from flaair_analysis.discrepancy.identification import identify_plant
from flaair_analysis.discrepancy.runs import Run, check_runs, simulate_runs
from flaair_common.cli_help import HelpFormatter
from flaair_common.outputs import check_output, write_outputs
from flaair_common.strictjson import json_safe
from flaair_model.model_io import load_model, save_model
from flaair_tools.discrepancy.run_inputs import (
    bad_input_errors,
    preload,
    sort_inputs,
    split_multisine,
)
from flaair_tools.tables.identify_cli import run as table_identify

from .joint_cli import identify as joint_identify

PROG = "flaair identify"
USAGE = (
    "flaair identify INPUT ... --out DIR [--model FILE] [--force]\n"
    "       (INPUT: a measured-run CSV, a bag, a frequency-response table or a multisine\n"
    "       set's runs; any mix)"
)
OUT_FILES = ("model.yaml", "identification.json")


def _terminate(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG, usage=USAGE, description=__doc__, formatter_class=HelpFormatter
    )
    parser.add_argument(
        "inputs",
        nargs="*",
        type=Path,
        metavar="INPUT",
        help="measured-run CSV files, bag directories and frequency-response tables (CSV), "
        "told apart by their content",
    )
    parser.add_argument(
        "--table",
        type=Path,
        action="append",
        default=[],
        metavar="TABLE.csv",
        help="a frequency-response table, named as one (a table among the inputs is found "
        "without it) (default: none)",
    )
    parser.add_argument(
        "--model",
        type=Path,
        default=None,
        metavar="FILE",
        help="model YAML to start from (default: config/model.yaml)",
    )
    parser.add_argument("--out", type=Path, required=True, metavar="DIR", help="output directory")
    parser.add_argument("--force", action="store_true", help="replace existing outputs in --out")
    return parser


def main(argv: list[str] | None = None) -> int:
    """`flaair identify INPUT... [--model FILE] --out DIR`; returns the exit status."""
    parser = _parser()
    args = parser.parse_args(argv)
    args.inputs, args.table = sort_inputs(args.inputs, args.table)
    if not args.inputs and not args.table:
        parser.error("give measured-run CSV files, bags or a frequency-response table")
    args.loaded = None
    if args.table:
        return joint_identify(args) if args.inputs else table_identify(args)
    loaded = preload(PROG, args.inputs)
    if isinstance(loaded, int):
        return loaded
    if split_multisine(loaded)[1]:  # line spectra among the evidence: the joint fit
        args.loaded = loaded
        return joint_identify(args)
    return _identify_runs(args, loaded)


def _identify_runs(args: argparse.Namespace, loaded: list[Run]) -> int:
    """The plant fitted to runs alone; the exit status."""
    previous = signal.signal(signal.SIGTERM, _terminate)
    try:
        written = check_output(args.out, [*args.inputs, args.model], args.force, OUT_FILES)
        with tqdm(total=3, desc="identify", unit="step", file=sys.stderr, leave=False) as bar:
            bar.set_postfix_str("read runs")
            model = load_model(args.model)
            runs = check_runs(loaded)
            bar.update(1)
            bar.set_postfix_str("noise")
            noise = noise_estimates(runs, simulate_runs([model], runs)[0], model)
            bar.update(1)
            bar.set_postfix_str("fit plant")
            t0 = time.perf_counter()
            fit = identify_plant(runs, model, noise)
            elapsed = time.perf_counter() - t0
            bar.update(1)
    except bad_input_errors() as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted; nothing written", file=sys.stderr)
        return 130
    finally:
        signal.signal(signal.SIGTERM, previous)
    doc = json_safe(
        {
            "runs": [r.name for r in runs],
            "model_in": str(args.model or "config/model.yaml"),
            "model_out": str(args.out / "model.yaml"),
            **fit.as_dict(),
        }
    )

    def write_files(stage: Path) -> None:
        save_model(fit.model, stage / "model.yaml")
        (stage / "identification.json").write_text(
            json.dumps(doc, indent=2, allow_nan=False), encoding="utf-8"
        )

    if (failed := write_outputs(PROG, args.out, written, write_files)) is not None:
        return failed
    print(f"{PROG}: {len(runs)} run(s), plant fitted in {elapsed:.1f} s")
    print(f"  {'parameter':30s} {'fitted':>11s} {'model':>11s} {'change':>8s} {'rel. SE':>8s}")
    for k in fit.keys:
        v, nom, se = fit.values[k], fit.nominal[k], fit.stderr[k]
        print(f"  {k:30s} {v:11.5g} {nom:11.5g} {v / nom - 1.0:+8.2%} {se / v:8.2%}")
    for note in fit.inseparable:
        print(f"  cannot separate: {note}")
    print(f"  -> {args.out / 'model.yaml'}, {args.out / 'identification.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
