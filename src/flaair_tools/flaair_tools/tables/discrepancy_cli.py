"""`flaair discrepancy TABLE.csv --out DIR`: the discrepancy workflow on a table.

The plant is fitted first (as `identify TABLE.csv`); then the vocabulary effects a table can show
and the library's terms are searched, each kept only if it predicts drive levels it was not
fitted on better (docs/TABLES.md). Effects on sensor signals (delays, filters) are not searched:
a table read from video has no sensor voltage and no time axis.

Writes into --out DIR: discrepancy.json (status, effects, discovered, identification, gap per
response column before / identified / after on held-out levels), model.yaml, report.html and
its figure table_response.png.

Exit status: 0 when analysed, 2 on bad input (one line naming the line and column, or an --out
that would overwrite an input or an existing output without --force; nothing written), 130
when interrupted.

Terms (gap, held-out, vocabulary, discovered): docs/GLOSSARY.md.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from flaair_analysis.tables.workflow import analyse_table
from flaair_common.outputs import write_outputs
from flaair_model.model_io import save_model

from .command import computed, table_outputs, warn
from .report import write_report

PROG = "flaair discrepancy"
OUT_FILES = ("model.yaml", "discrepancy.json", "report.html", "table_response.png")


def run(args: argparse.Namespace) -> int:
    """`flaair discrepancy TABLE.csv [--model FILE] --out DIR` (parsed by `flaair discrepancy`,
    which tells a table from runs); returns the exit status.
    """
    written = table_outputs(PROG, args, OUT_FILES)
    if isinstance(written, int):
        return written
    done = computed(PROG, args, analyse_table)
    if isinstance(done, int):
        return done
    table, _, s, result, elapsed = done
    docs: list[dict] = []  # the report's document, for the summary printed after

    def write_files(stage: Path) -> None:
        save_model(result.model_out, stage / "model.yaml")
        docs.append(write_report(result, table, s, stage))

    if (failed := write_outputs(PROG, args.out, written, write_files)) is not None:
        return failed
    doc = docs[0]
    print(f"{PROG}: table {table.name}, {table.n_points} points, {elapsed:.1f} s")
    print(f"  {doc['summary']}")
    for c, v in doc["gap_before"].items():
        gi, ga = doc["gap_identified"][c], doc["gap_after"][c]
        fmt = lambda x: "-" if x is None else f"{x:.3f}"
        print(f"  {c:22s} gap before {fmt(v)}, plant fitted {fmt(gi)}, after {fmt(ga)}")
    for note in doc["notes"]:
        print(f"  note: {note}")
    warn(PROG, doc["notes"])
    print(f"  -> {args.out / 'report.html'}")
    return 0
