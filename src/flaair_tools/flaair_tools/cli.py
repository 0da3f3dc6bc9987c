"""The `flaair` command line (bin/flaair). Each
subcommand lives in its own module with main(argv).
"""

from __future__ import annotations

import faulthandler
import importlib
import os
import signal
import sys

# name -> (module, one-line help). `run` is handled by bin/flaair itself (it execs the node).
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "topic": (
        "flaair_tools.roscli.topic",
        "list, echo, hz, info and publish topics (stands in for `ros2 topic`: its flags, output)",
    ),
    "param": (
        "flaair_tools.roscli.param",
        "read and set a running node's parameters (stands in for `ros2 param`)",
    ),
    "node": ("flaair_tools.roscli.node_cli", "list the running nodes (stands in for `ros2 node`)"),
    "service": (
        "flaair_tools.roscli.service",
        "list services and call one (stands in for `ros2 service`)",
    ),
    "foxglove": (
        "flaair_tools.liveview.foxglove_cli",
        "serve the live graph to Foxglove / Lichtblick over WebSocket",
    ),
    "simulate": (
        "flaair_sim.simulate_cli",
        "replay a measured run's drive through the model: CSV in, CSV out",
    ),
    "calibrate": (
        "flaair_tools.analysis.calibrate",
        "fit sensor gain and lag against ground truth in bags",
    ),
    "health": (
        "flaair_tools.analysis.health_cli",
        "the health monitor on bags: wing inertia and film gains per wingbeat, change events",
    ),
    "import": (
        "flaair_tools.bagio.import_cli",
        "turn a lab's runs (CSV exports, or MAT logs with DLTdv5-8a tracks) into a bag",
    ),
    "record": (
        "flaair_tools.recorder.recorder_node",
        "record flaair topics to a rosbag2 (MCAP) bag",
    ),
    "play": ("flaair_tools.recorder.player", "replay a bag onto its topics"),
    "bag": (
        "flaair_tools.roscli.bag_cli",
        "bag info (checks every chunk), or reindex (recover) a damaged or unfinished bag",
    ),
    "launch": (
        "flaair_tools.orchestration.launch_cli",
        "run a ROS 2 XML launch file, e.g. flaair_tools lockstep_loop.launch.xml (stands in "
        "for `ros2 launch`)",
    ),
    "live": (
        "flaair_tools.orchestration.live",
        "run the live graph on a real-time target (or --sim) and record it",
    ),
    "experiment": (
        "flaair_tools.orchestration.experiment",
        "run a paper experiment on the simulated robot and record it",
    ),
    "analyze": (
        "flaair_tools.analysis.analyze",
        "analyse bags: Bode, RMSE, collision FFT, Hilbert; HTML report",
    ),
    "import-table": (
        "flaair_tools.tables.import_cli",
        "check a lab's frequency-response table (drive levels x frequencies) and summarise it",
    ),
    "multisine": (
        "flaair_tools.multisine.cli",
        "design a multisine excitation, or analyse its runs: how nonlinear, and where",
    ),
    "discrepancy": (
        "flaair_tools.discrepancy",
        "find where the model is wrong: name the missing effect (runs and/or a table)",
    ),
    "identify": (
        "flaair_tools.discrepancy.identify",
        "fit this robot's plant (frequencies, damping, gain, couplings) to its runs or table",
    ),
    "sweep": (
        "flaair_tools.sweeps.sweep_cli",
        "simulation studies on Dask (wing damage, dSA map) and the stroke-control experiments",
    ),
    "demo": (
        "flaair_tools.orchestration.demo",
        "run every experiment, record bags, write the report",
    ),
}

# The top-level help's groups, by job, in this order; a command in no group is listed last.
GROUPS: tuple[tuple[str, tuple[str, ...]], ...] = (
    (
        "run a bench (the simulated robot, or a real-time target)",
        ("demo", "experiment", "live", "foxglove", "sweep"),
    ),
    ("bring a lab's data", ("import", "import-table")),
    (
        "analyse",
        ("calibrate", "analyze", "identify", "discrepancy", "multisine", "health", "simulate"),
    ),
    (
        "ROS tools (stand-ins for ros2 run, launch, node, topic, param, service, bag)",
        ("run", "launch", "node", "topic", "param", "service", "record", "play", "bag"),
    ),
)
RUN_HELP = "start a node, like `ros2 run`: run <package> <executable> [--ros-args ...]"

USAGE = """usage: bin/flaair <command> [args...]
{commands}

`bin/flaair <command> --help` explains each command, every option with its default.
Guides: README.md and docs/ (terms: docs/GLOSSARY.md). A command or node that seems stuck:
`kill -USR1 PID` writes where each of its threads is to its stderr (a node's: its log)."""


def _usage() -> str:
    # the commands whose package is installed (found without importing it: --help stays quick)
    available = {
        name: text
        for name, (module, text) in SUBCOMMANDS.items()
        if importlib.util.find_spec(module.split(".", 1)[0]) is not None
    }
    available["run"] = RUN_HELP
    grouped = [name for _, names in GROUPS for name in names]
    groups = [*GROUPS, ("other", tuple(n for n in available if n not in grouped))]
    lines = []
    for title, names in groups:
        shown = [n for n in names if n in available]
        if shown:
            lines += ["", f"{title}:", *(f"  {n:14s} {available[n]}" for n in shown)]
    return USAGE.format(commands="\n".join(lines))


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(_usage())
        return 0
    name, rest = argv[0], argv[1:]
    if name not in SUBCOMMANDS:
        print(f"flaair: unknown command '{name}'\n\n{_usage()}", file=sys.stderr)
        return 2
    module_name = SUBCOMMANDS[name][0]
    try:  # a Ctrl-C while numpy, scipy... load (an import's first seconds) is one line too
        module = importlib.import_module(module_name)
        return int(module.main(rest) or 0)
    except ModuleNotFoundError as exc:
        if exc.name and module_name.startswith(exc.name):
            print(f"flaair: command '{name}' is not built yet", file=sys.stderr)
            return 2
        raise
    except (KeyboardInterrupt, ImportError) as exc:
        # a Ctrl-C inside a compiled module's initialisation (scipy's, rclpy's pybind11 code)
        # comes out as "ImportError: initialization failed" caused by the KeyboardInterrupt
        if not _caused_by_interrupt(exc):
            raise
        print(f"flaair {name}: interrupted; nothing written", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader of stdout went away (`| head`): the rest is not wanted
        _quiet_stdout()
        return EXIT_BROKEN_PIPE


def _caused_by_interrupt(exc: BaseException) -> bool:
    """Whether a KeyboardInterrupt is in ``exc``'s chain of causes."""
    seen: set[int] = set()
    current: BaseException | None = exc
    while current is not None and id(current) not in seen:
        if isinstance(current, KeyboardInterrupt):
            return True
        seen.add(id(current))
        current = current.__cause__ or current.__context__
    return False


EXIT_BROKEN_PIPE = 141  # 128 + SIGPIPE, what a shell reports for a tool its pipe's reader left


def _quiet_stdout() -> None:
    """Point stdout at /dev/null: the interpreter's last flush meets no closed pipe."""
    try:
        descriptor = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # not a file (captured): nothing to flush
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, descriptor)
    os.close(devnull)


if __name__ == "__main__":
    # `kill -USR1 PID` writes every thread's stack to stderr (where is a command stuck?)
    faulthandler.register(signal.SIGUSR1, all_threads=True)
    sys.exit(main())
