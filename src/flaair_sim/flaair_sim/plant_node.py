"""plant_node: the simulated flapping-wing robot (stroke, pitch, PVDF sensors) as a ROS 2 node.

Subscribes to drive-command blocks (/flaair/drive) and publishes raw sensor-voltage blocks
(/flaair/sensor_v), ground-truth wing-state blocks (/flaair/wing_state/truth) and /clock.

Pacing (lockstep: one block per command block; realtime: the wall clock), command checks
and the lockstep drive watchdog (zero drive and ring-down when a driving source falls silent)
are the pure core `flaair_sim.core.actuator`; drive is clamped to +-drive_limit_v before the model.
When composed with the front end and a controller (`flaair_common.container`), the block
streams travel in-process.

An obstacle (the paper's collision experiment) can be scheduled in sim time with
obstacle_windows_s (pairs of start/end seconds) at obstacle_stroke_limit_deg.

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
from flaair_sim.core import actuator, plant
from flaair_sim.plant_io import (
    CLOCK_DEPTH,
    CONFIG_FILE,
    NODE_NAME,
    PLANT_PARAMS,
    actuator_params_from_config,
    plant_models,
)

PARAMS = PLANT_PARAMS


class PlantNode(FlaairNode):
    """Thin shell over flaair_sim.core.actuator.step and flaair_sim.core.plant.step."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        self.p = declare_parameters(self, PARAMS, CONFIG_FILE)
        self.model, self.obstacle_model, self.windows_s = plant_models(self.p)
        self.damage = io.plant_damage(self.p, self.model, self.obstacle_model)
        self.fs_hz, self.block_size = self.p["sample_rate_hz"], self.p["block_size"]
        self.params = actuator_params_from_config(self.p)
        self.driver = actuator.initial_state(self.params, t_wall=time.monotonic())
        self.state = plant.initial_state(plant.PlantStepParams(self.model, self.fs_hz))
        self.noise_rng = np.random.default_rng(self.p["noise_seed"]) if self.p["noise"] else None
        self.tracking_rng = (
            np.random.default_rng([self.p["noise_seed"], 1])
            if self.p["noise"] and self.p["truth_frame_every"] > 1
            else None
        )
        self.sensor = intra.block_publisher(
            self, topics.SENSOR_VOLTAGE, self.block_size, BLOCK_STREAM
        )
        self.truth = intra.block_publisher(
            self, topics.WING_STATE_TRUTH, self.block_size, BLOCK_STREAM
        )
        # One /clock per block (2000/s): a 10-deep reliable history lost ticks to a recorder a
        # moment behind (bench_recorder: 33 of 20,843); 1000 deep is 0.5 s of slack.
        self.clock_pub = (
            self.create_publisher(Clock, topics.CLOCK, CLOCK_DEPTH)
            if self.p["publish_clock"]
            else None
        )
        # next_index: first sample of the next stepped block
        self.undecodable, self.next_index = 0, 0
        # Writer-side readiness: a lockstep source starts once the plant subscribes to the drive, so
        # the plant subscribes only once its outputs' listeners are matched (none misses block 0).
        self.listeners_timer = self.create_timer(0.01, self.subscribe_when_listened)
        self.subscribe_when_listened()
        if self.p["mode"] == "realtime" or self.p["command_timeout_s"] > 0:
            period = (
                0.005
                if self.p["mode"] == "realtime"
                else min(0.01, self.p["command_timeout_s"] / 4)
            )
            self.create_timer(period, self.on_tick)
        self.get_logger().info(io.ready_text(self.p, self.model, self.windows_s))

    def subscribe_when_listened(self) -> None:
        """Subscribe to the drive once sensor_v and truth have min_sensor_subscribers and
        min_truth_subscribers matched listeners (counted on the writer's side).
        """
        sensors, truths = self.p["min_sensor_subscribers"], self.p["min_truth_subscribers"]
        if self.sensor.subscription_count() < sensors or self.truth.subscription_count() < truths:
            return
        self.destroy_timer(self.listeners_timer)
        intra.subscribe_stream(
            self, topics.DRIVE, self.block_size, self.on_command, BLOCK_STREAM, self.on_undecodable
        )
        if sensors or truths:
            self.get_logger().info(
                f"outputs matched (sensor {sensors}, truth {truths} "
                "listener(s)): taking drive commands"
            )

    def on_undecodable(self, exc: Exception) -> None:
        self.undecodable += 1
        warn_counted(
            self.get_logger(),
            self.undecodable,
            f"rejected command block ({exc}); ignored [{self.undecodable} undecodable so far]",
        )

    def on_command(self, m) -> None:
        self.drive(
            actuator.Command(
                time.monotonic(),
                int(m["first_sample_index"]),
                float(m["sample_rate_hz"]),
                m["drive_v"],
            )
        )

    def on_tick(self) -> None:
        # realtime: the due blocks one at a time, at most 20 ms of them per tick (a plant behind
        # the wall clock must not starve the executor: timers, shutdown)
        for _ in range(int(0.02 * self.fs_hz / self.block_size)):
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
        limit = self.get_parameter("drive_limit_v").value
        # np.clip, at a third of its call overhead
        drive_v = np.minimum(np.maximum(drive_v, -limit), limit)
        index = self.next_index
        self.next_index += drive_v.size
        model = io.model_at(
            index / self.fs_hz, self.model, self.obstacle_model, self.windows_s, self.damage
        )
        self.state, out = plant.step(
            self.state,
            plant.PlantInputs(drive_v, self.noise_rng),
            plant.PlantStepParams(model, self.fs_hz),
        )
        stamp_ns = stamp_ns_of_sample(index, self.fs_hz)
        self.sensor.publish(stamp_ns, io.sensor_fields(index, self.fs_hz, out))
        # Truth and /clock only when someone listens (volatile: a subscriber gets what follows its
        # match either way); the composed loop alone spends no encoding or DDS write on them.
        if self.truth.subscription_count():
            self.truth.publish(
                stamp_ns,
                io.truth_fields(
                    index,
                    self.fs_hz,
                    out,
                    WingStateBlock.SOURCE_GROUND_TRUTH,
                    self.p["truth_frame_every"],
                    self.tracking_rng,
                    self.model.noise.tracking_noise_deg_rms,
                ),
            )
        if self.clock_pub is not None and self.clock_pub.get_subscription_count():
            self.clock_pub.publish(
                Clock(clock=stamp_from_time_s((index + drive_v.size) / self.fs_hz))
            )


def main(args: list[str] | None = None) -> int:
    return run_node(PlantNode, PARAMS, CONFIG_FILE, NODE_NAME, args)


if __name__ == "__main__":
    raise SystemExit(main())
