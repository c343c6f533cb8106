"""pytest configuration shared by every softgrip_ros test.

Network rule: every process that starts rclpy here keeps DDS on loopback
(``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``) and this session gets its own
``ROS_DOMAIN_ID``, so parallel runs on one machine do not cross-talk. Both are
set in ``os.environ`` before anything imports rclpy, and subprocesses inherit them, as they
inherit config/fastdds_tests.xml (Fast DDS's library settings for many participants in one
process).
"""
import os
import pathlib
import random
import threading

import pytest

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
if "SOFTGRIP_TEST_DOMAIN_ID" in os.environ:
    os.environ["ROS_DOMAIN_ID"] = os.environ["SOFTGRIP_TEST_DOMAIN_ID"]
else:
    # 1..100 stays inside the port range every RMW accepts on Linux; pytest-xdist's workers
    # (scripts/test.sh runs the tests marked cpu two at a time) take neighbouring domains
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    seed = os.getppid() if worker else os.getpid()
    offset = int(worker[2:]) if worker.startswith("gw") and worker[2:].isdigit() else 0
    os.environ["ROS_DOMAIN_ID"] = str((random.Random(seed).randint(0, 99) + offset) % 100 + 1)
os.environ.setdefault("MPLBACKEND", "Agg")
# Discovery between this process's DDS participants (one per rclpy context) through the
# transport: in-process, Fast DDS 2.14 can deadlock destroying a publisher (see the file)
FAST_DDS_PROFILE = pathlib.Path(__file__).resolve().parents[1] / "config" / "fastdds_tests.xml"
os.environ.setdefault("FASTRTPS_DEFAULT_PROFILES_FILE", str(FAST_DDS_PROFILE))


@pytest.fixture
def rclpy_context():
    """A fresh rclpy context, shut down afterwards; fails the test if threads leak."""
    import rclpy

    threads_before = set(threading.enumerate())
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)
    leaked = [t for t in threading.enumerate() if t not in threads_before and t.is_alive()]
    for thread in leaked:
        thread.join(timeout=2.0)
    leaked = [t for t in leaked if t.is_alive()]
    assert not leaked, f"threads leaked by the test: {[t.name for t in leaked]}"


@pytest.fixture
def ros_node(rclpy_context, request):
    """A node on the fresh context, destroyed afterwards."""
    import rclpy.node

    node = rclpy.node.Node(
        f"test_{request.node.name[:40].replace('[', '_').replace(']', '_')}".replace(
            "-", "_").replace(".", "_"), context=rclpy_context)
    try:
        yield node
    finally:
        node.destroy_node()


def pytest_collection_modifyitems(config, items):
    """A test marked cpu runs beside another one (scripts/test.sh): it may not also start rclpy
    or depend on timing, so cpu and ros together are a mistake in the marks."""
    both = [item.nodeid for item in items
            if item.get_closest_marker("cpu") and item.get_closest_marker("ros")]
    if both:
        raise pytest.UsageError(f"marked both cpu and ros: {', '.join(both)}")
