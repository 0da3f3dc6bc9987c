"""drive_node over DDS with a plant that never answers: retries (warnings), then the run's end (info)."""
from __future__ import annotations

import pytest

import signal
import sys

import numpy as np

from rosproc import ros_processes

# A silent "plant": subscribes to /flaair/drive and offers /flaair/sensor_v but never publishes
# on it, so the lockstep drive gets no acknowledgement; prints every drive block it receives.
SILENT_PLANT = r"""
import sys, time
import rclpy
from flaair_common.qos import BLOCK_STREAM
from flaair_msgs.msg import DriveCommandBlock, SensorVoltageBlock

pytestmark = pytest.mark.graph   # ROS 2 processes exchanging data in real time: run alone
rclpy.init()
node = rclpy.create_node("silent_plant")
node.create_publisher(SensorVoltageBlock, "/flaair/sensor_v", BLOCK_STREAM)
ended = []
def on_drive(m):
    print(m.first_sample_index, max(abs(v) for v in m.drive_v), flush=True)
    if max(abs(v) for v in m.drive_v) == 0.0:
        ended.append(time.monotonic())   # the run's zero block: stay 2 s more, then go
node.create_subscription(DriveCommandBlock, "/flaair/drive", on_drive, BLOCK_STREAM)
deadline = time.monotonic() + float(sys.argv[1])   # a loaded machine may take long to start the drive
while time.monotonic() < deadline and not (ended and time.monotonic() > ended[0] + 2.0):
    rclpy.spin_once(node, timeout_sec=0.05)
"""


def test_lockstep_drive_retries_then_ends_on_a_zero_block_and_keeps_running() -> None:
    with ros_processes() as procs:
        plant = procs.start(sys.executable, "-c", SILENT_PLANT, "100")
        drive = procs.flaair("run", "flaair_sim", "drive_node", "--ros-args", "-p", "pacing:=lockstep",
                             "-p", "lockstep_window_blocks:=1", "-p", "ack_retry_s:=0.2",
                             "-p", "run_time_s:=0.002", "-p", "frequency_hz:=140.0")  # 4 blocks of 10 samples
        out, _ = plant.communicate(timeout=120)
        assert drive.poll() is None, drive.stderr.read()   # still running after warnings and the info line
        assert procs.stop(drive, signal.SIGINT, timeout_s=30) == 0
        log = drive.stderr.read()
    blocks = np.array([[float(x) for x in line.split()] for line in out.splitlines()])
    # one block per retry (nothing acknowledges), then the zero block that ends the run
    assert list(blocks[:, 0]) == [0, 10, 20, 30, 40]
    assert np.all(blocks[:4, 1] > 0) and blocks[4, 1] == 0.0
    assert log.count("no acknowledgement for 0.2 s") == 3 and "run complete at sample 40; zero drive sent" in log
