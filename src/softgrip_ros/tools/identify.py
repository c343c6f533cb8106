"""softgrip_identify: fit the plant file (config/plant.yaml) to your gripper, through the running
pressure controller over DDS and CAN, as on hardware; or again from the log it recorded.

    softgrip_identify --output my_gripper --volume-m3 21e-6     # live: ~50 s of excitation
    softgrip_identify --from-log my_gripper/recording --output refit

Live, it deactivates the pressure controller (which vents), sets its identification_mode,
activates it, and runs an excitation on ~/identification_command: the regulator alone, fills,
vents, the chamber swung across the limits, evacuations, a PRBS, then a held-out part for
validation (softgrip_ros.estimation.identification). Every reading and status goes into a
rosbag2 log (MCAP). Then the controller is restored (deactivated, mode off, activated) and the
fit runs. A sensor that drops out or saturates, a fault the controller latches, or Ctrl-C stops
it: it vents, restores the controller, says why, and writes nothing. A run whose readings
cannot be fitted writes no plant file but keeps its log in --output/recording, to fit again
with --from-log.

Writes into --output: plant.yaml (provenance, each value's source, interval and flag; select it
with the nodes' plant_file parameter), identification.md (the report), identification.png
(measured against fitted pressure, and the residuals), recording/ (the log).

Pressure data cannot tell the chamber's volume from the conductances (the report says why):
give the volume you measured with --volume-m3, or the base file's is kept and said to be.

With --known-object-m D, the known-object step instead (softgrip_ros.tools.identify_contact):
clamps on nothing, then on a rigid object D m wide that you place between the fingers when asked
(press Enter), learn how much air the fingers' bending takes, so that the grasp sensing judges
with your gripper's figure; it writes the base plant file with its contact section, contact.md
and contact.png. Run it after the pneumatics' identification, with that file as --base.

Exit status: 0 written; 1 stopped, refused or not fittable; 2 bad arguments; 3 no controller.
"""
from __future__ import annotations

import argparse
import datetime
import math
import pathlib
import shutil
import sys
import tempfile
import threading
import time

import yaml

from softgrip_ros.argtypes import Number
from softgrip_ros.client import add_namespace_argument
from softgrip_ros.control.reports import outputs_changed_at
from softgrip_ros.estimation import identification
from softgrip_ros.model import plant_file
from softgrip_ros.model.pneumatics import P_ATM_PA, Valve
from softgrip_ros.tools import bag, identify_contact
from softgrip_ros.tools.identification_report import write

INFO_TOPIC = "/softgrip_identify/info"
LOG_FORMAT = "softgrip_identify/1"
KNOWN_OBJECT_RANGE_M = (0.002, 0.2)
CLOSING_KINDS = ("empty", "object")
VALVE_STATES = frozenset(int(valve) for valve in Valve)
# a sensor whose readings stop this long on DDS has dropped out or saturated (DDS may lose a few
# when this process is starved; the controller's own frame age, which sees the bus, says sooner
# when every sensor stops)
SILENT_S = 1.0
FRAME_AGE_S = 0.25
BLIND_GRACE_S = 0.3  # the controller unable to see the chamber this long: stop (as the grasp does)
CHANGE_RESOLUTION_S = 1e-3  # statuses dating their outputs this close say the same change
REFRESH_S = 0.5  # a held command is sent again this often (the controller's command timeout)
LIMIT_USE = 0.9  # the excitation uses this much of each pressure limit


class Stopped(Exception):
    """The live run stopped: the reason, said to the user."""


def _plant_range(name: str) -> Number:
    """The plant file's range of ``name`` (softgrip_ros.model.plant_file.PARAMETERS)."""
    unit, low, high, _ = plant_file.PARAMETERS[name]
    return Number(low, high, unit)


