"""emulated_target: plays the real-time target's side of the UDP protocol around the plant model.

Rehearse a bench session without hardware: this program stands where the lab's real-time
target (a Speedgoat) stands. Every n samples, paced by the wall clock at the sample rate, it
sends a sensor packet (the drive it applied and the simulated charge-amplifier outputs of the
plant model, flaair_sim.core.plant) to the bridge, and it applies the drive packets it receives:

- a drive sample is applied at its index if it arrived in time; one that arrives after its
  index has passed is discarded and counted late. A packet's drive is decided at the packet's
  first sample, so every sample of it must be there by then (a real target is as strict or
  more lenient);
- with no drive sample for an index it holds the last applied value for at most
  --hold-samples, then applies zero and sets flags bit 0 until fresh drive arrives (watchdog);
- every applied sample is clamped to +-target_drive_limit_v (the amplifier's safe range);
- packets with the wrong magic, a wrong length or a non-finite value are dropped whole;
- a stop packet zeroes the drive at once and holds it at zero until drive for a later index
  arrives.

A damaged robot (--damage-at S --damage inertia_factor=0.95 ...): from that signal time on the
plant runs on the damaged model (`flaair_sim.core.damage`), as plant_node's damage_* parameters
do, to rehearse what the health monitor reports against a target.

At exit (--duration reached, Ctrl-C or SIGTERM) it prints its counters as one line of strict
JSON (and writes them to --counters): samples late, missing (applied without a fresh drive
sample while being driven), fresh, dropped packets, stops, watchdog trips, its own overruns and
stalls (a packet sent more than --stall-ms late: the machine held the target's own clock, which
a real target's does not) with the samples missing during a stall or as long after it as it
lasted (`stall_missing_samples`: the loop, held too, catching up).
Written from docs/REALTIME_PROTOCOL.md alone, with its own packing (struct): it does not use
flaair_bridge.core.protocol, so the two implementations check each other.

Usage: bin/flaair run flaair_bridge emulated_target --duration 10 --counters out/target.json
"""

from __future__ import annotations

import argparse
import json
import math
import os
import select
import signal
import socket
import struct
import sys
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numba import njit
from tqdm import tqdm

from flaair_common.cli_help import HelpFormatter
from flaair_common.realtime import take_realtime_priority
from flaair_model.config import ConfigError, node_parameters

# magic, sequence, first_sample_index, sample_rate_hz, n, flags
SENSOR_HEAD = struct.Struct("<4sIQfHH")
DRIVE_HEAD = struct.Struct("<4sIQHH")  # magic, sequence, first_sample_index, m, flags
WATCHDOG_FLAG = 1
STOP_FLAG = 1
RING = 1 << 16  # drive samples buffered ahead (3.3 s at 20 kHz)


