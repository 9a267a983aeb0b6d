#!/usr/bin/env bash
# make benchmark-keypoints: what the map's quantised keypoints cost verification (issue 17). The
# node's map stores each keyframe's keypoints in 8 bytes (x and y in steps of max(w, h) / 65535
# px, ...); `gtbow eval` verifies against those stored keypoints, with --exact-keypoints against
# the unquantised ones. Both runs on the real floor photographs (make benchmark-real's dataset),
# the same vocabularies (the feature and vocabulary cache), then every verified pose of one run
# compared with the other's (verifications.csv): docs/RESULTS.md, section "keypoints". Exits
# non-zero when a claim is missed (scripts/targets.py, KEYPOINTS). About 25 s with make
# benchmark-real's feature and vocabulary cache.
# Usage: benchmark_keypoints.sh GTBOW REAL_DATA OUT_DIR
set -euo pipefail
export PATH="/usr/bin:$PATH"
gtbow="$1"; real="$2"; out="$3"
here="$(cd "$(dirname "$0")/.." && pwd)"
cfg="$here/config"
if [ ! -f "$real/dataset.yaml" ]; then
  echo "benchmark-keypoints: no $real; make benchmark-real renders it" >&2
  exit 2
fi
args=(--preset "$cfg/high_accuracy.yaml" --preset "$cfg/fast.yaml" --preset "$cfg/paper_literal.yaml")
mkdir -p "$out"
"$gtbow" eval --dataset "$real" --words 20000 "${args[@]}" --out "$out/stored" \
  --timing-queries 5 --no-plots -q > /dev/null
"$gtbow" eval --dataset "$real" --words 20000 "${args[@]}" --out "$out/exact" --exact-keypoints \
  --timing-queries 5 --no-plots -q > /dev/null
/usr/bin/python3 "$here/scripts/write_keypoint_results.py" "$here/docs" "$out/stored" "$out/exact"
