#!/usr/bin/env bash
# The README's main job: set up if needed, then run the grasp demo on the simulated gripper
# (scripts/demo_grasp.py: sim_device with the physics world and the controller executable,
# ENVELOP_CLAMP 20 mm 0.02 kg, then RELEASE).
set -euo pipefail
# shellcheck disable=SC1091
source "$(dirname "${BASH_SOURCE[0]}")/prepare.sh"
exec python scripts/demo_grasp.py "$@"
