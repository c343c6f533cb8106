"""softgrip_identify as a user runs it: its arguments, its log (rosbag2, MCAP) read back and
fitted, and a live run on the installed controller that a sensor dropout stops, writing nothing
and restoring the controller."""
import subprocess
import time

import pytest

from softgrip_ros.devtools import identification_sim
from softgrip_ros.devtools.processes import installed_executable, stop_process
from softgrip_ros.estimation import identification
from softgrip_ros.model import plant_file
from softgrip_ros.tools import bag, identify
from tests.helpers.ros import spinning, unique, wait_for

# a spinner thread's exception fails the test: SuiteRig's executor once raced its shutdown
pytestmark = [pytest.mark.ros,
              pytest.mark.filterwarnings("error::pytest.PytestUnhandledThreadExceptionWarning")]


def _run(*args, timeout=120):
    return subprocess.run([installed_executable("softgrip_identify"), *args],
                          capture_output=True, text=True, timeout=timeout)


@pytest.mark.parametrize("args, message", [
    (["--volume-m3", "5"], "argument --volume-m3: must lie in"),
    (["--vacuum-source-pa", "5"], "argument --vacuum-source-pa: must lie in"),
    (["--vacuum-source-pa", "nan"], "argument --vacuum-source-pa: must lie in"),
    (["--from-log", "/nonexistent"], "no rosbag2 log there"),
    (["--timeout", "0"], "argument --timeout: must lie in (0, 3600] s"),
    (["--fit-budget-s", "0"], "argument --fit-budget-s: must lie in (0, inf] s"),
    (["--fit-budget-s", "nan"], "argument --fit-budget-s: must lie in"),
])
def test_bad_arguments_exit_2_with_the_reason(args, message):
    result = _run(*args)
    assert result.returncode == 2 and message in result.stderr


def test_an_output_it_cannot_write_in_is_refused_before_anything_runs(tmp_path):
    """Before #52 a read-only or blocked --output ended in a traceback after the whole fit."""
    (tmp_path / "file").write_text("in the way")
    result = _run("--output", str(tmp_path / "file" / "out"), "--timeout", "0.5")
    assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr
    assert "--output: cannot write in" in result.stderr
    assert "controller" not in result.stdout  # refused before it looked for one


def _log_of(recording: identification.Recording, base: plant_file.PlantDescription, path):
    """A log as softgrip_identify writes it, from a recording made without ROS."""
    import yaml
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import FluidPressure
    from softgrip_interfaces.msg import ControllerStatus
    from softgrip_ros.nodes.common import stamp_msg
    from std_msgs.msg import String
    rows = []
    for name, (times, values) in recording.sensors.items():
        for t, v in zip(times, values):
            message = FluidPressure(fluid_pressure=float(v) + 101_325.0, variance=9e4)
            message.header.stamp = stamp_msg(float(t))
            rows.append((float(t), f"/pressure/sensor/{name}", "sensor_msgs/msg/FluidPressure",
                         message))
    report_times, report_values = recording.regulator
    changes = iter(recording.inputs)
    change, upcoming = next(changes), next(changes, None)
    for t, value in zip(report_times, report_values):
        while upcoming is not None and upcoming.time_s <= t:
            change, upcoming = upcoming, next(changes, None)
        status = ControllerStatus(
            mode=ControllerStatus.MODE_IDENTIFY, regulator_actual_gauge_pressure_pa=float(value),
            regulator_report_age_s=0.0, regulator_command_gauge_pressure_pa=float(
                change.regulator_setpoint_pa), regulator_enabled=change.regulator_enabled,
            valve_states=[change.valve], output_change_age_s=float(t) - change.time_s)
        status.header.stamp = stamp_msg(float(t))
        rows.append((float(t), "/controller/status", "softgrip_interfaces/msg/ControllerStatus",
                     status))
    rows.sort(key=lambda row: row[0])
    info = {"format": "softgrip_identify/1", "held_out_from_s": recording.held_out_from_s,
            "base_plant": plant_file.document(base), "base_plant_file": "shipped"}
    with bag.BagWriter(path) as log:
        log.write(identify.INFO_TOPIC, "std_msgs/msg/String", int(rows[0][0] * 1e9),
                  serialize_message(String(data=yaml.safe_dump(info))))
        for t, topic, msgtype, message in rows:
            log.write(topic, msgtype, int(t * 1e9), serialize_message(message))
    return path


