#!/usr/bin/env bash
# Build the softgrip_ros workspace from nothing: .venv with the ROS 2 Jazzy wheels
# and every pinned dependency, the CMake include-path remap, then colcon build of
# softgrip_interfaces and softgrip_ros into install/. Idempotent: a re-run with
# nothing changed only checks stamps and finishes in seconds.
set -euo pipefail

with_reference=0
which_control_msgs=0
usage="usage: scripts/setup.sh [--with-reference] [--which-control-msgs]"
for arg in "$@"; do
  case "$arg" in
    --with-reference) with_reference=1 ;;   # the optional references: PyElastica and the FE (requirements/reference.txt, fe.txt)
    --which-control-msgs) which_control_msgs=1 ;;   # print the prefix of a real control_msgs, or "stand-in"; build nothing
    -h|--help) echo "$usage"; exit 0 ;;
    *) echo "[setup] ERROR: unknown argument '$arg' ($usage)" >&2; exit 2 ;;
  esac
done

repo_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$repo_root"
venv="$repo_root/.venv"
python_bin="${SOFTGRIP_PYTHON:-python3}"

say() { printf '[setup] %s\n' "$*"; }
die() { printf '[setup] ERROR: %s\n' "$*" >&2; exit 1; }

# control_msgs is not on PyPI. The partial stand-in in compat/ (its gripper interfaces only) is
# built only when no other prefix provides the real package: a partial one must never shadow it.
real_control_msgs() {
  local prefix prefixes
  IFS=':' read -r -a prefixes <<< "$venv:${AMENT_PREFIX_PATH:-}"
  for prefix in "${prefixes[@]}"; do
    case "$prefix" in ""|"$repo_root/install"|"$repo_root/install/"*) continue ;; esac
    if [ -e "$prefix/share/ament_index/resource_index/packages/control_msgs" ]; then
      echo "$prefix"; return 0
    fi
  done
}
if [ "$which_control_msgs" = 1 ]; then
  found="$(real_control_msgs)"
  echo "${found:-stand-in}"
  exit 0
fi

# ---- platform: the ROS 2 Jazzy wheels exist for CPython 3.10-3.13 on x86_64 only
arch="$(uname -m)"
[ "$arch" = "x86_64" ] || die "unsupported architecture '$arch': the ROS 2 Jazzy PyPI wheels exist for x86_64 only. Use a full ROS 2 Jazzy install and 'colcon build' instead."
command -v "$python_bin" >/dev/null || die "'$python_bin' not found; set SOFTGRIP_PYTHON to a CPython 3.10-3.13 interpreter."
py_version="$("$python_bin" -c 'import sys; print(f"{sys.version_info[0]}.{sys.version_info[1]}")')"
py_impl="$("$python_bin" -c 'import platform; print(platform.python_implementation())')"
case "$py_impl:$py_version" in
  CPython:3.10|CPython:3.11|CPython:3.12|CPython:3.13) ;;
  *) die "unsupported interpreter $py_impl $py_version: the ROS 2 Jazzy wheels need CPython 3.10-3.13 (set SOFTGRIP_PYTHON)." ;;
esac
command -v cmake >/dev/null || die "cmake not found (apt-get install cmake): it builds the interface package."
command -v cc >/dev/null || command -v gcc >/dev/null || die "no C compiler found (apt-get install gcc g++): it builds the interface package."

hash_of() { cat "$@" | sha256sum | cut -d' ' -f1; }
# Some machines' pip config names local wheel mirrors that may be absent: drop that noise only.
quiet_pip() { "$venv/bin/python" -m pip "$@" 2> >(grep -v "is ignored: it is neither a file nor a directory" >&2); }
# install_pinned REQUIREMENTS_FILE: every version from constraints.txt, then a consistency check
install_pinned() {
  quiet_pip install --quiet --disable-pip-version-check -r "$1" -c requirements/constraints.txt
  "$venv/bin/python" -m pip check >/dev/null || die "pip check found inconsistent dependencies: $("$venv/bin/python" -m pip check)"
}

# stamp_matches FILE HASH: FILE records HASH (what was installed or built from is unchanged)
stamp_matches() { [ -f "$1" ] && [ "$(cat "$1")" = "$2" ]; }

