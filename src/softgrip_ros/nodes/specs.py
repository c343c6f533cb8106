"""Every node's parameters: name, default, meaning, unit and range, and how their values make
each core's configuration. A spec with a ``field`` sets that field of the core's dataclass and
takes its meaning, unit, range and default from the field's setting (softgrip_ros.settings), so
that the dataclass refuses what the parameter refuses. config/softgrip.yaml is written from these
specs (nodes.params_file)."""
from __future__ import annotations

import math

from softgrip_ros.control.grasp_fsm import GraspConfig
from softgrip_ros.config_paths import config_file
from softgrip_ros.control.pressure import PressureControlConfig
from softgrip_ros.estimation.config import EstimatorConfig, SensorConfig
from softgrip_ros.model.fidelity import CHOICES as FIDELITY_CHOICES
from softgrip_ros.model import plant_file
from softgrip_ros.model.force_law import ClampForceLaw, load_table
from softgrip_ros.nodes.parameters import CAN_SPECS, ParamSpec, field_spec, replace_fields
from softgrip_ros.runtime.worker_process import WORKER_NICE_INCREMENT



def gripper_model_spec(what: str = "the fingers' model") -> ParamSpec:
    return ParamSpec("gripper_model", "type_II", f"{what}: a paper cavity type "
                     "(type_I, type_II, type_III), a softgrip_calibrate calibration's name, or "
                     "its file")


# the physics world of the simulated device (sim_device, and controller with a virtual bus)
WORLD_SPECS = [
    ParamSpec("world.scene", "", "a scene file (config/scenes/*.yaml): the simulated device "
              "then simulates the fingers and the object in MuJoCo; empty: no world",
              allow_empty=True),
    ParamSpec("world.bending", "l0", "the bending law that drives the world's fingers",
              choices=("l0", "l1")),
    ParamSpec("world.truth_rate_hz", 50.0, "the rate of the ground truth (on sim/object_pose, "
              "sim/contacts, sim/grasp_truth)", "Hz", 1.0, 500.0),
]


def plant_file_spec(uses: str) -> ParamSpec:
    return ParamSpec("plant_file", "", f"the plant description ({uses}); empty: the installed "
                     "config/plant.yaml", allow_empty=True)


def load_plant(values: dict) -> plant_file.PlantDescription:
    """The plant file the ``plant_file`` parameter names (the installed one when empty);
    ValueError naming what is wrong with it."""
    try:
        path = values["plant_file"] or config_file("plant.yaml")
    except FileNotFoundError as error:
        raise ValueError(str(error)) from None
    return plant_file.load(path)


def _stamp_tolerance(what: str) -> ParamSpec:
    return ParamSpec("stamp_tolerance", 0.5, f"{what} stamped further ahead of this node's clock "
                     "than this is refused", "s", 0.0, 60.0)


# ---- pressure_controller ------------------------------------------------------------------------
_P = PressureControlConfig()
_SAFETY_FIELDS = ("reaction_time", "disagreement_pa", "disagreement_time", "stuck_time",
                  "stuck_motion_pa", "noise_ratio", "noise_time", "jump_sigmas", "response_window",
                  "response_settle", "response_min_change_pa", "response_tolerance",
                  "response_time", "regulator_deviation_pa", "regulator_deviation_time",
                  "nis_ratio", "nis_time", "clear_time")


def _seconds_field(name: str) -> str:
    """A parameter's field: the parameter's name, with _s for a time (ROS parameters name a time
    without its unit, as robot_localization does)."""
    return name if name.endswith(("_pa", "_ratio", "_sigmas", "_tolerance")) else name + "_s"


