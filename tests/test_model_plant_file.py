"""config/plant.yaml, the one description of the pneumatics: its format, its checks, and the
per-path critical ratios and two-sided compliance it describes."""
import dataclasses
import pathlib

import numpy as np
import pytest
import yaml

from softgrip_ros.canbus.sim_device import DEFAULT_SENSORS
from softgrip_ros.model import plant_file
from softgrip_ros.model.pneumatics import P_ATM_PA, PneumaticParameters, PneumaticPlant, Valve

pytestmark = pytest.mark.cpu  # computation only: scripts/test.sh runs it beside another

REPO_ROOT = pathlib.Path(__file__).resolve().parents[1]
SHIPPED = REPO_ROOT / "config" / "plant.yaml"


def test_the_shipped_file_holds_the_built_in_assumptions():
    description = plant_file.load(SHIPPED)
    assert description.parameters == PneumaticParameters()
    assert {s.name: s.noise_std_pa for s in DEFAULT_SENSORS} == {
        name: model.noise_std_pa for name, model in description.sensors.items()}
    assert all(model.bias_pa == 0.0 for model in description.sensors.values())
    assert description.provenance["source"] == "assumed"


def test_a_written_file_reads_back_with_its_provenance_and_intervals(tmp_path):
    parameters = dataclasses.replace(PneumaticParameters(), supply_conductance=1.23e-9,
                                     vent_critical_ratio=0.41)
    written = plant_file.PlantDescription(
        parameters, {"chamber_a": plant_file.SensorModel(250.0, 1200.0)},
        {"source": "identified", "date": "2026-12-02", "tool": "softgrip_identify"},
        {"supply_conductance": {"source": "identified", "ci95": [1.2e-9, 1.26e-9]},
         "chamber_a.bias_pa": {"source": "identified", "ci95": [1150.0, 1250.0]}})
    path = plant_file.save(written, tmp_path / "mine.yaml", header="my gripper")
    assert path.read_text().startswith("# my gripper\n")
    read = plant_file.load(path)
    assert read.parameters == parameters and read.sensors == written.sensors
    assert read.provenance == written.provenance
    assert read.details["supply_conductance"]["ci95"] == [1.2e-9, 1.26e-9]
    assert read.details["chamber_a.bias_pa"]["source"] == "identified"
    assert read.details["vent_conductance"]["source"] == "assumed"


def _edited(tmp_path, edit):
    document = yaml.safe_load(SHIPPED.read_text())
    edit(document)
    path = tmp_path / "edited.yaml"
    path.write_text(yaml.safe_dump(document))
    return path


@pytest.mark.parametrize("edit, message", [
    (lambda d: d["parameters"]["chamber_volume_m3"].update(unit="mL"),
     "chamber_volume_m3: the unit is m\\^3"),
    (lambda d: d["parameters"]["supply_conductance"].update(value=1.0),
     "supply_conductance: 1 m\\^3/\\(s Pa\\) lies outside"),
    (lambda d: d["parameters"].pop("vent_critical_ratio"), "missing \\['vent_critical_ratio'\\]"),
    (lambda d: d["parameters"].update(leak_conductance={"value": 1e-12}),
     "unknown \\['leak_conductance'\\]"),
    (lambda d: d["sensors"]["chamber_a"].pop("bias_pa"), "sensors.chamber_a needs exactly"),
    (lambda d: d.update(format="softgrip_plant/0"), "format must be"),
    (lambda d: d["parameters"]["regulator_time_constant_s"].update(value="fast"),
     "value must be a number"),
    (lambda d: d["parameters"]["min_chamber_volume_m3"].update(value=1e-4),
     "min_chamber_volume_m3 must be below"),
    (lambda d: d["parameters"]["supply_conductance"].update(source="guessed"),
     "source must be one of"),
])
def test_a_bad_file_is_refused_with_the_value_named(tmp_path, edit, message):
    with pytest.raises(ValueError, match=message):
        plant_file.load(_edited(tmp_path, edit))


def test_a_missing_or_broken_file_says_so(tmp_path):
    with pytest.raises(ValueError, match="the plant file .*absent.yaml: cannot read"):
        plant_file.load(tmp_path / "absent.yaml")
    broken = tmp_path / "broken.yaml"
    broken.write_text("parameters: [unclosed")
    with pytest.raises(ValueError, match=r"broken.yaml: not YAML: .* at line \d+, column \d+$"):
        plant_file.load(broken)
    with pytest.raises(ValueError, match="sensor 'chamber_c' is not in the plant file"):
        plant_file.load(SHIPPED).sensor("chamber_c")


def test_each_path_has_its_own_critical_ratio():
    """A vent path choked further (a larger b) drains faster near the end, and changes nothing on
    the supply path."""
    base = PneumaticPlant()
    vent_b = PneumaticPlant(dataclasses.replace(PneumaticParameters(), vent_critical_ratio=0.6))
    chamber = P_ATM_PA + 30e3
    assert vent_b.chamber_rate(chamber, Valve.VENT, 0.0) < base.chamber_rate(
        chamber, Valve.VENT, 0.0) < 0.0
    assert vent_b.chamber_rate(P_ATM_PA, Valve.SUPPLY, 30e3) == base.chamber_rate(
        P_ATM_PA, Valve.SUPPLY, 30e3)


def test_the_vacuum_side_has_its_own_compliance():
    stiff_vacuum = PneumaticPlant(dataclasses.replace(PneumaticParameters(),
                                                      vacuum_compliance_m3_per_pa=0.0))
    base = PneumaticPlant()
    above, below = P_ATM_PA + 20e3, P_ATM_PA - 20e3
    assert stiff_vacuum.capacitance(above) == base.capacitance(above)
    assert stiff_vacuum.capacitance(below) == pytest.approx(20e-6)  # V0 alone: no swelling term
    assert base.capacitance(below) > stiff_vacuum.capacitance(below)
    # the implicit step and the vectorised capacitance agree on it
    rate = stiff_vacuum.chamber_rate(below, Valve.VACUUM, 0.0)
    capacitance = stiff_vacuum.capacitance(np.array([below]))[0]
    flow = stiff_vacuum.chamber_mass_flow(below, Valve.VACUUM, 0.0)
    assert rate == pytest.approx(stiff_vacuum.parameters.gas_constant_times_temperature * flow /
                                 capacitance, rel=1e-9)
