"""The assumptions softgrip_ros.nodes.rclpy_compat makes about the pinned rclpy's private API.

Each test names what the workaround relies on. One that fails after an rclpy upgrade says the
workaround must change (or, where rclpy fixed the cause, can go)."""
import threading
import time
import types
from concurrent.futures import ThreadPoolExecutor

import pytest

pytestmark = pytest.mark.ros


def test_rcl_error_is_what_a_publish_raises_once_the_context_is_shut_down():
    import rclpy
    from std_msgs.msg import String

    from softgrip_ros.nodes.rclpy_compat import RCLError
    assert issubclass(RCLError, Exception)
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("compat_publish_after_shutdown", context=context)
    publisher = node.create_publisher(String, "compat_chatter", 1)
    rclpy.shutdown(context=context)
    try:
        with pytest.raises(RCLError):
            publisher.publish(String(data="after shutdown"))
    finally:
        node.destroy_node()


def test_multithreaded_executor_shutdown_leaves_its_pool_running_which_the_compat_shutdown_ends(
        rclpy_context):
    from rclpy.executors import MultiThreadedExecutor

    from softgrip_ros.nodes.rclpy_compat import shutdown_executor
    executor = MultiThreadedExecutor(num_threads=2, context=rclpy_context)
    assert isinstance(executor._executor, ThreadPoolExecutor)
    assert isinstance(executor._futures, list)
    executor._executor.submit(lambda: None).result()  # start a worker thread
    executor.shutdown(timeout_sec=1.0)
    # the reason for the workaround: the pool still takes work after Executor.shutdown()
    assert executor._executor.submit(lambda: 42).result(timeout=2.0) == 42
    workers = [t for t in threading.enumerate() if t.name.startswith("ThreadPoolExecutor")]
    assert workers
    shutdown_executor(executor, timeout_sec=1.0)
    with pytest.raises(RuntimeError, match="shutdown"):
        executor._executor.submit(lambda: None)
    deadline = time.monotonic() + 2.0
    while any(t.is_alive() for t in workers) and time.monotonic() < deadline:
        time.sleep(0.01)
    assert not any(t.is_alive() for t in workers)


def test_the_executor_keeps_its_started_tasks_in_futures(rclpy_context):
    """shutdown_executor reads errors from ``_futures``: it must hold the tasks spin_once ran."""
    from rclpy.executors import MultiThreadedExecutor

    from softgrip_ros.nodes.rclpy_compat import shutdown_executor
    node = __import__("rclpy").create_node("compat_futures", context=rclpy_context)
    ran = threading.Event()
    node.create_timer(0.001, ran.set)
    executor = MultiThreadedExecutor(num_threads=2, context=rclpy_context)
    executor.add_node(node)
    try:
        deadline = time.monotonic() + 5.0
        while not executor._futures and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        assert executor._futures, "spin_once ran a timer but left no task in _futures"
        assert all(
            hasattr(task, "exception") and hasattr(task, "done") for task in executor._futures)
        # the task runs on the executor's pool: on a starved host it had not yet when the
        # shutdown came (a fresh-clone CI run here), and the shutdown does not wait for it
        assert ran.wait(timeout=5.0)
    finally:
        shutdown_executor(executor, timeout_sec=1.0)
        node.destroy_node()


def test_shutdown_reads_the_errors_of_callbacks_it_cut_short_and_reports_any_other(capsys):
    """A handle destroyed under a running callback is expected and dropped (else rclpy prints
    "exception never retrieved" at exit); any other error is reported on stderr."""
    from rclpy.exceptions import InvalidHandle
    from rclpy.task import Future

    from softgrip_ros.nodes.rclpy_compat import read_errors_of_unfinished_callbacks
    cut_short, failed, finished, running = Future(), Future(), Future(), Future()
    cut_short.set_exception(
        InvalidHandle("cannot use Destroyable because destruction was requested"))
    failed.set_exception(ValueError("boom"))
    finished.set_result(1)
    read_errors_of_unfinished_callbacks(
        types.SimpleNamespace(_futures=[cut_short, failed, finished, running]))
    assert cut_short._exception_fetched and failed._exception_fetched
    err = capsys.readouterr().err
    assert "ValueError: boom" in err and "Destroyable" not in err



def test_the_suites_fast_dds_profile_is_read_without_an_error(tmp_path):
    """config/fastdds_tests.xml (Fast DDS's library settings: discovery between the participants
    of one process through the transport, see that file) parses. A profile Fast DDS rejects is
    only logged, and the deadlock it avoids would come back silently; a bad value is logged so."""
    import os
    import subprocess
    import sys

    from tests.conftest import FAST_DDS_PROFILE

    def node_log(profile):  # Fast DDS logs to stdout
        code = ("import rclpy, rclpy.node; rclpy.init(); node = rclpy.node.Node('profile_check');"
                " node.destroy_node(); rclpy.shutdown()")
        result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                                timeout=60,
                                env={**os.environ, "FASTRTPS_DEFAULT_PROFILES_FILE": str(profile)})
        assert result.returncode == 0, result.stderr
        return result.stdout + result.stderr

    assert os.environ["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(FAST_DDS_PROFILE)
    assert "XMLPARSER" not in node_log(FAST_DDS_PROFILE)
    bogus = tmp_path / "bogus.xml"
    bogus.write_text(FAST_DDS_PROFILE.read_text().replace("USER_DATA_ONLY", "NOT_A_SETTING"))
    assert "intraprocess_delivery' with bad content" in node_log(bogus)
