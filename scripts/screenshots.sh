#!/usr/bin/env bash
# make screenshots: the README's pictures, taken as a newcomer would see them. A 4 m drive in
# three laps with drifting wheel odometry (gtbow synth --drive) is replayed through
# launch/backend.launch (the localizer maps in the odometry frame, pose_graph_backend corrects it)
# with RViz on config/localizer.rviz under Xvfb; then RViz's window is captured (the whole floor,
# keyframe footprints, loop-closure edges, the backend's path) and the match overlay with the
# most verified matches is kept. Last, the map is saved with the backend's poses and a drive 30
# days later (a bag with odometry) is localized on it through demo.launch (mode:=localization
# publish_tf:=true rviz:=true), as a user replays a later recording: its RViz window is kept too.
# Usage: screenshots.sh WORKSPACE OUT_DIR IMAGES_DIR
set -euo pipefail
ws="$1"
out="$2"
images="$3"
here="$(cd "$(dirname "$0")" && pwd)"
export PATH=/usr/bin:$PATH
set +u
source "$ws/devel/setup.bash"
set -u
gtbow="$ws/devel/bin/gtbow"
mkdir -p "$out" "$images"
out="$(cd "$out" && pwd)"
images="$(cd "$images" && pwd)"
for tool in Xvfb rviz import; do
  command -v $tool > /dev/null || { echo "screenshots: $tool is missing (scripts/install_deps.sh --screenshots)"; exit 2; }
done

echo "== screenshots 1. a 4 m drive and its vocabulary"
"$gtbow" synth --out "$out/floor" --area 0.7 0.5 --train 40 --queries 0 --drive 4 \
  --later-drives 30 --later-drive-length 1.5 \
  --only train,drive --odom-heading-bias 0.004 --odom-turn-bias 0.01 --force -q > /dev/null
"$gtbow" train-vocab --dataset "$out/floor" --words 2000 --out "$out/floor.gtvoc" -q > /dev/null
"$ws/devel/bin/gtbow_images_to_bag" --dataset "$out/floor" --split drive \
  --odometry "$out/floor/drive_odometry.csv" --camera-offset 0.12 0.03 1.5708 \
  --out "$out/drive.bag" -q > /dev/null
"$ws/devel/bin/gtbow_images_to_bag" --dataset "$out/floor" --split drive_day030 \
  --odometry "$out/floor/drive_day030_odometry.csv" --camera-offset 0.12 0.03 1.5708 \
  --out "$out/later.bag" -q > /dev/null

source "$here/private_roscore.sh" "$out"  # a private ROS master; pids, cleanup
display=":$((50 + RANDOM % 40))"
Xvfb "$display" -screen 0 1280x800x24 -nolisten tcp > "$out/xvfb.log" 2>&1 &
pids+=($!)
export DISPLAY="$display"

echo "== screenshots 2. the localizer and the backend, RViz"
roslaunch ground_texture_bow backend.launch vocabulary:="$out/floor.gtvoc" > "$out/backend.log" 2>&1 &
pids+=($!)
for _ in $(seq 100); do
  rosservice list 2>/dev/null | grep -qx /localizer/get_info && break
  sleep 0.3
done
rviz -d "$ws/src/ground_texture_bow/config/localizer.rviz" > "$out/rviz.log" 2>&1 &
pids+=($!)
/usr/bin/python3 "$here/save_debug_image.py" --out "$images/debug_overlay.png" --timeout 90 \
  > "$out/save_debug_image.log" 2>&1 &
saver=$!
pids+=($saver)
sleep 8  # RViz's window and subscriptions
echo "== screenshots 3. replaying the drive"
rosbag play --quiet -d 2 "$out/drive.bag" > "$out/play.log" 2>&1
sleep 4
import -display "$display" -window root "$images/rviz.png"
rosservice call /localizer/get_info | grep -E "database_size|loop_closures" | sed 's/^/   /' || true
wait $saver || { echo "screenshots: no match overlay: see $out/save_debug_image.log"; exit 1; }
cat "$out/save_debug_image.log" | sed 's/^/   /'
echo "   $images/rviz.png"

echo "== screenshots 4. the map saved, a drive 30 days later localized on it, RViz"
/usr/bin/python3 "$here/save_optimised_map.py" "$out/floor.gtmap" > "$out/save_map.log" 2>&1 ||
  { cat "$out/save_map.log"; exit 1; }
for p in "${pids[@]:2}"; do kill -INT "$p" 2>/dev/null || true; done  # all but roscore and Xvfb
sleep 5
roslaunch ground_texture_bow demo.launch bag:="$out/later.bag" map:="$out/floor.gtmap" \
  mode:=localization publish_tf:=true rviz:=true > "$out/localization.log" 2>&1 &
pids+=($!)
# The bag starts 3 s after the launch; RViz stays open after it.
for _ in $(seq 120); do
  rosservice call /localizer/get_info 2>/dev/null | grep -q "^localized: True" && break
  sleep 0.5
done
sleep 20
import -display "$display" -window root "$images/rviz_localization.png"
rosservice call /localizer/get_info | grep -E "^(localized|fixes|fixes_held):" | sed 's/^/   /'
echo "   $images/rviz_localization.png"
