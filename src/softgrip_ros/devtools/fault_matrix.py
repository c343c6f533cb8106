"""The single-fault matrix: every simulated fault, injected in every grasp phase, on the composed
suite (the ``controller`` executable's nodes) over DDS, judged on the simulated device's true
chamber pressure. The device runs in a process of its own, as a real one has its own processor.

For each (fault, phase) :func:`run_case`:

1. drives an ENVELOP_CLAMP 40 mm, 0.02 kg grasp to the phase and injects the fault there (IDLE:
   before the grasp starts; OPENING, CLAMPING and RELEASING: as the phase begins);
2. goes on with the grasp as an arm would (CLAMP once ENVELOPED, RELEASE after 0.5 s of
   HOLDING), so that a fault that only shows once the pressure moves is exercised, and watches
   ``controller/status``, ``grasp_state`` and ``/diagnostics``;
3. checks that the true pressure stayed within [min - margin, max + margin], that the fault's
   named evidence appeared (and how long after the injection), and that the gripper ended in
   the fault's documented state;
4. clears the fault, sends STOP, and runs a new grasp to HOLDING and back to IDLE.

Each fault's evidence (status flags or diagnostic text) and documented end state are in
:data:`FAULTS`. ``scripts/bench_faults.py`` runs the whole matrix; the tests run a subset.
"""
from __future__ import annotations

import dataclasses
import gc
import math
import os
import statistics
import threading
import time
import uuid

from softgrip_ros.realtime import freeze_start_up_heap

NAN = math.nan
PHASES = ("IDLE", "OPENING", "ENVELOPED", "CLAMPING", "HOLDING", "RELEASING")
HOLD_S = 0.5  # how long the scripted grasp holds before its RELEASE
OBSERVE_S = 4.0  # the longest a case watches after the injection
PHASE_TIMEOUT_S = 5.0
# before fault-free grasps: longer than any report of an earlier fault lasts
REPORTS_EXPIRE_S = 6.0


@dataclasses.dataclass(frozen=True)
class FaultCase:
    """One simulated fault.

    inject / clear: {device fault: value} (``future_command``: none, see :func:`run_case`);
    flags: ControllerStatus fault bits, any of which names the fault;
    text: diagnostic or status text that names it (any of, case-insensitive);
    end: the documented end state: ``safe`` (the controller's safe state: valves VENT, regulator
    disabled), ``hold`` (valves held closed, the grasp in FAULT), ``continues`` (the grasp goes on
    to IDLE; a diagnostic names the fault) or ``continues_or_safe`` (either of the two)."""

    name: str
    inject: dict
    clear: dict
    flags: tuple = ()
    text: tuple = ()
    end: str = "safe"
    what: str = ""


def _stuck(sensor: str, at: str) -> FaultCase:
    return FaultCase(
        f"{sensor}_stuck_{at}", {"sensor_stuck_at": at, "sensor_stuck": sensor},
        {"sensor_stuck": "", "sensor_stuck_at": "present"},
        ("SENSOR_STUCK", "SENSOR_DISAGREE", "SENSOR_IMPLAUSIBLE", "SENSOR_INCONSISTENT"), (),
        "safe", f"{sensor} stuck {'at its reading' if at == 'present' else at}")


