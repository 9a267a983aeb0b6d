#!/usr/bin/env bash
# make test-arm: the core's SIMD kernels (hamming_distance.cpp, byte_distance.cpp and their
# dispatch, free of OpenCV) with their tests cross-built for aarch64 by Debian's
# g++-aarch64-linux-gnu, linked statically and run under qemu-user: once with GTBOW_SIMD unset
# (the neon kernel) and once per value (portable, neon). Not part of make test. Installs the
# cross compiler, qemu-user and googletest's sources when they are missing (apt-get, through sudo
# when not root).
# Usage: test_arm.sh [BUILD_DIR]   (default build/arm)
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
out="${1:-$repo/build/arm}"
export PATH="/usr/bin:$PATH"

need=()
command -v aarch64-linux-gnu-g++ > /dev/null || need+=(g++-aarch64-linux-gnu)
command -v qemu-aarch64 > /dev/null || command -v qemu-aarch64-static > /dev/null ||
  need+=(qemu-user)
[ -f /usr/src/googletest/googletest/src/gtest-all.cc ] || need+=(googletest)
if [ ${#need[@]} -gt 0 ]; then
  echo "test-arm: installing ${need[*]}"
  sudo=()  # as scripts/install_deps.sh: root installs itself, another user through sudo
  if [ "$(id -u)" -ne 0 ]; then sudo=(sudo); fi
  "${sudo[@]}" apt-get update
  "${sudo[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends \
    "${need[@]}"
fi
qemu="$(command -v qemu-aarch64 || command -v qemu-aarch64-static)"

cxx=aarch64-linux-gnu-g++
gflags=(-std=c++17 -O2 -pthread)  # googletest's own sources
flags=("${gflags[@]}" -Wall -Wextra -Werror)
gtest=/usr/src/googletest/googletest
mkdir -p "$out"
if [ ! -f "$out/gtest.a" ] || [ "$gtest/src/gtest-all.cc" -nt "$out/gtest.a" ]; then
  echo "test-arm: building googletest for aarch64"
  "$cxx" "${gflags[@]}" -I"$gtest/include" -I"$gtest" -c "$gtest/src/gtest-all.cc" \
    -o "$out/gtest-all.o"
  "$cxx" "${gflags[@]}" -I"$gtest/include" -c "$gtest/src/gtest_main.cc" \
    -o "$out/gtest_main.o"
  aarch64-linux-gnu-ar rcs "$out/gtest.a" "$out/gtest-all.o" "$out/gtest_main.o"
fi

core=(src/core/hamming_distance.cpp src/core/byte_distance.cpp src/core/simd_dispatch.cpp)
tests=(hamming_distance byte_distance)
for t in "${tests[@]}"; do
  echo "test-arm: building ${t}_test"
  (cd "$repo" && "$cxx" "${flags[@]}" -Iinclude -Isrc/core -I"$gtest/include" \
    "${core[@]}" "test/core/${t}_test.cpp" "$out/gtest.a" -static -o "$out/${t}_test")
done
aarch64-linux-gnu-readelf -h "$out/hamming_distance_test" | grep -q "Machine: *AArch64" ||
  { echo "test-arm: $out/hamming_distance_test is not an aarch64 program"; exit 1; }

failed=0
for simd in "" portable neon; do
  for t in "${tests[@]}"; do
    echo "test-arm: GTBOW_SIMD='$simd' qemu-aarch64 ${t}_test"
    if ! GTBOW_SIMD="$simd" "$qemu" "$out/${t}_test" > "$out/${t}_${simd:-unset}.log" 2>&1; then
      cat "$out/${t}_${simd:-unset}.log"
      failed=1
    else
      grep -E "kernels on this CPU|PASSED" "$out/${t}_${simd:-unset}.log" | sed 's/^/  /'
    fi
  done
done
if [ "$failed" -ne 0 ]; then
  echo "test-arm: FAILED"
  exit 1
fi
echo "test-arm: every aarch64 kernel test passed under qemu"
