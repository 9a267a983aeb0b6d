#!/usr/bin/env bash
# Installs every Debian package ground_texture_bow needs to build, test and run.
# Idempotent and non-interactive: packages already present are skipped, and apt is only
# touched when something is missing.
set -euo pipefail

PACKAGES=(
  # build tooling
  build-essential cmake pkg-config python3-catkin-pkg
  # ROS 1 from Debian
  ros-core-dev libcv-bridge-dev libimage-transport-dev
  libtf2-ros-dev libtf2-geometry-msgs-dev librosbag-dev librostest-dev python3-rostest
  libnodeletlib-dev libnodelet-dev ros-sensor-msgs ros-geometry-msgs ros-message-generation
  python3-rosbag python3-roslaunch python3-rosmaster
  libdiagnostic-updater-dev libvisualization-msgs-dev libnodeletlib-tools
  python3-geometry-msgs python3-sensor-msgs python3-std-msgs python3-tf2-msgs
  libnav-msgs-dev
  # core libraries
  libopencv-dev libflann-dev liblz4-dev libeigen3-dev libyaml-cpp-dev libcli11-dev
  # the pose-graph backend (src/backend)
  libceres-dev
  # tests and plots
  libgtest-dev libgmock-dev python3-matplotlib
  # make fuzz: clang with libFuzzer and the sanitizer runtimes; .ci/run: clang-format
  clang libclang-rt-14-dev clang-format
  # make test-sanitize: the ASan/UBSan/TSan runtimes, llvm-symbolizer for the TSan reports
  libasan8 libubsan1 libtsan2 llvm
)
# make screenshots (--screenshots): RViz under Xvfb, and ImageMagick's import to capture it.
if [ "${1:-}" = "--screenshots" ]; then
  PACKAGES+=(rviz xvfb imagemagick)
fi

missing=()
for p in "${PACKAGES[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "install_deps: all ${#PACKAGES[@]} packages already installed"
  exit 0
fi

echo "install_deps: installing ${#missing[@]} missing packages: ${missing[*]}"
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
echo "install_deps: done"
