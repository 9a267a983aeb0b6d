#!/usr/bin/env bash
# make benchmark-verification: issue 15's verification ablation (config/ablation/verification/
# and the presets) on the real floor photographs (make benchmark-real's dataset) and on the
# 4,000-image synthetic asphalt (make benchmark-authors' dataset), V = 20,000 each: every pose
# the top K candidates verify, the wrong ones (beyond 4.8 mm or 1.5 degrees), localization and
# the time verification takes. The table goes into docs/RESULTS.md (section "verification"),
# each preset beside its variant without descriptors into section "descriptors";
# every verification's evidence is in OUT/<dataset>/verifications.csv.
# Usage: benchmark_verification.sh GTBOW REAL_DATA S4K_DATA OUT_DIR
set -euo pipefail
export PATH="/usr/bin:$PATH"
gtbow="$1"; real="$2"; s4k="$3"; out="$4"
here="$(cd "$(dirname "$0")/.." && pwd)"
cfg="$here/config"
abl="$cfg/ablation/verification"
if [ ! -f "$real/dataset.yaml" ]; then
  echo "benchmark-verification: no $real; make benchmark-real renders it" >&2
  exit 2
fi
if [ ! -f "$s4k/dataset.yaml" ]; then
  "$gtbow" synth --out "$s4k" --database-images 4000 --train 300 --queries 100 --days 0,180 -q
fi
presets=(
  "$abl/ha_words.yaml" "$abl/ha_words_spread.yaml" "$abl/ha_words_fraction.yaml"
  "$abl/ha_words_angle.yaml" "$abl/ha_words_second.yaml" "$abl/ha_words_checks.yaml"
  "$abl/ha_descriptors.yaml" "$abl/ha_descriptors_sigma.yaml" "$abl/ha_descriptors_consensus.yaml"
  "$cfg/high_accuracy.yaml" "$abl/ha_no_descriptors.yaml"
  "$abl/fast_words.yaml" "$abl/fast_descriptors.yaml" "$cfg/fast.yaml" "$abl/fast_no_descriptors.yaml"
  "$cfg/paper_literal.yaml"
)
args=()
for p in "${presets[@]}"; do args+=(--preset "$p"); done
mkdir -p "$out"
"$gtbow" eval --dataset "$real" --words 20000 "${args[@]}" --out "$out/real" \
  --timing-queries 50 --no-plots -q > /dev/null
"$gtbow" eval --dataset "$s4k" --words 20000 "${args[@]}" --out "$out/s4k" \
  --timing-queries 50 --no-plots -q > /dev/null
# Sections "verification" and "descriptors" (each preset beside its variant without
# descriptors); exits non-zero when a claim is missed (scripts/targets.py, VERIFICATION).
/usr/bin/python3 "$here/scripts/write_verification_results.py" "$here/docs" \
  "real=$out/real/results.json" "s4k=$out/s4k/results.json"
