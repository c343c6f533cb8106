"""The single-fault matrix in its quick form (#20): every simulated fault once, its phase rotating
through the six grasp phases, on the composed suite over DDS, then fault-free grasps.
``python scripts/bench_faults.py`` runs all 17 x 6 and writes docs/benchmarks.md."""
import json
import pathlib
import subprocess
import sys

import pytest

from softgrip_ros.devtools.fault_matrix import (FAULTS, PHASES, DeviceApart, FaultFreeRound,
                                                fault_free_grasps)

REPO_ROOT = pathlib.Path(__file__).resolve().parents[1]
pytestmark = [pytest.mark.ros, pytest.mark.slow]


@pytest.fixture(scope="module")
def quick_matrix():
    # a case that fails with the pressure inside the limits runs once more: on this shared
    # 2-core host the suite's process (controller and judge) rarely mistimes a recovery grasp;
    # the retries are reported, and a limit violation is never retried. So do the fault-free
    # grasps when they warned while the control loop was held up past the valves' lifetime (CI:
    # 3 lapses and "no valid pressure reading" in 2 grasps; during this matrix here the
    # hypervisor took up to 0.41 of a CPU in 2 s windows); a warning with the loop on time is
    # not
    result = subprocess.run([sys.executable, "scripts/bench_faults.py", "--quick", "--json",
                             "--retries", "1"], cwd=REPO_ROOT, capture_output=True, text=True,
                            timeout=1200)
    assert "Traceback" not in result.stderr, result.stderr[-3000:]
    return result.returncode, json.loads(result.stdout), result.stderr


def test_no_fault_takes_the_true_pressure_past_its_limits(quick_matrix):
    _, figures, log = quick_matrix
    assert figures["cases"] == len(FAULTS)
    assert figures["limit_violations"] == 0, log[-3000:]
    low, high = figures["true_range_pa"]
    assert -65e3 <= low and high <= 55e3


def test_every_fault_is_named_ends_in_its_documented_state_and_a_new_grasp_works(quick_matrix):
    returncode, figures, log = quick_matrix
    assert figures["failures"] == [], log[-3000:]
    assert len(figures["retried"]) <= 2, figures["retried"]  # rare, not a pattern
    assert figures["undetected"] == figures["wrong_end_state"] == figures["not_recovered"] == 0
    assert set(figures["detection_s"]) == {case.name for case in FAULTS}
    assert returncode == 0


def test_fault_free_grasps_raise_no_warning(quick_matrix):
    _, figures, _ = quick_matrix
    assert figures["fault_free_grasps"] == 2
    assert figures["false_alarms_fault_free"] == 0, "\n".join(figures["fault_free_warnings"])


def test_the_quick_matrix_covers_every_fault_and_every_phase(quick_matrix):
    _, figures, _ = quick_matrix
    assert {fault for fault, _ in figures["case_list"]} == {case.name for case in FAULTS}
    assert {phase for _, phase in figures["case_list"]} == set(PHASES)


def _scripted_rounds(*rounds):
    """A stand-in for false_alarms: each call returns the next round; the calls are counted."""
    calls = []

    def run(rig, grasps):
        calls.append(grasps)
        return rounds[len(calls) - 1]
    return run, calls


def test_fault_free_grasps_run_once_more_only_when_the_control_loop_was_held_up():
    stalled = FaultFreeRound(1, ["valve lifetime lapses during the grasps: 3",
                                 "softgrip: pressure controller: no valid pressure reading"], 3)
    run, calls = _scripted_rounds(stalled, FaultFreeRound(0, [], 0))
    found, retried = fault_free_grasps(None, 2, retries=1, run=run)
    assert calls == [2, 2] and found.warnings == 0
    assert [r["fault"] for r in retried] == ["fault-free grasps"]
    assert "lapses during the grasps: 3" in retried[0]["problem"]


def test_a_fault_free_warning_with_the_control_loop_on_time_is_never_run_again():
    warned = FaultFreeRound(1, ["softgrip: estimator: chamber_b: mean NIS 2.37 above 1.36"], 0)
    run, calls = _scripted_rounds(warned, FaultFreeRound(0, [], 0))
    found, retried = fault_free_grasps(None, 2, retries=3, run=run)
    assert calls == [2] and found is warned and retried == []


def test_fault_free_retries_stop_at_their_number_and_keep_the_last_round():
    stalled = [FaultFreeRound(1, [f"round {i}"], 2) for i in range(3)]
    run, calls = _scripted_rounds(*stalled)
    found, retried = fault_free_grasps(None, 2, retries=2, run=run)
    assert len(calls) == 3 and len(retried) == 2 and found is stalled[2]
    assert fault_free_grasps(None, 0, retries=2, run=run)[0].warnings == 0 and len(calls) == 3


def test_the_rigs_device_runs_in_a_process_of_its_own_and_answers_the_matrix():
    """The matrix's device sends on its softgrip_ipc bus from another process; a fault set there
    acts (bus_silent: nothing more comes), its valves and truth are read back, and closing it
    ends that process."""
    import time
    import uuid

    import can

    from softgrip_ros.canbus.codec import FrameCodec
    from softgrip_ros.model.pneumatics import Valve

    channel = f"faults-test-{uuid.uuid4().hex[:8]}"
    device = DeviceApart(channel)
    bus = can.Bus(interface="softgrip_ipc", channel=channel)
    codec = FrameCodec()
    try:
        sensor_ids = {codec.frame_ids[name] for name in ("PressureSensor1", "PressureSensor2")}

        def sensor_frames(seconds):
            count, end = 0, time.monotonic() + seconds
            while time.monotonic() < end:
                frame = bus.recv(0.05)
                count += frame is not None and frame.arbitration_id in sensor_ids
            return count

        assert sensor_frames(0.5) > 100  # 500 + 200 Hz
        assert device.valves() == (Valve.CLOSED,) and not device.regulator_enabled()
        low, high = device.true_extremes()
        assert -2e3 < low <= high < 2e3  # at rest, near atmosphere
        device.set_fault("bus_silent", True)
        sensor_frames(0.1)  # those already under way
        assert sensor_frames(0.3) == 0
        with pytest.raises(ValueError):
            device.set_fault("no_such_fault", True)
    finally:
        bus.shutdown()
        device.close()
    children = list(device._worker._children)
    assert children and not any(child.is_alive() for child in children)