FAULTS = (
    *(_stuck(sensor, at) for sensor in ("chamber_a", "chamber_b")
      for at in ("low", "high", "present")),
    FaultCase("bias_plus_20kPa", {"sensor_bias_pa": 20e3}, {"sensor_bias_pa": 0.0},
              ("SENSOR_IMPLAUSIBLE", "RESPONSE", "SENSOR_DISAGREE", "SENSOR_INCONSISTENT",
               "OVERPRESSURE"), what="+20 kPa bias on both sensors"),
    FaultCase("bias_minus_20kPa", {"sensor_bias_pa": -20e3}, {"sensor_bias_pa": 0.0},
              ("SENSOR_IMPLAUSIBLE", "RESPONSE", "SENSOR_DISAGREE", "SENSOR_INCONSISTENT",
               "OVERPRESSURE"), what="-20 kPa bias on both sensors"),
    FaultCase("dropout_chamber_a", {"sensor_dropout": "chamber_a"}, {"sensor_dropout": ""}, (),
              ("sensors silent: chamber_a",), "continues",
              "chamber_a silent (chamber_b carries on)"),
    FaultCase("noise_x10", {"sensor_noise_scale": 10.0}, {"sensor_noise_scale": 1.0},
              ("SENSOR_NOISE", "SENSOR_INCONSISTENT", "SENSOR_DISAGREE", "SENSOR_IMPLAUSIBLE",
               "OVERPRESSURE"), what="sensor noise x10"),
    FaultCase("valve_stuck", {"valve_stuck": True}, {"valve_stuck": False},
              ("RESPONSE", "OVERPRESSURE"), what="valves keep their state"),
    FaultCase("valve_stuck_open", {"valve_stuck_open": True}, {"valve_stuck_open": False},
              ("RESPONSE", "OVERPRESSURE", "REGULATOR"), what="valves stuck open to SUPPLY"),
    FaultCase("regulator_overshoot", {"regulator_overshoot_pa": 100e3},
              {"regulator_overshoot_pa": 0.0}, ("REGULATOR", "OVERPRESSURE", "RESPONSE"),
              what="regulator settles 100 kPa above its setpoint"),
    FaultCase("bus_silent", {"bus_silent": True}, {"bus_silent": False},
              ("BUS_SILENT", "SENSOR_TIMEOUT"), ("holds the valves closed",), "hold",
              "the device sends nothing"),
    FaultCase("corrupt_frames", {"corrupt_rate": 0.3}, {"corrupt_rate": 0.0}, ("FRAMES_REJECTED",),
              (), "continues", "30 % of frames with a bad CRC or a repeated counter"),
    # a replayed ValveCommand makes the device distrust the controller's frames until 4 arrive in
    # sequence; its valves may close (OpenLifetime) meanwhile, which the controller's response
    # check may then find: going on and the safe state are both right
    FaultCase("replayed_frames", {"replay_rate_hz": 5.0}, {"replay_rate_hz": 0.0},
              ("FRAMES_REJECTED",), (), "continues_or_safe",
              "5 bursts/s of old sensor frames, an old ValveCommand into the device"),
    FaultCase("future_command", {}, {}, ("COMMAND_REJECTED",), ("in the future",), "continues",
              "a PressureCommand VENT stamped 30 s ahead"),
)
FAULTS_BY_NAME = {case.name: case for case in FAULTS}
SAFETY_FLAGS = ("OVERPRESSURE", "REGULATOR", "SENSOR_DISAGREE", "SENSOR_STUCK",
                "SENSOR_IMPLAUSIBLE", "SENSOR_NOISE", "RESPONSE", "SENSOR_INCONSISTENT")


@dataclasses.dataclass
class CaseResult:
    fault: str
    phase: str
    true_low_pa: float = NAN
    true_high_pa: float = NAN
    within_limits: bool = False
    detected: bool = False
    detection_s: float = NAN
    evidence: str = ""
    end_state_ok: bool = False
    end_state: str = ""
    recovered: bool = False
    problem: str = ""
    injected: bool = False  # the grasp reached its phase and the fault went in

    @property
    def passed(self) -> bool:
        return self.within_limits and self.detected and self.end_state_ok and self.recovered


# the longest a call into the device's process may take (its start: the imports, on a busy host)
DEVICE_START_TIMEOUT_S = 120.0
DEVICE_CALL_TIMEOUT_S = 10.0


def _start_device(channel: str):
    """In the device's process: the simulated device with every parameter at its default, as
    ``sim_device`` has it, sending on the softgrip_ipc bus ``channel``."""
    from softgrip_ros.canbus import open_bus
    from softgrip_ros.canbus.sim_device import SimulatedDevice
    from softgrip_ros.nodes.sim_device import default_values, device_setup
    values = default_values()
    _, config, world = device_setup(values)
    bus = open_bus("softgrip_ipc", channel, values["can.bitrate"], preserve_timestamps=True)
    device = SimulatedDevice(bus, config, world=world)
    freeze_start_up_heap()  # as sim_device's own process has it (run_node)
    device.start()
    return device, bus


