"""Gripper models by name: a finger geometry and its bending calibration.

A name is one of

- a built-in cavity type of the paper (``type_I``, ``type_II``, ``type_III``): the packaged
  ``config/gripper_geometry.yaml`` and ``config/model_calibration.yaml``;
- a calibration that ``softgrip_calibrate --name NAME`` wrote: ``NAME.yaml`` in the calibration
  directory, ``$SOFTGRIP_CALIBRATION_DIR``, else ``$ROS_HOME/softgrip_calibrations``, else
  ``~/.ros/softgrip_calibrations`` (camera_info_manager keeps camera calibrations in
  ``~/.ros/camera_info`` the same way);
- a path to such a file (anything ending in ``.yaml`` or holding a ``/``).

A calibration file holds the whole model, geometry and constants, so that a gripper's model
travels as one file.
"""
from __future__ import annotations

import dataclasses
import functools
import math
import os
import pathlib

import yaml

from softgrip_ros.fileio import read_yaml, write_text_atomically
from softgrip_ros.model.bending import BendingCalibration
from softgrip_ros.model.geometry import FingerGeometry, geometry_from_fields

FILE_HEADER = ("# softgrip_ros bending calibration, written by softgrip_calibrate. Select it with "
               "the nodes' gripper_model parameter.\n")


@functools.lru_cache(maxsize=1)
def built_in() -> tuple:
    """The paper's cavity types: those of the packaged config/model_calibration.yaml."""
    from softgrip_ros.config_paths import config_file
    from softgrip_ros.model.calibration import CALIBRATION_FILE
    return tuple(yaml.safe_load(config_file(CALIBRATION_FILE).read_text())["types"])


def calibration_dir() -> pathlib.Path:
    """Where named calibrations live (see the module docstring)."""
    explicit = os.environ.get("SOFTGRIP_CALIBRATION_DIR")
    if explicit:
        return pathlib.Path(explicit).expanduser()
    ros_home = os.environ.get("ROS_HOME")
    return (pathlib.Path(ros_home).expanduser() if ros_home
            else pathlib.Path.home() / ".ros") / "softgrip_calibrations"


def model_path(name: str) -> pathlib.Path | None:
    """The calibration file ``name`` refers to; None for a built-in type."""
    if name in built_in():
        return None
    if name.endswith(".yaml") or "/" in name:
        return pathlib.Path(name).expanduser()
    return calibration_dir() / f"{name}.yaml"


def resolve(name: str) -> tuple[FingerGeometry, BendingCalibration]:
    """The geometry and calibration of the gripper model ``name``; ValueError saying where it
    looked when there is none."""
    from softgrip_ros.model.calibration import load_calibration
    from softgrip_ros.model.geometry import load_geometry
    if not isinstance(name, str) or not name.strip():
        raise ValueError("gripper model: give a built-in type (type_I, type_II, type_III), a "
                         "calibration's name or a calibration file")
    path = model_path(name)
    if path is None:
        return load_geometry(name), load_calibration(name)
    if not path.is_file():
        raise ValueError(
            f"unknown gripper model {name!r}: not a built-in type ({', '.join(built_in())}) and "
            f"no calibration file {path}; make one with softgrip_calibrate --name {path.stem}")
    return load_file(path)


def load_file(path) -> tuple[FingerGeometry, BendingCalibration]:
    path = pathlib.Path(path)
    document = read_yaml(path)
    if not isinstance(document, dict) or not isinstance(document.get("geometry"), dict) or \
            not isinstance(document.get("calibration"), dict):
        raise ValueError(f"{path}: not a softgrip calibration (needs 'geometry' and "
                         "'calibration' sections)")
    name = str(document.get("name") or path.stem)
    geometry = geometry_from_fields(document["geometry"], name, path)
    known = {f.name for f in dataclasses.fields(BendingCalibration)}
    constants = document["calibration"]
    unknown = sorted(set(constants) - known)
    if unknown:
        raise ValueError(
            f"{path}: calibration: unknown constants {unknown}; known: {sorted(known)}")
    try:
        calibration = BendingCalibration(**{k: float(v) for k, v in constants.items()})
    except (TypeError, ValueError) as error:
        raise ValueError(f"{path}: calibration: {error}") from None
    return geometry, calibration


def geometry_fields(geometry: FingerGeometry) -> dict:
    """``geometry`` as the fields of config/gripper_geometry.yaml (angles in degrees)."""
    fields = {}
    for field in dataclasses.fields(FingerGeometry):
        if field.name == "name":
            continue
        value = getattr(geometry, field.name)
        if field.name.endswith("_rad"):
            fields[field.name[:-4] + "_deg"] = round(float(math.degrees(value)), 9)
        elif isinstance(value, tuple):
            fields[field.name] = [float(v) for v in value]
        else:
            fields[field.name] = float(value)
    return fields


def write_file(path, name: str, geometry: FingerGeometry, calibration: BendingCalibration,
               fit: dict, provenance: dict) -> pathlib.Path:
    """Write one gripper model: geometry, constants, how they were found."""
    path = pathlib.Path(path)
    document = {
        "name": name,
        "geometry": geometry_fields(geometry),
        "calibration": {f.name: float(getattr(calibration, f.name))
                        for f in dataclasses.fields(BendingCalibration)},
        "fit": fit,
        "provenance": provenance,
    }
    return write_text_atomically(path, FILE_HEADER + yaml.safe_dump(document, sort_keys=False))
