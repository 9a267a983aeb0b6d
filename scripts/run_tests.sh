#!/usr/bin/env bash
# Builds the catkin workspace and runs every gtest and rostest, then prints "N passed, N failed"
# and exits non-zero on any failure. Usage: run_tests.sh WORKSPACE JOBS
set -uo pipefail
export PATH="/usr/bin:$PATH"
ws="$1"
jobs="${2:-2}"
log="$ws/../test.log"
mkdir -p "$(dirname "$log")"
rm -rf "$ws/build/test_results"
echo "building and running tests (log: $log)"
if ! catkin_make -C "$ws" -DCMAKE_BUILD_TYPE=Release -j"$jobs" > "$log" 2>&1; then
  tail -n 60 "$log"
  echo "0 passed, 1 failed"
  echo "build failed: see $log"
  exit 1
fi
catkin_make -C "$ws" -j"$jobs" run_tests >> "$log" 2>&1
status=$?
/usr/bin/python3 "$(dirname "$0")/test_summary.py" "$ws/build/test_results"
summary=$?
if [ $status -ne 0 ] && [ $summary -eq 0 ]; then
  echo "run_tests exited with $status: see $log"
  exit 1
fi
exit $summary
