"""The stand-ins' pure parts: YAML as `ros2 topic echo` prints it, fields, ros2cli's flags, and
discovery that listens on while names still appear.
"""

from __future__ import annotations

import argparse

import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

from flaair_msgs.msg import WingStateBlock
from flaair_tools.roscli import ros2_args
from flaair_tools.roscli.yaml_out import field_of, message_to_yaml

pytestmark = pytest.mark.timeout(60)


def test_messages_print_as_rosidl_runtime_py_prints_them() -> None:
    block = WingStateBlock(sample_rate_hz=20000.0, first_sample_index=7, source=1)
    block.header.frame_id = "robot"
    block.stroke_deg = [1.5, -2.0]
    block.stroke_valid = [True, False]
    text = message_to_yaml(block)
    # field order of the .msg, nested header, float arrays as lists, byte-sized ints as ints
    assert text == (
        "header:\n  stamp:\n    sec: 0\n    nanosec: 0\n  frame_id: robot\n"
        "sample_rate_hz: 20000.0\nfirst_sample_index: 7\nsource: 1\n"
        "stroke_deg:\n- 1.5\n- -2.0\npitch_deg: []\nstroke_velocity_deg_s: []\n"
        "stroke_valid:\n- true\n- false\npitch_valid: []\n"
    )
    # a byte field prints as its character, arrays past the limit end in '...'
    health = DiagnosticArray(status=[DiagnosticStatus(level=b"\x02", name="n" * 5)])
    assert '- level: "\\x02"\n' in message_to_yaml(health)
    block.pitch_deg = [0.0] * 5
    assert "pitch_deg:\n- 0.0\n- 0.0\n- '...'\n" in message_to_yaml(block, truncate_length=2)
    assert field_of(block, "header.frame_id") == "robot"
    with pytest.raises(ValueError, match=r"Invalid field 'header\.frame': no field 'frame'"):
        field_of(block, "header.frame")


def test_a_flag_not_covered_names_the_real_command_in_one_line(capsys) -> None:
    parser = argparse.ArgumentParser(prog="flaair service")
    parser.add_argument("verb")
    parser.add_argument("name", nargs="?")
    parser.add_argument("--json", action="store_true")
    # flags among the positionals, as ros2cli takes them
    args = ros2_args.parse_or_refuse(parser, ["call", "--json", "/x"], "service")
    assert (args.verb, args.name, args.json) == ("call", "/x", True)
    with pytest.raises(SystemExit) as stop:
        ros2_args.parse_or_refuse(parser, ["call", "/x", "-r", "1"], "service")
    assert stop.value.code == 2
    assert capsys.readouterr().err == (
        "flaair service: -r is not covered by this stand-in (see --help); on a full ROS 2 "
        "install: ros2 service call /x -r 1\n"
    )


def test_discovery_listens_on_while_names_appear(monkeypatch) -> None:
    now = [0.0]
    monkeypatch.setattr(ros2_args.time, "monotonic", lambda: now[0])
    arrivals = {0.2: "/a", 0.6: "/b", 1.0: "/c"}  # a loaded graph arriving over 1 s

    def spin(timeout_s: float) -> None:
        now[0] += timeout_s

    def names() -> set[str]:
        return {n for t, n in arrivals.items() if t <= now[0] + 1e-9}

    # a fixed 0.5 s window (ros2cli's) would have seen /a only
    assert ros2_args.listen_until_settled(spin, names, 0.5) == {"/a", "/b", "/c"}
    assert now[0] == pytest.approx(1.5)  # 0.5 s after the last new name
    now[0] = 0.0
    arrivals.update({t / 10: f"/n{t}" for t in range(14, 100, 3)})  # never settles: capped
    ros2_args.listen_until_settled(spin, names, 0.5)
    assert ros2_args.MAX_SETTLE_S <= now[0] < ros2_args.MAX_SETTLE_S + 0.1
