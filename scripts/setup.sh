#!/usr/bin/env bash
# Installs what a fresh machine lacks; cheap to re-run (every step checks first).
#   - Rust targets for the Cortex-M builds of bino-core
#   - rustfmt and clippy
#   - a Python virtual environment for train/ ($BINO_VENV), reinstalled when requirements change
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"

command -v cargo >/dev/null || { echo "error: cargo not found; install Rust (rustup) first" >&2; exit 1; }
installed="$(rustup target list --installed)"
for target in $THUMB_TARGETS; do
  grep -qx "$target" <<<"$installed" || rustup target add "$target"
done
for component in rustfmt clippy; do
  rustup component list --installed | grep -q "^$component" || rustup component add "$component"
done

requirements="$BINO_ROOT/train/requirements.txt"
stamp="$BINO_VENV/.requirements.sha256"
want="$(sha256sum "$requirements" | cut -d' ' -f1)"
if [ ! -x "$BINO_VENV/bin/python" ] || [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
  echo "setting up the Python environment in $BINO_VENV (torch is a large download)"
  python3 -m venv "$BINO_VENV"
  "$BINO_VENV/bin/pip" install --quiet --upgrade pip
  "$BINO_VENV/bin/pip" install --quiet -r "$requirements"
  echo "$want" > "$stamp"
fi
