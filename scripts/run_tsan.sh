#!/usr/bin/env bash
# make test-sanitize, second part: the concurrency tests under ThreadSanitizer.
#   core: Database.ConcurrentQueriesSeeAPrefixOfTheInsertions (queries during insertion) and
#         CrashSafety.SavesAndQueriesDuringInsertionSeeConsistentMaps (saves and queries during
#         insertion into the node's map);
#   ROS:  the soak rostest for TSAN_SECONDS (default 60): the mapping bag looped at 4x into the
#         nodelet while four service clients query, localize, read the state and save the map.
# Our code (core, ROS layer, nodelet, tests) is built with -fsanitize=thread in its own
# workspace; Debian's nodelet manager gets the runtime preloaded. A report with this package's
# code on every side fails the run (scripts/tsan_reports.py).
# Usage: run_tsan.sh WORKSPACE ROSTEST_DATA_DIR
set -uo pipefail
export PATH="/usr/bin:$PATH"
root="$(cd "$(dirname "$0")/.." && pwd)"
ws="$1"
data="$2"
seconds="${TSAN_SECONDS:-60}"
log="$ws/../test-tsan.log"
reports="$ws/../sanitizer-tsan"
rm -rf "$reports"
mkdir -p "$reports" "$ws/src"
bash "$root/scripts/link_package.sh" "$root" "$ws/src/ground_texture_bow"
echo "ThreadSanitizer: building the concurrency tests (log: $log)"
if ! catkin_make -C "$ws" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DGTBOW_SANITIZE_THREAD=ON \
    -DCATKIN_ENABLE_TESTING=ON -j"${JOBS:-2}" \
    database_test crash_safety_test localizer_soak_rostest ground_texture_bow_nodelet > "$log" 2>&1; then
  tail -n 40 "$log"
  echo "ThreadSanitizer: build failed: see $log"
  exit 1
fi
[ -f "$data/mapping.bag" ] || { echo "ThreadSanitizer: no rostest data in $data"; exit 1; }
export TSAN_OPTIONS="log_path=$reports/tsan:log_exe_name=1:halt_on_error=0:second_deadlock_stack=1:suppressions=$root/test/sanitizer/tsan.supp"
bin="$ws/devel/lib/ground_texture_bow"
failed=0
run() {
  local name="$1"; shift
  if "$@" >> "$log" 2>&1; then echo "ThreadSanitizer: $name passed"; else echo "ThreadSanitizer: $name FAILED"; failed=1; fi
}
run "database_test (concurrent queries)" "$bin/database_test" --gtest_filter='Database.Concurrent*'
run "crash_safety_test (concurrent saves and queries)" "$bin/crash_safety_test" --gtest_filter='*DuringInsertion*'
set +u
source "$ws/devel/setup.bash"
set -u
export GTBOW_MANAGER_PREFIX="env LD_PRELOAD=$(gcc -print-file-name=libtsan.so)"
out="$ws/../tsan-soak"
rm -rf "$out"
mkdir -p "$out"
rostest --text "$root/test/ros/soak.test" data:="$data" seconds:="$seconds" out:="$out" \
  client:=localizer_soak_rostest save_every:=10 check_memory:=false > "$out/rostest.log" 2>&1
if grep -q "\[  PASSED  \] 1 test" "$out/rostest.log"; then
  echo "ThreadSanitizer: soak.test for ${seconds} s passed ($(grep -h '^soak:' "$out/rostest.log" | tail -n1))"
else
  echo "ThreadSanitizer: soak.test FAILED: see $out/rostest.log"
  failed=1
fi
# Reports with this package on every side fail the run; those inside Debian's uninstrumented
# roscpp, tf2_ros, bondcpp and log4cxx are counted (scripts/tsan_reports.py says why).
/usr/bin/python3 "$root/scripts/tsan_reports.py" "$reports" "$ws" || failed=1
exit $failed
