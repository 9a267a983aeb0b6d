# Sourced by the demo scripts: a private ROS master on a random port, so that a demo neither
# needs nor disturbs a running one. Usage: source private_roscore.sh OUT_DIR
# Sets ROS_MASTER_URI and ROS_HOME (OUT_DIR/ros_home), and `pids`, the processes the EXIT trap
# stops (SIGINT, then SIGKILL); append the ones you start.
port=$((11400 + RANDOM % 500))
export ROS_MASTER_URI="http://localhost:$port"
export ROS_HOME="$1/ros_home"
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill -INT "$p" 2>/dev/null || true; done
  sleep 1
  for p in "${pids[@]}"; do kill -9 "$p" 2>/dev/null || true; done
}
trap cleanup EXIT
roscore -p "$port" > "$1/roscore.log" 2>&1 &
pids+=($!)
for _ in $(seq 50); do rosparam list > /dev/null 2>&1 && break; sleep 0.2; done
