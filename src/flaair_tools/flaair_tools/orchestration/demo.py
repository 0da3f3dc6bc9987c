"""`flaair demo`: run every paper experiment on the
simulated robot, record the bags, write the report.

Runs each experiment of config/experiments.yaml in turn (bags in OUT/bags/<name>), analyses
all bags (OUT/report/report.html and report.json), prints the headline figures beside the
paper's, then runs the model-vs-measurement workflow on the sweeps (OUT/discrepancy) and shows
what it found beside what the simulated bench robot hides. An experiment whose nodes are not
built is skipped and said so.

Example:
  bin/flaair demo --out out/demo
"""

from __future__ import annotations

import argparse
import shutil
import sys
import time
from pathlib import Path
from typing import Any

from ament_index_python.packages import PackageNotFoundError, get_package_prefix

from flaair_common.cli_help import HelpFormatter
from flaair_model.term_entry import term_from_dict
from flaair_tools import discrepancy
from flaair_tools.analysis import calibrate, health_cli
from flaair_tools.analysis.analyze import analyze, print_headline
from flaair_tools.analysis.per_run import AnalysisError
from flaair_tools.orchestration.bench_robot import robot_effects, robot_section
from flaair_tools.orchestration.experiment import (
    ExperimentError,
    ExperimentSpec,
    experiment_roles,
    load_experiments,
    run_experiment,
)
from flaair_tools.orchestration.graphs import node_of


def missing_nodes(spec: ExperimentSpec) -> list[str]:
    """Executables an experiment needs that are not built."""
    missing = []
    for role in experiment_roles(spec):
        package, executable = node_of(role).package, node_of(role).executable
        try:
            prefix = Path(get_package_prefix(package))
        except PackageNotFoundError:
            missing.append(f"{package}/{executable}")
            continue
        script = prefix / "lib" / package / executable
        sources = Path(__file__).resolve().parents[3] / package / package
        if not script.exists() or (sources.exists() and not any(sources.rglob(f"{executable}.py"))):
            missing.append(f"{package}/{executable}")
    return missing


def _record(
    names: list[str], experiments: dict[str, Any], out: Path
) -> tuple[list[Path], Path | None] | int:
    """Each experiment recorded to its bag, the sweeps first (they calibrate the front end for
    the live experiments after them); the bags and the calibration, or the exit status.
    """
    bags_dir = out / "bags"
    bags: list[Path] = []
    calibration: Path | None = None
    # With the model's gains the bench robot's pitch reads 4.3x small and hides collisions.
    names = sorted(
        names,
        key=lambda n: experiments[n].kind not in ("chirp", "stepped_sine") or n == "drive_levels",
    )
    for name in names:
        spec = experiments[name]
        missing = missing_nodes(spec)
        if missing:
            print(f"[demo] skipping {name}: not built yet: {', '.join(missing)}")
            continue
        bag = bags_dir / name
        shutil.rmtree(bag, ignore_errors=True)
        shutil.rmtree(bags_dir / f"{name}.logs", ignore_errors=True)
        print(f"[demo] {name}: {spec.description}")
        live = spec.kind not in ("chirp", "stepped_sine")
        try:
            summary = run_experiment(spec, bag, calibration_file=calibration if live else None)
        except ExperimentError as exc:
            print(f"flaair demo: experiment {name} failed: {exc}", file=sys.stderr)
            return 1
        print(f"[demo]   recorded {sum(summary['message_counts'].values())} messages to {bag}")
        bags.append(bag)
        sweeps = [b for b in bags if b.name in ("characterization_chirp", "stepped_sine")]
        if calibration is None and len(sweeps) == 2:
            print("[demo] calibrating the front end from the chirp and stepped-sine bags")
            argv = [*map(str, sweeps), "--force", "--out", str(out / "calibration")]
            if calibrate.main(argv) != 0:
                print("flaair demo: calibration failed", file=sys.stderr)
                return 1
            calibration = out / "calibration" / "calibration.yaml"
    return bags, calibration


def _print_hidden_robot() -> None:
    """What config/experiments.yaml hid in the simulated bench robot (the answer to compare)."""
    robot = robot_section()
    hidden = ", ".join(f"{name} {params}" for name, params in robot_effects().items()) or "none"
    plant = ", ".join(f"{k} x{f:g}" for k, f in (robot.get("plant") or {}).items()) or "nominal"
    outside = (
        ", ".join(
            term_from_dict(t).expression + " on " + t["acts_on"]
            for t in robot.get("discovered") or []
        )
        or "none"
    )
    print("[demo] hidden in the simulated bench robot (config/experiments.yaml):")
    print(f"[demo]   plant off nominal: {plant}")
    print(f"[demo]   vocabulary effects: {hidden}")
    print(f"[demo]   outside the vocabulary: {outside}")


def _discrepancy_and_health(bags: list[Path], calibration: Path | None, out: Path) -> int:
    """The discrepancy workflow on the sweeps and the health monitor on the damaged-wing run."""
    sweeps = [
        b for b in bags if b.name in ("characterization_chirp", "stepped_sine", "drive_levels")
    ]
    if sweeps:
        print("\n[demo] model vs measurement: what does the nominal model miss in these bags?")
        code = discrepancy.main([*map(str, sweeps), "--force", "--out", str(out / "discrepancy")])
        if code != 0:
            print("flaair demo: the discrepancy workflow failed", file=sys.stderr)
            return 1
        _print_hidden_robot()
    damaged = [b for b in bags if b.name == "wing_damage"]
    if damaged:
        print("\n[demo] the health monitor on the damaged-wing run (the plant lost 20 % inertia):")
        lags = ["--calibration", str(calibration)] if calibration is not None else []
        if health_cli.main([str(damaged[0]), "--out", str(out / "health"), *lags]) != 0:
            print("flaair demo: the health monitor failed", file=sys.stderr)
            return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="flaair demo",
        description=__doc__,
        formatter_class=HelpFormatter,
    )
    parser.add_argument(
        "--out", type=Path, default=Path("out/demo"), help="output directory (default out/demo)"
    )
    parser.add_argument(
        "--only", nargs="*", help="run only these experiments (default: all of them)"
    )
    args = parser.parse_args(argv)
    experiments = load_experiments()
    # a multisine is analysed by `flaair multisine analyze`, not by the report this demo writes
    names = args.only or [n for n, s in experiments.items() if s.kind != "multisine"]
    start = time.monotonic()
    recorded = _record(names, experiments, args.out)
    if isinstance(recorded, int):
        return recorded
    bags, calibration = recorded
    if not bags:
        print("flaair demo: no experiment could run", file=sys.stderr)
        return 1
    try:
        # the paper's figures from the paper's experiments: the damaged-wing run is a transition
        # too, and its damaged wing (higher frequency, smaller stroke) is the health monitor's
        paper_bags = [b for b in bags if b.name != "wing_damage"]
        report = analyze(paper_bags, args.out / "report", calibration_file=calibration)
    except AnalysisError as exc:
        print(f"flaair demo: analysis failed: {exc}", file=sys.stderr)
        return 1
    print()
    print_headline(report)
    if (failed := _discrepancy_and_health(bags, calibration, args.out)) != 0:
        return failed
    print(f"\n[demo] done in {time.monotonic() - start:.0f} s.")
    print(f"[demo] report: {args.out / 'report' / 'report.html'}")
    if any(b.name in ("characterization_chirp", "stepped_sine", "drive_levels") for b in bags):
        print(f"[demo] discrepancy report: {args.out / 'discrepancy' / 'report.html'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
