#!/usr/bin/env bash
# The README's main job: set up if needed, then run the demo on the simulated gripper.
# Today: the pressure demo (scripts/demo_pressure.py); the grasp demo replaces it with the bringup.
set -euo pipefail
repo_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$repo_root"
bash scripts/setup.sh
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
# shellcheck disable=SC1091
source scripts/env.sh
export MPLBACKEND=Agg
exec python scripts/demo_pressure.py "$@"
