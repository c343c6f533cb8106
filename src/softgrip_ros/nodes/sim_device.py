"""sim_device: the simulated valve, regulator and sensor device as a node on a CAN bus.

Faults are ROS parameters, settable at runtime, e.g.
``ros2 param set /sim_device fault.sensor_dropout chamber_a``. The device itself is
softgrip_ros.canbus.sim_device.SimulatedDevice.

With ``world.scene`` set, the device simulates the fingers and an object in a physics world
(softgrip_ros.model.world) and publishes its ground truth on ``sim/object_pose``, ``sim/contacts``
and ``sim/grasp_truth``; ``sim/play_arm_move`` plays the scene's arm moves. Only tests,
benchmarks and the demo read these: no node of the product subscribes to a ``sim/`` topic.
"""
from __future__ import annotations

import dataclasses

import can
from rclpy.node import Node

from softgrip_ros.canbus.sim_device import (DEFAULT_SENSORS, FAULT_CHOICES, FAULTS,
                                            STUCK_READINGS_PA, SimDeviceConfig, SimulatedDevice)
from softgrip_ros.canbus import open_bus
from softgrip_ros.nodes.common import closed_if_cut_short, publish, run_node
from softgrip_ros.nodes.parameters import CAN_SPECS, ParamSpec, check_all, declare
from softgrip_ros.nodes.specs import WORLD_SPECS, gripper_model_spec, load_plant

FAULT_SPECS = [
    ParamSpec("fault.sensor_dropout", "", "silence a sensor (its name, or 'all'); '' = none",
              allow_empty=True),
    ParamSpec("fault.sensor_stuck", "",
              "stick a sensor at fault.sensor_stuck_at (its name, or 'all'); '' = none",
              allow_empty=True),
    ParamSpec(
        "fault.sensor_stuck_at", "present",
        "what a stuck sensor reads: its last reading, or a fixed "
        f"{STUCK_READINGS_PA['low']:.0f} or {STUCK_READINGS_PA['high']:.0f} Pa",
        choices=FAULT_CHOICES["sensor_stuck_at"]),
    ParamSpec("fault.sensor_bias_pa", 0.0, "bias added to every reading", "Pa", -50e3, 50e3),
    ParamSpec("fault.sensor_noise_scale", 1.0, "every sensor's noise multiplied by this", "", 0.0,
              100.0),
    ParamSpec("fault.regulator_overshoot_pa", 0.0,
              "the regulator settles this far above its setpoint", "Pa", -50e3, 100e3),
    ParamSpec("fault.valve_stuck", False, "the valves ignore commands and keep their state"),
    ParamSpec("fault.valve_stuck_open", False,
              "the valves ignore commands and stay open to SUPPLY"),
    ParamSpec("fault.bus_silent", False, "the device stops sending"),
    ParamSpec("fault.corrupt_rate", 0.0,
              "fraction of frames sent with a bad CRC or a repeated counter", "", 0.0, 1.0),
    ParamSpec(
        "fault.replay_rate_hz", 0.0,
        "bursts per second of replayed old frames (old sensor frames on the bus, "
        "an old ValveCommand into the device); 0 = none", "Hz", 0.0, 100.0),
    # firmware defects, for softgrip_check_device
    ParamSpec("fault.crc_corrupt", 0.0, "fraction of frames sent with a wrong CRC byte", "", 0.0,
              1.0),
    ParamSpec("fault.counter_stuck", False, "every frame carries alive counter 0"),
    ParamSpec("fault.heartbeat_off", False, "no DeviceHeartbeat"),
    ParamSpec("fault.ignore_valve_lifetime", False,
              "an open channel stays open past its OpenLifetime"),
    ParamSpec("fault.sensor_rate_hz", 0.0, "every sensor sends at this rate; 0 = each at its own",
              "Hz", 0.0, 1000.0),
]
SPECS = CAN_SPECS + [
    ParamSpec("plant_rate_hz", 1000.0, "plant integration rate", "Hz", 50.0, 5000.0),
    ParamSpec("seed", -1, "noise seed; -1 = random", "", -1, 2**31 - 1),
    ParamSpec("plant_file", "", "the device's truth: the pneumatics and each sensor's noise and "
              "bias (config/plant.yaml when empty; another file plays a user's hardware)",
              allow_empty=True),
] + FAULT_SPECS + [gripper_model_spec("the fingers of the physics world (world.scene)"),
                   *WORLD_SPECS]
assert {s.name[len("fault."):] for s in FAULT_SPECS} == set(FAULTS)


