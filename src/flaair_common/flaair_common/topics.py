"""Topic names of the FLAAIR graph (remap with --ros-args -r old:=new)."""

DRIVE = "/flaair/drive"  # DriveCommandBlock: drive voltage to the actuator
# DriveCommandBlock: the drive a real-time target applied
DRIVE_APPLIED = "/flaair/drive/applied"
SENSOR_VOLTAGE = "/flaair/sensor_v"  # SensorVoltageBlock: raw charge-amplifier outputs
WING_STATE = "/flaair/wing_state"  # WingStateBlock: estimated from the sensors
WING_STATE_TRUTH = "/flaair/wing_state/truth"  # WingStateBlock: simulator ground truth
COLLISION_STATUS = "/flaair/collision/status"  # CollisionStatus, one per wingbeat
COLLISION_EVENTS = "/flaair/collision/events"  # CollisionEvent at onset and clearance
HEALTH_STATUS = "/flaair/health"  # HealthStatus, one per wingbeat
HEALTH_EVENTS = "/flaair/health/events"  # HealthEvent at each detected change
CONTROLLER_STATE = "/flaair/controller/state"  # ControllerState, one per command block
CLOCK = "/clock"
TIME_ANCHOR = "/flaair/time_anchor"  # TimeAnchor: a stream's sample clock in ROS time

# The 20 kHz streams and their types (what a composed recorder records in-process)
BLOCK_STREAM_TYPES = {
    CONTROLLER_STATE: "flaair_msgs/msg/ControllerState",
    DRIVE: "flaair_msgs/msg/DriveCommandBlock",
    DRIVE_APPLIED: "flaair_msgs/msg/DriveCommandBlock",
    SENSOR_VOLTAGE: "flaair_msgs/msg/SensorVoltageBlock",
    WING_STATE: "flaair_msgs/msg/WingStateBlock",
    WING_STATE_TRUTH: "flaair_msgs/msg/WingStateBlock",
}

# header frame_id of the robot's block streams (the fixed-size CDR fast path expects it)
FRAME_ID = "robot"


def is_flaair(topic: str) -> bool:
    """Whether `topic` is one of FLAAIR's own streams (under /flaair/, or relative to a node)."""
    return topic.startswith("/flaair/") or topic.startswith("flaair/")


def relative(topic: str) -> str:
    """`topic` as a node creates it: FLAAIR's streams relative to the node's namespace, so a graph
    started in a namespace (`-r __ns:=/bench2`) keeps its streams to itself. The names above are
    what a graph in the root namespace resolves them to (and what its bags hold); /clock and
    every other name stay as they are.
    """
    return topic[1:] if topic.startswith("/flaair/") else topic
