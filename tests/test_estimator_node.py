"""The estimator node over real DDS: another node feeds it sensor samples and controller status."""
import math
import subprocess

import numpy as np
import pytest

from softgrip_ros.devtools.processes import installed_executable
from softgrip_ros.model.pneumatics import Valve
from softgrip_ros.nodes import messages

from tests.helpers.ros import spinning, wait_for

pytestmark = pytest.mark.ros
P_ATM_PA = 101_325.0


@pytest.fixture
def wired(rclpy_context, request):
    """The estimator (with the parameters of ``request.param``, if any) and a node feeding it."""
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import FluidPressure
    from diagnostic_msgs.msg import DiagnosticArray
    from softgrip_interfaces.msg import ControllerStatus
    from softgrip_ros.nodes.estimator import EstimatorNode

    overrides = [
        Parameter(name, value=value) for name, value in getattr(request, "param", {}).items()
    ]
    estimator = EstimatorNode(context=rclpy_context, parameter_overrides=overrides)
    feeder = Node("test_feeder", context=rclpy_context)
    publishers = {
        name: feeder.create_publisher(FluidPressure, f"pressure/sensor/{name}", 50)
        for name in ("chamber_a", "chamber_b")
    }
    status_pub = feeder.create_publisher(ControllerStatus, "controller/status", 10)
    estimates, diagnostics = [], []
    feeder.create_subscription(FluidPressure, "pressure/estimate", estimates.append, 50)
    feeder.create_subscription(
        DiagnosticArray, "/diagnostics",
        lambda m: diagnostics.extend(s for s in m.status if s.name == "softgrip: estimator"), 10)
    try:
        with spinning(rclpy_context, estimator, feeder, threads=1):
            wait_for(lambda: all(p.get_subscription_count() for p in publishers.values()),
                     message="estimator subscribed")
            yield feeder, publishers, status_pub, estimates, diagnostics
    finally:
        estimator.destroy_node()
        feeder.destroy_node()


def _feed(feeder, publishers, names, truth_pa, seconds, rng, rate_hz=250.0):
    """Publish noisy samples of a constant gauge pressure in real time, stamped now."""
    import time
    from sensor_msgs.msg import FluidPressure
    noise = {"chamber_a": 300.0, "chamber_b": 150.0}
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        stamp = feeder.get_clock().now().to_msg()
        for name in names:
            publishers[name].publish(
                FluidPressure(fluid_pressure=P_ATM_PA + truth_pa + rng.normal(0, noise[name]),
                              variance=noise[name]**2, header=_header(stamp, name)))
        time.sleep(1.0 / rate_hz)


def _header(stamp, frame):
    from std_msgs.msg import Header
    return Header(stamp=stamp, frame_id=frame)


@pytest.mark.parametrize("wired", [{"rest_frequency": 200.0}], indirect=True)
def test_fuses_sensor_topics_into_a_published_estimate_with_variance(wired):
    from diagnostic_msgs.msg import DiagnosticStatus
    from softgrip_interfaces.msg import ControllerStatus
    feeder, publishers, status_pub, estimates, diagnostics = wired
    rng = np.random.default_rng(0)
    truth = 20e3
    status_pub.publish(
        ControllerStatus(header=_header(feeder.get_clock().now().to_msg(), ""), valve_states=[0],
                         regulator_command_gauge_pressure_pa=truth, regulator_enabled=True))
    _feed(feeder, publishers, ("chamber_a", "chamber_b"), truth, 1.0, rng)
    fed = len(estimates)  # the fused ones; after the feed come predictions
    assert fed > 100
    last = estimates[fed - 50:fed]
    values = np.array([m.fluid_pressure - P_ATM_PA for m in last])
    stds = np.sqrt([m.variance for m in last])
    assert np.all(np.abs(values - truth) < 4 * stds + 1.0)  # within 4 sigma of the truth
    # tighter than the best sensor's one-sample noise
    assert np.median(stds) < 150.0 / math.sqrt(2)
    assert estimates[-1].header.stamp.sec > 0
    wait_for(
        lambda: any(d.level == DiagnosticStatus.OK and "fusing 2 sensors" in d.message
                    for d in diagnostics), message="diagnostics OK")


