"""`flaair live`'s arguments turned into the graph's inputs: which declared graph it runs, the
addresses it is given (checked, the error naming the option), and each node's parameter
overrides for the run (`node_parameters_for`, a ROS params file's sections); the health
monitor's saved baseline, an option `flaair experiment` shares (`add_health_baseline`).
"""

from __future__ import annotations

import argparse
import socket
from pathlib import Path
from typing import Any

import yaml

from flaair_model import settings
from flaair_tools.orchestration.graphs import GRAPHS, GraphDecl, node_of

__all__ = [
    "LiveError",
    "add_health_baseline",
    "host_port",
    "live_graph",
    "node_parameters_for",
    "port_free",
]


class LiveError(RuntimeError):
    """The live graph could not run; the message says why."""


def add_health_baseline(parser: argparse.ArgumentParser) -> None:
    """--health-baseline HEALTH.json: the health monitor's saved baseline (`baseline_file`)."""
    parser.add_argument(
        "--health-baseline",
        type=Path,
        metavar="HEALTH.json",
        help="the health monitor judges against this healthy run's baseline (a `flaair health` "
        "health.json of this robot, same model and calibration) from the first wingbeat, so a "
        "change during the K_r ramp is reported (default: it learns one after the ramp)",
    )


def live_graph(args: argparse.Namespace) -> GraphDecl:
    """The declared graph this run brings up (graphs.GRAPHS: live_sim or live_target)."""
    return GRAPHS["live_sim" if args.sim else "live_target"]


def host_port(text: str, what: str) -> tuple[str, int]:
    """'HOST:PORT' -> (host, port), with an error that names the option."""
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise LiveError(f"{what} {text!r}: expected HOST:PORT, e.g. 127.0.0.1:25000")
    return host, int(port)


def port_free(address: tuple[str, int], what: str) -> None:
    """Refuse, by name, a TCP address that another program already listens on."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        # as a server binds: a port only in TIME_WAIT is free, one with a listener is not
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind(address)
        except OSError as exc:
            raise LiveError(
                f"{what} {address[0]}:{address[1]}: port in use ({exc.strerror})"
            ) from None


def node_parameters_for(args: argparse.Namespace) -> dict[str, dict[str, Any]]:
    """Per-node overrides of config/flaair.yaml for this run (a ROS params file's sections)."""
    live = settings.live()
    block = settings.controller().block_size if args.sim else live.target_block_size
    sections: dict[str, dict[str, Any]] = {
        "frontend_node": {"gains_from": "calibration", "calibration_file": str(args.calibration)}
        if args.calibration
        else {},
        # the films' lags turned back and their gains as ratios to the calibration's, as
        # `flaair health --calibration` reruns it
        "health_node": {"calibration_file": str(args.calibration)} if args.calibration else {},
        # free flapping: wingbeats between stroke crossings, decided one wingbeat at a time
        "collision_monitor_node": {"window_source": "stroke", "decision": "distortion"},
        # the controller starts once the actuator's node and the recorder listen; live stops it
        "dsa_controller_node": {
            "run_time_s": 0.0,
            "min_drive_subscribers": 2 if args.out is not None else 1,
            "min_state_subscribers": 1 if args.out is not None else 0,
        },
    }
    # ControllerState travels on DDS one message per batch of blocks, as the block streams
    if not args.processes:
        sections["dsa_controller_node"]["state_every_blocks"] = live.dds_batch_blocks
        # the loop starts once the recorder is matched on every stream,
        # not only on /flaair/drive: this process listens to every batched
        # stream until then (Watcher), so the recorder makes it two
        sections["dsa_controller_node"]["min_stream_listeners"] = 2 if args.out is not None else 0
    for role, overrides in live_graph(args).parameters.items():
        sections.setdefault(node_of(role).node_name, {}).update(overrides)
    if not args.sim:
        (target_host, target_port), (listen_host, listen_port) = args.target, args.listen
        lead = (
            args.lead_samples if args.lead_samples is not None else settings.bridge().lead_samples
        )
        sections["bridge_node"] = {
            "listen_host": listen_host,
            "listen_port": listen_port,
            "target_host": target_host,
            "target_port": target_port,
            "lead_samples": lead,
        }
        # the bridge re-blocks the target's packets to this
        sections["/**"] = {"block_size": block}
        # the lead is loop delay too: the controller's phase advance covers it
        sections["dsa_controller_node"]["blocks_in_flight"] = 1 + -(-lead // block)
        for key, _, value in (item.partition("=") for item in args.bridge_param):
            sections["bridge_node"][key] = yaml.safe_load(value)
    if args.health_baseline is not None:
        sections["health_node"]["baseline_file"] = str(args.health_baseline)
    if args.out is not None:
        sections["recorder_node"] = {"output_path": str(args.out)}
    if args.foxglove is not None:
        sections["foxglove_node"] = {"host": args.foxglove[0], "port": args.foxglove[1]}
    return {name: {"ros__parameters": values} for name, values in sections.items()}
