"""The runtime core of the composed controller: the typed values its parts pass one another, the
ports they pass them through, and the one place those ports are wired. ROS-free.

The parts are the pressure controller (CAN reception, safety, control, CAN send), the estimator,
the kinematics and the grasp manager. Each part has output :class:`Port` s and input methods:

==================  ========================  ==========================================
part                emits (port: value)       takes (method: value)
==================  ========================  ==========================================
pressure            readings: [Reading]       take_order(PressureOrder)
                    reports: ControllerReport take_consistency(Consistency)
estimator           estimates: Estimate       take_readings([Reading]),
                    consistency: Consistency  take_report(ControllerReport),
                                              take_order(PressureOrder)
kinematics          (ROS topics only)         take_estimate(Estimate), take_scene(Scene)
grasp manager       orders: PressureOrder     take_readings([Reading]),
                    scenes: Scene             take_estimate(Estimate),
                                              take_report(ControllerReport)
==================  ========================  ==========================================

:func:`wire` connects them, once. A node running alone carries the same values over its topics
(nodes.messages converts them), so each part behaves alike composed or alone.
"""
from __future__ import annotations

from typing import Callable, Generic, NamedTuple, TypeVar

from softgrip_ros.control.pressure import Source

T = TypeVar("T")


class Reading(NamedTuple):
    """One valid sensor reading: gauge Pa, stamped (ROS time, s) when the device measured it."""

    sensor: str
    gauge_pa: float
    stamp_s: float


class Estimate(NamedTuple):
    """The chamber pressure estimate at ``stamp_s`` (ROS time, s): gauge Pa, variance Pa^2."""

    stamp_s: float
    gauge_pa: float
    variance_pa2: float


class Consistency(NamedTuple):
    """The estimator's evidence on a sensor: its windowed mean NIS and the bound a consistent
    sensor stays under."""

    sensor: str
    mean_nis: float
    bound: float


class PressureOrder(NamedTuple):
    """A pressure command: the target (gauge Pa; ignored for VENT and HOLD), its source, a slew
    limit (Pa/s; NaN: the controller's default) and its stamp (ROS time, s; 0: unstamped)."""

    target_gauge_pa: float
    source: Source
    max_rate_pa_per_s: float
    stamp_s: float


class ControllerReport(NamedTuple):
    """What the pressure controller's status tells the other parts (controller/status carries it
    and more). Times: ROS time, s; pressures gauge Pa; ``valve``: the first channel's
    model.pneumatics.Valve."""

    stamp_s: float
    outputs_changed_s: float  # when its regulator command and valves went out
    fault_flags: int
    measured_gauge_pa: float
    regulator_command_gauge_pa: float
    regulator_enabled: bool
    valve: int
    message: str


class Port(Generic[T]):
    """One output of a part. Each value emitted goes to every connected handler, in the order
    connected, in the emitting thread; a handler that raises does not starve the ones after it,
    and the first error is raised once all have run (for the emitter to count and report)."""

    __slots__ = ("name", "_handlers")

    def __init__(self, name: str):
        self.name = name
        self._handlers: tuple = ()

    def connect(self, handler: Callable[[T], None]) -> None:
        self._handlers = (*self._handlers, handler)

    @property
    def connected(self) -> bool:
        return bool(self._handlers)

    def emit(self, value: T) -> None:
        first = None
        for handler in self._handlers:
            try:
                handler(value)
            except Exception as error:
                first = first or error
        if first is not None:
            raise first


def wire(pressure, estimator, kinematics, grasp) -> None:
    """Connect the composed controller's parts (see the module's table), once. The busy links
    run in the emitter's thread: each reading batch from the CAN reception to the estimator and
    the grasp manager; each estimate to the kinematics and the grasp manager; each order from the
    grasp manager to the pressure controller (which steps and sends at once) and the estimator."""
    pressure.readings.connect(estimator.take_readings)
    pressure.readings.connect(grasp.take_readings)
    pressure.reports.connect(estimator.take_report)
    pressure.reports.connect(grasp.take_report)
    estimator.estimates.connect(kinematics.take_estimate)
    estimator.estimates.connect(grasp.take_estimate)
    estimator.consistency.connect(pressure.take_consistency)
    grasp.orders.connect(pressure.take_order)
    grasp.orders.connect(estimator.take_order)
    grasp.scenes.connect(kinematics.take_scene)
