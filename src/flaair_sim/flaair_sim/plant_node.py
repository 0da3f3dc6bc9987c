"""plant_node: the simulated flapping-wing robot (stroke, pitch, PVDF sensors) as a ROS 2 node.
Subscribes to /flaair/drive; publishes /flaair/sensor_v, /flaair/wing_state/truth, /clock and,
in realtime mode (commands queued), the drive at the samples it was applied (/flaair/drive/applied).
Pacing, command checks, the drive clamp and the lockstep drive watchdog are the pure core
`flaair_sim.core.actuator`; the obstacle schedule (obstacle_windows_s, the paper's collision
experiment) and the camera's view of the truth are `flaair_sim.core.scene`.

Usage: bin/flaair run flaair_sim plant_node [--ros-args -p mode:=realtime -p model_file:=my.yaml]
"""

from __future__ import annotations

import time

import numpy as np
from rosgraph_msgs.msg import Clock

from flaair_common import intra, topics
from flaair_common.blocks import stamp_from_time_s, stamp_ns_of_sample
from flaair_common.node import FlaairNode
from flaair_common.params import declare_parameters
from flaair_common.qos import BLOCK_STREAM
from flaair_common.runtime import log_notes, run_node, warn_counted
from flaair_msgs.msg import WingStateBlock
from flaair_sim import plant_io as io
from flaair_sim.core import actuator, plant, scene

PARAMS = io.PLANT_PARAMS
TRUTH = WingStateBlock.SOURCE_GROUND_TRUTH


class PlantNode(FlaairNode):
    """Thin shell over flaair_sim.core.actuator.step and flaair_sim.core.plant.step."""

    def __init__(self) -> None:
        super().__init__(io.NODE_NAME)
        self.p = declare_parameters(self, PARAMS, io.CONFIG_FILE)
        self.model, self.obstacle_model, self.windows_s = io.plant_models(self.p)
        self.damage = io.plant_damage(self.p, self.model, self.obstacle_model)
        self.fs_hz, self.block_size = self.p["sample_rate_hz"], self.p["block_size"]
        self.live = self.live_parameters("drive_limit_v")
        self.params = io.actuator_params_from_config(self.p)
        self.driver = actuator.initial_state(self.params, t_wall=time.monotonic())
        self.state = plant.initial_state(plant.PlantStepParams(self.model, self.fs_hz))
        plant.warm_up(plant.PlantStepParams(self.model, self.fs_hz), self.block_size)
        self.noise_rng, self.tracking_rng = io.generators_from_config(self.p)
        self.camera = io.camera_from_config(self.p, self.model)
        self.sensor, self.truth = (
            intra.block_publisher(self, topic, self.block_size, BLOCK_STREAM)
            for topic in (topics.SENSOR_VOLTAGE, topics.WING_STATE_TRUTH)
        )
        # realtime: commands queue, so the drive is also said at the samples it was applied
        self.applied = (
            intra.block_publisher(self, topics.DRIVE_APPLIED, self.block_size, BLOCK_STREAM)
            if self.params.mode == "realtime"
            else None
        )
        # One /clock per block (2000/s): a 10-deep reliable history lost ticks to a recorder a
        # moment behind (bench_recorder: 33 of 20,843); 1000 deep is 0.5 s of slack.
        clock = self.p["publish_clock"]
        self.clock_pub = (
            self.create_publisher(Clock, topics.CLOCK, io.CLOCK_DEPTH) if clock else None
        )
        self.clock_listeners = intra.ListenerCount(self.clock_pub)  # per-block decision
        # next_index: first sample of the next stepped block
        self.undecodable, self.next_index = 0, 0
        # Writer-side readiness: a lockstep source starts once the plant subscribes to the drive, so
        # the plant subscribes only once its outputs' listeners are matched (none misses block 0).
        self.listeners_timer = self.create_timer(0.01, self.subscribe_when_listened)
        self.subscribe_when_listened()
        if (period := actuator.tick_period_s(self.params)) is not None:
            self.create_timer(period, self.on_tick)
        self.get_logger().info(io.ready_text(self.p, self.model, self.windows_s))

    def subscribe_when_listened(self) -> None:
        """Subscribe to the drive once sensor_v, truth and /clock have min_sensor_subscribers,
        min_truth_subscribers and min_clock_subscribers matched listeners (counted on the
        writer's side: a subscription seen in the graph can match a moment later).
        """
        sensors, truths = self.p["min_sensor_subscribers"], self.p["min_truth_subscribers"]
        clocks = self.p["min_clock_subscribers"] if self.clock_pub is not None else 0
        if (
            self.sensor.subscription_count() < sensors
            or self.truth.subscription_count() < truths
            or (clocks and self.clock_pub.get_subscription_count() < clocks)
        ):
            return
        self.destroy_timer(self.listeners_timer)
        intra.subscribe_stream(
            self, topics.DRIVE, self.block_size, self.on_command, BLOCK_STREAM, self.on_undecodable
        )
        if sensors or truths:
            self.get_logger().info(io.matched_text(sensors, truths))

    def on_undecodable(self, exc: Exception) -> None:
        self.undecodable += 1
        warn_counted(self.get_logger(), self.undecodable, io.rejected_text(exc, self.undecodable))

    def on_command(self, m) -> None:
        self.drive(io.command_of(m, time.monotonic()))

    def on_tick(self) -> None:
        for _ in range(actuator.blocks_per_tick(self.params)):  # realtime: the due blocks
            if not self.drive(actuator.Tick(time.monotonic())):
                break

    def drive(self, inputs: actuator.Command | actuator.Tick) -> bool:
        """Run the driver core; step the model through every block it releases (True: some)."""
        self.driver, out = actuator.step(self.driver, inputs, self.params)
        log_notes(self.get_logger(), out.notes, lambda counter: getattr(self.driver, counter))
        for drive_v in out.drive_blocks:
            self.advance(drive_v)
        return bool(out.drive_blocks) and self.params.mode == "realtime"

    def advance(self, drive_v: np.ndarray) -> None:
        """Step the model one block and publish its outputs."""
        drive_v = actuator.clamp_drive(drive_v, self.live["drive_limit_v"])
        index, self.next_index = self.next_index, self.next_index + drive_v.size
        model = scene.model_at(
            index / self.fs_hz, self.model, self.obstacle_model, self.windows_s, self.damage
        )
        step = plant.PlantStepParams(model, self.fs_hz)
        self.state, out = plant.step(self.state, plant.PlantInputs(drive_v, self.noise_rng), step)
        stamp_ns = stamp_ns_of_sample(index, self.fs_hz)
        self.sensor.publish(stamp_ns, io.sensor_fields(index, self.fs_hz, out))
        # Truth and /clock only when someone listens (volatile: a subscriber gets what follows its
        # match either way); the composed loop alone spends no encoding or DDS write on them.
        if self.truth.has_listeners():
            self.truth.publish(
                stamp_ns,
                io.truth_fields(index, self.fs_hz, out, TRUTH, self.camera, self.tracking_rng),
            )
        if self.applied is not None and self.applied.has_listeners():
            self.applied.publish(stamp_ns, io.applied_fields(index, self.fs_hz, drive_v))
        if self.clock_pub is not None and self.clock_listeners():
            self.clock_pub.publish(Clock(clock=stamp_from_time_s(self.next_index / self.fs_hz)))


def main(args: list[str] | None = None) -> int:
    return run_node(PlantNode, PARAMS, io.CONFIG_FILE, io.NODE_NAME, args)


if __name__ == "__main__":
    raise SystemExit(main())