def parser() -> argparse.ArgumentParser:
    top = argparse.ArgumentParser(prog="softgrip_identify", description=__doc__,
                                  formatter_class=argparse.RawDescriptionHelpFormatter)
    add_namespace_argument(top)
    top.add_argument("--output", type=pathlib.Path, help="where to write (default: "
                     "identification-<date>-<time> here); must not hold a plant.yaml yet")
    top.add_argument("--from-log", type=pathlib.Path, metavar="DIR",
                     help="fit a log recorded earlier (its recording/ directory) instead of "
                     "running the excitation")
    top.add_argument("--volume-m3", type=_plant_range("chamber_volume_m3"),
                     help="the channel's air volume at 0 Pa gauge, measured (default: the base "
                     "file's, said to be inherited)")
    top.add_argument("--vacuum-source-pa", type=_plant_range("vacuum_source_gauge_pa"),
                     metavar="PA",
                     help="the vacuum pump's level, gauge Pa (negative: -80000, or "
                     "--vacuum-source-pa=-80e3), measured: held instead of fitted (within the "
                     "limits the data hardly tell it from the vacuum path's critical ratio; "
                     "default: fitted, and likely flagged)")
    top.add_argument("--base", type=pathlib.Path, help="the plant file for what the data cannot "
                     "give (default: the controller's own)")
    top.add_argument("--quick", action="store_true", help="a shorter excitation (~19 s)")
    top.add_argument("--seed", type=Number(0, 2**32 - 1, integer=True), default=0,
                     help="the PRBS's seed")
    top.add_argument("--fit-budget-s", type=Number(0.0, math.inf, "s", low_open=True),
                     default=identification.FIT_BUDGET_S,
                     metavar="S", help="the time the fit should take (default %(default)g s): "
                     "the fit starts no pass re-dating the valve switches that would end past "
                     f"{100 * identification.REDATE_SHARE:g} %% of it, and flags the result if "
                     "they had not settled; inf for no limit")
    top.add_argument("--timeout", type=Number(0.0, 3600.0, "s", low_open=True), default=15.0,
                     help="seconds to wait for the controller's services")
    top.add_argument("--known-object-m", type=Number(*KNOWN_OBJECT_RANGE_M, "m"), metavar="D",
                     help="the known-object step: a rigid object D m wide (a cylinder's "
                     "diameter), placed between the fingers when asked")
    top.add_argument("--gripper-model", default="type_II",
                     help="the fingers' model for the known-object step (the grasp manager's "
                     "gripper_model; default %(default)s)")
    return top


def _check(args, error) -> None:
    if args.from_log is not None and not (args.from_log / "metadata.yaml").is_file():
        error(f"--from-log {args.from_log}: no rosbag2 log there (no metadata.yaml)")
    if args.output is not None and (args.output / "plant.yaml").exists():
        error(f"{args.output / 'plant.yaml'} exists: choose another --output")
    from softgrip_ros.fileio import OutputError, check_writable_directory
    try:  # the default output goes into the working directory
        check_writable_directory(args.output or pathlib.Path.cwd())
    except OutputError as problem:
        error(f"--output: {problem}")
    if args.output is not None and args.from_log is None and (args.output / "recording").exists():
        error(f"{args.output / 'recording'} exists (a log kept from an earlier run: fit it with "
              "--from-log): choose another --output")
    if args.known_object_m is not None and args.from_log is None:
        from softgrip_ros.model import gripper_models
        try:
            gripper_models.resolve(args.gripper_model)
        except ValueError as problem:
            error(f"--gripper-model: {problem}")


