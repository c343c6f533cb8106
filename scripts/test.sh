#!/usr/bin/env bash
# The README's test command: set up the workspace if needed, then run all of pytest: the tests
# marked cpu (computation only) two at a time, then the rest (rclpy, processes, timing) one at
# a time. Extra arguments run pytest once with them instead (e.g. scripts/test.sh -k codec -x).
set -euo pipefail
# The tests also check the offline reference model, so they install its optional extra.
softgrip_setup_args="--with-reference"
# shellcheck disable=SC1091
source "$(dirname "${BASH_SOURCE[0]}")/prepare.sh"
status=0
run_pytest() {
  local rc=0
  python -m pytest "$@" || rc=$?
  if [ "$rc" -eq 5 ]; then
    echo "[test] pytest collected no tests ($*): that is a failure" >&2
    rc=1
  fi
  if [ "$status" -eq 0 ]; then status=$rc; fi
}
if [ "$#" -eq 0 ]; then
  # one BLAS thread per worker: two workers' spinning BLAS threads would share two cores
  OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 run_pytest -n 2 -m cpu
  run_pytest -m "not cpu"
else
  run_pytest "$@"
fi
exit "$status"