@dataclass
class TargetCore:
    """The target's drive logic, no I/O: buffer drive packets, decide each sample's drive."""

    hold_samples: int
    drive_limit_v: float
    values: np.ndarray = field(default_factory=lambda: np.zeros(RING))
    tags: np.ndarray = field(default_factory=lambda: np.full(RING, -1, dtype=np.int64))
    next_index: int = 0  # first index not yet decided
    last_v: float = 0.0
    missing_run: int = 0
    armed: bool = False  # fresh drive seen since start / the last stop
    tripped: bool = False
    stop_index: int = 0  # drive for indices below this (sent before a stop) is ignored
    applied_v: float = 0.0  # the drive applied at the last sample
    counts: dict = field(
        default_factory=lambda: dict.fromkeys(
            (
                "drive_packets",
                "dropped_packets",
                "late_samples",
                "ignored_after_stop_samples",
                "too_far_ahead_samples",
                "fresh_samples",
                "missing_samples",
                "held_samples",
                "zeroed_samples",
                "clamped_samples",
                "watchdog_trips",
                "stop_packets",
            ),
            0,
        )
    )

    def receive(self, data: bytes) -> None:
        """One datagram from FLAAIR: validate, then buffer its drive (or honour a stop)."""
        if len(data) < DRIVE_HEAD.size:
            self.counts["dropped_packets"] += 1
            return
        magic, _sequence, first, m, flags = DRIVE_HEAD.unpack_from(data)
        if magic != b"FLD1" or not 1 <= m <= 1000 or len(data) != DRIVE_HEAD.size + 4 * m:
            self.counts["dropped_packets"] += 1
            return
        drive = np.array(struct.unpack_from(f"<{m}f", data, DRIVE_HEAD.size))
        if not all(math.isfinite(v) for v in drive):
            self.counts["dropped_packets"] += 1
            return
        self.counts["drive_packets"] += 1
        if flags & STOP_FLAG:
            self.counts["stop_packets"] += 1
            self.armed, self.tripped, self.last_v, self.missing_run = False, False, 0.0, 0
            self.tags[:] = -1
            self.stop_index = max(first, self.next_index)
            return
        if first >= self.next_index + RING:  # (also keeps first + m inside int64)
            self.counts["too_far_ahead_samples"] += m
            return
        index = first + np.arange(m)
        late = index < self.next_index
        ignored = ~late & (index < self.stop_index)
        ahead = index >= self.next_index + RING
        self.counts["late_samples"] += int(late.sum())
        self.counts["ignored_after_stop_samples"] += int(ignored.sum())
        self.counts["too_far_ahead_samples"] += int(ahead.sum())
        keep = ~(late | ignored | ahead)
        self.values[index[keep] % RING] = drive[keep]
        self.tags[index[keep] % RING] = index[keep]

    def decide(self, n: int) -> tuple[np.ndarray, int]:
        """Drive applied at the next n samples (clamped) and the packet's flags."""
        out = np.empty(n)
        tally = np.zeros(6, dtype=np.int64)
        self.last_v, self.missing_run, self.armed, self.tripped = _decide(
            self.values,
            self.tags,
            self.next_index,
            self.hold_samples,
            self.drive_limit_v,
            self.last_v,
            self.missing_run,
            self.armed,
            self.tripped,
            out,
            tally,
        )
        for name, count in zip(_TALLY, tally, strict=True):
            self.counts[name] += int(count)
        self.applied_v = float(out[-1])
        self.next_index += n
        return out, WATCHDOG_FLAG if self.tripped else 0


_TALLY = (
    "fresh_samples",
    "clamped_samples",
    "missing_samples",
    "held_samples",
    "zeroed_samples",
    "watchdog_trips",
)


@njit(cache=True)
def _decide(
    values, tags, first, hold_samples, limit, last_v, missing_run, armed, tripped, out, tally
):
    """Per sample: the fresh drive sample (clamped),
    else hold the last for hold_samples, then zero.
    """
    for k in range(out.shape[0]):
        i = first + k
        slot = i % values.shape[0]
        if tags[slot] == i:
            raw = values[slot]
            v = min(max(raw, -limit), limit)
            tally[0] += 1
            tally[1] += v != raw
            last_v, missing_run, armed, tripped = v, 0, True, False
        elif armed:
            tally[2] += 1
            missing_run += 1
            if missing_run > hold_samples:
                tally[5] += not tripped
                tripped, v = True, 0.0
                tally[4] += 1
            else:
                v = last_v
                tally[3] += 1
        else:
            v = 0.0
        out[k] = v
    return last_v, missing_run, armed, tripped


def sensor_packet(
    sequence: int, first: int, rate_hz: float, flags: int, drive_v, stroke_v, pitch_v
) -> bytes:
    """One sensor packet, packed with struct (independent of flaair_bridge.core.protocol)."""
    n = len(drive_v)
    samples = np.column_stack([drive_v, stroke_v, pitch_v]).astype("<f4")
    return SENSOR_HEAD.pack(b"FLS1", sequence % 2**32, first, rate_hz, n, flags) + samples.tobytes()


