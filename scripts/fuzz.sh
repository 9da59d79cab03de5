#!/usr/bin/env bash
# Coverage-guided fuzzing of bino-core (cargo-fuzz / libFuzzer, overflow checks on).
#   scripts/fuzz.sh                    every target for 30 s (what CI runs)
#   scripts/fuzz.sh --minutes 20       every target for 20 minutes
#   scripts/fuzz.sh --seconds 5 pipeline readouts
# Fails on any crash (panic, overflow, timeout, out of memory); a crash's input is kept in
# fuzz/artifacts/TARGET/ and its path printed. The working corpus grows in fuzz/corpus/
# (not committed); fuzz/seeds/ is the committed seed corpus. A summary (executions, coverage,
# corpus, crashes per target) goes to out/fuzz/summary.tsv.
# Installs a pinned nightly toolchain (rustup) and cargo-fuzz when missing.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
cd "$BINO_ROOT/fuzz"

TOOLCHAIN="${BINO_FUZZ_TOOLCHAIN:-nightly-2026-10-30}"
CARGO_FUZZ_VERSION=0.13.2
seconds=30
targets=()
while [ $# -gt 0 ]; do
  case "$1" in
    --seconds) seconds="$2"; shift 2 ;;
    --minutes) seconds=$(( $2 * 60 )); shift 2 ;;
    -h|--help) sed -n '2,11p' "${BASH_SOURCE[0]}"; exit 0 ;;
    -*) echo "error: unknown option $1 (see --help)" >&2; exit 2 ;;
    *) targets+=("$1"); shift ;;
  esac
done

rustup toolchain list | grep -q "^$TOOLCHAIN" || rustup toolchain install "$TOOLCHAIN" --profile minimal
if ! cargo fuzz --version 2>/dev/null | grep -q "$CARGO_FUZZ_VERSION"; then
  cargo install cargo-fuzz --version "$CARGO_FUZZ_VERSION" --locked
fi
# Its own target folder: sanitizer builds share nothing with the workspace's.
export CARGO_TARGET_DIR="$BINO_CACHE/fuzz-target"
[ ${#targets[@]} -gt 0 ] || mapfile -t targets < <(cargo "+$TOOLCHAIN" fuzz list)
cargo "+$TOOLCHAIN" fuzz build -O

summary="$BINO_ROOT/out/fuzz/summary.tsv"
mkdir -p "$(dirname "$summary")" logs
printf 'target\tseconds\texecutions\tcoverage\tfeatures\tcorpus\tcrashes\n' > "$summary"
failed=0
for target in "${targets[@]}"; do
  mkdir -p "corpus/$target" "seeds/$target" "artifacts/$target"
  log="logs/$target.log"
  # -timeout: one input running 10 s counts as a hang; -rss_limit_mb: memory as a crash.
  if cargo "+$TOOLCHAIN" fuzz run -O "$target" "corpus/$target" "seeds/$target" -- \
      -max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 -print_final_stats=1 \
      -artifact_prefix="artifacts/$target/" >"$log" 2>&1; then
    crashes=0
  else
    crashes=1
    failed=1
    echo "CRASH in $target (log: fuzz/$log):" >&2
    grep -E "panicked|ERROR|SUMMARY|Test unit written" "$log" | head -5 >&2 || tail -20 "$log" >&2
  fi
  execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
  cov=$(grep -oE 'cov: [0-9]+ ft: [0-9]+ corp: [0-9]+' "$log" | tail -1 || true)
  read -r _ c _ f _ k <<<"${cov:-x 0 x 0 x 0}"
  printf '%s\t%s\t%s\t%s\t%s\t%s\t%s\n' "$target" "$seconds" "${execs:-0}" "$c" "$f" "$k" "$crashes" >> "$summary"
  printf '%-14s %6s s  %10s executions  coverage %5s  features %6s  corpus %5s  crashes %s\n' \
    "$target" "$seconds" "${execs:-0}" "$c" "$f" "$k" "$crashes"
done
exit "$failed"
