"""Graphs brought up and run: the paper experiments, `live`, the demo, the transition figure.

Modules (import them by name; this package imports none of them eagerly):
- `bench_robot`: the simulated bench robot (its plant, hidden effects and discovered terms)
- `experiment`: `bin/flaair experiment`: one paper experiment on the simulated robot, recorded
- `graphs`: the declared nodes and graphs, read from the launch files
- `launch_file`: the ROS 2 XML launch-file reader (no ROS)
- `launch_cli`: `bin/flaair launch`: run a launch file
- `live`: `bin/flaair live`: the live graph around a target (or --sim)
- `live_args`: live's arguments turned into the graph's inputs (addresses, node parameters)
- `demo`: `bin/flaair demo`: every experiment, then the report
- `second_terminal`: the lines a second terminal needs to join a graph's private domain
- `transition_figure`: the sync -> async transition figure
"""

__all__ = [
    "bench_robot",
    "demo",
    "experiment",
    "graphs",
    "launch_cli",
    "launch_file",
    "live",
    "live_args",
    "second_terminal",
    "transition_figure",
]
