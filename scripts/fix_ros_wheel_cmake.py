#!/usr/bin/env python3
"""Remap the wheel-build-machine include paths in the ROS 2 wheels' CMake exports.

The ROS 2 Jazzy message wheels export CMake targets whose include directories
point at the machine that built them (``/opt/python/cpXY-cpXY/include/python3.Y``
and ``.../site-packages/numpy/_core/include``). CMake refuses to configure any
package depending on such a target ("includes non-existent path"). This script
rewrites them to this interpreter's include directory and ``numpy.get_include()``.

It is idempotent and ends by verifying that no exported CMake file still names
a path under ``/opt/python``; a non-zero exit says which file does.
"""
import pathlib
import re
import sys
import sysconfig

import numpy

BUILD_MACHINE_PYTHON_INCLUDE = re.compile(r"/opt/python/cp3\d+-cp3\d+/include/python3\.\d+")
BUILD_MACHINE_NUMPY_INCLUDE = re.compile(
    r"/opt/python/cp3\d+-cp3\d+/lib/python3\.\d+/site-packages/numpy/(?:_core|core)/include")


def remap(share_dir: pathlib.Path) -> tuple[int, list[pathlib.Path]]:
    python_include = sysconfig.get_paths()["include"]
    numpy_include = numpy.get_include()
    changed = 0
    still_broken = []
    for cmake_file in share_dir.glob("*/cmake/*.cmake"):
        text = cmake_file.read_text()
        if "/opt/python/" not in text:
            continue
        fixed = BUILD_MACHINE_NUMPY_INCLUDE.sub(numpy_include, text)
        fixed = BUILD_MACHINE_PYTHON_INCLUDE.sub(python_include, fixed)
        if fixed != text:
            cmake_file.write_text(fixed)
            changed += 1
        if "/opt/python/" in fixed:
            still_broken.append(cmake_file)
    return changed, still_broken


def main() -> int:
    share_dir = pathlib.Path(sys.prefix) / "share"
    if not share_dir.is_dir():
        print(f"fix_ros_wheel_cmake: {share_dir} does not exist; are the ROS 2 wheels installed?",
              file=sys.stderr)
        return 1
    changed, still_broken = remap(share_dir)
    for path in still_broken:
        print(f"fix_ros_wheel_cmake: unrecognised build-machine path left in {path}",
              file=sys.stderr)
    if still_broken:
        return 1
    for needed in (sysconfig.get_paths()["include"], numpy.get_include()):
        if not pathlib.Path(needed).is_dir():
            print(
                f"fix_ros_wheel_cmake: include directory {needed} does not exist "
                "(install the Python development headers)", file=sys.stderr)
            return 1
    print(f"fix_ros_wheel_cmake: {changed} file(s) remapped, all CMake exports verified")
    return 0


if __name__ == "__main__":
    sys.exit(main())
