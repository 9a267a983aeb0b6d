#!/usr/bin/env bash
# make benchmark-real: the presets on datasets cut from real photographs of floors (issue 14).
# Ten surfaces from ../shared/real_floors (seven textured, three smooth concrete), each photo one
# bounded region at 0.5 mm per pixel, imaged by a 320 x 240 camera at 0.5 mm per pixel;
# queries on days 0 and 180 (40 per surface and day) at random poses, with the floor's ageing
# model; the train split from eight other photos set aside for it. The per-surface tables go
# into docs/RESULTS.md (section "real"), with the features ablation (config/ablation/features).
# Sequence queries (issue 28: each query with the images its trail holds, 3 and 5 in all) on
# the ten photos, and changing_floors on three more renderings of them. Then the low-contrast
# synthetic surfaces (smooth_concrete, epoxy) with the same presets, and the held-out
# photographs (issue 28: high_accuracy beside changing_floors), singly and in sequences. And the
# maintained map (issue 28): the robot's sessions on days 30 and 90 (40 images per photo) keep the
# map up (gtbow eval --maintain, the node's maintenance mode) before day 180 is queried, on every
# rendering, the synthetic surfaces and the held-out photos.
# write_real_results.py checks the ten surfaces, every split, the targets and the plain-ORB
# contrast on smooth concrete (scripts/targets.py, REAL); it exits non-zero, and so does this
# script, when an input is absent or a claim is missed.
# Usage: benchmark_real.sh GTBOW PHOTO_DIR DATA_DIR OUT_DIR
set -euo pipefail
export PATH="/usr/bin:$PATH"
gtbow="$1"; photos="$2"; data="$3"; out="$4"
here="$(cd "$(dirname "$0")/.." && pwd)"
cfg="$here/config"
if [ ! -d "$photos" ]; then
  echo "benchmark-real: no photo directory $photos (set REAL_FLOORS=DIR)" >&2
  exit 2
fi
# Every query with a trail of 4 images before it (sequence queries; the single-image figures
# are those of the same queries without it).
export REAL_TRAIL=4
# The robot's localization sessions on days 30 and 90, for the maintained map (the other splits
# are the same with or without them).
export REAL_SESSIONS=30,90
maint=(--maintain session_day030,session_day090)
mt=()
bash "$here/scripts/real_floor_dataset.sh" "$gtbow" "$photos" "$data"
"$gtbow" eval --dataset "$data" --words 20000 --preset "$cfg/high_accuracy.yaml" --preset "$cfg/fast.yaml" \
  --preset "$cfg/paper_literal.yaml" --preset "$cfg/paper_literal_fast.yaml" --preset "$cfg/authors.yaml" \
  --preset "$cfg/ablation/authors/ours_plain_orb.yaml" --preset "$cfg/dbow_baseline.yaml" \
  --preset "$cfg/ablation/features/clahe_only.yaml" --preset "$cfg/ablation/features/grid_only.yaml" \
  --preset "$cfg/ablation/features/normalize_grid.yaml" --preset "$cfg/ablation/features/adaptive_threshold.yaml" \
  --preset "$cfg/ablation/features/grid_refill.yaml" --preset "$cfg/ablation/features/dense_400.yaml" \
  --preset "$cfg/changing_floors.yaml" --preset "$cfg/ablation/changing/no_min_spread.yaml" \
  --preset "$cfg/ablation/changing/no_guided.yaml" \
  --preset "$cfg/ablation/changing/query_only.yaml" \
  --preset "$cfg/ablation/changing/transient_only.yaml" --preset "$cfg/ablation/changing/both_polarities.yaml" \
  --preset "$cfg/ablation/changing/six_inliers.yaml" --preset "$cfg/ablation/changing/guided.yaml" \
  --preset "$cfg/ablation/changing/guided_repeat_check.yaml" --preset "$cfg/ablation/changing/no_escalate.yaml" --preset "$cfg/ablation/changing/no_backoff.yaml" --preset "$cfg/ablation/changing/no_plain_repeat.yaml" --out "$out" --timing-queries 20 --no-plots -q
# Sequence queries (issue 28): each query with the 2 and 4 images before it, through odometry.
seq=()
for n in 3 5; do
  "$gtbow" eval --dataset "$data" --words 20000 --preset "$cfg/high_accuracy.yaml" \
    --preset "$cfg/changing_floors.yaml" --sequence "$n" --out "$out-sequence$n" --timing-queries 20 \
    --no-plots -q > /dev/null
  seq+=(--sequence "$out-sequence$n/results.json")
done
# The ablation: the combined view only, not the query alone first (--sequence-always).
"$gtbow" eval --dataset "$data" --words 20000 --preset "$cfg/high_accuracy.yaml" \
  --preset "$cfg/changing_floors.yaml" --sequence 5 --sequence-always --out "$out-sequence5-always" \
  --timing-queries 0 --no-plots -q > /dev/null
seq+=(--sequence "$out-sequence5-always/results.json")
# The maintained map: single images (high_accuracy and changing_floors) and 5-image sequences.
"$gtbow" eval --dataset "$data" --words 20000 --preset "$cfg/high_accuracy.yaml" \
  --preset "$cfg/changing_floors.yaml" "${maint[@]}" --out "$out-maintained" --timing-queries 0 \
  --no-plots -q > /dev/null
"$gtbow" eval --dataset "$data" --words 20000 --preset "$cfg/changing_floors.yaml" "${maint[@]}" \
  --sequence 5 --out "$out-maintained-sequence5" --timing-queries 0 --no-plots -q > /dev/null
