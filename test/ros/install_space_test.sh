#!/usr/bin/env bash
# The package from an install space (catkin_make install), with no devel space or source tree
# on the ROS package path: the nodelet loads, finds its default preset in the install space's
# share directory, and serves; the installed gtbow takes its defaults from there too. Writes a JUnit result for the test summary.
# Usage: install_space_test.sh INSTALL_DIR VOCABULARY RESULT_XML
set -uo pipefail
install="$1"
vocab="$2"
xml="$3"
here="$(cd "$(dirname "$0")/../../scripts" && pwd)"
work="$(mktemp -d)"
failure=""
run() {
  env -i HOME="$HOME" PATH=/usr/bin:/bin bash -c "set +u; source '$install/setup.bash'; $1"
}
expected="$install/share/ground_texture_bow/config/high_accuracy.yaml"
[ -f "$expected" ] || failure="no $expected"
for b in bin/gtbow bin/gtbow_images_to_bag bin/gtbow_bag_to_dataset \
         lib/ground_texture_bow/localizer_node; do
  [ -x "$install/$b" ] || failure="${failure:+$failure; }no $b installed"
done
if [ -z "$failure" ]; then
  out="$(run "
    source '$here/private_roscore.sh' '$work'
    echo \"package: \$(rospack find ground_texture_bow)\"
    roslaunch ground_texture_bow localizer.launch vocabulary:='$vocab' > '$work/launch.log' 2>&1 &
    pids+=(\$!)
    for _ in \$(seq 150); do
      rosservice list 2>/dev/null | grep -qx /localizer/get_info && break
      sleep 0.2
    done
    rosservice call /localizer/get_info
  " 2>&1)"
  echo "$out" | grep -q "package: $install/share/ground_texture_bow" ||
    failure="rospack does not find the installed package: $out"
  echo "$out" | grep -q "preset: \"$expected\"" ||
    failure="${failure:+$failure; }the node's preset is not the installed one: $out $(tail -5 "$work/launch.log" 2>/dev/null)"  # gtbow (ROS-free) finds its presets and parameter files beside itself, not in the source tree.
  tools="$(run "'$install/bin/gtbow' slam --help" 2>&1)"
  echo "$tools" | grep -q "$install/share/ground_texture_bow/config/localizer.yaml" ||
    failure="${failure:+$failure; }gtbow's default parameter files are not the installed ones: $(echo "$tools" | grep -- --params)"
fi
mkdir -p "$(dirname "$xml")"
if [ -z "$failure" ]; then
  cat > "$xml" <<XML
<?xml version="1.0" encoding="UTF-8"?>
<testsuite name="install_space" tests="1" failures="0" errors="0"><testcase classname="InstallSpace" name="TheNodeRunsFromAnInstallSpaceWithItsPreset"/></testsuite>
XML
  echo "install space: the nodelet runs from $install with $expected"
else
  # Printable characters only (the output carries terminal colour codes), on one line, escaped.
  msg="$(printf '%s' "$failure" | tr '\n' ' ' | tr -cd '[:print:]' | cut -c1-2000 |
    sed 's/&/\&amp;/g; s/</\&lt;/g; s/>/\&gt;/g; s/"/\&quot;/g')"
  cat > "$xml" <<XML
<?xml version="1.0" encoding="UTF-8"?>
<testsuite name="install_space" tests="1" failures="1" errors="0"><testcase classname="InstallSpace" name="TheNodeRunsFromAnInstallSpaceWithItsPreset"><failure message="$msg">$msg</failure></testcase></testsuite>
XML
  echo "install space: FAILED: $failure"
fi
rm -rf "$work"
