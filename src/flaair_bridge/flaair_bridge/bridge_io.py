"""The bridge node's parameters (their values: config/flaair.yaml, section bridge_node)."""
from __future__ import annotations

from flaair_common.params import ParamSpec

PARAMS = [
    ParamSpec("sample_rate_hz", float, "Sample rate of the target and every block stream [Hz]", 1000.0, 1.0e6, read_only=True),
    ParamSpec("block_size", int, "Samples per published block", 1, 1000, read_only=True),
    ParamSpec("drive_limit_v", float, "Drive clamped to +-this before it is sent [V]", 0.0, 300.0, read_only=True),
    ParamSpec("listen_host", str, "Address the target's sensor packets arrive at", read_only=True),
    ParamSpec("listen_port", int, "UDP port the target's sensor packets arrive at", 1, 65535, read_only=True),
    ParamSpec("target_host", str, "Where drive packets go (empty: the sender of the sensor packets)", read_only=True),
    ParamSpec("target_port", int, "UDP port drive packets go to (0: the sender's port)", 0, 65535, read_only=True),
    ParamSpec("lead_samples", int, "Drive sent this many samples ahead of the target's clock", 0, 100000, read_only=True),
    ParamSpec("max_ahead_samples", int, "Drive never sent more than this beyond clock + lead", 0, 1000000, read_only=True),
    ParamSpec("max_fill_samples", int, "Lost samples up to this many are published as NaN; longer gaps jump", 0, 10000000, read_only=True),
    ParamSpec("resync_packets", int, "Stale packets in a row that mean the target restarted", 1, 1000000, read_only=True),
    ParamSpec("drive_timeout_s", float, "Non-zero drive stream silent this long: stop packet [s]", 1e-4, 60.0, read_only=True),
    ParamSpec("sensor_timeout_s", float, "Target silent this long: stop packet, samples published as lost [s]", 1e-4, 60.0, read_only=True),
    ParamSpec("tick_period_s", float, "Wall-clock period of the timeout checks [s]", 1e-4, 1.0, read_only=True),
    ParamSpec("receive_buffer_bytes", int, "UDP receive buffer (absorbs the bridge's stalls)", 65536, 1 << 30, read_only=True),
    ParamSpec("realtime_priority", int, "SCHED_FIFO priority of the UDP reader thread (0: normal scheduling)", 0, 99, read_only=True),
    ParamSpec("publish_applied", bool, "Publish the applied drive on /flaair/drive/applied", read_only=True),
    ParamSpec("timing_file", str, "Event times (.npz) at exit for benchmarks (empty: off)", read_only=True),
]