def _call_device(method: str, *args):
    from softgrip_ros.runtime.worker_process import worker_state
    device, bus = worker_state()
    if method == "close":
        device.stop()
        bus.shutdown()
        return None
    return getattr(device, method)(*args)


class DeviceApart:
    """The simulated device in a process of its own on a softgrip_ipc bus, as a real device has
    its own processor: the suite's process then does only the suite's work (in it, the device's
    plant thread took the GIL from the control loop). Offers the device's methods the matrix uses;
    each call waits for the device's answer. :meth:`close` it."""

    def __init__(self, channel: str):
        from softgrip_ros.runtime.worker_process import WorkerProcess
        # nice 0: the device is the world, not background work
        self._worker = WorkerProcess(_start_device, (channel,), nice_increment=0,
                                     name="softgrip-device")
        try:
            self._worker.submit(os.getpid).result(timeout=DEVICE_START_TIMEOUT_S)
        except BaseException:
            self._worker.close()
            raise

    def _call(self, method: str, *args):
        return self._worker.submit(_call_device, method, *args).result(
            timeout=DEVICE_CALL_TIMEOUT_S)

    def set_fault(self, name: str, value) -> None:
        self._call("set_fault", name, value)

    def valves(self) -> tuple:
        return self._call("valves")

    def regulator_enabled(self) -> bool:
        return self._call("regulator_enabled")

    def true_extremes(self) -> tuple:
        return self._call("true_extremes")

    def reset_true_extremes(self) -> None:
        self._call("reset_true_extremes")

    def close(self) -> None:
        try:
            self._call("close")
        except Exception:  # a child already gone: closing the worker is all there is to do
            pass
        self._worker.close()


def _command(mode, command_id="", **fields):
    from softgrip_interfaces.msg import GraspCommand
    values = dict(object_diameter_m=NAN, object_mass_kg=NAN, target_tip_spacing_m=NAN,
                  friction_coefficient=NAN, open_pressure_pa=NAN, clamp_pressure_pa=NAN)
    values.update(fields)
    return GraspCommand(mode=mode, command_id=command_id, **values)


