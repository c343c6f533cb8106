#!/usr/bin/env bash
# The README's main job: set up if needed, then run the demo on the simulated gripper.
# Today: the pressure demo (scripts/demo_pressure.py); the grasp demo replaces it with the bringup.
set -euo pipefail
# shellcheck disable=SC1091
source "$(dirname "${BASH_SOURCE[0]}")/prepare.sh"
exec python scripts/demo_pressure.py "$@"
