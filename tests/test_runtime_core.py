"""The runtime core's ports and its one wiring, without ROS."""
import math

import pytest

from softgrip_ros.control.pressure import Source
from softgrip_ros.model.fidelity import FREE
from softgrip_ros.runtime.core import (Consistency, ControllerReport, Estimate, Port,
                                       PressureOrder, Reading, wire)


def test_a_port_gives_each_value_to_every_handler_in_order_and_a_failing_one_starves_none():
    port, seen = Port("readings"), []
    assert not port.connected

    def broken(_):
        raise RuntimeError("consumer bug")

    port.connect(lambda value: seen.append(("first", value)))
    port.connect(broken)
    port.connect(lambda value: seen.append(("last", value)))
    with pytest.raises(RuntimeError, match="consumer bug"):
        port.emit(1)
    assert seen == [("first", 1), ("last", 1)] and port.connected


class Part:
    """A stand-in part: every port a real part has, and every input recorded."""

    def __init__(self, *ports):
        self.taken = []
        for name in ports:
            setattr(self, name, Port(name))

    def __getattr__(self, name):
        if name.startswith("take_"):
            return lambda value: self.taken.append((name, value))
        raise AttributeError(name)


def test_wire_connects_each_link_of_the_composed_controller_once():
    pressure = Part("readings", "reports")
    estimator = Part("estimates", "consistency")
    kinematics = Part()
    grasp = Part("orders", "scenes")
    wire(pressure, estimator, kinematics, grasp)
    readings = [Reading("chamber_a", 1e3, 10.0)]
    report = ControllerReport(10.0, 9.99, 0, 1e3, 2e3, True, 1, "")
    estimate = Estimate(10.0, 1e3, 100.0)
    evidence = Consistency("chamber_a", 1.2, 1.36)
    order = PressureOrder(20e3, Source.SUPPLY, math.nan, 10.0)
    pressure.readings.emit(readings)
    pressure.reports.emit(report)
    estimator.estimates.emit(estimate)
    estimator.consistency.emit(evidence)
    grasp.orders.emit(order)
    grasp.scenes.emit(FREE)
    assert pressure.taken == [("take_consistency", evidence), ("take_order", order)]
    assert estimator.taken == [("take_readings", readings), ("take_report", report),
                               ("take_order", order)]
    assert kinematics.taken == [("take_estimate", estimate), ("take_scene", FREE)]
    assert grasp.taken == [("take_readings", readings), ("take_report", report),
                           ("take_estimate", estimate)]


def test_the_core_imports_no_ros():
    import subprocess
    import sys
    code = ("import sys, softgrip_ros.runtime.core; "
            "print(sorted(m for m in sys.modules if m.startswith(('rclpy', 'rcl_', 'std_msgs'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


@pytest.mark.parametrize("module, absent", [
    # run alone, the pressure controller needs neither the filter nor scipy (it once imported
    # the estimator's node for a topic's name, and with it filterpy and scipy.stats)
    ("softgrip_ros.nodes.pressure_controller", ("filterpy", "scipy.stats", "matplotlib")),
    # the composed controller's default path: no plotting, no fitting, no FE, no world
    ("softgrip_ros.nodes.controller", ("matplotlib", "softgrip_ros.estimation.identification",
                                       "softgrip_ros.model.fe", "mujoco", "skfem")),
])
def test_a_node_imports_only_what_its_default_path_needs(module, absent):
    import subprocess
    import sys
    code = (f"import sys, {module}; "
            f"print(sorted(m for m in {list(absent)!r} if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