class Rig:
    """The composed suite, with a user node that watches and commands, and the simulated device in
    a process of its own (:class:`DeviceApart`) on a private softgrip_ipc bus. Use as a context
    manager; ``rclpy`` must be initialised for ``context`` (None: the default)."""

    def __init__(self, context=None):
        self.context = context
        self.lock = threading.Lock()
        self.states, self.statuses, self.diagnostics = [], [], []

    def __enter__(self):
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.node import Node
        from rclpy.parameter import Parameter
        from softgrip_interfaces.msg import ControllerStatus, GraspCommand, GripperState
        from softgrip_ros.nodes.common import spinning
        from softgrip_ros.nodes.controller import make_nodes

        channel = f"faults-{uuid.uuid4().hex[:8]}"
        self.device = DeviceApart(channel)
        try:
            self.nodes = {
                n.get_name(): n
                for n in make_nodes(self.context, {"pressure_controller": [
                    Parameter("can.interface", value="softgrip_ipc"),
                    Parameter("can.channel", value=channel)
                ]})
            }
        except BaseException:
            self.device.close()
            raise
        self.user = Node(f"fault_matrix_{uuid.uuid4().hex[:6]}", context=self.context)
        now = time.monotonic
        self.user.create_subscription(GripperState, "grasp_state",
                                      lambda m: self._keep(self.states, m, now()), 200)
        self.user.create_subscription(ControllerStatus, "controller/status",
                                      lambda m: self._keep(self.statuses, m, now()), 200)
        self.user.create_subscription(
            DiagnosticArray, "/diagnostics",
            lambda m: [self._keep(self.diagnostics, s, now()) for s in m.status], 200)
        self.grasp = self.user.create_publisher(GraspCommand, "grasp_command", 10)
        self._spin = spinning(*self.nodes.values(), self.user, context=self.context, threads=2)
        self._spin.__enter__()
        deadline = now() + 30.0
        while not (self.states and self.statuses and
                   self.grasp.get_subscription_count()) and now() < deadline:
            time.sleep(0.05)
        if not self.states:
            self.__exit__(None, None, None)
            raise RuntimeError("the composed suite did not come up")
        # as the controller executable's own process has it (run_node)
        freeze_start_up_heap()
        return self

    def __exit__(self, *exc):
        from softgrip_ros.nodes.common import close_all
        self._spin.__exit__(None, None, None)
        close_all(list(self.nodes.values()))
        self.user.destroy_node()
        self.device.close()
        gc.unfreeze()

    def _keep(self, history, message, when):
        with self.lock:
            history.append((when, message))
            if len(history) > 20000:
                del history[:10000]

    # ---- what is seen ---------------------------------------------------------------------------
    def phase(self) -> str:
        from softgrip_interfaces.msg import GripperState
        names = {getattr(GripperState, p): p for p in (*PHASES, "FAULT")}
        with self.lock:
            return names[self.states[-1][1].phase] if self.states else ""

    def wait_phase(self, phase: str, timeout_s: float = PHASE_TIMEOUT_S,
                   stop_on_fault: bool = True) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            current = self.phase()
            if current == phase:
                return True
            if stop_on_fault and current == "FAULT" and phase != "FAULT":
                return False
            time.sleep(0.002)
        return False

    def send(self, mode_name: str, **fields) -> None:
        from softgrip_interfaces.msg import GraspCommand
        self.grasp.publish(
            _command(getattr(GraspCommand, mode_name), f"matrix-{mode_name.lower()}", **fields))

    def evidence_since(self, since: float, case: FaultCase):
        """(time, text) of the first evidence naming ``case`` since ``since``, or None."""
        from softgrip_interfaces.msg import ControllerStatus
        bits = [getattr(ControllerStatus, f"FAULT_{flag}") for flag in case.flags]
        with self.lock:
            statuses, diagnostics = list(self.statuses), list(self.diagnostics)
            states = list(self.states)
        found = []
        for when, status in statuses:
            if when >= since and any(status.fault_flags & bit for bit in bits):
                found.append((when, f"controller/status: {status.message}"))
                break
        texts = [t.lower() for t in case.text]
        for when, status in diagnostics:
            if when >= since and texts and any(t in status.message.lower() for t in texts):
                found.append((when, f"{status.name}: {status.message}"))
                break
        for when, state in states:
            if when >= since and texts and any(t in state.message.lower() for t in texts):
                found.append((when, f"grasp_state: {state.message}"))
                break
        return min(found) if found else None

    def warnings_since(self, since: float) -> list:
        """Diagnostics at WARN or above, and statuses with a safety flag, since ``since``."""
        from softgrip_interfaces.msg import ControllerStatus
        safety = sum(getattr(ControllerStatus, f"FAULT_{flag}") for flag in SAFETY_FLAGS)
        with self.lock:
            diagnostics, statuses = list(self.diagnostics), list(self.statuses)
        found = [
            f"{s.name}: {s.message}" for when, s in diagnostics
            if when >= since and s.name.startswith("softgrip") and _level(s) >= 1
        ]
        found += [
            f"controller/status: {s.message}" for when, s in statuses
            if when >= since and s.fault_flags & safety
        ]
        return found

    def reset(self) -> bool:
        """Every fault cleared, the grasp stopped and vented, the controller out of its safe
        state."""
        from softgrip_ros.canbus.sim_device import FAULTS as DEVICE_FAULTS
        for name, value in DEVICE_FAULTS.items():  # each at its default: no fault
            self.device.set_fault(name, value)
        controller = self.nodes["pressure_controller"].controller
        for _ in range(3):
            # the evidence must be gone for this long
            time.sleep(controller.config.safety.clear_time_s + 0.1)
            self.send("STOP")
            if (self.wait_phase("IDLE", 3.0, stop_on_fault=False) and
                    controller.last_output is not None and
                    controller.last_output.mode.name != "FAULT"):
                return True
        return False

    def grasp_cycle(self, timeout_s: float = PHASE_TIMEOUT_S) -> str:
        """A full grasp, ENVELOP_CLAMP 40 mm to HOLDING to IDLE; '' or where it failed."""
        self.send("ENVELOP_CLAMP", object_diameter_m=0.04, object_mass_kg=0.02)
        if not self.wait_phase("ENVELOPED", timeout_s):
            return f"ENVELOPED not reached ({self.last_message()})"
        time.sleep(0.2)
        self.send("CLAMP")
        if not self.wait_phase("HOLDING", timeout_s):
            return f"HOLDING not reached ({self.last_message()})"
        time.sleep(HOLD_S)
        self.send("RELEASE")
        if not self.wait_phase("IDLE", timeout_s):
            return f"IDLE not reached after RELEASE ({self.last_message()})"
        return ""

    def last_message(self) -> str:
        with self.lock:
            return self.states[-1][1].message if self.states else ""


