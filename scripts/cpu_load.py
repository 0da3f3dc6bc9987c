"""Load every core (or --workers N) with busy work until killed or --duration runs out.

A stand-in for `stress --cpu N`, so the graph tests' reliability can be checked on a busy machine
with nothing but the project's own environment (scripts/soak_graph_tests.sh).
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import signal
import time


def _spin(deadline: float) -> None:
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    x = 0
    while time.monotonic() < deadline:
        for i in range(100_000):  # plain integer work: one core, no memory traffic to speak of
            x = (x * 31 + i) & 0xFFFF_FFFF


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument(
        "--workers",
        type=int,
        default=os.cpu_count() or 1,
        help="busy processes (default: one per core)",
    )
    parser.add_argument(
        "--duration",
        type=float,
        default=3600.0,
        metavar="S",
        help="stop after S seconds (default 1 h)",
    )
    args = parser.parse_args()
    deadline = time.monotonic() + args.duration
    workers = [
        multiprocessing.Process(target=_spin, args=(deadline,), daemon=True)
        for _ in range(args.workers)
    ]
    for worker in workers:
        worker.start()

    def stop(*_: object) -> None:
        for worker in workers:
            worker.terminate()
        raise SystemExit(0)

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    for worker in workers:
        worker.join()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