# ---- 1. virtual environment with pinned dependencies
requirements_hash="$py_version-$(hash_of requirements/requirements.txt requirements/constraints.txt)"
stamp="$venv/.softgrip-requirements"
if [ -x "$venv/bin/python" ] && stamp_matches "$stamp" "$requirements_hash"; then
  say "venv up to date ($venv)"
else
  if [ -x "$venv/bin/python" ] && [ "$("$venv/bin/python" -c 'import sys; print(f"{sys.version_info[0]}.{sys.version_info[1]}")')" != "$py_version" ]; then
    say "venv was built for another Python; recreating it"
    rm -rf "$venv"
  fi
  [ -x "$venv/bin/python" ] || { say "creating $venv with $("$python_bin" --version)"; "$python_bin" -m venv "$venv"; }
  say "installing pinned dependencies (first run: about a minute)"
  quiet_pip install --quiet --disable-pip-version-check --upgrade "pip>=23"
  install_pinned requirements/requirements.txt
  echo "$requirements_hash" > "$stamp"
fi

# ---- 1b. the optional reference models' dependencies (PyElastica; scikit-fem, gmsh, NGSolve)
if [ "$with_reference" = 1 ]; then
  reference_hash="$py_version-$(hash_of requirements/reference.txt requirements/fe.txt requirements/constraints.txt)"
  reference_stamp="$venv/.softgrip-reference"
  if stamp_matches "$reference_stamp" "$reference_hash"; then
    say "reference extra up to date"
  else
    say "installing the reference extras (PyElastica; scikit-fem, gmsh and NGSolve)"
    install_pinned requirements/reference.txt
    install_pinned requirements/fe.txt
    echo "$reference_hash" > "$reference_stamp"
  fi
fi

# ---- 2. remap the wheels' build-machine include paths, then verify (see ros2-from-pypi notes)
"$venv/bin/python" scripts/fix_ros_wheel_cmake.py

# ---- 3. colcon build of both packages, when their sources changed
build_inputs() {
  local inputs=() path
  for path in msg_defs compat package.xml setup.py setup.cfg resource config src urdf launch; do
    [ -e "$path" ] && inputs+=("$path")
  done
  find "${inputs[@]}" -type f \
      -not -path '*/__pycache__/*' -not -name '*.pyc' | LC_ALL=C sort
}
base_paths=(. msg_defs)
real_control_msgs="$(real_control_msgs)"
if [ -n "$real_control_msgs" ]; then
  say "control_msgs found in $real_control_msgs: the partial stand-in is not built"
  rm -rf install/control_msgs build/control_msgs
else
  base_paths+=(compat/control_msgs)
fi
build_hash="$requirements_hash-${base_paths[*]}-$(build_inputs | xargs sha256sum | sha256sum | cut -d' ' -f1)"
build_stamp="$repo_root/install/.softgrip-build"
if stamp_matches "$build_stamp" "$build_hash"; then
  say "install/ up to date"
else
  say "colcon build (${base_paths[*]})"
  mkdir -p log
  # shellcheck disable=SC1091
  source "$venv/bin/activate"
  export AMENT_PREFIX_PATH="$VIRTUAL_ENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
  export CMAKE_PREFIX_PATH="$VIRTUAL_ENV${CMAKE_PREFIX_PATH:+:$CMAKE_PREFIX_PATH}"
  export PYTHONWARNINGS="ignore:setup.py install is deprecated,ignore:easy_install command is deprecated"
  colcon --log-base log build --base-paths "${base_paths[@]}" --symlink-install \
      --event-handlers console_cohesion- summary+ status- \
      --cmake-args -DPython3_EXECUTABLE="$venv/bin/python" -DBUILD_TESTING=OFF \
      > log/colcon-build.txt 2>&1 || { tail -n 60 log/colcon-build.txt >&2; die "colcon build failed (full log: log/colcon-build.txt)"; }
  echo "$build_hash" > "$build_stamp"
fi

# ---- 4. verify: both packages import from the built workspace
# shellcheck disable=SC1091
source "$repo_root/scripts/env.sh"
python -c 'import softgrip_interfaces.msg, softgrip_interfaces.action, softgrip_ros, rclpy, control_msgs.action' \
  || die "the built packages do not import; see log/colcon-build.txt"
say "ready: source scripts/env.sh to use the workspace"
