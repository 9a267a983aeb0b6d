#!/usr/bin/env bash
# Mirrors the repository (package root) into a catkin workspace's src/ as a directory of
# symlinks, one per top-level entry, leaving out build/ and hidden entries. Idempotent: run it
# before every build so that new top-level entries appear and removed ones disappear.
# Usage: link_package.sh REPO_ROOT WS_SRC_PACKAGE_DIR
set -euo pipefail
repo="$1"
dest="$2"
if [ -L "$dest" ]; then rm "$dest"; fi  # an older layout: one symlink to the whole repository
mkdir -p "$dest"
for entry in "$repo"/*; do
  name="$(basename "$entry")"
  [ "$name" = "build" ] && continue
  ln -sfn "$entry" "$dest/$name"
done
for link in "$dest"/*; do  # entries removed from the repository
  [ -L "$link" ] && [ ! -e "$link" ] && rm "$link"
done
exit 0
