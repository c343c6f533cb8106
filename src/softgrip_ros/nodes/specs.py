"""Every node's parameters: name, default, meaning, unit and range (config/softgrip.yaml holds
the same, and tests/test_parameters_file.py checks that they agree), and how their values make
each core's configuration: a spec with a ``field`` sets that field of the core's dataclass."""
from __future__ import annotations

import dataclasses
import math

from softgrip_ros.control.grasp_fsm import HOLD_AIR, ON_OBJECT_LOST, GraspConfig
from softgrip_ros.config_paths import config_file
from softgrip_ros.control.pressure import PressureControlConfig
from softgrip_ros.estimation.estimator import EstimatorConfig, SensorConfig
from softgrip_ros.model.fidelity import CHOICES as FIDELITY_CHOICES
from softgrip_ros.model import plant_file
from softgrip_ros.model.force_law import ClampForceLaw, load_table
from softgrip_ros.nodes.parameters import CAN_SPECS, ParamSpec, replace_fields
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
_S = _P.safety


def _safety(name: str, field: str, description: str, unit: str, low: float, high: float):
    return ParamSpec(f"safety.{name}", getattr(_S, field), description, unit, low, high,
                     field=f"safety.{field}")


PRESSURE_CONTROL_SPECS = [  # the control law and safety rules (settable while running)
    ParamSpec("max_gauge_pressure_pa", _P.max_gauge_pa, "hard upper limit of the setpoint", "Pa",
              1e3, 100e3, field="max_gauge_pa"),
    ParamSpec("min_gauge_pressure_pa", _P.min_gauge_pa, "hard lower limit of the setpoint", "Pa",
              -100e3, -1e3, field="min_gauge_pa"),
    ParamSpec("overpressure_margin_pa", _P.overpressure_margin_pa, "measured excess beyond a "
              "limit that vents", "Pa", 100.0, 50e3, field="overpressure_margin_pa"),
    ParamSpec("sensor_timeout", _P.sensor_timeout_s, "no valid reading for this long: hold and "
              "report", "s", 0.005, 10.0, field="sensor_timeout_s"),
    ParamSpec("command_timeout", _P.command_timeout_s, "no command for this long while "
              "regulating: safe action", "s", 0.1, 3600.0, field="command_timeout_s"),
    ParamSpec("command_timeout_action", _P.command_timeout_action, "safe action on a command "
              "timeout", choices=("hold", "vent"), field="command_timeout_action"),
    ParamSpec("default_rate_pa_per_s", _P.default_rate_pa_per_s, "setpoint slew when a command "
              "gives none", "Pa/s", 1e3, 1e8, field="default_rate_pa_per_s"),
    ParamSpec("kp", _P.kp, "proportional gain of the trim", "Pa/Pa", 0.0, 10.0, field="kp"),
    ParamSpec("ki_per_s", _P.ki_per_s, "integral gain of the trim", "1/s", 0.0, 1000.0,
              field="ki_per_s"),
    ParamSpec("trim_limit_pa", _P.trim_limit_pa, "largest trim of the regulator setpoint", "Pa",
              0.0, 50e3, field="trim_limit_pa"),
    _safety(
        "reaction_time", "reaction_time_s", "the limit trip extrapolates each pressure over "
        "this: a control period, the bus and the valve's response", "s", 0.001, 0.2),
    _safety("disagreement_pa", "disagreement_pa", "two sensors further apart than this ...", "Pa",
            500.0, 50e3),
    _safety("disagreement_time", "disagreement_time_s", "... for this long: SENSOR_DISAGREE", "s",
            0.005, 5.0),
    _safety("stuck_time", "stuck_time_s", "a reading unchanged this long ...", "s", 0.01, 10.0),
    _safety("stuck_motion_pa", "stuck_motion_pa", "... while another sensor or the plant moved "
            "the pressure by this: SENSOR_STUCK", "Pa", 100.0, 50e3),
    _safety("noise_ratio", "noise_ratio", "a sensor's noise above this times its rated noise ...",
            "", 1.5, 1000.0),
    _safety("noise_time", "noise_time_s", "... for this long: SENSOR_NOISE", "s", 0.01, 10.0),
    _safety(
        "jump_sigmas", "jump_sigmas", "every sensor stepping, in one sample, by more than the "
        "plant's fastest rate allows plus this many noise sigmas: SENSOR_IMPLAUSIBLE", "", 3.0,
        1000.0),
    _safety("response_window", "response_window_s", "the chamber's response to a valve state is "
            "judged over this", "s", 0.01, 1.0),
    _safety("response_settle", "response_settle_s", "... from this long after the valve state was "
            "commanded", "s", 0.0, 1.0),
    _safety(
        "response_min_change_pa", "response_min_change_pa", "a change judged against the "
        "plant must be predicted this large; a chamber moving this much with the valves "
        "closed is a fault", "Pa", 100.0, 50e3),
    _safety(
        "response_tolerance", "response_tolerance", "the measured change may differ from the "
        "plant's by this fraction of it (the model's rates within about 2x of the "
        "hardware's)", "", 0.05, 0.95),
    _safety("response_time", "response_time_s", "a response off the plant in every check this "
            "long: RESPONSE", "s", 0.005, 5.0),
    _safety("regulator_deviation_pa", "regulator_deviation_pa", "the regulator's output further "
            "from its model than this ...", "Pa", 1e3, 200e3),
    _safety("regulator_deviation_time", "regulator_deviation_time_s", "... for this long: "
            "REGULATOR", "s", 0.005, 5.0),
    _safety("nis_ratio", "nis_ratio", "the estimator's windowed NIS of a sensor above this times "
            "its bound ...", "", 1.0, 1e6),
    _safety("nis_time", "nis_time_s", "... for this long: SENSOR_INCONSISTENT", "s", 0.01, 60.0),
    _safety("clear_time", "clear_time_s", "a safety fault clears on a new command once its "
            "evidence has been gone this long", "s", 0.05, 60.0),
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
        "one per frame; a reading beyond the limits is then acted on within it; 0 = each "
        "frame at once", "s", 0.0, 0.05),
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
    ParamSpec("sensor_timeout", _E.sensor_timeout_s, "a sensor silent this long is dropped from "
              "fusion", "s", 0.001, 10.0, field="sensor_timeout_s"),
    ParamSpec("filter_type", _E.filter_type, "the filter", choices=("kf", "ekf", "ukf"),
              field="filter_type"),
    ParamSpec(
        "fusion_window", 0.02, "while the chamber rests, samples this close are fused in "
        "one filter step (0: each at once; 20 ms: one fusion every other bus batch while "
        "the controller rests)", "s", 0.0, 0.02, field="fusion_window_s"),
    ParamSpec(
        "input_timing_std", _E.input_timing_std_s, "how far an input's effect at the "
        "device may lie from its stamp (1 sigma); P grows by the change in rate times "
        "this at each input change", "s", 0.0, 0.1, field="input_timing_std_s"),
    ParamSpec(
        "sample_timing_std", _E.sample_timing_std_s, "how far a reading's stamp may lie from "
        "its sampling (1 sigma); the chamber's rate times this adds to each sensor's noise",
        "s", 0.0, 0.01, field="sample_timing_std_s"),
    ParamSpec(
        "nis_input_settle", _E.nis_input_settle_s, "samples this soon after an input "
        "change, or after every sensor fell silent, stay out of the NIS window (still gated and "
        "fused): the inputs' timing is uncertain there", "s", 0.0, 1.0,
        field="nis_input_settle_s"),
    ParamSpec(
        "rewind_horizon", _E.rewind_horizon_s, "an input change stamped up to this long before "
        "the filter's time (a status held up on a loaded host) is applied at its stamp, the "
        "samples since taken again; 0: applied at the filter's time", "s", 0.0, 1.0,
        field="rewind_horizon_s"),
    ParamSpec(
        "max_fusion_shift_pa", _E.max_fusion_shift_pa, "the chamber rests (see "
        "fusion_window) while its modelled change over the window stays within this", "Pa", 1.0,
        1000.0, field="max_fusion_shift_pa"),
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
    ParamSpec("nis_window", _E.nis_window, "samples per sensor in the NIS consistency window", "",
              10, 100000),
    ParamSpec("max_consecutive_rejections", _E.max_consecutive_rejections,
              "rejections in a row from every live sensor before re-initialising", "", 1, 100000),
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
        sensors=sensors, nis_window=values["nis_window"],
        process_noise_pa2_per_s=tuple(float(v) for v in values["process_noise_covariance"]),
        max_consecutive_rejections=values["max_consecutive_rejections"])
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
_G = GraspConfig()
_F = {f.name: f.default for f in dataclasses.fields(ClampForceLaw) if f.name != "table"}
GRASP_FSM_SPECS = [
    ParamSpec("max_gauge_pressure_pa", _G.max_gauge_pa, "highest pressure a command may ask "
              "for", "Pa", 1e3, 100e3, field="max_gauge_pa"),
    ParamSpec("min_gauge_pressure_pa", _G.min_gauge_pa, "lowest pressure a command may ask for",
              "Pa", -100e3, -1e3, field="min_gauge_pa"),
    ParamSpec("envelop_margin_m", _G.envelop_margin_m, "D2 beyond the object before ENVELOPED",
              "m", 1e-4, 0.1, field="envelop_margin_m"),
    ParamSpec("pinch_max_diameter_m", _G.pinch_max_diameter_m, "largest object for PINCH", "m",
              1e-4, 0.02, field="pinch_max_diameter_m"),
    ParamSpec("release_tip_spacing_m", _G.release_tip_spacing_m, "least opening after RELEASE",
              "m", 1e-3, 0.15, field="release_tip_spacing_m"),
    ParamSpec("pressure_tolerance_pa", _G.pressure_tolerance_pa, "a phase's pressure counts as "
              "reached within this", "Pa", 100.0, 20e3, field="pressure_tolerance_pa"),
    ParamSpec("settle_time", _G.settle_s, "time within tolerance before a phase completes", "s",
              0.01, 5.0, field="settle_s"),
    ParamSpec("auto_clamp_delay", _G.auto_clamp_delay_s, "ENVELOPED to CLAMPING on its own after "
              "this; < 0: wait for CLAMP", "s", -1.0, 600.0, field="auto_clamp_delay_s"),
    ParamSpec("opening_timeout", _G.opening_timeout_s, "OPENING longer than this: FAULT", "s", 0.1,
              60.0, field="opening_timeout_s"),
    ParamSpec("clamping_timeout", _G.clamping_timeout_s, "CLAMPING longer than this: FAULT", "s",
              0.1, 60.0, field="clamping_timeout_s"),
    ParamSpec("releasing_timeout", _G.releasing_timeout_s, "RELEASING longer than this: FAULT",
              "s", 0.1, 60.0, field="releasing_timeout_s"),
    ParamSpec("hold_error_limit_pa", _G.hold_error_limit_pa, "HOLDING pressure off target by "
              "more than this ...", "Pa", 500.0, 50e3, field="hold_error_limit_pa"),
    ParamSpec("hold_error_time", _G.hold_error_time_s, "... for this long: FAULT", "s", 0.01, 10.0,
              field="hold_error_time_s"),
    ParamSpec("hold_air", _G.hold_air, "HOLDING once settled: trap (valves closed, topped up "
              "past pressure_tolerance_pa; a lost object shows in the pressure) or regulate "
              "(the regulated line open; a loss is not sensed)", choices=HOLD_AIR,
              field="hold_air"),
    ParamSpec("on_object_lost", _G.on_object_lost, "a loss sensed in HOLDING: hold (report "
              "it), release, or fault (vent)", choices=ON_OBJECT_LOST, field="on_object_lost"),
    ParamSpec("sensing_wait", _G.sensing_wait_s, "a HOLDING goal waits this long for the "
              "closing's sensed verdict", "s", 0.0, 10.0, field="sensing_wait_s"),
]
CLAMP_FORCE_SPECS = [  # the clamp force law itself is the gripper model's table
    ParamSpec("friction_coefficient", _F["friction_coefficient"], "friction when a command gives "
              "none", "", 0.05, 2.0, field="friction_coefficient"),
    ParamSpec("safety_factor", _F["safety_factor"], "clamp force over what the weight needs", "",
              1.0, 10.0, field="safety_factor"),
    ParamSpec("min_squeeze_pa", _F["min_squeeze_pa"], "a clamp presses at least this far below "
              "the contact pressure, even for a weightless object", "Pa", 0.0, 50e3,
              field="min_squeeze_pa"),
]
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
    return replace_fields(_G, GRASP_FSM_SPECS, values)


def clamp_force_law(values: dict) -> ClampForceLaw:
    """The gripper model's tabulated law (``gripper_model``, ``fidelity``) with these parameters'
    friction and safety; ValueError when the model has no table and none can be made."""
    return ClampForceLaw(load_table(values["gripper_model"], values["fidelity"]),
                         **{s.field: values[s.name] for s in CLAMP_FORCE_SPECS})
