"""The plant file (config/plant.yaml): the one description of the pneumatics, read by the
simulated device (unless it is given a truth of its own), the estimator's process model and the
pressure controller's feed-forward, boost ceiling and safety checks; written by
``softgrip_identify``.

Each value carries its unit, its range and where it came from (``source``: assumed, identified
or inherited), and an identified one its 95 % confidence interval::

    parameters:
      supply_conductance: {value: 1.0e-9, unit: m^3/(s Pa), range: [1.0e-12, 1.0e-6],
                           source: identified, ci95: [0.97e-9, 1.03e-9]}
    sensors:
      chamber_a: {noise_std_pa: {value: 300.0, unit: Pa, ...}, bias_pa: {value: 0.0, ...}}
    contact:      # optional: softgrip_identify --known-object-m
      bending_volume_share: {value: 0.2, unit: '1', range: [0.01, 0.95], source: identified, ...}

The units and ranges here are the authority: a file whose unit differs, or whose value lies
outside the range, is refused with the parameter named.
"""
from __future__ import annotations

import dataclasses
import datetime
import math
import pathlib

import yaml

from softgrip_ros.fileio import read_yaml, write_text_atomically
from softgrip_ros.model.pneumatics import PneumaticParameters

FORMAT = "softgrip_plant/1"
SOURCES = ("assumed", "identified", "inherited", "measured")

# name: (unit, low, high, what it is)
PARAMETERS = {
    "chamber_volume_m3": ("m^3", 1e-7, 1e-3, "V0, the air in the channel at 0 Pa gauge"),
    "chamber_compliance_m3_per_pa": ("m^3/Pa", 0.0, 1e-8, "dV/dp above 0 Pa gauge (swelling)"),
    "vacuum_compliance_m3_per_pa": ("m^3/Pa", 0.0, 1e-8, "dV/dp below 0 Pa gauge"),
    "min_chamber_volume_m3": ("m^3", 1e-8, 1e-3, "the volume's floor under vacuum"),
    "supply_conductance": ("m^3/(s Pa)", 1e-12, 1e-6, "C of the supply path (ISO 6358)"),
    "vacuum_conductance": ("m^3/(s Pa)", 1e-12, 1e-6, "C of the vacuum path"),
    "vent_conductance": ("m^3/(s Pa)", 1e-12, 1e-6, "C of the vent path"),
    "supply_critical_ratio": ("1", 0.01, 0.99, "b of the supply path"),
    "vacuum_critical_ratio": ("1", 0.01, 0.99, "b of the vacuum path"),
    "vent_critical_ratio": ("1", 0.01, 0.99, "b of the vent path"),
    "temperature_k": ("K", 200.0, 400.0, "the gas temperature (isothermal)"),
    "supply_gauge_pa": ("Pa", 1e3, 1e6, "the regulator's inlet: its output cannot exceed it"),
    "vacuum_source_gauge_pa": ("Pa", -101e3, -1e3,
                               "the vacuum source's level (an ideal source: its characteristic "
                               "is this level at any flow)"),
    "regulator_time_constant_s": ("s", 1e-4, 10.0, "the regulator's first-order lag"),
    "regulator_rate_limit_pa_per_s": ("Pa/s", 1e3, 1e9, "the regulator's slew limit"),
}
# the fingers' contact, learnt on an object of known size; absent: the model's prediction
CONTACT_FIELDS = {
    "bending_volume_share": ("1", 0.01, 0.95, "the share of the chambers' dV/dp that the "
                             "fingers' bending makes (an object that stops them keeps it)"),
}
SENSOR_FIELDS = {
    "noise_std_pa": ("Pa", 0.0, 1e5, "1-sigma noise of the reading"),
    "bias_pa": ("Pa", -1e5, 1e5, "the reading less the true gauge pressure, on average"),
}


@dataclasses.dataclass(frozen=True)
class SensorModel:
    noise_std_pa: float
    bias_pa: float = 0.0