# ---- live ---------------------------------------------------------------------------------------
class Live:
    """The controller's services and topics, and what arrives, recorded (CDR bytes)."""

    def __init__(self, node, namespace: str, timeout_s: float):
        from rcl_interfaces.srv import GetParameters, SetParameters
        from lifecycle_msgs.srv import ChangeState
        from softgrip_interfaces.msg import PressureCommand
        self.node, self.timeout_s = node, timeout_s
        prefix = namespace.rstrip("/")
        self.controller = f"{prefix}/pressure_controller"
        self.prefix = prefix
        self._get = node.create_client(GetParameters, f"{self.controller}/get_parameters")
        self._set = node.create_client(SetParameters, f"{self.controller}/set_parameters")
        self._change = node.create_client(ChangeState, f"{self.controller}/change_state")
        self.publisher = node.create_publisher(PressureCommand,
                                               f"{self.controller}/identification_command", 10)
        self.lock = threading.Lock()
        self.messages = []  # (topic, msgtype, receive ns, cdr bytes)
        self.last_reading, self.status = {}, None
        # (when the controller's outputs went out, ROS s; its status message then), each change
        # once: the known-object step tells a clamp the controller interrupted
        self.output_changes = []
        self.recording = False
        self._blind_since = None

    def ready(self) -> bool:
        return all(c.wait_for_service(timeout_sec=self.timeout_s)
                   for c in (self._get, self._set, self._change))

    def _call(self, client, request, what: str):
        future = client.call_async(request)
        deadline = time.monotonic() + self.timeout_s
        while not future.done():
            if time.monotonic() > deadline:
                raise Stopped(f"the pressure controller did not answer {what}")
            time.sleep(0.01)
        return future.result()

    def parameters(self, names: list) -> dict:
        from rcl_interfaces.msg import ParameterType
        from rcl_interfaces.srv import GetParameters
        reply = self._call(self._get, GetParameters.Request(names=names), "get_parameters")
        fields = {ParameterType.PARAMETER_BOOL: "bool_value",
                  ParameterType.PARAMETER_DOUBLE: "double_value",
                  ParameterType.PARAMETER_STRING: "string_value",
                  ParameterType.PARAMETER_STRING_ARRAY: "string_array_value"}
        return {name: getattr(value, fields[value.type]) for name, value in
                zip(names, reply.values) if value.type in fields}

    def set_identification(self, on: bool) -> None:
        """Deactivate (the controller vents), set the mode, activate again."""
        from lifecycle_msgs.msg import Transition
        from lifecycle_msgs.srv import ChangeState
        from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
        from rcl_interfaces.srv import SetParameters
        self._call(self._change, ChangeState.Request(transition=Transition(
            id=Transition.TRANSITION_DEACTIVATE)), "deactivate")
        reply = self._call(self._set, SetParameters.Request(parameters=[Parameter(
            name="identification_mode", value=ParameterValue(
                type=ParameterType.PARAMETER_BOOL, bool_value=on))]), "set_parameters")
        activated = self._call(self._change, ChangeState.Request(transition=Transition(
            id=Transition.TRANSITION_ACTIVATE)), "activate")
        if not reply.results[0].successful:
            raise Stopped(f"identification_mode refused: {reply.results[0].reason}")
        if not activated.success:
            raise Stopped("the pressure controller did not activate again")

    def subscribe(self, sensors: list) -> None:
        """The readings as they come, serialised (parsed only from the log: a reader that keeps
        up with 700 readings a second); controller/status parsed too, to watch it."""
        from rclpy.serialization import deserialize_message
        from sensor_msgs.msg import FluidPressure
        from softgrip_interfaces.msg import ControllerStatus
        from softgrip_ros.nodes.common import stamp_seconds

        def keep(topic, msgtype, data, name=None):
            with self.lock:
                if self.recording:
                    self.messages.append((topic, msgtype, time.time_ns(), bytes(data)))
                if name is not None:
                    self.last_reading[name] = time.monotonic()
            if name is None:
                status = deserialize_message(data, ControllerStatus)
                changed = outputs_changed_at(stamp_seconds(status.header.stamp),
                                             status.output_change_age_s)
                with self.lock:
                    self.status = status
                    if (not self.output_changes or
                            abs(changed - self.output_changes[-1][0]) > CHANGE_RESOLUTION_S):
                        self.output_changes.append((changed, status.message))

        for name in sensors:
            topic = f"{self.prefix}/pressure/sensor/{name}"
            self.node.create_subscription(
                FluidPressure, topic, lambda m, t=topic, n=name: keep(
                    t, "sensor_msgs/msg/FluidPressure", m, n), 1000, raw=True)
        topic = f"{self.prefix}/controller/status"
        self.node.create_subscription(ControllerStatus, topic, lambda m: keep(
            topic, "softgrip_interfaces/msg/ControllerStatus", m), 1000, raw=True)

    def send(self, source: str, target_pa: float) -> None:
        from softgrip_interfaces.msg import PressureCommand
        from softgrip_ros.nodes.common import stamp_msg
        message = PressureCommand(target_gauge_pressure_pa=float(target_pa),
                                  max_rate_pa_per_s=math.nan,
                                  source=getattr(PressureCommand, source))
        message.header.stamp = stamp_msg(self.node.get_clock().now().nanoseconds * 1e-9)
        self.publisher.publish(message)

    def output_changes_between(self, start_s: float, end_s: float) -> list:
        """The controller's output changes from ``start_s`` to ``end_s`` (ROS s), as (when,
        its status message then), in order."""
        with self.lock:
            return [change for change in self.output_changes if start_s <= change[0] <= end_s]

    def measured_gauge_pa(self) -> float:
        """The chamber's pressure (Pa gauge) as the controller last reported it measured; NaN
        before a status or with no valid sensor."""
        with self.lock:
            status = self.status
        return math.nan if status is None else status.measured_gauge_pressure_pa

    def problem(self, sensors: list) -> str:
        """Why the run must stop now ('' when nothing is wrong)."""
        from softgrip_interfaces.msg import ControllerStatus
        now = time.monotonic()
        with self.lock:
            status, last = self.status, dict(self.last_reading)
        for name in sensors:
            if now - last.get(name, -math.inf) > SILENT_S:
                return f"sensor {name} silent for {SILENT_S} s (dropped out, or saturated)"
        if status is None:
            return "no controller/status yet"
        if status.last_sensor_frame_age_s > FRAME_AGE_S:
            return (f"no sensor frame for {status.last_sensor_frame_age_s:.2f} s at the "
                    "controller (dropped out, or saturated)")
        if status.mode == ControllerStatus.MODE_FAULT:
            return f"the pressure controller faulted: {status.message}"
        blind = ControllerStatus.FAULT_SENSOR_TIMEOUT | ControllerStatus.FAULT_BUS_SILENT
        if not status.fault_flags & blind:
            self._blind_since = None
        elif self._blind_since is None:
            self._blind_since = now
        elif now - self._blind_since >= BLIND_GRACE_S:
            return f"the pressure controller cannot see the chamber: {status.message}"
        return ""


