"""softgrip_record and softgrip_replay (#25): the estimator's journal replays to the same
estimates bit for bit; a recorded demo run is read back by rosbags message for message and
replays within 1e-9; bad input gets a clear message and an exit code, never a traceback."""
import json
import math
import pathlib
import shutil
import signal
import subprocess
import time

import numpy as np
import pytest

from softgrip_ros.devtools.estimator_simulation import simulate, step_scenario
from softgrip_ros.devtools.processes import installed_executable, stop_process
from softgrip_ros.estimation.estimator import EstimatorConfig, PressureEstimator, SensorConfig
from softgrip_ros.estimation.runner import INPUTS, PREDICT, SAMPLES, EstimatorRunner, replay


def runner(journal=None):
    config = EstimatorConfig(sensors=(SensorConfig("chamber_a", 300.0),
                                      SensorConfig("chamber_b", 150.0)))
    return EstimatorRunner(PressureEstimator(config), 1 / 200.0, 1 / 20.0, journal=journal)


def test_a_journal_replays_to_the_same_estimates_bit_for_bit():
    """The step scenario's readings in batches, its input changes and timer predictions in
    between: a fresh runner through the journal gives every estimate again, equal as floats."""
    trajectory = simulate(scenario=step_scenario())
    journal = []
    live = runner(journal.append)
    changes, estimates = list(trajectory.input_changes), []
    batch, predicted = [], False
    for t, name, value in trajectory.samples:
        if 1.1 < t < 1.2:  # the sensors silent for 0.1 s: the timer predicts
            if not predicted:
                estimates += [e for e in (live.predict(1.15), live.predict(1.19)) if e]
                predicted = True
            continue
        while changes and changes[0][0] <= t:
            start, inputs = changes.pop(0)
            live.inputs(inputs.regulator_setpoint_gauge_pa, inputs.regulator_enabled,
                        inputs.valves[0], start)
        batch.append((name, value, t))
        if len(batch) == 3:  # a bus batch
            estimate, refused = live.samples(batch)
            assert refused is None
            estimates += [estimate] if estimate else []
            batch = []
    assert len(estimates) > 100
    assert {e.kind for e in journal} == {SAMPLES, INPUTS, PREDICT}
    again = replay(runner(), journal)
    assert [(e.stamp_s, e.gauge_pa, e.variance_pa2) for e in again] == [
        (e.stamp_s, e.gauge_pa, e.variance_pa2) for e in estimates]
    # shuffled delivery: the sequence numbers restore the order
    assert replay(runner(), list(reversed(journal)))[-1] == again[-1]
    with pytest.raises(ValueError, match="lacks events"):
        replay(runner(), journal[:10] + journal[11:])


def tool(name, *args, timeout=120):
    return subprocess.run([installed_executable(name), *map(str, args)], capture_output=True,
                          text=True, timeout=timeout)


# the controller at rest after the release: 20 estimates a second (rest_frequency)
RECORD_AFTER_S = 10.0


