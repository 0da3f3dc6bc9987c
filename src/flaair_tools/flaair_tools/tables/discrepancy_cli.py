"""`flaair discrepancy --table TABLE.csv --out DIR`: the discrepancy workflow on a table.

The plant is fitted first (as `identify --table`); then the vocabulary effects a table can show
and the library's terms are searched, each kept only if it predicts drive levels it was not
fitted on better (docs/TABLES.md). Effects on sensor signals (delays, filters) are not searched:
a table read from video has no sensor voltage and no time axis.

Writes into --out DIR: discrepancy.json (status, effects, discovered, identification, gap per
response column before / identified / after on held-out levels), model.yaml, report.html and
its figure table_response.png.

Exit status: 0 when analysed, 2 on bad input (one line naming the line and column; nothing
written), 130 when interrupted.
"""

from __future__ import annotations

import argparse
import signal
import sys
import time
from pathlib import Path

from flaair_analysis.tables.workflow import analyse_table
from flaair_model import settings
from flaair_model.model_io import load_model, save_model

from .identify_cli import bad_input, one_table
from .report import write_report

PROG = "flaair discrepancy"


def _terminate(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def main(argv: list[str] | None = None) -> int:
    """`flaair discrepancy --table TABLE [--model FILE] --out DIR`; returns the exit status."""
    parser = argparse.ArgumentParser(
        prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--table", type=Path, action="append", required=True, help="CSV table")
    parser.add_argument("--model", type=Path, default=None, help="model YAML to start from")
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    args = parser.parse_args(argv)
    previous = signal.signal(signal.SIGTERM, _terminate)
    try:
        s = settings.tables()
        model = load_model(args.model)
        table = one_table(args.table)
        t0 = time.perf_counter()
        result = analyse_table(table, model, s)
        elapsed = time.perf_counter() - t0
    except bad_input() as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted; nothing written", file=sys.stderr)
        return 130
    finally:
        signal.signal(signal.SIGTERM, previous)
    args.out.mkdir(parents=True, exist_ok=True)
    save_model(result.model_out, args.out / "model.yaml")
    doc = write_report(result, table, s, args.out)
    print(f"{PROG}: table {table.name}, {table.n_points} points, {elapsed:.1f} s")
    print(f"  {doc['summary']}")
    for c, v in doc["gap_before"].items():
        gi, ga = doc["gap_identified"][c], doc["gap_after"][c]
        fmt = lambda x: "-" if x is None else f"{x:.3f}"
        print(f"  {c:22s} gap before {fmt(v)}, plant fitted {fmt(gi)}, after {fmt(ga)}")
    for note in doc["notes"]:
        print(f"  note: {note}")
    print(f"  -> {args.out / 'report.html'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
