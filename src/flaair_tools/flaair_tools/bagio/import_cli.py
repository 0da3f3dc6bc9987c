"""`flaair import`: a lab's bench runs into one rosbag2 (MCAP) bag.

Two kinds of input, each giving the same bag (drive and sensor blocks on the DAQ clock, ground
truth where the video saw the wing, NaN between, one run marker per run):

  measured-run CSV exports (docs/formats/MEASURED_RUN_CSV.md), any number per call:
    bin/flaair import RUN.csv [RUN.csv ...] --out BAG [--rest-s S] [--kind KIND]

  a real-time target's MAT log with its DLTdv video tracks (DLTdv5 to DLTdv8a) and the
  bench's rig file
  (docs/LAB_FILES.md), one run:
    bin/flaair import RUN.mat --rig RIG.yaml --tracks RUN_xyzpts.csv
                      [--tip-track RUN_xypts.csv] --out BAG
  or a whole session from a manifest (YAML: `rig: RIG.yaml` and `runs:`, a list of
  `{mat: RUN.mat, tracks: RUN_xyzpts.csv, tip_track: RUN_xypts.csv}`, paths relative to it):
    bin/flaair import --manifest SESSION.yaml --out BAG

A lab run's marker records its files, the rig file's text and the sync used (trigger time,
frames placed and dropped, and the offset between the video's stroke and the stroke sensor's
estimate by cross-correlation; over one frame is warned). Every file is checked before anything
is written; a bad file is named with what is wrong (exit 2), and a failed or interrupted import
leaves no bag behind (exit 130, 143 for SIGTERM). Once the bag is whole, a Ctrl-C or SIGTERM
changes nothing: the import ends as a completed one ("wrote BAG", exit 0), saying that it came
late, and no exit handler is interrupted.
"""

from __future__ import annotations

import argparse
import shutil
import signal
import sys
from pathlib import Path

from tqdm import tqdm

from flaair_common.cli_help import HelpFormatter
from flaair_common.runcsv import RunFileError
from flaair_model.config import ConfigError, node_parameters
from flaair_tools import bagio
from flaair_tools.bagio import import_runs as csv_import
from flaair_tools.bagio import lab_import
from flaair_tools.bagio.markers import RUN_KINDS as KINDS
from flaair_tools.bagio.target_log import LabFileError

__all__ = ["main"]


def _interrupted(signum: int, _frame: object) -> None:
    raise KeyboardInterrupt(signum)


LATE_SIGNALS: list[int] = []  # signals that came once the bag was whole


def _bag_complete() -> None:
    """From now on Ctrl-C and SIGTERM are noted, not raised: the bag is whole and stays."""

    def late(signum: int, _frame: object) -> None:
        LATE_SIGNALS.append(signum)

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, late)


def _parser(defaults: dict) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="flaair import",
        description=__doc__,
        formatter_class=HelpFormatter,
    )
    parser.add_argument(
        "runs",
        nargs="*",
        type=Path,
        help="measured-run CSV files, or one MAT log (with --rig and --tracks)",
    )
    parser.add_argument("-o", "--out", type=Path, required=True, help="bag directory to create")
    parser.add_argument(
        "--rest-s",
        "--gap-s",
        dest="gap_s",
        type=float,
        default=float(defaults["gap_s"]),
        metavar="S",
        help="CSV runs: the rest between one run's end and the next run's start on the bag's "
        "timeline [s] (--gap-s is the old name) (default: %(default)s, "
        "config/flaair.yaml import_runs.gap_s)",
    )
    parser.add_argument(
        "--kind",
        choices=[k for k in KINDS if k != "unrecognised"],
        default=None,
        help="the drive of every run given (default: `flaair analyze` recognises "
        "it from the drive)",
    )
    lab = parser.add_argument_group("a lab's MAT log and video tracks (docs/LAB_FILES.md)")
    lab.add_argument("--rig", type=Path, help="the bench's rig file (YAML)")
    lab.add_argument(
        "--tracks", type=Path, help="DLTdv (5 to 8a) 3D points of the run (*_xyzpts.csv)"
    )
    lab.add_argument(
        "--tip-track",
        type=Path,
        help="DLTdv (5 to 8a) 2D points (*_xypts.csv) holding the actuator tip, for "
        "stroke_from: actuator_tip",
    )
    lab.add_argument(
        "--manifest", type=Path, help="a session's runs (YAML; see above) instead of RUN arguments"
    )
    return parser


