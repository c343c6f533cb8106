# Source me:  source scripts/env.sh
# Activates .venv and the colcon install/ of softgrip_ros, sets the prefix variables
# the ROS 2 wheels need, and keeps DDS discovery on loopback unless you chose otherwise.
_softgrip_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
if [ ! -x "$_softgrip_root/.venv/bin/python" ] || [ ! -f "$_softgrip_root/install/setup.bash" ]; then
  echo "softgrip env: run scripts/setup.sh first" >&2
  return 1 2>/dev/null || exit 1
fi
# shellcheck disable=SC1091
source "$_softgrip_root/.venv/bin/activate"
# The wheels' start-up hook sets LD_LIBRARY_PATH and re-executes Python once, guarded by this
# variable. A guard inherited from another interpreter's process would skip this venv's hook.
unset _ROS_WHEELS_BOOTSTRAP_COMPLETE
# The wheels install share/ into the venv prefix; rosidl and ament_index look there.
case ":${AMENT_PREFIX_PATH:-}:" in *":$VIRTUAL_ENV:"*) ;; *) export AMENT_PREFIX_PATH="$VIRTUAL_ENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}";; esac
case ":${CMAKE_PREFIX_PATH:-}:" in *":$VIRTUAL_ENV:"*) ;; *) export CMAKE_PREFIX_PATH="$VIRTUAL_ENV${CMAKE_PREFIX_PATH:+:$CMAKE_PREFIX_PATH}";; esac
# colcon's setup scripts reference unset variables; tolerate a caller's `set -u`.
_softgrip_nounset="$(set -o | awk '$1=="nounset"{print $2}')"
set +u
# shellcheck disable=SC1091
source "$_softgrip_root/install/setup.bash"
[ "$_softgrip_nounset" = "on" ] && set -u
# Only loopback here; a real multi-machine deployment sets its own range (e.g. SUBNET).
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
# the executables (controller, sim_device, ...) where ros2 run would find them, on this shell's PATH
case ":$PATH:" in *":$_softgrip_root/install/softgrip_ros/lib/softgrip_ros:"*) ;;
  *) export PATH="$_softgrip_root/install/softgrip_ros/lib/softgrip_ros:$PATH";; esac
export SOFTGRIP_ROOT="$_softgrip_root"
unset _softgrip_root _softgrip_nounset
