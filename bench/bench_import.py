"""`flaair import` of a 200 MB measured-run CSV: peak memory against the file's size.

Each figure runs in its own child process (its peak RSS, VmHWM, is its own): `flaair import`
(lines counted, rows parsed a block at a time straight into float64 arrays of that length,
messages made and streamed into the bag a block at a time, block_size 10 as config/flaair.yaml
sets it) against the same-run baseline of reading the whole file at once (csv.reader over every
row, then numpy), which is how the reader worked first. Target: import peak < 2x the file size.

Run: scripts/in_env.sh python bench/bench_import.py [--mb 200]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchlib import REPO_ROOT, compare, info, print_table, write_json

FS_HZ = 20000.0

# VmHWM is the child's own peak; ru_maxrss would carry this process's across fork and exec
PEAK = """
def peak_bytes():
    with open("/proc/self/status") as status:
        return 1024 * int(next(l for l in status if l.startswith("VmHWM:")).split()[1])
"""
CHILD_IMPORT = (
    PEAK
    + """
import sys
from flaair_tools.bagio.import_runs import import_runs
from pathlib import Path
import_runs([Path(sys.argv[1])], Path(sys.argv[2]), gap_s=1.0, block_size=10, frame_id='robot')
print(peak_bytes())
"""
)
CHILD_WHOLE = (
    PEAK
    + """
import csv, sys
import numpy as np
with open(sys.argv[1], newline='') as handle:
    rows = list(csv.reader(handle))
columns = {name: np.array([row[i] for row in rows[1:]], dtype=np.float64)
           for i, name in enumerate(rows[0])}
print(peak_bytes())
"""
)
CHILD_BASE = (
    PEAK
    + """
import flaair_tools.bagio.import_runs
print(peak_bytes())
"""
)


def write_csv(path: Path, megabytes: float) -> int:
    """A chirp-like measured run of about `megabytes` MB at 20 kHz (with ground truth)."""
    rng = np.random.default_rng(0)
    bytes_per_row = 64
    rows = int(megabytes * 1e6 / bytes_per_row)
    with open(path, "w") as handle:
        handle.write("time_s,drive_v,stroke_sensor_v,pitch_sensor_v,stroke_deg,pitch_deg\n")
        for start in range(0, rows, 500_000):
            n = min(500_000, rows - start)
            t = (start + np.arange(n)) / FS_HZ
            drive = 100.0 * np.sin(2 * np.pi * 120.0 * t)
            table = np.column_stack(
                [
                    t,
                    drive,
                    1.25 + 0.1 * np.sin(2 * np.pi * 120.0 * t) + rng.normal(0, 0.002, n),
                    1.25 + 0.05 * np.cos(2 * np.pi * 120.0 * t),
                    30 * np.sin(2 * np.pi * 120.0 * t),
                    20 * np.cos(2 * np.pi * 120.0 * t),
                ]
            )
            np.savetxt(handle, table, delimiter=",", fmt="%.9g")
    return path.stat().st_size


def child_peak_bytes(code: str, *args: str) -> tuple[int, float]:
    """(peak RSS in bytes, wall seconds) of `code` run in a fresh interpreter."""
    start = time.perf_counter()
    result = subprocess.run(
        [sys.executable, "-c", code, *args], capture_output=True, text=True, check=True
    )
    return int(result.stdout.split()[-1]), time.perf_counter() - start


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mb", type=float, default=200.0, help="CSV size to import [MB]")
    parser.add_argument(
        "--json", type=Path, default=REPO_ROOT / "out" / "bench" / "bench_import.json"
    )
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        csv_path = Path(tmp) / "big.csv"
        size = write_csv(csv_path, args.mb)
        base, _ = child_peak_bytes(CHILD_BASE)
        whole, whole_s = child_peak_bytes(CHILD_WHOLE, str(csv_path))
        peak, import_s = child_peak_bytes(CHILD_IMPORT, str(csv_path), str(Path(tmp) / "bag"))
    mb = 1e6
    figures = [
        compare(
            f"import {size / mb:.0f} MB CSV: peak RSS / file size",
            peak / size,
            "x",
            "<",
            2.0,
            f"whole-file read alone: {whole / size:.2f}x ({whole / mb:.0f} MB)",
        ),
        compare(
            "import: peak RSS",
            peak / mb,
            "MB",
            "<",
            int(20 * size / mb) / 10,  # twice the file, down to the 0.1 MB printed
            f"the bound is twice the file's {size / mb:.2f} MB; interpreter + imports alone: "
            f"{base / mb:.0f} MB",
        ),
        info(
            "import: wall time",
            import_s,
            "s",
            f"whole-file read alone: {whole_s:.1f} s",
        ),
    ]
    print_table(figures)
    write_json(figures, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
