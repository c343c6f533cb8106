#!/usr/bin/env bash
# The README's test command: set up the workspace if needed, then run all of pytest.
# Extra arguments go to pytest (e.g. scripts/test.sh -k codec -x).
set -euo pipefail
# The tests also check the offline reference model, so they install its optional extra.
softgrip_setup_args="--with-reference"
# shellcheck disable=SC1091
source "$(dirname "${BASH_SOURCE[0]}")/prepare.sh"
status=0
python -m pytest "$@" || status=$?
if [ "$status" -eq 5 ]; then
  echo "[test] pytest collected no tests: that is a failure" >&2
  exit 1
fi
exit "$status"
