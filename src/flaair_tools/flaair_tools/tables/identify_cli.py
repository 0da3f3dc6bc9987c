"""`flaair identify TABLE.csv --out DIR`: fit the plant to a frequency-response table.

The stroke natural frequency, aerodynamic damping and actuator gain are fitted to the stroke
columns, then the pitch natural frequency, hinge damping and couplings to the pitch columns,
each point simulated to steady state with the simulator's plant core, started from the table's
own peaks (docs/TABLES.md). Writes DIR/model.yaml and DIR/identification.json (parameters with
value, nominal, start, stderr; correlations; what the table cannot separate; notes).

Exit status: 0 when fitted, 2 on bad input (one line naming the line and column, or an --out
that would overwrite an input or an existing output without --force; nothing written), 130
when interrupted.

Terms (held-out): docs/GLOSSARY.md.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import yaml

from flaair_analysis.tables.fit import identify_table
from flaair_analysis.tables.reader import Table, TableInputError
from flaair_common.outputs import OutputError, check_output, write_outputs
from flaair_common.strictjson import json_safe
from flaair_model import settings
from flaair_model.config import ConfigError
from flaair_model.model import Model
from flaair_model.model_io import load_model, save_model
from flaair_model.validation import ModelError

from .report import identification_doc
from .table_io import load_tables

PROG = "flaair identify"
OUT_FILES = ("model.yaml", "identification.json")
T = TypeVar("T")


def _terminate(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def bad_input() -> tuple[type[Exception], ...]:
    """The errors a command reports in one line with exit 2."""
    return (TableInputError, ConfigError, ModelError, OSError, yaml.YAMLError)


def one_table(paths: list[Path]):
    """The one robot's table in `paths` (several robots are refused by name)."""
    tables = load_tables(paths)
    if len(tables) > 1:
        names = ", ".join(t.name for t in tables)
        raise TableInputError(f"{paths[0]}: several robots ({names}); give one robot's table")
    return tables[0]


def warn(prog: str, notes: list[str]) -> None:
    """Each note that is a warning (the plant misses a column beyond noise), on stderr too."""
    for note in notes:
        if note.startswith("warning: "):
            print(f"{prog}: {note}", file=sys.stderr)


def table_outputs(
    prog: str, args: argparse.Namespace, out_files: tuple[str, ...]
) -> list[Path] | int:
    """The outputs a table command may write (`args.table`, `args.model`, `args.out`,
    `args.force`), or the exit status of a refusal (checked before anything is computed: never
    an input, never the project's config, an existing one replaced only with --force).
    """
    inputs = [*args.table, *([args.model] if args.model else [])]
    try:
        return check_output(args.out, inputs, args.force, out_files)
    except OutputError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2


def computed(
    prog: str, args: argparse.Namespace, compute: Callable[[Table, Model, Any], T]
) -> tuple[Table, Model, Any, T, float] | int:
    """`compute(table, model, settings)` on the command's one table, timed, with SIGTERM taken
    as Ctrl-C; or the exit status of bad input (2) or an interruption (130), nothing written.
    """
    previous = signal.signal(signal.SIGTERM, _terminate)
    try:
        s = settings.tables()
        model = load_model(args.model)
        table = one_table(args.table)
        t0 = time.perf_counter()
        result = compute(table, model, s)
        return table, model, s, result, time.perf_counter() - t0
    except bad_input() as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{prog}: interrupted; nothing written", file=sys.stderr)
        return 130
    finally:
        signal.signal(signal.SIGTERM, previous)


def run(args: argparse.Namespace) -> int:
    """`flaair identify TABLE.csv [--model FILE] --out DIR` (parsed by `flaair identify`, which
    tells a table from runs); returns the exit status.
    """
    written = table_outputs(PROG, args, OUT_FILES)
    if isinstance(written, int):
        return written
    done = computed(PROG, args, identify_table)
    if isinstance(done, int):
        return done
    table, model, _, (fitted, fits, start, notes), elapsed = done

    def write_files(stage: Path) -> None:
        _write(stage, args.out, table, model, fitted, fits, start, notes, elapsed, args.model)

    if (failed := write_outputs(PROG, args.out, written, write_files)) is not None:
        return failed
    return 0


def _write(stage, out, table, model, fitted, fits, start, notes, elapsed, model_in) -> None:
    doc = identification_doc(table, model, fitted, fits, start, notes)
    doc.update(model_in=str(model_in or "config/model.yaml"), seconds=elapsed)
    save_model(fitted, stage / "model.yaml")
    (stage / "identification.json").write_text(
        json.dumps(json_safe(doc), indent=2, allow_nan=False), encoding="utf-8"
    )
    print(f"{PROG}: table {table.name}, {table.n_points} points, plant fitted in {elapsed:.1f} s")
    print(f"  {'parameter':30s} {'fitted':>11s} {'model':>11s} {'change':>8s} {'rel. SE':>8s}")
    for k, p in doc["parameters"].items():
        v, nom, se = p["value"], p["nominal"], p["stderr"]
        print(f"  {k:30s} {v:11.5g} {nom:11.5g} {v / nom - 1.0:+8.2%} {se / v:8.2%}")
    for note in [*doc["inseparable"], *notes]:
        print(f"  note: {note}")
    warn(PROG, notes)
    print(f"  -> {out / 'model.yaml'}, {out / 'identification.json'}")
