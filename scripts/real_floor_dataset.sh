#!/usr/bin/env bash
# The real-floor dataset of make benchmark-real and make benchmark-kernels: ten photos from
# ../shared/real_floors (seven textured, three smooth concrete), each one bounded region at
# 0.5 mm per pixel, imaged by a 320 x 240 camera; queries on days 0 and 180 (40 per surface
# and day) with the floor's ageing model; the train split from eight other photos.
# With `heldout`: the photos the benchmark neither maps nor trains on (issue 28), plaster1
# (a training photo above) among them as a map, the vocabulary trained on the other seven.
# REAL_SEED (default 1) renders other query poses, ageing and debris (RESULTS.md: the spread
# over renderings). REAL_TRAIL=N gives each query a trail of N images before it (sequence
# queries: gtbow synth --query-trail; the queries themselves are the same).
# Usage: real_floor_dataset.sh GTBOW PHOTO_DIR DATA_DIR [heldout]
set -euo pipefail
gtbow="$1"; photos="$2"; data="$3"; which="${4:-benchmark}"
if [ ! -d "$photos" ]; then
  echo "real floors: no photo directory $photos (set REAL_FLOORS=DIR)" >&2
  exit 2
fi
map=(ufoai-textures_street001.png ufoai-textures_e8crete03.jpg ufoai-textures_concrete_g_11.jpg
     nexuiz-textures_gravel01.png nexuiz-textures_mudground04.png supertuxkart-data_Paving_stones_2.jpg
     lugaru-data_MossRock.jpg
     ufoai-textures_concrete_g_9.jpg nexuiz-textures_eX_cretebase_02.png nexuiz-textures_eX_cretebase_03_dark.png)
train=(ufoai-textures_street002.png nexuiz-textures_mudground03.png supertuxkart-data_road2.jpg
       ufoai-textures_concrete_s_1.jpg redeclipse-data_plaster1.jpg ufoai-textures_concrete003.png
       redeclipse-data_sand01_c.png redeclipse-data_redrock02.png)
if [ "$which" = heldout ]; then
  map=(lugaru-data_GrassDirt.jpg lugaru-data_Sand.jpg lugaru-data_Snow.jpg nexuiz-textures_sand.png
       redeclipse-data_carpet01.png ufoai-textures_desert009.png ufoai-textures_floor036.png
       ufoai-textures_grass_g_7.jpg ufoai-textures_tiles_m_5.jpg ufoai-textures_wood_b_10.jpg
       ufoai-textures_wood_b_3.jpg ufoai-textures_wood_b_9.jpg redeclipse-data_plaster1.jpg)
  train=("${train[@]/redeclipse-data_plaster1.jpg}")
fi
args=()
for f in "${map[@]}"; do args+=(--photo "$photos/$f"); done
for f in "${train[@]}"; do [ -n "$f" ] && args+=(--train-photo "$photos/$f"); done
"$gtbow" synth --out "$data" --force "${args[@]}" --width 320 --height 240 --meters-per-pixel 0.0005 \
  --queries 40 --days 0,180 --train 300 --seed "${REAL_SEED:-1}" ${REAL_TRAIL:+--query-trail "$REAL_TRAIL"} \
  ${REAL_SESSIONS:+--session-days "$REAL_SESSIONS" --session-images "${REAL_SESSION_IMAGES:-40}"} -q