def run_live(args, progress) -> tuple[pathlib.Path, dict]:
    """Run the excitation; the log's directory (in a temporary place) and the run's info.
    Raises Stopped (the controller vented and restored) or ConnectionError (no controller)."""
    import rclpy

    from softgrip_ros.nodes.common import spinning
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node(f"softgrip_identify_{int(time.time()) % 100000}", context=context)
    live = Live(node, args.namespace, args.timeout)
    try:
        # one thread: rclpy's multi-threaded executor took so much longer per message that, next
        # to a controller and a device on two cores, 30-80 % of the 700 readings a second were
        # lost (bench_identify's logs); the single-threaded one keeps them all (< 1 % lost)
        with spinning(node, context=context, threads=1):
            if not live.ready():
                raise ConnectionError(f"no pressure controller answered at {live.controller} in "
                                      f"{args.timeout:g} s (is the controller running, in this "
                                      "namespace and ROS_DOMAIN_ID?)")
            values = live.parameters(["plant_file", "sensors.names", "max_gauge_pressure_pa",
                                      "min_gauge_pressure_pa"])
            sensors = list(values["sensors.names"])
            base_path = args.base or values["plant_file"] or _installed_plant()
            base = plant_file.load(base_path)
            high = LIMIT_USE * values["max_gauge_pressure_pa"]
            low = LIMIT_USE * values["min_gauge_pressure_pa"]
            if args.known_object_m is not None:
                from softgrip_ros.estimation.grasp_sensing import contact_model_for
                progress(f"the fingers' model ({args.gripper_model})")
                model = contact_model_for(args.gripper_model, "l0", base.parameters)
                try:
                    contact_plan = identify_contact.plan(model, args.known_object_m, high, low)
                except ValueError as problem:
                    raise Stopped(str(problem)) from None
            else:
                steps, held_out = identification.excitation(high, low, seed=args.seed,
                                                            quick=args.quick)
            live.subscribe(sensors)
            progress(f"controller {live.controller}: identification mode (it vents first)")
            try:
                live.set_identification(True)
                _wait_flowing(live, sensors)
                if args.known_object_m is None:
                    info = _excite(live, steps, held_out, sensors, progress)
                else:
                    closings = identify_contact.run(live, contact_plan, sensors, progress,
                                                    identify_contact.wait_for_enter)
                    info = {"format": LOG_FORMAT, "contact": {
                        "known_object_m": args.known_object_m,
                        "gripper_model": args.gripper_model,
                        "open_pa": contact_plan.open_pa, "clamp_pa": contact_plan.clamp_pa,
                        "closings": [[kind, sent] for kind, sent in closings]}}
            finally:
                live.send("VENT", 0.0)
                progress("restoring the controller: identification mode off")
                live.set_identification(False)
        info.update(base_plant_file=str(base_path), base_plant=plant_file.document(base),
                    sensors=sensors, namespace=args.namespace)
        return _write_log(live, info), info
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def hold_for(live: Live, sensors: list, source: str, target_pa: float, duration_s: float) -> None:
    """Keep ``source`` at ``target_pa`` for ``duration_s``, sending it again every REFRESH_S
    (a VACUUM once there stays closed); Stopped when :meth:`Live.problem` says so."""
    end, refreshed = time.monotonic() + duration_s, time.monotonic()
    while time.monotonic() < end:
        reason = live.problem(sensors)
        if reason:
            raise Stopped(reason)
        if time.monotonic() - refreshed >= REFRESH_S and source != "VACUUM":
            live.send(source, target_pa)
            refreshed = time.monotonic()
        time.sleep(0.005)


