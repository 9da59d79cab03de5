#!/usr/bin/env bash
# The project's whole test suite: what CI runs, and what the README calls "the tests"
# (docs/testing.md).
#
#   scripts/test.sh           everything (installs what is missing first)
#   scripts/test.sh --quick   the contributor tier: the docs' figures, Rust format, lints and
#                             `cargo test --workspace`; no installs, fuzzing, Cortex-M builds,
#                             QEMU or Python steps (tests that need ../shared/data or the Python
#                             environment skip where they are missing, unless CI=true)
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
cd "$BINO_ROOT"

quick=0
case "${1:-}" in
  --quick) quick=1 ;;
  "") ;;
  *) echo "usage: scripts/test.sh [--quick]" >&2; exit 2 ;;
esac

step() { printf '\n== %s\n' "$*"; }

step "docs: every rendered table equals a fresh render of the measurement files"
python3 scripts/render_docs.py --check
python3 scripts/render_docs.py --self-test >/dev/null

if [ "$quick" = 1 ]; then
  step "rust: format and lints"
  cargo fmt --all --check
  cargo clippy --workspace --all-targets --locked -- -D warnings
  step "rust: tests"
  cargo test --workspace --locked
  step "quick tier passed"
  exit 0
fi

# The full suite has every input: a test whose ../shared/data or Python environment is
# missing fails instead of skipping.
export BINO_REQUIRE_DATA=1

step setup
scripts/setup.sh

step "rust: format and lints"
cargo fmt --all --check
cargo clippy --workspace --all-targets --locked -- -D warnings
# The engine's API documentation must build without broken links.
RUSTDOCFLAGS="-D warnings" cargo doc -p bino-core --no-deps --locked -q

step "rust: tests"
cargo test --workspace --locked

step "fuzzing: every target of fuzz/ for 30 s (cargo-fuzz, nightly), failing on any crash"
scripts/fuzz.sh --seconds "${BINO_FUZZ_SECONDS:-30}"

step "bino-core for the Cortex-M targets (no_std, no alloc)"
for target in $THUMB_TARGETS; do
  cargo build -p bino-core --locked --release --target "$target"
  # The optional integrations (depth, defmt) must build and lint clean there too.
  cargo clippy -p bino-core --locked --release --target "$target" --features depth,defmt -- -D warnings
done

step "examples: examples/board (host test of the firmware's digests, Cortex-M builds) and examples/host"
# Outside crates of their own (docs/integration.md, "Examples"); their own target folder, as the
# board example's Cortex-M builds carry its .cargo/config.toml's flags. bino-core's crate-docs
# example ran as a doctest in `cargo test --workspace` above.
(
  export CARGO_TARGET_DIR="$BINO_CACHE/target-examples"
  cd examples/board
  cargo fmt --check
  cargo clippy --locked --all-targets -- -D warnings
  cargo test --locked
  for target in $THUMB_TARGETS; do
    cargo clippy --locked --release --target "$target" -- -D warnings
    cargo build --locked --release --target "$target"
  done
  cd ../host
  cargo fmt --check
  cargo clippy --locked --all-targets -- -D warnings
  cargo test --locked
)

step "real boards: STM32H743 and Alif E7 firmware, release builds and memory-region use (nothing flashed)"
# boards/ (docs/boards.md): fmt, clippy, the host tests of bino-board, both builds,
# each region's use next to its size; a region that overflows fails.
scripts/boards.sh

step "firmware under QEMU: both cores, outputs bit-identical to the host, instruction counts"
# Cortex-M55 (mps3-an547) and Cortex-M7 (mps2-an500), one 48x160 band pair each (~4 min);
# results in out/firmware/ (docs/firmware.md), then the budget report of these runs.
scripts/firmware.sh
cargo run -q --locked -p bino-host --bin bino -- budget --firmware out/firmware \
  --json out/firmware/budget.json --md out/firmware/budget.md --png out/firmware/budget.png

step "python: format, lints, types, tests"
cd train
"$BINO_VENV/bin/ruff" format --check .
"$BINO_VENV/bin/ruff" check .
"$BINO_VENV/bin/mypy" bino_train
"$BINO_VENV/bin/python" -m pytest -p no:cacheprovider

step "training smoke: tiny pretraining + head, export, run both in tract"
# Seconds-long runs that exit non-zero unless their loss fell; the exports must load and run
# in tract through the same CLI path as the shipped weights.
smoke="$(mktemp -d)"
trap 'rm -rf "$smoke"' EXIT
py() { "$BINO_VENV/bin/python" -W ignore "$@"; }
py -m bino_train.pretrain --out "$smoke/pretrain" --smoke
py -m bino_train.export --checkpoint "$smoke/pretrain/last.pt" --out "$smoke/encoder.onnx"
py -m bino_train.head_train --encoder "$smoke/pretrain/last.pt" --out "$smoke/head" --smoke
py -m bino_train.head --checkpoint "$smoke/head/last.pt" --out "$smoke/head.onnx"
cd "$BINO_ROOT"
cargo run -q --locked -p bino-host --bin bino -- reference --profile native \
  --onnx "$smoke/encoder.onnx" --head "$smoke/head.onnx" --out "$smoke/reference.npz"
py -c "import numpy as np, sys; d = np.load(sys.argv[1])['disparity']; \
assert d.shape == (24, 40) and np.isfinite(d).all(), d.shape" "$smoke/reference.npz"

step "all tests passed"
