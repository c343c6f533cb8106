"""Every input file format, mutated at random (hypothesis): the loader gives a valid result or a
ValueError with a one-line reason, and nothing else.

Each format starts from a valid document; a mutation replaces one value anywhere in it by a
hostile one (NaN, infinities, huge, negative, a string, a list, a mapping, null), deletes a key,
or adds one. The tools turn a ValueError into that line and a non-zero exit (their own tests
check the exit codes).
"""
import copy
import csv
import io
import math

import pytest
import yaml
from hypothesis import given
from hypothesis import strategies as st

from softgrip_ros.config_paths import config_file
from softgrip_ros.model import bending_fit, geometry, plant_file
from softgrip_ros.model.world import scene

from tests.helpers.mutation import EXAMPLES, mutated, refused_in_one_line

pytestmark = pytest.mark.cpu  # computation only: scripts/test.sh runs it beside another

def _finite_fields(value):
    import dataclasses
    for field in dataclasses.fields(value):
        item = getattr(value, field.name)
        if isinstance(item, float):
            assert math.isfinite(item), (field.name, item)


GEOMETRY = yaml.safe_load(config_file("gripper_geometry.yaml").read_text())
PLANT = yaml.safe_load(config_file("plant.yaml").read_text())
SCENE = yaml.safe_load(config_file("scenes/sheet.yaml").read_text())


@EXAMPLES
@given(document=mutated(GEOMETRY))
def test_a_mutated_geometry_file_loads_valid_or_is_refused_in_one_line(document, tmp_path):
    path = tmp_path / "geometry.yaml"
    path.write_text(yaml.safe_dump(document))
    for name in ("type_I", "type_II", "type_III"):
        loaded = refused_in_one_line(lambda p, n=name: geometry.load_geometry(n, p), path)
        if loaded is not None:
            _finite_fields(loaded)


@EXAMPLES
@given(document=mutated(PLANT))
def test_a_mutated_plant_file_loads_valid_or_is_refused_in_one_line(document, tmp_path):
    path = tmp_path / "plant.yaml"
    path.write_text(yaml.safe_dump(document))
    loaded = refused_in_one_line(plant_file.load, path)
    if loaded is not None:
        _finite_fields(loaded.parameters)


@EXAMPLES
@given(document=mutated(SCENE))
def test_a_mutated_scene_file_loads_valid_or_is_refused_in_one_line(document, tmp_path):
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(document))
    loaded = refused_in_one_line(scene.load_scene, path)
    if loaded is not None:
        assert all(math.isfinite(v) for v in loaded.start_m)


CSV_ROWS = [["pressure_pa", "alpha_deg", "tip_spacing_m"],
            ["0", "15.0", "0.001"], ["10000", "30.0", "0.02"], ["20000", "45.0", "0.04"],
            ["30000", "60.0", "0.06"]]
CELL = st.one_of(st.sampled_from(["nan", "inf", "-inf", "1e300", "-1e300", "", "x", "1,5",
                                  "-5", "0"]),
                 st.floats(allow_nan=True, allow_infinity=True).map(repr),
                 st.text(max_size=6))


@EXAMPLES
@given(row=st.integers(0, len(CSV_ROWS) - 1), column=st.integers(0, 2), cell=CELL)
def test_a_mutated_measurement_csv_loads_valid_or_is_refused_in_one_line(row, column, cell,
                                                                        tmp_path):
    rows = copy.deepcopy(CSV_ROWS)
    rows[row][column] = cell
    text = io.StringIO()
    csv.writer(text).writerows(rows)
    path = tmp_path / "measurements.csv"
    path.write_text(text.getvalue())
    loaded = refused_in_one_line(bending_fit.load_csv, path)
    if loaded is not None:
        assert all(math.isfinite(v) for v in loaded.pressure_pa)
        for values in loaded.values.values():
            assert all(math.isfinite(v) or math.isnan(v) for v in values)
            assert not any(math.isinf(v) for v in values)


@pytest.mark.parametrize("text", ["", "{", ": :", "- a\n- b", "\x00", "a: [1, 2"])
def test_broken_yaml_is_refused_in_one_line_by_every_loader(text, tmp_path):
    path = tmp_path / "broken.yaml"
    path.write_text(text)
    for load in (lambda p: geometry.load_geometry("type_II", p), plant_file.load,
                 scene.load_scene):
        assert refused_in_one_line(load, path) is None
