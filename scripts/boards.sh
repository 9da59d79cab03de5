#!/usr/bin/env bash
# Builds the firmware of both real boards (boards/: STM32H743, Alif Ensemble E7) in release,
# every build each has: the fast preset's (the default: census+lr+ref, no weights) and the
# learned preset's (feature `learned`: the weight blob linked), each on whole frames of the board's size (H743 160x120, E7
# 320x240: bino_board::options), and on the H743 each also on the embedded test frame
# (feature `test-frame`; the E7 always runs its test frame), and prints each build's memory
# regions' use next to their size. Nothing is flashed: the QEMU boards (scripts/firmware.sh) stay the ones that
# run. A region that overflows fails the link; this script checks the sums again from the ELF's
# section table.
#
#   scripts/boards.sh [--no-lint] [--out DIR]
#
#   --no-lint   skip rustfmt, clippy and the host tests of boards/common
#   --out DIR   also write each board's region use (its `learned` build, the one whose arena
#               and weights fill the memories) as
#               DIR/board-<board>.json (the committed ones: --out firmware-sim/measured;
#               docs/boards.md renders its table from them)
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
cd "$BINO_ROOT"

lint=1
out=""
while [ $# -gt 0 ]; do
  case "$1" in
    --no-lint) lint=0; shift ;;
    --out) out="$2"; mkdir -p "$out"; shift 2 ;;
    *) echo "unknown argument $1" >&2; exit 2 ;;
  esac
done

# Its own workspace and target directory, like the QEMU firmware's.
export CARGO_TARGET_DIR="$BINO_CACHE/boards-target"
installed="$(rustup target list --installed)"
for target in $THUMB_TARGETS; do
  grep -qx "$target" <<<"$installed" || rustup target add "$target"
done
rustup component list --installed | grep -q '^llvm-tools' || rustup component add llvm-tools
objdump="$(rustc --print sysroot)/lib/rustlib/$(rustc -vV | sed -n 's/^host: //p')/bin/llvm-objdump"

if [ "$lint" = 1 ]; then
  (cd boards && cargo fmt --all --check)
  (cd boards && cargo test -p bino-board --locked -q)
fi

# board:target:the feature sets of its other builds (each linted, built, its regions printed)
for board in stm32h7:thumbv7em-none-eabihf:"learned test-frame learned,test-frame" alif-e7:thumbv8m.main-none-eabihf:learned; do
  IFS=: read -r dir target others <<<"$board"
  echo "== boards/$dir ($target, release)"
  if [ "$lint" = 1 ]; then
    (cd "boards/$dir" && cargo clippy --locked --release -q -- -D warnings)
    for features in $others; do
      (cd "boards/$dir" && cargo clippy --locked --release -q --features "$features" -- -D warnings)
    done
  fi
  (cd "boards/$dir" && cargo build --locked --release -q)
  python3 scripts/board_regions.py --objdump "$objdump" --memory "boards/$dir/memory.x" \
    "$CARGO_TARGET_DIR/$target/release/bino-$dir"
  for features in $others; do
    echo "== boards/$dir ($target, release, --features $features)"
    (cd "boards/$dir" && cargo build --locked --release -q --features "$features")
    json=()
    [ -n "$out" ] && [ "$features" = learned ] && json=(--json "$out/board-$dir.json")
    python3 scripts/board_regions.py --objdump "$objdump" --memory "boards/$dir/memory.x" \
      "${json[@]}" "$CARGO_TARGET_DIR/$target/release/bino-$dir"
  done
done
