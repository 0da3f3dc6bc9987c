"""`bin/flaair sweep`: simulation studies on a Dask cluster, and the stroke-controller experiments.

    bin/flaair sweep wing-damage --out DIR [--scheduler tcp://HOST:PORT] [--workers N]
    bin/flaair sweep dsa-map     --out DIR [--scheduler tcp://HOST:PORT] [--workers N]
    bin/flaair sweep stroke      --out DIR [--mode dsa|sync]

wing-damage: the stroke frequency, stroke amplitude, pitch amplitude and lift proxy
(amplitude^2 x frequency^2) of a wing whose inertia is scaled 0.5-1.0 (and, on a second axis,
whose aerodynamic damping scales with its area), for a synchronous open-loop drive at the
undamaged resonance, the dSA loop, and the dSA loop with the stroke-amplitude controller; each
relative to the undamaged wing. dsa-map: the dSA loop over mu, kappa and r3: onset, emergent
frequency and amplitude, against the Hopf theory (flaair_control.core.hopf). Both write
DIR/sweep.json (strict JSON, one row per point), DIR/sweep.csv, DIR/*.png and DIR/reading.md.

The grid comes from config/sweeps.yaml, the controller numbers from config/flaair.yaml. Each
task carries a chunk of simulations through one compiled batch
(flaair_analysis.closed_loop), sized for the workers found (`TaskSizing`,
config/sweeps.yaml `tasks:`: ~0.3 s of compute, or an even spread of a small sweep); a row's
result depends on that row alone, so any number of workers and any chunking give the same
numbers. By default a LocalCluster sized to the machine (one single-threaded worker process
per core, bound to 127.0.0.1, no dashboard) runs them and is shut down with the command (also
on Ctrl-C / SIGTERM); --scheduler uses an existing cluster (docs/SWEEPS.md: `dask scheduler` /
`dask worker`, or Slurm through dask-jobqueue). --in-process runs the chunks here (no Dask).

stroke: the stroke controller's three experiments (flaair_tools.sweeps.stroke_experiments), one bag
each in DIR/bags, analysed from the bags: DIR/stroke.json, DIR/stroke_*.png, DIR/reading.md.

Exit codes: 0 done, 2 bad input (one line on stderr), 130 interrupted.

Terms (dSA, Hopf): docs/GLOSSARY.md.
"""

from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path

from flaair_common.cli_help import HelpFormatter
from flaair_model.config import ConfigError, config_dir
from flaair_model.validation import ModelError
from flaair_tools.sweeps.sweep import SUBCOMMANDS, SweepError

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="bin/flaair sweep",
        description=__doc__.split("\n\n")[1],
        formatter_class=HelpFormatter,
        epilog="\n\n".join(__doc__.split("\n\n")[2:]),
    )
    parser.add_argument("study", choices=SUBCOMMANDS, help="which study")
    parser.add_argument(
        "--out",
        required=True,
        type=Path,
        help="output directory (created; files inside are replaced)",
    )
    parser.add_argument(
        "--scheduler",
        help="address of an existing Dask scheduler, tcp://HOST:PORT (default: a local cluster)",
    )
    parser.add_argument(
        "--workers", type=int, help="local cluster: worker processes (default: one per core)"
    )
    parser.add_argument(
        "--in-process", action="store_true", help="run the chunks in this process, no Dask"
    )
    parser.add_argument(
        "--config", type=Path, default=None, help="sweeps file (default: config/sweeps.yaml)"
    )
    parser.add_argument(
        "--mode",
        choices=("dsa", "sync"),
        action="append",
        help="stroke: controller mode(s) (default: config)",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)

    def _terminate(signum: int, _frame: object) -> None:
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, _terminate)
    try:
        # deferred: sweep_report loads matplotlib (0.75 s), which --help never needs
        from flaair_tools.sweeps import sweep_report

        config = args.config or config_dir() / "sweeps.yaml"
        if args.workers is not None and args.workers < 1:
            raise SweepError(f"--workers must be >= 1, got {args.workers}")
        if args.scheduler and not args.scheduler.startswith(
            ("tcp://", "tls://", "inproc://", "ucx://")
        ):
            raise SweepError(f"--scheduler must look like tcp://HOST:PORT, got {args.scheduler!r}")
        args.out.mkdir(parents=True, exist_ok=True)
        return sweep_report.run_study(args, config)
    except (SweepError, ConfigError, ModelError, ValueError, OSError) as exc:
        print(f"flaair sweep: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("flaair sweep: interrupted; cluster shut down", file=sys.stderr)
        return 130
    finally:
        signal.signal(signal.SIGTERM, previous)