@pytest.fixture(scope="module")
def demo_bag(tmp_path_factory):
    """softgrip_record started first, then the controller; a grasp through the `softgrip` command
    line (open to 50 mm, then release); a Ctrl-C ends the recording RECORD_AFTER_S after the
    release (a fixed duration from the start left a controller slow to come up on a starved host
    few estimates: 164 in CI)."""
    from tests.helpers.ros import unique
    directory = tmp_path_factory.mktemp("record")
    bag, namespace = directory / "demo", f"/{unique('rec').replace('-', '_')}"
    recorder = subprocess.Popen([installed_executable("softgrip_record"), str(bag), "--namespace",
                                 namespace, "--duration", "120"], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
    time.sleep(1.5)
    controller = subprocess.Popen(
        [installed_executable("controller"), "--ros-args", "-r", f"__ns:={namespace}", "-p",
         f"can.channel:={unique('rec')}"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        opened = tool("softgrip", "open", "--spacing", "0.05", "--namespace", namespace,
                      "--timeout", "20")
        released = tool("softgrip", "release", "--namespace", namespace, "--timeout", "20")
        time.sleep(RECORD_AFTER_S)
        recorder.send_signal(signal.SIGINT)
        out, err = recorder.communicate(timeout=60)
    finally:
        if recorder.poll() is None:
            stop_process(recorder)
        stop_process(controller)
    # what is tested is the recording of whatever happened; the grasp's own success is the
    # grasp tests' (a loaded host's rare false fault must not take these tests with it)
    assert opened.returncode in (0, 1) and released.returncode in (0, 1), opened.stdout
    assert recorder.returncode == 0, err
    return bag, err


@pytest.mark.ros
def test_the_recorded_bag_reads_back_message_for_message(demo_bag):
    from rosbags.rosbag2 import Reader
    import yaml
    from softgrip_ros.tools import bag as bags
    bag, log = demo_bag
    metadata = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert metadata["storage_identifier"] == "mcap"
    declared = {t["topic_metadata"]["name"]: t["message_count"]
                for t in metadata["topics_with_message_count"]}
    read = {}
    phases, sequences = [], []
    for topic, _, _, message in bags.read(bag):
        read[topic] = read.get(topic, 0) + 1
        if topic.endswith("grasp_state"):
            phases.append(message.phase)
        if topic.endswith("estimator_input"):
            sequences.append(message.sequence)
    assert read == declared and sum(read.values()) == metadata["message_count"]
    suffixes = ("grasp_state", "controller/status", "pressure/sensor/chamber_a",
                "pressure/estimate", "pressure/estimator_input", "tip_pose/left",
                "joint_states")
    assert all(any(t.endswith(s) for t in read) for s in suffixes), sorted(read)
    assert "/diagnostics" in read
    # the recorder counted what it wrote
    assert f"{sum(read.values())} messages" in log
    # the journal from the estimator's first event, without a gap
    assert sorted(sequences) == list(range(len(sequences)))
    with Reader(bag) as reader:  # the rosbags library itself, with the definitions embedded
        assert reader.message_count == sum(read.values())
    assert "softgrip.estimator_parameters" in bags.custom_data(bag)


@pytest.mark.ros
def test_replay_reproduces_the_recorded_estimates(demo_bag, tmp_path):
    bag, _ = demo_bag
    done = tool("softgrip_replay", bag, "--output", tmp_path / "out")
    assert done.returncode == 0, done.stdout + done.stderr
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["max_relative_difference"] <= 1e-9
    assert summary["matched"] > 200 and summary["matched"] >= 0.95 * summary["recorded"]
    assert (tmp_path / "out" / "replay.png").stat().st_size > 10_000
    rows = (tmp_path / "out" / "estimates.csv").read_text().splitlines()
    assert rows[0] == "stamp_s,gauge_pa,variance_pa2" and len(rows) > summary["matched"]


@pytest.mark.ros
def test_replay_without_a_journal_is_close_and_says_so(demo_bag, tmp_path):
    """The same bag without pressure/estimator_input: the readings and statuses in stamp order,
    batched at the recorded estimates' instants, give estimates near the recorded ones, not equal
    (exit 1), and the summary says why."""
    from softgrip_ros.tools import bag as bags
    from softgrip_ros.tools.bag import BagWriter
    source, _ = demo_bag
    stripped = tmp_path / "stripped"
    store = bags.typestore()
    with BagWriter(stripped) as out:
        for topic, msgtype, stamp_ns, message in bags.read(source):
            if not topic.endswith("estimator_input"):
                out.write(topic, msgtype, stamp_ns, store.serialize_cdr(message, msgtype))
        out.set_custom_data("softgrip.estimator_parameters",
                            bags.custom_data(source)["softgrip.estimator_parameters"])
    done = tool("softgrip_replay", stripped, "--output", tmp_path / "out", "--no-plot")
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert "no journal" in summary["source"]
    # the readings batched at the recorded estimates' instants: most estimates share a stamp with
    # a recorded one (282 of 310 here; one reading at a time, 6 of ~300 in CI)
    assert done.returncode == 1 and summary["matched"] >= 0.5 * summary["recorded"] >= 100
    # typically within the sensors' noise (0.15-0.3 kPa) of the recorded estimate: 95 % of them
    # within 15 Pa here beside two busy processes. The largest difference is the live
    # estimator's own: the estimates it gave before a status that reached it late (it then went
    # back to the status's stamp), which the replay, taking each status at its stamp, never
    # gives. It grows with the host's load, over a fast fill's 100-300 kPa/s: 73 Pa idle here,
    # 237 Pa beside two busy processes, 3954 Pa in a fresh-clone CI run here (1.04 kPa in CI
    # before the statuses dated valve switches by their frames, when the replay took them as late
    # as the live estimator). The 3 kPa bound stays: a replay that takes each status as late as
    # the live estimator did would meet it, and none does yet
    assert 0.0 < summary["median_pressure_difference_pa"] < 150.0
    assert summary["p95_pressure_difference_pa"] < 300.0
    assert summary["max_pressure_difference_pa"] < 3000.0
    assert not (tmp_path / "out" / "replay.png").exists()


@pytest.mark.ros
def test_a_truncated_or_corrupt_bag_is_reported_not_a_traceback(demo_bag, tmp_path):
    bag, _ = demo_bag
    truncated = tmp_path / "truncated"
    shutil.copytree(bag, truncated)
    storage = next(truncated.glob("*.mcap"))
    data = storage.read_bytes()
    storage.write_bytes(data[:len(data) // 2])
    done = tool("softgrip_replay", truncated, "--output", tmp_path / "out")
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert str(truncated) in done.stderr
    broken = tmp_path / "broken"
    shutil.copytree(bag, broken)
    (broken / "metadata.yaml").write_text("rosbag2_bagfile_information: [unclosed")
    done = tool("softgrip_replay", broken)
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    done = tool("softgrip_replay", tmp_path / "no_such_bag")
    assert done.returncode == 2 and "Traceback" not in done.stderr


def _foreign_bag(path):
    """A log with a std_msgs/String topic and one of a type the suite does not know."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(get_types_from_msg("float64 x\n", "my_pkg/msg/Foo"))
    writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.open()
    foo = writer.add_connection("/foo", "my_pkg/msg/Foo", typestore=store)
    text = writer.add_connection("/note", "std_msgs/msg/String", typestore=store)
    writer.write(foo, 1000, store.serialize_cdr(store.types["my_pkg/msg/Foo"](x=1.0),
                                                "my_pkg/msg/Foo"))
    writer.write(text, 2000, store.serialize_cdr(
        store.types["std_msgs/msg/String"](data="hi"), "std_msgs/msg/String"))
    writer.close()
    return path


def test_a_topic_of_an_unknown_type_is_skipped_with_a_note_not_a_traceback(tmp_path):
    """softgrip_identify --from-log ended in a KeyError on such a log (#52, class 5)."""
    from softgrip_ros.tools import bag

    log = _foreign_bag(tmp_path / "log")
    unknown = []
    assert [(t, m.data) for t, _, _, m in bag.read(log, lambda *a: unknown.append(a))] == [
        ("/note", "hi")]
    assert unknown == [("/foo", "my_pkg/msg/Foo")]
    for name, arguments, code in (("softgrip_identify", ["--from-log", log], 1),
                                  ("softgrip_replay", [log, "--output", tmp_path / "out"], 2)):
        done = tool(name, *arguments)
        assert done.returncode == code and "Traceback" not in done.stderr, done.stderr
        assert "ignoring /foo: its type my_pkg/msg/Foo" in done.stderr
        assert done.stderr.strip().splitlines()[-1].startswith(f"{name}: ")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["log"]


@pytest.mark.ros
def test_the_recorder_refuses_an_existing_directory_and_warns_of_missing_topics(tmp_path):
    (tmp_path / "exists").mkdir()
    done = tool("softgrip_record", tmp_path / "exists", "--duration", "1")
    assert done.returncode == 2 and "exists" in done.stderr
    done = tool("softgrip_record", tmp_path / "quiet", "--topics", "no_such_topic",
                "--namespace", "/nobody_here", "--duration", "1.5")
    assert done.returncode == 0, done.stderr
    assert "never appeared: /nobody_here/no_such_topic" in done.stderr
    from softgrip_ros.tools import bag as bags
    assert list(bags.read(tmp_path / "quiet")) == []


@pytest.mark.ros
def test_a_full_disk_stops_recording_with_a_message_and_a_readable_bag(tmp_path):
    """Free space below --min-free-mb (here: more than any disk has) stops the recording at its
    first check; the bag is closed and reads."""
    done = tool("softgrip_record", tmp_path / "full", "--min-free-mb", "1e12", "--duration", "10")
    assert done.returncode == 1
    assert "recording stopped: the disk has" in done.stderr
    from softgrip_ros.tools import bag as bags
    assert list(bags.read(tmp_path / "full")) == []


@pytest.mark.ros
def test_the_raw_can_traffic_goes_to_a_python_can_log(tmp_path):
    """--can with the simulated device's frames on softgrip_ipc: a .blf that python-can reads."""
    import can
    from tests.helpers.ros import unique
    # a name ending in a number beyond 16 bits: python-can's BLF writer took it as the channel
    # number and failed on every frame (2 of 2 CI runs logged nothing, by a unique()'s chance)
    channel = f"{unique('reccan')}-70000"
    device_log = (tmp_path / "device.log").open("w")
    device = subprocess.Popen(
        [installed_executable("sim_device"), "--ros-args", "-p", "can.interface:=softgrip_ipc",
         "-p", f"can.channel:={channel}"], stdout=device_log, stderr=subprocess.STDOUT)
    try:
        # the device's first frame, not a fixed wait (a device slow to start on a loaded host)
        from softgrip_ros.canbus import open_bus
        probe = open_bus("softgrip_ipc", channel, 500000)
        try:
            first = probe.recv(timeout=20.0)
        finally:
            probe.shutdown()
        assert first is not None, "the simulated device sent nothing within 20 s"
        done = tool("softgrip_record", tmp_path / "bag", "--topics", "grasp_state", "--duration",
                    "2", "--can", tmp_path / "trial.blf", "--can-interface", "softgrip_ipc",
                    "--can-channel", channel)
    finally:
        stop_process(device)
        device_log.close()
    assert done.returncode == 0, done.stderr
    frames = list(can.BLFReader(str(tmp_path / "trial.blf")))
    # 2 s of sensor frames at 500 + 200 Hz (a quarter lost would still pass)
    assert len(frames) > 1000, (done.stderr, (tmp_path / "device.log").read_text())
    assert f"trial.blf: {len(frames)} CAN frames" in done.stderr
    assert {f.arbitration_id for f in frames} >= {0x210, 0x211, 0x200, 0x280}
    assert math.isfinite(np.mean([f.timestamp for f in frames]))


@pytest.mark.ros
def test_a_failing_can_log_stops_the_recording_with_a_message(tmp_path, monkeypatch, capsys):
    """The CAN log's writer failing (here: a full disk) ends the recording early with status 1
    and says why; the bag is closed and reads."""
    import can
    from softgrip_ros.canbus import open_bus
    from softgrip_ros.canbus.sim_device import SimulatedDevice
    from softgrip_ros.tools import bag as bags
    from softgrip_ros.tools import record
    from tests.helpers.ros import unique

    class FullDisk(can.Listener):
        def __init__(self, path):
            pass

        def on_message_received(self, msg):
            raise OSError(28, "No space left on device")

    monkeypatch.setattr(can, "Logger", FullDisk)
    channel = unique("recfail")
    bus = open_bus("softgrip_ipc", channel, 500000, preserve_timestamps=True)
    device = SimulatedDevice(bus)
    device.start()
    try:
        started = time.monotonic()
        status = record.main([str(tmp_path / "bag"), "--topics", "grasp_state", "--duration",
                              "60", "--can", str(tmp_path / "trial.blf"), "--can-interface",
                              "softgrip_ipc", "--can-channel", channel])
        elapsed_s = time.monotonic() - started
    finally:
        device.stop()
        bus.shutdown()
    err = capsys.readouterr().err
    assert status == 1, err
    assert "the CAN log failed: [Errno 28] No space left on device" in err
    # stopped at the first check after the failure, not at --duration (a bound, not a timing)
    assert elapsed_s < 50.0
    assert list(bags.read(tmp_path / "bag")) == []


# the messages of the demo bag the damaged bags start from: enough for an opening's journal,
# readings and status, few enough to read and replay many times
SMALL_BAG_MESSAGES = 600
REPLAYED_TOPICS = ("pressure/estimator_input", "pressure/estimate", "controller/status",
                   "grasp_state", "pressure/sensor/chamber_a", "pressure/sensor/chamber_b")


@pytest.fixture(scope="module")
def small_bags(demo_bag, tmp_path_factory):
    """Small logs to damage: the replay's, the demo bag's first messages of the topics it reads
    (its custom data too); softgrip_identify's, made here (an opening, then a clamp), with an
    info as for an excitation and as for a known-object step."""
    from softgrip_ros.tools import bag as bags
    path, _ = demo_bag
    store = bags.typestore()
    messages = []
    for topic, msgtype, stamp_ns, message in bags.read(path):
        if topic.endswith(REPLAYED_TOPICS):
            messages.append((topic, msgtype, stamp_ns, store.serialize_cdr(message, msgtype)))
            if len(messages) == SMALL_BAG_MESSAGES:
                break
    directory = tmp_path_factory.mktemp("small_bags")
    replayed = directory / "replay"
    with bags.BagWriter(replayed) as out:
        for key, value in bags.custom_data(path).items():
            out.set_custom_data(key, value)
        for message in messages:
            out.write(*message)
    logs, infos = _identification_logs(directory)
    return replayed, logs, infos


# the made-up identification log: opened at OPEN_PA, a clamp to CLAMP_PA sent at CLAMP_AT_S
LOG_START_S, CLAMP_AT_S, LOG_END_S = 1_796_000_000.0, 1_796_000_000.6, 1_796_000_001.4
OPEN_PA, CLAMP_PA = 10e3, -20e3


def _identification_logs(directory) -> tuple:
    """({kind: path}, {kind: info}) of two softgrip_identify logs of the same readings."""
    import yaml
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import FluidPressure
    from softgrip_interfaces.msg import ControllerStatus
    from softgrip_ros.model import plant_file
    from softgrip_ros.model.pneumatics import P_ATM_PA, Valve
    from softgrip_ros.nodes.common import stamp_msg
    from softgrip_ros.tools import bag as bags
    from softgrip_ros.tools import identify
    from std_msgs.msg import String
    rows = []
    for k in range(int((LOG_END_S - LOG_START_S) / 0.002)):
        t = LOG_START_S + 0.002 * k
        gauge = OPEN_PA if t < CLAMP_AT_S else CLAMP_PA + (OPEN_PA - CLAMP_PA) * math.exp(
            -(t - CLAMP_AT_S) / 0.1)
        for name in ("chamber_a", "chamber_b"):
            reading = FluidPressure(fluid_pressure=gauge + P_ATM_PA, variance=9e4)
            reading.header.stamp = stamp_msg(t)
            rows.append((t, f"/pressure/sensor/{name}", "sensor_msgs/msg/FluidPressure", reading))
    for k in range(int((LOG_END_S - LOG_START_S) / 0.02)):
        t = LOG_START_S + 0.02 * k
        clamping = t >= CLAMP_AT_S
        status = ControllerStatus(
            mode=ControllerStatus.MODE_IDENTIFY,
            regulator_command_gauge_pressure_pa=CLAMP_PA if clamping else OPEN_PA,
            regulator_actual_gauge_pressure_pa=CLAMP_PA if clamping else OPEN_PA,
            regulator_report_age_s=0.0, regulator_enabled=True,
            valve_states=[int(Valve.VACUUM if clamping else Valve.CLOSED)],
            output_change_age_s=t - (CLAMP_AT_S if clamping else LOG_START_S))
        status.header.stamp = stamp_msg(t)
        rows.append((t, "/controller/status", "softgrip_interfaces/msg/ControllerStatus", status))
    rows.sort(key=lambda row: row[0])
    infos = {
        "excitation": {"format": identify.LOG_FORMAT, "held_out_from_s": CLAMP_AT_S,
                       "steps": [["SUPPLY", OPEN_PA, 0.6], ["VACUUM", CLAMP_PA, 0.8]]},
        "contact": {"format": identify.LOG_FORMAT, "contact": {
            "known_object_m": 0.02, "gripper_model": "type_II", "open_pa": OPEN_PA,
            "clamp_pa": CLAMP_PA, "closings": [["empty", CLAMP_AT_S], ["object", CLAMP_AT_S]]}},
    }
    logs = {}
    for kind, info in infos.items():
        info["base_plant"] = plant_file.document(plant_file.default_description())
        logs[kind] = directory / f"identify_{kind}"
        with bags.BagWriter(logs[kind]) as out:
            out.write(identify.INFO_TOPIC, "std_msgs/msg/String", int(LOG_START_S * 1e9),
                      serialize_message(String(data=yaml.safe_dump(info))))
            for t, topic, msgtype, message in rows:
                out.write(topic, msgtype, int(t * 1e9), serialize_message(message))
    return logs, infos


def _damaged_copy(data, source, into):
    """A copy of the bag ``source`` in ``into`` with one damage drawn by hypothesis: its storage
    cut short or overwritten in part, or its metadata.yaml mutated."""
    import yaml
    from hypothesis import strategies as st
    from tests.helpers.mutation import mutated
    copy = into / "bag"
    shutil.copytree(source, copy)
    storage = next(copy.glob("*.mcap"))
    content = storage.read_bytes()
    damage = data.draw(st.sampled_from(["cut", "overwrite", "overwrite", "metadata"]))
    if damage == "cut":
        storage.write_bytes(content[:data.draw(st.integers(0, len(content) - 1))])
    elif damage == "overwrite":
        at = data.draw(st.integers(0, len(content) - 1))
        junk = data.draw(st.binary(min_size=1, max_size=64))
        storage.write_bytes(content[:at] + junk + content[at + len(junk):])
    else:
        metadata = yaml.safe_load((copy / "metadata.yaml").read_text())
        (copy / "metadata.yaml").write_text(yaml.safe_dump(data.draw(mutated(metadata))))
    return copy


@pytest.mark.ros
def test_a_damaged_bag_replays_or_is_refused_in_one_line(small_bags, tmp_path):
    """softgrip_replay on a bag cut short, overwritten in part or with a mutated metadata.yaml:
    the replay runs, or says in one line why not (exit 2); before #52, any error deep inside
    the readers or the recorded parameters escaped as a traceback."""
    import tempfile
    from hypothesis import given
    from hypothesis import strategies as st
    from softgrip_ros.tools import replay
    from tests.helpers.mutation import EXAMPLES, refused_in_one_line
    source, _, _ = small_bags
    assert replay.replay(source, None)[1], "the undamaged bag replays"

    @EXAMPLES
    @given(data=st.data())
    def check(data):
        with tempfile.TemporaryDirectory(dir=tmp_path) as into:
            damaged = _damaged_copy(data, source, pathlib.Path(into))
            refused_in_one_line(lambda path: replay.replay(path, None), damaged)

    check()


@pytest.mark.ros
def test_a_damaged_identification_log_is_read_or_refused_in_one_line(small_bags, tmp_path):
    """softgrip_identify --from-log on a log damaged as above, or whose info (the YAML the
    tool wrote beside the readings) is mutated: the recording and the known-object step's
    closings are read, or it says in one line why not, before any fit; before #52 a missing or
    mistyped info key was a KeyError or TypeError."""
    import tempfile
    from hypothesis import given
    from hypothesis import strategies as st
    from softgrip_ros.model import plant_file
    from softgrip_ros.tools import bag as bags
    from softgrip_ros.tools import identify, identify_contact
    from tests.helpers.mutation import EXAMPLES, mutated, refused_in_one_line
    _, logs, infos = small_bags

    def read(path):
        recording, info = identify.recording_from_log(path)
        if "contact" in info:
            identify_contact.jobs_from_log(recording, info, plant_file.parse(
                info["base_plant"], "the log's base plant"))
        return recording

    for kind in logs:
        assert read(logs[kind]).sensors, f"the undamaged {kind} log is read"

    @EXAMPLES
    @given(data=st.data())
    def check(data):
        kind = data.draw(st.sampled_from(sorted(logs)))
        with tempfile.TemporaryDirectory(dir=tmp_path) as into:
            if data.draw(st.booleans()):
                damaged = _damaged_copy(data, logs[kind], pathlib.Path(into))
            else:  # the same readings, beside a mutated info
                import yaml
                damaged = pathlib.Path(into) / "log"
                store = bags.typestore()
                with bags.BagWriter(damaged) as out:
                    for topic, msgtype, stamp_ns, message in bags.read(logs[kind]):
                        if topic == identify.INFO_TOPIC:
                            message = store.types[msgtype](
                                data=yaml.safe_dump(data.draw(mutated(infos[kind]))))
                        out.write(topic, msgtype, stamp_ns, store.serialize_cdr(message, msgtype))
            refused_in_one_line(read, damaged)

    check()


@pytest.mark.ros
def test_a_bag_that_cannot_be_created_is_said_so_and_not_claimed(tmp_path, monkeypatch, capsys):
    """A directory the recorder may not write in (here the writer refuses, as for a read-only
    parent, which a root test run cannot make): exit 1, saying the bag could not be created;
    before #52 it said the directory held everything recorded, and it did not exist."""
    from softgrip_ros.tools import bag as bags
    from softgrip_ros.tools import record

    def refuse(self):
        raise PermissionError(13, "Permission denied", str(self.path))

    monkeypatch.setattr(bags.BagWriter, "__enter__", refuse)
    status = record.main([str(tmp_path / "bag"), "--topics", "grasp_state", "--duration", "5"])
    err = capsys.readouterr().err
    assert status == 1, err
    assert "cannot record: the bag could not be created: [Errno 13] Permission denied" in err
    assert "holds everything" not in err and not (tmp_path / "bag").exists()


@pytest.mark.ros
def test_replay_into_a_place_it_cannot_write_says_so_before_replaying(small_bags, tmp_path):
    """An --output under a file: exit 2 with the reason, nothing written (it was a traceback,
    #52); an output it can write gets estimates.csv, summary.json and replay.png whole."""
    source, _, _ = small_bags
    (tmp_path / "file").write_text("in the way")
    done = tool("softgrip_replay", source, "--output", tmp_path / "file" / "out")
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert done.stderr.strip().splitlines()[-1].startswith("softgrip_replay: cannot write in")
    assert "[replay]" not in done.stderr  # refused before the replay ran
    done = tool("softgrip_replay", source, "--output", tmp_path / "out")
    assert done.returncode in (0, 1), done.stderr
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [
        "estimates.csv", "replay.png", "summary.json"]