PRESSURE_CONTROL_SPECS = [  # the control law and safety rules (settable while running)
    field_spec("max_gauge_pressure_pa", PressureControlConfig, "max_gauge_pa"),
    field_spec("min_gauge_pressure_pa", PressureControlConfig, "min_gauge_pa"),
    field_spec("overpressure_margin_pa", PressureControlConfig, "overpressure_margin_pa"),
    field_spec("sensor_timeout", PressureControlConfig, "sensor_timeout_s"),
    field_spec("command_timeout", PressureControlConfig, "command_timeout_s"),
    field_spec("command_timeout_action", PressureControlConfig, "command_timeout_action"),
    field_spec("default_rate_pa_per_s", PressureControlConfig, "default_rate_pa_per_s"),
    field_spec("kp", PressureControlConfig, "kp"),
    field_spec("ki_per_s", PressureControlConfig, "ki_per_s"),
    field_spec("trim_limit_pa", PressureControlConfig, "trim_limit_pa"),
    *(field_spec(f"safety.{name}", PressureControlConfig, f"safety.{_seconds_field(name)}")
      for name in _SAFETY_FIELDS),
]
PRESSURE_CONTROLLER_SPECS = (CAN_SPECS + [
    ParamSpec("autostart", True, "configure and activate on start-up"),
    ParamSpec(
        "identification_mode", False, "open loop for softgrip_identify: commands come on "
        "~/identification_command only, their source is the valve and their target the "
        "regulator setpoint (SUPPLY) or where an evacuation stops (VACUUM); every limit and "
        "safety check stays; changes only while the node is inactive"),
    ParamSpec("control_rate_hz", 500.0, "control loop rate", "Hz", 10.0, 1000.0),
    ParamSpec(
        "rest_rate_hz", 50.0, "control loop rate while venting, holding or faulted (a "
        "command or a reading beyond the limits steps at once); <= control_rate_hz", "Hz", 10.0,
        1000.0),
    ParamSpec(
        "rest_receive_period", 0.01, "while the controller rests (not regulating), "
        "received frames are taken in batches this often, one thread wake each instead of "
        "one per frame; a reading beyond the limits is then acted on within it; 0 = at every "
        "control period", "s", 0.0, 0.05),
    ParamSpec("status_rate_hz", 50.0, "controller/status publish rate", "Hz", 1.0, 200.0),
    ParamSpec(
        "command_frame_period", 0.01, "RegulatorSetpoint and ValveCommand re-sent this "
        "often when unchanged (a change goes out in its control period); 0 = every "
        "period", "s", 0.0, 0.1),
    ParamSpec(
        "valve_lifetime", 0.025, "the device closes SUPPLY/VACUUM valves this long after "
        "the last ValveCommand (a stalled controller leaves the chamber held); >= 2 "
        "re-send periods", "s", 0.004, 0.255),
    ParamSpec(
        "use_estimate", False, "regulate on pressure/estimate while it is fresh (its "
        "latency makes the boost overshoot)"),
    ParamSpec("sensors.names", ["chamber_a", "chamber_b"], "sensor names: topics "
              "pressure/sensor/<name>"),
    ParamSpec("sensors.messages", ["PressureSensor1", "PressureSensor2"], "the DBC message of "
              "each sensor"),
    plant_file_spec("its feed-forward, boost ceiling and safety checks; each sensor's noise, "
                    "for FluidPressure.variance and the noise check, and its bias, taken off "
                    "every reading"),
    _stamp_tolerance("a command"),
    *PRESSURE_CONTROL_SPECS,
])
# the settings the bus, the sensors and the loop are built with: they apply at configure
PRESSURE_CONFIGURE_PREFIXES = ("can.", "sensors.", "control_rate_hz", "rest_rate_hz",
                               "rest_receive_period", "command_frame_period", "valve_lifetime")


def frame_id_specs(message_names) -> list:
    """can.frame_ids.<message> for each DBC message: an arbitration ID that replaces the DBC's."""
    return [
        ParamSpec(f"can.frame_ids.{name}", 0, f"arbitration ID of {name}; 0 = the DBC's", "", 0,
                  0x7FF) for name in message_names
    ]


def frame_id_overrides(values: dict, message_names) -> dict:
    """{message: arbitration ID} of the can.frame_ids.<message> that are set (not 0)."""
    return {n: values[f"can.frame_ids.{n}"] for n in message_names if values[f"can.frame_ids.{n}"]}