def _wait_flowing(live: Live, sensors: list) -> None:
    """Until the readings flow and a status has been seen; Stopped after 5 s."""
    deadline = time.monotonic() + 5.0
    while live.problem(sensors):
        if time.monotonic() > deadline:
            raise Stopped(f"before the excitation: {live.problem(sensors)}")
        time.sleep(0.02)


def _excite(live: Live, steps: list, held_out: float, sensors: list, progress) -> dict:
    with live.lock:
        live.recording = True
    started = live.node.get_clock().now().nanoseconds * 1e-9
    elapsed, total = 0.0, sum(step.duration_s for step in steps)
    held_out_at = math.inf
    for index, step in enumerate(steps):
        if elapsed >= held_out and not math.isfinite(held_out_at):
            held_out_at = live.node.get_clock().now().nanoseconds * 1e-9
        progress(f"[{index + 1}/{len(steps)}] {elapsed:5.1f}/{total:.0f} s  {step.source:6s} "
                 f"{step.target_pa / 1e3:+6.1f} kPa for {step.duration_s:.2f} s")
        live.send(step.source, step.target_pa)
        hold_for(live, sensors, step.source, step.target_pa, step.duration_s)
        elapsed += step.duration_s
    with live.lock:
        live.recording = False
    return {"format": LOG_FORMAT, "started_s": started, "held_out_from_s": held_out_at,
            "steps": [[s.source, s.target_pa, s.duration_s] for s in steps]}


def _installed_plant() -> pathlib.Path:
    from softgrip_ros.config_paths import config_file
    return config_file("plant.yaml")


def _write_log(live: Live, info: dict) -> pathlib.Path:
    from rclpy.serialization import serialize_message
    from std_msgs.msg import String
    folder = pathlib.Path(tempfile.mkdtemp(prefix="softgrip_identify_")) / "recording"
    with bag.BagWriter(folder) as log:
        first = min(stamp for _, _, stamp, _ in live.messages)
        log.write(INFO_TOPIC, "std_msgs/msg/String", first,
                  serialize_message(String(data=yaml.safe_dump(info))))
        for topic, msgtype, stamp, data in live.messages:
            log.write(topic, msgtype, stamp, data)
    return folder


def _keep_log(log: pathlib.Path, output: pathlib.Path) -> pathlib.Path:
    """Move a live run's log (``_write_log``'s folder) to ``output``/recording; that path."""
    kept = output / "recording"
    try:
        output.mkdir(parents=True, exist_ok=True)
        shutil.move(str(log), str(kept))
    except OSError as error:
        from softgrip_ros.fileio import OutputError
        raise OutputError(f"cannot keep the log in {kept}: {error.strerror or error}; it is "
                          f"still in {log}") from None
    shutil.rmtree(log.parent, ignore_errors=True)
    return kept


