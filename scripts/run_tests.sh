#!/usr/bin/env bash
# Builds the catkin workspace and runs every gtest and rostest, then prints "N passed, N failed"
# and exits non-zero on any failure. Usage: run_tests.sh WORKSPACE JOBS [sanitize|slow-disk]
# GTBOW_SLOW_DISK=1 runs any mode on a slow disk and busy cores (as slow-disk does, below);
# `GTBOW_SLOW_DISK=1 .ci/run` so runs CI's whole sequence.
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
  # The nodes' output, searched for UBSan's reports (which go to stderr) with the test log.
  export ROS_LOG_DIR="$ws/../ros_log_sanitize"
  rm -rf "$ROS_LOG_DIR"
  cmake_args=(-DCMAKE_BUILD_TYPE=RelWithDebInfo -DGTBOW_SANITIZE=ON)
  supp="$(cd "$(dirname "$0")/.." && pwd)/test/sanitizer"
  # intercept_tls_get_addr=0: up to GCC 13 the runtime's __tls_get_addr interceptor takes a
  # dynamic TLS block whose address happens to sit at a certain offset in its page for a
  # pre-2.25 glibc block with a header, and LeakSanitizer's tracer, reading that "header" at
  # exit, faults ("Tracer caught signal 11"): a flake of the tool in processes that dlopen
  # libraries with thread-local storage (the nodelet manager). Without the interceptor those
  # blocks are ordinary heap blocks reachable from each thread's DTV, and still scanned.
  export ASAN_OPTIONS="log_path=$reports/asan:log_exe_name=1:detect_leaks=1:strict_string_checks=1:detect_stack_use_after_return=1:check_initialization_order=1:intercept_tls_get_addr=0"
  export UBSAN_OPTIONS="log_path=$reports/ubsan:log_exe_name=1:print_stacktrace=1:halt_on_error=1"
  export LSAN_OPTIONS="suppressions=$supp/lsan.supp:print_suppressions=0"
  # Debian's nodelet manager is not instrumented; our nodelet library needs the runtimes
  # loaded first (launch files: manager_prefix).
  export GTBOW_MANAGER_PREFIX="env LD_PRELOAD=$(gcc -print-file-name=libasan.so):$(gcc -print-file-name=libubsan.so)"
fi
# With "slow-disk" (make test-slow-disk) the same build runs every test with each call that
# waits for the disk delayed by GTBOW_FSYNC_DELAY_MS (default 200 ms: an SD card; the shim
# test/slow_disk/slow_fsync.c, compiled here without sanitizers, is preloaded into every
# process) while two CPU-bound processes keep both cores busy. A test that depends on the
# disk's or the machine's speed fails here.
slow=0
if [ "$mode" = "slow-disk" ]; then
  log="$ws/../test-slow-disk.log"
  slow=1
fi
[ "${GTBOW_SLOW_DISK:-0}" = 1 ] && slow=1
mkdir -p "$(dirname "$log")"
rm -rf "$ws/build/test_results"
# real_floor_small_test's photographs: beside the repository, or from their Debian packages.
repo="$(cd "$(dirname "$0")/.." && pwd)"
if [ ! -d "$repo/../shared/real_floors" ]; then
  bash "$repo/scripts/real_floor_photos.sh" "$repo/build/real_floors"
fi
echo "building and running tests (log: $log)"
if ! catkin_make -C "$ws" "${cmake_args[@]}" -j"$jobs" > "$log" 2>&1; then
  tail -n 60 "$log"
  echo "0 passed, 1 failed"
  echo "build failed: see $log"
  exit 1
fi
busy=()
if [ $slow = 1 ]; then
  if ! catkin_make -C "$ws" -j"$jobs" tests >> "$log" 2>&1; then
    tail -n 60 "$log"
    echo "0 passed, 1 failed"
    echo "build failed: see $log"
    exit 1
  fi
  shim="$ws/../slow_fsync.so"
  if ! gcc -shared -fPIC -O2 -o "$shim" "$(dirname "$0")/../test/slow_disk/slow_fsync.c" -ldl; then
    echo "cannot build the slow-disk shim"; echo "0 passed, 1 failed"; exit 1
  fi
  export GTBOW_FSYNC_DELAY_MS="${GTBOW_FSYNC_DELAY_MS:-200}"
  if [ "$mode" = "sanitize" ]; then
    # The shim comes before the sanitizer runtimes in the preload list: tell ASan so.
    export ASAN_OPTIONS="$ASAN_OPTIONS:verify_asan_link_order=0"
    export GTBOW_MANAGER_PREFIX="$GTBOW_MANAGER_PREFIX:$shim"
  fi
  for _ in 1 2; do
    bash -c 'while :; do :; done' &
    busy+=($!)
  done
  trap 'kill "${busy[@]}" 2>/dev/null' EXIT
  echo "every fsync delayed ${GTBOW_FSYNC_DELAY_MS} ms, two CPU-bound processes running (pids ${busy[*]})"
  LD_PRELOAD="$shim${LD_PRELOAD:+:$LD_PRELOAD}" catkin_make -C "$ws" -j"$jobs" run_tests >> "$log" 2>&1
  status=$?
  kill "${busy[@]}" 2>/dev/null
else
  catkin_make -C "$ws" -j"$jobs" run_tests >> "$log" 2>&1
  status=$?
fi
# The package from an install space (not under the sanitizers: the same code).
if [ "$mode" != "sanitize" ]; then
  # catkin_make's install space (build/ws/install unless the cache says otherwise).
  install="$(sed -n 's/^CMAKE_INSTALL_PREFIX:PATH=//p' "$ws/build/CMakeCache.txt")"
  xml="$ws/build/test_results/ground_texture_bow/install_space.xml"
  if catkin_make -C "$ws" -j"$jobs" install >> "$log" 2>&1; then
    bash "$(dirname "$0")/../test/ros/install_space_test.sh" "$install" \
      "$ws/build/ground_texture_bow/rostest_data/vocab.gtvoc" "$xml" >> "$log" 2>&1
  else
    mkdir -p "$(dirname "$xml")"
    echo '<?xml version="1.0"?><testsuite name="install_space" tests="1" failures="1"><testcase classname="InstallSpace" name="TheNodeRunsFromAnInstallSpaceWithItsPreset"><failure message="catkin_make install failed">catkin_make install failed (see the log)</failure></testcase></testsuite>' > "$xml"
  fi
fi
/usr/bin/python3 "$(dirname "$0")/test_summary.py" "$ws/build/test_results"
summary=$?
if [ "$mode" = "sanitize" ]; then
  # Reports of defects fail the run; a sanitizer's own crash is shown and counted apart.
  /usr/bin/python3 "$(dirname "$0")/sanitizer_reports.py" "$reports" "$log" "$ROS_LOG_DIR" ||
    summary=1
fi
if [ $status -ne 0 ] && [ $summary -eq 0 ]; then
  echo "run_tests exited with $status: see $log"
  exit 1
fi
exit $summary
