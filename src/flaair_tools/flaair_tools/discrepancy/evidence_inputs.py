"""A command's evidence, read from its inputs and recognised by content: the time-series runs,
the multisine set (its runs and line spectra), the frequency-response table, the model and the
settings, with the runs' noise; and the one way `identify` and `discrepancy` check outputs, load,
compute and refuse bad input in one line.
"""

from __future__ import annotations

import argparse
import signal
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

from tqdm import tqdm

from flaair_analysis.discrepancy.diagnosis import noise_estimates
from flaair_analysis.discrepancy.runs import Run, check_runs, simulate_runs
from flaair_analysis.evidence import EvidenceSet
from flaair_analysis.multisine.analysis import SENSORS, VIDEO, find_design
from flaair_analysis.multisine.spectrum_evidence import SpectrumEvidence, spectrum_channels
from flaair_analysis.tables.reader import Table
from flaair_common.outputs import check_output
from flaair_model import settings as config
from flaair_model.model import Model
from flaair_model.model_io import load_model
from flaair_model.settings import TableSettings
from flaair_tools.tables.table_io import bad_input, one_table

from .run_inputs import (
    InputError,
    bad_input_errors,
    load_inputs,
    multisine_inputs,
    split_multisine,
)

__all__ = ["CommandInputs", "evidence_arguments", "load_evidence", "run_command"]


def evidence_arguments(parser: argparse.ArgumentParser, inputs_help: str = "") -> None:
    """The arguments both commands take: the inputs (any mix), --table, --model, --out, --force."""
    parser.add_argument(
        "inputs",
        nargs="*",
        type=Path,
        metavar="INPUT",
        help="measured-run CSV files, bag directories and frequency-response tables (CSV), "
        "told apart by their content" + inputs_help,
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


def _terminate(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


@dataclass(frozen=True)
class CommandInputs:
    """What a command fits: the model, the table settings, the table (or None), the time-series
    runs, the multisine set (its runs and spectra, or none), the runs the search works on (the
    time-series runs, or the set's own when there are none) and, when asked, their noise.
    """

    model: Model
    s: TableSettings
    table: Table | None
    runs: list[Run]
    multisine: list[Run]
    spectra: SpectrumEvidence | None
    searched: list[Run]
    # any other kind of measured set (`EvidenceSet`): fitted and scored by `identify` as these
    extra: tuple[EvidenceSet, ...] = ()

    @cached_property
    def noise(self) -> dict[str, float]:
        """The noise RMS per channel of the runs searched (a simulation of them: computed when a
        fit first asks, never for the runs' own workflow, which estimates its own).
        """
        if not self.searched:
            return {}
        return noise_estimates(
            self.searched, simulate_runs([self.model], self.searched)[0], self.model
        )

    @property
    def what(self) -> str:
        """The inputs in words, for the summary line."""
        parts = [f"{len(self.runs)} run(s)"] if self.runs else []
        if self.multisine:
            parts.append(f"a multisine set of {len(self.multisine)} realization(s)")
        if self.table is not None:
            parts.append(f"table {self.table.name} ({self.table.n_points} points)")
        parts += [f"the {other.name}" for other in self.extra]
        return " + ".join(parts)

    @property
    def sets(self) -> int:
        """How many sets of evidence: runs, a multisine set, a table, any other kind."""
        return sum((bool(self.runs), bool(self.multisine), self.table is not None)) + len(
            self.extra
        )


def _spectra(runs: list[Run]) -> tuple[SpectrumEvidence | None, list[str]]:
    """The multisine set's spectra (None without a set) and why a channel is not read."""
    if not runs:
        return None, []
    inputs = multisine_inputs(runs)
    found = find_design(inputs, None)
    channels, skipped = spectrum_channels(inputs, found, (*VIDEO, *SENSORS))
    return SpectrumEvidence(inputs, found, channels), [
        f"multisine {c}: {why}" for c, why in skipped.items()
    ]


def load_evidence(args: argparse.Namespace) -> CommandInputs:
    """The inputs of `args` (`inputs`, `table`, `others`: `run_inputs.sort_inputs`'s, and
    `model`), checked: a bad table is refused before the runs are read; each other evidence file
    is read by its kind.
    """
    model = load_model(args.model)
    s = config.tables()
    table = one_table(args.table) if args.table else None
    plain, multisine = split_multisine(load_inputs(args.inputs))
    runs = check_runs(plain) if plain else []
    spectra, skipped = _spectra(multisine)
    for why in skipped:
        print(f"note: {why}", file=sys.stderr)
    searched = runs or (check_runs(multisine) if multisine else [])
    extra = tuple(kind.read(path) for kind, path in args.others)
    if table is None and not searched and not extra:
        raise InputError("the inputs hold no runs")
    return CommandInputs(model, s, table, runs, multisine, spectra, searched, extra)


def run_command(
    prog: str,
    args: argparse.Namespace,
    files: tuple[str, ...],
    compute: Callable[[CommandInputs, Callable[[str], None]], Any],
    protected: Sequence[Path | None] = (),
) -> tuple[list[Path], CommandInputs, Any, float] | int:
    """Check the outputs (never over an input or a `protected` file), load and compute, with a
    progress bar and one-line refusals. `compute(inputs, progress)` calls `progress(label)` as
    each step starts. Returns the outputs to write, the inputs, the result and the seconds the
    computation took; or the exit status (2 bad input, 130 interrupted; nothing written).
    """
    previous = signal.signal(signal.SIGTERM, _terminate)
    bar = None  # shown once the outputs are known to be writable: a refusal stays one line
    try:
        others = [path for _, path in args.others]
        inputs = [*args.inputs, *args.table, *others, args.model, *protected]
        written = check_output(args.out, [p for p in inputs if p], args.force, files)
        bar = tqdm(  # on a terminal only: a log or a pipe gets the refusal as one line
            desc=prog.split()[-1], unit="step", file=sys.stderr, leave=False, disable=None
        )
        shown = bar

        def progress(label: str) -> None:
            shown.update(1)
            shown.set_postfix_str(label)

        shown.set_postfix_str("read inputs")
        evidence = load_evidence(args)
        t0 = time.perf_counter()
        result = compute(evidence, progress)
        return written, evidence, result, time.perf_counter() - t0
    except (*bad_input_errors(), *bad_input()) as exc:
        _close(bar)
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        _close(bar)
        print(f"{prog}: interrupted; nothing written", file=sys.stderr)
        return 130
    finally:
        _close(bar)
        signal.signal(signal.SIGTERM, previous)


def _close(bar: tqdm | None) -> None:
    if bar is not None:
        bar.close()
