"""FLAAIR node plumbing, shared by every node and tool.

Load rclpy on import (ROS shells only):
- `params`: declare a node's parameters from its schema (descriptors, units, ranges);
- `runtime`: run a node with clean Ctrl-C/SIGTERM and one-line parameter errors;
- `qos`: the QoS profiles of FLAAIR topics;
- `node`: `FlaairNode`, the Node every FLAAIR node derives from (relative topics, QoS overrides,
  /diagnostics).

Load no rclpy on import:
- `container`: several nodes in one process and executor; `intra`: their in-process streams;
- `blocks`: block messages <-> numpy arrays; `msgdict`: any message <-> dict;
- `graph`: the one launcher (private ROS domain, localhost discovery, parent-death signal);
- `cdr`: numpy CDR codec of the block messages; `msgdefs`: the `.msg` definitions;
- `stream`: block continuity checks; `topics`: topic names; `realtime`: thread scheduling;
- `runcsv`: measured-run CSV; `strictjson`: strict JSON out;
- `diagnostics`: a node's /diagnostics status as data (level, message, values), decided by
  pure functions;
- `signal_ranges`: the plausible range of each measured-run column;
- `outputs`: a command's `--out` checked first (never an input, `--force` to replace);
- `cli_help`: the help formatter of every command line (each option's default shown).
"""

__all__ = [
    "blocks",
    "cdr",
    "cli_help",
    "container",
    "diagnostics",
    "graph",
    "intra",
    "msgdefs",
    "msgdict",
    "node",
    "outputs",
    "params",
    "qos",
    "realtime",
    "runcsv",
    "runtime",
    "signal_ranges",
    "stream",
    "strictjson",
    "topics",
]
