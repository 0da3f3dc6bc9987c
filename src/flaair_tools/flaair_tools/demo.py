"""`flaair demo`: run every paper experiment on the simulated robot, record the bags, write the report.

Runs each experiment of config/experiments.yaml in turn (bags in OUT/bags/<name>), analyses
all bags (OUT/report/report.html and report.json) and prints the headline figures beside the
paper's. An experiment whose nodes are not built is skipped and said so.

Example:
  bin/flaair demo --out out/demo
"""
from __future__ import annotations

import argparse
import shutil
import sys
import time
from pathlib import Path

from ament_index_python.packages import PackageNotFoundError, get_package_prefix

from flaair_tools.analyze import AnalysisError, analyze, print_headline
from flaair_tools.experiment import NODE_EXECUTABLES, ExperimentError, ExperimentSpec, load_experiments, run_experiment


def missing_nodes(spec: ExperimentSpec) -> list[str]:
    """Executables an experiment needs that are not built."""
    roles = ["plant", "frontend", "recorder", *spec.nodes, "controller" if spec.controller else "drive"]
    missing = []
    for role in roles:
        package, executable = NODE_EXECUTABLES[role]
        try:
            prefix = Path(get_package_prefix(package))
        except PackageNotFoundError:
            missing.append(f"{package}/{executable}")
            continue
        script = prefix / "lib" / package / executable
        module = executable
        source = Path(__file__).resolve().parents[2] / package / package / f"{module}.py"
        if not script.exists() or (source.parent.exists() and not source.exists()):
            missing.append(f"{package}/{executable}")
    return missing


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="flaair demo", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=Path("out/demo"), help="output directory (default out/demo)")
    parser.add_argument("--only", nargs="*", help="run only these experiments")
    args = parser.parse_args(argv)
    experiments = load_experiments()
    names = args.only or list(experiments)
    bags_dir = args.out / "bags"
    bags: list[Path] = []
    start = time.monotonic()
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
        try:
            summary = run_experiment(spec, bag)
        except ExperimentError as exc:
            print(f"flaair demo: experiment {name} failed: {exc}", file=sys.stderr)
            return 1
        print(f"[demo]   recorded {sum(summary['message_counts'].values())} messages to {bag}")
        bags.append(bag)
    if not bags:
        print("flaair demo: no experiment could run", file=sys.stderr)
        return 1
    try:
        report = analyze(bags, args.out / "report")
    except AnalysisError as exc:
        print(f"flaair demo: analysis failed: {exc}", file=sys.stderr)
        return 1
    print()
    print_headline(report)
    print(f"\n[demo] done in {time.monotonic() - start:.0f} s. Report: {args.out / 'report' / 'report.html'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
