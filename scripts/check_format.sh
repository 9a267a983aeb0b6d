#!/usr/bin/env bash
# Fails when a C++ file of the package differs from what clang-format (.clang-format) makes of
# it, listing the files. Fix with: clang-format -i FILE. Called by .ci/run before the tests.
set -uo pipefail
cd "$(dirname "$0")/.."
files=$(git ls-files '*.cpp' '*.h' '*.hpp' | grep -v '^test/fuzz/\(corpus\|seeds\|regressions\)/')
bad=()
for f in $files; do
  clang-format --dry-run --Werror "$f" > /dev/null 2>&1 || bad+=("$f")
done
if [ ${#bad[@]} -gt 0 ]; then
  echo "clang-format: ${#bad[@]} file(s) are not formatted (clang-format -i FILE):"
  printf '  %s\n' "${bad[@]}"
  exit 1
fi
echo "clang-format: $(echo "$files" | wc -l) files formatted"