def test_at_rest_estimates_go_out_at_the_rest_rate(wired):
    """A sealed chamber at a constant pressure rests: estimates at rest_frequency (20 Hz; one per
    45 ms of sample stamps at most, but for noise beyond 3 sigma, which ends a rest:
    test_estimation pins that rule), as accurate as ever."""
    from softgrip_interfaces.msg import ControllerStatus
    from softgrip_ros.nodes.common import stamp_seconds as stamp_s
    feeder, publishers, status_pub, estimates, _ = wired
    rng = np.random.default_rng(2)
    truth = 10e3
    status_pub.publish(
        ControllerStatus(header=_header(feeder.get_clock().now().to_msg(), ""), valve_states=[0],
                         regulator_command_gauge_pressure_pa=truth, regulator_enabled=True))
    _feed(feeder, publishers, ("chamber_a", "chamber_b"), truth, 0.3, rng)  # converge
    start = len(estimates)
    _feed(feeder, publishers, ("chamber_a", "chamber_b"), truth, 1.0, rng)
    at_rest = estimates[start:]
    gaps = np.diff([stamp_s(m.header.stamp) for m in at_rest])
    # a 3-sigma sample ends a rest too: about 1 in 370 samples of pure noise, 1-2 of these 500
    assert 5 <= len(at_rest) <= 27 and np.median(gaps) >= 0.045 - 1e-6 and np.sum(gaps < 0.045 -
                                                                                  1e-6) <= 4, gaps
    values = np.array([m.fluid_pressure - P_ATM_PA for m in at_rest])
    assert np.all(np.abs(values - truth) < 4 * np.sqrt([m.variance for m in at_rest]) + 1.0)


def test_a_batch_of_readings_gives_one_estimate_at_its_newest_and_an_unknown_sensor_is_refused(
        rclpy_context):
    """The composed controller hands over the readings of a bus batch together (10 ms of them
    while it rests): one estimate comes of it, stamped at the newest sample, not at an older one
    that happened to make an estimate due."""
    from softgrip_ros.nodes.estimator import EstimatorNode
    estimator = EstimatorNode(in_process=True, context=rclpy_context)
    published = []
    estimator.estimates.connect(lambda e: published.append((e.stamp_s, e.gauge_pa)))
    try:
        t0 = estimator._now()
        estimator.take_readings([("chamber_a", 10e3, t0)])
        assert [stamp for stamp, _ in published] == [t0]
        estimator.take_readings([("chamber_b" if k % 2 else "chamber_a", 10e3, t0 + 0.006 * k)
                                     for k in range(1, 11)])
        assert len(published) == 2 and published[-1][0] == pytest.approx(t0 + 0.06)
        with pytest.raises(ValueError, match=r"unknown sensor 'chamber_z'"):
            estimator.take_readings([("chamber_z", 1.0, t0 + 0.061),
                                         ("chamber_a", 10e3, t0 + 0.062)])
        assert estimator.estimator.stats["chamber_a"].last_stamp_s == pytest.approx(t0 + 0.062)
    finally:
        estimator.close()
        estimator.destroy_node()