@dataclasses.dataclass(frozen=True)
class PlantDescription:
    """``parameters`` (the pneumatics), ``sensors`` {name: SensorModel}, ``provenance`` (a dict:
    source, date, by, note...), ``details`` {name: {source, ci95, ...}} per value (the keys
    beside value, unit and range in the file; sensor values as ``<sensor>.<field>``, contact
    values as ``contact.<field>``), ``bending_volume_share`` (dimensionless; None: not identified,
    the grasp sensing uses its model's prediction)."""

    parameters: PneumaticParameters
    sensors: dict
    provenance: dict = dataclasses.field(default_factory=dict)
    details: dict = dataclasses.field(default_factory=dict)
    bending_volume_share: float | None = None

    def sensor(self, name: str) -> SensorModel:
        if name not in self.sensors:
            raise ValueError(f"sensor {name!r} is not in the plant file (it has "
                             f"{sorted(self.sensors)}); add its noise_std_pa and bias_pa")
        return self.sensors[name]


def default_description() -> PlantDescription:
    """The built-in assumptions (PneumaticParameters' defaults, the simulated sensors' noise):
    what config/plant.yaml holds as shipped."""
    return PlantDescription(PneumaticParameters(), {
        "chamber_a": SensorModel(300.0), "chamber_b": SensorModel(150.0)
    }, {"source": "assumed"})


def _value(where: str, entry, spec) -> tuple[float, dict]:
    unit, low, high, _ = spec
    if not isinstance(entry, dict) or "value" not in entry:
        raise ValueError(f"{where}: needs a mapping with 'value' (and 'unit'), got {entry!r}")
    if entry.get("unit", unit) != unit:
        raise ValueError(f"{where}: the unit is {unit}, the file says {entry['unit']!r}")
    try:
        value = float(entry["value"])
    except (TypeError, ValueError):
        raise ValueError(f"{where}: value must be a number, got {entry['value']!r}") from None
    if not (math.isfinite(value) and low <= value <= high):
        raise ValueError(f"{where}: {value:g} {unit} lies outside [{low:g}, {high:g}]")
    source = entry.get("source", "assumed")
    if source not in SOURCES:
        raise ValueError(f"{where}: source must be one of {SOURCES}, got {source!r}")
    extra = {k: v for k, v in entry.items() if k not in ("value", "unit", "range")}
    return value, extra


def parse(document: dict, where: str = "plant file") -> PlantDescription:
    """A PlantDescription from a loaded YAML document; ValueError naming what is wrong."""
    if not isinstance(document, dict):
        raise ValueError(f"{where}: expected a mapping at the top")
    if document.get("format") != FORMAT:
        raise ValueError(f"{where}: format must be {FORMAT!r}, got {document.get('format')!r}")
    unknown = set(document) - {"format", "provenance", "parameters", "sensors", "contact"}
    if unknown:
        raise ValueError(f"{where}: unknown sections {sorted(unknown)}")
    entries = document.get("parameters") or {}
    contact = document.get("contact") or {}
    for section, value in (("parameters", entries), ("sensors", document.get("sensors") or {}),
                           ("provenance", document.get("provenance") or {}),
                           ("contact", contact)):
        if not isinstance(value, dict):
            raise ValueError(f"{where}: {section} must be a mapping, got {value!r}")
    missing = sorted(set(PARAMETERS) - set(entries))
    extra = sorted(set(entries) - set(PARAMETERS))
    if missing or extra:
        raise ValueError(f"{where}: parameters missing {missing}, unknown {extra}")
    values, details = {}, {}
    for name, spec in PARAMETERS.items():
        values[name], details[name] = _value(f"{where}: parameters.{name}", entries[name], spec)
    sensors = {}
    for sensor, fields in (document.get("sensors") or {}).items():
        if not isinstance(fields, dict) or set(fields) != set(SENSOR_FIELDS):
            raise ValueError(f"{where}: sensors.{sensor} needs exactly {sorted(SENSOR_FIELDS)}")
        read = {}
        for field, spec in SENSOR_FIELDS.items():
            read[field], details[f"{sensor}.{field}"] = _value(
                f"{where}: sensors.{sensor}.{field}", fields[field], spec)
        sensors[str(sensor)] = SensorModel(**read)
    unknown = sorted(set(contact) - set(CONTACT_FIELDS))
    if unknown:
        raise ValueError(f"{where}: contact: unknown {unknown}")
    share = None
    if "bending_volume_share" in contact:
        share, details["contact.bending_volume_share"] = _value(
            f"{where}: contact.bending_volume_share", contact["bending_volume_share"],
            CONTACT_FIELDS["bending_volume_share"])
    try:
        parameters = PneumaticParameters(**values)
    except ValueError as error:
        raise ValueError(f"{where}: {error}") from None
    if parameters.min_chamber_volume_m3 >= parameters.chamber_volume_m3:
        raise ValueError(f"{where}: min_chamber_volume_m3 must be below chamber_volume_m3")
    return PlantDescription(parameters, sensors, dict(document.get("provenance") or {}), details,
                            share)


