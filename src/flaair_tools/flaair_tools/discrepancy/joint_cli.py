"""`flaair identify RUN... TABLE.csv --out DIR` and `flaair discrepancy RUN... TABLE.csv --out
DIR`: a robot's runs and its frequency-response table in one fit (docs/TABLES.md,
"Tables and runs together").

identify writes model.yaml (the plant fitted on both) and identification.json (each parameter's
value, nominal, start, standard error, the table's fit alone and the runs' frequency-domain
estimate; per data set its residual over its noise, its NRMSE and its weight; warnings when the
sets disagree). discrepancy writes model.yaml, discrepancy.json (the runs' workflow document
plus a `joint` section: the joint plant, the table's held-out drive levels before and after the
runs' findings, whether the table kept them) and report.html (the runs' workflow report).

Exit status: 0 when fitted (a disagreement between the sets is a warning on stderr and in the
JSON, not a failure), 2 on bad input (one line naming the file, line and column; nothing
written), 130 when interrupted.

Terms (held-out, gap, discovered): docs/GLOSSARY.md.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from flaair_analysis.discrepancy.diagnosis import noise_estimates
from flaair_analysis.discrepancy.runs import Run, check_runs, simulate_runs
from flaair_analysis.multisine.analysis import SENSORS, VIDEO, find_design
from flaair_analysis.multisine.spectrum_evidence import SpectrumEvidence, spectrum_channels
from flaair_analysis.tables.joint import JointFit, identify_joint
from flaair_analysis.tables.joint_workflow import JointDiscrepancy, analyse_joint
from flaair_analysis.tables.reader import Table
from flaair_common.outputs import check_output, write_outputs
from flaair_common.strictjson import json_safe
from flaair_model import settings as config
from flaair_model.config import ConfigError
from flaair_model.model import Model
from flaair_model.model_io import load_model, save_model
from flaair_model.settings import TableSettings, node_section
from flaair_sim.plant_io import PLANT_PARAMS
from flaair_tools.tables.identify_cli import bad_input, one_table

from .report import write_report
from .run_inputs import bad_input_errors, load_inputs, multisine_inputs, split_multisine

IDENTIFY_FILES = ("model.yaml", "identification.json")
DISCREPANCY_FILES = ("model.yaml", "discrepancy.json", "report.html")


def _terminate(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def _outputs(args: argparse.Namespace, files: tuple[str, ...]) -> list[Path]:
    inputs = [*args.inputs, *args.table, *([args.model] if args.model else [])]
    return check_output(args.out, inputs, args.force, files)


@dataclass(frozen=True)
class _Inputs:
    """What a joint command fits: the model, the table settings, the table (or None), the
    time-series runs, the multisine set (its runs and spectra, or none), the runs the search
    works on (the time-series runs, or the set's own when there are none) and their noise.
    """

    model: Model
    s: TableSettings
    table: Table | None
    runs: list[Run]
    multisine: list[Run]
    spectra: SpectrumEvidence | None
    searched: list[Run]
    noise: dict[str, float]

    @property
    def what(self) -> str:
        """The inputs in words, for the summary line."""
        parts = [f"{len(self.runs)} run(s)"] if self.runs else []
        if self.multisine:
            parts.append(f"a multisine set of {len(self.multisine)} realization(s)")
        if self.table is not None:
            parts.append(f"table {self.table.name} ({self.table.n_points} points)")
        return " + ".join(parts)


def _spectra(runs: list[Run]) -> tuple[SpectrumEvidence | None, list[str]]:
    """The multisine set's truth-channel spectra (None without a set) and why a channel is not
    read.
    """
    if not runs:
        return None, []
    inputs = multisine_inputs(runs)
    found = find_design(inputs, None)
    channels, skipped = spectrum_channels(inputs, found, (*VIDEO, *SENSORS))
    return SpectrumEvidence(inputs, found, channels), [
        f"multisine {c}: {why}" for c, why in skipped.items()
    ]


def _load(args: argparse.Namespace) -> _Inputs:
    """The inputs, checked (a bad table is refused before the runs are read)."""
    model = load_model(args.model)
    s = config.tables()
    table = one_table(args.table) if args.table else None
    loaded = args.loaded if args.loaded is not None else load_inputs(args.inputs)
    plain, multisine = split_multisine(loaded)
    runs = check_runs(plain) if plain else []
    spectra, skipped = _spectra(multisine)
    for why in skipped:
        print(f"note: {why}", file=sys.stderr)
    searched = runs or (check_runs(multisine) if multisine else [])
    noise = (
        noise_estimates(searched, simulate_runs([model], searched)[0], model) if searched else {}
    )
    return _Inputs(model, s, table, runs, multisine, spectra, searched, noise)


def _run(prog: str, args: argparse.Namespace, files: tuple[str, ...], compute) -> Any:
    """Check the outputs, load and compute with one-line refusals; the exit status or the
    inputs, the results and the seconds taken.
    """
    previous = signal.signal(signal.SIGTERM, _terminate)
    try:
        written = _outputs(args, files)
        inputs = _load(args)
        t0 = time.perf_counter()
        result = compute(inputs)
        return written, inputs, result, time.perf_counter() - t0
    except (*bad_input_errors(), *bad_input()) as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{prog}: interrupted; nothing written", file=sys.stderr)
        return 130
    finally:
        signal.signal(signal.SIGTERM, previous)


def _sets(fit: JointFit) -> str:
    return {1: "it", 2: "both"}.get(len(fit.agreement), "every set")


def _agreement_line(fit: JointFit) -> str:
    parts = []
    for name, a in fit.agreement.items():
        worst = max(a.noise_ratio.values(), default=float("nan"))
        parts.append(f"{name} {worst:.2f}x noise")
    return ", ".join(parts)


def _print_fit(prog: str, fit: JointFit) -> None:
    print(f"  {'parameter':30s} {'fitted':>11s} {'model':>11s} {'change':>8s} {'rel. SE':>8s}")
    for k in fit.keys:
        v, nom, se = fit.values[k], fit.nominal[k], fit.stderr[k]
        print(f"  {k:30s} {v:11.5g} {nom:11.5g} {v / nom - 1.0:+8.2%} {se / v:8.2%}")
    for name, a in fit.agreement.items():
        cols = ", ".join(
            f"{c} {v:.2f}x noise (NRMSE {a.nrmse[c]:.4f})" for c, v in a.noise_ratio.items()
        )
        print(f"  {name}: {cols}")
    for note in fit.notes:
        print(f"  note: {note}")
    for w in fit.warnings:
        print(f"{prog}: warning: {w}", file=sys.stderr)


def identify(args: argparse.Namespace) -> int:
    """`flaair identify RUN... TABLE.csv --out DIR` (parsed by `flaair identify`); returns the
    exit status.
    """
    prog = "flaair identify"

    def compute(i: _Inputs) -> JointFit:
        return identify_joint(i.runs, i.table, i.model, i.noise, i.s, spectra=i.spectra)

    done = _run(prog, args, IDENTIFY_FILES, compute)
    if isinstance(done, int):
        return done
    written, inputs, fit, elapsed = done
    table = inputs.table
    doc = {
        "runs": [r.name for r in inputs.runs],
        "multisine_runs": [r.name for r in inputs.multisine],
        "table": table.name if table is not None else None,
        "table_points": table.n_points if table is not None else 0,
        "model_in": str(args.model or "config/model.yaml"),
        "model_out": str(args.out / "model.yaml"),
        "seconds": elapsed,
        **fit.as_dict(),
    }

    def write_files(stage: Path) -> None:
        save_model(fit.model, stage / "model.yaml")
        text = json.dumps(json_safe(doc), indent=2, allow_nan=False)
        (stage / "identification.json").write_text(text, encoding="utf-8")

    if (failed := write_outputs(prog, args.out, written, write_files)) is not None:
        return failed
    verdict = "the sets agree" if not fit.warnings else "the sets DISAGREE (see warning)"
    print(
        f"{prog}: {inputs.what}, plant fitted on {_sets(fit)} in {elapsed:.1f} s: "
        f"{_agreement_line(fit)}; {verdict}"
    )
    _print_fit(prog, fit)
    print(f"  -> {args.out / 'model.yaml'}, {args.out / 'identification.json'}")
    return 0


def discrepancy(args: argparse.Namespace) -> int:
    """`flaair discrepancy RUN... TABLE.csv --out DIR` (parsed by `flaair discrepancy`); returns
    the exit status.
    """
    prog = "flaair discrepancy"
    try:
        workflow = config.discrepancy()
        drive_limit_v = float(
            node_section(PLANT_PARAMS, "plant_node", "flaair.yaml")["drive_limit_v"]
        )
    except ConfigError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2

    def compute(i: _Inputs) -> JointDiscrepancy:
        return analyse_joint(
            i.runs,
            i.table,
            i.model,
            i.noise,
            i.s,
            workflow,
            spectra=i.spectra,
            search_runs=i.searched,
            drive_limit_v=drive_limit_v,
        )

    done = _run(prog, args, DISCREPANCY_FILES, compute)
    if isinstance(done, int):
        return done
    written, inputs, result, elapsed = done
    report_runs = list(result.joint.runs) or inputs.searched

    def write_files(stage: Path) -> None:
        model_path = args.out / "model.yaml"
        save_model(result.model_out, stage / "model.yaml")
        joint = json_safe(result.as_dict())
        doc = write_report(
            stage, report_runs, result.runs_result, str(model_path), workflow, joint=joint
        )
        doc["status"] = result.status
        doc["joint"] = json_safe(result.as_dict())
        text = json.dumps(json_safe(doc), indent=2, allow_nan=False)
        (stage / "discrepancy.json").write_text(text, encoding="utf-8")

    if (failed := write_outputs(prog, args.out, written, write_files)) is not None:
        return failed
    print(f"{prog}: {inputs.what} in {elapsed:.1f} s: status {result.status}")
    _print_fit(prog, result.final or result.joint)
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
    print(f"  -> {args.out / 'model.yaml'}, {args.out / 'discrepancy.json'}, report.html")
    return 0
