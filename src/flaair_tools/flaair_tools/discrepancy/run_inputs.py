"""Measured runs from the command line's inputs (CSV files and bags) and the errors a command
reports in one line (the shell around `flaair_analysis.discrepancy.runs`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import yaml

from flaair_analysis.discrepancy.runs import DiscrepancyInputError, Run
from flaair_common.outputs import OutputError
from flaair_common.runcsv import RunFileError, read_run
from flaair_model.validation import ModelError

from .validation_file import ValidationFileError

__all__ = ["InputError", "bad_input_errors", "load_inputs", "runs_from_bag", "runs_from_csv"]


class InputError(ValueError):
    """Bad command-line input (file missing, wrong kind)."""


def _is_bag(path: Path) -> bool:
    return path.is_dir() or path.suffix == ".mcap"


def _run(name: str, fs_hz: float, c: Mapping[str, np.ndarray]) -> Run:
    """A core Run from a measured run's columns."""
    return Run(
        name=name,
        fs_hz=fs_hz,
        drive_v=c["drive_v"],
        stroke_sensor_v=c["stroke_sensor_v"],
        pitch_sensor_v=c["pitch_sensor_v"],
        stroke_deg=c["stroke_deg"],
        pitch_deg=c["pitch_deg"],
    )


def runs_from_csv(path: Path) -> Run:
    """One measured-run CSV as a core Run."""
    mr = read_run(path)
    return _run(mr.name, mr.sample_rate_hz, mr.columns)


def runs_from_bag(path: Path) -> list[Run]:
    """Every run of a bag as core Runs (ground truth NaN where invalid)."""
    # deferred: bag support (rosbags, mcap: 0.2 s) only when a bag is given
    from flaair_tools.bagio import runs as bag_runs

    bag = path.parent if path.suffix == ".mcap" else path
    return [
        _run(r.name, r.sample_rate_hz, r.columns)
        for r in bag_runs.load_runs([bag], need_truth=True, need_drive=True)
    ]


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


def bad_input_errors() -> tuple[type, ...]:
    errors: list[type] = [
        InputError,
        OutputError,
        ValidationFileError,
        RunFileError,
        ModelError,
        DiscrepancyInputError,
        OSError,
        yaml.YAMLError,
    ]
    try:
        # deferred: bag support (rosbags, mcap: 0.2 s) only when an error is being named
        from flaair_tools.bagio import BagError

        errors.append(BagError)
    except ImportError:  # pragma: no cover - bag support not installed
        pass
    return tuple(errors)