mt+=(--maintained "$out-maintained/results.json" --maintained "$out-maintained-sequence5/results.json")
# The same on three more renderings of the ten photos (other query poses, ageing and debris):
# changing_floors alone, single images and 5-image sequences.
for s in 2 3 4; do
  REAL_SEED=$s bash "$here/scripts/real_floor_dataset.sh" "$gtbow" "$photos" "$data-seed$s"
  for n in 1 5; do
    "$gtbow" eval --dataset "$data-seed$s" --words 20000 --preset "$cfg/changing_floors.yaml" \
      --sequence "$n" --out "$out-seed$s-sequence$n" --timing-queries 0 --no-plots -q > /dev/null
    seq+=(--sequence "$out-seed$s-sequence$n/results.json")
    "$gtbow" eval --dataset "$data-seed$s" --words 20000 --preset "$cfg/changing_floors.yaml" \
      "${maint[@]}" --sequence "$n" --out "$out-seed$s-maintained$n" --timing-queries 0 --no-plots \
      -q > /dev/null
    mt+=(--maintained "$out-seed$s-maintained$n/results.json")
  done
done
# The low-contrast synthetic surfaces (0.6 x 0.6 m each, 640 x 480 at 0.25 mm per pixel).
lc=()
for surface in smooth_concrete epoxy; do
  "$gtbow" synth --out "$data-$surface" --force --surface "$surface" --area 0.6 0.6 --train 100 \
    --queries 30 --days 0,180 --query-trail 4 --session-days 30,90 -q > /dev/null
  "$gtbow" eval --dataset "$data-$surface" --words 5000 --preset "$cfg/high_accuracy.yaml" \
    --preset "$cfg/fast.yaml" --preset "$cfg/paper_literal.yaml" --preset "$cfg/authors.yaml" \
    --preset "$cfg/changing_floors.yaml" --preset "$cfg/ablation/changing/no_min_spread.yaml" \
  --preset "$cfg/ablation/changing/no_guided.yaml" \
    --preset "$cfg/ablation/changing/query_only.yaml" \
    --preset "$cfg/ablation/changing/transient_only.yaml" --preset "$cfg/ablation/changing/both_polarities.yaml" \
    --preset "$cfg/ablation/changing/guided.yaml" --preset "$cfg/ablation/changing/guided_repeat_check.yaml" --preset "$cfg/ablation/changing/no_escalate.yaml" --preset "$cfg/ablation/changing/no_backoff.yaml" --preset "$cfg/ablation/changing/no_plain_repeat.yaml" \
    --out "$out-$surface" --timing-queries 20 --timing-alternate --no-plots -q > /dev/null
  lc+=("$out-$surface/results.json")
  for n in 3 5; do
    "$gtbow" eval --dataset "$data-$surface" --words 5000 --preset "$cfg/high_accuracy.yaml" \
      --preset "$cfg/changing_floors.yaml" --sequence "$n" --out "$out-$surface-sequence$n" \
      --timing-queries 20 --no-plots -q > /dev/null
    seq+=(--sequence "$out-$surface-sequence$n/results.json")
  done
  for n in 1 5; do
    "$gtbow" eval --dataset "$data-$surface" --words 5000 --preset "$cfg/changing_floors.yaml" \
      "${maint[@]}" --sequence "$n" --out "$out-$surface-maintained$n" --timing-queries 0 \
      --no-plots -q > /dev/null
    mt+=(--maintained "$out-$surface-maintained$n/results.json")
  done
done
# The held-out photographs (issue 28): never used to design the presets.
bash "$here/scripts/real_floor_dataset.sh" "$gtbow" "$photos" "$data-heldout" heldout
"$gtbow" eval --dataset "$data-heldout" --words 20000 --preset "$cfg/high_accuracy.yaml" \
  --preset "$cfg/changing_floors.yaml" --preset "$cfg/ablation/changing/no_min_spread.yaml" \
  --preset "$cfg/ablation/changing/no_guided.yaml" \
  --preset "$cfg/ablation/changing/six_inliers.yaml" \
  --preset "$cfg/ablation/changing/guided.yaml" --preset "$cfg/ablation/changing/guided_repeat_check.yaml" --preset "$cfg/ablation/changing/no_escalate.yaml" --preset "$cfg/ablation/changing/no_backoff.yaml" --preset "$cfg/ablation/changing/no_plain_repeat.yaml" \
  --out "$out-heldout" --timing-queries 0 --no-plots -q > /dev/null
"$gtbow" eval --dataset "$data-heldout" --words 20000 --preset "$cfg/high_accuracy.yaml" \
  --preset "$cfg/changing_floors.yaml" --sequence 5 --out "$out-heldout-sequence5" \
  --timing-queries 0 --no-plots -q > /dev/null
"$gtbow" eval --dataset "$data-heldout" --words 20000 --preset "$cfg/high_accuracy.yaml" \
  --preset "$cfg/changing_floors.yaml" --sequence 5 --sequence-always \
  --out "$out-heldout-sequence5-always" --timing-queries 0 --no-plots -q > /dev/null
seq+=(--sequence "$out-heldout/results.json" --sequence "$out-heldout-sequence5/results.json")
seq+=(--sequence "$out-heldout-sequence5-always/results.json")
for n in 1 5; do
  "$gtbow" eval --dataset "$data-heldout" --words 20000 --preset "$cfg/changing_floors.yaml" \
    "${maint[@]}" --sequence "$n" --out "$out-heldout-maintained$n" --timing-queries 0 --no-plots \
    -q > /dev/null
  mt+=(--maintained "$out-heldout-maintained$n/results.json")
done
/usr/bin/python3 "$here/scripts/write_real_results.py" --heldout "$out-heldout/results.json" \
  "${seq[@]}" "${mt[@]}" "$out/results.json" "$here/docs" "${lc[@]}"