def sensor_settings(values: dict, plant: plant_file.PlantDescription) -> list:
    """[(name, DBC message, SensorModel from the plant file)] of the pressure controller's
    sensors; ValueError unless the two lists are equally long and not empty, and the plant file
    describes every sensor."""
    names, dbc_messages = values["sensors.names"], values["sensors.messages"]
    if len(names) != len(dbc_messages) or not names:
        raise ValueError("sensors.names and sensors.messages need equal, non-zero lengths")
    return [(n, m, plant.sensor(n)) for n, m in zip(names, dbc_messages)]


def pressure_control_config(values: dict) -> PressureControlConfig:
    return replace_fields(_P, PRESSURE_CONTROL_SPECS, values)


def check_rest_rate(values: dict) -> None:
    if values["rest_rate_hz"] > values["control_rate_hz"]:
        raise ValueError(f"rest_rate_hz ({values['rest_rate_hz']:g} Hz) must not exceed "
                         f"control_rate_hz ({values['control_rate_hz']:g} Hz)")


# ---- estimator ----------------------------------------------------------------------------------
_E = EstimatorConfig()
ESTIMATOR_FILTER_SPECS = [
    field_spec("sensor_timeout", EstimatorConfig, "sensor_timeout_s"),
    field_spec("filter_type", EstimatorConfig, "filter_type"),
    # the library fuses each sample at once; the node batches them while the chamber rests
    field_spec("fusion_window", EstimatorConfig, "fusion_window_s", default=0.02),
    field_spec("input_timing_std", EstimatorConfig, "input_timing_std_s"),
    field_spec("sample_timing_std", EstimatorConfig, "sample_timing_std_s"),
    field_spec("nis_input_settle", EstimatorConfig, "nis_input_settle_s"),
    field_spec("rewind_horizon", EstimatorConfig, "rewind_horizon_s"),
    field_spec("max_fusion_shift_pa", EstimatorConfig, "max_fusion_shift_pa"),
    field_spec("nis_window", EstimatorConfig, "nis_window"),
    field_spec("max_consecutive_rejections", EstimatorConfig, "max_consecutive_rejections"),
]
ESTIMATOR_SPECS = [
    ParamSpec("frequency", 200.0, "largest pressure/estimate rate (predictions while silent: at "
              "most 50 Hz)", "Hz", 1.0, 2000.0),
    ParamSpec(
        "rest_frequency", 20.0, "pressure/estimate rate while the chamber rests (see "
        "fusion_window); <= frequency", "Hz", 1.0, 2000.0),
    *ESTIMATOR_FILTER_SPECS,
    ParamSpec("sensors.names", ["chamber_a", "chamber_b"], "sensors fused: topics "
              "pressure/sensor/<name>"),
    plant_file_spec("the process model, and each sensor's noise: R = noise^2"),
    ParamSpec("sensors.rejection_threshold", [16.0, 16.0], "Mahalanobis gate of each sensor, "
              "chi-square with 1 dof (16 = 4 sigma)"),
    ParamSpec(
        "process_noise_covariance", list(_E.process_noise_pa2_per_s),
        "Q spectral density over [chamber, regulator]: 2 values (diagonal) or 4 (full, "
        "row-major)", "Pa^2/s"),
    _stamp_tolerance("a sample, status or command"),
]


def estimator_config(values: dict, plant: plant_file.PlantDescription) -> EstimatorConfig:
    """The estimator's configuration from the parameter values and the plant file (each sensor's
    noise); ValueError names a bad one."""
    names, gates = values["sensors.names"], values["sensors.rejection_threshold"]
    if len(names) != len(gates):
        raise ValueError(f"sensors.names and sensors.rejection_threshold need one entry per "
                         f"sensor; got {len(names)} and {len(gates)}")
    sensors = tuple(SensorConfig(n, plant.sensor(n).noise_std_pa, float(g))
                    for n, g in zip(names, gates))
    base = EstimatorConfig(
        sensors=sensors,
        process_noise_pa2_per_s=tuple(float(v) for v in values["process_noise_covariance"]))
    if values["rest_frequency"] > values["frequency"]:
        raise ValueError(f"rest_frequency ({values['rest_frequency']:g} Hz) must not exceed "
                         f"frequency ({values['frequency']:g} Hz)")
    return replace_fields(base, ESTIMATOR_FILTER_SPECS, values)


