#!/usr/bin/env bash
# The project's whole test suite: what CI runs, and what the README calls "the tests".
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
cd "$BINO_ROOT"

step() { printf '\n== %s\n' "$*"; }

step setup
scripts/setup.sh

step "rust: format and lints"
cargo fmt --all --check
cargo clippy --workspace --all-targets --locked -- -D warnings

step "rust: tests"
cargo test --workspace --locked

step "bino-core for the Cortex-M targets (no_std, no alloc)"
for target in $THUMB_TARGETS; do
  cargo build -p bino-core --locked --release --target "$target"
done

step "python: format, lints, types, tests"
cd train
"$BINO_VENV/bin/ruff" format --check .
"$BINO_VENV/bin/ruff" check .
"$BINO_VENV/bin/mypy" bino_train
"$BINO_VENV/bin/python" -m pytest -p no:cacheprovider

step "all tests passed"
