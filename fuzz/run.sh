#!/usr/bin/env bash
# Runs both fuzz targets for SECONDS each (default 1800), growing fuzz/corpus/<target>/.
# Needs cargo-fuzz (cargo install cargo-fuzz); RUSTC_BOOTSTRAP lets the stable toolchain build
# the sanitizer-coverage instrumentation. Findings land in fuzz/artifacts/<target>/.
set -euo pipefail
cd "$(dirname "$0")"
seconds=${1:-1800}
for target in clip model; do
  mkdir -p "corpus/$target" "artifacts/$target" "logs"
  RUSTC_BOOTSTRAP=1 cargo fuzz run --sanitizer none -O "$target" "corpus/$target" -- \
    -max_total_time="$seconds" -rss_limit_mb=2048 -malloc_limit_mb=1024 -timeout=10 \
    -print_final_stats=1 2>&1 | tee "logs/$target.log" | grep -E "^#[0-9]+.*(pulse|DONE)|ERROR|panicked|SUMMARY|stat::" || true
done
