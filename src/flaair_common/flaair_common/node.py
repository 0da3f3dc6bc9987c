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
* Health goes to /diagnostics (`publish_health`), once a second, as ROS's diagnostic_updater does.
* Block stamps are acquisition times in the ROS clock (`stamp_ns_of`): sample time plus an offset
  that a source anchors to its clock at its first block (`anchor_sample_clock`, recorded on
  flaair/time_anchor) and that the nodes downstream take from their input (`follow_sample_clock`).
  In simulation the offset is 0: sample time is the plant's /clock.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from rclpy.qos_overriding_options import QoSOverridingOptions

from flaair_common import cdr, topics
from flaair_common.blocks import stamp_ns_of_sample
from flaair_common.diagnostics import DIAGNOSTICS_PERIOD_S, Health
from flaair_common.qos import EVENTS
from flaair_msgs.msg import TimeAnchor

T = TypeVar("T")

__all__ = ["FlaairNode"]

# history, depth and reliability: the policies rclcpp's nodes let a parameter override
_QOS_OVERRIDES = QoSOverridingOptions.with_default_policies()


class FlaairNode(Node):
    """An rclpy Node named `default_name` unless renamed at launch; see the module."""

    def __init__(self, default_name: str, **kwargs: Any) -> None:
        super().__init__(default_name, **kwargs)
        self.default_name = default_name
        self.sample_clock_offset_ns: int | None = None  # ROS time - sample time, once known

    def create_publisher(self, msg_type: Any, topic: str, qos_profile: Any, **kwargs: Any) -> Any:
        if topics.is_flaair(topic):
            kwargs.setdefault("qos_overriding_options", _QOS_OVERRIDES)
        return super().create_publisher(msg_type, topics.relative(topic), qos_profile, **kwargs)

    def create_subscription(
        self, msg_type: Any, topic: str, callback: Any, qos_profile: Any, **kwargs: Any
    ) -> Any:
        if topics.is_flaair(topic):
            kwargs.setdefault("qos_overriding_options", _QOS_OVERRIDES)
        return super().create_subscription(
            msg_type, topics.relative(topic), callback, qos_profile, **kwargs
        )

    def count_publishers(self, topic_name: str) -> int:
        return super().count_publishers(topics.relative(topic_name))

    def count_subscribers(self, topic_name: str) -> int:
        return super().count_subscribers(topics.relative(topic_name))

    def live_parameters(self, *names: str) -> dict[str, Any]:
        """The current values of the declared parameters `names`, renewed whenever one is set:
        for a read on every block, where rclpy's get_parameter walks its parameter store.
        """
        values = {name: self.get_parameter(name).value for name in names}

        def renew(parameters: list[Any]) -> None:
            for parameter in parameters:
                if parameter.name in values:
                    values[parameter.name] = parameter.value

        self.add_post_set_parameters_callback(renew)
        return values

    def publish_health(
        self, snapshot: Callable[[], T], judge: Callable[[T, T | None], Health]
    ) -> None:
        """Every DIAGNOSTICS_PERIOD_S, publish `judge(snapshot(), previous snapshot)` on
        /diagnostics (hardware id: this node's fully qualified name). The judge is a pure function
        (flaair_common.diagnostics); the previous snapshot lets it speak of the last period.
        """
        publisher = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        previous: list[Any] = [None]

        def tick() -> None:
            now = snapshot()
            found = judge(now, previous[0])
            previous[0] = now
            message = DiagnosticArray()
            message.header.stamp = self.get_clock().now().to_msg()
            message.status = [
                DiagnosticStatus(
                    level=bytes([found.level]),
                    name=f"{self.get_name()}: {found.name}",
                    message=found.message,
                    hardware_id=self.get_fully_qualified_name(),
                    values=[KeyValue(key=k, value=v) for k, v in found.values],
                )
            ]
            publisher.publish(message)

        self.create_timer(DIAGNOSTICS_PERIOD_S, tick)

    def anchor_sample_clock(self, sample_index: int, sample_rate_hz: float, clock: str) -> None:
        """Sample `sample_index` is acquired now (ROS time): from here on `stamp_ns_of` is ROS
        time. The anchoring is published once, latched, on flaair/time_anchor, and logged.
        """
        now = self.get_clock().now()
        self.sample_clock_offset_ns = now.nanoseconds - stamp_ns_of_sample(
            sample_index, sample_rate_hz
        )
        anchor = TimeAnchor(
            sample_index=sample_index, sample_rate_hz=sample_rate_hz, sample_clock=clock
        )
        anchor.header.stamp = now.to_msg()
        self.create_publisher(TimeAnchor, topics.TIME_ANCHOR, EVENTS).publish(anchor)
        self.get_logger().info(
            f"{clock} sample {sample_index} anchored at ROS time "
            f"{now.nanoseconds * 1e-9:.6f} s (block stamps follow from it)"
        )

    def follow_sample_clock(self, fields: dict, sample_rate_hz: float) -> None:
        """Take the stamp offset from an input block's header (once), so what this node publishes
        carries the same clock as what it reads.
        """
        if self.sample_clock_offset_ns is None:
            self.sample_clock_offset_ns = cdr.stamp_ns(fields) - stamp_ns_of_sample(
                int(fields["first_sample_index"]), sample_rate_hz
            )

    def stamp_ns_of(self, sample_index: int, sample_rate_hz: float) -> int:
        """Header stamp (ns) of the block starting at `sample_index`: its acquisition time."""
        return (self.sample_clock_offset_ns or 0) + stamp_ns_of_sample(sample_index, sample_rate_hz)
