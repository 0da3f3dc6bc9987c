"""rosbag2 (MCAP) bag I/O for FLAAIR: typestore, writer, block reader, run markers, reindex.

A bag is a rosbag2 directory as ROS 2 Jazzy writes it: `metadata.yaml` (version 9) next to
one MCAP file (`<bag>_0.mcap`, profile `ros2`, `cdr` messages, `ros2msg` schemas, zstd-compressed
chunks, each channel's offered QoS profiles in its metadata as rosbag2 records them).
Types come from rosbags' Jazzy typestore plus this project's `.msg` files. The MCAP file is
written with the `mcap` library (chunk size and flush under our control, so a writer killed
with SIGKILL leaves every flushed chunk readable); `reindex` turns such an unfinished bag back
into a complete one. Reading goes through rosbags.

Bag-level conventions
---------------------
- Block topics (SensorVoltageBlock, DriveCommandBlock, WingStateBlock) are read back whole with
  `read_blocks`: each array field concatenated, `first_sample_index` continuity checked.
- Runs (imported lab CSVs) are marked by std_msgs/String messages on `RUN_MARKER_TOPIC` holding
  JSON `{"run", "first_sample_index", "n_samples", "source_file", ...}`, and listed in the bag's
  `custom_data` under `RUNS_CUSTOM_KEY`.

Recovery: `scan_mcap` reads every record an MCAP file still holds, through cut-off and
corrupt chunks; `reindex` rebuilds a bag from it (verified before it replaces anything) and
`check_bag` reports damage. The command line is `flaair_tools.roscli.bag_cli` (`bin/flaair bag`).

Modules
-------
- `messages`: types, new messages, stamps, errors, conventions
- `qos`: QoS profiles as rosbag2 records them
- `writer`: BagWriter
- `blocks`: block streams joined and checked
- `markers`: run markers and the drive kinds they name
- `runs`: the measured-run columns of every run in bags (imported on use)
- `import_runs`: measured-run CSV files (or runs already read) into a bag (imported on use)
- `import_cli`: `bin/flaair import`, CSV exports or a lab's MAT logs and tracks (imported on use)
- `target_log`: a real-time target's MAT log (Structure with time, v5 and v7.3) (imported on use)
- `mat_v5`: MAT v5 files read element by element, one variable at a time (imported on use)
- `rig`: a lab's rig file, checked key by key (imported on use)
- `dlt_tracks`: DLTdv point tracks, xyzpts and xypts, flat or sparse (imported on use)
- `track_outliers`: a track's outlying frames dropped and counted, pure (imported on use)
- `mat_bounds`: how far a MAT file's compressed data may expand (imported on use)
- `video_angles`: stroke and pitch from tracked video points (DLTdv), pure (imported on use)
- `lab_run`: a lab run's drive, frame placement, truth columns and sync check, pure (on use)
- `lab_import`: a lab run (MAT + tracks + rig) or a session manifest read and checked (on use)
- `reader`: info, messages, read_bag, read_blocks
- `scan`: MCAP record scan through damage
- `recovery`: reindex, check_bag

This `__init__` is the public table of contents: import from `flaair_tools.bagio`.
"""

from __future__ import annotations

from rosbags.interfaces import QosDurability, QosReliability

from flaair_tools.bagio.blocks import (
    Blocks,
    assemble_blocks,
    block_array_fields,
    blocks_from_cdr,
    select_samples,
)
from flaair_tools.bagio.markers import (
    RUN_KINDS,
    RunMarker,
)
from flaair_tools.bagio.messages import (
    BAG_VERSION,
    CONFIG_FILE,
    HEADER_TYPE,
    NS_PER_S,
    ROS_DISTRO,
    RUN_MARKER_TOPIC,
    RUN_MARKER_TYPE,
    RUNS_CUSTOM_KEY,
    STORAGE_SECTION,
    TIME_TYPE,
    BagContinuityError,
    BagError,
    BagTopicError,
    BagUnfinishedError,
    deserialize,
    has_leading_stamp,
    leading_stamp_ns,
    message_definition,
    new_message,
    time_msg,
    typestore,
)
from flaair_tools.bagio.qos import (
    qos_from_rclpy,
    qos_from_yaml,
    qos_to_yaml,
)
from flaair_tools.bagio.reader import (
    BagContents,
    BagInfo,
    TopicInfo,
    bag_info,
    iter_messages,
    iter_raw,
    message_counts,
    read_bag,
    read_blocks,
    read_run_markers,
)
from flaair_tools.bagio.recovery import (
    ReindexReport,
    TopicRecovery,
    check_bag,
    damage_lines,
    reindex,
    single_mcap_file,
)
from flaair_tools.bagio.scan import (
    MCAP_MAGIC,
    RECOVERED_CUSTOM_KEY,
    ScanLog,
    ScannedMessage,
    scan_mcap,
)
from flaair_tools.bagio.writer import (
    BagWriter,
    bag_metadata,
    storage_settings,
)

__all__ = [
    "BAG_VERSION",
    "CONFIG_FILE",
    "HEADER_TYPE",
    "MCAP_MAGIC",
    "NS_PER_S",
    "RECOVERED_CUSTOM_KEY",
    "ROS_DISTRO",
    "RUNS_CUSTOM_KEY",
    "RUN_KINDS",
    "RUN_MARKER_TOPIC",
    "RUN_MARKER_TYPE",
    "STORAGE_SECTION",
    "TIME_TYPE",
    "BagContents",
    "BagContinuityError",
    "BagError",
    "BagInfo",
    "BagTopicError",
    "BagUnfinishedError",
    "BagWriter",
    "Blocks",
    "QosDurability",
    "QosReliability",
    "ReindexReport",
    "RunMarker",
    "ScanLog",
    "ScannedMessage",
    "TopicInfo",
    "TopicRecovery",
    "assemble_blocks",
    "bag_info",
    "bag_metadata",
    "block_array_fields",
    "blocks_from_cdr",
    "check_bag",
    "damage_lines",
    "deserialize",
    "has_leading_stamp",
    "iter_messages",
    "iter_raw",
    "leading_stamp_ns",
    "message_counts",
    "message_definition",
    "new_message",
    "qos_from_rclpy",
    "qos_from_yaml",
    "qos_to_yaml",
    "read_bag",
    "read_blocks",
    "read_run_markers",
    "reindex",
    "scan_mcap",
    "select_samples",
    "single_mcap_file",
    "storage_settings",
    "time_msg",
    "typestore",
]
