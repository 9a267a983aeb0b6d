#!/usr/bin/env bash
# make benchmark-authors: our presets side by side with the authors' choices (issue 14) on the
# dataset the issue measured napp-lab/GTBoW on: `gtbow synth --database-images 4000 --train 300
# --queries 100 --days 0,180` (seed 1), V = 20,000 trained on its train split, one thread for
# timing. Each of the authors' choices is evaluated alone on top of config/paper_literal.yaml and
# all together; the table goes into docs/RESULTS.md (section "authors").
# Usage: benchmark_authors.sh GTBOW DATA_DIR OUT_DIR
set -euo pipefail
export PATH="/usr/bin:$PATH"
gtbow="$1"; data="$2"; out="$3"
here="$(cd "$(dirname "$0")/.." && pwd)"
cfg="$here/config"
if [ ! -f "$data/dataset.yaml" ]; then
  "$gtbow" synth --out "$data" --database-images 4000 --train 300 --queries 100 --days 0,180
fi
presets=(
  "$cfg/paper_literal.yaml"
  "$cfg/ablation/authors/exact_search.yaml"
  "$cfg/ablation/authors/converged.yaml"
  "$cfg/ablation/authors/per_bin.yaml"
  "$cfg/ablation/authors/hamming_sigma580.yaml"
  "$cfg/ablation/authors/hamming.yaml"
  "$cfg/ablation/authors/all_authors_exact.yaml"
  "$cfg/authors.yaml"
  "$cfg/ablation/authors/ours_plain_orb.yaml"
  "$cfg/high_accuracy.yaml"
  "$cfg/paper_literal_fast.yaml"
  "$cfg/authors_fast.yaml"
  "$cfg/ablation/authors/fast_plain_orb.yaml"
  "$cfg/fast.yaml"
  "$cfg/dbow_baseline.yaml"
)
args=()
for p in "${presets[@]}"; do args+=(--preset "$p"); done
"$gtbow" eval --dataset "$data" --words 20000 "${args[@]}" --out "$out" --timing-queries 100 --no-plots
/usr/bin/python3 "$here/scripts/write_authors_results.py" "$out/results.json" "$here/docs"
