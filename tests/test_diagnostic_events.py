"""flaair_tools.analysis.diagnostic_events: a run's health level changes read back from its bag."""

from __future__ import annotations

from pathlib import Path

import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.qos import QoSProfile
from rclpy.serialization import serialize_message

from flaair_tools import bagio
from flaair_tools.analysis import diagnostic_events as de

pytestmark = pytest.mark.timeout(60)

CONTROLLER = "/dsa_controller_node"
BRIDGE = "/bridge_node"


def _array(name: str, node: str, level: int, message: str) -> DiagnosticArray:
    return DiagnosticArray(
        status=[
            DiagnosticStatus(
                level=bytes([level]),
                name=name,
                message=message,
                hardware_id=node,
                values=[KeyValue(key="trips", value="1")],
            )
        ]
    )


def test_level_changes_are_the_events_and_repeats_are_not() -> None:
    s = de.Status
    statuses = [
        s(1_000_000_000, "ctl", CONTROLLER, 0, "flapping"),
        s(2_000_000_000, "ctl", CONTROLLER, 0, "flapping"),
        s(2_000_000_000, "br", BRIDGE, 1, "packet loss 2.5 %"),  # first seen, not OK: an event
        s(3_000_000_000, "ctl", CONTROLLER, 2, "drive watchdog tripped"),
        s(4_000_000_000, "ctl", CONTROLLER, 2, "drive watchdog tripped"),
        s(5_500_000_000, "ctl", CONTROLLER, 0, "flapping"),
    ]
    events = de.level_changes(statuses, start_ns=500_000_000)
    assert [(e["time_s"], e["node"], e["previous"], e["level"], e["message"]) for e in events] == [
        (1.5, BRIDGE, "OK", "WARN", "packet loss 2.5 %"),
        (2.5, CONTROLLER, "OK", "ERROR", "drive watchdog tripped"),
        (5.0, CONTROLLER, "ERROR", "OK", "flapping"),
    ]
    assert events[1]["time_ns"] == 3_000_000_000 and de.level_name(7) == "7"


def test_events_are_read_from_a_bags_diagnostics(tmp_path: Path) -> None:
    bag = tmp_path / "run"
    qos = [bagio.qos_from_rclpy(QoSProfile(depth=10))]
    with bagio.BagWriter(bag) as writer:
        writer.add_topic(de.DIAGNOSTICS, "diagnostic_msgs/msg/DiagnosticArray", qos)
        writer.add_topic("/flaair/other", "std_msgs/msg/String", qos)
        writer.write("/flaair/other", 10_000_000_000, serialize_message(_ok_string()))
        for k, (level, text) in enumerate(
            [(0, "flapping"), (2, "drive watchdog tripped"), (2, "drive watchdog tripped")]
        ):
            array = _array("dSA controller", CONTROLLER, level, text)
            array.header.stamp.sec = 1_700_000_000 + k  # the node's wall clock
            data = serialize_message(array)
            writer.write(de.DIAGNOSTICS, 11_000_000_000 + k * 1_000_000_000, data)
    (event,) = de.from_bag(bag)
    assert (event["time_s"], event["level"], event["message"], event["stamp_ns"]) == (
        pytest.approx(2.0),
        "ERROR",
        "drive watchdog tripped",
        1_700_000_001_000_000_000,
    )
    # a bag without /diagnostics (recorded before the recorder kept it): no events, no error
    older = tmp_path / "older"
    with bagio.BagWriter(older) as writer:
        writer.add_topic("/flaair/other", "std_msgs/msg/String", qos)
        writer.write("/flaair/other", 1, serialize_message(_ok_string()))
    assert de.from_bag(older) == []


def _ok_string():
    from std_msgs.msg import String

    return String(data="x")


def test_the_report_lists_the_events_with_their_times(tmp_path: Path) -> None:
    from flaair_tools.analysis import report

    event = de.level_changes(
        [de.Status(2_500_000_000, "dSA controller", CONTROLLER, 2, "watchdog tripped: silence")],
        start_ns=0,
    )
    bag = {"experiment": "live", "description": "a run", "bag": "b", "estimate_source": "live"}
    bag |= {"warnings": [], "missing": [], "runs": {}, "diagnostic_events": event}
    summary = {"created": "now", "bags": [bag], "headline": {}, "figures": [], "partial": []}
    summary |= {"model_gains_warning": None, "calibration_file": None}
    html = report.write_html(summary, tmp_path).read_text()
    assert "<li>2.5 s: /dsa_controller_node OK &rarr; ERROR: watchdog tripped: silence</li>" in html
