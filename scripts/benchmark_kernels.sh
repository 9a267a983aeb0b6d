#!/usr/bin/env bash
# make benchmark-kernels: the timings under every Hamming kernel this CPU runs (GTBOW_SIMD =
# avx512, avx2, popcnt, portable), on make benchmark-real's real-floor dataset (320 x 240,
# 1,278 images), one thread for timing, as the issue on robot computers measured:
#  - the vocabulary training, V = 20,000 on 240 of the train images, one thread, under each
#    kernel (and under avx2 without the triangle bound of k-means); the vocabularies must be
#    byte-identical, or the script fails;
#  - gtbow eval with that vocabulary, high accuracy and fast (and high accuracy with the
#    triangle bound at query time), once under each GTBOW_SIMD: every answer of every kernel
#    must equal the portable kernel's (rankings and poses are compared);
#  - the timings, in one more eval: each of QUERIES (default 200) random queries runs through
#    every stage under each kernel in turn (--timing-kernels, the order rotating), so that a
#    change in the machine's speed falls on every kernel alike; with them, the presets probing
#    fewer word lists (config/ablation/search/*_nprobe*.yaml), for the search's effort against
#    its accuracy.
# write_kernels.py puts the medians and the targets into docs/RESULTS.md (section "kernels").
# Usage: benchmark_kernels.sh GTBOW PHOTO_DIR DATA_DIR OUT_DIR
set -euo pipefail
export PATH="/usr/bin:$PATH"
gtbow="$1"; photos="$2"; data="$3"; out="$4"
queries="${QUERIES:-200}"
here="$(cd "$(dirname "$0")/.." && pwd)"
cfg="$here/config"
[ -f "$data/dataset.yaml" ] || bash "$here/scripts/real_floor_dataset.sh" "$gtbow" "$photos" "$data"
mkdir -p "$out"
# The CPU, for the report (the claim against the authors' quoted timing holds for its CPU only).
# With its family and model (AMD's first Zen cores, family 23 below model 48, run the popcnt
# kernel rather than avx2 by default).
printf '%s (family %s, model %s)\n' "$(sed -n 's/^model name[[:space:]]*: //p' /proc/cpuinfo | head -1)" \
  "$(sed -n 's/^cpu family[[:space:]]*: //p' /proc/cpuinfo | head -1)" \
  "$(sed -n 's/^model[[:space:]]*: //p' /proc/cpuinfo | head -1)" > "$out/cpu.txt"
# A kernel this CPU lacks runs the next one down; write_kernels.py reads the kernel each run
# reports and keeps one row per kernel.
kernels=(portable popcnt avx2 avx512)
train() {  # KERNEL PRESET NAME
  GTBOW_SIMD="$1" "$gtbow" train-vocab --dataset "$data" --split train --preset "$2" --words 20000 \
    --max-images 240 -j 1 -q -o "$out/vocab_$3.bin" | tee "$out/train_$3.txt"
}
for k in "${kernels[@]}"; do
  echo "benchmark-kernels: training under $k"
  train "$k" "$cfg/high_accuracy.yaml" "$k"
done
train avx2 "$cfg/ablation/search/high_accuracy_bound.yaml" avx2_no_bound
for k in "${kernels[@]}" avx2_no_bound; do
  if ! cmp -s "$out/vocab_portable.bin" "$out/vocab_$k.bin"; then
    echo "benchmark-kernels: the vocabulary trained under $k differs from the portable kernel's" >&2
    exit 1
  fi
done
presets=(--preset "$cfg/high_accuracy.yaml" --preset "$cfg/fast.yaml"
         --preset "$cfg/ablation/search/high_accuracy_bound.yaml")
for k in "${kernels[@]}"; do
  echo "benchmark-kernels: the answers under $k"
  GTBOW_SIMD="$k" "$gtbow" eval --dataset "$data" --vocab "$out/vocab_portable.bin" "${presets[@]}" \
    --timing-queries 1 --no-plots -q --no-cache -j 0 --dump-rankings "$out/rankings_$k.csv" \
    --dump-poses "$out/poses_$k.csv" --out "$out/eval_$k" > /dev/null
done
echo "benchmark-kernels: the timings, every kernel on each of $queries queries"
# With them, the same presets probing fewer word lists (the search's effort against accuracy).
search=()
for f in high_accuracy_nprobe24 high_accuracy_nprobe16 high_accuracy_nprobe12 fast_nprobe16; do
  search+=(--preset "$cfg/ablation/search/$f.yaml")
done
"$gtbow" eval --dataset "$data" --vocab "$out/vocab_portable.bin" "${presets[@]}" "${search[@]}" \
  --timing-queries "$queries" --timing-kernels "${kernels[@]}" --no-plots -q --no-cache -j 0 \
  --out "$out/eval_timing" > /dev/null
for k in "${kernels[@]}"; do
  for f in "$out"/rankings_portable.*.csv "$out"/poses_portable.*.csv; do
    if ! cmp -s "$f" "${f/_portable./_$k.}"; then
      echo "benchmark-kernels: ${f/_portable./_$k.} differs from the portable kernel's answers" >&2
      exit 1
    fi
  done
done
echo "benchmark-kernels: every kernel's vocabulary, rankings and poses equal the portable kernel's"
/usr/bin/python3 "$here/scripts/write_kernels.py" "$out" "$here/docs"