# ---- kinematics ---------------------------------------------------------------------------------
KINEMATICS_SPECS = [
    ParamSpec("publish_rate_hz", 200.0, "largest tip_pose rate (one per estimate up to this)",
              "Hz", 1.0, 2000.0),
    ParamSpec("marker_rate_hz", 10.0, "finger_markers rate while subscribed", "Hz", 0.5, 60.0),
    ParamSpec("fidelity", "auto", "model: l0, l1, l2, or auto (the cheapest whose error bound "
              "meets tolerance_m)", choices=FIDELITY_CHOICES),
    ParamSpec(
        "tolerance_m", 1e-2, "tip-position error auto must stay within (bounds: "
        "config/model_error_bounds.yaml; no law is within 1 mm of the FE in free bending)", "m",
        1e-6, 0.1),
    ParamSpec("resolve_pressure_pa", 200.0, "an L2 solve runs again once the pressure moved by "
              "more than this", "Pa", 0.0, 5000.0),
    ParamSpec("min_solve_interval", 0.1, "... and at most once per this (its CPU would starve "
              "the pressure loop)", "s", 0.0, 10.0),
    ParamSpec(
        "l2_nice_increment", WORKER_NICE_INCREMENT, "added to the nice value of "
        "the L2 solver's child process, so that its solves yield the CPU to the pressure "
        "loop, the CAN reception and the estimator", "", 0, 19),
    gripper_model_spec(),
    ParamSpec("frame_id", "softgrip_base", "frame of the tip poses and markers (after prefix)"),
    ParamSpec("prefix", "", "put before every joint and frame name, as the URDF's prefix does "
              "(several grippers in one robot)", allow_empty=True),
    _stamp_tolerance("an estimate"),
]

# ---- grasp_manager ------------------------------------------------------------------------------
_G_FIELDS = (("max_gauge_pressure_pa", "max_gauge_pa"), ("min_gauge_pressure_pa", "min_gauge_pa"),
             ("envelop_margin_m", "envelop_margin_m"),
             ("pinch_max_diameter_m", "pinch_max_diameter_m"),
             ("release_tip_spacing_m", "release_tip_spacing_m"),
             ("pressure_tolerance_pa", "pressure_tolerance_pa"), ("settle_time", "settle_s"),
             ("auto_clamp_delay", "auto_clamp_delay_s"), ("opening_timeout", "opening_timeout_s"),
             ("clamping_timeout", "clamping_timeout_s"),
             ("releasing_timeout", "releasing_timeout_s"),
             ("hold_error_limit_pa", "hold_error_limit_pa"),
             ("hold_error_time", "hold_error_time_s"),
             ("hold_air", "hold_air"), ("on_object_lost", "on_object_lost"),
             ("sensing_wait", "sensing_wait_s"))
GRASP_FSM_SPECS = [field_spec(name, GraspConfig, field) for name, field in _G_FIELDS]
# the clamp force law itself is the gripper model's table
CLAMP_FORCE_SPECS = [field_spec(name, ClampForceLaw, name)
                     for name in ("friction_coefficient", "safety_factor", "min_squeeze_pa")]
