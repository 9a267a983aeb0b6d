#!/usr/bin/env bash
# `make demo`: the whole story on the built-in default, headless.
#   1. render a small synthetic asphalt floor (gtbow synth)
#   2. train a small vocabulary on its separate training area (gtbow train-vocab)
#   3. replay a mapping bag (images + ground-truth TF) through the localizer nodelet
#   4. save the map (~save_map)
#   5. start a fresh nodelet in localization mode with that map, replay a day-180 bag without
#      TF, and score its pose fixes against the ground truth (scripts/fix_accuracy.py)
# Usage: ros_demo.sh WORKSPACE OUT_DIR
set -euo pipefail
export PATH="/usr/bin:$PATH"
ws="$1"
out="$2"
here="$(cd "$(dirname "$0")" && pwd)"
set +u
source "$ws/devel/setup.bash"
set -u
gtbow="$ws/devel/bin/gtbow"
mkdir -p "$out"
out="$(cd "$out" && pwd)"

echo "== 1. floor"
"$gtbow" synth --out "$out/floor" --area 0.5 0.4 --train 40 --queries 20 --days 0,180 --force -q
echo "== 2. vocabulary"
"$gtbow" train-vocab --dataset "$out/floor" --words 3000 --out "$out/floor.gtvoc" -q
"$ws/devel/bin/gtbow_images_to_bag" --dataset "$out/floor" --split database --out "$out/mapping.bag" -q
# Day 180 without TF to the map: the robot must localize globally. Its camera hangs from
# base_link (a static mount straight above the footprint, as robot_state_publisher would send).
"$ws/devel/bin/gtbow_images_to_bag" --dataset "$out/floor" --split query_day180 --no-tf \
  --camera-offset 0 0 0 \
  --out "$out/day180.bag" -q

source "$here/private_roscore.sh" "$out"  # a private ROS master; pids, cleanup
# Wall time: the bags' stamps are only compared with each other (TF lookups at image stamps).
# (launch/demo.launch replays with simulated time instead, for RViz.)

wait_for_node() {
  for _ in $(seq 150); do
    rosservice list 2>/dev/null | grep -qx /localizer/get_info && return 0
    sleep 0.2
  done
  echo "the localizer did not start: see $1"
  return 1
}

echo "== 3. mapping: replaying $(basename "$out/mapping.bag") through the nodelet"
roslaunch ground_texture_bow localizer.launch vocabulary:="$out/floor.gtvoc" mode:=mapping \
  > "$out/mapping.log" 2>&1 &
mapping_pid=$!
pids+=($mapping_pid)
wait_for_node "$out/mapping.log"
rosbag play --quiet "$out/mapping.bag" > "$out/play_mapping.log" 2>&1
sleep 1
rosservice call /localizer/get_info | grep -E "database_size|images_(processed|dropped)" | sed 's/^/   /'
echo "== 4. save_map"
rosservice call /localizer/save_map "path: '$out/floor.gtmap'" | grep message | sed 's/^/   /'
kill -INT $mapping_pid
wait $mapping_pid 2>/dev/null || true

echo "== 5. localization: a fresh nodelet loads the map and replays day 180 (no TF)"
roslaunch ground_texture_bow localizer.launch vocabulary:="$out/floor.gtvoc" \
  map:="$out/floor.gtmap" mode:=localization > "$out/localization.log" 2>&1 &
pids+=($!)
wait_for_node "$out/localization.log"
rm -f "$out/.ready"
/usr/bin/python3 "$here/fix_accuracy.py" "$out/day180.bag" --ready-file "$out/.ready" \
  --timeout 5 > "$out/fix_accuracy.txt" 2>&1 &
scorer=$!
for _ in $(seq 50); do [ -f "$out/.ready" ] && break; sleep 0.1; done
sleep 0.5
rosbag play --quiet "$out/day180.bag" > "$out/play_day180.log" 2>&1
status=0
wait $scorer || status=$?
sed 's/^/   /' "$out/fix_accuracy.txt"
echo "Logs, bags and map in $out"
exit $status
