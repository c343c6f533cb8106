"""realtime: the threads that run the suite's periodic work off the executor."""
import threading

import pytest

from softgrip_ros.realtime import TimerThread, clock_offset_s

from tests.helpers.ros import wait_for


def test_timer_thread_runs_each_callback_and_survives_a_failing_one():
    counts, errors = {"fast": 0, "slow": 0}, []
    timers = TimerThread("test-timers",
                         on_error=lambda name, error: errors.append((name, str(error))))

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
        wait_for(lambda: counts["slow"] >= 3 and counts["fast"] >= 10, timeout=5.0,
                 message="both callbacks")
    finally:
        timers.stop()
    # each on its own period (no timing bound: shared machines)
    assert counts["fast"] > counts["slow"]
    assert errors and errors[0] == ("broken", "callback bug") and timers.errors == len(errors)
    stopped = dict(counts)
    threading.Event().wait(0.05)
    assert counts == stopped  # nothing runs after stop()
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


def test_periodic_thread_slows_down_at_rest_and_wakes_at_once():
    """A step that reports rest gets the rest rate (1 Hz here, against 1 kHz); wake() runs a step
    at once, and a step that no longer rests is back at the full rate."""
    from softgrip_ros.realtime import PeriodicThread
    state = {"resting": True, "steps": 0}

    def step():
        state["steps"] += 1
        return state["resting"]

    loop = PeriodicThread(step, 1000.0, "test-loop", rest_rate_hz=1.0,
                          resting=lambda resting: resting)
    loop.start()
    try:
        wait_for(lambda: state["steps"] >= 1, message="the first step")
        threading.Event().wait(0.2)
        # the next one is a second away
        assert state["steps"] == 1 and loop.rest_ticks == 1
        state["resting"] = False
        loop.wake()
        wait_for(lambda: state["steps"] >= 50, timeout=0.9, message="full rate after wake()")
        state["resting"] = True
        wait_for(lambda: loop.rest_ticks >= 2, message="at rest again")
        resting_at = state["steps"]
        threading.Event().wait(0.2)
        assert state["steps"] == resting_at
    finally:
        loop.stop()
    with pytest.raises(ValueError, match="rest_rate_hz must lie in"):
        PeriodicThread(step, 100.0, "test-loop", rest_rate_hz=200.0, resting=bool)


def test_a_receiving_loop_takes_its_inputs_between_rest_ticks_and_before_each_tick():
    """At rest (1 Hz ticks) ``receive`` runs every receive period (50 ms) in the loop's own
    thread, and before each tick; a wake from within ``receive`` (an input that needs the step)
    runs the tick at once; a failing receive is counted and the loop goes on."""
    from softgrip_ros.realtime import PeriodicThread
    calls, threads = [], set()
    state = {"wake": False, "fail": False}

    def step():
        calls.append("step")
        return True

    def receive():
        calls.append("receive")
        threads.add(threading.current_thread().name)
        if state["fail"]:
            state["fail"] = False
            raise OSError("bus closed")
        if state["wake"]:
            state["wake"] = False
            loop.wake()

    loop = PeriodicThread(step, 1000.0, "test-loop", rest_rate_hz=1.0, resting=bool,
                          receive=receive, receive_period_s=0.05)
    loop.start()
    try:
        wait_for(lambda: loop.ticks >= 1, message="the first step")
        threading.Event().wait(0.5)
        # about 10 receives in 0.5 s at rest, no second tick
        assert loop.ticks == 1 and 5 <= loop.receives <= 12, (loop.ticks, loop.receives)
        assert calls[:2] == ["receive", "step"] and threads == {"test-loop"}
        state["wake"] = True
        wait_for(lambda: loop.ticks >= 2, timeout=0.3, message="a tick at once on the wake")
        state["fail"] = True
        wait_for(lambda: loop.errors == 1, timeout=0.3, message="the failing receive counted")
        receives = loop.receives
        wait_for(lambda: loop.receives >= receives + 2, timeout=0.5, message="receiving on")
        assert "bus closed" in loop.last_error
    finally:
        loop.stop()
    with pytest.raises(ValueError, match="receive_period_s must lie in"):
        PeriodicThread(step, 100.0, "test-loop", receive=receive, receive_period_s=0.0)


def test_a_clock_offset_is_read_between_two_reads_of_the_other_clock_not_across_a_pause():
    """Two clocks read one after the other are an instant apart only while the thread runs: the
    first bracket here spans a 40 ms pause (another thread took the GIL), the second does not,
    and the offset is the second's."""
    link = iter([10.000, 10.040, 10.0401, 10.0402])
    ros = iter([1000.0, 1000.0402])  # ros - link = 990.0 at every instant
    assert clock_offset_s(lambda: next(link), lambda: next(ros)) == pytest.approx(990.0, abs=1e-4)
    # every bracket wide: the narrowest is kept, never more than `attempts` reads
    link = iter([0.0, 0.05, 1.0, 1.03, 2.0, 2.04])
    ros = iter([5.0, 6.03, 7.0])
    assert clock_offset_s(lambda: next(link), lambda: next(ros),
                          attempts=3) == pytest.approx(6.03 - 1.015, abs=1e-9)