def _level(status) -> int:
    level = status.level
    return level[0] if isinstance(level, (bytes, bytearray)) else int(level)


def _inject(rig: Rig, case: FaultCase) -> None:
    if case.name == "future_command":
        from softgrip_interfaces.msg import PressureCommand
        from softgrip_ros.nodes.common import stamp_msg
        message = PressureCommand(target_gauge_pressure_pa=0.0, max_rate_pa_per_s=NAN,
                                  source=PressureCommand.VENT)
        message.header.stamp = stamp_msg(rig.user.get_clock().now().nanoseconds * 1e-9 + 30.0)
        # at the controller's command input: composed, it takes no pressure/command from DDS
        rig.nodes["pressure_controller"].on_command(message)
        return
    for name, value in case.inject.items():
        rig.device.set_fault(name, value)


def _script_until(rig: Rig, phase: str) -> bool:
    """Drive the grasp to ``phase`` (as it begins); False when it could not get there."""
    if phase == "IDLE":
        return rig.phase() == "IDLE"
    rig.send("ENVELOP_CLAMP", object_diameter_m=0.04, object_mass_kg=0.02)
    if phase == "OPENING":
        return rig.wait_phase("OPENING")
    if not rig.wait_phase("ENVELOPED"):
        return False
    if phase == "ENVELOPED":
        return True
    rig.send("CLAMP")
    if phase == "CLAMPING":
        return rig.wait_phase("CLAMPING")
    if not rig.wait_phase("HOLDING"):
        return False
    if phase == "HOLDING":
        return True
    rig.send("RELEASE")
    return rig.wait_phase("RELEASING")


def _script_on(rig: Rig, phase: str, deadline: float) -> None:
    """Go on with the grasp from ``phase`` as an arm would, until IDLE, FAULT or the deadline."""
    steps = {
        "IDLE": ["start", "clamp",
                 "release"], "OPENING": ["clamp", "release"], "ENVELOPED": ["clamp", "release"],
        "CLAMPING": ["release"], "HOLDING": ["release"], "RELEASING": []
    }[phase]
    for step in steps:
        if time.monotonic() >= deadline or rig.phase() == "FAULT":
            return
        if step == "start":
            rig.send("ENVELOP_CLAMP", object_diameter_m=0.04, object_mass_kg=0.02)
        elif step == "clamp":
            if not rig.wait_phase("ENVELOPED", deadline - time.monotonic()):
                return
            time.sleep(0.2)
            rig.send("CLAMP")
        elif step == "release":
            if not rig.wait_phase("HOLDING", deadline - time.monotonic()):
                return
            time.sleep(HOLD_S)
            rig.send("RELEASE")
    rig.wait_phase("IDLE", max(deadline - time.monotonic(), 0.0))


