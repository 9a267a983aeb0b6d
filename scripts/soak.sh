#!/usr/bin/env bash
# make soak: SOAK_SECONDS (default 600) of the rostests' synthetic mapping bag looped at 4x real
# time into the nodelet, with concurrent service calls from a second process
# (test/ros/soak.test, Soak.* in test/ros/soak_rostest.cpp); then the figures and a plot
# go into docs/RESULTS.md (scripts/write_soak.py). Usage: soak.sh WORKSPACE
set -euo pipefail
export PATH="/usr/bin:$PATH"
root="$(cd "$(dirname "$0")/.." && pwd)"
ws="$(cd "$1" && pwd)"
seconds="${SOAK_SECONDS:-600}"
out="$root/build/soak"
make -C "$ws/build" gtbow_rostest_data localizer_rostest ground_texture_bow_nodelet > /dev/null
data="$ws/build/ground_texture_bow/rostest_data"
[ -f "$data/mapping.bag" ] || data="$ws/build/rostest_data"
rm -rf "$out"
mkdir -p "$out"
set +u
source "$ws/devel/setup.bash"
set -u
echo "soak: ${seconds} s of 4x replay with concurrent service calls (log: $out/rostest.log)"
status=0
rostest --text "$root/test/ros/soak.test" data:="$data" seconds:="$seconds" out:="$out" \
  2>&1 | tee "$out/rostest.log" | grep --line-buffered -E "^soak|FAIL|Failure|\[ +(OK|FAILED) +\]" || true
grep -q "\[  PASSED  \] 1 test" "$out/rostest.log" || status=1
if [ -f "$out/soak.json" ]; then
  python3 "$root/scripts/write_soak.py" "$out" "$root/docs"
fi
[ $status -eq 0 ] && echo "soak: passed" || echo "soak: FAILED (see $out/rostest.log)"
exit $status
