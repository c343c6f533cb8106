# Sourced by scripts/test.sh and scripts/demo.sh: set the workspace up if needed, then enter it
# (venv, install/, loopback-only DDS discovery unless set, a display-free matplotlib).
repo_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$repo_root"
bash scripts/setup.sh
# shellcheck disable=SC1091
source scripts/env.sh
export MPLBACKEND=Agg
