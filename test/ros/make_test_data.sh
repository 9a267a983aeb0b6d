#!/usr/bin/env bash
# Generates the data the rostests replay: a small synthetic asphalt floor, a vocabulary trained
# on its separate training area (and a second one), and bags (database with TF: a mapping run; day-30 queries
# without TF: a robot that must localize globally), and a larger floor for large_map.test.
# Usage: make_test_data.sh GTBOW GTBOW_IMAGES_TO_BAG OUT_DIR
set -euo pipefail
GTBOW="$1"
TO_BAG="$2"
OUT="$3"
rm -rf "$OUT.partial"
mkdir -p "$OUT.partial"
"$GTBOW" synth --out "$OUT.partial/floor" --area 0.4 0.3 --train 30 --queries 20 --days 0,30 -q
"$GTBOW" train-vocab --dataset "$OUT.partial/floor" --words 2000 --out "$OUT.partial/vocab.gtvoc" -q
# Another vocabulary for the same preset (fewer words, another seed): a map made with
# vocab.gtvoc must be refused by a nodelet that starts with this one.
"$GTBOW" train-vocab --dataset "$OUT.partial/floor" --words 500 --seed 2 \
  --out "$OUT.partial/other_vocab.gtvoc" -q
"$TO_BAG" --dataset "$OUT.partial/floor" --split database \
  --out "$OUT.partial/mapping.bag" -q > /dev/null
"$TO_BAG" --dataset "$OUT.partial/floor" --split query_day030 --no-tf \
  --out "$OUT.partial/localization.bag" -q > /dev/null
# backend.test: a 4 m drive (three laps) with wheel odometry drifting by centimetres, the
# camera mounted ahead of and turned against the base (so that the backend's conversion of
# closures from the camera to the base frame is exercised).
"$GTBOW" synth --out "$OUT.partial/drive" --area 0.7 0.5 --train 0 --queries 0 --drive 4 \
  --only drive --odom-heading-bias 0.004 --odom-turn-bias 0.01 -q > /dev/null
"$TO_BAG" --dataset "$OUT.partial/drive" --split drive \
  --odometry "$OUT.partial/drive/drive_odometry.csv" --camera-offset 0.12 0.03 1.5708 \
  --out "$OUT.partial/drive.bag" -q > /dev/null
# large_map.test: a map of about 2,000 keyframes (every image of a lawnmower run over a 1.26 m
# square), small cheap images (320 x 240, no supersampling) of the same kind of floor as
# vocab.gtvoc's; the nodes' ~meters_per_pixel in large_map.test must match this one.
"$GTBOW" synth --out "$OUT.partial/many" --database-images 2000 --width 320 --height 240 \
  --meters-per-pixel 0.00025 --supersample 1 --train 0 --queries 20 --days 30 -q > /dev/null
"$TO_BAG" --dataset "$OUT.partial/many" --split database \
  --out "$OUT.partial/many_mapping.bag" -q > /dev/null
"$TO_BAG" --dataset "$OUT.partial/many" --split query_day030 --no-tf \
  --out "$OUT.partial/many_queries.bag" -q > /dev/null
# The bags hold the images; only the dataset's description (dataset.yaml: meters_per_pixel) and
# ground truth are kept.
rm -rf "$OUT.partial/many/images"
rm -rf "$OUT"
mv "$OUT.partial" "$OUT"
