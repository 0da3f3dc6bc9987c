"""`FlaairNode`: the rclpy Node every FLAAIR node derives from, with the ROS naming conventions
a lab's workspace expects kept in one place.

* Topics are relative to the node's namespace: started with `-r __ns:=/bench2` (or inside a
  launch file's `push-ros-namespace`), a node's streams become /bench2/flaair/..., so two benches
  share one domain without seeing each other's data. /clock and ROS's own topics stay absolute.
* Every FLAAIR publisher and subscription takes the standard QoS override parameters
  (`qos_overrides./flaair/wing_state.subscription.reliability:=best_effort`, as rclcpp nodes do).
* Parameters come from config/ under the node's default name (`plant_node`), then from a section
  named as the node was renamed at launch (`-r __node:=plant2`), so a renamed node still finds
  its parameters; see `flaair_common.params.declare_parameters`.
"""
from __future__ import annotations

from typing import Any

from rclpy.node import Node
from rclpy.qos_overriding_options import QoSOverridingOptions

from flaair_common import topics

__all__ = ["FlaairNode"]

# history, depth and reliability: the policies rclcpp's nodes let a parameter override
_QOS_OVERRIDES = QoSOverridingOptions.with_default_policies()


class FlaairNode(Node):
    """An rclpy Node named `default_name` unless renamed at launch; see the module."""

    def __init__(self, default_name: str, **kwargs: Any) -> None:
        super().__init__(default_name, **kwargs)
        self.default_name = default_name

    def create_publisher(self, msg_type: Any, topic: str, qos_profile: Any,
                         **kwargs: Any) -> Any:
        if topics.is_flaair(topic):
            kwargs.setdefault("qos_overriding_options", _QOS_OVERRIDES)
        return super().create_publisher(msg_type, topics.relative(topic), qos_profile, **kwargs)

    def create_subscription(self, msg_type: Any, topic: str, callback: Any, qos_profile: Any,
                            **kwargs: Any) -> Any:
        if topics.is_flaair(topic):
            kwargs.setdefault("qos_overriding_options", _QOS_OVERRIDES)
        return super().create_subscription(msg_type, topics.relative(topic), callback,
                                           qos_profile, **kwargs)

    def count_publishers(self, topic_name: str) -> int:
        return super().count_publishers(topics.relative(topic_name))

    def count_subscribers(self, topic_name: str) -> int:
        return super().count_subscribers(topics.relative(topic_name))