def test_a_status_switches_the_process_model_from_when_its_outputs_went_out(rclpy_context):
    """A status published 40 ms after the ValveCommand it reports went out (its thread held up on
    a loaded host): the process model's inputs change at the send, stamp less
    output_change_age_s, as softgrip_identify dates them, not at the status's stamp. Unknown
    (infinite: nothing sent yet), the stamp is taken."""
    from softgrip_interfaces.msg import ControllerStatus
    from softgrip_ros.nodes.common import stamp_msg
    from softgrip_ros.nodes.estimator import EstimatorNode
    estimator = EstimatorNode(in_process=True, context=rclpy_context)
    taken = []
    inputs = estimator.runner.inputs
    estimator.runner.inputs = lambda *args: (taken.append(args[-1]), inputs(*args))
    try:
        t0 = estimator._now()
        for stamp, valve, age in ((t0, 0, math.inf), (t0 + 0.1, 1, 0.04)):
            estimator.take_report(messages.controller_report(ControllerStatus(
                header=_header(stamp_msg(stamp), ""), valve_states=[valve],
                regulator_command_gauge_pressure_pa=30e3, regulator_enabled=True,
                output_change_age_s=age)))
        estimator._on_timer()  # in process, its timer takes them
        assert taken == [pytest.approx(t0, abs=1e-6), pytest.approx(t0 + 0.06, abs=1e-6)]
    finally:
        estimator.close()
        estimator.destroy_node()


def test_an_in_process_status_leaves_the_work_to_the_estimators_own_threads(rclpy_context):
    """The composed controller calls take_report from its control loop: it returns at once, even
    while a batch of readings holds the estimator's lock, and the readings that come next take
    its inputs first (a rewind in the loop's thread held the loop up past the valves' lifetime:
    17-29 lapses in two idle grasps)."""
    import threading
    from softgrip_interfaces.msg import ControllerStatus
    from softgrip_ros.nodes.common import stamp_msg
    from softgrip_ros.nodes.estimator import EstimatorNode
    estimator = EstimatorNode(in_process=True, context=rclpy_context)
    try:
        t0 = estimator._now()
        estimator.take_readings([("chamber_a", 0.0, t0), ("chamber_b", 0.0, t0)])
        status = messages.controller_report(ControllerStatus(
            header=_header(stamp_msg(t0 + 0.01), ""), valve_states=[1],
            regulator_command_gauge_pressure_pa=30e3, regulator_enabled=True,
            output_change_age_s=0.0))
        with estimator._lock:  # a batch being fused
            caller = threading.Thread(target=estimator.take_report, args=(status,))
            caller.start()
            caller.join(timeout=5.0)
            assert not caller.is_alive()
        assert estimator.estimator.inputs.valves == (Valve.CLOSED,)
        estimator.take_readings([("chamber_a", 0.0, t0 + 0.02)])
        assert estimator.estimator.inputs.valves == (Valve.SUPPLY,)
        assert estimator.estimator.inputs.regulator_setpoint_gauge_pa == 30e3
    finally:
        estimator.close()
        estimator.destroy_node()


def test_silent_sensors_give_predictions_with_growing_variance_and_a_warning(wired):
    from diagnostic_msgs.msg import DiagnosticStatus
    feeder, publishers, status_pub, estimates, diagnostics = wired
    rng = np.random.default_rng(1)
    _feed(feeder, publishers, ("chamber_a", "chamber_b"), 5e3, 0.5, rng)
    fused_variance = estimates[-1].variance
    count = len(estimates)
    wait_for(lambda: len(estimates) > count + 50, message="predictions while silent")
    assert estimates[-1].variance > fused_variance
    wait_for(
        lambda: any(d.level == DiagnosticStatus.WARN and "all sensors silent" in d.message
                    for d in diagnostics[-3:]), message="a WARN while every sensor is silent")
    _feed(feeder, publishers, ("chamber_b",), 5e3, 0.5, rng)
    wait_for(
        lambda: any(d.level == DiagnosticStatus.WARN and "sensors silent: chamber_a" in d.message
                    for d in diagnostics[-3:]), message="a WARN naming the lost sensor")


