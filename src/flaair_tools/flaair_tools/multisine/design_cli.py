"""`flaair multisine design --out DIR`: an odd random-phase multisine a lab loads into its
real-time target (or `flaair experiment multisine` plays on the simulated robot).

Writes DIR/realization_<m>.csv (time_s, drive_v; (T + P) N rows each) and DIR/multisine.yaml
(the lines, the phases the CSVs were computed from, the seed). The odd lines of the band are
taken in groups of G and one of each complete group is left out (an odd detection line); no
even line is excited. ../shared/multisine.md and docs/MULTISINE.md say the rest.

Exit status: 0 written, 2 on a bad option (one line naming it; nothing written).

Examples
--------
  bin/flaair multisine design --out examples/multisine/design --seed 51
  bin/flaair multisine design --band 60:200 --base-hz 1 --rms-v 20 --realizations 6 --out ms60
"""

from __future__ import annotations

import argparse
import secrets
import sys
from pathlib import Path

import numpy as np

from flaair_analysis.multisine.design import DesignError, design_multisine, realization_drive
from flaair_common.cli_help import HelpFormatter
from flaair_common.outputs import OutputError, check_output, write_outputs

from .design_file import DESIGN_FILE, dump_design, realization_file

PROG = "flaair multisine design"


def parse_band(text: str) -> tuple[float, float]:
    """'F1:F2' in Hz."""
    try:
        low, high = (float(v) for v in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--band {text!r}: expected F1:F2 in Hz") from None
    return low, high


def parser() -> argparse.ArgumentParser:
    """The command's options (defaults: the contract's)."""
    p = argparse.ArgumentParser(prog=PROG, description=__doc__, formatter_class=HelpFormatter)
    p.add_argument("--out", type=Path, required=True, help="directory to create")
    p.add_argument("--band", type=parse_band, default=(100.0, 250.0), help="F1:F2 excited [Hz]")
    p.add_argument("--base-hz", type=float, default=2.0, help="f0; fs/f0 whole [Hz]")
    p.add_argument("--lines-per-group", type=int, default=3, help="one odd line of G left out")
    p.add_argument("--rms-v", type=float, default=25.0, help="RMS of the drive [V]")
    p.add_argument("--periods", type=int, default=4, help="steady-state periods P (>= 2)")
    p.add_argument("--transient-periods", type=int, default=1, help="periods T before them")
    p.add_argument("--realizations", type=int, default=4, help="phase draws M, one run each")
    p.add_argument("--fs", type=float, default=20000.0, help="sample rate [Hz]")
    p.add_argument("--max-v", type=float, default=100.0, help="refuse a peak above this [V]")
    p.add_argument("--seed", type=int, default=None, help="phase seed (default: drawn)")
    p.add_argument("--force", action="store_true", help="write into an existing non-empty DIR")
    return p


def main(argv: list[str] | None = None) -> int:
    """`flaair multisine design`; returns the exit status."""
    args = parser().parse_args(argv)
    seed = secrets.randbelow(2**32) if args.seed is None else args.seed
    try:
        design = design_multisine(
            band_hz=args.band,
            base_hz=args.base_hz,
            lines_per_group=args.lines_per_group,
            rms_v=args.rms_v,
            periods=args.periods,
            transient_periods=args.transient_periods,
            realizations=args.realizations,
            fs_hz=args.fs,
            max_v=args.max_v,
            seed=seed,
        )
        files = [realization_file(m) for m in range(design.realizations)] + [DESIGN_FILE]
        if args.out.is_dir() and any(args.out.iterdir()) and not args.force:
            raise OutputError(f"--out {args.out}: exists and is not empty (--force writes in it)")
        written = check_output(args.out, [], True, files)
    except (DesignError, OutputError) as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return 2
    time_s = np.arange(design.n_samples) / design.fs_hz

    def write_files(stage: Path) -> None:
        for m in range(design.realizations):
            table = np.column_stack([time_s, realization_drive(design, m)])
            with open(stage / realization_file(m), "w", encoding="utf-8") as handle:
                handle.write("time_s,drive_v\n")
                np.savetxt(handle, table, delimiter=",", fmt="%.10g")
        (stage / DESIGN_FILE).write_text(dump_design(design), encoding="utf-8")

    if (failed := write_outputs(PROG, args.out, written, write_files)) is not None:
        return failed
    print(
        f"{PROG}: {design.realizations} realization(s) of {len(design.excited_lines)} excited "
        f"lines ({len(design.odd_detection_lines)} odd detection lines), N = "
        f"{design.period_samples} at {design.fs_hz:g} Hz, {design.rms_v:g} V rms, seed {seed} "
        f"-> {args.out}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
