"""`flaair bag`: inspect a rosbag2 (MCAP) bag, or recover a damaged or unfinished one.

  bin/flaair bag info BAG       topics, types, counts, time span; then every chunk is read and
                                checked (CRC), and damage is reported (exit 1) - `--quick` skips it
  bin/flaair bag reindex BAG    rebuild the bag from what its MCAP file still holds: complete
                                chunks, the readable part of a chunk cut off by the end of the
                                file (kill -9, a copy cut short) and of a corrupt chunk. The
                                copy is verified with rosbags and the mcap library before it
                                replaces the original; a damaged original is kept as *.mcap.damaged.

Exit codes: 0 nothing lost (for a killed recorder: every message that reached the disk);
1 the bag is damaged (info) or messages were lost (reindex: counts per topic are printed);
2 not a bag, or it cannot be read or rebuilt (nothing was changed); 130/143 interrupted.
"""

from __future__ import annotations

import argparse
import signal
import sys
import time
from pathlib import Path

from tqdm import tqdm

from flaair_common.cli_help import HelpFormatter
from flaair_tools import bagio

_NS_PER_S = 1_000_000_000


def _interrupted(signum: int, _frame: object) -> None:
    raise KeyboardInterrupt(signum)


def _reindex(bag: Path) -> int:
    source = bagio.single_mcap_file(bag)
    start = time.perf_counter()
    with tqdm(
        total=source.stat().st_size,
        unit="B",
        unit_scale=True,
        desc="reindex",
        file=sys.stderr,
        disable=not sys.stderr.isatty(),
    ) as bar:
        report = bagio.reindex(bag, progress=lambda offset: bar.update(offset - bar.n))
    print(f"{report.path}: read up to {report.stopped_at} in {time.perf_counter() - start:.2f} s")
    for line in report.damage:
        print(f"  damaged: {line}")
    width = max((len(t) for t in report.topics), default=0)
    for topic, counts in report.topics.items():
        lost = "unknown" if counts.lost is None else str(counts.lost)
        print(f"  {topic:{width}s}  kept {counts.kept:8d}  lost {lost:>8s}")
    if report.unverified_dropped:
        print(
            f"  {report.unverified_dropped} undecodable message record(s) from damaged chunks "
            "dropped"
        )
    if report.partial_tail:
        print("  the file ends inside a chunk: what it held past the cut never reached the disk")
    if report.backup is not None:
        print(f"  the damaged original is kept as {report.backup}")
    if report.lost or report.backup is not None:
        print(
            f"flaair bag reindex: {report.path}: {report.lost} message(s) lost; the bag now "
            f"holds {sum(report.counts.values())}",
            file=sys.stderr,
        )
        return 1
    return 0


def _info(bag: Path, quick: bool) -> int:
    info = bagio.bag_info(bag)
    span_s = max(0, info.end_ns - info.start_ns) / _NS_PER_S
    print(f"{info.path}: {info.message_count} messages, {span_s:.6f} s")
    for topic, topic_info in sorted(info.topics.items()):
        print(f"  {topic} [{topic_info.msgtype}] {topic_info.count}")
    for key, value in sorted(info.custom_data.items()):
        print(f"  custom_data {key}: {value[:200]}")
    if quick:
        return 0
    log, readable = bagio.check_bag(bag)
    if not log.damaged:
        return 0
    for line in bagio.damage_lines(log):
        print(f"  damaged: {line}")
    unreadable = {
        t: info.topics[t].count - readable.get(t, 0)
        for t in info.topics
        if info.topics[t].count > readable.get(t, 0)
    }
    listing = ", ".join(f"{t} {n}" for t, n in sorted(unreadable.items())) or "count unknown"
    print(
        f"flaair bag info: {bag}: DAMAGED, messages listed but unreadable: {listing}; "
        f"recover what is left with: bin/flaair bag reindex {bag}",
        file=sys.stderr,
    )
    return 1


def main(argv: list[str] | None = None) -> int:
    """`flaair bag info BAG` / `flaair bag reindex BAG`; see the module docstring for exit codes."""
    parser = argparse.ArgumentParser(
        prog="flaair bag", description=__doc__, formatter_class=HelpFormatter
    )
    sub = parser.add_subparsers(dest="verb", required=True)
    info = sub.add_parser(
        "info",
        formatter_class=HelpFormatter,
        help="topics, types, counts, time span; checks every chunk",
    )
    info.add_argument("bag", type=Path)
    info.add_argument("--quick", action="store_true", help="do not read the chunks to check them")
    sub.add_parser(
        "reindex",
        formatter_class=HelpFormatter,
        help="recover a damaged bag or one whose recorder was killed",
    ).add_argument("bag", type=Path)
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    signal.signal(signal.SIGTERM, _interrupted)
    try:
        return _reindex(args.bag) if args.verb == "reindex" else _info(args.bag, args.quick)
    except KeyboardInterrupt as exc:
        signum = exc.args[0] if exc.args else signal.SIGINT
        print(f"flaair bag: interrupted; {args.bag} is unchanged", file=sys.stderr)
        return 128 + int(signum)
    except (bagio.BagError, OSError) as exc:
        print(f"flaair bag: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
