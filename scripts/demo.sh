#!/usr/bin/env bash
# The README's main job: set up if needed, then run the grasp demo on the simulated gripper
# (scripts/demo_grasp.py: the controller executable, ENVELOP_CLAMP 40 mm 0.2 kg, then RELEASE).
set -euo pipefail
# shellcheck disable=SC1091
source "$(dirname "${BASH_SOURCE[0]}")/prepare.sh"
exec python scripts/demo_grasp.py "$@"