class SimDeviceNode(Node):

    def __init__(self, bus: can.BusABC | None = None, **kwargs):
        super().__init__("sim_device", **kwargs)
        self.specs = {s.name: s for s in SPECS}
        values = declare(self, SPECS)
        # a bad plant file or scene refused before the bus is open
        truth, config, world = device_setup(values)
        self._own_bus, self.device = bus is None, None
        # its frames reach the controller stamped when their readings were taken
        self.bus = bus or open_bus(values["can.interface"], values["can.channel"],
                                   values["can.bitrate"], preserve_timestamps=True)
        # a device thread left running into the interpreter's exit may crash it
        with closed_if_cut_short(self):
            self.device = SimulatedDevice(self.bus, config, world=world)
            for name in FAULTS:
                self.device.set_fault(name, values[f"fault.{name}"])
            self.add_on_set_parameters_callback(self._on_set)
            if world is not None:
                self.truth = WorldTruthPublisher(self, self.device, values["world.truth_rate_hz"],
                                                 lambda path: make_world_from(
                                                     dict(values, **{"world.scene": path}),
                                                     truth.parameters))
            self.get_logger().info(
                f"simulated device on {values['can.interface']}:{values['can.channel']}" +
                (f", world: scene {world.scene.name!r}" if world is not None else ""))
            self.device.start()

    def _on_set(self, parameters):

        def apply(params):
            for parameter in params:
                if parameter.name.startswith("fault."):
                    try:
                        self.device.set_fault(parameter.name[len("fault."):], parameter.value)
                    except ValueError as error:
                        return str(error)
                    self.get_logger().warn(
                        f"fault injected: {parameter.name} = {parameter.value!r}")
                elif parameter.name in self.specs:
                    return f"{parameter.name} is read at start-up only"
            return ""

        return check_all(self.specs, parameters, apply)

    def close(self) -> None:
        """Stop the device and shut the bus it opened; also for a node built part-way."""
        if self.device is not None:
            self.device.stop()
        if self._own_bus:
            self.bus.shutdown()


def device_setup(values: dict):
    """(the plant file's description, the device's SimDeviceConfig, its world or None) from the
    node's parameter values (``default_values()`` for the defaults); ValueError naming a bad plant
    file or scene."""
    truth = load_plant(values)
    sensors = tuple(dataclasses.replace(s, noise_std_pa=truth.sensor(s.name).noise_std_pa,
                                        bias_pa=truth.sensor(s.name).bias_pa)
                    for s in DEFAULT_SENSORS)
    config = SimDeviceConfig(plant=truth.parameters, sensors=sensors,
                             plant_rate_hz=values["plant_rate_hz"],
                             seed=None if values["seed"] < 0 else values["seed"])
    return truth, config, make_world_from(values, truth.parameters)


def default_values() -> dict:
    """Every parameter of the node at its default."""
    return {spec.name: spec.default for spec in SPECS}


def make_world_from(values: dict, plant):
    """The physics world the parameters ask for, None when ``world.scene`` is empty; ValueError
    (the scene's, the model's) naming what is wrong."""
    if not values["world.scene"]:
        return None
    from softgrip_ros.model.world import make_world
    try:
        return make_world(values["world.scene"], values["gripper_model"], values["world.bending"],
                          plant)
    except RuntimeError as error:  # MuJoCo missing
        raise ValueError(f"world.scene: {error}") from None


class WorldTruthPublisher:
    """The world's ground truth on sim/object_pose, sim/contacts and sim/grasp_truth at
    ``rate_hz``, and the services sim/play_arm_move and sim/load_scene (``make_world(path)``
    builds a scene's world)."""

    def __init__(self, node: Node, device: SimulatedDevice, rate_hz: float, make_world):
        from geometry_msgs.msg import PoseStamped

        from softgrip_interfaces.msg import GraspTruth, SimContacts
        from softgrip_interfaces.srv import LoadScene, PlayArmMove
        self.node, self.device, self.make_world = node, device, make_world
        node.create_service(LoadScene, "sim/load_scene", self._load)
        self.publishers = (node.create_publisher(PoseStamped, "sim/object_pose", 10),
                           node.create_publisher(SimContacts, "sim/contacts", 10),
                           node.create_publisher(GraspTruth, "sim/grasp_truth", 10))
        node.create_service(PlayArmMove, "sim/play_arm_move", self._play)
        node.create_timer(1.0 / rate_hz, self._publish)

    def _publish(self) -> None:
        from std_msgs.msg import Header

        from softgrip_ros.nodes.messages import world_truth
        truth = self.device.world_truth()
        header = Header(stamp=self.node.get_clock().now().to_msg(), frame_id="world")
        for publisher, message in zip(self.publishers, world_truth(truth, header)):
            publish(self.node, publisher, message)

    def _load(self, request, response):
        if not request.scene_file:
            response.accepted, response.message = False, "scene_file is empty"
            return response
        try:
            world = self.make_world(request.scene_file)
        except ValueError as error:
            response.accepted, response.message = False, str(error)
            return response
        self.device.replace_world(world)
        response.accepted, response.message = True, ""
        self.node.get_logger().info(f"world: scene {world.scene.name!r}")
        return response

    def _play(self, request, response):
        try:
            self.device.play_arm_move(request.move)
        except ValueError as error:
            response.accepted, response.message = False, str(error)
            return response
        response.accepted, response.message = True, ""
        self.node.get_logger().info(f"arm move {request.move!r}")
        return response


def main(args=None) -> int:
    return run_node(SimDeviceNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