def test_silent_sensors_are_reported_while_the_controller_status_keeps_coming(wired):
    """The report judges silence at the last controller/status (a stalled host is no silence of
    the sensors), so with the status flowing a silent bus is still named."""
    import time
    from diagnostic_msgs.msg import DiagnosticStatus
    from softgrip_interfaces.msg import ControllerStatus
    feeder, publishers, status_pub, estimates, diagnostics = wired
    rng = np.random.default_rng(2)
    _feed(feeder, publishers, ("chamber_a", "chamber_b"), 5e3, 0.5, rng)

    def warned():
        return any(d.level == DiagnosticStatus.WARN and "all sensors silent" in d.message
                   for d in diagnostics[-3:])

    end = time.monotonic() + 10.0
    while time.monotonic() < end and not warned():
        status_pub.publish(
            ControllerStatus(header=_header(feeder.get_clock().now().to_msg(), ""),
                             valve_states=[0], regulator_enabled=True))
        time.sleep(0.02)
    assert warned(), [d.message for d in diagnostics[-3:]]


@pytest.mark.parametrize("argument, message", [
    ("filter_type:=particle", "must be one of ['kf', 'ekf', 'ukf']"),
    ("process_noise_covariance:=[1.0,2.0,3.0]", "process noise needs 2 values"),
    ("sensors.rejection_threshold:=[16.0]", "one entry per sensor"),
    ("plant_file:=/nonexistent/plant.yaml", "the plant file /nonexistent/plant.yaml: cannot read"),
    ("sensors.names:=[chamber_a,chamber_c]", "sensor 'chamber_c' is not in the plant file"),
    ("rest_frequency:=500.0", "rest_frequency (500 Hz) must not exceed frequency (200 Hz)"),
    ("fusion_window:=0.05", "fusion_window"),
])
def test_bad_startup_parameter_exits_1_with_its_reason(argument, message):
    run = subprocess.run([installed_executable("estimator"), "--ros-args", "-p", argument],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 1, run.stderr
    assert message in run.stderr
    assert "Traceback" not in run.stderr


def test_messages_stamped_far_ahead_are_ignored_and_the_estimates_go_on(wired):
    """#20.5: one sample stamped an hour ahead would move the filter there, after which every real
    sample is "late" and dropped: the estimator froze. Now it is ignored, counted and reported."""
    from sensor_msgs.msg import FluidPressure
    from softgrip_ros.nodes.common import stamp_msg
    feeder, publishers, status_pub, estimates, diagnostics = wired
    rng = np.random.default_rng(2)
    _feed(feeder, publishers, ("chamber_a", "chamber_b"), 5e3, 0.3, rng)
    ahead = stamp_msg(feeder.get_clock().now().nanoseconds * 1e-9 + 3600.0)
    publishers["chamber_a"].publish(
        FluidPressure(fluid_pressure=P_ATM_PA + 5e3, variance=9e4, header=_header(ahead, "a")))
    count = len(estimates)
    _feed(feeder, publishers, ("chamber_a", "chamber_b"), 5e3, 0.5, rng)
    assert len(estimates) - count > 5
    assert all(m.header.stamp.sec < ahead.sec - 1000 for m in estimates[count:])
    wait_for(lambda: any("in the future" in d.message for d in diagnostics),
             message="the refusal reported")


def test_the_nis_evidence_is_published_typed_for_a_lone_pressure_controller(wired):
    from softgrip_interfaces.msg import EstimatorConsistency
    feeder, publishers, _, _, _ = wired
    evidence = []
    feeder.create_subscription(EstimatorConsistency, "estimator/consistency", evidence.append, 10)
    _feed(feeder, publishers, ("chamber_a", "chamber_b"), 0.0, 1.5, np.random.default_rng(5))
    wait_for(lambda: evidence, message="estimator/consistency")
    last = evidence[-1]
    assert sorted(last.sensor_names) == ["chamber_a", "chamber_b"]
    assert len(last.mean_nis) == 2 and last.nis_upper_bound > 1.0
    # consistent noise: each sensor's windowed NIS well under its bound
    assert all(0.0 < nis < last.nis_upper_bound for nis in last.mean_nis), last