def load(path) -> PlantDescription:
    path = pathlib.Path(path)
    try:
        document = read_yaml(path)
    except ValueError as error:
        raise ValueError(f"the plant file {error}") from None
    return parse(document, str(path))


def _entry(value: float, spec, detail: dict) -> dict:
    unit, low, high, _ = spec
    entry = {"value": float(value), "unit": unit, "range": [low, high]}
    entry.update({k: v for k, v in detail.items() if k not in entry})
    entry.setdefault("source", "assumed")
    return entry


def document(description: PlantDescription) -> dict:
    """The YAML document of ``description`` (round-trips through :func:`parse`)."""
    details = description.details
    contact = {}
    if description.bending_volume_share is not None:
        contact["bending_volume_share"] = _entry(
            description.bending_volume_share, CONTACT_FIELDS["bending_volume_share"],
            details.get("contact.bending_volume_share", {}))
    result = {
        "format": FORMAT,
        "provenance": dict(description.provenance),
        "parameters": {
            name: _entry(getattr(description.parameters, name), spec, details.get(name, {}))
            for name, spec in PARAMETERS.items()
        },
        "sensors": {
            sensor: {
                field: _entry(getattr(model, field), spec, details.get(f"{sensor}.{field}", {}))
                for field, spec in SENSOR_FIELDS.items()
            } for sensor, model in description.sensors.items()
        },
    }
    if contact:
        result["contact"] = contact
    return result


def save(description: PlantDescription, path, header: str = "") -> pathlib.Path:
    """Write ``description`` to ``path`` (YAML, one line per value), ``header`` as comments."""
    path = pathlib.Path(path)
    doc = document(description)
    lines = [f"# {line}" if line else "#" for line in header.splitlines()]
    lines += [f"format: {FORMAT}", "provenance:"]
    lines += ["  " + line for line in yaml.safe_dump(
        doc["provenance"], default_flow_style=False, width=1000, sort_keys=False).splitlines()]
    lines.append("parameters:")
    width = max(len(n) for n in PARAMETERS) + 1
    for name, entry in doc["parameters"].items():
        flow = yaml.safe_dump(entry, default_flow_style=True, width=1000, sort_keys=False).strip()
        lines.append(f"  {name + ':':{width}} {flow}")
    lines.append("sensors:")
    for sensor, fields in doc["sensors"].items():
        lines.append(f"  {sensor}:")
        for field, entry in fields.items():
            flow = yaml.safe_dump(entry, default_flow_style=True, width=1000,
                                  sort_keys=False).strip()
            lines.append(f"    {field}: {flow}")
    if "contact" in doc:
        lines.append("contact:")
        for name, entry in doc["contact"].items():
            flow = yaml.safe_dump(entry, default_flow_style=True, width=1000,
                                  sort_keys=False).strip()
            lines.append(f"  {name}: {flow}")
    text = "\n".join(lines) + "\n"
    parse(yaml.safe_load(text), str(path))  # what is written reads back
    return write_text_atomically(path, text)


def today() -> str:
    return datetime.date.today().isoformat()