def _end_state(rig: Rig, case: FaultCase) -> tuple[bool, str]:
    controller = rig.nodes["pressure_controller"].controller.last_output
    valves = rig.device.valves()
    phase = rig.phase()
    described = (f"controller {controller.mode.name if controller else '?'}, device valves "
                 f"{'/'.join(v.name for v in valves)}, regulator "
                 f"{'on' if rig.device.regulator_enabled() else 'off'}, "
                 f"grasp {phase}" + (f" ({controller.message[:120]})"
                                     if controller and controller.mode.name == "FAULT" else ""))
    if case.end == "safe":
        ok = (controller is not None and controller.mode.name == "FAULT" and
              not rig.device.regulator_enabled() and phase == "FAULT")
        # the device obeys VENT unless its valves are stuck; then the sources are cut instead
        ok = ok and (all(v.name == "VENT" for v in valves) or case.name.startswith("valve_stuck"))
    elif case.end == "hold":
        ok = phase == "FAULT" and all(v.name == "CLOSED" for v in valves)
    else:
        ok = phase in ("IDLE", "HOLDING", "ENVELOPED", "OPENING", "CLAMPING", "RELEASING")
        if case.end == "continues_or_safe" and not ok:
            ok = (controller is not None and controller.mode.name == "FAULT" and
                  not rig.device.regulator_enabled())
    return ok, described


def run_case(rig: Rig, case: FaultCase, phase: str) -> CaseResult:
    result = CaseResult(case.name, phase)
    config = rig.nodes["pressure_controller"].controller.config
    low_limit = config.min_gauge_pa - config.overpressure_margin_pa
    high_limit = config.max_gauge_pa + config.overpressure_margin_pa
    if not rig.reset():
        result.problem = "could not reset the suite before the case"
        return result
    if not _script_until(rig, phase):
        result.problem = f"could not reach {phase} before the injection ({rig.last_message()})"
        return result
    rig.device.reset_true_extremes()
    injected = time.monotonic()
    _inject(rig, case)
    result.injected = True
    deadline = injected + OBSERVE_S
    _script_on(rig, phase, deadline)
    while time.monotonic() < deadline and rig.evidence_since(injected, case) is None:
        time.sleep(0.01)
    time.sleep(0.3)  # the end state settles
    evidence = rig.evidence_since(injected, case)
    if evidence is not None:
        result.detected, result.detection_s, result.evidence = True, evidence[
            0] - injected, evidence[1][:220]
    result.end_state_ok, result.end_state = _end_state(rig, case)
    result.true_low_pa, result.true_high_pa = rig.device.true_extremes()
    result.within_limits = low_limit <= result.true_low_pa and result.true_high_pa <= high_limit
    # recovery: the fault cleared, a new grasp works
    if rig.reset():
        problem = rig.grasp_cycle()
        result.recovered = not problem
        result.problem = problem
    else:
        result.problem = "the suite did not come out of the fault after it was cleared"
    return result


@dataclasses.dataclass(frozen=True)
class FaultFreeRound:
    """What :func:`false_alarms` found. ``warnings``: WARN-or-worse diagnostics, safety flags and
    failed grasps; ``texts``: the evidence of what the host did meanwhile, then each of those;
    ``valve_lapses``: how often the controller's own count found its loop held up past the
    valves' lifetime during the grasps (the device closed the valves meanwhile)."""

    warnings: int
    texts: list
    valve_lapses: int

    @property
    def host_stalled(self) -> bool:
        """Warned in grasps during which the control loop itself was held up: on a shared host
        (other processes or the hypervisor taking the CPUs) the warning is the suite reporting
        the stall, as it must, not a false alarm of its own."""
        return self.warnings > 0 and self.valve_lapses > 0


def _cpu_stolen_jiffies() -> float:
    """The host's CPU time taken by the hypervisor so far (Linux /proc/stat; NaN elsewhere)."""
    try:
        with open("/proc/stat", encoding="ascii") as stat:
            return float(stat.readline().split()[8])
    except (OSError, IndexError, ValueError):
        return NAN


