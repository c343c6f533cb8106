"""realtime: the threads that run the suite's periodic work off the executor."""
import threading

import pytest

from softgrip_ros.realtime import TimerThread

from tests.helpers.ros import wait_for


def test_timer_thread_runs_each_callback_and_survives_a_failing_one():
    counts, errors = {"fast": 0, "slow": 0}, []
    timers = TimerThread("test-timers", on_error=lambda name, error: errors.append((name, str(error))))

    def fast():
        counts["fast"] += 1

    def slow():
        counts["slow"] += 1

    def broken():
        raise RuntimeError("callback bug")

    timers.add(0.002, fast)
    timers.add(0.02, slow)
    timers.add(0.005, broken)
    timers.start()
    try:
        wait_for(lambda: counts["slow"] >= 3 and counts["fast"] >= 10, timeout=5.0, message="both callbacks")
    finally:
        timers.stop()
    assert counts["fast"] > counts["slow"]            # each on its own period (no timing bound: shared machines)
    assert errors and errors[0] == ("broken", "callback bug") and timers.errors == len(errors)
    stopped = dict(counts)
    threading.Event().wait(0.05)
    assert counts == stopped                          # nothing runs after stop()
    assert not any(t.name == "test-timers" for t in threading.enumerate())


def test_timer_thread_refuses_a_bad_period_and_late_additions():
    timers = TimerThread("test-timers")
    with pytest.raises(ValueError, match="period_s must be positive"):
        timers.add(0.0, lambda: None)
    timers.add(1.0, lambda: None)
    timers.start()
    try:
        with pytest.raises(RuntimeError, match="before start"):
            timers.add(1.0, lambda: None)
    finally:
        timers.stop()