GRASP_MANAGER_SPECS = [
    gripper_model_spec(),
    ParamSpec("fidelity", "l0", "bending law of the grasp model (opening pressures, D2)",
              choices=("l0", "l1")),
    ParamSpec("scene_fidelity", "auto", "model reported in grasp_state for the scene: as the "
              "kinematics node's fidelity", choices=FIDELITY_CHOICES),
    ParamSpec("tolerance_m", 1e-2, "as the kinematics node's tolerance_m", "m", 1e-6, 0.1),
    ParamSpec("state_rate_hz", 20.0, "grasp_state publish rate (and on every change)", "Hz", 10.0,
              200.0),
    ParamSpec("command_refresh_s", 0.5, "pressure/command re-sent this often", "s", 0.05, 10.0),
    ParamSpec("estimate_timeout", 0.1, "an estimate older than this is not used "
              "(controller/status instead)", "s", 0.01, 5.0),
    ParamSpec("status_timeout", 1.0, "no controller/status this long during a grasp: FAULT", "s",
              0.1, 60.0),
    ParamSpec(
        "sensor_fault_grace", 0.3, "a sensor timeout or silent bus this long during a "
        "grasp: FAULT (the controller holds meanwhile)", "s", 0.0, 5.0),
    ParamSpec("gripper_action", "gripper_cmd", "name of the control_msgs/GripperCommand "
              "action (relative: a namespace applies)"),
    ParamSpec("parallel_gripper_action", "parallel_gripper_cmd", "name of the "
              "control_msgs/ParallelGripperCommand action"),
    ParamSpec("goal_tolerance_m", 0.005, "a gripper goal's position counts as reached within "
              "this of the modelled D2 (an opening aims pressure_tolerance_pa above the goal's "
              "pressure: some mm)", "m", 1e-4, 0.05),
    ParamSpec("default_effort_n", 1.0, "the closing force per finger of a gripper goal whose "
              "max_effort is 0", "N", 0.01, 20.0),
    ParamSpec("prefix", "", "put before the tip_spacing joint name of ParallelGripperCommand, "
              "as the URDF's prefix", allow_empty=True),
    ParamSpec("object_sensing", False, "judge the object from the air (object_status; "
              "docs/grasp_sensing.md; with hold_air trap for losses); false: object_held is "
              "always false"),
    ParamSpec("sensors.names", ["chamber_a", "chamber_b"], "sensors the object sensing reads: "
              "topics pressure/sensor/<name>, their noise from the plant file"),
    ParamSpec("sensors.rates_hz", [500.0, 200.0], "each sensor's reading rate, as the device "
              "sends (what a loss's step must clear)", "Hz"),
    plant_file_spec("the air's flows the object sensing simulates, and each sensor's noise"),
    *GRASP_FSM_SPECS,
    *CLAMP_FORCE_SPECS,
]


def sensing_sensors(values: dict, plant: plant_file.PlantDescription) -> dict:
    """{name: SensorNoise} of the sensors the object sensing reads (``sensors.names``,
    ``sensors.rates_hz``, the plant file's noise); ValueError names a bad one."""
    from softgrip_ros.estimation.grasp_sensing import SensorNoise

    names, rates = values["sensors.names"], values["sensors.rates_hz"]
    if not names or len(names) != len(rates):
        raise ValueError(f"sensors.names and sensors.rates_hz need one entry per sensor; got "
                         f"{len(names)} and {len(rates)}")
    for name, rate in zip(names, rates):
        if not (math.isfinite(rate) and 0.0 < rate <= 10e3):
            raise ValueError(f"sensors.rates_hz: {name} at {rate} Hz; each must lie in "
                             "(0, 10000] Hz")
    return {name: SensorNoise(max(plant.sensor(name).noise_std_pa, 1.0), float(rate))
            for name, rate in zip(names, rates)}


def grasp_config(values: dict) -> GraspConfig:
    return replace_fields(GraspConfig(), GRASP_FSM_SPECS, values)


def clamp_force_law(values: dict) -> ClampForceLaw:
    """The gripper model's tabulated law (``gripper_model``, ``fidelity``) with these parameters'
    friction and safety; ValueError when the model has no table and none can be made."""
    return ClampForceLaw(load_table(values["gripper_model"], values["fidelity"]),
                         **{s.field: values[s.name] for s in CLAMP_FORCE_SPECS})
