#!/usr/bin/env bash
# Run the test suite beside a CPU hog on every core (stress-ng --cpu N), to check that no test depends on timing.
#
#   bash scripts/stress_test.sh                       # the whole suite once, hog on all cores
#   bash scripts/stress_test.sh --runs 3              # three times in a row (the issue-14 acceptance run)
#   bash scripts/stress_test.sh tests/test_nodes.py -k faster     # any pytest arguments after the options
#   STRESS_CPUS=1 bash scripts/stress_test.sh         # hog on one worker only
#
# The hog (stress-ng --cpu N, N = nproc unless STRESS_CPUS is set) starts before the first run and is stopped
# when the script ends (also on Ctrl-C). Each run prints pytest's summary line; the exit status is 0 only when
# every run passed. stress-ng is a Debian package listed in scripts/apt-packages.txt (bash scripts/setup.sh
# installs it).
set -euo pipefail
cd "$(dirname "$0")/.."

runs=1
if [[ "${1:-}" == "--runs" ]]; then
  runs="${2:?--runs needs a number}"
  shift 2
fi
if ! command -v stress-ng > /dev/null; then
  echo "stress_test: stress-ng is not installed; run: bash scripts/setup.sh (or apt-get install stress-ng)" >&2
  exit 2
fi
python=.venv/bin/python
[[ -x "$python" ]] || { echo "stress_test: no .venv; run: bash scripts/setup.sh" >&2; exit 2; }
cpus="${STRESS_CPUS:-$(nproc)}"
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"

stress-ng --cpu "$cpus" --timeout 0 --quiet &
hog=$!
trap 'kill "$hog" 2> /dev/null || true; wait "$hog" 2> /dev/null || true' EXIT
echo "stress_test: stress-ng --cpu $cpus running (pid $hog); $runs run(s) of: pytest -q $*"

failed=0
for run in $(seq 1 "$runs"); do
  started=$(date +%s)
  if "$python" -m pytest -q -p no:cacheprovider "$@"; then
    result=passed
  else
    result=FAILED
    failed=$((failed + 1))
  fi
  echo "stress_test: run $run of $runs $result in $(( $(date +%s) - started )) s (load average $(cut -d' ' -f1-3 /proc/loadavg))"
done
echo "stress_test: $((runs - failed)) of $runs run(s) passed beside stress-ng --cpu $cpus"
[[ "$failed" -eq 0 ]]
