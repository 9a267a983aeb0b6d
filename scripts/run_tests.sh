#!/usr/bin/env bash
# Builds the catkin workspace and runs every gtest and rostest, then prints "N passed, N failed"
# and exits non-zero on any failure. Usage: run_tests.sh WORKSPACE JOBS [sanitize]
# With "sanitize" (make test-sanitize) everything is built with AddressSanitizer and
# UndefinedBehaviorSanitizer (CMake option GTBOW_SANITIZE), the nodelet manager gets the
# sanitizer runtimes preloaded, every process writes its sanitizer reports under
# WORKSPACE/../sanitizer, and any report fails the run.
set -uo pipefail
export PATH="/usr/bin:$PATH"
ws="$1"
jobs="${2:-2}"
mode="${3:-}"
log="$ws/../test.log"
cmake_args=(-DCMAKE_BUILD_TYPE=Release)
if [ "$mode" = "sanitize" ]; then
  log="$ws/../test-sanitize.log"
  reports="$ws/../sanitizer"
  rm -rf "$reports"
  mkdir -p "$reports"
  cmake_args=(-DCMAKE_BUILD_TYPE=RelWithDebInfo -DGTBOW_SANITIZE=ON)
  supp="$(cd "$(dirname "$0")/.." && pwd)/test/sanitizer"
  export ASAN_OPTIONS="log_path=$reports/asan:log_exe_name=1:detect_leaks=1:strict_string_checks=1:detect_stack_use_after_return=1:check_initialization_order=1"
  export UBSAN_OPTIONS="log_path=$reports/ubsan:log_exe_name=1:print_stacktrace=1:halt_on_error=1"
  export LSAN_OPTIONS="suppressions=$supp/lsan.supp:print_suppressions=0"
  # Debian's nodelet manager is not instrumented; our nodelet library needs the runtimes
  # loaded first (launch files: manager_prefix).
  export GTBOW_MANAGER_PREFIX="env LD_PRELOAD=$(gcc -print-file-name=libasan.so):$(gcc -print-file-name=libubsan.so)"
fi
mkdir -p "$(dirname "$log")"
rm -rf "$ws/build/test_results"
echo "building and running tests (log: $log)"
if ! catkin_make -C "$ws" "${cmake_args[@]}" -j"$jobs" > "$log" 2>&1; then
  tail -n 60 "$log"
  echo "0 passed, 1 failed"
  echo "build failed: see $log"
  exit 1
fi
catkin_make -C "$ws" -j"$jobs" run_tests >> "$log" 2>&1
status=$?
/usr/bin/python3 "$(dirname "$0")/test_summary.py" "$ws/build/test_results"
summary=$?
if [ "$mode" = "sanitize" ]; then
  found=$(find "$reports" -type f | sort)
  if [ -n "$found" ]; then
    echo "sanitizer reports (each one fails the run):"
    for f in $found; do
      echo "== $f"
      grep -m1 -E "ERROR|runtime error|SUMMARY" "$f" || head -n 3 "$f"
    done
    summary=1
  else
    echo "sanitizers: no report from any process (ASan, UBSan, LeakSanitizer)"
  fi
fi
if [ $status -ne 0 ] && [ $summary -eq 0 ]; then
  echo "run_tests exited with $status: see $log"
  exit 1
fi
exit $summary