@pytest.mark.slow
def test_a_log_reads_back_and_is_fitted_into_a_plant_file_with_its_report(tmp_path):
    """The log format round trip (rosbags, MCAP), then the tool fits it: a plant file that
    loads, with provenance, intervals, the measured volume and pump level, and its report and
    figure."""
    truth = plant_file.default_description()
    steps, held_out = identification.excitation(quick=True)
    recording = identification_sim.record(truth, steps, held_out, seed=2)
    start = 1_796_000_000.0  # ROS time, as a live log's stamps
    recording.sensors = {n: (t + start, v) for n, (t, v) in recording.sensors.items()}
    recording.regulator = (recording.regulator[0] + start, recording.regulator[1])
    recording.inputs = [identification.InputChange(c.time_s + start, c.valve,
                                                   c.regulator_setpoint_pa, c.regulator_enabled)
                        for c in recording.inputs]
    recording.held_out_from_s = held_out + start
    log = _log_of(recording, truth, tmp_path / "recording")
    assert (log / "metadata.yaml").is_file() and list(log.glob("*.mcap"))
    back, info = identify.recording_from_log(log)
    assert len(back.sensors["chamber_a"][0]) == len(recording.sensors["chamber_a"][0])
    assert [c.valve for c in back.inputs] == [c.valve for c in recording.inputs]
    assert back.held_out_from_s == pytest.approx(recording.held_out_from_s)
    result = _run("--from-log", str(log), "--output", str(tmp_path / "out"), "--volume-m3",
                  "2e-5", "--vacuum-source-pa=-80e3", timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    written = plant_file.load(tmp_path / "out" / "plant.yaml")
    assert written.provenance["source"] == "identified"
    assert written.details["chamber_volume_m3"]["source"] == "measured"
    assert written.details["vacuum_source_gauge_pa"]["source"] == "measured"
    assert written.parameters.vacuum_source_gauge_pa == -80000.0
    assert "(--vacuum-source-pa)" in written.provenance["vacuum_source"]
    assert "ci95" in written.details["supply_conductance"]
    assert written.parameters.supply_conductance == pytest.approx(1e-9, rel=0.05)
    report = (tmp_path / "out" / "identification.md").read_text()
    assert "| `supply_conductance` |" in report and "identification.png" in report
    assert "Valve switches: the fit dated" in report and "Sensor latency" in report
    assert (tmp_path / "out" / "identification.png").stat().st_size > 10_000
    again = _run("--from-log", str(log), "--output", str(tmp_path / "out"))
    assert again.returncode == 2 and "exists" in again.stderr


@pytest.mark.slow
def test_a_sensor_dropout_stops_a_live_run_which_vents_restores_and_writes_nothing(tmp_path):
    """The installed controller and device on an inter-process bus; chamber_a silenced mid-run."""
    import rclpy
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import GetParameters, SetParameters

    channel = unique("identify")
    ros_args = ["--ros-args", "-p", "can.interface:=softgrip_ipc", "-p",
                f"can.channel:={channel}"]
    logs = open(tmp_path / "processes.log", "w+")
    device = subprocess.Popen([installed_executable("sim_device"), *ros_args], stdout=logs,
                              stderr=subprocess.STDOUT)
    controller = subprocess.Popen([installed_executable("controller"), *ros_args], stdout=logs,
                                  stderr=subprocess.STDOUT)
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("identify_test", context=context)
    try:
        with spinning(context, node, threads=1):
            time.sleep(2.0)
            run = subprocess.Popen([installed_executable("softgrip_identify"), "--output",
                                    str(tmp_path / "out"), "--quick", "--timeout", "30"],
                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            setter = node.create_client(SetParameters, "/sim_device/set_parameters")
            assert setter.wait_for_service(timeout_sec=20.0)
            time.sleep(5.0)  # into the excitation
            future = setter.call_async(SetParameters.Request(parameters=[Parameter(
                name="fault.sensor_dropout", value=ParameterValue(
                    type=ParameterType.PARAMETER_STRING, string_value="chamber_a"))]))
            wait_for(future.done, message="the fault set")
            out, err = run.communicate(timeout=120)
            assert run.returncode == 1, out + err
            # the first to see it names it: the sensor's silence on DDS, or, on a loaded host,
            # the controller's own frame age
            assert ("stopped: sensor chamber_a silent" in err or
                    "stopped: no sensor frame" in err) and "nothing written" in err, err
            assert not (tmp_path / "out").exists()
            getter = node.create_client(GetParameters, "/pressure_controller/get_parameters")
            assert getter.wait_for_service(timeout_sec=10.0)
            future = getter.call_async(GetParameters.Request(names=["identification_mode"]))
            wait_for(future.done, message="identification_mode read")
            assert future.result().values[0].bool_value is False  # restored
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        codes = [stop_process(p, timeout_s=15.0) for p in (controller, device)]
        logs.close()
    assert codes == [0, 0], (tmp_path / "processes.log").read_text()[-3000:]


def _known_object_run(tmp_path, place: bool) -> tuple:
    """softgrip_identify's known-object step for a 30 mm cylinder on the installed controller,
    with the device and its physics world apart; after the clamps on nothing the arm brings the
    cylinder between the fingers (``place``) or not, and Enter is pressed. (return code, all
    the tool printed)."""
    from softgrip_ros.devtools.grasp_bench import GraspCase, Placement, SuiteRig, write_scene
    from softgrip_ros.tools import identify_contact
    scene = write_scene(Placement().scene(GraspCase("cylinder", 0.03, 0.02, 0.8)), tmp_path)
    rig = SuiteRig(scene, unique("contact"), tmp_path / "rig.log", device_apart=True)
    told = []
    try:
        rig.wait_ready()
        run = subprocess.Popen([installed_executable("softgrip_identify"), "--known-object-m",
                                "0.03", "--output", str(tmp_path / "out"), "--timeout", "30"],
                               stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
        try:
            for line in run.stdout:
                told.append(line)
                if identify_contact.PLACE_PROMPT in line:
                    break
            # each clamp on nothing once, however often one interrupted was done again
            clamps = {line.split(":")[0] for line in told
                      if "on nothing:" in line and "interrupted" not in line}
            if len(clamps) != identify_contact.EMPTY_CLOSINGS or not any(
                    identify_contact.PLACE_PROMPT in line for line in told):
                out, err = run.communicate(timeout=30)
                pytest.fail("softgrip_identify ended before the prompt: " + "".join(told) + out
                            + err)
            if place:
                rig.play_through("approach")
            try:
                run.stdin.write("\n")
                run.stdin.flush()
            except BrokenPipeError:  # the tool stopped at the prompt: say why
                out, err = run.communicate(timeout=30)
                pytest.fail("softgrip_identify ended at the prompt: " + "".join(told) + out + err)
            out, err = run.communicate(timeout=300)
        finally:
            stop_process(run, timeout_s=10.0)
    finally:
        rig.close()
    return run.returncode, "".join(told) + out + err


@pytest.mark.slow
def test_the_known_object_step_learns_the_share_on_the_worlds_fingers(tmp_path):
    """The tool opens, clamps twice on nothing, asks for the object, which the arm brings between
    the fingers, clamps three times on it, and writes a plant file whose contact share is pinned
    (an interval narrower than 0.1) around the world's own (FE_BENDING_VOLUME_SHARE), and under
    which the world's 30 mm cylinder is felt, the median of the clamps, within the 5 mm the
    sensing is asked for (one clamp of several may read further off: the felt sizes' p95 in the
    world is some 15 mm, docs/grasp_sensing.md); the report and the figure beside it."""
    from softgrip_ros.model.world.fingers import FE_BENDING_VOLUME_SHARE
    from softgrip_ros.tools import identify_contact
    code, printed = _known_object_run(tmp_path, place=True)
    assert code == 0, printed
    written = plant_file.load(tmp_path / "out" / "plant.yaml")
    detail = written.details["contact.bending_volume_share"]
    low, high = detail["ci95"]
    assert detail["source"] == "identified" and detail["known_object_m"] == 0.03
    assert low <= written.bending_volume_share <= high and high - low < 0.1, detail
    assert low <= FE_BENDING_VOLUME_SHARE <= high, detail  # the world's truth
    report = (tmp_path / "out" / identify_contact.REPORT).read_text()
    felt = report.split("identified share (mm) | ", 1)[1].split(" |", 1)[0]
    sizes = sorted(float(size) for size in felt.split(", "))
    assert abs(sizes[len(sizes) // 2] - 30.0) < 5.0, report
    assert (tmp_path / "out" / identify_contact.FIGURE).stat().st_size > 10_000
    assert (tmp_path / "out" / "recording" / "metadata.yaml").is_file()


@pytest.mark.slow
def test_an_object_never_placed_is_not_fitted_and_the_log_is_kept(tmp_path):
    """Enter pressed with nothing between the fingers: the object's clamps are clamps on
    nothing, the tool refuses to fit (exit 1, the reason, no plant file), and keeps the log in
    --output/recording, which refits from the log to the same refusal (the fit is
    deterministic); a second live run into that --output is refused before it starts."""
    code, printed = _known_object_run(tmp_path, place=False)
    assert code == 1, printed
    # an empty hand's closings are best explained by no bending volume, or not judged as the
    # object's under the best share
    assert "cannot fit:" in printed and any(reason in printed for reason in (
        "did the object stop them?", "on the object, is not judged so")), printed
    assert "the log kept in" in printed and "--from-log" in printed, printed
    assert not (tmp_path / "out" / "plant.yaml").exists()
    log = tmp_path / "out" / "recording"
    assert (log / "metadata.yaml").is_file()
    again = subprocess.run([installed_executable("softgrip_identify"), "--from-log", str(log),
                            "--output", str(tmp_path / "refit")], capture_output=True,
                           text=True, timeout=120)
    assert again.returncode == 1, again.stderr
    assert again.stderr.split("cannot fit: ")[1].split(";")[0] == printed.split(
        "cannot fit: ")[1].split(";")[0], again.stderr  # the same reason from the same readings
    assert not (tmp_path / "refit").exists()
    live_again = subprocess.run([installed_executable("softgrip_identify"), "--known-object-m",
                                 "0.03", "--output", str(tmp_path / "out")],
                                capture_output=True, text=True, timeout=60)
    assert live_again.returncode == 2 and "recording exists" in live_again.stderr, \
        live_again.stderr


class _FakeLive:
    """softgrip_identify's Live to identify_contact.run, with the chamber reading
    ``measured_pa`` and nothing wrong: what it was sent."""

    def __init__(self, measured_pa: float):
        import threading
        self.lock, self.recording, self.sent = threading.Lock(), False, []
        self.measured_pa, self.extra = measured_pa, []

        class Clock:
            def now(self):
                return type("T", (), {"nanoseconds": time.time_ns()})()
        self.node = type("N", (), {"get_clock": lambda self: Clock()})()

    def send(self, source, target_pa):
        self.sent.append((source, target_pa))

    def problem(self, sensors):
        return ""

    def measured_gauge_pa(self):
        return self.measured_pa

    def output_changes_between(self, start_s, end_s):
        return [(start_s + 0.3, "identification: valve open to the regulator")] + self.extra


def test_a_clamp_the_controller_interrupts_is_done_again_and_not_fitted(monkeypatch):
    """A clamp during which the controller changed its outputs again (its valves held closed
    while its readings were late) is not the closing the fit models: said, done again, and only
    the clean one kept; past MAX_REDONE the step stops, saying why."""
    from softgrip_ros.tools import identify_contact
    monkeypatch.setattr(identify_contact, "OPEN_S", 0.01)
    monkeypatch.setattr(identify_contact, "CLAMP_S", 0.01)
    monkeypatch.setattr(identify_contact, "OBJECT_CLOSINGS", 0)
    live, told = _FakeLive(measured_pa=13e3), []
    live.extra = [(0.0, "no valid pressure reading: valves held closed")]

    def clean_after_two(source, target_pa):  # the first two clamps interrupted
        _FakeLive.send(live, source, target_pa)
        if sum(sent == ("SUPPLY", -30e3) for sent in live.sent) > 2:
            live.extra = []
    live.send = clean_after_two
    contact_plan = identify_contact.ContactPlan(0.03, 13e3, -30e3)
    closings = identify_contact.run(live, contact_plan, ["chamber_a"], told.append,
                                    lambda check: None)
    assert [kind for kind, _ in closings] == ["empty"] * identify_contact.EMPTY_CLOSINGS
    interrupted = [line for line in told if "interrupted" in line]
    assert len(interrupted) == 2 and "valves held closed" in interrupted[0], told
    assert interrupted[0].startswith("clamp 1/2 on nothing interrupted"), told
    live.send, live.sent = lambda source, target_pa: None, []
    live.extra = [(0.0, "no valid pressure reading: valves held closed")]
    with pytest.raises(identify.Stopped, match=f"{identify_contact.MAX_REDONE + 1} clamps "
                       "interrupted by the controller .*valves held closed"):
        identify_contact.run(live, contact_plan, ["chamber_a"], told.append, lambda c: None)


def test_the_known_object_step_stops_when_no_one_can_place_the_object():
    """stdin closed at the prompt (a script, no terminal): the step stops as any other stop,
    after its clamps on nothing, with the reason."""
    from softgrip_ros.tools import identify_contact

    def closed_stdin(check):
        check()
        raise EOFError("stdin closed before the object was placed")

    live, told = _FakeLive(measured_pa=13.2e3), []
    contact_plan = identify_contact.ContactPlan(0.03, 13e3, -30e3)
    with pytest.raises(identify.Stopped, match="stdin closed before the object was placed"):
        identify_contact.run(live, contact_plan, ["chamber_a"], told.append, closed_stdin)
    assert sum("on nothing" in line for line in told) == identify_contact.EMPTY_CLOSINGS
    assert ("SUPPLY", -30e3) in live.sent and identify_contact.PLACE_PROMPT in told[-1]


def test_the_object_is_asked_for_only_once_the_fingers_read_open(monkeypatch):
    """A chamber still 1.5 kPa short of the opening after OPEN_S (fingers that would knock the
    object away as it comes in): no prompt, the opening held, and a stop saying so."""
    from softgrip_ros.tools import identify_contact
    monkeypatch.setattr(identify_contact, "OPEN_S", 0.05)
    monkeypatch.setattr(identify_contact, "OPEN_TIMEOUT_S", 0.3)
    monkeypatch.setattr(identify_contact, "EMPTY_CLOSINGS", 0)
    live, told = _FakeLive(measured_pa=11.5e3), []
    contact_plan = identify_contact.ContactPlan(0.03, 13e3, -30e3)
    with pytest.raises(identify.Stopped, match="did not open to 13.0 kPa .* reads 11.5 kPa"):
        identify_contact.run(live, contact_plan, ["chamber_a"], told.append,
                             lambda check: pytest.fail("asked for the object"))
    assert not any(identify_contact.PLACE_PROMPT in line for line in told)
    assert set(live.sent) == {("SUPPLY", 13e3)}

    def never_placed(check):
        check()
        raise EOFError("never placed")
    live.measured_pa = 12.1e3  # within OPEN_TOLERANCE_PA: asked for
    with pytest.raises(identify.Stopped, match="never placed"):
        identify_contact.run(live, contact_plan, ["chamber_a"], told.append, never_placed)
    assert identify_contact.PLACE_PROMPT in told[-1]
