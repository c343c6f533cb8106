"""The simulated device with a physics world: the plant and the world step together, and the
chamber's air follows the fingers' bending in the world (softgrip_ros.canbus.sim_device)."""
import can
import numpy as np
import pytest

from softgrip_ros.canbus.sim_device import SimDeviceConfig, SimulatedDevice
from softgrip_ros.model import gripper_models
from softgrip_ros.model.pneumatics import P_ATM_PA, PlantInputs, Valve
from softgrip_ros.model.world.fingers import PseudoRigidFinger
from softgrip_ros.model.world.scene import scene_from_document
from softgrip_ros.model.world.world import GripperWorld

pytestmark = pytest.mark.cpu  # computation only: scripts/test.sh runs it beside another

FINGER = PseudoRigidFinger(*gripper_models.resolve("type_II"), bending="l0")
# a fill, a hold, a vent, an evacuation, a vent: (valve, regulator setpoint, seconds)
PROGRAM = ((Valve.SUPPLY, 40e3, 0.6), (Valve.CLOSED, 40e3, 0.2), (Valve.VENT, 0.0, 0.5),
           (Valve.VACUUM, 0.0, 0.6), (Valve.VENT, 0.0, 0.5))


@pytest.fixture
def bus():
    bus = can.Bus(interface="virtual", channel="world_coupling")
    yield bus
    bus.shutdown()


def device(bus, scene_document=None, fingers_collide=True):
    world = None
    if scene_document is not None:
        world = GripperWorld(scene_from_document(scene_document), FINGER,
                             fingers_collide=fingers_collide)
    simulated = SimulatedDevice(bus, SimDeviceConfig(seed=1), world=world)
    simulated._started_at = simulated._last_tick = 0.0
    return simulated


def run(simulated, program=PROGRAM, step_s=1e-3):
    """The true chamber gauge pressure every step of ``program``, the device stepped in its
    plant's time as its thread does (spans of ``step_s``), with no bus traffic."""
    trace, now = [], 0.0
    for valve, setpoint, seconds in program:
        simulated._inputs = PlantInputs(regulator_setpoint_gauge_pa=setpoint,
                                        regulator_enabled=True, valves=(valve,))
        simulated._valves_open_until = np.inf
        for _ in range(round(seconds / step_s)):
            simulated._last_valve_command = now
            simulated._advance(step_s, now + step_s)
            now += step_s
            simulated._last_tick = now
            trace.append(simulated._state.chamber_pa[0] - P_ATM_PA)
    return np.array(trace)


FREE = {"name": "free", "arm": {"start_m": [0, 0, 0.3]}}


def test_free_fingers_leave_the_pressure_response_as_it_was(bus):
    """No object and the fingers passing each other: the world's volume offset stays 0, and the
    chamber's pressure is today's to the last bit."""
    without = run(device(bus))
    free = device(bus, FREE, fingers_collide=False)
    with_world = run(free)
    assert np.array_equal(without, with_world)
    assert free.world.time_s == pytest.approx(sum(s for _, _, s in PROGRAM), abs=1e-3)


def test_fingers_held_back_hold_less_air_and_fill_faster(bus):
    """A fixed post outside the left finger's last chamber stops its opening: it holds less air,
    and cannot swell by bending, so the same fill reaches 30 kPa sooner than free fingers."""
    chain = FINGER.planar_chain(np.zeros(FINGER.hinge_count))
    end, heading = chain["backbone"][-2], FINGER.geometry.inclination_rad
    centre = end + 0.0055 * np.array([-np.cos(heading), np.sin(heading)])
    posts = dict(FREE, floor=False, object={
        "shape": "cylinder", "diameter_m": 0.01, "mass_kg": 0.05, "friction": 0.5,
        "fixed": True, "position_m": [float(centre[0]), 0.0, 0.3 - float(centre[1])]})
    program = ((Valve.SUPPLY, 40e3, 0.4),)
    free = run(device(bus, FREE, fingers_collide=False), program)
    blocked_device = device(bus, posts)
    blocked = run(blocked_device, program)
    assert blocked_device.world.truth().touching[0]
    assert blocked_device.world.volume_offset_m3() < -0.05e-6
    reach = [int(np.argmax(trace > 30e3)) for trace in (free, blocked)]
    assert reach[1] < reach[0], reach


def test_fingers_pressed_together_under_vacuum_hold_more_air(bus):
    """Below the tips' contact the fingers press on each other: the chambers cannot shrink by
    bending as free ones do, so they hold more air, and (being stiffer) reach -30 kPa sooner."""
    program = ((Valve.VACUUM, 0.0, 0.3),)
    apart = run(device(bus, FREE, fingers_collide=False), program)
    touching_device = device(bus, FREE)
    touching = run(touching_device, program)
    assert touching_device.world.volume_offset_m3() > 0.3e-6
    reach = [int(np.argmax(trace < -30e3)) for trace in (apart, touching)]
    assert reach[1] < reach[0], reach