def _lab_files(
    args: argparse.Namespace, parser: argparse.ArgumentParser
) -> list[lab_import.LabRunFiles] | None:
    """The lab runs asked for, None for CSV runs; usage mistakes exit through the parser."""
    lab_options = [name for name in ("rig", "tracks", "tip_track") if getattr(args, name)]
    mats = [path for path in args.runs if path.suffix.lower() == ".mat"]
    if args.manifest is not None:
        if args.runs or lab_options:
            parser.error(
                "--manifest lists the runs and their files: give no RUN, --rig, "
                "--tracks or --tip-track with it"
            )
        return lab_import.read_manifest(args.manifest)
    if not args.runs:
        parser.error("give RUN.csv files, a RUN.mat with --rig and --tracks, or --manifest")
    if not mats:
        if lab_options:
            parser.error(
                f"--{lab_options[0].replace('_', '-')} goes with a MAT log, not with CSV runs"
            )
        return None
    if len(args.runs) != 1:
        parser.error("one MAT log per call (a session of several: --manifest)")
    if args.rig is None or args.tracks is None:
        parser.error("a MAT log needs --rig RIG.yaml and --tracks RUN_xyzpts.csv")
    return [lab_import.LabRunFiles(mats[0], args.rig, args.tracks, args.tip_track)]


def _summary(marker: bagio.RunMarker, extras: dict) -> str:
    line = (
        f"{marker.run}: {marker.n_samples} samples at {marker.sample_rate_hz:g} Hz "
        f"(first_sample_index {marker.first_sample_index}) from {marker.source_file}"
    )
    if "video" in extras:
        video, sync = extras["video"], extras["sync"]
        line += (
            f"; video {video['fps']:g} fps, {video['frames']} frames "
            f"({100 * video['tracked_share']:.1f} % tracked), {sync['frames_placed']} "
            f"placed, {sync['frames_dropped']} outside the log"
        )
        if sync["trigger_time_s"] is not None:
            line += f"; trigger at {sync['trigger_time_s']:.6f} s"
        if sync["offset_s"] is not None:
            line += (
                f"; video vs stroke sensor {1e3 * sync['offset_s']:+.3f} ms "
                f"(correlation {sync['correlation']:+.3f})"
            )
    return line


def main(argv: list[str] | None = None) -> int:
    """`bin/flaair import ...`; exit 2 naming the file and what is wrong."""
    try:
        defaults = node_parameters(csv_import.CONFIG_FILE, csv_import.SECTION)
        max_lag_s = lab_import.check_max_lag(float(defaults["sync_check_max_lag_s"]))
    except (ConfigError, LabFileError, KeyError) as exc:
        print(f"flaair import: config/{csv_import.CONFIG_FILE}: {exc}", file=sys.stderr)
        return 2
    parser = _parser(defaults)
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    if args.out.exists():
        print(
            f"flaair import: {args.out}: exists already; choose a new bag directory",
            file=sys.stderr,
        )
        return 2
    signal.signal(signal.SIGTERM, _interrupted)
    settings = {
        "gap_s": args.gap_s,
        "block_size": int(defaults["block_size"]),
        "frame_id": str(defaults["frame_id"]),
    }
    try:
        csv_import.check_settings(args.gap_s, settings["block_size"])
        lab_files = _lab_files(args, parser)
        extras: list[dict] = []
        with tqdm(
            total=None,
            unit=" samples",
            unit_scale=True,
            desc="import",
            file=sys.stderr,
            disable=not sys.stderr.isatty(),
        ) as bar:
            if lab_files is None:
                markers = csv_import.import_runs(
                    args.runs,
                    args.out,
                    **settings,
                    kind=args.kind,
                    progress=lambda n: bar.update(n - bar.n),
                )
                extras = [{} for _ in markers]
            else:
                runs = [lab_import.read_lab_run(files, max_lag_s) for files in lab_files]
                csv_import.check_runs(
                    [(f.mat, r.run) for f, r in zip(lab_files, runs, strict=True)]
                )
                for lab_run in runs:
                    for warning in lab_run.warnings:
                        print(f"flaair import: warning: {warning}", file=sys.stderr)
                markers = csv_import.write_runs(
                    [(str(f.mat), r.run, r.extras) for f, r in zip(lab_files, runs, strict=True)],
                    args.out,
                    **settings,
                    kind=args.kind,
                    progress=lambda n: bar.update(n - bar.n),
                )
                extras = [r.extras for r in runs]
        LATE_SIGNALS.clear()
        _bag_complete()  # inside the try: an interruption before this leaves no bag
    except (RunFileError, csv_import.RunSetError, LabFileError, bagio.BagError) as exc:
        shutil.rmtree(args.out, ignore_errors=True)  # it did not exist: nothing of anyone's lost
        print(f"flaair import: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        # the bag writer may have made the directory before its own clean-up could run
        shutil.rmtree(args.out, ignore_errors=True)  # it did not exist when the import began
        signum = int(exc.args[0]) if exc.args else int(signal.SIGINT)
        print(f"flaair import: interrupted; no bag written at {args.out}", file=sys.stderr)
        return 128 + signum
    for marker, extra in zip(markers, extras, strict=True):
        print(_summary(marker, extra))
    print(f"wrote {args.out}")
    if LATE_SIGNALS:
        name = signal.Signals(LATE_SIGNALS[0]).name
        print(f"flaair import: {name} came after the bag was complete: kept", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