def _address(text: str, option: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    if not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        print(f"emulated_target: {option} '{text}' is not HOST:PORT", file=sys.stderr)
        raise SystemExit(2)
    return host, int(port)


def parse_args(argv: list[str]) -> argparse.Namespace:
    """The command line over config/flaair.yaml's `emulated_target` defaults, ranges checked."""
    try:
        shared = node_parameters("flaair.yaml", "emulated_target")
    except ConfigError as exc:
        print(f"emulated_target: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    parser = _parser(shared)
    args = parser.parse_args(argv)
    _check_ranges(parser, args)
    return args


def _parser(shared: dict[str, Any]) -> argparse.ArgumentParser:
    """The target's options, their defaults from `shared` (its section of flaair.yaml)."""
    parser = argparse.ArgumentParser(
        prog="emulated_target",
        description=__doc__,
        formatter_class=HelpFormatter,
    )
    parser.add_argument(
        "--bridge",
        default=shared["bridge"],
        help="HOST:PORT the sensor packets go to [%(default)s]",
    )
    parser.add_argument(
        "--listen", default=shared["listen"], help="HOST:PORT drive packets arrive at [%(default)s]"
    )
    parser.add_argument(
        "--duration",
        type=float,
        default=0.0,
        help="stop after this much signal time, s (0: until Ctrl-C)",
    )
    parser.add_argument(
        "--packet-samples",
        type=int,
        default=shared["packet_samples"],
        help="samples per sensor packet n [%(default)s]",
    )
    parser.add_argument(
        "--sample-rate", type=float, default=shared["sample_rate_hz"], help="Hz [%(default)s]"
    )
    parser.add_argument(
        "--hold-samples",
        type=int,
        default=shared["hold_samples"],
        help="watchdog hold before zero [%(default)s]",
    )
    parser.add_argument(
        "--drive-limit-v",
        type=float,
        default=shared["target_drive_limit_v"],
        help="own clamp, V [%(default)s]",
    )
    parser.add_argument(
        "--model", default=shared["model_file"] or None, help="plant model YAML [config/model.yaml]"
    )
    parser.add_argument(
        "--noise",
        action=argparse.BooleanOptionalAction,
        default=shared["noise"],
        help="sensor noise",
    )
    parser.add_argument(
        "--seed", type=int, default=shared["noise_seed"], help="noise seed [%(default)s]"
    )
    parser.add_argument(
        "--damage-at",
        type=float,
        default=-1.0,
        metavar="S",
        help="the robot changes at this signal time, s (< 0: never) [%(default)s]",
    )
    parser.add_argument(
        "--damage",
        action="append",
        default=[],
        metavar="KEY=FACTOR",
        help="what changes, repeatable: " + ", ".join(DAMAGE_KEYS) + " (1: unchanged)",
    )
    parser.add_argument(
        "--counters",
        help="also write the counters (strict JSON) to this file: "
        'once a second of signal while running ("final": '
        "false), and at exit",
    )
    parser.add_argument(
        "--stall-ms",
        type=float,
        default=shared["stall_ms"],
        help="count a packet sent more than this late as a stall (counter `stalls`): the "
        "machine held the target's own clock, which a real target's does not [%(default)s]",
    )
    parser.add_argument(
        "--realtime-priority",
        type=int,
        default=shared["realtime_priority"],
        help="SCHED_FIFO priority of the target's loop, 0: normal scheduling (a "
        "real target is hardware of its own; on a shared machine this keeps "
        "its clock) [%(default)s]",
    )
    return parser


def _check_ranges(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Exit 2 through `parser.error` naming an option out of its range."""
    if not 1 <= args.packet_samples <= 1000:
        parser.error(f"--packet-samples {args.packet_samples}: must be 1..1000")
    if not 0 <= args.realtime_priority <= 99:
        parser.error(f"--realtime-priority {args.realtime_priority}: must be 0..99")
    if (
        args.hold_samples < 0
        or not args.drive_limit_v >= 0
        or not args.sample_rate > 0
        or args.duration < 0
        or not args.stall_ms > 0
    ):
        parser.error(
            "--hold-samples, --drive-limit-v, --duration must be >= 0 and --sample-rate, "
            "--stall-ms > 0"
        )


DAMAGE_KEYS = (
    "inertia_factor",
    "stiffness_factor",
    "stroke_film_gain",
    "pitch_film_gain",
    "actuator_gain",
)


def damage_factors(items: list[str]) -> dict[str, float]:
    """--damage KEY=FACTOR items as {key: factor}; ValueError naming a bad one."""
    factors = dict.fromkeys(DAMAGE_KEYS, 1.0)
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or key not in DAMAGE_KEYS:
            raise ValueError(f"--damage {item!r}: expected KEY=FACTOR, KEY one of {DAMAGE_KEYS}")
        try:
            factors[key] = float(value)
        except ValueError:
            raise ValueError(f"--damage {item!r}: {value!r} is not a number") from None
    return factors


def count_lag(
    stats: dict, lag_s: float, now_s: float, packet_s: float, stall_s: float, stalled_until: float
) -> float:
    """Count a packet sent `lag_s` late at `now_s` (an overrun past one packet, a stall past
    `stall_s`); returns until when (s, the same clock) missing drive samples count as a stall's.
    """
    stats["max_lag_ms"] = max(stats["max_lag_ms"], 1e3 * lag_s)
    stats["overruns"] += lag_s > packet_s
    if lag_s <= stall_s:
        return stalled_until
    stats["stalls"] += 1
    # held this long, the loop needs as long again to catch up on the sensor packets
    return max(stalled_until, now_s + lag_s)


def decide_counting(
    core: TargetCore, n: int, stats: dict, in_stall: bool
) -> tuple[np.ndarray, int]:
    """core.decide(n), its missing samples also counted as the stall's when `in_stall`."""
    missing = core.counts["missing_samples"]
    drive, flags = core.decide(n)
    if in_stall:
        stats["stall_missing_samples"] += core.counts["missing_samples"] - missing
    return drive, flags


def main(argv: list[str] | None = None) -> int:
    stop_requested = False

    def _stop(_signum, _frame) -> None:
        nonlocal stop_requested
        stop_requested = True

    # first: a signal during start-up also ends cleanly, with counters
    signal.signal(signal.SIGINT, _stop)
    signal.signal(signal.SIGTERM, _stop)
    args = parse_args(sys.argv[1:] if argv is None else argv)
    # deferred: these load scipy.signal (1.2-2 s), after the handlers above (a signal meanwhile
    # still ends cleanly) and after the arguments (--help and a bad one answer at once)
    from flaair_model.model_io import load_model
    from flaair_model.validation import ModelError
    from flaair_sim.core import damage, plant

    try:
        model = load_model(args.model)
    except (ModelError, OSError) as exc:
        print(f"emulated_target: --model: {exc}", file=sys.stderr)
        return 2
    try:
        harm = damage.DamageParams(args.damage_at, **damage_factors(args.damage))
    except ValueError as exc:
        print(f"emulated_target: {exc}", file=sys.stderr)
        return 2
    bridge = _address(args.bridge, "--bridge")
    sock = _bound_socket(args)
    if sock is None:
        return 2
    fs, n = args.sample_rate, args.packet_samples
    core = TargetCore(args.hold_samples, args.drive_limit_v)
    params = plant.PlantStepParams(model, fs)
    damaged = plant.PlantStepParams(damage.damaged(model, harm), fs)
    state = plant.initial_state(plant.PlantStepParams(model, fs))
    rng = np.random.default_rng(args.seed) if args.noise else None
    # compile before the clock starts
    state, _ = plant.step(state, plant.PlantInputs(np.zeros(n), None), params)
    TargetCore(args.hold_samples, args.drive_limit_v).decide(n)
    state = plant.initial_state(plant.PlantStepParams(model, fs))
    total = math.ceil(args.duration * fs / n) if args.duration else None
    progress = _progress(total, n / fs)
    stats = dict(_STATS)
    stall_s, stalled_until = 1e-3 * args.stall_ms, -math.inf

    def drain() -> None:
        _drain(sock, core)

    _announce(args, sock, bridge)
    held: bytes | None = None
    t0 = time.monotonic()
    j = 0
    snapshot_every = max(1, round(fs / n))

    def counters(final: bool) -> dict:
        return _counters(core, stats, args, time.monotonic() - t0, final)

    while not stop_requested and (total is None or j <= total):
        due = t0 + j * n / fs
        while (remaining := due - time.monotonic()) > 0 and not stop_requested:
            if select.select([sock], [], [], remaining)[0]:
                drain()
        drain()
        now = time.monotonic()
        stalled_until = count_lag(stats, now - due, now, n / fs, stall_s, stalled_until)
        if held is not None:  # the packet whose last sample was taken just before `due`
            _send(sock, held, bridge, stats)
        if total is not None and j == total:
            break
        was_tripped = core.tripped
        drive, flags = decide_counting(core, n, stats, due <= stalled_until)
        if core.tripped != was_tripped:
            _say_watchdog(core)
        now_params = damaged if harm.active and j * n / fs >= harm.time_s else params
        state, out = plant.step(state, plant.PlantInputs(drive, rng), now_params)
        held = sensor_packet(j, j * n, fs, flags, drive, out.stroke_sensor_v, out.pitch_sensor_v)
        j += 1
        progress(1)
        # the counters so far, once a second of signal
        if args.counters and j % snapshot_every == 0:
            _write_atomically(args.counters, json.dumps(counters(final=False), allow_nan=False))
    sock.close()
    text = json.dumps(counters(final=True), allow_nan=False)
    print(text, flush=True)
    if args.counters:
        _write_atomically(args.counters, text)
    return 0


_STATS = {
    "packets_sent": 0,
    "send_errors": 0,
    "overruns": 0,
    "stalls": 0,
    "stall_missing_samples": 0,
    "max_lag_ms": 0.0,
}


def _bound_socket(args: argparse.Namespace) -> socket.socket | None:
    """The drive receiver's socket, bound to --listen and non-blocking (None: said why)."""
    listen = _address(args.listen, "--listen")
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.bind(listen)
    except OSError as exc:
        print(f"emulated_target: --listen {args.listen}: {exc}", file=sys.stderr)
        sock.close()
        return None
    sock.setblocking(False)
    return sock


def _announce(args: argparse.Namespace, sock: socket.socket, bridge: tuple[str, int]) -> None:
    """The real-time priority it runs without (if so) and what it sends where."""
    if error := take_realtime_priority(args.realtime_priority):
        print(
            f"emulated_target: WARNING: runs without real-time priority {args.realtime_priority} "
            f"({error})",
            file=sys.stderr,
            flush=True,
        )
    print(
        f"emulated target running: {args.sample_rate:g} Hz, {args.packet_samples}-sample packets "
        f"to {bridge[0]}:{bridge[1]}, drive packets on {sock.getsockname()[0]}:"
        f"{sock.getsockname()[1]}, hold {args.hold_samples} samples, limit "
        f"+-{args.drive_limit_v:g} V",
        file=sys.stderr,
        flush=True,
    )


def _counters(
    core: TargetCore, stats: dict, args: argparse.Namespace, wall_s: float, final: bool
) -> dict:
    """What the target counted so far; `final` once it has stopped."""
    return {
        **core.counts,
        **stats,
        "samples": core.next_index,
        "sample_rate_hz": args.sample_rate,
        "packet_samples": args.packet_samples,
        "stall_ms": args.stall_ms,
        "wall_s": wall_s,
        "stopped": not core.armed and core.counts["stop_packets"] > 0,
        "watchdog_tripped_now": core.tripped,
        "final": final,
        "watchdog_tripped_at_exit": core.tripped if final else None,
        "applied_v_at_exit": core.applied_v if final else None,
    }


def _drain(sock: socket.socket, core: TargetCore) -> None:
    """Take every datagram waiting on `sock` into the core."""
    while True:
        try:
            data, sender = sock.recvfrom(65536)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:  # e.g. ICMP port unreachable reported on the socket
            continue
        before = core.counts["drive_packets"], core.counts["stop_packets"]
        core.receive(data)
        # said once each (stderr): a script or test can wait on them instead of guessing a time
        if before[0] == 0 and core.counts["drive_packets"] > 0:
            print(
                f"emulated_target: first drive packet from {sender[0]}:{sender[1]}",
                file=sys.stderr,
                flush=True,
            )
        if core.counts["stop_packets"] > before[1]:
            print(
                f"emulated_target: stop packet {core.counts['stop_packets']} received: drive "
                "zeroed, disarmed",
                file=sys.stderr,
                flush=True,
            )


def _send(sock: socket.socket, packet: bytes, bridge: tuple[str, int], stats: dict) -> None:
    """Send a sensor packet to the bridge, counting it or its error."""
    try:
        sock.sendto(packet, bridge)
        stats["packets_sent"] += 1
    except OSError:
        stats["send_errors"] += 1


def _say_watchdog(core: TargetCore) -> None:
    """Said at each change: a script can wait on the state, not guess a time."""
    print(
        f"emulated_target: drive watchdog {'tripped' if core.tripped else 'cleared'} at "
        f"sample {core.next_index}: "
        f"{'holding zero drive' if core.tripped else 'fresh drive again'}",
        file=sys.stderr,
        flush=True,
    )


def _write_atomically(path: str, text: str) -> None:
    """Replace `path` whole, so a reader never sees half a file."""
    partial = f"{path}.partial"
    with open(partial, "w", encoding="utf-8") as handle:
        handle.write(text + "\n")
    os.replace(partial, path)


def _progress(total: int | None, period_s: float):
    """Tqdm over signal time when a person watches (stderr a terminal), else nothing."""
    if total is None or not sys.stderr.isatty():
        return lambda _k: None
    bar = tqdm(
        total=round(total * period_s, 3),
        unit="s",
        desc="emulated target",
        bar_format="{l_bar}{bar}| {n:.2f}/{total:.2f} s",
    )
    return lambda k: bar.update(k * period_s)


if __name__ == "__main__":
    raise SystemExit(main())