# ---- from a log ---------------------------------------------------------------------------------
def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def log_info(text: str, path) -> dict:
    """The info a softgrip_identify log carries on INFO_TOPIC (YAML), checked so that every
    later use of it holds: ValueError, in one line, naming what is wrong."""
    where = f"{path}: the log's {INFO_TOPIC}"
    try:
        info = yaml.safe_load(text)
    except yaml.YAMLError as error:
        raise ValueError(f"{where} is not YAML ({' '.join(str(error).split())})") from None
    if not isinstance(info, dict) or info.get("format") != LOG_FORMAT:
        raise ValueError(f"{where} is not a {LOG_FORMAT} mapping")
    if not isinstance(info.get("base_plant"), dict):
        raise ValueError(f"{where} holds no base_plant mapping")
    held_out = info.get("held_out_from_s", math.inf)
    if not _number(held_out) or math.isnan(held_out):
        raise ValueError(f"{where}: held_out_from_s {held_out!r} is not a time in s")
    if "contact" not in info:
        return info
    contact = info["contact"]
    low, high = KNOWN_OBJECT_RANGE_M
    if not isinstance(contact, dict):
        raise ValueError(f"{where}: contact is not a mapping")
    if not (_number(contact.get("known_object_m")) and low <= contact["known_object_m"] <= high):
        raise ValueError(f"{where}: contact.known_object_m {contact.get('known_object_m')!r} "
                         f"is not a size in [{low:g}, {high:g}] m")
    if not isinstance(contact.get("gripper_model"), str):
        raise ValueError(f"{where}: contact.gripper_model is not a model's name")
    if not (_number(contact.get("clamp_pa")) and math.isfinite(contact["clamp_pa"])):
        raise ValueError(f"{where}: contact.clamp_pa {contact.get('clamp_pa')!r} is not a "
                         "pressure in Pa")
    closings = contact.get("closings")
    if not isinstance(closings, list) or not all(
            isinstance(c, list) and len(c) == 2 and c[0] in CLOSING_KINDS and _number(c[1])
            and math.isfinite(c[1]) for c in closings):
        raise ValueError(f"{where}: contact.closings is not a list of [kind, time s] with kind "
                         f"one of {', '.join(CLOSING_KINDS)}")
    return info


def recording_from_log(path: pathlib.Path) -> tuple[identification.Recording, dict]:
    """The Recording in a log softgrip_identify wrote, and its info (:func:`log_info`). The
    readings there have the base file's biases taken off (the controller did); they are put
    back, so that the biases found are the sensors' own. ValueError, in one line, for a log that
    cannot be read, an info that does not hold, or a reading or status that is not finite."""
    info, sensors, regulator, inputs, last = None, {}, {}, [], None
    for topic, msgtype, _, msg in bag.read(path, bag.note_unknown):
        if topic == INFO_TOPIC:
            info = log_info(msg.data, path)
        elif msgtype == "sensor_msgs/msg/FluidPressure":
            name = topic.rsplit("/", 1)[1]
            stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
            if not math.isfinite(msg.fluid_pressure):
                raise ValueError(f"{path}: a reading on {topic} at {stamp:.3f} s is not finite")
            sensors.setdefault(name, ([], []))
            sensors[name][0].append(stamp)
            sensors[name][1].append(msg.fluid_pressure - P_ATM_PA)
        elif msgtype == "softgrip_interfaces/msg/ControllerStatus":
            stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
            command_pa, change_age_s = (msg.regulator_command_gauge_pressure_pa,
                                        msg.output_change_age_s)
            if not (math.isfinite(command_pa) and math.isfinite(change_age_s)):
                raise ValueError(f"{path}: the controller's status at {stamp:.3f} s holds a "
                                 "command or an output age that is not finite")
            if math.isfinite(msg.regulator_report_age_s) and math.isfinite(
                    msg.regulator_actual_gauge_pressure_pa):
                regulator[round(stamp - msg.regulator_report_age_s, 4)] = \
                    msg.regulator_actual_gauge_pressure_pa
            valve = int(msg.valve_states[0]) if len(msg.valve_states) else int(Valve.CLOSED)
            if valve not in VALVE_STATES:
                raise ValueError(f"{path}: the controller's status at {stamp:.3f} s holds the "
                                 f"unknown valve state {valve}")
            key = (valve, command_pa, bool(msg.regulator_enabled))
            if key != last:
                # when its frames went out, not when the status that says so was published
                changed = outputs_changed_at(stamp, change_age_s)
                inputs.append(identification.InputChange(changed, *key))
                last = key
    if info is None:
        raise ValueError(f"{path} holds no {INFO_TOPIC}: it was not written by softgrip_identify")
    base = plant_file.parse(info["base_plant"], "the log's base plant")
    for name, (times, values) in sensors.items():
        bias = base.sensors[name].bias_pa if name in base.sensors else 0.0
        sensors[name] = (times, [v + bias for v in values])
    report_times = sorted(regulator)
    return identification.Recording(
        sensors, (report_times, [regulator[t] for t in report_times]), inputs,
        held_out_from_s=float(info.get("held_out_from_s", math.inf))), info