def false_alarms(rig: Rig, grasps: int) -> FaultFreeRound:
    """Fault-free grasps, counted for warnings. When anything warned, the texts begin with the
    evidence of what the host did meanwhile: the values of the estimator's first warning (its
    rewinds, late inputs, rejections), the lapses of the valves' lifetime during the grasps (the
    control loop held up) and the CPU time the hypervisor took."""
    if not rig.reset():
        raise RuntimeError("could not reset the suite")
    # the reports of earlier faults (a refusal is reported for 5 s) run out
    time.sleep(REPORTS_EXPIRE_S)
    link = rig.nodes["pressure_controller"].link
    since, lapses_before, stolen_before = time.monotonic(), link.lapses, _cpu_stolen_jiffies()
    problems = []
    for _ in range(grasps):
        problem = rig.grasp_cycle()
        if problem:
            problems.append(f"grasp failed: {problem}")
        time.sleep(0.3)
    # the 1 Hz diagnostics of the last grasp
    time.sleep(1.2)
    lapses = link.lapses - lapses_before
    stolen_share = ((_cpu_stolen_jiffies() - stolen_before) / os.sysconf("SC_CLK_TCK") /
                    (time.monotonic() - since) / (os.cpu_count() or 1))
    warnings = rig.warnings_since(since)
    if not warnings + problems:
        return FaultFreeRound(0, [], lapses)
    with rig.lock:
        diagnostics = list(rig.diagnostics)
    estimator = [s for when, s in diagnostics
                 if when >= since and s.name.endswith(": estimator") and _level(s) >= 1]
    evidence = [
        "estimator values at its first warning: " +
        ", ".join(f"{kv.key}={kv.value}" for kv in estimator[0].values)
    ] if estimator else []
    evidence.append(f"valve lifetime lapses during the grasps: {lapses}")
    if math.isfinite(stolen_share):
        evidence.append(f"CPU time taken by the hypervisor meanwhile: {100 * stolen_share:.1f} %")
    return FaultFreeRound(len(warnings) + len(problems), evidence + warnings + problems, lapses)


def fault_free_grasps(rig: Rig, grasps: int, retries: int, on_retry=None,
                      run=false_alarms) -> tuple[FaultFreeRound, list]:
    """``run(rig, grasps)``, and again up to ``retries`` times while it warned in grasps that held
    the control loop up (:attr:`FaultFreeRound.host_stalled`); a warning with the loop on time
    is never run again. (the last round, [what ran once more, and why]); ``on_retry()`` before
    each retry."""
    if grasps <= 0:
        return FaultFreeRound(0, [], 0), []
    found, retried = run(rig, grasps), []
    for _ in range(retries):
        if not found.host_stalled:
            break
        retried.append({"fault": "fault-free grasps", "phase": "",
                        "problem": "; ".join(found.texts[:4])})
        if on_retry is not None:
            on_retry()
        found = run(rig, grasps)
    return found, retried


def summarise(results: list) -> dict:
    """The matrix's figures: violations, detection latency per fault (median, max), failures."""
    latencies = {}
    for r in results:
        if r.detected:
            latencies.setdefault(r.fault, []).append(r.detection_s)
    ran = [r for r in results if r.injected]
    return {
        "cases": len(results),
        # a case whose grasp could not reach its phase never injected its fault: counted apart
        "not_run": len(results) - len(ran),
        "limit_violations": sum(not r.within_limits for r in ran),
        "undetected": sum(not r.detected for r in ran),
        "wrong_end_state": sum(not r.end_state_ok for r in ran),
        "not_recovered": sum(not r.recovered for r in ran),
        "detection_s": {
            fault: {"median": statistics.median(v), "max": max(v)}
            for fault, v in latencies.items()
        },
        "true_range_pa": [
            min((r.true_low_pa for r in ran), default=NAN),
            max((r.true_high_pa for r in ran), default=NAN)
        ],
    }
