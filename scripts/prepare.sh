# Sourced by scripts/test.sh and scripts/demo.sh: set the workspace up if needed (with the flags in
# $softgrip_setup_args), then enter it
# (venv, install/, loopback-only DDS discovery unless set, a display-free matplotlib).
repo_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$repo_root"
mkdir -p log
# kept, so that tests/test_packaging.py can tell a workspace built from nothing by this run
export SOFTGRIP_SETUP_LOG="$repo_root/log/setup-prepare.txt"
# shellcheck disable=SC2086  # word splitting wanted: a list of flags
bash scripts/setup.sh ${softgrip_setup_args:-} | tee "$SOFTGRIP_SETUP_LOG"
# shellcheck disable=SC1091
source scripts/env.sh
export MPLBACKEND=Agg
