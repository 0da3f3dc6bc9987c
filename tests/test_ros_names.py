"""ROS naming a lab's workspace expects: renamed nodes find their parameters, FLAAIR's topics
follow the node's namespace, and their QoS takes the standard override parameters.
"""

from __future__ import annotations

from pathlib import Path

import pytest


def test_a_renamed_node_reads_its_default_section_then_the_one_named_at_launch(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from flaair_model.config import CONFIG_DIR_ENV, ConfigError, node_parameters

    (tmp_path / "flaair.yaml").write_text(
        "/**:\n  ros__parameters: {block_size: 10, sample_rate_hz: 20000.0}\n"
        "plant_node:\n  ros__parameters: {mode: lockstep, noise: false}\n"
        "plant2:\n  ros__parameters: {noise: true}\n"
    )
    monkeypatch.setenv(CONFIG_DIR_ENV, str(tmp_path))
    assert node_parameters("flaair.yaml", "plant_node", renamed="plant2") == {
        "block_size": 10,
        "sample_rate_hz": 20000.0,
        "mode": "lockstep",
        "noise": True,
    }
    # renamed with no section of its own: the default section, whole
    assert node_parameters("flaair.yaml", "plant_node", renamed="plant3")["noise"] is False
    with pytest.raises(ConfigError, match="no 'drive_node: ros__parameters:' section"):
        node_parameters("flaair.yaml", "drive_node", renamed="drive2")


def test_topics_follow_the_namespace_and_take_qos_override_parameters() -> None:
    import rclpy
    from rclpy.qos import ReliabilityPolicy

    from flaair_common import topics
    from flaair_common.node import FlaairNode
    from flaair_common.qos import BLOCK_STREAM
    from flaair_msgs.msg import DriveCommandBlock, WingStateBlock

    context = rclpy.Context()
    rclpy.init(
        context=context,
        args=[
            "--ros-args",
            "-r",
            "__ns:=/bench2",
            "-r",
            "__node:=plant2",
            "-p",
            "qos_overrides./bench2/flaair/drive.publisher.depth:=7",
            "-p",
            "qos_overrides./bench2/flaair/wing_state.subscription.reliability:=best_effort",
        ],
    )
    try:
        node = FlaairNode("plant_node", context=context)
        publisher = node.create_publisher(DriveCommandBlock, topics.DRIVE, BLOCK_STREAM)
        subscription = node.create_subscription(
            WingStateBlock, topics.WING_STATE, lambda _: None, BLOCK_STREAM
        )
        clock = node.create_publisher(DriveCommandBlock, topics.CLOCK, BLOCK_STREAM)
        assert (node.get_fully_qualified_name(), node.default_name) == (
            "/bench2/plant2",
            "plant_node",
        )
        assert publisher.topic_name == "/bench2/flaair/drive" and clock.topic_name == "/clock"
        assert subscription.topic_name == "/bench2/flaair/wing_state"
        assert (publisher.qos_profile.depth, BLOCK_STREAM.depth) == (7, BLOCK_STREAM.depth)
        assert subscription.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT
        assert node.count_publishers(topics.DRIVE) == 1  # the namespaced one: its own
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