def fit_log(log: pathlib.Path, args, output: pathlib.Path, progress, command: str) -> dict:
    recording, info = recording_from_log(log)
    base = plant_file.load(args.base) if args.base else plant_file.parse(
        info["base_plant"], "the log's base plant")
    if "contact" in info:
        return _fit_contact(recording, info, base, output, progress, command)
    progress(f"fitting {sum(len(t) for t, _ in recording.sensors.values())} readings")
    result = identification.fit(recording, base.parameters, args.volume_m3, progress,
                                vacuum_source_pa=args.vacuum_source_pa,
                                budget_s=args.fit_budget_s)
    volume = (f"measured, {args.volume_m3:g} m^3 (--volume-m3)" if args.volume_m3 is not None
              else f"inherited, {base.parameters.chamber_volume_m3:g} m^3 from the base file")
    provenance = {"source": "identified", "date": datetime.date.today().isoformat(),
                  "tool": "softgrip_identify", "recording": str(output / "recording"),
                  "base": str(args.base or info.get("base_plant_file", "")), "volume": volume}
    if args.vacuum_source_pa is not None:
        provenance["vacuum_source"] = (f"measured, {args.vacuum_source_pa:g} Pa gauge "
                                       "(--vacuum-source-pa)")
    written = write(result, base, provenance, output, command)
    for flag in result.flags:
        print(f"softgrip_identify: flagged: {flag}", file=sys.stderr)
    return {**written, "result": result}


def _fit_contact(recording, info: dict, base, output: pathlib.Path, progress,
                 command: str) -> dict:
    from softgrip_ros.estimation.contact_identification import fit_bending_share
    from softgrip_ros.estimation.grasp_sensing import contact_model_for
    contact = info["contact"]
    model = contact_model_for(contact["gripper_model"], "l0", base.parameters)
    object_jobs, empty_jobs = identify_contact.jobs_from_log(recording, info, base)
    fit = fit_bending_share(object_jobs, empty_jobs, model, float(contact["known_object_m"]),
                            progress=progress)
    written = identify_contact.write(fit, base, model.bending_volume_share, output, command)
    return {**written, "contact": fit}


def main(argv=None) -> int:
    from softgrip_ros.fileio import OutputError
    args = parser().parse_args(argv)
    _check(args, parser().error)
    output = args.output or pathlib.Path(
        f"identification-{datetime.datetime.now().strftime('%Y%m%d-%H%M%S')}")
    command = "softgrip_identify " + " ".join(sys.argv[1:] if argv is None else argv)

    def progress(text: str) -> None:
        print(text, flush=True)

    log = args.from_log
    try:
        if log is None:
            log, _ = run_live(args, progress)
        written = fit_log(log, args, output, progress, command)
        if args.from_log is None:
            _keep_log(log, output)
    except ConnectionError as error:
        print(f"softgrip_identify: {error}", file=sys.stderr)
        return 3
    except Stopped as stop:
        print(f"softgrip_identify: stopped: {stop}; vented, nothing written", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("softgrip_identify: stopped by Ctrl-C; vented, nothing written", file=sys.stderr)
        return 1
    except OutputError as error:
        print(f"softgrip_identify: {error}; nothing more written", file=sys.stderr)
        return 1
    except ValueError as error:
        if log is None or args.from_log is not None:
            print(f"softgrip_identify: cannot fit: {error}; nothing written", file=sys.stderr)
        else:  # the run's readings are worth keeping: a fix may let them be fitted again
            try:
                kept = f"the log kept in {_keep_log(log, output)}"
            except OutputError as problem:
                kept = str(problem)
            print(f"softgrip_identify: cannot fit: {error}; no plant file written, {kept} "
                  "(fit it again with --from-log)", file=sys.stderr)
        return 1
    if "contact" in written:
        fit = written["contact"]
        print(f"wrote {written['plant']} (bending_volume_share {fit.bending_volume_share:.3f}, "
              f"95 % {fit.ci95[0]:.3f} to {fit.ci95[1]:.3f}), {written['report']}, "
              f"{written['figure']}")
        return 0
    result = written["result"]
    print(f"wrote {written['plant']} ({len(result.flags)} flagged), {written['report']}, "
          f"{written['figure']}; fit {result.fit_s:.1f} s, validation "
          f"{result.validation_rmse_over_noise:.2f}x the noise")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
