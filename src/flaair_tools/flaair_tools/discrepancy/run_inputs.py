"""The command line's inputs (measured-run CSV files, bags, frequency-response tables and any
other kind of measured set in `EVIDENCE_FILES`), told apart by their content, the runs read from
them, and the errors a command reports in one line (the shell around
`flaair_analysis.discrepancy.runs`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import yaml

from flaair_analysis.discrepancy.runs import DiscrepancyInputError, Run
from flaair_analysis.evidence import EvidenceSet
from flaair_analysis.multisine.analysis import MultisineInputError, RunInput
from flaair_analysis.multisine.spectra import is_multisine
from flaair_common.outputs import OutputError
from flaair_common.runcsv import RunFileError, read_run
from flaair_model.config import ConfigError
from flaair_model.validation import ModelError

from .validation_file import ValidationFileError

__all__ = [
    "EVIDENCE_FILES",
    "EvidenceFile",
    "InputError",
    "SortedInputs",
    "bad_input_errors",
    "load_inputs",
    "multisine_inputs",
    "runs_from_bag",
    "runs_from_csv",
    "sort_inputs",
    "split_multisine",
]

_HEADER_PEEK_BYTES = 65536  # a header sits in the first lines; a huge file is not read here


class InputError(ValueError):
    """Bad command-line input (file missing, wrong kind)."""


@dataclass(frozen=True)
class EvidenceFile:
    """A kind of measured set besides runs and tables: a CSV recognised by its header.

    Attributes
    ----------
    columns : a CSV whose header names all of these is one of this kind.
    read : the file as evidence (`flaair_analysis.evidence.EvidenceSet`), fitted beside the rest.
    errors : what `read` raises for a bad file (its message names the file): one line, exit 2.
    """

    columns: frozenset[str]
    read: Callable[[Path], EvidenceSet]
    errors: tuple[type[Exception], ...] = ()


# The other kinds of measured set a command takes by content (docs/CONTRIBUTING.md, "An
# evidence kind"): a new kind of evidence file is one row here.
EVIDENCE_FILES: tuple[EvidenceFile, ...] = ()


@dataclass(frozen=True)
class SortedInputs:
    """The inputs by kind: run files and bags, tables, and each other evidence file's kind."""

    runs: list[Path]
    tables: list[Path]
    others: list[tuple[EvidenceFile, Path]]


def _is_bag(path: Path) -> bool:
    return path.is_dir() or path.suffix == ".mcap"


def runs_from_csv(path: Path) -> Run:
    """One measured-run CSV as a core Run."""
    mr = read_run(path)
    return Run.from_columns(mr.name, mr.sample_rate_hz, mr.columns)


def runs_from_bag(path: Path) -> list[Run]:
    """Every run of a bag as core Runs (ground truth NaN where invalid)."""
    # deferred: bag support (rosbags, mcap: 0.2 s) only when a bag is given
    from flaair_tools.bagio import runs as bag_runs

    bag = path.parent if path.suffix == ".mcap" else path
    return [
        Run.from_columns(r.name, r.sample_rate_hz, r.columns)
        for r in bag_runs.load_runs([bag], need_truth=True, need_drive=True)
    ]


def _csv_header(path: Path) -> list[str]:
    """The column names of a CSV's first line that is neither empty nor a # comment ([] when
    the file cannot be peeked at: its reader names the problem).
    """
    if not path.is_file():
        return []
    try:
        with path.open("rb") as f:
            head = f.read(_HEADER_PEEK_BYTES).decode("utf-8-sig", errors="replace")
    except OSError:
        return []
    for line in head.splitlines():
        text = line.strip()
        if text and not text.startswith("#"):
            return [c.strip() for c in text.split(",")]
    return []


def sort_inputs(paths: Sequence[Path], tables: Sequence[Path] = ()) -> SortedInputs:
    """The inputs told apart by content: runs (bags and measured-run CSVs), tables and the other
    evidence files (`EVIDENCE_FILES`).

    A CSV whose header names `frequency_hz` and no `time_s` is a frequency-response table
    (docs/TABLES.md); a CSV whose header names all of a kind's `columns` is of that kind; any
    other CSV, a bag directory or an .mcap file holds runs, and so does a path that is not there
    or cannot be read (the runs' reader names it, after any table is checked). `tables`: paths
    given as tables (`--table`), taken as tables without looking.
    """
    runs: list[Path] = []
    found: list[Path] = []
    others: list[tuple[EvidenceFile, Path]] = []
    for p in paths:
        header = [] if _is_bag(p) else _csv_header(p)
        kind = next((k for k in EVIDENCE_FILES if k.columns <= set(header)), None)
        if kind is not None:
            others.append((kind, p))
        elif "frequency_hz" in header and "time_s" not in header:
            found.append(p)
        else:
            runs.append(p)
    return SortedInputs(runs, [*found, *tables], others)


def load_inputs(paths: Sequence[Path]) -> list[Run]:
    """Runs from CSV files and bags, in the order given.

    Raises
    ------
    InputError, RunFileError, bagio.BagError
        Missing path, unreadable file, bag without the needed topics.
    """
    runs: list[Run] = []
    for p in paths:
        if not p.exists():
            raise InputError(f"{p}: no such file or bag directory")
        if _is_bag(p):
            runs.extend(runs_from_bag(p))
        elif p.suffix.lower() == ".csv":
            runs.append(runs_from_csv(p))
        else:
            raise InputError(f"{p}: not a measured-run CSV (.csv) or a bag (directory or .mcap)")
    return runs


def split_multisine(runs: Sequence[Run]) -> tuple[list[Run], list[Run]]:
    """(time-series runs, multisine runs): a run whose drive is a periodic odd multisine
    (`multisine.spectra.is_multisine`) belongs to a multisine set, read as line spectra.
    """
    plain, multisine = [], []
    for run in runs:
        (multisine if is_multisine(run.drive_v) else plain).append(run)
    return plain, multisine


def multisine_inputs(runs: Sequence[Run]) -> list[RunInput]:
    """A multisine set's runs as the multisine analysis reads them."""
    return [
        RunInput(
            r.name,
            r.fs_hz,
            {
                "drive_v": r.drive_v,
                "stroke_sensor_v": r.stroke_sensor_v,
                "pitch_sensor_v": r.pitch_sensor_v,
                "stroke_deg": r.stroke_deg,
                "pitch_deg": r.pitch_deg,
            },
        )
        for r in runs
    ]


def bad_input_errors() -> tuple[type, ...]:
    errors: list[type] = [
        InputError,
        OutputError,
        ValidationFileError,
        RunFileError,
        ModelError,
        ConfigError,
        DiscrepancyInputError,
        MultisineInputError,
        OSError,
        yaml.YAMLError,
        *(error for kind in EVIDENCE_FILES for error in kind.errors),
    ]
    try:
        # deferred: bag support (rosbags, mcap: 0.2 s) only when an error is being named
        from flaair_tools.bagio import BagError

        errors.append(BagError)
    except ImportError:  # pragma: no cover - bag support not installed
        pass
    return tuple(errors)
