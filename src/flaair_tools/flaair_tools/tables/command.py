"""The shell a table command shares (`flaair discrepancy TABLE.csv`; `flaair identify` reads its
table through it too): the outputs checked before anything is computed, the one robot's table
loaded, bad input refused in one line (exit 2), Ctrl-C and SIGTERM (exit 130), nothing written.
"""

from __future__ import annotations

import argparse
import signal
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import yaml

from flaair_analysis.tables.reader import Table, TableInputError
from flaair_common.outputs import OutputError, check_output
from flaair_model import settings
from flaair_model.config import ConfigError
from flaair_model.model import Model
from flaair_model.model_io import load_model
from flaair_model.validation import ModelError

from .table_io import load_tables

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
